//! `deepview train`: train the DeepView network on one or more datasets.

use anyhow::{Context, bail};
use deepview_net::config::DeepViewConfig;
use deepview_net::loss::LossKind;
use deepview_net::train::{
    Collective, RunConfig, TrainConfig, Trainer, install_ctrlc, list_checkpoints, load_data,
};
use std::path::PathBuf;
use std::rc::Rc;

#[cfg(feature = "mpi")]
#[path = "train_mpi.rs"]
mod mpi;

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
    deepview train --data synthetic:two-planes --preset cpu --name smoke --steps 50 --loss l1 --devices cpu,cpu"
)]
pub struct Args {
    /// Dataset folder (repeat for several; any format `deepview info` reads). `synthetic:two-planes` is a
    /// built-in analytic scene. With --resume, defaults to the run's own list.
    #[arg(long = "data", value_name = "DIR")]
    pub data: Vec<PathBuf>,
    /// Network preset: cpu, paper-kalantari, paper-spaces-4view, paper-spaces-12view.
    #[arg(long, default_value = "cpu", conflicts_with = "init")]
    pub preset: String,
    /// Start from these weights instead of a random initialisation (fine-tuning): a weights folder
    /// (config.json + model.safetensors, e.g. weights/cpu) or a checkpoint folder. The network
    /// configuration is the one saved with them. The optimizer starts afresh.
    #[arg(long, value_name = "WEIGHTS_DIR", visible_alias = "weights")]
    pub init: Option<PathBuf>,
    /// Run name: the run lives in <runs>/<name>/.
    #[arg(long)]
    pub name: String,
    /// Folder holding the runs.
    #[arg(long, default_value = "runs")]
    pub runs: PathBuf,
    /// Total number of steps of the run (with --resume: the new total).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Training tuples per step, split over the devices.
    #[arg(long, default_value_t = 1)]
    pub batch: usize,
    /// Target crop side in pixels (paper: 32).
    #[arg(long, default_value_t = 32)]
    pub crop: usize,
    /// Number of input views: `K` or a range `A..B` (inclusive) drawn per batch. Default: the preset's
    /// fixed count, or 2..4.
    #[arg(long)]
    pub views: Option<String>,
    /// MPI planes during training (default: the preset's training plane count).
    #[arg(long)]
    pub planes: Option<usize>,
    /// Training loss: vgg (the paper's feature loss) or l1.
    #[arg(long, default_value = "vgg")]
    pub loss: LossKind,
    /// Learning rate (paper: 1.5e-4).
    #[arg(long, default_value_t = deepview_net::train::PAPER_LEARNING_RATE)]
    pub lr: f64,
    /// Global gradient-norm clipping threshold (paper: 8).
    #[arg(long, default_value_t = 8.0)]
    pub clip: f64,
    /// Continue the run from its latest checkpoint (optimizer and RNG state included).
    #[arg(long)]
    pub resume: bool,
    /// Comma-separated devices for data parallelism: cpu, wgpu[:N], cuda[:N] (GPU ones need the
    /// deepview-net features `wgpu` / `cuda`). Example: cpu,cpu.
    #[arg(long)]
    pub devices: Option<String>,
    /// Write a checkpoint every N steps (and always at the end or on Ctrl-C).
    #[arg(long, default_value_t = 500)]
    pub checkpoint_every: u64,
    /// Keep the last N checkpoints (older ones are removed after each new one). Default: 3, or the
    /// run's own setting with --resume.
    #[arg(long, value_name = "N")]
    pub keep_checkpoints: Option<usize>,
    /// Random seed (weights initialisation and tuple sampling).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Disable the random jitter of plane depths.
    #[arg(long)]
    pub no_jitter: bool,
    /// Hold out every N-th view of LLFF/COLMAP/light-field scenes for evaluation (0: none).
    #[arg(long, default_value_t = 8)]
    pub holdout_every: usize,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Recompute each net's activations during the backward pass (the paper's gradient checkpointing:
    /// peak memory of one net instead of all nets, one extra forward pass per step). Default: on for
    /// presets with more than 2 nets (all paper-* presets). Kept in the run's config.json.
    #[arg(long, conflicts_with = "no_recompute")]
    pub recompute: bool,
    /// Keep all activations for the backward pass (faster, more memory).
    #[arg(long)]
    pub no_recompute: bool,
    #[command(flatten)]
    pub scene: deepview_data::SceneArgs,
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
    #[cfg(feature = "mpi")]
    if launcher_ranks().is_some_and(|n| n > 1) {
        return mpi::run_ranks(|comm| train(args, Some(comm)));
    }
    #[cfg(not(feature = "mpi"))]
    if let Some(n) = launcher_ranks().filter(|&n| n > 1) {
        bail!(
            "started by an MPI launcher as one of {n} ranks, but this deepview was built without MPI \
             support: rebuild it with `cargo build --release -p deepview --features mpi`"
        );
    }
    train(args, None)
}

