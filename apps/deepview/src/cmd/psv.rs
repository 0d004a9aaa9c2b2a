//! `deepview psv`: the plane sweep volume of one view, written as RGBA images (alpha = validity).

use super::args::{self, DataArg};
use super::safety::{Kind, OutputDir, check_output};
use anyhow::Context;
use deepview_data::SceneArgs;
use deepview_geometry::{PlaneSpacing, ReferenceOptions, plane_depths, reference_camera};
use deepview_methods::Planes;
use deepview_mpi::plane_sweep;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview psv --data ../shared/data/llff/fern --images images_8 --view 1 --reference 0 --planes 16 --out psv/\n  \
    deepview psv --data ../shared/data/llff/fern --images images_8 --view 2 --reference centroid:0,1,2,3 --planes auto --out psv/")]
pub struct Args {
    #[command(flatten)]
    pub data: DataArg,
    /// The view to sweep.
    #[arg(long, default_value_t = 0)]
    pub view: usize,
    /// The camera whose planes to sweep onto: a view index, or `centroid:0,1,2,3` (the reference camera of
    /// those views). Default: the swept view's own camera.
    #[arg(long)]
    pub reference: Option<String>,
    /// Number of planes, equally spaced in inverse depth between near and far, or `auto`: at most 1 px of
    /// disparity apart between the reference camera and the swept view (8..=256; see `deepview infer --help`).
    #[arg(long, default_value = "32")]
    pub planes: Planes,
    /// Output folder for psv_NNN.png (far plane first).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
    #[command(flatten)]
    pub scene: SceneArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let data = args.data.path();
    check_output("--out", &args.out, Kind::Psv, &[("--data", data)])?;
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let scene = super::args::load_scene_noted(data, &args.scene.load_options())
        .with_context(|| format!("cannot load scene {}", data.display()))?;
    let n = scene.views.len();
    super::parse_indices(&args.view.to_string(), n)?;
    let reference = match args.reference.as_deref() {
        None => scene.views[args.view].camera,
        Some(r) if r.starts_with("centroid:") => {
            let idx = super::parse_indices(&r["centroid:".len()..], n)?;
            let cams: Vec<_> = idx.iter().map(|&i| scene.views[i].camera).collect();
            reference_camera(&cams, &ReferenceOptions::default())?
        }
        Some(r) => scene.views[super::parse_indices(r, n)?[0]].camera,
    };
    let (near, far) = scene.near_far()?;
    let view_camera = scene.views[args.view].camera;
    let choice = deepview_methods::choose_planes(
        args.planes,
        &reference,
        &[view_camera],
        &[args.view],
        (near, far),
        None,
        &mut |n| args::psv_bytes(&reference, &view_camera, n) <= budget,
        &mut |n| args::psv_bytes(&reference, &view_camera, n),
    )?;
    if args.planes == Planes::Auto {
        eprintln!("{}", choice.message);
    }
    let depths = plane_depths(near, far, choice.count, PlaneSpacing::InverseDepth)?;
    let image = scene.load_image(args.view)?;
    let psv = plane_sweep(&image, &scene.views[args.view].camera, &reference, &depths);
    let out = OutputDir::new(&args.out, Kind::Psv)?;
    for d in 0..depths.len() {
        let plane = psv.plane(d);
        let img = deepview_image::ImageF32 {
            width: psv.width,
            height: psv.height,
            channels: 4,
            data: plane.to_vec(),
        };
        deepview_image::write_png(&out.path().join(format!("psv_{d:03}.png")), &img)?;
    }
    let meta = serde_json::json!({ "view": args.view, "depths": depths, "width": psv.width, "height": psv.height });
    deepview_image::write_atomic(
        &out.path().join("psv.json"),
        serde_json::to_string_pretty(&meta)?.as_bytes(),
    )?;
    out.commit()?;
    println!(
        "wrote {} planes ({}x{}) to {}",
        depths.len(),
        psv.width,
        psv.height,
        args.out.display()
    );
    Ok(())
}
