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
        .arg(deepview_image::ffmpeg_file_arg(video))
        .args(["-vf", &format!("fps={fps}"), "-q:v", "2"])
        .arg(deepview_image::ffmpeg_file_arg(
            &frames.join("frame_%05d.jpg"),
        ));
    runner.run(Stage::Frames, c, |reason| ProcessError::FfmpegMissing {
        program: ffmpeg.into(),
        reason,
    })
}

/// Check that `ffmpeg` runs (`ffmpeg -version`), before any work.
pub(crate) fn check_ffmpeg(ffmpeg: &Path) -> Result<(), ProcessError> {
    let missing = |reason: String| ProcessError::FfmpegMissing {
        program: ffmpeg.into(),
        reason,
    };
    let out = Command::new(ffmpeg)
        .arg("-version")
        .stdin(std::process::Stdio::null())
        .output()
        .map_err(|e| missing(e.to_string()))?;
    if !out.status.success() {
        return Err(missing(format!(
            "`{} -version` failed ({})",
            ffmpeg.display(),
            out.status
        )));
    }
    Ok(())
}
