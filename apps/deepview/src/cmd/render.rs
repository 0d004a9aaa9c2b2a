//! `deepview render`: an MPI seen from a camera (JSON file or a dataset's view).

use super::CameraSource;
use super::args;
use super::safety::{ImageFormat, Input, Kind, OutputDir, check_output, write_file};
use anyhow::bail;
use deepview_image::ImageF32;
use deepview_media::VideoFormat;
use deepview_mpi::{MpiMeta, read_mpi, render};
use std::path::{Path, PathBuf};

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
    /// Frames of a --path (streamed to the output one by one; default 60).
    #[arg(long, value_parser = args::parse_positive, requires = "path")]
    pub frames: Option<usize>,
    /// Radius of a --path as a fraction of the MPI's nearest plane depth (default 0.05).
    #[arg(long, value_parser = args::parse_positive_f64, requires = "path")]
    pub radius: Option<f64>,
    /// Frames per second of a --path video (default 30; a --camera-path uses its own `seconds`).
    #[arg(long, value_parser = args::parse_positive_f64, requires = "path")]
    pub fps: Option<f64>,
    /// Output: an image for one camera (.png, or .jpg/.jpeg: the format follows the name); for a path: a
    /// .gif, a .mp4/.mov/.mkv (needs ffmpeg on the PATH) or a folder (no extension) of PNG frames. Images
    /// are RGB composited over black, or RGBA with --alpha (PNG only).
    #[arg(long)]
    pub out: PathBuf,
    /// Keep the accumulated alpha (straight-alpha RGBA PNG).
    #[arg(long)]
    pub alpha: bool,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
    /// The ffmpeg program for MP4 output (default: `ffmpeg` on PATH).
    #[arg(long, value_name = "PROGRAM", default_value = "ffmpeg")]
    pub ffmpeg: String,
}

impl Args {
    fn inputs(&self) -> Vec<Input<'_>> {
        let mut v: Vec<Input> = vec![("--mpi", self.mpi.as_path())];
        if let Some(c) = &self.source.camera {
            v.push(("--camera", c));
        }
        if let Some(d) = &self.source.scene_dir {
            v.push(("--data", d));
        }
        if let Some(c) = &self.camera_path {
            v.push(("--camera-path", c));
        }
        v
    }
}

