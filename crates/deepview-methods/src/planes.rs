//! How many planes an MPI gets: the rule every method shares (`auto` from the cameras' disparity,
//! clamped to the memory budget; the learned model's own count; or an explicit count), the reference
//! camera every method places its MPI in, and the memory estimates of the classical methods.

use crate::error::MethodError;
pub use crate::error::{PlanesHow, human};
use deepview_geometry::{AUTO_MAX_SPACING_PX, AUTO_PLANES_MIN, Camera, auto_planes};
use deepview_mpi::PlanesRule;
use std::str::FromStr;

/// The plane count rule: `auto | weights | N`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Planes {
    /// From the cameras' disparity ([`deepview_geometry::auto_planes`]), at most what the budget allows.
    #[default]
    Auto,
    /// The learned model's `infer_planes` (learned model only).
    Weights,
    /// Exactly this many (at least 1).
    Count(usize),
}

impl FromStr for Planes {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "weights" => Ok(Self::Weights),
            t => match t.parse::<usize>() {
                Ok(0) => Err("an MPI needs at least one plane (got 0)".into()),
                Ok(n) => Ok(Self::Count(n)),
                Err(_) => Err(format!(
                    "{s:?} is not a plane count (expected auto, weights or a number)"
                )),
            },
        }
    }
}

impl std::fmt::Display for Planes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Auto => f.write_str("auto"),
            Self::Weights => f.write_str("weights"),
            Self::Count(n) => write!(f, "{n}"),
        }
    }
}

/// A chosen plane count and how it was chosen (for `mpi.json` and the log).
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneChoice {
    pub count: usize,
    pub rule: PlanesRule,
    /// One line saying how the count was chosen (`planes: auto -> 33 (...)`).
    pub message: String,
}

/// The reference camera every method places its MPI in ([`deepview_geometry::mpi_reference`], which
/// training's plane rule uses too), with `scale` times its pixels along each axis (`--mpi-scale`; 1: the
/// inputs' pixel pitch).
pub fn mpi_reference(
    cameras: &[Camera],
    near_far: (f64, f64),
    scale: f64,
) -> Result<Camera, MethodError> {
    Ok(deepview_geometry::mpi_reference_scaled(
        cameras, near_far, scale,
    )?)
}

/// [`mpi_reference`] of the input views `ids` (dataset indices, in the cameras' order): an error
/// about two of them names them by their view numbers, not their places in the list.
pub fn mpi_reference_of(
    cameras: &[Camera],
    ids: &[usize],
    near_far: (f64, f64),
    scale: f64,
) -> Result<Camera, MethodError> {
    deepview_geometry::mpi_reference_scaled(cameras, near_far, scale).map_err(|e| {
        MethodError::Geometry(match e {
            deepview_geometry::GeometryError::FacingApart {
                first,
                second,
                degrees,
            } if ids.len() == cameras.len() => deepview_geometry::GeometryError::FacingApart {
                first: ids[first],
                second: ids[second],
                degrees,
            },
            e => e,
        })
    })
}

