//! Camera paths around an MPI's reference camera: `spiral`, `circle`, `swing`.
//!
//! Offsets are expressed in the reference camera's frame (OpenCV axes: x right, y down, z forward). Every
//! camera looks at a focus point on the reference optical axis (default: the plane at the middle of the
//! MPI's disparity range), so content at that depth stays still and nearer content moves the most. The
//! radius is either absolute (scene units) or a fraction of the near plane's depth; motions beyond
//! [`MAX_NEAR_FRACTION`] of the near depth leave the range where an MPI gives sensible views and are refused.
//! Paths are closed loops: frame `i` is at angle `2 pi i / frames` (the first frame is not repeated).

use crate::MediaError;
use deepview_geometry::{Camera, DMat3, DVec3, Pose};
use std::f64::consts::TAU;
use std::str::FromStr;

/// The largest allowed camera offset, as a fraction of the near plane's depth.
pub const MAX_NEAR_FRACTION: f64 = 0.25;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PathKind {
    /// Two turns of a circle in the image plane while moving forward and back once (LLFF-style).
    Spiral,
    /// One turn of a circle in the reference image plane.
    Circle,
    /// Side to side along the reference x axis (one period).
    Swing,
}

impl FromStr for PathKind {
    type Err = MediaError;
    fn from_str(s: &str) -> Result<Self, MediaError> {
        match s {
            "spiral" => Ok(PathKind::Spiral),
            "circle" => Ok(PathKind::Circle),
            "swing" => Ok(PathKind::Swing),
            _ => Err(MediaError::Config(format!(
                "unknown camera path {s:?} (expected spiral, circle or swing)"
            ))),
        }
    }
}

/// How far the camera moves from the reference position.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Radius {
    /// In scene units (the units of the MPI's depths).
    Scene(f64),
    /// As a fraction of the MPI's near plane depth (e.g. 0.05).
    NearFraction(f64),
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSpec {
    pub kind: PathKind,
    pub frames: usize,
    pub radius: Radius,
    /// Depth (along the reference axis) the cameras look at; default: middle of the disparity range.
    pub focus_depth: Option<f64>,
}

/// Cameras along `spec` around `reference` for an MPI whose plane depths are `depths` (any order).
/// Every camera has the reference's size and intrinsics.
pub fn camera_path(
    reference: &Camera,
    depths: &[f64],
    spec: &PathSpec,
) -> Result<Vec<Camera>, MediaError> {
    if spec.frames == 0 {
        return Err(MediaError::Config(
            "a camera path needs at least one frame".into(),
        ));
    }
    if depths.is_empty() || !depths.iter().all(|d| d.is_finite() && *d > 0.0) {
        return Err(MediaError::Config(
            "camera path: MPI depths must be finite and positive".into(),
        ));
    }
    let near = depths.iter().cloned().fold(f64::INFINITY, f64::min);
    let far = depths.iter().cloned().fold(0.0, f64::max);
    let r = match spec.radius {
        Radius::Scene(r) => r,
        Radius::NearFraction(f) => f * near,
    };
    if !r.is_finite() || r < 0.0 {
        return Err(MediaError::Config(format!(
            "camera path radius must be finite and >= 0 (got {r})"
        )));
    }
    if r > MAX_NEAR_FRACTION * near {
        return Err(MediaError::Config(format!(
            "camera path radius {r} is more than {MAX_NEAR_FRACTION} x the near depth {near}: \
             views that far from the reference camera are outside the range where the MPI is valid"
        )));
    }
    let focus = spec.focus_depth.unwrap_or(2.0 / (1.0 / near + 1.0 / far));
    if !focus.is_finite() || focus <= r {
        return Err(MediaError::Config(format!(
            "focus depth {focus} must be finite and larger than the radius {r}"
        )));
    }
    let n = spec.frames as f64;
    Ok((0..spec.frames)
        .map(|i| {
            let t = TAU * i as f64 / n;
            let offset = match spec.kind {
                // Two turns, one forward-back period: closed after one path.
                PathKind::Spiral => DVec3::new((2.0 * t).cos(), (2.0 * t).sin(), 0.5 * t.sin()) * r,
                PathKind::Circle => DVec3::new(t.cos(), t.sin(), 0.0) * r,
                PathKind::Swing => DVec3::new(t.sin(), 0.0, 0.0) * r,
            };
            look_at_from_reference(reference, offset, focus)
        })
        .collect())
}

