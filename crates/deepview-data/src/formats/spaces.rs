//! Spaces: `models.json`, a list per rig position of camera dicts (16 per rig in the dataset).
//!
//! Per camera: `principal_point [cx, cy]` and `focal_length` in pixels (`fy = focal_length *
//! pixel_aspect_ratio`), `position` (camera centre, world), `orientation` (axis-angle of the camera-from-world
//! rotation, converted by `spaces_to_pose`), `width`, `height`, `relative_path` (`cam_NN/image_NNN.JPG`).
//! The principal point is used as given (this project's pixel-centre convention is assumed). The file has no
//! depth bounds: pass `--near/--far`.

use crate::{DataError, LoadOptions, Scene, SceneFormat, View};
use deepview_geometry::convention::{pose_to_spaces, spaces_to_pose};
use deepview_geometry::{Camera, Intrinsics};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub const MODELS_JSON: &str = "models.json";

/// Mirror of one camera dict of `models.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpacesCamera {
    pub principal_point: [f64; 2],
    pub focal_length: f64,
    #[serde(default = "one")]
    pub pixel_aspect_ratio: f64,
    pub position: [f64; 3],
    pub orientation: [f64; 3],
    pub width: f64,
    pub height: f64,
    pub relative_path: String,
}

fn one() -> f64 {
    1.0
}

/// The conventional relative path of camera `cam` at rig position `rig`: `cam_NN/image_NNN.JPG`.
pub fn spaces_relative_path(cam: usize, rig: usize) -> String {
    format!("cam_{cam:02}/image_{rig:03}.JPG")
}

/// Parse `models.json` text; `path` only names the source in errors.
pub fn parse_models(text: &str, path: &Path) -> Result<Vec<Vec<SpacesCamera>>, DataError> {
    serde_json::from_str(text).map_err(|source| DataError::Json {
        path: path.into(),
        source,
    })
}

impl SpacesCamera {
    /// This camera in the project's conventions.
    pub fn to_camera(&self, path: &Path, what: &str) -> Result<Camera, DataError> {
        let size = |v: f64, name: &str| -> Result<u32, DataError> {
            if v.is_finite() && v >= 1.0 && v.fract() == 0.0 && v <= u32::MAX as f64 {
                Ok(v as u32)
            } else {
                Err(DataError::invalid(
                    path,
                    format!("{what}: {name} {v} is not a positive whole number"),
                ))
            }
        };
        let (w, h) = (size(self.width, "width")?, size(self.height, "height")?);
        let pose = spaces_to_pose(self.orientation, self.position)
            .map_err(|e| DataError::geometry(path, what, e))?;
        let k = Intrinsics::new(
            self.focal_length,
            self.focal_length * self.pixel_aspect_ratio,
            self.principal_point[0],
            self.principal_point[1],
        );
        k.validate()
            .map_err(|e| DataError::geometry(path, what, e))?;
        Ok(Camera::new(w, h, k, pose))
    }

    pub fn from_camera(cam: &Camera, relative_path: &str) -> Self {
        let (orientation, position) = pose_to_spaces(&cam.pose);
        let k = &cam.intrinsics;
        SpacesCamera {
            principal_point: [k.cx, k.cy],
            focal_length: k.fx,
            pixel_aspect_ratio: k.fy / k.fx,
            position,
            orientation,
            width: cam.width as f64,
            height: cam.height as f64,
            relative_path: relative_path.into(),
        }
    }
}

