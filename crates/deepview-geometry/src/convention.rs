//! One named converter per foreign pose convention, each with its inverse (round trips are tested).
//!
//! - LLFF `poses_bounds.npy`: 3x4 camera-to-world whose rotation columns are the camera's
//!   [down, right, back] axes in world coordinates.
//! - OpenGL / nerfstudio: 4x4 camera-to-world with columns [right, up, back].
//! - Spaces `models.json`: camera centre `position` and axis-angle `orientation` of the camera-from-world
//!   rotation, `x_cam = R (X - position)`.
//! - COLMAP `images.txt`: unit quaternion `qvec = [w, x, y, z]` and `tvec`, `x_cam = R(q) X + t`.

use crate::camera::{GeometryError, Pose};
use glam::{DMat3, DQuat, DVec3};

fn check_finite(values: &[f64], what: &'static str) -> Result<(), GeometryError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(GeometryError::NonFinite(what))
    }
}

/// LLFF: `c2w` rows of a 3x4 matrix (rotation columns [down, right, back], then the camera centre).
pub fn llff_c2w_to_pose(c2w: [[f64; 4]; 3]) -> Result<Pose, GeometryError> {
    check_finite(c2w.as_flattened(), "LLFF pose")?;
    let col = |j: usize| DVec3::new(c2w[0][j], c2w[1][j], c2w[2][j]);
    let (down, right, back) = (col(0), col(1), col(2));
    // OpenCV camera axes in world coordinates: x = right, y = down, z = forward = -back.
    let world_from_cam = DMat3::from_cols(right, down, -back);
    let pose = Pose::from_center(world_from_cam.transpose(), col(3));
    pose.validate()?;
    Ok(pose)
}

pub fn pose_to_llff_c2w(pose: &Pose) -> [[f64; 4]; 3] {
    let wfc = pose.rotation.transpose();
    let (right, down, fwd) = (wfc.x_axis, wfc.y_axis, wfc.z_axis);
    let c = pose.center();
    let cols = [down, right, -fwd, c];
    let mut m = [[0.0; 4]; 3];
    for (j, v) in cols.iter().enumerate() {
        m[0][j] = v.x;
        m[1][j] = v.y;
        m[2][j] = v.z;
    }
    m
}

/// OpenGL / nerfstudio camera-to-world, 16 numbers row-major (columns [right, up, back, centre]).
pub fn opengl_c2w_to_pose(m: &[f64; 16]) -> Result<Pose, GeometryError> {
    check_finite(m, "camera_to_world")?;
    let col = |j: usize| DVec3::new(m[j], m[4 + j], m[8 + j]);
    let world_from_cam = DMat3::from_cols(col(0), -col(1), -col(2));
    let pose = Pose::from_center(world_from_cam.transpose(), col(3));
    pose.validate()?;
    Ok(pose)
}

pub fn pose_to_opengl_c2w(pose: &Pose) -> [f64; 16] {
    let wfc = pose.rotation.transpose();
    let cols = [wfc.x_axis, -wfc.y_axis, -wfc.z_axis, pose.center()];
    let mut m = [0.0; 16];
    for (j, v) in cols.iter().enumerate() {
        m[j] = v.x;
        m[4 + j] = v.y;
        m[8 + j] = v.z;
    }
    m[15] = 1.0;
    m
}

/// Spaces: `orientation` (axis-angle of camera-from-world rotation) and `position` (camera centre).
pub fn spaces_to_pose(orientation: [f64; 3], position: [f64; 3]) -> Result<Pose, GeometryError> {
    check_finite(&orientation, "Spaces orientation")?;
    check_finite(&position, "Spaces position")?;
    let aa = DVec3::from_array(orientation);
    let angle = aa.length();
    let rotation = if angle < 1e-300 {
        DMat3::IDENTITY
    } else {
        DMat3::from_axis_angle(aa / angle, angle)
    };
    Ok(Pose::from_center(rotation, DVec3::from_array(position)))
}

/// Inverse of [`spaces_to_pose`]: `(orientation, position)`.
pub fn pose_to_spaces(pose: &Pose) -> ([f64; 3], [f64; 3]) {
    let (axis, angle) = DQuat::from_mat3(&pose.rotation).normalize().to_axis_angle();
    // Keep the angle in [0, pi] so the axis-angle vector is canonical.
    let (axis, angle) = if angle > std::f64::consts::PI {
        (-axis, 2.0 * std::f64::consts::PI - angle)
    } else {
        (axis, angle)
    };
    ((axis * angle).to_array(), pose.center().to_array())
}

