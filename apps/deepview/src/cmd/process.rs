//! `deepview process --data PHOTOS --out SCENE`: poses for one's own photos (or a video) with COLMAP.

use super::safety::{Kind, check_output};
use deepview_process::{CameraModel, Event, Input, Matcher, ProcessOptions, process};
use std::path::PathBuf;
use std::time::Duration;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  deepview process --data my_photos --out scenes/mine\n  \
    deepview process --video walk.mp4 --fps 2 --max-size 1600 --out scenes/walk\n\n\
    Needs COLMAP (Debian/Ubuntu: apt-get install colmap; ffmpeg too for --video). The output is a COLMAP \
    scene (images/, sparse/0/, colmap.log) that every command reads with --data; depth bounds come from \
    COLMAP's 3D points."
)]
pub struct Args {
    /// Folder of photos (.jpg, .jpeg, .png) of one scene.
    #[arg(long, required_unless_present = "video", conflicts_with = "video")]
    pub data: Option<PathBuf>,
    /// A video to take frames from instead (needs ffmpeg).
    #[arg(long)]
    pub video: Option<PathBuf>,
    /// Frames per second taken from --video (default 2).
    #[arg(long, requires = "video", value_parser = super::args::parse_positive_f64)]
    pub fps: Option<f64>,
    /// The scene folder to write; must not exist yet (or be empty).
    #[arg(long)]
    pub out: PathBuf,
    /// Image pairing: auto = exhaustive up to 50 images, else sequential (file-name order).
    #[arg(long, value_enum, default_value_t = Matcher::Auto)]
    pub matcher: Matcher,
    /// The camera model shared by all photos while solving (undistorted to PINHOLE at the end).
    #[arg(long, value_enum, default_value_t = CameraModel::SimpleRadial)]
    pub camera_model: CameraModel,
    /// Downscale photos whose larger side exceeds N pixels first (at least 16).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(16..))]
    pub max_size: Option<u32>,
    /// The COLMAP program.
    #[arg(long, default_value = "colmap")]
    pub colmap: PathBuf,
    /// The ffmpeg program (for --video).
    #[arg(long, default_value = "ffmpeg")]
    pub ffmpeg: PathBuf,
}

fn secs(d: Duration) -> String {
    format!("{:.1} s", d.as_secs_f64())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // (clap lets `requires = "video"` pass when --data, which excludes --video, is given.)
    if args.fps.is_some() && args.video.is_none() {
        anyhow::bail!(
            "--fps applies to frames taken from a --video; photos (--data) have none: leave it out"
        );
    }
    let input = match (&args.data, &args.video) {
        (_, Some(v)) => Input::Video {
            path: v.clone(),
            fps: args.fps.unwrap_or(2.0),
        },
        (Some(d), None) => Input::Photos(d.clone()),
        (None, None) => anyhow::bail!("give --data PHOTOS_DIR or --video FILE"),
    };
    let given: Vec<super::safety::Input> = match (&args.data, &args.video) {
        (_, Some(v)) => vec![("--video", v.as_path())],
        (Some(d), None) => vec![("--data", d.as_path())],
        (None, None) => vec![],
    };
    check_output("--out", &args.out, Kind::ProcessedScene, &given)?;
    // The working folder `OUT.incomplete` goes with a signal too (unless it is someone else's).
    let mut work_name = args.out.file_name().unwrap_or_default().to_os_string();
    work_name.push(".incomplete");
    let work = args.out.with_file_name(work_name);
    // (Not one another running process holds: it refuses to start then, and a Ctrl-C must not take
    // the other run's work with it.)
    let ours = !work.exists()
        || (work.join(".deepview-process").is_file() && !deepview_image::is_held(&work));
    if ours {
        super::signals::register(&work);
    }
    let mut opts = ProcessOptions::new(input, &args.out);
    opts.matcher = args.matcher;
    opts.camera_model = args.camera_model;
    opts.max_size = args.max_size;
    opts.colmap = args.colmap.clone();
    opts.ffmpeg = args.ffmpeg.clone();

    let bar = indicatif::ProgressBar::new_spinner();
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} {msg} ({elapsed})")
            .expect("valid template"),
    );
    bar.enable_steady_tick(Duration::from_millis(120));
    let result = process(&opts, &mut |e| match e {
        Event::Started(stage, what) => {
            bar.suspend(|| eprintln!("{stage}: {what}"));
            bar.reset_elapsed();
            bar.set_message(stage.to_string());
        }
        Event::Finished(stage, took) => {
            bar.suspend(|| eprintln!("  {stage} done in {}", secs(took)))
        }
        Event::Warning(w) => bar.suspend(|| eprintln!("warning: {w}")),
    });
    bar.finish_and_clear();
    if ours {
        super::signals::unregister(&work);
    }
    let r = result?;
    let [fx, fy, cx, cy] = r.intrinsics;
    println!(
        "wrote {}: {} of {} images registered ({} matching), {} points, {}x{} PINHOLE fx {fx:.2} fy {fy:.2} \
         cx {cx:.2} cy {cy:.2}, in {}",
        r.out.display(),
        r.registered.len(),
        r.images,
        r.matcher,
        r.points,
        r.size.0,
        r.size.1,
        secs(r.elapsed)
    );
    match r.depth_bounds {
        Some((n, f)) => println!("depth bounds from the points: near {n:.4}, far {f:.4}"),
        None => println!("no depth bounds (no 3D points): pass --near and --far to other commands"),
    }
    println!("COLMAP's log: {}", r.log.display());
    // (infer's default rule, nearest:4, needs four views.)
    let inputs = if r.registered.len() < 4 {
        " --inputs all"
    } else {
        ""
    };
    println!(
        "next: deepview info --data {0}; deepview infer --data {0}{inputs} --out {1}",
        r.out.display(),
        r.out
            .with_file_name(format!(
                "{}_mpi",
                r.out.file_name().unwrap_or_default().to_string_lossy()
            ))
            .display()
    );
    Ok(())
}
