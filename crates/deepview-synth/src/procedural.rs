//! Procedural training scenes made on the fly from a seed: many surfaces in 3D (slanted planes, discs,
//! thin bars, boxes, spheres, semi-transparent sheets) in front of a background, textured with crops of
//! real photographs (or band-limited noise; 15% plain, smoothly shaded colours, whose depth only their
//! edges give), over depth ranges like real captures, seen through random
//! rigs (jittered grids, hand-held paths, sparse wide sets), rendered exactly by ray casting.
//!
//! Unlike [`crate::scene`] (fronto-parallel layers with a ground-truth MPI, for evaluation), these scenes
//! have slanted and curved surfaces between the planes of any MPI: what real captures hold. Nothing is
//! stored: [`generate`] makes the same cameras and images from the same seed and textures.
//!
//! Conventions: OpenCV axes; the reference camera sits at the origin looking down +z; pixel centres at
//! `+0.5`; every view is supersampled `supersample x supersample` (box filter).

use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, Pose};
use deepview_image::ImageF32;
use rayon::prelude::*;

/// Size and sampling of a generated scene.
#[derive(Clone, Debug)]
pub struct ProceduralOptions {
    /// Image size of every view.
    pub width: u32,
    pub height: u32,
    /// At least this many views (the rig grows to have them).
    pub min_views: usize,
    /// Rays per pixel side.
    pub supersample: u32,
}

impl Default for ProceduralOptions {
    fn default() -> Self {
        Self {
            width: 160,
            height: 120,
            min_views: 6,
            supersample: 2,
        }
    }
}

/// How the views were placed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RigKind {
    /// A jittered `g x g` grid.
    Grid,
    /// A jittered hand-held sweep along a wobbly line.
    Path,
    /// A few views spread over a wide disc.
    Sparse,
}

/// A generated scene: views, their images, and the depth range holding all of its content.
#[derive(Clone, Debug)]
pub struct ProceduralScene {
    pub cameras: Vec<Camera>,
    pub images: Vec<ImageF32>,
    pub near: f64,
    pub far: f64,
    pub rig: RigKind,
    /// Largest disparity (reference pixels) between two views at the near depth.
    pub max_disparity: f64,
}

/// splitmix64: small, fast, reproducible.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    fn log_range(&mut self, lo: f64, hi: f64) -> f64 {
        self.range(lo.ln(), hi.ln()).exp()
    }
    fn below(&mut self, n: usize) -> usize {
        ((self.uniform() * n as f64) as usize).min(n.saturating_sub(1))
    }
    fn chance(&mut self, p: f64) -> bool {
        self.uniform() < p
    }
}

/// Where a surface gets its colour: surface coordinates (world units) -> RGB.
#[derive(Clone, Debug)]
enum Texture {
    /// A crop of a photo, `scale` texels per world unit, mirrored at the crop's edges.
    Photo {
        image: usize,
        origin: (f64, f64),
        size: (f64, f64),
        scale: f64,
        tint: [f32; 3],
    },
    /// Oriented sinusoids (frequency in radians per world unit, phase, amplitude per channel).
    Waves {
        base: [f32; 3],
        waves: Vec<([f64; 2], f64, [f32; 3])>,
    },
}

/// Mirror `x` into `[0, n)` (a reflected repeat: no seams).
fn mirror(x: f64, n: f64) -> f64 {
    let p = x.rem_euclid(2.0 * n);
    if p < n { p } else { 2.0 * n - p }
}

impl Texture {
    fn eval(&self, s: f64, t: f64, photos: &[&ImageF32]) -> [f32; 3] {
        match self {
            Texture::Photo {
                image,
                origin,
                size,
                scale,
                tint,
            } => {
                let img = photos[*image];
                let x = origin.0 + mirror(s * scale, size.0 - 1.0);
                let y = origin.1 + mirror(t * scale, size.1 - 1.0);
                let c = bilinear(img, x, y);
                std::array::from_fn(|i| (c[i] * tint[i]).clamp(0.0, 1.0))
            }
            Texture::Waves { base, waves } => {
                let mut c = *base;
                for (k, phase, amp) in waves {
                    let v = (k[0] * s + k[1] * t + phase).sin() as f32;
                    for i in 0..3 {
                        c[i] += amp[i] * v;
                    }
                }
                c.map(|x| x.clamp(0.0, 1.0))
            }
        }
    }
}

