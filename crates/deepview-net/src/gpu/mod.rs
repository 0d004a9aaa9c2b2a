//! Our own GPU kernels (cubecl, any of its runtimes: wgpu, CUDA), hooked into burn with its backend
//! extension mechanism as the CPU kernels are ([`crate::cpu::ops`]): one dispatch where burn's ops take
//! many. So far (`kernels.rs`, one thread per pixel or sample):
//! - the over-composite and its backward (a loop over the planes; the arithmetic of the CPU kernel
//!   [`crate::cpu::renderops::composite_forward`]);
//! - the agreement prior of net 0's input ([`crate::network::agreement_prior_logits`]; no gradient);
//! - homography warps ([`crate::forward::WarpTable::apply`]) that compute their bilinear taps on the
//!   device from the table's per-plane and per-row coefficients (nothing but those uploaded; the plane
//!   sweep and the gradient components write their validity channel in the same dispatch), and their
//!   backward as a gather on the device (each source texel finds its samples through the inverse
//!   homography; no atomics, nothing built on the host);
//! - the state's RGBA (sigmoid, premultiplied colour) and its backward;
//! - the nets' ELU and its backward (in the layout of its input), and their max over views with the
//!   concatenation a stage takes (written channels-last for the convolution that reads it);
//! - Adam's step of a parameter (the training's optimizer on a GPU) and each gradient's share of the
//!   global norm (one dispatch per parameter into one buffer, read once);
//! - the feature loss's input: prediction and target reflect-padded, concatenated and preprocessed for
//!   VGG, and its per-layer L1 terms, with their backward.
//!
//! burn's ops stay the reference: the tests compare each kernel's outputs (and gradients) with them.

use crate::forward::WarpTable;
use burn::backend::TensorMetadata;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, Backend, BackendTensor, Dispatch, DispatchAutodiffContext, DispatchDevice,
    DispatchTensor, DispatchTensorKind, backend_extension,
};
use burn::tensor::{Device, Shape, Tensor, TensorData};
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::ops::permute_nhwc_to_nchw;
use burn_cubecl::tensor::CubeTensor;
use cubecl::calculate_cube_count_elemwise;
use cubecl::prelude::*;
use std::sync::Arc;

/// Custom GPU operations.
#[backend_extension(Cube, Autodiff)]
pub trait GpuOps: Backend {
    /// Over-compositing: `rgba` `[D, 4, h, w]` -> `[D + 1, 4, h, w]` (`A`, `T`; the render), as
    /// [`crate::cpu::ops::KernelOps::composite`].
    fn gpu_composite(rgba: FloatTensor<Self>) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_composite`] at `rgba`, given its output and the output's gradient.
    fn gpu_composite_backward(
        rgba: FloatTensor<Self>,
        out: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The agreement prior's logits ([`crate::network::agreement_prior_logits`]) as a state of
    /// `channels` channels (zeros beyond the RGBA logits): `psv` `[K*D, 4, h, w]` (the views' plane
    /// sweeps, view-major) -> `[D, channels, h, w]`, the depth weights' costs aggregated over `radius`
    /// at `weight` (one launch without aggregation, four with). No gradient (the sweeps are data).
    fn gpu_prior_state(
        psv: FloatTensor<Self>,
        planes: usize,
        temperature: f64,
        channels: usize,
        radius: usize,
        weight: f64,
    ) -> FloatTensor<Self>;

    /// An update net's input: `x` `[K*D, Cv, h, w]` (view-major) with the state `[D, S, h, w]` beside
    /// each view's planes, `[K*D, Cv + S, h, w]`, channels-last, in one dispatch (burn: a concatenation
    /// per view and one over the views).
    fn gpu_append_state(x: FloatTensor<Self>, state: FloatTensor<Self>) -> FloatTensor<Self>;

    /// The gradients of [`GpuOps::gpu_append_state`] at `x` (`cv` channels) and at the state (summed
    /// over the views), given the output's.
    fn gpu_append_state_backward(
        grad: FloatTensor<Self>,
        planes: usize,
        cv: usize,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// A homography warp ([`crate::forward::WarpTable`]: the taps computed on the device from the
    /// table's coefficients, nothing but them uploaded): `src` `[S, C, sh, sw]` (`S` the table's
    /// planes, or 1: broadcast) -> `[planes, C, out_h, out_w]`. Under autodiff a tracked source gets
    /// [`GpuOps::gpu_warp_backward`].
    fn gpu_warp(src: FloatTensor<Self>, table: Arc<WarpTable>) -> FloatTensor<Self>;

    /// A plane sweep ([`crate::forward::plane_sweep_volume`]): [`GpuOps::gpu_warp`] of `src`
    /// `[1, C, sh, sw]` with the validity as channel `C`, `[planes, C + 1, out_h, out_w]`, in one
    /// dispatch. No gradient (the images are data).
    fn gpu_sweep(src: FloatTensor<Self>, table: Arc<WarpTable>) -> FloatTensor<Self>;

    /// The gradient components' warp ([`crate::forward::gradient_components`]) straight from the
    /// view's image `[1, Ci, ..]` and the composite kernel's packed output `[planes + 1, 4, ..]`
    /// ([`GpuOps::gpu_composite`]: `A` and `T` of each plane, the render in the last), warped by one
    /// table into `[planes, Ci + 8, out_h, out_w]`: the image, the render, `A`, `T` and the validity.
    /// Three dispatches, no slices or concatenations; both inputs differentiable.
    fn gpu_components(
        image: FloatTensor<Self>,
        packed: FloatTensor<Self>,
        table: Arc<WarpTable>,
    ) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_components`] at its image (`ci` channels), given the output's.
    fn gpu_components_image_grad(
        grad: FloatTensor<Self>,
        table: Arc<WarpTable>,
        ci: usize,
    ) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_components`] at the packed composite (zero at the render plane's
    /// fourth channel), given the output's (whose image has `ci` channels).
    fn gpu_components_packed_grad(
        grad: FloatTensor<Self>,
        table: Arc<WarpTable>,
        ci: usize,
    ) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_warp`] at its source of `s` planes, given the output's gradient
    /// `[planes, C, out_h, out_w]`: one thread per source texel gathers the samples that read it, found
    /// through the inverse homography and their taps recomputed as the forward computes them (no
    /// atomics, the sums in sample order, as [`WarpTable::transposed`] lists them).
    fn gpu_warp_backward(
        grad: FloatTensor<Self>,
        table: Arc<WarpTable>,
        s: usize,
    ) -> FloatTensor<Self>;

    /// The nets' activation, ELU (alpha 1), or with `relu` VGG's ReLU, of a feature map: one dispatch
    /// forward and one backward (in the layout of its input) where burn's take two to five and more.
    fn gpu_act(x: FloatTensor<Self>, relu: bool) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_act`] from its output and the output's gradient.
    fn gpu_act_backward(
        out: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        relu: bool,
    ) -> FloatTensor<Self>;

    /// A rank-4 tensor with the same values laid out channels-last in memory (the layout burn's GPU
    /// convolutions read their weights in): itself where it is, else one copy. No gradient.
    fn gpu_channels_last(t: FloatTensor<Self>) -> FloatTensor<Self>;

    /// The state's RGBA ([`crate::network::state_to_rgba`]): `[D, S, h, w]` -> `[D, 4, h, w]` in one
    /// dispatch (burn: three slices, a sigmoid, a product and a concatenation, more backward).
    fn gpu_state_rgba(state: FloatTensor<Self>) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_state_rgba`] at the state, given the output's.
    fn gpu_state_rgba_backward(
        state: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The max over views of `f` `[K*D, C, h, w]` (view-major): with `keep`, `[K*D, 2C, h, w]`, the
    /// features with the max beside them (a stage's input), else the max `[D, C, h, w]`; one dispatch
    /// where burn's reshape, max, repeat and concatenation take five, written channels-last (the
    /// next convolution reads it without a layout copy).
    fn gpu_view_max(f: FloatTensor<Self>, views: usize, keep: bool) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_view_max`] at `f`, given the output's (the max's to the first view
    /// holding it).
    fn gpu_view_max_backward(
        f: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        views: usize,
        keep: bool,
    ) -> FloatTensor<Self>;

    /// The feature loss's input: `a` and `b` `[n, C, h, w]` each reflect-padded by `ph` rows and `pw`
    /// columns per side (burn's `PadMode::Reflect`) and concatenated, `[2n, C, h + 2ph, w + 2pw]`,
    /// channels-last, in one dispatch (burn: a fill, slices, flips and slice-assigns per side and per
    /// tensor, then the concatenation, and more backward).
    /// Each value is mapped by `map` on the way (VGG's preprocessing, or the identity).
    fn gpu_reflect_pad_pair(
        a: FloatTensor<Self>,
        b: FloatTensor<Self>,
        ph: usize,
        pw: usize,
        map: ChannelMap,
    ) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_reflect_pad_pair`] at `a` (`second` false) or `b`, given the
    /// output's.
    fn gpu_reflect_pad_pair_backward(
        grad: FloatTensor<Self>,
        second: bool,
        ph: usize,
        pw: usize,
        map: ChannelMap,
    ) -> FloatTensor<Self>;

    /// A 3x3 convolution with stride 1 and padding 1 (every convolution of the nets and of VGG):
    /// `x` `[N, I, h, w]`, `weight` `[O, I, 3, 3]`, `bias` `[O]` -> `[N, O, h, w]`, burn's forward. Its
    /// gradient at `x` is the convolution of the output's gradient with the weights flipped and
    /// transposed ([`GpuOps::gpu_conv3x3_x_backward`]: burn's forward kernel, where burn's own
    /// backward takes its slower transposed convolution); at the weights and bias, burn's.
    fn gpu_conv3x3(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_conv3x3`] at its input, given the output's: two dispatches (the
    /// weights flipped and transposed, channels-last; the convolution).
    fn gpu_conv3x3_x_backward(
        weight: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// [`GpuOps::gpu_conv3x3_x_backward`] for weights that take no gradient (VGG's, in the feature
    /// loss): they cannot change while a tensor holds them, so on cubecl devices each one's flipped and
    /// transposed copy is made once and kept ([`frozen_flips`]) instead of at every backward pass.
    fn gpu_conv3x3_x_backward_frozen(
        weight: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        Self::gpu_conv3x3_x_backward(weight, grad)
    }

    /// A window of `x` `[N, C, h, w]`: rows `y0..y0 + oh` and columns `x0..x0 + ow`, `[N, C, oh, ow]`
    /// in `x`'s layout (channels-last stays so), one dispatch (burn: a slice per axis); under autodiff
    /// its backward pads the gradient back with zeros in one dispatch (burn: a fill and a
    /// slice-assign per axis).
    fn gpu_crop(
        x: FloatTensor<Self>,
        y0: usize,
        x0: usize,
        oh: usize,
        ow: usize,
    ) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_crop`] at an input of `h x w` pixels, given the output's.
    fn gpu_crop_backward(
        grad: FloatTensor<Self>,
        h: usize,
        w: usize,
        y0: usize,
        x0: usize,
    ) -> FloatTensor<Self>;

    /// A convolution's bias gradient given its output's `grad` `[N, C, h, w]` (any layout): `[C]`, in
    /// one dispatch (burn: a contiguous copy and a reduction). No gradient.
    fn gpu_bias_grad(grad: FloatTensor<Self>) -> FloatTensor<Self>;

    /// The feature loss's weighted per-layer term: `[n]`, `scale` times the L1 distance between the
    /// two halves of `f` `[2n, C, h, w]` per example (prediction against target), one dispatch each
    /// way (burn: a subtraction, an absolute value, a layout copy, a sum and a product, and more
    /// backward).
    fn gpu_pair_l1(f: FloatTensor<Self>, scale: f32) -> FloatTensor<Self>;

    /// The gradient of [`GpuOps::gpu_pair_l1`] at `f`, given the output's.
    fn gpu_pair_l1_backward(
        f: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        scale: f32,
    ) -> FloatTensor<Self>;

    /// One Adam step of a parameter (any rank): `(param, moment_1, moment_2)` after the step, in one
    /// dispatch where burn's `Adam` takes a dozen, in the parameter's layout (channels-last for a
    /// rank-4 one, taken on its first step), the gradient read in its own. No gradient (the optimizer
    /// works on inner tensors).
    fn gpu_adam(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        step: AdamStep,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// A per-channel affine map of a padded pair ([`GpuOps::gpu_reflect_pad_pair`]): channel `c` of the
/// output is `v * scale - offset[c]` of the input's channel `c`, or of `C - 1 - c` where `reverse`
/// (RGB <-> BGR). Offsets beyond the input's channels must be zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChannelMap {
    pub scale: f32,
    pub offset: [f32; 3],
    pub reverse: bool,
}

