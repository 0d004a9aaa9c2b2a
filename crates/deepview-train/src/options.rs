//! `deepview train`'s options as one clap struct ([`TrainOptions`], flattened into the command): what the
//! user chose, every field optional. A new run applies them onto [`TrainConfig::defaults`]
//! ([`TrainOptions::config`]); a resumed run keeps its `config.json` and refuses a choice that differs
//! from it ([`TrainOptions::fixed_on_resume`]). Both directions live here, beside the config they map to.

use crate::config::{RunConfig, TrainConfig};
use crate::error::TrainError;
use crate::load::DataSpec;
use crate::loss::LossKind;
use deepview_net::config::{Census, DeepViewConfig, Smoothing};
use std::path::PathBuf;

/// Largest plane count of `--planes auto` in training (the cost of a step grows with it).
pub const TRAIN_AUTO_PLANES_MAX: usize = 64;

/// The training options of `deepview train` (see each one's help).
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
pub struct TrainOptions {
    /// Network preset: cpu, cpu-large, paper-kalantari, paper-spaces-4view, paper-spaces-12view
    /// (default: cpu). With --init: grow those weights into this larger preset first (the grown model
    /// computes the same MPI; the new feature channels and update nets then train).
    #[arg(long)]
    pub preset: Option<String>,
    /// Cost aggregation radius of the agreement prior in MPI pixels (`cpu` and `cpu-large`, whose
    /// prior it is): each plane's colour variance averaged over the (2r+1) x (2r+1) window around each
    /// pixel before the softmax over planes. Default: the preset's or --init's (0, per pixel). Kept in
    /// the weights' config.json; --init weights train on with a new radius (it has no parameters).
    #[arg(long, value_name = "R")]
    pub prior_radius: Option<usize>,
    /// The weight of the aggregation window's mean in the prior's variance, the rest being the pixel's
    /// own (0..1). Default: the preset's or --init's (1). Kept in the weights' config.json.
    #[arg(long, value_name = "A")]
    pub prior_weight: Option<f64>,
    /// The image size (larger side, pixels) up to which --prior-radius applies as it is; on larger
    /// images the radius grows in proportion (e.g. 512 with radius 5: radius 10 on 1024-pixel images),
    /// in training and inference alike. 0: one radius at every size. Default: the preset's or --init's
    /// (none: one radius at every size). Kept in the weights' config.json.
    #[arg(long, value_name = "PIXELS")]
    pub prior_radius_size: Option<u32>,
    /// Semi-global matching of the prior's costs over the planes, as penalties P1,P2 in the prior's
    /// logit units (e.g. 2,64: one plane's step between neighbouring pixels costs 2, a larger jump 64),
    /// or `off`. Default: the preset's (off) or --init's (the shipped weights: 2,128). Kept in the
    /// weights' config.json. Training smooths each window's prior on its own (inference: the whole
    /// image's), so paths are shorter in training.
    #[arg(long, value_name = "P1,P2|off", value_parser = parse_or_off::<Smoothing>)]
    pub prior_smoothing: Option<OrOff<Smoothing>>,
    /// A census term in the prior's matching cost, as WEIGHT[,RADIUS] (e.g. 0.03: 0.03 times the
    /// fraction of the views' census bits over the (2r+1)x(2r+1) window, 5x5 by default, that differ
    /// is added to each plane point's colour variance), or `off`. Default: the preset's (off) or --init's (the shipped weights:
    /// 0.015). Kept in the weights' config.json.
    #[arg(long, value_name = "WEIGHT[,RADIUS]|off", value_parser = parse_or_off::<Census>)]
    pub prior_census: Option<OrOff<Census>>,
    /// Occlusion-robust variance in the prior's matching cost, as the weight B of its leave-one-out
    /// part (0 < B <= 1, e.g. 0.75: where three or more views see a plane point, its colour variance
    /// becomes 1 - B times itself plus B times the least variance of the samples left when one view is
    /// left out), or `off`. Default: the preset's (off) or --init's. Kept in the weights' config.json.
    #[arg(long, value_name = "B|off", value_parser = parse_leave_one_out)]
    pub prior_leave_one_out: Option<OrOff<f32>>,
    /// The sample variance in the prior's matching cost: `on` (the variance of a point n >= 2 views see
    /// is scaled by n / (n - 1)) or `off`. Default: the preset's (off) or --init's. Kept in the
    /// weights' config.json.
    #[arg(long, value_name = "on|off", value_parser = parse_on_off)]
    pub prior_sample_variance: Option<bool>,
    /// Start from these weights instead of a random initialisation (fine-tuning): a weights folder
    /// (config.json + model.safetensors), a checkpoint folder, or `builtin` (the weights built into the
    /// program). The network
    /// configuration is the one saved with them, unless --preset names a larger one to grow them into.
    /// The optimizer starts afresh.
    #[arg(long, value_name = "WEIGHTS_DIR")]
    pub init: Option<PathBuf>,
    /// Total number of steps of the run (with --resume: the new total). Default 1000.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub steps: Option<u64>,
    /// Training tuples per step, split over the devices (default 1).
    #[arg(long, value_parser = parse_positive)]
    pub batch: Option<usize>,
    /// Target crop side in pixels (paper and default: 32).
    #[arg(long, value_parser = clap::value_parser!(u64).range(4..=4096))]
    pub crop: Option<u64>,
    /// Number of input views: `K` or a range `A..B` (inclusive) drawn per batch. Default: the preset's
    /// fixed count, or 2..4.
    #[arg(long, value_parser = parse_views)]
    pub views: Option<(usize, usize)>,
    /// MPI planes during training: a count (default: the preset's training plane count), or `auto` /
    /// `auto:MAX`: per tuple, the count `infer --planes auto` chooses for its inputs (1 px of disparity
    /// between planes), from 8 to MAX (default 64).
    #[arg(long, value_parser = parse_train_planes)]
    pub planes: Option<(bool, usize)>,
    /// Training loss: vgg (the paper's feature loss, default), vgg+ssim (plus 1e5 x (1 - SSIM), the
    /// evaluation metric) or l1.
    #[arg(long)]
    pub loss: Option<LossKind>,
    /// Learning rate (paper and default: 1.5e-4).
    #[arg(long, value_parser = parse_positive_f64)]
    pub lr: Option<f64>,
    /// Global gradient-norm clipping threshold (paper and default: 8).
    #[arg(long, value_parser = parse_positive_f64)]
    pub clip: Option<f64>,
    /// Comma-separated devices for data parallelism: cpu, wgpu[:N], wgpu:cpu (the CPU Vulkan
    /// adapter), cuda[:N] (GPU ones need a build with the features `wgpu` / `cuda`); under mpirun,
    /// wgpu:local or cuda:local gives each rank the GPU of its rank on its machine. Example: cpu,cpu.
    #[arg(long, value_parser = parse_devices)]
    pub devices: Option<DeviceList>,
    /// Write a checkpoint every N steps (and always at the end, on Ctrl-C or SIGTERM). Default 500.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub checkpoint_every: Option<u64>,
    /// Keep the last N checkpoints (older ones are removed after each new one; one holding files
    /// training did not write is kept, with a warning). Default: 3, or the run's own setting with
    /// --resume.
    #[arg(long, value_name = "N", value_parser = parse_positive)]
    pub keep_checkpoints: Option<usize>,
    /// Score the held-out views of the run's posed real datasets (4 nearest and 3 spread inputs, at most
    /// 256 px wide) at the session's first checkpoint and at the first one past every multiple of N steps,
    /// into runs/NAME/validation.jsonl (choose the checkpoint to ship by it). Kept in the run's
    /// config.json: --resume goes on validating (give it again to change N).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub validate_every: Option<u64>,
    /// Memory a training step may take, e.g. 12GiB, 800MiB, or auto (default): three quarters of the
    /// memory available when the session starts, leaving at least 1 GiB free. A tuple whose step would
    /// need more (wide spread inputs at a high resolution have large training windows) gets fewer planes,
    /// down to 8, or is drawn again. A property of the machine, not kept in config.json: give it on every
    /// session (--resume included) that needs another bound.
    #[arg(long, value_name = "SIZE")]
    pub max_memory: Option<String>,
    /// Random seed (weights initialisation and tuple sampling; default 0).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Disable the random jitter of plane depths.
    #[arg(long)]
    pub no_jitter: bool,
    /// Disable the colour and exposure jitter of training tuples (one random exposure and channel gain
    /// per tuple, +-5% exposure per input view).
    #[arg(long)]
    pub no_colour_jitter: bool,
    /// Probability (0..1) that a tuple's K inputs are K random views among the target's 3K nearest
    /// instead of its K nearest: wider, uneven baselines (default 0).
    #[arg(long, value_name = "P", value_parser = parse_probability)]
    pub wide_inputs: Option<f64>,
    /// Probability (0..1) that a tuple's K inputs surround the target: one random view per angular sector
    /// around it among its 3K nearest (rendering between the inputs, like the demo's corner views). A
    /// target with an empty sector (an edge view: extrapolation) is redrawn. Drawn before --wide-inputs;
    /// default 0.
    #[arg(long, value_name = "P", value_parser = parse_probability)]
    pub surround_inputs: Option<f64>,
    /// Probability (0..1) that a tuple's K inputs are spread over the whole capture (the 3-view
    /// protocol's `linspace` over the training views in name order, jittered) and its target any other
    /// training view: sparse inputs, targets between and beyond them. Drawn before --surround-inputs;
    /// default 0.
    #[arg(long, value_name = "P", value_parser = parse_probability)]
    pub spread_inputs: Option<f64>,
    /// Render the views for the update nets' gradient components from the agreement prior outside the
    /// training window (with the window's state inside) instead of a transparent MPI there: closer to
    /// inference's full MPI where wide inputs' rays leave the window. Off by default: it did not change
    /// the demo's outcome (BENCHMARKS.md, "The training window's context"). Kept in the run's config.
    #[arg(long)]
    pub window_context: bool,
    /// Downscale each dataset by the smallest integer factor that brings its images to at most W pixels
    /// wide, instead of one --downscale for all: scenes of different sizes train at their own factor
    /// (e.g. LLFF `images_4` at 2 and 256 px synthetic grids at 1 with `--max-width 512`). Each factor is
    /// kept in the run's config.json; with --resume it applies only to datasets the run did not have.
    #[arg(long, value_name = "W", conflicts_with = "downscale", value_parser = clap::value_parser!(u32).range(16..))]
    pub max_width: Option<u32>,
    /// Hold out every N-th view of LLFF/COLMAP/light-field scenes for evaluation (0: none; 1 would hold out
    /// every view). Default 8.
    #[arg(long, value_parser = parse_holdout)]
    pub holdout_every: Option<usize>,
    /// Recompute each net's activations during the backward pass (the paper's gradient checkpointing:
    /// peak memory of one net instead of all nets, one extra forward pass per step). Default: on for
    /// presets with more than 2 nets (all paper-* presets). Kept in the run's config.json.
    #[arg(long, conflicts_with = "no_recompute")]
    pub recompute: bool,
    /// Keep all activations for the backward pass (faster, more memory).
    #[arg(long)]
    pub no_recompute: bool,
    /// The VGG-16 weights of the VGG loss (vgg16_conv1_1-conv3_3.safetensors; the data folder's
    /// vgg16/README.md), kept in the run's config.json (as an absolute path) for --resume; give it again
    /// on resume to use another copy.
    #[arg(long, value_name = "FILE")]
    pub vgg_weights: Option<PathBuf>,
}

