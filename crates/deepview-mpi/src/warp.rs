//! Homography warps with the project's sampling rule.
//!
//! Output pixel `(i, j)` samples the source at `H (i + 0.5, j + 0.5, 1)` (continuous coordinates, pixel
//! centres at +0.5). A sample outside the source extent `[0, W] x [0, H]` (or behind the camera,
//! `w <= 0`) is transparent / invalid; inside it, bilinear interpolation between the four nearest texel
//! centres, clamped to the edge texel. An identity homography therefore reproduces the source exactly.

use deepview_geometry::{Camera, plane_homography};

/// Per-plane homographies mapping target pixels to the plane's (reference) pixels, as row-major f64.
pub fn target_to_plane_homographies(
    reference: &Camera,
    target: &Camera,
    depths: &[f64],
) -> Vec<[f64; 9]> {
    depths
        .iter()
        .map(|&d| {
            plane_homography(reference, target, d)
                .inverse()
                .to_row_major()
        })
        .collect()
}

/// Precomputed bilinear sample: texel indices (already multiplied by the channel count) and weights.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tap {
    pub idx: [u32; 4],
    pub w: [f32; 4],
}

/// Maps output pixels of one row to source samples for a homography.
#[derive(Clone, Copy, Debug)]
pub struct Sampler {
    h: [f64; 9],
    src_w: u32,
    src_h: u32,
}

impl Sampler {
    /// `h`: row-major homography from output pixels to source pixels; `src_w x src_h`: source size.
    pub fn new(h: [f64; 9], src_w: u32, src_h: u32) -> Self {
        Self { h, src_w, src_h }
    }

    /// Row set-up: returns per-pixel increments and the row constant terms, in f32.
    #[inline]
    pub fn row(&self, y: u32) -> RowSampler {
        let v = y as f64 + 0.5;
        let h = &self.h;
        RowSampler {
            a: [h[0] as f32, h[3] as f32, h[6] as f32],
            b: [
                (h[1] * v + h[2]) as f32,
                (h[4] * v + h[5]) as f32,
                (h[7] * v + h[8]) as f32,
            ],
            wf: self.src_w as f32,
            hf: self.src_h as f32,
            wmax: self.src_w as i32 - 1,
            hmax: self.src_h as i32 - 1,
            stride: self.src_w,
        }
    }
}

/// The sampler restricted to one output row (`u` varies, `v` fixed).
#[derive(Clone, Copy, Debug)]
pub struct RowSampler {
    a: [f32; 3],
    b: [f32; 3],
    wf: f32,
    hf: f32,
    wmax: i32,
    hmax: i32,
    stride: u32,
}

impl RowSampler {
    /// The row's coefficients `src = a * u + b` for the SIMD kernels.
    pub fn coefficients(&self) -> crate::simd::RowCoefficients {
        crate::simd::RowCoefficients {
            a: self.a,
            b: self.b,
        }
    }

    /// The bilinear tap of output column `x` (texel indices in texels, not channels), or `None` outside.
    #[inline(always)]
    pub fn tap(&self, x: u32) -> Option<Tap> {
        let u = x as f32 + 0.5;
        let wn = self.a[2].mul_add(u, self.b[2]);
        if wn <= 0.0 {
            return None;
        }
        let inv = 1.0 / wn;
        let sx = self.a[0].mul_add(u, self.b[0]) * inv;
        let sy = self.a[1].mul_add(u, self.b[1]) * inv;
        // NaN-safe: the comparisons fail for NaN.
        if !(sx >= 0.0 && sx <= self.wf && sy >= 0.0 && sy <= self.hf) {
            return None;
        }
        let fx = sx - 0.5;
        let fy = sy - 0.5;
        let x0 = fx.floor();
        let y0 = fy.floor();
        let tx = fx - x0;
        let ty = fy - y0;
        let (x0, y0) = (x0 as i32, y0 as i32);
        let xa = x0.clamp(0, self.wmax) as u32;
        let xb = (x0 + 1).clamp(0, self.wmax) as u32;
        let ya = y0.clamp(0, self.hmax) as u32 * self.stride;
        let yb = (y0 + 1).clamp(0, self.hmax) as u32 * self.stride;
        Some(Tap {
            idx: [ya + xa, ya + xb, yb + xa, yb + xb],
            w: [
                (1.0 - tx) * (1.0 - ty),
                tx * (1.0 - ty),
                (1.0 - tx) * ty,
                tx * ty,
            ],
        })
    }
}

