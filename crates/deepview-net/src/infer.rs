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
//! beyond +-65504 saturate). The final RGBA comes from the last net's f32 output (no rounding there).
//! [`plan_inference`] picks the precision and, per net, the tile and plane chunk from calibrated
//! estimates of the peak resident memory.

use crate::forward::{Hom, crop_output, crop_source, gradient_components, image_tensor, invert};
use crate::network::{DeepViewModel, state_to_rgba};
use burn::tensor::{Device, Tensor, TensorData};
use deepview_geometry::{Camera, plane_homography};
use deepview_image::ImageF32;
use deepview_mpi::Mpi;
use half::f16;
use half::slice::HalfFloatSliceExt;

/// A pixel rectangle `(x0, y0, w, h)`.
type Rect = (usize, usize, usize, usize);

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InferError {
    #[error("inference needs at least one input view")]
    NoViews,
    #[error("inference needs at least one plane depth")]
    NoPlanes,
    #[error("these weights take exactly {expected} input views, got {got}")]
    WrongViews { expected: usize, got: usize },
    #[error("the inference plan has {plan} nets but the model has {model}")]
    PlanMismatch { plan: usize, model: usize },
    #[error("input view {view}: image is {iw}x{ih} but its camera is {cw}x{ch}")]
    SizeMismatch {
        view: usize,
        iw: u32,
        ih: u32,
        cw: u32,
        ch: u32,
    },
    #[error(
        "memory budget {budget} bytes is too small: the MPI state ({planes} planes of {w}x{h}) and the inputs \
         need {fixed} bytes plus {min_tile} for the smallest tile; use fewer planes, a smaller reference image \
         or a larger budget"
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

/// How the whole-MPI state is stored between nets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StatePrecision {
    F32,
    /// IEEE half floats (see the module docs for the rounding).
    F16,
}

impl StatePrecision {
    pub fn bytes(self) -> u64 {
        match self {
            Self::F32 => 4,
            Self::F16 => 2,
        }
    }
}

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
const BASE_BYTES: u64 = 32 << 20;

fn model_device(model: &DeepViewModel) -> Device {
    model.nets[0].out.weight.val().device()
}

/// The per-view geometry of an inference problem.
struct Geometry {
    w: usize,
    h: usize,
    d: usize,
    /// `[view][plane]`: MPI pixels -> view pixels.
    homs: Vec<Vec<Hom>>,
    /// `(width, height)` of each view.
    view_sizes: Vec<(usize, usize)>,
}

/// What one view contributes to a tile: the view-image crop, the homographies MPI -> crop pixels and
/// the MPI sub-window rendered into the crop (update nets only; the region itself for the init net).
struct ViewWindow {
    crop: Rect,
    mpi_to_crop: Vec<Hom>,
    sub: Rect,
}

impl Geometry {
    fn new(views: &[(ImageF32, Camera)], reference: &Camera, depths: &[f64]) -> Self {
        Self {
            w: reference.width as usize,
            h: reference.height as usize,
            d: depths.len(),
            homs: views
                .iter()
                .map(|(_, cam)| {
                    depths
                        .iter()
                        .map(|&z| plane_homography(reference, cam, z).to_row_major())
                        .collect()
                })
                .collect(),
            view_sizes: views
                .iter()
                .map(|(img, _)| (img.width as usize, img.height as usize))
                .collect(),
        }
    }

    fn tiles(&self, tile: usize) -> Vec<Rect> {
        let (w, h) = (self.w, self.h);
        (0..h)
            .step_by(tile)
            .flat_map(|y| {
                (0..w)
                    .step_by(tile)
                    .map(move |x| (x, y, tile.min(w - x), tile.min(h - y)))
            })
            .collect()
    }

    /// The tile grown by `margin`, clamped to the MPI.
    fn region(&self, tile: Rect, margin: usize) -> Rect {
        let (tx, ty, tw, th) = tile;
        let (x0, y0) = (tx.saturating_sub(margin), ty.saturating_sub(margin));
        let (x1, y1) = (
            (tx + tw + margin).min(self.w),
            (ty + th + margin).min(self.h),
        );
        (x0, y0, x1 - x0, y1 - y0)
    }

    fn view_window(&self, k: usize, region: Rect, with_sub: bool) -> ViewWindow {
        let (vw, vh) = self.view_sizes[k];
        let (crop, sees) = view_crop(&self.homs[k], region, vw, vh);
        let mpi_to_crop: Vec<Hom> = self.homs[k]
            .iter()
            .map(|hm| crop_source(hm, crop.0 as f64, crop.1 as f64))
            .collect();
        // A view that no sample of the region sees needs no render: any window will do.
        let sub = if with_sub && sees {
            mpi_window(&mpi_to_crop, crop.2, crop.3, self.w, self.h, region)
        } else {
            region
        };
        ViewWindow {
            crop,
            mpi_to_crop,
            sub,
        }
    }
}

