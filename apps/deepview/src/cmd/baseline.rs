//! `deepview baseline`: the MPI of a classical baseline (no learning, no weights), written as an MPI folder
//! that `render`, `view`, `depth` and `export` read.

use super::{parse_indices, views_nearest_centroid};
use anyhow::Context;
use deepview_data::{SceneArgs, load_scene};
use deepview_eval::{PsvMeanOptions, agreement_mpi, nearest_view_mpi};
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_mpi::write_mpi;
use std::path::PathBuf;

/// Which baseline MPI to build.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BaselineKind {
    /// Plane sweep volume mean colour per plane, alpha from cross-view colour agreement (--planes planes,
    /// in the reference camera of the inputs).
    PsvMean,
    /// One opaque plane holding the input view nearest the inputs' centroid, at the inverse-depth midpoint
    /// of near/far (what `eval --method nearest` reprojects).
    Nearest,
}

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview baseline ../shared/data/llff/fern --images images_8 --method psv-mean --out fern_psv/\n  \
    deepview baseline ../shared/data/llff/fern --images images_8 --method nearest --inputs 3,4,5 --out fern_nearest/\n  \
    deepview render --mpi fern_psv/ --scene ../shared/data/llff/fern --images images_8 --view 0 --out v0.png")]
pub struct Args {
    /// Dataset folder (LLFF, COLMAP, Spaces, light-field grid).
    pub scene_dir: PathBuf,
    /// The baseline.
    #[arg(long, value_enum)]
    pub method: BaselineKind,
    /// Output MPI folder (mpi.json + layer PNGs).
    #[arg(long)]
    pub out: PathBuf,
    /// Input view indices, comma-separated. Default: the 4 views nearest the centroid of all camera centres.
    #[arg(long)]
    pub inputs: Option<String>,
    /// psv-mean: number of MPI planes, equally spaced in inverse depth between near and far (nearest always
    /// writes one plane).
    #[arg(long, default_value_t = 32)]
    pub planes: usize,
    #[command(flatten)]
    pub scene: SceneArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let scene = load_scene(&args.scene_dir, &args.scene.load_options())
        .with_context(|| format!("cannot load scene {}", args.scene_dir.display()))?;
    let near_far = scene.near_far()?;
    let cameras = scene.cameras();
    let indices = match &args.inputs {
        Some(text) => parse_indices(text, cameras.len())?,
        None => views_nearest_centroid(&cameras, 4),
    };
    let load =
        |i: usize| -> anyhow::Result<(ImageF32, Camera)> { Ok((scene.load_image(i)?, cameras[i])) };
    let (mpi, what) = match args.method {
        BaselineKind::PsvMean => {
            let inputs = indices
                .iter()
                .map(|&i| load(i))
                .collect::<anyhow::Result<Vec<_>>>()?;
            let options = PsvMeanOptions {
                planes: args.planes,
                ..Default::default()
            };
            let mpi = agreement_mpi(&inputs, near_far, &options)?;
            (mpi, format!("psv-mean MPI of views {indices:?}"))
        }
        BaselineKind::Nearest => {
            let chosen: Vec<Camera> = indices.iter().map(|&i| cameras[i]).collect();
            let view = indices[views_nearest_centroid(&chosen, 1)[0]];
            let mpi = nearest_view_mpi(&load(view)?, near_far)?;
            let mut what = format!("nearest MPI of view {view} ({})", scene.views[view].name);
            if indices.len() > 1 {
                what += &format!(", the one of views {indices:?} nearest their centroid");
            }
            (mpi, what)
        }
    };
    write_mpi(&args.out, &mpi)
        .with_context(|| format!("cannot write the MPI to {}", args.out.display()))?;
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
    println!("wrote {}: {what}, {planes}", args.out.display());
    Ok(())
}