/// An option's value, or `off` (`None`): `--prior-smoothing`, `--prior-census`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrOff<T>(pub Option<T>);

/// `on` or `off`.
fn parse_on_off(s: &str) -> Result<bool, String> {
    match s.trim() {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("{s:?} is not `on` or `off`")),
    }
}

/// `off`, or a leave-one-out weight (`0 < B <= 1`).
fn parse_leave_one_out(s: &str) -> Result<OrOff<f32>, String> {
    if s.trim() == "off" {
        return Ok(OrOff(None));
    }
    deepview_net::config::parse_leave_one_out(s).map(|b| OrOff(Some(b)))
}

/// `off`, or what `T` parses.
fn parse_or_off<T: std::str::FromStr<Err = String>>(s: &str) -> Result<OrOff<T>, String> {
    if s.trim() == "off" {
        Ok(OrOff(None))
    } else {
        s.parse().map(|v| OrOff(Some(v)))
    }
}

impl TrainOptions {
    /// The network of a new run: `--init`'s saved configuration, or `--preset` (default `cpu`), which
    /// `--init`'s weights must be able to grow into.
    pub fn model(&self) -> Result<DeepViewConfig, TrainError> {
        let load = |dir: &std::path::Path| {
            deepview_net::weights::load_config_any(dir).map_err(|source| TrainError::Init {
                dir: dir.to_path_buf(),
                source,
            })
        };
        let cfg_err = TrainError::Refused;
        let mut cfg = self.model_before_radius(load)?;
        if let Some(r) = self.prior_radius {
            cfg.prior_radius = r;
            cfg.validate()
                .map_err(|e| cfg_err(format!("--prior-radius {r}: {e}")))?;
        }
        if let Some(a) = self.prior_weight {
            cfg.prior_weight = a;
            cfg.validate()
                .map_err(|e| cfg_err(format!("--prior-weight {a}: {e}")))?;
        }
        if let Some(n) = self.prior_radius_size {
            cfg.prior_radius_size = (n > 0).then_some(n);
            cfg.validate()
                .map_err(|e| cfg_err(format!("--prior-radius-size {n}: {e}")))?;
        }
        if let Some(OrOff(s)) = self.prior_smoothing {
            cfg.prior_smoothing = s;
            cfg.validate()
                .map_err(|e| cfg_err(format!("--prior-smoothing: {e}")))?;
        }
        if let Some(OrOff(c)) = self.prior_census {
            cfg.prior_census = c;
            cfg.validate()
                .map_err(|e| cfg_err(format!("--prior-census: {e}")))?;
        }
        if let Some(OrOff(b)) = self.prior_leave_one_out {
            cfg.prior_leave_one_out = b;
            cfg.validate()
                .map_err(|e| cfg_err(format!("--prior-leave-one-out: {e}")))?;
        }
        if let Some(on) = self.prior_sample_variance {
            cfg.prior_sample_variance = on;
            cfg.validate()
                .map_err(|e| cfg_err(format!("--prior-sample-variance: {e}")))?;
        }
        Ok(cfg)
    }

