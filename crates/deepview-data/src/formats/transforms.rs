//! nerfstudio / instant-ngp `transforms.json`: camera-to-world `transform_matrix` per frame in OpenGL axes
//! (columns [right, up, back, centre], converted by `opengl_c2w_to_pose`), and pinhole intrinsics shared at
//! the top level or given per frame (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`; instant-ngp's `camera_angle_x`
//! / `camera_angle_y` instead of focal lengths).
//!
//! - `camera_model`: PINHOLE, SIMPLE_PINHOLE, or OPENCV (the default) whose distortion `k1..k4`, `p1`, `p2`
//!   must be zero: distorted cameras are refused with a message saying how to undistort them.
//! - `file_path` is relative to the JSON's folder, with or without an extension (png, jpg, jpeg tried).
//! - Downscaled copies (`images_2/`, `images_4/`, nerfstudio's `downscale_factor` folders): `--images
//!   images_4` replaces the first folder of every `file_path`; intrinsics are scaled to the size of the
//!   images actually found (an image whose size is not the JSON's `w x h` scaled is an error).
//! - Depth bounds: top-level `near` and `far` when present, else the `aabb` ([[min], [max]]) when all its
//!   corners lie in front of every camera, else none (`--near/--far` are then required).
//!
//! Principal points follow the same convention as COLMAP and this project (the centre of the top-left pixel
//! is at (0.5, 0.5)), so they are used as given.

use crate::{DataError, LoadOptions, Scene, SceneFormat, View};
use deepview_geometry::convention::{opengl_c2w_to_pose, pose_to_opengl_c2w};
use deepview_geometry::{Camera, DVec3, Intrinsics};
use deepview_image::ImageF32;
use serde::{Deserialize, Serialize};
use std::path::{Component, Path, PathBuf};

pub const TRANSFORMS_JSON: &str = "transforms.json";

/// Intrinsics as written at the top level of the file or in a frame (a frame's values win).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformsIntrinsics {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_model: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub w: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub h: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_angle_x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_angle_y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k3: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k4: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p2: Option<f64>,
}

impl TransformsIntrinsics {
    /// `self`'s values where set, else `base`'s.
    fn over(&self, base: &TransformsIntrinsics) -> TransformsIntrinsics {
        macro_rules! pick {
            ($($f:ident),*) => { TransformsIntrinsics { $($f: self.$f.clone().or(base.$f.clone()),)* } };
        }
        pick!(
            camera_model,
            fl_x,
            fl_y,
            cx,
            cy,
            w,
            h,
            camera_angle_x,
            camera_angle_y,
            k1,
            k2,
            k3,
            k4,
            p1,
            p2
        )
    }
}

/// One frame: its image and camera-to-world matrix (OpenGL axes), optionally its own intrinsics.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformsFrame {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file_path: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transform_matrix: Option<Vec<Vec<f64>>>,
    #[serde(flatten)]
    pub intrinsics: TransformsIntrinsics,
}

/// The parts of `transforms.json` this project reads and writes (other keys are ignored).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformsFile {
    #[serde(flatten)]
    pub intrinsics: TransformsIntrinsics,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<Vec<TransformsFrame>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aabb: Option<[[f64; 3]; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub near: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub far: Option<f64>,
}

/// One frame resolved: relative image path as written, camera in the JSON's `w x h`.
#[derive(Clone, Debug, PartialEq)]
pub struct TransformsCamera {
    pub file_path: String,
    /// `w x h` from the file, or `None` when the file gives no size (taken from the image then).
    pub size: Option<(u32, u32)>,
    pub intrinsics: FrameIntrinsics,
    pub pose: deepview_geometry::Pose,
}

/// Focal lengths may be given as angles, which need the image width; resolved once the size is known.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameIntrinsics {
    pub fl_x: Option<f64>,
    pub fl_y: Option<f64>,
    pub angle_x: Option<f64>,
    pub angle_y: Option<f64>,
    pub cx: Option<f64>,
    pub cy: Option<f64>,
}

