//! `deepview bench`: timings printed as one JSON line.

use anyhow::bail;
use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths};
use deepview_mpi::{MpiU8, Occupancy, read_mpi_u8, render_rgba8_with};
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Render an MPI repeatedly into a novel view (8-bit layers, image I/O excluded).
    Render(RenderArgs),
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
    #[arg(long, default_value_t = 30)]
    pub repeats: usize,
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Render(a) => bench_render(a),
    }
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

/// Read bandwidth of this machine with all threads: GB/s for summing a 512 MiB buffer.
fn read_bandwidth() -> f64 {
    let buf = vec![1u64; 64 << 20];
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
    (buf.len() * 8) as f64 / best / 1e9
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
    let mpi = match (&args.mpi, &args.synthetic) {
        (Some(dir), _) => read_mpi_u8(dir)?,
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
            synthetic_mpi(v[0] as u32, v[1] as u32, v[2])?
        }
        (None, None) => bail!("give --mpi DIR or --synthetic WxHxD"),
    };
    let near = *mpi.depths.last().expect("an MPI has planes");
    let camera = match &args.camera {
        Some(p) => super::read_camera_json(p)?,
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
    let bw = read_bandwidth();
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
        "read_bandwidth_gbs": (bw * 100.0).round() / 100.0,
        "bandwidth_limit_fps": (bw * 1e9 / bytes * 10.0).round() / 10.0,
    });
    println!("{line}");
    Ok(())
}
