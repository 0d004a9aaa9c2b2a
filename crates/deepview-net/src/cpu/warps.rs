//! The engine's bilinear warps straight into the kernels' padded planes: an input image's plane sweep
//! ([`warp_into`]) and the gradient components' two sources of one view ([`warp_pair_into`]), with the
//! taps of [`deepview_mpi::warp`] (the project's sampling rule).

use crate::forward::Hom;
use deepview_kernels::Plane;
use deepview_mpi::warp::{RowTaps, Sampler};

/// Bilinear warp of an interleaved `channels`-channel `src_w x src_h` source by `hom` (output pixels ->
/// source pixels, the project's sampling rule) into channel planes `dst[c]` of `plane`, whose row `y`
/// is output row `y0 + y`; `valid` gets 1 where the sample is inside the source. Outside: 0.
pub(crate) fn warp_into(
    src: &[f32],
    channels: usize,
    src_w: u32,
    src_h: u32,
    hom: &Hom,
    (plane, y0): (Plane, usize),
    dst: &mut [&mut [f32]],
    valid: Option<&mut [f32]>,
) {
    // Not through `with_fma`: a closure over the three channel-count monomorphs is not inlined into it.
    #[cfg(target_arch = "x86_64")]
    if deepview_kernels::simd() {
        #[target_feature(enable = "avx2,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn fma(
            src: &[f32],
            channels: usize,
            src_w: u32,
            src_h: u32,
            hom: &Hom,
            plane: (Plane, usize),
            dst: &mut [&mut [f32]],
            valid: Option<&mut [f32]>,
        ) {
            let (plane, y0) = plane;
            warp_into_portable(src, channels, src_w, src_h, hom, (plane, y0), dst, valid)
        }
        #[target_feature(enable = "avx512f,avx2,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn avx512(
            src: &[f32],
            channels: usize,
            src_w: u32,
            src_h: u32,
            hom: &Hom,
            plane: (Plane, usize),
            dst: &mut [&mut [f32]],
            valid: Option<&mut [f32]>,
        ) {
            let (plane, y0) = plane;
            warp_into_portable(src, channels, src_w, src_h, hom, (plane, y0), dst, valid)
        }
        if deepview_kernels::isa() == deepview_kernels::Isa::Avx512 {
            // SAFETY: AVX-512F, AVX2 and FMA are present (checked).
            unsafe { avx512(src, channels, src_w, src_h, hom, (plane, y0), dst, valid) };
        } else {
            // SAFETY: AVX2 and FMA are present (checked).
            unsafe { fma(src, channels, src_w, src_h, hom, (plane, y0), dst, valid) };
        }
        return;
    }
    warp_into_portable(src, channels, src_w, src_h, hom, (plane, y0), dst, valid)
}

#[inline(always)]
fn warp_into_portable(
    src: &[f32],
    channels: usize,
    src_w: u32,
    src_h: u32,
    hom: &Hom,
    (plane, y0): (Plane, usize),
    dst: &mut [&mut [f32]],
    valid: Option<&mut [f32]>,
) {
    match dst.len() {
        3 => warp_into_c::<3>(src, channels, src_w, src_h, hom, (plane, y0), dst, valid),
        4 => warp_into_c::<4>(src, channels, src_w, src_h, hom, (plane, y0), dst, valid),
        6 => warp_into_c::<6>(src, channels, src_w, src_h, hom, (plane, y0), dst, valid),
        n => panic!("warp of {n} channels"),
    }
}

