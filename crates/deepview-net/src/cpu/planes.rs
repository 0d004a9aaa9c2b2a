//! Plane buffers and threads shared by the CPU operations (`ops`), the packed net (`packed`) and the
//! fused net (`fused`): one thread's scratch planes ([`Planes`]), work dealt to one task per rayon thread
//! ([`per_thread`], [`for_each_chunk_with`]) and the element-wise maximum of planes ([`max_into`]).

use deepview_kernels::{Act, Plane, elu_backward, relu_backward};
use rayon::prelude::*;

/// Scratch planes of one thread.
pub(crate) struct Planes {
    pub(crate) plane: Plane,
    pub(crate) bufs: Vec<Vec<f32>>,
}

impl Planes {
    pub(crate) fn new(plane: Plane, n: usize) -> Self {
        Self {
            plane,
            bufs: (0..n).map(|_| plane.zeroed()).collect(),
        }
    }
    /// Pad `c` channels of an unpadded `[c][h][w]` block into planes `from..from + c`.
    pub(crate) fn load(&mut self, from: usize, src: &[f32]) {
        let hw = self.plane.h * self.plane.w;
        for (k, img) in src.chunks_exact(hw).enumerate() {
            self.plane.pad_into(img, &mut self.bufs[from + k]);
        }
    }
    /// Pad the gradient at `c` output channels (`grad`, unpadded `[c][h][w]`) into planes `from..from +
    /// c`, multiplied by the activation's derivative (from its output `out`) on the way.
    pub(crate) fn load_act_grad(&mut self, from: usize, grad: &[f32], out: &[f32], act: Act) {
        let hw = self.plane.h * self.plane.w;
        let w = self.plane.w;
        for (k, (g, o)) in grad.chunks_exact(hw).zip(out.chunks_exact(hw)).enumerate() {
            let dst = &mut self.bufs[from + k];
            for (y, (gr, or)) in g.chunks_exact(w).zip(o.chunks_exact(w)).enumerate() {
                let i = self.plane.index(y, 0);
                let row = &mut dst[i..i + w];
                row.copy_from_slice(gr);
                match act {
                    Act::Linear => {}
                    Act::Elu => elu_backward(or, row),
                    Act::Relu => relu_backward(or, row),
                }
            }
        }
    }
    pub(crate) fn split(&mut self, at: usize) -> (Vec<&[f32]>, Vec<&mut [f32]>) {
        let (a, b) = self.bufs.split_at_mut(at);
        (
            a.iter().map(|v| v.as_slice()).collect(),
            b.iter_mut().map(|v| v.as_mut_slice()).collect(),
        )
    }
}

/// `f(state, item)` for every item, the items dealt round-robin to one task per rayon thread, each with
/// one `init()` state, made only for a task with items (rayon's `for_each_init` / `fold` may call `init`
/// once per split: for plane-sized scratch that is hundreds of MB zeroed again and again). The tasks'
/// states, in thread order.
pub(crate) fn per_thread<T, S, I, F>(items: impl IntoIterator<Item = T>, init: I, f: F) -> Vec<S>
where
    T: Send,
    S: Send,
    I: Fn() -> S + Sync,
    F: Fn(&mut S, T) + Sync,
{
    let threads = rayon::current_num_threads().max(1);
    let mut groups: Vec<Vec<T>> = (0..threads).map(|_| Vec::new()).collect();
    for (i, item) in items.into_iter().enumerate() {
        groups[i % threads].push(item);
    }
    groups
        .into_par_iter()
        .filter(|g| !g.is_empty())
        .map(|g| {
            let mut s = init();
            for item in g {
                f(&mut s, item);
            }
            s
        })
        .collect()
}

/// `f(state, item)` for every item, the items dealt round-robin to `states` (one task each; states made
/// once and kept across calls).
pub(crate) fn for_each_with<T, S, F>(items: impl IntoIterator<Item = T>, states: &mut [S], f: F)
where
    T: Send,
    S: Send,
    F: Fn(&mut S, T) + Sync,
{
    let n = states.len().max(1);
    let mut groups: Vec<Vec<T>> = (0..n).map(|_| Vec::new()).collect();
    for (i, item) in items.into_iter().enumerate() {
        groups[i % n].push(item);
    }
    states
        .par_iter_mut()
        .zip(groups)
        .for_each(|(s, g)| g.into_iter().for_each(|item| f(s, item)));
}

/// `f(scratch, (i, chunk))` for every `len`-sized chunk of `data`, with one scratch per thread
/// ([`per_thread`]).
pub(crate) fn for_each_chunk_with<S: Send, I, F>(data: &mut [f32], len: usize, init: I, f: F)
where
    I: Fn() -> S + Sync,
    F: Fn(&mut S, (usize, &mut [f32])) + Sync,
{
    per_thread(data.chunks_mut(len.max(1)).enumerate(), init, f);
}

/// Element-wise maximum of `srcs` into `dst` (whole plane buffers: zero borders stay zero).
pub(crate) fn max_into(dst: &mut [f32], srcs: &[&[f32]]) {
    // In runs that stay in L1 (one pass over the planes instead of one per view), as vector loops.
    const RUN: usize = 1024;
    deepview_kernels::fastmath::with_simd(
        #[inline(always)]
        || {
            for (k, d) in dst.chunks_mut(RUN).enumerate() {
                let (o, n) = (k * RUN, d.len());
                d.copy_from_slice(&srcs[0][o..o + n]);
                for s in &srcs[1..] {
                    for (d, &v) in d.iter_mut().zip(&s[o..o + n]) {
                        // Not `f32::max` (its NaN rule costs a compare and a blend per vector); the
                        // values are finite. (An unconditional store, so that it vectorises to `maxps`.)
                        *d = if v > *d { v } else { *d };
                    }
                }
            }
        },
    )
}
