//! `deepview eval`: score a method on a scene under a protocol. Every method makes an MPI from the
//! target's inputs (as `deepview infer --method M` does) and is scored on its render into the target.

use super::args;
use super::method::{INPUTS_HELP, Reporter};
use super::safety::{Input, Kind, OutputDir, check_output, commit_together, write_file};
use anyhow::Context;
use deepview_eval::{EvalOptions, MpiPredictor, Protocol, TargetRule, evaluate};
use deepview_methods::{InputRule, MethodKind, MethodOptions, make_method};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview eval --data ../shared/data/llff/fern --images images_8 --method psv-mean --out results.json\n  \
    deepview eval --data ../shared/data/llff/fern --images images_8 --method deepview --inputs nearest:4 --targets every:8\n  \
    deepview eval --data scene_000 --near 0.7 --far 100 --protocol small_quad --method nearest\n  \
    deepview eval --data ../shared/data/hci/antinous --method optimize --protocol light-field --targets 40 \
    --save-renders renders/\n  \
    deepview eval --data ../shared/data/llff/fern --images images_8 --method deepview --targets 0 --inputs 1,2,3,4 --save-mpi mpis/")]
pub struct Args {
    /// Dataset folder (LLFF, COLMAP, Spaces, light-field grid).
    #[arg(long, value_name = "DIR")]
    pub data: PathBuf,
    #[command(flatten)]
    pub scene: deepview_data::SceneArgs,
    /// How each target's MPI is made (as `deepview infer --method`).
    #[arg(long, value_enum, default_value_t = MethodKind::PsvMean)]
    pub method: MethodKind,
    /// small_quad | medium_quad | large_quad | dense (Spaces), posed (LLFF, COLMAP), light-field, or auto.
    #[arg(long, default_value = "auto")]
    pub protocol: String,
    /// Targets of posed / light-field protocols: every:N (index % N == 0) or a list like 3,11.
    #[arg(long, value_name = "RULE")]
    pub targets: Option<TargetRule>,
    /// The inputs of each target of the posed protocol. See `--help`.
    #[arg(long, value_name = "RULE", long_help = INPUTS_HELP)]
    pub inputs: Option<InputRule>,
    /// Crop this many pixels from every side instead of the protocol's crop (scaled with --downscale).
    #[arg(long)]
    pub crop: Option<u32>,
    /// Score float predictions as they are instead of rounding to 8 bits like saved PNGs.
    #[arg(long)]
    pub no_quantize: bool,
    #[command(flatten)]
    pub options: MethodOptions,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
    /// Write the report here (JSON: method, checkpoint, protocol, results, views).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write prediction | ground truth | error images here (the folder is replaced when the evaluation
    /// is done: an earlier evaluation's images go, a stopped one leaves them as they were).
    #[arg(long)]
    pub save_renders: Option<PathBuf>,
    /// Write the MPI each target was rendered from here (one MPI folder per target, named like the
    /// renders, replaced as --save-renders): the MPI `deepview infer --method M --inputs ...` writes from
    /// the same inputs.
    #[arg(long, value_name = "DIR")]
    pub save_mpi: Option<PathBuf>,
    /// Score each MPI after `deepview compact` (empty planes dropped, near-empty neighbours merged):
    /// what compaction costs on held-out views.
    #[arg(long)]
    pub compact: bool,
    #[command(flatten)]
    pub compaction: super::compact::CompactArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.options.weights.is_some() && args.method != MethodKind::Deepview {
        anyhow::bail!(
            "--weights applies to --method deepview (the learned model), not to {}",
            args.method
        );
    }
    let weights = args.options.weights.clone().unwrap_or_default();
    let mut inputs: Vec<Input> = vec![("--data", args.data.as_path())];
    if args.options.weights.is_some() {
        inputs.push(("--weights", &weights));
    }
    let mut outputs: Vec<(&str, &std::path::Path, Kind)> = Vec::new();
    if let Some(out) = &args.out {
        outputs.push(("--out", out, Kind::File));
    }
    if let Some(dir) = &args.save_renders {
        outputs.push(("--save-renders", dir, Kind::Renders));
    }
    if let Some(dir) = &args.save_mpi {
        outputs.push(("--save-mpi", dir, Kind::Mpis));
    }
    for (i, &(option, path, kind)) in outputs.iter().enumerate() {
        // Two outputs in one place: each needs its own.
        let r = super::safety::resolve(path);
        for &(other, p, _) in &outputs[..i] {
            let q = super::safety::resolve(p);
            if r == q || r.starts_with(&q) || q.starts_with(&r) {
                anyhow::bail!(
                    "{other} {} and {option} {} overlap: give each output its own place",
                    p.display(),
                    path.display()
                );
            }
        }
        check_output(option, path, kind, &inputs)?;
    }
    // The runner downscales (and scales the protocol's crops with it), so the scene loads at full size.
    let load = deepview_data::LoadOptions {
        downscale: 1,
        ..args.scene.load_options()
    };
    let scene = super::args::load_scene_noted(&args.data, &load)
        .with_context(|| format!("cannot load scene {}", args.data.display()))?;
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let method = make_method(args.method, &args.options, budget)?;
    let given = args.inputs.is_some();
    let mut protocol =
        Protocol::from_name(&args.protocol, args.targets.clone(), args.inputs.clone())?
            .resolve(&scene)?;
    if !given {
        protocol = protocol.with_default_inputs(method.views());
    }
    let checkpoint = method.weights();
    let mut reporter = Reporter::new(args.method, &[], None, false);
    let mut predictor = MpiPredictor::new(method, move |e| reporter.event(e));
    if args.compact {
        predictor = predictor.compacted(args.compaction.options());
    }
    // The renders and MPIs are written into temporary siblings and swapped in once the evaluation is
    // done: an interrupted or failed run leaves the earlier folders (and report) as they were, never a
    // mix of two runs' views.
    let renders = (args.save_renders.as_deref())
        .map(|d| OutputDir::for_option("--save-renders", d, Kind::Renders))
        .transpose()?;
    let mpis = (args.save_mpi.as_deref())
        .map(|d| OutputDir::for_option("--save-mpi", d, Kind::Mpis))
        .transpose()?;
    let options = EvalOptions {
        downscale: args.scene.downscale.max(1),
        near_far: None,
        crop: args.crop,
        quantize: !args.no_quantize,
        save_renders: renders.as_ref().map(|d| d.path().to_path_buf()),
        save_mpis: mpis.as_ref().map(|d| d.path().to_path_buf()),
        // The report names the weights the learned method used (the built-in ones when none was given).
        checkpoint,
        verbose: true,
    };
    let report = evaluate(&scene, &protocol, &mut predictor, &options)?;
    print!("{}", report.table());
    if let Some(mb) = super::bench::peak_rss_mb() {
        println!(
            "peak memory {:.2} GiB (resident, the whole run)",
            mb / 1024.0
        );
    }
    // The folders and the report at one moment (a signal comes before or after all three); where the
    // report cannot be written (a full disk) the folders go back: the earlier run's three stay.
    let dirs: Vec<OutputDir> = [renders, mpis].into_iter().flatten().collect();
    match &args.out {
        Some(out) => write_file(out, |out| {
            commit_together(dirs, || Ok(report.write_json(out)?))
        })?,
        None => commit_together(dirs, || Ok(()))?,
    }
    if let Some(out) = &args.out {
        println!("wrote {}", out.display());
    }
    Ok(())
}
