//! The reference camera of an MPI: at the centroid of the input cameras, oriented as their average,
//! with its field of view enlarged so the planes cover what the input cameras see.

use crate::camera::{Camera, GeometryError, Intrinsics, Pose, orthonormalize};
use crate::homography::plane_homography;
use glam::{DMat3, DVec2, DVec3};

/// How to choose the reference camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceOptions {
    /// Take this input view's camera (orientation, intrinsics, size) instead of the average one
    /// (still placed at the centroid unless `at_view_center`).
    pub view: Option<usize>,
    /// With `view`: keep that camera's own position too.
    pub at_view_center: bool,
    /// Enlarge the field of view (and image size, keeping the pixel pitch) to cover the union of the
    /// input frusta between the given depths.
    pub cover: Option<(f64, f64)>,
    /// Upper bound of the enlargement per side, as a fraction of the base size (0.25 = 25% more per side).
    pub max_margin: f64,
    /// Pixels per base pixel along each axis (1 = the inputs' pixel pitch; 1.5 = a finer grid with
    /// 1.5 times the width and height over the same field of view), applied after `cover`.
    pub scale: f64,
    /// Round the final size up to a multiple of this (1 = no rounding).
    pub size_multiple: u32,
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        Self {
            view: None,
            at_view_center: false,
            cover: None,
            max_margin: 0.25,
            scale: 1.0,
            size_multiple: 1,
        }
    }
}

/// Choose the reference camera for a set of input cameras (see [`ReferenceOptions`]).
pub fn reference_camera(
    inputs: &[Camera],
    options: &ReferenceOptions,
) -> Result<Camera, GeometryError> {
    if inputs.is_empty() {
        return Err(GeometryError::Invalid(
            "no input cameras to place a reference camera".into(),
        ));
    }
    let n = inputs.len() as f64;
    let centroid = inputs
        .iter()
        .map(|c| c.center())
        .fold(DVec3::ZERO, |a, b| a + b)
        / n;
    let mut base = match options.view {
        Some(i) => *inputs.get(i).ok_or_else(|| {
            GeometryError::Invalid(format!(
                "reference view {i} out of range ({} inputs)",
                inputs.len()
            ))
        })?,
        None => {
            // Average rotation: mean of the rotation matrices projected back to SO(3) (none for
            // views facing opposite ways: said so, with the pair).
            let sum = inputs.iter().fold(DMat3::ZERO, |a, c| a + c.pose.rotation);
            let rotation = orthonormalize(sum * (1.0 / n));
            if !rotation.is_finite() || (rotation.determinant() - 1.0).abs() > 1e-6 {
                return Err(facing_apart(inputs).unwrap_or(GeometryError::NonFinite("pose")));
            }
            let (fx, fy) = inputs.iter().fold((0.0, 0.0), |a, c| {
                (a.0 + c.intrinsics.fx, a.1 + c.intrinsics.fy)
            });
            // The principal point's offset from the image centre: the median (one view with an
            // odd offset, as a crop's, does not move the reference off the others).
            let (dx, dy) = (
                median(
                    inputs
                        .iter()
                        .map(|c| c.intrinsics.cx - c.width as f64 / 2.0),
                ),
                median(
                    inputs
                        .iter()
                        .map(|c| c.intrinsics.cy - c.height as f64 / 2.0),
                ),
            );
            let w = (inputs.iter().map(|c| c.width as f64).sum::<f64>() / n).round() as u32;
            let h = (inputs.iter().map(|c| c.height as f64).sum::<f64>() / n).round() as u32;
            let intr = Intrinsics::new(fx / n, fy / n, w as f64 / 2.0 + dx, h as f64 / 2.0 + dy);
            Camera::new(w, h, intr, Pose::from_center(rotation, centroid))
        }
    };
    if !(options.view.is_some() && options.at_view_center) {
        base.pose = Pose::from_center(base.pose.rotation, centroid);
    }
    if let Some((near, far)) = options.cover {
        base = enlarge_to_cover(&base, inputs, near, far, options.max_margin);
    }
    if options.scale != 1.0 {
        base = rescaled(&base, options.scale)?;
    }
    let m = options.size_multiple.max(1);
    if m > 1 {
        let w = base.width.div_ceil(m) * m;
        let h = base.height.div_ceil(m) * m;
        let (dx, dy) = (
            (w - base.width) as f64 / 2.0,
            (h - base.height) as f64 / 2.0,
        );
        base.intrinsics.cx += dx;
        base.intrinsics.cy += dy;
        base.width = w;
        base.height = h;
    }
    base.validate()?;
    Ok(base)
}

