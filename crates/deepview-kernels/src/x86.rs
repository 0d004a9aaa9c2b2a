//! AVX2 + FMA kernels (this project's machines are AMD Zen 3: 16 ymm registers, two 256-bit FMA pipes,
//! three loads per cycle). The forward kernel computes 16 outputs (2 registers) of 4 output channels
//! per step in 8 accumulators (enough to cover the FMA latency, and with the inputs and a broadcast
//! weight within the 16 registers: 12 accumulators spilled), broadcasting each weight once per 2 FMAs;
//! the weight gradient keeps the nine taps of one output and input channel in 9 accumulators.

use crate::act::{Act, CO_BLOCK};
use crate::elu::{C2, C3, C4, C5, C6, C7, LN2_HI, LN2_LO};
use std::arch::x86_64::*;

/// Outputs per step of the forward kernel.
pub const STEP: usize = 16;
/// Output channels per pass of the forward kernel.
const CO_PASS: usize = 4;

/// ELU of 8 lanes (see `elu::expm1_neg`, same arithmetic).
#[inline]
#[target_feature(enable = "avx2,fma")]
fn elu8(x: __m256) -> __m256 {
    let zero = _mm256_setzero_ps();
    let neg = _mm256_cmp_ps::<_CMP_LE_OQ>(x, zero);
    if _mm256_movemask_ps(neg) == 0 {
        return x;
    }
    let xc = _mm256_max_ps(x, _mm256_set1_ps(-87.0));
    let n = _mm256_round_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(_mm256_mul_ps(
        xc,
        _mm256_set1_ps(std::f32::consts::LOG2_E),
    ));
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_HI), xc);
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_LO), r);
    let one = _mm256_set1_ps(1.0);
    let mut q = _mm256_set1_ps(C7);
    for c in [C6, C5, C4, C3, C2] {
        q = _mm256_fmadd_ps(q, r, _mm256_set1_ps(c));
    }
    q = _mm256_fmadd_ps(q, r, one);
    q = _mm256_mul_ps(q, r);
    // 2^n for n in [-126, 0]: the exponent field directly.
    let e = _mm256_slli_epi32::<23>(_mm256_add_epi32(
        _mm256_cvtps_epi32(n),
        _mm256_set1_epi32(127),
    ));
    let p = _mm256_castsi256_ps(e);
    let v = _mm256_fmadd_ps(p, q, _mm256_sub_ps(p, one));
    _mm256_blendv_ps(x, v, neg)
}

/// # Safety
/// As `scalar::conv_block`, for reads up to one step (16) past `end` plus the taps (and of `init`) and
/// writes up to one step past `end`; requires AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
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
    for half in 0..outs.len().div_ceil(CO_PASS) {
        let j0 = half * CO_PASS;
        let outs = &outs[j0..outs.len().min(j0 + CO_PASS)];
        // SAFETY: forwarded contract; `j0 + CO_PASS <= CO_BLOCK`.
        unsafe {
            conv_pass(
                ins,
                w.as_ptr().add(j0),
                &b[j0..j0 + CO_PASS],
                init.map(|p| &p[j0..p.len().min(j0 + CO_PASS)]),
                outs,
                start,
                end,
                taps,
                act,
                half == 0,
            )
        };
    }
}

/// One pass of `CO_PASS` output channels, `STEP` outputs (`R` registers) per step in `R * CO_PASS`
/// accumulators (3 registers, 12 accumulators, spill: measured 40% slower).
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn conv_pass(
    ins: &[*const f32],
    w: *const f32,
    b: &[f32],
    init: Option<&[*const f32]>,
    outs: &[*mut f32],
    start: usize,
    end: usize,
    taps: &[isize; 9],
    act: Act,
    prefetch: bool,
) {
    const R: usize = STEP / 8;
    // The leading row of the taps (`taps[8]`: one row below) is new data at every step of the first
    // pass: fetch it a few steps ahead into L1 (the hardware prefetcher does not follow as many streams
    // as there are input channels).
    // Measured as an A/B in one run (one thread, 575x412 planes, 4..64 channels): 10-25% faster.
    let lead = taps[8] + 4 * STEP as isize;
    let mut bias = [_mm256_setzero_ps(); CO_PASS];
    for j in 0..CO_PASS {
        bias[j] = _mm256_set1_ps(b[j]);
    }
    let mut i = start;
    while i < end {
        let mut a = [bias; R];
        if let Some(init) = init {
            for (j, &p) in init.iter().enumerate() {
                for r in 0..R {
                    // SAFETY: in bounds by the caller's contract.
                    a[r][j] = unsafe { _mm256_loadu_ps(p.add(i + 8 * r)) };
                }
            }
        }
        if prefetch {
            for &inp in ins {
                // A prefetch never faults; the address is not dereferenced.
                _mm_prefetch::<_MM_HINT_T0>(inp.wrapping_add(i).wrapping_offset(lead) as *const i8);
            }
        }
        for (ci, &inp) in ins.iter().enumerate() {
            // SAFETY: in bounds by the caller's contract (every tap of this step).
            unsafe {
                let base = inp.add(i);
                let wc = w.add(ci * 9 * CO_BLOCK);
                for (t, &off) in taps.iter().enumerate() {
                    let p = base.offset(off);
                    let x: [__m256; R] = std::array::from_fn(|r| _mm256_loadu_ps(p.add(8 * r)));
                    let wt = wc.add(t * CO_BLOCK);
                    for j in 0..CO_PASS {
                        let wv = _mm256_broadcast_ss(&*wt.add(j));
                        for r in 0..R {
                            a[r][j] = _mm256_fmadd_ps(x[r], wv, a[r][j]);
                        }
                    }
                }
            }
        }
        for (j, &o) in outs.iter().enumerate() {
            for r in 0..R {
                let v = match act {
                    Act::Linear => a[r][j],
                    Act::Elu => elu8(a[r][j]),
                    Act::Relu => _mm256_max_ps(a[r][j], _mm256_setzero_ps()),
                };
                // SAFETY: in bounds by the caller's contract.
                unsafe { _mm256_storeu_ps(o.add(i + 8 * r), v) };
            }
        }
        i += STEP;
    }
}

#[inline]
#[target_feature(enable = "avx2,fma")]
fn hsum(v: __m256) -> f32 {
    let s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
    let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
    let s = _mm_add_ss(s, _mm_shuffle_ps::<1>(s, s));
    _mm_cvtss_f32(s)
}

/// # Safety
/// As `scalar::weight_grad`, for reads up to 8 past `end` plus the taps (the gradients must be zero
/// from `end` on); requires AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
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
        let mut s = _mm256_setzero_ps();
        let mut i = start;
        while i < end {
            // SAFETY: in bounds by the caller's contract.
            s = _mm256_add_ps(s, unsafe { _mm256_loadu_ps(g.add(i)) });
            i += 8;
        }
        gb[co] += hsum(s);
        for (ci, &x) in xs.iter().enumerate() {
            let mut a = [_mm256_setzero_ps(); 9];
            let mut i = start;
            while i < end {
                // SAFETY: in bounds by the caller's contract.
                unsafe {
                    let v = _mm256_loadu_ps(g.add(i));
                    let base = x.add(i);
                    for t in 0..9 {
                        a[t] = _mm256_fmadd_ps(v, _mm256_loadu_ps(base.offset(taps[t])), a[t]);
                    }
                }
                i += 8;
            }
            for t in 0..9 {
                gw[(co * cin + ci) * 9 + t] += hsum(a[t]);
            }
        }
    }
}
