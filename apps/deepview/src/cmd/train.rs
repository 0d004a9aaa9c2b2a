//! `deepview train`: train the DeepView network on one or more datasets.

use super::args;
use super::safety::{Input, Kind, check_output, parse_component};
use super::signals;
use anyhow::{Context, bail};
use deepview_net::config::DeepViewConfig;
use deepview_train::loss::LossKind;
use deepview_train::{
    Collective, RunConfig, SYNTHETIC_PROCEDURAL, SYNTHETIC_TWO_PLANES, TrainConfig, Trainer,
    list_checkpoints, load_data,
};
use std::path::PathBuf;
use std::rc::Rc;

#[path = "train_data.rs"]
mod data;
#[cfg(feature = "openmpi")]
#[path = "train_mpi.rs"]
mod mpi;
#[path = "train_progress.rs"]
mod progress;
#[path = "train_validate.rs"]
mod validate;
use data::{check_views, data_spec, resumed_data};
use progress::Progress;
use validate::Validation;

/// Train the network (Adam, lr 1.5e-4, global gradient clipping at 8, VGG feature loss on 32x32 target
/// crops, as in the paper). A run lives in `<runs>/<name>/`: config.json, metrics.jsonl and
/// checkpoints/step-NNNNNNN/ (the last 3 are kept, --keep-checkpoints). A checkpoint is written into a
/// temporary folder and renamed when complete, so a run killed at any moment resumes from its last
/// complete checkpoint. Ctrl-C saves a checkpoint and exits; `--resume`
/// continues a run exactly where its last checkpoint left it.
#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  deepview train --data ../shared/data/llff/fern --preset cpu --name fern --steps 2000\n  \
    deepview train --name fern --resume --steps 4000\n  \
    deepview train --init weights/cpu --data ../shared/data/llff/flower --name flower-ft --steps 500 --crop 16\n  \
    deepview train --init weights/cpu --preset cpu-large --data ../shared/data/llff/flower --name grown --steps 500\n  \
    deepview train --data synthetic:two-planes --preset cpu --name smoke --steps 50 --loss l1 --devices cpu,cpu\n  \
    deepview train --data ../shared/data/llff/fern --data runs/synth/grid-20 --images images_4 --max-width 512 \
    --views 4 --surround-inputs 1 --name mixed\n\n\
    Ctrl-C or SIGTERM saves a checkpoint and exits (130 / 143); --resume continues from it. With --resume only \
    --steps, --devices, --data, --keep-checkpoints and --vgg-weights may be given: the others are the run's own, \
    and its datasets load with the scene options they were first loaded with (kept in its config.json).\n\n\
    The VGG loss (the default) reads the VGG-16 weights from --vgg-weights FILE or the environment variable \
    DEEPVIEW_VGG_WEIGHTS."
)]
pub struct Args {
    /// Dataset folders (`--data A B` or `--data A --data B`; any format `deepview info` reads).
    /// `synthetic:two-planes` is a built-in analytic scene; `synthetic:procedural` makes a new 3D scene
    /// for every tuple (slanted planes, boxes, spheres, thin bars, semi-transparent sheets, textured with
    /// crops of the other scenes' training views; half the tuples when other data is given, reproducible
    /// from the run's seed, nothing stored). With --resume, defaults to the run's own list
    /// (each with the scene options it was loaded with).
    #[arg(long = "data", value_name = "DIR", num_args = 1.., value_parser = parse_data)]
    pub data: Vec<PathBuf>,
    /// Network preset: cpu, cpu-large, paper-kalantari, paper-spaces-4view, paper-spaces-12view
    /// (default: cpu). With --init: grow those weights into this larger preset first (the grown model
    /// computes the same MPI; the new feature channels and update nets then train).
    #[arg(long)]
    pub preset: Option<String>,
    /// Start from these weights instead of a random initialisation (fine-tuning): a weights folder
    /// (config.json + model.safetensors, e.g. weights/cpu) or a checkpoint folder. The network
    /// configuration is the one saved with them, unless --preset names a larger one to grow them into.
    /// The optimizer starts afresh.
    #[arg(long, value_name = "WEIGHTS_DIR", visible_alias = "weights")]
    pub init: Option<PathBuf>,
    /// Run name: the run lives in <runs>/<name>/ (a plain name, no '/').
    #[arg(long, value_parser = parse_component)]
    pub name: String,
    /// Folder holding the runs.
    #[arg(long, default_value = "runs")]
    pub runs: PathBuf,
    /// Total number of steps of the run (with --resume: the new total). Default 1000.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub steps: Option<u64>,
    /// Training tuples per step, split over the devices (default 1).
    #[arg(long, value_parser = args::parse_positive)]
    pub batch: Option<usize>,
    /// Target crop side in pixels (paper and default: 32).
    #[arg(long, value_parser = clap::value_parser!(u64).range(4..=4096))]
    pub crop: Option<u64>,
    /// Number of input views: `K` or a range `A..B` (inclusive) drawn per batch. Default: the preset's
    /// fixed count, or 2..4.
    #[arg(long, value_parser = parse_views_arg)]
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
    #[arg(long, value_parser = args::parse_positive_f64)]
    pub lr: Option<f64>,
    /// Global gradient-norm clipping threshold (paper and default: 8).
    #[arg(long, value_parser = args::parse_positive_f64)]
    pub clip: Option<f64>,
    /// Continue the run from its latest checkpoint (optimizer and RNG state included).
    #[arg(long)]
    pub resume: bool,
    /// Comma-separated devices for data parallelism: cpu, wgpu[:N], wgpu:cpu (the CPU Vulkan
    /// adapter), cuda[:N] (GPU ones need a build with the features `wgpu` / `cuda`). Example: cpu,cpu.
    #[arg(long)]
    pub devices: Option<String>,
    /// Write a checkpoint every N steps (and always at the end, on Ctrl-C or SIGTERM). Default 500.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub checkpoint_every: Option<u64>,
    /// Keep the last N checkpoints (older ones are removed after each new one). Default: 3, or the
    /// run's own setting with --resume.
    #[arg(long, value_name = "N", value_parser = args::parse_positive)]
    pub keep_checkpoints: Option<usize>,
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
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Score the held-out views of the run's posed real datasets (4 nearest and 3 spread inputs, at most
    /// 256 px wide) at the session's first checkpoint and at the first one past every multiple of N steps,
    /// into runs/NAME/validation.jsonl (choose the checkpoint to ship by it).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub validate_every: Option<u64>,
    /// Recompute each net's activations during the backward pass (the paper's gradient checkpointing:
    /// peak memory of one net instead of all nets, one extra forward pass per step). Default: on for
    /// presets with more than 2 nets (all paper-* presets). Kept in the run's config.json.
    #[arg(long, conflicts_with = "no_recompute")]
    pub recompute: bool,
    /// Keep all activations for the backward pass (faster, more memory).
    #[arg(long)]
    pub no_recompute: bool,
    #[command(flatten)]
    pub vgg: VggArg,
    #[command(flatten)]
    pub scene: deepview_data::SceneArgs,
}