/// The view-image crop `(x0, y0, w, h)` that every sample of MPI region `region` (all planes) needs, and
/// whether any sample can fall inside the view (if not, the crop is a 1x1 placeholder no sample reaches).
fn view_crop(homs: &[Hom], region: Rect, vw: usize, vh: usize) -> (Rect, bool) {
    let (rx, ry, rw, rh) = region;
    let corners = [(rx, ry), (rx + rw, ry), (rx, ry + rh), (rx + rw, ry + rh)]
        .map(|(u, v)| (u as f64, v as f64));
    match bounding_box(homs, &corners) {
        None => ((0, 0, vw, vh), true),
        Some(b) => match grown_box(b, vw, vh) {
            Some(crop) => (crop, true),
            None => ((0, 0, vw.min(1), vh.min(1)), false),
        },
    }
}

/// The bounding box `(x0, y0, x1, y1)` of the images of `corners` under every homography, or `None` when
/// a corner maps to infinity or behind the camera (the image of the rectangle is then unbounded).
fn bounding_box(homs: &[Hom], corners: &[(f64, f64); 4]) -> Option<(f64, f64, f64, f64)> {
    let (mut x0, mut y0, mut x1, mut y1) = (
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    );
    for h in homs {
        for &(u, v) in corners {
            let z = h[6] * u + h[7] * v + h[8];
            let x = (h[0] * u + h[1] * v + h[2]) / z;
            let y = (h[3] * u + h[4] * v + h[5]) / z;
            if !(z > 0.0 && x.is_finite() && y.is_finite()) {
                return None;
            }
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
        }
    }
    Some((x0, y0, x1, y1))
}

/// The texels `[floor(x0) - 2, ceil(x1) + 2)` (and the same in y) clamped to a `w x h` image, or `None`
/// when that is empty. A bilinear sample at continuous `s` reads texels `floor(s - 0.5)` and the next one,
/// so for `s` in `[x0, x1]` both lie within one texel of the box; the second texel of slack covers the
/// f32 rounding of shifted homographies.
fn grown_box(b: (f64, f64, f64, f64), w: usize, h: usize) -> Option<Rect> {
    let (x0, y0, x1, y1) = b;
    let clamp = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
    let (cx0, cx1) = (clamp(x0.floor() - 2.0, w), clamp(x1.ceil() + 2.0, w));
    let (cy0, cy1) = (clamp(y0.floor() - 2.0, h), clamp(y1.ceil() + 2.0, h));
    (cx1 > cx0 && cy1 > cy0).then_some((cx0, cy0, cx1 - cx0, cy1 - cy0))
}

/// The sub-window of a `w x h` MPI holding every texel that a render into a `cw x ch` view crop samples
/// on any plane (`mpi_to_crop[d]`: MPI pixels -> crop pixels), joined with `region` (which the gradient
/// components are computed on, relative to the sub-window). Exact: a sample inside the MPI lies in the
/// crop's back-projected bounding box, hence inside the window with its bilinear taps; a sample outside
/// the MPI is outside the window, which is clamped to the MPI; and the window's edge clamping only
/// differs from the MPI's where no tap reaches it.
fn mpi_window(mpi_to_crop: &[Hom], cw: usize, ch: usize, w: usize, h: usize, region: Rect) -> Rect {
    let inverse: Vec<Hom> = mpi_to_crop.iter().map(invert).collect();
    let corners = [(0, 0), (cw, 0), (0, ch), (cw, ch)].map(|(u, v)| (u as f64, v as f64));
    let Some(b) = bounding_box(&inverse, &corners) else {
        return (0, 0, w, h);
    };
    let Some((x0, y0, sw, sh)) = grown_box(b, w, h) else {
        return region;
    };
    let (rx, ry, rw, rh) = region;
    let (x1, y1) = ((x0 + sw).max(rx + rw), (y0 + sh).max(ry + rh));
    let (x0, y0) = (x0.min(rx), y0.min(ry));
    (x0, y0, x1 - x0, y1 - y0)
}

/// Storage of a `[D][C][H][W]` state between nets.
enum Values {
    F32(Vec<f32>),
    F16(Vec<f16>),
}

struct StateStore {
    d: usize,
    c: usize,
    h: usize,
    w: usize,
    values: Values,
}