    fn model_before_radius(
        &self,
        load: impl Fn(&std::path::Path) -> Result<DeepViewConfig, TrainError>,
    ) -> Result<DeepViewConfig, TrainError> {
        let cfg_err = TrainError::Refused;
        match (&self.init, &self.preset) {
            (Some(dir), None) => load(dir),
            (init, preset) => {
                let mut to = DeepViewConfig::preset(preset.as_deref().unwrap_or("cpu"))
                    .map_err(|e| cfg_err(e.to_string()))?;
                if let Some(dir) = init {
                    // Refuse a preset the weights cannot grow into now, not after loading the data.
                    let from = load(dir)?;
                    // The grown model keeps the weights' prior: its temperature, radius (--prior-radius
                    // sets another) and every other setting.
                    if to.init_prior.is_some() && from.init_prior.is_some() {
                        to.init_prior = from.init_prior;
                        to.prior_radius = from.prior_radius;
                        to.prior_weight = from.prior_weight;
                        to.prior_radius_size = from.prior_radius_size;
                        to.prior_smoothing = from.prior_smoothing;
                        to.prior_census = from.prior_census;
                        to.prior_leave_one_out = from.prior_leave_one_out;
                        to.prior_sample_variance = from.prior_sample_variance;
                    }
                    // And the MPI grid the weights run (and train) on.
                    to.infer_mpi_scale = from.infer_mpi_scale;
                    if from != to {
                        deepview_net::grow::check_growth(&from, &to).map_err(|e| {
                            cfg_err(format!(
                                "--init {} --preset {}: {e}",
                                dir.display(),
                                to.name
                            ))
                        })?;
                    }
                }
                Ok(to)
            }
        }
    }