/// The kind of a video output: a file named .gif/.mp4/.mov/.mkv, or a folder of frames (no extension).
fn video_kind(out: &Path) -> anyhow::Result<Kind> {
    if VideoFormat::from_path(out) != VideoFormat::PngFrames {
        return Ok(Kind::File);
    }
    if out.extension().is_some() && !out.is_dir() {
        bail!(
            "--out {}: unknown video format (use .gif, .mp4, .mov, .mkv, or a folder name for PNG frames)",
            out.display()
        );
    }
    Ok(Kind::Frames)
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
    if args.alpha {
        bail!(
            "--alpha keeps the alpha of one image (--camera or --view); a camera path's frames, GIF \
             and videos are RGB: leave --alpha out"
        );
    }
    // A dataset view's options (--view, --near, ...) have no dataset here, and a camera path file
    // sets its own frames, rate and cameras: an error, not ignored.
    args.source.camera()?;
    if args.camera_path.is_some() {
        let given: Vec<&str> = [
            (args.frames.is_some(), "--frames"),
            (args.radius.is_some(), "--radius"),
            (args.fps.is_some(), "--fps"),
        ]
        .into_iter()
        .filter_map(|(g, name)| g.then_some(name))
        .collect();
        if !given.is_empty() {
            bail!(
                "{} shape{} a --path only; a --camera-path file sets its own cameras, frame count and \
                 duration (\"seconds\"): leave {} out",
                given.join(", "),
                if given.len() == 1 { "s" } else { "" },
                if given.len() == 1 { "it" } else { "them" }
            );
        }
    }
    let kind = video_kind(&args.out)?;
    check_output("--out", &args.out, kind, &args.inputs())?;
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let (meta, reference) = MpiMeta::read(&args.mpi)?;
    let file = args
        .camera_path
        .as_deref()
        .map(deepview_media::read_camera_path)
        .transpose()?;
    let (frame, frames) = match &file {
        Some(p) => (
            p.cameras.first().copied().unwrap_or(reference),
            p.cameras.len(),
        ),
        None => (reference, args.frames.unwrap_or(60)),
    };
    args::check_memory(
        &format!(
            "{frames} frames of {}x{} from a {}-plane {}x{} MPI",
            frame.width,
            frame.height,
            meta.depths.len(),
            meta.width,
            meta.height
        ),
        args::mpi_bytes(meta.width, meta.height, meta.depths.len(), true)
            .saturating_add(args::video_bytes(&frame, frames)),
        budget,
    )?;
    let mpi = deepview_mpi::read_mpi::<u8>(&args.mpi)?;
    let (cameras, fps) = if let Some(path) = file {
        let fps = path.fps();
        (path.cameras, fps)
    } else {
        let kind: deepview_media::PathKind = args.path.as_deref().unwrap_or("spiral").parse()?;
        let spec = deepview_media::PathSpec {
            kind,
            frames: args.frames.unwrap_or(60),
            radius: deepview_media::Radius::NearFraction(args.radius.unwrap_or(0.05)),
            focus_depth: None,
        };
        (
            deepview_media::make_camera_path(&mpi.camera, &mpi.depths, &spec)?,
            args.fps.unwrap_or(30.0),
        )
    };
    // Frames whose camera is at or beyond the nearest plane show what the scene does not.
    let beyond: Vec<usize> = (0..cameras.len())
        .filter(|&i| deepview_mpi::view_warning(&mpi, &cameras[i], 1.0).is_some())
        .collect();
    if let Some(&first) = beyond.first() {
        eprintln!(
            "warning: {} of {} frames (the first: {first}) have their camera at or beyond the \
             MPI's nearest plane (depth {:.4}); an MPI is made to be seen from in front of its \
             planes",
            beyond.len(),
            cameras.len(),
            mpi.depths.iter().copied().fold(f64::INFINITY, f64::min)
        );
    }
    let report = if kind == Kind::Frames {
        let out = OutputDir::new(&args.out, Kind::Frames)?;
        let r = super::method::video(&mpi, &cameras, (out.path(), &args.out), fps)?;
        out.commit()?;
        r
    } else {
        // The MP4 sink's temporary (`.NAME.PID.tmp.EXT`), removed by a signal like GIF's.
        let ext = args
            .out
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("mp4");
        let mp4_tmp = deepview_image::temp_path(&args.out).with_extension(format!("tmp.{ext}"));
        super::signals::register(&mp4_tmp);
        let r = write_file(&args.out, |out| {
            super::method::video(&mpi, &cameras, (out, &args.out), fps)
        });
        super::signals::unregister(&mp4_tmp);
        r?
    };
    println!(
        "wrote {} ({} frames, {:.1} frames/s rendering)",
        args.out.display(),
        report.frames,
        report.frames as f64 / report.seconds_rendering.max(1e-9)
    );
    Ok(())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    deepview_media::set_ffmpeg_program(&args.ffmpeg);
    super::check_deepview_mpi("--mpi", &args.mpi)?;
    if args.path.is_some() || args.camera_path.is_some() {
        return run_path(&args);
    }
    // (clap lets their `requires = "path"` pass where --camera or --data, which exclude --path, is given.)
    if let Some(flag) = [
        (args.frames.is_some(), "--frames"),
        (args.radius.is_some(), "--radius"),
        (args.fps.is_some(), "--fps"),
    ]
    .into_iter()
    .find_map(|(g, name)| g.then_some(name))
    {
        bail!(
            "{flag} shapes a --path; one image (--camera, --view or the reference) has none: leave it out"
        );
    }
    check_output("--out", &args.out, Kind::File, &args.inputs())?;
    let format = ImageFormat::of("--out", &args.out)?;
    if args.alpha && format == ImageFormat::Jpeg {
        bail!(
            "--alpha needs a PNG output (JPEG has no alpha): --out {}",
            args.out.display()
        );
    }
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let (meta, reference) = MpiMeta::read(&args.mpi)?;
    let camera = args.source.camera()?.unwrap_or(reference);
    args::check_memory(
        &format!(
            "rendering a {}x{} image from a {}-plane {}x{} MPI",
            camera.width,
            camera.height,
            meta.depths.len(),
            meta.width,
            meta.height
        ),
        args::mpi_bytes(meta.width, meta.height, meta.depths.len(), false)
            .saturating_add(args::render_bytes(&camera)),
        budget,
    )?;
    // f32 texels: the colour premultiplied exactly (8-bit texels round it again, and the roundings of
    // faint texels add up over the planes: up to 8.6/255 off on a 33-plane fern MPI, 2026-12-08 audit);
    // the camera paths' frames, like the viewer, take 8-bit ones.
    let mpi = read_mpi::<f32>(&args.mpi)?;
    let img = render(&mpi, &camera);
    if let Some(w) = deepview_mpi::view_warning(&mpi, &camera, deepview_mpi::coverage(&img)) {
        eprintln!("warning: {w}");
    }
    write_file(&args.out, |out| {
        format.write(out, &to_output(&img, args.alpha))
    })?;
    println!(
        "wrote {} ({}x{}, {} planes)",
        args.out.display(),
        camera.width,
        camera.height,
        mpi.planes()
    );
    Ok(())
}