/// COLMAP: `qvec = [w, x, y, z]` (normalised here) and `tvec`.
pub fn colmap_to_pose(qvec: [f64; 4], tvec: [f64; 3]) -> Result<Pose, GeometryError> {
    check_finite(&qvec, "COLMAP qvec")?;
    check_finite(&tvec, "COLMAP tvec")?;
    let q = DQuat::from_xyzw(qvec[1], qvec[2], qvec[3], qvec[0]);
    let n = q.length();
    if n < 1e-12 {
        return Err(GeometryError::Invalid("COLMAP qvec has zero length".into()));
    }
    Ok(Pose::new(DMat3::from_quat(q / n), DVec3::from_array(tvec)))
}

/// Inverse of [`colmap_to_pose`], with `w >= 0`.
pub fn pose_to_colmap(pose: &Pose) -> ([f64; 4], [f64; 3]) {
    let mut q = DQuat::from_mat3(&pose.rotation).normalize();
    if q.w < 0.0 {
        q = -q;
    }
    ([q.w, q.x, q.y, q.z], pose.translation.to_array())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Camera, Intrinsics};
    use glam::DVec2;

    fn poses() -> Vec<Pose> {
        let mut v = vec![Pose::IDENTITY];
        for (i, (a, b, c)) in [
            (0.1, -0.2, 0.3),
            (2.0, 0.5, -1.0),
            (3.1, 0.0, 0.0),
            (0.0, 3.1, 0.01),
        ]
        .into_iter()
        .enumerate()
        {
            let r = DMat3::from_euler(glam::EulerRot::ZYX, a, b, c);
            v.push(Pose::from_center(
                r,
                DVec3::new(i as f64, -0.5, 2.0 * i as f64),
            ));
        }
        v
    }

    fn close(a: &Pose, b: &Pose) -> bool {
        a.rotation.abs_diff_eq(b.rotation, 1e-12) && a.translation.abs_diff_eq(b.translation, 1e-12)
    }

    #[test]
    fn llff_round_trip_and_axes() {
        for p in poses() {
            assert!(close(&p, &llff_c2w_to_pose(pose_to_llff_c2w(&p)).unwrap()));
        }
        // A camera at the origin looking down world -z (LLFF "back" = +z), image down = world -y.
        let c2w = [
            [0.0, 1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let cam = Camera::new(
            10,
            10,
            Intrinsics::centred(10.0, 10, 10),
            llff_c2w_to_pose(c2w).unwrap(),
        );
        // A point in front (world -z) and up (world +y) projects above the image centre.
        let p = cam.project(DVec3::new(0.0, 1.0, -5.0)).unwrap();
        assert!((p - DVec2::new(5.0, 3.0)).length() < 1e-12, "{p}");
    }

    #[test]
    fn opengl_round_trip_and_axes() {
        for p in poses() {
            assert!(close(
                &p,
                &opengl_c2w_to_pose(&pose_to_opengl_c2w(&p)).unwrap()
            ));
        }
        // Identity OpenGL camera looks down world -z with +y up.
        let mut m = [0.0; 16];
        m[0] = 1.0;
        m[5] = 1.0;
        m[10] = 1.0;
        m[15] = 1.0;
        let cam = Camera::new(
            10,
            10,
            Intrinsics::centred(10.0, 10, 10),
            opengl_c2w_to_pose(&m).unwrap(),
        );
        let p = cam.project(DVec3::new(1.0, 1.0, -10.0)).unwrap();
        assert!((p - DVec2::new(6.0, 4.0)).length() < 1e-12, "{p}");
    }

    #[test]
    fn spaces_round_trip() {
        for p in poses() {
            let (o, c) = pose_to_spaces(&p);
            assert!(close(&p, &spaces_to_pose(o, c).unwrap()), "{p:?}");
        }
        // Small rotation about y: x_cam = R (X - position).
        let p = spaces_to_pose([0.0, 0.1, 0.0], [1.0, 2.0, 3.0]).unwrap();
        assert!(p.transform_point(DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
        let r = DMat3::from_rotation_y(0.1);
        assert!(p.rotation.abs_diff_eq(r, 1e-15));
    }

    #[test]
    fn colmap_round_trip() {
        for p in poses() {
            let (q, t) = pose_to_colmap(&p);
            assert!(close(&p, &colmap_to_pose(q, t).unwrap()));
        }
        let p = colmap_to_pose([2.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0]).unwrap();
        assert_eq!(p.rotation, DMat3::IDENTITY);
        assert!(colmap_to_pose([0.0; 4], [0.0; 3]).is_err());
        assert!(colmap_to_pose([1.0, f64::NAN, 0.0, 0.0], [0.0; 3]).is_err());
    }
}
