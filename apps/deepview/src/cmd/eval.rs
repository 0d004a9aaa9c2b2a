//! `deepview eval`: score a method (a baseline or the learned model) on a scene under a protocol.

use super::args::{self, PlaneChoice, PlanesArg};
use anyhow::Context;
use deepview_eval::{
    Baseline, EvalOptions, InputRule, Method, OptimizeOptions, Protocol, PsvMeanOptions,
    TargetRule, baseline_method, evaluate,
};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview eval --data ../shared/data/llff/fern --images images_8 --method psv-mean --out results.json\n  \
    deepview eval --data ../shared/data/llff/fern --images images_8 --method deepview --inputs nearest:4 --targets every:8\n  \
    deepview eval --data scene_000 --near 0.7 --far 100 --protocol small_quad --method nearest\n  \
    deepview eval --data ../shared/data/hci/antinous --method optimize --protocol light-field --targets 40 \
    --save-renders renders/")]
pub struct Args {
    /// Dataset folder (LLFF, COLMAP, Spaces, light-field grid).
    #[arg(long, value_name = "DIR")]
    pub data: PathBuf,
    #[command(flatten)]
    pub scene: deepview_data::SceneArgs,
    /// nearest | psv-mean | optimize | deepview.
    #[arg(long, default_value = "psv-mean")]
    pub method: String,
    /// small_quad | medium_quad | large_quad | dense (Spaces), posed (LLFF, COLMAP), light-field, or auto.
    #[arg(long, default_value = "auto")]
    pub protocol: String,
    /// Targets of posed / light-field protocols: every:N (index % N == 0) or a list like 3,11.
    #[arg(long)]
    pub targets: Option<String>,
    /// Inputs of the posed protocol: nearest:K (K nearest non-target views by camera centre) or a list.
    #[arg(long)]
    pub inputs: Option<String>,
    /// Crop this many pixels from every side instead of the protocol's crop (scaled with --downscale).
    #[arg(long)]
    pub crop: Option<u32>,
    /// Score float predictions as they are instead of rounding to 8 bits like saved PNGs.
    #[arg(long)]
    pub no_quantize: bool,
    /// MPI planes of psv-mean, optimize and deepview (the same rule for every method; per input set for
    /// `auto`). See `deepview infer --help`.
    #[arg(long, default_value = "auto", help = args::PLANES_HELP)]
    pub planes: PlanesArg,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
    /// Colour variance treated as disagreement, s in exp(-variance / s) (psv-mean).
    #[arg(long, default_value_t = PsvMeanOptions::default().temperature)]
    pub temperature: f64,
    /// Adam steps (optimize).
    #[arg(long, default_value_t = 300, value_parser = args::parse_positive)]
    pub steps: usize,
    /// Adam learning rate on the RGBA logits (optimize).
    #[arg(long, default_value_t = 0.1, value_parser = args::parse_positive_f64)]
    pub lr: f64,
    /// Working width of the optimisation (optimize).
    #[arg(long, default_value_t = 160, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_width: u32,
    /// Trained weights for --method deepview: a weights folder or a training checkpoint folder
    /// (default: the shipped weights/cpu).
    #[arg(long, visible_alias = "checkpoint")]
    pub weights: Option<PathBuf>,
    /// Write the report here (JSON: method, checkpoint, protocol, results, views).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write prediction | ground truth | error images here.
    #[arg(long)]
    pub save_renders: Option<PathBuf>,
}

fn method_error(method: &str, e: &dyn std::fmt::Display) -> deepview_eval::EvalError {
    deepview_eval::EvalError::Method {
        method: method.into(),
        msg: e.to_string(),
    }
}

/// Print `choice`'s line unless it is the one printed last.
fn announce(last: &mut Option<String>, choice: &PlaneChoice) {
    if last.as_deref() != Some(choice.message.as_str()) {
        eprintln!("{}", choice.message);
        *last = Some(choice.message.clone());
    }
}

/// The learned model behind `--method deepview`: tiled inference from the inputs, then rendering the
/// MPI into the target. Weights from `--weights`, or the shipped `weights/cpu`.
pub struct LearnedMethod {
    model: deepview_net::network::DeepViewModel,
    config: deepview_net::config::DeepViewConfig,
    planes: PlanesArg,
    budget: u64,
    last_message: Option<String>,
    /// The last MPI, the inputs it came from and its plane choice: targets sharing inputs reuse it.
    cache: Option<CachedMpi>,
}

/// An inferred MPI with the input cameras and bounds it came from, and its plane choice.
type CachedMpi = (
    Vec<deepview_geometry::Camera>,
    (f64, f64),
    deepview_mpi::Mpi,
    PlaneChoice,
);

