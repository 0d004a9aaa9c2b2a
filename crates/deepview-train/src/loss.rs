//! The training loss: the paper's VGG-16 feature loss (supplement, "Training hyperparameters"), the same
//! plus an SSIM term (`vgg+ssim`), or plain L1.
//!
//! SSIM term (`vgg+ssim`): `SSIM_LOSS_WEIGHT * (1 - SSIM)` per example, SSIM exactly as the evaluation
//! computes it (`deepview_metrics::ssim`: 11-tap Gaussian, sigma 1.5, 'valid' windows, K1 0.01, K2 0.03,
//! data range 1, mean over RGB), as separable convolutions so that autodiff gives its gradient. The weight
//! puts the term on the scale of the feature loss (a VGG loss of 1e4..1e5 per crop; 1 - SSIM of 0.05..0.3).
//!
//! Feature loss, as written in the supplement:
//! 1. reflect-pad the 32x32 prediction and target crops to 40x40 (conv3_3's receptive field is 40x40);
//!    for a crop of any size `s` we pad by `s / 8` per side, i.e. 4 px for 32;
//! 2. VGG-16 features conv1_2, conv2_2, conv3_3 (after ReLU; Caffe preprocessing, see [`crate::vgg`]);
//! 3. sum the L1 differences of the layers weighted by `[11.17, 35.04, 29.09]`;
//! 4. divide by the crop area `32 * 32`.
//!
//! Interpretation (the supplement does not spell these out): "L1 difference of a layer" is the *sum* of
//! absolute differences over all channels and positions of that layer's feature map of the padded crop
//! (the division by the crop area in step 4 only makes sense for a sum); features are on the Caffe scale
//! (inputs 0..255), which these weights expect. A batch's loss is the mean of its examples' losses.

use crate::vgg::Vgg16;
use burn::tensor::Tensor;
use burn::tensor::ops::PadMode;
use serde::{Deserialize, Serialize};

/// Per-layer weights of conv1_2, conv2_2, conv3_3 (Chen & Koltun style scaling, values from the supplement).
pub const VGG_LAYER_WEIGHTS: [f32; 3] = [11.17, 35.04, 29.09];

/// Which training loss.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum LossKind {
    /// The paper's VGG-16 feature loss.
    #[default]
    Vgg,
    /// Mean absolute colour difference (cheap; for smoke tests and quick runs).
    L1,
    /// The feature loss plus `SSIM_LOSS_WEIGHT * (1 - SSIM)` (the evaluation metric).
    #[serde(rename = "vgg+ssim")]
    VggSsim,
}

/// Weight of `1 - SSIM` in the `vgg+ssim` loss.
pub const SSIM_LOSS_WEIGHT: f32 = 1.0e5;

impl std::str::FromStr for LossKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "vgg" => Ok(Self::Vgg),
            "l1" => Ok(Self::L1),
            "vgg+ssim" => Ok(Self::VggSsim),
            other => Err(format!(
                "unknown loss `{other}` (expected vgg, vgg+ssim or l1)"
            )),
        }
    }
}

/// A loss function ready to evaluate (holds the VGG weights when needed).
#[derive(Clone, Debug)]
pub enum Loss {
    Vgg(Box<Vgg16>),
    VggSsim(Box<Vgg16>),
    L1,
}

impl Loss {
    pub fn kind(&self) -> LossKind {
        match self {
            Loss::Vgg(_) => LossKind::Vgg,
            Loss::VggSsim(_) => LossKind::VggSsim,
            Loss::L1 => LossKind::L1,
        }
    }

    /// Per-example losses, shape [n]. `pred`, `target`: [n, 3, h, w] RGB in 0..1.
    pub fn per_example(&self, pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        let [n, _, h, w] = pred.dims();
        match self {
            Loss::L1 => (pred - target)
                .abs()
                .reshape([n as i32, -1])
                .mean_dim(1)
                .reshape([n]),
            Loss::Vgg(vgg) => vgg_feature_loss(vgg, pred, target, h, w),
            Loss::VggSsim(vgg) => {
                let s = ssim_per_example(pred.clone(), target.clone());
                vgg_feature_loss(vgg, pred, target, h, w) + (s.neg() + 1.0) * SSIM_LOSS_WEIGHT
            }
        }
    }

