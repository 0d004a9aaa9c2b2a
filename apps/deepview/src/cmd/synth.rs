//! `deepview synth`: a synthetic scene with ground truth, rendered through a camera rig.

use super::args;
use super::safety::{Kind, OutputDir, check_output};
use anyhow::Context;
use deepview_data::SceneArgs;
use deepview_synth::{Rig, SynthOptions, synthesize_as};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  deepview synth --out synth/grid\n  \
    deepview synth --data ../shared/data/spaces/scene_000 --out synth/spaces_000\n  \
    deepview synth --data ../shared/data/llff/fern --images images_8 --out synth/fern_rig\n  \
    deepview synth --out synth/grid_ns --out-format transforms")]
pub struct Args {
    /// Output folder: a dataset in the rig's own format, plus ground_truth_mpi/ and synth.json.
    #[arg(long)]
    pub out: PathBuf,
    /// The rig: `grid` (a generated N x N light-field grid, the default) or a dataset folder whose
    /// cameras to use (Spaces models.json, LLFF, COLMAP, light field, transforms.json).
    #[arg(
        long = "data",
        default_value = "grid",
        value_name = "grid|DIR",
        value_parser = parse_rig
    )]
    pub cameras: String,
    /// Grid rig: views per side (at least 2).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(2..=64))]
    pub grid: u64,
    /// Grid rig: image width (at least 3 pixels; a narrower grid's enlarged reference camera is not one
    /// the scene's own reader accepts).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(3..))]
    pub width: u32,
    /// Grid rig: image height (at least 3 pixels).
    #[arg(long, default_value_t = 192, value_parser = clap::value_parser!(u32).range(3..))]
    pub height: u32,
    /// Planes of the ground-truth MPI (at least 2).
    #[arg(long, default_value_t = 32, value_parser = parse_planes)]
    pub planes: u64,
    /// Random seed of the scene's layout and textures.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Rays per pixel side (antialiasing), 1..=16.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub supersample: u32,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
    /// Write the dataset in this format instead of the rig's own: `transforms` (nerfstudio
    /// transforms.json) works for every rig.
    #[arg(long, value_enum)]
    pub out_format: Option<deepview_data::SceneFormat>,
    #[command(flatten)]
    pub scene: SceneArgs,
}

/// `--planes`: at least 2 (the ground truth's layers lie between planes).
fn parse_planes(s: &str) -> Result<u64, String> {
    match s.trim().parse::<u64>() {
        Ok(n) if n >= 2 => Ok(n),
        Ok(n) => Err(format!("must be at least 2 (got {n})")),
        Err(_) => Err(format!("{s:?} is not a whole number")),
    }
}