/// Bilinear sample of an RGB(A) image at continuous texel coordinates (texel centres at integers).
fn bilinear(img: &ImageF32, x: f64, y: f64) -> [f32; 3] {
    let (w, h) = (img.width as i64, img.height as i64);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let at = |xi: i64, yi: i64| {
        let p = img.pixel(xi.clamp(0, w - 1) as u32, yi.clamp(0, h - 1) as u32);
        [p[0], p[1], p[2]]
    };
    let (x0, y0) = (x0 as i64, y0 as i64);
    let (a, b, c, d) = (
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    );
    std::array::from_fn(|i| {
        let top = a[i] + (b[i] - a[i]) * fx;
        let bottom = c[i] + (d[i] - c[i]) * fx;
        top + (bottom - top) * fy
    })
}

/// The outline of a planar patch in its own axes (world units).
#[derive(Clone, Copy, Debug)]
enum Outline {
    /// `|s| <= a, |t| <= b`.
    Rect { a: f64, b: f64 },
    /// `s^2 + t^2 <= r^2`.
    Disc { r: f64 },
    /// Everywhere (the background).
    Infinite,
}

#[derive(Clone, Debug)]
enum Geometry {
    /// A planar patch: centre, in-plane unit axes `u`, `v`, normal `u x v`.
    Patch {
        centre: DVec3,
        u: DVec3,
        v: DVec3,
        normal: DVec3,
        outline: Outline,
    },
    Sphere {
        centre: DVec3,
        radius: f64,
    },
    /// A box: centre, `local_from_world` rotation, half sizes.
    Cuboid {
        centre: DVec3,
        rotation: DMat3,
        half: DVec3,
    },
}

impl Geometry {
    /// The nearest hit along `origin + t dir` with `t > 0`: `t` and the surface coordinates there.
    fn hit(&self, origin: DVec3, dir: DVec3) -> Option<(f64, f64, f64)> {
        match self {
            Geometry::Patch {
                centre,
                u,
                v,
                normal,
                outline,
            } => {
                let den = normal.dot(dir);
                if den.abs() < 1e-12 {
                    return None;
                }
                let t = normal.dot(*centre - origin) / den;
                if t <= 0.0 {
                    return None;
                }
                let p = origin + dir * t - *centre;
                let (s, q) = (p.dot(*u), p.dot(*v));
                let inside = match *outline {
                    Outline::Rect { a, b } => s.abs() <= a && q.abs() <= b,
                    Outline::Disc { r } => s * s + q * q <= r * r,
                    Outline::Infinite => true,
                };
                inside.then_some((t, s, q))
            }
            Geometry::Sphere { centre, radius } => {
                let oc = origin - *centre;
                let b = oc.dot(dir);
                let c = oc.length_squared() - radius * radius;
                let a = dir.length_squared();
                let disc = b * b - a * c;
                if disc < 0.0 {
                    return None;
                }
                let t = (-b - disc.sqrt()) / a;
                if t <= 0.0 {
                    return None;
                }
                let n = (origin + dir * t - *centre) / *radius;
                Some((
                    t,
                    radius * n.x.atan2(-n.z),
                    radius * n.y.clamp(-1.0, 1.0).asin(),
                ))
            }
            Geometry::Cuboid {
                centre,
                rotation,
                half,
            } => {
                let o = *rotation * (origin - *centre);
                let d = *rotation * dir;
                let (mut t0, mut t1, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
                for i in 0..3 {
                    if d[i].abs() < 1e-12 {
                        if o[i].abs() > half[i] {
                            return None;
                        }
                        continue;
                    }
                    let (a, b) = ((-half[i] - o[i]) / d[i], (half[i] - o[i]) / d[i]);
                    let (a, b) = if a < b { (a, b) } else { (b, a) };
                    if a > t0 {
                        t0 = a;
                        axis = i;
                    }
                    t1 = t1.min(b);
                }
                if t0 > t1 || t0 <= 0.0 {
                    return None;
                }
                let p = o + d * t0;
                // Coordinates on the face hit: the two other axes (offset per face so faces differ).
                let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
                let face = if p[axis] > 0.0 { 3.0 } else { 0.0 } + axis as f64;
                Some((t0, p[i] + 7.0 * face, p[j]))
            }
        }
    }
}

#[derive(Clone, Debug)]
struct Object {
    geometry: Geometry,
    texture: Texture,
    /// Opacity (1: opaque; below: a semi-transparent sheet).
    alpha: f32,
}

/// A random rotation of at most `max_angle` radians about a random axis.
fn small_rotation(rng: &mut Rng, max_angle: f64) -> DMat3 {
    let axis = random_unit(rng);
    DMat3::from_axis_angle(axis, rng.range(-max_angle, max_angle))
}

fn random_unit(rng: &mut Rng) -> DVec3 {
    loop {
        let v = DVec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        );
        let l = v.length();
        if l > 1e-3 && l <= 1.0 {
            return v / l;
        }
    }
}