    /// Sum of the per-example losses (the batch mean is this over the global batch size).
    pub fn sum(&self, pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        self.per_example(pred, target).sum()
    }
}

/// Reflect padding per side used for an `h x w` crop: `size / 8` (4 for 32, giving the paper's 40).
pub fn feature_loss_padding(h: usize, w: usize) -> (usize, usize) {
    (h / 8, w / 8)
}

/// A crop `[n, c, h, w]` as the feature loss feeds it to VGG: reflect-padded by
/// [`feature_loss_padding`] per side (`[n, c, 40, 40]` for a 32x32 crop).
pub(crate) fn pad_for_feature_loss(t: Tensor<4>) -> Tensor<4> {
    let [_, _, h, w] = t.dims();
    let (ph, pw) = feature_loss_padding(h, w);
    if ph + pw > 0 {
        t.pad([(ph, ph), (pw, pw)], PadMode::Reflect)
    } else {
        t
    }
}

/// VGG's features of `pred` and `target` (`[2n, ..]`, `pred`'s first) as [`pad_for_feature_loss`] pads
/// them: the padding, concatenation and preprocessing in one dispatch with our GPU kernels
/// ([`deepview_net::gpu::reflect_pad_pair`]), burn's ops elsewhere.
fn padded_pair_features(
    vgg: &Vgg16,
    pred: Tensor<4>,
    target: Tensor<4>,
) -> crate::vgg::VggFeatures {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if deepview_net::gpu::gpu_kernels(&pred.device()) {
        let [_, _, h, w] = pred.dims();
        let (ph, pw) = feature_loss_padding(h, w);
        let caffe = deepview_net::gpu::ChannelMap {
            scale: 255.0,
            offset: crate::vgg::CAFFE_MEAN_BGR,
            reverse: true,
        };
        let both = deepview_net::gpu::reflect_pad_pair(pred, target, ph, pw, caffe);
        return vgg.features_preprocessed(both);
    }
    vgg.features(Tensor::cat(
        vec![pad_for_feature_loss(pred), pad_for_feature_loss(target)],
        0,
    ))
}

/// SSIM of each example, shape [n], with autodiff: `deepview_metrics::ssim` (see the module docs) on
/// `[n, c, h, w]` tensors (h, w >= 11).
pub fn ssim_per_example(x: Tensor<4>, y: Tensor<4>) -> Tensor<1> {
    use burn::tensor::TensorData;
    use burn::tensor::module::conv2d;
    use burn::tensor::ops::ConvOptions;
    const SIGMA: f64 = 1.5;
    const RADIUS: i32 = 5;
    let [n, c, h, w] = x.dims();
    let device = x.device();
    let taps: Vec<f64> = (-RADIUS..=RADIUS)
        .map(|k| (-(k * k) as f64 / (2.0 * SIGMA * SIGMA)).exp())
        .collect();
    let total: f64 = taps.iter().sum();
    let g: Vec<f32> = taps.iter().map(|t| (t / total) as f32).collect();
    let t = g.len();
    let gx = Tensor::<4>::from_data(TensorData::new(g.clone(), [1, 1, 1, t]), &device);
    let gy = Tensor::<4>::from_data(TensorData::new(g, [1, 1, t, 1]), &device);
    let opts = || ConvOptions::new([1, 1], [0, 0], [1, 1], 1);
    // Every channel of every example as its own single-channel image.
    let blur = |v: Tensor<4>| {
        let v = v.reshape([(n * c) as i32, 1, h as i32, w as i32]);
        conv2d(
            conv2d(v, gx.clone(), None, opts()),
            gy.clone(),
            None,
            opts(),
        )
    };
    let (c1, c2) = (0.01f32 * 0.01, 0.03f32 * 0.03);
    let mx = blur(x.clone());
    let my = blur(y.clone());
    let sxx = blur(x.clone() * x.clone()) - mx.clone() * mx.clone();
    let syy = blur(y.clone() * y.clone()) - my.clone() * my.clone();
    let sxy = blur(x * y) - mx.clone() * my.clone();
    let num = (mx.clone() * my.clone() * 2.0 + c1) * (sxy * 2.0 + c2);
    let den = (mx.clone() * mx + my.clone() * my + c1) * (sxx + syy + c2);
    (num / den).reshape([n as i32, -1]).mean_dim(1).reshape([n])
}