impl FrameIntrinsics {
    /// Pinhole intrinsics for a `w x h` image: focal from `fl_x` or `0.5 w / tan(camera_angle_x / 2)`;
    /// `fl_y` from `fl_y`, `camera_angle_y`, else `fl_x`; principal point defaults to the centre.
    pub fn resolve(&self, w: u32, h: u32) -> Result<Intrinsics, String> {
        let (w, h) = (w as f64, h as f64);
        let from_angle = |a: f64, size: f64, name: &str| {
            if a > 0.0 && a < std::f64::consts::PI {
                Ok(0.5 * size / (a / 2.0).tan())
            } else {
                Err(format!("{name} = {a} is not an angle in (0, pi) radians"))
            }
        };
        let fx = match (self.fl_x, self.angle_x) {
            (Some(f), _) => f,
            (None, Some(a)) => from_angle(a, w, "camera_angle_x")?,
            (None, None) => {
                return Err(
                    "missing focal length: give \"fl_x\" (pixels) or \"camera_angle_x\" (radians)"
                        .into(),
                );
            }
        };
        let fy = match (self.fl_y, self.angle_y) {
            (Some(f), _) => f,
            (None, Some(a)) => from_angle(a, h, "camera_angle_y")?,
            (None, None) => fx,
        };
        let k = Intrinsics::new(
            fx,
            fy,
            self.cx.unwrap_or(w / 2.0),
            self.cy.unwrap_or(h / 2.0),
        );
        k.validate().map_err(|e| e.to_string())?;
        Ok(k)
    }
}

/// Parse `transforms.json` text into mirror structs (`path` only names the file in errors).
pub fn parse_transforms(text: &str, path: &Path) -> Result<TransformsFile, DataError> {
    serde_json::from_str(text).map_err(|source| DataError::Json {
        path: path.into(),
        source,
    })
}

fn finite_opt(v: Option<f64>, name: &str, ctx: &str) -> Result<Option<f64>, String> {
    match v {
        Some(x) if !x.is_finite() => Err(format!("{ctx}non-finite \"{name}\" {x}")),
        v => Ok(v),
    }
}

fn size_value(v: Option<f64>, name: &str, ctx: &str) -> Result<Option<u32>, String> {
    match finite_opt(v, name, ctx)? {
        None => Ok(None),
        Some(x) if x >= 1.0 && x.fract() == 0.0 && x <= u32::MAX as f64 => Ok(Some(x as u32)),
        Some(x) => Err(format!(
            "{ctx}\"{name}\" = {x} is not a positive whole number of pixels"
        )),
    }
}