/// `--data`: `grid` or an existing dataset folder.
fn parse_rig(s: &str) -> Result<String, String> {
    if s == "grid" || std::path::Path::new(s).is_dir() {
        Ok(s.to_string())
    } else {
        Err(format!(
            "{s:?} is neither `grid` nor a dataset folder (unknown rig)"
        ))
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let planes = args.planes as usize;
    let (rig, sizes) = if args.cameras == "grid" {
        check_output("--out", &args.out, Kind::SynthScene, &[])?;
        // The scene options read a dataset's cameras; a generated grid has none to read.
        let sc = &args.scene;
        let given: Vec<&str> = [
            ("--format", sc.format.is_some()),
            ("--images", sc.images.is_some()),
            ("--rig", sc.rig != 0),
            ("--near", sc.near.is_some()),
            ("--far", sc.far.is_some()),
            ("--downscale", sc.downscale > 1),
        ]
        .into_iter()
        .filter_map(|(name, set)| set.then_some(name))
        .collect();
        if !given.is_empty() {
            anyhow::bail!(
                "{} shape{} the cameras read from a dataset (--data DIR); the generated grid takes \
                 --width, --height and --grid",
                given.join(", "),
                if given.len() == 1 { "s" } else { "" }
            );
        }
        let side = args.grid as usize;
        (
            Rig::Grid {
                side,
                width: args.width,
                height: args.height,
            },
            vec![(args.width, args.height); side * side],
        )
    } else {
        let cams = std::path::Path::new(&args.cameras);
        check_output("--out", &args.out, Kind::SynthScene, &[("--data", cams)])?;
        if (args.width, args.height, args.grid) != (256, 192, 4) {
            anyhow::bail!(
                "--width, --height and --grid shape a generated grid; the rig {} brings its own cameras \
                 (use --downscale to make them smaller)",
                cams.display()
            );
        }
        let scene = super::args::load_scene_noted(cams, &args.scene.load_options())
            .with_context(|| format!("cannot load the rig {}", cams.display()))?;
        // A rig is written in its own format or as transforms (said before its views are checked for
        // another format's needs).
        if let Some(f) = args.out_format
            && f != scene.format
            && f != deepview_data::SceneFormat::Transforms
        {
            anyhow::bail!(
                "the rig {} is a {} scene: it can be written as {} or transforms (--out-format), not {f}",
                cams.display(),
                scene.format,
                scene.format
            );
        }
        // LLFF's poses_bounds.npy holds one focal length and a centred principal point: a --downscale that
        // does not divide the image size moves it off centre, so say so now, not after the rendering.
        let llff_out = args
            .out_format
            .map_or(scene.format == deepview_data::SceneFormat::Llff, |f| {
                f == deepview_data::SceneFormat::Llff
            });
        if llff_out {
            for v in &scene.views {
                if !deepview_data::formats::llff::llff_representable(&v.camera) {
                    anyhow::bail!(
                        "view {} of {} is {}x{} with its principal point off centre at this --downscale {}: \
                         LLFF output needs a centred one; use a --downscale that divides the image size, or \
                         --out-format transforms",
                        v.name,
                        cams.display(),
                        v.camera.width,
                        v.camera.height,
                        args.scene.downscale
                    );
                }
            }
        }
        let sizes = scene
            .views
            .iter()
            .map(|v| (v.camera.width, v.camera.height))
            .collect();
        (
            Rig::Dataset {
                path: PathBuf::from(&args.cameras),
                options: args.scene.load_options(),
            },
            sizes,
        )
    };
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    args::check_memory(
        &format!(
            "a synthetic scene of {} views ({}x{} the largest) with {planes} planes",
            sizes.len(),
            sizes.iter().map(|s| s.0).max().unwrap_or(0),
            sizes.iter().map(|s| s.1).max().unwrap_or(0)
        ),
        args::synth_bytes(&sizes, planes),
        budget,
    )?;
    let near_far = match (args.scene.near, args.scene.far) {
        (Some(n), Some(f)) => Some((n, f)),
        (None, None) => None,
        _ => anyhow::bail!("give both --near and --far, or neither"),
    };
    let opts = SynthOptions {
        rig,
        seed: args.seed,
        planes,
        near_far,
        supersample: args.supersample,
    };
    let dir = OutputDir::new(&args.out, Kind::SynthScene)?;
    let out = synthesize_as(dir.path(), &opts, args.out_format)
        .with_context(|| format!("cannot synthesise into {}", args.out.display()))?;
    // The dataset must read back with the depth bounds it was rendered with (a light field's disparity
    // range cannot hold every far depth): checked before it replaces anything.
    // (Spaces' models.json holds no bounds at all: nothing to compare.)
    let read = deepview_data::load_scene(dir.path(), &deepview_data::LoadOptions::default())
        .with_context(|| {
            format!(
                "the scene written to {} does not read back",
                args.out.display()
            )
        })?;
    // Nor other cameras than it was rendered through (a light field's reader derives them from the
    // image size: a --downscale of a light-field rig read back with another principal point).
    let cameras = read.cameras();
    if let Some(i) = (0..out.cameras.len()).find(|&i| {
        cameras
            .get(i)
            .is_none_or(|c| !same_camera(c, &out.cameras[i]))
    }) {
        anyhow::bail!(
            "a {} scene cannot hold this rig's cameras: view {i} would read back as another camera \
             (the format's reader derives them from the images); use --out-format transforms{}",
            out.format,
            if args.scene.downscale != 1 {
                ", or leave --downscale out"
            } else {
                ""
            }
        );
    }
    let back = read.depth_bounds;
    let (n, f) = out.near_far;
    let same = |a: f64, b: f64| (a - b).abs() <= 1e-6 * a.abs().max(b.abs());
    if let Some((bn, bf)) = back
        && !(same(bn, n) && same(bf, f))
    {
        anyhow::bail!(
            "a {} scene cannot hold the depth bounds {n}..{f}: it would read back as {bn}..{bf}; use \
             --out-format transforms, or a nearer --far",
            out.format
        );
    }
    dir.commit()?;
    println!(
        "wrote a {} scene with {} views, {} layers between depth {:.3} and {:.3}, to {}",
        out.format,
        out.cameras.len(),
        out.scene.layers.len(),
        out.near_far.0,
        out.near_far.1,
        args.out.display()
    );
    println!(
        "ground-truth MPI ({} planes): {}",
        out.ground_truth.planes(),
        args.out.join("ground_truth_mpi").display()
    );
    Ok(())
}

/// The same camera to within rounding: size, intrinsics and pose.
fn same_camera(a: &deepview_geometry::Camera, b: &deepview_geometry::Camera) -> bool {
    let (ka, kb) = (&a.intrinsics, &b.intrinsics);
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-6 * (1.0 + x.abs().max(y.abs()));
    a.width == b.width
        && a.height == b.height
        && close(ka.fx, kb.fx)
        && close(ka.fy, kb.fy)
        && close(ka.cx, kb.cx)
        && close(ka.cy, kb.cy)
        && a.pose.rotation.abs_diff_eq(b.pose.rotation, 1e-6)
        && a.center()
            .abs_diff_eq(b.center(), 1e-6 * (1.0 + b.center().length()))
}
