//! The cross-view agreement MPI: the one definition of `psv-mean`'s MPI and of the learned model's
//! agreement prior (`deepview_net`'s burn graph and its CPU engine compute the same arithmetic in their own
//! layouts and are tested against [`agreement_mpi`]).
//!
//! For every plane `d` and reference pixel: colour = mean of the views' valid plane-sweep samples;
//! agreement logit `l_d = -v_d / s` with `v_d` the variance of the valid samples (mean over RGB;
//! [`SINGLE_VIEW_VARIANCE`] where one view sees the point, no weight where none does) and `s` the
//! temperature ([`TEMPERATURE`] by default); with a [`Census`] term, its weight times the fraction of the
//! views' census bits that differ ([`census_disagreement`]) is added to `v_d` where two or more views see
//! the point. With a leave-one-out weight `b` ([`Aggregation::leave_one_out`]) and three or more views
//! seeing the point, `v_d` is first `(1 - b) v_d + b` times the least variance of the samples left when one
//! view is left out ([`leave_one_out_variance`]): a view occluded at that depth no longer hides the
//! others' agreement (the occlusion handling of multi-view stereo by view selection). With
//! [`Aggregation::sample_variance`] `v_d` of a point `n >= 2` views see is then scaled by `n / (n - 1)`
//! (the sample variance: a plane where two views happen to agree no longer beats one that more views
//! see for the estimator's bias alone).
//! With an [`Aggregation`] of radius `r > 0` and weight `a`
//! each plane's variance is first replaced by `a` times its mean over the seen pixels of the
//! `(2r+1) x (2r+1)` window around each pixel plus `1 - a` times its own value ([`aggregate_seen`]:
//! classic stereo cost aggregation, the window clipped at the image border, with extra weight on the
//! centre). With [`Smoothing`] the logits then go through semi-global matching over the planes
//! ([`smooth_semi_global`]: the classic stereo regulariser that favours depth staying on a plane or one
//! plane away along 8 image directions). A softmax over planes turns the logits into a depth
//! distribution `w_d` (sum 1), which becomes alpha so that each plane's visible contribution in the
//! reference view is exactly `w_d`: `a_d = w_d / sum_{i<=d} w_i` (planes back to front, so the farthest
//! plane with weight is opaque).

use crate::composite::SyncPtr;
use crate::{Mpi, plane_sweep};
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use rayon::prelude::*;

/// `s` in `exp(-variance / s)`: the colour variance (mean over RGB, values in 0..1) that counts as
/// disagreement (0.0005, a colour standard deviation of about 0.02, worked best of 0.002 / 0.0005 / 0.0002 /
/// 0.00005 on LLFF fern at 1/8 resolution).
pub const TEMPERATURE: f64 = 0.0005;
/// The variance assumed where only one view sees a plane point (no agreement can be measured).
pub const SINGLE_VIEW_VARIANCE: f64 = 0.02;
/// The learned model's prior clamps colour and alpha to `[LOGIT_EPS, 1 - LOGIT_EPS]` before their logits.
pub const LOGIT_EPS: f64 = 1e-4;

/// The agreement MPI of `inputs` (RGB) in `reference` at `depths` (see the module docs): mean colour
/// premultiplied by the alpha of the depth distribution.
pub fn agreement_mpi(
    inputs: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: Vec<f64>,
    temperature: f64,
    single_view_variance: f64,
    aggregation: Aggregation,
) -> Mpi {
    let (mut mpi, logits) = sweep_statistics(
        inputs,
        reference,
        depths,
        temperature,
        single_view_variance,
        aggregation,
    );
    let n = reference.width as usize * reference.height as usize;
    let alphas = depth_distribution_to_alpha(&logits, mpi.planes(), n);
    // Premultiply: texel (mean colour) * alpha.
    let (plane_len, planes) = (mpi.plane_len(), mpi.planes());
    mpi.layers
        .par_chunks_mut(plane_len)
        .enumerate()
        .for_each(|(d, plane)| {
            for (p, t) in plane.chunks_exact_mut(4).enumerate() {
                let a = alphas[p * planes + d];
                t[0] *= a;
                t[1] *= a;
                t[2] *= a;
                t[3] = a;
            }
        });
    mpi
}

/// Per plane: the mean colour of the valid samples in the MPI texels (alpha still 0), and the agreement logits
/// `[D][n]` (with `aggregation`, see the module docs), computed one plane at a time so memory stays
/// at one MPI.
pub fn sweep_statistics(
    inputs: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: Vec<f64>,
    temperature: f64,
    single_view_variance: f64,
    aggregation: Aggregation,
) -> (Mpi, Vec<f32>) {
    let n = reference.width as usize * reference.height as usize;
    let mut mpi = Mpi::transparent(*reference, depths);
    let mut logits = vec![f32::NEG_INFINITY; mpi.planes() * n];
    let depths = mpi.depths.clone();
    let s = temperature;
    let single = -(single_view_variance / s) as f32;
    mpi.layers
        .par_chunks_mut(n * 4)
        .zip(logits.par_chunks_mut(n))
        .zip(depths.par_iter())
        .for_each(|((texels, logit), &depth)| {
            // Running sums per pixel: [sum r, g, b, sum r^2, g^2, b^2, count].
            let mut acc = vec![[0.0f64; 7]; n];
            let mut greys = Vec::new();
            // With the leave-one-out term: the views' samples, for their deviations from the mean.
            let mut samples = Vec::new();
            for (img, cam) in inputs {
                let psv = plane_sweep(img, cam, reference, &[depth]);
                if aggregation.census.is_some() {
                    greys.push(grey_levels(&psv.data));
                }
                for (a, s) in acc.iter_mut().zip(psv.data.chunks_exact(4)) {
                    if s[3] > 0.0 {
                        for c in 0..3 {
                            a[c] += s[c] as f64;
                            a[3 + c] += (s[c] as f64) * (s[c] as f64);
                        }
                        a[6] += 1.0;
                    }
                }
                if aggregation.leave_one_out.is_some() {
                    samples.push(psv.data);
                }
            }
            let (w, h) = (reference.width as usize, reference.height as usize);
            // The census term's share of each pixel's cost.
            let census = aggregation.census.map(|c| {
                let views: Vec<&[f32]> = greys.iter().map(Vec::as_slice).collect();
                let mut cost = vec![0f32; n];
                census_disagreement(
                    &views,
                    w,
                    h,
                    c.radius,
                    &mut CensusScratch::default(),
                    &mut cost,
                );
                (cost, c.weight as f64)
            });
            for (p, ((t, l), a)) in texels
                .chunks_exact_mut(4)
                .zip(logit.iter_mut())
                .zip(&acc)
                .enumerate()
            {
                let k = a[6];
                if k == 0.0 {
                    continue;
                }
                let mut var = 0.0;
                for c in 0..3 {
                    let m = a[c] / k;
                    t[c] = m as f32;
                    var += (a[3 + c] / k - m * m).max(0.0);
                }
                let mut var = var / 3.0;
                if let Some(b) = aggregation.leave_one_out.filter(|_| k >= 3.0) {
                    // The largest deviation (summed over RGB) of one view's sample from the mean.
                    let mut max_dev = 0.0f64;
                    for v in &samples {
                        let x = &v[4 * p..4 * p + 4];
                        if x[3] > 0.0 {
                            let dev: f64 = (0..3).map(|c| (x[c] as f64 - a[c] / k).powi(2)).sum();
                            max_dev = max_dev.max(dev);
                        }
                    }
                    let loo = leave_one_out_variance(var * 3.0 * k, max_dev, k);
                    var = (1.0 - b as f64) * var + b as f64 * loo;
                }
                if aggregation.sample_variance && k >= 2.0 {
                    var *= k / (k - 1.0);
                }
                *l = if k >= 2.0 {
                    let census = census.as_ref().map_or(0.0, |(c, w)| w * c[p] as f64);
                    -((var + census) / s) as f32
                } else {
                    single
                };
            }
            aggregate_seen(logit, w, h, aggregation, &mut Vec::new());
        });
    if let Some(smoothing) = aggregation.smoothing {
        let (w, h) = (reference.width as usize, reference.height as usize);
        let cap = (single_view_variance / s) as f32;
        smooth_semi_global(&mut logits, w, h, mpi.planes(), smoothing, cap);
    }
    (mpi, logits)
}

