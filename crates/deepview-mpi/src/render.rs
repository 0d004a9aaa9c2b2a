//! The fast CPU renderer: warp every plane into the target camera and over-composite back to front.
//!
//! Rows of the output are independent: rayon splits them into bands, and each row keeps a small
//! accumulator (`W x 4` floats, in L1) while the planes are visited back to front, so every plane's
//! texels are read once per output row, in order. No allocation happens inside the loops.

use crate::mpi::{Mpi, MpiU8, Texel};
use crate::simd::Occupancy;
use crate::warp::{Sampler, target_to_plane_homographies};
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use rayon::prelude::*;

/// Composite `planes` (each `[H][W][4]` premultiplied, back to front) seen through `homs` (target pixel ->
/// plane pixel) into `out` (`[out_h][out_w][4]` premultiplied RGBA; alpha = 1 - prod(1 - a)).
pub fn render_layers<T: Texel>(
    layers: &[T],
    plane_w: u32,
    plane_h: u32,
    homs: &[[f64; 9]],
    out_w: u32,
    out_h: u32,
    out: &mut [f32],
) {
    render_layers_with(layers, plane_w, plane_h, homs, out_w, out_h, out, None)
}

/// [`render_layers`] with an optional [`Occupancy`] of 8-bit layers (skips empty tiles).
pub fn render_layers_with<T: Texel>(
    layers: &[T],
    plane_w: u32,
    plane_h: u32,
    homs: &[[f64; 9]],
    out_w: u32,
    out_h: u32,
    out: &mut [f32],
    occupancy: Option<&Occupancy>,
) {
    let plane_len = plane_w as usize * plane_h as usize * 4;
    assert_eq!(
        layers.len(),
        plane_len * homs.len(),
        "layer data does not match the plane count"
    );
    assert_eq!(out.len(), out_w as usize * out_h as usize * 4);
    let samplers: Vec<Sampler> = homs
        .iter()
        .map(|h| Sampler::new(*h, plane_w, plane_h))
        .collect();
    let row_len = out_w as usize * 4;
    // Bands of a few rows: enough work per task, enough tasks to balance.
    let rows_per_band = (out_h as usize / 64).clamp(1, 16);
    #[cfg(target_arch = "x86_64")]
    if let Some(bytes) = T::as_bytes(layers)
        && render_rows_simd(
            bytes,
            plane_w,
            plane_h,
            &samplers,
            out_w,
            out_h,
            out,
            occupancy,
            |v| v,
        )
    {
        return;
    }
    out.par_chunks_mut(row_len * rows_per_band)
        .enumerate()
        .for_each(|(band, chunk)| {
            for (r, row) in chunk.chunks_exact_mut(row_len).enumerate() {
                let y = (band * rows_per_band + r) as u32;
                row.fill(0.0);
                for (d, sampler) in samplers.iter().enumerate() {
                    let layer = &layers[d * plane_len..(d + 1) * plane_len];
                    composite_row(layer, sampler, y, row);
                }
            }
        });
}

