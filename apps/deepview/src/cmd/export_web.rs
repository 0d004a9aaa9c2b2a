//! `deepview export-web MPI_DIR OUT`: the viewer page and the MPI's files as a static folder.

use anyhow::Context;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// MPI folder (`mpi.json` + layers, or a compact export).
    pub mpi_dir: PathBuf,
    /// Output folder (created): index.html + the MPI files; upload it to any static web host.
    pub out: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let files = deepview_viewer::export_web(&args.mpi_dir, &args.out).with_context(|| {
        format!(
            "cannot export the web viewer for {}",
            args.mpi_dir.display()
        )
    })?;
    let bytes: u64 = files
        .iter()
        .filter_map(|f| std::fs::metadata(f).ok())
        .map(|m| m.len())
        .sum();
    println!(
        "wrote {} files ({:.1} MB) to {}",
        files.len(),
        bytes as f64 / 1e6,
        args.out.display()
    );
    println!(
        "serve it with any static web server (browsers do not fetch files from file:// pages), e.g. \
         `python3 -m http.server -d {}`",
        args.out.display()
    );
    Ok(())
}