/// The grey level [`census_disagreement`] takes of a plane-sweep sample: the mean of R, G, B where the
/// view sees the point (`valid > 0`), NaN where it does not.
#[inline]
pub fn grey_level(r: f32, g: f32, b: f32, valid: f32) -> f32 {
    if valid > 0.0 {
        (r + g + b) / 3.0
    } else {
        f32::NAN
    }
}

/// [`grey_level`]s of pixel-major RGBA samples (A: validity).
pub fn grey_levels(rgba: &[f32]) -> Vec<f32> {
    rgba.chunks_exact(4)
        .map(|s| grey_level(s[0], s[1], s[2], s[3]))
        .collect()
}

/// Values at or below this are "unseen" in [`aggregate_seen`] (the engines mark unseen plane points with
/// `-1e30` or `-inf`).
pub const UNSEEN_BELOW: f32 = -1e29;

/// The agreement's cost and its aggregation: optionally a census term in each plane point's cost
/// ([`Census`]), the radius `r` of the window and the weight `a` of its mean (the rest is the pixel's own
/// cost; `r = 0` or `a = 0`: per pixel), then optionally semi-global matching over the planes
/// ([`Smoothing`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aggregation {
    pub radius: usize,
    pub weight: f64,
    /// Semi-global matching after the window ([`smooth_semi_global`]); `None`: none.
    pub smoothing: Option<Smoothing>,
    /// The census term of the matching cost ([`Census`]), added to each plane's variance before the
    /// window; `None`: the variance alone.
    pub census: Option<Census>,
    /// The weight `b` (in `(0, 1]`) of the least leave-one-out variance ([`leave_one_out_variance`]) in
    /// the variance of a plane point three or more views see: `(1 - b) v + b v_loo`; `None`: `v`.
    pub leave_one_out: Option<f32>,
    /// Scale the variance (after the leave-one-out blend) of a point `n >= 2` views see by
    /// `n / (n - 1)`: the sample variance instead of the population variance.
    pub sample_variance: bool,
}

impl Aggregation {
    /// Per pixel (`psv-mean`'s default).
    pub const NONE: Aggregation = Aggregation {
        radius: 0,
        weight: 1.0,
        smoothing: None,
        census: None,
        leave_one_out: None,
        sample_variance: false,
    };

    /// A window of radius `radius` weighted `weight`, without smoothing or a census term.
    pub const fn window(radius: usize, weight: f64) -> Aggregation {
        Aggregation {
            radius,
            weight,
            smoothing: None,
            census: None,
            leave_one_out: None,
            sample_variance: false,
        }
    }

    /// Whether the window changes anything.
    pub fn is_active(&self) -> bool {
        self.radius > 0 && self.weight > 0.0
    }
}

/// Whether `b` is a leave-one-out weight [`Aggregation::leave_one_out`] takes: finite, in `(0, 1]`.
pub fn leave_one_out_weight_is_valid(b: f32) -> bool {
    b.is_finite() && b > 0.0 && b <= 1.0
}

/// A leave-one-out weight as the options take it: a number in `(0, 1]`.
pub fn parse_leave_one_out(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(b) if leave_one_out_weight_is_valid(b) => Ok(b),
        Ok(_) => Err(format!("{s:?} must be above 0 and at most 1")),
        Err(_) => Err(format!("{s:?} is not a number")),
    }
}

/// The least variance (mean over RGB) of a plane point's samples when one of the `n >= 3` views that see
/// it is left out: from the sum over the views and RGB of the squared deviations from the mean, `ss`, and
/// the largest of one view's (summed over RGB), `max_dev`. Leaving out sample `i` takes
/// `n / (n - 1)` times its squared deviation from the sum of squares, so the least variance leaves out
/// the farthest sample: `(ss - n / (n - 1) max_dev) / (3 (n - 1))` (at least 0).
#[inline]
pub fn leave_one_out_variance(ss: f64, max_dev: f64, n: f64) -> f64 {
    debug_assert!(n >= 3.0, "leave-one-out with {n} views");
    ((ss - n / (n - 1.0) * max_dev) / (3.0 * (n - 1.0))).max(0.0)
}

/// The census term of the agreement's matching cost: each view's plane sweep (its grey level, the mean of
/// R, G, B) is census-transformed over the `(2r+1)^2` window around each pixel (a bit per neighbour: darker
/// than the centre or not; Zabih & Woodfill 1994), and a plane point's census cost is the mean, over the
/// pairs of views that see it, of the fraction of the window's bits (neighbours both see) that differ
/// ([`census_disagreement`]). `weight` times that cost (0..1) is added to the colour variance where two
/// or more views see the point. Unlike the variance it ignores the views' differences in exposure and
/// colour, and it sees the window's structure: the classic robust cost of stereo matching.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Census {
    pub weight: f32,
    /// The window's radius (2, a 5x5 window, when a config omits it).
    #[serde(default = "census_radius")]
    pub radius: usize,
}

fn census_radius() -> usize {
    2
}

impl Census {
    /// The largest radius (`(2r+1)^2 - 1` bits must fit 64).
    pub const MAX_RADIUS: usize = 3;

    /// Whether it is usable: a finite `weight > 0` (no term is `None`), `1 <= radius <= MAX_RADIUS`.
    pub fn is_valid(&self) -> bool {
        self.weight.is_finite()
            && self.weight > 0.0
            && (1..=Self::MAX_RADIUS).contains(&self.radius)
    }
}

impl std::str::FromStr for Census {
    type Err = String;