    /// The configuration of a new run of `model` on `data`: the defaults with every given option applied.
    pub fn config(&self, model: &DeepViewConfig, data: Vec<DataSpec>) -> TrainConfig {
        let mut train = TrainConfig::defaults(model);
        train.init = self.init.clone();
        train.base = std::env::current_dir().ok();
        train.data = data;
        train.steps = self.steps.unwrap_or(train.steps);
        train.batch = self.batch.unwrap_or(train.batch);
        if let Some(c) = self.crop {
            train.sample.crop = c as usize;
        }
        if let Some((a, b)) = self.views {
            (train.sample.views_min, train.sample.views_max) = (a, b);
        }
        if let Some((auto, p)) = self.planes {
            (train.sample.auto_planes, train.sample.planes) = (auto, p);
        }
        train.sample.jitter = !self.no_jitter;
        train.sample.colour_jitter = !self.no_colour_jitter;
        train.sample.wide_inputs = self.wide_inputs.unwrap_or(0.0);
        train.sample.surround_inputs = self.surround_inputs.unwrap_or(0.0);
        train.sample.spread_inputs = self.spread_inputs.unwrap_or(0.0);
        train.sample.window_context = self.window_context;
        if let Some(l) = self.loss {
            train.loss = l;
        }
        train.learning_rate = self.lr.unwrap_or(train.learning_rate);
        train.clip_norm = self.clip.unwrap_or(train.clip_norm);
        train.checkpoint_every = self.checkpoint_every.unwrap_or(train.checkpoint_every);
        if let Some(k) = self.keep_checkpoints {
            train.keep_checkpoints = k;
        }
        train.seed = self.seed.unwrap_or(train.seed);
        train.holdout_every = self.holdout_every.unwrap_or(train.holdout_every);
        if self.recompute || self.no_recompute {
            train.recompute = self.recompute;
        }
        if let Some(d) = &self.devices {
            train.devices = d.0.clone();
        }
        train.vgg_weights = self.vgg_weights.as_deref().map(absolute);
        train.validate_every = self.validate_every;
        train
    }

