//! Loading a dataset folder: format detection, the format's reader, then the options common to every
//! format (downscaling, depth-bound overrides) and validation.

use crate::{DataError, LoadOptions, Scene, SceneFormat, TRANSFORMS_JSON, formats};
use deepview_geometry::Camera;
use std::path::Path;

/// What [`detect_format`] looks for, for error messages.
pub const DETECTION_RULES: &str = "poses_bounds.npy (LLFF), models.json (Spaces), cameras.txt / cameras.bin / \
     sparse/0/ (COLMAP), input_Cam000.png (light field), transforms.json (nerfstudio)";

/// The largest far / near ratio of a scene's depth bounds (real captures: up to about 10^3).
pub const MAX_DEPTH_RATIO: f64 = 1e7;

/// Detect the format of a dataset folder from its contents.
pub fn detect_format(path: &Path) -> Result<SceneFormat, DataError> {
    // A nerfstudio / instant-ngp JSON given as a file (e.g. Blender's transforms_train.json).
    if path.is_file()
        && path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        return Ok(SceneFormat::Transforms);
    }
    if !path.exists() {
        return Err(DataError::invalid(
            path,
            "does not exist (expected a dataset folder)",
        ));
    }
    if !path.is_dir() {
        return Err(DataError::invalid(
            path,
            "is not a folder (expected a dataset folder)",
        ));
    }
    let has = |p: &str| path.join(p).exists();
    if has("poses_bounds.npy") {
        Ok(SceneFormat::Llff)
    } else if has("models.json") {
        Ok(SceneFormat::Spaces)
    } else if has("cameras.txt") || has("cameras.bin") || has("sparse/0") {
        Ok(SceneFormat::Colmap)
    } else if has("input_Cam000.png") {
        Ok(SceneFormat::LightField)
    } else if has(TRANSFORMS_JSON) {
        Ok(SceneFormat::Transforms)
    } else if let Err(e) = std::fs::read_dir(path) {
        // A folder whose files cannot be seen (permissions) says so, not that its format is unknown.
        Err(DataError::io(path, e))
    } else {
        Err(DataError::NotDetected {
            path: path.into(),
            looked_for: DETECTION_RULES.into(),
        })
    }
}