impl StateStore {
    fn new(d: usize, c: usize, h: usize, w: usize, precision: StatePrecision) -> Self {
        let n = d * c * h * w;
        let values = match precision {
            StatePrecision::F32 => Values::F32(vec![0.0; n]),
            StatePrecision::F16 => Values::F16(vec![f16::ZERO; n]),
        };
        Self { d, c, h, w, values }
    }

    /// Channels `c0..c0 + nc` of window `r`, as f32 `[D][nc][r.h][r.w]`.
    fn read(&self, c0: usize, nc: usize, r: Rect) -> Vec<f32> {
        let (x, y, rw, rh) = r;
        let mut out = vec![0f32; self.d * nc * rw * rh];
        for p in 0..self.d {
            for c in 0..nc {
                for row in 0..rh {
                    let src = ((p * self.c + c0 + c) * self.h + y + row) * self.w + x;
                    let dst = ((p * nc + c) * rh + row) * rw;
                    let out = &mut out[dst..dst + rw];
                    match &self.values {
                        Values::F32(v) => out.copy_from_slice(&v[src..src + rw]),
                        Values::F16(v) => v[src..src + rw].convert_to_f32_slice(out),
                    }
                }
            }
        }
        out
    }

    /// Write `vals` `[np][C][r.h][r.w]` (all channels of planes `p0..p0 + np`) into window `r`.
    fn write(&mut self, vals: &[f32], p0: usize, np: usize, r: Rect) {
        let (x, y, rw, rh) = r;
        let mut row_buf = vec![0f32; rw];
        for p in 0..np {
            for c in 0..self.c {
                for row in 0..rh {
                    let src = &vals[((p * self.c + c) * rh + row) * rw..][..rw];
                    let dst = (((p0 + p) * self.c + c) * self.h + y + row) * self.w + x;
                    match &mut self.values {
                        Values::F32(v) => v[dst..dst + rw].copy_from_slice(src),
                        Values::F16(v) => {
                            for (b, &s) in row_buf.iter_mut().zip(src) {
                                *b = s.clamp(-65504.0, 65504.0);
                            }
                            v[dst..dst + rw].convert_from_f32_slice(&row_buf);
                        }
                    }
                }
            }
        }
    }

    fn tensor(&self, c0: usize, nc: usize, r: Rect, device: &Device) -> Tensor<4> {
        Tensor::from_data(
            TensorData::new(self.read(c0, nc, r), [self.d, nc, r.3, r.2]),
            device,
        )
    }
}

/// Whether net `n` may run on a subset of the planes: the core nets treat planes independently
/// ([`crate::network::CoreNet`]: convs per (view, plane) slice, maxima over views per plane), but
/// net 0's agreement prior (`prior_temperature > 0`) accumulates over all planes.
fn plane_separable(model: &DeepViewModel, n: usize) -> bool {
    n > 0 || model.prior_temperature <= 0.0
}