impl ChannelMap {
    /// Values as they are.
    pub const IDENTITY: Self = Self {
        scale: 1.0,
        offset: [0.0; 3],
        reverse: false,
    };
}

/// The scalars of one Adam step ([`GpuOps::gpu_adam`]), as burn's `Adam` computes them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamStep {
    pub beta_1: f32,
    pub beta_2: f32,
    /// `sqrt(1 - beta_2^t) / (1 - beta_1^t)`.
    pub combined: f32,
    /// `epsilon * sqrt(1 - beta_2^t)`.
    pub epsilon: f32,
    pub lr: f32,
    /// The factor of the gradient (global-norm clipping folded into the step: 1 for none).
    pub grad_scale: f32,
}

impl AdamStep {
    /// Step `time` (1 for the first) of Adam with these betas, epsilon and learning rate.
    pub fn new(beta_1: f32, beta_2: f32, epsilon: f32, lr: f64, time: usize) -> Self {
        let time = time as i32;
        let bias_correction2_sqrt = (1.0 - beta_2.powi(time)).sqrt();
        Self {
            beta_1,
            beta_2,
            combined: bias_correction2_sqrt / (1.0 - beta_1.powi(time)),
            epsilon: epsilon * bias_correction2_sqrt,
            lr: lr as f32,
            grad_scale: 1.0,
        }
    }
}

/// [`GpuOps::gpu_adam`] on tensors of a cubecl device: `(param, moment_1, moment_2)` after the step.
pub fn adam<const D: usize>(
    param: Tensor<D>,
    grad: Tensor<D>,
    moment_1: Tensor<D>,
    moment_2: Tensor<D>,
    step: AdamStep,
) -> (Tensor<D>, Tensor<D>, Tensor<D>) {
    let batching = ADAM_BATCH.with(|b| b.borrow().is_some());
    let [param, grad, moment_1, moment_2] =
        [param, grad, moment_1, moment_2].map(Tensor::into_dispatch);
    if batching
        && [&param, &grad, &moment_1, &moment_2]
            .iter()
            .all(|t| plain_cube(t))
    {
        let [p, m, v] = defer_adam([param, grad, moment_1, moment_2].map(cube_float), step)
            .map(|t| Tensor::from_dispatch(plain_dispatch(t)));
        return (p, m, v);
    }
    let (p, m, v) = <Dispatch as GpuOps>::gpu_adam(param, grad, moment_1, moment_2, step);
    (
        Tensor::from_dispatch(p),
        Tensor::from_dispatch(m),
        Tensor::from_dispatch(v),
    )
}

/// [`GpuOps::gpu_reflect_pad_pair`]: `a` and `b` `[n, C, h, w]` reflect-padded by `ph` rows and `pw`
/// columns per side, concatenated (`a` first) and mapped by `map`, with gradients to both.
pub fn reflect_pad_pair(
    a: Tensor<4>,
    b: Tensor<4>,
    ph: usize,
    pw: usize,
    map: ChannelMap,
) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_reflect_pad_pair(
        a.into_dispatch(),
        b.into_dispatch(),
        ph,
        pw,
        map,
    ))
}

/// [`GpuOps::gpu_crop`] on a cubecl device: rows `y0..y0 + h` and columns `x0..x0 + w` of `x`.
pub(crate) fn crop(x: Tensor<4>, y0: usize, x0: usize, h: usize, w: usize) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_crop(
        x.into_dispatch(),
        y0,
        x0,
        h,
        w,
    ))
}

/// [`GpuOps::gpu_conv3x3`] on a cubecl device: a 3x3 convolution, stride 1, padding 1, with bias.
pub(crate) fn conv3x3(x: Tensor<4>, weight: Tensor<4>, bias: Tensor<1>) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_conv3x3(
        x.into_dispatch(),
        weight.into_dispatch(),
        bias.into_dispatch(),
    ))
}

/// The options of [`GpuOps::gpu_conv3x3`]'s convolutions: stride 1, padding 1.
fn same3x3() -> burn::backend::ops::ConvOptions<2> {
    burn::backend::ops::ConvOptions::new([1, 1], [1, 1], [1, 1], 1)
}

/// [`GpuOps::gpu_pair_l1`]: per example, `scale` times the L1 distance between the two halves of
/// `f` `[2n, ..]`.
pub fn pair_l1(f: Tensor<4>, scale: f32) -> Tensor<1> {
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_pair_l1(f.into_dispatch(), scale))
}

/// An Adam step taken inside [`adam_batch`], waiting for its launch: the parameter, its gradient and
/// moments, and the outputs already handed back.
struct PendingAdam {
    inputs: [CubeTensor; 4],
    outputs: [CubeTensor; 3],
    step: AdamStep,
}

/// A 3x3 convolution's weights `[O, I, 3, 3]` flipped and transposed, `[I, O, 3, 3]` channels-last:
/// the weights of the convolution that gives its input's gradient. One dispatch.
fn flip_transpose(weight: CubeTensor) -> CubeTensor {
    let [o, i, kh, kw] = weight.meta.shape().dims::<4>();
    assert_eq!([kh, kw], [3, 3], "a 3x3 convolution");
    let flipped = permute_nhwc_to_nchw(empty_shaped(&weight, Shape::new([i, kh, kw, o])));
    let (count, dim) = grid(&weight, o * i * kh * kw);
    kernels::flip_transpose_kernel::launch(
        &flipped.client,
        count,
        dim,
        weight.into_tensor_arg(),
        flipped.clone().into_tensor_arg(),
    );
    flipped
}

/// Which weights a kept flip belongs to: the memory (cubecl never reuses a memory id, and the kept
/// entry holds the weights, so their memory is neither freed nor written in place while it is kept:
/// burn writes in place only into a tensor nobody else holds) and where the weights lie in it.
#[derive(Clone, Debug, PartialEq, Eq)]
struct FrozenKey {
    memory: usize,
    offset: (Option<u64>, Option<u64>),
    shape: Vec<usize>,
    strides: Vec<usize>,
}

