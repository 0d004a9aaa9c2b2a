//! `deepview export --mpi MPI_DIR --out OUT --format llff|stereo-mag|compact`: write an MPI in another tool's format.

use super::args::{MpiArg, OutArg};
use super::safety::{Kind, OutputDir, check_output};
use anyhow::Context;
use deepview_mpi::ExportFormat;

#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    deepview export --mpi fern_mpi/ --out fern_llff/ --format llff\n  \
    deepview export --mpi fern_mpi/ --out fern_sm/ --format stereo-mag\n  \
    deepview export --mpi fern_mpi/ --out fern_compact/ --format compact")]
pub struct Args {
    #[command(flatten)]
    pub mpi: MpiArg,
    #[command(flatten)]
    pub out: OutArg,
    /// llff (metadata.txt + mpi.b), stereo-mag (mpi_rgb_NN.png, mpi_alpha_NN.png, intrinsics.txt) or compact
    /// (32x32 tiles, fully transparent ones dropped; readable by the web viewer and `deepview import`).
    #[arg(long)]
    pub format: String,
    #[arg(long, value_name = "SIZE", help = super::args::MEMORY_HELP, value_parser = super::args::parse_memory)]
    pub max_memory: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let format: ExportFormat = args.format.parse()?;
    let (mpi_dir, out) = (args.mpi.path(), args.out.path());
    super::check_deepview_mpi("--mpi", mpi_dir)?;
    check_output("--out", out, Kind::Export, &[("--mpi", mpi_dir)])?;
    let budget = super::args::memory_budget(args.max_memory.as_deref())?;
    super::args::check_mpis_fit("exporting", &[mpi_dir], true, 2, budget)?;
    let dir = OutputDir::new(out, Kind::Export)?;
    // Errors name the output as the user gave it, not the temporary folder it is written in.
    let report = deepview_mpi::export(mpi_dir, dir.path(), format)
        .map_err(|e| {
            let (text, tmp) = (e.to_string(), dir.path().display().to_string());
            if text.contains(&tmp) {
                anyhow::anyhow!(text.replace(&tmp, &out.display().to_string()))
            } else {
                anyhow::Error::new(e)
            }
        })
        .with_context(|| format!("cannot export {} as {}", mpi_dir.display(), args.format))?;
    super::safety::write_export_manifest(dir.path(), &report.files)?;
    dir.commit()?;
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    println!(
        "wrote {} files, {} bytes, to {}",
        report.files.len(),
        report.bytes,
        out.display()
    );
    if let Some((kept, total)) = report.tiles {
        println!(
            "compact: kept {kept} of {total} tiles ({:.1}% of the texels); {} bytes vs {} bytes of layer PNGs ({:+.1}%)",
            100.0 * kept as f64 / total.max(1) as f64,
            report.bytes,
            report.source_bytes,
            100.0 * (report.bytes as f64 / report.source_bytes.max(1) as f64 - 1.0)
        );
    }
    Ok(())
}
