//! `deepview train`: train the DeepView network on one or more datasets.

use super::safety::{Input, Kind, check_output, parse_component};
use super::signals;
use deepview_train::{
    Collective, SYNTHETIC_PROCEDURAL, SYNTHETIC_TWO_PLANES, TrainOptions, list_checkpoints,
};
use std::path::PathBuf;
use std::rc::Rc;

#[cfg(feature = "openmpi")]
#[path = "train_mpi.rs"]
mod mpi;
#[path = "train_progress.rs"]
mod progress;
#[path = "train_validate.rs"]
mod validate;
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
    after_help = "Examples (VGG=../shared/data/vgg16/vgg16_conv1_1-conv3_3.safetensors):\n  \
    deepview train --data ../shared/data/llff/fern --preset cpu --name fern --steps 2000 --vgg-weights $VGG\n  \
    deepview train --name fern --resume --steps 4000\n  \
    deepview train --init builtin --data ../shared/data/llff/flower --name flower-ft --steps 500 --crop 16 --vgg-weights $VGG\n  \
    deepview train --init builtin --preset cpu-large --data ../shared/data/llff/flower --name grown --steps 500 --loss l1\n  \
    deepview train --data synthetic:two-planes --preset cpu --name smoke --steps 50 --loss l1 --devices cpu,cpu\n  \
    deepview train --data ../shared/data/llff/fern --data runs/synth/grid-20 --images images_4 --max-width 512 \
    --views 4 --surround-inputs 1 --name mixed --vgg-weights $VGG\n\n\
    Ctrl-C or SIGTERM saves a checkpoint and exits (130 / 143); --resume continues from it. With --resume only \
    --steps, --devices, --data, --keep-checkpoints, --vgg-weights, --validate-every and --max-memory may be given: the others are the run's own, \
    and its datasets load with the scene options they were first loaded with (kept in its config.json). What \
    those options change (all but --max-memory) is written into the run's config.json, so the next --resume \
    goes on with it.\n\n\
    The VGG loss (the default) reads the VGG-16 weights from --vgg-weights FILE (kept in the run's config.json)."
)]
pub struct Args {
    /// Dataset folders (`--data A B` or `--data A --data B`; any format `deepview info` reads).
    /// `synthetic:two-planes` is a built-in analytic scene; `synthetic:procedural` makes a new 3D scene
    /// for every tuple (slanted planes, boxes, spheres, thin bars, semi-transparent sheets, textured with
    /// crops of the other scenes' training views or plain and smoothly shaded; half the tuples when other
    /// data is given, reproducible
    /// from the run's seed, nothing stored). With --resume, defaults to the run's own list
    /// (each with the scene options it was loaded with).
    #[arg(long = "data", value_name = "DIR", num_args = 1.., value_parser = parse_data)]
    pub data: Vec<PathBuf>,
    /// Run name: the run lives in <runs>/<name>/ (a plain name, no '/').
    #[arg(long, value_parser = parse_component)]
    pub name: String,
    /// Folder holding the runs.
    #[arg(long, default_value = "runs")]
    pub runs: PathBuf,
    /// Continue the run from its latest checkpoint (optimizer and RNG state included).
    #[arg(long)]
    pub resume: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub options: TrainOptions,
    #[command(flatten)]
    pub scene: deepview_data::SceneArgs,
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
        anyhow::bail!(
            "started by an MPI launcher as one of {n} ranks, but this deepview was built without MPI \
             support: rebuild it with `cargo build --release -p deepview --features openmpi`"
        );
    }
    train(args, None)
}

fn train(args: Args, comm: Option<Rc<dyn Collective>>) -> anyhow::Result<()> {
    // From here on Ctrl-C / SIGTERM stop the loop, which saves a checkpoint.
    let stop = signals::graceful();
    let run_dir = args.runs.join(&args.name);
    let mut inputs: Vec<Input> = args.data.iter().map(|d| ("--data", d.as_path())).collect();
    if let Some(init) = &args.options.init {
        inputs.push(("--init", init));
    }
    if let Some(v) = &args.options.vgg_weights {
        inputs.push(("--vgg-weights", v));
    }
    check_output("--runs/--name", &run_dir, Kind::Run, &inputs)?;
    let opts = args.scene.load_options();
    let writer = comm.as_ref().is_none_or(|c| c.rank() == 0);
    // Before the data loads: a wrong --max-memory is refused at once.
    let (budget, line) = super::args::memory_budget_of(
        args.options.max_memory.as_deref(),
        super::args::available_memory(),
        super::args::total_memory(),
    )?;
    if budget <= deepview_train::data::STEP_BASE_BYTES {
        anyhow::bail!(
            "--max-memory {}: a training step holds {} MiB whatever its tuple; give more",
            args.options.max_memory.as_deref().unwrap_or("auto"),
            deepview_train::data::STEP_BASE_BYTES >> 20
        );
    }
    if writer {
        eprintln!("training: {line}");
    }
    let request = deepview_train::Request {
        run_dir: &run_dir,
        data: &args.data,
        scene: &opts,
        options: &args.options,
        resume: args.resume,
    };
    let session = deepview_train::session::open(&request, comm)?;
    if writer {
        for n in &session.notices {
            eprintln!("{n}");
        }
    }
    let mut trainer = session.trainer;
    // The datasets, the model and the runtime are loaded: the steps get the rest of the budget.
    let held = super::args::resident_bytes().unwrap_or(0);
    let steps = budget.saturating_sub(held);
    if steps <= deepview_train::data::STEP_BASE_BYTES {
        anyhow::bail!(
            "--max-memory {}: the loaded datasets and the model already hold {} MiB of its {} MiB, which \
             leaves {} MiB for a training step, less than the {} MiB one holds whatever its tuple; give \
             more, or train on fewer or smaller datasets (--max-width)",
            args.options.max_memory.as_deref().unwrap_or("auto"),
            held >> 20,
            budget >> 20,
            steps >> 20,
            deepview_train::data::STEP_BASE_BYTES >> 20
        );
    }
    trainer.set_memory_budget(Some(steps));
    if writer {
        eprintln!(
            "training: the loaded data holds {} MiB of the budget; each step gets up to {} MiB",
            held >> 20,
            steps >> 20
        );
    }
    let start_step = trainer.step;
    let mut progress = Progress::new(writer && !args.quiet, writer);
    let mut validation = match trainer.config.train.validate_every.filter(|_| writer) {
        Some(n) => Some(Validation::new(&trainer.config.train.data, &run_dir, n)?),
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
    let ran = trainer.step - start_step;
    let mut summary = format!(
        "{} at step {} ({ran} steps this session, {skipped} skipped",
        if stop.load(std::sync::atomic::Ordering::SeqCst) {
            "stopped"
        } else {
            "done"
        },
        trainer.step,
    );
    // A session that ran no step (a resume of a finished run) has no speed or losses to report.
    if ran > 0 {
        summary += &format!(", {:.3} steps/s", trainer.steps_per_second());
    }
    summary += ")";
    if !last.is_empty() {
        summary += &format!(
            "; mean loss of the last {}: {:.5}",
            last.len(),
            last.iter().sum::<f64>() / last.len() as f64
        );
    }
    eprintln!("{summary}");
    if let Some((_, ck)) = list_checkpoints(&run_dir)?.pop() {
        eprintln!("checkpoint: {}", ck.display());
    }
    if stop.load(std::sync::atomic::Ordering::SeqCst) {
        return Err(signals::Interrupted(signals::received().unwrap_or(signals::SIGINT)).into());
    }
    Ok(())
}
