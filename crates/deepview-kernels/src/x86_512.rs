//! AVX-512 kernels (32 zmm registers, 16 lanes; Intel Sapphire Rapids and AMD Zen 4 machines of this
//! project). The forward kernel computes 48 outputs (3 registers) of all 8 output channels of a block
//! per step in 24 accumulators: each input load feeds 8 FMAs and each broadcast weight 3, and the
//! accumulators, the inputs and a broadcast fit the register file without spills (measured one thread,
//! 575x412 planes: 2 registers per step were 0-25% slower, AVX2's 16 outputs x 4 channels 1.4-2.2x
//! slower). The weight gradient keeps the nine taps of one output and input channel in 9 accumulators,
//! 16 lanes each.

use crate::act::{Act, CO_BLOCK};
use crate::elu::{C2, C3, C4, C5, C6, C7, LN2_HI, LN2_LO};
use std::arch::x86_64::*;

/// Outputs per step of the forward kernel.
pub const STEP: usize = 48;
const R: usize = STEP / 16;

/// ELU of 16 lanes (see `elu::expm1_neg`, same arithmetic as the AVX2 `elu8`).
#[inline]
#[target_feature(enable = "avx512f")]
fn elu16(x: __m512) -> __m512 {
    let neg = _mm512_cmp_ps_mask::<_CMP_LE_OQ>(x, _mm512_setzero_ps());
    if neg == 0 {
        return x;
    }
    let xc = _mm512_max_ps(x, _mm512_set1_ps(-87.0));
    let n = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(
        _mm512_mul_ps(xc, _mm512_set1_ps(std::f32::consts::LOG2_E)),
    );
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(LN2_HI), xc);
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(LN2_LO), r);
    let one = _mm512_set1_ps(1.0);
    let mut q = _mm512_set1_ps(C7);
    for c in [C6, C5, C4, C3, C2] {
        q = _mm512_fmadd_ps(q, r, _mm512_set1_ps(c));
    }
    q = _mm512_fmadd_ps(q, r, one);
    q = _mm512_mul_ps(q, r);
    // 2^n for n in [-126, 0] (exact: the same bits as the AVX2 path's exponent field).
    let p = _mm512_scalef_ps(one, n);
    let v = _mm512_fmadd_ps(p, q, _mm512_sub_ps(p, one));
    _mm512_mask_blend_ps(neg, x, v)
}

/// # Safety
/// As `scalar::conv_block`, for reads up to one step (32) past `end` plus the taps (and of `init`) and
/// writes up to one step past `end`; requires AVX-512F.
#[target_feature(enable = "avx512f")]
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
    debug_assert!(outs.len() <= CO_BLOCK && b.len() >= CO_BLOCK);
    debug_assert!(w.len() >= ins.len() * 9 * CO_BLOCK);
    let n = outs.len();
    let w = w.as_ptr();
    // The leading row of the taps (`taps[8]`: one row below) is new data at every step: fetch it a few
    // steps ahead into L1 (`R` cache lines per step), as the AVX2 kernel does.
    let lead = taps[8] + 2 * STEP as isize;
    let bias: [__m512; CO_BLOCK] = std::array::from_fn(|j| _mm512_set1_ps(b[j]));
    let mut i = start;
    while i < end {
        let mut a = [bias; R];
        if let Some(init) = init {
            for (j, &p) in init.iter().enumerate() {
                for r in 0..R {
                    // SAFETY: in bounds by the caller's contract.
                    a[r][j] = unsafe { _mm512_loadu_ps(p.add(i + 16 * r)) };
                }
            }
        }
        for &inp in ins {
            for r in 0..R {
                let p = inp.wrapping_add(i + 16 * r).wrapping_offset(lead);
                // A prefetch never faults; the address is not dereferenced.
                _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
            }
        }
        for (ci, &inp) in ins.iter().enumerate() {
            // SAFETY: in bounds by the caller's contract (every tap of this step).
            unsafe {
                let base = inp.add(i);
                let wc = w.add(ci * 9 * CO_BLOCK);
                for (t, &off) in taps.iter().enumerate() {
                    let p = base.offset(off);
                    let x: [__m512; R] = std::array::from_fn(|r| _mm512_loadu_ps(p.add(16 * r)));
                    let wt = wc.add(t * CO_BLOCK);
                    for j in 0..CO_BLOCK {
                        let wv = _mm512_set1_ps(*wt.add(j));
                        for r in 0..R {
                            a[r][j] = _mm512_fmadd_ps(x[r], wv, a[r][j]);
                        }
                    }
                }
            }
        }
        for j in 0..n {
            let o = outs[j];
            for r in 0..R {
                let v = match act {
                    Act::Linear => a[r][j],
                    Act::Elu => elu16(a[r][j]),
                    Act::Relu => _mm512_max_ps(a[r][j], _mm512_setzero_ps()),
                };
                // SAFETY: in bounds by the caller's contract.
                unsafe { _mm512_storeu_ps(o.add(i + 16 * r), v) };
            }
        }
        i += STEP;
    }
}

