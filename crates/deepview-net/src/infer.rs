//! Tiled inference: a whole MPI from posed images with bounded memory.
//!
//! Each net runs tile by tile over the MPI (paper supplement, "Reducing Memory Usage"): for a tile the
//! net's input is computed on the tile grown by the net's receptive-field margin
//! ([`DeepViewModel::margin`]), from each view's image crop covering that region and (for update nets)
//! from the views rendered from the *whole* current MPI; only the tile's centre is kept. The full MPI state
//! between nets is held in memory (`D x H x W x (2 * state + 4)` f32), the activations only per tile, so
//! the result equals the untiled [`DeepViewModel::forward`] on the whole reference image (to f32 rounding
//! of the shifted homographies), whatever the tile size.

use crate::forward::{Hom, crop_source, gradient_components, image_tensor};
use crate::network::{DeepViewModel, state_to_rgba};
use burn::tensor::{Device, Tensor, TensorData};
use deepview_geometry::{Camera, plane_homography};
use deepview_image::ImageF32;
use deepview_mpi::Mpi;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InferError {
    #[error("inference needs at least one input view")]
    NoViews,
    #[error("inference needs at least one plane depth")]
    NoPlanes,
    #[error("these weights take exactly {expected} input views, got {got}")]
    WrongViews { expected: usize, got: usize },
    #[error("input view {view}: image is {iw}x{ih} but its camera is {cw}x{ch}")]
    SizeMismatch {
        view: usize,
        iw: u32,
        ih: u32,
        cw: u32,
        ch: u32,
    },
    #[error(
        "memory budget {budget} bytes is too small: the MPI state alone ({planes} planes of {w}x{h}) needs {fixed} \
         bytes plus at least {min_tile} for one tile; use fewer planes, a smaller reference image or a larger budget"
    )]
    BudgetTooSmall {
        budget: u64,
        fixed: u64,
        min_tile: u64,
        planes: usize,
        w: u32,
        h: u32,
    },
}

/// Progress of [`infer_mpi`]: `done` of `total` tile-net steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InferProgress {
    pub done: usize,
    pub total: usize,
    pub net: usize,
}

fn model_device(model: &DeepViewModel) -> Device {
    model.nets[0].out.weight.val().device()
}

/// Bytes of the full-MPI state kept between nets (old state, new state, RGBA).
pub fn fixed_memory(model: &DeepViewModel, planes: usize, w: u32, h: u32) -> u64 {
    (planes as u64) * w as u64 * h as u64 * (2 * model.state_channels as u64 + 4) * 4
}

/// Rough peak bytes per (view, plane, region pixel) of one tile of net `n`: the conv activations that are
/// alive together, the warp taps and the view renders.
fn bytes_per_slice_pixel(model: &DeepViewModel, n: usize) -> u64 {
    let f = model.nets[n].head.weight.val().dims()[0] as u64;
    let cin = model.nets[n].input[0].weight.val().dims()[1] as u64;
    4 * (2 * cin + 6 * f) + 400
}

/// The largest even tile side whose memory estimate fits `tile_budget` for every net.
pub fn tile_size(model: &DeepViewModel, views: usize, planes: usize, tile_budget: u64) -> usize {
    (0..model.nets.len())
        .map(|n| {
            let per = bytes_per_slice_pixel(model, n) * (views * planes) as u64;
            let side = ((tile_budget / per.max(1)) as f64).sqrt() as usize;
            side.saturating_sub(2 * model.margin(n)) & !1
        })
        .min()
        .unwrap_or(0)
        .max(2)
}

/// Infer an MPI with planes at `depths` (back to front, decreasing) in front of `reference` from posed
/// images, keeping peak memory near `max_memory_bytes` (state + one tile). Runs on the model's device;
/// use a model on a non-autodiff device.
pub fn infer_mpi(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    max_memory_bytes: u64,
    progress: &mut dyn FnMut(InferProgress),
) -> Result<Mpi, InferError> {
    let fixed = fixed_memory(model, depths.len(), reference.width, reference.height);
    let min_tile = bytes_per_slice_pixel(model, 0) * (views.len() * depths.len()) as u64 * 64 * 64;
    if max_memory_bytes < fixed + min_tile {
        return Err(InferError::BudgetTooSmall {
            budget: max_memory_bytes,
            fixed,
            min_tile,
            planes: depths.len(),
            w: reference.width,
            h: reference.height,
        });
    }
    let tile = tile_size(model, views.len(), depths.len(), max_memory_bytes - fixed);
    infer_mpi_tiled(model, views, reference, depths, tile, progress)
}

