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

/// The bytes a temporary sibling's name may add around its output's name (`.`, a tag such as
/// `.deepview-tmp.`, a [`temp_token`], `.tmp.mp4`).
pub const TEMP_NAME_EXTRA: usize = 40;

/// `name` as it appears inside the names of its temporary siblings: itself, or where it is so long that
/// a temporary's name would pass the file systems' 255 bytes (a legal name of 216 bytes or more), its
/// first bytes and a hash of the whole (`LONGPREFIX~1a2b3c4d`), so that every legal output name has
/// temporaries.
pub fn temp_stem(name: &str) -> String {
    const MAX: usize = 255 - TEMP_NAME_EXTRA;
    if name.len() <= MAX {
        return name.to_string();
    }
    // FNV-1a over the bytes: stable across runs and builds, which is what finding a stale one needs.
    let hash = name.bytes().fold(0x811c_9dc5u32, |h, b| {
        (h ^ b as u32).wrapping_mul(0x0100_0193)
    });
    let mut cut = MAX - 9;
    while !name.is_char_boundary(cut) {
        cut -= 1;
    }
    format!("{}~{hash:08x}", &name[..cut])
}

/// This process's part of its temporaries' names: `PID-RANDOM`, the process id (which tells a later run
/// whether the writer still runs) and 8 random hex digits drawn once per process (no other process makes
/// the same names, even with the same id in another PID namespace: every container's first process is 1).
pub fn temp_token() -> &'static str {
    static TOKEN: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    TOKEN.get_or_init(|| {
        use std::hash::{BuildHasher, Hasher};
        // RandomState's keys come from the system's random source, fresh for each process.
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u32(std::process::id());
        format!("{}-{:08x}", std::process::id(), h.finish() as u32)
    })
}

/// What a temporary's name says ([`parse_temp`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TempName<'a> {
    /// The output's name as [`temp_stem`] gives it.
    pub stem: &'a str,
    /// The writer's process id.
    pub pid: &'a str,
    /// `None` for a file (`.STEM.TOKEN.tmp[.EXT]`, EXT given), `Some(tag)` for a folder
    /// (`.STEM.deepview-TAG.TOKEN`).
    pub folder: Option<&'a str>,
    /// A file temporary's extension after `.tmp` (a video's `.tmp.mp4`).
    pub ext: Option<&'a str>,
}

/// The process id of a [`temp_token`] (or of the bare process id older versions wrote).
fn token_pid(token: &str) -> Option<&str> {
    let (pid, random) = token.split_once('-').unwrap_or((token, "0"));
    (!pid.is_empty()
        && pid.bytes().all(|b| b.is_ascii_digit())
        && !random.is_empty()
        && random.len() <= 16
        && random.bytes().all(|b| b.is_ascii_hexdigit()))
    .then_some(pid)
}

/// Parse the name of any temporary this workspace writes: a file's (`.STEM.TOKEN.tmp`, a video's
/// `.STEM.TOKEN.tmp.mp4`) or a folder's (`.STEM.deepview-TAG.TOKEN`); `None` for any other name. The one
/// reader of these names, for the cleanup of stale ones and for telling them from a user's files.
pub fn parse_temp(name: &str) -> Option<TempName<'_>> {
    let n = name.strip_prefix('.')?;
    if let Some((stem, rest)) = n.rsplit_once(".deepview-")
        && let Some((tag, token)) = rest.split_once('.')
        && let Some(pid) = token_pid(token)
        && !stem.is_empty()
        && !tag.is_empty()
    {
        return Some(TempName {
            stem,
            pid,
            folder: Some(tag),
            ext: None,
        });
    }
    parse_temp_file(n)
}

/// The file form of [`parse_temp`] (`n` without its leading dot).
fn parse_temp_file(n: &str) -> Option<TempName<'_>> {
    let (before, ext) = match n.rsplit_once(".tmp.") {
        Some((b, e)) if !e.is_empty() && !e.contains('.') => (b, Some(e)),
        _ => (n.strip_suffix(".tmp")?, None),
    };
    let (stem, token) = before.rsplit_once('.')?;
    let pid = token_pid(token)?;
    // A video sink's `.NAME.TOKEN.tmp.EXT` repeats its output's extension (`a.mp4` -> `.tmp.mp4`);
    // any other tail (`.tmp.bak`) is somebody's file.
    if let Some(e) = ext
        && !stem
            .rsplit_once('.')
            .is_some_and(|(_, own)| own.eq_ignore_ascii_case(e))
    {
        return None;
    }
    (!stem.is_empty()).then_some(TempName {
        stem,
        pid,
        folder: None,
        ext,
    })
}