/// Resolve `rule` for an MPI in `reference` from input cameras `views` (dataset indices `view_ids`, for the
/// record; may be empty). `weights`: the learned model's count, when there is one. `fits(n)`: whether `n`
/// planes fit the memory budget; `auto` takes the largest count up to the rule's that fits (at least
/// [`AUTO_PLANES_MIN`]). An explicit count is used as given. `minimum(n)`: the bytes `n` planes need (for
/// the refusal).
pub fn choose_planes(
    rule: Planes,
    reference: &Camera,
    views: &[Camera],
    view_ids: &[usize],
    near_far: (f64, f64),
    weights: Option<usize>,
    fits: &mut dyn FnMut(usize) -> bool,
    minimum: &mut dyn FnMut(usize) -> u64,
) -> Result<PlaneChoice, MethodError> {
    let mut refuse = |planes: usize, how: PlanesHow| MethodError::PlanesOverBudget {
        planes,
        how,
        need: minimum(planes),
    };
    let simple = |count: usize, rule: &str, message: String| PlaneChoice {
        count,
        rule: PlanesRule {
            rule: rule.into(),
            max_disparity_px: None,
            max_spacing_px: None,
            view: None,
            limited_by: None,
        },
        message,
    };
    match rule {
        Planes::Count(0) => Err(MethodError::NoPlanes),
        Planes::Count(n) if !fits(n) => Err(refuse(n, PlanesHow::Explicit)),
        Planes::Count(n) => Ok(simple(n, "explicit", format!("planes: {n} (explicit)"))),
        Planes::Weights => match weights {
            Some(n) if !fits(n) => Err(refuse(n, PlanesHow::Weights)),
            Some(n) => Ok(simple(
                n,
                "weights",
                format!("planes: weights -> {n} (the weights' inference plane count)"),
            )),
            None => Err(MethodError::PlanesNeedWeights),
        },
        Planes::Auto => {
            let auto = auto_planes(
                reference,
                views,
                near_far.0,
                near_far.1,
                AUTO_MAX_SPACING_PX,
            );
            let view = match view_ids.get(auto.view) {
                Some(i) => format!("view {i}"),
                None => format!("input {}", auto.view),
            };
            let mut count = auto.count;
            let mut limited_by = None;
            let least = AUTO_PLANES_MIN.min(count);
            if !fits(least) {
                return Err(refuse(least, PlanesHow::AutoMinimum));
            }
            if !fits(count) {
                // The largest count in [MIN, count) that fits (fitting is monotone in the count).
                let (mut lo, mut hi) = (AUTO_PLANES_MIN, count);
                while lo + 1 < hi {
                    let mid = (lo + hi) / 2;
                    if fits(mid) { lo = mid } else { hi = mid }
                }
                count = lo.min(auto.count);
                limited_by = Some("memory budget".to_string());
            }
            let mut message = format!(
                "planes: auto -> {count} (max disparity {:.1} px between reference and {view}",
                auto.max_disparity_px
            );
            if limited_by.is_some() {
                message += &format!(
                    "; the rule's {} planes do not fit the memory budget",
                    auto.count
                );
            }
            message.push(')');
            Ok(PlaneChoice {
                count,
                rule: PlanesRule {
                    rule: "auto".into(),
                    max_disparity_px: Some((auto.max_disparity_px * 1000.0).round() / 1000.0),
                    max_spacing_px: Some(auto.max_spacing_px),
                    view: view_ids.get(auto.view).copied(),
                    limited_by,
                },
                message,
            })
        }
    }
}

/// Refuse work estimated at `need` bytes that does not fit `budget`, before anything is allocated.
pub fn check_memory(what: &str, need: u64, budget: u64) -> Result<(), MethodError> {
    if need > budget {
        return Err(MethodError::OverBudget {
            what: what.into(),
            need,
            budget,
        });
    }
    Ok(())
}

/// A simple estimate for the classical methods: whether `fixed + count * per_plane` bytes fit `budget`.
pub fn fits_estimate(fixed: u64, per_plane: u64, budget: u64) -> impl FnMut(usize) -> bool {
    move |n| fixed.saturating_add(per_plane.saturating_mul(n as u64)) <= budget
}

/// Bytes of an MPI of `planes` planes of `w x h` read as f32 premultiplied texels (layer decoding
/// included), `u8`: as 8-bit texels.
pub fn mpi_bytes(w: u32, h: u32, planes: usize, u8: bool) -> u64 {
    let px = w as u64 * h as u64;
    let threads = rayon::current_num_threads().max(1) as u64;
    let texel = if u8 { 4 } else { 16 };
    px.saturating_mul(planes as u64)
        .saturating_mul(texel)
        .saturating_add(px.saturating_mul(20).saturating_mul(threads))
}

/// Bytes of a `psv-mean` MPI in `reference` with `aggregation`: the fixed part (`inputs` RGB f32
/// images; per thread the running sums, the sweep of the view at hand, with a window its f64 sums, with
/// the leave-one-out term every view's sweep of the plane, with a census term the views' grey levels,
/// bit strings and the cost) and the part per plane (f32 RGBA texels, agreement logits, alphas, and with
/// smoothing the paths' sums).
pub fn psv_mean_bytes(
    reference: &Camera,
    inputs: &[Camera],
    aggregation: deepview_mpi::agreement::Aggregation,
) -> (u64, u64) {
    let px = reference.width as u64 * reference.height as u64;
    let input_px: u64 = inputs
        .iter()
        .map(|c| c.width as u64 * c.height as u64)
        .sum();
    let k = inputs.len() as u64;
    let threads = rayon::current_num_threads() as u64;
    let window = if aggregation.is_active() { 32 } else { 0 };
    let loo = if aggregation.leave_one_out.is_some() {
        16 * k
    } else {
        0
    };
    let census = if aggregation.census.is_some() {
        20 * k + 4
    } else {
        0
    };
    let smoothing = if aggregation.smoothing.is_some() {
        4
    } else {
        0
    };
    (
        12 * input_px + (72 + window + loo + census) * px * threads,
        (24 + smoothing) * px,
    )
}