    /// What may change when a run resumes: the total steps, the devices, how many checkpoints are kept,
    /// where the VGG weights are and how often the validation set is scored.
    pub fn adjust_on_resume(&self, train: &mut TrainConfig) {
        if let Some(s) = self.steps {
            train.steps = s;
        }
        if let Some(d) = &self.devices {
            train.devices = d.0.clone();
        }
        if let Some(k) = self.keep_checkpoints {
            train.keep_checkpoints = k;
        }
        if let Some(v) = &self.vgg_weights {
            train.vgg_weights = Some(absolute(v));
        }
        if let Some(n) = self.validate_every {
            train.validate_every = Some(n);
        }
    }

    /// The options given that differ from a resumed run's own (they cannot take effect). Repeating the
    /// run's own value is fine: scripts re-run the same command with --resume.
    pub fn fixed_on_resume(&self, cfg: &RunConfig) -> Vec<&'static str> {
        let t = &cfg.train;
        let differs = [
            (
                self.preset.as_ref().is_some_and(|p| *p != cfg.model.name),
                "--preset",
            ),
            (
                self.init
                    .as_ref()
                    .is_some_and(|i| Some(i) != t.init.as_ref()),
                "--init",
            ),
            (
                self.prior_radius
                    .is_some_and(|r| r != cfg.model.prior_radius),
                "--prior-radius",
            ),
            (
                self.prior_weight
                    .is_some_and(|a| a != cfg.model.prior_weight),
                "--prior-weight",
            ),
            (
                self.prior_radius_size
                    .is_some_and(|n| (n > 0).then_some(n) != cfg.model.prior_radius_size),
                "--prior-radius-size",
            ),
            (
                self.prior_smoothing
                    .is_some_and(|OrOff(s)| s != cfg.model.prior_smoothing),
                "--prior-smoothing",
            ),
            (
                self.prior_census
                    .is_some_and(|OrOff(c)| c != cfg.model.prior_census),
                "--prior-census",
            ),
            (
                self.prior_leave_one_out
                    .is_some_and(|OrOff(b)| b != cfg.model.prior_leave_one_out),
                "--prior-leave-one-out",
            ),
            (
                self.prior_sample_variance
                    .is_some_and(|on| on != cfg.model.prior_sample_variance),
                "--prior-sample-variance",
            ),
            (self.batch.is_some_and(|b| b != t.batch), "--batch"),
            (
                self.crop.is_some_and(|c| c as usize != t.sample.crop),
                "--crop",
            ),
            (
                self.views
                    .is_some_and(|v| v != (t.sample.views_min, t.sample.views_max)),
                "--views",
            ),
            (
                self.planes
                    .is_some_and(|p| p != (t.sample.auto_planes, t.sample.planes)),
                "--planes",
            ),
            (self.loss.is_some_and(|l| l != t.loss), "--loss"),
            (self.lr.is_some_and(|l| l != t.learning_rate), "--lr"),
            (self.clip.is_some_and(|c| c != t.clip_norm), "--clip"),
            (
                self.checkpoint_every
                    .is_some_and(|c| c != t.checkpoint_every),
                "--checkpoint-every",
            ),
            (self.seed.is_some_and(|v| v != t.seed), "--seed"),
            (self.no_jitter && t.sample.jitter, "--no-jitter"),
            (
                self.no_colour_jitter && t.sample.colour_jitter,
                "--no-colour-jitter",
            ),
            (
                self.wide_inputs.is_some_and(|p| p != t.sample.wide_inputs),
                "--wide-inputs",
            ),
            (
                self.surround_inputs
                    .is_some_and(|p| p != t.sample.surround_inputs),
                "--surround-inputs",
            ),
            (
                self.spread_inputs
                    .is_some_and(|p| p != t.sample.spread_inputs),
                "--spread-inputs",
            ),
            (
                self.window_context && !t.sample.window_context,
                "--window-context",
            ),
            (
                self.holdout_every.is_some_and(|h| h != t.holdout_every),
                "--holdout-every",
            ),
            (self.recompute && !t.recompute, "--recompute"),
            (self.no_recompute && t.recompute, "--no-recompute"),
        ];
        differs.iter().filter(|g| g.0).map(|g| g.1).collect()
    }
}

