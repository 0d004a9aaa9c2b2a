//! Plane-induced homographies between a reference camera and any other camera.

use crate::camera::Camera;
use glam::{DMat3, DVec2, DVec3};

/// A 3x3 homography acting on continuous pixel coordinates (pixel centres at +0.5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Homography(pub DMat3);

impl Homography {
    pub fn apply(&self, p: DVec2) -> DVec2 {
        let q = self.0 * DVec3::new(p.x, p.y, 1.0);
        DVec2::new(q.x / q.z, q.y / q.z)
    }

    pub fn inverse(&self) -> Homography {
        Homography(self.0.inverse())
    }

    /// Row-major 3x3, as f32 (for kernels and tensors).
    pub fn to_row_major_f32(&self) -> [f32; 9] {
        let m = self.0.transpose().to_cols_array();
        m.map(|v| v as f32)
    }

    pub fn to_row_major(&self) -> [f64; 9] {
        self.0.transpose().to_cols_array()
    }
}

/// The homography from reference pixels to target pixels induced by the fronto-parallel plane at
/// `depth` in the reference camera: `H = K_t (R + t n^T / d) K_ref^-1` with `n = (0, 0, 1)` and
/// `X_t = R X_ref + t` the relative pose.
///
/// Warping a plane into the target samples the plane at `H^-1 p` for every target pixel `p`; the plane
/// sweep (inverse warp) samples the target image at `H p` for every reference pixel `p`.
pub fn plane_homography(reference: &Camera, target: &Camera, depth: f64) -> Homography {
    let rel = target.pose.compose(&reference.pose.inverse());
    // Outer product t n^T / d with n = (0, 0, 1): only the third column is non-zero.
    let tn = DMat3::from_cols(DVec3::ZERO, DVec3::ZERO, rel.translation / depth);
    Homography(
        target.intrinsics.matrix() * (rel.rotation + tn) * reference.intrinsics.inverse_matrix(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Intrinsics, Pose};

    #[test]
    fn homography_agrees_with_projecting_points() {
        let reference = Camera::new(
            80,
            60,
            Intrinsics::new(70.0, 72.0, 41.0, 29.5),
            Pose::from_center(DMat3::from_rotation_y(0.05), DVec3::new(0.1, 0.0, -0.2)),
        );
        let target = Camera::new(
            100,
            50,
            Intrinsics::new(90.0, 88.0, 48.0, 26.0),
            Pose::from_center(
                DMat3::from_euler(glam::EulerRot::XYZ, 0.02, -0.1, 0.03),
                DVec3::new(0.4, -0.1, 0.1),
            ),
        );
        for depth in [1.0, 2.5, 10.0, 100.0] {
            let h = plane_homography(&reference, &target, depth);
            for p in [
                DVec2::new(0.0, 0.0),
                DVec2::new(40.5, 30.5),
                DVec2::new(79.9, 12.25),
            ] {
                let x = reference.unproject(p, depth);
                let expected = target.project(x).unwrap();
                assert!(
                    (h.apply(p) - expected).length() < 1e-9,
                    "depth {depth} p {p}"
                );
                assert!((h.inverse().apply(expected) - p).length() < 1e-9);
            }
        }
    }

    #[test]
    fn same_camera_gives_identity() {
        let cam = Camera::new(
            32,
            32,
            Intrinsics::centred(30.0, 32, 32),
            Pose::from_center(DMat3::from_rotation_x(0.3), DVec3::new(1.0, 2.0, 3.0)),
        );
        for d in [0.5, 7.0] {
            let h = plane_homography(&cam, &cam, d);
            assert!(h.0.abs_diff_eq(DMat3::IDENTITY, 1e-12));
        }
    }
}