impl FrozenKey {
    fn of(t: &CubeTensor) -> Self {
        Self {
            memory: t.handle.memory.descriptor().id.value,
            offset: (t.handle.offset_start, t.handle.offset_end),
            shape: t.meta.shape().to_vec(),
            strides: t.meta.strides().to_vec(),
        }
    }
}

/// A kept flip ([`GpuOps::gpu_conv3x3_x_backward_frozen`]) and the weights it was made from.
struct FrozenFlip {
    key: FrozenKey,
    _weight: CubeTensor,
    flipped: CubeTensor,
}

/// How many flips of frozen weights a thread keeps (VGG's feature loss has 7 convolutions; the oldest
/// goes first).
const FROZEN_FLIPS_KEPT: usize = 32;

thread_local! {
    /// The flips of frozen weights kept on this thread (each replica's thread has its own device).
    static FROZEN_FLIPS: std::cell::RefCell<Vec<FrozenFlip>> =
        const { std::cell::RefCell::new(Vec::new()) };
    /// How many backward passes this thread took a kept flip in (tests).
    static FROZEN_FLIP_HITS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

/// How many frozen convolutions' backward passes on this thread used a kept flip
/// ([`GpuOps::gpu_conv3x3_x_backward_frozen`]).
pub fn frozen_flip_hits() -> u64 {
    FROZEN_FLIP_HITS.with(|h| h.get())
}

thread_local! {
    /// The Adam steps of the [`adam_batch`] running on this thread (`None` outside one).
    static ADAM_BATCH: std::cell::RefCell<Option<Vec<PendingAdam>>> =
        const { std::cell::RefCell::new(None) };
}

/// Run `f` with the Adam steps it takes through [`adam`] on cubecl devices gathered and launched
/// together when it returns: one dispatch for as many parameters as the device binds (7 buffers
/// each, at most 8 parameters) where each would take its own. What [`adam`] hands back inside `f` is
/// written by that launch, so `f` must not read it (an optimizer's step over a module only stores
/// it). Launches happen in submission order, so everything after `f` sees the stepped values.
pub fn adam_batch<R>(f: impl FnOnce() -> R) -> R {
    /// Ends the batch even if `f` panics (its steps are then dropped unlaunched).
    struct Batch;
    impl Drop for Batch {
        fn drop(&mut self) {
            ADAM_BATCH.with(|b| b.borrow_mut().take());
        }
    }
    ADAM_BATCH.with(|b| *b.borrow_mut() = Some(Vec::new()));
    let batch = Batch;
    let r = f();
    let pending = ADAM_BATCH
        .with(|b| b.borrow_mut().take())
        .unwrap_or_default();
    drop(batch);
    launch_adam_many(pending);
    r
}

/// [`adam`] inside [`adam_batch`]: the parameter laid out as [`GpuOps::gpu_adam`] lays it out, the
/// outputs allocated and handed back, the step queued.
fn defer_adam(inputs: [CubeTensor; 4], step: AdamStep) -> [CubeTensor; 3] {
    let (inputs, outputs) = adam_prepare(inputs);
    ADAM_BATCH.with(|b| {
        b.borrow_mut()
            .as_mut()
            .expect("inside adam_batch")
            .push(PendingAdam {
                inputs,
                outputs: outputs.clone(),
                step,
            })
    });
    outputs
}

/// An Adam step's `[param, grad, moment_1, moment_2]` laid out for the kernel, and its outputs
/// allocated: element-wise in the parameter's layout, channels-last for a convolution's weights (the
/// layout burn's convolutions read them in; they take it on their first step and keep it), the
/// moments in it too, the gradient read through its strides (burn's weight gradient comes with the
/// output channels fastest, and a parameter in that layout would be copied by every convolution).
fn adam_prepare(inputs: [CubeTensor; 4]) -> ([CubeTensor; 4], [CubeTensor; 3]) {
    let [param, grad, moment_1, moment_2] = inputs;
    let param = if param.meta.num_dims() == 4 {
        <CubeBackend as GpuOps>::gpu_channels_last(param)
    } else {
        dense(param)
    };
    let [moment_1, moment_2] = [moment_1, moment_2].map(|t| like(t, &param));
    let outputs = [(); 3].map(|_| empty_same_layout(&param));
    ([param, grad, moment_1, moment_2], outputs)
}

/// Launch the queued Adam steps: consecutive ones with the same scalars together, as many per
/// dispatch as the device binds.
fn launch_adam_many(pending: Vec<PendingAdam>) {
    let Some(first) = pending.first() else {
        return;
    };
    let per_launch =
        (first.inputs[0].client.properties().hardware.max_bindings as usize / 7).clamp(1, 8);
    let mut rest = pending.as_slice();
    while let Some(head) = rest.first() {
        let same = rest
            .iter()
            .take(per_launch)
            .take_while(|p| p.step == head.step)
            .count();
        let (chunk, tail) = rest.split_at(same);
        rest = tail;
        let mut ins: [SequenceArg<OwnedTensor<f32>>; 4] = Default::default();
        let mut outs: [SequenceArg<OwnedTensor<f32>>; 3] = Default::default();
        let mut most = 1;
        for p in chunk {
            most = most.max(p.inputs[0].meta.shape().num_elements());
            for (seq, t) in ins.iter_mut().zip(&p.inputs) {
                seq.push(t.clone().into_tensor_arg());
            }
            for (seq, t) in outs.iter_mut().zip(&p.outputs) {
                seq.push(t.clone().into_tensor_arg());
            }
        }
        let [ps, gs, ms, vs] = ins;
        let [p_outs, m_outs, v_outs] = outs;
        let step = head.step;
        let client = &head.inputs[0].client;
        kernels::adam_many_kernel::launch(
            client,
            CubeCount::Static(most.div_ceil(256) as u32, chunk.len() as u32, 1),
            CubeDim::new_1d(256),
            ps,
            gs,
            ms,
            vs,
            p_outs,
            m_outs,
            v_outs,
            step.beta_1,
            1.0 - step.beta_1,
            step.beta_2,
            1.0 - step.beta_2,
            step.combined,
            step.epsilon,
            step.lr,
            step.grad_scale,
        );
    }
}

/// Whether `t` is a float tensor of a cubecl device outside autodiff (what [`cube_float`] unwraps and
/// [`plain_dispatch`] wraps back unchanged).
fn plain_cube(t: &DispatchTensor) -> bool {
    matches!(
        (&t.kind, &t.autodiff),
        (
            DispatchTensorKind::Cube(BackendTensor::Float(_)),
            DispatchAutodiffContext::Disabled
        )
    )
}

/// A cubecl float tensor as a dispatch tensor outside autodiff.
fn plain_dispatch(t: CubeTensor) -> DispatchTensor {
    DispatchTensor {
        kind: DispatchTensorKind::Cube(BackendTensor::Float(t)),
        autodiff: DispatchAutodiffContext::Disabled,
    }
}

/// The squared global norm of `tensors` (any ranks, on one cubecl device): each tensor's f32 sum of
/// squares into a slot of one buffer (one dispatch for as many tensors as the device binds at once)
/// and one read of that buffer, the per-tensor sums added in f64 as the CPU path adds them.
pub fn squared_norms(tensors: Vec<burn::tensor::DispatchTensor>, device: &Device) -> f64 {
    if tensors.is_empty() {
        return 0.0;
    }
    // Several tensors per dispatch, which burn's backend extensions cannot take (no `Vec` of
    // tensors): the cubecl tensors are taken out of their dispatch wrappers here.
    let acc = cube_float(Tensor::<1>::zeros([tensors.len()], device).into_dispatch());
    let acc = sum_squares_into(tensors.into_iter().map(cube_float).collect(), acc, 0);
    let sums = Tensor::<1>::from_dispatch(plain_dispatch(acc)).into_data();
    sums.iter::<f32>().map(f64::from).sum()
}

/// The sum of the squares of each of `ts`'s elements (dense, any ranks) written into elements
/// `first..` of `acc` (a contiguous rank-1 tensor): one dispatch for as many tensors as the device
/// binds (at most 32); returns `acc`.
fn sum_squares_into(ts: Vec<CubeTensor>, acc: CubeTensor, first: usize) -> CubeTensor {
    assert!(
        acc.meta.num_dims() == 1 && first + ts.len() <= acc.meta.shape()[0] && acc.is_contiguous(),
        "slots of a contiguous rank-1 tensor"
    );
    // One buffer of the device's bindings is `acc`; at most 32 tensors per launch bounds the
    // unrolled kernel (each count of tensors and their ranks is one compiled variant).
    let per_launch = (acc.client.properties().hardware.max_bindings as usize)
        .saturating_sub(1)
        .clamp(1, 32);
    let mut slot = first;
    let mut ts = ts.into_iter().map(dense).peekable();
    while ts.peek().is_some() {
        let mut seq = SequenceArg::<OwnedTensor<f32>>::new();
        let mut count = 0;
        for t in ts.by_ref().take(per_launch) {
            seq.push(t.into_tensor_arg());
            count += 1;
        }
        kernels::sum_squares_many_kernel::launch(
            &acc.client,
            CubeCount::Static(count as u32, 1, 1),
            CubeDim::new_1d(256),
            seq,
            acc.clone().into_tensor_arg(),
            slot as u32,
        );
        slot += count;
    }
    acc
}

/// The cubecl tensor of a float tensor of a cubecl device (an autodiff one's inner tensor).
fn cube_float(t: DispatchTensor) -> CubeTensor {
    fn inner(kind: DispatchTensorKind) -> CubeTensor {
        match kind {
            DispatchTensorKind::Cube(BackendTensor::Float(t)) => t,
            DispatchTensorKind::Autodiff(kind) => inner(*kind),
            other => panic!("a float tensor of a cubecl device, got {other:?}"),
        }
    }
    inner(t.kind)
}

/// Whether tensors on `device` take our GPU kernels: a cubecl device (with or without autodiff),
/// unless `deepview --engine burn` turned the custom kernels off.
pub fn gpu_kernels(device: &Device) -> bool {
    !crate::cpu::ops::burn_ops()
        && matches!(
            device.clone().inner().as_dispatch(),
            DispatchDevice::Cube(_)
        )
}

/// Whether the fused prior kernel computes the prior of `aggregation`: not with semi-global matching,
/// a census term, the leave-one-out variance or the sample variance (those take burn's ops,
/// [`agreement_prior_logits`]).
///
/// [`agreement_prior_logits`]: crate::network::agreement_prior_logits
pub fn prior_is_fused(aggregation: deepview_mpi::agreement::Aggregation) -> bool {
    aggregation.smoothing.is_none()
        && aggregation.census.is_none()
        && aggregation.leave_one_out.is_none()
        && !aggregation.sample_variance
}

/// [`GpuOps::gpu_composite`] on a tensor of a cubecl device.
pub(crate) fn composite(rgba: Tensor<4>) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_composite(rgba.into_dispatch()))
}

