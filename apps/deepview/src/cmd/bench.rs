//! `deepview bench`: timings printed as one JSON line.

use super::args;
use anyhow::bail;
use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths};
use deepview_mpi::{MpiU8, Occupancy, read_mpi, render_rgba8_with};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Render an MPI repeatedly into a novel view (8-bit layers, image I/O excluded).
    Render(RenderArgs),
    /// The learned model's whole forward pass as `infer` computes it (plane sweeps, gradient
    /// components, every net; tiled within --max-memory) on synthetic views; no image I/O.
    Net(NetArgs),
    /// Median time of a whole training step (VGG loss, backward, clipping, Adam) after warm-up.
    Train(TrainArgs),
    /// Median time to make one procedural training scene (`train --data synthetic:procedural`).
    Scenes(ScenesArgs),
}

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  deepview bench scenes --count 20\n  \
    deepview bench scenes --data ../shared/data/llff/fern --images images_8   # photo textures")]
pub struct ScenesArgs {
    /// Scenes made (seeds 0..COUNT).
    #[arg(long, default_value_t = 20, value_parser = args::parse_positive)]
    pub count: usize,
    /// A dataset whose views lend the textures (default: noise textures only).
    #[arg(long)]
    pub data: Option<PathBuf>,
    #[command(flatten)]
    pub scene: deepview_data::SceneArgs,
}

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  deepview bench net --preset cpu --views 4 --planes 32 --size 575x412\n  \
    deepview bench net --weights weights/cpu --views 4 --planes 32 --size 504x378\n  \
    deepview bench net --preset cpu --engine burn   # burn's own conv2d instead of the kernels"
)]
pub struct NetArgs {
    /// Weights folder or checkpoint; default: `--preset` with random weights.
    #[arg(long, conflicts_with = "preset")]
    pub weights: Option<PathBuf>,
    /// Architecture preset (random weights): cpu, paper-kalantari, paper-spaces-4view, ...
    #[arg(long, default_value = "cpu")]
    pub preset: String,
    #[arg(long, default_value_t = 4, value_parser = args::parse_view_count)]
    pub views: usize,
    #[arg(long, default_value_t = 32, value_parser = args::parse_plane_count)]
    pub planes: usize,
    /// MPI size WIDTHxHEIGHT (the input views have the same size).
    #[arg(long, default_value = "575x412")]
    pub size: String,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
    /// Timed forward passes (after one warm-up pass).
    #[arg(long, default_value_t = 1, value_parser = args::parse_positive)]
    pub repeats: usize,
    /// Device: cpu, wgpu, wgpu:N, wgpu:cpu, cuda, cuda:N (GPU devices in builds with their feature).
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples (VGG=../shared/data/vgg16/vgg16_conv1_1-conv3_3.safetensors):\n  \
    deepview bench train --preset cpu --views 4 --planes 32 --crop 16 --vgg-weights $VGG\n  \
    deepview bench train --preset paper-spaces-4view --views 4 --planes 8 --crop 16 --steps 3 --vgg-weights $VGG"
)]
pub struct TrainArgs {
    #[arg(long, default_value = "cpu")]
    pub preset: String,
    #[arg(long, default_value_t = 4, value_parser = args::parse_view_count)]
    pub views: usize,
    #[arg(long, default_value_t = 32, value_parser = args::parse_plane_count)]
    pub planes: usize,
    /// Target crop side in pixels.
    #[arg(long, default_value_t = 16, value_parser = args::parse_positive)]
    pub crop: usize,
    /// Timed steps (after 2 warm-up steps).
    #[arg(long, default_value_t = 5, value_parser = args::parse_positive)]
    pub steps: usize,
    /// Recompute each net's activations in the backward pass (default: the preset's training default).
    #[arg(long)]
    pub recompute: Option<bool>,
    /// The VGG-16 weights of the VGG loss (vgg16_conv1_1-conv3_3.safetensors).
    #[arg(long, value_name = "FILE")]
    pub vgg_weights: Option<PathBuf>,
    /// Device: cpu, wgpu, wgpu:N, wgpu:cpu, cuda, cuda:N (as `train --devices`; GPU devices in builds with
    /// their feature).
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  deepview bench render --synthetic 1008x756x32\n  \
    deepview bench render --mpi mpi/ --camera cam.json --repeats 50"
)]
pub struct RenderArgs {
    /// MPI folder.
    #[arg(long, required_unless_present = "synthetic")]
    pub mpi: Option<PathBuf>,
    /// A built-in MPI of the given size instead of a folder, `WIDTHxHEIGHTxPLANES` (every plane textured
    /// and partly transparent).
    #[arg(long, conflicts_with = "mpi")]
    pub synthetic: Option<String>,
    /// Camera JSON; default: a novel view (the reference camera moved sideways and turned slightly).
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Timed renders (after 3 warm-up renders).
    #[arg(long, default_value_t = 30, value_parser = args::parse_positive)]
    pub repeats: usize,
    #[arg(long, value_name = "SIZE", help = args::MEMORY_HELP, value_parser = args::parse_memory)]
    pub max_memory: Option<String>,
}