/// The share of surfaces without texture: a plain colour under smooth shading (a wave of 150-600 screen
/// pixels, amplitude 0.005-0.03), like the painted walls, ceilings and panels of real rooms, whose depth
/// only their edges and their neighbours give.
const FLAT_SHARE: f64 = 0.15;

fn texture(rng: &mut Rng, photos: &[&ImageF32], focal: f64, depth: f64) -> Texture {
    // About 0.5-2 texels per screen pixel at the surface's depth.
    let scale = rng.log_range(0.5, 2.0) * focal / depth;
    if rng.chance(FLAT_SHARE) {
        let base: [f32; 3] = std::array::from_fn(|_| rng.range(0.1, 0.9) as f32);
        let angle = rng.range(0.0, std::f64::consts::TAU);
        let k = std::f64::consts::TAU * scale / rng.log_range(150.0, 600.0);
        let amp = rng.range(0.005, 0.03) as f32;
        return Texture::Waves {
            base,
            waves: vec![(
                [k * angle.cos(), k * angle.sin()],
                rng.range(0.0, 6.3),
                [amp; 3],
            )],
        };
    }
    if !photos.is_empty() && rng.chance(0.85) {
        let image = rng.below(photos.len());
        let img = photos[image];
        let (w, h) = (img.width as f64, img.height as f64);
        let cw = rng.range(0.15, 0.6) * w;
        let ch = (cw * rng.log_range(0.6, 1.6)).min(h * 0.9).max(4.0);
        let cw = cw.max(4.0);
        return Texture::Photo {
            image,
            origin: (rng.range(0.0, w - cw), rng.range(0.0, h - ch)),
            size: (cw, ch),
            scale,
            tint: std::array::from_fn(|_| rng.log_range(0.8, 1.25) as f32),
        };
    }
    let base: [f32; 3] = std::array::from_fn(|_| rng.range(0.15, 0.85) as f32);
    let waves = (0..3 + rng.below(4))
        .map(|_| {
            let angle = rng.range(0.0, std::f64::consts::TAU);
            // Periods of 2-40 screen pixels.
            let k = std::f64::consts::TAU * scale / rng.log_range(2.0, 40.0);
            let amp = rng.range(0.05, 0.3) as f32;
            let tint: [f32; 3] = std::array::from_fn(|_| amp * rng.range(0.4, 1.0) as f32);
            (
                [k * angle.cos(), k * angle.sin()],
                rng.range(0.0, 6.3),
                tint,
            )
        })
        .collect();
    Texture::Waves { base, waves }
}

