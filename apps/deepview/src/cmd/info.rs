//! `deepview info SCENE`: what a dataset folder contains (format, views, image size, depth bounds, cameras).

use super::args::DataArg;
use anyhow::Context;
use deepview_data::{Scene, SceneArgs};
use std::fmt::Write as _;
use std::io::Write as _;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview info --data ../shared/data/llff/fern\n  \
    deepview info --data ../shared/data/llff/fern --images images_4 --camera 0 > cam.json\n  \
    deepview synth --data ../shared/data/spaces/scene_000 --out scene_000   # the calibration, with images\n  \
    deepview info --data scene_000 --rig 0 --json")]
pub struct Args {
    #[command(flatten)]
    pub data: DataArg,
    #[command(flatten)]
    pub scene_args: SceneArgs,
    /// Print a JSON summary (every camera included) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Number of camera centres to print in the text summary.
    #[arg(long, default_value_t = 5)]
    pub show: usize,
    /// Print only view N's camera as a camera JSON (the format `render --camera`, `depth` and `bench`
    /// read), e.g. `deepview info --data fern --images images_4 --camera 0 > cam.json`.
    #[arg(long, value_name = "N")]
    pub camera: Option<usize>,
}

/// `(min, max)` of image widths and heights over the views.
fn size_range(scene: &Scene) -> ((u32, u32), (u32, u32)) {
    let ws = scene.views.iter().map(|v| v.camera.width);
    let hs = scene.views.iter().map(|v| v.camera.height);
    (
        (ws.clone().min().unwrap_or(0), ws.max().unwrap_or(0)),
        (hs.clone().min().unwrap_or(0), hs.max().unwrap_or(0)),
    )
}

fn range_text((lo, hi): (u32, u32)) -> String {
    if lo == hi {
        lo.to_string()
    } else {
        format!("{lo}..{hi}")
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let data = args.data.path();
    let scene = super::args::load_scene_noted(data, &args.scene_args.load_options())
        .with_context(|| format!("cannot load scene {}", data.display()))?;
    if let Some(n) = args.camera {
        let Some(view) = scene.views.get(n) else {
            anyhow::bail!(
                "view {n} is out of range: {} has {} views (0..{})",
                data.display(),
                scene.views.len(),
                scene.views.len().saturating_sub(1)
            );
        };
        println!("{}", serde_json::to_string_pretty(&view.camera.to_json())?);
        return Ok(());
    }
    let (wr, hr) = size_range(&scene);
    // Image problems (missing files, wrong sizes) are reported, not fatal: cameras alone are useful.
    let image_problem = scene.check_images().err().map(|e| e.to_string());
    if args.json {
        let cameras: Vec<serde_json::Value> = scene
            .views
            .iter()
            .map(|v| {
                serde_json::json!({
                    "name": v.name,
                    "image": v.image_path,
                    "center": v.camera.center().to_array(),
                    "camera": v.camera.to_json(),
                })
            })
            .collect();
        let summary = serde_json::json!({
            "root": scene.root,
            "format": scene.format,
            "views": scene.len(),
            "width": [wr.0, wr.1],
            "height": [hr.0, hr.1],
            "depth_bounds": scene.depth_bounds.map(|(n, f)| [n, f]),
            "grid": scene.grid.map(|(r, c)| [r, c]),
            "rig": args.scene_args.rig,
            "rig_count": scene.rig_count,
            "images_ok": image_problem.is_none(),
            "image_problem": image_problem,
            "cameras": cameras,
        });
        emit(&(serde_json::to_string_pretty(&summary)? + "\n"))?;
        return problem_exit(data, image_problem);
    }
    let mut out = String::new();
    writeln!(out, "scene        {}", scene.root.display())?;
    writeln!(out, "format       {}", scene.format)?;
    writeln!(out, "views        {}", scene.len())?;
    if let Some((r, c)) = scene.grid {
        writeln!(out, "grid         {r} x {c} (row-major)")?;
    }
    if scene.format == deepview_data::SceneFormat::Spaces {
        writeln!(
            out,
            "rig          {} of {} rig position(s)",
            args.scene_args.rig, scene.rig_count
        )?;
    }
    writeln!(out, "image size   {} x {}", range_text(wr), range_text(hr))?;
    let k = scene.views[0].camera.intrinsics;
    writeln!(
        out,
        "intrinsics   view 0: fx {:.3} fy {:.3} cx {:.3} cy {:.3}",
        k.fx, k.fy, k.cx, k.cy
    )?;
    match scene.depth_bounds {
        Some((n, f)) => writeln!(out, "depth        near {n:.6} far {f:.6}"),
        None => writeln!(out, "depth        unknown (pass --near and --far)"),
    }?;
    match &image_problem {
        None => writeln!(
            out,
            "images       all present, sizes match the cameras (from the headers: pixels are decoded when used)"
        ),
        Some(e) => writeln!(out, "images       problem: {e}"),
    }?;
    let shown = args.show.min(scene.len());
    writeln!(out, "centres      first {shown} of {}:", scene.len())?;
    for v in scene.views.iter().take(shown) {
        let c = v.camera.center();
        // `+ 0.0` turns -0 into 0.
        writeln!(
            out,
            "  {:<24} [{:.6}, {:.6}, {:.6}]",
            v.name,
            c.x + 0.0,
            c.y + 0.0,
            c.z + 0.0
        )?;
    }
    emit(&out)?;
    problem_exit(data, image_problem)
}

/// After the report: a problem it showed makes the command fail (exit 2).
fn problem_exit(data: &std::path::Path, problem: Option<String>) -> anyhow::Result<()> {
    match problem {
        None => Ok(()),
        Some(p) => anyhow::bail!("{} has a problem: {p}", data.display()),
    }
}

/// Print `text`; a closed pipe (`| head`) is not an error.
fn emit(text: &str) -> anyhow::Result<()> {
    match std::io::stdout().lock().write_all(text.as_bytes()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => Ok(r?),
    }
}