/// [`GpuOps::gpu_prior_state`] (RGBA only) of the views' plane sweeps (each `[D, 4, h, w]`) on a
/// cubecl device.
pub(crate) fn prior(
    per_view: &[Tensor<4>],
    temperature: f64,
    aggregation: deepview_mpi::agreement::Aggregation,
) -> Tensor<4> {
    let d = per_view[0].dims()[0];
    let psv = Tensor::cat(per_view.to_vec(), 0);
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_prior_state(
        psv.into_dispatch(),
        d,
        temperature,
        4,
        aggregation.radius,
        aggregation.weight,
    ))
}

/// [`GpuOps::gpu_warp`] of `src` by `table` on a cubecl device (with its backward where `src` is
/// tracked).
pub(crate) fn warp(table: &WarpTable, src: Tensor<4>) -> Tensor<4> {
    let out = <Dispatch as GpuOps>::gpu_warp(src.into_dispatch(), Arc::new(table.clone()));
    Tensor::from_dispatch(out)
}

/// [`GpuOps::gpu_sweep`]: the plane sweep of `src` `[1, C, sh, sw]` with its validity channel.
pub(crate) fn sweep(table: &WarpTable, src: Tensor<4>) -> Tensor<4> {
    let out = <Dispatch as GpuOps>::gpu_sweep(src.into_dispatch(), Arc::new(table.clone()));
    Tensor::from_dispatch(out)
}

/// [`GpuOps::gpu_components`]: `image` `[1, Ci, ..]` and the composite's `packed` output warped by
/// `table`: `[D, Ci + 8, ..]`.
pub(crate) fn components(table: &WarpTable, image: Tensor<4>, packed: Tensor<4>) -> Tensor<4> {
    let out = <Dispatch as GpuOps>::gpu_components(
        image.into_dispatch(),
        packed.into_dispatch(),
        Arc::new(table.clone()),
    );
    Tensor::from_dispatch(out)
}

/// A net's input on a cubecl device: the views' inputs (each `[D, C, h, w]`) concatenated view-major,
/// with the state beside each view's planes ([`GpuOps::gpu_append_state`]) where given; and the
/// agreement prior of the views' plane sweeps as a state of `channels` channels where asked.
pub(crate) fn net_input(
    per_view: Vec<Tensor<4>>,
    state: Option<Tensor<4>>,
    prior: Option<(f64, usize, deepview_mpi::agreement::Aggregation)>,
) -> (Tensor<4>, Option<Tensor<4>>) {
    let d = per_view[0].dims()[0];
    let views = Tensor::cat(per_view, 0);
    let prior = prior.map(|(temperature, channels, aggregation)| {
        Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_prior_state(
            views.clone().into_dispatch(),
            d,
            temperature,
            channels,
            aggregation.radius,
            aggregation.weight,
        ))
    });
    let x = match state {
        Some(s) => Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_append_state(
            views.into_dispatch(),
            s.into_dispatch(),
        )),
        None => views,
    };
    (x, prior)
}

/// `module` with its rank-4 float parameters (convolution weights) laid out channels-last in memory
/// where they are on a cubecl device: burn's GPU convolutions read weights in that layout, and would copy
/// them into it at every call (frozen or inference weights; trained ones also take it in Adam's first
/// step, [`GpuOps::gpu_adam`]). Values, ids and gradient requirements are kept.
pub fn channels_last_weights<M: burn::module::Module>(module: M) -> M {
    struct Mapper;
    impl burn::module::ModuleMapper for Mapper {
        fn map_float<const D: usize>(
            &mut self,
            param: burn::module::Param<Tensor<D>>,
        ) -> burn::module::Param<Tensor<D>> {
            if D != 4 || !gpu_kernels(&param.val().device()) {
                return param;
            }
            param.map(|t| {
                let grad = t.is_require_grad();
                let t = <Dispatch as GpuOps>::gpu_channels_last(t.into_dispatch());
                Tensor::<D>::from_dispatch(t).set_require_grad(grad)
            })
        }
    }
    module.map(&mut Mapper)
}

/// [`GpuOps::gpu_state_rgba`] on a cubecl device.
pub(crate) fn state_rgba(state: Tensor<4>) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_state_rgba(state.into_dispatch()))
}

/// [`GpuOps::gpu_view_max`] on a cubecl device: with `keep` the features and their max over views
/// `[K*D, 2C, h, w]`, else the max `[D, C, h, w]`.
pub(crate) fn view_max(f: Tensor<4>, views: usize, keep: bool) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_view_max(
        f.into_dispatch(),
        views,
        keep,
    ))
}

/// ELU ([`GpuOps::gpu_act`]) on a cubecl device.
pub(crate) fn elu(x: Tensor<4>) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_act(x.into_dispatch(), false))
}

/// ReLU ([`GpuOps::gpu_act`]) on a cubecl device.
pub(crate) fn relu(x: Tensor<4>) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as GpuOps>::gpu_act(x.into_dispatch(), true))
}

/// `values` as a 1-d f32 tensor on `t`'s device.
fn upload_f32(t: &CubeTensor, values: Vec<f32>) -> CubeTensor {
    let n = values.len();
    CubeBackend::float_from_data(TensorData::new(values, [n]), &t.device)
}

/// What a warp reads of its source tensor: one fixed plane for every output plane (else plane `d` for
/// plane `d`, or a single-plane source broadcast), and `c` channels from `c0`.
#[derive(Clone, Copy)]
struct Source {
    plane: Option<usize>,
    c0: usize,
    c: usize,
}

impl Source {
    /// The first `c` channels, plane by plane (or broadcast).
    fn all(c: usize) -> Self {
        Self {
            plane: None,
            c0: 0,
            c,
        }
    }
}

/// [`kernels::warp_hom_kernel`]: `from` of `src` warped by `table` (its coefficients uploaded as
/// `coef`) into channels `c0..` of `out`, and the validity into channel `valid` where given.
fn warp_into(
    table: &WarpTable,
    coef: &CubeTensor,
    src: CubeTensor,
    from: Source,
    out: &CubeTensor,
    c0: usize,
    valid: Option<usize>,
) {
    let f = table.frames();
    let (count, dim) = grid(out, table.planes * table.out_h * table.out_w);
    kernels::warp_hom_kernel::launch(
        &out.client,
        count,
        dim,
        src.into_tensor_arg(),
        coef.clone().into_tensor_arg(),
        out.clone().into_tensor_arg(),
        from.plane.map_or(u32::MAX, |p| p as u32),
        from.c0 as u32,
        from.c as u32,
        c0 as u32,
        valid.map_or(u32::MAX, |v| v as u32),
        f.out_origin.0 as u32,
        f.src_full.0 as u32,
        f.src_full.1 as u32,
        f.src_origin.0 as i32,
        f.src_origin.1 as i32,
    );
}

/// What [`warp_backward_into`] reads of `table`, uploaded to `t`'s device: its coefficients and its
/// inverse homographies (one upload for every backward launch of one table).
fn backward_tables(table: &WarpTable, t: &CubeTensor) -> (CubeTensor, CubeTensor) {
    (
        upload_f32(t, table.coefficients()),
        upload_f32(t, table.inverse_coefficients()),
    )
}

/// [`kernels::warp_backward_kernel`]: the gradient of a warp of `s` source planes by `table` from
/// channels `grad_c0..grad_c0 + c` of `grad`, into planes `p0..p0 + s` and channels `c0..c0 + c` of
/// `gsrc`, computed on the device (the table's coefficients and inverse homographies uploaded).
#[allow(clippy::too_many_arguments)]
fn warp_backward_into(
    table: &WarpTable,
    (coef, inv): &(CubeTensor, CubeTensor),
    s: usize,
    grad: &CubeTensor,
    grad_c0: usize,
    c: usize,
    gsrc: &CubeTensor,
    p0: usize,
    c0: usize,
    zeros: usize,
) {
    let f = table.frames();
    let (count, dim) = grid(grad, s * table.src_h * table.src_w);
    kernels::warp_backward_kernel::launch(
        &gsrc.client,
        count,
        dim,
        grad.clone().into_tensor_arg(),
        coef.clone().into_tensor_arg(),
        inv.clone().into_tensor_arg(),
        gsrc.clone().into_tensor_arg(),
        f.out_origin.0 as i32,
        f.out_origin.1 as i32,
        f.src_full.0 as i32,
        f.src_full.1 as i32,
        f.src_origin.0 as i32,
        f.src_origin.1 as i32,
        s as u32,
        c as u32,
        grad_c0 as u32,
        p0 as u32,
        c0 as u32,
        zeros as u32,
    );
}

