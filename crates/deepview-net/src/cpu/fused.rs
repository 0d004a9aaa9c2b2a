//! A whole core net (without the U-Net's resampling) as one differentiable operation on the CPU: its
//! forward keeps every activation in zero-padded planes ([`deepview_kernels::Plane`]) and its backward
//! walks them back (ELU derivatives from the outputs, the max over views routed to the first view that
//! holds it, as burn's `max_dim` does), one plane's `K` slices per task. Training then costs one
//! operation per net instead of dozens of burn tensors per layer (concatenations, repeats, per-layer
//! padding); the arithmetic of each convolution is the per-layer op's ([`crate::cpu::ops`]), so the
//! forward equals [`crate::cpu::packed::core_net_inference`] bit for bit (training's per-net recompute
//! relies on it).
//!
//! Parameters travel as one flat vector: for each convolution in the order `input[0], input[1],
//! stages..., head, out`, its `[cout, cin, 3, 3]` weights then its `[cout]` bias ([`NetShape::convs`]).

use crate::cpu::planes::{max_into, per_thread};
use deepview_kernels::{
    Act, PackedConv, Plane, conv3x3, conv3x3_input_grad, conv3x3_weight_grad, elu_backward,
};

/// The sizes of a core net: `K` views, `cin` input channels per slice, `f` features, `so` output
/// channels, `stages` (max over views, concat, two convs) steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NetShape {
    pub views: usize,
    pub cin: usize,
    pub f: usize,
    pub so: usize,
    pub stages: usize,
}

impl NetShape {
    /// `(cin, cout)` of every convolution, in parameter order.
    pub fn convs(&self) -> Vec<(usize, usize)> {
        let f = self.f;
        let mut c = vec![(self.cin, f), (f, f)];
        for _ in 0..self.stages {
            c.push((2 * f, f));
            c.push((f, f));
        }
        c.push((f, f));
        c.push((f, self.so));
        c
    }

    /// Each convolution's sizes and the places of its weights and bias in the flat parameters.
    fn slots(&self) -> Vec<Slot> {
        let mut at = 0;
        self.convs()
            .into_iter()
            .map(|(cin, cout)| {
                let w = at..at + cout * cin * 9;
                at = w.end + cout;
                Slot {
                    cin,
                    cout,
                    b: w.end..at,
                    w,
                }
            })
            .collect()
    }

    /// Length of the flat parameter vector.
    pub fn params_len(&self) -> usize {
        self.slots().last().map_or(0, |s| s.b.end)
    }

    /// Saved planes per MPI plane: `A1`, `B1` of every view, then per stage the max it reads and its
    /// `A`, `B` of every view, then the final max and the head's output. Each layer's outputs lie after
    /// all of its inputs.
    fn saved_planes(&self) -> usize {
        let kf = self.views * self.f;
        2 * kf + self.stages * (self.f + 2 * kf) + 2 * self.f
    }

    fn a1(&self, k: usize) -> usize {
        k * self.f
    }
    fn b1(&self, k: usize) -> usize {
        (self.views + k) * self.f
    }
    fn stage_base(&self, s: usize) -> usize {
        let kf = self.views * self.f;
        2 * kf + s * (self.f + 2 * kf)
    }
    /// The max over views that stage `s` reads.
    fn m(&self, s: usize) -> usize {
        self.stage_base(s)
    }
    fn a(&self, s: usize, k: usize) -> usize {
        self.stage_base(s) + self.f + k * self.f
    }
    fn b(&self, s: usize, k: usize) -> usize {
        self.stage_base(s) + self.f + (self.views + k) * self.f
    }
    /// The `B` planes of view `k` after stage `s` (`s = 0`: the input convs; `s = i + 1`: stage `i`).
    fn b_after(&self, s: usize, k: usize) -> usize {
        if s == 0 { self.b1(k) } else { self.b(s - 1, k) }
    }
    fn m_final(&self) -> usize {
        self.stage_base(self.stages)
    }
    fn head(&self) -> usize {
        self.m_final() + self.f
    }
}

/// One convolution of the flat parameters: its sizes and the ranges of its weights and bias.
struct Slot {
    cin: usize,
    cout: usize,
    w: std::ops::Range<usize>,
    b: std::ops::Range<usize>,
}

