//! Tiled inference: a whole MPI from posed images with bounded memory.
//!
//! Each net runs tile by tile over the MPI (paper supplement, "Reducing Memory Usage"): for a tile the
//! net's input is computed on the tile grown by the net's receptive-field margin
//! ([`DeepViewModel::margin`]) and only the tile's centre is kept. A tile needs, per view,
//! - the view-image crop that the grown region maps to on any plane (`view_crop`), and
//! - for update nets, the view's renders `R`, `A`, `T` on that crop, computed from the *MPI sub-window*
//!   that can reach the crop on any plane (`mpi_window`: the crop mapped back by every plane's inverse
//!   homography, grown by the bilinear taps, clamped to the MPI). Every MPI texel that reaches a needed
//!   view pixel is in the sub-window, so the renders equal those of the whole MPI.
//!
//! The result therefore equals the untiled [`DeepViewModel::forward`] on the whole reference image (to f32
//! rounding of the shifted homographies) whatever the tiling, and the work per tile depends on the tile
//! and the parallax, not on the MPI's size. The nets treat planes independently (except net 0's
//! agreement prior), so a tile's net can also run a chunk of planes at a time ([`NetPlan::plane_chunk`]).
//!
//! Memory: the only whole-MPI data is the state between nets (the previous state and the one being
//! written, `D x H x W x state_channels` each; the last net writes the RGBA result instead). A sub-window's
//! RGBA is recomputed from the state when a tile needs it. When the f32 state would take more than half
//! of the budget it is stored as IEEE half floats ([`StatePrecision::F16`]): the nets still compute in
//! f32, but the stored state is rounded to 11 significant bits (relative error <= 2^-11 ~ 4.9e-4, so
//! <= 5e-3 on logits of magnitude <= 10 and, through the sigmoid (slope <= 1/4), ~1e-3 on RGBA; values
//! beyond +-65504 saturate). The tiled path makes the final RGBA from the last net's f32 output (no
//! rounding there); the engine ([`Execution::Engine`] with [`StatePrecision::F16`]) stores that output in
//! its half-float state first, so its RGBA differs from the f32 engine's by up to ~2/255 (1.95/255 on fern
//! `images_4`, 16 planes, 2026-12-08 audit) where the tiled path's stays within 1/255.
//! [`plan_inference`] picks the precision and, per net, the tile and plane chunk from calibrated
//! estimates of the peak resident memory.

mod error;
mod plan;
mod progress;
mod run;
mod state;
mod synthetic;
mod tiling;

pub use error::InferError;
pub use plan::{DeviceLimits, InferPlan, MIN_TILE, NetPlan, plan_inference, plan_inference_within};
pub use progress::InferProgress;
pub use run::infer_mpi_planned;
pub use state::StatePrecision;
pub use synthetic::synthetic_views;

use crate::network::DeepViewModel;
use burn::tensor::Device;
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_mpi::Mpi;
use error::validate;
use run::model_device;

/// How an inference runs (see [`plan`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Execution {
    /// The whole image at once on the CPU kernels ([`crate::cpu::engine`]): the tiled path's result (within
    /// 1/255 with an f32 state, ~2/255 with a half-float one: see the module's note on memory).
    Engine(StatePrecision),
    /// Net after net, tile after tile, on the model's device.
    Tiled(InferPlan),
}

/// What an inference will do, on which device, and its estimated peak memory: the one answer used both
/// to admit a plane count and to run ([`run`]).
#[derive(Clone, Debug)]
pub struct Plan {
    pub execution: Execution,
    /// The model's device, on which the inference runs.
    pub device: Device,
    /// Estimated peak resident bytes.
    pub peak_bytes: u64,
}

impl Plan {
    /// A short description: `whole image on the CPU engine` or `N tiles of net 0 on <device>`.
    pub fn describe(&self) -> String {
        match &self.execution {
            Execution::Engine(StatePrecision::F32) => "whole image on the CPU engine".into(),
            Execution::Engine(StatePrecision::F16) => {
                "whole image on the CPU engine (state stored as f16)".into()
            }
            Execution::Tiled(p) => {
                let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
                let mut s = format!(
                    "tiled ({}-pixel tiles of net 0, {} state) on {:?}",
                    p.nets.first().map_or(0, |n| n.tile),
                    p.precision.name(),
                    self.device
                );
                if let Some(m) = p.limits.memory {
                    s += &format!(", tile steps within {:.1} GiB of its memory", gib(m));
                }
                if let Some(a) = p.limits.max_allocation {
                    s += &format!(", tensors of at most {} MiB", a >> 20);
                }
                s
            }
        }
    }
}