/// The median of `values` (the mean of the middle two for an even count).
fn median(values: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.collect();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// The two inputs whose viewing directions lie furthest apart, where that is 90 degrees or more:
/// they share no planes an MPI could hold (and opposite ones have no average orientation).
fn facing_apart(inputs: &[Camera]) -> Option<GeometryError> {
    let axis = |c: &Camera| c.pose.rotation.transpose() * DVec3::Z;
    let mut worst: Option<(usize, usize, f64)> = None;
    for i in 0..inputs.len() {
        for j in i + 1..inputs.len() {
            let cos = axis(&inputs[i]).dot(axis(&inputs[j])).clamp(-1.0, 1.0);
            if worst.is_none_or(|w| cos < w.2) {
                worst = Some((i, j, cos));
            }
        }
    }
    match worst {
        Some((first, second, cos)) if cos <= 1e-9 => Some(GeometryError::FacingApart {
            first,
            second,
            degrees: cos.acos().to_degrees(),
        }),
        _ => None,
    }
}

/// `base` with `scale` times its pixels along each axis over the same field of view: the intrinsics
/// scaled by exactly `scale` (a point's continuous pixel coordinates scale by it, pixel centres at
/// `i + 0.5` in both grids, square pixels stay square), the size rounded up so that the grid covers the
/// whole base image (less than one pixel more at the right and bottom edges).
fn rescaled(base: &Camera, scale: f64) -> Result<Camera, GeometryError> {
    if !(scale.is_finite() && scale > 0.0) {
        return Err(GeometryError::Invalid(format!(
            "MPI scale {scale} must be positive"
        )));
    }
    let size = |n: u32| (n as f64 * scale - 1e-9).ceil().max(1.0) as u32;
    let i = base.intrinsics;
    let mut out = *base;
    out.intrinsics = Intrinsics::new(i.fx * scale, i.fy * scale, i.cx * scale, i.cy * scale);
    out.width = size(base.width);
    out.height = size(base.height);
    Ok(out)
}

/// Grow the image of `base` (same focal length, shifted principal point) so every input image's
/// footprint on the planes at `near` and `far` lies inside it, by at most `max_margin` per side.
fn enlarge_to_cover(
    base: &Camera,
    inputs: &[Camera],
    near: f64,
    far: f64,
    max_margin: f64,
) -> Camera {
    let (w, h) = (base.width as f64, base.height as f64);
    let (mut x0, mut y0, mut x1, mut y1) = (0.0f64, 0.0f64, w, h);
    for cam in inputs {
        for depth in [near, far] {
            // Input pixels -> reference pixels through the plane: inverse of ref -> input.
            let hinv = plane_homography(base, cam, depth).inverse();
            let (cw, ch) = (cam.width as f64, cam.height as f64);
            for p in [
                DVec2::new(0.0, 0.0),
                DVec2::new(cw, 0.0),
                DVec2::new(0.0, ch),
                DVec2::new(cw, ch),
            ] {
                let q = hinv.apply(p);
                if q.is_finite() {
                    x0 = x0.min(q.x);
                    y0 = y0.min(q.y);
                    x1 = x1.max(q.x);
                    y1 = y1.max(q.y);
                }
            }
        }
    }
    let clamp = |v: f64, size: f64| (v - 1e-6).clamp(0.0, max_margin * size).ceil();
    let (left, top, right, bottom) = (
        clamp(-x0, w),
        clamp(-y0, h),
        clamp(x1 - w, w),
        clamp(y1 - h, h),
    );
    let mut out = *base;
    out.width = (w + left + right) as u32;
    out.height = (h + top + bottom) as u32;
    out.intrinsics.cx += left;
    out.intrinsics.cy += top;
    out
}

/// The reference camera every MPI is made in (every method of `infer`, and training's plane rule): the
/// inputs' centroid and average orientation ([`reference_camera`]), its field of view enlarged to cover
/// them between near and far.
pub fn mpi_reference(cameras: &[Camera], near_far: (f64, f64)) -> Result<Camera, GeometryError> {
    mpi_reference_scaled(cameras, near_far, 1.0)
}

/// [`mpi_reference`] with `scale` times its pixels along each axis (`--mpi-scale`; see
/// [`ReferenceOptions::scale`]).
pub fn mpi_reference_scaled(
    cameras: &[Camera],
    near_far: (f64, f64),
    scale: f64,
) -> Result<Camera, GeometryError> {
    // (An MPI's planes face its reference camera: inputs 90 degrees apart share none.)
    if let Some(e) = facing_apart(cameras) {
        return Err(e);
    }
    reference_camera(
        cameras,
        &ReferenceOptions {
            cover: Some(near_far),
            scale,
            ..Default::default()
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> Vec<Camera> {
        (0..4)
            .map(|i| {
                let x = if i % 2 == 0 { -0.1 } else { 0.1 };
                let y = if i / 2 == 0 { -0.1 } else { 0.1 };
                let r = DMat3::IDENTITY;
                Camera::new(
                    64,
                    48,
                    Intrinsics::centred(60.0, 64, 48),
                    Pose::from_center(r, DVec3::new(x, y, 0.0)),
                )
            })
            .collect()
    }

    #[test]
    fn centroid_and_average_orientation() {
        let r = reference_camera(&rig(), &ReferenceOptions::default()).unwrap();
        assert!(r.center().length() < 1e-12);
        assert!(r.pose.rotation.abs_diff_eq(DMat3::IDENTITY, 1e-9));
        assert_eq!((r.width, r.height), (64, 48));
    }

    /// An MPI's inputs 90 degrees or more apart are refused with the pair and their angle; a view
    /// turned 60 degrees is not. A reference camera alone is refused only where the views have no
    /// average orientation (two one way, two the other: a NaN pose before).
    #[test]
    fn inputs_facing_apart_are_refused_by_name() {
        for (deg, refused) in [(180.0, true), (120.0, true), (90.0, true), (60.0, false)] {
            let mut cams = rig();
            let r = DMat3::from_rotation_y(f64::to_radians(deg));
            cams[2].pose = Pose::from_center(r, cams[2].center());
            match mpi_reference(&cams, (1.0, 10.0)) {
                Err(e) if refused => {
                    let e = e.to_string();
                    assert!(
                        e.contains("views 0 and 2")
                            && e.contains(&format!("look {deg:.0} degrees apart")),
                        "{deg}: {e}"
                    );
                }
                Ok(c) if !refused => assert!(c.validate().is_ok()),
                other => panic!("{deg} degrees: {other:?}"),
            }
            // (Three views one way and one the other still have an average orientation.)
            let alone = reference_camera(&cams, &ReferenceOptions::default());
            assert!(alone.is_ok(), "{deg}: {alone:?}");
        }
        let mut cams = rig();
        for c in &mut cams[2..] {
            c.pose = Pose::from_center(DMat3::from_rotation_y(std::f64::consts::PI), c.center());
        }
        let e = reference_camera(&cams, &ReferenceOptions::default()).unwrap_err();
        assert!(
            matches!(e, GeometryError::FacingApart { degrees, .. } if degrees > 179.9),
            "{e}"
        );
    }

    /// One view whose principal point lies far off its image (a crop's) does not move the
    /// reference's principal point off the others' (the median offset).
    #[test]
    fn one_odd_principal_point_leaves_the_reference_centred() {
        let mut cams = rig();
        cams[2].intrinsics.cx = 640.0;
        let r = reference_camera(&cams, &ReferenceOptions::default()).unwrap();
        assert_eq!(r.intrinsics.cx, 32.0);
        assert_eq!(r.intrinsics.cy, 24.0);
        for c in &mut cams[1..3] {
            c.intrinsics.cx = 40.0;
        }
        let r = reference_camera(&cams, &ReferenceOptions::default()).unwrap();
        assert_eq!(r.intrinsics.cx, 36.0);
    }

    #[test]
    fn cover_enlarges_to_see_all_inputs() {
        let opts = ReferenceOptions {
            cover: Some((1.0, 10.0)),
            ..Default::default()
        };
        let r = reference_camera(&rig(), &opts).unwrap();
        // At depth 1 the inputs are shifted by 0.1 * 60 = 6 px on each side.
        assert_eq!((r.width, r.height), (76, 60));
        assert!((r.intrinsics.cx - 38.0).abs() < 1e-9);
        // Every input corner seen at the near plane lies inside the reference image.
        for cam in rig() {
            let h = plane_homography(&r, &cam, 1.0).inverse();
            for p in [DVec2::new(0.0, 0.0), DVec2::new(64.0, 48.0)] {
                let q = h.apply(p);
                assert!(q.x >= -1e-9 && q.y >= -1e-9 && q.x <= 76.0 + 1e-9 && q.y <= 60.0 + 1e-9);
            }
        }
    }

    #[test]
    fn scale_refines_the_grid_over_the_same_view() {
        let cover = Some((1.0, 10.0));
        let base = reference_camera(
            &rig(),
            &ReferenceOptions {
                cover,
                ..Default::default()
            },
        )
        .unwrap();
        let fine = mpi_reference_scaled(&rig(), (1.0, 10.0), 1.5).unwrap();
        assert_eq!((fine.width, fine.height), (114, 90));
        assert_eq!(fine.pose, base.pose);
        // Any point's continuous pixel coordinates are 1.5 times the base camera's; the image corners map to
        // the image corners, so both grids cover the same view.
        for world in [DVec3::new(0.3, -0.2, 2.0), DVec3::new(-1.0, 0.7, 7.5)] {
            let (p, q) = (base.project(world).unwrap(), fine.project(world).unwrap());
            assert!((q - p * 1.5).length() < 1e-9, "{p} -> {q}");
        }
        let corner = base.unproject(DVec2::new(76.0, 60.0), 3.0);
        assert!((fine.project(corner).unwrap() - DVec2::new(114.0, 90.0)).length() < 1e-9);
        // Sizes round up (76 * 1.3 = 98.8 -> 99, 60 * 1.3 = 78); the intrinsics scale by exactly 1.3 on both
        // axes, so the base image's corner falls inside the last pixel.
        let odd = mpi_reference_scaled(&rig(), (1.0, 10.0), 1.3).unwrap();
        assert_eq!((odd.width, odd.height), (99, 78));
        for (a, b) in [
            (odd.intrinsics.fx, base.intrinsics.fx),
            (odd.intrinsics.fy, base.intrinsics.fy),
            (odd.intrinsics.cx, base.intrinsics.cx),
            (odd.intrinsics.cy, base.intrinsics.cy),
        ] {
            assert!((a - b * 1.3).abs() < 1e-9, "{a} vs {b} * 1.3");
        }
        let q = odd.project(corner).unwrap();
        assert!((q - DVec2::new(98.8, 78.0)).length() < 1e-9, "{q}");
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(
                mpi_reference_scaled(&rig(), (1.0, 10.0), bad).is_err(),
                "{bad}"
            );
        }
    }

    #[test]
    fn chosen_view() {
        let cams = rig();
        let opts = ReferenceOptions {
            view: Some(3),
            at_view_center: true,
            ..Default::default()
        };
        assert_eq!(reference_camera(&cams, &opts).unwrap(), cams[3]);
        let bad = ReferenceOptions {
            view: Some(9),
            ..Default::default()
        };
        assert!(reference_camera(&cams, &bad).is_err());
    }
}