/// Resolve every frame's camera (in the file's own `w x h`) and check the numbers.
pub fn transforms_cameras(
    file: &TransformsFile,
    path: &Path,
) -> Result<Vec<TransformsCamera>, DataError> {
    let frames = file.frames.as_ref().ok_or_else(|| {
        DataError::invalid(
            path,
            "missing \"frames\" (the list of images and their poses)",
        )
    })?;
    if frames.is_empty() {
        return Err(DataError::invalid(path, "\"frames\" is empty"));
    }
    let mut out = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let ctx = match &f.file_path {
            Some(p) => format!("frame {i} ({p}): "),
            None => format!("frame {i}: "),
        };
        let bad = |msg: String| DataError::invalid(path, msg);
        let file_path = f
            .file_path
            .clone()
            .ok_or_else(|| bad(format!("{ctx}missing \"file_path\"")))?;
        let m = f
            .transform_matrix
            .as_ref()
            .ok_or_else(|| bad(format!("{ctx}missing \"transform_matrix\"")))?;
        if !(m.len() == 4 || m.len() == 3) || m.iter().any(|r| r.len() != 4) {
            return Err(bad(format!(
                "{ctx}\"transform_matrix\" must be 4 rows of 4 numbers (or 3 rows of 4), got {} rows of {:?}",
                m.len(),
                m.iter().map(Vec::len).collect::<Vec<_>>()
            )));
        }
        let mut flat = [0.0; 16];
        for (r, row) in m.iter().enumerate() {
            flat[r * 4..r * 4 + 4].copy_from_slice(row);
        }
        if m.len() == 3 {
            flat[15] = 1.0;
        }
        if let Some(x) = flat.iter().find(|x| !x.is_finite()) {
            return Err(bad(format!(
                "{ctx}non-finite value {x} in \"transform_matrix\""
            )));
        }
        let last = [flat[12], flat[13], flat[14], flat[15]];
        if last
            .iter()
            .zip([0.0, 0.0, 0.0, 1.0])
            .any(|(a, b)| (a - b).abs() > 1e-9)
        {
            return Err(bad(format!(
                "{ctx}the last row of \"transform_matrix\" must be [0, 0, 0, 1], got {last:?}"
            )));
        }
        let pose = opengl_c2w_to_pose(&flat)
            .map_err(|e| DataError::geometry(path, format!("{ctx}transform_matrix"), e))?;
        let k = f.intrinsics.over(&file.intrinsics);
        let model = k.camera_model.as_deref().unwrap_or("OPENCV");
        if !matches!(model, "PINHOLE" | "SIMPLE_PINHOLE" | "OPENCV") {
            return Err(bad(format!(
                "{ctx}camera_model {model} is not supported (PINHOLE, SIMPLE_PINHOLE or OPENCV without \
                 distortion); undistort the images to a pinhole camera first, e.g. with `colmap \
                 image_undistorter`, or run `deepview process --data PHOTOS --out SCENE` on the photos"
            )));
        }
        let distortion = [
            ("k1", k.k1),
            ("k2", k.k2),
            ("k3", k.k3),
            ("k4", k.k4),
            ("p1", k.p1),
            ("p2", k.p2),
        ];
        for (name, v) in distortion {
            finite_opt(v, name, &ctx).map_err(bad)?;
        }
        let nonzero: Vec<String> = distortion
            .iter()
            .filter_map(|(n, v)| v.filter(|x| *x != 0.0).map(|x| format!("{n} = {x}")))
            .collect();
        if !nonzero.is_empty() {
            return Err(bad(format!(
                "{ctx}camera_model {model} has non-zero distortion ({}); only pinhole cameras are read. \
                 Undistort the images first (e.g. `colmap image_undistorter`, or `deepview process --data \
                 PHOTOS --out SCENE` on the original photos) and write PINHOLE intrinsics",
                nonzero.join(", ")
            )));
        }
        let w = size_value(k.w, "w", &ctx).map_err(bad)?;
        let h = size_value(k.h, "h", &ctx).map_err(bad)?;
        let size = match (w, h) {
            (Some(w), Some(h)) => Some((w, h)),
            (None, None) => None,
            _ => {
                return Err(bad(format!(
                    "{ctx}give both \"w\" and \"h\", or neither (then the image's size is used)"
                )));
            }
        };
        let intrinsics = FrameIntrinsics {
            fl_x: finite_opt(k.fl_x, "fl_x", &ctx).map_err(bad)?,
            fl_y: finite_opt(k.fl_y, "fl_y", &ctx).map_err(bad)?,
            angle_x: finite_opt(k.camera_angle_x, "camera_angle_x", &ctx).map_err(bad)?,
            angle_y: finite_opt(k.camera_angle_y, "camera_angle_y", &ctx).map_err(bad)?,
            cx: finite_opt(k.cx, "cx", &ctx).map_err(bad)?,
            cy: finite_opt(k.cy, "cy", &ctx).map_err(bad)?,
        };
        if intrinsics.fl_x.is_none() && intrinsics.angle_x.is_none() {
            return Err(bad(format!(
                "{ctx}missing focal length: give \"fl_x\" (pixels) or \"camera_angle_x\" (radians)"
            )));
        }
        // With a size known, resolve now so bad numbers are reported even when images are absent.
        if let Some((w, h)) = size {
            intrinsics
                .resolve(w, h)
                .map_err(|e| bad(format!("{ctx}{e}")))?;
        }
        out.push(TransformsCamera {
            file_path,
            size,
            intrinsics,
            pose,
        });
    }
    Ok(out)
}