/// The SIMD path of [`render_layers_with`] for 8-bit layers, writing each finished row through `convert`
/// (f32 as is, or straight to 8 bits: no full-frame f32 scratch). False when the CPU lacks the kernel.
#[cfg(target_arch = "x86_64")]
fn render_rows_simd<O: Copy + Send>(
    bytes: &[u8],
    plane_w: u32,
    plane_h: u32,
    samplers: &[Sampler],
    out_w: u32,
    out_h: u32,
    out: &mut [O],
    occupancy: Option<&Occupancy>,
    convert: impl Fn(f32) -> O + Sync,
) -> bool {
    let Some(kernel) = crate::simd::kernel() else {
        return false;
    };
    let plane_len = plane_w as usize * plane_h as usize * 4;
    let w = out_w as usize;
    let row_len = w * 4;
    // Bands of a few rows: enough tasks to balance, and each band shares its planes' spans (their
    // hulls loosen with the band's height: `bench render` on a 230-plane 718x561 learned MPI 29.5-30.6
    // fps with 4-row bands, 29.5-29.8 with 8, 28.5-28.9 with 16; a 65-plane 1119x865 one 25.7-25.9,
    // 25.3-25.8, 22.3-22.8).
    let rows_per_band = (out_h as usize / 128).clamp(1, 6);
    let wp = crate::simd::padded_width(w);
    out.par_chunks_mut(row_len * rows_per_band)
        .enumerate()
        .for_each_init(
            || (vec![0.0f32; 4 * wp], Vec::new()),
            |(acc, spans), (band, chunk)| {
                let y0 = band * rows_per_band;
                let y1 = y0 + chunk.len() / row_len - 1;
                // Per plane, the band's spans that can see its occupied tiles (the whole rows for
                // a plane without an empty tile), and whether to test tiles group by group.
                spans.resize_with(samplers.len(), || (Vec::new(), false));
                for (d, (sampler, (s, test))) in samplers.iter().zip(spans.iter_mut()).enumerate() {
                    match occupancy.filter(|o| o.sparse_plane(d).is_some()) {
                        Some(o) => {
                            let rows = [y0, y1].map(|y| sampler.row(y as u32).coefficients());
                            *test = o.band_spans(d, rows, w, plane_h, s);
                        }
                        None => {
                            s.clear();
                            s.push((0, wp));
                            *test = false;
                        }
                    }
                }
                for (r, row) in chunk.chunks_exact_mut(row_len).enumerate() {
                    let y = (y0 + r) as u32;
                    acc.fill(0.0);
                    // The columns not yet opaque (a superset, in whole groups of 8): they only shrink.
                    let (mut open_lo, mut open_hi) = (0, wp);
                    // Front to back: opaque pixels stop costing anything.
                    for (d, sampler) in samplers.iter().enumerate().rev() {
                        if open_lo >= open_hi {
                            break;
                        }
                        let (plane_spans, test) = &spans[d];
                        if plane_spans.is_empty() {
                            continue;
                        }
                        let layer = &bytes[d * plane_len..(d + 1) * plane_len];
                        let coeff = sampler.row(y).coefficients();
                        let tiles = if *test {
                            occupancy.and_then(|o| o.sparse_plane(d))
                        } else {
                            None
                        };
                        // SAFETY: `kernel()` checked the CPU features; the layer has plane_w * plane_h
                        // texels; the spans are within the accumulators.
                        let (lo, hi) = unsafe {
                            kernel(
                                layer,
                                plane_w,
                                plane_h,
                                coeff,
                                acc,
                                plane_spans,
                                (open_lo, open_hi),
                                tiles,
                            )
                        };
                        (open_lo, open_hi) = (lo, hi);
                    }
                    let (r_, rest) = acc.split_at(wp);
                    let (g_, rest) = rest.split_at(wp);
                    let (b_, a_) = rest.split_at(wp);
                    for (x, px) in row.chunks_exact_mut(4).enumerate() {
                        px[0] = convert(r_[x]);
                        px[1] = convert(g_[x]);
                        px[2] = convert(b_[x]);
                        px[3] = convert(a_[x]);
                    }
                }
            },
        );
    true
}

#[inline(always)]
fn composite_row<T: Texel>(layer: &[T], sampler: &Sampler, y: u32, row: &mut [f32]) {
    let rs = sampler.row(y);
    for (x, acc) in row.chunks_exact_mut(4).enumerate() {
        if let Some(t) = rs.tap(x as u32) {
            let p0 = T::rgba(layer, t.idx[0] as usize);
            let p1 = T::rgba(layer, t.idx[1] as usize);
            let p2 = T::rgba(layer, t.idx[2] as usize);
            let p3 = T::rgba(layer, t.idx[3] as usize);
            let mut c = [0.0f32; 4];
            for k in 0..4 {
                c[k] = t.w[0] * p0[k] + t.w[1] * p1[k] + t.w[2] * p2[k] + t.w[3] * p3[k];
            }
            let keep = 1.0 - c[3];
            for k in 0..4 {
                acc[k] = c[k] + keep * acc[k];
            }
        }
    }
}

