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

pub mod clip;
pub mod data;
pub mod dist;
pub mod loss;
pub mod recompute;
pub mod synthetic;
pub mod vgg;

pub use data::{Example, Holdout, Rng, SampleConfig, TrainData, TrainScene};
pub use dist::Collective;

use deepview_net::config::DeepViewConfig;
use deepview_net::forward::{Hom, crop_output, image_tensor, invert, render_view};
use crate::loss::{Loss, LossKind};
use deepview_net::network::{DeepViewModel, ModelInputs};
use crate::vgg::{Vgg16, VggError};
use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// The paper's learning rate.
pub const PAPER_LEARNING_RATE: f64 = 1.5e-4;

/// Errors of a training run; messages name the file or folder.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Data(#[from] data::DataError),
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
    #[error("device `{name}`: {message}")]
    Device { name: String, message: String },
    /// The ranks of a distributed run disagree (weights out of sync, no common checkpoint).
    #[error("rank {rank}: {message}")]
    Rank { rank: usize, message: String },
    /// A write of the run folder failed (disk full, read-only or removed folder): the run stops, its
    /// last complete checkpoint is untouched.
    #[error("step {step}: cannot write {what}: {source}; {kept}")]
    Write {
        step: u64,
        what: String,
        source: Box<TrainError>,
        /// Which checkpoint a `--resume` continues from.
        kept: String,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |source| TrainError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn run_err(path: &Path, message: impl std::fmt::Display) -> TrainError {
    TrainError::Run {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// Everything about how to train (saved in `config.json` beside the model config).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Dataset folders (`synthetic:two-planes` for the built-in analytic scene).
    pub data: Vec<PathBuf>,
    /// Total number of steps of the run.
    pub steps: u64,
    /// Tuples per step (over all devices).
    pub batch: usize,
    pub sample: SampleConfig,
    pub loss: LossKind,
    pub learning_rate: f64,
    /// Global gradient-norm threshold (paper: 8.0).
    pub clip_norm: f64,
    pub checkpoint_every: u64,
    pub keep_checkpoints: usize,
    pub seed: u64,
    /// Devices (`cpu`, `wgpu`, `wgpu:N`, `cuda:N`); the first one holds the master weights.
    pub devices: Vec<String>,
    /// Hold out every n-th view of LLFF/COLMAP/light-field scenes (0 or 1: none).
    pub holdout_every: usize,
    /// Recompute each net's activations during the backward pass instead of keeping them (the paper's
    /// gradient checkpointing; see [`recompute`]). Default: on for models with more than 2 nets. Absent
    /// in older `config.json` files: off (their behaviour then).
    #[serde(default)]
    pub recompute: bool,
    /// Weights folder (or checkpoint) the run started from instead of a random initialisation
    /// (fine-tuning); the model configuration is then the one saved with those weights.
    #[serde(default)]
    pub init: Option<PathBuf>,
}

impl TrainConfig {
    /// Defaults for `model`: paper learning rate and clipping, VGG loss, 32x32 crops, the model's
    /// training plane count, 2..=4 views (or the preset's fixed count), batch 1.
    pub fn defaults(model: &DeepViewConfig) -> Self {
        let (lo, hi) = match model.views {
            Some(k) => (k, k),
            None => (2, 4),
        };
        Self {
            data: Vec::new(),
            steps: 1000,
            batch: 1,
            sample: SampleConfig {
                crop: 32,
                views_min: lo,
                views_max: hi,
                planes: model.train_planes,
                jitter: true,
                auto_planes: false,
                colour_jitter: false,
                wide_inputs: 0.0,
            },
            loss: LossKind::Vgg,
            learning_rate: PAPER_LEARNING_RATE,
            clip_norm: clip::PAPER_CLIP_NORM,
            checkpoint_every: 500,
            keep_checkpoints: 3,
            seed: 0,
            devices: vec!["cpu".into()],
            holdout_every: 8,
            recompute: model.nets() > 2,
            init: None,
        }
    }

    pub fn validate(&self) -> Result<(), TrainError> {
        let bad = |m: String| Err(TrainError::Config(m));
        if self.batch == 0 {
            return bad("batch must be at least 1".into());
        }
        if self.sample.crop < 4 {
            return bad(format!(
                "crop {} is too small (at least 4)",
                self.sample.crop
            ));
        }
        if self.sample.views_min == 0 || self.sample.views_min > self.sample.views_max {
            return bad(format!(
                "bad view range {}..={}",
                self.sample.views_min, self.sample.views_max
            ));
        }
        if self.sample.planes == 0 {
            return bad("planes must be at least 1".into());
        }
        if !(self.learning_rate > 0.0 && self.learning_rate.is_finite()) {
            return bad(format!(
                "learning rate {} must be positive",
                self.learning_rate
            ));
        }
        if self.clip_norm.is_nan() || self.clip_norm <= 0.0 {
            return bad(format!("clip norm {} must be positive", self.clip_norm));
        }
        if self.devices.is_empty() {
            return bad("no devices".into());
        }
        if self.checkpoint_every == 0 || self.keep_checkpoints == 0 {
            return bad("checkpoint_every and keep_checkpoints must be at least 1".into());
        }
        Ok(())
    }
}

/// `config.json` of a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunConfig {
    pub model: DeepViewConfig,
    pub train: TrainConfig,
}

/// `state.json` of a checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointState {
    pub step: u64,
    pub rng: Rng,
    /// Training wall time up to this checkpoint (seconds, over all sessions).
    pub wall_time_s: f64,
}

