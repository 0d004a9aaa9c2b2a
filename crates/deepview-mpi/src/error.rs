//! The errors of this crate: the folder format, the interchange formats and their files.

use deepview_image::ImageError;
use std::path::{Path, PathBuf};

/// Every message names the file (when there is one) and the problem.
#[derive(Debug, thiserror::Error)]
pub enum MpiError {
    #[error("{path}: {msg}")]
    Invalid { path: PathBuf, msg: String },
    #[error(
        "{path}: stereo magnification folders do not store plane depths and this one has no README naming \
         them: give the near and far depths (its defaults are 1 and 100)"
    )]
    NoPlaneDepths { path: PathBuf },
    #[error("{0}")]
    Config(String),
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    /// `what`: `mpi.json`, or `JSON for NAME` for the other formats' JSON files.
    #[error("{path} is not valid {what}: {source}")]
    Json {
        path: PathBuf,
        what: &'static str,
        source: serde_json::Error,
    },
    #[error(transparent)]
    Image(#[from] ImageError),
}

pub(crate) fn invalid(path: impl Into<PathBuf>, msg: impl Into<String>) -> MpiError {
    MpiError::Invalid {
        path: path.into(),
        msg: msg.into(),
    }
}

pub(crate) fn read_err(path: &Path) -> impl FnOnce(std::io::Error) -> MpiError + '_ {
    move |source| MpiError::Io {
        path: path.to_path_buf(),
        source,
    }
}

pub(crate) fn write_err(path: &Path) -> impl FnOnce(std::io::Error) -> MpiError + '_ {
    move |source| MpiError::Write {
        path: path.to_path_buf(),
        source,
    }
}
