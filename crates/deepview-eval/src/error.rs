//! The crate's error type; every message names the scene, view or protocol involved (errors of making an
//! MPI are [`MethodError`]s).

use deepview_data::DataError;
use deepview_image::ImageError;
use deepview_methods::MethodError;
use deepview_metrics::MetricsError;

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(
        "unknown protocol '{0}' (expected small_quad, medium_quad, large_quad, dense, posed, light-field or auto)"
    )]
    UnknownProtocol(String),
    #[error(
        "protocol {protocol}: view index {index} is out of range (the scene has {views} views)"
    )]
    ViewOutOfRange {
        protocol: String,
        index: usize,
        views: usize,
    },
    #[error(
        "protocol {protocol}: target view {target} has only {available} candidate input view(s), {wanted} wanted"
    )]
    NotEnoughInputs {
        protocol: String,
        target: usize,
        wanted: usize,
        available: usize,
    },
    #[error("protocol {protocol} does not fit scene {scene}: {msg}")]
    WrongScene {
        protocol: String,
        scene: String,
        msg: String,
    },
    #[error("protocol {protocol} selects no target views in scene {scene}")]
    NoTargets { protocol: String, scene: String },
    #[error("{0}")]
    Invalid(String),
    #[error("cannot write {path}: {source}")]
    Write {
        path: std::path::PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    #[error(transparent)]
    Mpi(#[from] deepview_mpi::MpiError),
    /// Making an MPI failed (the method, its inputs, planes or memory).
    #[error(transparent)]
    Method(#[from] MethodError),
}
