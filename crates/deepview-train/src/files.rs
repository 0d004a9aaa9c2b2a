//! File operations of the run folder: the run lock, atomic writes, flushes.

use crate::error::{TrainError, io_err};
use std::path::Path;

/// The message of a burn store error, without its `Record I/O error:` prefix.
pub(crate) fn record_message(e: &impl std::fmt::Display) -> String {
    let m = e.to_string();
    m.strip_prefix("Record I/O error: ")
        .unwrap_or(&m)
        .to_string()
}

/// The lock file of a run folder ([`lock_run`]).
const LOCK_FILE: &str = ".lock";

/// A training run folder: `config.json` with `checkpoints/` or `metrics.jsonl`; or a run stopped while
/// [`Trainer::create`](crate::Trainer::create) started it, before its `config.json` was in place:
/// nothing but what it makes first (an empty `checkpoints/`, the `.lock` file, a temporary
/// `config.json`), so that `--resume` starts it.
pub fn is_run_folder(dir: &Path) -> bool {
    if dir.join("config.json").is_file() {
        return dir.join("checkpoints").is_dir() || dir.join("metrics.jsonl").is_file();
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    let mut any = false;
    for e in entries {
        let Ok(e) = e else { return false };
        let name = e.file_name().to_string_lossy().into_owned();
        let starting = match name.as_str() {
            "checkpoints" => std::fs::read_dir(e.path()).is_ok_and(|mut d| d.next().is_none()),
            LOCK_FILE => e.path().is_file(),
            n => deepview_image::is_temp_of(n, "config.json"),
        };
        if !starting {
            return false;
        }
        any = true;
    }
    any
}

/// Lock `run_dir/.lock` so that two processes never train the same run at once (the file is held open
/// read-only: the folder can still be remounted read-only under a running trainer).
pub(crate) fn lock_run(run_dir: &Path) -> Result<std::fs::File, TrainError> {
    let path = run_dir.join(LOCK_FILE);
    if !path.exists() {
        std::fs::File::create(&path).map_err(io_err(&path))?;
    }
    let f = std::fs::File::open(&path).map_err(io_err(&path))?;
    match f.try_lock() {
        // The file locked must still be the one at the path (a run removed meanwhile, with its
        // `.lock`, would leave this lock on a file nobody else opens).
        Ok(()) => {
            use std::os::unix::fs::MetadataExt;
            let same = match (f.metadata(), std::fs::metadata(&path)) {
                (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
                _ => false,
            };
            if same {
                Ok(f)
            } else {
                Err(TrainError::Busy {
                    path: run_dir.to_path_buf(),
                })
            }
        }
        Err(std::fs::TryLockError::WouldBlock) => Err(TrainError::Busy {
            path: run_dir.to_path_buf(),
        }),
        Err(std::fs::TryLockError::Error(e)) => Err(io_err(&path)(e)),
    }
}

/// Write `bytes` to `path` atomically: a temporary file in the same folder, flushed to disk, then
/// renamed over `path` (a crash leaves either the old or the new content, never a torn file).
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), TrainError> {
    deepview_image::write_atomic_with(path, bytes, deepview_image::Durability::Synced)
        .map_err(io_err(path))
}

/// Flush a folder's entries (renames, new files) to disk; best effort (not every filesystem allows it).
pub(crate) fn sync_dir(dir: &Path) {
    if let Ok(f) = std::fs::File::open(dir) {
        let _ = f.sync_all();
    }
}

/// Flush a file's content to disk.
pub(crate) fn sync_file(path: &Path) -> Result<(), TrainError> {
    std::fs::File::open(path)
        .and_then(|f| f.sync_all())
        .map_err(io_err(path))
}