impl LearnedMethod {
    /// Load weights (config.json + model.safetensors) from `weights`; `budget` bounds inference memory.
    pub fn load(weights: &std::path::Path, planes: PlanesArg, budget: u64) -> anyhow::Result<Self> {
        let device = deepview_net::burn::tensor::Device::flex();
        let (model, config) = deepview_net::weights::load_model(weights, &device)
            .with_context(|| format!("cannot load weights from {}", weights.display()))?;
        Ok(Self {
            model,
            config,
            planes,
            budget,
            last_message: None,
            cache: None,
        })
    }

    /// Forget the cached MPI (so timings include inference).
    pub fn clear_cache(&mut self) {
        self.cache = None;
    }

    /// The plane choice of the last MPI.
    pub fn last_choice(&self) -> Option<&PlaneChoice> {
        self.cache.as_ref().map(|c| &c.3)
    }

    /// The MPI inferred from `inputs` (cached for repeated calls with the same inputs).
    pub fn mpi(
        &mut self,
        inputs: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
        near_far: (f64, f64),
    ) -> Result<&deepview_mpi::Mpi, deepview_eval::EvalError> {
        use deepview_geometry::{PlaneSpacing, plane_depths};
        let fail = |e: &dyn std::fmt::Display| method_error("deepview", e);
        let cams: Vec<_> = inputs.iter().map(|(_, c)| *c).collect();
        let hit = matches!(&self.cache, Some((c, nf, _, _)) if *c == cams && *nf == near_far);
        if !hit {
            deepview_net::weights::check_views(&self.config, inputs.len()).map_err(|e| fail(&e))?;
            let reference = args::mpi_reference(&cams, near_far).map_err(|e| fail(&e))?;
            let views: Vec<_> = inputs
                .iter()
                .map(|(img, cam)| (img.to_rgb(), *cam))
                .collect();
            let (model, budget) = (&self.model, self.budget);
            precheck_planes(
                model,
                &views,
                &reference,
                self.planes,
                self.config.infer_planes,
                budget,
            )
            .map_err(|e| fail(&e))?;
            let mut fits =
                |count: usize| learned_fits(model, &views, &reference, near_far, count, budget);
            let mut minimum =
                |count: usize| learned_minimum(model, &views, &reference, near_far, count);
            let choice = args::choose_planes(
                self.planes,
                &reference,
                &cams,
                &[],
                near_far,
                Some(self.config.infer_planes),
                &mut fits,
                &mut minimum,
            )
            .map_err(|e| fail(&e))?;
            announce(&mut self.last_message, &choice);
            let depths = plane_depths(
                near_far.0,
                near_far.1,
                choice.count,
                PlaneSpacing::InverseDepth,
            )?;
            let mpi = deepview_net::infer::infer_mpi(
                &self.model,
                &views,
                &reference,
                &depths,
                self.budget,
                &mut |_| {},
            )
            .map_err(|e| fail(&e))?;
            self.cache = Some((cams, near_far, mpi, choice));
        }
        Ok(&self.cache.as_ref().expect("just filled").2)
    }
}

/// A quick lower bound of the inference's memory for `planes` planes (the MPI state at half precision,
/// twice when there are several nets, and the input images): larger counts are refused without planning.
pub fn learned_lower_bound(
    model: &deepview_net::network::DeepViewModel,
    views: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
    reference: &deepview_geometry::Camera,
    planes: usize,
) -> u64 {
    let store = (reference.width as u64 * reference.height as u64)
        .saturating_mul(planes as u64)
        .saturating_mul(model.state_channels as u64)
        .saturating_mul(2);
    let stores = if model.nets.len() > 1 { 2 } else { 1 };
    let images: u64 = views
        .iter()
        .map(|(i, _)| 24 * i.width as u64 * i.height as u64)
        .sum();
    store.saturating_mul(stores).saturating_add(images)
}

