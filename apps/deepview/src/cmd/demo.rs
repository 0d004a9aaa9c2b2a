//! `deepview demo`: the whole pipeline on a built-in synthetic scene, no files needed.

use super::method::Reporter;
use anyhow::Context;
use deepview_data::{LoadOptions, load_scene};
use deepview_eval::{EvalOptions, EvalReport, MpiPredictor, Protocol, TargetRule, evaluate};
use deepview_methods::{InputRule, MethodKind, MethodOptions, MpiRequest, Planes, make_method};
use deepview_synth::{Rig, SynthOptions, synthesize};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  deepview demo\n  deepview demo --out demo/ --planes 32 --no-optimize\n  \
    deepview demo --device wgpu    # the learned model on a GPU (a build with --features wgpu)"
)]
pub struct Args {
    /// Output folder.
    #[arg(long, default_value = "deepview-demo")]
    pub out: PathBuf,
    /// Weights for the learned model (default: the built-in weights, the repository's weights/cpu).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Scene seed (layout and textures of the synthetic scene).
    #[arg(long, default_value_t = 3)]
    pub seed: u64,
    /// Skip the slow `optimize` baseline.
    #[arg(long)]
    pub no_optimize: bool,
    /// MPI planes of every method (see `deepview infer --help`).
    #[arg(long, default_value = "auto", help = deepview_methods::PLANES_HELP)]
    pub planes: Planes,
    #[arg(long, value_name = "SIZE", help = super::args::MEMORY_HELP, value_parser = super::args::parse_memory)]
    pub max_memory: Option<String>,
    /// Device of the learned model (as `infer --device` and `train --devices`): cpu, wgpu, wgpu:N,
    /// wgpu:cpu, cuda, cuda:N (GPU devices in builds with `--features wgpu` or `--features cuda`).
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

const INPUTS: &str = "0,3,12,15";

const TARGETS: &str = "5,10";

pub fn run(args: Args) -> anyhow::Result<()> {
    let shown = &args.out;
    let weights = args.weights.clone().unwrap_or_default();
    let inputs: Vec<super::safety::Input> = match &args.weights {
        Some(_) => vec![("--weights", &weights)],
        None => Vec::new(),
    };
    super::safety::check_output("--out", shown, super::safety::Kind::Demo, &inputs)?;
    let budget = super::args::memory_budget(args.max_memory.as_deref())?;
    // The same plane rule for every method, so the comparison is fair.
    let options = |steps: usize| MethodOptions {
        planes: args.planes,
        weights: args.weights.clone(),
        device: args.device.clone(),
        steps,
        ..MethodOptions::default()
    };
    let default_steps = MethodOptions::default().steps;
    let learned_method = make_method(MethodKind::Deepview, &options(default_steps), budget)
        .context("cannot load the learned model for the demo")?;
    let weights_name = learned_method.weights().unwrap_or_default();
    // Weights for a fixed number of views other than the demo's four corners: said now, in the demo's
    // terms (the generic hint names --inputs, which the demo does not take).
    if let Some(k) = learned_method.views().filter(|&k| k != 4) {
        anyhow::bail!(
            "the weights {weights_name} take exactly {k} input views, and the demo infers from its 4 \
             corner views ({INPUTS}): pass --weights trained for 4 views or any number (the shipped \
             weights take any)"
        );
    }
    let mut reporter = Reporter::new(MethodKind::Deepview, &[], None, false);
    let mut learned = MpiPredictor::new(learned_method, move |e| reporter.event(e));
    // Everything is made in a temporary sibling and swapped in at the end: a failure or a signal leaves
    // the earlier demo folder (or none) as it was.
    let dir = super::safety::OutputDir::new(shown, super::safety::Kind::Demo)?;
    let out = &dir.path().to_path_buf();

    // 1. A synthetic scene through a 4 x 4 light-field rig, with its exact ground truth.
    let scene_dir = out.join("scene");
    eprintln!(
        "[1/5] synthesising a scene with ground truth in {}",
        shown.join("scene").display()
    );
    std::fs::create_dir_all(&scene_dir)?;
    let synth = synthesize(
        &scene_dir,
        &SynthOptions {
            rig: Rig::Grid {
                side: 4,
                width: 256,
                height: 192,
            },
            seed: args.seed,
            planes: 32,
            near_far: None,
            supersample: 2,
        },
    )?;
    let scene = load_scene(&scene_dir, &LoadOptions::default())?;
    let near_far = synth.near_far;
    let inputs: Vec<usize> = INPUTS
        .split(',')
        .map(|s| s.parse().expect("constant"))
        .collect();
    let targets: Vec<usize> = TARGETS
        .split(',')
        .map(|s| s.parse().expect("constant"))
        .collect();

    // 2. The MPI from the four corner views with the learned model.
    eprintln!("[2/5] inferring an MPI from the corner views {INPUTS} with {weights_name}");
    let views = inputs
        .iter()
        .map(|&i| Ok((scene.load_image(i)?, scene.views[i].camera)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let started = std::time::Instant::now();
    let made = learned.mpi(&MpiRequest {
        inputs: &views,
        ids: &inputs,
        near_far,
        toward: None,
    })?;
    let mpi = made.mpi.clone();
    let infer_seconds = started.elapsed().as_secs_f64();
    let mpi_dir = out.join("mpi");
    deepview_mpi::write_mpi_with(&mpi_dir, &mpi, made.planes.as_ref().map(|c| &c.rule))?;

    // 3. Novel views (the inner, held-out cameras) beside their ground truth, depth, a camera path.
    eprintln!("[3/5] rendering novel views, a depth map and a spiral animation");
    let novel_dir = out.join("novel_views");
    std::fs::create_dir_all(&novel_dir)?;
    for &t in &targets {
        let cam = scene.views[t].camera;
        let pred = deepview_mpi::render(&mpi, &cam).to_rgb();
        let truth = scene.load_image(t)?;
        deepview_image::write_png(&novel_dir.join(format!("view_{t:02}.png")), &pred)?;
        deepview_image::write_png(
            &novel_dir.join(format!("view_{t:02}_ground_truth.png")),
            &truth,
        )?;
    }
    let depth_dir = out.join("depth");
    deepview_mpi::depth_maps(&mpi, &mpi.camera).write(&depth_dir, "depth")?;
    let mpi_u8 = mpi.to_u8();
    let path = deepview_media::make_camera_path(
        &mpi.camera,
        &mpi.depths,
        &deepview_media::PathSpec {
            kind: deepview_media::PathKind::Spiral,
            frames: 48,
            radius: deepview_media::Radius::NearFraction(0.15),
            focus_depth: None,
        },
    )?;
    let gif = out.join("spiral.gif");
    super::method::video(&mpi_u8, &path, (&gif, &shown.join("spiral.gif")), 24.0)?;

    // 4. The evaluation table: the learned model against the baselines on the held-out views.
    eprintln!("[4/5] evaluating on the held-out views {TARGETS} against the baselines");
    let protocol = Protocol::from_name(
        "posed",
        Some(TARGETS.parse::<TargetRule>()?),
        Some(INPUTS.parse::<InputRule>()?),
    )?;
    let mut reports: Vec<EvalReport> = Vec::new();
    let mut kinds = vec![
        (MethodKind::Nearest, default_steps),
        (MethodKind::PsvMean, default_steps),
    ];
    if !args.no_optimize {
        kinds.push((MethodKind::Optimize, 150));
    }
    let options_eval = EvalOptions {
        near_far: Some(near_far),
        ..EvalOptions::default()
    };
    for (kind, steps) in kinds {
        eprintln!("      {kind}");
        let mut reporter = Reporter::new(kind, &[], None, false);
        // The baselines run on the CPU (--device is the learned method's).
        // (nearest's MPI is one plane whatever --planes says.)
        let on = |kind: MethodKind| MethodOptions {
            device: if kind == MethodKind::Deepview {
                args.device.clone()
            } else {
                "cpu".into()
            },
            planes: if kind == MethodKind::Nearest {
                Planes::Auto
            } else {
                args.planes
            },
            ..options(steps)
        };
        let mut method = MpiPredictor::new(make_method(kind, &on(kind), budget)?, move |e| {
            reporter.event(e)
        });
        reports.push(evaluate(&scene, &protocol, &mut method, &options_eval)?);
    }
    eprintln!("      deepview");
    let learned_options = EvalOptions {
        checkpoint: Some(weights_name.clone()),
        save_renders: Some(out.join("renders")),
        ..options_eval.clone()
    };
    learned.clear();
    reports.push(evaluate(&scene, &protocol, &mut learned, &learned_options)?);

    // 5. Write the table and say what was made.
    let mut table =
        String::from("| method | SSIM | PSNR (dB) | seconds per view |\n|---|---|---|---|\n");
    for r in &reports {
        table.push_str(&format!(
            "| {} | {:.4} | {:.2} | {:.2} |\n",
            r.method, r.results.ssim, r.results.psnr, r.results.seconds_per_view
        ));
    }
    let json = serde_json::to_string_pretty(&reports)?;
    deepview_image::write_atomic(&out.join("eval.json"), json.as_bytes())?;
    deepview_image::write_atomic(&out.join("eval.md"), table.as_bytes())?;
    dir.commit()?;
    eprintln!("[5/5] done");
    println!(
        "\nHeld-out views {TARGETS} of the synthetic scene, inputs {INPUTS} (SSIM and PSNR against ground truth):\n"
    );
    println!("{table}");
    println!("Made in {}:", shown.display());
    println!("  scene/            the synthetic scene (4x4 light field) and its ground_truth_mpi/");
    println!(
        "  mpi/              the inferred MPI ({} planes, {:.1} s)",
        mpi.planes(),
        infer_seconds
    );
    println!("  novel_views/      renders of the held-out views beside their ground truth");
    println!("  renders/          prediction | ground truth | error, per held-out view");
    println!("  depth/            depth_color.png (turbo), depth_disparity16.png");
    println!("  spiral.gif        a camera path through the MPI");
    println!("  eval.json, eval.md  the table above");
    // Built in a checkout (the README's first command runs it through cargo): say it the same way; an
    // installed binary by name.
    let through_cargo =
        std::env::current_exe().is_ok_and(|p| p.components().any(|c| c.as_os_str() == "target"));
    println!(
        "\nLook at it in the browser:  {} view --mpi {}",
        if through_cargo {
            "cargo run --release --"
        } else {
            "deepview"
        },
        shown.join("mpi").display()
    );
    Ok(())
}
