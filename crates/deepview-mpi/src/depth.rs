//! Depth from an MPI: alpha-weighted expected depth and disparity in any view, a false-colour map
//! (turbo) like the paper's depth figures, and a 16-bit disparity PNG.

use crate::mpi::{Mpi, Texel};
use crate::warp::{Sampler, target_to_plane_homographies};
use deepview_geometry::Camera;
use deepview_image::{ImageError, ImageF32, write_png, write_png_u16};
use rayon::prelude::*;
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
///
/// Each plane's contribution `w_d = a_d T_d` is composited back to front as the renderer composites
/// colour (`disparity <- disparity (1 - a) + a / z_d`, `coverage <- coverage (1 - a) + a`, the same
/// bilinear taps), row by row: no per-plane warped stack, so the memory is the MPI and the maps.
pub fn depth_maps<T: Texel>(mpi: &Mpi<T>, target: &Camera) -> DepthMaps {
    let (w, h) = (target.width as usize, target.height as usize);
    let n = w * h;
    let homs = target_to_plane_homographies(&mpi.camera, target, &mpi.depths);
    let samplers: Vec<Sampler> = homs
        .iter()
        .map(|m| Sampler::new(*m, mpi.camera.width, mpi.camera.height))
        .collect();
    let plane_len = mpi.camera.width as usize * mpi.camera.height as usize * 4;
    let mut disparity = vec![0.0f32; n];
    let mut coverage = vec![0.0f32; n];
    disparity
        .par_chunks_mut(w.max(1))
        .zip(coverage.par_chunks_mut(w.max(1)))
        .enumerate()
        .for_each(|(y, (disp, cov))| {
            for (d, sampler) in samplers.iter().enumerate() {
                let layer = &mpi.layers[d * plane_len..(d + 1) * plane_len];
                let inv = (1.0 / mpi.depths[d]) as f32;
                let row = sampler.row(y as u32);
                for x in 0..w {
                    let Some(tap) = row.tap(x as u32) else {
                        continue;
                    };
                    let a: f32 = (0..4)
                        .map(|k| tap.w[k] * T::rgba(layer, tap.idx[k] as usize)[3])
                        .sum();
                    disp[x] = disp[x] * (1.0 - a) + a * inv;
                    cov[x] = cov[x] * (1.0 - a) + a;
                }
            }
        });
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

    /// The streaming composite equals the sum of the planes' contributions `a_d T_d` from
    /// [`crate::render_components`] (the renderer's warped alpha and transmittance), in a view that
    /// sees the planes with parallax and past their edges; the 8-bit MPI gives the same maps.
    #[test]
    fn maps_equal_the_planes_contributions() {
        let cam = Camera::new(23, 17, Intrinsics::centred(20.0, 23, 17), Pose::IDENTITY);
        let depths = vec![9.0, 5.0, 3.0, 2.0];
        let mut mpi = Mpi::transparent(cam, depths.clone());
        let mut state = 7u32;
        for v in mpi.layers.chunks_exact_mut(4) {
            state = state.wrapping_mul(1664525).wrapping_add(1013904223);
            let a = (state >> 24) as f32 / 255.0;
            v.copy_from_slice(&[0.3 * a, 0.5 * a, 0.1 * a, a]);
        }
        let target = Camera {
            pose: Pose::from_center(
                deepview_geometry::DMat3::from_rotation_y(0.05),
                deepview_geometry::DVec3::new(0.4, -0.2, 0.1),
            ),
            ..cam
        };
        let m = depth_maps(&mpi, &target);
        let c = crate::render_components(&mpi, &target);
        let n = 23 * 17;
        for p in 0..n {
            let (mut disp, mut cov) = (0.0f64, 0.0f64);
            for (d, z) in depths.iter().enumerate() {
                let wgt = (c.warped[(d * n + p) * 4 + 3] * c.transmittance[d * n + p]) as f64;
                disp += wgt / z;
                cov += wgt;
            }
            assert!((m.coverage[p] as f64 - cov).abs() < 1e-5, "{p}");
            let disp = if cov > 1e-6 { disp / cov } else { 0.0 };
            assert!(
                (m.disparity[p] as f64 - disp).abs() < 1e-5,
                "{p}: {} {disp}",
                m.disparity[p]
            );
        }
        assert!(m.coverage.iter().any(|&c| c < 0.5) && m.coverage.iter().any(|&c| c > 0.9));
        let bytes = Mpi::<u8> {
            camera: cam,
            depths: depths.clone(),
            layers: mpi
                .layers
                .iter()
                .map(|&v| (v * 255.0).round() as u8)
                .collect(),
        };
        let m8 = depth_maps(&bytes, &target);
        for p in 0..n {
            assert!((m8.disparity[p] - m.disparity[p]).abs() < 2e-3, "{p}");
        }
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
