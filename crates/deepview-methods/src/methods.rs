//! The methods by name, their settings, and the classical ones (`nearest`, `psv-mean`, `optimize`) as
//! [`MpiMethod`]s whose plane count follows the same rule as the learned model's.

use crate::baselines::{PsvMeanOptions, agreement_mpi, nearest_view_mpi};
use crate::check::check_inputs;
use crate::error::MethodError;
use crate::learned::LearnedMethod;
use crate::method::{MadeMpi, MethodEvent, MpiMethod, MpiRequest};
use crate::optimize::{OptimizeOptions, optimize_mpi_reporting};
use crate::planes::{
    PlaneChoice, Planes, check_memory, choose_planes, fits_estimate, mpi_bytes, mpi_reference,
    mpi_reference_of, optimize_bytes, psv_mean_bytes,
};
use deepview_geometry::{Camera, DVec3};
use std::path::PathBuf;
use std::str::FromStr;

/// The ways of making an MPI.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodKind {
    /// The learned network (weights: --weights, default the built-in ones).
    Deepview,
    /// Plane sweep volume mean colour per plane, alpha from cross-view colour agreement.
    PsvMean,
    /// One opaque plane holding the input view nearest the target (without a target: nearest the
    /// inputs' centroid) at the inverse-depth midpoint of near/far.
    Nearest,
    /// An MPI fitted to the inputs by classical gradient descent (Adam; no learning).
    Optimize,
}

impl MethodKind {
    pub const ALL: [MethodKind; 4] = [
        MethodKind::Deepview,
        MethodKind::PsvMean,
        MethodKind::Nearest,
        MethodKind::Optimize,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            MethodKind::Deepview => "deepview",
            MethodKind::PsvMean => "psv-mean",
            MethodKind::Nearest => "nearest",
            MethodKind::Optimize => "optimize",
        }
    }
}

impl std::fmt::Display for MethodKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for MethodKind {
    type Err = MethodError;
    fn from_str(s: &str) -> Result<Self, MethodError> {
        match s.trim().to_ascii_lowercase().replace('_', "-").as_str() {
            "deepview" => Ok(MethodKind::Deepview),
            "nearest" => Ok(MethodKind::Nearest),
            "psv-mean" => Ok(MethodKind::PsvMean),
            "optimize" => Ok(MethodKind::Optimize),
            _ => Err(MethodError::UnknownMethod(s.into())),
        }
    }
}

/// The help text of `--planes`.
pub const PLANES_HELP: &str = "Number of MPI planes, equally spaced in inverse depth between near and far: \
    `auto` (default) chooses them from the cameras so that neighbouring planes are at most 1 px of disparity \
    apart between the reference camera and the input view farthest from it (clamped to 8..=256 and to what \
    --max-memory allows); `weights` takes the learned model's own inference count; a number is used as given.";

fn positive(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(_) => Err(format!("{s:?} is not a positive whole number")),
    }
}

fn aggregation_radius(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(r) if r <= 64 => Ok(r),
        Ok(r) => Err(format!("{r} is above the largest radius, 64")),
        Err(_) => Err(format!("{s:?} is not a whole number of pixels")),
    }
}

fn unit_f64(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!("{s:?} is not a number from 0 to 1")),
    }
}

/// `P1,P2` semi-global matching penalties (finite, `0 <= P1 <= P2`).
pub fn parse_smoothing(s: &str) -> Result<deepview_mpi::agreement::Smoothing, String> {
    s.parse()
}

/// `WEIGHT[,RADIUS]`: the census term of the matching cost.
pub fn parse_census(s: &str) -> Result<deepview_mpi::agreement::Census, String> {
    s.parse()
}

/// A leave-one-out weight in `(0, 1]`.
pub fn parse_leave_one_out(s: &str) -> Result<f32, String> {
    deepview_mpi::agreement::parse_leave_one_out(s)
}

fn positive_f64(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(_) => Err(format!("{s:?} must be a finite number above 0")),
        Err(_) => Err(format!("{s:?} is not a number")),
    }
}

