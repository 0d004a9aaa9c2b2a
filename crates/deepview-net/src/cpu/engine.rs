//! Whole-image inference on plain `f32` arrays with the CPU kernels: the same model as
//! [`DeepViewModel::forward`] (plane sweeps, the agreement prior, renders `R`, `A`, `T` into every view
//! and their inverse warps, every net), with no tensor per operation. Each net runs one plane at a time
//! per thread ([`NetScratch`]): its inputs are warped straight into the kernels' padded planes.
//!
//! Memory: the state between nets (`D x S x H x W`), for update nets the views' renders (`K x D x 4`
//! texels per view pixel: `A` and `T` of every plane, plus `I` and `R`), and per thread one plane's
//! activations. [`engine_bytes`] estimates it; `infer` falls back to the tiled burn path
//! ([`crate::infer`]) when it exceeds the budget. The renders `A`, `T` (the largest part at wide
//! captures' plane counts) can be stored as half floats ([`StatePrecision::F16`]: 11 significant bits,
//! relative error <= 4.9e-4 on values in 0..1), half their memory, where the f32 ones do not fit.

use crate::cpu::packed::{NetScratch, PackedNet};
use crate::cpu::planes::for_each_chunk_with;
use crate::cpu::prior::{prior_logits, prior_stats};
use crate::cpu::warps::{warp_into, warp_pair_into};
use crate::forward::{Hom, invert, mpi_to_view_homographies};
use crate::infer::StatePrecision;
use crate::network::DeepViewModel;
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_kernels::Plane;
use deepview_kernels::fastmath;
use deepview_mpi::warp::{RowTaps, Sampler};
use half::f16;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

/// Estimated peak bytes of [`infer_engine`] (besides the inputs' images).
pub fn engine_bytes(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    w: usize,
    h: usize,
    d: usize,
    renders: StatePrecision,
) -> u64 {
    let k = views.len() as u64;
    let (hw, d64) = ((w * h) as u64, d as u64);
    let view_px: u64 = views
        .iter()
        .map(|(i, _)| i.width as u64 * i.height as u64)
        .sum();
    let s = model.state_channels as u64;
    let plane = Plane::new(h, w).len() as u64;
    let threads = rayon::current_num_threads() as u64;
    let half = Plane::new(h.div_ceil(2), w.div_ceil(2)).len() as u64;
    let scratch = model
        .nets
        .iter()
        .map(|n| {
            let cin = n.input[0].weight.dims()[1] as u64;
            let f = n.head.weight.dims()[1] as u64;
            let planes = k * (cin + 2 * f) + 3 * f + s;
            // A U-Net net's scratch is at half resolution, beside its full-resolution inputs.
            if n.unet {
                planes * half + k * cin * plane
            } else {
                planes * plane
            }
        })
        .max()
        .unwrap_or(0);
    let (at, convert) = if model.nets.len() > 1 {
        let at = view_px * 4 * d64 * renders.bytes();
        // Half floats are widened one view plane at a time, per thread.
        let widest = views
            .iter()
            .map(|(i, _)| i.width as u64 * i.height as u64)
            .max()
            .unwrap_or(0);
        let row = views.iter().map(|(i, _)| i.width as u64).max().unwrap_or(0);
        let convert = match renders {
            StatePrecision::F32 => 0,
            // A widened view plane per thread, and a view row of every plane per thread.
            StatePrecision::F16 => threads * (widest * 4 * 4 + d64 * row * 4 * 4),
        };
        (at + view_px * 6 * 4, convert)
    } else {
        (0, 0)
    };
    4 * (d64 * s * hw + d64 * 4 * hw + threads * scratch) + at + convert
}

/// Run `f` compiled with AVX-512 or AVX2 + FMA where the CPU has them (the warps' `mul_add` and `floor`
/// become instructions instead of libm calls; `f`'s body is inlined into the feature-enabled function),
/// else as is.
#[inline(always)]
fn with_fma<R>(f: impl FnOnce() -> R) -> R {
    fastmath::with_simd(f)
}