    /// `WEIGHT[,RADIUS]` (radius 2 by default), e.g. `0.03` or `0.03,3`.
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || {
            format!(
                "{s:?} is not a census weight with an optional radius, WEIGHT[,RADIUS] with WEIGHT > 0 \
                 and RADIUS 1..={} (e.g. 0.03 or 0.03,2)",
                Census::MAX_RADIUS
            )
        };
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let (weight, radius) = match parts[..] {
            [w] => (w, "2"),
            [w, r] => (w, r),
            _ => return Err(bad()),
        };
        let census = Census {
            weight: weight.parse().map_err(|_| bad())?,
            radius: radius.parse().map_err(|_| bad())?,
        };
        if census.is_valid() {
            Ok(census)
        } else {
            Err(bad())
        }
    }
}

/// Reusable scratch of [`census_disagreement`]: the views' census codes and masks, 32 bits per pixel
/// where the window's neighbours fit (radius 1 and 2: 8 and 24 bits), else 64.
#[derive(Clone, Debug, Default)]
pub struct CensusScratch {
    narrow: Vec<u32>,
    wide: Vec<u64>,
}

/// A census code (one bit per neighbour of the window) as [`census_disagreement`] stores it.
trait CensusCode: Copy + Default + PartialEq + Send + Sync {
    const BITS: u32;
    fn bit(set: bool, at: u32) -> Self;
    fn or(self, other: Self) -> Self;
    fn and(self, other: Self) -> Self;
    fn xor(self, other: Self) -> Self;
    fn ones(self) -> u32;
}

macro_rules! census_code {
    ($t:ty) => {
        impl CensusCode for $t {
            const BITS: u32 = <$t>::BITS;
            #[inline(always)]
            fn bit(set: bool, at: u32) -> Self {
                <$t>::from(set) << at
            }
            #[inline(always)]
            fn or(self, other: Self) -> Self {
                self | other
            }
            #[inline(always)]
            fn and(self, other: Self) -> Self {
                self & other
            }
            #[inline(always)]
            fn xor(self, other: Self) -> Self {
                self ^ other
            }
            #[inline(always)]
            fn ones(self) -> u32 {
                self.count_ones()
            }
        }
    };
}
census_code!(u32);
census_code!(u64);

/// The census cost of [`Census`] on one plane: `greys` holds each view's plane sweep as grey levels
/// `[h][w]` (NaN where the view does not see the plane point); `out` (`[h][w]`) gets the mean over the
/// pairs of views seeing a pixel (with a neighbour both see) of the fraction of differing census bits
/// over the window of `radius`, 0 where no pair does. `scratch` is reused (any content). Serial: callers
/// run planes in parallel.
pub fn census_disagreement(
    greys: &[&[f32]],
    w: usize,
    h: usize,
    radius: usize,
    scratch: &mut CensusScratch,
    out: &mut [f32],
) {
    assert!(
        (1..=Census::MAX_RADIUS).contains(&radius),
        "census radius {radius}"
    );
    assert_eq!(out.len(), w * h, "census_disagreement: output size");
    // The neighbours of the window, (2r+1)^2 - 1, in a code of 32 bits where they fit (8 lanes of a
    // vector register where 64-bit codes take 4).
    if (2 * radius + 1).pow(2) - 1 <= u32::BITS as usize {
        census_dispatch(greys, w, h, radius, &mut scratch.narrow, out);
    } else {
        census_dispatch(greys, w, h, radius, &mut scratch.wide, out);
    }
}

/// [`census_with`] compiled for AVX2 and `popcnt` where the CPU has them (the codes built 8 lanes at a
/// time, each pair's differing bits counted by one instruction), else for the baseline x86-64.
fn census_dispatch<C: CensusCode>(
    greys: &[&[f32]],
    w: usize,
    h: usize,
    radius: usize,
    bits: &mut Vec<C>,
    out: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("popcnt") {
        // SAFETY: the CPU has the features `census_avx2` is compiled for.
        return unsafe { census_avx2(greys, w, h, radius, bits, out) };
    }
    census_with(greys, w, h, radius, bits, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
fn census_avx2<C: CensusCode>(
    greys: &[&[f32]],
    w: usize,
    h: usize,
    radius: usize,
    bits: &mut Vec<C>,
    out: &mut [f32],
) {
    census_with(greys, w, h, radius, bits, out)
}

/// [`census_disagreement`] with codes of type `C` (at least `(2r+1)^2 - 1` bits); inlined into the
/// callers of [`census_dispatch`], each compiled for its instruction set.
#[inline(always)]
fn census_with<C: CensusCode>(
    greys: &[&[f32]],
    w: usize,
    h: usize,
    radius: usize,
    bits: &mut Vec<C>,
    out: &mut [f32],
) {
    let n = w * h;
    debug_assert!((2 * radius + 1).pow(2) - 1 <= C::BITS as usize);
    let k = greys.len();
    // Per view: the census codes `[n]`, then the masks of the neighbours it sees `[n]`.
    bits.clear();
    bits.resize(2 * k * n, C::default());
    let r = radius as isize;
    for (g, b) in greys.iter().zip(bits.chunks_exact_mut((2 * n).max(1))) {
        assert_eq!(g.len(), n, "census_disagreement: view size");
        let (codes, masks) = b.split_at_mut(n);
        // One neighbour offset at a time over whole rows (vector loops): bit `bit` is set in the code
        // where the neighbour is darker than the centre, in the mask where the view sees the neighbour
        // (a comparison with NaN is false).
        let mut bit = 0u32;
        for oy in -r..=r {
            for ox in -r..=r {
                if ox == 0 && oy == 0 {
                    continue;
                }
                let xs = (-ox).max(0) as usize..(w as isize - ox.max(0)).max(0) as usize;
                let ys = (-oy).max(0) as usize..(h as isize - oy.max(0)).max(0) as usize;
                if !xs.is_empty() {
                    for y in ys {
                        let row = y * w;
                        // The neighbour of the row's first centre (never negative: `xs` and the rows
                        // keep every neighbour in the image).
                        let q0 = ((y as isize + oy) * w as isize + xs.start as isize + ox) as usize;
                        let centre = &g[row + xs.start..row + xs.end];
                        let neighbour = &g[q0..q0 + xs.len()];
                        let code = &mut codes[row + xs.start..row + xs.end];
                        let mask = &mut masks[row + xs.start..row + xs.end];
                        for (((code, mask), &c), &q) in code
                            .iter_mut()
                            .zip(mask.iter_mut())
                            .zip(centre)
                            .zip(neighbour)
                        {
                            *code = code.or(C::bit(q < c, bit));
                            *mask = mask.or(C::bit(!q.is_nan(), bit));
                        }
                    }
                }
                bit += 1;
            }
        }
        // No bits where the view does not see the centre.
        for ((code, mask), &c) in codes.iter_mut().zip(masks.iter_mut()).zip(g.iter()) {
            if c.is_nan() {
                (*code, *mask) = (C::default(), C::default());
            }
        }
    }
    let zero = C::default();
    for (p, o) in out.iter_mut().enumerate() {
        let (mut total, mut pairs) = (0.0f32, 0u32);
        for i in 0..k {
            let mi = bits[2 * i * n + n + p];
            if mi == zero {
                continue;
            }
            let ci = bits[2 * i * n + p];
            for j in i + 1..k {
                let m = mi.and(bits[2 * j * n + n + p]);
                if m != zero {
                    let differ = ci.xor(bits[2 * j * n + p]).and(m);
                    total += differ.ones() as f32 / m.ones() as f32;
                    pairs += 1;
                }
            }
        }
        *o = if pairs > 0 { total / pairs as f32 } else { 0.0 };
    }
}

/// Semi-global matching's penalties, in logit units (the agreement's `variance / temperature`): `p1` for a
/// change of one plane between neighbouring pixels along a path, `p2` for a larger jump.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Smoothing {
    pub p1: f32,
    pub p2: f32,
}

impl Smoothing {
    /// Whether the penalties are usable: finite, `0 <= p1 <= p2`.
    pub fn is_valid(&self) -> bool {
        self.p1.is_finite() && self.p2.is_finite() && 0.0 <= self.p1 && self.p1 <= self.p2
    }
}

impl std::str::FromStr for Smoothing {
    type Err = String;

    /// `P1,P2` (finite, `0 <= P1 <= P2`), e.g. `2,64`.
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("{s:?} is not two penalties P1,P2 with 0 <= P1 <= P2 (e.g. 2,64)");
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let [a, b] = parts[..] else {
            return Err(bad());
        };
        let smoothing = Smoothing {
            p1: a.parse().map_err(|_| bad())?,
            p2: b.parse().map_err(|_| bad())?,
        };
        if smoothing.is_valid() {
            Ok(smoothing)
        } else {
            Err(bad())
        }
    }
}