/// The view-image crop `(x0, y0, w, h)` that every sample of MPI region `region` (all planes) needs.
fn view_crop(
    homs: &[Hom],
    region: (usize, usize, usize, usize),
    vw: usize,
    vh: usize,
) -> (usize, usize, usize, usize) {
    let (rx, ry, rw, rh) = region;
    let (mut x0, mut y0, mut x1, mut y1) = (
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    );
    for h in homs {
        for (u, v) in [(rx, ry), (rx + rw, ry), (rx, ry + rh), (rx + rw, ry + rh)] {
            let (u, v) = (u as f64, v as f64);
            let z = h[6] * u + h[7] * v + h[8];
            let x = (h[0] * u + h[1] * v + h[2]) / z;
            let y = (h[3] * u + h[4] * v + h[5]) / z;
            if !(z > 0.0 && x.is_finite() && y.is_finite()) {
                return (0, 0, vw, vh);
            }
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
        }
    }
    let cx0 = ((x0.floor() - 2.0).max(0.0) as usize).min(vw.saturating_sub(1));
    let cy0 = ((y0.floor() - 2.0).max(0.0) as usize).min(vh.saturating_sub(1));
    let cx1 = ((x1.ceil() + 2.0).min(vw as f64).max(0.0) as usize).max(cx0 + 1);
    let cy1 = ((y1.ceil() + 2.0).min(vh as f64).max(0.0) as usize).max(cy0 + 1);
    (cx0, cy0, cx1 - cx0, cy1 - cy0)
}

