//! Procedural planar scenes: textured, partly transparent and occluding fronto-parallel layers (thin
//! structures included), rendered exactly by ray casting, with their ground-truth MPI.
//!
//! Every layer lies on a plane `z = depth` of the scene's reference camera, and its colour and alpha are
//! smooth functions of that camera's continuous pixel coordinates `(u, v)` on the plane. So the scene is
//! itself an MPI with analytic texels: sampling the functions at the reference pixel centres gives the
//! ground-truth MPI, and ray casting gives the exact image seen by any camera.

use deepview_geometry::{Camera, DVec2, DVec3, Homography, plane_homography};
use deepview_image::ImageF32;
use deepview_mpi::Mpi;
use rayon::prelude::*;

/// A sum of oriented sinusoids per channel: smooth, band-limited colour.
#[derive(Clone, Debug)]
struct Texture {
    base: [f32; 3],
    /// (frequency vector in radians per reference pixel, phase, amplitude per channel)
    waves: Vec<([f32; 2], f32, [f32; 3])>,
}

impl Texture {
    fn eval(&self, u: f32, v: f32) -> [f32; 3] {
        let mut c = self.base;
        for (k, phase, amp) in &self.waves {
            let s = (k[0] * u + k[1] * v + phase).sin();
            for i in 0..3 {
                c[i] += amp[i] * s;
            }
        }
        c.map(|x| x.clamp(0.0, 1.0))
    }
}

/// Where a layer is opaque.
#[derive(Clone, Debug)]
enum Shape {
    /// Everywhere (a background).
    Full,
    /// A rounded rectangle `[x0, x1] x [y0, y1]` (reference pixels) with corner radius.
    RoundedRect {
        min: [f32; 2],
        max: [f32; 2],
        radius: f32,
    },
    /// A disc.
    Disc { centre: [f32; 2], radius: f32 },
    /// Thin bars: lines `n . (u, v) = offset + k * spacing`, `width` pixels wide, within a band.
    Bars {
        normal: [f32; 2],
        spacing: f32,
        offset: f32,
        width: f32,
        band: Option<([f32; 2], [f32; 2])>,
    },
}

impl Shape {
    /// Signed distance (negative inside) in reference pixels.
    fn distance(&self, u: f32, v: f32) -> f32 {
        match self {
            Shape::Full => -1e9,
            Shape::RoundedRect { min, max, radius } => {
                let cx = 0.5 * (min[0] + max[0]);
                let cy = 0.5 * (min[1] + max[1]);
                let hx = 0.5 * (max[0] - min[0]) - radius;
                let hy = 0.5 * (max[1] - min[1]) - radius;
                let qx = (u - cx).abs() - hx;
                let qy = (v - cy).abs() - hy;
                let outside = (qx.max(0.0).powi(2) + qy.max(0.0).powi(2)).sqrt();
                outside + qx.max(qy).min(0.0) - radius
            }
            Shape::Disc { centre, radius } => {
                ((u - centre[0]).powi(2) + (v - centre[1]).powi(2)).sqrt() - radius
            }
            Shape::Bars {
                normal,
                spacing,
                offset,
                width,
                band,
            } => {
                let t = normal[0] * u + normal[1] * v - offset;
                let r = t - spacing * (t / spacing).round();
                let d = r.abs() - 0.5 * width;
                match band {
                    Some((lo, hi)) => {
                        let qx = (lo[0] - u).max(u - hi[0]);
                        let qy = (lo[1] - v).max(v - hi[1]);
                        d.max(qx.max(qy))
                    }
                    None => d,
                }
            }
        }
    }
}

/// One planar layer of a synthetic scene.
#[derive(Clone, Debug)]
pub struct Layer {
    /// Depth along the scene reference camera's axis.
    pub depth: f64,
    texture: Texture,
    shape: Shape,
    /// Opacity inside the shape (< 1 for glass-like layers).
    opacity: f32,
    /// Edge softness in reference pixels (keeps the scene band-limited).
    softness: f32,
}

impl Layer {
    /// Premultiplied RGBA at reference pixel coordinates `(u, v)`.
    pub fn rgba(&self, u: f32, v: f32) -> [f32; 4] {
        let d = self.shape.distance(u, v);
        // Smoothstep over [-softness, softness].
        let t = (0.5 - 0.5 * d / self.softness).clamp(0.0, 1.0);
        let a = self.opacity * t * t * (3.0 - 2.0 * t);
        if a <= 0.0 {
            return [0.0; 4];
        }
        let c = self.texture.eval(u, v);
        [c[0] * a, c[1] * a, c[2] * a, a]
    }
}

