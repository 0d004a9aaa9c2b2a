//! `deepview depth`: expected depth through the alpha, as a false-colour image and a 16-bit disparity PNG.

use super::CameraSource;
use super::args;
use super::safety::{CreatedDirs, Input, Kind, check_output, parse_component};
use anyhow::Context;
use deepview_mpi::{MpiMeta, depth_maps, read_mpi};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  deepview depth --mpi mpi/ --out depth/   (writes depth_color.png, depth_disparity16.png)\n  \
    deepview depth --mpi mpi/ --data ../shared/data/llff/fern --images images_8 --view 3 --out depth3/"
)]
pub struct Args {
    /// MPI folder.
    #[arg(long)]
    pub mpi: PathBuf,
    /// The view to compute depth in (default: the MPI's reference camera).
    #[command(flatten)]
    pub source: CameraSource,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// File name prefix (a plain name: the files go into --out).
    #[arg(long, default_value = "depth", value_parser = parse_component)]
    pub prefix: String,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    super::check_deepview_mpi("--mpi", &args.mpi)?;
    let mut inputs: Vec<Input> = vec![("--mpi", args.mpi.as_path())];
    if let Some(c) = &args.source.camera {
        inputs.push(("--camera", c));
    }
    if let Some(d) = &args.source.scene_dir {
        inputs.push(("--data", d));
    }
    // The pair is written into a temporary folder beside the first file, then both are moved into
    // place together (see below); one a killed run left is removed first.
    let color = args.out.join(format!("{}_color.png", args.prefix));
    super::safety::remove_stale_inside(&args.out, Kind::DepthMaps);
    check_output("--out", &args.out, Kind::DepthMaps, &inputs)?;
    for suffix in ["color", "disparity16"] {
        let file = args.out.join(format!("{}_{suffix}.png", args.prefix));
        check_output("--out", &file, Kind::File, &inputs)?;
    }
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let (meta, reference) = MpiMeta::read(&args.mpi)?;
    let camera = args.source.camera()?.unwrap_or(reference);
    args::check_memory(
        &format!(
            "a {}x{} depth map from a {}-plane {}x{} MPI",
            camera.width,
            camera.height,
            meta.depths.len(),
            meta.width,
            meta.height
        ),
        args::mpi_bytes(meta.width, meta.height, meta.depths.len(), true)
            .saturating_add(args::depth_bytes(&camera)),
        budget,
    )?;
    // 8-bit texels: the maps need alpha alone, which is stored straight (8-bit texels keep it exactly),
    // composited row by row (no warped stack).
    let mpi = read_mpi::<u8>(&args.mpi)?;
    let maps = depth_maps(&mpi, &camera);
    let dirs = CreatedDirs::create(&args.out)?;
    let (stage, lock) = super::safety::make_temp_dir(&color, "tmp")?;
    let written = (|| -> anyhow::Result<()> {
        maps.write(&stage, &args.prefix)?;
        // Both files or neither; and both of one run: another `depth` into this folder publishes its
        // pair under the same lock (an flock of the folder), never between these two renames.
        super::signals::publish(&stage, || {
            let folder = std::fs::File::open(&args.out)
                .with_context(|| format!("cannot open {}", args.out.display()))?;
            // SAFETY: flock on a descriptor `folder` owns; the lock goes when it is closed.
            unsafe {
                use std::os::fd::AsRawFd;
                libc::flock(folder.as_raw_fd(), libc::LOCK_EX);
            }
            for suffix in ["color", "disparity16"] {
                let name = format!("{}_{suffix}.png", args.prefix);
                std::fs::rename(stage.join(&name), args.out.join(&name))
                    .with_context(|| format!("cannot write {}", args.out.join(&name).display()))?;
            }
            Ok(())
        })
    })();
    let _ = std::fs::remove_dir_all(&stage);
    drop(lock);
    super::signals::unregister(&stage);
    written?;
    dirs.keep();
    let file = |suffix: &str| args.out.join(format!("{}_{suffix}.png", args.prefix));
    println!(
        "wrote {} and {} (disparity 0 = depth {:.4}, 65535 = depth {:.4})",
        file("color").display(),
        file("disparity16").display(),
        mpi.depths[0],
        mpi.depths[mpi.planes() - 1]
    );
    Ok(())
}
