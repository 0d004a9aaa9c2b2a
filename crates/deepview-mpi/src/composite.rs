//! Over-compositing with the paper's per-plane quantities.
//!
//! Planes 0..D back to front, warped premultiplied colour `c_d` and alpha `a_d` at a target pixel:
//! - render `= sum_d c_d prod_{i>d} (1 - a_i)`;
//! - net transmittance `T_d = prod_{i>d} (1 - a_i)` (what the planes in front of `d` let through);
//! - accumulated over `A_d = sum_{i<d} c_i prod_{i<j<d} (1 - a_j)` (the over of everything behind `d`);
//! - `d render / d c_d = T_d`, `d render / d a_d = -A_d T_d` (tested by finite differences).

use crate::mpi::Mpi;
use crate::warp::{target_to_plane_homographies, warp_image};
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use rayon::prelude::*;

/// Everything the gradient components need from one target view.
#[derive(Clone, Debug)]
pub struct RenderComponents {
    pub width: u32,
    pub height: u32,
    /// Warped planes `[D][H][W][4]` (premultiplied RGBA in the target view).
    pub warped: Vec<f32>,
    /// Net transmittance `[D][H][W]`.
    pub transmittance: Vec<f32>,
    /// Accumulated over `[D][H][W][3]`.
    pub accumulated_over: Vec<f32>,
    /// The rendered image, 4 channels (premultiplied RGB, alpha).
    pub render: ImageF32,
}

/// Composite already-warped planes (`[D][n][4]`, back to front) into `(T, A, render)`.
pub fn composite_warped(
    warped: &[f32],
    planes: usize,
    pixels: usize,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    assert_eq!(warped.len(), planes * pixels * 4);
    let mut t = vec![0.0f32; planes * pixels];
    let mut a = vec![0.0f32; planes * pixels * 3];
    let mut render = vec![0.0f32; pixels * 4];
    // Pixels are independent; split them into chunks processed in parallel.
    const CHUNK: usize = 4096;
    let t_ptr = SyncPtr(t.as_mut_ptr());
    let a_ptr = SyncPtr(a.as_mut_ptr());
    render
        .par_chunks_mut(CHUNK * 4)
        .enumerate()
        .for_each(|(ci, out)| {
            let p0 = ci * CHUNK;
            let n = out.len() / 4;
            for p in p0..p0 + n {
                // Back to front: A_0 = 0, A_{d+1} = c_d + (1 - a_d) A_d.
                let mut acc = [0.0f32; 4];
                for d in 0..planes {
                    let w = &warped[(d * pixels + p) * 4..(d * pixels + p) * 4 + 4];
                    // SAFETY: each pixel index p is written by exactly one task.
                    unsafe {
                        let ap = a_ptr.get().add((d * pixels + p) * 3);
                        for k in 0..3 {
                            *ap.add(k) = acc[k];
                        }
                    }
                    let keep = 1.0 - w[3];
                    for k in 0..4 {
                        acc[k] = w[k] + keep * acc[k];
                    }
                }
                out[(p - p0) * 4..(p - p0) * 4 + 4].copy_from_slice(&acc);
                // Front to back: T_{D-1} = 1, T_{d-1} = T_d (1 - a_d).
                let mut trans = 1.0f32;
                for d in (0..planes).rev() {
                    // SAFETY: as above.
                    unsafe { *t_ptr.get().add(d * pixels + p) = trans };
                    trans *= 1.0 - warped[(d * pixels + p) * 4 + 3];
                }
            }
        });
    (t, a, render)
}

/// A raw pointer shared by tasks that write disjoint parts of one buffer (`composite_warped`,
/// `agreement::smooth_semi_global`).
#[derive(Clone, Copy)]
pub(crate) struct SyncPtr(pub(crate) *mut f32);
// SAFETY: used only for writes that the callers keep disjoint across tasks.
unsafe impl Send for SyncPtr {}
unsafe impl Sync for SyncPtr {}
impl SyncPtr {
    pub(crate) fn get(self) -> *mut f32 {
        self.0
    }
}

