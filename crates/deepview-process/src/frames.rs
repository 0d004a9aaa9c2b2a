//! Video input: frames extracted with ffmpeg.

use crate::runner::Runner;
use crate::{ProcessError, Stage};
use std::path::Path;
use std::process::Command;

/// Extract `fps` frames per second of `video` into `frames/frame_NNNNN.jpg` (ffmpeg's output in the log).
pub(crate) fn extract_frames(
    runner: &Runner,
    ffmpeg: &Path,
    video: &Path,
    fps: f64,
    frames: &Path,
) -> Result<(), ProcessError> {
    let mut c = Command::new(ffmpeg);
    c.args(["-hide_banner", "-nostdin", "-loglevel", "error", "-i"])
        .arg(video)
        .args(["-vf", &format!("fps={fps}"), "-q:v", "2"])
        .arg(frames.join("frame_%05d.jpg"));
    runner.run(Stage::Frames, c, |reason| ProcessError::FfmpegMissing {
        program: ffmpeg.into(),
        reason,
    })
}