/// A random scene (deterministic in `seed`, `photos` and `opts`); `photos` lend their crops as textures
/// (none: noise textures only).
pub fn generate(seed: u64, photos: &[&ImageF32], opts: &ProceduralOptions) -> ProceduralScene {
    let mut rng = Rng(seed ^ 0x005E_ED0F_DEE9_F1E3);
    let (w, h) = (opts.width.max(8), opts.height.max(8));
    let focal = w as f64 * rng.range(0.7, 1.3);
    let k = Intrinsics::new(focal, focal, w as f64 / 2.0, h as f64 / 2.0);
    // Depths like real captures: near 0.5-20 units, far 10-200x near.
    let near = rng.log_range(0.5, 20.0);
    let far = near * rng.log_range(10.0, 200.0);
    let reference = Camera::new(w, h, k, Pose::IDENTITY);

    let mut objects = Vec::new();
    // The background: a plane near the far bound, facing the cameras (slightly slanted).
    let zb = far * rng.range(0.75, 0.95);
    let n = (small_rotation(&mut rng, 0.25) * DVec3::Z).normalize();
    let u = n.cross(DVec3::Y).normalize();
    objects.push(Object {
        geometry: Geometry::Patch {
            centre: DVec3::new(0.0, 0.0, zb),
            u,
            v: n.cross(u),
            normal: n,
            outline: Outline::Infinite,
        },
        texture: texture(&mut rng, photos, focal, zb),
        alpha: 1.0,
    });
    // The surfaces in front of it, much of the content close to the near plane: disparity drawn with a
    // density growing toward the near bound.
    let count = 4 + rng.below(14);
    for _ in 0..count {
        let disparity = 1.0 / zb + (1.0 / near - 1.0 / zb) * rng.uniform().sqrt();
        let z = (1.0 / disparity).clamp(near * 1.02, zb * 0.98);
        // Anywhere over the reference image and a little beyond it.
        let px = rng.range(-0.2, 1.2) * w as f64;
        let py = rng.range(-0.2, 1.2) * h as f64;
        let centre = reference.unproject(deepview_geometry::DVec2::new(px, py), z);
        // Screen size 5-60% of the width.
        let size = rng.log_range(0.05, 0.6) * w as f64 * z / focal;
        let kind = rng.uniform();
        let tex = texture(&mut rng, photos, focal, z);
        let (geometry, alpha) = if kind < 0.45 {
            // A slanted patch (up to 70 degrees), sometimes semi-transparent.
            let n = (small_rotation(&mut rng, 1.2) * DVec3::Z).normalize();
            let u = n.cross(random_unit(&mut rng)).normalize();
            let outline = if rng.chance(0.7) {
                Outline::Rect {
                    a: size * rng.range(0.3, 1.0),
                    b: size * rng.range(0.3, 1.0),
                }
            } else {
                Outline::Disc {
                    r: size * rng.range(0.3, 0.8),
                }
            };
            let alpha = if rng.chance(0.15) {
                rng.range(0.25, 0.75) as f32
            } else {
                1.0
            };
            (
                Geometry::Patch {
                    centre,
                    u,
                    v: n.cross(u),
                    normal: n,
                    outline,
                },
                alpha,
            )
        } else if kind < 0.6 {
            // A thin structure: a bar 1-4 screen pixels wide and long.
            let n = (small_rotation(&mut rng, 0.8) * DVec3::Z).normalize();
            let u = n.cross(random_unit(&mut rng)).normalize();
            let width = rng.range(0.5, 2.0) * z / focal;
            (
                Geometry::Patch {
                    centre,
                    u,
                    v: n.cross(u),
                    normal: n,
                    outline: Outline::Rect {
                        a: size * rng.range(1.0, 3.0),
                        b: width,
                    },
                },
                1.0,
            )
        } else if kind < 0.8 {
            let half = DVec3::new(
                size * rng.range(0.2, 0.6),
                size * rng.range(0.2, 0.6),
                size * rng.range(0.2, 0.6),
            );
            (
                Geometry::Cuboid {
                    centre: centre + DVec3::Z * half.z,
                    rotation: small_rotation(&mut rng, std::f64::consts::PI),
                    half,
                },
                1.0,
            )
        } else {
            let radius = size * rng.range(0.2, 0.5);
            (
                Geometry::Sphere {
                    centre: centre + DVec3::Z * radius,
                    radius,
                },
                1.0,
            )
        };
        objects.push(Object {
            geometry,
            texture: tex,
            alpha,
        });
    }

    // The rig: its span gives 2-40% of the width of disparity at the near bound.
    let max_disparity = w as f64 * rng.log_range(0.02, 0.4);
    let span = max_disparity * near / focal;
    let rig_draw = rng.uniform();
    let min_views = opts.min_views.max(2);
    let mut centres: Vec<DVec3> = Vec::new();
    let rig = if rig_draw < 0.35 {
        let g = ((min_views as f64).sqrt().ceil() as usize).max(2 + rng.below(3));
        let step = span / (g - 1) as f64;
        for j in 0..g {
            for i in 0..g {
                let jitter = DVec3::new(rng.range(-0.1, 0.1), rng.range(-0.1, 0.1), 0.0) * step;
                centres.push(
                    DVec3::new(
                        (i as f64 / (g - 1) as f64 - 0.5) * span,
                        (j as f64 / (g - 1) as f64 - 0.5) * span,
                        0.0,
                    ) + jitter,
                );
            }
        }
        RigKind::Grid
    } else if rig_draw < 0.75 {
        let n = min_views.max(6 + rng.below(9));
        let angle = rng.range(0.0, std::f64::consts::PI);
        let (dir, side) = (
            DVec3::new(angle.cos(), angle.sin(), 0.0),
            DVec3::new(-angle.sin(), angle.cos(), 0.0),
        );
        let (wobble, phase) = (rng.range(0.0, 0.2) * span, rng.range(0.0, 6.3));
        for i in 0..n {
            let f = i as f64 / (n - 1) as f64 - 0.5;
            let jitter = DVec3::new(rng.range(-0.03, 0.03), rng.range(-0.03, 0.03), 0.0) * span;
            centres.push(dir * f * span + side * wobble * (3.0 * f + phase).sin() + jitter);
        }
        RigKind::Path
    } else {
        let n = min_views.max(4 + rng.below(4));
        for _ in 0..n {
            let (r, a) = (0.5 * span * rng.uniform().sqrt(), rng.range(0.0, 6.3));
            centres.push(DVec3::new(r * a.cos(), r * a.sin(), 0.0));
        }
        RigKind::Sparse
    };
    let cameras: Vec<Camera> = centres
        .into_iter()
        .map(|c| {
            // Hand-held: a little forward/backward, and a degree or two of rotation.
            let c = c + DVec3::Z * rng.range(-0.05, 0.05) * span;
            Camera::new(
                w,
                h,
                k,
                Pose::from_center(small_rotation(&mut rng, 0.03), c),
            )
        })
        .collect();
    let images = cameras
        .iter()
        .map(|c| render(&objects, c, photos, opts.supersample.max(1)))
        .collect();
    ProceduralScene {
        cameras,
        images,
        near,
        far,
        rig,
        max_disparity,
    }
}

