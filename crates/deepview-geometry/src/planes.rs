//! MPI plane depths: equally spaced in inverse depth (disparity), stored back to front.

use crate::camera::{Camera, GeometryError};
use glam::DVec2;

/// How planes are spaced between near and far.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PlaneSpacing {
    /// Equal steps in 1/depth (the paper's choice; equal steps in disparity for light fields).
    #[default]
    InverseDepth,
    /// Equal steps in depth (for comparisons only).
    Linear,
}

/// The depths deepview works with, in scene units (any unit: millimetres to kilometres fit). Outside them
/// the f32 arithmetic of sweeps, renders and depth maps loses the values (depths of 1e-300 gave
/// transparent MPIs and all-zero depth maps without an error).
pub const DEPTH_LIMITS: (f64, f64) = (1e-6, 1e12);

/// The most planes an MPI may have (`auto` chooses at most 256).
pub const MAX_PLANES: usize = 4096;

/// The rules every MPI's plane depths keep, whoever makes or reads them: at least one and at most
/// [`MAX_PLANES`], finite, decreasing (far plane first), within [`DEPTH_LIMITS`], far at most 1e7 times
/// near, and neighbours at least a millionth apart (closer planes are one plane in f32).
pub fn check_plane_depths(depths: &[f64]) -> Result<(), String> {
    if depths.is_empty() {
        return Err("the MPI has zero planes".into());
    }
    if depths.len() > MAX_PLANES {
        return Err(format!(
            "{} planes: deepview makes and reads MPIs of at most {MAX_PLANES}",
            depths.len()
        ));
    }
    if !depths.iter().all(|d| d.is_finite() && *d > 0.0) {
        return Err("depths must be finite and positive".into());
    }
    if depths.windows(2).any(|w| w[1] >= w[0]) {
        return Err("depths must decrease (far plane first)".into());
    }
    // Beyond this ratio the planes' disparities are no numbers a capture has (1e10..1e-10 printed a
    // disparity map of depth 0 everywhere).
    let (far, near) = (depths[0], depths[depths.len() - 1]);
    if far / near > 1e7 {
        return Err(format!(
            "depths {far:e}..{near:e}: far is more than 1e7 times near"
        ));
    }
    let (lo, hi) = DEPTH_LIMITS;
    if near < lo || far > hi {
        return Err(format!(
            "depths {far:e}..{near:e} lie outside {lo:e}..{hi:e}, the depths deepview works with"
        ));
    }
    if let Some(i) = depths.windows(2).position(|w| w[1] > w[0] * (1.0 - 1e-6)) {
        return Err(format!(
            "planes {i} and {} (depths {:e}, {:e}) are less than a millionth apart",
            i + 1,
            depths[i],
            depths[i + 1]
        ));
    }
    Ok(())
}

/// `count` plane depths from `far` (index 0) to `near` (last).
///
/// A single plane sits at the inverse-depth midpoint. Errors on zero planes, non-finite or non-positive
/// bounds, or `near >= far`.
pub fn plane_depths(
    near: f64,
    far: f64,
    count: usize,
    spacing: PlaneSpacing,
) -> Result<Vec<f64>, GeometryError> {
    if count == 0 {
        return Err(GeometryError::Invalid(
            "an MPI needs at least one plane (got 0)".into(),
        ));
    }
    if !near.is_finite() || !far.is_finite() {
        return Err(GeometryError::NonFinite("near/far depth bounds"));
    }
    if near <= 0.0 || far <= near {
        return Err(GeometryError::Invalid(format!(
            "depth bounds must satisfy 0 < near < far (near {near}, far {far})"
        )));
    }
    let depths: Vec<f64> = if count == 1 {
        vec![match spacing {
            PlaneSpacing::InverseDepth => 2.0 / (1.0 / near + 1.0 / far),
            PlaneSpacing::Linear => 0.5 * (near + far),
        }]
    } else {
        let n = (count - 1) as f64;
        (0..count)
            .map(|i| {
                let s = i as f64 / n;
                match spacing {
                    PlaneSpacing::InverseDepth => 1.0 / ((1.0 - s) / far + s / near),
                    PlaneSpacing::Linear => far + s * (near - far),
                }
            })
            .collect()
    };
    // What readers refuse is not made (4,100 planes, or 8 planes between 4 and 4.00002).
    check_plane_depths(&depths).map_err(|e| {
        GeometryError::Invalid(format!("planes between near {near} and far {far}: {e}"))
    })?;
    Ok(depths)
}

/// The plane rule's default: neighbouring planes at most this many pixels of disparity apart (the LLFF
/// sampling rule: a plane per pixel of disparity between the reference and the farthest input view).
pub const AUTO_MAX_SPACING_PX: f64 = 1.0;

