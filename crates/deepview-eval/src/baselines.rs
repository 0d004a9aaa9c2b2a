//! Two baselines without learning: the nearest input view reprojected through one plane, and an MPI built
//! from the plane sweep volume's mean colour with alpha from cross-view colour agreement.

use crate::check::check_inputs;
use crate::error::EvalError;
use crate::method::Method;
use crate::planes::mpi_reference;
use deepview_geometry::{Camera, PlaneSpacing, plane_depths};
use deepview_image::ImageF32;
use deepview_mpi::{Mpi, plane_sweep, render};
use rayon::prelude::*;

/// `nearest`: the input view whose camera centre is nearest the target's, reprojected into the target through a
/// single fronto-parallel plane (in that input's camera) at the inverse-depth midpoint of `near_far`.
/// Target pixels that see beyond the input image are black.
#[derive(Clone, Copy, Debug, Default)]
pub struct NearestView;

impl Method for NearestView {
    fn name(&self) -> &str {
        "nearest"
    }

    fn predict(
        &mut self,
        inputs: &[(ImageF32, Camera)],
        target: &Camera,
        near_far: (f64, f64),
    ) -> Result<ImageF32, EvalError> {
        check_inputs(self.name(), inputs, near_far)?;
        let ct = target.center();
        let nearest = inputs
            .iter()
            .min_by(|a, b| {
                a.1.center()
                    .distance(ct)
                    .total_cmp(&b.1.center().distance(ct))
            })
            .expect("checked non-empty");
        let mpi = nearest_view_mpi(nearest, near_far)?;
        Ok(render(&mpi, target).to_rgb())
    }
}

/// The MPI that [`NearestView`] reprojects: one opaque plane in `input`'s own camera holding its image, at the
/// inverse-depth midpoint of `near_far` (rendered into that camera, it is the image itself).
pub fn nearest_view_mpi(
    input: &(ImageF32, Camera),
    near_far: (f64, f64),
) -> Result<Mpi, EvalError> {
    check_inputs("nearest", std::slice::from_ref(input), near_far)?;
    let (img, cam) = input;
    let depths = plane_depths(near_far.0, near_far.1, 1, PlaneSpacing::InverseDepth)?;
    let layers = img
        .data
        .chunks_exact(img.channels)
        .flat_map(|p| [p[0], p[1], p[2], 1.0])
        .collect();
    Ok(Mpi {
        camera: *cam,
        depths,
        layers,
    })
}

/// Settings of the `psv-mean` baseline.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PsvMeanOptions {
    /// MPI planes, equally spaced in inverse depth between near and far.
    pub planes: usize,
    /// `s` in `exp(-variance / s)`: the colour variance (mean over RGB, values in 0..1) that counts as disagreement
    /// (0.0005, i.e. a colour standard deviation of about 0.02, worked best of 0.002 / 0.0005 / 0.0002 / 0.00005 on
    /// LLFF fern at 1/8 resolution).
    pub temperature: f64,
    /// The variance assumed where only one view sees a plane point (no agreement can be measured).
    pub single_view_variance: f64,
}

impl Default for PsvMeanOptions {
    fn default() -> Self {
        Self {
            planes: 32,
            temperature: 0.0005,
            single_view_variance: 0.02,
        }
    }
}

/// `psv-mean`: [`agreement_mpi`] rendered into the target.
#[derive(Clone, Copy, Debug, Default)]
pub struct PsvMean {
    pub options: PsvMeanOptions,
}

impl Method for PsvMean {
    fn name(&self) -> &str {
        "psv-mean"
    }

    fn predict(
        &mut self,
        inputs: &[(ImageF32, Camera)],
        target: &Camera,
        near_far: (f64, f64),
    ) -> Result<ImageF32, EvalError> {
        let mpi = agreement_mpi(inputs, near_far, &self.options)?;
        Ok(render(&mpi, target).to_rgb())
    }
}

/// The reference camera of a baseline MPI: centroid and average orientation of the inputs, field of view
/// enlarged to cover them between near and far.
pub(crate) fn baseline_reference(
    inputs: &[(ImageF32, Camera)],
    near_far: (f64, f64),
) -> Result<Camera, EvalError> {
    let cams: Vec<Camera> = inputs.iter().map(|(_, c)| *c).collect();
    mpi_reference(&cams, near_far)
}

/// An MPI from the plane sweep volume by cross-view colour agreement.
///
/// For every plane `d` and reference pixel: colour = mean of the views' valid samples; agreement logit
/// `l_d = -v_d / s` with `v_d` the variance of the valid samples (mean over RGB; `single_view_variance` where one
/// view sees the point, no weight where none does). A softmax over planes turns the logits into a depth
/// distribution `w_d` (sum 1), which becomes alpha front to back so that each plane's visible contribution in the
/// reference view is exactly `w_d`: `a_d = w_d / sum_{i<=d} w_i` (planes back to front, so the farthest plane
/// with weight is opaque). The reference view then renders `sum_d w_d colour_d`; other views see the same soft
/// layering with occlusion.
pub fn agreement_mpi(
    inputs: &[(ImageF32, Camera)],
    near_far: (f64, f64),
    options: &PsvMeanOptions,
) -> Result<Mpi, EvalError> {
    check_inputs("psv-mean", inputs, near_far)?;
    if !(options.temperature.is_finite() && options.temperature > 0.0) {
        return Err(EvalError::Method {
            method: "psv-mean".into(),
            msg: format!("temperature {} must be positive", options.temperature),
        });
    }
    let reference = baseline_reference(inputs, near_far)?;
    let depths = plane_depths(
        near_far.0,
        near_far.1,
        options.planes,
        PlaneSpacing::InverseDepth,
    )?;
    let rgb: Vec<(ImageF32, Camera)> = inputs.iter().map(|(i, c)| (i.to_rgb(), *c)).collect();
    let (mut mpi, logits) = sweep_statistics(&rgb, &reference, depths, options);
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
    Ok(mpi)
}

/// Per plane: the mean colour of the valid samples in the MPI texels (alpha still 0), and the agreement logits
/// `[D][n]`, computed one plane at a time so memory stays at one MPI.
pub(crate) fn sweep_statistics(
    inputs: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: Vec<f64>,
    options: &PsvMeanOptions,
) -> (Mpi, Vec<f32>) {
    let n = reference.width as usize * reference.height as usize;
    let mut mpi = Mpi::transparent(*reference, depths);
    let mut logits = vec![f32::NEG_INFINITY; mpi.planes() * n];
    let depths = mpi.depths.clone();
    let s = options.temperature;
    let single = -(options.single_view_variance / s) as f32;
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
        });
    (mpi, logits)
}

/// Softmax over planes of `logits` (`[D][n]`) and conversion to alphas (`[n][D]`, pixel-major) such that plane
/// `d`'s visible contribution in the reference view is its weight: `a_d = w_d / sum_{i<=d} w_i`.
pub(crate) fn depth_distribution_to_alpha(logits: &[f32], planes: usize, n: usize) -> Vec<f32> {
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