/// Render an MPI (f32 or 8-bit texels) into `target`: 4 channels, premultiplied RGB and accumulated alpha.
pub fn render<T: Texel>(mpi: &Mpi<T>, target: &Camera) -> ImageF32 {
    let homs = target_to_plane_homographies(&mpi.camera, target, &mpi.depths);
    let mut out = ImageF32::new(target.width, target.height, 4);
    render_layers(
        &mpi.layers,
        mpi.camera.width,
        mpi.camera.height,
        &homs,
        target.width,
        target.height,
        &mut out.data,
    );
    out
}

/// The fraction of a render's pixels (from [`render`]: alpha in channel 3) the MPI covers (alpha at
/// least 1/2).
pub fn coverage(rendered: &ImageF32) -> f64 {
    if rendered.channels != 4 || rendered.data.is_empty() {
        return 0.0;
    }
    let covered = rendered
        .data
        .chunks_exact(4)
        .filter(|p| p[3] >= 0.5)
        .count();
    covered as f64 / (rendered.data.len() / 4) as f64
}

/// Below this [`coverage`] a render shows almost nothing of its MPI.
pub const LOW_COVERAGE: f64 = 0.01;

/// Why a render of an MPI from `target` shows little of it, where it does: a camera at or beyond
/// the MPI's nearest plane (the planes are composited for cameras in front of them), or one that
/// sees less than [`LOW_COVERAGE`] of its image covered (`coverage`: [`coverage`] of the render),
/// told apart by where the view looks: outside the planes' frames (facing away, or far outside the
/// inputs' view: [`frame_coverage`]) or at planes that are transparent there. `None` for an ordinary
/// view.
pub fn view_warning<T: Texel>(mpi: &Mpi<T>, target: &Camera, coverage: f64) -> Option<String> {
    let z = mpi.camera.pose.transform_point(target.center()).z;
    let nearest = mpi.depths.iter().copied().fold(f64::INFINITY, f64::min);
    if z >= nearest {
        return Some(format!(
            "the camera is at depth {z:.4} of the MPI's reference camera, at or beyond its nearest \
             plane ({nearest:.4}): an MPI is made to be seen from in front of its planes, and this \
             view is not what the scene looks like from there"
        ));
    }
    if coverage >= LOW_COVERAGE {
        return None;
    }
    let framed = frame_coverage(&mpi.camera, &mpi.depths, target);
    Some(if framed < LOW_COVERAGE {
        format!(
            "the MPI covers {:.1}% of this view: the camera looks outside its planes (facing away \
             from them, or far outside the inputs' view), and the image is mostly empty",
            100.0 * coverage
        )
    } else {
        format!(
            "the MPI covers {:.1}% of this view: the view looks at {:.0}% of its planes' frames, but \
             the planes are transparent there (an MPI of a scene with an empty background), and the \
             image is mostly empty",
            100.0 * coverage,
            100.0 * framed
        )
    })
}

/// The fraction of `target`'s pixels whose ray meets an MPI plane (reference camera `reference`,
/// `depths`) inside the plane's frame, whatever the plane holds: what a render could show at most.
/// Measured on a grid of at most 64 x 64 pixels.
pub fn frame_coverage(reference: &Camera, depths: &[f64], target: &Camera) -> f64 {
    // The renderer's own test of a pixel inside a plane ([`crate::warp::RowSampler::tap`]).
    let samplers: Vec<Sampler> = target_to_plane_homographies(reference, target, depths)
        .into_iter()
        .map(|m| Sampler::new(m, reference.width, reference.height))
        .collect();
    let (w, h) = (target.width.max(1), target.height.max(1));
    let (nx, ny) = (w.min(64), h.min(64));
    let mut inside = 0usize;
    for j in 0..ny {
        let rows: Vec<_> = samplers.iter().map(|s| s.row(j * h / ny)).collect();
        for i in 0..nx {
            inside += usize::from(rows.iter().any(|r| r.tap(i * w / nx).is_some()));
        }
    }
    inside as f64 / (nx * ny) as f64
}