/// Ray-cast `objects` into `camera`: per ray, every hit sorted front to back and composited over.
fn render(objects: &[Object], camera: &Camera, photos: &[&ImageF32], ss: u32) -> ImageF32 {
    let (w, h) = (camera.width, camera.height);
    let k = camera.intrinsics;
    let world_from_camera = camera.pose.rotation.transpose();
    let origin = camera.center();
    let mut img = ImageF32::new(w, h, 3);
    let inv = 1.0 / (ss * ss) as f32;
    img.data
        .par_chunks_exact_mut(3 * w as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let mut hits: Vec<(f64, usize, f64, f64)> = Vec::with_capacity(objects.len());
            for x in 0..w as usize {
                let mut acc = [0f32; 3];
                for sy in 0..ss {
                    for sx in 0..ss {
                        let px = x as f64 + (sx as f64 + 0.5) / ss as f64;
                        let py = y as f64 + (sy as f64 + 0.5) / ss as f64;
                        let d = world_from_camera
                            * DVec3::new((px - k.cx) / k.fx, (py - k.cy) / k.fy, 1.0);
                        hits.clear();
                        for (i, o) in objects.iter().enumerate() {
                            if let Some((t, s, q)) = o.geometry.hit(origin, d) {
                                hits.push((t, i, s, q));
                            }
                        }
                        hits.sort_by(|a, b| a.0.total_cmp(&b.0));
                        let mut transmittance = 1f32;
                        for &(_, i, s, q) in &hits {
                            let o = &objects[i];
                            let c = o.texture.eval(s, q, photos);
                            for ch in 0..3 {
                                acc[ch] += inv * transmittance * o.alpha * c[ch];
                            }
                            transmittance *= 1.0 - o.alpha;
                            if transmittance < 1e-4 {
                                break;
                            }
                        }
                    }
                }
                row[3 * x..3 * x + 3].copy_from_slice(&acc);
            }
        });
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    fn photo() -> ImageF32 {
        let (w, h) = (64u32, 48u32);
        let data = (0..w * h)
            .flat_map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                [x / w as f32, y / h as f32, ((x * 0.3).sin() * 0.5 + 0.5)]
            })
            .collect();
        ImageF32::from_data(w, h, 3, data).unwrap()
    }

    /// The colour's standard deviation over a 40 x 40 screen-pixel patch of the surface at `depth`.
    fn patch_contrast(t: &Texture, photos: &[&ImageF32], focal: f64, depth: f64) -> f64 {
        let unit = depth / focal; // world units per screen pixel
        let mut v = Vec::new();
        for j in 0..20 {
            for i in 0..20 {
                let c = t.eval(2.0 * i as f64 * unit, 2.0 * j as f64 * unit, photos);
                v.push(c.iter().map(|&x| x as f64).sum::<f64>() / 3.0);
            }
        }
        let m = v.iter().sum::<f64>() / v.len() as f64;
        (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt()
    }

    #[test]
    fn some_surfaces_have_no_texture() {
        // Over many draws about FLAT_SHARE of the surfaces are a plain colour under smooth shading
        // (contrast under 0.01 over 40 px: the shading wave's 150+ px period and 0.03 amplitude allow
        // at most ~0.03 * sin(2 pi 40 / 150) / sqrt(2) ~ 0.02 peak, less in the mean), and the textured
        // ones (the photo's gradient and stripes, the noise waves) are well above it.
        let p = photo();
        let (focal, depth) = (200.0, 10.0);
        let (mut flat, mut textured, n) = (0, 0, 2000);
        let mut rng = Rng(12345);
        for _ in 0..n {
            let t = texture(&mut rng, &[&p], focal, depth);
            let c = patch_contrast(&t, &[&p], focal, depth);
            if c < 0.012 {
                flat += 1;
            } else if c > 0.03 {
                textured += 1;
            }
        }
        let share = flat as f64 / n as f64;
        assert!(
            (share - FLAT_SHARE).abs() < 0.03,
            "{flat} of {n} surfaces without texture (expected about {FLAT_SHARE})"
        );
        assert!(
            flat + textured > n * 97 / 100,
            "{} of {n} surfaces neither plain nor textured",
            n - flat - textured
        );
    }

    #[test]
    fn same_seed_same_scene_and_the_rigs_vary() {
        let p = photo();
        let opts = ProceduralOptions {
            width: 48,
            height: 36,
            min_views: 5,
            supersample: 1,
        };
        let a = generate(7, &[&p], &opts);
        let b = generate(7, &[&p], &opts);
        assert_eq!(a.cameras, b.cameras);
        assert_eq!(a.images[0].data, b.images[0].data);
        let mut rigs = std::collections::HashSet::new();
        for seed in 0..40 {
            let s = generate(seed, &[&p], &opts);
            assert!(s.cameras.len() >= 5, "{} views", s.cameras.len());
            assert!(s.near >= 0.5 && s.near <= 20.0 && s.far >= 10.0 * s.near * 0.999);
            assert!(s.far <= 200.0 * s.near * 1.001);
            for img in &s.images {
                assert!(img.data.iter().all(|v| (0.0..=1.0).contains(v)));
            }
            rigs.insert(format!("{:?}", s.rig));
        }
        assert_eq!(rigs.len(), 3, "{rigs:?}");
    }

    /// An independent check of the ray caster: a scene of one fronto-parallel photo patch, seen by a
    /// camera moved sideways, is the reference image shifted by the disparity `f b / z`.
    #[test]
    fn a_fronto_parallel_patch_shifts_by_its_disparity() {
        let p = photo();
        let (w, h, f, z, b) = (40u32, 30u32, 40.0, 4.0, 0.5);
        let k = Intrinsics::new(f, f, w as f64 / 2.0, h as f64 / 2.0);
        let objects = vec![Object {
            geometry: Geometry::Patch {
                centre: DVec3::new(0.0, 0.0, z),
                u: DVec3::X,
                v: DVec3::Y,
                normal: DVec3::Z,
                outline: Outline::Infinite,
            },
            texture: Texture::Photo {
                image: 0,
                origin: (0.0, 0.0),
                size: (64.0, 48.0),
                scale: f / z,
                tint: [1.0; 3],
            },
            alpha: 1.0,
        }];
        let c0 = Camera::new(w, h, k, Pose::IDENTITY);
        let c1 = Camera::new(w, h, k, Pose::from_center(DMat3::IDENTITY, DVec3::X * b));
        let (i0, i1) = (
            render(&objects, &c0, &[&p], 1),
            render(&objects, &c1, &[&p], 1),
        );
        let shift = (f * b / z) as u32; // 5 px
        for y in 2..h - 2 {
            for x in 2..w - shift - 2 {
                let (a, c) = (i0.pixel(x + shift, y), i1.pixel(x, y));
                for ch in 0..3 {
                    assert!((a[ch] - c[ch]).abs() < 1e-4, "({x},{y}) {a:?} {c:?}");
                }
            }
        }
        // A half-transparent sheet in front: over-compositing, exactly.
        let mut two = objects.clone();
        two.insert(
            0,
            Object {
                geometry: Geometry::Patch {
                    centre: DVec3::new(0.0, 0.0, 2.0),
                    u: DVec3::X,
                    v: DVec3::Y,
                    normal: DVec3::Z,
                    outline: Outline::Infinite,
                },
                texture: Texture::Waves {
                    base: [0.2, 0.4, 0.6],
                    waves: vec![],
                },
                alpha: 0.5,
            },
        );
        let i2 = render(&two, &c0, &[&p], 1);
        for (o, (a, c)) in i2
            .data
            .iter()
            .zip(i0.data.iter().zip([0.2f32, 0.4, 0.6].iter().cycle()))
        {
            assert!((o - (0.5 * c + 0.5 * a)).abs() < 1e-5);
        }
    }

    #[test]
    fn spheres_and_boxes_are_hit_where_analysis_says() {
        let s = Geometry::Sphere {
            centre: DVec3::new(0.0, 0.0, 5.0),
            radius: 1.0,
        };
        let (t, _, _) = s.hit(DVec3::ZERO, DVec3::Z).unwrap();
        assert!((t - 4.0).abs() < 1e-12);
        assert!(s.hit(DVec3::ZERO, DVec3::new(0.3, 0.0, 1.0)).is_none());
        let b = Geometry::Cuboid {
            centre: DVec3::new(0.0, 0.0, 5.0),
            rotation: DMat3::IDENTITY,
            half: DVec3::new(1.0, 1.0, 0.5),
        };
        let (t, _, _) = b.hit(DVec3::ZERO, DVec3::Z).unwrap();
        assert!((t - 4.5).abs() < 1e-12);
        // Rotated 45 degrees about y: the front edge is at distance 5 - sqrt(0.5^2 + 0.5^2)... for a cube.
        let cube = Geometry::Cuboid {
            centre: DVec3::new(0.0, 0.0, 5.0),
            rotation: DMat3::from_rotation_y(std::f64::consts::FRAC_PI_4),
            half: DVec3::splat(0.5),
        };
        let (t, _, _) = cube.hit(DVec3::ZERO, DVec3::Z).unwrap();
        assert!((t - (5.0 - 0.5 * 2f64.sqrt())).abs() < 1e-9, "{t}");
    }
}
