//! Media around multiplane images: camera paths, nerfstudio `camera_path.json` and videos (the MPI
//! interchange formats live next to the MPI format, in `deepview_mpi::interchange`).
//!
//! - [`path`]: `spiral`, `circle` and `swing` paths around an MPI's reference camera, kept inside the range
//!   where the MPI is valid (translations small relative to the near plane).
//! - [`camera_path`]: nerfstudio's `camera_path.json` (OpenGL camera-to-world, vertical fov in degrees).
//! - [`video`]: PNG frames, animated GIF, MP4 through an `ffmpeg` found on `PATH`, with a progress bar.
//!
//! ```
//! use deepview_geometry::{Camera, Intrinsics, Pose};
//! use deepview_media::path::{PathKind, PathSpec, Radius, camera_path};
//! let reference = Camera::new(64, 48, Intrinsics::centred(60.0, 64, 48), Pose::IDENTITY);
//! let depths = [10.0, 5.0, 2.0];
//! let spec = PathSpec { kind: PathKind::Spiral, frames: 30, radius: Radius::NearFraction(0.05), focus_depth: None };
//! let cams = camera_path(&reference, &depths, &spec).unwrap();
//! assert_eq!(cams.len(), 30);
//! ```

pub mod camera_path;
pub mod path;
pub mod video;

use std::path::PathBuf;

/// Errors of this crate; every message names the file (when there is one) and the problem.
#[derive(Debug, thiserror::Error)]
pub enum MediaError {
    #[error("{path}: {msg}")]
    Invalid { path: PathBuf, msg: String },
    #[error("{0}")]
    Config(String),
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
    #[error("{path} is not valid JSON for {what}: {source}")]
    Json {
        path: PathBuf,
        what: &'static str,
        source: serde_json::Error,
    },
    #[error(transparent)]
    Image(#[from] deepview_image::ImageError),
    #[error(transparent)]
    Mpi(#[from] deepview_mpi::MpiError),
    #[error("{0}")]
    Ffmpeg(String),
    #[error(
        "an MP4 (H.264, yuv420p) needs frames of at least 2x2 pixels, got {width}x{height}; write a GIF or a \
         folder of PNG frames instead"
    )]
    OddFrameSize { width: u32, height: u32 },
}

pub(crate) fn invalid(path: impl Into<PathBuf>, msg: impl Into<String>) -> MediaError {
    MediaError::Invalid {
        path: path.into(),
        msg: msg.into(),
    }
}

pub(crate) fn read_err(path: &std::path::Path) -> impl FnOnce(std::io::Error) -> MediaError + '_ {
    move |source| MediaError::Read {
        path: path.to_path_buf(),
        source,
    }
}

pub(crate) fn write_err(path: &std::path::Path) -> impl FnOnce(std::io::Error) -> MediaError + '_ {
    move |source| MediaError::Write {
        path: path.to_path_buf(),
        source,
    }
}

pub use camera_path::{CameraPathFile, read_camera_path, write_camera_path};
pub use path::{PathKind, PathSpec, Radius, camera_path as make_camera_path};
pub use video::{VideoFormat, VideoReport, render_video, set_ffmpeg_program};