/// The plane counts [`auto_plane_count`] may choose (8 keeps a scene with almost no parallax layered; 256 is
/// the paper's largest and bounds the cost of wide baselines).
pub const AUTO_PLANES_MIN: usize = 8;
/// See [`AUTO_PLANES_MIN`].
pub const AUTO_PLANES_MAX: usize = 256;

/// What [`auto_planes`] measured and chose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AutoPlanes {
    /// The plane count: `ceil(max_disparity_px / max_spacing_px) + 1`, clamped to
    /// [`AUTO_PLANES_MIN`]`..=`[`AUTO_PLANES_MAX`].
    pub count: usize,
    /// The largest disparity, in pixels of the view, between a point on the near plane and the point on the far
    /// plane seen at the same reference pixel.
    pub max_disparity_px: f64,
    /// The index (into `views`) of the view with that disparity (0 when there is none).
    pub view: usize,
    /// The spacing the count was computed for.
    pub max_spacing_px: f64,
}

/// The disparity range, in view `view`'s pixels, of the depth range `near..far` seen from `reference`: the
/// largest distance between the projections into `view` of the near-plane point and the far-plane point on
/// the same reference ray, over the reference image's four corners and its centre (rays whose points both
/// fall behind the view are skipped; a ray whose near point is behind the view but far point in front of
/// it sweeps across the whole view: infinite). For two cameras with focal `f` (pixels) and a baseline `b`
/// parallel to the image plane this is exactly `f * b * (1/near - 1/far)`.
pub fn disparity_range(reference: &Camera, view: &Camera, near: f64, far: f64) -> f64 {
    let (w, h) = (reference.width as f64, reference.height as f64);
    let samples = [
        DVec2::new(0.0, 0.0),
        DVec2::new(w, 0.0),
        DVec2::new(0.0, h),
        DVec2::new(w, h),
        DVec2::new(0.5 * w, 0.5 * h),
    ];
    samples
        .iter()
        .filter_map(|&p| {
            let a = view.project(reference.unproject(p, near));
            let b = view.project(reference.unproject(p, far));
            match (a, b) {
                (Some(a), Some(b)) => Some(a.distance(b)),
                (None, Some(_)) => Some(f64::INFINITY),
                _ => None,
            }
        })
        .fold(0.0, f64::max)
}

/// The number of inverse-depth planes between `near` and `far` such that neighbouring planes are at most
/// `max_spacing_px` pixels of disparity apart between `reference` and the view farthest from it in disparity
/// (see [`disparity_range`]), clamped to [`AUTO_PLANES_MIN`]`..=`[`AUTO_PLANES_MAX`]. Planes equally spaced in
/// inverse depth are equally spaced in disparity, so `N` planes over a disparity range `r` are `r / (N - 1)`
/// apart: `N = ceil(r / max_spacing_px) + 1`.
pub fn auto_plane_count(
    reference: &Camera,
    views: &[Camera],
    near: f64,
    far: f64,
    max_spacing_px: f64,
) -> usize {
    auto_planes(reference, views, near, far, max_spacing_px).count
}

