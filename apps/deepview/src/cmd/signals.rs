//! SIGINT (Ctrl-C) and SIGTERM (`kill`, docker, systemd, schedulers), handled alike by every command.
//!
//! [`install`] runs first in `main`. By default a signal removes the temporaries registered with
//! [`register`] (the `.NAME.deepview-tmp.PID` siblings an [`super::safety::OutputDir`] writes into) and exits
//! with 128 + the signal (130 for Ctrl-C, 143 for SIGTERM): the old output stays as it was. A command that
//! can stop cleanly (`train`) calls [`graceful`]: the first signal only sets the returned flag (the trainer
//! saves a checkpoint and returns; `main` then exits with [`Interrupted`]'s code), a second one exits at once.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

/// The signal received (0: none yet).
static SIGNAL: AtomicI32 = AtomicI32::new(0);
/// Temporaries to remove when a signal ends the process.
static TEMPORARIES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
/// Earlier outputs a published one replaced, being removed ([`superseded`]): a signal meanwhile
/// removes them too, and says the new output is in place.
static SUPERSEDED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
/// Set by [`graceful`]: the flag the first signal sets instead of exiting.
static GRACEFUL: OnceLock<Arc<AtomicBool>> = OnceLock::new();

pub const SIGINT: i32 = 2;
pub const SIGTERM: i32 = 15;

/// The error a command returns when it stopped early because of a signal; `main` exits with
/// [`Interrupted::exit_code`].
#[derive(Debug)]
pub struct Interrupted(pub i32);

impl Interrupted {
    pub fn exit_code(&self) -> u8 {
        (128 + self.0).clamp(0, 255) as u8
    }
}

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "interrupted by {}", signal_name(self.0))
    }
}

impl std::error::Error for Interrupted {}

pub fn signal_name(sig: i32) -> &'static str {
    match sig {
        SIGINT => "SIGINT (Ctrl-C)",
        SIGTERM => "SIGTERM",
        _ => "a signal",
    }
}

/// The signal received so far, if any.
pub fn received() -> Option<i32> {
    match SIGNAL.load(Ordering::SeqCst) {
        0 => None,
        s => Some(s),
    }
}

/// The signal that is ending the process, if one came (none for a [`graceful`] command, which goes on
/// to save its work after the first).
pub fn ending() -> Option<i32> {
    match GRACEFUL.get() {
        Some(_) => None,
        None => received(),
    }
}

/// Run `publish` (the renames that put the finished output written in the registered temporary `tmp`
/// in place) with the registry held, so that a signal's cleanup waits for it; not once a signal that
/// ends the process has come (the output stays as it was: an [`Interrupted`] error, while the
/// signal's thread removes `tmp` and ends the process). Published, `tmp` leaves the registry: a later
/// signal finds nothing of this output to remove, and does not say earlier outputs are untouched.
pub fn publish<T>(tmp: &Path, publish: impl FnOnce() -> anyhow::Result<T>) -> anyhow::Result<T> {
    publish_all(&[tmp.to_path_buf()], publish)
}

/// [`publish`] of several outputs at one moment (their temporaries `tmps`).
pub fn publish_all<T>(
    tmps: &[PathBuf],
    publish: impl FnOnce() -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    let mut registry = lock();
    if let Some(sig) = ending() {
        drop(registry);
        return Err(Interrupted(sig).into());
    }
    let published = publish()?;
    registry.retain(|p| !tmps.contains(p));
    Ok(published)
}

/// `path` holds an earlier output that a published one replaced and is about to be removed: a signal
/// until [`unregister_superseded`] removes it and says the new output is in place. Called inside
/// [`publish`]'s closure, so that no signal comes between the swap and this.
pub fn superseded(path: &Path) {
    lock_superseded().push(path.to_path_buf());
}

pub fn unregister_superseded(path: &Path) {
    lock_superseded().retain(|p| p != path);
}

/// The earlier outputs being removed, locked (after the registry, where both are held).
fn lock_superseded() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    SUPERSEDED.lock().unwrap_or_else(|e| e.into_inner())
}

/// Remove `path` (a temporary folder or file) if a signal ends the process before [`unregister`].
pub fn register(path: &Path) {
    lock().push(path.to_path_buf());
}

pub fn unregister(path: &Path) {
    lock().retain(|p| p != path);
}

/// The registry, locked (a panic elsewhere does not stop the cleanup).
pub fn lock() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    TEMPORARIES.lock().unwrap_or_else(|e| e.into_inner())
}

/// From now on the first signal sets the returned flag instead of ending the process.
pub fn graceful() -> Arc<AtomicBool> {
    GRACEFUL
        .get_or_init(|| Arc::new(AtomicBool::new(received().is_some())))
        .clone()
}

fn remove(path: &Path) {
    for _ in 0..5 {
        let r = if path.is_dir() {
            std::fs::remove_dir_all(path)
        } else {
            std::fs::remove_file(path)
        };
        if r.is_ok() || !path.exists() {
            return;
        }
    }
}

