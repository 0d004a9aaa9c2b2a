//! `deepview infer`: an MPI from a few posed views with the learned network (tiled, bounded memory).

use anyhow::{Context, bail};
use deepview_data::{SceneArgs, load_scene};
use deepview_geometry::{PlaneSpacing, ReferenceOptions, plane_depths, reference_camera};
use deepview_net::infer::infer_mpi;
use deepview_net::weights::{check_views, load_model};
use std::path::PathBuf;

/// The weights shipped with the repository (trained `cpu` preset).
pub const DEFAULT_WEIGHTS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../weights/cpu");

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  deepview infer ../shared/data/llff/fern --images images_8 --planes 32 --out fern_mpi/"
)]
pub struct Args {
    /// Dataset folder.
    pub scene_dir: PathBuf,
    /// Input view indices, comma-separated. Default: the views nearest the centroid of all camera centres
    /// (as many as the weights need; 4 for weights that take any number).
    #[arg(long)]
    pub inputs: Option<String>,
    /// Number of MPI planes (equally spaced in inverse depth between near and far).
    #[arg(long, default_value_t = 32)]
    pub planes: usize,
    /// Weights folder (config.json + model.safetensors). Default: the shipped weights/cpu.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Memory budget, e.g. 2GiB, 512MiB, 1500000000.
    #[arg(long, default_value = "2GiB")]
    pub max_memory: String,
    /// Output MPI folder.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub scene: SceneArgs,
}

/// Parse a byte count with an optional unit (B, K/KB/KiB, M/MB/MiB, G/GB/GiB; binary multiples).
pub fn parse_bytes(text: &str) -> anyhow::Result<u64> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let value: f64 = num
        .parse()
        .with_context(|| format!("{text:?} is not a memory size (e.g. 2GiB)"))?;
    let mult: u64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "k" | "kb" | "kib" => 1 << 10,
        "m" | "mb" | "mib" => 1 << 20,
        "g" | "gb" | "gib" => 1 << 30,
        "t" | "tb" | "tib" => 1 << 40,
        u => bail!("unknown memory unit {u:?} in {text:?} (use B, KiB, MiB or GiB)"),
    };
    if !value.is_finite() || value <= 0.0 {
        bail!("memory size must be positive, got {text:?}");
    }
    Ok((value * mult as f64) as u64)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let weights = args
        .weights
        .clone()
        .unwrap_or_else(|| PathBuf::from(DEFAULT_WEIGHTS));
    if !weights.join(deepview_net::weights::CONFIG_FILE).is_file() {
        bail!(
            "no weights in {} (expected {} and {}); train some with `deepview train` or pass --weights",
            weights.display(),
            deepview_net::weights::CONFIG_FILE,
            deepview_net::weights::WEIGHTS_FILE
        );
    }
    let budget = parse_bytes(&args.max_memory)?;
    let device = deepview_net::burn::tensor::Device::flex();
    let (model, config) = load_model(&weights, &device)
        .with_context(|| format!("cannot load weights from {}", weights.display()))?;
    let scene = load_scene(&args.scene_dir, &args.scene.load_options())?;
    let n = scene.views.len();
    let inputs = match &args.inputs {
        Some(text) => super::parse_indices(text, n)?,
        None => {
            let want = config.views.unwrap_or(4).min(n);
            let centres: Vec<_> = scene.views.iter().map(|v| v.camera.center()).collect();
            let centroid = centres
                .iter()
                .fold(deepview_geometry::DVec3::ZERO, |a, &c| a + c)
                / n as f64;
            let mut order: Vec<usize> = (0..n).collect();
            order.sort_by(|&a, &b| {
                centres[a]
                    .distance(centroid)
                    .total_cmp(&centres[b].distance(centroid))
            });
            order.truncate(want);
            order.sort_unstable();
            order
        }
    };
    check_views(&config, inputs.len())?;
    let (near, far) = scene.near_far()?;
    let depths = plane_depths(near, far, args.planes, PlaneSpacing::InverseDepth)?;
    let cams: Vec<_> = inputs.iter().map(|&i| scene.views[i].camera).collect();
    let reference = reference_camera(
        &cams,
        &ReferenceOptions {
            cover: Some((near, far)),
            ..Default::default()
        },
    )?;
    let views = inputs
        .iter()
        .map(|&i| Ok((scene.load_image(i)?.to_rgb(), scene.views[i].camera)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    eprintln!(
        "inferring a {}-plane {}x{} MPI from views {:?} (weights {}, config {})",
        depths.len(),
        reference.width,
        reference.height,
        inputs,
        weights.display(),
        config.name
    );
    let bar = indicatif::ProgressBar::new(1);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} tiles x nets ({elapsed}, eta {eta}) {msg}",
        )
        .expect("valid template"),
    );
    let mpi = infer_mpi(&model, &views, &reference, &depths, budget, &mut |p| {
        bar.set_length(p.total as u64);
        bar.set_position(p.done as u64);
        bar.set_message(format!("net {}", p.net));
    })?;
    bar.finish();
    deepview_mpi::write_mpi(&args.out, &mpi)
        .with_context(|| format!("cannot write the MPI to {}", args.out.display()))?;
    println!(
        "wrote {} ({} planes, {}x{})",
        args.out.display(),
        depths.len(),
        reference.width,
        reference.height
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse_bytes;

    #[test]
    fn memory_sizes() {
        assert_eq!(parse_bytes("2GiB").unwrap(), 2 << 30);
        assert_eq!(parse_bytes("512 MiB").unwrap(), 512 << 20);
        assert_eq!(parse_bytes("1000").unwrap(), 1000);
        assert_eq!(parse_bytes("1.5g").unwrap(), 3 << 29);
        assert!(parse_bytes("lots").is_err());
        assert!(parse_bytes("2XB").is_err());
        assert!(parse_bytes("0").is_err());
    }
}
