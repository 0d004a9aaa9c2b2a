//! AVX2 + FMA kernel for the 8-bit renderer: 8 output pixels at a time.
//!
//! Same maths and sampling rule as the scalar path in `render.rs` (tested against it): per plane, the
//! homography gives 8 source positions; in-extent lanes gather their 4 bilinear taps (RGBA8 as one u32),
//! and the premultiplied colour is over-composited into structure-of-arrays row accumulators.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// Whether the CPU can run [`composite_row_u8_avx2`] (AVX2 + FMA).
pub fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Accumulated alpha above which a pixel counts as opaque: planes behind change it by < 1/1024.
pub const SATURATED: f32 = 1.0 - 1.0 / 1024.0;

/// Side of the occupancy tiles.
pub const TILE: usize = 8;

/// Which `TILE x TILE` tiles of each plane hold any non-zero texel: lets the renderer skip empty space.
#[derive(Clone, Debug, PartialEq)]
pub struct Occupancy {
    pub tiles_x: usize,
    pub tiles_y: usize,
    /// `[D][tiles_y][tiles_x]`, 1 where the tile has a non-zero texel.
    pub tiles: Vec<u8>,
    /// `[D]`: whether the plane has an empty tile (decided once here, not per rendered row).
    sparse: Vec<bool>,
    /// `[D][tiles_y][tiles_x / 64 words]`: the occupied tile columns of each tile row, one bit each.
    bits: Vec<u64>,
}

impl Occupancy {
    /// Scan an 8-bit MPI's layers (`[D][H][W][4]`).
    pub fn new(layers: &[u8], width: u32, height: u32, planes: usize) -> Self {
        use rayon::prelude::*;
        let (w, h) = (width as usize, height as usize);
        let (tiles_x, tiles_y) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let mut tiles = vec![0u8; planes * tiles_x * tiles_y];
        tiles
            .par_chunks_mut(tiles_x * tiles_y)
            .enumerate()
            .for_each(|(d, t)| {
                let layer = &layers[d * w * h * 4..(d + 1) * w * h * 4];
                for y in 0..h {
                    let row = &layer[y * w * 4..(y + 1) * w * 4];
                    for (tx, chunk) in row.chunks(TILE * 4).enumerate() {
                        if chunk.iter().any(|&b| b != 0) {
                            t[(y / TILE) * tiles_x + tx] = 1;
                        }
                    }
                }
            });
        let sparse = tiles
            .chunks(tiles_x * tiles_y)
            .map(|t| t.contains(&0))
            .collect();
        let words = tiles_x.div_ceil(64);
        let mut bits = vec![0u64; planes * tiles_y * words];
        for (row, out) in tiles
            .chunks(tiles_x.max(1))
            .zip(bits.chunks_mut(words.max(1)))
        {
            for (t, &o) in row.iter().enumerate() {
                if o != 0 {
                    out[t / 64] |= 1 << (t % 64);
                }
            }
        }
        Self {
            tiles_x,
            tiles_y,
            tiles,
            sparse,
            bits,
        }
    }

