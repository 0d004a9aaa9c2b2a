//! What a run is: the training configuration ([`TrainConfig`]) and `config.json` ([`RunConfig`]).

use crate::clip;
use crate::data::SampleConfig;
use crate::error::TrainError;
use crate::load::DataSpec;
use crate::loss::LossKind;
use deepview_net::config::DeepViewConfig;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The paper's learning rate.
pub const PAPER_LEARNING_RATE: f64 = 1.5e-4;

/// Everything about how to train (saved in `config.json` beside the model config).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// The datasets: folders (`synthetic:two-planes` for the built-in analytic scene) with their load
    /// options ([`DataSpec`]).
    pub data: Vec<DataSpec>,
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
    /// Devices (`cpu`, `wgpu`, `wgpu:N`, `wgpu:cpu`, `cuda:N`); the first one holds the master weights.
    pub devices: Vec<String>,
    /// Hold out every n-th view of LLFF/COLMAP/light-field scenes (0 or 1: none).
    pub holdout_every: usize,
    /// Recompute each net's activations during the backward pass instead of keeping them (the paper's
    /// gradient checkpointing; see [`crate::recompute`]). Default: on for models with more than 2 nets.
    pub recompute: bool,
    /// Weights folder (or checkpoint) the run started from instead of a random initialisation
    /// (fine-tuning); the model configuration is then the one saved with those weights.
    pub init: Option<PathBuf>,
    /// The folder the run was started from: relative dataset paths are read against it on resume, from
    /// wherever the run is resumed (`None`: against the current folder).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base: Option<PathBuf>,
    /// The VGG-16 weights file of the VGG losses (`--vgg-weights`, absolute; `None`: give `--vgg-weights`
    /// on resume).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vgg_weights: Option<PathBuf>,
    /// Score the validation set every N steps (`--validate-every`; kept for `--resume`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validate_every: Option<u64>,
}

/// The largest batch (tuples per step) a run may ask for.
pub const MAX_BATCH: usize = 256;

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
                surround_inputs: 0.0,
                spread_inputs: 0.0,
                window_context: false,
                budget: None,
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
            base: None,
            vgg_weights: None,
            validate_every: None,
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
        // Beyond these a step cannot be held in any machine's memory: a damaged config.json.
        for (v, max, name) in [
            (self.sample.planes, 1024, "planes"),
            (self.sample.crop, 4096, "crop"),
            (self.batch, MAX_BATCH, "batch"),
            (self.sample.views_max, 64, "views"),
        ] {
            if v > max {
                return bad(format!("{name} {v} is more than {max}"));
            }
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

impl RunConfig {
    /// Read a run's `config.json`.
    pub fn read(run_dir: &Path) -> Result<RunConfig, TrainError> {
        let path = run_dir.join("config.json");
        let text = std::fs::read_to_string(&path).map_err(|source| TrainError::Io {
            path: path.clone(),
            source,
        })?;
        serde_json::from_str(&text).map_err(|e| TrainError::Run {
            path,
            message: format!(
                "invalid run configuration ({e}); a run from an earlier release cannot be resumed: start a \
                 new --name"
            ),
        })
    }
}
