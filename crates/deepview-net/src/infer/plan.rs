//! The inference plan: the state precision and, per net, the tile side and plane chunk whose estimated
//! peak memory fits the budget.

use super::error::{InferError, validate};
use super::state::StatePrecision;
use super::tiling::{Geometry, Rect, ViewWindow};
use crate::network::DeepViewModel;
use deepview_geometry::Camera;
use deepview_image::ImageF32;

/// How one net runs: tile side, plane chunk and the memory estimates behind them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NetPlan {
    /// Even tile side in MPI pixels.
    pub tile: usize,
    /// Planes per run of the net on a tile (the nets are independent across planes, except net 0 with
    /// an agreement prior, which always gets all planes).
    pub plane_chunk: usize,
    /// Estimated bytes of the whole-MPI data (states or result), the inputs and the process itself.
    pub fixed_bytes: u64,
    /// Estimated peak bytes of the largest tile step.
    pub tile_bytes: u64,
}

/// State precision and per-net tiling for a memory budget (see [`plan_inference`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InferPlan {
    pub precision: StatePrecision,
    pub nets: Vec<NetPlan>,
    /// The device limits the tiles were sized for (none on the CPU).
    pub limits: DeviceLimits,
}

/// What bounds a tile step on a device with memory of its own (a GPU), besides the host budget that
/// holds the whole-MPI state: `None` where the host budget bounds everything (the CPU).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DeviceLimits {
    /// Bytes a tile step may take on the device.
    pub memory: Option<u64>,
    /// Bytes of the largest single tensor the device can allocate.
    pub max_allocation: Option<u64>,
}

impl DeviceLimits {
    /// The limits of a model's device within the host budget: none for the CPU; on a GPU 3/4 of the
    /// capacity its runtime reports (capped by `budget`, so that `--max-memory` bounds the device too)
    /// and its largest allocation.
    pub fn of(device: &burn::tensor::Device, budget: u64) -> Self {
        if crate::cpu::ops::fast_device(device) {
            return Self::default();
        }
        let m = crate::device::device_memory(device);
        Self {
            memory: Some(m.capacity.map_or(budget, |c| (c / 4 * 3).min(budget))),
            max_allocation: m.max_allocation,
        }
    }
}

impl InferPlan {
    /// The same tile side and plane chunk for every net (no estimates).
    pub fn uniform(
        nets: usize,
        tile: usize,
        plane_chunk: usize,
        precision: StatePrecision,
    ) -> Self {
        let net = NetPlan {
            tile,
            plane_chunk,
            fixed_bytes: 0,
            tile_bytes: 0,
        };
        Self {
            precision,
            nets: vec![net; nets],
            limits: DeviceLimits::default(),
        }
    }

    /// The estimated peak over the nets.
    pub fn peak_bytes(&self) -> u64 {
        self.nets
            .iter()
            .map(|n| n.fixed_bytes + n.tile_bytes)
            .max()
            .unwrap_or(0)
    }
}

/// Smallest tile side [`plan_inference`] chooses (smaller tiles are dominated by their margins).
pub const MIN_TILE: usize = 32;

/// Resident bytes of the process besides the tensors (code, runtime, thread stacks, allocator slack).
pub(crate) const BASE_BYTES: u64 = 32 << 20;

/// Whether net `n` may run on a subset of the planes: the core nets treat planes independently
/// ([`crate::network::CoreNet`]: convs per (view, plane) slice, maxima over views per plane), but
/// net 0's agreement prior (`prior_temperature > 0`) accumulates over all planes.
pub(super) fn plane_separable(model: &DeepViewModel, n: usize) -> bool {
    n > 0 || model.prior_temperature <= 0.0
}

/// Estimated bytes of the whole-MPI data while net `n` runs (the previous state, and the next state or
/// for the last net the RGBA result), the inputs and the process.
pub(super) fn fixed_bytes(
    model: &DeepViewModel,
    geom: &Geometry,
    n: usize,
    precision: StatePrecision,
) -> u64 {
    let px = (geom.d * geom.w * geom.h) as u64;
    let store = px * model.state_channels as u64 * precision.bytes();
    let old = if n > 0 { store } else { 0 };
    // Net 0 with a smoothed prior (or a census term): the whole image's prior (`run::whole_image_prior`,
    // on the host, freed after net 0) and, while it is computed, its costs, sums and the alphas'
    // temporaries (about 16 floats per MPI texel at the peak), and with a census term a chunk's sweeps
    // copied to the host (about 4 more).
    let old = if n == 0 && model.prior_needs_whole_image() {
        px * 4
            * if model.active_census().is_some() {
                20
            } else {
                16
            }
    } else {
        old
    };
    let new = if n + 1 < model.nets.len() {
        store
    } else {
        px * 4 * 4
    };
    // The caller's images and their tensors.
    let images: u64 = geom
        .view_sizes
        .iter()
        .map(|&(w, h)| 2 * (w * h * 3 * 4) as u64)
        .sum();
    old + new + images + BASE_BYTES
}

