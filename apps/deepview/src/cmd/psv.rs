//! `deepview psv`: the plane sweep volume of one view, written as RGBA images (alpha = validity).

use anyhow::Context;
use deepview_data::{SceneArgs, load_scene};
use deepview_geometry::{PlaneSpacing, ReferenceOptions, plane_depths, reference_camera};
use deepview_mpi::plane_sweep;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  deepview psv ../shared/data/llff/fern --view 1 --reference 0 --planes 16 --out psv/"
)]
pub struct Args {
    /// Dataset folder.
    pub scene_dir: PathBuf,
    /// The view to sweep.
    #[arg(long, default_value_t = 0)]
    pub view: usize,
    /// The camera whose planes to sweep onto: a view index, or `centroid:0,1,2,3` (the reference camera of
    /// those views). Default: the swept view's own camera.
    #[arg(long)]
    pub reference: Option<String>,
    /// Number of planes (equally spaced in inverse depth between near and far).
    #[arg(long, default_value_t = 32)]
    pub planes: usize,
    /// Output folder for psv_NNN.png (far plane first).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub scene: SceneArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let scene = load_scene(&args.scene_dir, &args.scene.load_options())?;
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
    let depths = plane_depths(near, far, args.planes, PlaneSpacing::InverseDepth)?;
    let image = scene.load_image(args.view)?;
    let psv = plane_sweep(&image, &scene.views[args.view].camera, &reference, &depths);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    for d in 0..depths.len() {
        let plane = psv.plane(d);
        let img = deepview_image::ImageF32 {
            width: psv.width,
            height: psv.height,
            channels: 4,
            data: plane.to_vec(),
        };
        deepview_image::write_png(&args.out.join(format!("psv_{d:03}.png")), &img)?;
    }
    let meta = serde_json::json!({ "view": args.view, "depths": depths, "width": psv.width, "height": psv.height });
    deepview_image::write_atomic(
        &args.out.join("psv.json"),
        serde_json::to_string_pretty(&meta)?.as_bytes(),
    )?;
    println!(
        "wrote {} planes ({}x{}) to {}",
        depths.len(),
        psv.width,
        psv.height,
        args.out.display()
    );
    Ok(())
}
