//! `deepview export-web --mpi MPI_DIR --out OUT`: the viewer page and the MPI's files as a static folder.

use super::args::{MpiArg, OutArg};
use super::safety::{Kind, OutputDir, check_output};
use anyhow::Context;

#[derive(clap::Args)]
#[command(
    after_help = "Example:\n  deepview export-web --mpi fern_mpi/ --out fern_web/\n  python3 -m http.server -d fern_web"
)]
pub struct Args {
    #[command(flatten)]
    pub mpi: MpiArg,
    /// Output folder (created): index.html + the MPI files; upload it to any static web host.
    #[command(flatten)]
    pub out: OutArg,
    #[arg(long, value_name = "SIZE", help = super::args::MEMORY_HELP, value_parser = super::args::parse_memory)]
    pub max_memory: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (mpi_dir, out) = (args.mpi.path(), args.out.path());
    check_output("--out", out, Kind::Web, &[("--mpi", mpi_dir)])?;
    let budget = super::args::memory_budget(args.max_memory.as_deref())?;
    super::args::check_mpis_fit("checking", &[mpi_dir], true, 1, budget)?;
    let dir = OutputDir::new(out, Kind::Web)?;
    let files = deepview_viewer::export_web(mpi_dir, dir.path())
        .with_context(|| format!("cannot export the web viewer for {}", mpi_dir.display()))?;
    let bytes: u64 = files
        .iter()
        .filter_map(|f| std::fs::metadata(f).ok())
        .map(|m| m.len())
        .sum();
    dir.commit()?;
    println!(
        "wrote {} files ({:.1} MB) to {}",
        files.len(),
        bytes as f64 / 1e6,
        out.display()
    );
    println!(
        "serve it with any static web server (browsers do not fetch files from file:// pages), e.g. \
         `python3 -m http.server -d {}`",
        shell_word(&out.display().to_string())
    );
    Ok(())
}

/// `text` as one shell word: as it is where it has nothing the shell reads, else in single quotes.
fn shell_word(text: &str) -> String {
    let plain = !text.is_empty()
        && text
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"/._-+,:@%=".contains(&b));
    if plain {
        text.to_string()
    } else {
        format!("'{}'", text.replace('\'', "'\\''"))
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn shell_words_survive_the_shell() {
        assert_eq!(super::shell_word("fern_web/"), "fern_web/");
        assert_eq!(super::shell_word("my web"), "'my web'");
        assert_eq!(super::shell_word("it's"), "'it'\\''s'");
    }
}
