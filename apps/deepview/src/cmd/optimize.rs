//! `deepview optimize`: fit an MPI to input views by classical gradient descent (no learning) and write it.

use super::args::{self, DataArg, PlanesArg, ViewList};
use super::safety::{Kind, OutputDir, check_output};
use anyhow::Context;
use deepview_eval::Baseline;
use deepview_eval::{OptimizeOptions, optimize_mpi_with_history};
use deepview_geometry::Camera;
use deepview_mpi::write_mpi_with;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview optimize --data ../shared/data/llff/fern --images images_8 --out mpi/\n  \
    deepview optimize --data ../shared/data/llff/fern --images images_8 --inputs 0,1,2,3 --planes 32 --steps 500 --out mpi/")]
pub struct Args {
    #[command(flatten)]
    pub data: DataArg,
    #[command(flatten)]
    pub scene: deepview_data::SceneArgs,
    /// Input view indices, comma-separated. Default: the 4 views nearest the centroid of all camera centres.
    #[arg(long)]
    pub inputs: Option<ViewList>,
    /// Output MPI folder (mpi.json + layer PNGs).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value = "auto", help = args::PLANES_HELP)]
    pub planes: PlanesArg,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
    /// Adam steps.
    #[arg(long, default_value_t = 300, value_parser = args::parse_positive)]
    pub steps: usize,
    /// Adam learning rate on the RGBA logits.
    #[arg(long, default_value_t = 0.1, value_parser = args::parse_positive_f64)]
    pub lr: f64,
    /// Working width: inputs are box-downscaled by an integer factor to at most this width.
    #[arg(long, default_value_t = 160, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_width: u32,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let data = args.data.path();
    check_output("--out", &args.out, Kind::Mpi, &[("--data", data)])?;
    let scene = deepview_data::load_scene(data, &args.scene.load_options())
        .with_context(|| format!("cannot load scene {}", data.display()))?;
    let near_far = scene.near_far()?;
    let indices = match &args.inputs {
        Some(list) => list.check(scene.views.len())?,
        None => super::views_nearest_centroid(&scene.cameras(), 4),
    };
    let cams: Vec<Camera> = indices.iter().map(|&i| scene.views[i].camera).collect();
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let choice = super::eval::baseline_planes(
        Baseline::Optimize,
        args.planes,
        budget,
        &cams,
        &indices,
        near_far,
        args.max_width,
    )?;
    eprintln!("{}", choice.message);
    let inputs: Vec<(deepview_image::ImageF32, Camera)> = indices
        .iter()
        .map(|&i| Ok((scene.load_image(i)?, scene.views[i].camera)))
        .collect::<anyhow::Result<_>>()?;
    let options = OptimizeOptions {
        planes: choice.count,
        steps: args.steps,
        learning_rate: args.lr,
        max_width: args.max_width,
    };
    let start = std::time::Instant::now();
    let (mpi, history) = optimize_mpi_with_history(&inputs, near_far, &options)?;
    let out = OutputDir::new(&args.out)?;
    write_mpi_with(out.path(), &mpi, Some(&choice.rule))
        .with_context(|| format!("cannot write the MPI to {}", args.out.display()))?;
    out.commit()?;
    println!(
        "optimised {} planes {}x{} from {} views in {:.1} s: loss {:.5} -> {:.5}; wrote {}",
        mpi.planes(),
        mpi.camera.width,
        mpi.camera.height,
        inputs.len(),
        start.elapsed().as_secs_f64(),
        history.first().copied().unwrap_or(f64::NAN),
        history.last().copied().unwrap_or(f64::NAN),
        args.out.display()
    );
    Ok(())
}