/// `--mpi-scale`: a number in 1..=4 (a coarser grid than the inputs' would alias: `--downscale` the
/// inputs instead).
pub fn parse_mpi_scale(s: &str) -> Result<f64, String> {
    let v = positive_f64(s)?;
    if deepview_net::config::MPI_SCALES.contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{s:?} is outside 1..4 (MPI pixels per input pixel along each axis; for a coarser MPI, \
             --downscale the inputs)"
        ))
    }
}

/// The settings of every method, as the commands that make or score MPIs take them.
#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct MethodOptions {
    #[arg(long, default_value = "auto", help = PLANES_HELP)]
    pub planes: Planes,
    /// Trained weights of the learned method (deepview): a weights folder (config.json +
    /// model.safetensors), a training checkpoint folder (runs/<name>/checkpoints/step-N), or `builtin`:
    /// the weights built into the program (the repository's weights/cpu; the default).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Device of the learned model: cpu (the CPU engine, or tiles within --max-memory), wgpu, wgpu:N,
    /// wgpu:cpu, cuda, cuda:N (GPU devices in builds with `--features wgpu` or `--features cuda`).
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Colour variance treated as disagreement, s in exp(-variance / s) (psv-mean).
    #[arg(long, default_value_t = PsvMeanOptions::default().temperature, value_parser = positive_f64)]
    pub temperature: f64,
    /// Cost aggregation radius in MPI pixels (psv-mean): each plane's colour variance is averaged over
    /// the (2r+1) x (2r+1) window around each pixel before the softmax over planes; 0 (the default) is
    /// the per-pixel baseline; at most 64. The learned model's prior takes its own radius from its
    /// weights.
    #[arg(long, default_value_t = 0, value_parser = aggregation_radius)]
    pub aggregate: usize,
    /// The weight of the window's mean in the aggregated variance, the rest being the pixel's own
    /// (psv-mean with --aggregate; 0..1, default 1).
    #[arg(long, default_value_t = 1.0, value_parser = unit_f64)]
    pub aggregate_weight: f64,
    /// Semi-global matching of the agreement over the planes after the window, as penalties `P1,P2`
    /// (psv-mean; in units of the agreement's logits, e.g. `2,64`: one plane's step costs 2, a larger
    /// jump 64). Off by default.
    #[arg(long, value_name = "P1,P2", value_parser = parse_smoothing)]
    pub smoothing: Option<deepview_mpi::agreement::Smoothing>,
    /// A census term in the matching cost, as `WEIGHT[,RADIUS]` (psv-mean; e.g. `0.03`): each view's
    /// plane sweep is census-transformed over the (2r+1) x (2r+1) window (radius 2 by default), and
    /// WEIGHT times the fraction of census bits that differ between views is added to the colour
    /// variance, a cost that ignores differences in exposure. Off by default.
    #[arg(long, value_name = "WEIGHT[,RADIUS]", value_parser = parse_census)]
    pub census: Option<deepview_mpi::agreement::Census>,
    /// Occlusion-robust variance, as the weight B of its leave-one-out part (psv-mean; 0 < B <= 1, e.g.
    /// `0.75`): where three or more views see a plane point, its colour variance becomes (1 - B) times
    /// itself plus B times the least variance of the samples left when one view is left out, so one
    /// view that sees an occluder there does not hide the others' agreement. Off by default.
    #[arg(long, value_name = "B", value_parser = parse_leave_one_out)]
    pub leave_one_out: Option<f32>,
    /// The sample variance (psv-mean): the colour variance of a point n >= 2 views see is scaled by
    /// n / (n - 1), so that a plane where two views happen to agree does not beat one more views see for
    /// the population variance's bias alone. Off by default.
    #[arg(long)]
    pub sample_variance: bool,
    /// MPI pixels per input pixel along each axis (deepview and psv-mean; 1..4): e.g. `1.5` makes the
    /// MPI on a grid 1.5 times finer over the same view, so that the plane sweep's samples of the inputs
    /// blur less. About `S^2` times the time and the MPI's memory (BENCHMARKS.md, "A finer MPI grid").
    /// Default: the learned model's own (its weights' `infer_mpi_scale`: 1.25 for the built-in
    /// weights), 1 for psv-mean. The learned prior's window grows with the grid; psv-mean's --aggregate
    /// radius, the census radius and the smoothing penalties are in MPI pixels.
    #[arg(long, value_name = "S", value_parser = parse_mpi_scale)]
    pub mpi_scale: Option<f64>,
    /// Adam steps (optimize).
    #[arg(long, default_value_t = 300, value_parser = positive)]
    pub steps: usize,
    /// Adam learning rate on the RGBA logits (optimize).
    #[arg(long, default_value_t = 0.1, value_parser = positive_f64)]
    pub lr: f64,
    /// Working width of the optimisation: inputs are box-downscaled by an integer factor to at most this
    /// width (optimize; at least 16).
    #[arg(long, default_value_t = 160, value_parser = clap::value_parser!(u32).range(16..))]
    pub max_width: u32,
    /// The options given on the command line, by their field names (`"aggregate_weight"`), where the
    /// caller knows them: then an option of another method is refused even at its default value.
    /// `None`: an option counts as given where it differs from its default.
    #[arg(skip)]
    pub given: Option<Vec<String>>,
}