/// [`auto_plane_count`] with what it measured.
pub fn auto_planes(
    reference: &Camera,
    views: &[Camera],
    near: f64,
    far: f64,
    max_spacing_px: f64,
) -> AutoPlanes {
    let (view, max_disparity_px) = views
        .iter()
        .map(|v| disparity_range(reference, v, near, far))
        .enumerate()
        .fold(
            (0, 0.0),
            |best, (i, d)| if d > best.1 { (i, d) } else { best },
        );
    let spacing = if max_spacing_px.is_finite() && max_spacing_px > 0.0 {
        max_spacing_px
    } else {
        AUTO_MAX_SPACING_PX
    };
    // A hair of tolerance: a disparity of exactly k spacings (up to rounding) needs k + 1 planes, not k + 2.
    let wanted = (max_disparity_px / spacing - 1e-9).ceil().max(0.0);
    let count = if wanted.is_finite() {
        (wanted as usize).saturating_add(1)
    } else {
        AUTO_PLANES_MAX
    };
    AutoPlanes {
        count: count.clamp(AUTO_PLANES_MIN, AUTO_PLANES_MAX),
        max_disparity_px,
        view,
        max_spacing_px: spacing,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Intrinsics, Pose};
    use glam::{DMat3, DVec3};

    fn camera_at(x: f64, f: f64) -> Camera {
        Camera::new(
            640,
            480,
            Intrinsics::new(f, f, 320.0, 240.0),
            Pose::from_center(DMat3::IDENTITY, DVec3::new(x, 0.0, 0.0)),
        )
    }

    #[test]
    fn disparity_of_a_sideways_baseline_is_analytic() {
        let (f, b, near, far) = (500.0, 0.2, 2.0, 50.0);
        let reference = camera_at(0.0, f);
        let view = camera_at(b, f);
        let expected = f * b * (1.0 / near - 1.0 / far);
        let d = disparity_range(&reference, &view, near, far);
        assert!((d - expected).abs() < 1e-9, "{d} vs {expected}");
        // 48 px of disparity at 1 px spacing: 49 planes; the farthest view decides.
        let views = [camera_at(-0.05, f), view, camera_at(0.1, f)];
        let auto = auto_planes(&reference, &views, near, far, 1.0);
        assert_eq!(auto.view, 1);
        assert!((auto.max_disparity_px - 48.0).abs() < 1e-9);
        assert_eq!(auto.count, 49);
        assert_eq!(auto_plane_count(&reference, &views, near, far, 1.5), 33);
        // Neighbouring planes are at most the spacing apart in disparity.
        let depths = plane_depths(near, far, auto.count, PlaneSpacing::InverseDepth).unwrap();
        let step = f * b * (1.0 / depths[1] - 1.0 / depths[0]);
        assert!(step <= 1.0 + 1e-9, "{step}");
    }

    /// A near plane that passes behind a view (a view in front of the reference, nearer than the
    /// near bound) sweeps across the whole view: the most planes, not the fewest (`psv --near 0.1`
    /// chose 8 planes for 0.0 px).
    #[test]
    fn a_near_plane_behind_a_view_takes_the_most_planes() {
        let reference = camera_at(0.0, 500.0);
        let mut ahead = camera_at(0.1, 500.0);
        ahead.pose = Pose::from_center(DMat3::IDENTITY, DVec3::new(0.1, 0.0, 0.5));
        let d = disparity_range(&reference, &ahead, 0.1, 10.0);
        assert_eq!(d, f64::INFINITY);
        assert_eq!(
            auto_plane_count(&reference, &[ahead], 0.1, 10.0, 1.0),
            AUTO_PLANES_MAX
        );
        // Both points behind it: the view sees none of the ray, which counts for nothing.
        assert_eq!(disparity_range(&reference, &ahead, 0.1, 0.2), 0.0);
    }

    #[test]
    fn auto_plane_count_is_clamped() {
        let reference = camera_at(0.0, 500.0);
        // No parallax at all (the reference itself), and a tiny baseline: the minimum.
        assert_eq!(
            auto_plane_count(&reference, &[reference], 1.0, 10.0, 1.0),
            AUTO_PLANES_MIN
        );
        assert_eq!(
            auto_plane_count(&reference, &[camera_at(0.001, 500.0)], 1.0, 10.0, 1.0),
            AUTO_PLANES_MIN
        );
        // A huge one: the maximum.
        assert_eq!(
            auto_plane_count(&reference, &[camera_at(5.0, 500.0)], 1.0, 10.0, 1.0),
            AUTO_PLANES_MAX
        );
        assert_eq!(
            auto_plane_count(&reference, &[], 1.0, 10.0, 1.0),
            AUTO_PLANES_MIN
        );
    }

    #[test]
    fn inverse_depth_spacing() {
        let d = plane_depths(1.0, 100.0, 5, PlaneSpacing::InverseDepth).unwrap();
        assert_eq!(d.len(), 5);
        assert!((d[0] - 100.0).abs() < 1e-9 && (d[4] - 1.0).abs() < 1e-12);
        let inv: Vec<f64> = d.iter().map(|x| 1.0 / x).collect();
        for w in inv.windows(3) {
            assert!(((w[1] - w[0]) - (w[2] - w[1])).abs() < 1e-12);
        }
        assert!(d.windows(2).all(|w| w[0] > w[1]), "back to front");
    }

    #[test]
    fn bad_bounds() {
        assert!(plane_depths(1.0, 2.0, 0, PlaneSpacing::InverseDepth).is_err());
        assert!(plane_depths(2.0, 1.0, 4, PlaneSpacing::InverseDepth).is_err());
        assert!(plane_depths(0.0, 1.0, 4, PlaneSpacing::InverseDepth).is_err());
        assert!(plane_depths(1.0, f64::INFINITY, 4, PlaneSpacing::InverseDepth).is_err());
        assert_eq!(
            plane_depths(1.0, 3.0, 1, PlaneSpacing::InverseDepth).unwrap(),
            vec![1.5]
        );
    }
}