/// The state `[D][S][H*W]` -> premultiplied RGBA `[D][H*W][4]` (see `network::state_to_rgba`): the
/// sigmoids of a run of pixels as vector loops ([`fastmath::with_simd`]), then interleaved.
fn state_to_rgba(state: &[f32], s: usize, hw: usize) -> Vec<f32> {
    const RUN: usize = 256;
    let mut rgba = deepview_kernels::zeroed_buffer(state.len() / s * 4);
    rgba.par_chunks_mut(hw * 4).enumerate().for_each(|(p, r)| {
        let st = &state[p * s * hw..];
        fastmath::with_simd(
            #[inline(always)]
            || {
                let mut tmp = [[0f32; RUN]; 4];
                for (k, out) in r.chunks_mut(4 * RUN).enumerate() {
                    let (i0, n) = (k * RUN, out.len() / 4);
                    for (a, &x) in tmp[3][..n].iter_mut().zip(&st[3 * hw + i0..][..n]) {
                        *a = fastmath::sigmoid(x);
                    }
                    let (rgb, a) = tmp.split_at_mut(3);
                    for c in 0..3 {
                        let src = &st[c * hw + i0..][..n];
                        for ((t, &x), &a) in rgb[c][..n].iter_mut().zip(src).zip(&a[0][..n]) {
                            *t = fastmath::sigmoid(x) * a;
                        }
                    }
                    for (i, t) in out.chunks_exact_mut(4).enumerate() {
                        t.copy_from_slice(&[tmp[0][i], tmp[1][i], tmp[2][i], tmp[3][i]]);
                    }
                }
            },
        )
    });
    rgba
}

/// The views' renders of an RGBA MPI (`[D][H][W][4]`, premultiplied): per view, `[y][x][6]` of `I` and
/// `R`, and `[D][y][x][4]` of `A` (3) and `T` (1) in view pixels, in f32 or half floats.
struct Renders {
    ir: Vec<Vec<f32>>,
    at: AtStore,
}

enum AtStore {
    F32(Vec<Vec<f32>>),
    F16(Vec<Vec<f16>>),
}

impl Renders {
    /// Plane `p` of view `v`'s `A`/`T` (`vpx * 4` values), widened into `buf` when stored as half floats.
    fn at_plane<'a>(&'a self, v: usize, p: usize, vpx: usize, buf: &'a mut Vec<f32>) -> &'a [f32] {
        match &self.at {
            AtStore::F32(at) => &at[v][p * vpx * 4..][..vpx * 4],
            AtStore::F16(at) => {
                buf.resize(vpx * 4, 0.0);
                at[v][p * vpx * 4..][..vpx * 4].convert_to_f32_slice(buf);
                buf
            }
        }
    }
}