/// A planar synthetic scene in front of `reference`, layers back to front.
#[derive(Clone, Debug)]
pub struct SynthScene {
    pub reference: Camera,
    pub layers: Vec<Layer>,
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next()
    }
    fn colour(&mut self) -> [f32; 3] {
        [
            self.range(0.15, 0.85),
            self.range(0.15, 0.85),
            self.range(0.15, 0.85),
        ]
    }
}

fn texture(rng: &mut Rng, min_period: f32, amplitude: f32) -> Texture {
    let waves = (0..6)
        .map(|_| {
            let period = rng.range(min_period, min_period * 6.0);
            let angle = rng.range(0.0, std::f32::consts::TAU);
            let k = std::f32::consts::TAU / period;
            let amp = [
                rng.range(0.0, amplitude),
                rng.range(0.0, amplitude),
                rng.range(0.0, amplitude),
            ];
            (
                [k * angle.cos(), k * angle.sin()],
                rng.range(0.0, std::f32::consts::TAU),
                amp,
            )
        })
        .collect();
    Texture {
        base: rng.colour(),
        waves,
    }
}

impl SynthScene {
    /// A random scene (deterministic in `seed`) whose layers sit exactly at some of `depths` (far first):
    /// an opaque textured background, opaque textured cards and a disc that occlude each other, thin bars
    /// (a fence-like structure, 3 px wide), and a semi-transparent tinted pane in front.
    pub fn generate(reference: Camera, depths: &[f64], seed: u64) -> SynthScene {
        let mut rng = Rng(seed ^ 0x9e37_79b9_7f4a_7c15);
        rng.next();
        let (w, h) = (reference.width as f32, reference.height as f32);
        let n = depths.len();
        let at = |f: f64| depths[((n - 1) as f64 * f).round() as usize];
        let s = w.min(h);
        let mut layers = vec![Layer {
            depth: depths[0],
            texture: texture(&mut rng, s / 24.0, 0.18),
            shape: Shape::Full,
            opacity: 1.0,
            softness: 1.5,
        }];
        if n >= 2 {
            let cx = rng.range(0.2, 0.45) * w;
            let cy = rng.range(0.25, 0.6) * h;
            layers.push(Layer {
                depth: at(0.3),
                texture: texture(&mut rng, s / 20.0, 0.2),
                shape: Shape::RoundedRect {
                    min: [cx - 0.22 * w, cy - 0.25 * h],
                    max: [cx + 0.18 * w, cy + 0.3 * h],
                    radius: 0.04 * s,
                },
                opacity: 1.0,
                softness: 1.5,
            });
        }
        if n >= 3 {
            layers.push(Layer {
                depth: at(0.55),
                texture: texture(&mut rng, s / 16.0, 0.15),
                shape: Shape::Disc {
                    centre: [rng.range(0.55, 0.75) * w, rng.range(0.3, 0.7) * h],
                    radius: 0.18 * s,
                },
                opacity: 1.0,
                softness: 1.5,
            });
        }
        if n >= 4 {
            let angle = rng.range(-0.3, 0.3);
            layers.push(Layer {
                depth: at(0.75),
                texture: texture(&mut rng, s / 12.0, 0.1),
                shape: Shape::Bars {
                    normal: [angle.cos(), angle.sin()],
                    spacing: rng.range(0.07, 0.12) * w,
                    offset: rng.range(0.0, 50.0),
                    width: 3.0,
                    band: Some(([0.05 * w, 0.1 * h], [0.95 * w, 0.65 * h])),
                },
                opacity: 1.0,
                softness: 1.0,
            });
        }
        if n >= 5 {
            layers.push(Layer {
                depth: at(1.0),
                texture: texture(&mut rng, s / 10.0, 0.1),
                shape: Shape::RoundedRect {
                    min: [0.5 * w, 0.55 * h],
                    max: [0.9 * w, 0.92 * h],
                    radius: 0.03 * s,
                },
                opacity: 0.45,
                softness: 1.5,
            });
        }
        // Keep layers back to front and on distinct planes.
        layers.sort_by(|a, b| b.depth.total_cmp(&a.depth));
        layers.dedup_by(|a, b| a.depth == b.depth);
        SynthScene { reference, layers }
    }

