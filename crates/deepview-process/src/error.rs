//! The errors of processing; every message says what failed and what to do about it.

use crate::Stage;
use deepview_data::DataError;
use std::path::{Path, PathBuf};

/// The install hint shown when COLMAP cannot be run.
pub const INSTALL_COLMAP: &str = "install it with `apt-get install colmap` (Debian/Ubuntu; `brew install colmap` on macOS) or name the program";

#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error("cannot run COLMAP ({program}): {reason}; {INSTALL_COLMAP}")]
    ColmapMissing { program: PathBuf, reason: String },
    #[error(
        "cannot run ffmpeg ({program}): {reason}; install it with `apt-get install ffmpeg` or name the program"
    )]
    FfmpegMissing { program: PathBuf, reason: String },
    #[error("{stage} failed ({status}); the last lines of {log}:\n{tail}")]
    StageFailed {
        stage: Stage,
        status: String,
        log: PathBuf,
        tail: String,
    },
    #[error("{dir}: no images found (looked for .jpg, .jpeg and .png files){skipped}")]
    NoImages {
        dir: PathBuf,
        /// What the folder has that is not read ([`crate::photos::skipped_note`]), or empty.
        skipped: String,
    },
    #[error(
        "{dir}: only {count} image{}, but COLMAP needs at least 2 overlapping photos",
        if *.count == 1 { "" } else { "s" }
    )]
    TooFewImages { dir: PathBuf, count: usize },
    /// A video that gave fewer than 2 frames at the frame rate asked for.
    #[error(
        "{video}: {count} frame{} extracted at {fps} frames per second, but COLMAP needs at least 2 \
         overlapping photos: raise --fps (or check that it is a video)",
        if *.count == 1 { "" } else { "s" }
    )]
    TooFewFrames {
        video: PathBuf,
        fps: f64,
        count: usize,
    },
    #[error(
        "{dir}: only {readable} of {total} photos can be read as images, but COLMAP needs at least 2; \
         unreadable: {unreadable}"
    )]
    UnreadableImages {
        dir: PathBuf,
        readable: usize,
        total: usize,
        unreadable: String,
    },
    #[error(
        "COLMAP registered {registered} of {total} images, but at least 2 are needed; not registered: {missing}. \
         Are these photos of one scene, overlapping, sharp and textured? (COLMAP's log: {log})"
    )]
    NotRegistered {
        registered: usize,
        total: usize,
        missing: String,
        log: PathBuf,
    },
    #[error(
        "{path} already exists and is not empty; choose another output folder or move it away (existing output is \
         never replaced)"
    )]
    OutputExists { path: PathBuf },
    #[error(
        "{path} exists and was not made by `deepview process`; move it away (it is where the scene is built)"
    )]
    WorkFolderTaken { path: PathBuf },
    #[error(
        "another deepview process is building {out} (in {path}, which it holds): wait for it to \
         finish, or choose another --out"
    )]
    WorkFolderBusy { out: PathBuf, path: PathBuf },
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {msg}")]
    Image { path: PathBuf, msg: String },
    #[error("{0}")]
    Invalid(String),
    #[error("the scene COLMAP made does not load: {0}")]
    Data(#[from] DataError),
}

pub(crate) fn read_err(path: &Path) -> impl FnOnce(std::io::Error) -> ProcessError + '_ {
    move |source| ProcessError::Read {
        path: path.into(),
        source,
    }
}

pub(crate) fn write_err(path: &Path) -> impl FnOnce(std::io::Error) -> ProcessError + '_ {
    move |source| ProcessError::Write {
        path: path.into(),
        source,
    }
}