/// The 8 path directions `(dx, dy)` of [`smooth_semi_global`].
pub const SGM_DIRECTIONS: [(i64, i64); 8] = [
    (1, 0),
    (-1, 0),
    (0, 1),
    (0, -1),
    (1, 1),
    (-1, -1),
    (1, -1),
    (-1, 1),
];

/// Semi-global matching (Hirschmüller 2008) over the planes of the agreement logits `[D][w*h]` (`planes`
/// of them, plane-major; unseen values at or below [`UNSEEN_BELOW`]). The matching cost of plane `d` at
/// pixel `p` is `C(p, d) = min(-l, cap)` (`cap` where no view sees the plane point; `cap` is the
/// single-view cost, so no plane is worse than one only a single view sees). Along each of the 8
/// directions `r` ([`SGM_DIRECTIONS`]), starting at the image border,
/// `L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d±1) + p1, min_k L_r(p-r, k) + p2) - min_k L_r(p-r, k)`,
/// and every seen logit becomes `-(1/8) sum_r L_r(p, d)` (unseen ones stay). Memory: one more `[D][w*h]`
/// array (the sums) and a row per direction.
pub fn smooth_semi_global(
    logits: &mut [f32],
    w: usize,
    h: usize,
    planes: usize,
    smoothing: Smoothing,
    cap: f32,
) {
    let n = w * h;
    assert_eq!(logits.len(), planes * n, "smooth_semi_global: volume size");
    if n == 0 || planes == 0 {
        return;
    }
    let Smoothing { p1, p2 } = smoothing;
    let cost = |l: f32| if l > UNSEEN_BELOW { (-l).min(cap) } else { cap };
    let mut sum = vec![0f32; planes * n];
    let sum_ptr = SyncPtr(sum.as_mut_ptr());
    let logits_r: &[f32] = logits;
    // Planes per parallel task of a row's update.
    let chunk = 8usize;
    for &(dx, dy) in &SGM_DIRECTIONS {
        if dy == 0 {
            // Along rows: each row its own path, rows in parallel (pixel-major within a row).
            (0..h).into_par_iter().for_each_init(
                || {
                    (
                        vec![0f32; w * planes],
                        vec![0f32; planes],
                        vec![0f32; planes],
                    )
                },
                |(c, prev, cur), y| {
                    for x in 0..w {
                        for d in 0..planes {
                            c[x * planes + d] = cost(logits_r[d * n + y * w + x]);
                        }
                    }
                    let xs: Box<dyn Iterator<Item = usize>> = if dx > 0 {
                        Box::new(0..w)
                    } else {
                        Box::new((0..w).rev())
                    };
                    for (k, x) in xs.enumerate() {
                        let cx = &c[x * planes..(x + 1) * planes];
                        if k == 0 {
                            cur.copy_from_slice(cx);
                        } else {
                            sgm_step(cx, prev, cur, p1, p2);
                        }
                        for (d, &l) in cur.iter().enumerate() {
                            // SAFETY: row y of every plane is this task's only (rows are disjoint).
                            unsafe { *sum_ptr.get().add(d * n + y * w + x) += l };
                        }
                        std::mem::swap(prev, cur);
                    }
                },
            );
        } else {
            // Across rows: a wavefront row by row, every pixel of a row at once (planes in parallel).
            let ys: Vec<usize> = if dy > 0 {
                (0..h).collect()
            } else {
                (0..h).rev().collect()
            };
            let mut prev = vec![0f32; planes * w];
            let mut cur = vec![0f32; planes * w];
            let mut low = vec![0f32; w];
            for (k, &y) in ys.iter().enumerate() {
                if k > 0 {
                    // min over planes of the previous row, per pixel
                    low.fill(f32::INFINITY);
                    for row in prev.chunks_exact(w) {
                        for (m, &v) in low.iter_mut().zip(row) {
                            *m = m.min(v);
                        }
                    }
                }
                let (prev_r, low_r) = (&prev, &low);
                cur.par_chunks_mut(chunk * w)
                    .enumerate()
                    .for_each(|(t, block)| {
                        for (j, row) in block.chunks_exact_mut(w).enumerate() {
                            let d = t * chunk + j;
                            let src = &logits_r[d * n + y * w..d * n + (y + 1) * w];
                            for x in 0..w {
                                let c = cost(src[x]);
                                let px = x as i64 - dx;
                                row[x] = if k == 0 || px < 0 || px >= w as i64 {
                                    c
                                } else {
                                    let px = px as usize;
                                    let m = low_r[px];
                                    let mut best = prev_r[d * w + px];
                                    if d > 0 {
                                        best = best.min(prev_r[(d - 1) * w + px] + p1);
                                    }
                                    if d + 1 < planes {
                                        best = best.min(prev_r[(d + 1) * w + px] + p1);
                                    }
                                    c + best.min(m + p2) - m
                                };
                            }
                            // SAFETY: row y of plane d is this task's only (planes are disjoint).
                            let dst = unsafe {
                                std::slice::from_raw_parts_mut(sum_ptr.get().add(d * n + y * w), w)
                            };
                            for (s, &l) in dst.iter_mut().zip(row.iter()) {
                                *s += l;
                            }
                        }
                    });
                std::mem::swap(&mut prev, &mut cur);
            }
        }
    }
    let inv = 1.0 / SGM_DIRECTIONS.len() as f32;
    logits
        .par_chunks_mut(n)
        .zip(sum.par_chunks(n))
        .for_each(|(l, s)| {
            for (l, &s) in l.iter_mut().zip(s) {
                if *l > UNSEEN_BELOW {
                    *l = -s * inv;
                }
            }
        });
}