impl Default for MethodOptions {
    fn default() -> Self {
        let o = OptimizeOptions::default();
        Self {
            planes: Planes::Auto,
            weights: None,
            device: "cpu".into(),
            temperature: PsvMeanOptions::default().temperature,
            aggregate: 0,
            aggregate_weight: 1.0,
            smoothing: None,
            census: None,
            leave_one_out: None,
            sample_variance: false,
            mpi_scale: None,
            steps: o.steps,
            lr: o.learning_rate,
            max_width: o.max_width,
            given: None,
        }
    }
}

/// The method `kind` with `options` (the learned model on `options.device`); `budget` bounds its memory
/// (bytes).
pub fn make_method(
    kind: MethodKind,
    options: &MethodOptions,
    budget: u64,
) -> Result<Box<dyn MpiMethod>, MethodError> {
    let scale_given = match &options.given {
        Some(g) => g.iter().any(|id| id == "mpi_scale"),
        None => options.mpi_scale.is_some_and(|s| s != 1.0),
    };
    if let Some(scale) = options.mpi_scale
        && scale_given
        && !matches!(kind, MethodKind::Deepview | MethodKind::PsvMean)
    {
        return Err(MethodError::Method {
            method: kind.name().into(),
            msg: format!(
                "--mpi-scale {scale} applies to deepview and psv-mean only ({})",
                if kind == MethodKind::Nearest {
                    "nearest's MPI is the nearest input's own image"
                } else {
                    "optimize's grid follows --max-width"
                }
            ),
        });
    }
    // Options of one method given to another are refused, not ignored: those the command line gave
    // where the caller says which (`options.given`), else those that differ from their defaults.
    let d = MethodOptions::default();
    let given = |flag: &'static str, differs: bool| {
        let named = match &options.given {
            Some(g) => g.iter().any(|id| *id == flag[2..].replace('-', "_")),
            None => differs,
        };
        named.then_some(flag)
    };
    let psv_only: Vec<&str> = [
        given("--temperature", options.temperature != d.temperature),
        given("--aggregate", options.aggregate != d.aggregate),
        given(
            "--aggregate-weight",
            options.aggregate_weight != d.aggregate_weight,
        ),
        given("--smoothing", options.smoothing.is_some()),
        given("--census", options.census.is_some()),
        given("--leave-one-out", options.leave_one_out.is_some()),
        given("--sample-variance", options.sample_variance),
    ]
    .into_iter()
    .flatten()
    .collect();
    let optimize_only: Vec<&str> = [
        given("--steps", options.steps != d.steps),
        given("--lr", options.lr != d.lr),
        given("--max-width", options.max_width != d.max_width),
    ]
    .into_iter()
    .flatten()
    .collect();
    for (given, owner, of) in [
        (psv_only, MethodKind::PsvMean, "psv-mean's agreement"),
        (
            optimize_only,
            MethodKind::Optimize,
            "optimize's gradient descent",
        ),
    ] {
        if kind != owner && !given.is_empty() {
            return Err(MethodError::Method {
                method: kind.name().into(),
                msg: format!(
                    "{} shape{} {of} only (--method {}); leave {} out",
                    given.join(", "),
                    if given.len() == 1 { "s" } else { "" },
                    owner.name(),
                    if given.len() == 1 { "it" } else { "them" }
                ),
            });
        }
    }
    if kind == MethodKind::Nearest && !matches!(options.planes, Planes::Auto | Planes::Count(1)) {
        return Err(MethodError::Method {
            method: kind.name().into(),
            msg: "nearest's MPI is one plane (the nearest input's own image): --planes does not \
                  apply; leave it out"
                .into(),
        });
    }
    // The device is named the same way for every method (a typo is an error for all), and only the
    // learned method runs on one.
    let device = deepview_net::device::parse_device(&options.device)?;
    // (Parsed: every CPU spelling, `cpu:0`, `cpu:local`, `flex`, names the CPU.)
    let on_cpu = matches!(options.device.split(':').next(), Some("cpu" | "flex"));
    if kind != MethodKind::Deepview && !on_cpu {
        return Err(MethodError::Method {
            method: kind.name().into(),
            msg: format!(
                "--device {} applies to the learned method (deepview) only; {} runs on the CPU",
                options.device,
                kind.name()
            ),
        });
    }
    Ok(match kind {
        MethodKind::Deepview => Box::new(
            LearnedMethod::load(options.weights.as_deref(), options.planes, budget, &device)?
                .with_scale(options.mpi_scale),
        ),
        _ => Box::new(Classical {
            kind,
            psv: PsvMeanOptions {
                temperature: options.temperature,
                aggregation: deepview_mpi::agreement::Aggregation {
                    radius: options.aggregate,
                    weight: options.aggregate_weight,
                    smoothing: options.smoothing,
                    census: options.census,
                    leave_one_out: options.leave_one_out,
                    sample_variance: options.sample_variance,
                },
                scale: options.mpi_scale.unwrap_or(1.0),
                ..Default::default()
            },
            optimize: OptimizeOptions {
                planes: 0,
                steps: options.steps,
                learning_rate: options.lr,
                max_width: options.max_width,
            },
            planes: options.planes,
            budget,
        }),
    })
}

