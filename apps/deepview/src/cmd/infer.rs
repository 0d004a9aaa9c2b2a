//! `deepview infer`: an MPI from posed views by any method ([`MethodKind`]; the learned network by
//! default), exactly the MPI `deepview eval --method M` scores from the same inputs. `baseline` and
//! `optimize` are short spellings of `infer --method psv-mean|nearest` and `infer --method optimize`.

use super::args::{self, DataArg};
use super::method::{INPUTS_HELP, Reporter};
use super::safety::{Input, Kind, OutputDir, check_output};
use anyhow::Context;
use deepview_data::SceneArgs;
use deepview_methods::{InputRule, MethodKind, MethodOptions, MpiRequest, make_method};
use std::path::PathBuf;

/// What every MPI-making command takes besides the method.
#[derive(clap::Args, Debug)]
pub struct MpiArgs {
    #[command(flatten)]
    pub data: DataArg,
    #[arg(long, value_name = "RULE", help = INPUTS_HELP)]
    pub inputs: Option<InputRule>,
    #[command(flatten)]
    pub options: MethodOptions,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
    /// Output MPI folder (mpi.json + layer PNGs).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub scene: SceneArgs,
}

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview infer --data ../shared/data/llff/fern --images images_8 --out fern_mpi/\n  \
    deepview infer --data ../shared/data/llff/fern --images images_4 --inputs 1,2,3,4 --planes 64 --out fern_mpi/\n  \
    deepview infer --data ../shared/data/llff/fern --images images_8 --method psv-mean --inputs nearest:4@12 --out psv/\n  \
    deepview infer --data my_scene --downscale 2 --weights runs/mine/checkpoints/step-0005000 --planes weights --out mpi/\n  \
    deepview infer --data my_wide_scene --downscale 2 --compact --out mpi/   # fewer planes, faster to render")]
pub struct Args {
    /// How to make the MPI: deepview (the learned network), psv-mean, nearest or optimize (see `deepview
    /// eval --help`).
    #[arg(long, value_enum, default_value_t = MethodKind::Deepview)]
    pub method: MethodKind,
    #[command(flatten)]
    pub mpi: MpiArgs,
    /// Write the MPI compacted (as `deepview compact` does: planes that hold nothing visible dropped,
    /// runs of near-empty neighbours merged): about half the planes of a wide capture's MPI, faster to
    /// render, at ~0.002 SSIM on held-out views (BENCHMARKS.md; `eval --compact` scores it).
    #[arg(long)]
    pub compact: bool,
    #[command(flatten)]
    pub compaction: super::compact::CompactArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let compaction = args.compact.then(|| args.compaction.options());
    make(args.method, args.mpi, compaction)
}

/// Make the MPI of `kind` from the inputs `args` name and write it (compacted with `compaction`).
fn make(
    kind: MethodKind,
    args: MpiArgs,
    compaction: Option<deepview_mpi::CompactOptions>,
) -> anyhow::Result<()> {
    if args.options.weights.is_some() && kind != MethodKind::Deepview {
        anyhow::bail!("--weights applies to --method deepview (the learned model), not to {kind}");
    }
    let data = args.data.path();
    let mut inputs: Vec<Input> = vec![("--data", data)];
    let weights = args.options.weights.clone().unwrap_or_default();
    if kind == MethodKind::Deepview && args.options.weights.is_some() {
        inputs.push(("--weights", &weights));
    }
    check_output("--out", &args.out, Kind::Mpi, &inputs)?;
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let mut method = make_method(kind, &args.options, budget)?;
    let scene = super::args::load_scene_noted(data, &args.scene.load_options())
        .with_context(|| format!("cannot load scene {}", data.display()))?;
    let near_far = scene.near_far()?;
    let rule = args
        .inputs
        .clone()
        .unwrap_or_else(|| InputRule::default_for(method.views()));
    let ids = rule.select(&scene.cameras(), None, &[])?;
    let views = ids
        .iter()
        .map(|&i| Ok((scene.load_image(i)?, scene.views[i].camera)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let start = std::time::Instant::now();
    let mut reporter = Reporter::new(kind, &ids, method.weights(), true);
    let made = method.make_mpi(
        &MpiRequest {
            inputs: &views,
            ids: &ids,
            near_far,
            toward: None,
        },
        &mut |e| reporter.event(e),
    )?;
    reporter.finish();
    let out = OutputDir::new(&args.out, Kind::Mpi)?;
    // A compacted MPI's planes no longer follow the plane rule: it is not recorded.
    let (compacted, rule) = match compaction {
        Some(o) => {
            let c = deepview_mpi::compact(&made.mpi, &o);
            let note = format!(
                ", compacted from {} planes ({} empty dropped, {} merged)",
                made.mpi.planes(),
                c.dropped,
                c.merged
            );
            (Some((c.mpi, note)), None)
        }
        None => (None, made.planes.as_ref().map(|c| &c.rule)),
    };
    let mpi = compacted.as_ref().map_or(&made.mpi, |(m, _)| m);
    deepview_mpi::write_mpi_with(out.path(), mpi, rule)
        .with_context(|| format!("cannot write the MPI to {}", args.out.display()))?;
    out.commit()?;
    let (far, near) = (mpi.depths[0], mpi.depths[mpi.planes() - 1]);
    let planes = if mpi.planes() == 1 {
        format!(
            "1 plane of {}x{} at depth {near:.4}",
            mpi.camera.width, mpi.camera.height
        )
    } else {
        format!(
            "{} planes of {}x{}, depth {near:.4}..{far:.4}",
            mpi.planes(),
            mpi.camera.width,
            mpi.camera.height
        )
    };
    let note = match (&made.note, kind) {
        (Some(n), MethodKind::Nearest) if ids.len() > 1 => {
            format!(" ({n}, the one nearest their centroid)")
        }
        (Some(n), _) => format!(" ({n})"),
        (None, _) => String::new(),
    };
    let peak = super::bench::peak_rss_mb()
        .map(|mb| format!(", peak memory {:.2} GiB", mb / 1024.0))
        .unwrap_or_default();
    let compacted = compacted.as_ref().map_or("", |(_, n)| n.as_str());
    println!(
        "wrote {}: {kind} MPI of views {ids:?}{note}, {planes}{compacted} ({:.1} s{peak})",
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