/// What a signal does (runs on the watcher thread, not in signal context).
fn on_signal(sig: i32) {
    let first = SIGNAL.swap(sig, Ordering::SeqCst) == 0;
    if let Some(flag) = GRACEFUL.get()
        && first
    {
        flag.store(true, Ordering::SeqCst);
        eprintln!(
            "\n{}: finishing the current step and saving a checkpoint (send it again to stop at once)",
            signal_name(sig)
        );
        return;
    }
    // Hold the registry until the end, so no output is committed meanwhile.
    let temps = lock();
    let earlier = lock_superseded();
    let said = stop_note(&temps, &earlier);
    for t in temps.iter().chain(earlier.iter()) {
        remove(t);
    }
    eprintln!("\n{}: stopped{said}", signal_name(sig));
    std::process::exit(128 + sig);
}

/// What a signal's stop says of the outputs, before it removes `temps` (unfinished outputs) and
/// `earlier` (outputs a published one replaced). A registered temporary that is gone was renamed
/// into place a moment ago (a file's write is atomic, and unregistered after it): nothing of it is
/// unfinished, and nothing is claimed of the output it replaced.
fn stop_note(temps: &[PathBuf], earlier: &[PathBuf]) -> String {
    let unfinished = temps.iter().any(|t| std::fs::symlink_metadata(t).is_ok());
    match (unfinished, earlier.is_empty()) {
        (false, true) => String::new(),
        (true, true) => "; removed the unfinished output, earlier outputs are untouched".into(),
        (false, false) => {
            "; the new output was already in place (removed the earlier one it replaced)".into()
        }
        (true, false) => "; an output was already in place (the earlier one it replaced is \
                          removed); removed the unfinished one, whose earlier output is untouched"
            .into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stop says what is true: an unfinished output removed (the earlier one untouched), a new
    /// output already in place (the earlier one removed), or nothing where a temporary was already
    /// renamed into place.
    #[test]
    fn the_stop_says_what_happened_to_the_outputs() {
        let dir = tempfile::tempdir().unwrap();
        let (writing, renamed) = (dir.path().join(".a.tmp"), dir.path().join(".b.tmp"));
        std::fs::write(&writing, "half").unwrap();
        let old = dir.path().join(".c.deepview-tmp.1");
        assert_eq!(stop_note(std::slice::from_ref(&renamed), &[]), "");
        assert!(
            stop_note(&[writing.clone(), renamed], &[]).contains("earlier outputs are untouched")
        );
        let placed = stop_note(&[], std::slice::from_ref(&old));
        assert!(
            placed.contains("already in place") && !placed.contains("untouched"),
            "{placed}"
        );
        assert!(stop_note(&[writing], &[old]).contains("whose earlier output is untouched"));
    }
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
mod imp {
    use std::sync::atomic::{AtomicI32, Ordering};

    static WRITE_FD: AtomicI32 = AtomicI32::new(-1);

    extern "C" fn handler(sig: libc::c_int) {
        let fd = WRITE_FD.load(Ordering::Relaxed);
        let byte = sig as u8;
        // SAFETY: write(2) is async-signal-safe; the buffer is a local byte.
        unsafe {
            libc::write(fd, (&byte as *const u8).cast(), 1);
        }
    }

    pub fn install() -> std::io::Result<()> {
        let mut fds = [0 as libc::c_int; 2];
        // SAFETY: pipe2 fills the two descriptors of a fresh pipe.
        if unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
        WRITE_FD.store(fds[1], Ordering::SeqCst);
        let read_fd = fds[0];
        std::thread::Builder::new()
            .name("signals".into())
            .spawn(move || {
                loop {
                    let mut byte = 0u8;
                    // SAFETY: reads one byte into a local buffer from the pipe this thread owns.
                    let n = unsafe { libc::read(read_fd, (&mut byte as *mut u8).cast(), 1) };
                    if n == 1 {
                        super::on_signal(byte as i32);
                    } else if n < 0
                        && std::io::Error::last_os_error().kind() != std::io::ErrorKind::Interrupted
                    {
                        return;
                    }
                }
            })?;
        for sig in [libc::SIGINT, libc::SIGTERM] {
            // SAFETY: a zeroed sigaction with a handler that only calls write(2); SA_RESTART keeps
            // interrupted system calls going.
            unsafe {
                let mut sa: libc::sigaction = std::mem::zeroed();
                sa.sa_sigaction = handler as *const () as libc::sighandler_t;
                sa.sa_flags = libc::SA_RESTART;
                libc::sigemptyset(&mut sa.sa_mask);
                if libc::sigaction(sig, &sa, std::ptr::null_mut()) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
        }
        Ok(())
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
mod imp {
    pub fn install() -> std::io::Result<()> {
        // ctrlc's `termination` feature catches SIGTERM too, without saying which signal came.
        ctrlc::set_handler(|| super::on_signal(super::SIGINT)).map_err(std::io::Error::other)
    }
}

/// Install the handlers (once, first thing in `main`).
pub fn install() {
    if let Err(e) = imp::install() {
        eprintln!("warning: cannot handle Ctrl-C / SIGTERM: {e}");
    }
}