/// A classical method whose plane count follows `planes` per input set, by the same rule as the learned
/// model (the memory clamp from a simple bytes estimate).
#[derive(Clone, Copy, Debug)]
pub struct Classical {
    pub kind: MethodKind,
    pub psv: PsvMeanOptions,
    /// `planes` is replaced by the chosen count.
    pub optimize: OptimizeOptions,
    pub planes: Planes,
    pub budget: u64,
}

/// The plane count of `method` (`psv-mean`, whose aggregation radius counts, or `optimize`, whose working
/// width does) within its budget for input cameras `cams` (dataset indices `ids`, may be empty).
pub fn classical_planes(
    method: &Classical,
    cams: &[Camera],
    ids: &[usize],
    near_far: (f64, f64),
) -> Result<PlaneChoice, MethodError> {
    let (planes, budget) = (method.planes, method.budget);
    let scale = match method.kind {
        MethodKind::PsvMean => method.psv.scale,
        _ => 1.0,
    };
    let reference = mpi_reference_of(cams, ids, near_far, scale)?;
    let (fixed, per_plane) = match method.kind {
        MethodKind::Optimize => optimize_bytes(&reference, cams, method.optimize.max_width),
        _ => psv_mean_bytes(&reference, cams, method.psv.aggregation),
    };
    let mut fits = fits_estimate(fixed, per_plane, budget);
    let mut minimum = |n: usize| fixed.saturating_add(per_plane.saturating_mul(n as u64));
    choose_planes(
        planes,
        &reference,
        cams,
        ids,
        near_far,
        None,
        &mut fits,
        &mut minimum,
    )
}