fn render_views(
    rgba: &[f32],
    views: &[(ImageF32, Camera)],
    homs: &[Vec<Hom>],
    w: usize,
    h: usize,
    d: usize,
    precision: StatePrecision,
) -> Renders {
    let mut ir = Vec::with_capacity(views.len());
    let mut at32 = Vec::new();
    let mut at16 = Vec::new();
    for (v, (img, _)) in views.iter().enumerate() {
        let (vw, vh) = (img.width as usize, img.height as usize);
        let samplers: Vec<Sampler> = homs[v]
            .iter()
            .map(|m| Sampler::new(invert(m), w as u32, h as u32))
            .collect();
        let mut irv = vec![0f32; vw * vh * 6];
        match precision {
            StatePrecision::F32 => {
                let mut atv = deepview_kernels::zeroed_buffer(d * vw * vh * 4);
                let at_ptr = atv.as_mut_ptr() as usize;
                irv.par_chunks_mut(vw * 6).enumerate().for_each(|(y, row)| {
                    let at = AtRows {
                        ptr: at_ptr,
                        plane_stride: vh * vw * 4,
                        row_offset: y * vw * 4,
                    };
                    render_row(rgba, img, &samplers, y, row, at, w, h, d);
                });
                at32.push(atv);
            }
            StatePrecision::F16 => {
                // Each row of every plane in f32 first (the arithmetic of the f32 store), then rounded.
                let mut atv = vec![f16::ZERO; d * vw * vh * 4];
                let at_ptr = atv.as_mut_ptr() as usize;
                irv.par_chunks_mut(vw * 6).enumerate().for_each_init(
                    || vec![0f32; d * vw * 4],
                    |rows, (y, row)| {
                        let at = AtRows {
                            ptr: rows.as_mut_ptr() as usize,
                            plane_stride: vw * 4,
                            row_offset: 0,
                        };
                        render_row(rgba, img, &samplers, y, row, at, w, h, d);
                        for p in 0..d {
                            // SAFETY: row `y` of plane `p` of the store, written by this task only.
                            let dst = unsafe {
                                std::slice::from_raw_parts_mut(
                                    (at_ptr as *mut f16).add((p * vh + y) * vw * 4),
                                    vw * 4,
                                )
                            };
                            dst.convert_from_f32_slice(&rows[p * vw * 4..(p + 1) * vw * 4]);
                        }
                    },
                );
                at16.push(atv);
            }
        }
        ir.push(irv);
    }
    let at = match precision {
        StatePrecision::F32 => AtStore::F32(at32),
        StatePrecision::F16 => AtStore::F16(at16),
    };
    Renders { ir, at }
}

/// Where a render row writes `A`/`T`: plane `p`'s row at `ptr + p * plane_stride + row_offset` (floats).
#[derive(Clone, Copy)]
struct AtRows {
    ptr: usize,
    plane_stride: usize,
    row_offset: usize,
}