    /// The groups of 8 output columns of a band of rows whose samples of plane `d` (`plane_h` rows, seen
    /// through the coefficients of the band's first and last rows, `rows`) can touch an occupied tile,
    /// as sorted disjoint spans `x0..x1` (multiples of 8, within `0..padded_width(width)`) into `spans`:
    /// the runs of tile columns occupied on the source rows the band crosses, mapped back into the band
    /// (conservatively: where the band's corners map in front of the camera, the band maps onto a convex
    /// quadrilateral, and a source column onto a straight line in the band, so the extremes lie on its
    /// first and last rows). True when the band crosses more than two tile rows (a run then holds empty
    /// tiles worth testing group by group).
    pub fn band_spans(
        &self,
        d: usize,
        rows: [RowCoefficients; 2],
        width: usize,
        plane_h: u32,
        spans: &mut Vec<(usize, usize)>,
    ) -> bool {
        spans.clear();
        let wp = padded_width(width);
        let (u0, u1) = (0.5f64, width as f64 - 0.5);
        let at = |r: &RowCoefficients, k: usize, u: f64| r.a[k] as f64 * u + r.b[k] as f64;
        let (mut ylo, mut yhi, mut front) = (f64::INFINITY, f64::NEG_INFINITY, true);
        for r in &rows {
            for u in [u0, u1] {
                let w = at(r, 2, u);
                front &= w > 1e-12;
                let y = at(r, 1, u) / w;
                (ylo, yhi) = (ylo.min(y), yhi.max(y));
            }
        }
        // Otherwise (a corner behind the camera) the whole band.
        if !(front && ylo.is_finite() && yhi.is_finite()) {
            spans.push((0, wp));
            return true;
        }
        if yhi < 0.0 || ylo > plane_h as f64 {
            return false;
        }
        // The source rows the bilinear taps read, and the union of their tile rows' occupied columns.
        // (Truncation is the floor of these non-negative values; `+ 1` bounds the ceiling.)
        let r0 = (ylo - 1.5).max(0.0) as usize;
        let r1 = ((yhi + 1.5).max(0.0) as usize).min(plane_h as usize - 1);
        let (t0, t1) = (r0 / TILE, (r1 / TILE).min(self.tiles_y - 1));
        let words = self.tiles_x.div_ceil(64);
        let mut union = [0u64; 64];
        if words > union.len() {
            spans.push((0, wp));
            return true;
        }
        for ty in t0..=t1 {
            let row = &self.bits[(d * self.tiles_y + ty) * words..][..words];
            for (u, &r) in union.iter_mut().zip(row) {
                *u |= r;
            }
        }
        // Output `u` where the source x equals `s` on row `r` (solving (a0 u + b0) / (a2 u + b2) = s).
        let solve = |r: &RowCoefficients, s: f64| {
            (r.b[0] as f64 - s * r.b[2] as f64) / (s * r.a[2] as f64 - r.a[0] as f64)
        };
        // Runs of set bits, word by word.
        let mut t = 0usize;
        while t < self.tiles_x {
            let (wi, bi) = (t / 64, t % 64);
            let rest = union[wi] >> bi;
            if rest == 0 {
                t = (wi + 1) * 64;
                continue;
            }
            let lo = t + rest.trailing_zeros() as usize;
            // The run's end: the first clear bit from `lo` on.
            let mut end = lo;
            loop {
                let (wi, bi) = (end / 64, end % 64);
                if wi >= words {
                    break;
                }
                let ones = (!(union[wi] >> bi)).trailing_zeros() as usize;
                end += ones.min(64 - bi);
                if ones < 64 - bi {
                    break;
                }
            }
            let end = end.min(self.tiles_x);
            t = end + 1;
            // Samples within a texel and a half of the run's texels can touch them.
            let (slo, shi) = ((lo * TILE) as f64 - 1.5, (end * TILE) as f64 + 1.5);
            let (mut umin, mut umax) = (f64::INFINITY, f64::NEG_INFINITY);
            for r in &rows {
                for s in [slo, shi] {
                    let u = solve(r, s);
                    (umin, umax) = (umin.min(u), umax.max(u));
                }
            }
            if !(umin.is_finite() && umax.is_finite()) {
                spans.clear();
                spans.push((0, wp));
                return true;
            }
            if umax < -1.0 || umin > width as f64 + 1.0 {
                continue;
            }
            let x0 = ((umin - 1.0).max(0.0) as usize / 8) * 8;
            let x1 = (((umax + 2.0).max(0.0) as usize).min(width)).div_ceil(8) * 8;
            if x0 < x1 {
                spans.push((x0, x1));
            }
        }
        // Sorted (runs map in order, or in reverse order for a mirrored row) and merged: a group is
        // composited once.
        if spans.len() > 1 && spans[0].0 > spans[spans.len() - 1].0 {
            spans.reverse();
        }
        if !spans.is_sorted() {
            spans.sort_unstable();
        }
        let mut merged = 0;
        for i in 0..spans.len() {
            if merged > 0 && spans[i].0 <= spans[merged - 1].1 {
                spans[merged - 1].1 = spans[merged - 1].1.max(spans[i].1);
            } else {
                spans[merged] = spans[i];
                merged += 1;
            }
        }
        spans.truncate(merged);
        t1 > t0 + 1
    }

