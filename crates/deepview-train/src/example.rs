//! One training tuple through the model: its inputs, its loss, and the gradients of the ordinary
//! backward pass.

use crate::data::Example;
use crate::loss::Loss;
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor};
use deepview_image::ImageF32;
use deepview_net::forward::{Hom, crop_output, image_tensor, invert, render_view};
use deepview_net::network::{DeepViewModel, ModelInputs, WindowContext};

/// The model inputs of a tuple on `device` (its training window, shrinking by the nets' margins).
pub fn example_inputs(ex: &Example, device: &Device) -> ModelInputs {
    let tensors = |images: &[ImageF32]| -> Vec<Tensor<3>> {
        images
            .iter()
            .map(|im| {
                image_tensor(
                    &im.data,
                    im.width as usize,
                    im.height as usize,
                    im.channels,
                    device,
                )
            })
            .collect()
    };
    let (_, _, ww, wh) = ex.window;
    ModelInputs {
        images: tensors(&ex.images),
        mpi_to_view: ex.mpi_to_view.clone(),
        height: wh,
        width: ww,
        shrink: true,
        context: ex.context.as_ref().map(|c| WindowContext {
            images: tensors(&c.images),
            mpi_to_view: c.mpi_to_view.clone(),
            width: c.width,
            height: c.height,
            origin: c.origin,
        }),
    }
}

/// The loss of one tuple, shape `[1]`: run the model on the tuple's window, render the output MPI into
/// the target crop and compare.
pub fn example_loss(
    model: &DeepViewModel,
    loss: &Loss,
    ex: &Example,
    device: &Device,
) -> Tensor<1> {
    let out = model.forward(&example_inputs(ex, device));
    loss_tail(out.rgba, out.offset, ex, loss, device)
}

/// Render the model's output MPI `rgba` (at `offset` in the tuple's window) into the target crop and
/// compare: the loss `[1]`.
pub fn loss_tail(
    rgba: Tensor<4>,
    offset: (usize, usize),
    ex: &Example,
    loss: &Loss,
    device: &Device,
) -> Tensor<1> {
    let (ox, oy) = offset;
    let view_to_mpi: Vec<Hom> = ex
        .window_to_target
        .iter()
        .map(|h| invert(&crop_output(h, ox as f64, oy as f64)))
        .collect();
    let (c, r) = (
        ex.target_crop.width as usize,
        ex.target_crop.height as usize,
    );
    let pred = render_view(rgba, &view_to_mpi, r, c)
        .render
        .reshape([1, 3, r, c]);
    let target = image_tensor(&ex.target_crop.data, c, r, ex.target_crop.channels, device)
        .reshape([1, 3, r, c]);
    loss.per_example(pred, target)
}

/// All parameter values of a module (one definition, in `deepview-net`).
pub use deepview_net::rng::parameter_values;

/// Loss of one tuple and the parameter gradients of `loss / batch` with the ordinary backward pass
/// (all activations kept); `None` gradients when the loss is not finite.
pub fn loss_and_grads_full(
    model: &DeepViewModel,
    loss: &Loss,
    ex: &Example,
    device: &Device,
    batch: usize,
) -> (f32, Option<GradientsParams>) {
    let l = example_loss(model, loss, ex, device);
    let v = l.clone().into_scalar::<f32>();
    if !v.is_finite() {
        return (v, None);
    }
    (
        v,
        Some(GradientsParams::from_grads(
            (l / batch as f32).backward(),
            model,
        )),
    )
}
