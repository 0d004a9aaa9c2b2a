//! `deepview diff A B`: how far apart two MPIs of the same planes are (e.g. the GPU's and the CPU
//! engine's inference of the same views), in 8-bit steps of premultiplied RGBA.

use anyhow::{Context, bail};
use std::path::PathBuf;

/// Compare two MPIs texel by texel: the largest difference of premultiplied RGBA (what renders see;
/// the stored straight colour of a nearly transparent texel is ill-conditioned) and of alpha, in 8-bit
/// steps, and how many texels differ. Prints one line and a JSON line; exit status 1 when `--max` is
/// given and exceeded.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    deepview infer --data ../shared/data/llff/fern --images images_8 --planes 32 --out fern_cpu\n  \
    deepview infer --data ../shared/data/llff/fern --images images_8 --planes 32 --device wgpu --out fern_gpu\n  \
    deepview diff fern_cpu fern_gpu --max 1")]
pub struct Args {
    /// First MPI folder.
    #[arg(value_name = "MPI_A")]
    pub a: PathBuf,
    /// Second MPI folder: the same planes (count and depths) and size.
    #[arg(value_name = "MPI_B")]
    pub b: PathBuf,
    /// Exit with status 1 when premultiplied RGBA differs by more than this many 8-bit steps.
    #[arg(long, value_name = "STEPS", value_parser = parse_steps)]
    pub max: Option<f64>,
    #[arg(long, value_name = "SIZE", help = super::args::MEMORY_HELP, value_parser = super::args::parse_memory)]
    pub max_memory: Option<String>,
}

/// `--max`: a finite number of 8-bit steps from 0 to 255 (NaN or infinity would switch the check off, a
/// negative bound fail every comparison).
fn parse_steps(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=255.0).contains(&v) => Ok(v),
        Ok(_) => Err(format!(
            "{s:?} must be a number of 8-bit steps from 0 to 255"
        )),
        Err(_) => Err(format!("{s:?} is not a number")),
    }
}

/// What [`compare`] found.
#[derive(Debug, PartialEq)]
pub struct Difference {
    /// Largest |a - b| of premultiplied RGBA, in 8-bit steps.
    pub max: f64,
    /// Largest |a - b| of alpha, in 8-bit steps.
    pub max_alpha: f64,
    /// Texels whose premultiplied RGBA differs by more than half a step.
    pub differing: usize,
    pub texels: usize,
}

