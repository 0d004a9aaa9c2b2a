//! The errors of inference, and the checks of its inputs.

use crate::network::DeepViewModel;
use deepview_geometry::Camera;
use deepview_image::ImageF32;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InferError {
    #[error("inference needs at least one input view")]
    NoViews,
    #[error("inference needs at least one plane depth")]
    NoPlanes,
    #[error("these weights take exactly {expected} input views, got {got}")]
    WrongViews { expected: usize, got: usize },
    #[error("the inference plan has {plan} nets but the model has {model}")]
    PlanMismatch { plan: usize, model: usize },
    #[error("input view {view}: image is {iw}x{ih} but its camera is {cw}x{ch}")]
    SizeMismatch {
        view: usize,
        iw: u32,
        ih: u32,
        cw: u32,
        ch: u32,
    },
    #[error(
        "memory budget {budget} bytes is too small: the MPI state ({planes} planes of {w}x{h}) and the inputs \
         need {fixed} bytes plus {min_tile} for the smallest tile; use fewer planes, a smaller reference image \
         or a larger budget"
    )]
    BudgetTooSmall {
        budget: u64,
        fixed: u64,
        min_tile: u64,
        planes: usize,
        w: u32,
        h: u32,
    },
    #[error(
        "the device failed to compute a tile: {0} (on a GPU, a smaller --max-memory gives smaller tiles)"
    )]
    Device(String),
}

/// Check the inputs of an inference: views, planes, the view count of the weights, image sizes.
pub(super) fn validate(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    depths: &[f64],
) -> Result<(), InferError> {
    if views.is_empty() {
        return Err(InferError::NoViews);
    }
    if depths.is_empty() {
        return Err(InferError::NoPlanes);
    }
    if model.fixed_views != 0 && model.fixed_views != views.len() {
        return Err(InferError::WrongViews {
            expected: model.fixed_views,
            got: views.len(),
        });
    }
    for (i, (img, cam)) in views.iter().enumerate() {
        if img.width != cam.width || img.height != cam.height {
            return Err(InferError::SizeMismatch {
                view: i,
                iw: img.width,
                ih: img.height,
                cw: cam.width,
                ch: cam.height,
            });
        }
    }
    Ok(())
}
