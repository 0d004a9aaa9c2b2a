//! `deepview synth`: a synthetic scene with ground truth, rendered through a camera rig.

use anyhow::Context;
use deepview_data::SceneArgs;
use deepview_synth::{Rig, SynthOptions, synthesize_as};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  deepview synth --out synth/grid\n  \
    deepview synth --cameras ../shared/data/spaces/scene_000 --out synth/spaces_000\n  \
    deepview synth --data ../shared/data/llff/fern --images images_8 --out synth/fern_rig\n  \
    deepview synth --out synth/grid_ns --out-format transforms")]
pub struct Args {
    /// Output folder: a dataset in the rig's own format, plus ground_truth_mpi/ and synth.json.
    #[arg(long)]
    pub out: PathBuf,
    /// The rig: `grid` (a generated N x N light-field grid) or a dataset folder whose cameras to use
    /// (Spaces models.json, LLFF, COLMAP, light field).
    #[arg(
        long,
        default_value = "grid",
        visible_alias = "data",
        value_name = "grid|DIR"
    )]
    pub cameras: String,
    /// Grid rig: views per side.
    #[arg(long, default_value_t = 4)]
    pub grid: usize,
    /// Grid rig: image width.
    #[arg(long, default_value_t = 256)]
    pub width: u32,
    /// Grid rig: image height.
    #[arg(long, default_value_t = 192)]
    pub height: u32,
    /// Planes of the ground-truth MPI.
    #[arg(long, default_value_t = 32)]
    pub planes: usize,
    /// Random seed of the scene's layout and textures.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Rays per pixel side (antialiasing).
    #[arg(long, default_value_t = 1)]
    pub supersample: u32,
    /// Write the dataset in this format instead of the rig's own: `transforms` (nerfstudio
    /// transforms.json) works for every rig.
    #[arg(long, value_enum)]
    pub out_format: Option<deepview_data::SceneFormat>,
    #[command(flatten)]
    pub scene: SceneArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let rig = if args.cameras == "grid" {
        Rig::Grid {
            side: args.grid,
            width: args.width,
            height: args.height,
        }
    } else {
        Rig::Dataset {
            path: PathBuf::from(&args.cameras),
            options: args.scene.load_options(),
        }
    };
    let near_far = match (args.scene.near, args.scene.far) {
        (Some(n), Some(f)) => Some((n, f)),
        (None, None) => None,
        _ => anyhow::bail!("give both --near and --far, or neither"),
    };
    let opts = SynthOptions {
        rig,
        seed: args.seed,
        planes: args.planes,
        near_far,
        supersample: args.supersample,
    };
    let out = synthesize_as(&args.out, &opts, args.out_format)
        .with_context(|| format!("cannot synthesise into {}", args.out.display()))?;
    println!(
        "wrote a {} scene with {} views, {} layers between depth {:.3} and {:.3}, to {}",
        out.format,
        out.cameras.len(),
        out.scene.layers.len(),
        out.near_far.0,
        out.near_far.1,
        args.out.display()
    );
    println!(
        "ground-truth MPI ({} planes): {}",
        out.ground_truth.planes(),
        args.out.join("ground_truth_mpi").display()
    );
    Ok(())
}
