//! Child processes (COLMAP, ffmpeg) that end with their parent.

use std::process::Command;

/// Make the program `cmd` starts receive SIGTERM when this process ends, however it ends (a signal, an
/// exit, a crash): a stopped `deepview process` or `render` leaves no COLMAP or ffmpeg behind writing into
/// its folders. Linux only (`PR_SET_PDEATHSIG`); elsewhere a no-op.
///
/// Start the child from a thread that lives as long as the process (the main thread): the kernel sends
/// the signal when the thread that started it ends.
pub fn die_with_parent(cmd: &mut Command) -> &mut Command {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        let parent = std::process::id();
        // SAFETY: the closure runs in the child between fork and exec and only calls prctl(2) and
        // getppid(2), both async-signal-safe; it allocates nothing.
        unsafe {
            cmd.pre_exec(move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                // The parent may have ended before the prctl: then end now.
                if libc::getppid() as u32 != parent {
                    libc::_exit(143);
                }
                Ok(())
            });
        }
    }
    cmd
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;
    use std::io::Read;
    use std::process::Stdio;

    /// The hook leaves the program to start and run normally (that it ends with its parent is tested end
    /// to end: `deepview process` stopped by SIGTERM, in the app's tests).
    #[test]
    fn the_program_starts_and_runs_normally() {
        let mut c = Command::new("sh");
        c.args(["-c", "echo started"]).stdout(Stdio::piped());
        let mut child = die_with_parent(&mut c).spawn().unwrap();
        let mut out = String::new();
        child
            .stdout
            .take()
            .unwrap()
            .read_to_string(&mut out)
            .unwrap();
        assert_eq!(out.trim(), "started");
        assert!(child.wait().unwrap().success());
    }
}
