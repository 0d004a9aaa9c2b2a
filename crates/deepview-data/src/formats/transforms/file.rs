//! The `transforms.json` file: serde mirrors of what this project reads and writes, and the frames'
//! cameras resolved and checked.

use crate::DataError;
use deepview_geometry::Intrinsics;
use deepview_geometry::convention::opengl_c2w_to_pose;
use serde::{Deserialize, Serialize};
use std::path::Path;

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
