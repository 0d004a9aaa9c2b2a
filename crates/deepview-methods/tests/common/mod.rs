//! Synthetic scenes with known answers: a textured fronto-parallel plane rendered analytically (ray-plane
//! intersection, texture evaluated at the hit point; no resampling), so predictions can be compared with
//! an exact ground truth.
#![allow(dead_code)]

use deepview_geometry::{Camera, DMat3, DVec2, DVec3, Intrinsics, Pose};
use deepview_image::ImageF32;

/// Smooth colour texture on the world plane, values in about 0.05..0.95.
pub fn texture(x: f64, y: f64) -> [f32; 3] {
    [
        (0.5 + 0.25 * (7.0 * x + 3.0 * y).sin() + 0.15 * (5.0 * y - 2.0 * x).cos()) as f32,
        (0.5 + 0.3 * (4.0 * x - 6.0 * y).sin() * (3.0 * x).cos()) as f32,
        (0.45 + 0.2 * (9.0 * y).sin() + 0.2 * (2.0 * x + 5.0 * y).cos()) as f32,
    ]
}

/// The image `camera` sees of the plane `Z = depth` (world) carrying [`texture`]; black where the ray misses.
pub fn render_plane(camera: &Camera, depth: f64) -> ImageF32 {
    render_plane_scaled(camera, depth, 1.0)
}

/// [`render_plane`] with the texture's frequencies multiplied by `freq`.
pub fn render_plane_scaled(camera: &Camera, depth: f64, freq: f64) -> ImageF32 {
    let mut img = ImageF32::new(camera.width, camera.height, 3);
    let c = camera.center();
    for y in 0..camera.height {
        for x in 0..camera.width {
            let p = camera.unproject(DVec2::new(x as f64 + 0.5, y as f64 + 0.5), 1.0);
            let dir = p - c;
            if dir.z.abs() < 1e-12 {
                continue;
            }
            let s = (depth - c.z) / dir.z;
            if s <= 0.0 {
                continue;
            }
            let hit = c + dir * s;
            img.pixel_mut(x, y)
                .copy_from_slice(&texture(hit.x * freq, hit.y * freq));
        }
    }
    img
}

/// A `w x h` camera at `center`, looking down +Z, focal `f`, centred principal point.
pub fn camera_at(center: DVec3, w: u32, h: u32, f: f64) -> Camera {
    Camera::new(
        w,
        h,
        Intrinsics::centred(f, w, h),
        Pose::from_center(DMat3::IDENTITY, center),
    )
}

/// `(near, far)` whose inverse-depth midpoint is `depth` (so 1 plane, or the middle of an odd count, lies on it).
pub fn bounds_around(depth: f64) -> (f64, f64) {
    (depth / 1.25, depth / 0.75)
}

pub fn psnr_interior(a: &ImageF32, b: &ImageF32, margin: u32) -> f64 {
    let a = deepview_metrics::crop_border(a, margin, margin, margin, margin).unwrap();
    let b = deepview_metrics::crop_border(b, margin, margin, margin, margin).unwrap();
    deepview_metrics::psnr(&a, &b).unwrap()
}