/// The taps of a whole output row, structure of arrays: column `x` is inside when `ok[x]`, with texel
/// indices `idx[x]` and weights `w[x]` exactly as [`RowSampler::tap`] gives them.
#[derive(Clone, Debug, Default)]
pub struct RowTaps {
    pub idx: Vec<[u32; 4]>,
    pub w: Vec<[f32; 4]>,
    pub ok: Vec<bool>,
}

impl RowTaps {
    /// The tap of column `x` (as [`RowSampler::tap`]).
    #[inline(always)]
    pub fn tap(&self, x: usize) -> Option<Tap> {
        self.ok[x].then(|| Tap {
            idx: self.idx[x],
            w: self.w[x],
        })
    }
}

impl RowSampler {
    /// The taps of columns `0..n` into `out` (resized), 8 columns at a time with AVX2 where the CPU has
    /// it (the same IEEE operations as [`Self::tap`], so the same bits), else one by one.
    pub fn taps_into(&self, n: usize, out: &mut RowTaps) {
        out.idx.resize(n, [0; 4]);
        out.w.resize(n, [0.0; 4]);
        out.ok.resize(n, false);
        #[cfg(target_arch = "x86_64")]
        if crate::simd::available() {
            // SAFETY: AVX2 and FMA are present (checked); `out` holds `n` columns.
            unsafe { self.taps_avx2(n, out) };
            return;
        }
        for x in 0..n {
            match self.tap(x as u32) {
                Some(t) => {
                    out.idx[x] = t.idx;
                    out.w[x] = t.w;
                    out.ok[x] = true;
                }
                None => out.ok[x] = false,
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn taps_avx2(&self, n: usize, out: &mut RowTaps) {
        use std::arch::x86_64::*;
        let ax = _mm256_set1_ps(self.a[0]);
        let ay = _mm256_set1_ps(self.a[1]);
        let aw = _mm256_set1_ps(self.a[2]);
        let bx = _mm256_set1_ps(self.b[0]);
        let by = _mm256_set1_ps(self.b[1]);
        let bw = _mm256_set1_ps(self.b[2]);
        let wf = _mm256_set1_ps(self.wf);
        let hf = _mm256_set1_ps(self.hf);
        let zero = _mm256_setzero_ps();
        let half = _mm256_set1_ps(0.5);
        let one = _mm256_set1_ps(1.0);
        let wmax = _mm256_set1_epi32(self.wmax);
        let hmax = _mm256_set1_epi32(self.hmax);
        let izero = _mm256_setzero_si256();
        let ione = _mm256_set1_epi32(1);
        let stride = _mm256_set1_epi32(self.stride as i32);
        let lane = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let mut x = 0usize;
        while x < n {
            // u = x + 0.5 as in `tap` (x + lane is exact in f32 for any row width here).
            let u = _mm256_add_ps(_mm256_add_ps(_mm256_set1_ps(x as f32), lane), half);
            let wn = _mm256_fmadd_ps(aw, u, bw);
            let inv = _mm256_div_ps(one, wn);
            let sx = _mm256_mul_ps(_mm256_fmadd_ps(ax, u, bx), inv);
            let sy = _mm256_mul_ps(_mm256_fmadd_ps(ay, u, by), inv);
            let mut m = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GT_OQ>(wn, zero),
                _mm256_cmp_ps::<_CMP_GE_OQ>(sx, zero),
            );
            m = _mm256_and_ps(m, _mm256_cmp_ps::<_CMP_LE_OQ>(sx, wf));
            m = _mm256_and_ps(m, _mm256_cmp_ps::<_CMP_GE_OQ>(sy, zero));
            m = _mm256_and_ps(m, _mm256_cmp_ps::<_CMP_LE_OQ>(sy, hf));
            let fx = _mm256_sub_ps(sx, half);
            let fy = _mm256_sub_ps(sy, half);
            let x0f = _mm256_floor_ps(fx);
            let y0f = _mm256_floor_ps(fy);
            let tx = _mm256_sub_ps(fx, x0f);
            let ty = _mm256_sub_ps(fy, y0f);
            // Masked-out lanes may hold garbage (NaN, huge): their indices are never used.
            let x0 = _mm256_cvttps_epi32(x0f);
            let y0 = _mm256_cvttps_epi32(y0f);
            let clamp = |v: __m256i, hi: __m256i| _mm256_min_epi32(_mm256_max_epi32(v, izero), hi);
            let xa = clamp(x0, wmax);
            let xb = clamp(_mm256_add_epi32(x0, ione), wmax);
            let ya = _mm256_mullo_epi32(clamp(y0, hmax), stride);
            let yb = _mm256_mullo_epi32(clamp(_mm256_add_epi32(y0, ione), hmax), stride);
            let omx = _mm256_sub_ps(one, tx);
            let omy = _mm256_sub_ps(one, ty);
            let i4 = [
                _mm256_add_epi32(ya, xa),
                _mm256_add_epi32(ya, xb),
                _mm256_add_epi32(yb, xa),
                _mm256_add_epi32(yb, xb),
            ];
            let w4 = [
                _mm256_mul_ps(omx, omy),
                _mm256_mul_ps(tx, omy),
                _mm256_mul_ps(omx, ty),
                _mm256_mul_ps(tx, ty),
            ];
            let bits = _mm256_movemask_ps(m);
            if n - x >= 8 {
                // A whole step: the four index and weight vectors transposed into 8 columns' taps
                // (columns outside get index 0 and weights 0).
                let mi = _mm256_castps_si256(m);
                let iq = transpose4x8(i4.map(|v| _mm256_castsi256_ps(_mm256_and_si256(v, mi))));
                let wq = transpose4x8(w4.map(|v| _mm256_and_ps(v, m)));
                // SAFETY: `out` holds columns `x..x + 8` (`n - x >= 8`), 4 floats or u32 each.
                unsafe {
                    let ip = out.idx.as_mut_ptr().add(x) as *mut f32;
                    let wp = out.w.as_mut_ptr().add(x) as *mut f32;
                    for j in 0..4 {
                        _mm256_storeu_ps(ip.add(8 * j), iq[j]);
                        _mm256_storeu_ps(wp.add(8 * j), wq[j]);
                    }
                }
                for l in 0..8 {
                    out.ok[x + l] = bits >> l & 1 != 0;
                }
                x += 8;
                continue;
            }
            let mut idx = [[0u32; 8]; 4];
            let mut w = [[0f32; 8]; 4];
            // SAFETY (stores): each array holds 8 lanes.
            unsafe {
                for j in 0..4 {
                    _mm256_storeu_si256(idx[j].as_mut_ptr() as *mut __m256i, i4[j]);
                    _mm256_storeu_ps(w[j].as_mut_ptr(), w4[j]);
                }
            }
            for l in 0..(n - x).min(8) {
                let ok = bits >> l & 1 != 0;
                out.ok[x + l] = ok;
                if ok {
                    out.idx[x + l] = [idx[0][l], idx[1][l], idx[2][l], idx[3][l]];
                    out.w[x + l] = [w[0][l], w[1][l], w[2][l], w[3][l]];
                }
            }
            x += 8;
        }
    }
}

/// Four 8-lane vectors `v[j]` -> 8 groups of 4 (`[v0[l], v1[l], v2[l], v3[l]]` for `l` in `0..8`), as
/// four vectors of two groups each, in column order.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
fn transpose4x8(v: [std::arch::x86_64::__m256; 4]) -> [std::arch::x86_64::__m256; 4] {
    use std::arch::x86_64::*;
    let t0 = _mm256_unpacklo_ps(v[0], v[1]);
    let t1 = _mm256_unpackhi_ps(v[0], v[1]);
    let t2 = _mm256_unpacklo_ps(v[2], v[3]);
    let t3 = _mm256_unpackhi_ps(v[2], v[3]);
    let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
    let u1 = _mm256_shuffle_ps::<0xee>(t0, t2);
    let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
    let u3 = _mm256_shuffle_ps::<0xee>(t1, t3);
    [
        _mm256_permute2f128_ps::<0x20>(u0, u1),
        _mm256_permute2f128_ps::<0x20>(u2, u3),
        _mm256_permute2f128_ps::<0x31>(u0, u1),
        _mm256_permute2f128_ps::<0x31>(u2, u3),
    ]
}

/// Warp a `channels`-channel interleaved source into an `out_w x out_h` image; invalid samples are 0.
/// `valid`, when given, receives 1 where the sample was inside the source and 0 elsewhere.
pub fn warp_image(
    src: &[f32],
    src_w: u32,
    src_h: u32,
    channels: usize,
    h_out_to_src: [f64; 9],
    out_w: u32,
    out_h: u32,
    out: &mut [f32],
    mut valid: Option<&mut [f32]>,
) {
    assert_eq!(src.len(), src_w as usize * src_h as usize * channels);
    assert_eq!(out.len(), out_w as usize * out_h as usize * channels);
    let sampler = Sampler::new(h_out_to_src, src_w, src_h);
    let c = channels;
    for y in 0..out_h {
        let rs = sampler.row(y);
        let row = &mut out[(y * out_w) as usize * c..((y + 1) * out_w) as usize * c];
        for x in 0..out_w {
            let o = &mut row[x as usize * c..(x as usize + 1) * c];
            let vi = (y * out_w + x) as usize;
            match rs.tap(x) {
                None => {
                    o.fill(0.0);
                    if let Some(v) = valid.as_deref_mut() {
                        v[vi] = 0.0;
                    }
                }
                Some(t) => {
                    for (k, ok) in o.iter_mut().enumerate() {
                        let s = |i: usize| src[t.idx[i] as usize * c + k];
                        *ok = t.w[0] * s(0) + t.w[1] * s(1) + t.w[2] * s(2) + t.w[3] * s(3);
                    }
                    if let Some(v) = valid.as_deref_mut() {
                        v[vi] = 1.0;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn row_taps_equal_the_taps() {
        // Homographies with zoom, shear, perspective (some rows behind the camera) and sources the
        // samples leave on every side.
        let homs = [
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            [0.93, 0.05, 3.7, -0.04, 1.07, -2.2, 0.0, 0.0, 1.0],
            [1.3, 0.2, -11.0, 0.1, 0.8, 5.0, 0.002, -0.001, 0.9],
            [0.7, -0.3, 40.0, 0.25, 1.2, -30.0, -0.004, 0.003, 1.1],
            [2.5, 0.0, -60.0, 0.0, 2.5, -40.0, 0.01, 0.0, -0.2],
        ];
        for h in homs {
            for (sw, sh) in [(37u32, 29u32), (64, 48), (1, 1)] {
                let sampler = super::Sampler::new(h, sw, sh);
                let mut taps = super::RowTaps::default();
                for y in 0..31u32 {
                    let row = sampler.row(y);
                    for n in [0usize, 5, 8, 43] {
                        row.taps_into(n, &mut taps);
                        for x in 0..n {
                            assert_eq!(
                                taps.tap(x),
                                row.tap(x as u32),
                                "{h:?} {sw}x{sh} row {y} col {x}"
                            );
                        }
                    }
                }
            }
        }
    }

    use super::*;

    const IDENTITY: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

    fn noise(n: usize, seed: u32) -> Vec<f32> {
        let mut s = seed.wrapping_mul(2654435761).wrapping_add(1);
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                (s % 10007) as f32 / 10007.0
            })
            .collect()
    }

    #[test]
    fn identity_warp_is_bit_exact() {
        let (w, h, c) = (37, 23, 3);
        let src = noise(w * h * c, 7);
        let mut out = vec![0.0; src.len()];
        let mut valid = vec![0.0; w * h];
        warp_image(
            &src,
            w as u32,
            h as u32,
            c,
            IDENTITY,
            w as u32,
            h as u32,
            &mut out,
            Some(&mut valid),
        );
        assert_eq!(out, src);
        assert!(valid.iter().all(|&v| v == 1.0));
    }

    #[test]
    fn half_pixel_shift_averages_neighbours_and_clamps_at_edges() {
        // Output pixel x samples source at x + 0.5 + 0.5 = x + 1.0: halfway between texels x and x+1.
        let src = vec![0.0, 1.0, 4.0, 9.0];
        let h = [1.0, 0.0, 0.5, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let mut out = vec![0.0; 4];
        let mut valid = vec![0.0; 4];
        warp_image(&src, 4, 1, 1, h, 4, 1, &mut out, Some(&mut valid));
        // Last pixel samples at 4.0 (the source's right edge, still inside): clamped to the edge texel.
        assert_eq!(out, vec![0.5, 2.5, 6.5, 9.0]);
        assert_eq!(valid, vec![1.0; 4]);
        // A shift of more than half a pixel more leaves the extent: transparent.
        let h = [1.0, 0.0, 0.75, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        warp_image(&src, 4, 1, 1, h, 4, 1, &mut out, Some(&mut valid));
        assert_eq!(valid, vec![1.0, 1.0, 1.0, 0.0]);
        assert_eq!(out[3], 0.0);
    }

    #[test]
    fn downscale_by_two_samples_texel_corners() {
        // Output 2x1 from a 4x1 source with scale 2: output centre 0.5 -> source 1.0, between texels 0 and 1.
        let src = vec![0.0, 2.0, 4.0, 6.0];
        let h = [2.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let mut out = vec![0.0; 2];
        warp_image(&src, 4, 1, 1, h, 2, 1, &mut out, None);
        assert_eq!(out, vec![1.0, 5.0]);
    }
}