/// Estimated peak bytes of one tile step of net `n` on `region` (planes run `chunk` at a time), given
/// each view's crop and sub-window. Calibrated against peak RSS (`measure_fern_peak` below).
///
/// Per (view, plane, region pixel) "slice pixel", a net run holds its input three times (per view, per
/// view with the state, concatenated over views), the conv's NHWC copy of its input and a few feature
/// maps. Before it, the per-view inputs are computed one view at a time: the finished views' inputs are
/// held while the current view's warps run (bilinear taps: 4 indices, 4 weights and 4 gathered values per
/// sample and channel, on the render of the view crop and on the region); with plane chunks they stay
/// held during the net runs.
fn tile_estimate(
    model: &DeepViewModel,
    n: usize,
    planes: usize,
    chunk: usize,
    region: Rect,
    windows: &[ViewWindow],
) -> u64 {
    let net = &model.nets[n];
    let f = net.head.weight.val().dims()[0] as u64;
    let cin = net.input[0].weight.val().dims()[1] as u64;
    let s = model.state_channels as u64;
    let raw = cin - if n > 0 { s } else { 0 };
    let (k, d, chunk) = (
        windows.len() as u64,
        planes as u64,
        chunk.min(planes) as u64,
    );
    let r = (region.2 * region.3) as u64;
    let held = k * d * r * 4 * raw;
    let per_view = windows
        .iter()
        .map(|w| {
            let c = (w.crop.2 * w.crop.3) as u64;
            let sub = (w.sub.2 * w.sub.3) as u64;
            if n > 0 {
                d * (120 * c + 40 * sub + 150 * r)
            } else {
                d * 200 * r
            }
        })
        .max()
        .unwrap_or(0);
    let input_phase = held + per_view;
    let run = k * chunk * r * 4 * (3 * cin + 4 * f);
    let net_phase = if chunk < d {
        held + d * r * 4 * s + run
    } else {
        run
    };
    input_phase.max(net_phase) * 5 / 4
}

/// Bytes of the largest single tensor of one tile step of net `n` (see [`tile_estimate`]): the warps'
/// gathered taps (`[4, planes x pixels, channels]` f32: 3 channels for net 0's plane sweeps; for update
/// nets 4 for the render of the view crop and 6 for the image and render warped onto the region), the
/// MPI sub-window's RGBA, and a net run's widest map over every (view, plane) slice of the chunk. A device whose largest
/// allocation is smaller cannot run the step at all, whatever its memory.
fn buffer_estimate(
    model: &DeepViewModel,
    n: usize,
    planes: usize,
    chunk: usize,
    region: Rect,
    windows: &[ViewWindow],
) -> u64 {
    let net = &model.nets[n];
    // The widest feature map: any conv's input (a stage's is the features and their maximum over views,
    // concatenated) or output.
    let widest = net
        .input
        .iter()
        .chain(&net.stages)
        .chain([&net.head, &net.out])
        .map(|c| {
            let [o, i, _, _] = c.weight.val().dims();
            o.max(i) as u64
        })
        .max()
        .unwrap_or(0);
    let (k, d, chunk) = (
        windows.len() as u64,
        planes as u64,
        chunk.min(planes) as u64,
    );
    let r = (region.2 * region.3) as u64;
    let warps = windows
        .iter()
        .map(|w| {
            let c = (w.crop.2 * w.crop.3) as u64;
            let sub = (w.sub.2 * w.sub.3) as u64;
            if n > 0 {
                (64 * d * c).max(96 * d * r).max(16 * d * sub)
            } else {
                48 * d * r
            }
        })
        .max()
        .unwrap_or(0);
    warps.max(k * chunk * r * 4 * widest)
}

