//! The one atomic file write of the workspace: a temporary file beside the target, then a rename, so an
//! interrupted run never leaves a half-written file in place of an earlier one.

use crate::ImageError;
use std::io::Write;
use std::path::{Path, PathBuf};

/// How hard an atomic write tries to survive a crash of the machine (not just of the process).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Durability {
    /// Write, then rename: a killed process leaves the old or the new content.
    #[default]
    Rename,
    /// Also flush the file before the rename and the folder after it (training checkpoints' files): a
    /// power cut leaves the old or the new content.
    Synced,
}

/// A file a file browser leaves in every folder it shows (macOS Finder's `.DS_Store`, Windows Explorer's
/// `Thumbs.db` and `desktop.ini`): not the user's data, so it never keeps an output from being replaced.
pub fn is_file_browser_clutter(name: &str) -> bool {
    matches!(name, ".DS_Store" | "Thumbs.db" | "desktop.ini")
}

/// The temporary name used for an atomic write of `path`: `.NAME.PID.tmp` in the same folder.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// Whether the file name `name` is a [`temp_path`] of the file named `file` (from any process): the
/// leftover of an atomic write that was interrupted.
pub fn is_temp_of(name: &str, file: &str) -> bool {
    name.strip_prefix('.')
        .and_then(|n| n.strip_prefix(file))
        .and_then(|n| n.strip_prefix('.'))
        .and_then(|n| n.strip_suffix(".tmp"))
        .is_some_and(|pid| !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()))
}

/// Write `bytes` to `path` atomically ([`temp_path`], then a rename), with the I/O error for the caller
/// to wrap in its own error type. The temporary file is removed when any step fails.
pub fn write_atomic_with(path: &Path, bytes: &[u8], durability: Durability) -> std::io::Result<()> {
    let tmp = temp_path(path);
    let write = || -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        if durability == Durability::Synced {
            f.sync_all()?;
        }
        Ok(())
    };
    if let Err(e) = write().and_then(|()| std::fs::rename(&tmp, path)) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    if durability == Durability::Synced {
        // Best effort: not every filesystem lets a folder be opened and flushed.
        let dir = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        if let Ok(f) = std::fs::File::open(dir) {
            let _ = f.sync_all();
        }
    }
    Ok(())
}

/// [`write_atomic_with`] without flushing, the error naming `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ImageError> {
    write_atomic_with(path, bytes, Durability::Rename).map_err(|source| ImageError::Write {
        path: path.into(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_replace_and_leave_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.json");
        write_atomic(&p, b"one").unwrap();
        write_atomic_with(&p, b"two", Durability::Synced).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1);
        // A missing folder: an error, and nothing left behind.
        let e = write_atomic(&dir.path().join("no/such/file"), b"x").unwrap_err();
        assert!(e.to_string().contains("no/such/file"), "{e}");
    }

    #[test]
    fn temporary_names_are_recognised_for_their_file_only() {
        let tmp = temp_path(Path::new("run/config.json"));
        let name = tmp.file_name().unwrap().to_str().unwrap();
        assert!(is_temp_of(name, "config.json"));
        assert!(is_temp_of(".config.json.4242.tmp", "config.json"));
        for other in [
            "config.json",
            ".config.json.tmp",
            ".config.json.x1.tmp",
            ".metrics.jsonl.4242.tmp",
            ".config.json.4242.tmp.png",
        ] {
            assert!(!is_temp_of(other, "config.json"), "{other}");
        }
    }
}