/// One thread for each of `n` items on `t`'s device.
fn grid(t: &CubeTensor, n: usize) -> (CubeCount, CubeDim) {
    let dim = CubeDim::new(&t.client, n);
    (calculate_cube_count_elemwise(&t.client, n, dim), dim)
}

/// Threads over the `h x w` pixels.
fn pixel_grid(t: &CubeTensor) -> (CubeCount, CubeDim) {
    let [_, _, h, w] = t.meta.shape().dims::<4>();
    grid(t, h * w)
}

/// Whether `t`'s elements fill the start of its buffer without gaps, in some order of its axes (a contiguous tensor, or
/// a permuted one such as a convolution's channels-last output): element-wise kernels may then run
/// over the buffer.
fn is_dense(t: &CubeTensor) -> bool {
    let (shape, strides) = (t.meta.shape(), t.meta.strides());
    let n = shape.num_elements();
    // The buffer may be longer (allocations are padded): the elements must span exactly its first `n`.
    let span = 1 + shape
        .iter()
        .zip(strides.iter())
        .map(|(&d, &s)| d.saturating_sub(1) * s)
        .sum::<usize>();
    n > 0 && span == n && t.is_nonoverlapping() && t.handle.size() as usize >= n * t.dtype.size()
}

/// `t` itself where [`is_dense`], else a contiguous copy.
fn dense(t: CubeTensor) -> CubeTensor {
    if is_dense(&t) { t } else { into_contiguous(t) }
}

/// `t` in the dense layout of `reference` (same shape): itself where it has it, else a copy
/// (rank 4; tensors of other ranks are contiguous, as is every dense one of them).
fn like(t: CubeTensor, reference: &CubeTensor) -> CubeTensor {
    if is_dense(&t) && t.meta.strides() == reference.meta.strides() {
        return t;
    }
    if t.meta.num_dims() != 4 {
        // Dense tensors of rank below 2 are contiguous; others of these ranks are made so.
        assert!(
            reference.is_contiguous(),
            "a rank-{} layout",
            t.meta.num_dims()
        );
        return into_contiguous(t);
    }
    let dims = t.meta.shape().dims::<4>();
    let out = empty_same_layout(reference);
    let (count, dim) = grid(&t, dims.iter().product());
    kernels::relayout_kernel::launch(
        &out.client,
        count,
        dim,
        t.into_tensor_arg(),
        out.clone().into_tensor_arg(),
    );
    out
}

/// An uninitialised tensor with the shape and the strides of the dense tensor `t` ([`is_dense`]).
fn empty_same_layout(t: &CubeTensor) -> CubeTensor {
    let mut out = empty_shaped(t, t.meta.shape().clone());
    if out.meta.strides() != t.meta.strides() {
        assert!(
            out.handle.size() as usize >= t.meta.shape().num_elements() * t.dtype.size(),
            "an allocation of the tensor's elements"
        );
        out.meta = t.meta.clone();
    }
    out
}

/// An uninitialised tensor of `dims` on `t`'s device, of its dtype.
fn empty_like(t: &CubeTensor, dims: [usize; 4]) -> CubeTensor {
    empty_shaped(t, Shape::new(dims))
}

/// An uninitialised `dims` tensor on `t`'s device laid out as `t` is: channels-last where `t` is
/// (a convolution's output), else contiguous.
fn empty_in_layout(t: &CubeTensor, dims: [usize; 4]) -> CubeTensor {
    let [n, c, h, w] = t.meta.shape().dims::<4>();
    if is_dense(t) && t.meta.strides()[..] == [h * w * c, 1, w * c, c] {
        let [n, c, h, w] = dims;
        return permute_nhwc_to_nchw(empty_shaped(t, Shape::new([n, h, w, c])));
    }
    let _ = n;
    empty_like(t, dims)
}

/// An uninitialised tensor of any `shape` on `t`'s device, of its dtype.
fn empty_shaped(t: &CubeTensor, shape: Shape) -> CubeTensor {
    empty_device_dtype(t.client.clone(), t.device.clone(), shape, t.dtype)
}

impl GpuOps for CubeBackend {
    fn gpu_composite(rgba: CubeTensor) -> CubeTensor {
        let [d, c, h, w] = rgba.meta.shape().dims::<4>();
        assert_eq!(c, 4, "composite takes RGBA planes");
        let out = empty_like(&rgba, [d + 1, 4, h, w]);
        let (count, dim) = pixel_grid(&rgba);
        kernels::composite_kernel::launch(
            &out.client,
            count,
            dim,
            rgba.into_tensor_arg(),
            out.clone().into_tensor_arg(),
        );
        out
    }

    fn gpu_composite_backward(rgba: CubeTensor, out: CubeTensor, grad: CubeTensor) -> CubeTensor {
        let [d, _, h, w] = rgba.meta.shape().dims::<4>();
        let gin = empty_like(&rgba, [d, 4, h, w]);
        let (count, dim) = pixel_grid(&rgba);
        kernels::composite_backward_kernel::launch(
            &gin.client,
            count,
            dim,
            rgba.into_tensor_arg(),
            out.into_tensor_arg(),
            grad.into_tensor_arg(),
            gin.clone().into_tensor_arg(),
        );
        gin
    }

    fn gpu_append_state(x: CubeTensor, state: CubeTensor) -> CubeTensor {
        let [kd, cv, h, w] = x.meta.shape().dims::<4>();
        let sc = state.meta.shape().dims::<4>()[1];
        let out = permute_nhwc_to_nchw(empty_shaped(&x, Shape::new([kd, h, w, cv + sc])));
        let (count, dim) = grid(&x, kd * h * w * (cv + sc));
        kernels::append_state_kernel::launch(
            &out.client,
            count,
            dim,
            x.into_tensor_arg(),
            state.into_tensor_arg(),
            out.clone().into_tensor_arg(),
        );
        out
    }

    fn gpu_append_state_backward(
        grad: CubeTensor,
        planes: usize,
        cv: usize,
    ) -> (CubeTensor, CubeTensor) {
        let [kd, ct, h, w] = grad.meta.shape().dims::<4>();
        let gx = permute_nhwc_to_nchw(empty_shaped(&grad, Shape::new([kd, h, w, cv])));
        let gs = permute_nhwc_to_nchw(empty_shaped(&grad, Shape::new([planes, h, w, ct - cv])));
        let (count, dim) = grid(&grad, planes * h * w * ct);
        kernels::append_state_backward_kernel::launch(
            &gx.client,
            count,
            dim,
            grad.into_tensor_arg(),
            gx.clone().into_tensor_arg(),
            gs.clone().into_tensor_arg(),
        );
        (gx, gs)
    }

    fn gpu_prior_state(
        psv: CubeTensor,
        planes: usize,
        temperature: f64,
        channels: usize,
        radius: usize,
        weight: f64,
    ) -> CubeTensor {
        let [_, c, h, w] = psv.meta.shape().dims::<4>();
        assert_eq!(c, 4, "the prior takes RGB and validity");
        assert!(channels >= 4, "a state has at least RGBA");
        let out = empty_like(&psv, [planes, channels, h, w]);
        let (count, dim) = pixel_grid(&psv);
        let (t, single, eps) = (
            temperature as f32,
            deepview_mpi::agreement::SINGLE_VIEW_VARIANCE as f32,
            deepview_mpi::agreement::LOGIT_EPS as f32,
        );
        let aggregation = deepview_mpi::agreement::Aggregation::window(radius, weight);
        if !aggregation.is_active() {
            kernels::prior_kernel::launch(
                &out.client,
                count,
                dim,
                psv.into_tensor_arg(),
                out.clone().into_tensor_arg(),
                t,
                single,
                eps,
            );
            return out;
        }
        // Costs, their aggregation (separable: the windows' row sums and counts, then their column
        // sums and the blend into a second cost buffer), then the alphas.
        let lg = empty_like(&psv, [planes, 1, h, w]);
        let rows = empty_like(&psv, [planes, 2, h, w]);
        let agg = empty_like(&psv, [planes, 1, h, w]);
        kernels::prior_cost_kernel::launch(
            &out.client,
            count.clone(),
            dim,
            psv.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            lg.clone().into_tensor_arg(),
            t,
            single,
            eps,
        );
        let (all, all_dim) = grid(&lg, planes * h * w);
        kernels::aggregate_rows_kernel::launch(
            &out.client,
            all.clone(),
            all_dim,
            lg.clone().into_tensor_arg(),
            rows.clone().into_tensor_arg(),
            radius as u32,
        );
        kernels::aggregate_cols_kernel::launch(
            &out.client,
            all,
            all_dim,
            lg.into_tensor_arg(),
            rows.into_tensor_arg(),
            agg.clone().into_tensor_arg(),
            radius as u32,
            weight as f32,
        );
        kernels::prior_alpha_kernel::launch(
            &out.client,
            count,
            dim,
            agg.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            eps,
        );
        out
    }

