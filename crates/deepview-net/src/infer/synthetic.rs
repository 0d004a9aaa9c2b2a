//! Synthetic inputs for benchmarks.

use deepview_geometry::Camera;
use deepview_image::ImageF32;

/// Synthetic inputs of [`super::infer_mpi`] for benchmarks: `views` cameras of `w x h` pixels (focal `w`) on a
/// circle of radius 0.05 around a reference camera looking down +z, textured images, `planes`
/// inverse-depth planes between depth 1 and 10 (about `0.05 w` px of parallax at the near plane).
pub fn synthetic_views(
    views: usize,
    planes: usize,
    w: usize,
    h: usize,
) -> (Vec<(ImageF32, Camera)>, Camera, Vec<f64>) {
    use deepview_geometry::{DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths};
    let (wu, hu) = (w as u32, h as u32);
    let reference = Camera::new(
        wu,
        hu,
        Intrinsics::centred(w as f64, wu, hu),
        Pose::IDENTITY,
    );
    let depths = plane_depths(1.0, 10.0, planes, PlaneSpacing::InverseDepth).expect("valid depths");
    let cams = (0..views).map(|k| {
        let t = k as f64 / views as f64 * std::f64::consts::TAU;
        let pose = Pose::from_center(
            DMat3::IDENTITY,
            DVec3::new(0.05 * t.cos(), 0.05 * t.sin(), 0.0),
        );
        let mut img = ImageF32::new(wu, hu, 3);
        for (j, v) in img.data.iter_mut().enumerate() {
            let (p, c) = (j / 3, j % 3);
            let (x, y) = ((p % w) as f32, (p / w) as f32);
            let hash = ((p as u32).wrapping_mul(2654435761) >> 24) as f32 / 255.0;
            *v = 0.5 + 0.3 * (0.05 * x + 0.07 * y + c as f32 + k as f32).sin() * hash;
        }
        (img, Camera::new(wu, hu, reference.intrinsics, pose))
    });
    (cams.collect(), reference, depths)
}