/// What one step did.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    pub step: u64,
    /// Mean loss of the batch (NaN if skipped because of it).
    pub loss: f64,
    /// Global gradient norm before clipping (NaN when not computed).
    pub grad_norm: f64,
    pub views: usize,
    /// Why the step was skipped (weights untouched), if it was.
    pub skipped: Option<String>,
}

/// A wgpu device, initialised once per name (burn refuses a second initialisation of the same runtime)
/// through the options API, which reports a missing adapter as an error instead of panicking at the
/// first tensor operation. `wgpu` is the default adapter (a GPU, or a CPU Vulkan driver such as Mesa's
/// lavapipe), `wgpu:N` the N-th discrete GPU.
#[cfg(feature = "wgpu")]
fn wgpu_device(name: &str, index: Option<usize>) -> Result<Device, String> {
    use burn::tensor::DeviceKind;
    use std::sync::{Mutex, OnceLock};
    static DEVICES: OnceLock<Mutex<Vec<(String, Device)>>> = OnceLock::new();
    let mut cache = DEVICES
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    if let Some((_, d)) = cache.iter().find(|(n, _)| n == name) {
        return Ok(d.clone());
    }
    let kind = match index {
        Some(i) => DeviceKind::DiscreteGpu(i),
        None => DeviceKind::DefaultDevice,
    };
    let device = Device::wgpu_options()
        .device_kind(kind)
        .init()
        .map_err(|e| format!("cannot initialise the wgpu device: {e}"))?;
    cache.push((name.to_string(), device.clone()));
    Ok(device)
}

/// Parse a device name: `cpu` (burn's flex backend), `wgpu`/`wgpu:N` (feature `wgpu`), `cuda`/`cuda:N`
/// (feature `cuda`). The index `local` is the process's rank on its machine under an MPI launcher
/// (`cuda:local`: one GPU per rank), see [`dist::local_rank`].
pub fn parse_device(name: &str) -> Result<Device, TrainError> {
    let err = |m: &str| TrainError::Device {
        name: name.to_string(),
        message: m.to_string(),
    };
    let (kind, index) = match name.split_once(':') {
        Some((k, "local")) => (k, Some(dist::local_rank())),
        Some((k, i)) => (
            k,
            Some(
                i.parse::<usize>()
                    .map_err(|_| err("the index after ':' must be a number or `local`"))?,
            ),
        ),
        None => (name, None),
    };
    match kind {
        "cpu" | "flex" => Ok(Device::flex()),
        #[cfg(feature = "wgpu")]
        "wgpu" => wgpu_device(name, index).map_err(|m| err(&m)),
        #[cfg(not(feature = "wgpu"))]
        "wgpu" => {
            let _ = index;
            Err(err(
                "this build has no wgpu support (rebuild with `--features wgpu`)",
            ))
        }
        #[cfg(feature = "cuda")]
        "cuda" => Ok(Device::cuda(index.unwrap_or(0))),
        #[cfg(not(feature = "cuda"))]
        "cuda" => Err(err(
            "this build has no CUDA support (rebuild with `--features cuda`)",
        )),
        _ => Err(err("unknown device (expected cpu, wgpu[:N] or cuda[:N])")),
    }
}

/// The model inputs of a tuple on `device` (its training window, shrinking by the nets' margins).
pub fn example_inputs(ex: &Example, device: &Device) -> ModelInputs {
    let images = ex
        .images
        .iter()
        .map(|im| {
            image_tensor(
                &im.data,
                im.width as usize,
                im.height as usize,
                im.channels,
                device,
            )
        })
        .collect();
    let (_, _, ww, wh) = ex.window;
    ModelInputs {
        images,
        mpi_to_view: ex.mpi_to_view.clone(),
        height: wh,
        width: ww,
        shrink: true,
    }
}

/// The loss of one tuple, shape `[1]`: run the model on the tuple's window, render the output MPI into
/// the target crop and compare.
pub fn example_loss(
    model: &DeepViewModel,
    loss: &Loss,
    ex: &Example,
    device: &Device,
) -> Tensor<1> {
    let out = model.forward(&example_inputs(ex, device));
    loss_tail(out.rgba, out.offset, ex, loss, device)
}

/// Render the model's output MPI `rgba` (at `offset` in the tuple's window) into the target crop and
/// compare: the loss `[1]`.
pub fn loss_tail(
    rgba: Tensor<4>,
    offset: (usize, usize),
    ex: &Example,
    loss: &Loss,
    device: &Device,
) -> Tensor<1> {
    let (ox, oy) = offset;
    let view_to_mpi: Vec<Hom> = ex
        .window_to_target
        .iter()
        .map(|h| invert(&crop_output(h, ox as f64, oy as f64)))
        .collect();
    let (c, r) = (
        ex.target_crop.width as usize,
        ex.target_crop.height as usize,
    );
    let pred = render_view(rgba, &view_to_mpi, r, c)
        .render
        .reshape([1, 3, r, c]);
    let target = image_tensor(&ex.target_crop.data, c, r, ex.target_crop.channels, device)
        .reshape([1, 3, r, c]);
    loss.per_example(pred, target)
}

