//! `deepview compact --mpi IN --out OUT`: an MPI with fewer planes for faster rendering
//! ([`deepview_mpi::compact`]).

use super::args::{MpiArg, OutArg};
use super::safety::{Kind, OutputDir, check_output};
use anyhow::Context;
use deepview_mpi::CompactOptions;

/// How much compaction merges (shared by `compact` and `eval --compact`).
#[derive(clap::Args, Debug, Clone)]
pub struct CompactArgs {
    /// Neighbouring planes merge while their summed mean alpha stays at most this (0: only drop empty
    /// planes).
    #[arg(long, default_value_t = CompactOptions::default().merge_coverage as f64, value_parser = parse_fraction)]
    pub merge_coverage: f64,
    /// At most this many planes merge into one.
    #[arg(long, default_value_t = CompactOptions::default().max_run as u64, value_parser = clap::value_parser!(u64).range(1..=64))]
    pub max_run: u64,
}

impl CompactArgs {
    pub fn options(&self) -> CompactOptions {
        CompactOptions {
            merge_coverage: self.merge_coverage as f32,
            max_run: self.max_run as usize,
            ..Default::default()
        }
    }
}

fn parse_fraction(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!("expected a number from 0 to 1, got {s:?}")),
    }
}

/// Drop the planes of an MPI that hold nothing visible and merge runs of near-empty neighbours into one
/// (over-composited at the reference view, placed at their mean disparity): fewer planes to render. The
/// reference view is unchanged; novel views change little (BENCHMARKS.md measures it with `eval
/// --compact`).
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    deepview compact --mpi fern_mpi --out fern_compact\n  \
    deepview compact --mpi fern_mpi --out fern_dropped --merge-coverage 0\n  \
    deepview bench render --mpi fern_compact")]
pub struct Args {
    #[command(flatten)]
    pub mpi: MpiArg,
    /// Output MPI folder (created).
    #[command(flatten)]
    pub out: OutArg,
    #[command(flatten)]
    pub compaction: CompactArgs,
    #[arg(long, value_name = "SIZE", help = super::args::MEMORY_HELP, value_parser = super::args::parse_memory)]
    pub max_memory: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (input, out) = (args.mpi.path(), args.out.path());
    super::check_deepview_mpi("--mpi", input)?;
    check_output("--out", out, Kind::Mpi, &[("--mpi", input)])?;
    let budget = super::args::memory_budget(args.max_memory.as_deref())?;
    super::args::check_mpis_fit("compacting", &[input], false, 2, budget)?;
    let mpi = deepview_mpi::read_mpi::<f32>(input)
        .with_context(|| format!("cannot read the MPI {}", input.display()))?;
    let c = deepview_mpi::compact(&mpi, &args.compaction.options());
    let dir = OutputDir::new(out, Kind::Mpi)?;
    deepview_mpi::write_mpi(dir.path(), &c.mpi)?;
    dir.commit()?;
    println!(
        "wrote {}: {} planes of {} ({} empty dropped, {} merged into their neighbours)",
        out.display(),
        c.mpi.planes(),
        mpi.planes(),
        c.dropped,
        c.merged
    );
    Ok(())
}
