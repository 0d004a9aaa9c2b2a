//! `deepview export-weights`: turn a training checkpoint into a weights folder for `infer`, `eval`, `demo`.

use anyhow::Context;
use std::path::PathBuf;

/// Convert a training checkpoint (runs/<name>/checkpoints/step-N, or a run folder: its latest
/// checkpoint) into a weights folder: config.json + model.safetensors.
#[derive(clap::Args, Debug)]
#[command(after_help = "Example:\n  deepview export-weights runs/cpu-prior --out weights/cpu")]
pub struct Args {
    /// Checkpoint folder (checkpoints/step-N) or run folder (its latest checkpoint is used).
    pub checkpoint: PathBuf,
    /// Output weights folder.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let ck = if args.checkpoint.join("checkpoints").is_dir() {
        deepview_net::train::list_checkpoints(&args.checkpoint)?
            .pop()
            .map(|(_, p)| p)
            .with_context(|| format!("{}: the run has no checkpoints", args.checkpoint.display()))?
    } else {
        args.checkpoint.clone()
    };
    let config = deepview_net::weights::export_checkpoint(&ck, &args.out)
        .with_context(|| format!("cannot export {}", ck.display()))?;
    eprintln!(
        "exported {} ({} preset) to {}",
        ck.display(),
        config.name,
        args.out.display()
    );
    Ok(())
}
