//! `deepview render`: an MPI seen from a camera (JSON file or a dataset's view).

use super::CameraSource;
use anyhow::Context;
use deepview_image::{ImageF32, write_png};
use deepview_mpi::{read_mpi, render};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  deepview render --mpi mpi/ --camera cam.json --out view.png\n  \
    deepview render --mpi mpi/ --scene ../shared/data/llff/fern --view 3 --out view3.png")]
pub struct Args {
    /// MPI folder (mpi.json + layer_NNN.png).
    #[arg(long)]
    pub mpi: PathBuf,
    #[command(flatten)]
    pub source: CameraSource,
    /// Output image (PNG). RGB composited over black, or RGBA with --alpha.
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

pub fn run(args: Args) -> anyhow::Result<()> {
    let mpi = read_mpi(&args.mpi)?;
    let camera = args.source.camera()?.unwrap_or(mpi.camera);
    let img = render(&mpi, &camera);
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    write_png(&args.out, &to_output(&img, args.alpha))?;
    println!("wrote {} ({}x{}, {} planes)", args.out.display(), camera.width, camera.height, mpi.planes());
    Ok(())
}
