//! The tiled inference loop: net after net, tile after tile (a chunk of planes at a time), the state
//! between nets in a [`StateStore`].

use super::error::{InferError, validate};
use super::plan::{InferPlan, plane_separable};
use super::progress::InferProgress;
use super::state::StateStore;
use super::tiling::{Geometry, Rect};
use crate::forward::{
    Crops, Frames, gradient_components_framed, image_tensor, plane_sweep_volume_framed,
};
use crate::network::{
    DeepViewModel, PriorCosts, prior_costs_burn, prior_from_costs, state_to_rgba,
};
use burn::tensor::{Device, Tensor};
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_mpi::Mpi;

pub(super) fn model_device(model: &DeepViewModel) -> Device {
    model.nets[0].out.weight.val().device()
}

/// A tile's result back on the host; a device that failed computing it (a GPU out of memory or over a
/// buffer limit) is an error, not a panic.
fn read_back(t: Tensor<4>) -> Result<Vec<f32>, InferError> {
    // cubecl's report without its list of the kernels skipped after the failure: the first causes and
    // the root one (e.g. "can't allocate buffer of size: N").
    let device = |e: String| {
        let lines: Vec<&str> = e
            .lines()
            .map(str::trim)
            .filter(|l| {
                !l.is_empty()
                    && !l.starts_with("skipped")
                    && !l.starts_with('(')
                    && !matches!(*l, "Caused by:" | "No backtrace available" | "Asked at:")
            })
            .collect();
        let mut shown: Vec<&str> = lines.iter().take(3).copied().collect();
        if let Some(root) = lines.last().filter(|_| lines.len() > 3) {
            shown.push(root);
        }
        InferError::Device(shown.join("; "))
    };
    t.try_into_data()
        .map_err(|e| device(e.to_string()))?
        .try_to_vec()
        .map_err(|e| device(format!("{e:?}")))
}

