//! `deepview import IN OUT_MPI_DIR`: read an MPI in any supported format (detected) into our folder format.

use anyhow::Context;
use deepview_media::interchange::ImportOptions;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Folder in LLFF (metadata.txt + mpi.b), stereo magnification (mpi_rgb_NN.png ...), compact or deepview format.
    pub input: PathBuf,
    /// Output MPI folder (created): mpi.json + layer_NNN.png.
    pub out: PathBuf,
    /// Near plane depth, for stereo magnification folders (which do not store depths).
    #[arg(long, requires = "far")]
    pub near: Option<f64>,
    /// Far plane depth, for stereo magnification folders.
    #[arg(long, requires = "near")]
    pub far: Option<f64>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let opts = ImportOptions {
        near_far: args.near.zip(args.far),
    };
    let format = deepview_media::import(&args.input, &args.out, &opts)
        .with_context(|| format!("cannot import {}", args.input.display()))?;
    println!(
        "imported {} ({format:?}) into {}",
        args.input.display(),
        args.out.display()
    );
    Ok(())
}
