//! `deepview render`: an MPI seen from a camera (JSON file or a dataset's view).

use super::CameraSource;
use anyhow::Context;
use deepview_image::{ImageF32, write_png};
use deepview_mpi::{read_mpi, render};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  deepview render --mpi mpi/ --camera cam.json --out view.png\n  \
    deepview render --mpi mpi/ --data ../shared/data/llff/fern --images images_8 --view 3 --out view3.png\n  \
    deepview render --mpi mpi/ --path spiral --frames 90 --out spiral.gif\n  \
    deepview render --mpi mpi/ --camera-path camera_path.json --out path.mp4\n  \
    deepview render --mpi mpi/ --path swing --out frames/   (PNG frames)"
)]
pub struct Args {
    /// MPI folder (mpi.json + layer_NNN.png).
    #[arg(long)]
    pub mpi: PathBuf,
    #[command(flatten)]
    pub source: CameraSource,
    /// A camera path around the MPI's reference camera: spiral, circle or swing.
    #[arg(long, conflicts_with_all = ["camera", "scene_dir", "camera_path"])]
    pub path: Option<String>,
    /// A nerfstudio camera_path.json (render_width, render_height, seconds, camera_path[{camera_to_world, fov}]).
    #[arg(long, conflicts_with_all = ["camera", "scene_dir"])]
    pub camera_path: Option<PathBuf>,
    /// Frames of a --path.
    #[arg(long, default_value_t = 60)]
    pub frames: usize,
    /// Radius of a --path as a fraction of the MPI's nearest plane depth.
    #[arg(long, default_value_t = 0.05)]
    pub radius: f64,
    /// Frames per second of a --path video (a --camera-path uses its own `seconds`).
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Output: an image (PNG) for one camera; for a path: a .gif, a .mp4 (needs ffmpeg on the PATH) or a
    /// folder of PNG frames. Images are RGB composited over black, or RGBA with --alpha.
    #[arg(long)]
    pub out: PathBuf,
    /// Keep the accumulated alpha (straight-alpha RGBA PNG).
    #[arg(long)]
    pub alpha: bool,
}

/// Premultiplied RGBA render -> RGB over black, or straight RGBA.
pub fn to_output(img: &ImageF32, alpha: bool) -> ImageF32 {
    if !alpha {
        return img.to_rgb();
    }
    let mut out = img.clone();
    for p in out.data.chunks_exact_mut(4) {
        if p[3] > 0.0 {
            for k in 0..3 {
                p[k] /= p[3];
            }
        }
    }
    out
}

fn run_path(args: &Args) -> anyhow::Result<()> {
    let mpi = deepview_mpi::read_mpi_u8(&args.mpi)?;
    let (cameras, fps) = if let Some(file) = &args.camera_path {
        let path = deepview_media::read_camera_path(file)?;
        let fps = path.fps();
        (path.cameras, fps)
    } else {
        let kind: deepview_media::PathKind = args.path.as_deref().unwrap_or("spiral").parse()?;
        let spec = deepview_media::PathSpec {
            kind,
            frames: args.frames,
            radius: deepview_media::Radius::NearFraction(args.radius),
            focus_depth: None,
        };
        (
            deepview_media::make_camera_path(&mpi.camera, &mpi.depths, &spec)?,
            args.fps,
        )
    };
    let report = deepview_media::render_video(&mpi, &cameras, &args.out, fps, true)?;
    println!(
        "wrote {} ({} frames, {:.1} frames/s rendering)",
        report.path.display(),
        report.frames,
        report.frames as f64 / report.seconds_rendering.max(1e-9)
    );
    Ok(())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.path.is_some() || args.camera_path.is_some() {
        return run_path(&args);
    }
    let mpi = read_mpi(&args.mpi)?;
    let camera = args.source.camera()?.unwrap_or(mpi.camera);
    let img = render(&mpi, &camera);
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    write_png(&args.out, &to_output(&img, args.alpha))?;
    println!(
        "wrote {} ({}x{}, {} planes)",
        args.out.display(),
        camera.width,
        camera.height,
        mpi.planes()
    );
    Ok(())
}