/// `--vgg-weights`: the VGG-16 weights of the training loss.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct VggArg {
    /// The VGG-16 weights the VGG loss needs (vgg16_conv1_1-conv3_3.safetensors; see the data folder's
    /// vgg16/README.md). Default: the file named by the environment variable DEEPVIEW_VGG_WEIGHTS.
    #[arg(long, value_name = "FILE")]
    pub vgg_weights: Option<PathBuf>,
}

impl VggArg {
    /// Make `--vgg-weights` the file the VGG loss reads (else `DEEPVIEW_VGG_WEIGHTS`).
    pub fn configure(&self) -> anyhow::Result<()> {
        if let Some(p) = &self.vgg_weights {
            deepview_train::vgg::set_weights_path(Some(p.clone()));
        }
        Ok(())
    }

    /// Refuse a VGG loss without readable VGG weights before the training starts.
    pub fn check(&self, loss: LossKind) -> anyhow::Result<()> {
        if loss == LossKind::L1 {
            return Ok(());
        }
        let path = deepview_train::vgg::weights_path()?;
        if !path.is_file() {
            let from = if self.vgg_weights.is_some() {
                "--vgg-weights"
            } else {
                deepview_train::vgg::WEIGHTS_ENV
            };
            bail!(
                "the VGG-16 weights {} ({from}) are not a readable file: pass --vgg-weights FILE or set {} to \
                 vgg16_conv1_1-conv3_3.safetensors, or train with --loss l1",
                path.display(),
                deepview_train::vgg::WEIGHTS_ENV
            );
        }
        Ok(())
    }
}