    /// Plane `d`'s tiles.
    pub fn plane(&self, d: usize) -> &[u8] {
        let n = self.tiles_x * self.tiles_y;
        &self.tiles[d * n..(d + 1) * n]
    }

    /// Plane `d`'s tiles if any of them is empty (a full plane gains nothing from the check).
    pub fn sparse_plane(&self, d: usize) -> Option<&[u8]> {
        self.sparse[d].then(|| self.plane(d))
    }

    /// Fraction of non-empty tiles.
    pub fn fill(&self) -> f64 {
        self.tiles.iter().filter(|&&t| t != 0).count() as f64 / self.tiles.len().max(1) as f64
    }
}

/// Accumulator length per channel for a row of `width` pixels (a multiple of 8).
pub fn padded_width(width: usize) -> usize {
    width.div_ceil(8) * 8
}

/// Row set-up of one plane: `src = H (u, v, 1)` with `v` fixed, split into `a * u + b` per coordinate.
#[derive(Clone, Copy, Debug)]
pub struct RowCoefficients {
    pub a: [f32; 3],
    pub b: [f32; 3],
}

/// The signature of the row kernels ([`kernel`] picks one).
#[cfg(target_arch = "x86_64")]
pub type RowKernel = unsafe fn(
    &[u8],
    u32,
    u32,
    RowCoefficients,
    &mut [f32],
    &[(usize, usize)],
    (usize, usize),
    Option<&[u8]>,
) -> (usize, usize);

/// The fastest row kernel this CPU runs: the AVX2 code compiled with AVX-512VL enabled when present
/// (same 256-bit maths, 32 vector registers instead of 16: no spills), else plain AVX2; `None` without
/// AVX2 + FMA (the renderer then takes its scalar path).
#[cfg(target_arch = "x86_64")]
pub fn kernel() -> Option<RowKernel> {
    if !available() {
        return None;
    }
    if is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("avx512vl") {
        Some(composite_row_u8_avx512vl)
    } else {
        Some(composite_row_u8_avx2)
    }
}

