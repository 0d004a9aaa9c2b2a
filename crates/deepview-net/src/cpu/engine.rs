//! Whole-image inference on plain `f32` arrays with the CPU kernels: the same model as
//! [`DeepViewModel::forward`] (plane sweeps, the agreement prior, renders `R`, `A`, `T` into every view
//! and their inverse warps, every net), with no tensor per operation. Each net runs one plane at a time
//! per thread ([`NetScratch`]): its inputs are warped straight into the kernels' padded planes.
//!
//! Memory: the state between nets (`D x S x H x W`); for the first net the prior's depth weights (`D x
//! H x W`); for update nets the views' renders streamed a block of planes at a time ([`ViewRenders`]:
//! per view `I`, `R`, the transmittance, a composite per block and one block's `A`/`T`, instead of `A`
//! and `T` of every plane); per thread one plane's activations. [`engine_bytes`] estimates it; `infer`
//! falls back to the tiled burn path ([`crate::infer`]) when it exceeds the budget.

use crate::cpu::packed::{NetScratch, PackedNet};
use crate::cpu::planes::{for_each_with, per_thread};
use crate::cpu::prior::{add_colour_logits, census_cost, prior_logits, prior_stats};
use crate::cpu::renders::{ViewRenders, block_size, blocks, stream_bytes};
use crate::cpu::state::EngineState;
use crate::cpu::warps::{warp_into, warp_pair_into};
use crate::forward::mpi_to_view_homographies;
use crate::infer::StatePrecision;
use crate::network::DeepViewModel;
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_kernels::Plane;
use deepview_kernels::fastmath;
use deepview_mpi::agreement::{SINGLE_VIEW_VARIANCE, aggregate_seen, smooth_semi_global};
use rayon::prelude::*;
use std::ops::Range;

/// Estimated peak bytes of [`infer_engine`] (besides the inputs' images).
pub fn engine_bytes(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    w: usize,
    h: usize,
    d: usize,
    precision: StatePrecision,
) -> u64 {
    let (hw, d64) = ((w * h) as u64, d as u64);
    let view_px: u64 = views
        .iter()
        .map(|(i, _)| i.width as u64 * i.height as u64)
        .sum();
    let s = model.state_channels as u64;
    let threads = rayon::current_num_threads() as u64;
    // The widened plane of a half-float state, per thread.
    let widened = match precision {
        StatePrecision::F32 => 0,
        StatePrecision::F16 => s * hw,
    };
    // One thread's scratch of net `n` (floats), and the height of its strips.
    let scratch = |n: usize| {
        let net = &model.nets[n];
        let k = views.len() as u64;
        let strip = Strips::new(
            h,
            if net.unet { h } else { STRIP_ROWS },
            strip_margin(model, n),
        )
        .height;
        let plane = Plane::new(strip, w).len() as u64;
        let half = Plane::new(h.div_ceil(2), w.div_ceil(2)).len() as u64;
        let cin = net.input[0].weight.dims()[1] as u64;
        let f = net.head.weight.dims()[1] as u64;
        let planes = k * (cin + 2 * f) + 3 * f + s;
        // A U-Net net's scratch is at half resolution, beside its full-resolution inputs.
        let floats = if net.unet {
            planes * half + k * cin * plane
        } else {
            planes * plane
        };
        (floats, (strip * w) as u64)
    };
    // Besides the state: the first net's scratch, the mean colour and the prior's depth weights (then
    // the aggregation's f64 sums per thread, 32 bytes a pixel); an update net's scratch, the plane's
    // update and the streamed renders; at the end the RGBA result.
    let aggregation = if model.prior_aggregation().is_active() {
        threads * 32 * hw
    } else {
        0
    };
    // Semi-global matching's sums: one more `D x H x W` array beside the depth weights.
    let smoothing = if model.prior_smoothing.is_some() && model.prior_temperature > 0.0 {
        4 * d64 * hw
    } else {
        0
    };
    // The census term's scratch per thread: the views' grey levels, their bit strings (4 floats'
    // worth a pixel) and the cost.
    let census = |px: u64| {
        if model.active_census().is_some() {
            (5 * views.len() as u64 + 1) * px
        } else {
            0
        }
    };
    let first = (!model.nets.is_empty())
        .then(|| scratch(0))
        .map_or(0, |(sc, px)| {
            (4 * threads * (sc + 4 * px + widened + census(px)))
                .max(aggregation)
                .max(smoothing)
                + 4 * d64 * hw
        });
    let update = (1..model.nets.len())
        .map(|n| scratch(n).0)
        .max()
        .map_or(0, |sc| {
            let block = block_size(d, threads as usize, view_px, hw);
            4 * threads * (sc + s * hw + widened) + stream_bytes(d, block, view_px, hw)
        });
    let stored = stored_channels(model) as u64;
    // The result comes on top of the state, unless it is the state's own buffer.
    let result = if in_place_result(model, precision) {
        0
    } else {
        4 * d64 * 4 * hw
    };
    d64 * stored * hw * precision.bytes() + first.max(update).max(result)
}