/// The most repetitions a benchmark takes (more is a typo, and would allocate its timings first).
const MAX_REPEATS: usize = 100_000;

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    let (what, n) = match &cmd {
        BenchCommand::Render(a) => ("--repeats", a.repeats),
        BenchCommand::Net(a) => ("--repeats", a.repeats),
        BenchCommand::Train(a) => ("--steps", a.steps),
        BenchCommand::Scenes(a) => ("--count", a.count),
    };
    if n > MAX_REPEATS {
        anyhow::bail!("{what} {n} is more than a benchmark needs (at most {MAX_REPEATS})");
    }
    match cmd {
        BenchCommand::Render(a) => bench_render(a),
        BenchCommand::Net(a) => bench_net(a),
        BenchCommand::Train(a) => bench_train(a),
        BenchCommand::Scenes(a) => bench_scenes(a),
    }
}

fn bench_scenes(args: ScenesArgs) -> anyhow::Result<()> {
    use deepview_synth::procedural::{ProceduralOptions, generate};
    let photos = match &args.data {
        Some(d) => {
            let scene = args::load_scene_noted(d, &args.scene.load_options())?;
            (0..scene.len())
                .map(|i| scene.load_image(i))
                .collect::<Result<Vec<_>, _>>()?
        }
        None => Vec::new(),
    };
    let refs: Vec<&deepview_image::ImageF32> = photos.iter().collect();
    let opts = ProceduralOptions::default();
    let (mut times, mut views) = (Vec::new(), 0);
    for seed in 0..args.count as u64 {
        let t = std::time::Instant::now();
        let s = generate(seed, &refs, &opts);
        times.push(t.elapsed().as_secs_f64());
        views += s.cameras.len();
    }
    times.sort_by(f64::total_cmp);
    let line = serde_json::json!({
        "scene_ms": (times[times.len() / 2] * 1e4).round() / 10.0,
        "views_per_scene": views as f64 / args.count as f64,
        "width": opts.width,
        "height": opts.height,
        "supersample": opts.supersample,
        "photo_textures": refs.len(),
        "threads": rayon::current_num_threads(),
    });
    println!("{line}");
    Ok(())
}

/// A dense MPI: every plane textured, alpha varying between 0 and 0.5 (like a network's output).
pub fn synthetic_mpi(w: u32, h: u32, d: usize) -> anyhow::Result<MpiU8> {
    let camera = Camera::new(
        w,
        h,
        Intrinsics::centred(0.8 * w as f64, w, h),
        Pose::IDENTITY,
    );
    let depths = plane_depths(1.0, 100.0, d, PlaneSpacing::InverseDepth)?;
    let plane = w as usize * h as usize * 4;
    let mut layers = vec![0u8; plane * d];
    layers.par_chunks_mut(plane).enumerate().for_each(|(p, l)| {
        for (i, t) in l.chunks_exact_mut(4).enumerate() {
            let (x, y) = (i % w as usize, i / w as usize);
            let a = (((x * 7 + y * 3 + p * 31) % 128) as u32) as u8;
            let c = |s: usize| (((x * s + y * (s + 1) + p) % 256) as u32 * a as u32 / 255) as u8;
            t.copy_from_slice(&[c(3), c(5), c(7), a]);
        }
    });
    Ok(MpiU8 {
        camera,
        depths,
        layers,
    })
}

