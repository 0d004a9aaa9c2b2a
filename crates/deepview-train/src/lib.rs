//! Training the DeepView network (`deepview train`; the model itself is `deepview_net`): Adam (lr 1.5e-4), global-norm gradient clipping at 8.0, the VGG feature
//! loss (or L1) on `crop x crop` target crops, checkpoints with optimizer and RNG state, exact resume,
//! data parallelism across devices.
//!
//! A run lives in `runs/<name>/`:
//! - `config.json`: [`RunConfig`] (model + training config);
//! - `checkpoints/step-NNNNNNN/`: `model.bpk` (burnpack, parameter ids kept so the optimizer state maps
//!   back), `optimizer.bpk` (Adam moments), `state.json` (step, RNG state, wall time); each written into a
//!   temporary folder and renamed into place; the last `keep_checkpoints` (3) are kept;
//! - `metrics.jsonl`: one JSON object per step (step, loss, grad_norm, views, steps_per_s, wall_time_s,
//!   skipped);
//! - `.lock`: held (`flock`) by the process training the run.
//!
//! Faults: a process killed at any moment (SIGKILL, a lost node) leaves the run resumable: a checkpoint
//! folder `step-N` appears only once all its files are flushed to disk, so `--resume` continues from the
//! last complete one (leftover temporary folders are removed, a checkpoint that fails to load is skipped
//! for the one before), and `metrics.jsonl` loses the lines after that step (and a torn last line), so
//! the log has each step once. A failed write (full disk, read-only or vanished folder) stops the run
//! with [`TrainError::Write`], naming what failed and the checkpoint that is kept.
//!
//! A step: draw K (per batch) and `batch` tuples ([`data`]); split them across the devices; each replica
//! (a copy of the model on its device) runs forward, loss and backward per example (loss divided by the
//! batch size) and sums its gradients; the sums are moved to the first device and added (= the gradient
//! of the batch-mean loss); a non-finite loss or gradient norm skips the step (weights and optimizer state
//! untouched, message printed, `skipped` in the metrics); otherwise the global norm is clipped and Adam
//! steps. With one device the replicas run in turn; with several, one thread per device.
//!
//! Per-iteration activation recompute ([`recompute`], `TrainConfig::recompute`, CLI `--recompute` /
//! `--no-recompute`): the forward pass keeps only the small MPI states between nets and each net's
//! activations are recomputed during the backward pass, so the peak holds one net's activations (the
//! largest: net 0 on the widest window) instead of all nets'; the gradients equal those of the ordinary
//! backward (bit for bit in the tests). On by default for models with more than 2 nets (every `paper-*`
//! preset).

pub mod checkpoint;
pub mod clip;
pub mod config;
pub mod data;
pub mod device;
pub mod dist;
pub mod error;
pub mod example;
mod files;
pub mod load;
pub mod loss;
pub mod metrics;
pub mod recompute;
pub mod synthetic;
pub mod trainer;
pub mod vgg;

pub use checkpoint::{CHECKPOINT_FILES, CheckpointState, checkpoint_is_complete, list_checkpoints};
pub use config::{PAPER_LEARNING_RATE, RunConfig, TrainConfig};
pub use data::{Example, Holdout, Rng, SampleConfig, TrainData, TrainScene};
pub use device::parse_device;
pub use dist::Collective;
pub use error::TrainError;
pub use example::{example_inputs, example_loss, loss_and_grads_full, loss_tail, parameter_values};
pub use load::load_data;
pub use metrics::StepReport;
pub use trainer::Trainer;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Install a Ctrl-C handler that sets the returned flag (the training loop then saves a checkpoint and
/// returns); a second Ctrl-C exits at once with code 130.
pub fn install_ctrlc() -> Result<Arc<AtomicBool>, TrainError> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    ctrlc::set_handler(move || {
        if f.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        eprintln!(
            "\ninterrupted: finishing the current step, saving a checkpoint (Ctrl-C again to abort)"
        );
    })
    .map_err(|e| TrainError::Config(format!("cannot install the Ctrl-C handler: {e}")))?;
    Ok(flag)
}

#[cfg(test)]
mod tests;
