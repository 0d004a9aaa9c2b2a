//! `deepview baseline`: the MPI of a classical baseline (no learning, no weights), written as an MPI folder
//! that `render`, `view`, `depth` and `export` read.

use super::args::{self, DataArg, PlanesArg, ViewList};
use super::safety::{Kind, OutputDir, check_output};
use super::views_nearest_centroid;
use anyhow::Context;
use deepview_data::{SceneArgs, load_scene};
use deepview_eval::Baseline;
use deepview_eval::{PsvMeanOptions, agreement_mpi, nearest_view_mpi};
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_mpi::write_mpi_with;
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
    deepview baseline --data ../shared/data/llff/fern --images images_8 --method psv-mean --out fern_psv/\n  \
    deepview baseline --data ../shared/data/llff/fern --images images_8 --method nearest --inputs 3,4,5 --out fern_nearest/\n  \
    deepview render --mpi fern_psv/ --data ../shared/data/llff/fern --images images_8 --view 0 --out v0.png")]
pub struct Args {
    #[command(flatten)]
    pub data: DataArg,
    /// The baseline.
    #[arg(long, value_enum)]
    pub method: BaselineKind,
    /// Output MPI folder (mpi.json + layer PNGs).
    #[arg(long)]
    pub out: PathBuf,
    /// Input view indices, comma-separated. Default: the 4 views nearest the centroid of all camera centres.
    #[arg(long)]
    pub inputs: Option<ViewList>,
    /// psv-mean's planes (nearest always writes one plane). See `deepview infer --help`.
    #[arg(long, default_value = "auto", help = args::PLANES_HELP)]
    pub planes: PlanesArg,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
    #[command(flatten)]
    pub scene: SceneArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let data = args.data.path();
    check_output("--out", &args.out, Kind::Mpi, &[("--data", data)])?;
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let scene = load_scene(data, &args.scene.load_options())
        .with_context(|| format!("cannot load scene {}", data.display()))?;
    let near_far = scene.near_far()?;
    let cameras = scene.cameras();
    let indices = match &args.inputs {
        Some(list) => list.check(cameras.len())?,
        None => views_nearest_centroid(&cameras, 4),
    };
    let load =
        |i: usize| -> anyhow::Result<(ImageF32, Camera)> { Ok((scene.load_image(i)?, cameras[i])) };
    let mut rule = None;
    let (mpi, what) = match args.method {
        BaselineKind::PsvMean => {
            let cams: Vec<Camera> = indices.iter().map(|&i| cameras[i]).collect();
            let c = super::eval::baseline_planes(
                Baseline::PsvMean,
                args.planes,
                budget,
                &cams,
                &indices,
                near_far,
                0,
            )?;
            eprintln!("{}", c.message);
            let inputs = indices
                .iter()
                .map(|&i| load(i))
                .collect::<anyhow::Result<Vec<_>>>()?;
            let options = PsvMeanOptions {
                planes: c.count,
                ..Default::default()
            };
            let mpi = agreement_mpi(&inputs, near_far, &options)?;
            rule = Some(c.rule);
            (mpi, format!("psv-mean MPI of views {indices:?}"))
        }
        BaselineKind::Nearest => {
            let chosen: Vec<Camera> = indices.iter().map(|&i| cameras[i]).collect();
            let view = indices[views_nearest_centroid(&chosen, 1)[0]];
            let c = &cameras[view];
            args::check_memory(
                "the nearest-view MPI",
                args::mpi_bytes(c.width, c.height, 1, false).saturating_mul(2),
                budget,
            )?;
            let mpi = nearest_view_mpi(&load(view)?, near_far)?;
            let mut what = format!("nearest MPI of view {view} ({})", scene.views[view].name);
            if indices.len() > 1 {
                what += &format!(", the one of views {indices:?} nearest their centroid");
            }
            (mpi, what)
        }
    };
    let out = OutputDir::new(&args.out)?;
    write_mpi_with(out.path(), &mpi, rule.as_ref())
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
    println!("wrote {}: {what}, {planes}", args.out.display());
    Ok(())
}