/// All parameter values of a module, flattened in visiting order (for tests and comparisons).
pub fn parameter_values<M: Module>(module: &M) -> Vec<f32> {
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0
                .extend(param.val().into_data().convert::<f32>().iter::<f32>());
        }
    }
    let mut c = Collect(Vec::new());
    module.visit(&mut c);
    c.0
}

/// Loss of one tuple and the parameter gradients of `loss / batch` with the ordinary backward pass
/// (all activations kept); `None` gradients when the loss is not finite.
pub fn loss_and_grads_full(
    model: &DeepViewModel,
    loss: &Loss,
    ex: &Example,
    device: &Device,
    batch: usize,
) -> (f32, Option<GradientsParams>) {
    let l = example_loss(model, loss, ex, device);
    let v = l.clone().into_scalar::<f32>();
    if !v.is_finite() {
        return (v, None);
    }
    (
        v,
        Some(GradientsParams::from_grads(
            (l / batch as f32).backward(),
            model,
        )),
    )
}

/// One replica's work: per-example forward/backward, gradients summed on the replica's device.
fn run_replica(
    model: &DeepViewModel,
    loss: &Loss,
    examples: &[Example],
    device: &Device,
    batch: usize,
    recompute: bool,
) -> (Option<GradientsParams>, Vec<f32>) {
    let inner = device.clone().inner();
    let mut acc: Option<GradientsParams> = None;
    let mut losses = Vec::with_capacity(examples.len());
    for ex in examples {
        let (v, g) = if recompute {
            recompute::loss_and_grads(model, loss, ex, device, batch)
        } else {
            loss_and_grads_full(model, loss, ex, device, batch)
        };
        losses.push(v);
        let Some(g) = g else {
            return (None, losses);
        };
        acc = Some(match acc {
            None => g,
            Some(a) => clip::sum_on_device(model, vec![a, g], &inner),
        });
    }
    (acc, losses)
}

/// A training run in progress.
pub struct Trainer {
    run_dir: PathBuf,
    pub config: RunConfig,
    pub model: DeepViewModel,
    optim: ModuleOptimizer,
    pub step: u64,
    pub rng: Rng,
    data: TrainData,
    /// Autodiff devices; the first holds the master weights.
    devices: Vec<Device>,
    /// One loss (VGG copy) per device.
    losses: Vec<Loss>,
    wall_offset: f64,
    session_start: Instant,
    session_steps: u64,
    /// `runs/<name>/.lock`, locked while this trainer lives (released by the system when the process
    /// dies, even by SIGKILL); `None` on ranks other than 0, which do not write the run folder.
    _lock: Option<std::fs::File>,
    /// The other processes of a distributed run ([`dist`]); `None`: this process alone.
    comm: Option<Rc<dyn Collective>>,
    /// Whether this process asked to stop before the current step (Ctrl-C), and whether any rank did
    /// (agreed at the step's reduction, so that every rank stops after the same step).
    stop_requested: bool,
    stop_agreed: bool,
}

/// The message of a burn store error, without its `Record I/O error:` prefix.
fn record_message(e: &impl std::fmt::Display) -> String {
    let m = e.to_string();
    m.strip_prefix("Record I/O error: ")
        .unwrap_or(&m)
        .to_string()
}

/// Lock `run_dir/.lock` so that two processes never train the same run at once (the file is held open
/// read-only: the folder can still be remounted read-only under a running trainer).
fn lock_run(run_dir: &Path) -> Result<std::fs::File, TrainError> {
    let path = run_dir.join(".lock");
    if !path.exists() {
        std::fs::File::create(&path).map_err(io_err(&path))?;
    }
    let f = std::fs::File::open(&path).map_err(io_err(&path))?;
    match f.try_lock() {
        Ok(()) => Ok(f),
        Err(std::fs::TryLockError::WouldBlock) => Err(run_err(
            run_dir,
            "another `deepview train` is training this run right now",
        )),
        Err(std::fs::TryLockError::Error(e)) => Err(io_err(&path)(e)),
    }
}

type Loaded = (DeepViewModel, ModuleOptimizer, CheckpointState);

/// The latest checkpoint of `run_dir` that loads (a damaged one is reported and skipped).
fn latest_loadable(
    run_dir: &Path,
    model: &DeepViewConfig,
    device: &Device,
) -> Result<(u64, Loaded), TrainError> {
    let checkpoints = list_checkpoints(run_dir)?;
    if checkpoints.is_empty() {
        return Err(run_err(
            run_dir,
            "no complete checkpoint to resume from (checkpoints/step-*)",
        ));
    }
    for (step, ck) in checkpoints.iter().rev() {
        match load_checkpoint(ck, *step, model, device) {
            Ok(l) => return Ok((*step, l)),
            Err(e) => eprintln!("warning: skipping checkpoint {}: {e}", ck.display()),
        }
    }
    Err(run_err(run_dir, "no checkpoint of this run loads"))
}

