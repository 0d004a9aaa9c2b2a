//! `optimize`: classical gradient descent on the MPI to reproduce the input views (the paper's strawman).
//!
//! Parameters are per-texel RGBA logits; the MPI is `alpha = sigmoid(z_a)`, premultiplied colour
//! `c = alpha * sigmoid(z_rgb)`. The loss is the mean squared error between every input view and the MPI
//! rendered into it. Its gradient uses the paper's identities in each view's pixels, `d render / d c_d = T_d`
//! and `d render / d a_d = -A_d T_d` (per-plane net transmittance and accumulated over, from
//! `deepview_mpi::render_components`), then the exact adjoint of the bilinear warp (the same taps scattered
//! back onto the plane texels), then the sigmoid chain rule. Adam updates the logits. The optimisation runs at a
//! low resolution (inputs box-downscaled by an integer factor so they are at most `max_width` wide); the MPI is
//! then rendered into targets at any resolution.

use crate::baselines::baseline_reference;
use crate::check::check_inputs;
use crate::error::MethodError;
use deepview_geometry::{Camera, PlaneSpacing, plane_depths};
use deepview_image::ImageF32;
use deepview_mpi::agreement::{SINGLE_VIEW_VARIANCE, TEMPERATURE, sweep_statistics};
use deepview_mpi::warp::{Sampler, target_to_plane_homographies};
use deepview_mpi::{Mpi, render_components};
use rayon::prelude::*;

/// Settings of [`optimize_mpi`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OptimizeOptions {
    pub planes: usize,
    /// Adam steps.
    pub steps: usize,
    /// Adam learning rate on the logits.
    pub learning_rate: f64,
    /// Inputs are box-downscaled by the smallest integer factor that makes them at most this wide.
    pub max_width: u32,
}

impl Default for OptimizeOptions {
    fn default() -> Self {
        Self {
            planes: 32,
            steps: 300,
            learning_rate: 0.1,
            max_width: 160,
        }
    }
}

/// Optimise an MPI to reproduce `inputs` (see the module docs). The MPI's reference camera is the inputs'
/// centroid camera at the working resolution, enlarged to cover them between near and far.
pub fn optimize_mpi(
    inputs: &[(ImageF32, Camera)],
    near_far: (f64, f64),
    options: &OptimizeOptions,
) -> Result<Mpi, MethodError> {
    optimize_mpi_with_history(inputs, near_far, options).map(|(m, _)| m)
}

/// [`optimize_mpi`], also returning the loss before every step and after the last (`steps + 1` values).
pub fn optimize_mpi_with_history(
    inputs: &[(ImageF32, Camera)],
    near_far: (f64, f64),
    options: &OptimizeOptions,
) -> Result<(Mpi, Vec<f64>), MethodError> {
    optimize_mpi_reporting(inputs, near_far, options, &mut |_, _, _| {})
}

/// [`optimize_mpi_with_history`], calling `progress(reference, done, total)` with the MPI's reference
/// camera before the first step (`done` 0) and after every step (`total`: the steps).
pub fn optimize_mpi_reporting(
    inputs: &[(ImageF32, Camera)],
    near_far: (f64, f64),
    options: &OptimizeOptions,
    progress: &mut dyn FnMut(&Camera, usize, usize),
) -> Result<(Mpi, Vec<f64>), MethodError> {
    check_inputs("optimize", inputs, near_far)?;
    if options.max_width == 0 || !(options.learning_rate.is_finite() && options.learning_rate > 0.0)
    {
        return Err(MethodError::Method {
            method: "optimize".into(),
            msg: format!(
                "max width {} and learning rate {} must be positive",
                options.max_width, options.learning_rate
            ),
        });
    }
    let views: Vec<(ImageF32, Camera)> = inputs
        .iter()
        .map(|(img, cam)| working_view(img, cam, options.max_width))
        .collect();
    let reference = baseline_reference(&views, near_far, 1.0)?;
    let depths = plane_depths(
        near_far.0,
        near_far.1,
        options.planes,
        PlaneSpacing::InverseDepth,
    )?;
    let mut logits = initial_logits(&views, &reference, depths.clone());
    let mut adam = Adam::new(logits.len(), options.learning_rate as f32);
    let mut history = Vec::with_capacity(options.steps + 1);
    let total = options.steps;
    progress(&reference, 0, total);
    for step in 0..options.steps {
        let mpi = logits_to_mpi(&logits, reference, &depths);
        let (loss, grad_mpi) = loss_and_mpi_gradient(&mpi, &views);
        history.push(loss);
        let grad = mpi_gradient_to_logits(&logits, &grad_mpi);
        adam.step(&mut logits, &grad);
        progress(&reference, step + 1, total);
    }
    let mpi = logits_to_mpi(&logits, reference, &depths);
    history.push(loss_and_mpi_gradient(&mpi, &views).0);
    Ok((mpi, history))
}