/// # Safety
/// As `scalar::weight_grad`, for reads up to 16 past `end` plus the taps (the gradients must be zero
/// from `end` on); requires AVX-512F.
#[target_feature(enable = "avx512f")]
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
        let mut s = _mm512_setzero_ps();
        let mut i = start;
        while i < end {
            // SAFETY: in bounds by the caller's contract.
            s = _mm512_add_ps(s, unsafe { _mm512_loadu_ps(g.add(i)) });
            i += 16;
        }
        gb[co] += _mm512_reduce_add_ps(s);
    }
    // Three output channels at a time: each tap's input load feeds 3 FMAs (27 accumulators, the
    // three gradients and one input in the 32 registers), so that the loads (10 per 9 FMAs with one
    // channel, most of them split across cache lines) no longer bound the loop.
    let mut co = 0;
    while co < gs.len() {
        let n = (gs.len() - co).min(WG_CO);
        // SAFETY: forwarded contract; the extra lanes of a short group repeat its last channel.
        unsafe {
            weight_grad_group(
                xs,
                &gs[co..co + n],
                start,
                end,
                taps,
                &mut gw[co * cin * 9..],
            )
        };
        co += n;
    }
}

/// Output channels per pass of the weight gradient.
const WG_CO: usize = 3;

/// `gw[(j * cin + ci) * 9 + t] += sum_i g_j[i] x_ci[i + tap_t]` for the (at most `WG_CO`) gradients `gs`.
#[target_feature(enable = "avx512f")]
unsafe fn weight_grad_group(
    xs: &[*const f32],
    gs: &[*const f32],
    start: usize,
    end: usize,
    taps: &[isize; 9],
    gw: &mut [f32],
) {
    let cin = xs.len();
    let g: [*const f32; WG_CO] = std::array::from_fn(|j| gs[j.min(gs.len() - 1)]);
    for (ci, &x) in xs.iter().enumerate() {
        let mut a = [[_mm512_setzero_ps(); 9]; WG_CO];
        let mut i = start;
        while i < end {
            // SAFETY: in bounds by the caller's contract.
            unsafe {
                let v: [__m512; WG_CO] = std::array::from_fn(|j| _mm512_loadu_ps(g[j].add(i)));
                let base = x.add(i);
                for t in 0..9 {
                    let xv = _mm512_loadu_ps(base.offset(taps[t]));
                    for j in 0..WG_CO {
                        a[j][t] = _mm512_fmadd_ps(v[j], xv, a[j][t]);
                    }
                }
            }
            i += 16;
        }
        for j in 0..gs.len() {
            for t in 0..9 {
                gw[(j * cin + ci) * 9 + t] += _mm512_reduce_add_ps(a[j][t]);
            }
        }
    }
}
