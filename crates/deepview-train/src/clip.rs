//! Gradient utilities over a whole module: global-norm clipping (the paper's, after Adler et al.; burn's
//! `GradientClippingConfig::Norm` clips each tensor on its own), scaling, and moving/summing gradients of
//! replicas onto one device.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor};

/// The paper's clipping threshold.
pub const PAPER_CLIP_NORM: f64 = 8.0;

struct SquaredNorm<'a> {
    grads: &'a GradientsParams,
    sum: f64,
    /// Off the CPU: the sum so far as a one-element tensor on the gradients' device, read once at the
    /// end (a read per parameter would wait for the device each time).
    on_device: Option<Tensor<1>>,
}

impl ModuleVisitor for SquaredNorm<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.get::<D>(param.id) {
            if deepview_net::cpu::ops::fast_device(&g.device()) {
                self.sum += g.square().sum().into_scalar::<f32>() as f64;
            } else {
                let s = g.square().sum();
                self.on_device = Some(match self.on_device.take() {
                    Some(acc) => acc + s,
                    None => s,
                });
            }
        }
    }
}

/// The gradients of a module on a device of our GPU kernels, for [`deepview_net::gpu::squared_norms`]
/// (none collected elsewhere).
#[cfg(any(feature = "wgpu", feature = "cuda"))]
struct GpuGradients<'a> {
    grads: &'a GradientsParams,
    tensors: Vec<burn::tensor::DispatchTensor>,
    device: Option<Device>,
}

#[cfg(any(feature = "wgpu", feature = "cuda"))]
impl ModuleVisitor for GpuGradients<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.get::<D>(param.id) {
            let device = g.device();
            if !deepview_net::gpu::gpu_kernels(&device) {
                return;
            }
            self.device.get_or_insert(device);
            self.tensors.push(g.into_dispatch());
        }
    }
}

/// `sqrt(sum over all parameters of |grad|^2)`, over the parameters of `module` that have a gradient.
/// Non-finite if any gradient is. Each parameter's f32 sum is added in f64: on the CPU as each is
/// read; with our GPU kernels the sums go into one buffer on the device (one dispatch per 32 parameters),
/// read once; on other devices the sum stays on the device (f32) and is read once.
pub fn global_norm<M: Module>(module: &M, grads: &GradientsParams) -> f64 {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    {
        let mut gpu = GpuGradients {
            grads,
            tensors: Vec::new(),
            device: None,
        };
        module.visit(&mut gpu);
        if let Some(device) = gpu.device {
            return deepview_net::gpu::squared_norms(gpu.tensors, &device).sqrt();
        }
    }
    let mut v = SquaredNorm {
        grads,
        sum: 0.0,
        on_device: None,
    };
    module.visit(&mut v);
    if let Some(acc) = v.on_device {
        v.sum += acc.into_scalar::<f32>() as f64;
    }
    v.sum.sqrt()
}

struct Scale<'a> {
    grads: &'a mut GradientsParams,
    factor: f32,
}

impl ModuleVisitor for Scale<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.remove::<D>(param.id) {
            self.grads.register::<D>(param.id, g * self.factor);
        }
    }
}

/// Multiply every gradient of `module`'s parameters by `factor`.
pub fn scale<M: Module>(module: &M, mut grads: GradientsParams, factor: f32) -> GradientsParams {
    let mut v = Scale {
        grads: &mut grads,
        factor,
    };
    module.visit(&mut v);
    grads
}

/// The factor that clips gradients of global norm `norm` to `max_norm` (`max_norm / norm`), where it
/// exceeds it.
pub fn clip_factor(norm: f64, max_norm: f64) -> Option<f32> {
    (norm.is_finite() && norm > max_norm).then(|| (max_norm / norm) as f32)
}

/// Clip to global norm `max_norm`: if the global norm `n` exceeds it, scale every gradient by
/// `max_norm / n`. Returns the clipped gradients and the norm before clipping.
pub fn clip_global_norm<M: Module>(
    module: &M,
    grads: GradientsParams,
    max_norm: f64,
) -> (GradientsParams, f64) {
    let norm = global_norm(module, &grads);
    match clip_factor(norm, max_norm) {
        Some(f) => (scale(module, grads, f), norm),
        None => (grads, norm),
    }
}

struct Sum<'a> {
    acc: &'a mut GradientsParams,
    new: GradientsParams,
    device: &'a Device,
}