/// `file_path` relative to `base`, with `--images FOLDER` replacing its first folder, and an image
/// extension tried when it has none (or the file is missing).
fn image_path(base: &Path, file_path: &str, images: Option<&str>) -> Option<PathBuf> {
    let rel = Path::new(file_path);
    let rel: PathBuf = match images {
        None => rel
            .components()
            .filter(|c| *c != Component::CurDir)
            .collect(),
        Some(folder) => {
            let parts: Vec<Component> = rel
                .components()
                .filter(|c| *c != Component::CurDir)
                .collect();
            let mut p = PathBuf::from(folder);
            let skip = usize::from(parts.len() > 1);
            p.extend(parts.iter().skip(skip));
            p
        }
    };
    let full = base.join(&rel);
    if full.is_file() {
        return Some(full);
    }
    ["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"]
        .iter()
        .map(|ext| {
            let mut s = full.clone().into_os_string();
            s.push(".");
            s.push(ext);
            PathBuf::from(s)
        })
        .find(|p| p.is_file())
}

/// Depth bounds from `near`/`far`, else from the `aabb` corners if they are in front of every camera.
pub fn transforms_depth_bounds(file: &TransformsFile, cameras: &[Camera]) -> Option<(f64, f64)> {
    if let (Some(n), Some(f)) = (file.near, file.far) {
        return Some((n, f));
    }
    let [lo, hi] = file.aabb?;
    let mut near = f64::INFINITY;
    let mut far: f64 = 0.0;
    for c in cameras {
        for k in 0..8 {
            let x = DVec3::new(
                if k & 1 == 0 { lo[0] } else { hi[0] },
                if k & 2 == 0 { lo[1] } else { hi[1] },
                if k & 4 == 0 { lo[2] } else { hi[2] },
            );
            let z = c.pose.transform_point(x).z;
            if !(z > 0.0 && z.is_finite()) {
                return None;
            }
            near = near.min(z);
            far = far.max(z);
        }
    }
    (near < far).then_some((near, far))
}

/// The JSON file of a scene path: the path itself when it is a `.json` file, else `transforms.json` in it.
pub fn transforms_path(root: &Path) -> PathBuf {
    if root.is_file() {
        root.into()
    } else {
        root.join(TRANSFORMS_JSON)
    }
}

pub(crate) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let json = transforms_path(root);
    let base = json.parent().unwrap_or(Path::new(".")).to_path_buf();
    let file = parse_transforms(&crate::read_text(&json)?, &json)?;
    let cams = transforms_cameras(&file, &json)?;
    if let Some(folder) = &opts.images
        && !base.join(folder).is_dir()
    {
        return Err(DataError::NoImageFolder {
            path: base.join(folder),
        });
    }
    let mut views = Vec::with_capacity(cams.len());
    for (i, c) in cams.iter().enumerate() {
        let path = image_path(&base, &c.file_path, opts.images.as_deref()).ok_or_else(|| {
            let tried = image_path_display(&base, &c.file_path, opts.images.as_deref());
            DataError::MissingImage {
                path: tried,
                view: format!("frame {i} of {}", json.display()),
            }
        })?;
        let got = crate::image_size(&path)?;
        let (w, h) = c.size.unwrap_or(got);
        let k = c
            .intrinsics
            .resolve(w, h)
            .map_err(|e| DataError::invalid(&json, format!("frame {i} ({}): {e}", c.file_path)))?;
        // A downscaled copy: scale the intrinsics to the image found; LLFF-style rounding of 1 px allowed.
        let k = if got == (w, h) {
            k
        } else {
            let (sx, sy) = (got.0 as f64 / w as f64, got.1 as f64 / h as f64);
            if (got.1 as f64 - h as f64 * sx).abs() > 1.0 {
                return Err(DataError::ImageSize {
                    path: path.clone(),
                    calibration: json.clone(),
                    expected: (w, h),
                    got,
                });
            }
            k.scaled(sx, sy)
        };
        let name = Path::new(&c.file_path)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("frame{i:03}"));
        views.push(View {
            name,
            image_path: path,
            camera: Camera::new(got.0, got.1, k, c.pose),
        });
    }
    let cameras: Vec<Camera> = views.iter().map(|v| v.camera).collect();
    Ok(Scene {
        root: root.into(),
        format: SceneFormat::Transforms,
        views,
        depth_bounds: transforms_depth_bounds(&file, &cameras),
        grid: None,
        rig_count: 1,
        downscale: 1,
    })
}

