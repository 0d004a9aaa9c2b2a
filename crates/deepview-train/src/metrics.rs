//! `metrics.jsonl`: one line per step ([`StepReport`] with the speed and wall time).

use crate::error::{TrainError, io_err};
use crate::files::write_atomic;
use std::io::Write;
use std::path::Path;

/// What one step did.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    pub step: u64,
    /// Mean loss of the batch (NaN if skipped because of it).
    pub loss: f64,
    /// Global gradient norm before clipping (NaN when not computed).
    pub grad_norm: f64,
    pub views: usize,
    /// The most planes of a tuple in the batch.
    pub planes: usize,
    /// The largest estimated memory of a tuple's step in the batch ([`crate::data::step_bytes`]), MiB.
    pub step_mib: u64,
    /// Why the step was skipped (weights untouched), if it was.
    pub skipped: Option<String>,
}

/// Drop metric lines after the current step (written after the checkpoint we resume from).
pub(crate) fn truncate_metrics(run_dir: &Path, step: u64) -> Result<(), TrainError> {
    let path = run_dir.join("metrics.jsonl");
    // Bytes, line by line: a file damaged into something that is not UTF-8 loses its unreadable lines
    // here (it was kept whole, and the next step's line glued onto its last one).
    let Ok(bytes) = std::fs::read(&path) else {
        return Ok(());
    };
    let kept: String = bytes
        .split(|&b| b == b'\n')
        .filter_map(|l| std::str::from_utf8(l).ok())
        .filter(|l| {
            serde_json::from_str::<serde_json::Value>(l)
                .ok()
                .and_then(|v| v.get("step").and_then(|s| s.as_u64()))
                .is_some_and(|s| s <= step)
        })
        .map(|l| format!("{l}\n"))
        .collect();
    write_atomic(&path, kept.as_bytes())
}

pub(crate) fn append_metrics(
    run_dir: &Path,
    r: &StepReport,
    steps_per_s: f64,
    wall_time_s: f64,
) -> Result<(), TrainError> {
    let path = run_dir.join("metrics.jsonl");
    let num = |v: f64| {
        if v.is_finite() {
            serde_json::json!(v)
        } else {
            serde_json::Value::Null
        }
    };
    let line = serde_json::json!({
        "step": r.step,
        "loss": num(r.loss),
        "grad_norm": num(r.grad_norm),
        "views": r.views,
        "planes": r.planes,
        "step_mib": r.step_mib,
        "steps_per_s": num(steps_per_s),
        "wall_time_s": wall_time_s,
        "skipped": r.skipped.is_some(),
    });
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(io_err(&path))?;
    writeln!(f, "{line}").map_err(io_err(&path))
}

#[cfg(test)]
mod tests {
    /// At resume, the lines of steps up to the checkpoint are kept and everything else goes: later
    /// steps, a torn last line, bytes that are not UTF-8 (kept whole, they took the next line with them).
    #[test]
    fn resume_keeps_the_readable_lines_up_to_its_step() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.jsonl");
        let mut bytes = b"{\"step\":1,\"loss\":2.0}\n{\"step\":2,\"loss\":1.5}\n".to_vec();
        bytes.extend_from_slice(
            b"\xff\xfe garbage \x80\n{\"step\":3,\"loss\":1.0}\n{\"step\":4,\"lo",
        );
        std::fs::write(&path, &bytes).unwrap();
        super::truncate_metrics(dir.path(), 3).unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "{\"step\":1,\"loss\":2.0}\n{\"step\":2,\"loss\":1.5}\n{\"step\":3,\"loss\":1.0}\n"
        );
    }
}