/// An input at the working resolution: box-downscaled by an integer factor, intrinsics scaled by exactly
/// `1 / factor` (output pixel `i` covers input pixels `[f i, f i + f)`).
fn working_view(img: &ImageF32, cam: &Camera, max_width: u32) -> (ImageF32, Camera) {
    let f = cam.width.div_ceil(max_width).max(1);
    if f == 1 {
        return (img.to_rgb(), *cam);
    }
    let small = img.to_rgb().downscale(f);
    let s = 1.0 / f as f64;
    let c = Camera::new(
        small.width,
        small.height,
        cam.intrinsics.scaled(s, s),
        cam.pose,
    );
    (small, c)
}

fn logit(p: f32) -> f32 {
    let p = p.clamp(1e-3, 1.0 - 1e-3);
    (p / (1.0 - p)).ln()
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// Start: every plane's colour the PSV mean colour (grey where no view sees it), alpha `1 / (d + 1)` so every
/// plane contributes equally (`1/D`) in the reference view.
fn initial_logits(views: &[(ImageF32, Camera)], reference: &Camera, depths: Vec<f64>) -> Vec<f32> {
    let (mean, _) = sweep_statistics(
        views,
        reference,
        depths,
        TEMPERATURE,
        SINGLE_VIEW_VARIANCE,
        deepview_mpi::agreement::Aggregation::NONE,
    );
    let plane_len = mean.plane_len();
    let mut z = mean.layers;
    z.par_chunks_mut(plane_len)
        .enumerate()
        .for_each(|(d, plane)| {
            let a = logit(1.0 / (d as f32 + 1.0));
            for t in plane.chunks_exact_mut(4) {
                let unseen = t[0] == 0.0 && t[1] == 0.0 && t[2] == 0.0;
                for c in 0..3 {
                    t[c] = logit(if unseen { 0.5 } else { t[c] });
                }
                t[3] = a;
            }
        });
    z
}

/// `[D][H][W][4]` logits -> MPI with premultiplied colour.
pub(crate) fn logits_to_mpi(z: &[f32], camera: Camera, depths: &[f64]) -> Mpi {
    let layers = z
        .par_chunks(4)
        .flat_map_iter(|t| {
            let a = sigmoid(t[3]);
            [a * sigmoid(t[0]), a * sigmoid(t[1]), a * sigmoid(t[2]), a]
        })
        .collect();
    Mpi {
        camera,
        depths: depths.to_vec(),
        layers,
    }
}

/// Mean squared error over all views' pixels and RGB, and its gradient with respect to the MPI texels
/// (premultiplied colour and alpha, `[D][H][W][4]`).
pub(crate) fn loss_and_mpi_gradient(mpi: &Mpi, views: &[(ImageF32, Camera)]) -> (f64, Vec<f32>) {
    let total: usize = views
        .iter()
        .map(|(img, _)| img.width as usize * img.height as usize * 3)
        .sum();
    let norm = 1.0 / total as f64;
    let plane_len = mpi.plane_len();
    let (rw, rh) = (mpi.camera.width, mpi.camera.height);
    let mut grad = vec![0.0f32; mpi.layers.len()];
    let mut loss = 0.0f64;
    for (img, cam) in views {
        let comps = render_components(mpi, cam);
        let n = cam.width as usize * cam.height as usize;
        // dL/dR per pixel and channel.
        let mut dr = vec![0.0f32; n * 3];
        for p in 0..n {
            for c in 0..3 {
                let e = comps.render.data[p * 4 + c] as f64 - img.data[p * 3 + c] as f64;
                loss += e * e * norm;
                dr[p * 3 + c] = (2.0 * e * norm) as f32;
            }
        }
        let homs = target_to_plane_homographies(&mpi.camera, cam, &mpi.depths);
        grad.par_chunks_mut(plane_len)
            .enumerate()
            .for_each(|(d, g)| {
                let sampler = Sampler::new(homs[d], rw, rh);
                for y in 0..cam.height {
                    let row = sampler.row(y);
                    for x in 0..cam.width {
                        let Some(tap) = row.tap(x) else { continue };
                        let p = (y * cam.width + x) as usize;
                        let t = comps.transmittance[d * n + p];
                        let acc = &comps.accumulated_over[(d * n + p) * 3..(d * n + p) * 3 + 3];
                        let e = &dr[p * 3..p * 3 + 3];
                        // d render / d c_d = T_d ; d render / d a_d = -A_d T_d.
                        let gc = [e[0] * t, e[1] * t, e[2] * t];
                        let ga = -(e[0] * acc[0] + e[1] * acc[1] + e[2] * acc[2]) * t;
                        for j in 0..4 {
                            let w = tap.w[j];
                            if w == 0.0 {
                                continue;
                            }
                            let o = tap.idx[j] as usize * 4;
                            g[o] += w * gc[0];
                            g[o + 1] += w * gc[1];
                            g[o + 2] += w * gc[2];
                            g[o + 3] += w * ga;
                        }
                    }
                }
            });
    }
    (loss, grad)
}

/// Chain rule through `c = sigmoid(z_a) sigmoid(z_rgb)`, `a = sigmoid(z_a)`.
pub(crate) fn mpi_gradient_to_logits(z: &[f32], grad_mpi: &[f32]) -> Vec<f32> {
    let mut out = vec![0.0f32; z.len()];
    out.par_chunks_mut(4)
        .zip(z.par_chunks(4))
        .zip(grad_mpi.par_chunks(4))
        .for_each(|((o, t), g)| {
            let a = sigmoid(t[3]);
            let mut ga = g[3];
            for c in 0..3 {
                let col = sigmoid(t[c]);
                o[c] = g[c] * a * col * (1.0 - col);
                ga += g[c] * col;
            }
            o[3] = ga * a * (1.0 - a);
        });
    out
}

/// Adam (Kingma & Ba) with the usual betas.
struct Adam {
    m: Vec<f32>,
    v: Vec<f32>,
    t: i32,
    lr: f32,
}

impl Adam {
    fn new(n: usize, lr: f32) -> Self {
        Self {
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
            lr,
        }
    }

    fn step(&mut self, x: &mut [f32], g: &[f32]) {
        const B1: f32 = 0.9;
        const B2: f32 = 0.999;
        self.t += 1;
        let c1 = 1.0 - B1.powi(self.t);
        let c2 = 1.0 - B2.powi(self.t);
        let lr = self.lr;
        x.par_chunks_mut(4096)
            .zip(g.par_chunks(4096))
            .zip(self.m.par_chunks_mut(4096))
            .zip(self.v.par_chunks_mut(4096))
            .for_each(|(((x, g), m), v)| {
                for i in 0..x.len() {
                    m[i] = B1 * m[i] + (1.0 - B1) * g[i];
                    v[i] = B2 * v[i] + (1.0 - B2) * g[i] * g[i];
                    x[i] -= lr * (m[i] / c1) / ((v[i] / c2).sqrt() + 1e-8);
                }
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::{DMat3, DVec3, Intrinsics, Pose};

    /// Loss gradient w.r.t. logits against central finite differences of the loss.
    #[test]
    fn gradient_matches_finite_differences() {
        let reference = Camera::new(10, 8, Intrinsics::centred(10.0, 10, 8), Pose::IDENTITY);
        let depths = [4.0, 2.0, 1.0];
        let mut z = vec![0.0f32; 3 * 10 * 8 * 4];
        let mut s = 12345u32;
        for v in z.iter_mut() {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            *v = (s % 2000) as f32 / 500.0 - 2.0;
        }
        let views: Vec<(ImageF32, Camera)> = [(0.05, 0.0), (-0.04, 0.03)]
            .iter()
            .enumerate()
            .map(|(i, &(x, y))| {
                let cam = Camera::new(
                    9,
                    7,
                    Intrinsics::new(9.5, 9.0, 4.3, 3.6),
                    Pose::from_center(DMat3::from_rotation_y(0.01), DVec3::new(x, y, 0.0)),
                );
                let data = (0..9 * 7 * 3)
                    .map(|k| ((k * 7 + i * 13) % 17) as f32 / 16.0)
                    .collect();
                (ImageF32::from_data(9, 7, 3, data).unwrap(), cam)
            })
            .collect();
        let loss =
            |z: &[f32]| loss_and_mpi_gradient(&logits_to_mpi(z, reference, &depths), &views).0;
        let (_, gm) = loss_and_mpi_gradient(&logits_to_mpi(&z, reference, &depths), &views);
        let g = mpi_gradient_to_logits(&z, &gm);
        let eps = 1e-2f32;
        let mut checked = 0;
        for i in (0..z.len()).step_by(7) {
            let mut zp = z.clone();
            zp[i] += eps;
            let mut zm = z.clone();
            zm[i] -= eps;
            let fd = (loss(&zp) - loss(&zm)) / (2.0 * eps as f64);
            let tol = 2e-3 * g.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64 + 0.05 * fd.abs();
            assert!(
                (fd - g[i] as f64).abs() <= tol,
                "logit {i}: fd {fd} analytic {}",
                g[i]
            );
            checked += (g[i] != 0.0) as usize;
        }
        assert!(checked > 50, "only {checked} non-zero gradients checked");
    }
}
