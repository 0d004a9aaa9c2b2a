//! Pinhole intrinsics, rigid camera-from-world poses and cameras (OpenCV axes, pixel centres at +0.5).

use glam::{DMat3, DMat4, DVec2, DVec3, DVec4};
use serde::{Deserialize, Serialize};

/// Errors of geometric input: non-finite or non-rigid poses, degenerate intrinsics.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GeometryError {
    #[error("non-finite value in {0}")]
    NonFinite(&'static str),
    #[error("rotation is not orthonormal with determinant +1 (max deviation {0:.3e})")]
    NotRigid(f64),
    #[error("the last row of a camera_from_world matrix must be [0, 0, 0, 1], got {0:?}")]
    BadLastRow([f64; 4]),
    #[error("invalid intrinsics: {0}")]
    BadIntrinsics(String),
    #[error("invalid image size {0}x{1}")]
    BadSize(u32, u32),
    #[error(
        "views {first} and {second} look {degrees:.0} degrees apart: an MPI is made from views \
         that face the same way, within 90 degrees of each other (forward-facing captures)"
    )]
    /// Two cameras (their places in the list given, or their view numbers where the caller knows
    /// them) facing 90 degrees or more apart.
    FacingApart {
        first: usize,
        second: usize,
        degrees: f64,
    },
    #[error("{0}")]
    Invalid(String),
}

/// Pinhole intrinsics in pixels: `K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`.
///
/// `(cx, cy)` is in continuous pixel coordinates where pixel `i` spans `[i, i+1)`, so a centred principal
/// point of a `W x H` image is `(W/2, H/2)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self { fx, fy, cx, cy }
    }

    /// Centred principal point, square pixels.
    pub fn centred(focal: f64, width: u32, height: u32) -> Self {
        Self::new(focal, focal, width as f64 / 2.0, height as f64 / 2.0)
    }

    pub fn matrix(&self) -> DMat3 {
        DMat3::from_cols(
            DVec3::new(self.fx, 0.0, 0.0),
            DVec3::new(0.0, self.fy, 0.0),
            DVec3::new(self.cx, self.cy, 1.0),
        )
    }

    pub fn inverse_matrix(&self) -> DMat3 {
        DMat3::from_cols(
            DVec3::new(1.0 / self.fx, 0.0, 0.0),
            DVec3::new(0.0, 1.0 / self.fy, 0.0),
            DVec3::new(-self.cx / self.fx, -self.cy / self.fy, 1.0),
        )
    }

    /// The intrinsics of the same camera after resizing its image by `(sx, sy)`.
    pub fn scaled(&self, sx: f64, sy: f64) -> Self {
        Self::new(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy)
    }

    /// The intrinsics of a crop whose top-left corner is pixel `(x0, y0)`.
    pub fn cropped(&self, x0: f64, y0: f64) -> Self {
        Self::new(self.fx, self.fy, self.cx - x0, self.cy - y0)
    }

    pub fn validate(&self) -> Result<(), GeometryError> {
        if ![self.fx, self.fy, self.cx, self.cy]
            .iter()
            .all(|v| v.is_finite())
        {
            return Err(GeometryError::NonFinite("intrinsics"));
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(GeometryError::BadIntrinsics(format!(
                "focal lengths must be positive (fx {}, fy {})",
                self.fx, self.fy
            )));
        }
        Ok(())
    }
}

