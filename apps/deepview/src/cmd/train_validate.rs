//! `train --validate-every N`: a fixed validation set scored at checkpoints, into `validation.jsonl`.
//!
//! The set is the held-out views (every 8th) of the run's posed real datasets (LLFF, COLMAP,
//! transforms.json), downscaled to at most [`VALIDATION_WIDTH`] pixels wide, under both protocols of
//! issue 25: the 4 nearest inputs (16 px crop at full size, scaled) and the few-shot 3 spread inputs (no
//! crop). The learned method runs from the checkpoint exactly as `eval --method deepview --weights CK`
//! would. Synthetic data, light-field grids and Spaces rigs are not in it.

use super::progress::Progress;
use deepview_data::{LoadOptions, Scene, SceneFormat};
use deepview_eval::{EvalOptions, MpiPredictor, Protocol, TargetRule, evaluate};
use deepview_methods::{InputRule, MethodKind, MethodOptions, make_method};
use deepview_train::{DataSpec, TrainEvent};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The warning when a run asks for validation but has nothing to validate on.
pub const NO_SCENES: &str = "warning: --validate-every: the run has no posed real dataset (LLFF, COLMAP, \
    transforms.json) to hold views out of";

/// Images of the validation set are downscaled to at most this width.
pub const VALIDATION_WIDTH: u32 = 256;

/// The validation scenes of a run, loaded once (cameras only; images are read at each validation).
pub struct Validation {
    scenes: Vec<(String, Scene, u32)>,
    out: PathBuf,
    every: u64,
    last: Option<u64>,
}

impl Validation {
    /// The posed real datasets of `specs` (each with its own load options), scored every `every` steps
    /// into `run_dir/validation.jsonl`.
    pub fn new(specs: &[DataSpec], run_dir: &Path, every: u64) -> anyhow::Result<Self> {
        let mut scenes = Vec::new();
        for spec in specs {
            if deepview_train::is_synthetic(&spec.path) {
                continue;
            }
            // Full size: the validation chooses its own downscale.
            let load = LoadOptions {
                downscale: 1,
                ..spec.load.clone()
            };
            let scene = deepview_data::load_scene(&spec.path, &load)?;
            if !matches!(
                scene.format,
                SceneFormat::Llff | SceneFormat::Colmap | SceneFormat::Transforms
            ) || scene.len() < 9
            {
                continue;
            }
            let w = scene.views[0].camera.width;
            let factor = w.div_ceil(VALIDATION_WIDTH).max(1);
            scenes.push((spec.path.display().to_string(), scene, factor));
        }
        Ok(Self {
            scenes,
            out: run_dir.join("validation.jsonl"),
            every,
            last: None,
        })
    }

    /// Whether it holds any scene.
    pub fn is_empty(&self) -> bool {
        self.scenes.is_empty()
    }

    /// On a training event: at a checkpoint, [`Self::at_checkpoint`], said through `progress`.
    pub fn on_event(&mut self, e: &TrainEvent<'_>, progress: &Progress) {
        if let TrainEvent::Checkpoint { step, dir } = e {
            match self.at_checkpoint(*step, dir) {
                Ok(Some(line)) => progress.say(line),
                Ok(None) => {}
                Err(err) => progress.say(format!("warning: validation failed: {err:#}")),
            }
        }
    }

    /// At a checkpoint of `step` in `ck`: score it when a multiple of `every` was passed since the last
    /// validation, append one line per scene and protocol, and return a summary line.
    pub fn at_checkpoint(&mut self, step: u64, ck: &Path) -> anyhow::Result<Option<String>> {
        let due = match self.last {
            None => true,
            Some(l) => step / self.every > l / self.every,
        };
        if !due || self.scenes.is_empty() {
            return Ok(None);
        }
        self.last = Some(step);
        let budget = crate::cmd::args::default_budget(
            crate::cmd::args::available_memory().unwrap_or(4 << 30),
        );
        let options = MethodOptions {
            weights: Some(ck.to_path_buf()),
            ..Default::default()
        };
        let protocols: [(&str, InputRule, Option<u32>); 2] = [
            ("nearest:4", InputRule::Nearest(4), None),
            ("spread:3", InputRule::Spread(3), Some(0)),
        ];
        let mut lines = Vec::new();
        let mut means = vec![Vec::new(); protocols.len()];
        for (name, scene, factor) in &self.scenes {
            for (p, (label, inputs, crop)) in protocols.iter().enumerate() {
                let method = make_method(MethodKind::Deepview, &options, budget)?;
                let mut predictor = MpiPredictor::new(method, |_| {});
                let protocol =
                    Protocol::from_name("posed", Some(TargetRule::Every(8)), Some(inputs.clone()))?;
                let eval = EvalOptions {
                    downscale: *factor,
                    crop: *crop,
                    ..Default::default()
                };
                let r = evaluate(scene, &protocol, &mut predictor, &eval)?;
                means[p].push(r.results.ssim);
                lines.push(serde_json::json!({
                    "step": step,
                    "scene": name,
                    "protocol": label,
                    "downscale": factor,
                    "views": r.views.len(),
                    "ssim": r.results.ssim,
                    "psnr": r.results.psnr,
                }));
            }
        }
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.out)?;
        for l in &lines {
            writeln!(f, "{l}")?;
        }
        f.sync_data()?;
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        Ok(Some(format!(
            "validation at step {step} ({} scene{}): SSIM {:.4} (4 nearest), {:.4} (3 spread) -> {}",
            self.scenes.len(),
            if self.scenes.len() == 1 { "" } else { "s" },
            mean(&means[0]),
            mean(&means[1]),
            self.out.display()
        )))
    }
}
