//! The crate's error type: every message names the file and the problem.

use deepview_geometry::GeometryError;
use deepview_image::ImageError;
use std::path::{Path, PathBuf};

/// Errors of dataset input and output. Every message names the file and the problem.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
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
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error("{path}: malformed JSON: {source}")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{}: {msg}", location(.path, *.line))]
    Parse {
        path: PathBuf,
        line: Option<usize>,
        msg: String,
    },
    #[error("{path}: {what}: {source}")]
    Geometry {
        path: PathBuf,
        what: String,
        source: GeometryError,
    },
    #[error("image file {path} (view {view}) does not exist")]
    MissingImage { path: PathBuf, view: String },
    #[error(
        "image {path} is {got:?} (width, height) but its camera from {calibration} says {expected:?}"
    )]
    ImageSize {
        path: PathBuf,
        calibration: PathBuf,
        expected: (u32, u32),
        got: (u32, u32),
    },
    #[error("{path}: {msg}")]
    CountMismatch { path: PathBuf, msg: String },
    #[error(
        "{path}: rig position {rig} is out of range: the file has {count} rig position(s) (0..{count})"
    )]
    RigOutOfRange {
        path: PathBuf,
        rig: usize,
        count: usize,
    },
    #[error("{path}: no depth bounds known for this scene; give its near and far depths{hint}")]
    NoDepthBounds { path: PathBuf, hint: String },
    #[error(
        "{path}: this scene has no depth bounds of its own, so a {given} depth needs a {missing} depth too"
    )]
    HalfDepthBounds {
        path: PathBuf,
        given: &'static str,
        missing: &'static str,
    },
    #[error("{path}: image folder does not exist")]
    NoImageFolder { path: PathBuf },
    #[error(
        "{path}: downscaling by {factor} leaves nothing of view {view}'s {width}x{height} image"
    )]
    DownscaleTooLarge {
        path: PathBuf,
        factor: u32,
        view: String,
        width: u32,
        height: u32,
    },
    #[error("{path}: cannot detect the dataset format; looked for {looked_for}")]
    NotDetected { path: PathBuf, looked_for: String },
    #[error("{path}: {msg}")]
    Invalid { path: PathBuf, msg: String },
}

fn location(path: &Path, line: Option<usize>) -> String {
    match line {
        Some(l) => format!("{}:{l}", path.display()),
        None => path.display().to_string(),
    }
}

impl DataError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        DataError::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn write(path: &Path, source: std::io::Error) -> Self {
        DataError::Write {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn parse(path: &Path, line: Option<usize>, msg: impl Into<String>) -> Self {
        DataError::Parse {
            path: path.into(),
            line,
            msg: msg.into(),
        }
    }
    pub(crate) fn invalid(path: &Path, msg: impl Into<String>) -> Self {
        DataError::Invalid {
            path: path.into(),
            msg: msg.into(),
        }
    }
    pub(crate) fn geometry(path: &Path, what: impl Into<String>, source: GeometryError) -> Self {
        DataError::Geometry {
            path: path.into(),
            what: what.into(),
            source,
        }
    }
}