/// The state's channels the engine keeps: all of them where update nets read them, else the four
/// (RGBA logits) that the result is made of.
fn stored_channels(model: &DeepViewModel) -> usize {
    if model.nets.len() > 1 {
        model.state_channels
    } else {
        model.state_channels.min(4)
    }
}

/// Whether the result (premultiplied RGBA) is made in the state's own buffer: an f32 state of four
/// channels a plane has the result's size.
fn in_place_result(model: &DeepViewModel, precision: StatePrecision) -> bool {
    stored_channels(model) == 4 && precision == StatePrecision::F32
}

/// Planes `planes` of the state -> premultiplied RGBA `[plane][H*W][4]` in `rgba` (see
/// `network::state_to_rgba`), a plane per task.
fn state_to_rgba_into(state: &EngineState, planes: Range<usize>, hw: usize, rgba: &mut [f32]) {
    rgba.par_chunks_mut(hw * 4)
        .zip(planes)
        .for_each_init(Vec::new, |buf, (r, p)| {
            // SAFETY: nothing writes the state meanwhile (the engine converts between updates).
            unsafe { state.with_plane_ref(p, buf, |st| plane_to_rgba(st, hw, r)) }
        });
}

/// One plane's RGBA logits `st` (`[4 or more][H*W]`) -> premultiplied RGBA `[H*W][4]` in `out`: the
/// sigmoids of a run of pixels as vector loops ([`fastmath::with_simd`]), then interleaved.
pub(crate) fn plane_to_rgba(st: &[f32], hw: usize, out: &mut [f32]) {
    const RUN: usize = 256;
    fastmath::with_simd(
        #[inline(always)]
        || {
            let mut tmp = [[0f32; RUN]; 4];
            for (k, out) in out.chunks_mut(4 * RUN).enumerate() {
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
}

/// Rows of the MPI a net computes at once (besides the margins its receptive field needs): a strip's
/// activations stay closer to the caches than a whole plane's. `bench net` on fern's size (1008x756,
/// 32 planes, 4 views, weights/cpu, 2 cores): 6.2-6.6 s at 64 rows, 6.4 at 48, 6.8 at 32, 8.4 at 16,
/// 6.9 at 128 and 256, 6.9-7.1 for whole planes (3.0 GB instead of 1.5).
pub(crate) const STRIP_ROWS: usize = 64;

/// A net's strips of rows: each computes `height` rows from `top` and keeps the rows `keep` (all rows
/// that are at least the net's receptive-field margin away from the strip's edges, or at the image's
/// edge, where the strip's zero padding is the image's). Every strip has the same height, so that one
/// scratch serves them all.
struct Strips {
    height: usize,
    strips: Vec<Strip>,
}

struct Strip {
    top: usize,
    keep: std::ops::Range<usize>,
}

impl Strips {
    fn new(h: usize, rows: usize, margin: usize) -> Self {
        let height = rows.max(1) + 2 * margin;
        if height >= h {
            return Self {
                height: h,
                strips: vec![Strip { top: 0, keep: 0..h }],
            };
        }
        let strips = (0..h.div_ceil(rows))
            .map(|i| {
                let keep = i * rows..((i + 1) * rows).min(h);
                Strip {
                    top: keep.start.saturating_sub(margin).min(h - height),
                    keep,
                }
            })
            .collect();
        Self { height, strips }
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
/// kernels; `progress(done, total)` as planes are done (`total`: the planes times the nets). Any model: U-Net nets run their core at half resolution
/// between a 2x2 average pool and a bilinear upsampling, as `CoreNet::forward`.
pub fn infer_engine(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    precision: StatePrecision,
    progress: &mut dyn FnMut(usize, usize),
) -> Vec<f32> {
    let hw = reference.width as u64 * reference.height as u64;
    let view_px = views
        .iter()
        .map(|(i, _)| i.width as u64 * i.height as u64)
        .sum();
    let threads = rayon::current_num_threads();
    let block = block_size(depths.len(), threads, view_px, hw);
    infer_engine_blocks(
        model,
        views,
        reference,
        depths,
        (block, STRIP_ROWS, precision),
        progress,
    )
}

/// The rows net `n`'s strips carry beyond their kept rows: the net's receptive field, and for net 0 with
/// a census term the census window's (the prior's costs of the kept rows).
fn strip_margin(model: &DeepViewModel, n: usize) -> usize {
    let census_rows = match model.active_census() {
        Some(c) if n == 0 => c.radius,
        _ => 0,
    };
    model.conv_margin(n).max(census_rows)
}

/// Ticks of work done, sent from the threads doing it to the one that reports them
/// ([`with_progress`]).
struct Ticks(std::sync::mpsc::Sender<()>);

impl Ticks {
    fn tick(&self) {
        // (The receiver lives until the work ends.)
        let _ = self.0.send(());
    }
}

/// `work` on a thread of its own (its parallel loops on rayon's pool as before) while this thread
/// hands `progress` each tick it sends, as `(done, total)`: `progress` need not be `Send`, and the
/// kernels' threads never wait for it. Called on one of rayon's threads (which must not block on a
/// channel while its pool runs the work), or where no thread can be made, `work` runs here and its
/// ticks are reported when it ends.
fn with_progress<R: Send, F: FnOnce(&Ticks) -> R + Send>(
    total: usize,
    progress: &mut dyn FnMut(usize, usize),
    work: F,
) -> R {
    let (tx, rx) = std::sync::mpsc::channel();
    // The work goes with the only sender: the ticks end when the work does (or panics).
    let slot = std::sync::Mutex::new(Some((work, tx)));
    let take = || slot.lock().unwrap_or_else(|p| p.into_inner()).take();
    let run = |(work, tx): (F, std::sync::mpsc::Sender<()>)| work(&Ticks(tx));
    let tell = |progress: &mut dyn FnMut(usize, usize)| {
        for (done, ()) in (1..).zip(rx.iter()) {
            progress(usize::min(done, total), total);
        }
    };
    if rayon::current_thread_index().is_none() {
        let threaded = std::thread::scope(|scope| {
            let worker = std::thread::Builder::new()
                .name("deepview-engine".into())
                .stack_size(8 << 20)
                .spawn_scoped(scope, || take().map(run))
                .ok()?;
            tell(progress);
            worker
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
        });
        if let Some(result) = threaded {
            return result;
        }
    }
    let result = run(take().expect("the engine's work is not taken twice"));
    tell(progress);
    result
}

/// [`infer_engine`] with update nets' renders streamed `block` planes at a time and the nets run on
/// strips of `strip_rows` rows (the result depends on neither).
pub(crate) fn infer_engine_blocks(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    settings: (usize, usize, StatePrecision),
    progress: &mut dyn FnMut(usize, usize),
) -> Vec<f32> {
    let total = model.nets.len() * depths.len();
    with_progress(total, progress, |ticks| {
        engine_planes(model, views, reference, depths, settings, ticks)
    })
}

/// [`infer_engine_blocks`]' work: a tick for each plane of each net.
fn engine_planes(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    (block, strip_rows, precision): (usize, usize, StatePrecision),
    ticks: &Ticks,
) -> Vec<f32> {
    let (w, h, d) = (
        reference.width as usize,
        reference.height as usize,
        depths.len(),
    );
    let k = views.len();
    let hw = w * h;
    let s = model.state_channels;
    // The state's channels kept between the nets (and net 0's outputs taken).
    let kept_channels = stored_channels(model);
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
    // The state `[D][S][H*W]` (`S`: `kept_channels`).
    let state = EngineState::new(d, kept_channels, hw, precision);
    for (n, net) in nets.iter().enumerate() {
        let cin = net.in_channels();
        // A U-Net net: its inputs at full resolution, pooled into its half-resolution scratch, on the
        // whole plane; other nets on strips of rows.
        let unet = model.nets[n].unet;
        let strips = Strips::new(h, if unet { h } else { strip_rows }, strip_margin(model, n));
        // The planes of a strip, and the net's (half of them for a U-Net).
        let sp = Plane::new(strips.height, w);
        let np = if unet {
            Plane::new(h.div_ceil(2), w.div_ceil(2))
        } else {
            sp
        };
        let scratch = || {
            (
                NetScratch::new(net, np, k),
                unet.then(|| FullInputs::new(sp, k, cin)),
            )
        };
        // The net's output channel `c` at the strip's kept rows (from row `off` of the strip) into
        // (`add`: onto) `dst` (those rows, unpadded).
        let take_output = |sc: &NetScratch, c: usize, off: usize, dst: &mut [f32], add: bool| {
            if unet {
                upsample_into(np, sc.output(c), sp, dst, add);
                return;
            }
            let out = sc.output(c);
            for (y, row) in dst.chunks_exact_mut(w).enumerate() {
                let i = sp.index(off + y, 0);
                if add {
                    for (x, &u) in row.iter_mut().zip(&out[i..i + w]) {
                        *x += u;
                    }
                } else {
                    row.copy_from_slice(&out[i..i + w]);
                }
            }
        };
        if n == 0 {
            // The plane sweeps feed both the net and the agreement prior's first pass: the mean
            // colour's logits go onto the plane's state at once, the depth weights' wait for every
            // plane (`[D][H*W]`).
            let temperature = model.prior_temperature;
            let mut weights =
                deepview_kernels::zeroed_buffer(if temperature > 0.0 { d * hw } else { 0 });
            let weights_ptr = weights.as_mut_ptr() as usize;
            let census = model.active_census();
            let loo = model.prior_leave_one_out;
            let sampled = model.prior_sample_variance;
            let scratch = || {
                (
                    scratch(),
                    Vec::new(),
                    Vec::new(),
                    Vec::new(),
                    (Vec::new(), Default::default(), Vec::new()),
                )
            };
            per_thread(0..d, scratch, |((sc, full), mean, lg, buf, cs), p| {
                let body = |st: &mut [f32]| {
                    for strip in &strips.strips {
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
                                (sp, strip.top),
                                rgb,
                                Some(valid),
                            );
                        }
                        let (off, rows) = (strip.keep.start - strip.top, strip.keep.clone());
                        let kept = |c: usize| c * hw + rows.start * w..c * hw + rows.end * w;
                        if temperature > 0.0 {
                            let psv = match full {
                                Some(f) => f.all_mut(),
                                None => sc.inputs_mut(),
                            };
                            let spx = sp.h * sp.w;
                            mean.resize(3 * spx, 0.0);
                            lg.resize(spx, 0.0);
                            let census = census.map(|c| {
                                let (greys, bits, cost) = &mut *cs;
                                census_cost(&psv, sp, c.radius, greys, bits, cost);
                                (cost.as_slice(), c.weight)
                            });
                            prior_stats(&psv, sp, temperature, census, loo, sampled, mean, lg);
                            // SAFETY: the strip's kept rows of plane p's depth weights, written by
                            // this task only.
                            let dst = unsafe {
                                std::slice::from_raw_parts_mut(
                                    (weights_ptr as *mut f32).add(p * hw + rows.start * w),
                                    rows.len() * w,
                                )
                            };
                            dst.copy_from_slice(&lg[off * w..(off + rows.len()) * w]);
                        }
                        if let Some(f) = full {
                            f.pool_into(sp, np, sc, 0);
                        }
                        sc.run(net);
                        for c in 0..kept_channels {
                            take_output(sc, c, off, &mut st[kept(c)], false);
                        }
                        if temperature > 0.0 {
                            let spx = sp.h * sp.w;
                            for c in 0..3 {
                                let m = &mean[c * spx + off * w..][..rows.len() * w];
                                add_colour_logits(m, &mut st[kept(c)]);
                            }
                        }
                    }
                };
                // SAFETY: plane p, this task's only.
                unsafe { state.with_plane(p, buf, body) };
                ticks.tick();
            });
            if temperature > 0.0 {
                if model.prior_aggregation().is_active() {
                    weights
                        .par_chunks_mut(hw)
                        .for_each_init(Vec::new, |scratch, plane| {
                            aggregate_seen(plane, w, h, model.prior_aggregation(), scratch)
                        });
                }
                if let Some(smoothing) = model.prior_smoothing {
                    let cap = (SINGLE_VIEW_VARIANCE / temperature) as f32;
                    smooth_semi_global(&mut weights, w, h, d, smoothing, cap);
                }
                prior_logits(&mut weights, d, hw);
                weights
                    .par_chunks(hw)
                    .enumerate()
                    .for_each_init(Vec::new, |buf, (p, q)| {
                        // SAFETY: plane p, this task's only.
                        unsafe {
                            state.with_plane(p, buf, |st| {
                                for (o, &q) in st[3 * hw..4 * hw].iter_mut().zip(q) {
                                    *o += q;
                                }
                            })
                        }
                    });
            }
            debug_assert_eq!(cin, crate::network::INIT_CHANNELS);
        } else {
            // The views' renders of the current state, a block of planes at a time from the front: a
            // block's planes are updated in place after its renders (which read only planes not yet
            // updated, [`ViewRenders`]).
            let blocks = blocks(d, block);
            let mut rgba = Vec::new();
            let to_rgba = |state: &EngineState, blk: Range<usize>, out: &mut Vec<f32>| {
                out.resize(blk.len() * 4 * hw, 0.0);
                state_to_rgba_into(state, blk, hw, out);
            };
            let mut renders = ViewRenders::new(
                views,
                &homs,
                (w, h),
                blocks.clone(),
                &mut |b, o| to_rgba(&state, b, o),
                &mut rgba,
            );
            // Per thread the scratch and the plane's update (the strips read the plane's state around
            // their rows, so it changes only once every strip has run).
            let mut scratches: Vec<_> = (0..rayon::current_num_threads().min(block).max(1))
                .map(|_| (scratch(), Vec::new(), Vec::new()))
                .collect();
            for (i, blk) in blocks.iter().enumerate().rev() {
                to_rgba(&state, blk.clone(), &mut rgba);
                renders.render_block(i, &rgba, (w, h));
                for_each_with(
                    blk.clone(),
                    &mut scratches,
                    |((sc, full), update, buf), p| {
                        update.resize(s * hw, 0.0);
                        let body = |st: &mut [f32]| {
                            for strip in &strips.strips {
                                let ext = strip.top..strip.top + sp.h;
                                for (v, (img, _)) in views.iter().enumerate() {
                                    let mut ins = match full {
                                        Some(f) => f.view_mut(v),
                                        None => sc.view_inputs_mut(v),
                                    };
                                    // [I (3), R (3), A (3), T (1), validity (1), state (S)].
                                    let (ir, rest) = ins.split_at_mut(6);
                                    let (atp, rest) = rest.split_at_mut(4);
                                    let (valid, st_planes) = rest.split_at_mut(1);
                                    warp_pair_into(
                                        (&renders.ir[v], renders.at_plane(v, i, p)),
                                        (img.width, img.height),
                                        &homs[v][p],
                                        (sp, strip.top),
                                        (ir, atp),
                                        valid[0],
                                    );
                                    // The net reads the shared state from view 0's planes only.
                                    if v == 0 {
                                        for (c, dst) in st_planes.iter_mut().enumerate() {
                                            sp.pad_into(
                                                &st[c * hw + ext.start * w..c * hw + ext.end * w],
                                                dst,
                                            );
                                        }
                                    }
                                }
                                debug_assert_eq!((cin, net.shared_inputs()), (11 + s, s));
                                if let Some(f) = full {
                                    f.pool_into(sp, np, sc, s);
                                }
                                sc.run(net);
                                let (off, rows) =
                                    (strip.keep.start - strip.top, strip.keep.clone());
                                for c in 0..s {
                                    let dst =
                                        &mut update[c * hw + rows.start * w..c * hw + rows.end * w];
                                    take_output(sc, c, off, dst, false);
                                }
                            }
                            for (x, &u) in st.iter_mut().zip(update.iter()) {
                                *x += u;
                            }
                        };
                        // SAFETY: plane p, this task's only.
                        unsafe { state.with_plane(p, buf, body) };
                        ticks.tick();
                    },
                );
            }
        }
        // This net's scratch and renders are freed: return them before the next net's (or the
        // result's) buffers.
        deepview_kernels::release_free_memory();
    }
    // Premultiplied RGBA `[D][H][W][4]`.
    if in_place_result(model, precision) {
        return state.into_rgba(hw);
    }
    let mut rgba = deepview_kernels::zeroed_buffer(d * 4 * hw);
    state_to_rgba_into(&state, 0..d, hw, &mut rgba);
    rgba
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
        // Fixed weights (drawn under the generator's lock: other tests draw too): the random ones
        // of an unseeded run put the largest difference anywhere from ~1e-5 to 2.04e-5 (f32 sums in
        // another order), which failed a CI run at 2e-5.
        for (i, (k, d, updates, prior, unet_nets)) in [
            (3, 5, 1, true, 0),
            (4, 4, 2, false, 0),
            (1, 3, 0, true, 0),
            // The initialisation net alone (four state channels kept, the result made in their
            // buffer) with the whole prior.
            (3, 5, 0, true, 0),
            (5, 6, 1, false, 0),
            // U-Net nets (the paper-spaces presets' first two) on odd sizes (29 x 37).
            (3, 4, 2, false, 2),
            (2, 3, 1, true, 1),
        ]
        .into_iter()
        .enumerate()
        {
            let cfg = DeepViewConfig {
                features_large: 6,
                features_small: 5,
                updates,
                unet_nets,
                init_prior: None,
                ..DeepViewConfig::preset("cpu").unwrap()
            };
            // Random output convs (a prior model starts with zero ones), so every net matters.
            let mut model =
                crate::rng::seeded_module(&dev, 11 + i as u64, || DeepViewModel::new(&cfg, &dev));
            if prior {
                model.prior_temperature = crate::config::CPU_PRIOR_TEMPERATURE;
                // Odd view counts with an aggregated prior (a radius the strips' heights cross).
                model.prior_radius = if k % 2 == 1 { 3 } else { 0 };
                model.prior_weight = if k == 1 { 0.5 } else { 1.0 };
                // A census term (its window crosses the strips' heights too).
                model.prior_census = (k >= 2).then_some(deepview_mpi::agreement::Census {
                    weight: 0.03,
                    radius: if k == 3 { 2 } else { 3 },
                });
                // The leave-one-out variance (three views).
                model.prior_leave_one_out = (k >= 3).then_some(0.6);
                // The sample variance (two and three views).
                model.prior_sample_variance = k >= 2;
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
            // Progress: a tick for every plane of every net, counted up to the total.
            let mut ticks = Vec::new();
            let got = infer_engine(
                &model,
                &views,
                &reference,
                &depths,
                StatePrecision::F32,
                &mut |done, total| ticks.push((done, total)),
            );
            let total = (1 + updates) * d;
            assert_eq!(ticks, (1..=total).map(|i| (i, total)).collect::<Vec<_>>());
            // Called on one of rayon's threads (a pool of one: a worker blocked on the ticks would
            // deadlock it) the work runs there: the same MPI and ticks.
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap();
            let mut inner = Vec::new();
            let again = pool.install(|| {
                infer_engine(
                    &model,
                    &views,
                    &reference,
                    &depths,
                    StatePrecision::F32,
                    &mut |done, total| inner.push((done, total)),
                )
            });
            assert_eq!(inner, ticks);
            assert_eq!(again, got);
            let hw = 29 * 37;
            let max_diff = |got: &[f32]| {
                let mut max = 0f32;
                for p in 0..d {
                    for c in 0..4 {
                        for i in 0..hw {
                            max = max.max(
                                (want[(p * 4 + c) * hw + i] - got[(p * hw + i) * 4 + c]).abs(),
                            );
                        }
                    }
                }
                max
            };
            let max = max_diff(&got);
            let case = format!(
                "{k} views, {d} planes, {updates} updates, prior {prior} (radius {}, weight {}, census \
                 {:?}, leave-one-out {:?}, sample variance {}), {unet_nets} U-Net",
                model.prior_radius,
                model.prior_weight,
                model.prior_census,
                model.prior_leave_one_out,
                model.prior_sample_variance
            );
            assert!(max < 4e-5, "{case}: {max}");
            // The renders streamed in blocks of any size and the nets run on strips of any height
            // (down to 1 row: every strip's margin reaches its neighbours' rows) give the same bits.
            for (block, rows) in [(1, 1), (2, 3), (d, 7), (d + 3, 29), (3, 100)] {
                let other = infer_engine_blocks(
                    &model,
                    &views,
                    &reference,
                    &depths,
                    (block, rows, StatePrecision::F32),
                    &mut |_, _| {},
                );
                assert!(
                    other == got,
                    "{case}: blocks of {block}, strips of {rows} rows differ"
                );
            }
            // A half-float state: the nets in f32, the stored state rounded to 11 bits.
            let half = infer_engine(
                &model,
                &views,
                &reference,
                &depths,
                StatePrecision::F16,
                &mut |_, _| {},
            );
            let max = max_diff(&half);
            assert!(max < 5e-3 && half != got, "{case}: f16 state {max}");
        }
    }
}
