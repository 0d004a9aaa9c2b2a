//! The training's optimizer: Adam with TensorFlow's defaults (the paper's framework: beta 0.9 / 0.999,
//! epsilon 1e-8). burn's `Adam` on the CPU; on a GPU each parameter's step is one kernel
//! ([`deepview_net::gpu::adam`], burn's arithmetic in its order) where burn's takes a dozen dispatches,
//! and inside the trainer's step ([`with_gradient_scale`]) up to 8 parameters share one dispatch.
//! The state is burn's [`AdamState`], so checkpoints (`optimizer.bpk`) are the same either way.

use burn::optim::{Adam, AdamConfig, AdamState, LearningRate, ModuleOptimizer, Optimizer};
use burn::tensor::{Device, Tensor};
use std::cell::Cell;

thread_local! {
    /// The gradient factor of the optimizer steps running on this thread ([`with_gradient_scale`]).
    static GRADIENT_SCALE: Cell<f32> = const { Cell::new(1.0) };
}

/// Whether Adam on `device` scales the gradients itself ([`with_gradient_scale`]: our GPU kernel, one
/// dispatch per parameter for the step and the clipping together), rather than taking them scaled.
pub fn scales_gradients(device: &Device) -> bool {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if deepview_net::gpu::gpu_kernels(device) {
        return true;
    }
    let _ = device;
    false
}

/// Run `f` (an optimizer step on this thread, on a device where [`scales_gradients`]) with every
/// gradient multiplied by `scale` inside the step: the global-norm clipping without a pass of its own
/// over the gradients (which would also lose the layout a convolution's weight gradient comes in).
/// With our GPU kernels the parameters' steps are launched together when `f` returns
/// ([`deepview_net::gpu::adam_batch`]: a dispatch per 8 parameters rather than one each).
pub fn with_gradient_scale<R>(scale: f32, f: impl FnOnce() -> R) -> R {
    GRADIENT_SCALE.with(|s| s.set(scale));
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    let r = deepview_net::gpu::adam_batch(f);
    #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
    let r = f();
    GRADIENT_SCALE.with(|s| s.set(1.0));
    r
}

const BETA_1: f32 = 0.9;
const BETA_2: f32 = 0.999;
const EPSILON: f32 = 1e-8;

/// Adam: burn's on the CPU (the reference), our kernel on cubecl devices.
#[derive(Clone)]
pub struct DeepviewAdam {
    burn: Adam,
    /// Use the GPU kernel where the device has it (off: burn's ops everywhere; tests compare the two).
    #[cfg_attr(not(any(feature = "wgpu", feature = "cuda")), allow(dead_code))]
    kernel: bool,
}

impl DeepviewAdam {
    pub fn new() -> Self {
        Self {
            burn: AdamConfig::new()
                .with_beta_1(BETA_1)
                .with_beta_2(BETA_2)
                .with_epsilon(EPSILON)
                .build(),
            kernel: true,
        }
    }

    /// burn's `Adam` on every device (the reference of the kernel).
    pub fn burn_only() -> Self {
        Self {
            kernel: false,
            ..Self::new()
        }
    }

    /// The module optimizer of the training (one parameter group, no clipping of its own: the trainer
    /// clips by the global norm).
    pub fn module_optimizer(self) -> ModuleOptimizer {
        ModuleOptimizer::from(self)
    }
}

impl Default for DeepviewAdam {
    fn default() -> Self {
        Self::new()
    }
}