/// The convolutions of a net's flat parameters packed for the kernels: as they are (forward) or
/// transposed (the input gradients).
fn packed(slots: &[Slot], params: &[f32], transposed: bool) -> Vec<PackedConv> {
    let len = slots.last().map_or(0, |s| s.b.end);
    assert_eq!(
        params.len(),
        len,
        "core net parameters: {len} values expected"
    );
    slots
        .iter()
        .map(|s| {
            let w = &params[s.w.clone()];
            if transposed {
                PackedConv::transposed(w, s.cout, s.cin)
            } else {
                PackedConv::new(w, Some(&params[s.b.clone()]), s.cout, s.cin)
            }
        })
        .collect()
}

/// Indices of planes in a list of plane buffers.
fn refs<'a>(bufs: &'a [&mut [f32]], idx: impl IntoIterator<Item = usize>) -> Vec<&'a [f32]> {
    idx.into_iter().map(|i| &*bufs[i]).collect()
}

/// `conv` of the planes `from` (all before `to`) into the `conv.cout` planes from `to` on.
fn layer(
    plane: Plane,
    bufs: &mut [&mut [f32]],
    from: &[usize],
    to: usize,
    conv: &PackedConv,
    act: Act,
) {
    let (lo, hi) = bufs.split_at_mut(to);
    let ins = refs(lo, from.iter().copied());
    let mut outs: Vec<&mut [f32]> = hi[..conv.cout].iter_mut().map(|v| &mut **v).collect();
    conv3x3(plane, &ins, conv, act, &mut outs);
}

/// The max over views of the planes `b(k) + c` into `m + c` (`m` after every `b(k)`).
fn max_views(
    bufs: &mut [&mut [f32]],
    f: usize,
    views: usize,
    b: impl Fn(usize) -> usize,
    m: usize,
) {
    let (lo, hi) = bufs.split_at_mut(m);
    for c in 0..f {
        let srcs: Vec<&[f32]> = (0..views).map(|k| &*lo[b(k) + c]).collect();
        max_into(hi[c], &srcs);
    }
}

/// The forward of one MPI plane: `x` the `K * cin` padded input planes (view-major), `saved` the
/// [`NetShape::saved_planes`] planes, `out` the `so` padded output planes.
fn forward_plane(
    shape: &NetShape,
    net: &[PackedConv],
    plane: Plane,
    x: &[Vec<f32>],
    saved: &mut [&mut [f32]],
    out: &mut [&mut [f32]],
) {
    let (k_n, cin, f) = (shape.views, shape.cin, shape.f);
    for k in 0..k_n {
        let ins: Vec<&[f32]> = x[k * cin..(k + 1) * cin]
            .iter()
            .map(|v| v.as_slice())
            .collect();
        let a1 = shape.a1(k);
        let mut outs: Vec<&mut [f32]> = saved[a1..a1 + f].iter_mut().map(|v| &mut **v).collect();
        conv3x3(plane, &ins, &net[0], Act::Elu, &mut outs);
    }
    for k in 0..k_n {
        let from: Vec<usize> = (shape.a1(k)..shape.a1(k) + f).collect();
        layer(plane, saved, &from, shape.b1(k), &net[1], Act::Elu);
    }
    for s in 0..shape.stages {
        max_views(saved, f, k_n, |k| shape.b_after(s, k), shape.m(s));
        for k in 0..k_n {
            let bp = shape.b_after(s, k);
            let from: Vec<usize> = (bp..bp + f).chain(shape.m(s)..shape.m(s) + f).collect();
            layer(
                plane,
                saved,
                &from,
                shape.a(s, k),
                &net[2 + 2 * s],
                Act::Elu,
            );
        }
        for k in 0..k_n {
            let from: Vec<usize> = (shape.a(s, k)..shape.a(s, k) + f).collect();
            layer(
                plane,
                saved,
                &from,
                shape.b(s, k),
                &net[3 + 2 * s],
                Act::Elu,
            );
        }
    }
    let last = shape.stages;
    max_views(saved, f, k_n, |k| shape.b_after(last, k), shape.m_final());
    let from: Vec<usize> = (shape.m_final()..shape.m_final() + f).collect();
    layer(
        plane,
        saved,
        &from,
        shape.head(),
        &net[2 + 2 * last],
        Act::Elu,
    );
    let ins = refs(saved, shape.head()..shape.head() + f);
    conv3x3(plane, &ins, &net[3 + 2 * last], Act::Linear, out);
}

