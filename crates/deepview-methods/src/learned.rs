//! The learned model (`deepview`) as an [`MpiMethod`]: tiled inference from the inputs with a bounded
//! memory budget, the plane count by the shared rule ([`choose_planes`]), and the memory checks that refuse
//! a plane count before anything is allocated.

use crate::error::MethodError;
use crate::method::{MadeMpi, MethodEvent, MpiMethod, MpiRequest};
use crate::planes::{Planes, choose_planes, mpi_reference_of};
use deepview_geometry::{Camera, PlaneSpacing, plane_depths};
use deepview_image::ImageF32;
use deepview_net::burn::tensor::Device;
use deepview_net::config::DeepViewConfig;
use deepview_net::infer::{self, InferError, Plan, lower_bound_bytes};
use deepview_net::network::DeepViewModel;
use deepview_net::weights::{self, SHIPPED_NAME};
use std::path::Path;

/// Where the weights of a [`LearnedMethod`] come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum WeightsSource {
    /// The weights compiled into the program ([`weights::load_shipped`]).
    Shipped,
    /// A weights folder or a training checkpoint folder.
    Folder(std::path::PathBuf),
}

impl std::fmt::Display for WeightsSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            WeightsSource::Shipped => f.write_str(SHIPPED_NAME),
            WeightsSource::Folder(p) => write!(f, "{}", p.display()),
        }
    }
}

/// The learned model: weights, the plane rule and the memory budget of its inference.
pub struct LearnedMethod {
    model: DeepViewModel,
    config: DeepViewConfig,
    source: WeightsSource,
    planes: Planes,
    budget: u64,
    /// MPI pixels per input pixel along each axis (`--mpi-scale`, or the weights' `infer_mpi_scale`).
    scale: f64,
}

impl LearnedMethod {
    /// Load the weights in `weights` (a weights folder or a checkpoint folder; `None`: the built-in
    /// ones) onto `device` (the CPU: `Device::flex()`, whose inference runs on the CPU engine when it
    /// fits); `budget` bounds the inference's memory (bytes).
    pub fn load(
        weights: Option<&Path>,
        planes: Planes,
        budget: u64,
        device: &Device,
    ) -> Result<Self, MethodError> {
        let device = device.clone();
        let (source, (model, config)) = match weights {
            None => (WeightsSource::Shipped, weights::load_shipped(&device)?),
            Some(dir) if weights::is_builtin(dir) => {
                (WeightsSource::Shipped, weights::load_shipped(&device)?)
            }
            Some(dir) => {
                if !dir.join(weights::CONFIG_FILE).is_file() && !weights::is_checkpoint(dir) {
                    return Err(MethodError::NoWeights {
                        dir: dir.to_path_buf(),
                    });
                }
                (
                    WeightsSource::Folder(dir.to_path_buf()),
                    weights::load_model(dir, &device)?,
                )
            }
        };
        Ok(Self {
            model,
            scale: config.infer_mpi_scale.unwrap_or(1.0),
            config,
            source,
            planes,
            budget,
        })
    }

    /// Make MPIs with `scale` times the reference camera's pixels along each axis (`--mpi-scale`;
    /// `None`: the weights' own `infer_mpi_scale`, else 1): a finer grid over the same view, sharper
    /// where the inputs' samples fall between MPI pixels, at about `scale^2` times the work. The prior's
    /// aggregation window grows with it (`DeepViewConfig::prior_radius_on`: it covers the same part of
    /// the scene).
    pub fn with_scale(mut self, scale: Option<f64>) -> Self {
        if let Some(scale) = scale {
            self.scale = scale;
        }
        self
    }

    /// The model configuration saved with the weights.
    pub fn config(&self) -> &DeepViewConfig {
        &self.config
    }

    /// Where the weights came from.
    pub fn source(&self) -> &WeightsSource {
        &self.source
    }
}

impl MpiMethod for LearnedMethod {
    fn name(&self) -> &str {
        "deepview"
    }

    fn views(&self) -> Option<usize> {
        self.config.views
    }

    fn weights(&self) -> Option<String> {
        Some(self.source.to_string())
    }