/// [`warp_into`] for `C` output channels (the first `C` of each `channels`-float source texel).
#[inline(always)]
fn warp_into_c<const C: usize>(
    src: &[f32],
    channels: usize,
    src_w: u32,
    src_h: u32,
    hom: &Hom,
    (plane, y0): (Plane, usize),
    dst: &mut [&mut [f32]],
    valid: Option<&mut [f32]>,
) {
    assert!(channels >= C && dst.len() == C);
    assert!(dst.iter().all(|d| d.len() >= plane.len()));
    assert!(valid.as_ref().is_none_or(|v| v.len() >= plane.len()));
    let texels = src.len() / channels;
    assert!(texels >= src_w as usize * src_h as usize);
    let ptrs: [*mut f32; C] = std::array::from_fn(|c| dst[c].as_mut_ptr());
    let vptr = valid.map(|v| v.as_mut_ptr());
    let sampler = Sampler::new(*hom, src_w, src_h);
    let mut taps = RowTaps::default();
    for y in 0..plane.h {
        sampler.row((y0 + y) as u32).taps_into(plane.w, &mut taps);
        let base = plane.index(y, 0);
        for x in 0..plane.w {
            let i = base + x;
            let (vals, ok) = match taps.tap(x) {
                None => ([0f32; C], 0.0),
                Some(t) => {
                    // The taps are texels of the source (clamped into it by the sampler).
                    let s: [&[f32]; 4] =
                        std::array::from_fn(|j| &src[t.idx[j] as usize * channels..][..C]);
                    let mut v = [0f32; C];
                    for c in 0..C {
                        // Same order as the burn path's sum over the four taps.
                        v[c] = t.w[0] * s[0][c]
                            + t.w[1] * s[1][c]
                            + t.w[2] * s[2][c]
                            + t.w[3] * s[3][c];
                    }
                    (v, 1.0)
                }
            };
            // SAFETY: `i < plane.len()` (an interior index), and every plane holds `plane.len()` floats
            // (asserted above); the planes are distinct buffers.
            unsafe {
                for c in 0..C {
                    *ptrs[c].add(i) = vals[c];
                }
                if let Some(v) = vptr {
                    *v.add(i) = ok;
                }
            }
        }
    }
}

/// The gradient components' warps of one view and plane: `[I, R]` (6 channels) and `[A, T]` (4) of the same
/// view pixels, with one bilinear tap per output texel for both (see [`warp_into`]; `plane`'s row `y` is
/// output row `y0 + y`).
pub(crate) fn warp_pair_into(
    src: (&[f32], &[f32]),
    size: (u32, u32),
    hom: &Hom,
    plane: (Plane, usize),
    dst: (&mut [&mut [f32]], &mut [&mut [f32]]),
    valid: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if deepview_kernels::simd() {
        // SAFETY: AVX2 and FMA are present (checked).
        unsafe { warp_pair_avx2(src, size, hom, plane, dst, valid) };
        return;
    }
    warp_pair_rows(src, size, hom, plane, dst, valid, tap_sums)
}

/// Channels of the gradient components' two sources: `[I, R]` and `[A, T]`.
const PAIR_A: usize = 6;
const PAIR_B: usize = 4;

/// [`warp_pair_rows`] with each tap's channels summed in vectors (the same products and sums in the same
/// order as [`tap_sums`], so the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn warp_pair_avx2(
    src: (&[f32], &[f32]),
    size: (u32, u32),
    hom: &Hom,
    plane: (Plane, usize),
    dst: (&mut [&mut [f32]], &mut [&mut [f32]]),
    valid: &mut [f32],
) {
    // SAFETY (the closure): AVX2 and FMA are enabled here; `warp_pair_rows` passes in-bounds taps.
    warp_pair_rows(src, size, hom, plane, dst, valid, |a, b, ix, w| unsafe {
        tap_sums_avx2(a, b, ix, w)
    })
}

/// `[I, R]` and `[A, T]` at one bilinear tap: `w0 s0 + w1 s1 + w2 s2 + w3 s3` per channel, left to right.
#[inline(always)]
fn tap_sums(a: &[f32], b: &[f32], ix: [u32; 4], w: [f32; 4]) -> ([f32; 8], [f32; 4]) {
    let ix: [usize; 4] = ix.map(|i| i as usize);
    let mut va = [0f32; 8];
    let mut vb = [0f32; PAIR_B];
    for c in 0..PAIR_A {
        va[c] = w[0] * a[ix[0] * PAIR_A + c]
            + w[1] * a[ix[1] * PAIR_A + c]
            + w[2] * a[ix[2] * PAIR_A + c]
            + w[3] * a[ix[3] * PAIR_A + c];
    }
    for c in 0..PAIR_B {
        vb[c] = w[0] * b[ix[0] * PAIR_B + c]
            + w[1] * b[ix[1] * PAIR_B + c]
            + w[2] * b[ix[2] * PAIR_B + c]
            + w[3] * b[ix[3] * PAIR_B + c];
    }
    (va, vb)
}