/// `--data`: a folder, or one of the built-in synthetic scenes.
fn parse_data(s: &str) -> Result<PathBuf, String> {
    const SYNTHETIC: &[&str] = &[SYNTHETIC_TWO_PLANES, SYNTHETIC_PROCEDURAL];
    if s.is_empty() {
        return Err("empty dataset path".into());
    }
    if s.starts_with("synthetic:") && !SYNTHETIC.contains(&s) {
        return Err(format!(
            "unknown synthetic scene {s:?} (known: {})",
            SYNTHETIC.join(", ")
        ));
    }
    Ok(PathBuf::from(s))
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

/// Largest plane count of `--planes auto` in training (the cost of a step grows with it).
const TRAIN_AUTO_PLANES_MAX: usize = 64;

/// `--planes N`, `auto` or `auto:MAX` -> (auto, count or maximum).
fn parse_train_planes(s: &str) -> Result<(bool, usize), String> {
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

fn parse_views_arg(s: &str) -> Result<(usize, usize), String> {
    parse_views(s).map_err(|e| e.to_string())
}

/// The options a resumed run keeps from its config.json, given on the command line.
fn fixed_on_resume(args: &Args, cfg: &RunConfig) -> Vec<&'static str> {
    // Repeating the run's own value is fine (scripts re-run the same command with --resume); a
    // different value cannot take effect, so it is refused rather than ignored.
    let t = &cfg.train;
    let differs = [
        (
            args.preset.as_ref().is_some_and(|p| *p != cfg.model.name),
            "--preset",
        ),
        (
            args.init
                .as_ref()
                .is_some_and(|i| Some(i) != t.init.as_ref()),
            "--init",
        ),
        (args.batch.is_some_and(|b| b != t.batch), "--batch"),
        (
            args.crop.is_some_and(|c| c as usize != t.sample.crop),
            "--crop",
        ),
        (
            args.views
                .is_some_and(|v| v != (t.sample.views_min, t.sample.views_max)),
            "--views",
        ),
        (
            args.planes
                .is_some_and(|p| p != (t.sample.auto_planes, t.sample.planes)),
            "--planes",
        ),
        (args.loss.is_some_and(|l| l != t.loss), "--loss"),
        (args.lr.is_some_and(|l| l != t.learning_rate), "--lr"),
        (args.clip.is_some_and(|c| c != t.clip_norm), "--clip"),
        (
            args.checkpoint_every
                .is_some_and(|c| c != t.checkpoint_every),
            "--checkpoint-every",
        ),
        (args.seed.is_some_and(|v| v != t.seed), "--seed"),
        (args.no_jitter && t.sample.jitter, "--no-jitter"),
        (
            args.no_colour_jitter && t.sample.colour_jitter,
            "--no-colour-jitter",
        ),
        (
            args.wide_inputs.is_some_and(|p| p != t.sample.wide_inputs),
            "--wide-inputs",
        ),
        (
            args.surround_inputs
                .is_some_and(|p| p != t.sample.surround_inputs),
            "--surround-inputs",
        ),
        (
            args.window_context && !t.sample.window_context,
            "--window-context",
        ),
        (
            args.holdout_every.is_some_and(|h| h != t.holdout_every),
            "--holdout-every",
        ),
        (args.recompute && !t.recompute, "--recompute"),
        (args.no_recompute && t.recompute, "--no-recompute"),
    ];
    differs.iter().filter(|g| g.0).map(|g| g.1).collect()
}

fn check_fixed_on_resume(args: &Args, cfg: &RunConfig) -> anyhow::Result<()> {
    let fixed = fixed_on_resume(args, cfg);
    if !fixed.is_empty() {
        bail!(
            "--resume keeps the run's own {}: {} differ from the run's config.json and cannot change on \
             resume (only --steps, --devices, --data and --keep-checkpoints can); start a new --name instead",
            if fixed.len() == 1 {
                "setting"
            } else {
                "settings"
            },
            fixed.join(", ")
        );
    }
    Ok(())
}

fn parse_views(s: &str) -> anyhow::Result<(usize, usize)> {
    let parse = |t: &str| {
        t.trim()
            .parse::<usize>()
            .with_context(|| format!("--views: {t:?} is not a number"))
    };
    let (a, b) = match s.split_once("..") {
        Some((a, b)) => (parse(a)?, parse(b.trim_start_matches('='))?),
        None => (parse(s)?, parse(s)?),
    };
    if a == 0 || a > b {
        bail!("--views {s}: need 1 <= A <= B");
    }
    Ok((a, b))
}

fn device_list(s: &Option<String>) -> Option<Vec<String>> {
    s.as_ref().map(|s| {
        s.split(',')
            .map(|d| d.trim().to_string())
            .filter(|d| !d.is_empty())
            .collect()
    })
}

/// The number of ranks an MPI launcher (Open MPI's `mpirun`, MPICH/Intel MPI's Hydra, Slurm with PMI)
/// started, from its environment; `None` outside a launcher.
fn launcher_ranks() -> Option<usize> {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE"]
        .iter()
        .find_map(|k| std::env::var(k).ok()?.parse().ok())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    #[cfg(feature = "openmpi")]
    if launcher_ranks().is_some_and(|n| n > 1) {
        return mpi::run_ranks(|comm| train(args, Some(comm)));
    }
    #[cfg(not(feature = "openmpi"))]
    if let Some(n) = launcher_ranks().filter(|&n| n > 1) {
        bail!(
            "started by an MPI launcher as one of {n} ranks, but this deepview was built without MPI \
             support: rebuild it with `cargo build --release -p deepview --features openmpi`"
        );
    }
    train(args, None)
}

/// How a run starts, as rank 0 decides for every rank.
const FRESH: u64 = 0;
const RESUME: u64 = 1;
const RESTART: u64 = 2;

fn train(args: Args, comm: Option<Rc<dyn Collective>>) -> anyhow::Result<()> {
    // From here on Ctrl-C / SIGTERM stop the loop, which saves a checkpoint.
    let stop = signals::graceful();
    let run_dir = args.runs.join(&args.name);
    let mut inputs: Vec<Input> = args.data.iter().map(|d| ("--data", d.as_path())).collect();
    if let Some(init) = &args.init {
        inputs.push(("--init", init));
    }
    if let Some(v) = &args.vgg.vgg_weights {
        inputs.push(("--vgg-weights", v));
    }
    check_output("--runs/--name", &run_dir, Kind::Run, &inputs)?;
    args.vgg.configure()?;
    let opts = args.scene.load_options();
    let writer = comm.as_ref().is_none_or(|c| c.rank() == 0);
    // `--resume` of a run without config.json (killed before it wrote anything, or never started).
    // With --data (the whole command repeated, as a job script does after a crash) it starts; without,
    // it is an error.
    let started = run_dir.join("config.json").is_file();
    if args.resume && !started && args.data.is_empty() {
        bail!(
            "--resume: there is no run {} (no config.json); start it without --resume",
            run_dir.display()
        );
    }
    if args.resume && !started && writer {
        eprintln!(
            "--resume: there is no run {} yet (no config.json; stopped before it started?): starting it",
            run_dir.display()
        );
    }
    // A run killed before its first checkpoint restarts from its config.json (said on stderr); one whose
    // every checkpoint is damaged is refused, naming them, rather than started over.
    if args.resume && started && list_checkpoints(&run_dir)?.is_empty() {
        let damaged = deepview_train::damaged_checkpoints(&run_dir);
        if !damaged.is_empty() {
            bail!(
                "--resume: no checkpoint of {} is complete ({} lack one of {}): move them away to start \
                 the run over from step 0",
                run_dir.display(),
                damaged.join(", "),
                deepview_train::CHECKPOINT_FILES.join(", ")
            );
        }
    }
    let mut mode = [if !args.resume || !started {
        FRESH
    } else if !list_checkpoints(&run_dir)?.is_empty() {
        RESUME
    } else {
        RESTART
    }];
    if let Some(c) = &comm {
        c.broadcast_u64(&mut mode);
    }
    let mut trainer = if mode[0] == RESUME {
        let cfg_path = run_dir.join("config.json");
        let text = std::fs::read_to_string(&cfg_path)
            .with_context(|| format!("cannot read {}", cfg_path.display()))?;
        let cfg: RunConfig = serde_json::from_str(&text)
            .with_context(|| format!("invalid {}", cfg_path.display()))?;
        check_fixed_on_resume(&args, &cfg)?;
        let specs = resumed_data(&args, &cfg, &opts)?;
        let data = load_data(&specs, &opts, cfg.train.holdout_every)?;
        check_views(&data, cfg.train.sample.views_max, cfg.train.sample.crop)?;
        args.vgg.check(cfg.train.loss)?;
        let mut t = Trainer::resume_on(
            &run_dir,
            data,
            args.steps,
            device_list(&args.devices),
            comm.clone(),
        )?;
        if let Some(k) = args.keep_checkpoints {
            t.config.train.keep_checkpoints = k;
        }
        if let Some(n) = args.steps.filter(|&n| n < t.step) {
            bail!(
                "--steps {n} is below the step the run {} has reached ({}): --steps is the new total, \
                 e.g. --steps {}",
                run_dir.display(),
                t.step,
                t.step + 1000
            );
        }
        if writer {
            for n in t.take_notices() {
                eprintln!("{n}");
            }
            eprintln!(
                "resuming {} at step {} of {}{}",
                run_dir.display(),
                t.step,
                t.config.train.steps,
                comm.as_ref()
                    .map(|c| format!(" on {} MPI ranks", c.size()))
                    .unwrap_or_default()
            );
        }
        t
    } else if mode[0] == RESTART {
        // Killed before its first checkpoint: start the run over with its own configuration.
        let cfg_path = run_dir.join("config.json");
        let text = std::fs::read_to_string(&cfg_path)
            .with_context(|| format!("cannot read {}", cfg_path.display()))?;
        let mut cfg: RunConfig = serde_json::from_str(&text).with_context(|| {
            format!(
                "--resume: the run {} has no checkpoints yet, and its {} (to start it over from) is invalid",
                run_dir.display(),
                cfg_path.display()
            )
        })?;
        check_fixed_on_resume(&args, &cfg)?;
        if let Some(s) = args.steps {
            cfg.train.steps = s;
        }
        if let Some(k) = args.keep_checkpoints {
            cfg.train.keep_checkpoints = k;
        }
        cfg.train.data = resumed_data(&args, &cfg, &opts)?;
        if let Some(d) = device_list(&args.devices) {
            cfg.train.devices = d;
        }
        args.vgg.check(cfg.train.loss)?;
        let data = load_data(&cfg.train.data, &opts, cfg.train.holdout_every)?;
        if writer {
            eprintln!(
                "{} has no complete checkpoint yet: starting it over from step 0 with its config.json",
                run_dir.display()
            );
        }
        Trainer::create_on(&run_dir, cfg, data, comm.clone())?
    } else {
        if args.data.is_empty() {
            bail!("no training data: pass --data DIR (repeatable)");
        }
        let model = match (&args.init, &args.preset) {
            (Some(dir), None) => deepview_net::weights::load_config_any(dir)
                .with_context(|| format!("--init {}", dir.display()))?,
            (init, preset) => {
                let to = DeepViewConfig::preset(preset.as_deref().unwrap_or("cpu"))?;
                if let Some(dir) = init {
                    // Refuse a preset the weights cannot grow into now, not after loading the data.
                    let from = deepview_net::weights::load_config_any(dir)
                        .with_context(|| format!("--init {}", dir.display()))?;
                    if from != to {
                        deepview_net::grow::check_growth(&from, &to).with_context(|| {
                            format!("--init {} --preset {}", dir.display(), to.name)
                        })?;
                    }
                }
                to
            }
        };
        let mut train = TrainConfig::defaults(&model);
        train.init = args.init.clone();
        train.base = std::env::current_dir().ok();
        train.data = args
            .data
            .iter()
            .map(|p| data_spec(p, &opts, args.max_width))
            .collect::<anyhow::Result<_>>()?;
        train.steps = args.steps.unwrap_or(train.steps);
        train.batch = args.batch.unwrap_or(train.batch);
        if let Some(c) = args.crop {
            train.sample.crop = c as usize;
        }
        if let Some((a, b)) = args.views {
            (train.sample.views_min, train.sample.views_max) = (a, b);
        }
        if let Some((auto, p)) = args.planes {
            (train.sample.auto_planes, train.sample.planes) = (auto, p);
        }
        train.sample.jitter = !args.no_jitter;
        train.sample.colour_jitter = !args.no_colour_jitter;
        train.sample.wide_inputs = args.wide_inputs.unwrap_or(0.0);
        train.sample.surround_inputs = args.surround_inputs.unwrap_or(0.0);
        train.sample.window_context = args.window_context;
        if let Some(l) = args.loss {
            train.loss = l;
        }
        train.learning_rate = args.lr.unwrap_or(train.learning_rate);
        train.clip_norm = args.clip.unwrap_or(train.clip_norm);
        train.checkpoint_every = args.checkpoint_every.unwrap_or(train.checkpoint_every);
        if let Some(k) = args.keep_checkpoints {
            train.keep_checkpoints = k;
        }
        train.seed = args.seed.unwrap_or(train.seed);
        train.holdout_every = args.holdout_every.unwrap_or(train.holdout_every);
        if args.recompute || args.no_recompute {
            train.recompute = args.recompute;
        }
        if let Some(d) = device_list(&args.devices) {
            train.devices = d;
        }
        for d in &train.devices {
            deepview_net::device::parse_device(d)?;
        }
        let data = load_data(&train.data, &opts, train.holdout_every)?;
        check_views(&data, train.sample.views_max, train.sample.crop)?;
        args.vgg.check(train.loss)?;
        let views: usize = data.scenes.iter().map(|s| s.train_views.len()).sum();
        if writer {
            let procedural = data.procedural_note();
            eprintln!(
                "training {} ({} preset) on {} scene(s), {views} training views{procedural}, devices {:?}{}",
                run_dir.display(),
                model.name,
                data.scenes.len(),
                train.devices,
                ranks_note(&comm)
            );
        }
        let existed = run_dir.exists();
        match Trainer::create_on(&run_dir, RunConfig { model, train }, data, comm.clone()) {
            Ok(t) => t,
            Err(e) => {
                // A run that failed to start (unreadable --init weights, ...) leaves no folder behind.
                if !existed && writer && list_checkpoints(&run_dir).is_ok_and(|c| c.is_empty()) {
                    let _ = std::fs::remove_dir_all(&run_dir);
                }
                return Err(e.into());
            }
        }
    };
    let start_step = trainer.step;
    let mut progress = Progress::new(writer && !args.quiet, writer);
    let mut validation = match args.validate_every.filter(|_| writer) {
        Some(n) => Some(Validation::new(
            &trainer.config.train.data,
            &opts,
            &run_dir,
            n,
        )?),
        None => None,
    };
    if validation.as_ref().is_some_and(|v| v.is_empty()) {
        progress.say(validate::NO_SCENES.into());
    }
    let result = trainer.run(&stop, &mut |e| {
        if let Some(v) = validation.as_mut() {
            v.on_event(&e, &progress);
        }
        progress.event(e)
    });
    progress.finish();
    let reports = result?;
    let last: Vec<f64> = reports
        .iter()
        .rev()
        .take(50)
        .filter(|r| r.skipped.is_none())
        .map(|r| r.loss)
        .collect();
    let skipped = reports.iter().filter(|r| r.skipped.is_some()).count();
    if !writer {
        return Ok(());
    }
    eprintln!(
        "{} at step {} ({} steps this session, {skipped} skipped, {:.3} steps/s); mean loss of the last {}: {:.5}",
        if stop.load(std::sync::atomic::Ordering::SeqCst) {
            "stopped"
        } else {
            "done"
        },
        trainer.step,
        trainer.step - start_step,
        trainer.steps_per_second(),
        last.len(),
        last.iter().sum::<f64>() / last.len().max(1) as f64
    );
    if let Some((_, ck)) = list_checkpoints(&run_dir)?.pop() {
        eprintln!("checkpoint: {}", ck.display());
    }
    if stop.load(std::sync::atomic::Ordering::SeqCst) {
        return Err(signals::Interrupted(signals::received().unwrap_or(signals::SIGINT)).into());
    }
    Ok(())
}

/// ` on each of N MPI ranks ...` for a run across processes.
fn ranks_note(comm: &Option<Rc<dyn Collective>>) -> String {
    match comm {
        Some(c) => format!(
            " on each of {} MPI ranks (the global batch split across them)",
            c.size()
        ),
        None => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_ranges() {
        assert_eq!(parse_views("4").unwrap(), (4, 4));
        assert_eq!(parse_views("2..4").unwrap(), (2, 4));
        assert_eq!(parse_views("2..=5").unwrap(), (2, 5));
        assert!(parse_views("4..2").is_err());
        assert!(parse_views("0").is_err());
        assert!(parse_views("x").is_err());
    }
}