    fn gpu_warp(src: CubeTensor, table: Arc<WarpTable>) -> CubeTensor {
        let [_, c, _, _] = src.meta.shape().dims::<4>();
        let out = empty_like(&src, [table.planes, c, table.out_h, table.out_w]);
        let coef = upload_f32(&src, table.coefficients());
        let from = Source::all(c);
        warp_into(&table, &coef, src, from, &out, 0, None);
        out
    }

    fn gpu_sweep(src: CubeTensor, table: Arc<WarpTable>) -> CubeTensor {
        let [_, c, _, _] = src.meta.shape().dims::<4>();
        let out = empty_like(&src, [table.planes, c + 1, table.out_h, table.out_w]);
        let coef = upload_f32(&src, table.coefficients());
        warp_into(&table, &coef, src, Source::all(c), &out, 0, Some(c));
        out
    }

    fn gpu_components(image: CubeTensor, packed: CubeTensor, table: Arc<WarpTable>) -> CubeTensor {
        let ci = image.meta.shape().dims::<4>()[1];
        let [d1, pc, _, _] = packed.meta.shape().dims::<4>();
        assert!(
            d1 == table.planes + 1 && pc == 4,
            "components take the composite's packed output"
        );
        let dims = [table.planes, ci + 8, table.out_h, table.out_w];
        let out = empty_like(&image, dims);
        let coef = upload_f32(&image, table.coefficients());
        warp_into(&table, &coef, image, Source::all(ci), &out, 0, None);
        // The render (plane D's colour) into every plane, then each plane's A and T.
        let render = Source {
            plane: Some(table.planes),
            c0: 0,
            c: 3,
        };
        warp_into(&table, &coef, packed.clone(), render, &out, ci, None);
        let planes = Source::all(4);
        warp_into(&table, &coef, packed, planes, &out, ci + 3, Some(ci + 7));
        out
    }

    fn gpu_components_image_grad(grad: CubeTensor, table: Arc<WarpTable>, ci: usize) -> CubeTensor {
        let gi = empty_like(&grad, [1, ci, table.src_h, table.src_w]);
        let tables = backward_tables(&table, &grad);
        warp_backward_into(&table, &tables, 1, &grad, 0, ci, &gi, 0, 0, 0);
        gi
    }

    fn gpu_components_packed_grad(
        grad: CubeTensor,
        table: Arc<WarpTable>,
        ci: usize,
    ) -> CubeTensor {
        let (d, sh, sw) = (table.planes, table.src_h, table.src_w);
        // Every texel of the packed gradient is written: the render plane's fourth channel (read by
        // nothing) as 0.
        let gp = empty_like(&grad, [d + 1, 4, sh, sw]);
        let tables = backward_tables(&table, &grad);
        warp_backward_into(&table, &tables, 1, &grad, ci, 3, &gp, d, 0, 1);
        warp_backward_into(&table, &tables, d, &grad, ci + 3, 4, &gp, 0, 0, 0);
        gp
    }

    fn gpu_warp_backward(grad: CubeTensor, table: Arc<WarpTable>, s: usize) -> CubeTensor {
        let [_, c, _, _] = grad.meta.shape().dims::<4>();
        let gsrc = empty_like(&grad, [s, c, table.src_h, table.src_w]);
        let tables = backward_tables(&table, &grad);
        warp_backward_into(&table, &tables, s, &grad, 0, c, &gsrc, 0, 0, 0);
        gsrc
    }

    fn gpu_act(x: CubeTensor, relu: bool) -> CubeTensor {
        // Element-wise over the buffer, in the input's layout: a convolution's output (channels
        // last in memory) stays so, and the next convolution reads it without a layout copy.
        let x = dense(x);
        let out = empty_same_layout(&x);
        let (count, dim) = grid(&x, x.meta.shape().num_elements());
        kernels::act_kernel::launch(
            &out.client,
            count,
            dim,
            x.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            relu as u32,
        );
        out
    }

    fn gpu_channels_last(t: CubeTensor) -> CubeTensor {
        let [n, c, h, w] = t.meta.shape().dims::<4>();
        // Already so: nothing allocated.
        if is_dense(&t) && t.meta.strides()[..] == [h * w * c, 1, w * c, c] {
            return t;
        }
        let reference = permute_nhwc_to_nchw(empty_shaped(&t, Shape::new([n, h, w, c])));
        like(t, &reference)
    }

    fn gpu_state_rgba(state: CubeTensor) -> CubeTensor {
        let [d, _, h, w] = state.meta.shape().dims::<4>();
        let out = empty_like(&state, [d, 4, h, w]);
        let (count, dim) = grid(&state, d * h * w);
        kernels::state_rgba_kernel::launch(
            &out.client,
            count,
            dim,
            state.into_tensor_arg(),
            out.clone().into_tensor_arg(),
        );
        out
    }

    fn gpu_state_rgba_backward(state: CubeTensor, grad: CubeTensor) -> CubeTensor {
        let [d, sc, h, w] = state.meta.shape().dims::<4>();
        let gin = empty_like(&state, [d, sc, h, w]);
        let (count, dim) = grid(&state, d * h * w);
        kernels::state_rgba_backward_kernel::launch(
            &gin.client,
            count,
            dim,
            state.into_tensor_arg(),
            grad.into_tensor_arg(),
            gin.clone().into_tensor_arg(),
        );
        gin
    }

    fn gpu_view_max(f: CubeTensor, views: usize, keep: bool) -> CubeTensor {
        let [kd, c, h, w] = f.meta.shape().dims::<4>();
        let (d, oc) = if keep { (kd, 2 * c) } else { (kd / views, c) };
        let out = permute_nhwc_to_nchw(empty_shaped(&f, Shape::new([d, h, w, oc])));
        let (count, dim) = grid(&f, (kd / views) * c * h * w);
        kernels::view_max_kernel::launch(
            &out.client,
            count,
            dim,
            f.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            views as u32,
            keep as u32,
        );
        out
    }

    fn gpu_view_max_backward(
        f: CubeTensor,
        grad: CubeTensor,
        views: usize,
        keep: bool,
    ) -> CubeTensor {
        let [kd, c, h, w] = f.meta.shape().dims::<4>();
        let gin = permute_nhwc_to_nchw(empty_shaped(&f, Shape::new([kd, h, w, c])));
        let (count, dim) = grid(&f, (kd / views) * c * h * w);
        kernels::view_max_backward_kernel::launch(
            &gin.client,
            count,
            dim,
            f.into_tensor_arg(),
            grad.into_tensor_arg(),
            gin.clone().into_tensor_arg(),
            views as u32,
            keep as u32,
        );
        gin
    }

    fn gpu_reflect_pad_pair(
        a: CubeTensor,
        b: CubeTensor,
        ph: usize,
        pw: usize,
        map: ChannelMap,
    ) -> CubeTensor {
        let [n, c, h, w] = a.meta.shape().dims::<4>();
        let mut offset = vec![0.0f32; c.max(3)];
        offset[..3].copy_from_slice(&map.offset);
        assert!(
            offset[c..].iter().all(|&o| o == 0.0),
            "offsets for the input's channels only"
        );
        let offset = upload_f32(&a, offset);
        assert_eq!(
            [n, c, h, w],
            b.meta.shape().dims::<4>(),
            "a padded pair has one shape"
        );
        assert!(
            ph < h && pw < w,
            "reflection padding narrower than the image"
        );
        let (oh, ow) = (h + 2 * ph, w + 2 * pw);
        let out = permute_nhwc_to_nchw(empty_shaped(&a, Shape::new([2 * n, oh, ow, c])));
        let (count, dim) = grid(&a, 2 * n * c * oh * ow);
        kernels::reflect_pad_pair_kernel::launch(
            &out.client,
            count,
            dim,
            a.into_tensor_arg(),
            b.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            ph as u32,
            pw as u32,
            map.scale,
            offset.into_tensor_arg(),
            map.reverse as u32,
        );
        out
    }

    fn gpu_reflect_pad_pair_backward(
        grad: CubeTensor,
        second: bool,
        ph: usize,
        pw: usize,
        map: ChannelMap,
    ) -> CubeTensor {
        let [n2, c, oh, ow] = grad.meta.shape().dims::<4>();
        let n = n2 / 2;
        let gin = empty_like(&grad, [n, c, oh - 2 * ph, ow - 2 * pw]);
        let (count, dim) = grid(&grad, gin.meta.shape().num_elements());
        kernels::reflect_pad_backward_kernel::launch(
            &gin.client,
            count,
            dim,
            grad.into_tensor_arg(),
            gin.clone().into_tensor_arg(),
            if second { n as u32 } else { 0 },
            ph as u32,
            pw as u32,
            map.scale,
            map.reverse as u32,
        );
        gin
    }

    fn gpu_conv3x3(x: CubeTensor, weight: CubeTensor, bias: CubeTensor) -> CubeTensor {
        <Self as burn::backend::ops::ModuleOps<Self>>::conv2d(x, weight, Some(bias), same3x3())
    }

    fn gpu_conv3x3_x_backward(weight: CubeTensor, grad: CubeTensor) -> CubeTensor {
        let flipped = flip_transpose(weight);
        <Self as burn::backend::ops::ModuleOps<Self>>::conv2d(grad, flipped, None, same3x3())
    }