/// Estimated bytes of the whole-MPI data while net `n` runs (the previous state, and the next state or
/// for the last net the RGBA result), the inputs and the process.
fn fixed_bytes(model: &DeepViewModel, geom: &Geometry, n: usize, precision: StatePrecision) -> u64 {
    let px = (geom.d * geom.w * geom.h) as u64;
    let store = px * model.state_channels as u64 * precision.bytes();
    let old = if n > 0 { store } else { 0 };
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

/// The largest estimate of net `n` over its tiles of side `tile`.
fn max_tile_bytes(
    model: &DeepViewModel,
    geom: &Geometry,
    n: usize,
    tile: usize,
    chunk: usize,
) -> u64 {
    let m = model.margin(n);
    geom.tiles(tile)
        .into_iter()
        .map(|t| {
            let region = geom.region(t, m);
            let windows: Vec<ViewWindow> = (0..geom.homs.len())
                .map(|k| geom.view_window(k, region, n > 0))
                .collect();
            tile_estimate(model, n, geom.d, chunk, region, &windows)
        })
        .max()
        .unwrap_or(0)
}

/// The largest tile (then the largest plane chunk) of net `n` whose estimate fits `budget`.
fn plan_net(
    model: &DeepViewModel,
    geom: &Geometry,
    n: usize,
    precision: StatePrecision,
    budget: u64,
) -> Result<NetPlan, InferError> {
    let fixed = fixed_bytes(model, geom, n, precision);
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
            let tile_bytes = max_tile_bytes(model, geom, n, tile, chunk);
            if fixed + tile_bytes <= budget {
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

fn validate(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    depths: &[f64],
) -> Result<(), InferError> {
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
    Ok(())
}

/// The plan [`infer_mpi`] uses for `max_memory_bytes`: an f32 state when it takes at most half the
/// budget, f16 otherwise; then per net the largest tile (from one tile for the whole MPI down to
/// [`MIN_TILE`]) and the largest plane chunk whose estimated peak, with the whole-MPI data, fits.
pub fn plan_inference(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    max_memory_bytes: u64,
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
        .map(|n| plan_net(model, &geom, n, precision, max_memory_bytes))
        .collect::<Result<_, _>>()?;
    Ok(InferPlan { precision, nets })
}

/// Synthetic inputs of [`infer_mpi`] for benchmarks: `views` cameras of `w x h` pixels (focal `w`) on a
/// circle of radius 0.05 around a reference camera looking down +z, textured images, `planes`
/// inverse-depth planes between depth 1 and 10 (about `0.05 w` px of parallax at the near plane).
pub fn synthetic_views(
    views: usize,
    planes: usize,
    w: usize,
    h: usize,
) -> (Vec<(ImageF32, Camera)>, Camera, Vec<f64>) {
    use deepview_geometry::{DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths};
    let (wu, hu) = (w as u32, h as u32);
    let reference = Camera::new(
        wu,
        hu,
        Intrinsics::centred(w as f64, wu, hu),
        Pose::IDENTITY,
    );
    let depths = plane_depths(1.0, 10.0, planes, PlaneSpacing::InverseDepth).expect("valid depths");
    let cams = (0..views).map(|k| {
        let t = k as f64 / views as f64 * std::f64::consts::TAU;
        let pose = Pose::from_center(
            DMat3::IDENTITY,
            DVec3::new(0.05 * t.cos(), 0.05 * t.sin(), 0.0),
        );
        let mut img = ImageF32::new(wu, hu, 3);
        for (j, v) in img.data.iter_mut().enumerate() {
            let (p, c) = (j / 3, j % 3);
            let (x, y) = ((p % w) as f32, (p / w) as f32);
            let hash = ((p as u32).wrapping_mul(2654435761) >> 24) as f32 / 255.0;
            *v = 0.5 + 0.3 * (0.05 * x + 0.07 * y + c as f32 + k as f32).sin() * hash;
        }
        (img, Camera::new(wu, hu, reference.intrinsics, pose))
    });
    (cams.collect(), reference, depths)
}

/// Infer an MPI with planes at `depths` (back to front, decreasing) in front of `reference` from posed
/// images, keeping peak memory within `max_memory_bytes` (see [`plan_inference`]). Runs on the model's
/// device; use a model on a non-autodiff device.
pub fn infer_mpi(
    model: &DeepViewModel,
    views: &[(ImageF32, Camera)],
    reference: &Camera,
    depths: &[f64],
    max_memory_bytes: u64,
    progress: &mut dyn FnMut(InferProgress),
) -> Result<Mpi, InferError> {
    validate(model, views, depths)?;
    let (w, h) = (reference.width as usize, reference.height as usize);
    if crate::kernels::fast_device(&model_device(model))
        && crate::engine::supported(model)
        && crate::engine::engine_bytes(model, views, w, h, depths.len()) <= max_memory_bytes
    {
        // Whole image at once on the CPU kernels (see `engine`): the same result as the tiled path.
        let total = model.nets.len();
        let layers = crate::engine::infer_engine(model, views, reference, depths, &mut |n| {
            progress(InferProgress {
                done: n + 1,
                total,
                net: n,
            })
        });
        return Ok(Mpi {
            camera: *reference,
            depths: depths.to_vec(),
            layers,
        });
    }
    let plan = plan_inference(model, views, reference, depths, max_memory_bytes)?;
    infer_mpi_planned(model, views, reference, depths, &plan, progress)
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

/// [`infer_mpi`] with an explicit plan (`plan.nets` has one entry per net).
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
    let tiles: Vec<Vec<Rect>> = plan
        .nets
        .iter()
        .map(|p| geom.tiles(p.tile.max(2).next_multiple_of(2)))
        .collect();
    let total: usize = tiles.iter().map(Vec::len).sum();
    let mut done = 0;
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
                    match &state {
                        None => DeepViewModel::init_input(crop, &win.mpi_to_crop, region),
                        Some(st) => {
                            let (sx, sy, _, _) = win.sub;
                            let rgba = state_to_rgba(st.tensor(0, 4, win.sub, &device));
                            let homs: Vec<Hom> = win
                                .mpi_to_crop
                                .iter()
                                .map(|hm| crop_output(hm, sx as f64, sy as f64))
                                .collect();
                            gradient_components(rgba, crop, &homs, (rx0 - sx, ry0 - sy, rw, rh))
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
                let out = model.run_net(n, inputs, chunk_state.clone());
                let out = match chunk_state {
                    Some(rs) => rs + out,
                    None => out,
                };
                let out = out.narrow(2, ty - ry0, th).narrow(3, tx - rx0, tw);
                match next.as_mut() {
                    Some(next) => {
                        let vals: Vec<f32> = out.into_data().try_to_vec().expect("f32 tensor");
                        next.write(&vals, p0, np, (tx, ty, tw, th));
                    }
                    None => {
                        let vals: Vec<f32> = state_to_rgba(out)
                            .into_data()
                            .try_to_vec()
                            .expect("f32 tensor");
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
        // Different tiles per net, planes in chunks.
        let mut plan = InferPlan::uniform(3, 10, 4, StatePrecision::F32);
        (plan.nets[1].tile, plan.nets[1].plane_chunk) = (6, 3);
        (plan.nets[2].tile, plan.nets[2].plane_chunk) = (64, 1);
        let mut steps = (0, 0);
        let mpi = infer_mpi_planned(&model, &views, &reference, &depths, &plan, &mut |p| {
            steps = (p.done, p.total)
        })
        .unwrap();
        assert_eq!(steps, (20 + 8 * 7 + 1, 20 + 8 * 7 + 1));
        let diff = max_layer_diff(&full, &mpi.layers, 38 * 46);
        assert!(diff < 2e-5, "chunked: max difference {diff}");
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
            let mpi =
                infer_mpi_tiled(&model, &views, &reference, &depths, 16, &mut |_| {}).unwrap();
            assert_eq!(mpi.layers.len(), expected.layers.len());
            let (mut max, mut mixed) = (0f32, 0usize);
            for (a, b) in mpi
                .layers
                .chunks_exact(4)
                .zip(expected.layers.chunks_exact(4))
            {
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
        assert_eq!(steps, model.nets.len());
        assert_eq!(mpi.layers.len(), 4 * 38 * 46 * 4);
        let plan = InferPlan::uniform(1, 16, 4, StatePrecision::F32);
        assert_eq!(
            infer_mpi_planned(&model, &views, &reference, &depths, &plan, &mut |_| {}).unwrap_err(),
            InferError::PlanMismatch {
                plan: 1,
                model: model.nets.len()
            }
        );
    }

    fn small_model(dev: &Device, unet_nets: usize) -> DeepViewModel {
        let cfg = DeepViewConfig {
            features_large: 6,
            features_small: 4,
            updates: 2,
            unet_nets,
            init_prior: None,
            ..DeepViewConfig::preset("cpu").unwrap()
        };
        DeepViewModel::new(&cfg, dev)
    }

    /// The untiled model on the whole reference image, as `[D][4][H][W]`.
    fn untiled(
        model: &DeepViewModel,
        views: &[(ImageF32, Camera)],
        reference: &Camera,
        depths: &[f64],
        dev: &Device,
    ) -> Vec<f32> {
        let geom = Geometry::new(views, reference, depths);
        let inputs = ModelInputs {
            images: views
                .iter()
                .map(|(i, _)| image_tensor(&i.data, i.width as usize, i.height as usize, 3, dev))
                .collect(),
            mpi_to_view: geom.homs.clone(),
            height: geom.h,
            width: geom.w,
            shrink: false,
        };
        model
            .forward(&inputs)
            .rgba
            .into_data()
            .try_to_vec()
            .unwrap()
    }

    /// Max |a - b| between `[D][4][H][W]` and an MPI's `[D][H][W][4]` layers.
    fn max_layer_diff(full: &[f32], layers: &[f32], px: usize) -> f32 {
        let mut max = 0f32;
        for (i, &b) in layers.iter().enumerate() {
            let (c, q) = (i % 4, i / 4);
            let (p, j) = (q / px, q % px);
            max = max.max((full[(p * 4 + c) * px + j] - b).abs());
        }
        max
    }

    /// Three views far apart relative to the depth range: 24 px of disparity between the nearest and the
    /// farthest plane horizontally, 10 px vertically, on a 240x64 MPI.
    fn parallax_scene() -> (Vec<(ImageF32, Camera)>, Camera, Vec<f64>) {
        let (w, h) = (240u32, 64u32);
        let intr = Intrinsics::centred(40.0, w, h);
        let reference = Camera::new(w, h, intr, Pose::IDENTITY);
        let depths = plane_depths(1.0, 20.0, 5, PlaneSpacing::InverseDepth).unwrap();
        let centres = [(-0.6, 0.0), (0.6, 0.05), (0.0, 0.25)];
        let views = centres
            .iter()
            .enumerate()
            .map(|(i, &(x, y))| {
                let cam = Camera::new(
                    w,
                    h,
                    intr,
                    Pose::from_center(DMat3::from_rotation_y(0.01), DVec3::new(x, y, 0.0)),
                );
                let mut img = ImageF32::new(w, h, 3);
                for (j, v) in img.data.iter_mut().enumerate() {
                    let (p, c) = (j / 3, j % 3);
                    let (px, py) = ((p % w as usize) as f32, (p / w as usize) as f32);
                    let noise = ((j * 7919 + i * 104729) % 1000) as f32 / 1000.0;
                    *v = 0.5 * noise + 0.25 * (1.0 + (0.2 * px + 0.3 * py + c as f32).sin());
                }
                (img, cam)
            })
            .collect();
        (views, reference, depths)
    }

    #[test]
    fn strong_parallax_sub_windows_are_exact_and_small() {
        use burn::tensor::Distribution;
        let dev = Device::flex();
        let (views, reference, depths) = parallax_scene();
        let geom = Geometry::new(&views, &reference, &depths);
        let (w, h, d) = (geom.w, geom.h, geom.d);
        // A random MPI (not the model's): the views' gradient components on a region from the sub-window
        // equal those from the whole MPI.
        let alpha = Tensor::<4>::random([d, 1, h, w], Distribution::Uniform(0.05, 0.95), &dev);
        let col = Tensor::<4>::random([d, 3, h, w], Distribution::Uniform(0.0, 1.0), &dev);
        let rgba = Tensor::cat(vec![col * alpha.clone(), alpha], 1);
        let images: Vec<Tensor<3>> = views
            .iter()
            .map(|(i, _)| image_tensor(&i.data, i.width as usize, i.height as usize, 3, &dev))
            .collect();
        let (mut area, mut count, mut max_diff) = (0usize, 0usize, 0f32);
        for t in geom.tiles(8) {
            let region = geom.region(t, 8);
            for k in 0..views.len() {
                let win = geom.view_window(k, region, true);
                let (cx, cy, cw, ch) = win.crop;
                let (sx, sy, sw, sh) = win.sub;
                if t == (112, 24, 8, 8) && k < 2 {
                    // The parallax is strong: the crop spans the region plus the disparity range.
                    assert!(cw >= region.2 + 22, "crop {cw} for region {}", region.2);
                }
                let crop = images[k].clone().narrow(1, cy, ch).narrow(2, cx, cw);
                let full =
                    gradient_components(rgba.clone(), crop.clone(), &win.mpi_to_crop, region);
                let homs: Vec<Hom> = win
                    .mpi_to_crop
                    .iter()
                    .map(|hm| crop_output(hm, sx as f64, sy as f64))
                    .collect();
                let sub_rgba = rgba.clone().narrow(2, sy, sh).narrow(3, sx, sw);
                let rel = (region.0 - sx, region.1 - sy, region.2, region.3);
                let sub = gradient_components(sub_rgba, crop, &homs, rel);
                let diff: f32 = (full - sub).abs().max().into_scalar();
                max_diff = max_diff.max(diff);
                area += sw * sh;
                count += 1;
            }
        }
        // f32 rounding of the shifted homographies moves samples by ~1e-5 px at x ~ 240.
        assert!(
            max_diff < 5e-5,
            "sub-window components differ by {max_diff}"
        );
        let mean = area as f64 / count as f64 / (w * h) as f64;
        assert!(
            mean < 0.35,
            "sub-windows cover {mean:.2} of the MPI on average"
        );
        // And the whole tiled inference equals the untiled model.
        let model = small_model(&dev, 0);
        let full = untiled(&model, &views, &reference, &depths, &dev);
        for chunk in [5, 2] {
            let plan = InferPlan::uniform(model.nets.len(), 8, chunk, StatePrecision::F32);
            let mpi =
                infer_mpi_planned(&model, &views, &reference, &depths, &plan, &mut |_| {}).unwrap();
            let diff = max_layer_diff(&full, &mpi.layers, w * h);
            assert!(
                diff < 2e-5,
                "plane chunk {chunk}: tiled vs untiled differ by {diff}"
            );
        }
    }

    #[test]
    fn f16_state_agrees_with_f32_state() {
        let dev = Device::flex();
        let model = small_model(&dev, 1);
        let (views, reference, depths) = scene(3);
        let run = |precision| {
            let plan = InferPlan::uniform(model.nets.len(), 16, 4, precision);
            infer_mpi_planned(&model, &views, &reference, &depths, &plan, &mut |_| {})
                .unwrap()
                .layers
        };
        let (a, b) = (run(StatePrecision::F32), run(StatePrecision::F16));
        let max = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max);
        assert!(max < 1e-2, "f16 state differs by {max}");
        assert!(max > 0.0, "the f16 state should round something");
    }

    #[test]
    fn f16_store_rounds_to_11_bits_and_saturates() {
        let mut st = StateStore::new(2, 3, 4, 5, StatePrecision::F16);
        let vals: Vec<f32> = (0..2 * 3 * 2 * 3)
            .map(|i| ((i * 37) % 101) as f32 / 5.0 - 10.0 + 1e-3 * i as f32)
            .collect();
        st.write(&vals, 0, 2, (1, 2, 3, 2));
        let back = st.read(0, 3, (1, 2, 3, 2));
        for (v, b) in vals.iter().zip(&back) {
            assert!((v - b).abs() <= v.abs() * 2f32.powi(-11), "{v} -> {b}");
        }
        // Outside the written window the store is still zero; a window of one channel reads that channel.
        assert!(st.read(0, 3, (0, 0, 5, 2)).iter().all(|&v| v == 0.0));
        let ch1: Vec<f32> = [&back[6..12], &back[24..30]].concat();
        assert_eq!(st.read(1, 1, (1, 2, 3, 2)), ch1);
        st.write(&[1e6; 2 * 3], 0, 2, (0, 0, 1, 1));
        assert_eq!(st.read(0, 3, (0, 0, 1, 1)), vec![65504.0; 6]);
        // Writing plane 1 only leaves plane 0.
        st.write(&[-1e6, 0.5, 2.0], 1, 1, (0, 0, 1, 1));
        assert_eq!(
            st.read(0, 3, (0, 0, 1, 1)),
            vec![65504.0, 65504.0, 65504.0, -65504.0, 0.5, 2.0]
        );
    }

    #[test]
    fn plan_picks_precision_tiles_and_chunks_within_budget() {
        let dev = Device::flex();
        let model = DeepViewModel::new(&DeepViewConfig::preset("cpu").unwrap(), &dev);
        let (views, reference, depths) = parallax_scene();
        let geom = Geometry::new(&views, &reference, &depths);
        let nets = model.nets.len();
        let plan = plan_inference(&model, &views, &reference, &depths, 1 << 34).unwrap();
        assert_eq!(plan.precision, StatePrecision::F32);
        assert!(
            plan.nets
                .iter()
                .all(|p| p.tile == 240 && p.plane_chunk == 5)
        );
        let fixed = |p| {
            (0..nets)
                .map(|n| fixed_bytes(&model, &geom, n, p))
                .max()
                .unwrap()
        };
        let (f32_fixed, f16_fixed) = (fixed(StatePrecision::F32), fixed(StatePrecision::F16));
        assert!(f16_fixed < f32_fixed);
        // Below twice the f32 state's fixed part the state is f16.
        let plan = plan_inference(&model, &views, &reference, &depths, 2 * f32_fixed - 1).unwrap();
        assert_eq!(plan.precision, StatePrecision::F16);
        // Smaller budgets: smaller plane chunks, then smaller tiles; the estimate always fits.
        let mut last = vec![(usize::MAX, usize::MAX); nets];
        for extra in [32u64 << 20, 20 << 20, 14 << 20, 11 << 20] {
            let budget = f16_fixed + extra;
            let plan = plan_inference(&model, &views, &reference, &depths, budget).unwrap();
            assert_eq!(plan.precision, StatePrecision::F16);
            assert!(plan.peak_bytes() <= budget);
            for (p, l) in plan.nets.iter().zip(last.iter_mut()) {
                assert!(p.tile >= MIN_TILE && p.tile % 2 == 0);
                assert!(
                    (p.tile, p.plane_chunk) <= *l,
                    "{:?} after {l:?}",
                    (p.tile, p.plane_chunk)
                );
                *l = (p.tile, p.plane_chunk);
            }
        }
        assert!(
            last[1].0 < 240 || last[1].1 < 5,
            "the budget never constrained net 1"
        );
        // Net 0 has the agreement prior: always all planes.
        assert_eq!(last[0].1, 5);
        let e = plan_inference(&model, &views, &reference, &depths, f16_fixed + 1000).unwrap_err();
        assert!(matches!(e, InferError::BudgetTooSmall { .. }));
    }

    /// Calibration of the memory estimate: peak RSS of a real inference against the estimate.
    /// `DEEPVIEW_MEASURE=images_8,32,TILE,f32|f16,CHUNK cargo test --release -p deepview-net -- --ignored \
    ///  measure_fern_peak --nocapture` (fern, views 1-4, the untrained `cpu` preset), or
    /// `DEEPVIEW_MEASURE=images_4,64,0,BUDGET_MIB` for the plan of a budget (`DEEPVIEW_MEASURE_PLAN_ONLY=1`:
    /// print the plan without running it).
    #[test]
    #[ignore]
    fn measure_fern_peak() {
        use deepview_data::{LoadOptions, data_dir, load_scene};
        use deepview_geometry::{ReferenceOptions, reference_camera};
        let Ok(spec) = std::env::var("DEEPVIEW_MEASURE") else {
            return;
        };
        let parts: Vec<&str> = spec.split(',').collect();
        let (images, planes, tile) = (
            parts[0].to_string(),
            parts[1].parse::<usize>().unwrap(),
            parts[2].parse::<usize>().unwrap(),
        );
        let precision = match parts.get(3) {
            Some(&"f16") => StatePrecision::F16,
            _ => StatePrecision::F32,
        };
        let chunk = parts.get(4).map_or(planes, |c| c.parse::<usize>().unwrap());
        let dev = Device::flex();
        let model = DeepViewModel::new(&DeepViewConfig::preset("cpu").unwrap(), &dev);
        let opts = LoadOptions {
            images: Some(images),
            ..Default::default()
        };
        let scene = load_scene(&data_dir().join("llff/fern"), &opts).unwrap();
        let (near, far) = scene.near_far().unwrap();
        let depths = plane_depths(near, far, planes, PlaneSpacing::InverseDepth).unwrap();
        let inputs = [1, 2, 3, 4];
        let cams: Vec<Camera> = inputs.iter().map(|&i| scene.views[i].camera).collect();
        let reference = reference_camera(
            &cams,
            &ReferenceOptions {
                cover: Some((near, far)),
                ..Default::default()
            },
        )
        .unwrap();
        let views: Vec<(ImageF32, Camera)> = inputs
            .iter()
            .map(|&i| (scene.load_image(i).unwrap().to_rgb(), scene.views[i].camera))
            .collect();
        drop(scene);
        let geom = Geometry::new(&views, &reference, &depths);
        let plan = if tile == 0 {
            let budget = parts
                .get(3)
                .map_or(3 << 30, |b| b.parse::<u64>().unwrap() << 20);
            plan_inference(&model, &views, &reference, &depths, budget).unwrap()
        } else {
            let mut plan = InferPlan::uniform(model.nets.len(), tile, chunk, precision);
            for (n, p) in plan.nets.iter_mut().enumerate() {
                p.fixed_bytes = fixed_bytes(&model, &geom, n, precision);
                p.tile_bytes = max_tile_bytes(&model, &geom, n, tile, chunk);
            }
            plan
        };
        println!("{plan:?}");
        // The largest view crop and MPI sub-window of the last net's tiles.
        let n = model.nets.len() - 1;
        let (mut crop, mut sub) = ((0, 0), (0, 0));
        for t in geom.tiles(plan.nets[n].tile) {
            for k in 0..views.len() {
                let win = geom.view_window(k, geom.region(t, model.margin(n)), n > 0);
                crop = crop.max((win.crop.2 * win.crop.3, win.crop.2));
                sub = sub.max((win.sub.2 * win.sub.3, win.sub.2));
            }
        }
        println!(
            "largest view crop {} px, MPI sub-window {} px",
            crop.0, sub.0
        );
        if std::env::var_os("DEEPVIEW_MEASURE_PLAN_ONLY").is_some() {
            return;
        }
        let hwm = || {
            let status = std::fs::read_to_string("/proc/self/status").unwrap();
            let line = status
                .lines()
                .find(|l| l.starts_with("VmHWM"))
                .unwrap()
                .to_string();
            line.split_whitespace()
                .nth(1)
                .unwrap()
                .parse::<u64>()
                .unwrap()
                * 1024
        };
        let before = hwm();
        let t0 = std::time::Instant::now();
        let mut tiles = 0;
        let mpi = infer_mpi_planned(&model, &views, &reference, &depths, &plan, &mut |p| {
            tiles = p.total
        })
        .unwrap();
        let secs = t0.elapsed().as_secs_f64();
        let peak = hwm();
        println!(
            "{}x{} x {planes} planes, {tiles} steps: {secs:.1} s; peak RSS {:.0} MiB (before {:.0}); \
             estimated peak {:.0} MiB",
            reference.width,
            reference.height,
            peak as f64 / 1048576.0,
            before as f64 / 1048576.0,
            plan.peak_bytes() as f64 / 1048576.0,
        );
        assert_eq!(mpi.layers.len(), planes * geom.w * geom.h * 4);
    }
}
