//! Per-iteration activation recompute (the paper's gradient checkpointing, supplement): the peak training
//! memory holds one net's activations instead of all nets'.
//!
//! The model is a chain of segments, one per net, on the shrinking training windows of
//! [`DeepViewModel::forward`]:
//!
//! ```text
//! M_1     = crop_0(N_0(PSVs))                              (segment 0)
//! M_{n+1} = crop_n(M_n + N_n([grad_k(M_n), M_n]_k))        (segment n >= 1)
//! loss    = L(render(rgba(M_N)), target)
//! ```
//!
//! (`M_n` here is the state *entering* net `n`, already cropped by the previous net's margin.)
//!
//! 1. Forward without a graph: nets `0..N-1` run on the inner (non-autodiff) device with the validation
//!    copy of the model (`Module::valid`); only the states `M_1..M_{N-1}` (`[D, 8, h, w]` each) are kept.
//! 2. Backward, last segment first: segment `N-1` is recomputed on the autodiff device from a leaf
//!    `M_{N-1}.require_grad()` up to the real loss (render + VGG/L1), divided by the batch size; its
//!    backward gives that net's parameter gradients and `g_{N-1} = dL/dM_{N-1}`. Every earlier segment
//!    `n` is recomputed from its leaf `M_n` and back-propagated with the surrogate `sum(M_{n+1} * g_{n+1})`
//!    (`g_{n+1}` a constant), whose gradient w.r.t. `M_{n+1}` is exactly `g_{n+1}`: this is the
//!    vector-Jacobian product of the segment, so the parameter gradients equal those of the full backward
//!    (test: `recompute_gradients_match_full_backward`). The parameter gradients of all segments are
//!    collected into one [`GradientsParams`] (each parameter belongs to exactly one net, so nothing is
//!    summed twice).
//!
//! Peak memory: one net's activations (plus the loss tail's for the last one) instead of all of them.
//! Cost: nets `0..N-1` run forward twice (measured numbers in BENCHMARKS.md).
//!
//! The segment code mirrors [`DeepViewModel::forward`] (same building blocks: `init_input`,
//! `gradient_components`, `run_net`, `margin`, the same crop rule); the test
//! `recompute_loss_equals_model_forward` pins the two together bit for bit.

use crate::data::Example;
use crate::example::{example_inputs, loss_tail};
use crate::loss::Loss;
use burn::module::Module;
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor};
use deepview_net::forward::{Hom, crop_output};
use deepview_net::network::{
    ContextRgba, DeepViewModel, ModelInputs, state_to_rgba, window_gradient_components, window_rgba,
};

/// Geometry of a window: its size and the homographies from its pixels (per view, per plane).
#[derive(Clone, Debug)]
pub struct Window {
    pub width: usize,
    pub height: usize,
    pub mpi_to_view: Vec<Vec<Hom>>,
    /// Top-left in the pixels of the model's input window.
    pub offset: (usize, usize),
}

/// The windows entering every net and the output window (`nets + 1` entries), with the crop rule of
/// [`DeepViewModel::forward`] (crop by the net's margin, clamped and kept even, when `inputs.shrink`).
pub fn windows(model: &DeepViewModel, inputs: &ModelInputs) -> Vec<Window> {
    let mut win = Window {
        width: inputs.width,
        height: inputs.height,
        mpi_to_view: inputs.mpi_to_view.clone(),
        offset: (0, 0),
    };
    let mut out = vec![win.clone()];
    for n in 0..model.nets.len() {
        if inputs.shrink {
            let (w, h) = (win.width, win.height);
            let m = model
                .margin(n)
                .min(w.saturating_sub(1) / 2)
                .min(h.saturating_sub(1) / 2)
                & !1;
            if m > 0 {
                win.width -= 2 * m;
                win.height -= 2 * m;
                win.offset = (win.offset.0 + m, win.offset.1 + m);
                for hv in win.mpi_to_view.iter_mut() {
                    for hom in hv.iter_mut() {
                        *hom = crop_output(hom, m as f64, m as f64);
                    }
                }
            }
        }
        out.push(win.clone());
    }
    out
}