    /// The exact image seen by `camera` (RGB, straight colour; the background is opaque), by casting the
    /// ray through each pixel centre and compositing the layers it crosses. `supersample` > 1 averages a
    /// regular grid of rays per pixel (a box-filtered camera).
    pub fn render(&self, camera: &Camera, supersample: u32) -> ImageF32 {
        // Camera pixel -> reference pixel through each layer's plane.
        let homs: Vec<Homography> = self
            .layers
            .iter()
            .map(|l| plane_homography(&self.reference, camera, l.depth).inverse())
            .collect();
        // A layer is only visible if it is in front of the camera.
        let visible: Vec<bool> = self
            .layers
            .iter()
            .map(|l| {
                camera
                    .pose
                    .transform_point(self.reference.unproject(DVec2::ZERO, l.depth))
                    .z
                    > 0.0
            })
            .collect();
        let w = camera.width as usize;
        let ss = supersample.max(1);
        let mut img = ImageF32::new(camera.width, camera.height, 3);
        img.data
            .par_chunks_mut(w * 3)
            .enumerate()
            .for_each(|(y, row)| {
                for x in 0..w {
                    let mut sum = [0.0f32; 3];
                    for sy in 0..ss {
                        for sx in 0..ss {
                            let p = DVec2::new(
                                x as f64 + (sx as f64 + 0.5) / ss as f64,
                                y as f64 + (sy as f64 + 0.5) / ss as f64,
                            );
                            let mut acc = [0.0f32; 4];
                            for (l, layer) in self.layers.iter().enumerate() {
                                if !visible[l] {
                                    continue;
                                }
                                let q = homs[l].apply(p);
                                let c = layer.rgba(q.x as f32, q.y as f32);
                                for k in 0..4 {
                                    acc[k] = c[k] + (1.0 - c[3]) * acc[k];
                                }
                            }
                            for k in 0..3 {
                                sum[k] += acc[k];
                            }
                        }
                    }
                    let n = (ss * ss) as f32;
                    for k in 0..3 {
                        row[x * 3 + k] = sum[k] / n;
                    }
                }
            });
        img
    }

    /// The ground-truth MPI on the reference camera with planes at `depths` (far first): each layer's
    /// texels sampled at the pixel centres of the plane it lies on; planes without a layer are transparent.
    /// Errors if a layer's depth is not one of `depths`.
    pub fn ground_truth_mpi(&self, depths: &[f64]) -> Result<Mpi, String> {
        let mut mpi = Mpi::transparent(self.reference, depths.to_vec());
        let w = self.reference.width as usize;
        for layer in &self.layers {
            let d = depths
                .iter()
                .position(|&z| (z - layer.depth).abs() <= 1e-9 * z.abs())
                .ok_or_else(|| format!("layer at depth {} is not on an MPI plane", layer.depth))?;
            mpi.plane_mut(d)
                .par_chunks_mut(w * 4)
                .enumerate()
                .for_each(|(y, row)| {
                    for x in 0..w {
                        let c = layer.rgba(x as f32 + 0.5, y as f32 + 0.5);
                        let o = &mut row[x * 4..x * 4 + 4];
                        // Two layers on one plane are composited onto it.
                        for k in 0..4 {
                            o[k] = c[k] + (1.0 - c[3]) * o[k];
                        }
                    }
                });
        }
        Ok(mpi)
    }

    /// The depth of the first (nearly) opaque surface along the ray through a reference pixel.
    pub fn depth_at(&self, u: f32, v: f32) -> f64 {
        for layer in self.layers.iter().rev() {
            if layer.rgba(u, v)[3] > 0.5 {
                return layer.depth;
            }
        }
        self.layers[0].depth
    }

    /// A few 3D points on the layers' opaque parts (for COLMAP `points3D`).
    pub fn sample_points(&self, count: usize) -> Vec<DVec3> {
        let (w, h) = (self.reference.width as f32, self.reference.height as f32);
        let mut rng = Rng(17);
        (0..count)
            .map(|_| {
                let (u, v) = (rng.range(0.0, w), rng.range(0.0, h));
                self.reference
                    .unproject(DVec2::new(u as f64, v as f64), self.depth_at(u, v))
            })
            .collect()
    }
}