fn image_path_display(base: &Path, file_path: &str, images: Option<&str>) -> PathBuf {
    let rel = Path::new(file_path);
    match images {
        None => base.join(rel),
        Some(folder) => {
            let parts: Vec<Component> = rel
                .components()
                .filter(|c| *c != Component::CurDir)
                .collect();
            let mut p = base.join(folder);
            p.extend(parts.iter().skip(usize::from(parts.len() > 1)));
            p
        }
    }
}

/// The `transforms.json` of `cameras` (PINHOLE; intrinsics shared when all cameras agree, else per frame),
/// with `file_paths` as the frames' images and optional `near`/`far`.
pub fn transforms_file(
    file_paths: &[String],
    cameras: &[Camera],
    near_far: Option<(f64, f64)>,
) -> TransformsFile {
    let intr = |c: &Camera| TransformsIntrinsics {
        fl_x: Some(c.intrinsics.fx),
        fl_y: Some(c.intrinsics.fy),
        cx: Some(c.intrinsics.cx),
        cy: Some(c.intrinsics.cy),
        w: Some(c.width as f64),
        h: Some(c.height as f64),
        ..Default::default()
    };
    let shared = cameras
        .first()
        .filter(|c0| {
            cameras.iter().all(|c| {
                c.intrinsics == c0.intrinsics && (c.width, c.height) == (c0.width, c0.height)
            })
        })
        .map(intr);
    let frames = file_paths
        .iter()
        .zip(cameras)
        .map(|(p, c)| {
            let m = pose_to_opengl_c2w(&c.pose);
            TransformsFrame {
                file_path: Some(p.clone()),
                transform_matrix: Some(m.chunks_exact(4).map(<[f64]>::to_vec).collect()),
                intrinsics: if shared.is_some() {
                    TransformsIntrinsics::default()
                } else {
                    intr(c)
                },
            }
        })
        .collect();
    TransformsFile {
        intrinsics: TransformsIntrinsics {
            camera_model: Some("PINHOLE".into()),
            ..shared.unwrap_or_default()
        },
        frames: Some(frames),
        aabb: None,
        near: near_far.map(|b| b.0),
        far: near_far.map(|b| b.1),
    }
}

