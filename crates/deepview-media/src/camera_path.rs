//! nerfstudio's `camera_path.json`.
//!
//! ```json
//! {"camera_type": "perspective", "render_width": W, "render_height": H, "seconds": S, "fps": F,
//!  "camera_path": [{"camera_to_world": [16 numbers, row-major], "fov": 50.0, "aspect": 1.33}, ...]}
//! ```
//! `camera_to_world` uses OpenGL axes (columns right, up, back, centre), converted with
//! [`deepview_geometry::convention`]; `fov` is the vertical field of view in degrees, so
//! `fy = H / (2 tan(fov / 2))`; nerfstudio uses square pixels (`fx = fy`) and a centred principal point
//! `(W/2, H/2)`. Writing keeps `fy` (a camera with `fx != fy` or an off-centre principal point cannot be
//! represented exactly). Other nerfstudio keys (`keyframes`, `smoothness_value`, ...) are ignored.

use crate::{MediaError, invalid, read_err};
use deepview_geometry::convention::{opengl_c2w_to_pose, pose_to_opengl_c2w};
use deepview_geometry::{Camera, Intrinsics};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CameraPathEntry {
    pub camera_to_world: Vec<f64>,
    pub fov: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aspect: Option<f64>,
}

/// Serde mirror of the file.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CameraPathFile {
    #[serde(default = "perspective")]
    pub camera_type: String,
    pub render_width: u32,
    pub render_height: u32,
    pub seconds: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fps: Option<f64>,
    pub camera_path: Vec<CameraPathEntry>,
}

fn perspective() -> String {
    "perspective".into()
}

/// A parsed path: the cameras and the video duration.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    pub cameras: Vec<Camera>,
    pub seconds: f64,
}

impl CameraPath {
    /// Frames per second implied by `seconds` (frames / seconds).
    pub fn fps(&self) -> f64 {
        self.cameras.len() as f64 / self.seconds
    }
}

/// Read and validate a `camera_path.json`.
pub fn read_camera_path(path: &Path) -> Result<CameraPath, MediaError> {
    // (A byte order mark, which Windows editors write, is not JSON's: read_text drops it.)
    let text = deepview_image::read_text(path).map_err(read_err(path))?;
    parse_camera_path(&text, path)
}

/// Parse the text of a `camera_path.json` (`path` only names it in errors).
pub fn parse_camera_path(text: &str, path: &Path) -> Result<CameraPath, MediaError> {
    let file: CameraPathFile = serde_json::from_str(text).map_err(|source| MediaError::Json {
        path: path.into(),
        what: "a nerfstudio camera_path.json",
        source,
    })?;
    if file.camera_type != "perspective" {
        return Err(invalid(
            path,
            format!(
                "camera_type {:?} is not supported (only \"perspective\")",
                file.camera_type
            ),
        ));
    }
    let (w, h) = (file.render_width, file.render_height);
    if w == 0 || h == 0 {
        return Err(invalid(
            path,
            format!("render size {w}x{h} must be positive"),
        ));
    }
    if !(file.seconds.is_finite() && file.seconds > 0.0) {
        return Err(invalid(
            path,
            format!("\"seconds\" must be positive (got {})", file.seconds),
        ));
    }
    if file.camera_path.is_empty() {
        return Err(invalid(path, "\"camera_path\" is empty"));
    }
    let mut cameras = Vec::with_capacity(file.camera_path.len());
    for (i, e) in file.camera_path.iter().enumerate() {
        let m: [f64; 16] = e.camera_to_world.as_slice().try_into().map_err(|_| {
            invalid(
                path,
                format!(
                    "camera_path[{i}].camera_to_world has {} numbers, expected 16",
                    e.camera_to_world.len()
                ),
            )
        })?;
        if m[12..] != [0.0, 0.0, 0.0, 1.0] {
            return Err(invalid(
                path,
                format!("camera_path[{i}].camera_to_world: last row must be 0 0 0 1"),
            ));
        }
        let pose = opengl_c2w_to_pose(&m)
            .map_err(|err| invalid(path, format!("camera_path[{i}].camera_to_world: {err}")))?;
        if !(e.fov.is_finite() && e.fov > 0.0 && e.fov < 180.0) {
            return Err(invalid(
                path,
                format!(
                    "camera_path[{i}].fov must be in (0, 180) degrees (got {})",
                    e.fov
                ),
            ));
        }
        let f = h as f64 / (2.0 * (e.fov.to_radians() / 2.0).tan());
        // A fov of a few subnormal degrees passes the range check but its focal length is infinite.
        let k = Intrinsics::centred(f, w, h);
        let camera = Camera::new(w, h, k, pose);
        camera.validate().map_err(|err| {
            invalid(
                path,
                format!("camera_path[{i}].fov {:e} degrees ({w}x{h}): {err}", e.fov),
            )
        })?;
        cameras.push(camera);
    }
    Ok(CameraPath {
        cameras,
        seconds: file.seconds,
    })
}

/// The file contents for `cameras` (all must share one image size) lasting `seconds`.
pub fn camera_path_file(cameras: &[Camera], seconds: f64) -> Result<CameraPathFile, MediaError> {
    let first = cameras
        .first()
        .ok_or_else(|| MediaError::Config("cannot write an empty camera path".into()))?;
    if !(seconds.is_finite() && seconds > 0.0) {
        return Err(MediaError::Config(format!(
            "camera path duration must be positive (got {seconds})"
        )));
    }
    let (w, h) = (first.width, first.height);
    let mut entries = Vec::with_capacity(cameras.len());
    for c in cameras {
        if (c.width, c.height) != (w, h) {
            return Err(MediaError::Config(format!(
                "camera_path.json has one render size; cameras are {w}x{h} and {}x{}",
                c.width, c.height
            )));
        }
        let fov = (2.0 * (h as f64 / (2.0 * c.intrinsics.fy)).atan()).to_degrees();
        entries.push(CameraPathEntry {
            camera_to_world: pose_to_opengl_c2w(&c.pose).to_vec(),
            fov,
            aspect: Some(w as f64 / h as f64),
        });
    }
    Ok(CameraPathFile {
        camera_type: perspective(),
        render_width: w,
        render_height: h,
        seconds,
        fps: Some(cameras.len() as f64 / seconds),
        camera_path: entries,
    })
}

/// Write `cameras` as a nerfstudio `camera_path.json` (atomically).
pub fn write_camera_path(path: &Path, cameras: &[Camera], seconds: f64) -> Result<(), MediaError> {
    let file = camera_path_file(cameras, seconds)?;
    let json = serde_json::to_string_pretty(&file).expect("camera path serialises");
    deepview_image::write_atomic(path, json.as_bytes())?;
    Ok(())
}