fn vgg_feature_loss(
    vgg: &Vgg16,
    pred: Tensor<4>,
    target: Tensor<4>,
    h: usize,
    w: usize,
) -> Tensor<1> {
    let n = pred.dims()[0];
    // One VGG pass over prediction and target together.
    let f = padded_pair_features(vgg, pred, target);
    let [a, b, c] = VGG_LAYER_WEIGHTS;
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if deepview_net::gpu::gpu_kernels(&f.conv1_2.device()) {
        // Each layer's weight and the area folded into its kernel (one launch each way per layer).
        let area = (h * w) as f32;
        let l1 = deepview_net::gpu::pair_l1;
        return l1(f.conv1_2, a / area) + l1(f.conv2_2, b / area) + l1(f.conv3_3, c / area);
    }
    let l1 = |t: Tensor<4>| {
        let d = t.dims()[0] / 2;
        (t.clone().narrow(0, 0, d) - t.narrow(0, d, d))
            .abs()
            .reshape([n as i32, -1])
            .sum_dim(1)
            .reshape([n])
    };
    (l1(f.conv1_2) * a + l1(f.conv2_2) * b + l1(f.conv3_3) * c) / (h * w) as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trainer::seeded;
    use burn::tensor::{Device, Distribution};

    /// A tensor of uniform values in [0, 1) drawn from burn's generator seeded with `seed` ([`seeded`]).
    fn uniform(dims: [usize; 4], seed: u64, device: &Device) -> Tensor<4> {
        seeded(device, seed, || {
            Tensor::<4>::random(dims, Distribution::Uniform(0.0, 1.0), device)
        })
    }

    fn losses(device: &Device) -> Vec<Loss> {
        let mut v = vec![Loss::L1];
        match Vgg16::load(&crate::vgg::test_weights_path(), device) {
            Ok(vgg) => {
                v.push(Loss::VggSsim(Box::new(vgg.clone())));
                v.push(Loss::Vgg(Box::new(vgg)));
            }
            Err(e) => eprintln!("SKIP vgg loss: {e}"),
        }
        v
    }

    /// The differentiable SSIM equals the evaluation's (`deepview_metrics`, an independent f64
    /// implementation) on random and on related images, and its gradient matches central differences.
    #[test]
    fn ssim_term_matches_the_metric_and_its_gradient() {
        let device = Device::flex().autodiff();
        let (h, w) = (19usize, 23usize);
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let a: Vec<f32> = (0..3 * h * w).map(|_| next()).collect();
        // b: a blurred, shifted, noisy version of a (SSIM well inside (0, 1)).
        let b: Vec<f32> = (0..3 * h * w)
            .map(|i| {
                (0.6 * a[i] + 0.4 * a[(i + 1) % a.len()] + 0.1 * (next() - 0.5)).clamp(0.0, 1.0)
            })
            .collect();
        let to_tensor = |v: &[f32]| {
            Tensor::<4>::from_data(
                burn::tensor::TensorData::new(v.to_vec(), [1, 3, h, w]),
                &device,
            )
        };
        let to_image = |v: &[f32]| {
            // planar -> interleaved
            let mut img = deepview_image::ImageF32::new(w as u32, h as u32, 3);
            for c in 0..3 {
                for p in 0..h * w {
                    img.data[p * 3 + c] = v[c * h * w + p];
                }
            }
            img
        };
        let want = deepview_metrics::ssim(&to_image(&a), &to_image(&b)).unwrap();
        let x = to_tensor(&a).require_grad();
        let got = ssim_per_example(x.clone(), to_tensor(&b));
        let v: f32 = got.clone().into_scalar();
        assert!((v as f64 - want).abs() < 2e-5, "{v} vs {want}");
        assert!(v > 0.2 && v < 0.95, "{v}");
        let same: f32 = ssim_per_example(to_tensor(&a), to_tensor(&a)).into_scalar();
        assert!((same - 1.0).abs() < 1e-5, "{same}");
        // Gradient against central differences of the f64 metric at a few pixels.
        let grads = got.sum().backward();
        let g = x
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        for &i in &[0usize, 77, 3 * h * w / 2, 3 * h * w - 5] {
            let eps = 1e-3f32;
            let (mut p, mut m) = (a.clone(), a.clone());
            p[i] += eps;
            m[i] -= eps;
            let fd = (deepview_metrics::ssim(&to_image(&p), &to_image(&b)).unwrap()
                - deepview_metrics::ssim(&to_image(&m), &to_image(&b)).unwrap())
                / (2.0 * eps as f64);
            assert!(
                (g[i] as f64 - fd).abs() < 1e-3 * fd.abs().max(1e-2),
                "pixel {i}: autodiff {} vs finite difference {fd}",
                g[i]
            );
        }
    }

    /// The VGG feature loss on wgpu (the padded pair as one kernel, burn's convolutions on the
    /// channels-last weights) equals the CPU's: the per-example losses, and the gradient at the
    /// prediction (through the padding's backward kernel), for a 16 px crop (padded by 2) and a
    /// 24 x 32 one (by 3 and 4). Measured on lavapipe: losses 1e-6 apart relative, gradients 3e-7 of
    /// their largest.
    #[cfg(feature = "wgpu")]
    #[test]
    fn wgpu_vgg_loss_equals_the_cpus() {
        use burn::tensor::TensorData;
        let gpu =
            deepview_net::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
        let cpu = Device::flex();
        let vec = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
        for dims in [[2, 3, 16, 16], [1, 3, 24, 32]] {
            let (p, t) = (vec(uniform(dims, 7, &cpu)), vec(uniform(dims, 8, &cpu)));
            let run = |dev: &Device| {
                let ad = dev.clone().autodiff();
                let vgg = Vgg16::load(&crate::vgg::test_weights_path(), &ad).unwrap();
                let loss = Loss::Vgg(Box::new(vgg));
                let pred =
                    Tensor::<4>::from_data(TensorData::new(p.clone(), dims), &ad).require_grad();
                let target = Tensor::<4>::from_data(TensorData::new(t.clone(), dims), &ad);
                let l = loss.per_example(pred.clone(), target);
                let values = l.clone().inner().into_data().try_to_vec::<f32>().unwrap();
                let grads = l.sum().backward();
                (values, vec(pred.grad(&grads).unwrap()))
            };
            let (want, want_grad) = run(&cpu);
            assert!(deepview_net::gpu::gpu_kernels(&gpu));
            let (got, got_grad) = run(&gpu);
            for (a, b) in want.iter().zip(&got) {
                assert!(
                    (a - b).abs() <= 1e-5 * a.abs(),
                    "{dims:?}: losses {a} and {b}"
                );
            }
            let scale = want_grad.iter().fold(0f32, |m, g| m.max(g.abs()));
            let e = want_grad
                .iter()
                .zip(&got_grad)
                .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(
                scale > 0.0 && e <= 1e-5 * scale,
                "{dims:?}: gradients {e} apart of {scale}"
            );
        }
    }

    #[test]
    fn zero_for_identical_positive_otherwise_and_grad_flows() {
        let device = Device::flex().autodiff();
        for loss in losses(&device) {
            let t = uniform([2, 3, 32, 32], 1, &device);
            let same = loss
                .per_example(t.clone(), t.clone())
                .into_data()
                .try_to_vec::<f32>()
                .unwrap();
            assert!(
                same.iter().all(|v| *v == 0.0),
                "{:?}: {same:?}",
                loss.kind()
            );
            let p = uniform([2, 3, 32, 32], 2, &device).require_grad();
            let l = loss.sum(p.clone(), t);
            let v = l.clone().into_scalar::<f32>();
            assert!(v.is_finite() && v > 0.0, "{:?}: {v}", loss.kind());
            let g = p
                .grad(&l.backward())
                .expect("gradient reaches the prediction");
            let g = g.into_data().try_to_vec::<f32>().unwrap();
            assert!(g.iter().all(|x| x.is_finite()));
            assert!(
                g.iter().any(|x| *x != 0.0),
                "{:?}: zero gradient",
                loss.kind()
            );
        }
    }

    /// Reflect padding by hand (the edge texel is not repeated: index `-1` reads `1`, index `n` reads
    /// `n - 2`), `[n, c, h, w]` -> `[n, c, h + 2 p, w + 2 q]`.
    fn reflect_pad_by_hand(v: &[f32], dims: [usize; 4], p: usize, q: usize) -> Vec<f32> {
        let [n, c, h, w] = dims;
        let reflect = |i: i64, len: usize| -> usize {
            let len = len as i64;
            let j = if i < 0 {
                -i
            } else if i >= len {
                2 * (len - 1) - i
            } else {
                i
            };
            assert!((0..len).contains(&j));
            j as usize
        };
        let (hp, wp) = (h + 2 * p, w + 2 * q);
        let mut out = vec![0f32; n * c * hp * wp];
        for b in 0..n * c {
            for y in 0..hp {
                let sy = reflect(y as i64 - p as i64, h);
                for x in 0..wp {
                    let sx = reflect(x as i64 - q as i64, w);
                    out[(b * hp + y) * wp + x] = v[(b * h + sy) * w + sx];
                }
            }
        }
        out
    }

    /// The paper's rule (supplement): a 32x32 crop is reflect-padded to 40x40 before VGG, and the loss is
    /// `sum_l w_l |phi_l(pred) - phi_l(target)|_1 / (32 * 32)` with weights 11.17, 35.04, 29.09 for
    /// conv1_2, conv2_2, conv3_3. Both the padding and the loss are recomputed here independently: the
    /// padding by index arithmetic, the loss from VGG features of the hand-padded crops (one crop per
    /// VGG call, sums in f64). Tolerance: relative 1e-4 for the f32 sums over ~1.5e5 feature values
    /// (observed ~2e-8).
    #[test]
    fn vgg_loss_pads_32_to_40_and_divides_by_the_crop_area() {
        let device = Device::flex();
        // The padding the loss feeds to VGG: 4 px per side for 32x32, and size / 8 per axis otherwise
        // (a non-square crop pins the axis order).
        for (dims, p, q) in [([1, 3, 32, 32], 4, 4), ([2, 3, 16, 40], 2, 5)] {
            let x = uniform(dims, 3, &device);
            let v = x.clone().into_data().try_to_vec::<f32>().unwrap();
            let padded = pad_for_feature_loss(x);
            let [n, c, h, w] = dims;
            assert_eq!(padded.dims(), [n, c, h + 2 * p, w + 2 * q]);
            let got = padded.into_data().try_to_vec::<f32>().unwrap();
            assert_eq!(got, reflect_pad_by_hand(&v, dims, p, q), "{dims:?}");
        }
        assert_eq!(feature_loss_padding(32, 32), (4, 4));

        let vgg = match Vgg16::load(&crate::vgg::test_weights_path(), &device) {
            Ok(vgg) => vgg,
            Err(e) => {
                eprintln!("SKIP vgg padding rule: {e}");
                return;
            }
        };
        let dims = [1, 3, 32, 32];
        let pred = uniform(dims, 4, &device);
        let target = uniform(dims, 5, &device);
        let features = |t: &Tensor<4>| {
            let v = t.clone().into_data().try_to_vec::<f32>().unwrap();
            let padded = Tensor::<4>::from_data(
                burn::tensor::TensorData::new(reflect_pad_by_hand(&v, dims, 4, 4), [1, 3, 40, 40]),
                &device,
            );
            let f = vgg.features(padded);
            assert_eq!(f.conv3_3.dims(), [1, 256, 10, 10]);
            [f.conv1_2, f.conv2_2, f.conv3_3].map(|t| t.into_data().try_to_vec::<f32>().unwrap())
        };
        let (fp, ft) = (features(&pred), features(&target));
        let weights = [11.17f64, 35.04, 29.09];
        let mut expect = 0.0f64;
        for l in 0..3 {
            let l1: f64 = fp[l]
                .iter()
                .zip(&ft[l])
                .map(|(a, b)| (*a as f64 - *b as f64).abs())
                .sum();
            expect += weights[l] * l1;
        }
        let expect = expect / (32.0 * 32.0);
        let loss = Loss::Vgg(Box::new(vgg));
        let got = loss.per_example(pred, target).into_scalar::<f32>() as f64;
        assert!(
            (got - expect).abs() <= 1e-4 * expect,
            "loss {got} vs independent {expect}"
        );
    }

    /// Deterministic `[2, 3, 16, 16]` test data: `f(i)` for flat index `i`.
    fn pattern(device: &Device, f: impl Fn(usize) -> f32) -> Tensor<4> {
        let v: Vec<f32> = (0..2 * 3 * 16 * 16).map(f).collect();
        Tensor::<4>::from_data(burn::tensor::TensorData::new(v, [2, 3, 16, 16]), device)
    }

    /// The loss of one example does not depend on the other examples of the batch, and the directional
    /// derivative agrees with a central finite difference. Deterministic data; the prediction differs
    /// from the target by at least 0.05 everywhere and L1's step is 0.01, so L1 has no kink inside the
    /// difference (exact up to rounding); VGG (ReLU and max-pool kinks) uses a small step.
    #[test]
    fn per_example_and_finite_difference() {
        let device = Device::flex().autodiff();
        let frac = |i: usize, a: usize| ((i * a) % 97) as f32 / 97.0;
        for loss in losses(&device) {
            let t = pattern(&device, |i| 0.2 + 0.6 * frac(i, 37));
            let p = pattern(&device, |i| {
                let s = if (i * 13) % 7 < 3 { -1.0 } else { 1.0 };
                0.2 + 0.6 * frac(i, 37) + s * (0.05 + 0.1 * frac(i, 11))
            });
            let dir = pattern(&device, |i| 2.0 * frac(i, 53) - 1.0);
            let both = loss
                .per_example(p.clone(), t.clone())
                .into_data()
                .try_to_vec::<f32>()
                .unwrap();
            let first = loss
                .per_example(p.clone().narrow(0, 0, 1), t.clone().narrow(0, 0, 1))
                .into_scalar::<f32>();
            assert!(
                (both[0] - first).abs() <= 1e-4 * first.abs(),
                "{both:?} vs {first}"
            );
            let pg = p.clone().require_grad();
            let l = loss.sum(pg.clone(), t.clone());
            let g = pg.grad(&l.backward()).unwrap();
            let analytic = (g * dir.clone().inner()).sum().into_scalar::<f32>() as f64;
            let eps = match loss.kind() {
                LossKind::L1 => 1e-2,
                LossKind::Vgg | LossKind::VggSsim => 1e-4,
            };
            let lp = loss
                .sum(p.clone() + dir.clone() * eps, t.clone())
                .into_scalar::<f32>() as f64;
            let lm = loss.sum(p - dir * eps, t).into_scalar::<f32>() as f64;
            let numeric = (lp - lm) / (2.0 * eps);
            assert!(
                (analytic - numeric).abs() < 0.02 * numeric.abs().max(1e-3),
                "{:?}: analytic {analytic} numeric {numeric}",
                loss.kind()
            );
        }
    }
}