/// Both row kernels share one body (a macro), compiled for two feature sets.
#[cfg(target_arch = "x86_64")]
macro_rules! row_kernel {
    ($(#[$doc:meta])* $name:ident, $features:literal) => {
        /// Composite one plane *under* the row accumulators `acc` (`[4][padded_width(width)]`, planar r, g, b,
        /// a; the padding lanes receive unused values): planes are visited front to back, `acc += (1 - acc_a) c`.
        ///
        /// Only the groups of 8 pixels in both the sorted disjoint `spans` and the `open` columns (each
        /// `x0..x1`, multiples of 8 within `acc.len() / 4`) are visited. Work is skipped for groups that
        /// are already opaque (`acc_a >= SATURATED`, so what lies behind changes them by less than 1/1024)
        /// and, given `tiles` (the plane's [`Occupancy`] row), for groups whose taps all fall in fully
        /// transparent tiles. Returns the open columns after this plane (a superset, `lo >= hi`: none):
        /// the hull of the open ones not visited and of the visited ones found open.
        ///
        /// # Safety
        /// The CPU must support the enabled features ([`kernel`] checks). `layer` holds `plane_w * plane_h`
        /// RGBA8 texels.
        $(#[$doc])*
        #[target_feature(enable = $features)]
        pub unsafe fn $name(
            layer: &[u8],
            plane_w: u32,
            plane_h: u32,
            coeff: RowCoefficients,
            acc: &mut [f32],
            spans: &[(usize, usize)],
            (open_lo, open_hi): (usize, usize),
            tiles: Option<&[u8]>,
        ) -> (usize, usize) {
            debug_assert_eq!(layer.len(), plane_w as usize * plane_h as usize * 4);
            let wp = acc.len() / 4;
            assert!(wp % 8 == 0 && open_lo % 8 == 0 && open_hi <= wp);
            assert!(spans.iter().all(|&(a, b)| a % 8 == 0 && b <= wp));
            // The new open columns: the hull of the open ones not visited and of the visited groups
            // found open.
            let (mut lo, mut hi) = (usize::MAX, 0usize);
            let mut cursor = open_lo;
            let base = layer.as_ptr() as *const i32;
            let (ar, ag, ab, aa) = {
                let (r, rest) = acc.split_at_mut(wp);
                let (g, rest) = rest.split_at_mut(wp);
                let (b, a) = rest.split_at_mut(wp);
                (
                    r.as_mut_ptr(),
                    g.as_mut_ptr(),
                    b.as_mut_ptr(),
                    a.as_mut_ptr(),
                )
            };
            let ax = _mm256_set1_ps(coeff.a[0]);
            let ay = _mm256_set1_ps(coeff.a[1]);
            let aw = _mm256_set1_ps(coeff.a[2]);
            let bx = _mm256_set1_ps(coeff.b[0]);
            let by = _mm256_set1_ps(coeff.b[1]);
            let bw = _mm256_set1_ps(coeff.b[2]);
            let wf = _mm256_set1_ps(plane_w as f32);
            let hf = _mm256_set1_ps(plane_h as f32);
            let zero = _mm256_setzero_ps();
            let half = _mm256_set1_ps(0.5);
            let one = _mm256_set1_ps(1.0);
            let inv255 = _mm256_set1_ps(1.0 / 255.0);
            let wmax = _mm256_set1_epi32(plane_w as i32 - 1);
            let hmax = _mm256_set1_epi32(plane_h as i32 - 1);
            let izero = _mm256_setzero_si256();
            let ione = _mm256_set1_epi32(1);
            let stride = _mm256_set1_epi32(plane_w as i32);
            let byte = _mm256_set1_epi32(0xff);
            let seven = _mm256_set1_epi32(7);
            let fifteen = _mm256_set1_epi32(15);
            let lane = _mm256_setr_ps(0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5);
            let saturated = _mm256_set1_ps(SATURATED);
            let tiles_x = (plane_w as usize).div_ceil(TILE);
            for &(a, b) in spans {
            let (x0, x1) = (a.max(open_lo), b.min(open_hi));
            if x0 >= x1 {
                continue;
            }
            if x0 > cursor {
                (lo, hi) = (lo.min(cursor), hi.max(x0));
            }
            let mut x = x0;
            while x < x1 {
                // SAFETY: x + 8 <= wp, the padded length of each accumulator.
                let cur_a = unsafe { _mm256_loadu_ps(aa.add(x)) };
                if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(cur_a, saturated)) == 0 {
                    x += 8;
                    continue;
                }
                (lo, hi) = (lo.min(x), x + 8);
                let u = _mm256_add_ps(_mm256_set1_ps(x as f32), lane);
                let wn = _mm256_fmadd_ps(aw, u, bw);
                let inv = _mm256_div_ps(one, wn);
                let sx = _mm256_mul_ps(_mm256_fmadd_ps(ax, u, bx), inv);
                let sy = _mm256_mul_ps(_mm256_fmadd_ps(ay, u, by), inv);
                // Inside the plane's extent and in front (ordered comparisons are false for NaN).
                let mut m = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GT_OQ>(wn, zero),
                    _mm256_cmp_ps::<_CMP_GE_OQ>(sx, zero),
                );
                m = _mm256_and_ps(m, _mm256_cmp_ps::<_CMP_LE_OQ>(sx, wf));
                m = _mm256_and_ps(m, _mm256_cmp_ps::<_CMP_GE_OQ>(sy, zero));
                m = _mm256_and_ps(m, _mm256_cmp_ps::<_CMP_LE_OQ>(sy, hf));
                let mi = _mm256_castps_si256(m);
                if _mm256_testz_si256(mi, mi) == 0 {
                    let fx = _mm256_sub_ps(sx, half);
                    let fy = _mm256_sub_ps(sy, half);
                    let x0f = _mm256_floor_ps(fx);
                    let y0f = _mm256_floor_ps(fy);
                    let tx = _mm256_sub_ps(fx, x0f);
                    let ty = _mm256_sub_ps(fy, y0f);
                    let x0 = _mm256_cvttps_epi32(x0f);
                    let y0 = _mm256_cvttps_epi32(y0f);
                    macro_rules! clamp {
                        ($v:expr, $hi:expr) => {
                            _mm256_min_epi32(_mm256_max_epi32($v, izero), $hi)
                        };
                    }
                    let xa = clamp!(x0, wmax);
                    let xb = clamp!(_mm256_add_epi32(x0, ione), wmax);
                    let yra = clamp!(y0, hmax);
                    let yrb = clamp!(_mm256_add_epi32(y0, ione), hmax);
                    if let Some(t) = tiles {
                        // Source coordinates are monotonic along an output row (a homography restricted to a
                        // line), so lanes 0 and 7 bound the taps of the group.
                        let (xa0, xa7) = (
                            _mm256_extract_epi32::<0>(xa) as usize,
                            _mm256_extract_epi32::<7>(xb) as usize,
                        );
                        let (ya0, ya7) = (
                            _mm256_extract_epi32::<0>(yra) as usize,
                            _mm256_extract_epi32::<7>(yra) as usize,
                        );
                        let (yb0, yb7) = (
                            _mm256_extract_epi32::<0>(yrb) as usize,
                            _mm256_extract_epi32::<7>(yrb) as usize,
                        );
                        let (tx0, tx1) = (xa0.min(xa7) / TILE, xa0.max(xa7) / TILE);
                        let (ty0, ty1) = (
                            ya0.min(ya7).min(yb0.min(yb7)) / TILE,
                            ya0.max(ya7).max(yb0.max(yb7)) / TILE,
                        );
                        let mut any = false;
                        for ty in ty0..=ty1 {
                            any |= t[ty * tiles_x + tx0..=ty * tiles_x + tx1]
                                .iter()
                                .any(|&o| o != 0);
                        }
                        if !any {
                            x += 8;
                            continue;
                        }
                    }
                    let ya = _mm256_mullo_epi32(yra, stride);
                    let yb = _mm256_mullo_epi32(yrb, stride);
                    // Fast path: when every active lane reads the same two source rows, its left taps lie within
                    // 16 consecutive texels and its right taps are the next texels (no edge clamping; true for
                    // views near the reference camera, translations and zooms up to 2x included), contiguous
                    // loads (two rows, offsets 0 and 1; and 8 texels further when the taps span more than 8)
                    // and lane permutations replace the four gathers.
                    let ya0 = _mm256_permutevar8x32_epi32(ya, izero);
                    let xs = _mm256_min_epi32(
                        _mm256_permutevar8x32_epi32(xa, izero),
                        _mm256_set1_epi32(plane_w as i32 - 17),
                    );
                    let ia = _mm256_and_si256(_mm256_sub_epi32(xa, xs), mi);
                    // Both rows: near the top edge, row b is clamped onto row a for some lanes only.
                    let yb0 = _mm256_permutevar8x32_epi32(yb, izero);
                    let same_rows = _mm256_andnot_si256(
                        _mm256_and_si256(_mm256_cmpeq_epi32(ya, ya0), _mm256_cmpeq_epi32(yb, yb0)),
                        mi,
                    );
                    let not_next =
                        _mm256_andnot_si256(_mm256_cmpeq_epi32(xb, _mm256_add_epi32(xa, ione)), mi);
                    let out_of_window =
                        _mm256_or_si256(_mm256_cmpgt_epi32(izero, ia), _mm256_cmpgt_epi32(ia, fifteen));
                    let lane0_active = _mm256_extract_epi32::<0>(mi) != 0;
                    let permutable = plane_w >= 17
                        && lane0_active
                        && _mm256_testz_si256(
                            _mm256_or_si256(_mm256_or_si256(same_rows, not_next), out_of_window),
                            mi,
                        ) != 0;
                    let (t00, t01, t10, t11) = if permutable {
                        let off = (_mm256_extract_epi32::<0>(ya0) + _mm256_extract_epi32::<0>(xs)) as usize;
                        let dy = (_mm256_extract_epi32::<0>(yb0) - _mm256_extract_epi32::<0>(ya0)) as usize;
                        // The next output rows read the source rows below: ask for them early (a
                        // prefetch never faults, so the address may lie past the plane).
                        _mm_prefetch::<_MM_HINT_T0>(
                            base.wrapping_add(off + 2 * plane_w as usize) as *const i8
                        );
                        // Lanes whose left tap lies 8..15 texels to the right of the window start.
                        let upper = _mm256_and_si256(_mm256_cmpgt_epi32(ia, seven), mi);
                        // Eight texels from `at`, permuted into the lanes (`permutevar` uses the low 3 bits of
                        // `ia`); when some lane reaches past them, blended with the eight that follow.
                        // SAFETY (the loads): 0 <= xs and xs + 17 <= plane_w, and both rows are inside the plane.
                        let wide = _mm256_testz_si256(upper, upper) == 0;
                        macro_rules! taps {
                            ($at:expr) => {{
                                let at: usize = $at;
                                let lo = _mm256_permutevar8x32_epi32(
                                    unsafe { _mm256_loadu_si256(base.add(at) as *const __m256i) },
                                    ia,
                                );
                                let t = if wide {
                                    let hi = _mm256_permutevar8x32_epi32(
                                        unsafe {
                                            _mm256_loadu_si256(base.add(at + 8) as *const __m256i)
                                        },
                                        ia,
                                    );
                                    _mm256_blendv_epi8(lo, hi, upper)
                                } else {
                                    lo
                                };
                                _mm256_and_si256(t, mi)
                            }};
                        }
                        (taps!(off), taps!(off + 1), taps!(off + dy), taps!(off + dy + 1))
                    } else {
                        // SAFETY: indices are clamped into the plane, so every lane (masked or not) is in bounds.
                        unsafe {
                            (
                                _mm256_mask_i32gather_epi32::<4>(izero, base, _mm256_add_epi32(ya, xa), mi),
                                _mm256_mask_i32gather_epi32::<4>(izero, base, _mm256_add_epi32(ya, xb), mi),
                                _mm256_mask_i32gather_epi32::<4>(izero, base, _mm256_add_epi32(yb, xa), mi),
                                _mm256_mask_i32gather_epi32::<4>(izero, base, _mm256_add_epi32(yb, xb), mi),
                            )
                        }
                    };
                    // Bilinear weights with the 1/255 of the 8-bit texels folded in.
                    let sx1 = _mm256_mul_ps(_mm256_sub_ps(one, tx), inv255);
                    let sx2 = _mm256_mul_ps(tx, inv255);
                    let oy = _mm256_sub_ps(one, ty);
                    let w00 = _mm256_mul_ps(sx1, oy);
                    let w01 = _mm256_mul_ps(sx2, oy);
                    let w10 = _mm256_mul_ps(sx1, ty);
                    let w11 = _mm256_mul_ps(sx2, ty);
                    macro_rules! chan {
                        ($t:expr, $shift:literal) => {
                            _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32::<$shift>($t), byte))
                        };
                    }
                    macro_rules! sample {
                        ($shift:literal) => {{
                            let s = _mm256_mul_ps(w00, chan!(t00, $shift));
                            let s = _mm256_fmadd_ps(w01, chan!(t01, $shift), s);
                            let s = _mm256_fmadd_ps(w10, chan!(t10, $shift), s);
                            _mm256_fmadd_ps(w11, chan!(t11, $shift), s)
                        }};
                    }
                    let a = sample!(24);
                    let keep = _mm256_sub_ps(one, cur_a);
                    // SAFETY (the four accumulators): x + 8 <= wp, the padded length of each.
                    macro_rules! under {
                        ($ptr:expr, $value:expr) => {{
                            let p = unsafe { $ptr.add(x) };
                            let cur = unsafe { _mm256_loadu_ps(p) };
                            unsafe { _mm256_storeu_ps(p, _mm256_fmadd_ps(keep, $value, cur)) };
                        }};
                    }
                    under!(ar, sample!(0));
                    under!(ag, sample!(8));
                    under!(ab, sample!(16));
                    // SAFETY: as above.
                    unsafe { _mm256_storeu_ps(aa.add(x), _mm256_fmadd_ps(keep, a, cur_a)) };
                }
                x += 8;
            }
            cursor = cursor.max(x1);
            }
            if cursor < open_hi {
                (lo, hi) = (lo.min(cursor), open_hi);
            }
            (lo, hi)
        }
    };
}

