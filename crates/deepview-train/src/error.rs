//! The errors of a training run.

use crate::scene::DataError;
use crate::vgg::VggError;
use std::path::{Path, PathBuf};

/// Errors of a training run; messages name the file or folder.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Vgg(#[from] VggError),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Run { path: PathBuf, message: String },
    #[error("invalid training configuration: {0}")]
    Config(String),
    /// The weights of `--init` cannot be read.
    #[error("--init {}: {source}", .dir.display())]
    Init {
        dir: PathBuf,
        #[source]
        source: deepview_net::weights::WeightsError,
    },
    /// What the user asked for cannot be done as asked (the message names the option that fixes it).
    #[error("{0}")]
    Refused(String),
    #[error(transparent)]
    Device(#[from] deepview_net::device::DeviceError),
    /// The ranks of a distributed run disagree (weights out of sync, no common checkpoint).
    #[error("rank {rank}: {message}")]
    Rank { rank: usize, message: String },
    /// Another process holds the run's lock: it is training that run now.
    #[error("{}: another `deepview train` is training this run right now", .path.display())]
    Busy { path: PathBuf },
    /// A new run in a folder that already holds checkpoints (resume it instead, or use another
    /// folder).
    #[error("{path}: this run already has checkpoints")]
    HasCheckpoints { path: PathBuf },
    /// A write of the run folder failed (disk full, read-only or removed folder): the run stops, its
    /// last complete checkpoint is untouched.
    #[error("step {step}: cannot write {what}: {source}; {}", kept_text(.kept))]
    Write {
        step: u64,
        what: String,
        source: Box<TrainError>,
        /// The checkpoint a resumed run continues from (step and folder), if any.
        kept: Option<(u64, PathBuf)>,
    },
}

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |source| TrainError::Io {
        path: path.to_path_buf(),
        source,
    }
}

pub(crate) fn run_err(path: &Path, message: impl std::fmt::Display) -> TrainError {
    TrainError::Run {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

fn kept_text(kept: &Option<(u64, PathBuf)>) -> String {
    match kept {
        Some((step, p)) => format!(
            "the last complete checkpoint {} (step {step}) is kept",
            p.display()
        ),
        None => "the run has no complete checkpoint yet".into(),
    }
}