/// Warp every plane into `target` and composite, keeping `T` and `A` per plane.
pub fn render_components(mpi: &Mpi, target: &Camera) -> RenderComponents {
    let homs = target_to_plane_homographies(&mpi.camera, target, &mpi.depths);
    let pixels = target.width as usize * target.height as usize;
    let mut warped = vec![0.0f32; mpi.planes() * pixels * 4];
    warped
        .par_chunks_mut(pixels * 4)
        .enumerate()
        .for_each(|(d, out)| {
            warp_image(
                mpi.plane(d),
                mpi.camera.width,
                mpi.camera.height,
                4,
                homs[d],
                target.width,
                target.height,
                out,
                None,
            );
        });
    let (transmittance, accumulated_over, render) = composite_warped(&warped, mpi.planes(), pixels);
    RenderComponents {
        width: target.width,
        height: target.height,
        warped,
        transmittance,
        accumulated_over,
        render: ImageF32 {
            width: target.width,
            height: target.height,
            channels: 4,
            data: render,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::render;
    use deepview_geometry::{DMat3, DVec3, Intrinsics, Pose};

    fn random_mpi(w: u32, h: u32, d: usize, seed: u64) -> Mpi {
        let cam = Camera::new(w, h, Intrinsics::centred(w as f64, w, h), Pose::IDENTITY);
        let depths: Vec<f64> = (0..d).map(|i| 10.0 / (1.0 + i as f64)).collect();
        let mut mpi = Mpi::transparent(cam, depths);
        let mut s = seed;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 33) as f64 / (1u64 << 31) as f64) as f32
        };
        for p in mpi.layers.chunks_exact_mut(4) {
            let a = rnd();
            p[3] = a;
            for k in 0..3 {
                p[k] = rnd() * a;
            }
        }
        mpi
    }

    #[test]
    fn components_match_render_and_identities_hold() {
        let mpi = random_mpi(6, 5, 5, 1);
        let cam = mpi.camera;
        let comps = render_components(&mpi, &cam);
        let direct = render(&mpi, &cam);
        for (a, b) in comps.render.data.iter().zip(&direct.data) {
            assert!((a - b).abs() < 1e-6);
        }
        // Finite differences in f64 arithmetic on the f32 MPI: perturb one texel's premultiplied colour or
        // alpha (identity camera: texel == warped sample).
        let eps = 1e-3f32;
        let pixels = 30;
        for d in 0..5 {
            for p in [0usize, 7, 29] {
                let t = comps.transmittance[d * pixels + p];
                for k in 0..3 {
                    let mut m2 = mpi.clone();
                    m2.plane_mut(d)[p * 4 + k] += eps;
                    let r2 = render(&m2, &cam);
                    let g = (r2.data[p * 4 + k] - direct.data[p * 4 + k]) / eps;
                    assert!((g - t).abs() < 2e-3, "dR/dc plane {d} px {p}: {g} vs T {t}");
                }
                let mut m2 = mpi.clone();
                m2.plane_mut(d)[p * 4 + 3] += eps;
                let r2 = render(&m2, &cam);
                for k in 0..3 {
                    let g = (r2.data[p * 4 + k] - direct.data[p * 4 + k]) / eps;
                    let expect = -comps.accumulated_over[(d * pixels + p) * 3 + k] * t;
                    assert!(
                        (g - expect).abs() < 2e-3,
                        "dR/da plane {d} px {p} ch {k}: {g} vs {expect}"
                    );
                }
            }
        }
    }

    #[test]
    fn decomposition_holds_in_a_novel_view() {
        let mut mpi = random_mpi(24, 18, 4, 9);
        mpi.camera.pose = Pose::from_center(DMat3::IDENTITY, DVec3::ZERO);
        let target = Camera::new(
            20,
            16,
            Intrinsics::new(22.0, 22.0, 10.5, 8.0),
            Pose::from_center(DMat3::from_rotation_y(0.03), DVec3::new(0.2, -0.1, 0.3)),
        );
        let c = render_components(&mpi, &target);
        let n = 20 * 16;
        // render = T_d (c_d + (1 - a_d) A_d) + front_d, and front of the nearest plane is 0.
        let last = 3;
        for p in 0..n {
            let w = &c.warped[(last * n + p) * 4..(last * n + p) * 4 + 4];
            for k in 0..3 {
                let expect = w[k] + (1.0 - w[3]) * c.accumulated_over[(last * n + p) * 3 + k];
                assert!((c.render.data[p * 4 + k] - expect).abs() < 1e-5);
            }
            assert_eq!(c.transmittance[last * n + p], 1.0);
        }
    }
}