/// Compare two MPIs' premultiplied layers (same planes, depths and size, else an error naming them).
pub fn compare(
    a: &deepview_mpi::Mpi,
    b: &deepview_mpi::Mpi,
    names: (&str, &str),
) -> anyhow::Result<Difference> {
    let size = |m: &deepview_mpi::Mpi| (m.planes(), m.camera.width, m.camera.height);
    if size(a) != size(b) {
        let ((pa, wa, ha), (pb, wb, hb)) = (size(a), size(b));
        bail!(
            "{} has {pa} planes of {wa}x{ha} but {} has {pb} planes of {wb}x{hb}",
            names.0,
            names.1
        );
    }
    // Texels compare only where both MPIs' planes lie alike in the world: one reference camera.
    let cam = |m: &deepview_mpi::Mpi| {
        let k = m.camera.intrinsics;
        let mut v = vec![k.fx, k.fy, k.cx, k.cy];
        v.extend(m.camera.pose.to_row_major());
        v
    };
    let (ca, cb) = (cam(a), cam(b));
    let scale = ca.iter().chain(&cb).fold(1.0f64, |m, v| m.max(v.abs()));
    if ca
        .iter()
        .zip(&cb)
        .any(|(x, y)| (x - y).abs() > 1e-6 * scale)
    {
        bail!(
            "{} and {} have different reference cameras (focal length, principal point or pose): their \
             planes lie elsewhere, so their texels cannot be compared",
            names.0,
            names.1
        );
    }
    if let Some(d) = (0..a.planes())
        .find(|&d| (a.depths[d] - b.depths[d]).abs() > 1e-6 * a.depths[d].abs().max(1e-12))
    {
        bail!(
            "plane {d} is at depth {} in {} but {} in {}",
            a.depths[d],
            names.0,
            b.depths[d],
            names.1
        );
    }
    let (mut max, mut max_alpha, mut differing) = (0f64, 0f64, 0);
    for (x, y) in a.layers.chunks_exact(4).zip(b.layers.chunks_exact(4)) {
        let d = |c: usize| (x[c] as f64 - y[c] as f64).abs() * 255.0;
        let m = (0..4).map(d).fold(0.0, f64::max);
        max = max.max(m);
        max_alpha = max_alpha.max(d(3));
        differing += usize::from(m > 0.5);
    }
    // Stored layers are 8-bit: round off the f32 conversions' last bits (1.0000037 steps is 1).
    let steps = |v: f64| (v * 1e4).round() / 1e4;
    Ok(Difference {
        max: steps(max),
        max_alpha: steps(max_alpha),
        differing,
        texels: a.layers.len() / 4,
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let read = |p: &PathBuf| {
        deepview_mpi::read_mpi::<f32>(p)
            .with_context(|| format!("cannot read the MPI {}", p.display()))
    };
    super::check_deepview_mpi("MPI_A", &args.a)?;
    super::check_deepview_mpi("MPI_B", &args.b)?;
    let budget = super::args::memory_budget(args.max_memory.as_deref())?;
    super::args::check_mpis_fit("comparing", &[&args.a, &args.b], false, 1, budget)?;
    let (a, b) = (read(&args.a)?, read(&args.b)?);
    let (na, nb) = (args.a.display().to_string(), args.b.display().to_string());
    let d = compare(&a, &b, (&na, &nb))?;
    println!(
        "{na} vs {nb}: premultiplied RGBA differs by at most {:.2}/255 (alpha {:.2}/255); {} of {} texels differ by more than half a step",
        d.max, d.max_alpha, d.differing, d.texels
    );
    println!(
        "{}",
        serde_json::json!({
            "a": na, "b": nb, "max_diff_255": d.max, "max_alpha_diff_255": d.max_alpha,
            "differing_texels": d.differing, "texels": d.texels,
        })
    );
    if let Some(limit) = args.max
        && d.max > limit
    {
        eprintln!("over --max {limit}");
        std::process::exit(1);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::{Camera, Intrinsics, Pose};

    fn mpi(values: &[f32], depths: Vec<f64>) -> deepview_mpi::Mpi {
        let camera = Camera::new(2, 1, Intrinsics::new(10.0, 10.0, 1.0, 0.5), Pose::default());
        deepview_mpi::Mpi {
            camera,
            depths,
            layers: values.to_vec(),
        }
    }

    #[test]
    fn max_is_a_number_of_steps() {
        for ok in ["0", "1", "0.5", " 255 "] {
            assert!(parse_steps(ok).is_ok(), "{ok}");
        }
        // NaN and infinity would pass any difference, a negative bound none.
        for bad in ["nan", "NaN", "inf", "-inf", "-1", "256", "one", ""] {
            assert!(parse_steps(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn differences_in_8_bit_steps() {
        let a = mpi(&[0.5, 0.5, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0], vec![2.0]);
        let b = mpi(&[0.5, 0.5, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0], vec![2.0]);
        let same = compare(&a, &b, ("a", "b")).unwrap();
        assert_eq!((same.max, same.differing, same.texels), (0.0, 0, 2));
        // 3/255 on green of texel 1 and 1/255 on its alpha.
        let c = mpi(
            &[0.5, 0.5, 0.5, 0.5, 0.0, 3.0 / 255.0, 0.0, 1.0 / 255.0],
            vec![2.0],
        );
        let d = compare(&a, &c, ("a", "c")).unwrap();
        assert!((d.max - 3.0).abs() < 1e-4 && (d.max_alpha - 1.0).abs() < 1e-4);
        assert_eq!(d.differing, 1);
        // Another reference camera is an error naming both.
        let mut moved = mpi(&[0.0; 8], vec![2.0]);
        moved.camera.intrinsics.fx = 100.0;
        let e = compare(&a, &moved, ("a", "m")).unwrap_err();
        assert!(
            e.to_string()
                .contains("a and m have different reference cameras"),
            "{e}"
        );
        let mut moved = mpi(&[0.0; 8], vec![2.0]);
        moved.camera.pose = Pose::from_center(
            deepview_geometry::DMat3::IDENTITY,
            deepview_geometry::DVec3::new(5.0, 0.0, 0.0),
        );
        assert!(compare(&a, &moved, ("a", "m")).is_err());
        // Other planes or sizes are an error naming both.
        let e = compare(&a, &mpi(&[0.0; 8], vec![3.0]), ("a", "z")).unwrap_err();
        assert!(e.to_string().contains("depth 2 in a but 3 in z"), "{e}");
        let e = compare(&a, &mpi(&[0.0; 16], vec![2.0, 1.0]), ("a", "z")).unwrap_err();
        assert!(
            e.to_string().contains("a has 1 planes of 2x1 but z has 2"),
            "{e}"
        );
    }
}