/// [`infer_mpi`] with an explicit (even) tile side in MPI pixels.
pub fn infer_mpi_tiled(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    tile: usize,
    progress: &mut dyn FnMut(InferProgress),
) -> Result<Mpi, InferError> {
    if views.is_empty() {
        return Err(InferError::NoViews);
    }
    if depths.is_empty() {
        return Err(InferError::NoPlanes);
    }
    if model.fixed_views != 0 && model.fixed_views != views.len() {
        return Err(InferError::WrongViews {
            expected: model.fixed_views,
            got: views.len(),
        });
    }
    for (i, (img, cam)) in views.iter().enumerate() {
        if img.width != cam.width || img.height != cam.height {
            return Err(InferError::SizeMismatch {
                view: i,
                iw: img.width,
                ih: img.height,
                cw: cam.width,
                ch: cam.height,
            });
        }
    }
    let device = model_device(model);
    let (w, h, d) = (
        reference.width as usize,
        reference.height as usize,
        depths.len(),
    );
    let s = model.state_channels;
    let tile = tile.max(2).next_multiple_of(2);
    let images: Vec<Tensor<3>> = views
        .iter()
        .map(|(img, _)| {
            image_tensor(
                &img.data,
                img.width as usize,
                img.height as usize,
                img.channels,
                &device,
            )
        })
        .collect();
    let homs: Vec<Vec<Hom>> = views
        .iter()
        .map(|(_, cam)| {
            depths
                .iter()
                .map(|&z| plane_homography(reference, cam, z).to_row_major())
                .collect()
        })
        .collect();
    let tiles: Vec<(usize, usize, usize, usize)> = (0..h)
        .step_by(tile)
        .flat_map(|y| {
            (0..w)
                .step_by(tile)
                .map(move |x| (x, y, tile.min(w - x), tile.min(h - y)))
        })
        .collect();
    let total = tiles.len() * model.nets.len();
    let mut state: Option<Tensor<4>> = None;
    for n in 0..model.nets.len() {
        let m = model.margin(n);
        let rgba = state.clone().map(state_to_rgba);
        let mut next = vec![0f32; d * s * h * w];
        for (t, &(tx, ty, tw, th)) in tiles.iter().enumerate() {
            let (rx0, ry0) = (tx.saturating_sub(m), ty.saturating_sub(m));
            let (rx1, ry1) = ((tx + tw + m).min(w), (ty + th + m).min(h));
            let region = (rx0, ry0, rx1 - rx0, ry1 - ry0);
            let per_view: Vec<Tensor<4>> = (0..views.len())
                .map(|k| {
                    let (vw, vh) = (views[k].0.width as usize, views[k].0.height as usize);
                    let (cx, cy, cw, ch) = view_crop(&homs[k], region, vw, vh);
                    let crop = images[k].clone().narrow(1, cy, ch).narrow(2, cx, cw);
                    let hk: Vec<Hom> = homs[k]
                        .iter()
                        .map(|hm| crop_source(hm, cx as f64, cy as f64))
                        .collect();
                    match &rgba {
                        None => DeepViewModel::init_input(crop, &hk, region),
                        Some(rgba) => gradient_components(rgba.clone(), crop, &hk, region),
                    }
                })
                .collect();
            let region_state = state
                .as_ref()
                .map(|st| st.clone().narrow(2, ry0, region.3).narrow(3, rx0, region.2));
            let out = model.run_net(n, per_view, region_state.clone());
            let out = match region_state {
                Some(rs) => rs + out,
                None => out,
            };
            let out = out.narrow(2, ty - ry0, th).narrow(3, tx - rx0, tw);
            let vals: Vec<f32> = out.into_data().try_to_vec().expect("f32 tensor");
            for p in 0..d * s {
                for y in 0..th {
                    let src = &vals[(p * th + y) * tw..(p * th + y + 1) * tw];
                    let o = (p * h + ty + y) * w + tx;
                    next[o..o + tw].copy_from_slice(src);
                }
            }
            progress(InferProgress {
                done: n * tiles.len() + t + 1,
                total,
                net: n,
            });
        }
        drop(rgba);
        state = Some(Tensor::from_data(
            TensorData::new(next, [d, s, h, w]),
            &device,
        ));
    }
    let rgba: Vec<f32> = state_to_rgba(state.expect("at least one net"))
        .into_data()
        .try_to_vec()
        .expect("f32");
    // [D][4][H][W] -> [D][H][W][4]
    let mut layers = vec![0f32; d * h * w * 4];
    for p in 0..d {
        for c in 0..4 {
            for i in 0..h * w {
                layers[(p * h * w + i) * 4 + c] = rgba[(p * 4 + c) * h * w + i];
            }
        }
    }
    Ok(Mpi {
        camera: *reference,
        depths: depths.to_vec(),
        layers,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::DeepViewConfig;
    use crate::network::ModelInputs;
    use deepview_geometry::{DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths};

    fn scene(k: usize) -> (Vec<(ImageF32, Camera)>, Camera, Vec<f64>) {
        let reference = Camera::new(46, 38, Intrinsics::centred(40.0, 46, 38), Pose::IDENTITY);
        let depths = plane_depths(1.5, 12.0, 4, PlaneSpacing::InverseDepth).unwrap();
        let views = (0..k)
            .map(|i| {
                let (vw, vh) = (40 + 3 * i as u32, 34 + 2 * i as u32);
                let a = i as f64 * 2.1;
                let cam = Camera::new(
                    vw,
                    vh,
                    Intrinsics::new(38.0, 39.0, vw as f64 / 2.0 + 0.3, vh as f64 / 2.0 - 0.2),
                    Pose::from_center(
                        DMat3::from_rotation_y(0.02 * i as f64),
                        DVec3::new(0.1 * a.cos(), 0.08 * a.sin(), 0.01),
                    ),
                );
                let mut img = ImageF32::new(vw, vh, 3);
                for (j, v) in img.data.iter_mut().enumerate() {
                    *v = ((j * 7919 + i * 104729) % 1000) as f32 / 1000.0;
                }
                (img, cam)
            })
            .collect();
        (views, reference, depths)
    }

    #[test]
    fn tiled_equals_untiled() {
        let dev = Device::flex();
        let cfg = DeepViewConfig {
            features_large: 6,
            features_small: 4,
            updates: 2,
            unet_nets: 1,
            init_prior: None,
            ..DeepViewConfig::preset("cpu").unwrap()
        };
        let model = DeepViewModel::new(&cfg, &dev);
        let (views, reference, depths) = scene(3);
        // Untiled reference: the model's own window forward on the whole reference image.
        let inputs = ModelInputs {
            images: views
                .iter()
                .map(|(i, _)| image_tensor(&i.data, i.width as usize, i.height as usize, 3, &dev))
                .collect(),
            mpi_to_view: views
                .iter()
                .map(|(_, c)| {
                    depths
                        .iter()
                        .map(|&z| plane_homography(&reference, c, z).to_row_major())
                        .collect()
                })
                .collect(),
            height: 38,
            width: 46,
            shrink: false,
        };
        let full: Vec<f32> = model
            .forward(&inputs)
            .rgba
            .into_data()
            .try_to_vec()
            .unwrap();
        let mut calls = 0;
        for tile in [64, 10, 6] {
            let mpi = infer_mpi_tiled(&model, &views, &reference, &depths, tile, &mut |_| {
                calls += 1
            })
            .unwrap();
            let mut max = 0f32;
            for p in 0..4 {
                for c in 0..4 {
                    for i in 0..38 * 46 {
                        let a = full[(p * 4 + c) * 38 * 46 + i];
                        let b = mpi.layers[(p * 38 * 46 + i) * 4 + c];
                        max = max.max((a - b).abs());
                    }
                }
            }
            assert!(max < 2e-5, "tile {tile}: max difference {max}");
        }
        assert_eq!(calls, 3 * (1 + 20 + 8 * 7));
    }

    /// With the agreement prior and zero-initialised output convs, the model's MPI is the `psv-mean`
    /// baseline's MPI (`deepview_eval::agreement_mpi`, an independent f64 implementation on the CPU).
    #[test]
    fn untrained_prior_model_equals_agreement_mpi() {
        use deepview_eval::{PsvMeanOptions, agreement_mpi};
        use deepview_geometry::{ReferenceOptions, reference_camera};
        let dev = Device::flex();
        for (k, planes, smooth) in [(3, 8, true), (4, 5, false), (2, 6, true)] {
            let cfg = DeepViewConfig {
                features_large: 4,
                features_small: 3,
                updates: 2,
                max_pool_stages: 1,
                ..DeepViewConfig::preset("cpu").unwrap()
            };
            let model = DeepViewModel::new(&cfg, &dev);
            let (mut views, _, _) = scene(k);
            if smooth {
                // Smooth textures, so that views agree at some depths and the weights are mixed.
                for (img, _) in views.iter_mut() {
                    let w = img.width as usize;
                    for (j, v) in img.data.iter_mut().enumerate() {
                        let (p, c) = (j / 3, j % 3);
                        let (x, y) = ((p % w) as f32, (p / w) as f32);
                        *v = 0.5 + 0.4 * (0.3 * x + 0.2 * y + c as f32).sin() * (0.11 * y).cos();
                    }
                }
            }
            let near_far = (1.5, 12.0);
            let options = PsvMeanOptions {
                planes,
                ..Default::default()
            };
            let expected = agreement_mpi(&views, near_far, &options).unwrap();
            let cams: Vec<Camera> = views.iter().map(|(_, c)| *c).collect();
            let reference = reference_camera(
                &cams,
                &ReferenceOptions {
                    cover: Some(near_far),
                    ..Default::default()
                },
            )
            .unwrap();
            let depths = plane_depths(1.5, 12.0, planes, PlaneSpacing::InverseDepth).unwrap();
            assert_eq!(expected.camera, reference);
            let mpi = infer_mpi_tiled(&model, &views, &reference, &depths, 16, &mut |_| {}).unwrap();
            assert_eq!(mpi.layers.len(), expected.layers.len());
            let (mut max, mut mixed) = (0f32, 0usize);
            for (a, b) in mpi.layers.chunks_exact(4).zip(expected.layers.chunks_exact(4)) {
                for c in 0..4 {
                    max = max.max((a[c] - b[c]).abs());
                }
                mixed += usize::from(b[3] > 0.05 && b[3] < 0.95);
            }
            assert!(max < 3e-4, "k {k}, planes {planes}: max difference {max}");
            if smooth {
                assert!(mixed > 100, "only {mixed} partially transparent texels");
            }
        }
    }

    #[test]
    fn budget_and_input_errors() {
        let dev = Device::flex();
        let model = DeepViewModel::new(&DeepViewConfig::preset("paper-kalantari").unwrap(), &dev);
        let (views, reference, depths) = scene(3);
        let e = infer_mpi(&model, &views, &reference, &depths, 1 << 40, &mut |_| {}).unwrap_err();
        assert_eq!(
            e,
            InferError::WrongViews {
                expected: 4,
                got: 3
            }
        );
        let model = DeepViewModel::new(&DeepViewConfig::preset("cpu").unwrap(), &dev);
        let e = infer_mpi(&model, &views, &reference, &depths, 1000, &mut |_| {}).unwrap_err();
        assert!(matches!(e, InferError::BudgetTooSmall { .. }));
        assert_eq!(
            infer_mpi(&model, &[], &reference, &depths, 1 << 30, &mut |_| {}).unwrap_err(),
            InferError::NoViews
        );
        // A generous budget gives one tile.
        let mut steps = 0;
        let mpi = infer_mpi(&model, &views, &reference, &depths, 1 << 31, &mut |p| {
            steps = p.total
        })
        .unwrap();
        assert_eq!(steps, 3);
        assert_eq!(mpi.layers.len(), 4 * 38 * 46 * 4);
    }
}