/// One step of a path (pixel-major): `cur[d] = c[d] + min(prev[d], prev[d±1] + p1, min prev + p2) - min prev`.
#[inline]
fn sgm_step(c: &[f32], prev: &[f32], cur: &mut [f32], p1: f32, p2: f32) {
    let planes = c.len();
    let m = prev.iter().copied().fold(f32::INFINITY, f32::min);
    for d in 0..planes {
        let mut best = prev[d];
        if d > 0 {
            best = best.min(prev[d - 1] + p1);
        }
        if d + 1 < planes {
            best = best.min(prev[d + 1] + p1);
        }
        cur[d] = c[d] + best.min(m + p2) - m;
    }
}

impl Default for Aggregation {
    fn default() -> Self {
        Self::NONE
    }
}

/// Cost aggregation: every seen value `x` of the `w x h` plane `v` (above [`UNSEEN_BELOW`]) becomes
/// `a * m + (1 - a) * x`, with `m` the mean of the seen values in the `(2r+1) x (2r+1)` window around it
/// (clipped at the border) and `(r, a)` = `aggregation`; unseen values stay. Separable running sums in
/// `f64` (`scratch` is reused), `O(1)` per pixel for any radius.
pub fn aggregate_seen(
    v: &mut [f32],
    w: usize,
    h: usize,
    aggregation: Aggregation,
    scratch: &mut Vec<f64>,
) {
    let Aggregation {
        radius: r, weight, ..
    } = aggregation;
    if !aggregation.is_active() || w == 0 || h == 0 {
        return;
    }
    assert_eq!(v.len(), w * h, "aggregate_seen: plane size");
    // Horizontal window sums of (value, count) per pixel, then vertical sums of those.
    scratch.clear();
    scratch.resize(4 * w * h + 2 * (w.max(h) + 1), 0.0);
    let (hs, rest) = scratch.split_at_mut(2 * w * h);
    let (vs, prefix) = rest.split_at_mut(2 * w * h);
    for y in 0..h {
        let row = &v[y * w..(y + 1) * w];
        // prefix[2i], prefix[2i+1]: sums of values and counts before column i.
        prefix[0] = 0.0;
        prefix[1] = 0.0;
        for (x, &t) in row.iter().enumerate() {
            let seen = t > UNSEEN_BELOW;
            prefix[2 * x + 2] = prefix[2 * x] + if seen { t as f64 } else { 0.0 };
            prefix[2 * x + 3] = prefix[2 * x + 1] + if seen { 1.0 } else { 0.0 };
        }
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r + 1).min(w));
            hs[2 * (y * w + x)] = prefix[2 * b] - prefix[2 * a];
            hs[2 * (y * w + x) + 1] = prefix[2 * b + 1] - prefix[2 * a + 1];
        }
    }
    for x in 0..w {
        prefix[0] = 0.0;
        prefix[1] = 0.0;
        for y in 0..h {
            prefix[2 * y + 2] = prefix[2 * y] + hs[2 * (y * w + x)];
            prefix[2 * y + 3] = prefix[2 * y + 1] + hs[2 * (y * w + x) + 1];
        }
        for y in 0..h {
            let (a, b) = (y.saturating_sub(r), (y + r + 1).min(h));
            vs[2 * (y * w + x)] = prefix[2 * b] - prefix[2 * a];
            vs[2 * (y * w + x) + 1] = prefix[2 * b + 1] - prefix[2 * a + 1];
        }
    }
    for (i, t) in v.iter_mut().enumerate() {
        if *t > UNSEEN_BELOW {
            let mean = vs[2 * i] / vs[2 * i + 1];
            *t = (weight * mean + (1.0 - weight) * *t as f64) as f32;
        }
    }
}