pub(crate) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let path = root.join(MODELS_JSON);
    let rigs = parse_models(&crate::read_text(&path)?, &path)?;
    let rig = rigs.get(opts.rig).ok_or(DataError::RigOutOfRange {
        path: path.clone(),
        rig: opts.rig,
        count: rigs.len(),
    })?;
    if rig.is_empty() {
        return Err(DataError::invalid(
            &path,
            format!("rig position {} has no cameras", opts.rig),
        ));
    }
    let mut views = Vec::with_capacity(rig.len());
    for (i, c) in rig.iter().enumerate() {
        if let Some(j) = rig[..i]
            .iter()
            .position(|o| o.relative_path == c.relative_path)
        {
            return Err(DataError::invalid(
                &path,
                format!(
                    "rig {} cameras {j} and {i} both name the image {}: list each image once",
                    opts.rig, c.relative_path
                ),
            ));
        }
        let camera = c.to_camera(&path, &format!("rig {} camera {i}", opts.rig))?;
        let name = Path::new(&c.relative_path)
            .with_extension("")
            .to_string_lossy()
            .into_owned();
        views.push(View {
            name,
            image_path: root.join(&c.relative_path),
            camera,
        });
    }
    Ok(Scene {
        root: root.into(),
        format: SceneFormat::Spaces,
        views,
        depth_bounds: None,
        grid: None,
        rig_count: rigs.len(),
        downscale: 1,
    })
}

