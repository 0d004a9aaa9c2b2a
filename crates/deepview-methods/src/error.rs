//! The crate's error type; every message names the view, rule or method involved.

use deepview_data::DataError;
use deepview_geometry::GeometryError;
use deepview_image::ImageError;

#[derive(Debug, thiserror::Error)]
pub enum MethodError {
    #[error("bad view rule '{rule}': {msg}")]
    BadRule { rule: String, msg: String },
    #[error("unknown method '{0}' (expected nearest, psv-mean, optimize or deepview)")]
    UnknownMethod(String),
    #[error(
        "view index {index} out of range: the scene has {views} views (0..{})",
        .views.saturating_sub(1)
    )]
    ViewIndex { index: usize, views: usize },
    #[error("input rule {rule}: it wants {wanted} views but {available} are available")]
    TooFewViews {
        rule: String,
        wanted: usize,
        available: usize,
    },
    #[error("an MPI needs at least one plane (got 0)")]
    NoPlanes,
    #[error("a plane count from the weights needs a learned model (use auto or a number)")]
    PlanesNeedWeights,
    #[error(
        "{planes} planes ({how}) do not fit the memory budget: they need at least {}",
        human(*.need)
    )]
    PlanesOverBudget {
        planes: usize,
        how: PlanesHow,
        /// Bytes the planes need at least.
        need: u64,
    },
    #[error(
        "{what} needs about {} of memory but the budget is {}",
        human(*.need),
        human(*.budget)
    )]
    OverBudget {
        what: String,
        need: u64,
        budget: u64,
    },
    #[error(
        "{what} needs more than {} of memory (the MPI state alone) but the budget is {}: fewer than \
         {fewer_than} planes fit it",
        human(*.lower),
        human(*.budget)
    )]
    StateOverBudget {
        what: String,
        /// A lower bound of the bytes needed.
        lower: u64,
        budget: u64,
        /// The smallest plane count whose lower bound exceeds the budget.
        fewer_than: usize,
    },
    #[error(
        "no weights in {} (expected config.json and model.safetensors, or a training checkpoint)",
        .dir.display()
    )]
    NoWeights { dir: std::path::PathBuf },
    #[error("method {method}: {msg}")]
    Method { method: String, msg: String },
    #[error("{0}")]
    Invalid(String),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    #[error(transparent)]
    Mpi(#[from] deepview_mpi::MpiError),
    #[error(transparent)]
    Weights(#[from] deepview_net::weights::WeightsError),
    #[error(transparent)]
    Infer(#[from] deepview_net::infer::InferError),
    #[error(transparent)]
    Device(#[from] deepview_net::device::DeviceError),
}

/// How a refused plane count came about (in [`MethodError::PlanesOverBudget`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlanesHow {
    /// An explicit count.
    Explicit,
    /// The learned model's own count.
    Weights,
    /// The fewest planes the `auto` rule takes.
    AutoMinimum,
}

impl std::fmt::Display for PlanesHow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Explicit => "the explicit count",
            Self::Weights => "the weights' count",
            Self::AutoMinimum => "the fewest the auto rule takes",
        })
    }
}

/// `human(bytes)`: e.g. `1.5 GiB`, `12.0 MiB`.
pub fn human(bytes: u64) -> String {
    if bytes >= 1 << 30 {
        format!("{:.1} GiB", bytes as f64 / (1u64 << 30) as f64)
    } else {
        format!("{:.1} MiB", bytes as f64 / (1u64 << 20) as f64)
    }
}