/// `v` for a message: plain, or in scientific notation when very large or small.
fn short(v: f64) -> String {
    if v != 0.0 && !(1e-3..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// The largest camera translation (scene units) [`Pose::validate`] accepts.
pub const MAX_TRANSLATION: f64 = 1e12;

/// A rigid camera-from-world transform: `x_cam = rotation * x_world + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub rotation: DMat3,
    pub translation: DVec3,
}

impl Default for Pose {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        rotation: DMat3::IDENTITY,
        translation: DVec3::ZERO,
    };

    pub fn new(rotation: DMat3, translation: DVec3) -> Self {
        Self {
            rotation,
            translation,
        }
    }

    /// The pose of a camera at world position `center` with camera-from-world rotation `rotation`.
    pub fn from_center(rotation: DMat3, center: DVec3) -> Self {
        Self {
            rotation,
            translation: -(rotation * center),
        }
    }

    /// Camera centre in world coordinates, `-R^T t`.
    pub fn center(&self) -> DVec3 {
        -(self.rotation.transpose() * self.translation)
    }

    pub fn transform_point(&self, x: DVec3) -> DVec3 {
        self.rotation * x + self.translation
    }

    /// The inverse transform (world-from-camera as a `Pose`).
    pub fn inverse(&self) -> Pose {
        let rt = self.rotation.transpose();
        Pose {
            rotation: rt,
            translation: -(rt * self.translation),
        }
    }

    /// `self * other`: first `other`, then `self`.
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose {
            rotation: self.rotation * other.rotation,
            translation: self.rotation * other.translation + self.translation,
        }
    }

    pub fn matrix(&self) -> DMat4 {
        let r = self.rotation;
        DMat4::from_cols(
            r.x_axis.extend(0.0),
            r.y_axis.extend(0.0),
            r.z_axis.extend(0.0),
            DVec4::new(
                self.translation.x,
                self.translation.y,
                self.translation.z,
                1.0,
            ),
        )
    }

    /// 16 numbers, row-major, as in `mpi.json` and camera JSON files.
    pub fn to_row_major(&self) -> [f64; 16] {
        self.matrix().transpose().to_cols_array()
    }

    /// Parse 16 row-major numbers; checks finiteness, the last row and that the rotation is rigid.
    pub fn from_row_major(m: &[f64]) -> Result<Pose, GeometryError> {
        if m.len() != 16 {
            return Err(GeometryError::Invalid(format!(
                "camera_from_world needs 16 numbers, got {}",
                m.len()
            )));
        }
        if !m.iter().all(|v| v.is_finite()) {
            return Err(GeometryError::NonFinite("camera_from_world"));
        }
        let last = [m[12], m[13], m[14], m[15]];
        if last != [0.0, 0.0, 0.0, 1.0] {
            return Err(GeometryError::BadLastRow(last));
        }
        let rotation = DMat3::from_cols(
            DVec3::new(m[0], m[4], m[8]),
            DVec3::new(m[1], m[5], m[9]),
            DVec3::new(m[2], m[6], m[10]),
        );
        let pose = Pose {
            rotation,
            translation: DVec3::new(m[3], m[7], m[11]),
        };
        pose.validate()?;
        Ok(pose)
    }

    /// Rotation must be orthonormal (to 1e-4, enough for poses read from text files) with det +1.
    pub fn validate(&self) -> Result<(), GeometryError> {
        let r = self.rotation;
        if !r.is_finite() || !self.translation.is_finite() {
            return Err(GeometryError::NonFinite("pose"));
        }
        // Beyond 1e12 scene units the pose's arithmetic (a plane sweep's depths, homographies) loses every
        // significant digit of a capture's scale: not a position of a real camera.
        if self.translation.abs().max_element() > MAX_TRANSLATION {
            return Err(GeometryError::Invalid(format!(
                "camera translation {:?} is beyond {MAX_TRANSLATION:e} scene units",
                self.translation.to_array()
            )));
        }
        let e = (r.transpose() * r - DMat3::IDENTITY).to_cols_array();
        let dev = e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if dev > 1e-4 || r.determinant() < 0.0 {
            return Err(GeometryError::NotRigid(
                dev.max((r.determinant() - 1.0).abs()),
            ));
        }
        Ok(())
    }

    /// Re-orthonormalise the rotation (polar decomposition by Newton iterations).
    pub fn orthonormalized(&self) -> Pose {
        Pose {
            rotation: orthonormalize(self.rotation),
            translation: self.translation,
        }
    }
}

/// Nearest rotation to `m` (polar decomposition, Newton iteration `X <- (X + X^-T) / 2`).
pub fn orthonormalize(m: DMat3) -> DMat3 {
    let mut x = m;
    for _ in 0..30 {
        let next = (x + x.inverse().transpose()) * 0.5;
        let diff = (next - x)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        x = next;
        if diff < 1e-15 {
            break;
        }
    }
    x
}

/// A pinhole camera: image size, intrinsics and camera-from-world pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub intrinsics: Intrinsics,
    pub pose: Pose,
}

impl Camera {
    pub fn new(width: u32, height: u32, intrinsics: Intrinsics, pose: Pose) -> Self {
        Self {
            width,
            height,
            intrinsics,
            pose,
        }
    }