/// Spiral path (see [`PathKind::Spiral`]); `radius_fraction` of the near depth.
pub fn spiral(
    reference: &Camera,
    depths: &[f64],
    radius_fraction: f64,
    frames: usize,
) -> Result<Vec<Camera>, MediaError> {
    let spec = PathSpec {
        kind: PathKind::Spiral,
        frames,
        radius: Radius::NearFraction(radius_fraction),
        focus_depth: None,
    };
    camera_path(reference, depths, &spec)
}

/// Circle path (see [`PathKind::Circle`]); `radius_fraction` of the near depth.
pub fn circle(
    reference: &Camera,
    depths: &[f64],
    radius_fraction: f64,
    frames: usize,
) -> Result<Vec<Camera>, MediaError> {
    let spec = PathSpec {
        kind: PathKind::Circle,
        frames,
        radius: Radius::NearFraction(radius_fraction),
        focus_depth: None,
    };
    camera_path(reference, depths, &spec)
}

/// Swing path (see [`PathKind::Swing`]); `radius_fraction` of the near depth.
pub fn swing(
    reference: &Camera,
    depths: &[f64],
    radius_fraction: f64,
    frames: usize,
) -> Result<Vec<Camera>, MediaError> {
    let spec = PathSpec {
        kind: PathKind::Swing,
        frames,
        radius: Radius::NearFraction(radius_fraction),
        focus_depth: None,
    };
    camera_path(reference, depths, &spec)
}

/// A camera at `offset` (reference camera coordinates) looking at `(0, 0, focus)` with the reference's
/// "down" as its approximate down direction.
pub fn look_at_from_reference(reference: &Camera, offset: DVec3, focus: f64) -> Camera {
    let forward = (DVec3::new(0.0, 0.0, focus) - offset).normalize();
    let right = DVec3::Y.cross(forward).normalize();
    let down = forward.cross(right);
    // Rows of cam_from_ref are the new camera's axes expressed in reference coordinates.
    let cam_from_ref = DMat3::from_cols(right, down, forward).transpose();
    let ref_from_world = reference.pose;
    let rotation = cam_from_ref * ref_from_world.rotation;
    let center = ref_from_world.inverse().transform_point(offset);
    Camera {
        pose: Pose::from_center(rotation, center),
        ..*reference
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::Intrinsics;

    fn reference() -> Camera {
        let r = DMat3::from_rotation_x(0.2)
            * DMat3::from_rotation_y(-0.1)
            * DMat3::from_rotation_z(0.05);
        Camera::new(
            80,
            60,
            Intrinsics::centred(70.0, 80, 60),
            Pose::from_center(r, DVec3::new(1.0, 2.0, -3.0)),
        )
    }

    #[test]
    fn zero_radius_reproduces_the_reference() {
        for kind in [PathKind::Spiral, PathKind::Circle, PathKind::Swing] {
            let spec = PathSpec {
                kind,
                frames: 5,
                radius: Radius::Scene(0.0),
                focus_depth: None,
            };
            for c in camera_path(&reference(), &[8.0, 2.0], &spec).unwrap() {
                assert!(
                    c.pose
                        .rotation
                        .abs_diff_eq(reference().pose.rotation, 1e-12)
                );
                assert!(
                    c.pose
                        .translation
                        .abs_diff_eq(reference().pose.translation, 1e-12)
                );
            }
        }
    }
}