/// Softmax over planes of `logits` (`[D][n]`) and conversion to alphas (`[n][D]`, pixel-major) such that plane
/// `d`'s visible contribution in the reference view is its weight: `a_d = w_d / sum_{i<=d} w_i`.
pub fn depth_distribution_to_alpha(logits: &[f32], planes: usize, n: usize) -> Vec<f32> {
    let mut alphas = vec![0.0f32; planes * n];
    alphas
        .par_chunks_mut(planes)
        .enumerate()
        .for_each(|(p, out)| {
            let max = (0..planes)
                .map(|d| logits[d * n + p])
                .fold(f32::NEG_INFINITY, f32::max);
            if max == f32::NEG_INFINITY {
                return; // no view sees this ray: transparent
            }
            let w: Vec<f64> = (0..planes)
                .map(|d| ((logits[d * n + p] - max) as f64).exp())
                .collect();
            let total: f64 = w.iter().sum();
            let mut cum = 0.0f64;
            for d in 0..planes {
                cum += w[d] / total;
                out[d] = if cum > 0.0 {
                    ((w[d] / total) / cum).min(1.0) as f32
                } else {
                    0.0
                };
            }
        });
    alphas
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aggregation_is_the_weighted_windowed_mean_of_seen_values() {
        // Against the definition, pixel by pixel, on a plane with unseen holes and ragged borders.
        let (w, h) = (13usize, 7usize);
        let v: Vec<f32> = (0..w * h)
            .map(|i| {
                if i % 5 == 3 {
                    f32::NEG_INFINITY
                } else if i % 11 == 4 {
                    -1e30
                } else {
                    ((i * 37 % 17) as f32 - 8.0) * 0.25
                }
            })
            .collect();
        for (r, weight) in [
            (0usize, 1.0),
            (1, 1.0),
            (2, 0.5),
            (6, 1.0),
            (20, 0.3),
            (3, 0.0),
        ] {
            let mut got = v.clone();
            aggregate_seen(
                &mut got,
                w,
                h,
                Aggregation::window(r, weight),
                &mut Vec::new(),
            );
            for y in 0..h {
                for x in 0..w {
                    let t = v[y * w + x];
                    if t <= UNSEEN_BELOW {
                        assert_eq!(got[y * w + x], t, "unseen ({x}, {y}) kept");
                        continue;
                    }
                    let (mut s, mut c) = (0.0f64, 0.0f64);
                    for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                        for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                            let u = v[yy * w + xx];
                            if u > UNSEEN_BELOW {
                                s += u as f64;
                                c += 1.0;
                            }
                        }
                    }
                    let want = (weight * s / c + (1.0 - weight) * t as f64) as f32;
                    assert!((got[y * w + x] - want).abs() < 1e-5, "r {r} ({x}, {y})");
                }
            }
        }
    }

    /// Semi-global matching by its definition: every path walked pixel by pixel from the border, in f64.
    fn sgm_reference(
        l: &[f32],
        w: usize,
        h: usize,
        d: usize,
        p1: f64,
        p2: f64,
        cap: f64,
    ) -> Vec<f32> {
        let n = w * h;
        let cost = |p: usize, k: usize| {
            let v = l[k * n + p];
            if v > UNSEEN_BELOW {
                (-(v as f64)).min(cap)
            } else {
                cap
            }
        };
        let mut sum = vec![0f64; d * n];
        for &(dx, dy) in &SGM_DIRECTIONS {
            for y in 0..h as i64 {
                for x in 0..w as i64 {
                    let (px, py) = (x - dx, y - dy);
                    if px >= 0 && py >= 0 && px < w as i64 && py < h as i64 {
                        continue; // not a path start
                    }
                    let (mut x, mut y) = (x, y);
                    let mut prev: Option<Vec<f64>> = None;
                    while x >= 0 && y >= 0 && x < w as i64 && y < h as i64 {
                        let p = y as usize * w + x as usize;
                        let cur: Vec<f64> = (0..d)
                            .map(|k| match &prev {
                                None => cost(p, k),
                                Some(q) => {
                                    let m = q.iter().cloned().fold(f64::INFINITY, f64::min);
                                    let mut best = q[k].min(m + p2);
                                    if k > 0 {
                                        best = best.min(q[k - 1] + p1);
                                    }
                                    if k + 1 < d {
                                        best = best.min(q[k + 1] + p1);
                                    }
                                    cost(p, k) + best - m
                                }
                            })
                            .collect();
                        for k in 0..d {
                            sum[k * n + p] += cur[k];
                        }
                        prev = Some(cur);
                        x += dx;
                        y += dy;
                    }
                }
            }
        }
        (0..d * n)
            .map(|i| {
                if l[i] > UNSEEN_BELOW {
                    (-sum[i] / 8.0) as f32
                } else {
                    l[i]
                }
            })
            .collect()
    }

    #[test]
    fn semi_global_matching_follows_its_definition() {
        // Ragged sizes (more planes than a task's 8, rows of 1), unseen points, costs above the cap.
        for (w, h, d) in [(7usize, 5usize, 11usize), (1, 6, 3), (9, 1, 9), (4, 4, 1)] {
            let n = w * h;
            let l: Vec<f32> = (0..d * n)
                .map(|i| {
                    if i % 13 == 5 {
                        -1e30
                    } else {
                        -(((i * 7919) % 97) as f32) * 0.5
                    }
                })
                .collect();
            for (p1, p2) in [(2.0f32, 64.0f32), (0.5, 3.0), (1.0, 1.0)] {
                let mut got = l.clone();
                smooth_semi_global(&mut got, w, h, d, Smoothing { p1, p2 }, 40.0);
                let want = sgm_reference(&l, w, h, d, p1 as f64, p2 as f64, 40.0);
                for i in 0..d * n {
                    let tol = 1e-4 * want[i].abs().max(1.0);
                    assert!(
                        (got[i] - want[i]).abs() <= tol,
                        "{w}x{h}x{d} ({p1}, {p2}) [{i}]: {} vs {}",
                        got[i],
                        want[i]
                    );
                }
            }
            // No penalties: every path adds exactly its own cost, so the logits are the (capped) costs.
            let mut got = l.clone();
            smooth_semi_global(&mut got, w, h, d, Smoothing { p1: 0.0, p2: 0.0 }, 40.0);
            for i in 0..d * n {
                let want = if l[i] > UNSEEN_BELOW {
                    l[i].max(-40.0)
                } else {
                    l[i]
                };
                assert!((got[i] - want).abs() < 1e-4, "no penalties [{i}]");
            }
        }
    }

    #[test]
    fn semi_global_matching_fills_a_textureless_pixel_from_its_neighbours() {
        // A 9x9 image, 6 planes: every pixel agrees best on plane 2, except the centre, whose costs are
        // flat (no texture) but for a slight, wrong minimum at plane 5. Smoothed, the centre's best plane
        // is its neighbours'; without penalties it keeps its own.
        let (w, h, d) = (9usize, 9usize, 6usize);
        let n = w * h;
        let centre = 4 * w + 4;
        let mut l = vec![0f32; d * n];
        for p in 0..n {
            for k in 0..d {
                l[k * n + p] = if p == centre {
                    if k == 5 { -1.0 } else { -1.5 }
                } else if k == 2 {
                    -0.5
                } else {
                    -8.0
                };
            }
        }
        let best = |v: &[f32]| {
            (0..d)
                .max_by(|&a, &b| v[a * n + centre].total_cmp(&v[b * n + centre]))
                .unwrap()
        };
        assert_eq!(best(&l), 5);
        let mut s = l.clone();
        smooth_semi_global(&mut s, w, h, d, Smoothing { p1: 2.0, p2: 64.0 }, 40.0);
        assert_eq!(best(&s), 2);
    }

    #[test]
    fn alphas_reproduce_the_depth_distribution() {
        // Visible contribution a_d prod_{i>d} (1 - a_i) equals the softmax weight.
        let logits = [0.3f32, -1.0, 2.0, f32::NEG_INFINITY, 0.0];
        let alphas = depth_distribution_to_alpha(&logits, 5, 1);
        let z: f64 = logits.iter().map(|&l| (l as f64).exp()).sum();
        for d in 0..5 {
            let front: f64 = (d + 1..5).map(|i| 1.0 - alphas[i] as f64).product();
            let expect = (logits[d] as f64).exp() / z;
            assert!(
                (alphas[d] as f64 * front - expect).abs() < 1e-6,
                "plane {d}"
            );
        }
        assert_eq!(alphas[0], 1.0);
        assert!(
            depth_distribution_to_alpha(&[f32::NEG_INFINITY; 3], 3, 1)
                .iter()
                .all(|&a| a == 0.0)
        );
    }

    #[test]
    fn census_cost_follows_its_definition() {
        // 3 x 1 pixels, radius 1 (the in-image neighbours: left and right), worked by hand. Pixel 1 of A
        // (0.5): left darker (bit 1), right not (0); of B: both darker (1, 1): 1 of 2 bits differ. Pixel
        // 2: the left neighbour is darker in A (0.5 < 0.9), not in B (0.5 > 0.2).
        let (a, b) = ([0.1f32, 0.5, 0.9], [0.1f32, 0.5, 0.2]);
        let mut out = vec![-1f32; 3];
        census_disagreement(&[&a, &b], 3, 1, 1, &mut CensusScratch::default(), &mut out);
        assert_eq!(out, [0.0, 0.5, 1.0]);
        // C does not see pixel 0: pixel 1's pairs with C compare the right neighbour only (A-C: 0 of 1
        // bits differ, B-C: 1 of 1), pixel 0 is A-B's alone, and pixel 2's C-pairs compare the left one.
        let c = [f32::NAN, 0.5, 0.9];
        census_disagreement(
            &[&a, &b, &c],
            3,
            1,
            1,
            &mut CensusScratch::default(),
            &mut out,
        );
        let expected = [0.0, (0.5 + 0.0 + 1.0) / 3.0, (1.0 + 0.0 + 1.0) / 3.0];
        for (o, e) in out.iter().zip(expected) {
            assert!((o - e).abs() < 1e-6, "{out:?} against {expected:?}");
        }
        // A pixel one view sees, or none: no pair, cost 0.
        let d = [f32::NAN, f32::NAN, 0.3];
        census_disagreement(&[&d, &c], 3, 1, 1, &mut CensusScratch::default(), &mut out);
        assert_eq!(out, [0.0, 0.0, 0.0]);
    }

    #[test]
    fn census_cost_ignores_exposure_and_sees_structure() {
        let (w, h) = (23usize, 17usize);
        let base: Vec<f32> = (0..w * h)
            .map(|p| {
                let (x, y) = ((p % w) as f32, (p / w) as f32);
                0.5 + 0.2 * (0.9 * x + 0.3 * y).sin() + 0.1 * (0.37 * x - 1.3 * y).cos()
            })
            .collect();
        // Another exposure (gain and offset): every comparison, so every bit, is the same.
        let exposed: Vec<f32> = base.iter().map(|v| 0.6 * v + 0.25).collect();
        // The negative: every comparison reverses (the texture has no ties).
        let negative: Vec<f32> = base.iter().map(|v| 1.0 - v).collect();
        let mut bits = CensusScratch::default();
        for radius in 1..=Census::MAX_RADIUS {
            let mut out = vec![-1f32; w * h];
            census_disagreement(&[&base, &exposed], w, h, radius, &mut bits, &mut out);
            assert!(out.iter().all(|&c| c == 0.0), "radius {radius}: exposure");
            census_disagreement(&[&base, &negative], w, h, radius, &mut bits, &mut out);
            assert!(out.iter().all(|&c| c == 1.0), "radius {radius}: negative");
            // Three views: the two pairs with the negative differ entirely, the exposed pair not at all.
            census_disagreement(
                &[&base, &exposed, &negative],
                w,
                h,
                radius,
                &mut bits,
                &mut out,
            );
            assert!(
                out.iter().all(|&c| (c - 2.0 / 3.0).abs() < 1e-6),
                "radius {radius}"
            );
        }
    }

    /// The 32-bit codes (radius 1 and 2) give the 64-bit codes' costs exactly: random grey levels with
    /// ties and unseen pixels, two to five views. (On a machine with AVX2 this also compares that build,
    /// which `census_disagreement` dispatches to, with the baseline one of `census_with`.)
    #[test]
    fn narrow_census_codes_equal_wide_ones() {
        let (w, h) = (31usize, 19usize);
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut scratch = CensusScratch::default();
        for views in 2..=5 {
            let greys: Vec<Vec<f32>> = (0..views)
                .map(|_| {
                    (0..w * h)
                        .map(|_| match next() % 16 {
                            0 => f32::NAN,
                            // Ties: a few levels only.
                            v => (v % 6) as f32 / 5.0,
                        })
                        .collect()
                })
                .collect();
            let refs: Vec<&[f32]> = greys.iter().map(Vec::as_slice).collect();
            for radius in 1..=2 {
                let mut narrow = vec![-1f32; w * h];
                census_disagreement(&refs, w, h, radius, &mut scratch, &mut narrow);
                assert!(!scratch.narrow.is_empty() && scratch.wide.is_empty());
                let mut wide = vec![-1f32; w * h];
                census_with::<u64>(&refs, w, h, radius, &mut Vec::new(), &mut wide);
                assert_eq!(narrow, wide, "{views} views, radius {radius}");
                assert!(wide.iter().any(|&c| c > 0.0) && wide.iter().any(|&c| c < 1.0));
            }
        }
    }

    /// A `w x h` camera of focal length `f` at `(x, 0, 0)`, looking down +z.
    fn camera_at(w: u32, h: u32, f: f64, x: f64) -> Camera {
        use deepview_geometry::{DMat3, DVec3, Intrinsics, Pose};
        Camera::new(
            w,
            h,
            Intrinsics::new(f, f, w as f64 / 2.0, h as f64 / 2.0),
            Pose::from_center(DMat3::IDENTITY, DVec3::new(x, 0.0, 0.0)),
        )
    }

    /// The fraction of the reference pixels in `columns` whose best plane (the largest logit of
    /// [`sweep_statistics`] with `aggregation`) is at depth `truth`.
    fn right_depth_fraction(
        inputs: &[(ImageF32, Camera)],
        reference: &Camera,
        depths: &[f64],
        truth: f64,
        aggregation: Aggregation,
        columns: std::ops::Range<usize>,
    ) -> f64 {
        let (mpi, logits) = sweep_statistics(
            inputs,
            reference,
            depths.to_vec(),
            0.0005,
            0.02,
            aggregation,
        );
        let (w, n) = (
            reference.width as usize,
            reference.width as usize * reference.height as usize,
        );
        let pixels: Vec<usize> = (0..n).filter(|p| columns.contains(&(p % w))).collect();
        let right = pixels
            .iter()
            .filter(|&&p| {
                let best = (0..mpi.planes())
                    .max_by(|&a, &b| logits[a * n + p].total_cmp(&logits[b * n + p]))
                    .unwrap();
                mpi.depths[best] == truth
            })
            .count();
        right as f64 / pixels.len() as f64
    }

    /// Three views of a textured fronto-parallel plane, each with its own exposure: the colour variance
    /// alone mistakes the depth, the census term finds it.
    #[test]
    fn census_term_finds_the_depth_across_exposures() {
        let (w, h, f) = (48u32, 32u32, 20.0);
        // Cameras at x = -0.4, 0, 0.4; the plane at depth 4: 2 px of disparity per view step.
        // Per-pixel noise (the views' shifts are whole pixels, so every view samples it exactly).
        let texture = |u: f64, v: f64| {
            let r = ((u * 12.9898 + v * 78.233).sin() * 43758.5453).rem_euclid(1.0);
            (0.45 + 0.2 * r) as f32
        };
        let inputs: Vec<(ImageF32, Camera)> = [(-0.4, 0.8f32), (0.0, 1.0), (0.4, 1.25)]
            .iter()
            .map(|&(x, gain)| {
                let cam = camera_at(w, h, f, x);
                let mut img = ImageF32::new(w, h, 3);
                for (p, px) in img.data.chunks_exact_mut(3).enumerate() {
                    let (u, v) = ((p % w as usize) as f64, (p / w as usize) as f64);
                    let t = gain * texture(u + f * x / 4.0, v);
                    px.copy_from_slice(&[t, t * 0.9, t * 0.8]);
                }
                (img, cam)
            })
            .collect();
        let reference = inputs[1].1;
        // Planes 1 px of disparity apart (for the outer views), the plane's depth among them.
        let depths: Vec<f64> = (1..=8).map(|k| 16.0 / k as f64).collect();
        let truth = depths.iter().position(|&d| d == 4.0).unwrap();
        // The interior, where every view sees every plane.
        let found = |census| {
            let aggregation = Aggregation {
                census,
                ..Aggregation::NONE
            };
            right_depth_fraction(
                &inputs,
                &reference,
                &depths,
                depths[truth],
                aggregation,
                10..w as usize - 10,
            )
        };
        let (plain, census) = (
            found(None),
            found(Some(Census {
                weight: 0.03,
                radius: 2,
            })),
        );
        assert!(
            census > 0.95,
            "census: the right depth at {census} of the pixels"
        );
        assert!(
            plain < 0.5,
            "variance alone: the right depth at {plain} of the pixels"
        );
    }

    #[test]
    fn leave_one_out_variance_is_the_least_variance_of_the_others() {
        // Brute force: every view left out in turn, the variance (mean over RGB) of the rest.
        let mut seed = 7u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as f64 / (1u64 << 31) as f64
        };
        for n in 3..=6 {
            let x: Vec<[f64; 3]> = (0..n).map(|_| [rnd(), rnd(), rnd()]).collect();
            let mean =
                |s: &[&[f64; 3]], c: usize| s.iter().map(|v| v[c]).sum::<f64>() / s.len() as f64;
            let var = |s: &[&[f64; 3]]| {
                (0..3)
                    .map(|c| {
                        let m = mean(s, c);
                        s.iter().map(|v| (v[c] - m).powi(2)).sum::<f64>() / s.len() as f64
                    })
                    .sum::<f64>()
                    / 3.0
            };
            let all: Vec<&[f64; 3]> = x.iter().collect();
            let least = (0..n)
                .map(|i| {
                    let rest: Vec<&[f64; 3]> = x
                        .iter()
                        .enumerate()
                        .filter(|&(j, _)| j != i)
                        .map(|(_, v)| v)
                        .collect();
                    var(&rest)
                })
                .fold(f64::INFINITY, f64::min);
            let ss = var(&all) * 3.0 * n as f64;
            let max_dev = x
                .iter()
                .map(|v| (0..3).map(|c| (v[c] - mean(&all, c)).powi(2)).sum::<f64>())
                .fold(0.0, f64::max);
            let got = leave_one_out_variance(ss, max_dev, n as f64);
            assert!((got - least).abs() < 1e-12, "{n} views: {got} vs {least}");
        }
        // Grey samples 0, 0, 0 and 1 (mean 0.25): the sum of squares over RGB 3 * 0.75, the outlier's
        // deviation 3 * 0.5625; the other three agree exactly. Samples 0, 0, 0.3, 1: leaving out 1,
        // the variance of 0, 0, 0.3 is 0.02.
        assert!(leave_one_out_variance(2.25, 1.6875, 4.0).abs() < 1e-12);
        let ss = 3.0
            * [0.0f64, 0.0, 0.3, 1.0]
                .iter()
                .map(|x| (x - 0.325).powi(2))
                .sum::<f64>();
        let got = leave_one_out_variance(ss, 3.0 * 0.675f64.powi(2), 4.0);
        assert!((got - 0.02).abs() < 1e-12, "{got}");
    }

    /// Four views of a textured fronto-parallel plane; an object right in front of one camera covers
    /// part of its image. Where it does, that view's sample disagrees at the plane's depth: the
    /// variance of all four mistakes the depth at some pixels, the leave-one-out term finds it.
    #[test]
    fn leave_one_out_term_finds_the_depth_behind_one_views_occluder() {
        let (w, h, f) = (64u32, 32u32, 20.0);
        let noise = |u: f64, v: f64, s: f64| {
            let r = ((u * 12.9898 + v * 78.233 + s).sin() * 43758.5453).rem_euclid(1.0);
            (0.4 + 0.3 * r) as f32
        };
        // Cameras at x = -1.6, -0.8, 0.8, 1.6; the plane at depth 4: 4 px of disparity per 0.8.
        let inputs: Vec<(ImageF32, Camera)> = [-1.6, -0.8, 0.8, 1.6]
            .iter()
            .map(|&x| {
                let cam = camera_at(w, h, f, x);
                let mut img = ImageF32::new(w, h, 3);
                for (p, px) in img.data.chunks_exact_mut(3).enumerate() {
                    let (u, v) = ((p % w as usize) as f64, (p / w as usize) as f64);
                    let occluded = x > 1.0 && (24.0..44.0).contains(&u);
                    let t = if occluded {
                        [noise(u, v, 1.0), noise(u, v, 2.0), noise(u, v, 3.0)]
                    } else {
                        let t = noise(u + f * x / 4.0, v, 0.0);
                        [t, t * 0.9, t * 0.8]
                    };
                    px.copy_from_slice(&t);
                }
                (img, cam)
            })
            .collect();
        let reference = camera_at(w, h, f, 0.0);
        // Planes 1 px of disparity apart for the inner views, the plane's depth among them.
        let depths: Vec<f64> = (1..=8).map(|k| 16.0 / k as f64).collect();
        let truth = depths.iter().position(|&d| d == 4.0).unwrap();
        // The reference pixels the occluded part of the last view covers at the plane's depth (its
        // columns 24..44 are reference columns 32..52), where every view sees every plane.
        let found = |leave_one_out| {
            let aggregation = Aggregation {
                leave_one_out,
                ..Aggregation::NONE
            };
            right_depth_fraction(
                &inputs,
                &reference,
                &depths,
                depths[truth],
                aggregation,
                33..51,
            )
        };
        // The sample variance: where all four views see (columns 17..47 at every plane), every logit is
        // 4/3 of the population variance's.
        let logits = |sample_variance| {
            let aggregation = Aggregation {
                sample_variance,
                ..Aggregation::NONE
            };
            sweep_statistics(
                &inputs,
                &reference,
                depths.clone(),
                0.0005,
                0.02,
                aggregation,
            )
            .1
        };
        let (population, sample) = (logits(false), logits(true));
        for (i, (&p, &s)) in population.iter().zip(&sample).enumerate() {
            if (17..47).contains(&(i % w as usize)) {
                assert!(
                    (s - p * 4.0 / 3.0).abs() <= 1e-4 * p.abs() + 1e-3,
                    "{i}: {s} vs {p}"
                );
            }
        }
        let (plain, half, full) = (found(None), found(Some(0.5)), found(Some(1.0)));
        assert!(
            full > 0.99,
            "leave-one-out: the right depth at {full} of the pixels"
        );
        assert!(
            half > plain + 0.05,
            "weight 0.5 ({half}) against none ({plain})"
        );
        assert!(
            plain < 0.8,
            "variance alone: the right depth at {plain} of the pixels"
        );
    }
}