/// `path` made absolute against the current folder (no file system access).
fn absolute(path: &std::path::Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// A whole number of at least 1.
pub fn parse_positive(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(_) => Err(format!("{s:?} is not a positive whole number")),
    }
}

/// A finite number above zero.
pub fn parse_positive_f64(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(_) => Err(format!("{s:?} must be a finite number above 0")),
        Err(_) => Err(format!("{s:?} is not a number")),
    }
}

fn parse_holdout(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(1) => Err("1 would hold out every view: use 0 (none) or 2 and more".into()),
        Ok(n) => Ok(n),
        Err(_) => Err(format!("{s:?} is not a whole number")),
    }
}

fn parse_probability(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(p) if (0.0..=1.0).contains(&p) => Ok(p),
        _ => Err(format!("expected a probability between 0 and 1, got `{s}`")),
    }
}

/// `--devices a,b,c`: the device names in order (one value, comma-separated).
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceList(pub Vec<String>);

fn parse_devices(s: &str) -> Result<DeviceList, String> {
    let d: Vec<String> = s
        .split(',')
        .map(|d| d.trim().to_string())
        .filter(|d| !d.is_empty())
        .collect();
    if d.is_empty() {
        return Err("no device named (e.g. cpu, or cpu,cpu)".into());
    }
    Ok(DeviceList(d))
}

/// `--planes N`, `auto` or `auto:MAX` -> (auto, count or maximum).
pub fn parse_train_planes(s: &str) -> Result<(bool, usize), String> {
    let count = |v: &str| match v.parse::<usize>() {
        Ok(n) if (2..=1024).contains(&n) => Ok(n),
        _ => Err(format!(
            "expected a plane count in 2..=1024, `auto` or `auto:MAX`, got `{s}`"
        )),
    };
    match s.strip_prefix("auto") {
        Some("") => Ok((true, TRAIN_AUTO_PLANES_MAX)),
        Some(rest) => match rest.strip_prefix(':') {
            Some(m) => count(m).map(|n| (true, n)),
            None => count(s).map(|n| (false, n)),
        },
        None => count(s).map(|n| (false, n)),
    }
}