/// How a run starts, as rank 0 decides for every rank.
const FRESH: u64 = 0;
const RESUME: u64 = 1;
const RESTART: u64 = 2;

fn train(args: Args, comm: Option<Rc<dyn Collective>>) -> anyhow::Result<()> {
    let run_dir = args.runs.join(&args.name);
    let opts = args.scene.load_options();
    let writer = comm.as_ref().is_none_or(|c| c.rank() == 0);
    let mut mode = [if !args.resume {
        FRESH
    } else if !list_checkpoints(&run_dir)?.is_empty() {
        RESUME
    } else if run_dir.join("config.json").is_file() {
        RESTART
    } else {
        FRESH
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
        let paths = if args.data.is_empty() {
            cfg.train.data.clone()
        } else {
            args.data.clone()
        };
        let data = load_data(&paths, &opts, cfg.train.holdout_every)?;
        let mut t = Trainer::resume_on(
            &run_dir,
            data,
            args.steps,
            device_list(&args.devices),
            comm.clone(),
        )?;
        if let Some(k) = args.keep_checkpoints {
            anyhow::ensure!(k >= 1, "--keep-checkpoints must be at least 1");
            t.config.train.keep_checkpoints = k;
        }
        if writer {
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
        let mut cfg: RunConfig = serde_json::from_str(&text)
            .with_context(|| format!("invalid {}", cfg_path.display()))?;
        if let Some(s) = args.steps {
            cfg.train.steps = s;
        }
        if let Some(k) = args.keep_checkpoints {
            cfg.train.keep_checkpoints = k;
        }
        if !args.data.is_empty() {
            cfg.train.data = args.data.clone();
        }
        if let Some(d) = device_list(&args.devices) {
            cfg.train.devices = d;
        }
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
        let model = match &args.init {
            Some(dir) => deepview_net::weights::load_config_any(dir)
                .with_context(|| format!("--init {}", dir.display()))?,
            None => DeepViewConfig::preset(&args.preset)?,
        };
        let mut train = TrainConfig::defaults(&model);
        train.init = args.init.clone();
        train.data = args.data.clone();
        train.steps = args.steps.unwrap_or(train.steps);
        train.batch = args.batch;
        train.sample.crop = args.crop;
        if let Some(v) = &args.views {
            (train.sample.views_min, train.sample.views_max) = parse_views(v)?;
        }
        if let Some(p) = args.planes {
            train.sample.planes = p;
        }
        train.sample.jitter = !args.no_jitter;
        train.loss = args.loss;
        train.learning_rate = args.lr;
        train.clip_norm = args.clip;
        train.checkpoint_every = args.checkpoint_every;
        if let Some(k) = args.keep_checkpoints {
            train.keep_checkpoints = k;
        }
        train.seed = args.seed;
        train.holdout_every = args.holdout_every;
        if args.recompute || args.no_recompute {
            train.recompute = args.recompute;
        }
        if let Some(d) = device_list(&args.devices) {
            train.devices = d;
        }
        for d in &train.devices {
            deepview_net::train::parse_device(d)?;
        }
        let data = load_data(&train.data, &opts, train.holdout_every)?;
        let views: usize = data.scenes.iter().map(|s| s.train_views.len()).sum();
        if writer {
            eprintln!(
                "training {} ({} preset) on {} scene(s), {views} training views, devices {:?}{}",
                run_dir.display(),
                model.name,
                data.scenes.len(),
                train.devices,
                ranks_note(&comm)
            );
        }
        Trainer::create_on(&run_dir, RunConfig { model, train }, data, comm.clone())?
    };
    let stop = install_ctrlc()?;
    let start_step = trainer.step;
    let reports = trainer.run(&stop, !args.quiet)?;
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