/// The index of the input nearest `toward`, or (without) the inputs' centroid; ties: the first.
fn nearest_input(cams: &[Camera], toward: Option<&Camera>) -> usize {
    let anchor = match toward {
        Some(t) => t.center(),
        None => cams.iter().fold(DVec3::ZERO, |a, c| a + c.center()) / cams.len().max(1) as f64,
    };
    (0..cams.len())
        .min_by(|&a, &b| {
            cams[a]
                .center()
                .distance(anchor)
                .total_cmp(&cams[b].center().distance(anchor))
        })
        .unwrap_or(0)
}

impl MpiMethod for Classical {
    fn name(&self) -> &str {
        self.kind.name()
    }

    fn uses_target(&self) -> bool {
        self.kind == MethodKind::Nearest
    }

    fn make_mpi(
        &mut self,
        request: &MpiRequest<'_>,
        events: &mut dyn FnMut(MethodEvent<'_>),
    ) -> Result<MadeMpi, MethodError> {
        let (inputs, near_far) = (request.inputs, request.near_far);
        check_inputs(self.kind.name(), inputs, near_far)?;
        let cams: Vec<Camera> = inputs.iter().map(|(_, c)| *c).collect();
        if self.kind == MethodKind::Nearest {
            let k = nearest_input(&cams, request.toward);
            let c = &cams[k];
            check_memory(
                "the nearest-view MPI",
                mpi_bytes(c.width, c.height, 1, false).saturating_mul(2),
                self.budget,
            )?;
            events(MethodEvent::Start {
                planes: 1,
                width: c.width,
                height: c.height,
            });
            let mpi = nearest_view_mpi(&inputs[k], near_far)?;
            let note = match request.ids.get(k) {
                Some(i) => format!("view {i}"),
                None => format!("input {k}"),
            };
            return Ok(MadeMpi {
                mpi,
                planes: None,
                note: Some(note),
            });
        }
        let choice = classical_planes(self, &cams, request.ids, near_far)?;
        events(MethodEvent::Planes(&choice));
        let (mpi, note) = if self.kind == MethodKind::Optimize {
            let options = OptimizeOptions {
                planes: choice.count,
                ..self.optimize
            };
            let (mpi, history) = optimize_mpi_reporting(
                inputs,
                near_far,
                &options,
                &mut |reference, done, total| {
                    if done == 0 {
                        events(MethodEvent::Start {
                            planes: choice.count,
                            width: reference.width,
                            height: reference.height,
                        });
                    }
                    events(MethodEvent::Progress { done, total });
                },
            )?;
            let note = format!(
                "loss {:.5} -> {:.5}",
                history.first().copied().unwrap_or(f64::NAN),
                history.last().copied().unwrap_or(f64::NAN)
            );
            (mpi, Some(note))
        } else {
            let options = PsvMeanOptions {
                planes: choice.count,
                ..self.psv
            };
            let reference = mpi_reference(&cams, near_far, options.scale)?;
            events(MethodEvent::Start {
                planes: choice.count,
                width: reference.width,
                height: reference.height,
            });
            (agreement_mpi(inputs, near_far, &options)?, None)
        };
        Ok(MadeMpi {
            mpi,
            planes: Some(choice),
            note,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leave_one_out_weights_parse_in_their_range() {
        assert_eq!(parse_leave_one_out("0.75"), Ok(0.75));
        assert_eq!(parse_leave_one_out(" 1 "), Ok(1.0));
        for bad in ["0", "-0.1", "1.01", "nan", "inf", "x", ""] {
            assert!(parse_leave_one_out(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn mpi_scales_parse_in_their_range() {
        for (s, v) in [("1", 1.0), ("1.5", 1.5), (" 4 ", 4.0)] {
            assert_eq!(parse_mpi_scale(s), Ok(v), "{s:?}");
        }
        for bad in ["0.99", "0.25", "0", "-1", "4.01", "nan", "inf", "x", ""] {
            assert!(parse_mpi_scale(bad).is_err(), "{bad:?}");
        }
    }
}