/// `--views K` or `A..B` / `A..=B` (inclusive).
pub fn parse_views(s: &str) -> Result<(usize, usize), String> {
    let parse = |t: &str| {
        t.trim()
            .parse::<usize>()
            .map_err(|_| format!("{t:?} is not a number"))
    };
    let (a, b) = match s.split_once("..") {
        Some((a, b)) => (parse(a)?, parse(b.trim_start_matches('='))?),
        None => (parse(s)?, parse(s)?),
    };
    if a == 0 || a > b {
        return Err(format!("{s}: need 1 <= A <= B"));
    }
    Ok((a, b))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every option parses from a command line into its field (clap checks the types only when a field is
    /// read: a mismatch would panic in the program).
    #[test]
    fn every_option_parses() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            options: TrainOptions,
        }
        let cli = Cli::try_parse_from([
            "train",
            "--preset",
            "cpu-large",
            "--init",
            "builtin",
            "--steps",
            "9",
            "--batch",
            "2",
            "--crop",
            "24",
            "--views",
            "2..4",
            "--planes",
            "auto:32",
            "--loss",
            "l1",
            "--lr",
            "1e-4",
            "--clip",
            "4",
            "--devices",
            "cpu, cpu",
            "--checkpoint-every",
            "5",
            "--keep-checkpoints",
            "2",
            "--seed",
            "7",
            "--no-jitter",
            "--no-colour-jitter",
            "--wide-inputs",
            "0.5",
            "--surround-inputs",
            "0.25",
            "--window-context",
            "--max-width",
            "512",
            "--holdout-every",
            "4",
            "--recompute",
            "--vgg-weights",
            "v.safetensors",
            "--prior-radius",
            "8",
            "--prior-weight",
            "0.5",
        ])
        .unwrap();
        let o = cli.options;
        assert_eq!((o.prior_radius, o.prior_weight), (Some(8), Some(0.5)));
        assert_eq!(o.preset.as_deref(), Some("cpu-large"));
        assert_eq!(o.views, Some((2, 4)));
        assert_eq!(o.planes, Some((true, 32)));
        assert_eq!(o.loss, Some(LossKind::L1));
        assert_eq!(
            o.devices,
            Some(DeviceList(vec!["cpu".into(), "cpu".into()]))
        );
        assert_eq!((o.wide_inputs, o.surround_inputs), (Some(0.5), Some(0.25)));
        assert!(o.no_jitter && o.no_colour_jitter && o.window_context && o.recompute);
        assert_eq!(o.max_width, Some(512));
        assert!(Cli::try_parse_from(["train", "--devices", ","]).is_err());
        assert!(Cli::try_parse_from(["train", "--holdout-every", "1"]).is_err());
    }

    /// `--prior-radius` sets the new run's model (a prior preset's, or --init's), and is refused
    /// for a model without the agreement prior.
    #[test]
    fn prior_radius_sets_the_model() {
        let with = |preset: &str, r| TrainOptions {
            preset: Some(preset.into()),
            prior_radius: Some(r),
            ..Default::default()
        };
        assert_eq!(with("cpu", 8).model().unwrap().prior_radius, 8);
        // Net 0 reaches max(6, 9) rounded up to even; the update nets 6 each.
        assert_eq!(
            with("cpu-large", 9).model().unwrap().margin_from(0),
            10 + 6 + 6
        );
        assert_eq!(with("cpu-large", 3).model().unwrap().margin_from(0), 18);
        let err = with("paper-kalantari", 2).model().unwrap_err().to_string();
        assert!(err.contains("--prior-radius 2"), "{err}");
        assert!(with("cpu", 65).model().is_err());
        let weighted = TrainOptions {
            prior_weight: Some(1.5),
            ..with("cpu", 4)
        };
        assert!(
            weighted
                .model()
                .unwrap_err()
                .to_string()
                .contains("--prior-weight 1.5")
        );
        // --init weights with a radius grown into a larger preset keep it unless --prior-radius is given.
        let dir = tempfile::tempdir().unwrap();
        let weights = DeepViewConfig {
            init_prior: Some(0.0007),
            prior_radius: 5,
            prior_weight: 0.5,
            prior_radius_size: Some(512),
            prior_census: Some(Census {
                weight: 0.015,
                radius: 2,
            }),
            prior_leave_one_out: Some(0.75),
            prior_sample_variance: true,
            infer_mpi_scale: Some(1.25),
            ..DeepViewConfig::preset("cpu").unwrap()
        };
        std::fs::write(
            dir.path().join("config.json"),
            serde_json::to_string(&weights).unwrap(),
        )
        .unwrap();
        let grow = |radius| TrainOptions {
            init: Some(dir.path().to_path_buf()),
            preset: Some("cpu-large".into()),
            prior_radius: radius,
            ..Default::default()
        };
        let grown = grow(None).model().unwrap();
        assert_eq!(
            (
                grown.prior_radius,
                grown.prior_weight,
                grown.prior_radius_size
            ),
            (5, 0.5, Some(512))
        );
        assert_eq!(grown.init_prior, Some(0.0007));
        assert_eq!(grown.prior_census, weights.prior_census);
        assert_eq!(grown.prior_leave_one_out, Some(0.75));
        assert!(grown.prior_sample_variance);
        assert_eq!(grown.infer_mpi_scale, Some(1.25));
        let unsampled = TrainOptions {
            prior_sample_variance: Some(false),
            ..grow(None)
        };
        assert!(!unsampled.model().unwrap().prior_sample_variance);
        assert_eq!(parse_on_off("on"), Ok(true));
        assert!(parse_on_off("yes").is_err());
        assert_eq!(grow(Some(2)).model().unwrap().prior_radius, 2);
        // --prior-radius-size sets the size, 0 clears it (one radius at every size).
        let sized = |n| TrainOptions {
            prior_radius_size: Some(n),
            ..grow(None)
        };
        assert_eq!(sized(256).model().unwrap().prior_radius_size, Some(256));
        assert_eq!(sized(0).model().unwrap().prior_radius_size, None);
        // --prior-smoothing sets the penalties, `off` clears them, bad ones are refused.
        let smoothed = |s: &str| TrainOptions {
            prior_smoothing: Some(parse_or_off::<Smoothing>(s).unwrap()),
            ..grow(None)
        };
        let sgm = deepview_net::config::Smoothing { p1: 2.0, p2: 64.0 };
        assert_eq!(smoothed("2,64").model().unwrap().prior_smoothing, Some(sgm));
        assert_eq!(smoothed("off").model().unwrap().prior_smoothing, None);
        assert!(parse_or_off::<Smoothing>("64,2").is_err());
        assert!(parse_or_off::<Smoothing>("2").is_err());
        // --prior-census sets the term (radius 2 unless given), `off` clears it, bad ones are refused.
        let census = |s: &str| TrainOptions {
            prior_census: Some(parse_or_off::<Census>(s).unwrap()),
            ..grow(None)
        };
        let c = |weight, radius| Some(deepview_net::config::Census { weight, radius });
        assert_eq!(census("0.03").model().unwrap().prior_census, c(0.03, 2));
        assert_eq!(census("0.05,3").model().unwrap().prior_census, c(0.05, 3));
        assert_eq!(census("off").model().unwrap().prior_census, None);
        for bad in ["-1", "0", "0.03,0", "0.03,4", "x", "0.03,2,1"] {
            assert!(parse_or_off::<Census>(bad).is_err(), "{bad}");
        }
        // --prior-leave-one-out sets the weight, `off` clears it, bad ones are refused.
        let loo = |s: &str| TrainOptions {
            prior_leave_one_out: Some(parse_leave_one_out(s).unwrap()),
            ..grow(None)
        };
        assert_eq!(loo("0.75").model().unwrap().prior_leave_one_out, Some(0.75));
        assert_eq!(loo("1").model().unwrap().prior_leave_one_out, Some(1.0));
        assert_eq!(loo("off").model().unwrap().prior_leave_one_out, None);
        for bad in ["0", "-0.5", "1.5", "nan", "x"] {
            assert!(parse_leave_one_out(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn views_ranges() {
        assert_eq!(parse_views("4").unwrap(), (4, 4));
        assert_eq!(parse_views("2..4").unwrap(), (2, 4));
        assert_eq!(parse_views("2..=5").unwrap(), (2, 5));
        assert!(parse_views("4..2").is_err());
        assert!(parse_views("0").is_err());
        assert!(parse_views("x").is_err());
    }

    /// A new run's config holds what was given; resuming with the same options refuses nothing, with a
    /// different one names it, and only the resumable ones change the config.
    #[test]
    fn options_map_onto_the_config_and_back() {
        let model = DeepViewConfig::preset("cpu").unwrap();
        let given = TrainOptions {
            steps: Some(77),
            crop: Some(24),
            views: Some((3, 4)),
            planes: Some((true, 48)),
            lr: Some(5e-5),
            wide_inputs: Some(0.25),
            no_jitter: true,
            devices: Some(DeviceList(vec!["cpu".into(), "cpu".into()])),
            vgg_weights: Some("v.safetensors".into()),
            ..Default::default()
        };
        let train = given.config(&model, Vec::new());
        assert_eq!(train.steps, 77);
        assert_eq!(train.sample.crop, 24);
        assert_eq!((train.sample.views_min, train.sample.views_max), (3, 4));
        assert_eq!((train.sample.auto_planes, train.sample.planes), (true, 48));
        assert_eq!(train.learning_rate, 5e-5);
        assert_eq!(train.sample.wide_inputs, 0.25);
        assert!(!train.sample.jitter && train.sample.colour_jitter);
        assert_eq!(train.devices, ["cpu", "cpu"]);
        assert!(train.vgg_weights.as_ref().unwrap().is_absolute());
        let cfg = RunConfig {
            model: model.clone(),
            train,
        };
        assert!(given.fixed_on_resume(&cfg).is_empty());
        let other = TrainOptions {
            crop: Some(32),
            lr: Some(5e-5),
            no_colour_jitter: true,
            steps: Some(500),
            ..Default::default()
        };
        assert_eq!(
            other.fixed_on_resume(&cfg),
            ["--crop", "--no-colour-jitter"]
        );
        let radius = TrainOptions {
            prior_radius: Some(8),
            ..Default::default()
        };
        assert_eq!(radius.fixed_on_resume(&cfg), ["--prior-radius"]);
        // The run's leave-one-out weight (none here) given again is no change; another one is.
        let loo = |b: Option<f32>| TrainOptions {
            prior_leave_one_out: Some(OrOff(b)),
            ..Default::default()
        };
        assert!(loo(None).fixed_on_resume(&cfg).is_empty());
        assert_eq!(
            loo(Some(0.75)).fixed_on_resume(&cfg),
            ["--prior-leave-one-out"]
        );
        let sampled = TrainOptions {
            prior_sample_variance: Some(true),
            ..Default::default()
        };
        assert_eq!(sampled.fixed_on_resume(&cfg), ["--prior-sample-variance"]);
        let mut resumed = cfg.train.clone();
        other.adjust_on_resume(&mut resumed);
        assert_eq!(resumed.steps, 500);
        assert_eq!(resumed.sample.crop, 24, "fixed options stay the run's");
    }
}
