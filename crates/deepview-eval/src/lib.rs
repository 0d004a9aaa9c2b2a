//! Evaluation: which views are inputs and targets (protocols), the methods that predict a target view
//! (baselines here; the learned model implements [`Method`] in the app layer), and the runner that scores
//! predictions with the Spaces SSIM and PSNR and writes a nerfstudio-shaped JSON report.
//!
//! Data flow: `Scene` (deepview-data) + [`Protocol`] -> [`ViewSplit`]s (target, inputs, border crop) ->
//! [`Method::predict`] -> crop, 8-bit quantise -> SSIM / PSNR -> [`EvalReport`].

pub mod baselines;
pub mod error;
pub mod method;
pub mod optimize;
pub mod protocol;
pub mod runner;

pub use baselines::{NearestView, PsvMean, PsvMeanOptions, agreement_mpi, nearest_view_mpi};
pub use error::EvalError;
pub use method::{Baseline, Method, baseline_method};
pub use optimize::{OptimizeMethod, OptimizeOptions, optimize_mpi, optimize_mpi_with_history};
pub use protocol::{
    InputRule, Protocol, SPACES_BIG_CROP, SPACES_SMALL_CROP, SpacesConfig, TargetRule, ViewSplit,
    spaces_edge_crop,
};
pub use runner::{EvalOptions, EvalReport, EvalResults, ViewResult, evaluate, evaluate_splits};
