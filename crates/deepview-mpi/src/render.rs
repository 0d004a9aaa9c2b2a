//! The fast CPU renderer: warp every plane into the target camera and over-composite back to front.
//!
//! Rows of the output are independent: rayon splits them into bands, and each row keeps a small
//! accumulator (`W x 4` floats, in L1) while the planes are visited back to front, so every plane's
//! texels are read once per output row, in order. No allocation happens inside the loops.

use crate::mpi::{Mpi, MpiU8};
use crate::warp::{Sampler, target_to_plane_homographies};
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use rayon::prelude::*;

/// A texel type of MPI layers: f32 or u8 premultiplied RGBA.
pub trait Texel: Copy + Send + Sync + 'static {
    /// Premultiplied RGBA of texel `i` (in texels) as f32 in 0..1.
    fn rgba(layer: &[Self], i: usize) -> [f32; 4];
}

impl Texel for f32 {
    #[inline(always)]
    fn rgba(layer: &[f32], i: usize) -> [f32; 4] {
        let p = &layer[i * 4..i * 4 + 4];
        [p[0], p[1], p[2], p[3]]
    }
}

impl Texel for u8 {
    #[inline(always)]
    fn rgba(layer: &[u8], i: usize) -> [f32; 4] {
        let p = &layer[i * 4..i * 4 + 4];
        const S: f32 = 1.0 / 255.0;
        [p[0] as f32 * S, p[1] as f32 * S, p[2] as f32 * S, p[3] as f32 * S]
    }
}

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
    let plane_len = plane_w as usize * plane_h as usize * 4;
    assert_eq!(layers.len(), plane_len * homs.len(), "layer data does not match the plane count");
    assert_eq!(out.len(), out_w as usize * out_h as usize * 4);
    let samplers: Vec<Sampler> = homs.iter().map(|h| Sampler::new(*h, plane_w, plane_h)).collect();
    let row_len = out_w as usize * 4;
    // Bands of a few rows: enough work per task, enough tasks to balance.
    let rows_per_band = (out_h as usize / 64).clamp(1, 16);
    out.par_chunks_mut(row_len * rows_per_band).enumerate().for_each(|(band, chunk)| {
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

/// Render an MPI into `target`: 4 channels, premultiplied RGB and accumulated alpha.
pub fn render(mpi: &Mpi, target: &Camera) -> ImageF32 {
    let homs = target_to_plane_homographies(&mpi.camera, target, &mpi.depths);
    let mut out = ImageF32::new(target.width, target.height, 4);
    render_layers(&mpi.layers, mpi.camera.width, mpi.camera.height, &homs, target.width, target.height, &mut out.data);
    out
}

/// Render an 8-bit MPI into `target` (f32 result as [`render`]).
pub fn render_u8(mpi: &MpiU8, target: &Camera) -> ImageF32 {
    let homs = target_to_plane_homographies(&mpi.camera, target, &mpi.depths);
    let mut out = ImageF32::new(target.width, target.height, 4);
    render_layers(&mpi.layers, mpi.camera.width, mpi.camera.height, &homs, target.width, target.height, &mut out.data);
    out
}

/// Render an 8-bit MPI and convert to 8-bit RGBA, reusing `scratch` and `out` between frames.
pub fn render_rgba8_into(mpi: &MpiU8, target: &Camera, scratch: &mut Vec<f32>, out: &mut Vec<u8>) {
    let homs = target_to_plane_homographies(&mpi.camera, target, &mpi.depths);
    let n = target.width as usize * target.height as usize * 4;
    scratch.resize(n, 0.0);
    render_layers(&mpi.layers, mpi.camera.width, mpi.camera.height, &homs, target.width, target.height, scratch);
    out.resize(n, 0);
    out.par_chunks_mut(64 * 1024).zip(scratch.par_chunks(64 * 1024)).for_each(|(o, s)| {
        for (b, v) in o.iter_mut().zip(s) {
            *b = deepview_image::to_u8(*v);
        }
    });
}
