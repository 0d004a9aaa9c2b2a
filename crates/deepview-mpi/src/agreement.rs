//! The cross-view agreement MPI: the one definition of `psv-mean`'s MPI and of the learned model's
//! agreement prior (`deepview_net`'s burn graph and its CPU engine compute the same arithmetic in their own
//! layouts and are tested against [`agreement_mpi`]).
//!
//! For every plane `d` and reference pixel: colour = mean of the views' valid plane-sweep samples;
//! agreement logit `l_d = -v_d / s` with `v_d` the variance of the valid samples (mean over RGB;
//! [`SINGLE_VIEW_VARIANCE`] where one view sees the point, no weight where none does) and `s` the
//! temperature ([`TEMPERATURE`] by default). With an [`Aggregation`] of radius `r > 0` and weight `a`
//! each plane's variance is first replaced by `a` times its mean over the seen pixels of the
//! `(2r+1) x (2r+1)` window around each pixel plus `1 - a` times its own value ([`aggregate_seen`]:
//! classic stereo cost aggregation, the window clipped at the image border, with extra weight on the
//! centre). A softmax over planes turns the logits into a depth
//! distribution `w_d` (sum 1), which becomes alpha so that each plane's visible contribution in the
//! reference view is exactly `w_d`: `a_d = w_d / sum_{i<=d} w_i` (planes back to front, so the farthest
//! plane with weight is opaque).

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
            for (img, cam) in inputs {
                let psv = plane_sweep(img, cam, reference, &[depth]);
                for (a, s) in acc.iter_mut().zip(psv.data.chunks_exact(4)) {
                    if s[3] > 0.0 {
                        for c in 0..3 {
                            a[c] += s[c] as f64;
                            a[3 + c] += (s[c] as f64) * (s[c] as f64);
                        }
                        a[6] += 1.0;
                    }
                }
            }
            for ((t, l), a) in texels.chunks_exact_mut(4).zip(logit.iter_mut()).zip(&acc) {
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
                *l = if k >= 2.0 {
                    -(var / 3.0 / s) as f32
                } else {
                    single
                };
            }
            let (w, h) = (reference.width as usize, reference.height as usize);
            aggregate_seen(logit, w, h, aggregation, &mut Vec::new());
        });
    (mpi, logits)
}

/// Values at or below this are "unseen" in [`aggregate_seen`] (the engines mark unseen plane points with
/// `-1e30` or `-inf`).
pub const UNSEEN_BELOW: f32 = -1e29;

/// Cost aggregation of the agreement: the radius `r` of the window and the weight `a` of its mean (the
/// rest is the pixel's own cost). `r = 0` or `a = 0`: per pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aggregation {
    pub radius: usize,
    pub weight: f64,
}

impl Aggregation {
    /// Per pixel (`psv-mean`'s default).
    pub const NONE: Aggregation = Aggregation {
        radius: 0,
        weight: 1.0,
    };

    /// Whether it changes anything.
    pub fn is_active(&self) -> bool {
        self.radius > 0 && self.weight > 0.0
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
    let Aggregation { radius: r, weight } = aggregation;
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
                Aggregation { radius: r, weight },
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
}