    pub fn center(&self) -> DVec3 {
        self.pose.center()
    }

    /// Project a world point to continuous pixel coordinates; `None` behind the camera.
    pub fn project(&self, world: DVec3) -> Option<DVec2> {
        let c = self.pose.transform_point(world);
        if c.z <= 0.0 {
            return None;
        }
        let k = &self.intrinsics;
        Some(DVec2::new(k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy))
    }

    /// The world point at camera depth `z` (along the optical axis) seen at continuous pixel `p`.
    pub fn unproject(&self, p: DVec2, z: f64) -> DVec3 {
        let k = &self.intrinsics;
        let c = DVec3::new((p.x - k.cx) / k.fx * z, (p.y - k.cy) / k.fy * z, z);
        self.pose.inverse().transform_point(c)
    }

    /// Same camera, image resized by `scale` (size rounded to whole pixels, intrinsics scaled per axis).
    pub fn resized(&self, width: u32, height: u32) -> Camera {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Camera {
            width,
            height,
            intrinsics: self.intrinsics.scaled(sx, sy),
            pose: self.pose,
        }
    }

    /// Same camera restricted to the pixel window `[x0, x0+w) x [y0, y0+h)`.
    pub fn cropped(&self, x0: i64, y0: i64, width: u32, height: u32) -> Camera {
        Camera {
            width,
            height,
            intrinsics: self.intrinsics.cropped(x0 as f64, y0 as f64),
            pose: self.pose,
        }
    }

    pub fn validate(&self) -> Result<(), GeometryError> {
        if self.width == 0 || self.height == 0 {
            return Err(GeometryError::BadSize(self.width, self.height));
        }
        self.intrinsics.validate()?;
        // Values no camera has, which render nothing but an empty image: a focal length outside 1/1000 to
        // 100,000 times the image size (fields of view from about 180 degrees down to 0.0006), a principal
        // point more than ten image sizes off the image.
        let k = &self.intrinsics;
        let (w, h) = (self.width as f64, self.height as f64);
        let size = w.max(h);
        for (name, f) in [("fx", k.fx), ("fy", k.fy)] {
            if !(1e-3 * size..=1e5 * size).contains(&f) {
                return Err(GeometryError::BadIntrinsics(format!(
                    "{name} {} is not a focal length of a {}x{} image (1/1000 to 100,000 times its size)",
                    short(f),
                    self.width,
                    self.height
                )));
            }
        }
        for (name, c, n) in [("cx", k.cx, w), ("cy", k.cy, h)] {
            if !(-10.0 * n..=11.0 * n).contains(&c) {
                return Err(GeometryError::BadIntrinsics(format!(
                    "{name} {} lies more than ten image sizes off the {}x{} image",
                    short(c),
                    self.width,
                    self.height
                )));
            }
        }
        self.pose.validate()
    }

    pub fn to_json(&self) -> CameraJson {
        CameraJson {
            width: self.width,
            height: self.height,
            fx: self.intrinsics.fx,
            fy: self.intrinsics.fy,
            cx: self.intrinsics.cx,
            cy: self.intrinsics.cy,
            camera_from_world: self.pose.to_row_major().to_vec(),
        }
    }
}

/// The camera JSON accepted by `deepview render --camera`:
/// `{"width","height","fx","fy","cx","cy","camera_from_world":[16 numbers, row-major]}`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CameraJson {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub camera_from_world: Vec<f64>,
}