    fn gpu_conv3x3_x_backward_frozen(weight: CubeTensor, grad: CubeTensor) -> CubeTensor {
        let key = FrozenKey::of(&weight);
        let cached = FROZEN_FLIPS.with(|c| {
            c.borrow()
                .iter()
                .find(|e| e.key == key)
                .map(|e| e.flipped.clone())
        });
        let flipped = match cached {
            Some(f) => {
                FROZEN_FLIP_HITS.with(|h| h.set(h.get() + 1));
                f
            }
            None => {
                let flipped = flip_transpose(weight.clone());
                FROZEN_FLIPS.with(|c| {
                    let mut c = c.borrow_mut();
                    if c.len() == FROZEN_FLIPS_KEPT {
                        c.remove(0);
                    }
                    c.push(FrozenFlip {
                        key,
                        _weight: weight,
                        flipped: flipped.clone(),
                    });
                });
                flipped
            }
        };
        <Self as burn::backend::ops::ModuleOps<Self>>::conv2d(grad, flipped, None, same3x3())
    }

    fn gpu_crop(x: CubeTensor, y0: usize, x0: usize, oh: usize, ow: usize) -> CubeTensor {
        let [n, c, h, w] = x.meta.shape().dims::<4>();
        assert!(y0 + oh <= h && x0 + ow <= w, "a window inside the input");
        let out = empty_in_layout(&x, [n, c, oh, ow]);
        let (count, dim) = grid(&x, n * c * oh * ow);
        kernels::crop_kernel::launch(
            &out.client,
            count,
            dim,
            x.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            y0 as u32,
            x0 as u32,
        );
        out
    }

    fn gpu_crop_backward(grad: CubeTensor, h: usize, w: usize, y0: usize, x0: usize) -> CubeTensor {
        let [n, c, _, _] = grad.meta.shape().dims::<4>();
        let gin = empty_in_layout(&grad, [n, c, h, w]);
        let (count, dim) = grid(&grad, n * c * h * w);
        kernels::crop_backward_kernel::launch(
            &gin.client,
            count,
            dim,
            grad.into_tensor_arg(),
            gin.clone().into_tensor_arg(),
            y0 as u32,
            x0 as u32,
        );
        gin
    }

    fn gpu_bias_grad(grad: CubeTensor) -> CubeTensor {
        let c = grad.meta.shape()[1];
        let out = empty_shaped(&grad, Shape::new([c]));
        kernels::bias_grad_kernel::launch(
            &out.client,
            CubeCount::Static(c as u32, 1, 1),
            CubeDim::new_1d(256),
            grad.into_tensor_arg(),
            out.clone().into_tensor_arg(),
        );
        out
    }

    fn gpu_pair_l1(f: CubeTensor, scale: f32) -> CubeTensor {
        let n = f.meta.shape()[0] / 2;
        let out = empty_shaped(&f, Shape::new([n]));
        kernels::pair_l1_kernel::launch(
            &out.client,
            CubeCount::Static(n as u32, 1, 1),
            CubeDim::new_1d(256),
            f.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            scale,
        );
        out
    }

    fn gpu_pair_l1_backward(f: CubeTensor, grad: CubeTensor, scale: f32) -> CubeTensor {
        // In the features' layout (a convolution's, channels last), as the ReLU's backward reads it.
        let f = dense(f);
        let gin = empty_same_layout(&f);
        let (count, dim) = grid(&f, f.meta.shape().num_elements() / 2);
        kernels::pair_l1_backward_kernel::launch(
            &gin.client,
            count,
            dim,
            f.into_tensor_arg(),
            grad.into_tensor_arg(),
            gin.clone().into_tensor_arg(),
            scale,
        );
        gin
    }

    fn gpu_adam(
        param: CubeTensor,
        grad: CubeTensor,
        moment_1: CubeTensor,
        moment_2: CubeTensor,
        step: AdamStep,
    ) -> (CubeTensor, CubeTensor, CubeTensor) {
        let (inputs, outputs) = adam_prepare([param, grad, moment_1, moment_2]);
        launch_adam_many(vec![PendingAdam {
            inputs,
            outputs: outputs.clone(),
            step,
        }]);
        let [p, m, v] = outputs;
        (p, m, v)
    }

    fn gpu_act_backward(out: CubeTensor, grad: CubeTensor, relu: bool) -> CubeTensor {
        // Element-wise over the buffers where both share a dense layout (the gradient of a
        // convolution's input comes back in the layout its output had), else both made contiguous.
        let (out, grad) =
            if is_dense(&out) && is_dense(&grad) && out.meta.strides() == grad.meta.strides() {
                (out, grad)
            } else {
                (into_contiguous(out), into_contiguous(grad))
            };
        let gin = empty_same_layout(&out);
        let (count, dim) = grid(&out, out.meta.shape().num_elements());
        kernels::act_backward_kernel::launch(
            &gin.client,
            count,
            dim,
            out.into_tensor_arg(),
            grad.into_tensor_arg(),
            gin.clone().into_tensor_arg(),
            relu as u32,
        );
        gin
    }
}

impl<B: Backend + GpuOps, C: CheckpointStrategy> GpuOps for Autodiff<B, C> {
    fn gpu_composite(rgba: FloatTensor<Self>) -> FloatTensor<Self> {
        let guards = [rgba.node()];
        let rgba = rgba.into_primitive();
        match CompositeBackward
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_composite(rgba.clone());
                prep.finish((rgba, out.clone()), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_composite(rgba)),
        }
    }

    fn gpu_composite_backward(
        _rgba: FloatTensor<Self>,
        _out: FloatTensor<Self>,
        _grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of composite")
    }

    fn gpu_prior_state(
        psv: FloatTensor<Self>,
        planes: usize,
        temperature: f64,
        channels: usize,
        radius: usize,
        weight: f64,
    ) -> FloatTensor<Self> {
        // The plane sweeps are data (images warped by fixed homographies): nothing to differentiate.
        assert!(
            !psv.is_tracked(),
            "the agreement prior has no gradient (its plane sweeps must not require one)"
        );
        let out = B::gpu_prior_state(
            psv.into_primitive(),
            planes,
            temperature,
            channels,
            radius,
            weight,
        );
        FloatTensor::<Self>::new(out)
    }

    fn gpu_append_state(x: FloatTensor<Self>, state: FloatTensor<Self>) -> FloatTensor<Self> {
        let guards = [x.node(), state.node()];
        let (x, state) = (x.into_primitive(), state.into_primitive());
        let d = state.shape().dims::<4>()[0];
        let cv = x.shape().dims::<4>()[1];
        match AppendStateBackward
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((d, cv), B::gpu_append_state(x, state)),
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_append_state(x, state)),
        }
    }

    fn gpu_append_state_backward(
        _grad: FloatTensor<Self>,
        _planes: usize,
        _cv: usize,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        unimplemented!("second-order gradients of a net's input")
    }

    fn gpu_warp(src: FloatTensor<Self>, table: Arc<WarpTable>) -> FloatTensor<Self> {
        let guards = [src.node()];
        let src = src.into_primitive();
        let s = src.shape().dims::<4>()[0];
        match WarpBackward.prepare::<C>(guards).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_warp(src, table.clone());
                prep.finish((table, s), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_warp(src, table)),
        }
    }

    fn gpu_warp_backward(
        _grad: FloatTensor<Self>,
        _table: Arc<WarpTable>,
        _s: usize,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of warp")
    }

    fn gpu_sweep(src: FloatTensor<Self>, table: Arc<WarpTable>) -> FloatTensor<Self> {
        assert!(
            !src.is_tracked(),
            "a plane sweep has no gradient (its image must not require one)"
        );
        FloatTensor::<Self>::new(B::gpu_sweep(src.into_primitive(), table))
    }

    fn gpu_components(
        image: FloatTensor<Self>,
        packed: FloatTensor<Self>,
        table: Arc<WarpTable>,
    ) -> FloatTensor<Self> {
        let guards = [image.node(), packed.node()];
        let (image, packed) = (image.into_primitive(), packed.into_primitive());
        let ci = image.shape().dims::<4>()[1];
        match ComponentsBackward
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_components(image, packed, table.clone());
                prep.finish((table, ci), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_components(image, packed, table)),
        }
    }

    fn gpu_components_image_grad(
        _grad: FloatTensor<Self>,
        _table: Arc<WarpTable>,
        _ci: usize,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of the components")
    }

    fn gpu_components_packed_grad(
        _grad: FloatTensor<Self>,
        _table: Arc<WarpTable>,
        _ci: usize,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of the components")
    }

    fn gpu_act(x: FloatTensor<Self>, relu: bool) -> FloatTensor<Self> {
        let guards = [x.node()];
        let x = x.into_primitive();
        match ActBackward.prepare::<C>(guards).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_act(x, relu);
                prep.finish((out.clone(), relu), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_act(x, relu)),
        }
    }

    fn gpu_channels_last(t: FloatTensor<Self>) -> FloatTensor<Self> {
        // For weights (a leaf; the caller sets its gradient requirement again).
        FloatTensor::<Self>::new(B::gpu_channels_last(t.into_primitive()))
    }

    fn gpu_state_rgba(state: FloatTensor<Self>) -> FloatTensor<Self> {
        let guards = [state.node()];
        let state = state.into_primitive();
        match StateRgbaBackward
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_state_rgba(state.clone());
                prep.finish(state, out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_state_rgba(state)),
        }
    }

    fn gpu_state_rgba_backward(
        _state: FloatTensor<Self>,
        _grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of the state's RGBA")
    }

    fn gpu_view_max(f: FloatTensor<Self>, views: usize, keep: bool) -> FloatTensor<Self> {
        let guards = [f.node()];
        let f = f.into_primitive();
        match ViewMaxBackward
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_view_max(f.clone(), views, keep);
                prep.finish((f, views, keep), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_view_max(f, views, keep)),
        }
    }

    fn gpu_view_max_backward(
        _f: FloatTensor<Self>,
        _grad: FloatTensor<Self>,
        _views: usize,
        _keep: bool,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of the max over views")
    }

    fn gpu_reflect_pad_pair(
        a: FloatTensor<Self>,
        b: FloatTensor<Self>,
        ph: usize,
        pw: usize,
        map: ChannelMap,
    ) -> FloatTensor<Self> {
        let guards = [a.node(), b.node()];
        let (a, b) = (a.into_primitive(), b.into_primitive());
        match PadPairBackward
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_reflect_pad_pair(a, b, ph, pw, map);
                prep.finish((ph, pw, map), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_reflect_pad_pair(a, b, ph, pw, map)),
        }
    }

    fn gpu_reflect_pad_pair_backward(
        _grad: FloatTensor<Self>,
        _second: bool,
        _ph: usize,
        _pw: usize,
        _map: ChannelMap,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of the padding")
    }

    fn gpu_conv3x3(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let guards = [x.node(), weight.node(), bias.node()];
        let (x, weight, bias) = (
            x.into_primitive(),
            weight.into_primitive(),
            bias.into_primitive(),
        );
        match Conv3x3Backward
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_conv3x3(x.clone(), weight.clone(), bias);
                prep.finish((x, weight), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_conv3x3(x, weight, bias)),
        }
    }

    fn gpu_conv3x3_x_backward(
        _weight: FloatTensor<Self>,
        _grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of a convolution")
    }

    fn gpu_crop(
        x: FloatTensor<Self>,
        y0: usize,
        x0: usize,
        oh: usize,
        ow: usize,
    ) -> FloatTensor<Self> {
        let guards = [x.node()];
        let x = x.into_primitive();
        let [_, _, h, w] = x.shape().dims::<4>();
        match CropBackward.prepare::<C>(guards).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_crop(x, y0, x0, oh, ow);
                prep.finish((h, w, y0, x0), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_crop(x, y0, x0, oh, ow)),
        }
    }

    fn gpu_crop_backward(
        _grad: FloatTensor<Self>,
        _h: usize,
        _w: usize,
        _y0: usize,
        _x0: usize,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of a crop")
    }

    fn gpu_bias_grad(_grad: FloatTensor<Self>) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of a convolution")
    }

    fn gpu_pair_l1(f: FloatTensor<Self>, scale: f32) -> FloatTensor<Self> {
        let guards = [f.node()];
        let f = f.into_primitive();
        match PairL1Backward
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::gpu_pair_l1(f.clone(), scale);
                prep.finish((f, scale), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::gpu_pair_l1(f, scale)),
        }
    }

    fn gpu_pair_l1_backward(
        _f: FloatTensor<Self>,
        _grad: FloatTensor<Self>,
        _scale: f32,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of the feature loss")
    }

    fn gpu_adam(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        step: AdamStep,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        // Optimizers step inner tensors; an autodiff one is stepped untracked.
        let (p, m, v) = B::gpu_adam(
            param.into_primitive(),
            grad.into_primitive(),
            moment_1.into_primitive(),
            moment_2.into_primitive(),
            step,
        );
        (
            FloatTensor::<Self>::new(p),
            FloatTensor::<Self>::new(m),
            FloatTensor::<Self>::new(v),
        )
    }

    fn gpu_act_backward(
        _out: FloatTensor<Self>,
        _grad: FloatTensor<Self>,
        _relu: bool,
    ) -> FloatTensor<Self> {
        unimplemented!("second-order gradients of an activation")
    }
}