/// Render an 8-bit MPI and convert to 8-bit RGBA, reusing `scratch` and `out` between frames.
pub fn render_rgba8_into(mpi: &MpiU8, target: &Camera, scratch: &mut Vec<f32>, out: &mut Vec<u8>) {
    render_rgba8_with(mpi, None, target, scratch, out)
}

/// [`render_rgba8_into`] with the MPI's [`Occupancy`] (computed once per MPI) to skip empty tiles.
pub fn render_rgba8_with(
    mpi: &MpiU8,
    occupancy: Option<&Occupancy>,
    target: &Camera,
    scratch: &mut Vec<f32>,
    out: &mut Vec<u8>,
) {
    let homs = target_to_plane_homographies(&mpi.camera, target, &mpi.depths);
    let n = target.width as usize * target.height as usize * 4;
    out.resize(n, 0);
    #[cfg(target_arch = "x86_64")]
    {
        let samplers: Vec<Sampler> = homs
            .iter()
            .map(|h| Sampler::new(*h, mpi.camera.width, mpi.camera.height))
            .collect();
        if render_rows_simd(
            &mpi.layers,
            mpi.camera.width,
            mpi.camera.height,
            &samplers,
            target.width,
            target.height,
            out,
            occupancy,
            deepview_image::to_u8,
        ) {
            return;
        }
    }
    scratch.resize(n, 0.0);
    render_layers_with(
        &mpi.layers,
        mpi.camera.width,
        mpi.camera.height,
        &homs,
        target.width,
        target.height,
        scratch,
        occupancy,
    );
    out.par_chunks_mut(64 * 1024)
        .zip(scratch.par_chunks(64 * 1024))
        .for_each(|(o, s)| {
            for (b, v) in o.iter_mut().zip(s) {
                *b = deepview_image::to_u8(*v);
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::{DMat3, DVec3, Intrinsics, Pose};

    fn scalar_u8(mpi: &MpiU8, target: &Camera) -> Vec<f32> {
        // The scalar path, forced by viewing the bytes through a wrapper type without `as_bytes`.
        #[derive(Clone, Copy, Default)]
        struct B(u8);
        impl Texel for B {
            fn rgba(layer: &[B], i: usize) -> [f32; 4] {
                let p = &layer[i * 4..i * 4 + 4];
                [
                    p[0].0 as f32 / 255.0,
                    p[1].0 as f32 / 255.0,
                    p[2].0 as f32 / 255.0,
                    p[3].0 as f32 / 255.0,
                ]
            }
            fn premultiplied(_: image::DynamicImage) -> Vec<B> {
                unreachable!("only rendered")
            }
        }
        let layers: Vec<B> = mpi.layers.iter().map(|&b| B(b)).collect();
        let homs = target_to_plane_homographies(&mpi.camera, target, &mpi.depths);
        let mut out = vec![0.0; target.width as usize * target.height as usize * 4];
        render_layers(
            &layers,
            mpi.camera.width,
            mpi.camera.height,
            &homs,
            target.width,
            target.height,
            &mut out,
        );
        out
    }

    /// An opaque far plane seen from the reference is covered everywhere; from a camera turned
    /// away, or one beyond the nearest plane, the render warns (coverage 0, the camera's depth).
    #[test]
    fn views_that_show_little_of_the_mpi_are_named() {
        let cam = Camera::new(16, 12, Intrinsics::centred(14.0, 16, 12), Pose::IDENTITY);
        let mut layers = vec![0.0f32; 2 * 16 * 12 * 4];
        // Plane 0 (depth 10) opaque grey, plane 1 (depth 2) empty.
        for t in layers[..16 * 12 * 4].chunks_exact_mut(4) {
            t.copy_from_slice(&[0.5, 0.5, 0.5, 1.0]);
        }
        let mpi = Mpi {
            camera: cam,
            depths: vec![10.0, 2.0],
            layers,
        };
        let rendered = render(&mpi, &cam);
        assert_eq!(coverage(&rendered), 1.0);
        assert_eq!(view_warning(&mpi, &cam, coverage(&rendered)), None);
        let away = Camera {
            pose: Pose::from_center(DMat3::from_rotation_y(std::f64::consts::PI), DVec3::ZERO),
            ..cam
        };
        let rendered = render(&mpi, &away);
        assert_eq!(coverage(&rendered), 0.0);
        assert_eq!(frame_coverage(&mpi.camera, &mpi.depths, &away), 0.0);
        let w = view_warning(&mpi, &away, coverage(&rendered)).unwrap();
        assert!(
            w.contains("covers 0.0% of this view") && w.contains("looks outside its planes"),
            "{w}"
        );
        // The same planes emptied: seen from the reference, the view is all inside their frames and
        // the warning says they are transparent, not that the camera looks away.
        let empty = Mpi {
            layers: vec![0.0; mpi.layers.len()],
            ..mpi.clone()
        };
        let rendered = render(&empty, &cam);
        assert_eq!(frame_coverage(&empty.camera, &empty.depths, &cam), 1.0);
        let w = view_warning(&empty, &cam, coverage(&rendered)).unwrap();
        assert!(
            w.contains("covers 0.0%") && w.contains("looks at 100% of its planes' frames"),
            "{w}"
        );
        // A camera shifted sideways by half its width at the far plane sees half the frames.
        let half = Camera {
            pose: Pose::from_center(DMat3::IDENTITY, DVec3::new(10.0 * 8.0 / 14.0, 0.0, 0.0)),
            ..cam
        };
        let f = frame_coverage(&mpi.camera, &[10.0], &half);
        assert!((f - 0.5).abs() < 1e-9, "{f}");
        let beyond = Camera {
            pose: Pose::from_center(DMat3::IDENTITY, DVec3::new(0.0, 0.0, 3.0)),
            ..cam
        };
        let rendered = render(&mpi, &beyond);
        let w = view_warning(&mpi, &beyond, coverage(&rendered)).unwrap();
        assert!(
            w.contains("at depth 3.0000") && w.contains("nearest plane (2.0000)"),
            "{w}"
        );
    }

    #[test]
    fn simd_and_scalar_paths_agree() {
        let cam = Camera::new(37, 29, Intrinsics::centred(30.0, 37, 29), Pose::IDENTITY);
        let depths = vec![20.0, 5.0, 2.0, 1.0];
        let mut layers = vec![0u8; 4 * 37 * 29 * 4];
        for (i, t) in layers.chunks_exact_mut(4).enumerate() {
            let a = ((i * 97) % 256) as u32;
            for k in 0..3 {
                t[k] = (((i * (31 + k * 7)) % 256) as u32 * a / 255) as u8;
            }
            t[3] = a as u8;
        }
        let mpi = MpiU8 {
            camera: cam,
            depths,
            layers,
        };
        // The reference camera itself (identity warps), and novel views including one that sees past
        // the planes' edges (transparent samples) and a width that is not a multiple of 8.
        let targets = [
            cam,
            Camera::new(
                41,
                23,
                Intrinsics::new(33.0, 31.0, 20.0, 11.0),
                Pose::from_center(DMat3::from_rotation_y(0.05), DVec3::new(0.3, -0.1, 0.2)),
            ),
            Camera::new(
                19,
                7,
                Intrinsics::centred(10.0, 19, 7),
                Pose::from_center(DMat3::IDENTITY, DVec3::new(-0.5, 0.0, 0.0)),
            ),
            // Small sideways moves (pure shifts of every plane, the SIMD kernel's contiguous-load path),
            // both directions, reaching past the left and right edges.
            Camera::new(
                37,
                29,
                Intrinsics::centred(30.0, 37, 29),
                Pose::from_center(DMat3::IDENTITY, DVec3::new(0.07, 0.03, 0.0)),
            ),
            Camera::new(
                37,
                29,
                Intrinsics::centred(30.0, 37, 29),
                Pose::from_center(DMat3::from_rotation_z(0.01), DVec3::new(-0.09, 0.0, 0.0)),
            ),
            // A wider field of view than the planes' (1.5 texels per pixel: the taps of 8 pixels span
            // more than 8 texels, the kernel's 16-texel window).
            Camera::new(
                37,
                29,
                Intrinsics::centred(20.0, 37, 29),
                Pose::from_center(DMat3::IDENTITY, DVec3::new(0.05, 0.02, 0.0)),
            ),
        ];
        // The SIMD path composites front to back and stops at accumulated alpha 1 - 1/1024: equal to the
        // scalar back-to-front result within that bound.
        let occ = Occupancy::new(&mpi.layers, 37, 29, 4);
        for t in targets {
            let fast = render(&mpi, &t);
            let slow = scalar_u8(&mpi, &t);
            let err = fast
                .data
                .iter()
                .zip(&slow)
                .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(err < 1.0 / 1024.0 + 1e-5, "max difference {err} for {t:?}");
            let (mut scratch, mut out) = (Vec::new(), Vec::new());
            render_rgba8_with(&mpi, Some(&occ), &t, &mut scratch, &mut out);
            // 8-bit output: the rounding of the scalar result, give or take the 1/1024 bound.
            let err = out
                .iter()
                .zip(&slow)
                .fold(0.0f32, |m, (&a, &b)| m.max((a as f32 / 255.0 - b).abs()));
            assert!(
                err < 0.5 / 255.0 + 1.0 / 1024.0 + 1e-5,
                "with occupancy, 8-bit output: max difference {err}"
            );
        }
        let id = render(&mpi, &cam);
        let f32_render = render(&mpi.to_f32(), &cam);
        let err = id
            .data
            .iter()
            .zip(&f32_render.data)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(err < 1.0 / 1024.0 + 1e-5, "u8 vs f32 layers {err}");
    }

    #[test]
    fn empty_tiles_are_skipped_without_changing_the_image() {
        // Sparse content: one small opaque square per plane; everything else transparent.
        let cam = Camera::new(64, 48, Intrinsics::centred(60.0, 64, 48), Pose::IDENTITY);
        let depths = vec![10.0, 4.0, 2.0];
        let mut layers = vec![0u8; 3 * 64 * 48 * 4];
        for d in 0..3 {
            for y in 10 + d * 8..20 + d * 8 {
                for x in 5 + d * 15..17 + d * 15 {
                    let i = ((d * 48 + y) * 64 + x) * 4;
                    layers[i..i + 4].copy_from_slice(&[200, (40 * d) as u8, 90, 255]);
                }
            }
        }
        let mpi = MpiU8 {
            camera: cam,
            depths,
            layers,
        };
        let occ = Occupancy::new(&mpi.layers, 64, 48, 3);
        assert!(occ.fill() < 0.2, "fill {}", occ.fill());
        let target = Camera::new(
            64,
            48,
            cam.intrinsics,
            Pose::from_center(DMat3::from_rotation_z(0.1), DVec3::new(0.2, 0.1, 0.0)),
        );
        let full = render(&mpi, &target);
        let (mut scratch, mut out) = (Vec::new(), Vec::new());
        render_rgba8_with(&mpi, Some(&occ), &target, &mut scratch, &mut out);
        // Skipping empty tiles adds nothing that was not zero: the 8-bit image is exactly the full one's.
        assert_eq!(out, full.to_u8());
        assert!(
            full.data.iter().any(|&v| v > 0.5),
            "the squares are visible"
        );
    }

    /// Sparse content on many planes (blobs of every opacity, opaque ones included, so that rows
    /// saturate part way): the spans and the saturation tracking skip only what adds nothing, so the
    /// image equals the one rendered without the occupancy map, bit for bit, from views that shift,
    /// zoom, roll (rows crossing many tile rows), tilt (perspective) and see past the planes' edges.
    #[test]
    fn occupancy_spans_change_nothing() {
        let (w, h, d) = (150u32, 97u32, 24usize);
        let cam = Camera::new(w, h, Intrinsics::centred(120.0, w, h), Pose::IDENTITY);
        let depths = deepview_geometry::plane_depths(
            1.0,
            20.0,
            d,
            deepview_geometry::PlaneSpacing::InverseDepth,
        )
        .unwrap();
        let mut state = 99u64;
        let mut next = |n: u32| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) as u32) % n
        };
        let mut layers = vec![0u8; d * (w * h * 4) as usize];
        for p in 0..d {
            for _ in 0..3 {
                let (cx, cy, r) = (next(w), next(h), 3 + next(14));
                let alpha = [255, 255, 40, 130, 7][next(5) as usize];
                for y in cy.saturating_sub(r)..(cy + r).min(h) {
                    for x in cx.saturating_sub(r)..(cx + r).min(w) {
                        let i = ((p as u32 * h + y) * w + x) as usize * 4;
                        let (r, g, b) = (next(256), next(256), next(256));
                        let c = |v: u32| (v * alpha / 255) as u8;
                        layers[i..i + 4].copy_from_slice(&[c(r), c(g), c(b), alpha as u8]);
                    }
                }
            }
        }
        let mpi = MpiU8 {
            camera: cam,
            depths,
            layers,
        };
        let occ = Occupancy::new(&mpi.layers, w, h, d);
        assert!(occ.fill() < 0.5, "sparse: {}", occ.fill());
        let view = |rot: DMat3, c: DVec3, f: f64, size: (u32, u32)| {
            Camera::new(
                size.0,
                size.1,
                Intrinsics::centred(f, size.0, size.1),
                Pose::from_center(rot, c),
            )
        };
        let targets = [
            cam,
            view(
                DMat3::IDENTITY,
                DVec3::new(0.3, -0.2, 0.0),
                120.0,
                (150, 97),
            ),
            view(
                DMat3::IDENTITY,
                DVec3::new(-0.4, 0.1, 0.5),
                180.0,
                (161, 90),
            ),
            view(
                DMat3::from_rotation_z(0.35),
                DVec3::new(0.1, 0.0, 0.0),
                120.0,
                (150, 97),
            ),
            view(
                DMat3::from_rotation_x(0.2) * DMat3::from_rotation_y(-0.25),
                DVec3::new(0.2, 0.1, -0.3),
                90.0,
                (133, 101),
            ),
            view(
                DMat3::from_rotation_y(0.6),
                DVec3::new(1.5, 0.0, 0.0),
                60.0,
                (77, 45),
            ),
        ];
        for t in targets {
            let (mut scratch, mut with, mut without) = (Vec::new(), Vec::new(), Vec::new());
            assert!(occ.fill() < 0.5);
            render_rgba8_with(&mpi, Some(&occ), &t, &mut scratch, &mut with);
            render_rgba8_with(&mpi, None, &t, &mut scratch, &mut without);
            assert!(with == without, "{t:?}");
            assert!(
                with.iter().any(|&v| v > 100),
                "something is visible from {t:?}"
            );
        }
    }
}