/// [`super::infer_mpi`] with an explicit plan (`plan.nets` has one entry per net).
pub fn infer_mpi_planned(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    plan: &InferPlan,
    progress: &mut dyn FnMut(InferProgress),
) -> Result<Mpi, InferError> {
    validate(model, views, depths)?;
    if plan.nets.len() != model.nets.len() {
        return Err(InferError::PlanMismatch {
            plan: plan.nets.len(),
            model: model.nets.len(),
        });
    }
    let device = model_device(model);
    let geom = Geometry::new(views, reference, depths);
    let (w, h, d) = (geom.w, geom.h, geom.d);
    let s = model.state_channels;
    let nets = model.nets.len();
    let images = view_tensors(views, &device);
    let tiles: Vec<Vec<Rect>> = plan
        .nets
        .iter()
        .map(|p| geom.tiles(p.tile.max(2).next_multiple_of(2)))
        .collect();
    let total: usize = tiles.iter().map(Vec::len).sum();
    let mut done = 0;
    // A smoothed prior reaches across the whole image (semi-global matching along image paths), and a
    // census term needs each pixel's neighbours: computed once on the whole image, then every tile of
    // net 0 reads its region, so tiles equal the whole-image inference.
    // It is computed and kept on the host (a GPU's largest allocation need not hold it), and freed
    // after net 0.
    let mut whole_prior = model
        .prior_needs_whole_image()
        .then(|| whole_image_prior(model, views, &geom));
    // Premultiplied RGBA result `[D][H][W][4]`, written by the last net.
    let mut layers = Vec::new();
    let mut state: Option<StateStore> = None;
    for n in 0..nets {
        let last = n + 1 == nets;
        let m = model.margin(n);
        let chunk = if plane_separable(model, n) {
            plan.nets[n].plane_chunk.clamp(1, d)
        } else {
            d
        };
        let mut next = (!last).then(|| StateStore::new(d, s, h, w, plan.precision));
        if last {
            layers = vec![0f32; d * h * w * 4];
        }
        for &(tx, ty, tw, th) in &tiles[n] {
            let region = geom.region((tx, ty, tw, th), m);
            let (rx0, ry0, rw, rh) = region;
            let per_view: Vec<Tensor<4>> = (0..views.len())
                .map(|k| {
                    let win = geom.view_window(k, region, state.is_some());
                    let (cx, cy, cw, ch) = win.crop;
                    let crop = images[k].clone().narrow(1, cy, ch).narrow(2, cx, cw);
                    // The whole frames' homographies with the crops' integer origins: the samples
                    // are bit for bit those of the untiled inference.
                    let homs = &geom.homs[k];
                    match &state {
                        None => {
                            let frames = Frames {
                                src_origin: (cx, cy),
                                src_full: geom.view_sizes[k],
                                out_origin: (rx0, ry0),
                            };
                            plane_sweep_volume_framed(crop, homs, frames, rh, rw)
                        }
                        Some(st) => {
                            let (sx, sy, _, _) = win.sub;
                            let rgba = state_to_rgba(st.tensor(0, 4, win.sub, &device));
                            let crops = Crops {
                                window: (sx, sy),
                                mpi_size: (w, h),
                                crop: (cx, cy),
                                view_size: geom.view_sizes[k],
                            };
                            gradient_components_framed(rgba, crop, homs, crops, region)
                        }
                    }
                })
                .collect();
            let region_state = state.as_ref().map(|st| st.tensor(0, s, region, &device));
            // With one chunk the inputs move into the net (and are freed as it goes).
            let mut per_view = Some(per_view);
            for p0 in (0..d).step_by(chunk) {
                let np = chunk.min(d - p0);
                let (inputs, chunk_state) = if np == d {
                    (per_view.take().expect("one chunk"), region_state.clone())
                } else {
                    (
                        per_view
                            .iter()
                            .flatten()
                            .map(|v| v.clone().narrow(0, p0, np))
                            .collect(),
                        region_state.as_ref().map(|rs| rs.clone().narrow(0, p0, np)),
                    )
                };
                let given = (n == 0).then(|| {
                    whole_prior.as_ref().map(|p| {
                        p.clone()
                            .narrow(0, p0, np)
                            .narrow(2, ry0, rh)
                            .narrow(3, rx0, rw)
                            .to_device(&device)
                    })
                });
                let out = model.run_net_with_prior(n, inputs, chunk_state.clone(), given.flatten());
                let out = match chunk_state {
                    Some(rs) => rs + out,
                    None => out,
                };
                let out = out.narrow(2, ty - ry0, th).narrow(3, tx - rx0, tw);
                match next.as_mut() {
                    Some(next) => {
                        let vals = read_back(out)?;
                        next.write(&vals, p0, np, (tx, ty, tw, th));
                    }
                    None => {
                        let vals = read_back(state_to_rgba(out))?;
                        // [np][4][th][tw] -> [D][H][W][4]
                        for p in 0..np {
                            for c in 0..4 {
                                for y in 0..th {
                                    let src = &vals[((p * 4 + c) * th + y) * tw..][..tw];
                                    let row = ((p0 + p) * h + ty + y) * w + tx;
                                    for (x, &v) in src.iter().enumerate() {
                                        layers[(row + x) * 4 + c] = v;
                                    }
                                }
                            }
                        }
                    }
                }
            }
            done += 1;
            progress(InferProgress {
                done,
                total,
                net: n,
            });
        }
        state = next;
        whole_prior = None;
    }
    Ok(Mpi {
        camera: *reference,
        depths: depths.to_vec(),
        layers,
    })
}

/// The views' images as tensors `[C, H, W]` on `device`.
fn view_tensors(views: &[(ImageF32, Camera)], device: &Device) -> Vec<Tensor<3>> {
    views
        .iter()
        .map(|(img, _)| {
            image_tensor(
                &img.data,
                img.width as usize,
                img.height as usize,
                img.channels,
                device,
            )
        })
        .collect()
}

/// The agreement prior's RGBA logits `[D, 4, H, W]` on the whole MPI: the planes' sweeps of the whole
/// views a chunk at a time (about one 4-channel MPI of sweeps at once), their per-plane costs, then
/// across the planes the smoothing and the alphas ([`prior_from_costs`]).
fn whole_image_prior(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    geom: &Geometry,
) -> Tensor<4> {
    let (w, h, d) = (geom.w, geom.h, geom.d);
    let images = view_tensors(views, &Device::flex());
    let chunk = (d / images.len().max(1)).max(1);
    let costs: Vec<PriorCosts> = (0..d)
        .step_by(chunk)
        .map(|p0| {
            let np = chunk.min(d - p0);
            let per_view: Vec<Tensor<4>> = images
                .iter()
                .enumerate()
                .map(|(k, img)| {
                    let frames = Frames {
                        src_origin: (0, 0),
                        src_full: geom.view_sizes[k],
                        out_origin: (0, 0),
                    };
                    plane_sweep_volume_framed(img.clone(), &geom.homs[k][p0..p0 + np], frames, h, w)
                })
                .collect();
            prior_costs_burn(
                &per_view,
                model.prior_temperature,
                model.prior_aggregation(),
            )
        })
        .collect();
    prior_from_costs(
        PriorCosts::cat(costs),
        model.prior_temperature,
        model.prior_smoothing,
    )
}