/// [`tap_sums`] with a texel's channels in one vector each (4 + 2 of `[I, R]`, 4 of `[A, T]`).
///
/// # Safety
/// AVX2 and FMA; the taps `ix` are texels of both sources.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn tap_sums_avx2(a: &[f32], b: &[f32], ix: [u32; 4], w: [f32; 4]) -> ([f32; 8], [f32; 4]) {
    use std::arch::x86_64::*;
    let (ap, bp) = (a.as_ptr(), b.as_ptr());
    let mut va = [0f32; 8];
    let mut vb = [0f32; PAIR_B];
    // SAFETY: the taps are texels of the sources (the caller's contract); the 2-float load reads
    // channels 4 and 5 of the texel.
    unsafe {
        let mut lo = _mm_setzero_ps();
        let mut hi = _mm_setzero_ps();
        let mut sb = _mm_setzero_ps();
        for j in 0..4 {
            let wj = _mm_set1_ps(w[j]);
            let ta = ap.add(ix[j] as usize * PAIR_A);
            let pl = _mm_mul_ps(wj, _mm_loadu_ps(ta));
            let ph = _mm_mul_ps(wj, _mm_castpd_ps(_mm_load_sd(ta.add(4) as *const f64)));
            let pbv = _mm_mul_ps(wj, _mm_loadu_ps(bp.add(ix[j] as usize * PAIR_B)));
            if j == 0 {
                (lo, hi, sb) = (pl, ph, pbv);
            } else {
                lo = _mm_add_ps(lo, pl);
                hi = _mm_add_ps(hi, ph);
                sb = _mm_add_ps(sb, pbv);
            }
        }
        _mm_storeu_ps(va.as_mut_ptr(), lo);
        _mm_storeu_ps(va.as_mut_ptr().add(4), hi);
        _mm_storeu_ps(vb.as_mut_ptr(), sb);
    }
    (va, vb)
}

/// The warp of both sources by `hom` into the planes `da` (6) and `db` (4) and `valid`, with `sums`
/// giving a tap's values (zeros and validity 0 outside the source).
#[inline(always)]
fn warp_pair_rows(
    (a, b): (&[f32], &[f32]),
    (src_w, src_h): (u32, u32),
    hom: &Hom,
    (plane, y0): (Plane, usize),
    (da, db): (&mut [&mut [f32]], &mut [&mut [f32]]),
    valid: &mut [f32],
    sums: impl Fn(&[f32], &[f32], [u32; 4], [f32; 4]) -> ([f32; 8], [f32; 4]),
) {
    let n = src_w as usize * src_h as usize;
    assert!(
        a.len() >= n * PAIR_A && b.len() >= n * PAIR_B && da.len() == PAIR_A && db.len() == PAIR_B
    );
    assert!(
        da.iter().chain(db.iter()).all(|d| d.len() >= plane.len()) && valid.len() >= plane.len()
    );
    let pa: [*mut f32; PAIR_A] = std::array::from_fn(|c| da[c].as_mut_ptr());
    let pb: [*mut f32; PAIR_B] = std::array::from_fn(|c| db[c].as_mut_ptr());
    let sampler = Sampler::new(*hom, src_w, src_h);
    let mut taps = RowTaps::default();
    for y in 0..plane.h {
        sampler.row((y0 + y) as u32).taps_into(plane.w, &mut taps);
        let base = plane.index(y, 0);
        for x in 0..plane.w {
            let i = base + x;
            let ok = taps.ok[x];
            let (va, vb) = if ok {
                sums(a, b, taps.idx[x], taps.w[x])
            } else {
                ([0f32; 8], [0f32; PAIR_B])
            };
            // SAFETY: `i < plane.len()` (an interior index) and the planes hold `plane.len()` floats
            // (asserted); they are distinct buffers.
            unsafe {
                for c in 0..PAIR_A {
                    *pa[c].add(i) = va[c];
                }
                for c in 0..PAIR_B {
                    *pb[c].add(i) = vb[c];
                }
            }
            valid[i] = if ok { 1.0 } else { 0.0 };
        }
    }
}