/// The smallest memory budget the tiled inference of `depths` plans within: from below, each refusal of
/// the planner names what its net needs, until a plan fits.
pub fn learned_minimum_depths(
    model: &deepview_net::network::DeepViewModel,
    views: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
    reference: &deepview_geometry::Camera,
    depths: &[f64],
) -> u64 {
    use deepview_net::infer::{InferError, plan_inference};
    let mut b = learned_lower_bound(model, views, reference, depths.len()).max(1);
    for _ in 0..64 {
        match plan_inference(model, views, reference, depths, b) {
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
    model: &deepview_net::network::DeepViewModel,
    views: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
    reference: &deepview_geometry::Camera,
    near_far: (f64, f64),
    count: usize,
) -> u64 {
    use deepview_geometry::{PlaneSpacing, plane_depths};
    match plane_depths(near_far.0, near_far.1, count, PlaneSpacing::InverseDepth) {
        Ok(depths) => learned_minimum_depths(model, views, reference, &depths),
        Err(_) => 0,
    }
}

/// Whether `count` planes fit `budget`: the quick lower bound first, then the planner.
pub fn learned_fits(
    model: &deepview_net::network::DeepViewModel,
    views: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
    reference: &deepview_geometry::Camera,
    near_far: (f64, f64),
    count: usize,
    budget: u64,
) -> bool {
    use deepview_geometry::{PlaneSpacing, plane_depths};
    learned_lower_bound(model, views, reference, count) <= budget
        && plane_depths(near_far.0, near_far.1, count, PlaneSpacing::InverseDepth).is_ok_and(|d| {
            deepview_net::infer::plan_inference(model, views, reference, &d, budget).is_ok()
        })
}

/// Refuse at once an explicit plane count (`--planes N` or `weights`) whose quick lower bound is far over
/// the budget (planning so many planes would itself take long).
pub fn precheck_planes(
    model: &deepview_net::network::DeepViewModel,
    views: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
    reference: &deepview_geometry::Camera,
    arg: PlanesArg,
    weights_planes: usize,
    budget: u64,
) -> anyhow::Result<()> {
    let n = match arg {
        PlanesArg::Count(n) => n,
        PlanesArg::Weights => weights_planes,
        PlanesArg::Auto => return Ok(()),
    };
    if learned_lower_bound(model, views, reference, n) > budget {
        too_many_planes(model, views, reference, n, budget, &mut |_| 0)?;
    }
    Ok(())
}

/// Refuse an inference that cannot be planned within `budget`, naming the smallest budget that can.
pub fn check_learned(
    model: &deepview_net::network::DeepViewModel,
    views: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
    reference: &deepview_geometry::Camera,
    depths: &[f64],
    budget: u64,
) -> anyhow::Result<()> {
    let lower = learned_lower_bound(model, views, reference, depths.len());
    if lower <= budget
        && deepview_net::infer::plan_inference(model, views, reference, depths, budget).is_ok()
    {
        return Ok(());
    }
    too_many_planes(model, views, reference, depths.len(), budget, &mut |_| {
        learned_minimum_depths(model, views, reference, depths)
    })
}

/// The refusal of `planes` planes that do not fit `budget`. When even the quick lower bound is far over
/// the budget (planning itself would take long), the message names the largest plane count that fits
/// instead of a budget; otherwise the exact smallest `--max-memory`.
pub fn too_many_planes(
    model: &deepview_net::network::DeepViewModel,
    views: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
    reference: &deepview_geometry::Camera,
    planes: usize,
    budget: u64,
    minimum: &mut dyn FnMut(usize) -> u64,
) -> anyhow::Result<()> {
    let what = format!(
        "inferring {planes} planes of {}x{}",
        reference.width, reference.height
    );
    let lower = learned_lower_bound(model, views, reference, planes);
    if lower > budget {
        // The most planes whose lower bound fits (the plan may need a little more).
        let (mut lo, mut hi) = (0usize, planes);
        while lo + 1 < hi {
            let mid = lo + (hi - lo) / 2;
            if learned_lower_bound(model, views, reference, mid) <= budget {
                lo = mid
            } else {
                hi = mid
            }
        }
        anyhow::bail!(
            "{what} needs more than {} of memory (the MPI state alone) but the budget is {}: use fewer than \
             {} planes (--planes), smaller images (--downscale) or far more --max-memory",
            args::human(lower),
            args::human(budget),
            lo + 1
        );
    }
    args::check_memory(&what, minimum(planes).max(budget + 1), budget)
}

/// A baseline whose plane count follows `--planes` per input set, by the same rule as the learned model
/// (memory clamp from a simple bytes estimate).
pub struct PlannedBaseline {
    kind: Baseline,
    psv: PsvMeanOptions,
    optimize: OptimizeOptions,
    planes: PlanesArg,
    budget: u64,
    last_message: Option<String>,
}

impl PlannedBaseline {
    pub fn new(
        kind: Baseline,
        psv: PsvMeanOptions,
        optimize: OptimizeOptions,
        planes: PlanesArg,
        budget: u64,
    ) -> Self {
        Self {
            kind,
            psv,
            optimize,
            planes,
            budget,
            last_message: None,
        }
    }
}

/// The plane count of a classical method (`kind`) for `inputs` (dataset indices `ids`, may be empty).
pub fn baseline_planes(
    kind: Baseline,
    planes: PlanesArg,
    budget: u64,
    cams: &[deepview_geometry::Camera],
    ids: &[usize],
    near_far: (f64, f64),
    max_width: u32,
) -> anyhow::Result<PlaneChoice> {
    let reference = args::mpi_reference(cams, near_far)?;
    let (fixed, per_plane) = match kind {
        Baseline::Optimize => args::optimize_bytes(&reference, cams, max_width),
        _ => args::psv_mean_bytes(&reference, cams),
    };
    let mut fits = args::fits_estimate(fixed, per_plane, budget);
    let mut minimum = |n: usize| fixed.saturating_add(per_plane.saturating_mul(n as u64));
    args::choose_planes(
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

impl Method for PlannedBaseline {
    fn name(&self) -> &str {
        self.kind.name()
    }

    fn predict(
        &mut self,
        inputs: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
        target: &deepview_geometry::Camera,
        near_far: (f64, f64),
    ) -> Result<deepview_image::ImageF32, deepview_eval::EvalError> {
        let (mut psv, mut optimize) = (self.psv, self.optimize);
        if self.kind != Baseline::Nearest {
            let cams: Vec<_> = inputs.iter().map(|(_, c)| *c).collect();
            let choice = baseline_planes(
                self.kind,
                self.planes,
                self.budget,
                &cams,
                &[],
                near_far,
                self.optimize.max_width,
            )
            .map_err(|e| method_error(self.kind.name(), &e))?;
            announce(&mut self.last_message, &choice);
            psv.planes = choice.count;
            optimize.planes = choice.count;
        }
        baseline_method(self.kind, psv, optimize).predict(inputs, target, near_far)
    }
}

impl Method for LearnedMethod {
    fn name(&self) -> &str {
        "deepview"
    }

    fn predict(
        &mut self,
        inputs: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
        target: &deepview_geometry::Camera,
        near_far: (f64, f64),
    ) -> Result<deepview_image::ImageF32, deepview_eval::EvalError> {
        Ok(deepview_mpi::render(self.mpi(inputs, near_far)?, target).to_rgb())
    }
}

/// The weights `--method deepview` uses: `--weights`, else the shipped ones.
fn weights_of(args: &Args) -> anyhow::Result<PathBuf> {
    match &args.weights {
        Some(w) => Ok(w.clone()),
        None => super::infer::default_weights(),
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let weights = args.weights.clone().unwrap_or_default();
    let mut inputs: Vec<super::safety::Input> = vec![("--data", args.data.as_path())];
    if args.weights.is_some() {
        inputs.push(("--weights", &weights));
    }
    if let Some(out) = &args.out {
        super::safety::check_output("--out", out, super::safety::Kind::File, &inputs)?;
    }
    if let Some(dir) = &args.save_renders {
        super::safety::check_output("--save-renders", dir, super::safety::Kind::Files, &inputs)?;
    }
    if let (Some(a), Some(b)) = (&args.out, &args.save_renders) {
        super::safety::check_output(
            "--out",
            a,
            super::safety::Kind::File,
            &[("--save-renders", b)],
        )?;
    }
    // The runner downscales (and scales the protocol's crops with it), so the scene loads at full size.
    let load = deepview_data::LoadOptions {
        downscale: 1,
        ..args.scene.load_options()
    };
    let scene = deepview_data::load_scene(&args.data, &load)
        .with_context(|| format!("cannot load scene {}", args.data.display()))?;
    let targets = args
        .targets
        .as_deref()
        .map(str::parse::<TargetRule>)
        .transpose()?;
    let inputs = args
        .inputs
        .as_deref()
        .map(str::parse::<InputRule>)
        .transpose()?;
    let protocol = Protocol::from_name(&args.protocol, targets, inputs)?;
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let mut method: Box<dyn Method> = if args.method.trim().eq_ignore_ascii_case("deepview") {
        Box::new(LearnedMethod::load(
            &weights_of(&args)?,
            args.planes,
            budget,
        )?)
    } else {
        let kind: Baseline = args.method.parse()?;
        let psv = PsvMeanOptions {
            temperature: args.temperature,
            ..Default::default()
        };
        let opt = OptimizeOptions {
            planes: 0,
            steps: args.steps,
            learning_rate: args.lr,
            max_width: args.max_width,
        };
        Box::new(PlannedBaseline::new(kind, psv, opt, args.planes, budget))
    };
    let options = EvalOptions {
        downscale: args.scene.downscale.max(1),
        near_far: None,
        crop: args.crop,
        quantize: !args.no_quantize,
        save_renders: args.save_renders.clone(),
        // The report names the weights the learned method used (the shipped ones when none was given).
        checkpoint: if args.method.trim().eq_ignore_ascii_case("deepview") {
            Some(weights_of(&args)?.display().to_string())
        } else {
            None
        },
        verbose: true,
    };
    let renders = args
        .save_renders
        .as_deref()
        .map(super::safety::CreatedDirs::create)
        .transpose()?;
    let report = evaluate(&scene, &protocol, method.as_mut(), &options)?;
    if let Some(r) = renders {
        r.keep();
    }
    print!("{}", report.table());
    if let Some(out) = &args.out {
        super::safety::write_file(out, |out| Ok(report.write_json(out)?))?;
        println!("wrote {}", out.display());
    }
    Ok(())
}
