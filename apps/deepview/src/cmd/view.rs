//! `deepview view --mpi MPI_DIR [--port 8080] [--host 127.0.0.1]`: serve the WebGL2 viewer for an MPI folder.

use super::args::MpiArg;
use anyhow::Context;

#[derive(clap::Args)]
#[command(
    after_help = "Examples:\n  deepview view --mpi fern_mpi/\n  deepview view --mpi fern_mpi/ --port 0 --host 0.0.0.0"
)]
pub struct Args {
    #[command(flatten)]
    pub mpi: MpiArg,
    /// Port to listen on (0: any free port).
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Address to listen on; the default serves this machine only (use 0.0.0.0 to share on the network).
    #[arg(long, default_value = "127.0.0.1")]
    pub host: String,
    #[arg(long, value_name = "SIZE", help = super::args::MEMORY_HELP, value_parser = super::args::parse_memory)]
    pub max_memory: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mpi_dir = args.mpi.path();
    let budget = super::args::memory_budget(args.max_memory.as_deref())?;
    super::args::check_mpis_fit("checking", &[mpi_dir], true, 1, budget)?;
    let server = deepview_viewer::Server::start(mpi_dir, &args.host, args.port)
        .with_context(|| format!("cannot serve the viewer for {}", mpi_dir.display()))?;
    println!(
        "deepview viewer for {}: {}",
        mpi_dir.display(),
        server.url()
    );
    println!(
        "  drag: orbit, right/shift-drag: pan, wheel: dolly, arrows: nudge, D: depth map, R: reset; Ctrl-C to stop"
    );
    if !matches!(args.host.as_str(), "127.0.0.1" | "localhost" | "::1") {
        eprintln!(
            "note: listening on {}: other machines can reach this viewer",
            args.host
        );
    }
    server.wait();
    Ok(())
}
