//! Two baselines without learning: the nearest input view reprojected through one plane, and an MPI built
//! from the plane sweep volume's mean colour with alpha from cross-view colour agreement.

use crate::check::check_inputs;
use crate::error::MethodError;
use crate::planes::mpi_reference;
use deepview_geometry::{Camera, PlaneSpacing, plane_depths};
use deepview_image::ImageF32;
use deepview_mpi::{Mpi, agreement};

/// The MPI of `nearest`: one opaque plane in `input`'s own camera holding its image, at the
/// inverse-depth midpoint of `near_far` (rendered into that camera, it is the image itself).
pub fn nearest_view_mpi(
    input: &(ImageF32, Camera),
    near_far: (f64, f64),
) -> Result<Mpi, MethodError> {
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
    /// `s` in `exp(-variance / s)` (default [`agreement::TEMPERATURE`]).
    pub temperature: f64,
    /// The variance assumed where only one view sees a plane point (default
    /// [`agreement::SINGLE_VIEW_VARIANCE`]).
    pub single_view_variance: f64,
    /// Cost aggregation ([`agreement::aggregate_seen`]); the default, [`agreement::Aggregation::NONE`], is
    /// the per-pixel baseline of the tables.
    pub aggregation: agreement::Aggregation,
    /// MPI pixels per input pixel along each axis (`--mpi-scale`; 1 by default).
    pub scale: f64,
}

impl Default for PsvMeanOptions {
    fn default() -> Self {
        Self {
            planes: 32,
            temperature: agreement::TEMPERATURE,
            single_view_variance: agreement::SINGLE_VIEW_VARIANCE,
            aggregation: agreement::Aggregation::NONE,
            scale: 1.0,
        }
    }
}

/// The reference camera of a baseline MPI: centroid and average orientation of the inputs, field of view
/// enlarged to cover them between near and far.
pub(crate) fn baseline_reference(
    inputs: &[(ImageF32, Camera)],
    near_far: (f64, f64),
    scale: f64,
) -> Result<Camera, MethodError> {
    let cams: Vec<Camera> = inputs.iter().map(|(_, c)| *c).collect();
    mpi_reference(&cams, near_far, scale)
}

/// An MPI from the plane sweep volume by cross-view colour agreement ([`deepview_mpi::agreement`]) in the
/// inputs' [`mpi_reference`] with `options.planes` planes equally spaced in inverse depth.
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
) -> Result<Mpi, MethodError> {
    check_inputs("psv-mean", inputs, near_far)?;
    if !(options.temperature.is_finite() && options.temperature > 0.0) {
        return Err(MethodError::Method {
            method: "psv-mean".into(),
            msg: format!("temperature {} must be positive", options.temperature),
        });
    }
    let reference = baseline_reference(inputs, near_far, options.scale)?;
    let depths = plane_depths(
        near_far.0,
        near_far.1,
        options.planes,
        PlaneSpacing::InverseDepth,
    )?;
    let rgb: Vec<(ImageF32, Camera)> = inputs.iter().map(|(i, c)| (i.to_rgb(), *c)).collect();
    Ok(agreement::agreement_mpi(
        &rgb,
        &reference,
        depths,
        options.temperature,
        options.single_view_variance,
        options.aggregation,
    ))
}
