//! Depth from an MPI: alpha-weighted expected depth and disparity in any view, a false-colour map
//! (turbo) like the paper's depth figures, and a 16-bit disparity PNG.

use crate::composite::render_components;
use crate::mpi::Mpi;
use deepview_geometry::Camera;
use deepview_image::{ImageError, ImageF32, write_png, write_png_u16};
use std::path::Path;

/// Per-pixel maps of one view (`[H][W]` each).
#[derive(Clone, Debug)]
pub struct DepthMaps {
    pub width: u32,
    pub height: u32,
    /// Expected disparity `sum_d w_d / z_d / sum_d w_d` with `w_d = a_d T_d` (the plane's contribution).
    pub disparity: Vec<f32>,
    /// `1 / disparity` (0 where nothing is seen).
    pub depth: Vec<f32>,
    /// `sum_d w_d`: how opaque the MPI is along the ray (1 - final transmittance).
    pub coverage: Vec<f32>,
    /// The disparity range of the MPI's planes `(1/far, 1/near)` for normalisation.
    pub range: (f32, f32),
}

/// Depth maps of `mpi` seen from `target` (the reference camera for the MPI's own depth map).
pub fn depth_maps(mpi: &Mpi, target: &Camera) -> DepthMaps {
    let c = render_components(mpi, target);
    let n = target.width as usize * target.height as usize;
    let mut disparity = vec![0.0f32; n];
    let mut coverage = vec![0.0f32; n];
    for d in 0..mpi.planes() {
        let inv = (1.0 / mpi.depths[d]) as f32;
        for p in 0..n {
            let w = c.warped[(d * n + p) * 4 + 3] * c.transmittance[d * n + p];
            disparity[p] += w * inv;
            coverage[p] += w;
        }
    }
    let depth = disparity
        .iter_mut()
        .zip(&coverage)
        .map(|(disp, &cov)| {
            if cov > 1e-6 {
                *disp /= cov;
                1.0 / *disp
            } else {
                *disp = 0.0;
                0.0
            }
        })
        .collect();
    let range = (
        (1.0 / mpi.depths[0]) as f32,
        (1.0 / mpi.depths[mpi.planes() - 1]) as f32,
    );
    DepthMaps {
        width: target.width,
        height: target.height,
        disparity,
        depth,
        coverage,
        range,
    }
}

impl DepthMaps {
    /// Disparity normalised to 0 (far plane) .. 1 (near plane).
    pub fn normalized_disparity(&self) -> Vec<f32> {
        let (lo, hi) = self.range;
        let span = (hi - lo).max(1e-12);
        self.disparity
            .iter()
            .map(|&d| {
                if d > 0.0 {
                    ((d - lo) / span).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// False-colour image (turbo: far blue, near red), faded to black where the MPI is transparent.
    pub fn false_colour(&self) -> ImageF32 {
        let mut img = ImageF32::new(self.width, self.height, 3);
        for ((o, v), cov) in img
            .data
            .chunks_exact_mut(3)
            .zip(self.normalized_disparity())
            .zip(&self.coverage)
        {
            let c = turbo(v);
            for k in 0..3 {
                o[k] = c[k] * cov.clamp(0.0, 1.0);
            }
        }
        img
    }

    /// Write `<prefix>_color.png` (false colour) and `<prefix>_disparity16.png` (normalised disparity,
    /// 0 = far plane, 65535 = near plane; the range is in the MPI's `mpi.json` depths).
    pub fn write(&self, dir: &Path, prefix: &str) -> Result<(), ImageError> {
        std::fs::create_dir_all(dir).map_err(|source| ImageError::Write {
            path: dir.into(),
            source,
        })?;
        write_png(
            &dir.join(format!("{prefix}_color.png")),
            &self.false_colour(),
        )?;
        let d16: Vec<u16> = self
            .normalized_disparity()
            .iter()
            .map(|v| (v * 65535.0 + 0.5) as u16)
            .collect();
        write_png_u16(
            &dir.join(format!("{prefix}_disparity16.png")),
            self.width,
            self.height,
            &d16,
        )
    }
}

/// The turbo colour map (polynomial approximation), `x` in 0..1.
pub fn turbo(x: f32) -> [f32; 3] {
    let x = x.clamp(0.0, 1.0);
    let poly = |c: [f32; 6]| c[0] + x * (c[1] + x * (c[2] + x * (c[3] + x * (c[4] + x * c[5]))));
    [
        poly([
            0.135_721_38,
            4.615_392_6,
            -42.660_324,
            132.131_08,
            -152.942_39,
            59.286_38,
        ])
        .clamp(0.0, 1.0),
        poly([
            0.091_402_61,
            2.194_188_4,
            4.842_966_6,
            -14.185_033,
            4.277_298_6,
            2.829_566,
        ])
        .clamp(0.0, 1.0),
        poly([
            0.106_673_3,
            12.641_946,
            -60.582_05,
            110.362_77,
            -89.903_11,
            27.348_25,
        ])
        .clamp(0.0, 1.0),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::{Intrinsics, Pose};

    #[test]
    fn opaque_plane_gives_its_depth() {
        let cam = Camera::new(8, 6, Intrinsics::centred(8.0, 8, 6), Pose::IDENTITY);
        let mut mpi = Mpi::transparent(cam, vec![8.0, 4.0, 2.0]);
        // Plane 1 (depth 4) opaque on the left half, plane 0 (depth 8) opaque everywhere.
        for p in mpi.plane_mut(0).chunks_exact_mut(4) {
            p.copy_from_slice(&[0.5, 0.5, 0.5, 1.0]);
        }
        for (i, p) in mpi.plane_mut(1).chunks_exact_mut(4).enumerate() {
            if i % 8 < 4 {
                p.copy_from_slice(&[0.2, 0.2, 0.2, 1.0]);
            }
        }
        let m = depth_maps(&mpi, &cam);
        for (i, d) in m.depth.iter().enumerate() {
            let expect = if i % 8 < 4 { 4.0 } else { 8.0 };
            assert!((d - expect).abs() < 1e-5, "{i}: {d}");
        }
        assert!(m.coverage.iter().all(|c| (c - 1.0).abs() < 1e-6));
        let n = m.normalized_disparity();
        assert!(n[0] > 0.0 && n[7] == 0.0);
        // Half-transparent near plane: disparity between the two.
        for p in mpi.plane_mut(2).chunks_exact_mut(4) {
            p.copy_from_slice(&[0.0, 0.0, 0.0, 0.5]);
        }
        let m = depth_maps(&mpi, &cam);
        let expect = 0.5 * 0.5 + 0.5 / 8.0;
        assert!((m.disparity[7] - expect).abs() < 1e-6);
    }

    #[test]
    fn turbo_endpoints() {
        // Turbo runs blue (far) -> green -> red (near): the dominant channel at 0.15, 0.5 and 0.9.
        let argmax = |c: [f32; 3]| (0..3).max_by(|&a, &b| c[a].total_cmp(&c[b])).unwrap();
        assert_eq!(argmax(turbo(0.15)), 2, "{:?}", turbo(0.15));
        assert_eq!(argmax(turbo(0.5)), 1, "{:?}", turbo(0.5));
        assert_eq!(argmax(turbo(0.9)), 0, "{:?}", turbo(0.9));
    }
}
