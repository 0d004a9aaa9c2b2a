//! `deepview export-weights`: turn a training checkpoint into a weights folder for `infer`, `eval`, `demo`.

use super::safety::{Kind, OutputDir, check_output};
use anyhow::Context;
use std::path::{Path, PathBuf};

/// Convert a training checkpoint (runs/<name>/checkpoints/step-N, or a run folder: its latest
/// checkpoint) into a weights folder: config.json + model.safetensors.
#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview export-weights --checkpoint runs/cpu-prior --out weights/cpu\n  \
    deepview export-weights --checkpoint runs/cpu-prior/checkpoints/step-0005000 --out my_weights")]
pub struct Args {
    /// Checkpoint folder (checkpoints/step-N) or run folder (its latest checkpoint is used).
    #[arg(long, value_name = "DIR")]
    pub checkpoint: PathBuf,
    /// Output weights folder.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let given = args.checkpoint;
    check_output(
        "--out",
        &args.out,
        Kind::Weights,
        &[("--checkpoint", &given)],
    )?;
    let ck = if given.join("checkpoints").is_dir() {
        let (step, ck) = deepview_train::list_checkpoints(&given)?
            .pop()
            .with_context(|| format!("{}: the run has no complete checkpoint", given.display()))?;
        // Say so when newer checkpoints are damaged: the export is then not the run's latest step.
        for d in deepview_train::damaged_checkpoints(&given) {
            let newer = Path::new(&d)
                .file_name()
                .and_then(|n| n.to_str())
                .and_then(|n| n.strip_prefix("step-"))
                .and_then(|n| n.parse::<u64>().ok())
                .is_some_and(|s| s > step);
            if newer {
                eprintln!(
                    "warning: skipping the damaged checkpoint {d} (a file is missing or empty)"
                );
            }
        }
        ck
    } else {
        given.clone()
    };
    let dir = OutputDir::new(&args.out, Kind::Weights)?;
    let config = deepview_net::weights::export_checkpoint(&ck, dir.path())
        .with_context(|| format!("cannot export {}", ck.display()))?;
    dir.commit()?;
    eprintln!(
        "exported {} ({} preset) to {}",
        ck.display(),
        config.name,
        args.out.display()
    );
    Ok(())
}
