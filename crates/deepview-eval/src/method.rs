//! The interface every view-synthesis method implements, and the baselines by name.

use crate::baselines::{NearestView, PsvMean, PsvMeanOptions};
use crate::error::EvalError;
use crate::optimize::{OptimizeMethod, OptimizeOptions};
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use std::str::FromStr;

/// A view-synthesis method: input views with cameras in, the target view's image out.
///
/// `predict` returns an image of the target camera's size with at least 3 channels (RGB first; a 4th channel,
/// e.g. a rendered alpha, is ignored by the metrics). `near_far` are the scene's depth bounds.
pub trait Method {
    fn name(&self) -> &str;
    fn predict(
        &mut self,
        inputs: &[(ImageF32, Camera)],
        target: &Camera,
        near_far: (f64, f64),
    ) -> Result<ImageF32, EvalError>;
}

/// The baselines this crate provides.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Baseline {
    Nearest,
    PsvMean,
    Optimize,
}

impl Baseline {
    pub fn name(&self) -> &'static str {
        match self {
            Baseline::Nearest => "nearest",
            Baseline::PsvMean => "psv-mean",
            Baseline::Optimize => "optimize",
        }
    }
}

impl FromStr for Baseline {
    type Err = EvalError;
    fn from_str(s: &str) -> Result<Self, EvalError> {
        match s.trim().to_ascii_lowercase().replace('_', "-").as_str() {
            "nearest" => Ok(Baseline::Nearest),
            "psv-mean" | "psvmean" => Ok(Baseline::PsvMean),
            "optimize" | "optimise" => Ok(Baseline::Optimize),
            _ => Err(EvalError::UnknownMethod(s.into())),
        }
    }
}

/// A boxed baseline method with the given plane count (`psv-mean`, `optimize`) and optimiser settings.
pub fn baseline_method(
    kind: Baseline,
    psv: PsvMeanOptions,
    optimize: OptimizeOptions,
) -> Box<dyn Method> {
    match kind {
        Baseline::Nearest => Box::new(NearestView),
        Baseline::PsvMean => Box::new(PsvMean { options: psv }),
        Baseline::Optimize => Box::new(OptimizeMethod { options: optimize }),
    }
}

pub(crate) fn check_inputs(
    method: &str,
    inputs: &[(ImageF32, Camera)],
    near_far: (f64, f64),
) -> Result<(), EvalError> {
    let err = |msg: String| EvalError::Method {
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