/// Load a dataset folder (format detected unless `opts.format` is set).
pub fn load_scene(path: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let format = match opts.format {
        Some(f) => f,
        None => detect_format(path)?,
    };
    let mut scene = match format {
        SceneFormat::Llff => formats::llff::load(path, opts)?,
        SceneFormat::Colmap => formats::colmap::load(path, opts)?,
        SceneFormat::Spaces => formats::spaces::load(path, opts)?,
        SceneFormat::LightField => formats::lightfield::load(path, opts)?,
        SceneFormat::Transforms => formats::transforms::load(path, opts)?,
    };
    if scene.views.is_empty() {
        return Err(DataError::invalid(path, "the scene has no views"));
    }
    // Options of other formats are errors here, not silently ignored.
    if opts.rig != 0 && scene.format != SceneFormat::Spaces {
        return Err(DataError::invalid(
            path,
            format!(
                "--rig {} picks a rig position of a Spaces models.json; this is a {} scene",
                opts.rig, scene.format
            ),
        ));
    }
    // (Light fields ignore it: runs and recipes pass one --images for LLFF scenes and grids together.)
    if let Some(images) = &opts.images
        && scene.format == SceneFormat::Spaces
    {
        return Err(DataError::invalid(
            path,
            format!(
                "--images {images} names an image folder of LLFF, COLMAP or transforms.json scenes; a {} \
                 scene has its images where its calibration says",
                scene.format
            ),
        ));
    }
    let factor = opts.downscale.max(1);
    if factor > 1 {
        for v in &mut scene.views {
            let c = v.camera;
            let (w, h) = (c.width / factor, c.height / factor);
            if w == 0 || h == 0 {
                return Err(DataError::DownscaleTooLarge {
                    path: path.into(),
                    factor,
                    view: v.name.clone(),
                    width: c.width,
                    height: c.height,
                });
            }
            let s = 1.0 / factor as f64;
            v.camera = Camera::new(w, h, c.intrinsics.scaled(s, s), c.pose);
        }
        scene.downscale = factor;
    }
    for v in &scene.views {
        v.camera
            .validate()
            .map_err(|e| DataError::geometry(path, format!("camera of view {}", v.name), e))?;
    }
    scene.depth_bounds = match (opts.near, opts.far, scene.depth_bounds) {
        (Some(n), Some(f), _) => Some((n, f)),
        (Some(n), None, Some((_, f))) => Some((n, f)),
        (None, Some(f), Some((n, _))) => Some((n, f)),
        (None, None, b) => b,
        (n, _, None) => {
            let (given, missing) = if n.is_some() {
                ("near", "far")
            } else {
                ("far", "near")
            };
            return Err(DataError::HalfDepthBounds {
                path: path.into(),
                given,
                missing,
            });
        }
    };
    if let Some((n, f)) = scene.depth_bounds
        && !(n.is_finite() && f.is_finite() && n > 0.0 && f > n)
    {
        // Say which bound came from where: a --near beyond the dataset's far is the usual case.
        let from = |given: Option<f64>, name: &str| match given {
            Some(_) => format!("--{name} {}", if name == "near" { n } else { f }),
            None => format!(
                "{name} {:.4} (the dataset's)",
                if name == "near" { n } else { f }
            ),
        };
        let (near, far) = (from(opts.near, "near"), from(opts.far, "far"));
        let hint = match (opts.near, opts.far) {
            (Some(_), None) => ": give --far too, or a smaller --near",
            (None, Some(_)) => ": give --near too, or a larger --far",
            _ => "",
        };
        return Err(DataError::invalid(
            path,
            format!("invalid depth bounds {near}, {far} (need 0 < near < far, finite){hint}"),
        ));
    }
    // A plane sweep spaces its planes in inverse depth between them: beyond this ratio its disparities are
    // not numbers a capture has (near 1e-300, far 1e300 gave infinite disparity and 256 planes); outside
    // the depth limits f32 loses them.
    if let Some((n, f)) = scene.depth_bounds {
        let given = if opts.near.is_some() || opts.far.is_some() {
            " (--near/--far)"
        } else {
            ""
        };
        let (lo, hi) = deepview_geometry::DEPTH_LIMITS;
        let problem = if f / n > MAX_DEPTH_RATIO {
            format!(
                ": far is more than {MAX_DEPTH_RATIO:e} times near; give bounds that hold the scene"
            )
        } else if n < lo || f > hi {
            format!(
                " lie outside {lo:e}..{hi:e}, the depths deepview works with; give bounds that hold the \
                 scene, or scale its poses"
            )
        } else {
            return Ok(scene);
        };
        return Err(DataError::invalid(
            path,
            format!("depth bounds near {n:e}, far {f:e}{given}{problem}"),
        ));
    }
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SceneArgs;

    #[test]
    fn undetectable_folder_lists_what_was_looked_for() {
        let dir = tempfile::tempdir().unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("poses_bounds.npy")
                && e.contains("models.json")
                && e.contains("input_Cam000.png"),
            "{e}"
        );
        assert!(e.contains(&dir.path().display().to_string()), "{e}");
    }

    #[test]
    fn scene_args_parse() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            scene: SceneArgs,
        }
        let c = Cli::parse_from([
            "x",
            "--format",
            "light-field",
            "--rig",
            "2",
            "--near",
            "1.5",
            "--images",
            "images_4",
        ]);
        let o = c.scene.load_options();
        assert_eq!(o.format, Some(SceneFormat::LightField));
        assert_eq!((o.rig, o.near, o.far), (2, Some(1.5), None));
        assert_eq!(o.images.as_deref(), Some("images_4"));
    }
}