/// Load the model, optimizer and state of checkpoint `ck` (the folder of step `step`).
fn load_checkpoint(
    ck: &Path,
    step: u64,
    model: &DeepViewConfig,
    device: &Device,
) -> Result<Loaded, TrainError> {
    let state_path = ck.join("state.json");
    let text = std::fs::read_to_string(&state_path).map_err(io_err(&state_path))?;
    let state: CheckpointState =
        serde_json::from_str(&text).map_err(|e| run_err(&state_path, e))?;
    if state.step != step {
        return Err(run_err(
            &state_path,
            format!("says step {} but the folder is step {step}", state.step),
        ));
    }
    let model_path = ck.join("model.bpk");
    if !model_path.is_file() {
        return Err(run_err(&model_path, "missing"));
    }
    let model = DeepViewModel::new(model, device)
        .try_load_file(&model_path)
        .map_err(|e| run_err(&model_path, format!("{e:?}")))?;
    let optim_path = ck.join("optimizer.bpk");
    if !optim_path.is_file() {
        return Err(run_err(&optim_path, "missing"));
    }
    let optim = adam()
        .load(&optim_path)
        .map_err(|e| run_err(&optim_path, format!("{e:?}")))?;
    Ok((model, optim, state))
}

fn adam() -> ModuleOptimizer {
    // TensorFlow's Adam defaults (the paper's framework): beta 0.9 / 0.999, epsilon 1e-8.
    AdamConfig::new().with_epsilon(1e-8).init()
}

fn make_losses(kind: LossKind, devices: &[Device]) -> Result<Vec<Loss>, TrainError> {
    match kind {
        LossKind::L1 => Ok(devices.iter().map(|_| Loss::L1).collect()),
        LossKind::Vgg => {
            let vgg = Vgg16::load_default(&devices[0])?;
            Ok(devices
                .iter()
                .map(|d| Loss::Vgg(Box::new(vgg.clone().to_device(d))))
                .collect())
        }
    }
}

/// Write `bytes` to `path` atomically: a temporary file in the same folder, flushed to disk, then
/// renamed over `path` (a crash leaves either the old or the new content, never a torn file).
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), TrainError> {
    deepview_image::write_atomic_with(path, bytes, deepview_image::Durability::Synced)
        .map_err(io_err(path))
}

/// Flush a folder's entries (renames, new files) to disk; best effort (not every filesystem allows it).
fn sync_dir(dir: &Path) {
    if let Ok(f) = std::fs::File::open(dir) {
        let _ = f.sync_all();
    }
}

/// Flush a file's content to disk.
fn sync_file(path: &Path) -> Result<(), TrainError> {
    std::fs::File::open(path)
        .and_then(|f| f.sync_all())
        .map_err(io_err(path))
}

/// The files of a complete checkpoint folder.
pub const CHECKPOINT_FILES: [&str; 3] = ["model.bpk", "optimizer.bpk", "state.json"];

/// Whether `dir` holds all the files of a checkpoint (a folder named `step-N` only appears once it is
/// complete, see [`Trainer::save_checkpoint`]; this also rejects one damaged by hand or by the disk).
pub fn checkpoint_is_complete(dir: &Path) -> bool {
    CHECKPOINT_FILES
        .iter()
        .all(|f| std::fs::metadata(dir.join(f)).is_ok_and(|m| m.is_file() && m.len() > 0))
}

/// The complete checkpoints of a run folder, sorted by step (`checkpoints/step-N` folders holding every
/// file of [`CHECKPOINT_FILES`]; temporary folders of an interrupted write are not listed).
pub fn list_checkpoints(run_dir: &Path) -> Result<Vec<(u64, PathBuf)>, TrainError> {
    let dir = run_dir.join("checkpoints");
    if !dir.is_dir() {
        return Ok(Vec::new());
    }
    let mut out = Vec::new();
    for e in std::fs::read_dir(&dir).map_err(io_err(&dir))? {
        let e = e.map_err(io_err(&dir))?;
        let name = e.file_name().to_string_lossy().to_string();
        if let Some(n) = name
            .strip_prefix("step-")
            .and_then(|s| s.parse::<u64>().ok())
            && checkpoint_is_complete(&e.path())
        {
            out.push((n, e.path()));
        }
    }
    out.sort();
    Ok(out)
}

impl Trainer {
    /// Start a new run in `run_dir` (created; an error if it already holds checkpoints).
    pub fn create(run_dir: &Path, config: RunConfig, data: TrainData) -> Result<Self, TrainError> {
        Self::create_on(run_dir, config, data, None)
    }

    /// [`Trainer::create`] as one rank of `comm` (every rank calls it; rank 0 writes the run folder and
    /// its initial weights are broadcast to the others).
    pub fn create_on(
        run_dir: &Path,
        config: RunConfig,
        data: TrainData,
        comm: Option<Rc<dyn Collective>>,
    ) -> Result<Self, TrainError> {
        config
            .model
            .validate()
            .map_err(|e| TrainError::Config(e.to_string()))?;
        config.train.validate()?;
        let writer = comm.as_ref().is_none_or(|c| c.rank() == 0);
        let devices = Self::devices(&config.train.devices)?;
        let mut lock = None;
        if writer {
            if !list_checkpoints(run_dir)?.is_empty() {
                return Err(run_err(
                    run_dir,
                    "this run already has checkpoints: pass --resume to continue it, or choose another --name",
                ));
            }
            std::fs::create_dir_all(run_dir.join("checkpoints")).map_err(io_err(run_dir))?;
            lock = Some(lock_run(run_dir)?);
            let cfg_path = run_dir.join("config.json");
            write_atomic(
                &cfg_path,
                serde_json::to_string_pretty(&config)
                    .expect("serialisable")
                    .as_bytes(),
            )?;
            let _ = std::fs::remove_file(run_dir.join("metrics.jsonl"));
        }
        devices[0].seed(config.train.seed);
        let model = match &config.train.init {
            Some(init) => {
                let (model, init_config) =
                    deepview_net::weights::load_model(init, &devices[0]).map_err(|e| run_err(init, e))?;
                if init_config != config.model {
                    return Err(run_err(
                        init,
                        "the run's model configuration differs from the one saved with these weights",
                    ));
                }
                model
            }
            None => DeepViewModel::new(&config.model, &devices[0]),
        };
        // Materialise lazily initialised parameters now, right after seeding.
        let mut values = parameter_values(&model);
        let model = match &comm {
            Some(c) => {
                // Rank 0's initial weights everywhere.
                c.broadcast_f32(&mut values);
                if c.rank() == 0 {
                    model
                } else {
                    dist::with_parameter_values(model, &values)
                }
            }
            None => model,
        };
        let losses = make_losses(config.train.loss, &devices)?;
        Ok(Self {
            run_dir: run_dir.to_path_buf(),
            rng: Rng::new(config.train.seed),
            config,
            model,
            optim: adam(),
            step: 0,
            data,
            devices,
            losses,
            wall_offset: 0.0,
            session_start: Instant::now(),
            session_steps: 0,
            _lock: lock,
            comm,
            stop_requested: false,
            stop_agreed: false,
        })
    }

