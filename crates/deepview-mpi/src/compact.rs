//! Compaction: fewer planes for the same picture, so that rendering (whose cost grows with the planes a
//! pixel crosses before it is opaque) gets faster. Planes that hold nothing visible are dropped, and runs of
//! neighbouring planes that hold little are merged into one: over-composited front over back at the
//! reference view (exact there), placed at the coverage-weighted mean disparity of the run. Away from the
//! reference view the merged content moves by at most the run's disparity span, which is why only
//! near-empty planes merge (the quality cost is measured in BENCHMARKS.md).

use crate::mpi::Mpi;

/// How [`compact`] decides.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompactOptions {
    /// A plane whose largest alpha is below this is dropped (default 1/510: it rounds to nothing in an
    /// 8-bit layer).
    pub empty_alpha: f32,
    /// Neighbouring planes merge while the run's coverage (the sum of its planes' mean alphas) stays at
    /// most this (default 0.1: a run that covers 10% of the image; on held-out views of learned MPIs it
    /// costs 0.002 SSIM and halves a wide capture's planes, BENCHMARKS.md).
    pub merge_coverage: f32,
    /// At most this many planes merge into one (default 4).
    pub max_run: usize,
}

impl Default for CompactOptions {
    fn default() -> Self {
        Self {
            empty_alpha: 1.0 / 510.0,
            merge_coverage: 0.1,
            max_run: 4,
        }
    }
}

/// What [`compact`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct Compacted {
    pub mpi: Mpi,
    /// Planes dropped as empty.
    pub dropped: usize,
    /// Planes merged away (a run of `k` planes counts `k - 1`).
    pub merged: usize,
}

/// Compact `mpi` (see the module docs). The result keeps at least one plane, its depths decrease, and
/// rendered into the reference camera it equals the input up to f32 rounding and the dropped planes'
/// alphas (below `empty_alpha`).
pub fn compact(mpi: &Mpi, options: &CompactOptions) -> Compacted {
    let n = mpi.plane_len() / 4;
    let planes = mpi.planes();
    let stats: Vec<(f32, f32)> = (0..planes)
        .map(|d| {
            let p = mpi.plane(d);
            let (mut max, mut sum) = (0f32, 0f64);
            for t in p.chunks_exact(4) {
                max = max.max(t[3]);
                sum += t[3] as f64;
            }
            (max, (sum / n.max(1) as f64) as f32)
        })
        .collect();
    let kept: Vec<usize> = (0..planes)
        .filter(|&d| stats[d].0 >= options.empty_alpha)
        .collect();
    let kept = if kept.is_empty() {
        // Keep the one with the most coverage, so the MPI stays an MPI.
        vec![
            (0..planes)
                .max_by(|&a, &b| stats[a].1.total_cmp(&stats[b].1))
                .unwrap_or(0),
        ]
    } else {
        kept
    };
    let dropped = planes - kept.len();
    // Runs of kept planes, back to front.
    let mut runs: Vec<Vec<usize>> = Vec::new();
    for &d in &kept {
        match runs.last_mut() {
            Some(run)
                if run.len() < options.max_run.max(1)
                    && run.iter().map(|&p| stats[p].1).sum::<f32>() + stats[d].1
                        <= options.merge_coverage =>
            {
                run.push(d)
            }
            _ => runs.push(vec![d]),
        }
    }
    let merged = kept.len() - runs.len();
    let mut layers = vec![0f32; runs.len() * n * 4];
    let mut depths = Vec::with_capacity(runs.len());
    for (out, run) in layers.chunks_exact_mut(n * 4).zip(&runs) {
        // Back to front: each plane over what is behind it.
        for &d in run {
            for (o, t) in out.chunks_exact_mut(4).zip(mpi.plane(d).chunks_exact(4)) {
                let keep = 1.0 - t[3];
                for c in 0..4 {
                    o[c] = t[c] + keep * o[c];
                }
            }
        }
        // Coverage-weighted mean disparity; an empty run keeps its middle plane's.
        let weight: f64 = run.iter().map(|&d| stats[d].1 as f64).sum();
        let disparity = if weight > 0.0 {
            run.iter()
                .map(|&d| stats[d].1 as f64 / mpi.depths[d])
                .sum::<f64>()
                / weight
        } else {
            1.0 / mpi.depths[run[run.len() / 2]]
        };
        depths.push(1.0 / disparity);
    }
    Compacted {
        mpi: Mpi {
            camera: mpi.camera,
            depths,
            layers,
        },
        dropped,
        merged,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::{Camera, Intrinsics, Pose};

    fn mpi_with(alphas: &[f32], w: u32, h: u32) -> Mpi {
        let camera = Camera::new(w, h, Intrinsics::centred(w as f64, w, h), Pose::IDENTITY);
        let planes = alphas.len();
        let depths: Vec<f64> = (0..planes).map(|d| 10.0 / (1.0 + d as f64)).collect();
        let mut mpi = Mpi::transparent(camera, depths);
        let n = (w * h) as usize;
        for (d, &a) in alphas.iter().enumerate() {
            for (i, t) in mpi.plane_mut(d).chunks_exact_mut(4).enumerate() {
                // A few texels per plane carry the plane's alpha, with a colour of their own.
                if (i + d) % 7 == 0 || a >= 0.5 {
                    let c = ((i * 13 + d * 5) % 17) as f32 / 17.0;
                    t.copy_from_slice(&[c * a, (1.0 - c) * a, 0.5 * a, a]);
                }
            }
            let _ = n;
        }
        mpi
    }

    /// Empty planes go, near-empty neighbours merge, full planes stay; the reference view is unchanged.
    #[test]
    fn compaction_keeps_the_reference_view() {
        let alphas = [0.9, 0.0, 0.05, 0.05, 0.0005, 0.05, 0.8, 0.05];
        let mpi = mpi_with(&alphas, 21, 13);
        let options = CompactOptions {
            merge_coverage: 0.02,
            ..Default::default()
        };
        let c = compact(&mpi, &options);
        // Plane 1 is empty and plane 4's alpha is below 1/510: dropped.
        assert_eq!(c.dropped, 2);
        assert_eq!(c.merged + c.dropped + c.mpi.planes(), alphas.len());
        assert!(c.merged >= 1, "near-empty neighbours merge");
        assert!(c.mpi.depths.windows(2).all(|w| w[0] > w[1]));
        let a = crate::render(&mpi, &mpi.camera);
        let b = crate::render(&c.mpi, &mpi.camera);
        let diff = a
            .data
            .iter()
            .zip(&b.data)
            .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(diff < 2.0 / 510.0, "reference view changed by {diff}");
        // Nothing to merge under a zero coverage: only the drops.
        let none = compact(
            &mpi,
            &CompactOptions {
                merge_coverage: 0.0,
                ..Default::default()
            },
        );
        assert_eq!((none.dropped, none.merged), (2, 0));
        // An all-empty MPI keeps one plane.
        let empty = compact(&mpi_with(&[0.0, 0.0], 5, 4), &Default::default());
        assert_eq!(empty.mpi.planes(), 1);
    }
}