/// The temporary name used for an atomic write of `path`: `.NAME.TOKEN.tmp` in the same folder (NAME as
/// [`temp_stem`] gives it, TOKEN [`temp_token`]).
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{}.{}.tmp", temp_stem(&name), temp_token()))
}

/// An advisory lock (`flock`) a process holds on a temporary file or folder while it writes it, released
/// when dropped or when the process ends, however it ends. A later run tells a live writer's temporary
/// from the leftover of a killed one by it ([`is_held`]) where process ids do not tell: another PID
/// namespace (a container) on the same machine.
#[derive(Debug)]
pub struct TempLock(#[allow(dead_code)] std::fs::File);

/// Lock the temporary file or folder `path` ([`TempLock`]); `None` where the file system has no locks.
pub fn lock_temp(path: &Path) -> Option<TempLock> {
    let f = std::fs::File::open(path).ok()?;
    lock_file(&f).then_some(TempLock(f))
}

/// Lock an open temporary (exclusively, waiting out another run's brief [`is_held`] probe); false where
/// the file system has no locks. The lock lasts as long as `f` (and its clones) stay open.
pub fn lock_file(f: &std::fs::File) -> bool {
    #[cfg(unix)]
    {
        use std::os::fd::AsRawFd;
        // Another run's probe holds it for an instant: tried for about a second, never waited on
        // (a lock server in its grace period, or a user's `flock`, must not stall a write).
        for _ in 0..100 {
            // SAFETY: flock on a descriptor `f` owns.
            if unsafe { libc::flock(f.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
                return true;
            }
            if std::io::Error::last_os_error().raw_os_error() != Some(libc::EWOULDBLOCK) {
                return false;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        false
    }
    #[cfg(not(unix))]
    {
        let _ = f;
        false
    }
}

/// Whether a running process holds the [`TempLock`] of `path` (false where it cannot be told).
pub fn is_held(path: &Path) -> bool {
    #[cfg(unix)]
    if let Ok(f) = std::fs::File::open(path) {
        use std::os::fd::AsRawFd;
        // A shared probe (it works on a read-only descriptor, NFS included) conflicts with the writer's
        // exclusive lock. A probe that fails for another reason cannot tell: held, to be safe.
        // SAFETY: flock on a descriptor this function owns; a lock it gets goes with the descriptor.
        let r = unsafe { libc::flock(f.as_raw_fd(), libc::LOCK_SH | libc::LOCK_NB) };
        return r != 0;
    }
    false
}

/// Whether the file name `name` is a [`temp_path`] of the file named `file` (from any process): the
/// leftover of an atomic write that was interrupted.
pub fn is_temp_of(name: &str, file: &str) -> bool {
    parse_temp(name)
        .is_some_and(|t| t.folder.is_none() && t.ext.is_none() && t.stem == temp_stem(file))
}

/// Write `bytes` to `path` atomically ([`temp_path`], then a rename), with the I/O error for the caller
/// to wrap in its own error type. The temporary file is removed when any step fails.
pub fn write_atomic_with(path: &Path, bytes: &[u8], durability: Durability) -> std::io::Result<()> {
    let tmp = temp_path(path);
    // A new file (never another process's: the name is this process's), held while it is written: a
    // run that finds it meanwhile leaves it alone ([`is_held`]).
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)
        .map_err(|e| {
            if e.kind() == std::io::ErrorKind::AlreadyExists {
                // This process is writing the file already (another thread): not two at once, and
                // that write's temporary is left to it.
                std::io::Error::new(
                    e.kind(),
                    format!("{} is being written already", tmp.display()),
                )
            } else {
                e
            }
        })?;
    lock_file(&f);
    let mut write = || -> std::io::Result<()> {
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

    #[test]
    fn temporary_names_parse_back() {
        let token = temp_token();
        assert_eq!(token, temp_token(), "one token per process");
        let (pid, random) = token.split_once('-').unwrap();
        assert_eq!(pid, std::process::id().to_string());
        assert_eq!(random.len(), 8);
        let file = temp_path(Path::new("out/view.png"));
        let file = file.file_name().unwrap().to_str().unwrap();
        let t = parse_temp(file).unwrap();
        assert_eq!(
            (t.stem, t.pid, t.folder, t.ext),
            ("view.png", pid, None, None)
        );
        let video = format!(".a.b.mp4.{token}.tmp.mp4");
        let t = parse_temp(&video).unwrap();
        assert_eq!((t.stem, t.folder, t.ext), ("a.b.mp4", None, Some("mp4")));
        let t = parse_temp(".mpi.deepview-tmp.77-00ff12ab").unwrap();
        assert_eq!((t.stem, t.pid, t.folder), ("mpi", "77", Some("tmp")));
        // Older versions' bare process ids.
        let t = parse_temp(".x_color.png.deepview-old.4242").unwrap();
        assert_eq!(
            (t.stem, t.pid, t.folder),
            ("x_color.png", "4242", Some("old"))
        );
        assert_eq!(
            parse_temp(".config.json.4242.tmp").unwrap().stem,
            "config.json"
        );
        for other in [
            "view.png",
            ".view.png",
            ".view.png.tmp",
            ".view.png.x1.tmp",
            ".view.png.12-zz.tmp",
            ".view.png.12-.tmp",
            ".mpi.deepview-tmp.",
            ".mpi.deepview-tmp.abc",
            ".deepview-tmp.12",
            ".notes.txt",
            // A tail other than the output's own extension is somebody's backup, not a video's.
            ".r.png.4000000.tmp.bak",
            ".r.png.4000001-ab.tmp.orig",
        ] {
            assert_eq!(parse_temp(other), None, "{other}");
        }
        // An output whose name holds `.deepview-` has file temporaries too.
        let t = parse_temp(".run.deepview-1.json.77-00ff12ab.tmp").unwrap();
        assert_eq!((t.stem, t.folder), ("run.deepview-1.json", None));
    }

    #[test]
    fn temporaries_are_held_while_their_lock_lives() {
        let dir = tempfile::tempdir().unwrap();
        let (file, folder) = (dir.path().join(".a.png.7.tmp"), dir.path().join("t"));
        std::fs::write(&file, b"x").unwrap();
        std::fs::create_dir(&folder).unwrap();
        for p in [&file, &folder] {
            assert!(!is_held(p));
            let lock = lock_temp(p).expect("a lock on a local file system");
            assert!(is_held(p), "{}", p.display());
            assert!(is_held(p), "a probe took the lock away");
            drop(lock);
            assert!(!is_held(p));
        }
        assert!(!is_held(&dir.path().join("missing")));
    }

    #[test]
    fn every_legal_name_has_a_temporary_and_writes() {
        let dir = tempfile::tempdir().unwrap();
        // The longest names a file system takes (255 bytes), ASCII and with a multi-byte character
        // across the cut; and two of them that differ only at the end.
        let long_a = format!("{}a.png", "x".repeat(249));
        let long_b = format!("{}b.png", "x".repeat(249));
        let accented = format!("{}.json", "é".repeat(125));
        for name in [&long_a, &long_b, &accented] {
            assert!(name.len() <= 255, "{}", name.len());
            let p = dir.path().join(name);
            let tmp = temp_path(&p);
            let t = tmp.file_name().unwrap().to_str().unwrap();
            assert!(t.len() + ".mp4".len() <= 255, "{} bytes", t.len());
            assert!(is_temp_of(t, name), "{t}");
            write_atomic(&p, b"content").unwrap();
            assert_eq!(std::fs::read(&p).unwrap(), b"content");
        }
        assert_ne!(temp_stem(&long_a), temp_stem(&long_b));
        assert!(!is_temp_of(
            temp_path(Path::new(&long_a)).to_str().unwrap(),
            &long_b
        ));
        assert_eq!(temp_stem("short.png"), "short.png");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3);
    }
}