    /// Continue the run in `run_dir` from its latest checkpoint. `steps` overrides the total number of
    /// steps, `devices` the devices (neither changes the result of a step on CPU).
    pub fn resume(
        run_dir: &Path,
        data: TrainData,
        steps: Option<u64>,
        devices: Option<Vec<String>>,
    ) -> Result<Self, TrainError> {
        Self::resume_on(run_dir, data, steps, devices, None)
    }

    /// [`Trainer::resume`] as one rank of `comm`: rank 0 chooses the checkpoint (its latest one that
    /// loads), every rank loads that one (the runs folder must be visible to every rank), and the ranks
    /// check that they hold the same weights.
    pub fn resume_on(
        run_dir: &Path,
        data: TrainData,
        steps: Option<u64>,
        devices: Option<Vec<String>>,
        comm: Option<Rc<dyn Collective>>,
    ) -> Result<Self, TrainError> {
        let cfg_path = run_dir.join("config.json");
        let text = std::fs::read_to_string(&cfg_path).map_err(io_err(&cfg_path))?;
        let mut config: RunConfig =
            serde_json::from_str(&text).map_err(|e| run_err(&cfg_path, e))?;
        if let Some(s) = steps {
            config.train.steps = s;
        }
        if let Some(d) = devices {
            config.train.devices = d;
        }
        config.train.validate()?;
        let rank = comm.as_ref().map_or(0, |c| c.rank());
        let devices = Self::devices(&config.train.devices)?;
        let mut lock = None;
        let loaded = if rank == 0 {
            let found = lock_run(run_dir).and_then(|l| {
                lock = Some(l);
                latest_loadable(run_dir, &config.model, &devices[0])
            });
            if let Some(c) = &comm {
                let mut step = [found.as_ref().map_or(u64::MAX, |f| f.0)];
                c.broadcast_u64(&mut step);
            }
            found?
        } else {
            let c = comm.as_ref().expect("rank > 0 has a communicator");
            let mut step = [0];
            c.broadcast_u64(&mut step);
            let step = step[0];
            let rank_err = |message: String| TrainError::Rank { rank, message };
            if step == u64::MAX {
                return Err(rank_err("rank 0 found no checkpoint to resume from".into()));
            }
            let ck = run_dir.join("checkpoints").join(format!("step-{step:07}"));
            let l = load_checkpoint(&ck, step, &config.model, &devices[0]).map_err(|e| {
                rank_err(format!(
                    "cannot load the checkpoint rank 0 resumes from ({e}); the runs folder must be \
                     shared by all ranks"
                ))
            })?;
            (step, l)
        };
        let (step, (model, optim, state)) = loaded;
        let losses = make_losses(config.train.loss, &devices)?;
        let trainer = Self {
            run_dir: run_dir.to_path_buf(),
            config,
            model,
            optim,
            step,
            rng: state.rng,
            data,
            devices,
            losses,
            wall_offset: state.wall_time_s,
            session_start: Instant::now(),
            session_steps: 0,
            _lock: lock,
            comm,
            stop_requested: false,
            stop_agreed: false,
        };
        trainer.check_replicas()?;
        if trainer.is_writer() {
            trainer.remove_leftovers();
            trainer.truncate_metrics()?;
        }
        Ok(trainer)
    }

    fn devices(names: &[String]) -> Result<Vec<Device>, TrainError> {
        names
            .iter()
            .map(|n| parse_device(n).map(|d| d.autodiff()))
            .collect()
    }

    pub fn run_dir(&self) -> &Path {
        &self.run_dir
    }

    /// Whether this process writes the run folder and prints (rank 0, or a run without ranks).
    pub fn is_writer(&self) -> bool {
        self.comm.as_ref().is_none_or(|c| c.rank() == 0)
    }

    /// `(rank, number of ranks)`: `(0, 1)` without a communicator.
    pub fn rank(&self) -> (usize, usize) {
        self.comm.as_ref().map_or((0, 1), |c| (c.rank(), c.size()))
    }

