//! `deepview import --mpi IN --out OUT_MPI_DIR`: read an MPI in any supported format (detected) into our folder format.

use super::args::{MpiArg, OutArg};
use super::safety::{Kind, OutputDir, check_output};
use anyhow::Context;
use deepview_mpi::interchange::ImportOptions;

#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    deepview import --mpi fern_llff/ --out fern_back/\n  \
    deepview import --mpi stereo_mag_mpi/ --near 1 --far 100 --out mpi/   # another tool's, without its depths")]
pub struct Args {
    /// MPI folder in LLFF (metadata.txt + mpi.b), stereo magnification (mpi_rgb_NN.png ...), compact or
    /// deepview format (detected).
    #[command(flatten)]
    pub mpi: MpiArg,
    /// Output MPI folder (created): mpi.json + layer_NNN.png.
    #[command(flatten)]
    pub out: OutArg,
    /// Near plane depth, for stereo magnification folders (which do not store depths).
    #[arg(long, requires = "far")]
    pub near: Option<f64>,
    /// Far plane depth, for stereo magnification folders.
    #[arg(long, requires = "near")]
    pub far: Option<f64>,
    #[arg(long, value_name = "SIZE", help = super::args::MEMORY_HELP, value_parser = super::args::parse_memory)]
    pub max_memory: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let opts = ImportOptions {
        near_far: args.near.zip(args.far),
    };
    let (input, out) = (args.mpi.path(), args.out.path());
    check_output("--out", out, Kind::Mpi, &[("--mpi", input)])?;
    let budget = super::args::memory_budget(args.max_memory.as_deref())?;
    super::args::check_mpis_fit("importing", &[input], true, 2, budget)?;
    // --near/--far only fill in depths a folder lacks: never silently ignored.
    if opts.near_far.is_some() {
        use deepview_mpi::interchange::{ImportFormat, detect_format, stereo_mag};
        let format =
            detect_format(input).with_context(|| format!("cannot import {}", input.display()))?;
        // A README counts only where it records the depths (a user's notes do not).
        let own = match format {
            ImportFormat::StereoMag if input.join(stereo_mag::SIDECAR).is_file() => {
                Some(stereo_mag::SIDECAR)
            }
            ImportFormat::StereoMag => stereo_mag::readme_depths(input)
                .with_context(|| format!("cannot import {}", input.display()))?
                .map(|_| "README, its --min_depth and --max_depth"),
            _ => Some("its own metadata"),
        };
        if let Some(own) = own {
            anyhow::bail!(
                "--near/--far apply to a stereo magnification folder without depths; {} ({format:?}) \
                 carries its own ({own}): leave them out",
                input.display()
            );
        }
    }
    let dir = OutputDir::new(out, Kind::Mpi)?;
    let format = deepview_mpi::import(input, dir.path(), &opts)
        .with_context(|| format!("cannot import {}", input.display()))?;
    dir.commit()?;
    println!(
        "imported {} ({format:?}) into {}",
        input.display(),
        out.display()
    );
    Ok(())
}
