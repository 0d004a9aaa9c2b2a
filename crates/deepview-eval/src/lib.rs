//! Making and scoring MPIs. Every way of making an MPI from posed input views (`deepview`, the learned
//! model; `psv-mean`, `nearest`, `optimize`, without learning) is an [`MpiMethod`], picked by
//! [`MethodKind`] and set up by [`MethodOptions`]; its inputs follow one [`InputRule`] and its plane count
//! one [`Planes`] rule. The eval runner scores a [`Method`] (an image of a target view; [`MpiPredictor`]
//! renders any [`MpiMethod`]'s MPI into the target) under a [`Protocol`] with the Spaces SSIM and PSNR
//! and writes a nerfstudio-shaped JSON report.
//!
//! Data flow: `Scene` (deepview-data) + [`Protocol`] -> [`ViewSplit`]s (target, inputs, border crop) ->
//! [`Method::predict`] -> crop, 8-bit quantise -> SSIM / PSNR -> [`EvalReport`].
//!
//! Modules, each using only those listed before it: [`error`], `check`, [`planes`], [`method`],
//! [`inputs`], [`baselines`], [`optimize`], [`learned`], [`methods`], [`protocol`], [`runner`].

pub mod baselines;
mod check;
pub mod error;
pub mod inputs;
pub mod learned;
pub mod method;
pub mod methods;
pub mod optimize;
pub mod planes;
pub mod protocol;
pub mod runner;

pub use baselines::{NearestView, PsvMean, PsvMeanOptions, agreement_mpi, nearest_view_mpi};
pub use error::EvalError;
pub use inputs::{DEFAULT_INPUTS, INPUT_RULES, InputRule};
pub use learned::{LearnedMethod, WeightsSource, check_learned};
pub use method::{MadeMpi, Method, MethodEvent, MpiMethod, MpiPredictor, MpiRequest};
pub use methods::{
    Classical, MethodKind, MethodOptions, PLANES_HELP, classical_planes, make_method,
};
pub use optimize::{OptimizeMethod, OptimizeOptions, optimize_mpi, optimize_mpi_with_history};
pub use planes::{PlaneChoice, Planes, PlanesHow, choose_planes, human, mpi_reference};
pub use protocol::{
    Protocol, SPACES_BIG_CROP, SPACES_SMALL_CROP, SpacesConfig, TargetRule, ViewSplit,
    spaces_edge_crop,
};
pub use runner::{EvalOptions, EvalReport, EvalResults, ViewResult, evaluate, evaluate_splits};