impl Optimizer for DeepviewAdam {
    type State<const D: usize> = AdamState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if self.kernel && deepview_net::gpu::gpu_kernels(&tensor.device()) {
            let (time, m, v) = match state {
                Some(s) => (s.momentum.time, s.momentum.moment_1, s.momentum.moment_2),
                // burn's first step is the general one from zero moments.
                None => (0, tensor.zeros_like(), tensor.zeros_like()),
            };
            let time = time + 1;
            let step = deepview_net::gpu::AdamStep {
                grad_scale: GRADIENT_SCALE.with(Cell::get),
                ..deepview_net::gpu::AdamStep::new(BETA_1, BETA_2, EPSILON, lr, time)
            };
            let (p, m, v) = deepview_net::gpu::adam(tensor, grad, m, v, step);
            let state = AdamState::new(burn::optim::AdaptiveMomentumState::new(time, m, v));
            return (p, Some(state));
        }
        self.burn.step(lr, tensor, grad, state)
    }

    fn to_device<const D: usize>(state: Self::State<D>, device: &Device) -> Self::State<D> {
        <Adam as Optimizer>::to_device(state, device)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[cfg(feature = "wgpu")]
    use burn::module::Module;
    use burn::nn::{Linear, LinearConfig};
    use burn::optim::GradientsParams;
    use burn::tensor::TensorData;

    fn values(m: &Linear) -> Vec<f32> {
        let mut v = m.weight.val().into_data().try_to_vec::<f32>().unwrap();
        v.extend(
            m.bias
                .as_ref()
                .unwrap()
                .val()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap(),
        );
        v
    }

    /// Gradients of step `k`: fixed values (an LCG), so both devices get the same ones.
    fn grads(m: &Linear, k: usize, device: &Device) -> GradientsParams {
        let scale = [1.0f32, 1e-3, 30.0, 0.5][k % 4];
        let mut state = 0x9e37_79b9u32.wrapping_mul(k as u32 + 1);
        let mut next = |n: usize| -> Vec<f32> {
            (0..n)
                .map(|_| {
                    state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    ((state >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0) * scale
                })
                .collect()
        };
        let mut g = GradientsParams::new();
        let w = Tensor::<2>::from_data(TensorData::new(next(15), [5, 3]), device);
        let b = Tensor::<1>::from_data(TensorData::new(next(3), [3]), device);
        g.register::<2>(m.weight.id, w);
        g.register::<1>(m.bias.as_ref().unwrap().id, b);
        g
    }

    /// Checkpoints written before this optimizer (burn's `Adam` with the same settings, as
    /// `AdamConfig::init` built it) load into it and continue exactly: its state is burn's.
    #[test]
    fn burns_adam_checkpoints_resume_exactly() {
        let ad = Device::flex().autodiff();
        let cpu = Device::flex();
        // Drawn under the generator's lock, as every draw of these tests (other tests compare
        // seeded weights).
        let start: Linear =
            deepview_net::rng::seeded_module(&ad, 1, || LinearConfig::new(5, 3).init(&ad));
        let mut old = AdamConfig::new().with_epsilon(1e-8).init();
        let mut a = old.step(0.01, start.clone(), grads(&start, 0, &cpu));
        let mut new = DeepviewAdam::new()
            .module_optimizer()
            .from_bytes(old.into_bytes().unwrap())
            .unwrap();
        let mut b = a.clone();
        for k in 1..3 {
            a = old.step(0.01, a, grads(&start, k, &cpu));
            b = new.step(0.01, b, grads(&start, k, &cpu));
        }
        assert_eq!(values(&a), values(&b));
        assert_ne!(values(&a), values(&start));
    }

    /// The Adam kernel on wgpu (lavapipe) steps a module as burn's `Adam` does on the CPU (first step
    /// without state, then with it; gradients of very different sizes), one dispatch per parameter and
    /// the parameters batched into one (the trainer's way), and its state is burn's: saved
    /// after two kernel steps and loaded into burn's optimizer on the CPU, the third step gives the same
    /// weights as three CPU steps.
    #[cfg(feature = "wgpu")]
    #[test]
    fn wgpu_adam_kernel_equals_burns_adam() {
        let gpu = deepview_net::device::parse_device("wgpu:cpu").expect("lavapipe");
        // Loading a record materialises its state on burn's default device, which in a wgpu build
        // initialises the default wgpu runtime lazily; other tests of this process initialise `wgpu`
        // through the options API, which refuses a runtime already initialised. Initialise it first
        // through the same cache, so that the order of the tests does not matter.
        deepview_net::device::parse_device("wgpu").expect("the default wgpu adapter");
        let cpu = Device::flex();
        assert!(deepview_net::gpu::gpu_kernels(&gpu));
        // Modules on autodiff devices as in training (the optimizer steps their inner tensors).
        let ad = cpu.clone().autodiff();
        let start: Linear =
            deepview_net::rng::seeded_module(&ad, 1, || LinearConfig::new(5, 3).init(&ad));
        let w0 = values(&start);
        let lr = 0.01;
        let mut a = start.clone();
        let mut oa = DeepviewAdam::burn_only().module_optimizer();
        let mut b = start.clone().fork(&gpu.clone().autodiff());
        let mut ob = DeepviewAdam::new().module_optimizer();
        // The trainer's way: the parameters' steps batched into one dispatch.
        let mut d = start.clone().fork(&gpu.clone().autodiff());
        let mut od = DeepviewAdam::new().module_optimizer();
        for k in 0..2 {
            a = oa.step(lr, a, grads(&start, k, &cpu));
            b = ob.step(lr, b, grads(&start, k, &gpu));
            d = with_gradient_scale(1.0, || od.step(lr, d, grads(&start, k, &gpu)));
            for (other, how) in [(&b, "one dispatch each"), (&d, "batched")] {
                let (va, vb) = (values(&a), values(other));
                let e = va
                    .iter()
                    .zip(&vb)
                    .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
                assert!(e < 1e-6, "step {k} ({how}): weights differ by {e}");
            }
        }
        let moved = values(&a)
            .iter()
            .zip(&w0)
            .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(moved > 0.015, "the weights hardly moved ({moved})");
        // The kernel's state, saved and loaded into burn's optimizer on the CPU.
        let bytes = ob.into_bytes().unwrap();
        let mut oc = DeepviewAdam::burn_only()
            .module_optimizer()
            .from_bytes(bytes)
            .unwrap();
        let c = oc.step(lr, b.fork(&cpu.clone().autodiff()), grads(&start, 2, &cpu));
        a = oa.step(lr, a, grads(&start, 2, &cpu));
        let (va, vc) = (values(&a), values(&c));
        let e = va
            .iter()
            .zip(&vc)
            .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(e < 1e-6, "after a resume: weights differ by {e}");
    }
}
