//! COLMAP: its command lines (headless, CPU), the check that it runs, and choosing the model it made.

use crate::runner::Runner;
use crate::{CameraModel, Matcher, ProcessError, Stage};
use deepview_data::read_colmap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

impl Matcher {
    pub(crate) fn colmap_command(self) -> &'static str {
        match self {
            Matcher::Sequential => "sequential_matcher",
            _ => "exhaustive_matcher",
        }
    }
}

impl CameraModel {
    pub(crate) fn colmap_name(self) -> &'static str {
        match self {
            CameraModel::SimpleRadial => "SIMPLE_RADIAL",
            CameraModel::Pinhole => "PINHOLE",
        }
    }
}

fn colmap_command(program: &Path, sub: &str) -> Command {
    let mut c = Command::new(program);
    c.arg(sub)
        .env("QT_QPA_PLATFORM", "offscreen")
        .args(["--log_to_stderr", "1"]);
    c
}

/// The error when `program` cannot be started.
fn missing(program: &Path) -> impl FnOnce(String) -> ProcessError + '_ {
    move |reason| ProcessError::ColmapMissing {
        program: program.into(),
        reason,
    }
}

/// SIFT features on the CPU of the photos in `images` into the database `db`: one camera shared by all
/// photos (`shared`, when they have one size), else one camera per photo.
pub(crate) fn extract_features(
    runner: &Runner,
    program: &Path,
    camera_model: CameraModel,
    shared: bool,
    db: &Path,
    images: &Path,
) -> Result<(), ProcessError> {
    let mut c = colmap_command(program, "feature_extractor");
    c.arg("--database_path")
        .arg(db)
        .arg("--image_path")
        .arg(images)
        .args([
            "--ImageReader.single_camera",
            if shared { "1" } else { "0" },
        ])
        .args(["--ImageReader.camera_model", camera_model.colmap_name()])
        .args(["--SiftExtraction.use_gpu", "0"]);
    runner.run(Stage::Features, c, missing(program))
}

/// Match the features in `db` (`matcher` is never `Auto` here).
pub(crate) fn match_features(
    runner: &Runner,
    program: &Path,
    matcher: Matcher,
    db: &Path,
) -> Result<(), ProcessError> {
    let mut c = colmap_command(program, matcher.colmap_command());
    c.arg("--database_path")
        .arg(db)
        .args(["--SiftMatching.use_gpu", "0"]);
    runner.run(Stage::Matching, c, missing(program))
}

/// Incremental structure from motion: models `sparse/0`, `sparse/1`, ...
pub(crate) fn map(
    runner: &Runner,
    program: &Path,
    db: &Path,
    images: &Path,
    sparse: &Path,
) -> Result<(), ProcessError> {
    let mut c = colmap_command(program, "mapper");
    c.arg("--database_path")
        .arg(db)
        .arg("--image_path")
        .arg(images)
        .arg("--output_path")
        .arg(sparse);
    runner.run(Stage::Mapping, c, missing(program))
}

/// Undistort the images of `model` to one PINHOLE camera in `out` (`images/`, `sparse/`).
pub(crate) fn undistort(
    runner: &Runner,
    program: &Path,
    images: &Path,
    model: &Path,
    out: &Path,
) -> Result<(), ProcessError> {
    let mut c = colmap_command(program, "image_undistorter");
    c.arg("--image_path")
        .arg(images)
        .arg("--input_path")
        .arg(model)
        .arg("--output_path")
        .arg(out)
        .args(["--output_type", "COLMAP"]);
    runner.run(Stage::Undistortion, c, missing(program))
}

/// Check that `program` runs (`colmap help`), before any long work.
pub(crate) fn check_colmap(program: &Path) -> Result<(), ProcessError> {
    let missing = |reason: String| ProcessError::ColmapMissing {
        program: program.into(),
        reason,
    };
    let out = Command::new(program)
        .arg("help")
        .env("QT_QPA_PLATFORM", "offscreen")
        .stdin(Stdio::null())
        .output()
        .map_err(|e| missing(e.to_string()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !text.contains("COLMAP") {
        return Err(missing(format!(
            "`{} help` did not print COLMAP's help ({})",
            program.display(),
            out.status
        )));
    }
    Ok(())
}

/// The model folder under `sparse` with the most registered images, and their names.
pub(crate) fn best_model(sparse: &Path) -> Result<Option<(PathBuf, Vec<String>)>, ProcessError> {
    let mut best: Option<(PathBuf, Vec<String>)> = None;
    let Ok(rd) = std::fs::read_dir(sparse) else {
        return Ok(None);
    };
    let mut dirs: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("images.bin").is_file())
        .collect();
    dirs.sort();
    for d in dirs {
        let model = read_colmap(&d)?;
        let mut names: Vec<String> = model.images.iter().map(|i| i.name.clone()).collect();
        names.sort();
        if best.as_ref().is_none_or(|b| names.len() > b.1.len()) {
            best = Some((d, names));
        }
    }
    Ok(best)
}