/// Segment `n`: the state entering net `n + 1` from the state entering net `n` (`None` for net 0),
/// on the device of `model` and `images` (both inner, or both autodiff).
#[allow(clippy::too_many_arguments)]
pub fn segment(
    model: &DeepViewModel,
    n: usize,
    images: &[Tensor<3>],
    input: &Window,
    output: &Window,
    state: Option<Tensor<4>>,
    context: Option<&ContextRgba>,
) -> Tensor<4> {
    let (w, h) = (input.width, input.height);
    let win = state
        .as_ref()
        .map(|s| window_rgba(state_to_rgba(s.clone()), (w, h), input.offset, context));
    let per_view: Vec<Tensor<4>> = images
        .iter()
        .zip(&input.mpi_to_view)
        .map(|(im, homs)| match &win {
            None => DeepViewModel::init_input(im.clone(), homs, (0, 0, w, h)),
            Some(win) => window_gradient_components(win, im.clone(), homs),
        })
        .collect();
    let out = model.run_net(n, per_view, state.clone());
    let s = match state {
        None => out,
        Some(s) => s + out,
    };
    let m = output.offset.0 - input.offset.0;
    if m > 0 {
        s.narrow(3, m, output.width).narrow(2, m, output.height)
    } else {
        s
    }
}

/// Loss of one tuple (`[1]` value) and the parameter gradients of `loss / batch` on `device` (an
/// autodiff device), with per-net recompute. The gradients are `None` when the loss is not finite
/// (nothing is back-propagated then).
pub fn loss_and_grads(
    model: &DeepViewModel,
    loss: &Loss,
    ex: &Example,
    device: &Device,
    batch: usize,
) -> (f32, Option<GradientsParams>) {
    let inner = device.clone().inner();
    let inputs = example_inputs(ex, &inner);
    let wins = windows(model, &inputs);
    let nets = model.nets.len();
    // The window's context (no parameters): once, on the inner device.
    let context = inputs.context.as_ref().map(|c| model.context_rgba(c));
    let context_ad = context.as_ref().map(|c| c.autodiff());

    // 1. Forward on the inner device: the states entering nets 1..N-1.
    let states: Vec<Tensor<4>> = {
        let plain = model.valid();
        let mut states = Vec::with_capacity(nets.saturating_sub(1));
        for n in 0..nets - 1 {
            let s = segment(
                &plain,
                n,
                &inputs.images,
                &wins[n],
                &wins[n + 1],
                states.last().cloned(),
                context.as_ref(),
            );
            states.push(s);
        }
        states
    };
    let images: Vec<Tensor<3>> = inputs.images.into_iter().map(|t| t.autodiff()).collect();
    // The leaf for the state entering net n (n >= 1) on the autodiff device.
    let leaf = |n: usize| (n > 0).then(|| states[n - 1].clone().autodiff().require_grad());

    // 2. Last segment with the real loss.
    let last = nets - 1;
    let s_in = leaf(last);
    let out = segment(
        model,
        last,
        &images,
        &wins[last],
        &wins[nets],
        s_in.clone(),
        context_ad.as_ref(),
    );
    let l = loss_tail(state_to_rgba(out), wins[nets].offset, ex, loss, device);
    let value = l.clone().into_scalar::<f32>();
    if !value.is_finite() {
        return (value, None);
    }
    let grads = (l / batch as f32).backward();
    let mut g = s_in.and_then(|s| s.grad(&grads));
    let mut acc = GradientsParams::from_grads(grads, model);

    // 3. Earlier segments, last first, with the surrogate sum(M_{n+1} * g_{n+1}).
    for n in (0..last).rev() {
        let Some(g_next) = g.take() else { break };
        let s_in = leaf(n);
        let out = segment(
            model,
            n,
            &images,
            &wins[n],
            &wins[n + 1],
            s_in.clone(),
            context_ad.as_ref(),
        );
        let grads = (out * g_next.autodiff()).sum().backward();
        g = s_in.and_then(|s| s.grad(&grads));
        let new = GradientsParams::from_grads(grads, model);
        acc = crate::clip::sum_on_device(model, vec![acc, new], &inner);
    }
    (value, Some(acc))
}