    /// With ranks: an error on every rank unless all hold bit-identical weights.
    pub fn check_replicas(&self) -> Result<(), TrainError> {
        let Some(c) = &self.comm else {
            return Ok(());
        };
        let h = dist::hash_values(&parameter_values(&self.model));
        let mut root = [h];
        c.broadcast_u64(&mut root);
        let mut differ = [(root[0] != h) as u8 as f32];
        c.all_reduce_sum(&mut differ);
        if differ[0] > 0.0 {
            return Err(TrainError::Rank {
                rank: c.rank(),
                message: format!(
                    "the weights of {} rank(s) differ from rank 0's at step {} (replicas out of sync{})",
                    differ[0],
                    self.step,
                    if root[0] != h {
                        ", this one among them"
                    } else {
                        ""
                    }
                ),
            });
        }
        Ok(())
    }

    /// Steps per second in this session.
    pub fn steps_per_second(&self) -> f64 {
        self.session_steps as f64 / self.session_start.elapsed().as_secs_f64().max(1e-9)
    }

    /// Total training wall time (all sessions).
    pub fn wall_time(&self) -> f64 {
        self.wall_offset + self.session_start.elapsed().as_secs_f64()
    }

    /// Draw a batch with the run's RNG.
    pub fn draw_batch(&mut self) -> Result<Vec<Example>, TrainError> {
        let t = &self.config.train;
        let k = self.data.draw_views(&t.sample, &mut self.rng);
        (0..t.batch)
            .map(|_| {
                self.data
                    .sample(&t.sample, &self.config.model, k, &mut self.rng)
                    .map_err(TrainError::from)
            })
            .collect()
    }

    /// One training step on a freshly drawn batch.
    pub fn train_step(&mut self) -> Result<StepReport, TrainError> {
        let batch = self.draw_batch()?;
        Ok(self.step_on(batch))
    }

    /// One training step on a given batch (the step counter advances even when the step is skipped).
    /// With ranks, `batch` is the global batch (the same on every rank) and this rank computes its
    /// share of it ([`dist`]).
    pub fn step_on(&mut self, batch: Vec<Example>) -> StepReport {
        self.step += 1;
        self.session_steps += 1;
        let n = batch.len();
        let views = batch.first().map_or(0, |e| e.inputs.len());
        let (rank, size) = self.rank();
        let mine = dist::share(n, rank, size);
        let local = &batch[mine.clone()];
        let m = local.len();
        let nd = self.devices.len().min(m.max(1));
        let recompute = self.config.train.recompute;
        let ranges: Vec<std::ops::Range<usize>> =
            (0..nd).map(|i| i * m / nd..(i + 1) * m / nd).collect();
        let results: Vec<(Option<GradientsParams>, Vec<f32>)> = if nd == 1 {
            vec![run_replica(
                &self.model,
                &self.losses[0],
                local,
                &self.devices[0],
                n,
                recompute,
            )]
        } else {
            std::thread::scope(|scope| {
                let handles: Vec<_> = ranges
                    .iter()
                    .enumerate()
                    .map(|(i, r)| {
                        let chunk = &local[r.clone()];
                        let device = self.devices[i].clone();
                        let model = if i == 0 {
                            self.model.clone()
                        } else {
                            self.model.clone().fork(&device)
                        };
                        let loss = self.losses[i].clone();
                        scope
                            .spawn(move || run_replica(&model, &loss, chunk, &device, n, recompute))
                    })
                    .collect();
                handles
                    .into_iter()
                    .map(|h| h.join().expect("replica thread panicked"))
                    .collect()
            })
        };
        // The loss of every tuple of the batch at its index (0 where another rank computed it, or where
        // a replica stopped after a non-finite loss).
        let mut losses = vec![0.0f32; n];
        for (r, (_, l)) in ranges.iter().zip(&results) {
            losses[mine.start + r.start..][..l.len()].copy_from_slice(l);
        }
        let main = self.devices[0].clone().inner();
        let sets: Vec<GradientsParams> = results.into_iter().filter_map(|r| r.0).collect();
        let mut grads = clip::sum_on_device(&self.model, sets, &main);
        if let Some(c) = &self.comm {
            // One reduction: gradient sums, has-gradient flags, the tuples' losses, the stop flag.
            let mut flat = dist::flatten_grads(&self.model, Some(&grads));
            let g = flat.len();
            flat.extend_from_slice(&losses);
            flat.push(self.stop_requested as u8 as f32);
            c.all_reduce_sum(&mut flat);
            self.stop_agreed = flat[g + n] > 0.0;
            losses.copy_from_slice(&flat[g..g + n]);
            grads = dist::unflatten_grads(&self.model, &flat[..g], &main);
        }
        let mean = losses.iter().map(|&v| v as f64).sum::<f64>() / n.max(1) as f64;
        let mut report = StepReport {
            step: self.step,
            loss: mean,
            grad_norm: f64::NAN,
            views,
            skipped: None,
        };
        if let Some(i) = losses.iter().position(|v| !v.is_finite()) {
            let ex = &batch[i];
            let on_rank = if size > 1 {
                let r = (0..size)
                    .find(|&r| dist::share(n, r, size).contains(&i))
                    .unwrap_or(0);
                format!(", rank {r}")
            } else {
                String::new()
            };
            report.skipped = Some(format!(
                "step {}: non-finite loss ({}) on tuple {i} (scene {}, target view {}, inputs {:?}{on_rank}); step \
                 skipped, weights unchanged",
                self.step, losses[i], self.data.scenes[ex.scene].name, ex.target, ex.inputs
            ));
            return report;
        }
        let (grads, norm) = clip::clip_global_norm(&self.model, grads, self.config.train.clip_norm);
        report.grad_norm = norm;
        if !norm.is_finite() {
            report.skipped = Some(format!(
                "step {}: non-finite gradient norm ({norm}); step skipped, weights unchanged",
                self.step
            ));
            return report;
        }
        let model = self.model.clone();
        self.model = self
            .optim
            .step(self.config.train.learning_rate, model, grads);
        report
    }