impl CameraJson {
    pub fn to_camera(&self) -> Result<Camera, GeometryError> {
        let cam = Camera {
            width: self.width,
            height: self.height,
            intrinsics: Intrinsics::new(self.fx, self.fy, self.cx, self.cy),
            pose: Pose::from_row_major(&self.camera_from_world)?,
        };
        cam.validate()?;
        Ok(cam)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn some_pose() -> Pose {
        let r = DMat3::from_euler(glam::EulerRot::XYZ, 0.1, -0.3, 0.25);
        Pose::new(r, DVec3::new(0.3, -0.2, 1.5))
    }

    #[test]
    fn project_unproject_round_trip() {
        let cam = Camera::new(64, 48, Intrinsics::new(50.0, 52.0, 31.0, 25.0), some_pose());
        let p = DVec2::new(10.25, 40.5);
        let x = cam.unproject(p, 3.0);
        let q = cam.project(x).unwrap();
        assert!((p - q).length() < 1e-10);
        assert!((cam.pose.transform_point(x).z - 3.0).abs() < 1e-12);
    }

    #[test]
    fn pose_row_major_round_trip_and_inverse() {
        let p = some_pose();
        let q = Pose::from_row_major(&p.to_row_major()).unwrap();
        assert_eq!(p, q);
        let id = p.compose(&p.inverse());
        assert!((id.rotation - DMat3::IDENTITY).abs_diff_eq(DMat3::ZERO, 1e-12));
        assert!(id.translation.length() < 1e-12);
        assert!((p.transform_point(p.center())).length() < 1e-12);
    }

    #[test]
    fn absurd_cameras_are_refused() {
        let ok = Camera::new(64, 48, Intrinsics::centred(60.0, 64, 48), Pose::IDENTITY);
        ok.validate().unwrap();
        let with = |k: Intrinsics, t: DVec3| {
            Camera::new(64, 48, k, Pose::new(DMat3::IDENTITY, t))
                .validate()
                .map_err(|e| e.to_string())
        };
        let k = ok.intrinsics;
        for (bad, needle) in [
            (Intrinsics { cx: 1e300, ..k }, "cx"),
            (Intrinsics { cy: -1e6, ..k }, "cy"),
            (Intrinsics { fx: 1e300, ..k }, "fx"),
            (Intrinsics { fy: 1e-300, ..k }, "fy"),
        ] {
            let e = with(bad, DVec3::ZERO).unwrap_err();
            assert!(e.contains(needle), "{e}");
        }
        let e = with(k, DVec3::new(0.0, 1e300, 0.0)).unwrap_err();
        assert!(e.contains("translation"), "{e}");
        // Wide, long and off-centre but real: accepted.
        with(
            Intrinsics {
                fx: 0.2,
                fy: 0.2,
                ..k
            },
            DVec3::ZERO,
        )
        .unwrap();
        with(
            Intrinsics {
                fx: 1e6,
                fy: 1e6,
                cx: 600.0,
                ..k
            },
            DVec3::new(1e9, 0.0, 0.0),
        )
        .unwrap();
    }

    #[test]
    fn bad_poses_are_refused() {
        let mut m = Pose::IDENTITY.to_row_major();
        m[5] = f64::NAN;
        assert_eq!(
            Pose::from_row_major(&m),
            Err(GeometryError::NonFinite("camera_from_world"))
        );
        let mut m = Pose::IDENTITY.to_row_major();
        m[0] = 2.0;
        assert!(matches!(
            Pose::from_row_major(&m),
            Err(GeometryError::NotRigid(_))
        ));
        let mut m = Pose::IDENTITY.to_row_major();
        m[0] = -1.0; // reflection
        assert!(matches!(
            Pose::from_row_major(&m),
            Err(GeometryError::NotRigid(_))
        ));
        assert!(Pose::from_row_major(&[0.0; 12]).is_err());
    }

    #[test]
    fn scaling_intrinsics_keeps_pixel_areas() {
        // A point at the centre of pixel (1, 1) of a 4x4 image lies at the centre of the 2x2 block
        // (2..4, 2..4) of the 8x8 image: continuous coordinate 1.5 -> 3.0.
        let cam = Camera::new(4, 4, Intrinsics::centred(4.0, 4, 4), Pose::IDENTITY);
        let big = cam.resized(8, 8);
        let x = cam.unproject(DVec2::new(1.5, 1.5), 2.0);
        let q = big.project(x).unwrap();
        assert!((q - DVec2::new(3.0, 3.0)).length() < 1e-12);
    }

    #[test]
    fn orthonormalize_recovers_rotation() {
        let r = some_pose().rotation;
        let noisy = r + DMat3::from_cols_array(&[1e-3, 0.0, 2e-3, 0.0, -1e-3, 0.0, 5e-4, 0.0, 0.0]);
        let o = orthonormalize(noisy);
        assert!((o.transpose() * o).abs_diff_eq(DMat3::IDENTITY, 1e-12));
        assert!(o.abs_diff_eq(r, 5e-3));
    }
}