/// A quick lower bound of an inference's memory for `planes` planes (the MPI state at half precision,
/// twice when there are several nets, and the input images): the planner need not be asked about counts
/// over it.
pub fn lower_bound_bytes(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    planes: usize,
) -> u64 {
    let store = (reference.width as u64 * reference.height as u64)
        .saturating_mul(planes as u64)
        .saturating_mul(model.state_channels as u64)
        .saturating_mul(2);
    let stores = if model.nets.len() > 1 { 2 } else { 1 };
    let images: u64 = views
        .iter()
        .map(|(i, _)| 24 * i.width as u64 * i.height as u64)
        .sum();
    store.saturating_mul(stores).saturating_add(images)
}

/// The plan of inferring planes at `depths` in front of `reference` within `max_memory_bytes`: the whole
/// image on the CPU engine when the model is on the CPU and its estimate fits, else the tiled plan
/// ([`plan_inference`]) on the model's device.
pub fn plan(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    max_memory_bytes: u64,
) -> Result<Plan, InferError> {
    validate(model, views, depths)?;
    let device = model_device(model);
    let (w, h) = (reference.width as usize, reference.height as usize);
    if crate::cpu::ops::fast_device(&device) {
        // The engine's buffers and, as the tiled estimates count it, the process itself; its state in
        // f32, else in f16 (still many times faster than tiles).
        for precision in [StatePrecision::F32, StatePrecision::F16] {
            let bytes =
                crate::cpu::engine::engine_bytes(model, views, w, h, depths.len(), precision)
                    + plan::BASE_BYTES;
            if bytes <= max_memory_bytes {
                return Ok(Plan {
                    execution: Execution::Engine(precision),
                    device,
                    peak_bytes: bytes,
                });
            }
        }
    }
    let tiled = plan_inference(model, views, reference, depths, max_memory_bytes)?;
    Ok(Plan {
        peak_bytes: tiled.peak_bytes(),
        execution: Execution::Tiled(tiled),
        device,
    })
}

/// Run `plan` (from [`plan`] for the same arguments).
pub fn run(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    plan: &Plan,
    progress: &mut dyn FnMut(InferProgress),
) -> Result<Mpi, InferError> {
    validate(model, views, depths)?;
    match &plan.execution {
        Execution::Engine(precision) => {
            let d = depths.len().max(1);
            let layers = crate::cpu::engine::infer_engine(
                model,
                views,
                reference,
                depths,
                *precision,
                &mut |done, total| {
                    progress(InferProgress {
                        done,
                        total,
                        net: (done.max(1) - 1) / d,
                    })
                },
            );
            Ok(Mpi {
                camera: *reference,
                depths: depths.to_vec(),
                layers,
            })
        }
        Execution::Tiled(p) => infer_mpi_planned(model, views, reference, depths, p, progress),
    }
}

/// Infer an MPI with planes at `depths` (back to front, decreasing) in front of `reference` from posed
/// images, keeping peak memory within `max_memory_bytes`: [`plan`], then [`run`]. Runs on the model's
/// device; use a model on a non-autodiff device.
pub fn infer_mpi(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    max_memory_bytes: u64,
    progress: &mut dyn FnMut(InferProgress),
) -> Result<Mpi, InferError> {
    let plan = plan(model, views, reference, depths, max_memory_bytes)?;
    run(model, views, reference, depths, &plan, progress)
}

/// [`infer_mpi`] with an explicit (even) tile side in MPI pixels, all planes at once and an f32 state.
pub fn infer_mpi_tiled(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    tile: usize,
    progress: &mut dyn FnMut(InferProgress),
) -> Result<Mpi, InferError> {
    let plan = InferPlan::uniform(model.nets.len(), tile, depths.len(), StatePrecision::F32);
    infer_mpi_planned(model, views, reference, depths, &plan, progress)
}

#[cfg(test)]
mod tests;
