//! Running the external programs (COLMAP, ffmpeg) with their output appended to the scene's log.

use crate::error::write_err;
use crate::{ProcessError, Stage};
use std::fs::{File, OpenOptions};
use std::io::Write as _;
use std::path::PathBuf;
use std::process::{Command, Stdio};

/// Runs programs with their output appended to the log.
pub(crate) struct Runner {
    pub(crate) log: PathBuf,
}

impl Runner {
    fn open(&self) -> Result<File, ProcessError> {
        OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.log)
            .map_err(write_err(&self.log))
    }

    /// The last `n` non-empty lines of the log.
    fn tail(&self, n: usize) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
        lines[lines.len().saturating_sub(n)..].join("\n")
    }

    /// Run `cmd` for `stage`; `missing` builds the error when the program cannot be started.
    pub(crate) fn run(
        &self,
        stage: Stage,
        mut cmd: Command,
        missing: impl FnOnce(String) -> ProcessError,
    ) -> Result<(), ProcessError> {
        let mut f = self.open()?;
        let line = format!("{cmd:?}").replace('"', "");
        writeln!(f, "\n===== {stage}: {line}").map_err(write_err(&self.log))?;
        let out = f.try_clone().map_err(write_err(&self.log))?;
        let err = f.try_clone().map_err(write_err(&self.log))?;
        // COLMAP and ffmpeg end with this process (a SIGTERM to `deepview process` stops them too).
        let status = deepview_image::child::die_with_parent(&mut cmd)
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(err)
            .status()
            .map_err(|e| missing(e.to_string()))?;
        if status.success() {
            Ok(())
        } else {
            Err(ProcessError::StageFailed {
                stage,
                status: status.to_string(),
                log: self.log.clone(),
                tail: self.tail(15),
            })
        }
    }
}