/// The largest estimates of net `n` over its tiles of side `tile`: (peak bytes, largest tensor).
pub(super) fn max_tile_estimates(
    model: &DeepViewModel,
    geom: &Geometry,
    n: usize,
    tile: usize,
    chunk: usize,
) -> (u64, u64) {
    let m = model.margin(n);
    geom.tiles(tile)
        .into_iter()
        .map(|t| {
            let region = geom.region(t, m);
            let windows: Vec<ViewWindow> = (0..geom.homs.len())
                .map(|k| geom.view_window(k, region, n > 0))
                .collect();
            (
                tile_estimate(model, n, geom.d, chunk, region, &windows),
                buffer_estimate(model, n, geom.d, chunk, region, &windows),
            )
        })
        .fold((0, 0), |(a, b), (x, y)| (a.max(x), b.max(y)))
}

/// The largest peak estimate of net `n` over its tiles of side `tile`.
pub(super) fn max_tile_bytes(
    model: &DeepViewModel,
    geom: &Geometry,
    n: usize,
    tile: usize,
    chunk: usize,
) -> u64 {
    max_tile_estimates(model, geom, n, tile, chunk).0
}

/// The largest tile (then the largest plane chunk) of net `n` whose estimate fits `budget` (with the
/// whole-MPI data) or, on a device with memory of its own, the device's memory (the state stays in the
/// host's `budget`), and whose largest tensor the device can allocate.
fn plan_net(
    model: &DeepViewModel,
    geom: &Geometry,
    n: usize,
    precision: StatePrecision,
    budget: u64,
    limits: DeviceLimits,
) -> Result<NetPlan, InferError> {
    let fixed = fixed_bytes(model, geom, n, precision);
    let fits = |tile_bytes: u64, largest: u64| {
        let memory = match limits.memory {
            Some(device) => fixed <= budget && tile_bytes <= device,
            None => fixed + tile_bytes <= budget,
        };
        memory && limits.max_allocation.is_none_or(|a| largest <= a)
    };
    let chunks: Vec<usize> = if plane_separable(model, n) {
        let mut c = vec![geom.d];
        while *c.last().expect("non-empty") > 1 {
            c.push(c.last().expect("non-empty").div_ceil(2));
        }
        c
    } else {
        vec![geom.d]
    };
    let mut tile = geom.w.max(geom.h).next_multiple_of(2);
    loop {
        for &chunk in &chunks {
            let (tile_bytes, largest) = max_tile_estimates(model, geom, n, tile, chunk);
            if fits(tile_bytes, largest) {
                return Ok(NetPlan {
                    tile,
                    plane_chunk: chunk,
                    fixed_bytes: fixed,
                    tile_bytes,
                });
            }
        }
        if tile <= MIN_TILE {
            return Err(InferError::BudgetTooSmall {
                budget,
                fixed,
                min_tile: max_tile_bytes(model, geom, n, tile, 1),
                planes: geom.d,
                w: geom.w as u32,
                h: geom.h as u32,
            });
        }
        tile = ((tile * 7 / 8) & !1).max(MIN_TILE);
    }
}

/// The plan [`super::infer_mpi`] uses for `max_memory_bytes`: an f32 state when it takes at most half the
/// budget, f16 otherwise; then per net the largest tile (from one tile for the whole MPI down to
/// [`MIN_TILE`]) and the largest plane chunk whose estimated peak, with the whole-MPI data, fits, and on
/// a GPU the device's limits ([`DeviceLimits::of`] the model's device).
pub fn plan_inference(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    max_memory_bytes: u64,
) -> Result<InferPlan, InferError> {
    let limits = DeviceLimits::of(&super::run::model_device(model), max_memory_bytes);
    plan_inference_within(model, views, reference, depths, max_memory_bytes, limits)
}

/// [`plan_inference`] for given device limits.
pub fn plan_inference_within(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    max_memory_bytes: u64,
    limits: DeviceLimits,
) -> Result<InferPlan, InferError> {
    validate(model, views, depths)?;
    let geom = Geometry::new(views, reference, depths);
    let f32_fixed = (0..model.nets.len())
        .map(|n| fixed_bytes(model, &geom, n, StatePrecision::F32))
        .max()
        .unwrap_or(0);
    let precision = if 2 * f32_fixed <= max_memory_bytes {
        StatePrecision::F32
    } else {
        StatePrecision::F16
    };
    let nets = (0..model.nets.len())
        .map(|n| plan_net(model, &geom, n, precision, max_memory_bytes, limits))
        .collect::<Result<_, _>>()?;
    Ok(InferPlan {
        precision,
        nets,
        limits,
    })
}