impl ModuleVisitor for Sum<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let Some(g) = self.new.remove::<D>(param.id) else {
            return;
        };
        let g = g.to_device(self.device);
        let out = match self.acc.remove::<D>(param.id) {
            Some(a) => a + g,
            None => g,
        };
        self.acc.register::<D>(param.id, out);
    }
}

/// Sum gradient sets (one per replica) on `device`.
pub fn sum_on_device<M: Module>(
    module: &M,
    sets: Vec<GradientsParams>,
    device: &Device,
) -> GradientsParams {
    let mut acc = GradientsParams::new();
    for new in sets {
        let mut v = Sum {
            acc: &mut acc,
            new,
            device,
        };
        module.visit(&mut v);
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};

    #[derive(Module, Debug)]
    struct Two {
        a: Linear,
        b: Linear,
    }

    fn grads_of(m: &Two, dev: &Device, values: [f32; 4]) -> GradientsParams {
        // Known gradients: a.weight = values[0], a.bias = values[1], b.weight = values[2], b.bias = values[3]
        // everywhere (shapes 2x3, 3, 3x1, 1).
        let mut g = GradientsParams::new();
        g.register::<2>(m.a.weight.id, Tensor::<2>::full([2, 3], values[0], dev));
        g.register::<1>(
            m.a.bias.as_ref().unwrap().id,
            Tensor::<1>::full([3], values[1], dev),
        );
        g.register::<2>(m.b.weight.id, Tensor::<2>::full([3, 1], values[2], dev));
        g.register::<1>(
            m.b.bias.as_ref().unwrap().id,
            Tensor::<1>::full([1], values[3], dev),
        );
        g
    }

    #[test]
    fn global_norm_clipping_on_known_gradients() {
        let dev = Device::flex();
        // Drawn under the generator's lock (other tests compare seeded weights).
        let m = deepview_net::rng::seeded_module(&dev, 2, || Two {
            a: LinearConfig::new(2, 3).init(&dev),
            b: LinearConfig::new(3, 1).init(&dev),
        });
        // norm^2 = 6*2^2 + 3*1^2 + 3*2^2 + 1*3^2 = 24 + 3 + 12 + 9 = 48
        let g = grads_of(&m, &dev, [2.0, 1.0, 2.0, 3.0]);
        assert!((global_norm(&m, &g) - 48f64.sqrt()).abs() < 1e-6);
        // Below the threshold: untouched.
        let (g, n) = clip_global_norm(&m, g, 8.0);
        assert!((n - 48f64.sqrt()).abs() < 1e-6);
        assert_eq!(
            g.get::<2>(m.a.weight.id)
                .unwrap()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap(),
            vec![2.0; 6]
        );
        // Above: every tensor scaled by the same factor 2 / sqrt(48), so the global norm becomes 2, and the
        // direction is kept (per-tensor clipping would not keep it).
        let (g, _) = clip_global_norm(&m, g, 2.0);
        assert!((global_norm(&m, &g) - 2.0).abs() < 1e-5);
        let f = 2.0 / 48f32.sqrt();
        let bb = g
            .get::<1>(m.b.bias.as_ref().unwrap().id)
            .unwrap()
            .into_scalar::<f32>();
        assert!((bb - 3.0 * f).abs() < 1e-6, "{bb}");
        let aw = g
            .get::<2>(m.a.weight.id)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert!(aw.iter().all(|v| (v - 2.0 * f).abs() < 1e-6));
    }

    #[test]
    fn sum_and_nan() {
        let dev = Device::flex();
        // Drawn under the generator's lock (other tests compare seeded weights).
        let m = deepview_net::rng::seeded_module(&dev, 2, || Two {
            a: LinearConfig::new(2, 3).init(&dev),
            b: LinearConfig::new(3, 1).init(&dev),
        });
        let s = sum_on_device(
            &m,
            vec![
                grads_of(&m, &dev, [1.0; 4]),
                grads_of(&m, &dev, [2.0, 0.0, 0.0, 0.0]),
            ],
            &dev,
        );
        assert_eq!(
            s.get::<2>(m.a.weight.id)
                .unwrap()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap(),
            vec![3.0; 6]
        );
        assert_eq!(
            s.get::<1>(m.a.bias.as_ref().unwrap().id)
                .unwrap()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap(),
            vec![1.0; 3]
        );
        let bad = grads_of(&m, &dev, [1.0, f32::NAN, 0.0, 0.0]);
        assert!(!global_norm(&m, &bad).is_finite());
    }
}
