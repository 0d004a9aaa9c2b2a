//! MPI plane depths: equally spaced in inverse depth (disparity), stored back to front.

use crate::camera::GeometryError;

/// How planes are spaced between near and far.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PlaneSpacing {
    /// Equal steps in 1/depth (the paper's choice; equal steps in disparity for light fields).
    #[default]
    InverseDepth,
    /// Equal steps in depth (for comparisons only).
    Linear,
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
    if count == 1 {
        return Ok(vec![match spacing {
            PlaneSpacing::InverseDepth => 2.0 / (1.0 / near + 1.0 / far),
            PlaneSpacing::Linear => 0.5 * (near + far),
        }]);
    }
    let n = (count - 1) as f64;
    Ok((0..count)
        .map(|i| {
            let s = i as f64 / n;
            match spacing {
                PlaneSpacing::InverseDepth => 1.0 / ((1.0 - s) / far + s / near),
                PlaneSpacing::Linear => far + s * (near - far),
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

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
