//! `deepview optimize`: fit an MPI to input views by classical gradient descent (no learning) and write it.

use super::parse_indices;
use anyhow::Context;
use deepview_eval::{OptimizeOptions, optimize_mpi_with_history};
use deepview_geometry::Camera;
use deepview_mpi::write_mpi;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  deepview optimize ../shared/data/llff/fern --inputs 0,1,2,3 --out mpi/"
)]
pub struct Args {
    /// Dataset folder (LLFF, COLMAP, Spaces, light-field grid).
    pub scene_dir: PathBuf,
    #[command(flatten)]
    pub scene: deepview_data::SceneArgs,
    /// Input view indices, comma-separated (default: all views).
    #[arg(long)]
    pub inputs: Option<String>,
    /// Output MPI folder (mpi.json + layer PNGs).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 32)]
    pub planes: usize,
    /// Adam steps.
    #[arg(long, default_value_t = 300)]
    pub steps: usize,
    /// Adam learning rate on the RGBA logits.
    #[arg(long, default_value_t = 0.1)]
    pub lr: f64,
    /// Working width: inputs are box-downscaled by an integer factor to at most this width.
    #[arg(long, default_value_t = 160)]
    pub max_width: u32,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let scene = deepview_data::load_scene(&args.scene_dir, &args.scene.load_options())
        .with_context(|| format!("cannot load scene {}", args.scene_dir.display()))?;
    let near_far = scene.near_far()?;
    let indices = match &args.inputs {
        Some(t) => parse_indices(t, scene.views.len())?,
        None => (0..scene.views.len()).collect(),
    };
    let inputs: Vec<(deepview_image::ImageF32, Camera)> = indices
        .iter()
        .map(|&i| Ok((scene.load_image(i)?, scene.views[i].camera)))
        .collect::<anyhow::Result<_>>()?;
    let options = OptimizeOptions {
        planes: args.planes,
        steps: args.steps,
        learning_rate: args.lr,
        max_width: args.max_width,
    };
    let start = std::time::Instant::now();
    let (mpi, history) = optimize_mpi_with_history(&inputs, near_far, &options)?;
    write_mpi(&args.out, &mpi)?;
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
