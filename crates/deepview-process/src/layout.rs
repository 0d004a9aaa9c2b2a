//! The output folder: built beside `--out` in `OUT.incomplete` (marked as ours), moved into place at the end.

use crate::ProcessError;
use crate::error::write_err;
use std::path::{Path, PathBuf};

/// Marks a working folder as ours, so that a later run may reuse (clear) it.
pub(crate) const MARKER: &str = ".deepview-process";

/// The folder the scene is built in, beside `out`: cleared when it is ours and no running process holds
/// it, refused otherwise; locked ([`deepview_image::TempLock`]) for as long as the lock is kept, so that
/// a second run on the same `--out` refuses it instead of deleting the first run's work.
pub(crate) fn work_folder(
    out: &Path,
) -> Result<(PathBuf, Option<deepview_image::TempLock>), ProcessError> {
    let name = out.file_name().ok_or_else(|| {
        ProcessError::Invalid(format!("the output {} has no folder name", out.display()))
    })?;
    let mut work_name = name.to_os_string();
    work_name.push(".incomplete");
    let work = out.with_file_name(work_name);
    let busy = |work: PathBuf| ProcessError::WorkFolderBusy {
        out: out.into(),
        path: work,
    };
    if work.exists() {
        if !work.join(MARKER).is_file() {
            return Err(ProcessError::WorkFolderTaken { path: work });
        }
        if deepview_image::is_held(&work) {
            return Err(busy(work));
        }
        std::fs::remove_dir_all(&work).map_err(write_err(&work))?;
    }
    // Made here, not found: another run that made it a moment ago keeps it.
    match std::fs::create_dir(&work) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => return Err(busy(work)),
        Err(e) => return Err(write_err(&work)(e)),
    }
    let lock = deepview_image::lock_temp(&work);
    std::fs::write(work.join(MARKER), "built by deepview process\n").map_err(write_err(&work))?;
    Ok((work, lock))
}

pub(crate) fn out_is_free(out: &Path) -> Result<(), ProcessError> {
    let taken = match std::fs::read_dir(out) {
        Ok(mut rd) => rd.next().is_some(),
        Err(_) => out.exists(),
    };
    if taken {
        Err(ProcessError::OutputExists { path: out.into() })
    } else {
        Ok(())
    }
}

/// Move `from` to `to`, the error naming both.
pub(crate) fn rename(from: &Path, to: &Path) -> Result<(), ProcessError> {
    std::fs::rename(from, to).map_err(|e| ProcessError::Write {
        path: to.into(),
        source: std::io::Error::new(e.kind(), format!("moving {} here: {e}", from.display())),
    })
}