    /// Write a checkpoint of the current state and prune old ones. Returns its folder.
    ///
    /// The files go into `checkpoints/.tmp-step-N-PID/`, are flushed to disk, and the folder is renamed
    /// to `step-N` (a process killed at any moment leaves either no `step-N` or a complete one; the
    /// temporary folder is removed on the next `--resume`). A failed write (disk full, read-only
    /// folder) removes the temporary folder and is a [`TrainError::Write`] naming the checkpoint that is
    /// kept. Old checkpoints beyond `keep_checkpoints` are renamed to `.old-step-N` and then removed, so
    /// a kill during the removal never leaves a damaged `step-N`.
    ///
    /// With ranks every rank calls it (the ranks first check that their weights agree); only rank 0
    /// writes.
    pub fn save_checkpoint(&self) -> Result<PathBuf, TrainError> {
        let dir = self.run_dir.join("checkpoints");
        let done = dir.join(format!("step-{:07}", self.step));
        self.check_replicas()?;
        if !self.is_writer() {
            return Ok(done);
        }
        if checkpoint_is_complete(&done) {
            // Already written (a run resumed at a checkpoint it had saved but maybe not pruned after,
            // when it was killed in between): prune now.
            self.prune_checkpoints();
            return Ok(done);
        }
        let tmp = dir.join(format!(".tmp-step-{:07}-{}", self.step, std::process::id()));
        if let Err(e) = self.write_checkpoint(&dir, &tmp, &done) {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(self.write_error(format!("the checkpoint {}", done.display()), e));
        }
        sync_dir(&dir);
        self.prune_checkpoints();
        Ok(done)
    }

    fn write_checkpoint(&self, dir: &Path, tmp: &Path, done: &Path) -> Result<(), TrainError> {
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        if tmp.exists() {
            std::fs::remove_dir_all(tmp).map_err(io_err(tmp))?;
        }
        std::fs::create_dir(tmp).map_err(io_err(tmp))?;
        let model_path = tmp.join("model.bpk");
        self.model
            .clone()
            .save_file(&model_path)
            .map_err(|e| run_err(&model_path, record_message(&e)))?;
        sync_file(&model_path)?;
        let optim_path = tmp.join("optimizer.bpk");
        self.optim
            .save(&optim_path)
            .map_err(|e| run_err(&optim_path, record_message(&e)))?;
        sync_file(&optim_path)?;
        let state = CheckpointState {
            step: self.step,
            rng: self.rng,
            wall_time_s: self.wall_time(),
        };
        let state_path = tmp.join("state.json");
        let bytes = serde_json::to_string_pretty(&state).expect("serialisable");
        std::fs::File::create(&state_path)
            .and_then(|mut f| {
                f.write_all(bytes.as_bytes())?;
                f.sync_all()
            })
            .map_err(io_err(&state_path))?;
        sync_dir(tmp);
        if done.exists() {
            // A `step-N` without all its files (damaged by hand or by the disk): replace it.
            let stale = dir.join(format!(".old-step-{:07}-{}", self.step, std::process::id()));
            std::fs::rename(done, &stale).map_err(io_err(done))?;
            let _ = std::fs::remove_dir_all(&stale);
        }
        std::fs::rename(tmp, done).map_err(io_err(done))
    }

    /// A [`TrainError::Write`] for a failed write of `what` at the current step.
    fn write_error(&self, what: String, source: TrainError) -> TrainError {
        let kept = match list_checkpoints(&self.run_dir)
            .ok()
            .and_then(|mut v| v.pop())
        {
            Some((step, p)) => format!(
                "the last complete checkpoint {} (step {step}) is kept: free space or fix the folder, then \
                 --resume",
                p.display()
            ),
            None => "the run has no complete checkpoint yet".into(),
        };
        TrainError::Write {
            step: self.step,
            what,
            source: Box::new(source),
            kept,
        }
    }

    /// Remove all but the last `keep_checkpoints` checkpoints (failures are warnings: the new checkpoint
    /// is complete either way).
    fn prune_checkpoints(&self) {
        let Ok(all) = list_checkpoints(&self.run_dir) else {
            return;
        };
        let keep = self.config.train.keep_checkpoints.max(1);
        for (step, p) in all.iter().take(all.len().saturating_sub(keep)) {
            let trash = p.with_file_name(format!(".old-step-{step:07}-{}", std::process::id()));
            let r = std::fs::rename(p, &trash).and_then(|_| std::fs::remove_dir_all(&trash));
            if let Err(e) = r {
                eprintln!(
                    "warning: cannot remove the old checkpoint {}: {e}",
                    p.display()
                );
            }
        }
    }