/// Row `y` of one view's render: `row` gets `[x][I (3), R (3)]`, and `at` row `y` of every plane's
/// `A`/`T`.
#[allow(clippy::too_many_arguments)]
fn render_row(
    rgba: &[f32],
    img: &ImageF32,
    samplers: &[Sampler],
    y: usize,
    row: &mut [f32],
    at: AtRows,
    w: usize,
    h: usize,
    d: usize,
) {
    with_fma(
        #[inline(always)]
        || render_row_portable(rgba, img, samplers, y, row, at, w, h, d),
    )
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn render_row_portable(
    rgba: &[f32],
    img: &ImageF32,
    samplers: &[Sampler],
    y: usize,
    row: &mut [f32],
    at: AtRows,
    w: usize,
    h: usize,
    d: usize,
) {
    let vw = img.width as usize;
    // Plane by plane (each plane's row is one sequential stream of taps and of `A`/`T` writes; a
    // pixel-major order would follow `2 d` streams at once), back to front: `acc[x]` is the
    // composite of the planes behind `p` (`A_p`), stored with plane `p`'s alpha, which the front-to-back
    // pass then replaces by the transmittance `T_p` of the planes in front. Per pixel the arithmetic
    // and its order are those of the composite's definition.
    let mut acc = vec![[0f32; 3]; vw];
    let mut taps = RowTaps::default();
    // SAFETY (for every write through `at` below): row `y` of every plane of the store is written by
    // this task only.
    let at_row = |p: usize| unsafe {
        std::slice::from_raw_parts_mut(
            (at.ptr as *mut f32).add(p * at.plane_stride + at.row_offset),
            vw * 4,
        )
    };
    for (p, sampler) in samplers.iter().enumerate().take(d) {
        sampler.row(y as u32).taps_into(vw, &mut taps);
        let plane = &rgba[p * h * w * 4..][..h * w * 4];
        let out = at_row(p);
        for x in 0..vw {
            let (c, a) = match taps.tap(x) {
                None => ([0f32; 3], 0f32),
                Some(t) => {
                    let mut s = [0f32; 4];
                    for j in 0..4 {
                        let q = &plane[t.idx[j] as usize * 4..][..4];
                        for c in 0..4 {
                            s[c] += t.w[j] * q[c];
                        }
                    }
                    ([s[0], s[1], s[2]], s[3])
                }
            };
            let ax = &mut acc[x];
            out[x * 4..x * 4 + 4].copy_from_slice(&[ax[0], ax[1], ax[2], a]);
            let om = 1.0 - a;
            for ch in 0..3 {
                ax[ch] = ax[ch] * om + c[ch];
            }
        }
    }
    for x in 0..vw {
        let src = &img.data[(y * vw + x) * img.channels..];
        row[x * 6..x * 6 + 3].copy_from_slice(&src[..3]);
        row[x * 6 + 3..x * 6 + 6].copy_from_slice(&acc[x]);
    }
    let mut t = vec![1f32; vw];
    for p in (0..d).rev() {
        let out = at_row(p);
        for x in 0..vw {
            let alpha = out[x * 4 + 3];
            out[x * 4 + 3] = t[x];
            if p > 0 {
                t[x] *= 1.0 - alpha;
            }
        }
    }
}

/// The full-resolution input planes of a U-Net net's `K` views (`Cin` each), pooled into its scratch.
struct FullInputs {
    bufs: Vec<Vec<f32>>,
    cin: usize,
}

impl FullInputs {
    fn new(plane: Plane, views: usize, cin: usize) -> Self {
        Self {
            bufs: (0..views * cin).map(|_| plane.zeroed()).collect(),
            cin,
        }
    }
    fn view_mut(&mut self, v: usize) -> Vec<&mut [f32]> {
        self.bufs[v * self.cin..(v + 1) * self.cin]
            .iter_mut()
            .map(|b| b.as_mut_slice())
            .collect()
    }
    fn all_mut(&mut self) -> Vec<&mut [f32]> {
        self.bufs.iter_mut().map(|b| b.as_mut_slice()).collect()
    }
    /// Pool every plane into `sc` (skipping the views' copies of shared channels, which the net reads
    /// from view 0 only).
    fn pool_into(&self, full: Plane, half: Plane, sc: &mut NetScratch, shared: usize) {
        for (i, b) in self.bufs.iter().enumerate() {
            let (v, c) = (i / self.cin, i % self.cin);
            if v > 0 && c >= self.cin - shared {
                continue;
            }
            avg_pool_into(full, b, half, sc.input_mut(v, c));
        }
    }
}

/// The U-Net's input pooling (`avg_pool2d`, 2x2, stride 2, an odd last row / column padded with zeros
/// that count in the mean) of the padded plane `src` of `full` into the padded plane `dst` of `half`
/// (`ceil(h / 2) x ceil(w / 2)`): the padding is the planes' own zero border.
fn avg_pool_into(full: Plane, src: &[f32], half: Plane, dst: &mut [f32]) {
    for y in 0..half.h {
        let (r0, r1) = (full.index(2 * y, 0), full.index(2 * y + 1, 0));
        let o = half.index(y, 0);
        for x in 0..half.w {
            let (a, b) = (r0 + 2 * x, r1 + 2 * x);
            dst[o + x] = (src[a] + src[a + 1] + src[b] + src[b + 1]) / 4.0;
        }
    }
}

/// The U-Net's output upsampling (`interpolate` bilinear, `align_corners = false`, to twice the half
/// size, cropped to `full`): padded plane `src` of `half` into (`add`: onto) the unpadded `dst` of
/// `full`, with burn's coordinates and weights.
fn upsample_into(half: Plane, src: &[f32], full: Plane, dst: &mut [f32], add: bool) {
    // Source coordinate, low index, high index and weight along one axis (`in_size` -> `2 in_size`).
    let axis = |out: usize, in_size: usize| {
        let c = (out as f64 + 0.5) * (in_size as f64 / (2 * in_size) as f64) - 0.5;
        let lo = c.floor().max(0.0) as usize;
        (
            lo,
            (lo + 1).min(in_size - 1),
            (c - lo as f64).max(0.0) as f32,
        )
    };
    let xs: Vec<(usize, usize, f32)> = (0..full.w).map(|x| axis(x, half.w)).collect();
    for y in 0..full.h {
        let (y0, y1, wy) = axis(y, half.h);
        let (ra, rb) = (half.index(y0, 0), half.index(y1, 0));
        let row = &mut dst[y * full.w..(y + 1) * full.w];
        for (o, &(x0, x1, wx)) in row.iter_mut().zip(&xs) {
            let v = src[ra + x0] * (1.0 - wx) * (1.0 - wy)
                + src[ra + x1] * wx * (1.0 - wy)
                + src[rb + x0] * (1.0 - wx) * wy
                + src[rb + x1] * wx * wy;
            if add {
                *o += v;
            } else {
                *o = v;
            }
        }
    }
}

/// Infer the MPI (premultiplied RGBA `[D][H][W][4]`) of `reference` at `depths` from `views` with the
/// kernels; `progress(net)` after each net. Any model: U-Net nets run their core at half resolution
/// between a 2x2 average pool and a bilinear upsampling, as `CoreNet::forward`.
pub fn infer_engine(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    renders_precision: StatePrecision,
    progress: &mut dyn FnMut(usize),
) -> Vec<f32> {
    let (w, h, d) = (
        reference.width as usize,
        reference.height as usize,
        depths.len(),
    );
    let k = views.len();
    let hw = w * h;
    let plane = Plane::new(h, w);
    let s = model.state_channels;
    let homs = mpi_to_view_homographies(reference, views.iter().map(|(_, c)| c), depths);
    let nets: Vec<PackedNet> = model
        .nets
        .iter()
        .enumerate()
        // An update net's last `S` inputs are the state, the same for every view.
        .map(|(i, n)| {
            PackedNet::new(
                &n.input,
                &n.stages,
                &n.head,
                &n.out,
                if i == 0 { 0 } else { s },
                true,
            )
        })
        .collect();
    // The state `[D][S][H*W]`.
    let mut state = deepview_kernels::zeroed_buffer(d * s * hw);
    for (n, net) in nets.iter().enumerate() {
        let cin = net.in_channels();
        // A U-Net net: its inputs at full resolution, pooled into its half-resolution scratch.
        let unet = model.nets[n].unet;
        let np = if unet {
            Plane::new(h.div_ceil(2), w.div_ceil(2))
        } else {
            plane
        };
        let scratch = || {
            (
                NetScratch::new(net, np, k),
                unet.then(|| FullInputs::new(plane, k, cin)),
            )
        };
        // The net's output channel `c` into (`add`: onto) the unpadded state plane `dst`.
        let take_output = |sc: &NetScratch, c: usize, dst: &mut [f32], add: bool| {
            if unet {
                upsample_into(np, sc.output(c), plane, dst, add);
            } else if add {
                let out = sc.output(c);
                for (y, row) in dst.chunks_exact_mut(w).enumerate() {
                    let i = plane.index(y, 0);
                    for (x, &u) in row.iter_mut().zip(&out[i..i + w]) {
                        *x += u;
                    }
                }
            } else {
                plane.unpad_into(sc.output(c), dst);
            }
        };
        if n == 0 {
            // The plane sweeps feed both the net and the agreement prior's first pass.
            let temperature = model.prior_temperature;
            let mut prior =
                deepview_kernels::zeroed_buffer(if temperature > 0.0 { d * 4 * hw } else { 0 });
            let prior_ptr = prior.as_mut_ptr() as usize;
            for_each_chunk_with(&mut state, s * hw, scratch, |(sc, full), (p, st)| {
                for (v, (img, _)) in views.iter().enumerate() {
                    let mut ins = match full {
                        Some(f) => f.view_mut(v),
                        None => sc.view_inputs_mut(v),
                    };
                    let (rgb, rest) = ins.split_at_mut(3);
                    let valid = &mut *rest[0];
                    warp_into(
                        &img.data,
                        img.channels,
                        img.width,
                        img.height,
                        &homs[v][p],
                        plane,
                        rgb,
                        Some(valid),
                    );
                }
                if temperature > 0.0 {
                    let psv = match full {
                        Some(f) => f.all_mut(),
                        None => sc.inputs_mut(),
                    };
                    // SAFETY: plane p's `4 * hw` values of the prior, written by this task only.
                    let o = unsafe {
                        std::slice::from_raw_parts_mut(
                            (prior_ptr as *mut f32).add(p * 4 * hw),
                            4 * hw,
                        )
                    };
                    prior_stats(&psv, plane, temperature, o);
                }
                if let Some(f) = full {
                    f.pool_into(plane, np, sc, 0);
                }
                sc.run(net);
                for c in 0..s {
                    take_output(sc, c, &mut st[c * hw..(c + 1) * hw], false);
                }
            });
            if temperature > 0.0 {
                prior_logits(&mut prior, d, hw);
                state
                    .par_chunks_mut(s * hw)
                    .enumerate()
                    .for_each(|(p, st)| {
                        for (o, &q) in st[..4 * hw]
                            .iter_mut()
                            .zip(&prior[p * 4 * hw..(p + 1) * 4 * hw])
                        {
                            *o += q;
                        }
                    });
            }
            debug_assert_eq!(cin, crate::network::INIT_CHANNELS);
        } else {
            // RGBA of the current state, `[D][H][W][4]`.
            let rgba = state_to_rgba(&state, s, hw);
            let renders = render_views(&rgba, views, &homs, w, h, d, renders_precision);
            drop(rgba);
            // In place: plane p's update reads only its own state and the renders (made before).
            let scratch = || (scratch(), Vec::new());
            for_each_chunk_with(
                &mut state,
                s * hw,
                scratch,
                |((sc, full), wide), (p, st)| {
                    for (v, (img, _)) in views.iter().enumerate() {
                        let (vw, vh) = (img.width, img.height);
                        let vpx = vw as usize * vh as usize;
                        let mut ins = match full {
                            Some(f) => f.view_mut(v),
                            None => sc.view_inputs_mut(v),
                        };
                        // [I (3), R (3), A (3), T (1), validity (1), state (S)].
                        let (ir, rest) = ins.split_at_mut(6);
                        let (atp, rest) = rest.split_at_mut(4);
                        let (valid, st_planes) = rest.split_at_mut(1);
                        let at_plane = renders.at_plane(v, p, vpx, wide);
                        warp_pair_into(
                            (&renders.ir[v], at_plane),
                            (vw, vh),
                            &homs[v][p],
                            plane,
                            (ir, atp),
                            valid[0],
                        );
                        // The net reads the shared state from view 0's planes only.
                        if v == 0 {
                            for (c, dst) in st_planes.iter_mut().enumerate() {
                                plane.pad_into(&st[c * hw..(c + 1) * hw], dst);
                            }
                        }
                    }
                    debug_assert_eq!((cin, net.shared_inputs()), (11 + s, s));
                    if let Some(f) = full {
                        f.pool_into(plane, np, sc, s);
                    }
                    sc.run(net);
                    for c in 0..s {
                        take_output(sc, c, &mut st[c * hw..(c + 1) * hw], true);
                    }
                },
            );
        }
        progress(n);
    }
    // Premultiplied RGBA `[D][H][W][4]`.
    state_to_rgba(&state, s, hw)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::DeepViewConfig;
    use crate::forward::image_tensor;
    use crate::network::ModelInputs;
    use burn::tensor::Device;
    use deepview_geometry::{DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths};

    fn scene(k: usize, d: usize) -> (Vec<(ImageF32, Camera)>, Camera, Vec<f64>) {
        let reference = Camera::new(37, 29, Intrinsics::centred(33.0, 37, 29), Pose::IDENTITY);
        let depths = plane_depths(1.5, 12.0, d, PlaneSpacing::InverseDepth).unwrap();
        let views = (0..k)
            .map(|i| {
                let (vw, vh) = (31 + 3 * i as u32, 27 + 2 * i as u32);
                let a = i as f64 * 2.1;
                let cam = Camera::new(
                    vw,
                    vh,
                    Intrinsics::new(30.0, 31.0, vw as f64 / 2.0 + 0.3, vh as f64 / 2.0 - 0.2),
                    Pose::from_center(
                        DMat3::from_rotation_y(0.02 * i as f64),
                        DVec3::new(0.1 * a.cos(), 0.08 * a.sin(), 0.01),
                    ),
                );
                let mut img = ImageF32::new(vw, vh, 3);
                for (j, v) in img.data.iter_mut().enumerate() {
                    let (p, c) = (j / 3, j % 3);
                    let (x, y) = ((p % vw as usize) as f32, (p / vw as usize) as f32);
                    *v = 0.5
                        + 0.4 * (0.3 * x + 0.2 * y + c as f32 + i as f32).sin() * (0.11 * y).cos();
                }
                (img, cam)
            })
            .collect();
        (views, reference, depths)
    }

    /// The engine equals the model's own forward pass (burn's plane sweeps, prior, renders and warps)
    /// on the whole reference image: with and without the agreement prior, 1 to 3 nets, 1 to 5 views.
    #[test]
    fn engine_equals_model_forward() {
        let dev = Device::flex();
        for (k, d, updates, prior, unet_nets) in [
            (3, 5, 1, true, 0),
            (4, 4, 2, false, 0),
            (1, 3, 0, true, 0),
            (5, 6, 1, false, 0),
            // U-Net nets (the paper-spaces presets' first two) on odd sizes (29 x 37).
            (3, 4, 2, false, 2),
            (2, 3, 1, true, 1),
        ] {
            let cfg = DeepViewConfig {
                features_large: 6,
                features_small: 5,
                updates,
                unet_nets,
                init_prior: None,
                ..DeepViewConfig::preset("cpu").unwrap()
            };
            // Random output convs (a prior model starts with zero ones), so every net matters.
            let mut model = DeepViewModel::new(&cfg, &dev);
            if prior {
                model.prior_temperature = crate::config::CPU_PRIOR_TEMPERATURE;
            }
            let (views, reference, depths) = scene(k, d);
            let inputs = ModelInputs {
                images: views
                    .iter()
                    .map(|(i, _)| {
                        image_tensor(&i.data, i.width as usize, i.height as usize, 3, &dev)
                    })
                    .collect(),
                mpi_to_view: mpi_to_view_homographies(
                    &reference,
                    views.iter().map(|(_, c)| c),
                    &depths,
                ),
                height: 29,
                width: 37,
                shrink: false,
                context: None,
            };
            let want: Vec<f32> = model
                .forward(&inputs)
                .rgba
                .into_data()
                .try_to_vec()
                .unwrap();
            let mut calls = 0;
            let got = infer_engine(
                &model,
                &views,
                &reference,
                &depths,
                StatePrecision::F32,
                &mut |_| calls += 1,
            );
            assert_eq!(calls, 1 + updates);
            let hw = 29 * 37;
            let mut max = 0f32;
            for p in 0..d {
                for c in 0..4 {
                    for i in 0..hw {
                        max =
                            max.max((want[(p * 4 + c) * hw + i] - got[(p * hw + i) * 4 + c]).abs());
                    }
                }
            }
            assert!(
                max < 2e-5,
                "{k} views, {d} planes, {updates} updates, prior {prior}, {unet_nets} U-Net: {max}"
            );
        }
    }
}
