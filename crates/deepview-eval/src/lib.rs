//! Scoring MPIs. The eval runner renders the MPI an [`MpiMethod`](deepview_methods::MpiMethod) makes (through
//! an [`MpiPredictor`]) into every target of a [`Protocol`], scores it with the Spaces SSIM and PSNR and
//! writes a nerfstudio-shaped JSON report. Making MPIs is `deepview-methods`' job.
//!
//! Data flow: `Scene` (deepview-data) + [`Protocol`] -> [`ViewSplit`]s (target, inputs, border crop) ->
//! [`MpiPredictor::predict`] -> crop, 8-bit quantise -> SSIM / PSNR -> [`EvalReport`].
//!
//! Modules, each using only those listed before it: [`error`], [`predictor`], [`protocol`], [`runner`].

pub mod error;
pub mod predictor;
pub mod protocol;
pub mod runner;

pub use error::EvalError;
pub use predictor::MpiPredictor;
pub use protocol::{
    Protocol, SPACES_BIG_CROP, SPACES_SMALL_CROP, SpacesConfig, TargetRule, ViewSplit,
    spaces_edge_crop,
};
pub use runner::{EvalOptions, EvalReport, EvalResults, ViewResult, evaluate, evaluate_splits};
