//! Checks every method makes of its inputs.

use crate::error::MethodError;
use deepview_geometry::Camera;
use deepview_image::ImageF32;

/// Refuse inputs a method cannot use: none, an image whose size differs from its camera's, fewer than
/// 3 channels, or invalid depth bounds (errors name `method`).
pub(crate) fn check_inputs(
    method: &str,
    inputs: &[(ImageF32, Camera)],
    near_far: (f64, f64),
) -> Result<(), MethodError> {
    let err = |msg: String| MethodError::Method {
        method: method.into(),
        msg,
    };
    if inputs.is_empty() {
        return Err(err("no input views".into()));
    }
    for (i, (img, cam)) in inputs.iter().enumerate() {
        if (img.width, img.height) != (cam.width, cam.height) {
            return Err(err(format!(
                "input {i}: image is {}x{} but its camera is {}x{}",
                img.width, img.height, cam.width, cam.height
            )));
        }
        if img.channels < 3 {
            return Err(err(format!(
                "input {i}: image has {} channels, need RGB",
                img.channels
            )));
        }
    }
    let (near, far) = near_far;
    if !(near.is_finite() && far.is_finite() && near > 0.0 && far > near) {
        return Err(err(format!(
            "invalid depth bounds near {near}, far {far} (need 0 < near < far)"
        )));
    }
    Ok(())
}