/// Bytes of the `optimize` baseline: the fixed part of [`psv_mean_bytes`], and per plane Adam's logits,
/// moments and gradients (16 f32 per texel) at the working resolution (`max_width`) plus the full-size
/// result.
pub fn optimize_bytes(reference: &Camera, inputs: &[Camera], max_width: u32) -> (u64, u64) {
    let f = reference.width.div_ceil(max_width.max(1)).max(1) as u64;
    let px = reference.width as u64 * reference.height as u64;
    let small = px / (f * f);
    let (fixed, _) = psv_mean_bytes(
        reference,
        inputs,
        deepview_mpi::agreement::Aggregation::NONE,
    );
    (fixed, 64 * small + 16 * px)
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::{DMat3, DVec3, Intrinsics, Pose};

    #[test]
    fn planes_parse() {
        assert_eq!("auto".parse::<Planes>().unwrap(), Planes::Auto);
        assert_eq!("Weights".parse::<Planes>().unwrap(), Planes::Weights);
        assert_eq!("48".parse::<Planes>().unwrap(), Planes::Count(48));
        assert!("many".parse::<Planes>().is_err());
        assert!("0".parse::<Planes>().unwrap_err().contains("got 0"));
    }

    fn cam(x: f64) -> Camera {
        Camera::new(
            640,
            480,
            Intrinsics::new(500.0, 500.0, 320.0, 240.0),
            Pose::from_center(DMat3::IDENTITY, DVec3::new(x, 0.0, 0.0)),
        )
    }

    #[test]
    fn auto_planes_follow_disparity_and_memory() {
        // 500 * 0.2 * (1/2 - 1/50) = 48 px: 49 planes.
        let reference = cam(0.0);
        let views = [cam(-0.1), cam(0.2)];
        let choose = |rule, weights, fit: usize| {
            choose_planes(
                rule,
                &reference,
                &views,
                &[3, 7],
                (2.0, 50.0),
                weights,
                &mut |n| n <= fit,
                &mut |n| n as u64 * (1 << 20),
            )
        };
        let c = choose(Planes::Auto, Some(32), usize::MAX).unwrap();
        assert_eq!(c.count, 49);
        assert_eq!(c.rule.view, Some(7));
        assert_eq!(c.rule.rule, "auto");
        assert!(c.message.contains("auto -> 49") && c.message.contains("48.0 px"));
        assert!(c.message.contains("view 7"), "{}", c.message);
        // A budget for 20 planes.
        let c = choose(Planes::Auto, None, 20).unwrap();
        assert_eq!(
            (c.count, c.rule.limited_by.as_deref()),
            (20, Some("memory budget"))
        );
        assert!(!c.message.contains("--"), "{}", c.message);
        // Explicit counts and the weights' count are used as given when they fit, refused with the
        // bytes they need when they do not.
        assert_eq!(choose(Planes::Count(5), Some(32), 100).unwrap().count, 5);
        assert_eq!(choose(Planes::Weights, Some(32), 100).unwrap().count, 32);
        assert!(matches!(
            choose(Planes::Count(0), None, 100),
            Err(MethodError::NoPlanes)
        ));
        let e = choose(Planes::Count(100000), None, 100).unwrap_err();
        assert!(
            matches!(e, MethodError::PlanesOverBudget { planes: 100000, need, .. } if need == 100000 << 20),
            "{e}"
        );
        let e = choose(Planes::Auto, None, 2).unwrap_err();
        assert!(
            matches!(
                e,
                MethodError::PlanesOverBudget {
                    planes: 8,
                    how: PlanesHow::AutoMinimum,
                    ..
                }
            ),
            "{e}"
        );
        assert!(!e.to_string().contains("--"), "{e}");
        assert!(matches!(
            choose(Planes::Weights, None, 100),
            Err(MethodError::PlanesNeedWeights)
        ));
    }
}