    fn make_mpi(
        &mut self,
        request: &MpiRequest<'_>,
        events: &mut dyn FnMut(MethodEvent<'_>),
    ) -> Result<MadeMpi, MethodError> {
        let near_far = request.near_far;
        let cams: Vec<Camera> = request.inputs.iter().map(|(_, c)| *c).collect();
        weights::check_views(&self.config, cams.len())?;
        let reference = mpi_reference_of(&cams, request.ids, near_far, self.scale)?;
        let views: Vec<(ImageF32, Camera)> = request
            .inputs
            .iter()
            .map(|(img, cam)| (img.to_rgb(), *cam))
            .collect();
        // The prior's aggregation radius on these images (it grows on images larger than the weights
        // were trained on, and with a finer MPI grid: `DeepViewConfig::prior_radius_on`).
        let size = views
            .iter()
            .map(|(img, _)| img.width.max(img.height))
            .max()
            .unwrap_or(0);
        // (0 for a model without the prior, as its config validates to.)
        self.model.prior_radius = self.config.prior_radius_on(size, self.scale);
        let note = (self.model.prior_radius != self.config.prior_radius).then(|| {
            let at = if self.scale != 1.0 {
                format!(" at MPI scale {}", self.scale)
            } else {
                String::new()
            };
            format!(
                "prior window radius {}, grown from {} for {size}-px images{at}",
                self.model.prior_radius, self.config.prior_radius
            )
        });
        let (model, budget) = (&self.model, self.budget);
        precheck_planes(
            model,
            &views,
            &reference,
            self.planes,
            self.config.infer_planes,
            budget,
        )?;
        let mut fits =
            |count: usize| learned_fits(model, &views, &reference, near_far, count, budget);
        let mut minimum =
            |count: usize| learned_minimum(model, &views, &reference, near_far, count);
        let choice = choose_planes(
            self.planes,
            &reference,
            &cams,
            request.ids,
            near_far,
            Some(self.config.infer_planes),
            &mut fits,
            &mut minimum,
        )?;
        events(MethodEvent::Planes(&choice));
        let depths = plane_depths(
            near_far.0,
            near_far.1,
            choice.count,
            PlaneSpacing::InverseDepth,
        )?;
        let plan = check_learned(model, &views, &reference, &depths, budget)?;
        events(MethodEvent::Plan(&plan.describe()));
        events(MethodEvent::Start {
            planes: depths.len(),
            width: reference.width,
            height: reference.height,
        });
        let mpi = infer::run(model, &views, &reference, &depths, &plan, &mut |p| {
            events(MethodEvent::Progress {
                done: p.done,
                total: p.total,
            })
        })?;
        Ok(MadeMpi {
            mpi,
            planes: Some(choice),
            note,
        })
    }
}

/// The smallest memory budget the inference of `depths` plans within: from below, each refusal of the
/// planner names what its net needs, until a plan fits.
pub fn learned_minimum_depths(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
) -> u64 {
    let mut b = lower_bound_bytes(model, views, reference, depths.len()).max(1);
    for _ in 0..64 {
        match infer::plan(model, views, reference, depths, b) {
            Ok(_) => return b,
            Err(InferError::BudgetTooSmall {
                fixed, min_tile, ..
            }) => {
                let need = fixed.saturating_add(min_tile);
                b = if need > b { need } else { b + b / 32 + 1 };
            }
            Err(_) => return b,
        }
    }
    b
}

/// [`learned_minimum_depths`] for `count` planes between `near_far`.
pub fn learned_minimum(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    near_far: (f64, f64),
    count: usize,
) -> u64 {
    match plane_depths(near_far.0, near_far.1, count, PlaneSpacing::InverseDepth) {
        Ok(depths) => learned_minimum_depths(model, views, reference, &depths),
        Err(_) => 0,
    }
}

/// Whether `count` planes fit `budget`: the quick lower bound first, then the planner. Depths that
/// cannot be made count as fitting: making them then fails with the reason (planes a millionth apart),
/// not as over the budget.
pub fn learned_fits(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    near_far: (f64, f64),
    count: usize,
    budget: u64,
) -> bool {
    lower_bound_bytes(model, views, reference, count) <= budget
        && plane_depths(near_far.0, near_far.1, count, PlaneSpacing::InverseDepth)
            .map_or(true, |d| {
                infer::plan(model, views, reference, &d, budget).is_ok()
            })
}

/// Refuse at once an explicit plane count (`Count(n)` or `Weights`) whose quick lower bound is far over
/// the budget (planning so many planes would itself take long).
pub fn precheck_planes(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    rule: Planes,
    weights_planes: usize,
    budget: u64,
) -> Result<(), MethodError> {
    let n = match rule {
        Planes::Count(n) => n,
        Planes::Weights => weights_planes,
        Planes::Auto => return Ok(()),
    };
    if lower_bound_bytes(model, views, reference, n) > budget {
        too_many_planes(model, views, reference, n, budget, &mut |_| 0)?;
    }
    Ok(())
}

/// The plan of the inference of `depths` within `budget` ([`infer::plan`]), or its refusal naming the
/// smallest budget that can hold it.
pub fn check_learned(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    budget: u64,
) -> Result<Plan, MethodError> {
    let lower = lower_bound_bytes(model, views, reference, depths.len());
    if lower <= budget
        && let Ok(plan) = infer::plan(model, views, reference, depths, budget)
    {
        return Ok(plan);
    }
    too_many_planes(model, views, reference, depths.len(), budget, &mut |_| {
        learned_minimum_depths(model, views, reference, depths)
    })
    .map(|never| match never {})
}

/// The refusal of `planes` planes that do not fit `budget`. When even the quick lower bound is over the
/// budget (planning itself would take long), it names the plane count that no longer fits
/// ([`MethodError::StateOverBudget`]); otherwise the smallest budget that does ([`MethodError::OverBudget`]).
fn too_many_planes(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    planes: usize,
    budget: u64,
    minimum: &mut dyn FnMut(usize) -> u64,
) -> Result<std::convert::Infallible, MethodError> {
    let what = format!(
        "inferring {planes} planes of {}x{}",
        reference.width, reference.height
    );
    let lower = lower_bound_bytes(model, views, reference, planes);
    if lower > budget {
        // The most planes whose lower bound fits (the plan may need a little more).
        let (mut lo, mut hi) = (0usize, planes);
        while lo + 1 < hi {
            let mid = lo + (hi - lo) / 2;
            if lower_bound_bytes(model, views, reference, mid) <= budget {
                lo = mid
            } else {
                hi = mid
            }
        }
        return Err(MethodError::StateOverBudget {
            what,
            lower,
            budget,
            fewer_than: lo + 1,
        });
    }
    Err(MethodError::OverBudget {
        what,
        need: minimum(planes).max(budget + 1),
        budget,
    })
}
