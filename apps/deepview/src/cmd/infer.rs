//! `deepview infer`: an MPI from a few posed views with the learned network (tiled, bounded memory).

use super::args::{self, DataArg, PlanesArg, ViewList};
use super::safety::{Kind, OutputDir, check_output};
use anyhow::{Context, bail};
use deepview_data::{SceneArgs, load_scene};
use deepview_geometry::{PlaneSpacing, plane_depths};
use deepview_net::infer::infer_mpi;
use deepview_net::weights::{check_views, load_model};
use std::path::PathBuf;

/// The weights shipped with the repository (trained `cpu` preset).
pub const DEFAULT_WEIGHTS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../weights/cpu");

/// The shipped weights, also compiled into the binary (37 KB) so an installed or copied `deepview` works
/// without the repository.
const EMBEDDED_CONFIG: &[u8] = include_bytes!("../../../../weights/cpu/config.json");
const EMBEDDED_MODEL: &[u8] = include_bytes!("../../../../weights/cpu/model.safetensors");

/// The folder of the default weights: the repository's `weights/cpu` when it is there, otherwise the copy
/// compiled into the binary, unpacked once into the temporary folder (atomically: a half-written copy is
/// never used).
pub fn default_weights() -> anyhow::Result<PathBuf> {
    let repo = PathBuf::from(DEFAULT_WEIGHTS);
    if repo.join(deepview_net::weights::CONFIG_FILE).is_file()
        && repo.join(deepview_net::weights::WEIGHTS_FILE).is_file()
    {
        return Ok(repo);
    }
    unpack_embedded_weights()
}

/// Unpack the weights compiled into the binary (see [`default_weights`]).
fn unpack_embedded_weights() -> anyhow::Result<PathBuf> {
    // FNV-1a over both files names the unpacked copy, so different builds never share a folder.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in EMBEDDED_CONFIG.iter().chain(EMBEDDED_MODEL) {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
    }
    let dir = std::env::temp_dir().join(format!("deepview-weights-cpu-{h:016x}"));
    if dir.join(deepview_net::weights::CONFIG_FILE).is_file() {
        return Ok(dir);
    }
    let tmp = std::env::temp_dir().join(format!(
        "deepview-weights-cpu-{h:016x}.{}.tmp",
        std::process::id()
    ));
    let write = || -> std::io::Result<()> {
        std::fs::create_dir_all(&tmp)?;
        std::fs::write(
            tmp.join(deepview_net::weights::WEIGHTS_FILE),
            EMBEDDED_MODEL,
        )?;
        std::fs::write(
            tmp.join(deepview_net::weights::CONFIG_FILE),
            EMBEDDED_CONFIG,
        )?;
        std::fs::rename(&tmp, &dir)
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_dir_all(&tmp);
        // Another process may have unpacked the same weights meanwhile.
        if !dir.join(deepview_net::weights::CONFIG_FILE).is_file() {
            return Err(e).with_context(|| {
                format!("cannot unpack the built-in weights into {}", dir.display())
            });
        }
    }
    Ok(dir)
}

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    deepview infer --data ../shared/data/llff/fern --images images_8 --out fern_mpi/\n  \
    deepview infer --data ../shared/data/llff/fern --images images_4 --inputs 1,2,3,4 --planes 64 --out fern_mpi/\n  \
    deepview infer --data my_scene --downscale 2 --weights runs/mine/checkpoints/step-0005000 --planes weights --out mpi/")]
