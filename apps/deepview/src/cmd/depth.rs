//! `deepview depth`: expected depth through the alpha, as a false-colour image and a 16-bit disparity PNG.

use super::CameraSource;
use deepview_mpi::{depth_maps, read_mpi};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  deepview depth --mpi mpi/ --out depth/   (writes depth_color.png, depth_disparity16.png)\n  \
    deepview depth --mpi mpi/ --data ../shared/data/llff/fern --images images_8 --view 3 --out depth3/"
)]
pub struct Args {
    /// MPI folder.
    #[arg(long)]
    pub mpi: PathBuf,
    /// The view to compute depth in (default: the MPI's reference camera).
    #[command(flatten)]
    pub source: CameraSource,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// File name prefix.
    #[arg(long, default_value = "depth")]
    pub prefix: String,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mpi = read_mpi(&args.mpi)?;
    let camera = args.source.camera()?.unwrap_or(mpi.camera);
    let maps = depth_maps(&mpi, &camera);
    maps.write(&args.out, &args.prefix)?;
    println!(
        "wrote {0}/{1}_color.png and {0}/{1}_disparity16.png (disparity 0 = depth {2:.4}, 65535 = depth {3:.4})",
        args.out.display(),
        args.prefix,
        mpi.depths[0],
        mpi.depths[mpi.planes() - 1]
    );
    Ok(())
}