/// The default novel view: 2% of the near depth to the side, 1% up, 0.5 degrees of rotation.
pub fn novel_view(reference: &Camera, near: f64) -> Camera {
    let r = DMat3::from_rotation_y(0.5f64.to_radians()) * reference.pose.rotation;
    let centre = reference.center()
        + reference.pose.rotation.transpose() * DVec3::new(0.02 * near, -0.01 * near, 0.0);
    Camera {
        pose: Pose::from_center(r, centre),
        ..*reference
    }
}

/// Read bandwidth of this machine with all threads: GB/s for summing a buffer of `bytes` (512 MiB, or
/// what the memory budget leaves; `None` below 64 MiB, where caches would be measured, not memory).
fn read_bandwidth(bytes: u64) -> Option<f64> {
    let bytes = bytes.min(512 << 20);
    if bytes < 64 << 20 {
        return None;
    }
    let buf = vec![1u64; (bytes / 8) as usize];
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let t = Instant::now();
        let s: u64 = buf
            .par_chunks(1 << 16)
            .map(|c| c.iter().fold(0u64, |a, &b| a.wrapping_add(b)))
            .sum();
        std::hint::black_box(s);
        best = best.min(t.elapsed().as_secs_f64());
    }
    Some((buf.len() * 8) as f64 / best / 1e9)
}