pub struct Args {
    #[command(flatten)]
    pub data: DataArg,
    /// Input view indices, comma-separated. Default: the views nearest the centroid of all camera centres
    /// (as many as the weights need; 4 for weights that take any number).
    #[arg(long)]
    pub inputs: Option<ViewList>,
    #[arg(long, default_value = "auto", help = args::PLANES_HELP)]
    pub planes: PlanesArg,
    /// Weights folder (config.json + model.safetensors) or a training checkpoint folder
    /// (runs/<name>/checkpoints/step-N). Default: the shipped weights/cpu.
    #[arg(long, visible_alias = "checkpoint")]
    pub weights: Option<PathBuf>,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
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
    let weights = match &args.weights {
        Some(w) => w.clone(),
        None => default_weights()?,
    };
    if !weights.join(deepview_net::weights::CONFIG_FILE).is_file()
        && !deepview_net::weights::is_checkpoint(&weights)
    {
        bail!(
            "no weights in {} (expected {} and {}, or a training checkpoint); train some with `deepview train` or pass --weights",
            weights.display(),
            deepview_net::weights::CONFIG_FILE,
            deepview_net::weights::WEIGHTS_FILE
        );
    }
    let data = args.data.path();
    check_output(
        "--out",
        &args.out,
        Kind::Mpi,
        &[("--data", data), ("--weights", &weights)],
    )?;
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let device = deepview_net::burn::tensor::Device::flex();
    let (model, config) = load_model(&weights, &device)
        .with_context(|| format!("cannot load weights from {}", weights.display()))?;
    let scene = load_scene(data, &args.scene.load_options())
        .with_context(|| format!("cannot load scene {}", data.display()))?;
    let n = scene.views.len();
    let inputs = match &args.inputs {
        Some(list) => list.check(n)?,
        None => super::views_nearest_centroid(&scene.cameras(), config.views.unwrap_or(4)),
    };
    check_views(&config, inputs.len())?;
    let (near, far) = scene.near_far()?;
    let cams: Vec<_> = inputs.iter().map(|&i| scene.views[i].camera).collect();
    let reference = args::mpi_reference(&cams, (near, far))?;
    let views = inputs
        .iter()
        .map(|&i| Ok((scene.load_image(i)?.to_rgb(), scene.views[i].camera)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    // `auto` takes the largest count up to the rule's that the inference can plan within the budget.
    super::eval::precheck_planes(
        &model,
        &views,
        &reference,
        args.planes,
        config.infer_planes,
        budget,
    )?;
    let mut fits = |count: usize| {
        super::eval::learned_fits(&model, &views, &reference, (near, far), count, budget)
    };
    let mut minimum =
        |count: usize| super::eval::learned_minimum(&model, &views, &reference, (near, far), count);
    let choice = args::choose_planes(
        args.planes,
        &reference,
        &cams,
        &inputs,
        (near, far),
        Some(config.infer_planes),
        &mut fits,
        &mut minimum,
    )?;
    eprintln!("{}", choice.message);
    let depths = plane_depths(near, far, choice.count, PlaneSpacing::InverseDepth)?;
    eprintln!(
        "inferring a {}-plane {}x{} MPI from views {:?} (weights {}, config {})",
        depths.len(),
        reference.width,
        reference.height,
        inputs,
        weights.display(),
        config.name
    );
    super::eval::check_learned(&model, &views, &reference, &depths, budget)?;
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
    let out = OutputDir::new(&args.out)?;
    deepview_mpi::write_mpi_with(out.path(), &mpi, Some(&choice.rule))
        .with_context(|| format!("cannot write the MPI to {}", args.out.display()))?;
    out.commit()?;
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
    use super::{DEFAULT_WEIGHTS, parse_bytes, unpack_embedded_weights};
    use deepview_net::weights::{CONFIG_FILE, WEIGHTS_FILE};
    use std::path::Path;

    #[test]
    fn embedded_weights_unpack_to_the_repository_files() {
        // Twice: the second call reuses the unpacked folder.
        for _ in 0..2 {
            let dir = unpack_embedded_weights().unwrap();
            for f in [CONFIG_FILE, WEIGHTS_FILE] {
                let a = std::fs::read(dir.join(f)).unwrap();
                let b = std::fs::read(Path::new(DEFAULT_WEIGHTS).join(f)).unwrap();
                assert!(a == b, "{f} differs from the repository's copy");
            }
        }
        let dev = deepview_net::burn::tensor::Device::flex();
        deepview_net::weights::load_model(&unpack_embedded_weights().unwrap(), &dev).unwrap();
    }

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
