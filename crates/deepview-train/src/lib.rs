//! Training the DeepView network of `deepview_net` (`deepview train`): Adam (lr 1.5e-4), global-norm
//! gradient clipping at 8.0, the VGG feature loss ([`loss`], [`vgg`]) or L1 on `crop x crop` target
//! crops, checkpoints with optimizer and RNG state, exact resume, data parallelism across devices and
//! processes.
//!
//! The library prints nothing and installs no signal handler: [`Trainer::run`] reports its progress as
//! [`TrainEvent`]s to a callback and stops (after the current step, with a checkpoint) when the flag it
//! is given is set; the program draws the progress bar and sets the flag on Ctrl-C / SIGTERM.
//!
//! Modules: [`config`] (what a run is), [`load`] (its datasets), [`scene`] (a training scene and its
//! held-out views), [`data`] (tuple sampling), [`synthetic`] (a built-in scene), [`example`] (one tuple
//! through the model), [`recompute`], [`clip`], [`reduce`] (replicas of one process), [`dist`] (ranks),
//! [`trainer`] (the loop), [`checkpoint`], [`metrics`], [`events`], [`error`]; [`options`] (`deepview
//! train`'s options and how they map onto a run's config) and [`session`] (opening a run: new, resumed
//! or started over); devices by name are [`deepview_net::device`].
//!
//! A run lives in `runs/<name>/`:
//! - `config.json`: [`RunConfig`] (model + training config, with each dataset's load options, so a
//!   resumed run reads the same images);
//! - `checkpoints/step-NNNNNNN/`: `model.bpk` (burnpack, parameter ids kept so the optimizer state maps
//!   back), `optimizer.bpk` (Adam moments), `state.json` (step, RNG state, wall time); each written into a
//!   temporary folder and renamed into place; the last `keep_checkpoints` (3) are kept;
//! - `metrics.jsonl`: one JSON object per step (step, loss, grad_norm, views, steps_per_s, wall_time_s,
//!   skipped);
//! - `.lock`: held (`flock`) by the process training the run.
//!
//! Faults: a process killed at any moment (SIGKILL, a lost node) leaves the run resumable: a checkpoint
//! folder `step-N` appears only once all its files are flushed to disk, so a resumed run continues from
//! the last complete one (leftover temporary folders are removed, a checkpoint that fails to load is skipped
//! for the one before), and `metrics.jsonl` loses the lines after that step (and a torn last line), so
//! the log has each step once. A failed write (full disk, read-only or vanished folder) stops the run
//! with [`TrainError::Write`], naming what failed and the checkpoint that is kept.
//!
//! A step: draw K (per batch) and `batch` tuples ([`data`]); split them across the devices; each replica
//! (a copy of the model on its device) runs forward, loss and backward per example (loss divided by the
//! batch size) and sums its gradients; the replicas' sums are added onto the first device (= the
//! gradient of the batch-mean loss) by burn's collective `all_reduce` where the devices' runtime
//! supports it (CUDA), else by copies ([`reduce`]), then across ranks ([`dist`]); a non-finite loss or gradient norm skips the step (weights and optimizer state
//! untouched, the reason in the step's report, `skipped` in the metrics); otherwise the global norm is clipped and Adam
//! steps. With one device the replicas run in turn; with several, one thread per device.
//!
//! Per-iteration activation recompute ([`recompute`], `TrainConfig::recompute`): the forward pass keeps only the small MPI states between nets and each net's
//! activations are recomputed during the backward pass, so the peak holds one net's activations (the
//! largest: net 0 on the widest window) instead of all nets'; the gradients equal those of the ordinary
//! backward (bit for bit in the tests). On by default for models with more than 2 nets (every `paper-*`
//! preset).

pub mod adam;
pub mod checkpoint;
pub mod clip;
pub mod config;
pub mod data;
pub mod dist;
pub mod error;
pub mod events;
pub mod example;
mod files;
pub mod load;
pub mod loss;
pub mod metrics;
pub mod options;
pub mod recompute;
pub mod reduce;
pub mod scene;
pub mod session;
pub mod synthetic;
pub mod trainer;
pub mod vgg;

pub use checkpoint::{
    CHECKPOINT_FILES, CheckpointState, checkpoint_is_complete, damaged_checkpoints,
    list_checkpoints,
};
pub use config::{PAPER_LEARNING_RATE, RunConfig, TrainConfig};
pub use data::{Example, Rng, SampleConfig, StepBudget, TrainData, step_bytes};
pub use dist::Collective;
pub use error::TrainError;
pub use events::{Notice, TrainEvent};
pub use example::{example_inputs, example_loss, loss_and_grads_full, loss_tail, parameter_values};
pub use files::is_run_folder;
pub use load::{DataSpec, load_data};
pub use metrics::StepReport;
pub use options::TrainOptions;
pub use reduce::LocalReduction;
pub use scene::{Holdout, SYNTHETIC_PROCEDURAL, SYNTHETIC_TWO_PLANES, TrainScene, is_synthetic};
pub use session::{Request, Session, Start};
pub use trainer::Trainer;

#[cfg(test)]
mod tests;