/// `x` `[K*D, cin, h, w]` (view-major) -> the output `[D, so, h, w]` and the saved activations (every
/// MPI plane's [`NetShape::saved_planes`] padded planes), for [`backward`].
pub fn forward(
    shape: &NetShape,
    params: &[f32],
    x: &[f32],
    d: usize,
    h: usize,
    w: usize,
) -> (Vec<f32>, Vec<f32>) {
    let net = packed(&shape.slots(), params, false);
    let plane = Plane::new(h, w);
    let (hw, len, ns) = (h * w, plane.len(), shape.saved_planes());
    let (k_n, cin, so) = (shape.views, shape.cin, shape.so);
    assert_eq!(x.len(), k_n * d * cin * hw, "core net input size");
    let mut out = vec![0f32; d * so * hw];
    let mut saved = vec![0f32; d * ns * len];
    if hw == 0 || d == 0 {
        return (out, saved);
    }
    let jobs = out
        .chunks_mut(so * hw)
        .zip(saved.chunks_mut(ns * len))
        .enumerate();
    per_thread(
        jobs,
        || {
            (
                (0..k_n * cin).map(|_| plane.zeroed()).collect::<Vec<_>>(),
                (0..so).map(|_| plane.zeroed()).collect::<Vec<_>>(),
            )
        },
        |(xs, os), (p, (res, sv))| {
            for k in 0..k_n {
                for c in 0..cin {
                    let src = &x[((k * d + p) * cin + c) * hw..][..hw];
                    plane.pad_into(src, &mut xs[k * cin + c]);
                }
            }
            let mut sv: Vec<&mut [f32]> = sv.chunks_mut(len).collect();
            let mut outs: Vec<&mut [f32]> = os.iter_mut().map(|v| v.as_mut_slice()).collect();
            forward_plane(shape, &net, plane, xs, &mut sv, &mut outs);
            for (c, dst) in res.chunks_exact_mut(hw).enumerate() {
                plane.unpad_into(&os[c], dst);
            }
        },
    );
    (out, saved)
}

/// Route the gradient at a max over views (`gm`) to the first view holding the maximum: adds into
/// `gb[k]` where `b[k] == m` and no earlier view does.
fn route_max(b: &[&[f32]], m: &[f32], gm: &[f32], gb: &mut [&mut [f32]]) {
    for i in 0..m.len() {
        let g = gm[i];
        if g == 0.0 {
            continue;
        }
        for (k, bk) in b.iter().enumerate() {
            if bk[i] == m[i] {
                gb[k][i] += g;
                break;
            }
        }
    }
}

/// One thread's backward scratch.
struct Scratch {
    /// Padded inputs (`K * cin`).
    x: Vec<Vec<f32>>,
    /// The gradient at the output (`so`), at the head (`f`), at a max (`f`), at one view's `A` (`f`),
    /// at one view's concatenated stage input (`2 f`), at the net's input of one view (`cin`).
    g_out: Vec<Vec<f32>>,
    g_head: Vec<Vec<f32>>,
    g_m: Vec<Vec<f32>>,
    g_a: Vec<Vec<f32>>,
    g_cat: Vec<Vec<f32>>,
    g_x: Vec<Vec<f32>>,
    /// The gradient at every view's current `B` and at the previous one (`K * f` each).
    g_b: Vec<Vec<f32>>,
    g_bp: Vec<Vec<f32>>,
    /// Parameter gradient sums (the flat layout).
    grads: Vec<f32>,
}

impl Scratch {
    fn new(shape: &NetShape, plane: Plane) -> Self {
        let n = |c: usize| (0..c).map(|_| plane.zeroed()).collect::<Vec<_>>();
        let (k_n, f) = (shape.views, shape.f);
        Self {
            x: n(k_n * shape.cin),
            g_out: n(shape.so),
            g_head: n(f),
            g_m: n(f),
            g_a: n(f),
            g_cat: n(2 * f),
            g_x: n(shape.cin),
            g_b: n(k_n * f),
            g_bp: n(k_n * f),
            grads: vec![0.0; shape.params_len()],
        }
    }
}