#[derive(Debug)]
struct ActBackward;

impl<B: Backend + GpuOps> Backward<B, 1> for ActBackward {
    /// The output, and whether it is a ReLU.
    type State = (FloatTensor<B>, bool);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (out, relu) = ops.state;
        if let Some(node) = node {
            grads.register::<B>(node.id, B::gpu_act_backward(out, grad, relu));
        }
    }
}

#[derive(Debug)]
struct WarpBackward;

impl<B: Backend + GpuOps> Backward<B, 1> for WarpBackward {
    /// The table and the source's planes.
    type State = (Arc<WarpTable>, usize);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (table, s) = ops.state;
        if let Some(node) = node {
            grads.register::<B>(node.id, B::gpu_warp_backward(grad, table, s));
        }
    }
}

#[derive(Debug)]
struct AppendStateBackward;

impl<B: Backend + GpuOps> Backward<B, 2> for AppendStateBackward {
    /// The planes `D` and the channels of `x`.
    type State = (usize, usize);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x, state] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (d, cv) = ops.state;
        let (gx, gs) = B::gpu_append_state_backward(grad, d, cv);
        if let Some(node) = x {
            grads.register::<B>(node.id, gx);
        }
        if let Some(node) = state {
            grads.register::<B>(node.id, gs);
        }
    }
}

#[derive(Debug)]
struct StateRgbaBackward;

impl<B: Backend + GpuOps> Backward<B, 1> for StateRgbaBackward {
    /// The state.
    type State = FloatTensor<B>;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        if let Some(node) = node {
            grads.register::<B>(node.id, B::gpu_state_rgba_backward(ops.state, grad));
        }
    }
}

#[derive(Debug)]
struct ViewMaxBackward;

impl<B: Backend + GpuOps> Backward<B, 1> for ViewMaxBackward {
    /// The input, the views and `keep`.
    type State = (FloatTensor<B>, usize, bool);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (f, views, keep) = ops.state;
        if let Some(node) = node {
            grads.register::<B>(node.id, B::gpu_view_max_backward(f, grad, views, keep));
        }
    }
}

#[derive(Debug)]
struct Conv3x3Backward;

impl<B: Backend + GpuOps> Backward<B, 3> for Conv3x3Backward {
    /// The input and the weights.
    type State = (FloatTensor<B>, FloatTensor<B>);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node, w_node, b_node] = ops.parents;
        let w_frozen = w_node.is_none() && b_node.is_none();
        let grad = grads.consume::<B>(&ops.node);
        let (x, weight) = ops.state;
        if let Some(node) = b_node {
            grads.register::<B>(node.id, B::gpu_bias_grad(grad.clone()));
        }
        if let Some(node) = w_node {
            let g = B::conv2d_weight_backward(x, weight.clone(), grad.clone(), same3x3());
            grads.register::<B>(node.id, g);
        }
        if let Some(node) = x_node {
            let gx = if w_frozen {
                B::gpu_conv3x3_x_backward_frozen(weight, grad)
            } else {
                B::gpu_conv3x3_x_backward(weight, grad)
            };
            grads.register::<B>(node.id, gx);
        }
    }
}

#[derive(Debug)]
struct PairL1Backward;

impl<B: Backend + GpuOps> Backward<B, 1> for PairL1Backward {
    /// The features and the scale.
    type State = (FloatTensor<B>, f32);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        if let Some(node) = node {
            let (f, scale) = ops.state;
            grads.register::<B>(node.id, B::gpu_pair_l1_backward(f, grad, scale));
        }
    }
}

#[derive(Debug)]
struct CropBackward;

impl<B: Backend + GpuOps> Backward<B, 1> for CropBackward {
    /// The input's rows and columns, and the window's origin.
    type State = (usize, usize, usize, usize);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (h, w, y0, x0) = ops.state;
        if let Some(node) = node {
            grads.register::<B>(node.id, B::gpu_crop_backward(grad, h, w, y0, x0));
        }
    }
}

#[derive(Debug)]
struct PadPairBackward;

impl<B: Backend + GpuOps> Backward<B, 2> for PadPairBackward {
    /// The padding's rows and columns per side, and the channel map.
    type State = (usize, usize, ChannelMap);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [a, b] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (ph, pw, map) = ops.state;
        if let Some(node) = a {
            let g = B::gpu_reflect_pad_pair_backward(grad.clone(), false, ph, pw, map);
            grads.register::<B>(node.id, g);
        }
        if let Some(node) = b {
            let g = B::gpu_reflect_pad_pair_backward(grad, true, ph, pw, map);
            grads.register::<B>(node.id, g);
        }
    }
}

#[derive(Debug)]
struct ComponentsBackward;

impl<B: Backend + GpuOps> Backward<B, 2> for ComponentsBackward {
    /// The table and the image's channels.
    type State = (Arc<WarpTable>, usize);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [image, packed] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (table, ci) = ops.state;
        if let Some(node) = image {
            let g = B::gpu_components_image_grad(grad.clone(), table.clone(), ci);
            grads.register::<B>(node.id, g);
        }
        if let Some(node) = packed {
            grads.register::<B>(node.id, B::gpu_components_packed_grad(grad, table, ci));
        }
    }
}

#[derive(Debug)]
struct CompositeBackward;

impl<B: Backend + GpuOps> Backward<B, 1> for CompositeBackward {
    /// The RGBA planes and the output.
    type State = (FloatTensor<B>, FloatTensor<B>);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (rgba, out) = ops.state;
        if let Some(node) = node {
            grads.register::<B>(node.id, B::gpu_composite_backward(rgba, out, grad));
        }
    }
}

mod kernels;
#[cfg(test)]
mod tests;