/// Write a nerfstudio scene: `dir/transforms.json` and the images as `dir/images/imageNNN.png`.
pub fn write_transforms(
    dir: &Path,
    cameras: &[Camera],
    images: &[ImageF32],
    near_far: Option<(f64, f64)>,
) -> Result<(), DataError> {
    let json = dir.join(TRANSFORMS_JSON);
    if cameras.len() != images.len() {
        return Err(DataError::CountMismatch {
            path: json,
            msg: format!(
                "{} cameras but {} images (must agree)",
                cameras.len(),
                images.len()
            ),
        });
    }
    let paths: Vec<String> = (0..cameras.len())
        .map(|i| format!("images/image{i:03}.png"))
        .collect();
    for (i, (p, (img, cam))) in paths.iter().zip(images.iter().zip(cameras)).enumerate() {
        if (img.width, img.height) != (cam.width, cam.height) {
            return Err(DataError::invalid(
                &json,
                format!(
                    "image {i} is {}x{} but its camera is {}x{}",
                    img.width, img.height, cam.width, cam.height
                ),
            ));
        }
        crate::write_image(&dir.join(p), img)?;
    }
    let text = serde_json::to_string_pretty(&transforms_file(&paths, cameras, near_far))
        .expect("transforms.json serialises");
    crate::write_bytes(&json, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load_scene;
    use deepview_geometry::{DMat3, Pose};

    fn p() -> PathBuf {
        PathBuf::from("scene").join(TRANSFORMS_JSON)
    }

    const SHARED: &str = r#"{
        "camera_model": "OPENCV", "fl_x": 100, "fl_y": 101.5, "cx": 31.5, "cy": 24.25, "w": 64, "h": 48,
        "k1": 0, "k2": 0.0, "p1": 0, "p2": 0, "applied_transform": [[1,0,0,0],[0,1,0,0],[0,0,1,0]],
        "frames": [
            {"file_path": "images/a.png", "transform_matrix": [[1,0,0,1],[0,1,0,2],[0,0,1,3],[0,0,0,1]]},
            {"file_path": "images/b", "fl_x": 90, "w": 32, "h": 24, "cx": 16, "cy": 12,
             "transform_matrix": [[0,0,1,0],[0,1,0,0],[-1,0,0,0],[0,0,0,1]]}
        ]
    }"#;

    #[test]
    fn shared_and_per_frame_intrinsics_and_opengl_poses() {
        let f = parse_transforms(SHARED, &p()).unwrap();
        let c = transforms_cameras(&f, &p()).unwrap();
        assert_eq!(c.len(), 2);
        assert_eq!(c[0].size, Some((64, 48)));
        assert_eq!(
            c[0].intrinsics.resolve(64, 48).unwrap(),
            Intrinsics::new(100.0, 101.5, 31.5, 24.25)
        );
        // Frame 1 overrides fl_x, the size and the principal point; fl_y is the shared one.
        assert_eq!(c[1].size, Some((32, 24)));
        assert_eq!(
            c[1].intrinsics.resolve(32, 24).unwrap(),
            Intrinsics::new(90.0, 101.5, 16.0, 12.0)
        );
        // Identity OpenGL rotation: OpenCV y and z flip; the centre is the last column.
        let want = DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0));
        assert!(c[0].pose.rotation.abs_diff_eq(want, 1e-15));
        assert!(
            c[0].pose
                .center()
                .abs_diff_eq(DVec3::new(1.0, 2.0, 3.0), 1e-15)
        );
        // Frame 1 looks along world -x (its OpenGL back axis is world +x)... its OpenCV forward is -x.
        let fwd = c[1].pose.rotation.transpose() * DVec3::Z;
        assert!(fwd.abs_diff_eq(DVec3::new(-1.0, 0.0, 0.0), 1e-15), "{fwd}");
    }

    #[test]
    fn camera_angle_x_form() {
        let text = r#"{"camera_angle_x": 0.6911112070083618, "frames": [
            {"file_path": "./train/r_0", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}]}"#;
        let f = parse_transforms(text, &p()).unwrap();
        let c = transforms_cameras(&f, &p()).unwrap();
        assert_eq!(c[0].size, None);
        let k = c[0].intrinsics.resolve(800, 800).unwrap();
        let want = 0.5 * 800.0 / (0.6911112070083618f64 / 2.0).tan();
        assert!(
            (k.fx - want).abs() < 1e-9 && (k.fy - want).abs() < 1e-9,
            "{k:?}"
        );
        assert!((want - 1111.1110311937682).abs() < 1e-6);
        assert_eq!((k.cx, k.cy), (400.0, 400.0));
    }

    fn err(text: &str) -> String {
        match parse_transforms(text, &p()) {
            Err(e) => e.to_string(),
            Ok(f) => transforms_cameras(&f, &p()).unwrap_err().to_string(),
        }
    }

    #[test]
    fn errors_name_the_file_and_the_problem() {
        let frame = r#""file_path": "a.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"#;
        let cases = [
            ("{\"frames\": [".to_string(), "malformed JSON"),
            ("{\"fl_x\": 10}".to_string(), "missing \"frames\""),
            ("{\"fl_x\": 10, \"frames\": []}".to_string(), "empty"),
            (
                r#"{"fl_x": 10, "frames": [{"file_path": "a.png"}]}"#.to_string(),
                "frame 0 (a.png): missing \"transform_matrix\"",
            ),
            (
                r#"{"fl_x": 10, "frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0]]}]}"#
                    .to_string(),
                "missing \"file_path\"",
            ),
            (format!("{{\"frames\": [{{{frame}}}]}}"), "fl_x"),
            (
                format!("{{\"fl_x\": 1e999, \"frames\": [{{{frame}}}]}}"),
                "malformed JSON",
            ),
            (
                r#"{"fl_x": 10, "frames": [{"file_path": "a", "transform_matrix": [[1,0,0],[0,1,0],[0,0,1]]}]}"#
                    .to_string(),
                "4 rows of 4",
            ),
            (
                r#"{"fl_x": 10, "frames": [{"file_path": "a", "transform_matrix": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}"#
                    .to_string(),
                "orthonormal",
            ),
            (
                format!("{{\"fl_x\": 10, \"k1\": -0.1, \"p2\": 0.01, \"frames\": [{{{frame}}}]}}"),
                "non-zero distortion (k1 = -0.1, p2 = 0.01)",
            ),
            (
                format!(
                    "{{\"fl_x\": 10, \"camera_model\": \"OPENCV_FISHEYE\", \"frames\": [{{{frame}}}]}}"
                ),
                "OPENCV_FISHEYE is not supported",
            ),
            (
                format!("{{\"fl_x\": 10, \"w\": 10.5, \"h\": 4, \"frames\": [{{{frame}}}]}}"),
                "\"w\" = 10.5",
            ),
            (
                format!("{{\"fl_x\": -10, \"w\": 10, \"h\": 4, \"frames\": [{{{frame}}}]}}"),
                "focal lengths must be positive",
            ),
            (
                format!("{{\"camera_angle_x\": 4, \"w\": 10, \"h\": 4, \"frames\": [{{{frame}}}]}}"),
                "camera_angle_x = 4",
            ),
        ];
        for (text, needle) in cases {
            let e = err(&text);
            assert!(e.contains(needle), "{needle:?} not in {e:?}");
            assert!(e.contains("transforms.json"), "{e}");
        }
    }

    fn cams() -> Vec<Camera> {
        (0..3)
            .map(|i| {
                let r = DMat3::from_rotation_y(0.1 * i as f64) * DMat3::from_rotation_x(0.05);
                Camera::new(
                    16,
                    12,
                    Intrinsics::new(20.0, 21.0, 8.5, 6.25),
                    Pose::from_center(r, DVec3::new(0.2 * i as f64, 0.1, -1.0)),
                )
            })
            .collect()
    }

    fn images(n: usize, w: u32, h: u32) -> Vec<ImageF32> {
        (0..n)
            .map(|i| {
                ImageF32::from_data(w, h, 3, vec![i as f32 / 4.0; (w * h * 3) as usize]).unwrap()
            })
            .collect()
    }

    #[test]
    fn write_then_load_round_trip_and_downscaled_folder() {
        let dir = tempfile::tempdir().unwrap();
        let c = cams();
        write_transforms(dir.path(), &c, &images(3, 16, 12), Some((0.5, 8.0))).unwrap();
        let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
        assert_eq!(s.format, SceneFormat::Transforms);
        assert_eq!(s.depth_bounds, Some((0.5, 8.0)));
        assert_eq!(s.calibration_path(), dir.path().join(TRANSFORMS_JSON));
        for (v, c) in s.views.iter().zip(&c) {
            assert_eq!(v.camera.intrinsics, c.intrinsics);
            assert!(v.camera.pose.rotation.abs_diff_eq(c.pose.rotation, 1e-12));
            assert!(v.camera.center().abs_diff_eq(c.center(), 1e-12));
        }
        assert!((s.load_image(2).unwrap().data[0] - 0.5).abs() < 1.0 / 255.0);
        // The JSON file itself can be given.
        let s2 = load_scene(&dir.path().join(TRANSFORMS_JSON), &LoadOptions::default()).unwrap();
        assert_eq!(s2.views[1].camera, s.views[1].camera);
        // A half-size copy in images_2/: intrinsics scale with the images.
        for (i, img) in images(3, 8, 6).iter().enumerate() {
            crate::write_image(&dir.path().join(format!("images_2/image{i:03}.png")), img).unwrap();
        }
        let opts = LoadOptions {
            images: Some("images_2".into()),
            ..Default::default()
        };
        let s = load_scene(dir.path(), &opts).unwrap();
        assert_eq!((s.views[0].camera.width, s.views[0].camera.height), (8, 6));
        assert_eq!(
            s.views[0].camera.intrinsics,
            Intrinsics::new(10.0, 10.5, 4.25, 3.125)
        );
        s.check_images().unwrap();
        // A wrongly sized image, a missing one, a missing folder.
        crate::write_image(
            &dir.path().join("images_2/image001.png"),
            &images(1, 8, 3)[0],
        )
        .unwrap();
        let e = load_scene(dir.path(), &opts).unwrap_err().to_string();
        assert!(
            e.contains("image001.png") && e.contains("transforms.json"),
            "{e}"
        );
        std::fs::remove_file(dir.path().join("images_2/image001.png")).unwrap();
        let e = load_scene(dir.path(), &opts).unwrap_err().to_string();
        assert!(
            e.contains("image001.png") && e.contains("does not exist") && e.contains("frame 1"),
            "{e}"
        );
        let opts = LoadOptions {
            images: Some("images_9".into()),
            ..Default::default()
        };
        let e = load_scene(dir.path(), &opts).unwrap_err().to_string();
        assert!(
            e.contains("images_9") && e.contains("does not exist"),
            "{e}"
        );
    }

    #[test]
    fn bounds_from_aabb_or_required() {
        let dir = tempfile::tempdir().unwrap();
        let c = cams();
        write_transforms(dir.path(), &c, &images(3, 16, 12), None).unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap()
            .near_far()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("near and far") && e.contains("transforms.json"),
            "{e}"
        );
        // An aabb in front of the cameras (they look along +z of the world, roughly).
        let json = dir.path().join(TRANSFORMS_JSON);
        let mut f = parse_transforms(&std::fs::read_to_string(&json).unwrap(), &json).unwrap();
        f.aabb = Some([[-0.5, -0.5, 1.0], [0.5, 0.5, 3.0]]);
        std::fs::write(&json, serde_json::to_string(&f).unwrap()).unwrap();
        let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
        let (n, fa) = s.near_far().unwrap();
        assert!(n > 1.0 && n < 2.2 && fa > 3.5 && fa < 4.5, "{n} {fa}");
        // An aabb around the cameras gives no bounds.
        f.aabb = Some([[-5.0; 3], [5.0; 3]]);
        std::fs::write(&json, serde_json::to_string(&f).unwrap()).unwrap();
        let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
        assert_eq!(s.depth_bounds, None);
    }
}