    /// Remove what a killed process left behind: temporary checkpoint folders (`.tmp-step-*`),
    /// half-removed old ones (`.old-step-*`) and temporary files of atomic writes.
    fn remove_leftovers(&self) {
        let remove = |dir: &Path, is_leftover: &dyn Fn(&str) -> bool| {
            let Ok(entries) = std::fs::read_dir(dir) else {
                return;
            };
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().to_string();
                if !is_leftover(&name) {
                    continue;
                }
                let p = e.path();
                let r = if p.is_dir() {
                    std::fs::remove_dir_all(&p)
                } else {
                    std::fs::remove_file(&p)
                };
                match r {
                    Ok(()) => eprintln!("removed {} (left by an interrupted run)", p.display()),
                    Err(err) => eprintln!("warning: cannot remove {}: {err}", p.display()),
                }
            }
        };
        remove(&self.run_dir.join("checkpoints"), &|n| {
            n.starts_with(".tmp-step-") || n.starts_with(".old-step-")
        });
        remove(&self.run_dir, &|n| {
            // `deepview_image::temp_path` of metrics.jsonl and config.json.
            (n.starts_with(".metrics.jsonl.") || n.starts_with(".config.json."))
                && n.ends_with(".tmp")
        });
    }

    /// Drop metric lines after the current step (written after the checkpoint we resume from).
    fn truncate_metrics(&self) -> Result<(), TrainError> {
        let path = self.run_dir.join("metrics.jsonl");
        let Ok(text) = std::fs::read_to_string(&path) else {
            return Ok(());
        };
        let kept: String = text
            .lines()
            .filter(|l| {
                serde_json::from_str::<serde_json::Value>(l)
                    .ok()
                    .and_then(|v| v.get("step").and_then(|s| s.as_u64()))
                    .is_some_and(|s| s <= self.step)
            })
            .map(|l| format!("{l}\n"))
            .collect();
        write_atomic(&path, kept.as_bytes())
    }

    fn append_metrics(&self, r: &StepReport) -> Result<(), TrainError> {
        let path = self.run_dir.join("metrics.jsonl");
        let num = |v: f64| {
            if v.is_finite() {
                serde_json::json!(v)
            } else {
                serde_json::Value::Null
            }
        };
        let line = serde_json::json!({
            "step": r.step,
            "loss": num(r.loss),
            "grad_norm": num(r.grad_norm),
            "views": r.views,
            "steps_per_s": num(self.steps_per_second()),
            "wall_time_s": self.wall_time(),
            "skipped": r.skipped.is_some(),
        });
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(io_err(&path))?;
        writeln!(f, "{line}").map_err(io_err(&path))
    }

    /// Train until `config.train.steps` or until `stop` is set (Ctrl-C), checkpointing every
    /// `checkpoint_every` steps and at the end. Returns the reports of this session's steps.
    pub fn run(
        &mut self,
        stop: &AtomicBool,
        progress: bool,
    ) -> Result<Vec<StepReport>, TrainError> {
        let total = self.config.train.steps;
        let writer = self.is_writer();
        let pb = if progress && writer {
            let pb = indicatif::ProgressBar::new(total);
            pb.set_style(
                indicatif::ProgressStyle::with_template(
                    "{bar:30.cyan/blue} {pos}/{len} {msg} [{elapsed_precise} < {eta_precise}]",
                )
                .expect("valid template"),
            );
            pb.set_position(self.step);
            pb
        } else {
            indicatif::ProgressBar::hidden()
        };
        let mut reports = Vec::new();
        let mut ema: Option<f64> = None;
        // With ranks, a stop (Ctrl-C on any rank) is agreed at the next step's reduction so that all
        // ranks stop after the same step.
        let stopping = |t: &Self| match t.comm {
            Some(_) => t.stop_agreed,
            None => stop.load(Ordering::SeqCst),
        };
        while self.step < total && !stopping(self) {
            self.stop_requested = stop.load(Ordering::SeqCst);
            let r = self.train_step()?;
            if writer {
                self.append_metrics(&r)
                    .map_err(|e| self.write_error("metrics.jsonl".into(), e))?;
            }
            if let Some(msg) = &r.skipped {
                if !writer {
                } else if progress {
                    pb.println(format!("warning: {msg}"));
                } else {
                    eprintln!("warning: {msg}");
                }
            } else {
                ema = Some(ema.map_or(r.loss, |e| 0.9 * e + 0.1 * r.loss));
            }
            pb.set_position(self.step);
            pb.set_message(format!(
                "loss {:.4} (avg {:.4}) {:.2} steps/s",
                r.loss,
                ema.unwrap_or(f64::NAN),
                self.steps_per_second()
            ));
            if self.step.is_multiple_of(self.config.train.checkpoint_every) {
                self.save_checkpoint()?;
            }
            reports.push(r);
        }
        self.save_checkpoint()?;
        pb.finish_and_clear();
        Ok(reports)
    }
}

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

/// Load training data: dataset folders through `deepview_data`, or `synthetic:two-planes`.
pub fn load_data(
    paths: &[PathBuf],
    opts: &deepview_data::LoadOptions,
    holdout_every: usize,
) -> Result<TrainData, TrainError> {
    let mut scenes = Vec::new();
    for p in paths {
        if p.to_str() == Some("synthetic:two-planes") {
            scenes.push(synthetic::two_plane_scene(4, 4, 96, 0.08));
        } else {
            scenes.push(TrainScene::load(p, opts, holdout_every)?);
        }
    }
    Ok(TrainData::new(scenes)?)
}

#[cfg(test)]
mod tests;
