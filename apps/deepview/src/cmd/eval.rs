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
    /// Trained weights for --method deepview.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Write the report here (JSON: method, checkpoint, protocol, results, views).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write prediction | ground truth | error images here.
    #[arg(long)]
    pub save_renders: Option<PathBuf>,
}

/// The learned model behind `--method deepview`.
// -- LEAD: wire deepview-net here: build a `Box<dyn deepview_eval::Method>` from `args.checkpoint` (config +
// weights) whose `predict` runs tiled inference and renders the MPI into the target. Until then: a clear error.
fn deepview_method(args: &Args) -> anyhow::Result<Box<dyn Method>> {
    let ckpt = args
        .checkpoint
        .as_ref()
        .map(|p| p.display().to_string())
        .unwrap_or_else(|| "(none given)".into());
    anyhow::bail!(
        "--method deepview is not available in this build yet (checkpoint {ckpt}); use nearest, psv-mean or optimize"
    )
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
        checkpoint: args.checkpoint.as_ref().map(|p| p.display().to_string()),
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
