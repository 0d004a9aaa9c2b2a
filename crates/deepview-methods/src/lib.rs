//! Making MPIs. Every way of making an MPI from posed input views (`deepview`, the learned model;
//! `psv-mean`, `nearest`, `optimize`, without learning) is an [`MpiMethod`], picked by [`MethodKind`] and
//! set up by [`MethodOptions`]; its inputs follow one [`InputRule`] and its plane count one [`Planes`]
//! rule (shared with training through `deepview_geometry`). `infer` writes the MPI a method makes;
//! `deepview-eval` renders and scores it.
//!
//! Data flow: posed views + depth bounds -> [`MpiRequest`] -> [`MpiMethod::make_mpi`] (plane rule,
//! memory admission, the device) -> [`MadeMpi`].
//!
//! Modules, each using only those listed before it: [`error`], `check`, [`planes`], [`method`],
//! [`inputs`], [`baselines`], [`optimize`], [`learned`], [`methods`].

pub mod baselines;
mod check;
pub mod error;
pub mod inputs;
pub mod learned;
pub mod method;
pub mod methods;
pub mod optimize;
pub mod planes;

pub use baselines::{PsvMeanOptions, agreement_mpi, nearest_view_mpi};
pub use error::MethodError;
pub use inputs::{DEFAULT_INPUTS, INPUT_RULES, InputRule};
pub use learned::{LearnedMethod, WeightsSource, check_learned};
pub use method::{MadeMpi, MethodEvent, MpiMethod, MpiRequest};
pub use methods::{
    Classical, MethodKind, MethodOptions, PLANES_HELP, classical_planes, make_method,
};
pub use optimize::{
    OptimizeOptions, optimize_mpi, optimize_mpi_reporting, optimize_mpi_with_history,
};
pub use planes::{PlaneChoice, Planes, PlanesHow, choose_planes, human, mpi_reference};
