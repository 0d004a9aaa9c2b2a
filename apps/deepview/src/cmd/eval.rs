//! `deepview eval`: score a method (a baseline or the learned model) on a scene under a protocol.

use anyhow::Context;
use deepview_eval::{
    Baseline, EvalOptions, InputRule, Method, OptimizeOptions, Protocol, PsvMeanOptions,
    TargetRule, baseline_method, evaluate,
};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview eval --data ../shared/data/llff/fern --method psv-mean --out results.json\n  \
    deepview eval --data scene_000 --near 0.7 --far 100 --protocol small_quad --method nearest\n  \
    deepview eval --data ../shared/data/hci/antinous --method optimize --protocol light-field --targets 40 \
    --save-renders renders/")]
pub struct Args {
    /// Dataset folder (LLFF, COLMAP, Spaces, light-field grid).
    #[arg(long)]
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
    /// Box-downscale images by this integer factor (crops scale with it).
    #[arg(long, default_value_t = 1)]
    pub downscale: u32,
    /// Crop this many pixels from every side instead of the protocol's crop.
    #[arg(long)]
    pub crop: Option<u32>,
    /// Score float predictions as they are instead of rounding to 8 bits like saved PNGs.
    #[arg(long)]
    pub no_quantize: bool,
    /// MPI planes (psv-mean, optimize).
    #[arg(long, default_value_t = 32)]
    pub planes: usize,
    /// Colour variance treated as disagreement, s in exp(-variance / s) (psv-mean).
    #[arg(long, default_value_t = PsvMeanOptions::default().temperature)]
    pub temperature: f64,
    /// Adam steps (optimize).
    #[arg(long, default_value_t = 300)]
    pub steps: usize,
    /// Adam learning rate on the RGBA logits (optimize).
    #[arg(long, default_value_t = 0.1)]
    pub lr: f64,
    /// Working width of the optimisation (optimize).
    #[arg(long, default_value_t = 160)]
    pub max_width: u32,
    /// Trained weights for --method deepview: a weights folder or a training checkpoint folder
    /// (default: the shipped weights/cpu).
    #[arg(long, visible_alias = "weights")]
    pub checkpoint: Option<PathBuf>,
    /// Write the report here (JSON: method, checkpoint, protocol, results, views).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write prediction | ground truth | error images here.
    #[arg(long)]
    pub save_renders: Option<PathBuf>,
}

/// The learned model behind `--method deepview`: tiled inference from the inputs, then rendering the
/// MPI into the target. Weights from `--checkpoint`, or the shipped `weights/cpu`.
pub struct LearnedMethod {
    model: deepview_net::network::DeepViewModel,
    config: deepview_net::config::DeepViewConfig,
    planes: usize,
    budget: u64,
    /// The last MPI and the inputs it came from: targets sharing inputs reuse it.
    cache: Option<(
        Vec<deepview_geometry::Camera>,
        (f64, f64),
        deepview_mpi::Mpi,
    )>,
}

impl LearnedMethod {
    /// Load weights (config.json + model.safetensors) from `weights`.
    pub fn load(weights: &std::path::Path, planes: usize) -> anyhow::Result<Self> {
        let device = deepview_net::burn::tensor::Device::flex();
        let (model, config) = deepview_net::weights::load_model(weights, &device)
            .with_context(|| format!("cannot load weights from {}", weights.display()))?;
        Ok(Self {
            model,
            config,
            planes,
            budget: 2 << 30,
            cache: None,
        })
    }

    /// Forget the cached MPI (so timings include inference).
    pub fn clear_cache(&mut self) {
        self.cache = None;
    }

    /// The MPI inferred from `inputs` (cached for repeated calls with the same inputs).
    pub fn mpi(
        &mut self,
        inputs: &[(deepview_image::ImageF32, deepview_geometry::Camera)],
        near_far: (f64, f64),
    ) -> Result<&deepview_mpi::Mpi, deepview_eval::EvalError> {
        use deepview_eval::EvalError;
        use deepview_geometry::{PlaneSpacing, ReferenceOptions, plane_depths, reference_camera};
        let fail = |e: &dyn std::fmt::Display| EvalError::Method {
            method: "deepview".into(),
            msg: e.to_string(),
        };
        let cams: Vec<_> = inputs.iter().map(|(_, c)| *c).collect();
        let hit = matches!(&self.cache, Some((c, nf, _)) if *c == cams && *nf == near_far);
        if !hit {
            deepview_net::weights::check_views(&self.config, inputs.len()).map_err(|e| fail(&e))?;
            let reference = reference_camera(
                &cams,
                &ReferenceOptions {
                    cover: Some(near_far),
                    ..Default::default()
                },
            )?;
            let depths = plane_depths(
                near_far.0,
                near_far.1,
                self.planes,
                PlaneSpacing::InverseDepth,
            )?;
            let views: Vec<_> = inputs
                .iter()
                .map(|(img, cam)| (img.to_rgb(), *cam))
                .collect();
            let mpi = deepview_net::infer::infer_mpi(
                &self.model,
                &views,
                &reference,
                &depths,
                self.budget,
                &mut |_| {},
            )
            .map_err(|e| fail(&e))?;
            self.cache = Some((cams, near_far, mpi));
        }
        Ok(&self.cache.as_ref().expect("just filled").2)
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

fn deepview_method(args: &Args) -> anyhow::Result<Box<dyn Method>> {
    Ok(Box::new(LearnedMethod::load(
        &weights_of(args)?,
        args.planes,
    )?))
}

/// The weights `--method deepview` uses: `--checkpoint`, else the shipped ones.
fn weights_of(args: &Args) -> anyhow::Result<PathBuf> {
    match &args.checkpoint {
        Some(w) => Ok(w.clone()),
        None => super::infer::default_weights(),
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let scene = deepview_data::load_scene(&args.data, &args.scene.load_options())
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
    let mut method: Box<dyn Method> = if args.method.trim().eq_ignore_ascii_case("deepview") {
        deepview_method(&args)?
    } else {
        let kind: Baseline = args.method.parse()?;
        let psv = PsvMeanOptions {
            planes: args.planes,
            temperature: args.temperature,
            ..Default::default()
        };
        let opt = OptimizeOptions {
            planes: args.planes,
            steps: args.steps,
            learning_rate: args.lr,
            max_width: args.max_width,
        };
        baseline_method(kind, psv, opt)
    };
    let options = EvalOptions {
        downscale: args.downscale,
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
    let report = evaluate(&scene, &protocol, method.as_mut(), &options)?;
    print!("{}", report.table());
    if let Some(out) = &args.out {
        report.write_json(out)?;
        println!("wrote {}", out.display());
    }
    Ok(())
}
