//! What a training run reports while it runs ([`TrainEvent`], through the callback of
//! [`crate::trainer::Trainer::run`]) and what it says in passing ([`Notice`]): the library prints
//! nothing, the program shows them.

use crate::metrics::StepReport;
use std::path::{Path, PathBuf};

/// An event of [`crate::trainer::Trainer::run`]. Every rank of a distributed run reports its own
/// (only the writer, [`crate::trainer::Trainer::is_writer`], writes checkpoints).
#[derive(Debug)]
pub enum TrainEvent<'a> {
    /// The loop starts at `step` of `total` steps.
    Start { step: u64, total: u64 },
    /// A step is done (`report.skipped`: it changed nothing, and why). `steps_per_s`: the speed of
    /// this session so far.
    Step {
        report: &'a StepReport,
        steps_per_s: f64,
    },
    /// The checkpoint of `step` is complete in `dir`.
    Checkpoint { step: u64, dir: &'a Path },
    /// Something said in passing.
    Notice(&'a Notice),
}

/// Something a run says in passing, which does not stop it.
#[derive(Clone, Debug, PartialEq)]
pub enum Notice {
    /// A checkpoint that does not load, skipped for the one before; an old checkpoint or a leftover
    /// that cannot be removed.
    Warning(String),
    /// A leftover of an interrupted run (temporary checkpoint folder or file), removed.
    Removed(PathBuf),
}

impl std::fmt::Display for Notice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Notice::Warning(m) => write!(f, "warning: {m}"),
            Notice::Removed(p) => write!(f, "removed {} (left by an interrupted run)", p.display()),
        }
    }
}