/// User + system CPU time of this process (Linux `/proc/self/stat`, clock ticks of 10 ms).
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn bench_render(args: RenderArgs) -> anyhow::Result<()> {
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let camera_file = args
        .camera
        .as_deref()
        .map(super::read_camera_json)
        .transpose()?;
    // The MPI's size, and the render's (the MPI's own size for the default novel view).
    let check = |w: u32, h: u32, planes: usize| {
        let cam = camera_file.unwrap_or(Camera::new(
            w,
            h,
            Intrinsics::centred(w as f64, w, h),
            Pose::IDENTITY,
        ));
        args::check_memory(
            &format!(
                "rendering {}x{} from a {planes}-plane {w}x{h} MPI",
                cam.width, cam.height
            ),
            args::mpi_bytes(w, h, planes, true)
                .saturating_add(args::render_bytes(&cam).saturating_mul(2)),
            budget,
        )
    };
    let mpi = match (&args.mpi, &args.synthetic) {
        (Some(dir), _) => {
            super::check_deepview_mpi("--mpi", dir)?;
            let (meta, _) = deepview_mpi::MpiMeta::read(dir)?;
            check(meta.width, meta.height, meta.depths.len())?;
            read_mpi::<u8>(dir)?
        }
        (None, Some(spec)) => {
            let v: Vec<usize> = spec
                .split('x')
                .map(|s| s.trim().parse())
                .collect::<Result<_, _>>()
                .map_err(|_| {
                    anyhow::anyhow!(
                        "--synthetic takes WIDTHxHEIGHTxPLANES, e.g. 1008x756x32 (got {spec:?})"
                    )
                })?;
            if v.len() != 3 || v.contains(&0) {
                bail!("--synthetic takes WIDTHxHEIGHTxPLANES with positive numbers (got {spec:?})");
            }
            if v[0] > u32::MAX as usize || v[1] > u32::MAX as usize {
                bail!("--synthetic {spec}: the size is too large");
            }
            check(v[0] as u32, v[1] as u32, v[2])?;
            synthetic_mpi(v[0] as u32, v[1] as u32, v[2])?
        }
        (None, None) => bail!("give --mpi DIR or --synthetic WxHxD"),
    };
    let near = *mpi.depths.last().expect("an MPI has planes");
    let camera = match camera_file {
        Some(c) => c,
        None => novel_view(&mpi.camera, near),
    };
    // The occupancy of the planes' tiles is computed once per MPI (as a viewer does), not per frame.
    let occupancy = Occupancy::new(
        &mpi.layers,
        mpi.camera.width,
        mpi.camera.height,
        mpi.planes(),
    );
    let (mut scratch, mut out) = (Vec::new(), Vec::new());
    for _ in 0..3 {
        render_rgba8_with(&mpi, Some(&occupancy), &camera, &mut scratch, &mut out);
    }
    let cpu0 = process_cpu_seconds();
    let mut times: Vec<f64> = (0..args.repeats.max(1))
        .map(|_| {
            let t = Instant::now();
            render_rgba8_with(&mpi, Some(&occupancy), &camera, &mut scratch, &mut out);
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    let cpu_ms = process_cpu_seconds()
        .zip(cpu0)
        .map(|(b, a)| (b - a) * 1e3 / times.len() as f64);
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    let bytes = mpi.layers.len() as f64;
    // The bandwidth's buffer within the budget, beside the MPI and the render's buffers.
    let held = mpi.layers.len() as u64 + 4 * (scratch.capacity() + out.capacity()) as u64;
    let bw = read_bandwidth(budget.saturating_sub(held));
    let line = serde_json::json!({
        "median_ms": (median * 1000.0).round() / 1000.0,
        "fps": ((1000.0 / median) * 10.0).round() / 10.0,
        "planes": mpi.planes(),
        "width": camera.width,
        "height": camera.height,
        "mpi_width": mpi.camera.width,
        "mpi_height": mpi.camera.height,
        "threads": rayon::current_num_threads(),
        "cpu_ms_per_render": cpu_ms.map(|v| (v * 10.0).round() / 10.0),
        "layer_bytes": bytes as u64,
        "occupied_tiles": (occupancy.fill() * 1000.0).round() / 1000.0,
        "read_bandwidth_gbs": bw.map(|bw| (bw * 100.0).round() / 100.0),
        "bandwidth_limit_fps": bw.map(|bw| (bw * 1e9 / bytes * 10.0).round() / 10.0),
    });
    println!("{line}");
    Ok(())
}

/// The process's peak resident memory (`VmHWM`) in MiB, if known.
pub(crate) fn peak_rss_mb() -> Option<f64> {
    let kb = args::proc_status_kb("VmHWM")?;
    Some((kb as f64 / 1024.0).round())
}

fn parse_size(spec: &str) -> anyhow::Result<(usize, usize)> {
    let v: Vec<usize> = spec
        .split('x')
        .map(|s| s.trim().parse())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--size takes WIDTHxHEIGHT, e.g. 575x412 (got {spec:?})"))?;
    if v.len() != 2 || v.contains(&0) {
        bail!("--size takes WIDTHxHEIGHT with positive numbers (got {spec:?})");
    }
    Ok((v[0], v[1]))
}

fn bench_net(args: NetArgs) -> anyhow::Result<()> {
    use deepview_net::config::DeepViewConfig;
    use deepview_net::infer::{run, synthetic_views};
    use deepview_net::network::DeepViewModel;
    let (w, h) = parse_size(&args.size)?;
    if args.views == 0 || args.planes == 0 {
        bail!("--views and --planes must be positive");
    }
    let device = deepview_net::device::parse_device(&args.device)?;
    let (model, name) = match &args.weights {
        Some(dir) => {
            let (mut m, c) = deepview_net::weights::load_model(dir, &device)?;
            // The prior's radius at this size, as inference runs it (`DeepViewConfig::prior_radius_at`;
            // 0 for a model without the prior, as its config validates to).
            m.prior_radius = c.prior_radius_at(u32::try_from(w.max(h)).unwrap_or(u32::MAX));
            (m, c.name)
        }
        None => {
            let cfg = DeepViewConfig::preset(&args.preset)?;
            // Random weights laid out as loaded ones are (channels-last on a GPU), so that the
            // timing is inference's, without a weight copy at every convolution.
            let model = deepview_net::device::weights_layout(DeepViewModel::new(&cfg, &device));
            (model, cfg.name)
        }
    };
    let budget = args::memory_budget(args.max_memory.as_deref())?;
    let px = (w as u64).saturating_mul(h as u64);
    args::check_memory(
        &format!("{} synthetic {w}x{h} views", args.views),
        px.saturating_mul(12)
            .saturating_mul(args.views as u64 + 1)
            .saturating_add(px.saturating_mul(args.planes as u64).saturating_mul(8)),
        budget,
    )?;
    let (views, reference, depths) = synthetic_views(args.views, args.planes, w, h);
    let plan = deepview_methods::check_learned(&model, &views, &reference, &depths, budget)?;
    let mut times = Vec::new();
    for i in 0..=args.repeats.max(1) {
        let t = Instant::now();
        let mpi = run(&model, &views, &reference, &depths, &plan, &mut |_| {})?;
        std::hint::black_box(&mpi.layers);
        if i > 0 {
            times.push(t.elapsed().as_secs_f64());
        }
    }
    times.sort_by(f64::total_cmp);
    let line = serde_json::json!({
        "forward_s": (times[times.len() / 2] * 1000.0).round() / 1000.0,
        "nets": model.nets.len(),
        "views": args.views,
        "planes": args.planes,
        "width": w,
        "height": h,
        "peak_rss_mb": peak_rss_mb(),
        "model": name,
        "engine": if deepview_net::cpu::ops::fast_device(&device) { "kernels" } else { "burn" },
        "plan": plan.describe(),
        "peak_estimate_mb": plan.peak_bytes >> 20,
        "threads": rayon::current_num_threads(),
    });
    println!("{line}");
    Ok(())
}

fn bench_train(args: TrainArgs) -> anyhow::Result<()> {
    use deepview_net::config::DeepViewConfig;
    use deepview_train::{
        DataSpec, RunConfig, SYNTHETIC_TWO_PLANES, TrainConfig, Trainer, load_data,
    };
    let model = DeepViewConfig::preset(&args.preset)?;
    let mut train = TrainConfig::defaults(&model);
    train.data = vec![DataSpec::new(SYNTHETIC_TWO_PLANES, Default::default())];
    train.sample.views_min = args.views;
    train.sample.views_max = args.views;
    train.sample.planes = args.planes;
    train.sample.crop = args.crop;
    train.vgg_weights = args.vgg_weights.clone();
    deepview_net::device::parse_device(&args.device)?;
    train.devices = vec![args.device.clone()];
    if let Some(r) = args.recompute {
        train.recompute = r;
    }
    let recompute = train.recompute;
    let data = load_data(&train.data, train.holdout_every)?;
    let dir = std::env::temp_dir().join(format!("deepview-bench-train-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    // The tuple with the most slice pixels (views x planes x window pixels) and its memory estimate.
    let mut largest = (0usize, 0u64);
    let result = (|| -> anyhow::Result<Vec<f64>> {
        let mut trainer = Trainer::create(&dir, RunConfig { model, train }, data)?;
        let mut times = Vec::new();
        for i in 0..args.steps.max(1) + 2 {
            let batch = trainer.draw_batch()?;
            for ex in &batch {
                let slices = ex.inputs.len() * ex.depths.len() * ex.window.2 * ex.window.3;
                largest = largest.max((slices, ex.step_bytes(&trainer.config.model, recompute)));
            }
            let t = Instant::now();
            let r = trainer.step_on(batch);
            if let Some(why) = r.skipped {
                bail!("{why}");
            }
            if i >= 2 {
                times.push(t.elapsed().as_secs_f64());
            }
        }
        Ok(times)
    })();
    let _ = std::fs::remove_dir_all(&dir);
    let mut times = result?;
    times.sort_by(f64::total_cmp);
    let line = serde_json::json!({
        "step_s": (times[times.len() / 2] * 1000.0).round() / 1000.0,
        "min_s": (times[0] * 1000.0).round() / 1000.0,
        "preset": args.preset,
        "views": args.views,
        "planes": args.planes,
        "crop": args.crop,
        "recompute": recompute,
        "steps": times.len(),
        "peak_rss_mb": peak_rss_mb(),
        "largest_slice_px": largest.0,
        "largest_estimate_mb": largest.1 >> 20,
        "engine": if deepview_net::cpu::ops::fast_device(&deepview_net::burn::tensor::Device::flex()) { "kernels" } else { "burn" },
        "device": args.device,
    });
    println!("{line}");
    Ok(())
}
