//! `deepview export MPI_DIR OUT --format llff|stereo-mag|compact`: write an MPI in another tool's format.

use anyhow::Context;
use deepview_media::ExportFormat;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// MPI folder (`mpi.json` + layers).
    pub mpi_dir: PathBuf,
    /// Output folder (created).
    pub out: PathBuf,
    /// llff (metadata.txt + mpi.b), stereo-mag (mpi_rgb_NN.png, mpi_alpha_NN.png, intrinsics.txt) or compact
    /// (32x32 tiles, fully transparent ones dropped; readable by the web viewer and `deepview import`).
    #[arg(long)]
    pub format: String,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let format: ExportFormat = args.format.parse()?;
    let report = deepview_media::export(&args.mpi_dir, &args.out, format).with_context(|| {
        format!(
            "cannot export {} as {}",
            args.mpi_dir.display(),
            args.format
        )
    })?;
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    println!(
        "wrote {} files, {} bytes, to {}",
        report.files.len(),
        report.bytes,
        args.out.display()
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
