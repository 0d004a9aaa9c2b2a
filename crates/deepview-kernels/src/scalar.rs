//! Portable kernels (any CPU): the same loops as the AVX2 ones, one output at a time.

use crate::act::{Act, CO_BLOCK};
use crate::elu::elu;

/// One block of up to 8 output channels over flat indices `start..end`; the sums start from the bias
/// `b`, or from the planes `init` (one per output) when given.
///
/// # Safety
/// Inputs and outputs must cover `start + tap .. end + tap` for every tap, `init` planes `start..end`,
/// and outputs must not alias the inputs.
#[allow(clippy::too_many_arguments)]
pub unsafe fn conv_block(
    ins: &[*const f32],
    w: &[f32],
    b: &[f32],
    init: Option<&[*const f32]>,
    outs: &[*mut f32],
    start: usize,
    end: usize,
    taps: &[isize; 9],
    act: Act,
) {
    let cin = ins.len();
    for i in start..end {
        let mut acc = [0f32; CO_BLOCK];
        match init {
            // SAFETY: in bounds by the caller's contract.
            Some(init) => {
                for (a, &p) in acc.iter_mut().zip(init) {
                    *a = unsafe { *p.add(i) };
                }
            }
            None => acc.copy_from_slice(&b[..CO_BLOCK]),
        }
        for ci in 0..cin {
            for (t, &off) in taps.iter().enumerate() {
                // SAFETY: in bounds by the caller's contract.
                let x = unsafe { *ins[ci].offset(i as isize + off) };
                let wt = &w[(ci * 9 + t) * CO_BLOCK..][..CO_BLOCK];
                for j in 0..CO_BLOCK {
                    acc[j] += wt[j] * x;
                }
            }
        }
        for (j, &o) in outs.iter().enumerate() {
            let v = match act {
                Act::Linear => acc[j],
                Act::Elu => elu(acc[j]),
                Act::Relu => acc[j].max(0.0),
            };
            // SAFETY: in bounds by the caller's contract.
            unsafe { *o.add(i) = v };
        }
    }
}

/// Weight and bias gradients over flat indices `start..end` (accumulated).
///
/// # Safety
/// As [`conv_block`], for `xs` and `gs`.
pub unsafe fn weight_grad(
    xs: &[*const f32],
    gs: &[*const f32],
    start: usize,
    end: usize,
    taps: &[isize; 9],
    gw: &mut [f32],
    gb: &mut [f32],
) {
    let cin = xs.len();
    for (co, &g) in gs.iter().enumerate() {
        let mut sb = 0f64;
        let mut sw = vec![0f64; cin * 9];
        for i in start..end {
            // SAFETY: in bounds by the caller's contract.
            let gv = unsafe { *g.add(i) } as f64;
            if gv == 0.0 {
                continue;
            }
            sb += gv;
            for ci in 0..cin {
                for (t, &off) in taps.iter().enumerate() {
                    // SAFETY: as above.
                    sw[ci * 9 + t] += gv * unsafe { *xs[ci].offset(i as isize + off) } as f64;
                }
            }
        }
        gb[co] += sb as f32;
        for (k, s) in sw.iter().enumerate() {
            gw[co * cin * 9 + k] += *s as f32;
        }
    }
}