#[cfg(target_arch = "x86_64")]
row_kernel!(
    /// AVX2 + FMA.
    composite_row_u8_avx2,
    "avx2,fma"
);
#[cfg(target_arch = "x86_64")]
row_kernel!(
    /// The AVX2 body with AVX-512F/VL enabled (32 registers).
    composite_row_u8_avx512vl,
    "avx2,fma,avx512f,avx512vl"
);

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;

    /// The AVX-512VL build of the kernel computes exactly what the AVX2 build does (the renderer's tests
    /// compare the dispatched kernel with the scalar path).
    #[test]
    fn both_kernel_builds_agree() {
        if !available() {
            return;
        }
        let avx512 = is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("avx512vl");
        let (pw, ph) = (45u32, 31u32);
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as u32
        };
        let layer: Vec<u8> = (0..pw * ph * 4).map(|_| (next() % 256) as u8).collect();
        let occ = Occupancy::new(&layer, pw, ph, 1);
        let width = 37;
        let wp = padded_width(width);
        // Pure shifts (contiguous-load path), a zoom, a rotation-like shear, a perspective row.
        let rows = [
            ([1.0, 0.0, 0.0], [2.3, 7.6, 1.0]),
            ([1.0, 0.0, 0.0], [-3.7, 0.2, 1.0]),
            ([1.3, 0.02, 0.0], [0.4, 12.1, 1.0]),
            ([1.9, 0.0, 0.0], [-2.2, 4.4, 1.0]),
            ([0.97, 0.05, 0.0], [5.0, 3.0, 1.0]),
            ([0.9, 0.1, 0.004], [1.0, 2.0, 0.95]),
        ];
        for (a, b) in rows {
            let coeff = RowCoefficients { a, b };
            let start: Vec<f32> = (0..4 * wp).map(|i| (i % 7) as f32 * 0.1).collect();
            for tiles in [None, occ.sparse_plane(0)] {
                let mut x = start.clone();
                let mut y = start.clone();
                // SAFETY: AVX2 + FMA checked above (and AVX-512 before using it).
                let (spans, open) = ([(0, wp)], (0, wp));
                unsafe {
                    composite_row_u8_avx2(&layer, pw, ph, coeff, &mut x, &spans, open, tiles)
                };
                if avx512 {
                    unsafe {
                        composite_row_u8_avx512vl(
                            &layer, pw, ph, coeff, &mut y, &spans, open, tiles,
                        )
                    };
                    assert_eq!(x, y, "row {a:?} {b:?}");
                }
                assert_ne!(x, start, "the row composited nothing");
            }
        }
    }

    /// Every output pixel of a band whose bilinear taps (as the kernel computes them) touch an occupied
    /// tile lies in one of the band's spans: random sparse tiles, bands of 1 to 16 rows, homographies
    /// that shift, zoom, roll, mirror and tilt.
    #[test]
    fn band_spans_cover_every_sample_of_an_occupied_tile() {
        let (pw, ph) = (203u32, 131u32);
        let mut state = 7u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut spans = Vec::new();
        let mut checked = 0;
        for case in 0..500 {
            // A few occupied texels, each making its tile occupied.
            let mut layer = vec![0u8; (pw * ph * 4) as usize];
            for _ in 0..3 + case % 6 {
                let (x, y) = ((next() * pw as f64) as usize, (next() * ph as f64) as usize);
                layer[(y * pw as usize + x) * 4 + 3] = 255;
            }
            let occ = Occupancy::new(&layer, pw, ph, 1);
            // Output pixel (u, v) -> source: a similarity (scale, roll, mirror), a shift and a tilt.
            let (scale, roll) = (0.3 + 2.5 * next(), (next() - 0.5) * 2.0);
            let mirror = if case % 5 == 0 { -1.0 } else { 1.0 };
            let (c, s) = (roll.cos() * scale, roll.sin() * scale);
            let tilt = (next() - 0.5) * 0.004;
            let h = [
                mirror * c,
                -s,
                next() * 150.0 - 40.0,
                mirror * s,
                c,
                next() * 120.0 - 50.0,
                tilt,
                (next() - 0.5) * 0.002,
                1.0,
            ];
            let row = |v: f64| RowCoefficients {
                a: [h[0] as f32, h[3] as f32, h[6] as f32],
                b: [
                    (h[1] * v + h[2]) as f32,
                    (h[4] * v + h[5]) as f32,
                    (h[7] * v + h[8]) as f32,
                ],
            };
            let width = 150;
            let band = 1 + case % 16;
            let y0 = (next() * 100.0) as usize;
            let rows = [row(y0 as f64 + 0.5), row((y0 + band - 1) as f64 + 0.5)];
            occ.band_spans(0, rows, width, ph, &mut spans);
            for y in y0..y0 + band {
                let r = row(y as f64 + 0.5);
                for x in 0..width {
                    let u = x as f32 + 0.5;
                    let wn = r.a[2].mul_add(u, r.b[2]);
                    let (sx, sy) = (
                        r.a[0].mul_add(u, r.b[0]) / wn,
                        r.a[1].mul_add(u, r.b[1]) / wn,
                    );
                    if !(wn > 0.0
                        && (0.0..=pw as f32).contains(&sx)
                        && (0.0..=ph as f32).contains(&sy))
                    {
                        continue;
                    }
                    let (x0, y0) = ((sx - 0.5).floor() as i64, (sy - 0.5).floor() as i64);
                    let touches = [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)]
                        .iter()
                        .any(|&(tx, ty)| {
                            let (tx, ty) = (tx.clamp(0, pw as i64 - 1), ty.clamp(0, ph as i64 - 1));
                            occ.plane(0)[ty as usize / TILE * occ.tiles_x + tx as usize / TILE] != 0
                        });
                    if touches {
                        checked += 1;
                        assert!(
                            spans.iter().any(|&(a, b)| (a..b).contains(&x)),
                            "case {case}: pixel ({x}, {y}) touches an occupied tile outside {spans:?}"
                        );
                    }
                }
            }
        }
        assert!(
            checked > 1000,
            "only {checked} samples touched an occupied tile"
        );
    }
}