fn as_refs(v: &[Vec<f32>]) -> Vec<&[f32]> {
    v.iter().map(|b| b.as_slice()).collect()
}

fn as_muts(v: &mut [Vec<f32>]) -> Vec<&mut [f32]> {
    v.iter_mut().map(|b| b.as_mut_slice()).collect()
}

/// The parameter gradient slices `(weights, bias)` of a convolution.
fn grad_of<'a>(grads: &'a mut [f32], slot: &Slot) -> (&'a mut [f32], &'a mut [f32]) {
    grads[slot.w.start..slot.b.end].split_at_mut(slot.w.len())
}

/// Gradients of [`forward`]: `grad` at the output `[D, so, h, w]` -> (the input gradient `[K*D, cin,
/// h, w]` when `input_grad`, else empty; the flat parameter gradient).
#[allow(clippy::too_many_arguments)]
pub fn backward(
    shape: &NetShape,
    params: &[f32],
    x: &[f32],
    saved: &[f32],
    grad: &[f32],
    d: usize,
    h: usize,
    w: usize,
    input_grad: bool,
) -> (Vec<f32>, Vec<f32>) {
    let plane = Plane::new(h, w);
    let (hw, len, ns) = (h * w, plane.len(), shape.saved_planes());
    let (k_n, cin, so) = (shape.views, shape.cin, shape.so);
    assert_eq!(saved.len(), d * ns * len, "core net saved activations");
    assert_eq!(grad.len(), d * so * hw, "core net output gradient");
    let slots = shape.slots();
    let tr = packed(&slots, params, true);
    let plen = shape.params_len();
    let mut gx = vec![0f32; if input_grad { k_n * d * cin * hw } else { 0 }];
    if hw == 0 || d == 0 {
        return (gx, vec![0.0; plen]);
    }
    // Each MPI plane's input-gradient blocks, view after view (view-major in `gx`).
    let mut blocks: Vec<Vec<&mut [f32]>> = (0..d).map(|_| Vec::new()).collect();
    if input_grad {
        for (i, c) in gx.chunks_mut(cin * hw).enumerate() {
            blocks[i % d].push(c);
        }
    }
    let sums = per_thread(
        blocks.into_iter().enumerate(),
        || Scratch::new(shape, plane),
        |s, (p, gxp)| {
            let sv: Vec<&[f32]> = saved[p * ns * len..(p + 1) * ns * len]
                .chunks(len)
                .collect();
            for k in 0..k_n {
                for c in 0..cin {
                    let src = &x[((k * d + p) * cin + c) * hw..][..hw];
                    plane.pad_into(src, &mut s.x[k * cin + c]);
                }
            }
            for (c, src) in grad[p * so * hw..][..so * hw].chunks_exact(hw).enumerate() {
                plane.pad_into(src, &mut s.g_out[c]);
            }
            backward_plane(shape, &slots, &tr, plane, &sv, s, gxp);
        },
    );
    let mut total = vec![0f32; plen];
    for s in sums {
        total.iter_mut().zip(&s.grads).for_each(|(t, v)| *t += v);
    }
    (gx, total)
}

/// `dst += src` on whole plane buffers.
fn add_into(dst: &mut [f32], src: &[f32]) {
    dst.iter_mut().zip(src).for_each(|(d, s)| *d += s);
}