/// Write `models.json` for `rigs` (one list of cameras per rig position) with the image paths relative to
/// the file's folder (e.g. from [`spaces_relative_path`]).
pub fn write_spaces_models(
    path: &Path,
    rigs: &[Vec<Camera>],
    relative_paths: &[Vec<String>],
) -> Result<(), DataError> {
    if rigs.len() != relative_paths.len()
        || rigs
            .iter()
            .zip(relative_paths)
            .any(|(r, p)| r.len() != p.len())
    {
        return Err(DataError::CountMismatch {
            path: path.into(),
            msg: "every rig position needs one relative path per camera".into(),
        });
    }
    let models: Vec<Vec<SpacesCamera>> = rigs
        .iter()
        .zip(relative_paths)
        .map(|(r, p)| {
            r.iter()
                .zip(p)
                .map(|(c, p)| SpacesCamera::from_camera(c, p))
                .collect()
        })
        .collect();
    let text = serde_json::to_string_pretty(&models).map_err(|source| DataError::Json {
        path: path.into(),
        source,
    })?;
    crate::write_bytes(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load_scene;
    use deepview_geometry::{DMat3, DVec3, Pose};

    const ONE: &str = r#"[[{"pixel_aspect_ratio": 0.99, "position": [-0.017, 0.018, 0.013], "width": 800.0,
        "relative_path": "cam_00/image_000.JPG", "principal_point": [391.8, 244.4],
        "orientation": [0.0, 0.1, 0.0], "focal_length": 225.5, "height": 481.0}]]"#;

    #[test]
    fn parse_in_memory() {
        let m = parse_models(ONE, Path::new("models.json")).unwrap();
        let c = m[0][0].to_camera(Path::new("models.json"), "c").unwrap();
        assert_eq!((c.width, c.height), (800, 481));
        assert!((c.intrinsics.fy - 225.5 * 0.99).abs() < 1e-12);
        assert_eq!(c.intrinsics.cx, 391.8);
        // x_cam = R (X - position): the position maps to the camera origin, R rotates about y by 0.1.
        assert!(
            c.pose
                .transform_point(DVec3::new(-0.017, 0.018, 0.013))
                .length()
                < 1e-15
        );
        assert!(
            c.pose
                .rotation
                .abs_diff_eq(DMat3::from_rotation_y(0.1), 1e-15)
        );
    }

    #[test]
    fn malformed_json_and_bad_values() {
        let p = Path::new("dir/models.json");
        let e = parse_models("[[{\"width\": 8", p).unwrap_err().to_string();
        assert!(
            e.contains("dir/models.json") && e.contains("malformed JSON"),
            "{e}"
        );
        let e = parse_models(&ONE.replace("\"focal_length\"", "\"focal\""), p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("focal_length"), "{e}");
        let bad = parse_models(&ONE.replace("[0.0, 0.1, 0.0]", "[0.0, 1e400, 0.0]"), p);
        // serde_json refuses 1e400 as out of range; either way the error names the file.
        if let Err(e) = bad {
            assert!(e.to_string().contains("dir/models.json"));
        } else {
            panic!("an infinite orientation must be refused");
        }
        let m = parse_models(&ONE.replace("481.0", "481.5"), p).unwrap();
        let e = m[0][0]
            .to_camera(p, "rig 0 camera 0")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("dir/models.json") && e.contains("height 481.5"),
            "{e}"
        );
    }

    #[test]
    fn writer_round_trip_rig_index_and_missing_images() {
        let dir = tempfile::tempdir().unwrap();
        let rigs: Vec<Vec<Camera>> = (0..2)
            .map(|r| {
                (0..3)
                    .map(|i| {
                        let rot = DMat3::from_rotation_z(0.1 * i as f64)
                            * DMat3::from_rotation_x(0.02 * r as f64);
                        let k = Intrinsics::new(200.0 + i as f64, 201.0, 40.5, 30.25);
                        Camera::new(
                            80,
                            60 + i,
                            k,
                            Pose::from_center(rot, DVec3::new(i as f64 * 0.1, r as f64, 0.0)),
                        )
                    })
                    .collect()
            })
            .collect();
        let paths: Vec<Vec<String>> = (0..2)
            .map(|r| (0..3).map(|i| spaces_relative_path(i, r)).collect())
            .collect();
        write_spaces_models(&dir.path().join(MODELS_JSON), &rigs, &paths).unwrap();
        for r in 0..2 {
            let s = load_scene(
                dir.path(),
                &LoadOptions {
                    rig: r,
                    ..Default::default()
                },
            )
            .unwrap();
            assert_eq!(
                (s.format, s.rig_count, s.len()),
                (SceneFormat::Spaces, 2, 3)
            );
            for (v, c) in s.views.iter().zip(&rigs[r]) {
                assert_eq!((v.camera.width, v.camera.height), (c.width, c.height));
                assert!((v.camera.intrinsics.fy - c.intrinsics.fy).abs() < 1e-9);
                assert!(v.camera.pose.rotation.abs_diff_eq(c.pose.rotation, 1e-12));
                assert!(v.camera.center().abs_diff_eq(c.center(), 1e-12));
            }
            assert!(
                s.views[1]
                    .image_path
                    .ends_with(format!("cam_01/image_{r:03}.JPG"))
            );
        }
        let e = load_scene(
            dir.path(),
            &LoadOptions {
                rig: 2,
                ..Default::default()
            },
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("models.json")
                && e.contains("rig position 2 is out of range")
                && e.contains("2 rig"),
            "{e}"
        );
        let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
        let e = s.load_image(0).unwrap_err().to_string();
        assert!(
            e.contains("cam_00/image_000.JPG") && e.contains("does not exist"),
            "{e}"
        );
        let e = s.near_far().unwrap_err().to_string();
        assert!(e.contains("near and far"), "{e}");
        let s = load_scene(
            dir.path(),
            &LoadOptions {
                near: Some(1.0),
                far: Some(100.0),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(s.near_far().unwrap(), (1.0, 100.0));
        // Half a pair of bounds on a scene without bounds is refused, not dropped.
        let e = load_scene(
            dir.path(),
            &LoadOptions {
                near: Some(1.0),
                ..Default::default()
            },
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains(&dir.path().display().to_string())
                && e.contains("a near depth needs a far depth"),
            "{e}"
        );
        // A wrongly sized image is refused with both file names.
        let img = deepview_image::ImageF32::new(80, 61, 3);
        crate::write_image(&dir.path().join("cam_00/image_000.JPG"), &img).unwrap();
        let e = s.load_image(0).unwrap_err().to_string();
        assert!(
            e.contains("image_000.JPG") && e.contains("models.json") && e.contains("(80, 60)"),
            "{e}"
        );
    }
}
