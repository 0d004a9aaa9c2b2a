//! Cameras in the OpenCV convention, converters from foreign conventions, plane-induced homographies,
//! MPI plane depths and the reference camera.
//!
//! Conventions (decided once, tested everywhere):
//! - camera axes x right, y down, z forward; `x_cam = R x_world + t` (camera-from-world);
//! - pixel `(i, j)` covers `[i, i+1) x [j, j+1)`, its centre is `(i + 0.5, j + 0.5)`; intrinsics map camera
//!   rays to these continuous pixel coordinates, so scaling an image by `s` scales `fx, fy, cx, cy` by `s`;
//! - MPI planes are stored back to front (index 0 = farthest).

pub mod camera;
pub mod convention;
pub mod homography;
pub mod planes;
pub mod reference;

pub use camera::{Camera, CameraJson, GeometryError, Intrinsics, Pose};
pub use homography::{Homography, plane_homography};
pub use planes::{
    AUTO_MAX_SPACING_PX, AUTO_PLANES_MAX, AUTO_PLANES_MIN, AutoPlanes, DEPTH_LIMITS, MAX_PLANES,
    PlaneSpacing, auto_plane_count, auto_planes, check_plane_depths, disparity_range, plane_depths,
};
pub use reference::{ReferenceOptions, mpi_reference, mpi_reference_scaled, reference_camera};

pub use glam::{DMat3, DMat4, DVec2, DVec3};