/// The backward of one MPI plane, its padded inputs in `s.x` and output gradient in `s.g_out`: adds
/// the parameter gradients into `s.grads` and writes each view's input gradient into `gx` (`K`
/// unpadded `[cin][h][w]` blocks; empty: not wanted).
fn backward_plane(
    shape: &NetShape,
    slots: &[Slot],
    tr: &[PackedConv],
    plane: Plane,
    sv: &[&[f32]],
    s: &mut Scratch,
    mut gx: Vec<&mut [f32]>,
) {
    let (k_n, cin, f) = (shape.views, shape.cin, shape.f);
    let hw = plane.h * plane.w;
    let Scratch {
        x,
        g_out,
        g_head,
        g_m,
        g_a,
        g_cat,
        g_x,
        g_b,
        g_bp,
        grads,
    } = s;
    let planes =
        |from: usize, n: usize| -> Vec<&[f32]> { (from..from + n).map(|i| sv[i]).collect() };
    let mut wgrad = |i: usize, xs: &[&[f32]], gs: &[Vec<f32>]| {
        let (gw, gb) = grad_of(grads, &slots[i]);
        conv3x3_weight_grad(plane, xs, &as_refs(gs), gw, gb);
    };
    let last = shape.stages;
    let (i_head, i_out) = (2 + 2 * last, 3 + 2 * last);
    // out (linear) <- the head's output H (ELU) <- the final max.
    wgrad(i_out, &planes(shape.head(), f), g_out);
    conv3x3_input_grad(plane, &as_refs(g_out), &tr[i_out], &mut as_muts(g_head));
    for c in 0..f {
        elu_backward(sv[shape.head() + c], &mut g_head[c]);
    }
    wgrad(i_head, &planes(shape.m_final(), f), g_head);
    conv3x3_input_grad(plane, &as_refs(g_head), &tr[i_head], &mut as_muts(g_m));
    // The final max -> every view's last B.
    for b in g_b.iter_mut() {
        b.fill(0.0);
    }
    let route =
        |g_m: &[Vec<f32>], g_b: &mut [Vec<f32>], b_of: &dyn Fn(usize) -> usize, m: usize| {
            for c in 0..f {
                let bs: Vec<&[f32]> = (0..k_n).map(|k| sv[b_of(k) + c]).collect();
                let mut gb: Vec<&mut [f32]> = g_b
                    .iter_mut()
                    .skip(c)
                    .step_by(f)
                    .map(|v| v.as_mut_slice())
                    .collect();
                route_max(&bs, sv[m + c], &g_m[c], &mut gb);
            }
        };
    route(g_m, g_b, &|k| shape.b_after(last, k), shape.m_final());
    for st in (0..last).rev() {
        for v in g_bp.iter_mut().chain(g_m.iter_mut()) {
            v.fill(0.0);
        }
        let (ia, ib) = (2 + 2 * st, 3 + 2 * st);
        for k in 0..k_n {
            let gbk = &mut g_b[k * f..(k + 1) * f];
            for c in 0..f {
                elu_backward(sv[shape.b(st, k) + c], &mut gbk[c]);
            }
            wgrad(ib, &planes(shape.a(st, k), f), gbk);
            conv3x3_input_grad(plane, &as_refs(gbk), &tr[ib], &mut as_muts(g_a));
            for c in 0..f {
                elu_backward(sv[shape.a(st, k) + c], &mut g_a[c]);
            }
            let mut cat = planes(shape.b_after(st, k), f);
            cat.extend(planes(shape.m(st), f));
            wgrad(ia, &cat, g_a);
            conv3x3_input_grad(plane, &as_refs(g_a), &tr[ia], &mut as_muts(g_cat));
            for c in 0..f {
                add_into(&mut g_bp[k * f + c], &g_cat[c]);
                add_into(&mut g_m[c], &g_cat[f + c]);
            }
        }
        route(g_m, g_bp, &|k| shape.b_after(st, k), shape.m(st));
        std::mem::swap(g_b, g_bp);
    }
    // The input convs.
    for k in 0..k_n {
        let gbk = &mut g_b[k * f..(k + 1) * f];
        for c in 0..f {
            elu_backward(sv[shape.b1(k) + c], &mut gbk[c]);
        }
        wgrad(1, &planes(shape.a1(k), f), gbk);
        conv3x3_input_grad(plane, &as_refs(gbk), &tr[1], &mut as_muts(g_a));
        for c in 0..f {
            elu_backward(sv[shape.a1(k) + c], &mut g_a[c]);
        }
        wgrad(0, &as_refs(&x[k * cin..(k + 1) * cin]), g_a);
        if let Some(dst) = gx.get_mut(k) {
            conv3x3_input_grad(plane, &as_refs(g_a), &tr[0], &mut as_muts(g_x));
            for (c, out) in dst.chunks_exact_mut(hw).enumerate() {
                plane.unpad_into(&g_x[c], out);
            }
        }
    }
}
