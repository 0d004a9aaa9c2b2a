//! Training tuples: K input views, a target view and a `crop x crop` crop in the target, plus exactly the
//! MPI window and input-image crops needed to render that crop (supplement, "Reducing Memory Usage").
//!
//! Sampling (one tuple):
//! 1. a scene uniformly; a target among its training views (LLFF/COLMAP/light fields: every 8th view,
//!    `index % 8 == 0`, is held out as an evaluation target and never used in training, neither as target
//!    nor as input; Spaces and synthetic scenes hold out nothing by default);
//! 2. the inputs: the K training views nearest to the target by camera centre (K drawn per batch);
//! 3. the reference camera: [`deepview_geometry::reference_camera`] of the inputs (centroid, average
//!    orientation and intrinsics) on the MPI grid inference uses with the model's weights (their
//!    `infer_mpi_scale` times the inputs' pixels along each axis; the prior's window grows with it);
//! 4. plane depths: `D` planes equally spaced in inverse depth between the scene's near and far, the whole
//!    grid shifted by a random offset of up to half a step (plane-depth jitter, paper section 4);
//! 5. a uniformly random `crop x crop` crop of the target image.
//!
//! The MPI window (in reference-camera pixels): project the target crop's corners through every plane
//! into the reference camera (`plane_homography(ref, target, d)^-1`), take the bounding box, add 1 px
//! for the bilinear taps of the final render, then grow it by the model's total receptive-field margin
//! ([`DeepViewConfig::margin_from`]`(0)`, the sum of every net's margin); the width and height are
//! rounded up to even numbers (U-Net nets downsample by 2). The model shrinks the window by each net's
//! margin after that net (`ModelInputs::shrink`), so its output is the bounding box and its values there
//! have no conv zero-padding effects.
//!
//! Input crops: the window's corners projected through every plane into input view k give the part of
//! that image the window sees; its bounding box grown by 2 px (bilinear taps, edge clamping), clipped to
//! the image, is the crop. Samples that fall outside the crop also fall outside the image, so plane sweep
//! volumes and validity are those of the whole image. (The gradient components render the views from the
//! current window only, the approximation documented in `network.rs`, unless
//! [`SampleConfig::window_context`] adds the tuple's [`ExampleContext`]: the region of the reference camera
//! the input crops' rays cross, clipped to the reference image, with its own input crops for the
//! agreement prior there.)

use crate::scene::{DataError, Holdout, TrainScene};
use deepview_geometry::{
    Camera, DVec2, PlaneSpacing, ReferenceOptions, plane_homography, reference_camera,
};
use deepview_image::ImageF32;
use deepview_net::config::DeepViewConfig;
use deepview_net::forward::{Hom, crop_output, crop_source};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// A small, serialisable random number generator (SplitMix64): its whole state is one `u64`, saved in
/// checkpoints so a resumed run draws the same tuples.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Rng {
    pub state: u64,
}

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self {
            state: seed ^ 0x5DEE_CE66_D1CE_4E5B,
        }
    }
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform integer in `0..n` (`n > 0`).
    pub fn below(&mut self, n: usize) -> usize {
        (self.uniform() * n as f64) as usize % n.max(1)
    }
}

/// How tuples are drawn (part of the run's `config.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleConfig {
    /// Target crop side in pixels (paper: 32).
    pub crop: usize,
    /// Number of input views, drawn per batch uniformly in `views_min..=views_max`.
    pub views_min: usize,
    pub views_max: usize,
    /// Planes during training.
    pub planes: usize,
    /// Random offset of the inverse-depth grid by up to half a step.
    pub jitter: bool,
    /// Plane count per tuple from its cameras by the inference rule (`--planes auto`,
    /// [`deepview_geometry::auto_plane_count`] between the tuple's reference and its inputs), at least
    /// [`deepview_geometry::AUTO_PLANES_MIN`] and at most `planes`. Off: always `planes`.
    pub auto_planes: bool,
    /// Colour and exposure jitter: one random exposure and per-channel gain for the whole tuple, plus a
    /// small exposure difference per input view (captures from phones and video change exposure).
    pub colour_jitter: bool,
    /// Probability that a tuple's K inputs are K random views among the target's 3K nearest training
    /// views instead of its K nearest: wider and uneven baselines, targets inside or beyond the inputs
    /// (like the Spaces quads or the demo's corner views). 0: always the K nearest.
    pub wide_inputs: f64,
    /// Probability that a tuple's K inputs surround the target (the case of rendering between the
    /// inputs, like the demo's four corners around its held-out views): the directions from the target
    /// to its 3K nearest training views (in the target camera's image plane) are split into K equal
    /// sectors at a random angle, and one random view is drawn from each sector. A target with an empty
    /// sector (outside the views around it: an edge or corner view of a grid) is redrawn, up to 64 times
    /// (then the empty sectors are filled from the rest of the pool). Drawn before `wide_inputs`; 0: never.
    pub surround_inputs: f64,
    /// Probability that a tuple's K inputs are spread over the whole capture, as in the few-shot
    /// literature's 3-view protocol (`train[round(i)] for i in linspace(0, n - 1, K)` of the training views
    /// in name order, each position jittered by up to a quarter of the spacing), and its target any other
    /// training view: sparse, wide inputs and targets both between and beyond them. Drawn before
    /// `surround_inputs`; 0: never (and in configs written before it existed).
    #[serde(default)]
    pub spread_inputs: f64,
    /// Render the views for the update nets' gradient components from the agreement prior outside the
    /// training window (with the window's state inside) instead of a transparent MPI there: the rays of
    /// wide inputs leave the window, which inference never sees (`deepview_net::network` module docs).
    pub window_context: bool,
    /// The memory a tuple's training step may take (`train --max-memory`), set for each session by the
    /// trainer and not kept in config.json (it is the machine's, not the run's). A tuple whose estimated
    /// step ([`step_bytes`]) is over it gets fewer planes (down to [`deepview_geometry::AUTO_PLANES_MIN`]),
    /// or is drawn again when even those do not fit. Tuples within it are drawn exactly as without it.
    #[serde(skip)]
    pub budget: Option<StepBudget>,
}

/// The memory bound of one training step ([`SampleConfig::budget`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepBudget {
    /// Bytes the step may take (model, optimizer, loss network and the tuple's activations; the
    /// loaded datasets are not counted: the trainer's caller gives what its budget leaves after them).
    pub bytes: u64,
    /// Whether the nets recompute their activations in the backward pass (only one net's are held).
    pub recompute: bool,
}

/// Tuples drawn before [`TrainData::sample`] gives up on fitting one into [`SampleConfig::budget`].
pub const BUDGET_TRIES: usize = 64;

/// Estimated peak bytes of a training step (forward and backward) on one tuple of `views` inputs and
/// `planes` planes whose MPI window has `window_px` pixels, on the CPU: what a step holds whatever the
/// tuple (the runtime, the VGG loss on the target crop, and 64 bytes per parameter: weights, gradients,
/// Adam's two moments and the step's copies of them), plus per plane pixel of the window
/// `(views + 0.8) x (100 + 25 F)` bytes, where `F` sums the feature counts of the nets whose activations
/// are held for the backward pass (all of them; only the largest with `recompute`), each weighted by its
/// depth, `(4 + max-pool stages) / 5`, and by a quarter for a U-Net net (half resolution): the
/// plane-sweep volumes and per-view inputs, each view's conv activations and their gradients, and the
/// state and rendered components per plane (the 0.8). The loaded datasets come on top. Fitted to the peak RSS of `deepview bench train` (BENCHMARKS.md,
/// "Training memory": the `cpu`, `cpu-large` and `paper-kalantari` presets within 5%; the U-Net weight
/// is not measured).
pub fn step_bytes(
    model: &DeepViewConfig,
    views: usize,
    planes: usize,
    window_px: usize,
    recompute: bool,
) -> u64 {
    let depth = (4 + model.max_pool_stages) as f64 / 5.0;
    let weight =
        |n: usize| model.features(n) as f64 * depth * if model.unet(n) { 0.25 } else { 1.0 };
    let nets = 0..model.updates + 1;
    let f = if recompute {
        nets.map(weight).fold(0.0, f64::max)
    } else {
        nets.map(weight).sum()
    };
    let params = deepview_net::weights::parameter_count(model).unwrap_or(u128::MAX);
    let fixed = (STEP_BASE_BYTES as u128).saturating_add(params.saturating_mul(64));
    let plane_px = planes as f64 * window_px as f64;
    let tuple = plane_px * (views as f64 + 0.8) * (100.0 + 25.0 * f);
    (fixed.min(u64::MAX as u128) as u64).saturating_add(tuple as u64)
}

/// [`step_bytes`]'s fixed part besides the parameters.
pub const STEP_BASE_BYTES: u64 = 32 << 20;

/// What [`TrainData::tuple_window`] finds.
struct TupleWindow {
    reference: Camera,
    ref_to_target: Vec<Hom>,
    /// Top-left (reference pixels) and even size.
    window: (f64, f64, usize, usize),
}

/// Targets drawn for a surrounded tuple before one with its inputs around it is accepted.
const SURROUND_TRIES: usize = 64;

/// Colour jitter ranges (natural-log units): whole-tuple exposure, per-channel gain, per-input exposure.
const EXPOSURE_LOG: f64 = 0.3;
const CHANNEL_LOG: f64 = 0.1;
const VIEW_LOG: f64 = 0.05;

fn scale_clamped(img: &mut ImageF32, gains: [f32; 3]) {
    let c = img.channels;
    for px in img.data.chunks_exact_mut(c) {
        for (v, g) in px.iter_mut().zip(gains) {
            *v = (*v * g).clamp(0.0, 1.0);
        }
    }
}

/// One training tuple, device-free (plain `f32` data).
#[derive(Clone, Debug)]
pub struct Example {
    pub scene: usize,
    pub target: usize,
    pub inputs: Vec<usize>,
    pub depths: Vec<f64>,
    /// Input image crops (RGB, interleaved).
    pub images: Vec<ImageF32>,
    /// Top-left of each input crop in its full image.
    pub image_origins: Vec<(u32, u32)>,
    /// `mpi_to_view[k][d]`: MPI-window pixels of plane d -> pixels of `images[k]`.
    pub mpi_to_view: Vec<Vec<Hom>>,
    /// The window: top-left in reference pixels and size.
    pub window: (i64, i64, usize, usize),
    /// `window_to_target[d]`: MPI-window pixels of plane d -> target-crop pixels.
    pub window_to_target: Vec<Hom>,
    /// Target crop (RGB, interleaved, `crop x crop`) and its top-left in the target image.
    pub target_crop: ImageF32,
    pub crop_origin: (u32, u32),
    /// The MPI around the window that the input crops' rays cross ([`SampleConfig::window_context`]).
    pub context: Option<ExampleContext>,
    /// The prior's aggregation radius on this tuple's images (`DeepViewConfig::prior_radius_at` of the
    /// largest side among them; its window's margins are the model's at this radius); `None`: the
    /// model's own.
    pub prior_radius: Option<usize>,
}

impl Example {
    /// [`step_bytes`] of this tuple: its inputs, planes and window.
    pub fn step_bytes(&self, model: &DeepViewConfig, recompute: bool) -> u64 {
        step_bytes(
            model,
            self.inputs.len(),
            self.depths.len(),
            self.window.2 * self.window.3,
            recompute,
        )
    }
}

/// The region of the reference camera around a tuple's window that the rays of its input crops cross
/// (see `deepview_net::network::WindowContext`), with the input crops that region sees.
#[derive(Clone, Debug)]
pub struct ExampleContext {
    pub images: Vec<ImageF32>,
    /// `mpi_to_view[k][d]`: context pixels of plane d -> pixels of `images[k]`.
    pub mpi_to_view: Vec<Vec<Hom>>,
    pub width: usize,
    pub height: usize,
    /// Top-left of the window in context pixels.
    pub origin: (usize, usize),
}

/// All training scenes.
#[derive(Clone, Debug, Default)]
pub struct TrainData {
    pub scenes: Vec<TrainScene>,
    /// Procedural scenes made on the fly (`--data synthetic:procedural`), if any.
    pub procedural: Option<Procedural>,
}

/// [`Example::scene`] of a tuple drawn from a procedural scene.
pub const PROCEDURAL_SCENE: usize = usize::MAX;

/// Procedural 3D scenes ([`deepview_synth::procedural`]) made for each tuple from a seed drawn from the
/// run's generator (so a resumed run draws the same ones), textured with crops of the training views of
/// the dataset scenes (never a held-out view).
#[derive(Clone, Debug)]
pub struct Procedural {
    /// Share of the tuples drawn from procedural scenes when there are dataset scenes too.
    pub share: f64,
    /// Size and sampling of each scene.
    pub options: deepview_synth::procedural::ProceduralOptions,
}

impl Default for Procedural {
    fn default() -> Self {
        Self {
            share: 0.5,
            options: Default::default(),
        }
    }
}

/// Plane depths, back to front, with an optional jitter `u` in [-0.5, 0.5] steps of inverse depth.
pub fn jittered_depths(near: f64, far: f64, planes: usize, u: f64) -> Vec<f64> {
    if planes <= 1 {
        return deepview_geometry::plane_depths(
            near,
            far,
            planes.max(1),
            PlaneSpacing::InverseDepth,
        )
        .unwrap_or_else(|_| vec![0.5 * (near + far)]);
    }
    let step = (1.0 / near - 1.0 / far) / (planes - 1) as f64;
    // Keep the farthest plane at a positive inverse depth.
    let u = u.clamp(-0.5, 0.5).max(-0.9 / (far * step));
    (0..planes)
        .map(|i| 1.0 / (1.0 / far + (i as f64 + u) * step))
        .collect()
}

fn bbox(points: impl IntoIterator<Item = DVec2>) -> Option<(f64, f64, f64, f64)> {
    let mut b = (
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    );
    for p in points {
        if !p.is_finite() {
            return None;
        }
        b = (b.0.min(p.x), b.1.min(p.y), b.2.max(p.x), b.3.max(p.y));
    }
    Some(b)
}

fn apply(h: &Hom, x: f64, y: f64) -> Option<DVec2> {
    let w = h[6] * x + h[7] * y + h[8];
    if w <= 0.0 {
        return None;
    }
    Some(DVec2::new(
        (h[0] * x + h[1] * y + h[2]) / w,
        (h[3] * x + h[4] * y + h[5]) / w,
    ))
}

/// A tuple whose inputs face 90 degrees or more apart (a wide or 360-degree capture's spread
/// inputs) makes no MPI: a miss (`None`), drawn again, not an error that stops the run.
fn facing_apart_is_a_miss<T>(r: Result<T, DataError>) -> Result<Option<T>, DataError> {
    match r {
        Ok(v) => Ok(Some(v)),
        Err(DataError::Geometry {
            source: deepview_geometry::GeometryError::FacingApart { .. },
            ..
        }) => Ok(None),
        Err(e) => Err(e),
    }
}

impl TrainData {
    pub fn new(scenes: Vec<TrainScene>) -> Result<Self, DataError> {
        if scenes.is_empty() {
            return Err(DataError::Empty("no scenes given".into()));
        }
        Ok(Self {
            scenes,
            procedural: None,
        })
    }

    /// Dataset scenes (possibly none) and procedural scenes made on the fly.
    pub fn with_procedural(scenes: Vec<TrainScene>, procedural: Procedural) -> Self {
        Self {
            scenes,
            procedural: Some(procedural),
        }
    }

    /// How the procedural scenes join the data, for a run's first line ("" without them).
    pub fn procedural_note(&self) -> String {
        match &self.procedural {
            Some(_) if self.scenes.is_empty() => {
                " (every tuple from a new procedural scene)".into()
            }
            Some(p) => format!(
                " plus a new procedural scene for {:.0}% of the tuples",
                100.0 * p.share
            ),
            None => String::new(),
        }
    }

    /// The name of the scene of a tuple ([`Example::scene`]).
    pub fn scene_name(&self, scene: usize) -> &str {
        match self.scenes.get(scene) {
            Some(s) => &s.name,
            None => crate::scene::SYNTHETIC_PROCEDURAL,
        }
    }

    /// The photos procedural scenes take their textures from: the training views of the dataset scenes
    /// (never a held-out view).
    pub fn texture_photos(&self) -> Vec<&ImageF32> {
        self.scenes
            .iter()
            .flat_map(|s| s.train_views.iter().map(|&v| &s.images[v]))
            .collect()
    }

    /// A procedural scene from `seed` with enough views for `views` inputs and a target.
    pub fn procedural_scene(&self, seed: u64, views: usize) -> Result<TrainScene, DataError> {
        let p = self.procedural.clone().unwrap_or_default();
        let photos = self.texture_photos();
        let options = deepview_synth::procedural::ProceduralOptions {
            min_views: p.options.min_views.max(views + 2),
            ..p.options
        };
        let g = deepview_synth::procedural::generate(seed, &photos, &options);
        TrainScene::new(
            &format!("{}#{seed}", crate::scene::SYNTHETIC_PROCEDURAL),
            g.cameras,
            g.images,
            g.near,
            g.far,
            Holdout::Nothing,
        )
    }

    /// Load several dataset folders.
    pub fn load(
        paths: &[PathBuf],
        opts: &deepview_data::LoadOptions,
        holdout_every: usize,
    ) -> Result<Self, DataError> {
        Self::new(
            paths
                .iter()
                .map(|p| TrainScene::load(p, opts, holdout_every))
                .collect::<Result<_, _>>()?,
        )
    }

    /// Draw the number of input views for a batch.
    pub fn draw_views(&self, cfg: &SampleConfig, rng: &mut Rng) -> usize {
        let lo = cfg.views_min.max(1);
        let hi = cfg.views_max.max(lo);
        lo + rng.below(hi - lo + 1)
    }

    /// Draw one tuple with `views` inputs (fewer if the scene has fewer training views), within
    /// [`SampleConfig::budget`] when there is one.
    pub fn sample(
        &self,
        cfg: &SampleConfig,
        model: &DeepViewConfig,
        views: usize,
        rng: &mut Rng,
    ) -> Result<Example, DataError> {
        for _ in 0..BUDGET_TRIES {
            if let Some(ex) = self.sample_once(cfg, model, views, rng)? {
                return Ok(ex);
            }
        }
        let b = cfg.budget.map_or(0, |b| b.bytes);
        let names: Vec<&str> = self.scenes.iter().map(|s| s.name.as_str()).collect();
        Err(DataError::Invalid {
            path: PathBuf::from(names.join(", ")),
            message: format!(
                "none of {BUDGET_TRIES} tuples drawn fits a training step into the memory budget of \
                 {} MiB, even with {} planes: raise --max-memory, or lower --max-width or --crop",
                b >> 20,
                deepview_geometry::AUTO_PLANES_MIN.min(cfg.planes)
            ),
        })
    }

    /// One draw of [`Self::sample`]: `None` when the tuple does not fit the budget with the fewest planes.
    fn sample_once(
        &self,
        cfg: &SampleConfig,
        model: &DeepViewConfig,
        views: usize,
        rng: &mut Rng,
    ) -> Result<Option<Example>, DataError> {
        if let Some(p) = &self.procedural
            && (self.scenes.is_empty() || rng.uniform() < p.share)
        {
            let seed = rng.next_u64();
            let one = TrainData::new(vec![self.procedural_scene(seed, views)?])?;
            let ex = one.sample_once(cfg, model, views, rng)?;
            return Ok(ex.map(|mut ex| {
                ex.scene = PROCEDURAL_SCENE;
                ex
            }));
        }
        let si = rng.below(self.scenes.len());
        let s = &self.scenes[si];
        let mut target = s.train_views[rng.below(s.train_views.len())];
        let u = if cfg.jitter { rng.uniform() - 0.5 } else { 0.0 };
        let inputs = if cfg.spread_inputs > 0.0 && rng.uniform() < cfg.spread_inputs {
            let (inputs, t) = self.spread_inputs(si, views.max(1), rng);
            target = t;
            inputs
        } else if cfg.surround_inputs > 0.0 && rng.uniform() < cfg.surround_inputs {
            // A target with an empty sector lies outside its inputs (an edge or corner view of a grid):
            // that is extrapolation, not rendering between the inputs, so another target is drawn.
            let mut drawn = self.surrounding_inputs(si, target, views.max(1), rng);
            for _ in 0..SURROUND_TRIES {
                if drawn.1 {
                    break;
                }
                target = s.train_views[rng.below(s.train_views.len())];
                drawn = self.surrounding_inputs(si, target, views.max(1), rng);
            }
            drawn.0
        } else if cfg.wide_inputs > 0.0 && rng.uniform() < cfg.wide_inputs {
            let mut pool = self.nearest_inputs(si, target, 3 * views.max(1));
            // A uniformly random K-subset (partial Fisher-Yates), in pool order.
            let k = views.max(1).min(pool.len());
            for i in 0..k {
                let j = i + rng.below(pool.len() - i);
                pool.swap(i, j);
            }
            pool.truncate(k);
            pool
        } else {
            self.nearest_inputs(si, target, views)
        };
        let planes = if cfg.auto_planes {
            let Some(p) = facing_apart_is_a_miss(self.auto_planes_for(si, &inputs))? else {
                return Ok(None);
            };
            p.clamp(
                deepview_geometry::AUTO_PLANES_MIN.min(cfg.planes),
                cfg.planes,
            )
        } else {
            cfg.planes
        };
        let mut depths = jittered_depths(s.near, s.far, planes, u);
        let tcam = &s.cameras[target];
        // The model as it runs on this tuple's images (the prior's radius grows on large ones; the
        // largest side of any of them, as inference measures its inputs).
        let size = inputs
            .iter()
            .chain(std::iter::once(&target))
            .map(|&i| s.cameras[i].width.max(s.cameras[i].height))
            .max()
            .unwrap_or(0);
        // On the MPI grid inference uses with these weights (`infer_mpi_scale`: the prior's window
        // grows with it as at inference), so the nets learn on the samples they will be given.
        let scale = model.infer_mpi_scale.unwrap_or(1.0);
        let mut sized = model.at_image_size(size);
        sized.prior_radius = model.prior_radius_on(size, scale);
        let model = &sized;
        let c = cfg.crop as u32;
        if tcam.width < c || tcam.height < c {
            return Err(DataError::Invalid {
                path: s.name.clone().into(),
                message: format!(
                    "view {target} ({}x{}) is smaller than the {c}x{c} crop",
                    tcam.width, tcam.height
                ),
            });
        }
        let cx0 = rng.below((tcam.width - c + 1) as usize) as u32;
        let cy0 = rng.below((tcam.height - c + 1) as usize) as u32;
        if let Some(b) = cfg.budget {
            let fewest = deepview_geometry::AUTO_PLANES_MIN.min(cfg.planes);
            let mut d = planes;
            loop {
                let Some(tw) = facing_apart_is_a_miss(self.tuple_window(
                    si,
                    target,
                    &inputs,
                    &depths,
                    (cx0, cy0),
                    cfg.crop,
                    model.margin_from(0),
                    scale,
                ))?
                else {
                    return Ok(None);
                };
                let need = step_bytes(
                    model,
                    inputs.len(),
                    d,
                    tw.window.2 * tw.window.3,
                    b.recompute,
                );
                if need <= b.bytes {
                    break;
                }
                if d <= fewest {
                    return Ok(None);
                }
                // The activations grow in proportion to the planes; the window hardly changes.
                let base = STEP_BASE_BYTES.min(b.bytes);
                let scaled =
                    (d as u128 * (b.bytes - base) as u128 / (need - base).max(1) as u128) as usize;
                d = scaled.clamp(fewest, d - 1);
                depths = jittered_depths(s.near, s.far, d, u);
            }
        }
        let Some(mut ex) = facing_apart_is_a_miss(self.example_with_inputs(
            si,
            target,
            inputs,
            depths,
            (cx0, cy0),
            cfg.crop,
            model.margin_from(0),
            cfg.window_context && model.updates > 0,
            scale,
        ))?
        else {
            return Ok(None);
        };
        ex.prior_radius = Some(model.prior_radius);
        if cfg.colour_jitter {
            let mut log_uniform = |r: f64| ((rng.uniform() * 2.0 - 1.0) * r).exp();
            let e = log_uniform(EXPOSURE_LOG);
            let g: [f64; 3] = std::array::from_fn(|_| e * log_uniform(CHANNEL_LOG));
            let views: Vec<f64> = (0..ex.images.len())
                .map(|_| log_uniform(VIEW_LOG))
                .collect();
            scale_clamped(&mut ex.target_crop, g.map(|v| v as f32));
            for (k, v) in views.into_iter().enumerate() {
                let gains = g.map(|x| (x * v) as f32);
                scale_clamped(&mut ex.images[k], gains);
                if let Some(c) = ex.context.as_mut() {
                    scale_clamped(&mut c.images[k], gains);
                }
            }
        }
        Ok(Some(ex))
    }

    /// K training views spread over the capture and a target among the others
    /// ([`SampleConfig::spread_inputs`]).
    fn spread_inputs(&self, si: usize, k: usize, rng: &mut Rng) -> (Vec<usize>, usize) {
        let s = &self.scenes[si];
        let n = s.train_views.len();
        if n <= k {
            // Too few views to leave a target out: the nearest rule's tuple.
            let target = s.train_views[rng.below(n)];
            return (self.nearest_inputs(si, target, k), target);
        }
        let spacing = (n - 1) as f64 / (k.max(2) - 1) as f64;
        let mut picks: Vec<usize> = (0..k)
            .map(|i| {
                let at = if k == 1 {
                    (n - 1) as f64 / 2.0
                } else {
                    i as f64 * spacing
                };
                let jitter = (rng.uniform() - 0.5) * 0.5 * spacing;
                (at + jitter).round().clamp(0.0, (n - 1) as f64) as usize
            })
            .collect();
        picks.sort_unstable();
        picks.dedup();
        // Positions that collided: random free ones instead.
        let mut free: Vec<usize> = (0..n).filter(|p| !picks.contains(p)).collect();
        while picks.len() < k {
            let j = rng.below(free.len());
            picks.push(free.swap_remove(j));
        }
        picks.sort_unstable();
        let others: Vec<usize> = (0..n).filter(|p| !picks.contains(p)).collect();
        let target = s.train_views[others[rng.below(others.len())]];
        (
            picks.into_iter().map(|p| s.train_views[p]).collect(),
            target,
        )
    }

    /// K views around `target` ([`SampleConfig::surround_inputs`]), in pool order of distance, and whether
    /// every sector held one (false: the target lies outside the views around it; the empty sectors were
    /// filled from the rest of the pool).
    fn surrounding_inputs(
        &self,
        si: usize,
        target: usize,
        k: usize,
        rng: &mut Rng,
    ) -> (Vec<usize>, bool) {
        let s = &self.scenes[si];
        let pool = self.nearest_inputs(si, target, 3 * k);
        if pool.len() <= k {
            return (pool, false);
        }
        let tcam = s.cameras[target];
        let turn = std::f64::consts::TAU;
        let rot = rng.uniform() * turn;
        // Sector of each pool view: the angle of its centre seen from the target, in the target camera's
        // x/y plane (forward-facing captures spread their cameras there).
        let sector: Vec<usize> = pool
            .iter()
            .map(|&v| {
                let d = tcam.pose.rotation * (s.cameras[v].center() - tcam.center());
                let a = (d.y.atan2(d.x) - rot).rem_euclid(turn);
                ((a / turn * k as f64) as usize).min(k - 1)
            })
            .collect();
        let mut chosen: Vec<usize> = Vec::with_capacity(k);
        for q in 0..k {
            let members: Vec<usize> = (0..pool.len()).filter(|&i| sector[i] == q).collect();
            if !members.is_empty() {
                chosen.push(members[rng.below(members.len())]);
            }
        }
        let enclosed = chosen.len() == k;
        // Empty sectors: random views from the rest of the pool.
        while chosen.len() < k {
            let rest: Vec<usize> = (0..pool.len()).filter(|i| !chosen.contains(i)).collect();
            chosen.push(rest[rng.below(rest.len())]);
        }
        chosen.sort();
        (chosen.into_iter().map(|i| pool[i]).collect(), enclosed)
    }

    /// The K training views nearest to `target` by camera centre (ties broken by index), K = `views`.
    fn nearest_inputs(&self, si: usize, target: usize, views: usize) -> Vec<usize> {
        let s = &self.scenes[si];
        let tcam = s.cameras[target];
        let mut others: Vec<(f64, usize)> = s
            .train_views
            .iter()
            .filter(|&&v| v != target)
            .map(|&v| ((s.cameras[v].center() - tcam.center()).length(), v))
            .collect();
        others.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        others.iter().take(views.max(1)).map(|x| x.1).collect()
    }

    /// The inference plane rule ([`deepview_geometry::auto_plane_count`] in
    /// [`deepview_geometry::mpi_reference`]) for these input views of scene `si`: the count
    /// `infer --planes auto` uses for them (before the memory clamp).
    fn auto_planes_for(&self, si: usize, inputs: &[usize]) -> Result<usize, DataError> {
        let s = &self.scenes[si];
        let cams: Vec<Camera> = inputs.iter().map(|&i| s.cameras[i]).collect();
        let reference =
            deepview_geometry::mpi_reference(&cams, (s.near, s.far)).map_err(|source| {
                DataError::Geometry {
                    scene: s.name.clone(),
                    source,
                }
            })?;
        Ok(deepview_geometry::auto_plane_count(
            &reference,
            &cams,
            s.near,
            s.far,
            deepview_geometry::AUTO_MAX_SPACING_PX,
        ))
    }

    /// Build the tuple for a given scene, target, input count, plane depths and target crop, on the
    /// inputs' grid (MPI scale 1).
    pub fn example(
        &self,
        si: usize,
        target: usize,
        views: usize,
        depths: Vec<f64>,
        crop_origin: (u32, u32),
        crop: usize,
        margin: usize,
    ) -> Result<Example, DataError> {
        let inputs = self.nearest_inputs(si, target, views);
        self.example_with_inputs(
            si,
            target,
            inputs,
            depths,
            crop_origin,
            crop,
            margin,
            false,
            1.0,
        )
    }

    /// The reference camera of `inputs` (`scale` times their pixels along each axis: the MPI grid of
    /// [`ReferenceOptions::scale`]), the homographies from it to the target on each plane, and the
    /// tuple's MPI window (top-left and even size in reference pixels; module docs): what a tuple's
    /// memory depends on, found before its input crops are made.
    #[allow(clippy::too_many_arguments)]
    fn tuple_window(
        &self,
        si: usize,
        target: usize,
        inputs: &[usize],
        depths: &[f64],
        crop_origin: (u32, u32),
        crop: usize,
        margin: usize,
        scale: f64,
    ) -> Result<TupleWindow, DataError> {
        let s = &self.scenes[si];
        let geo = |source| DataError::Geometry {
            scene: s.name.clone(),
            source,
        };
        let tcam = s.cameras[target];
        let in_cams: Vec<Camera> = inputs.iter().map(|&i| s.cameras[i]).collect();
        let reference = reference_camera(
            &in_cams,
            &ReferenceOptions {
                scale,
                ..Default::default()
            },
        )
        .map_err(geo)?;

        // Window: target crop corners through every plane into the reference camera.
        let (cx0, cy0) = (crop_origin.0 as f64, crop_origin.1 as f64);
        let cf = crop as f64;
        let corners = [
            (cx0, cy0),
            (cx0 + cf, cy0),
            (cx0, cy0 + cf),
            (cx0 + cf, cy0 + cf),
        ];
        let ref_to_target: Vec<Hom> = depths
            .iter()
            .map(|&d| plane_homography(&reference, &tcam, d).to_row_major())
            .collect();
        let mut pts = Vec::new();
        for h in &ref_to_target {
            let inv = deepview_net::forward::invert(h);
            for &(x, y) in &corners {
                pts.push(apply(&inv, x, y).unwrap_or(DVec2::NAN));
            }
        }
        let invalid = |message: String| DataError::Invalid {
            path: s.name.clone().into(),
            message,
        };
        let (bx0, by0, bx1, by1) = bbox(pts).ok_or_else(|| {
            invalid(format!("the target view {target}'s crop is not visible on every plane from the reference camera"))
        })?;
        let m = margin as f64 + 1.0;
        let (wx0, wy0) = ((bx0 - m).floor(), (by0 - m).floor());
        let (mut ww, mut wh) = (
            ((bx1 + m).ceil() - wx0) as usize,
            ((by1 + m).ceil() - wy0) as usize,
        );
        ww += ww % 2;
        wh += wh % 2;
        if ww * wh > 4096 * 4096 {
            return Err(invalid(format!(
                "MPI window of {ww}x{wh} px for one crop: depth bounds too wide?"
            )));
        }
        Ok(TupleWindow {
            reference,
            ref_to_target,
            window: (wx0, wy0, ww, wh),
        })
    }

    /// [`Self::example`] with the input views given, on an MPI grid `scale` times the inputs' (the
    /// weights' `infer_mpi_scale` in training; [`ReferenceOptions::scale`]).
    #[allow(clippy::too_many_arguments)]
    pub fn example_with_inputs(
        &self,
        si: usize,
        target: usize,
        inputs: Vec<usize>,
        depths: Vec<f64>,
        crop_origin: (u32, u32),
        crop: usize,
        margin: usize,
        with_context: bool,
        scale: f64,
    ) -> Result<Example, DataError> {
        let s = &self.scenes[si];
        let tw = self.tuple_window(
            si,
            target,
            &inputs,
            &depths,
            crop_origin,
            crop,
            margin,
            scale,
        )?;
        let (reference, ref_to_target) = (tw.reference, tw.ref_to_target);
        let (wx0, wy0, ww, wh) = tw.window;
        let (cx0, cy0) = (crop_origin.0 as f64, crop_origin.1 as f64);

        // Input crops: what the window sees on all planes.
        let mut images = Vec::with_capacity(inputs.len());
        let mut image_origins = Vec::with_capacity(inputs.len());
        let mut mpi_to_view = Vec::with_capacity(inputs.len());
        for &v in &inputs {
            let (img, origin, homs) = input_crop(
                &s.images[v],
                &s.cameras[v],
                &reference,
                &depths,
                (wx0, wy0),
                (ww, wh),
            );
            images.push(img);
            image_origins.push(origin);
            mpi_to_view.push(homs);
        }
        let context = if with_context {
            Some(window_context(
                s,
                &inputs,
                &reference,
                &depths,
                (wx0, wy0, ww, wh),
                &images,
                &mpi_to_view,
            ))
        } else {
            None
        };
        let window_to_target = ref_to_target
            .iter()
            .map(|h| crop_source(&crop_output(h, wx0, wy0), cx0, cy0))
            .collect();
        let target_crop =
            s.images[target].crop(crop_origin.0, crop_origin.1, crop as u32, crop as u32);
        Ok(Example {
            scene: si,
            target,
            inputs,
            depths,
            images,
            image_origins,
            mpi_to_view,
            window: (wx0 as i64, wy0 as i64, ww, wh),
            window_to_target,
            target_crop,
            crop_origin,
            context,
            prior_radius: None,
        })
    }
}

/// The crop of input `image` (camera `cam`) that a region of the reference camera (`origin`, `size` in
/// reference pixels) sees on every plane, its top-left in the image, and the homographies from region
/// pixels of each plane to crop pixels. The bounding box of the projected region corners grows by 2 px
/// (bilinear taps, edge clamping) and is clipped to the image, so samples outside the crop are also
/// outside the image.
fn input_crop(
    image: &ImageF32,
    cam: &Camera,
    reference: &Camera,
    depths: &[f64],
    (x0, y0): (f64, f64),
    (ww, wh): (usize, usize),
) -> (ImageF32, (u32, u32), Vec<Hom>) {
    let homs: Vec<Hom> = depths
        .iter()
        .map(|&d| crop_output(&plane_homography(reference, cam, d).to_row_major(), x0, y0))
        .collect();
    let (w, h) = (cam.width as f64, cam.height as f64);
    let mut pts = Vec::new();
    for hm in &homs {
        for (x, y) in [
            (0.0, 0.0),
            (ww as f64, 0.0),
            (0.0, wh as f64),
            (ww as f64, wh as f64),
        ] {
            pts.push(apply(hm, x, y).unwrap_or(DVec2::NAN));
        }
    }
    let (ix0, iy0, ix1, iy1) = match bbox(pts) {
        Some((x0, y0, x1, y1)) => {
            let x0 = ((x0 - 2.0).floor().max(0.0)).min(w - 1.0);
            let y0 = ((y0 - 2.0).floor().max(0.0)).min(h - 1.0);
            (
                x0,
                y0,
                (x1 + 2.0).ceil().min(w).max(x0 + 1.0),
                (y1 + 2.0).ceil().min(h).max(y0 + 1.0),
            )
        }
        None => (0.0, 0.0, w, h),
    };
    let (ix0, iy0, iw, ih) = (
        ix0 as u32,
        iy0 as u32,
        (ix1 - ix0) as u32,
        (iy1 - iy0) as u32,
    );
    let homs = homs
        .iter()
        .map(|hm| crop_source(hm, ix0 as f64, iy0 as f64))
        .collect();
    (image.crop(ix0, iy0, iw, ih), (ix0, iy0), homs)
}

/// The window's context ([`ExampleContext`]): the region of the reference camera crossed, on some
/// plane, by the rays of the window's input crops (`crops`, with `homs` from window pixels), clipped to
/// the reference image but always containing the window, at most the window grown by its own size on
/// every side; and the input crops that region sees.
fn window_context(
    s: &TrainScene,
    inputs: &[usize],
    reference: &Camera,
    depths: &[f64],
    (wx0, wy0, ww, wh): (f64, f64, usize, usize),
    crops: &[ImageF32],
    homs: &[Vec<Hom>],
) -> ExampleContext {
    let (wwf, whf) = (ww as f64, wh as f64);
    let mut b = (0.0f64, 0.0f64, wwf, whf);
    for (crop, hv) in crops.iter().zip(homs) {
        let (cw, ch) = (crop.width as f64, crop.height as f64);
        for hm in hv {
            let inv = deepview_net::forward::invert(hm);
            for (x, y) in [(0.0, 0.0), (cw, 0.0), (0.0, ch), (cw, ch)] {
                if let Some(p) = apply(&inv, x, y) {
                    b = (b.0.min(p.x), b.1.min(p.y), b.2.max(p.x), b.3.max(p.y));
                }
            }
        }
    }
    // Window pixels: the reference image is [-wx0, rw - wx0) x [-wy0, rh - wy0).
    let (rx0, ry0) = (-wx0, -wy0);
    let (rx1, ry1) = (reference.width as f64 - wx0, reference.height as f64 - wy0);
    let lo = |v: f64, r: f64, cap: f64| (v - 1.0).max(r).max(-cap).min(0.0).floor();
    let hi = |v: f64, r: f64, size: f64| (v + 1.0).min(r).min(2.0 * size).max(size).ceil();
    let (x0, y0) = (lo(b.0, rx0, wwf), lo(b.1, ry0, whf));
    let (x1, y1) = (hi(b.2, rx1, wwf), hi(b.3, ry1, whf));
    let (cw, ch) = ((x1 - x0) as usize, (y1 - y0) as usize);
    let (cx0, cy0) = (wx0 + x0, wy0 + y0);
    let mut images = Vec::with_capacity(inputs.len());
    let mut mpi_to_view = Vec::with_capacity(inputs.len());
    for &v in inputs {
        let (img, _, hv) = input_crop(
            &s.images[v],
            &s.cameras[v],
            reference,
            depths,
            (cx0, cy0),
            (cw, ch),
        );
        images.push(img);
        mpi_to_view.push(hv);
    }
    ExampleContext {
        images,
        mpi_to_view,
        width: cw,
        height: ch,
        origin: ((-x0) as usize, (-y0) as usize),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::two_plane_scene;

    /// The tests' tuple settings: `views` inputs, `planes` planes, 16 px crops with jitter, no colour
    /// jitter, the nearest inputs; each test overrides what it is about.
    fn test_sample(views: std::ops::RangeInclusive<usize>, planes: usize) -> SampleConfig {
        SampleConfig {
            crop: 16,
            views_min: *views.start(),
            views_max: *views.end(),
            planes,
            jitter: true,
            auto_planes: false,
            colour_jitter: false,
            wide_inputs: 0.0,
            surround_inputs: 0.0,
            spread_inputs: 0.0,
            window_context: false,
            budget: None,
        }
    }

    /// A model whose weights make their MPIs on a finer grid (`infer_mpi_scale`) trains on that grid: the
    /// same tuple's window holds about `scale` times the pixels along each axis, and the prior's window
    /// grows with the grid as at inference.
    #[test]
    fn tuples_take_the_weights_mpi_grid() {
        let data = TrainData::new(vec![two_plane_scene(3, 3, 48, 0.15)]).unwrap();
        let cfg = test_sample(4..=4, 8);
        let base = DeepViewConfig {
            prior_radius: 2,
            infer_mpi_scale: None,
            ..DeepViewConfig::preset("cpu").unwrap()
        };
        let fine = DeepViewConfig {
            infer_mpi_scale: Some(1.5),
            ..base.clone()
        };
        let tuple = |model: &DeepViewConfig| {
            let mut rng = Rng::new(3);
            let k = data.draw_views(&cfg, &mut rng);
            data.sample(&cfg, model, k, &mut rng).unwrap()
        };
        let (a, b) = (tuple(&base), tuple(&fine));
        assert_eq!(
            (a.target, &a.inputs, a.crop_origin),
            (b.target, &b.inputs, b.crop_origin)
        );
        // The window is the crop's footprint plus the nets' margin and a pixel on each side.
        let m = 2 * (base.margin_from(0) + 1);
        for (wa, wb) in [(a.window.2, b.window.2), (a.window.3, b.window.3)] {
            let ratio = (wb - m) as f64 / (wa - m) as f64;
            assert!(
                (1.35..=1.65).contains(&ratio),
                "window {wa} -> {wb}: {ratio}"
            );
        }
        assert_eq!(a.prior_radius, Some(2));
        assert_eq!(b.prior_radius, Some(3));
    }

    #[test]
    fn jitter_keeps_spacing_and_bounds() {
        let d = jittered_depths(1.0, 10.0, 5, 0.0);
        assert!((d[0] - 10.0).abs() < 1e-9 && (d[4] - 1.0).abs() < 1e-9);
        let j = jittered_depths(1.0, 10.0, 5, 0.5);
        let step = (1.0 - 0.1) / 4.0;
        for (a, b) in d.iter().zip(&j) {
            assert!((1.0 / b - 1.0 / a - 0.5 * step).abs() < 1e-9);
        }
        assert!(
            jittered_depths(1.0, 1e9, 3, -0.5)
                .iter()
                .all(|x| x.is_finite() && *x > 0.0)
        );
    }

    /// `synthetic:procedural`: half the tuples (with dataset scenes beside it) come from a new procedural
    /// scene each, with valid crops and the inputs asked for; the same generator state draws the same
    /// tuples (a resumed run sees the same data), and the textures come from training views only.
    #[test]
    fn procedural_tuples_are_valid_and_reproducible() {
        let mut scene = two_plane_scene(3, 3, 48, 0.15);
        scene.train_views.retain(|&v| v != 4);
        let data = TrainData::with_procedural(vec![scene], Procedural::default());
        let cfg = SampleConfig {
            auto_planes: true,
            wide_inputs: 0.3,
            surround_inputs: 0.3,
            ..test_sample(3..=4, 32)
        };
        let model = DeepViewConfig::preset("cpu").unwrap();
        let draw = |seed| {
            let mut rng = Rng::new(seed);
            (0..12)
                .map(|_| {
                    let k = data.draw_views(&cfg, &mut rng);
                    data.sample(&cfg, &model, k, &mut rng).unwrap()
                })
                .collect::<Vec<_>>()
        };
        let (a, b) = (draw(5), draw(5));
        let procedural = a.iter().filter(|e| e.scene == PROCEDURAL_SCENE).count();
        assert!((3..=9).contains(&procedural), "{procedural} of 12");
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(
                (x.scene, x.target, &x.inputs),
                (y.scene, y.target, &y.inputs)
            );
            assert_eq!(x.target_crop.data, y.target_crop.data);
            assert!((3..=4).contains(&x.inputs.len()));
            assert!(!x.inputs.contains(&x.target));
            assert_eq!((x.target_crop.width, x.target_crop.height), (16, 16));
            assert!(x.depths.len() >= 8 && x.depths.len() <= 32);
            assert!(x.target_crop.data.iter().all(|v| (0.0..=1.0).contains(v)));
        }
        // Textures come from the 8 training views, never from the held-out one.
        let photos = data.texture_photos();
        assert_eq!(photos.len(), 8);
        assert!(
            !photos
                .iter()
                .any(|p| std::ptr::eq(*p, &data.scenes[0].images[4]))
        );
        for seed in 0..4 {
            assert!(data.procedural_scene(seed, 4).unwrap().cameras.len() >= 6);
        }
    }

    /// With `prior_radius_size`, a tuple of images larger than it gets the grown radius
    /// (`DeepViewConfig::prior_radius_at`) and a window with the margins of the model at that radius; on
    /// smaller images nothing changes.
    #[test]
    fn tuples_of_large_images_get_the_grown_prior_radius() {
        let data = TrainData::new(vec![two_plane_scene(3, 3, 48, 0.15)]).unwrap();
        let cfg = test_sample(3..=3, 6);
        let fixed = DeepViewConfig {
            prior_radius: 3,
            ..DeepViewConfig::preset("cpu").unwrap()
        };
        let draw = |model: &DeepViewConfig| {
            let mut rng = Rng::new(7);
            data.sample(&cfg, model, 3, &mut rng).unwrap()
        };
        let a = draw(&fixed);
        assert_eq!(a.prior_radius, Some(3));
        // 48-px images over a size of 16: radius 3 * 48 / 16 = 9, net 0's margin 10 instead of 6.
        let grown = DeepViewConfig {
            prior_radius_size: Some(16),
            ..fixed.clone()
        };
        assert_eq!(grown.prior_radius_at(48), 9);
        assert_eq!(
            (fixed.net_margin(0), grown.at_image_size(48).net_margin(0)),
            (6, 10)
        );
        let b = draw(&grown);
        assert_eq!(b.prior_radius, Some(9));
        assert_eq!((b.target, &b.inputs), (a.target, &a.inputs));
        assert_eq!(b.window.2, a.window.2 + 8, "window width");
        assert_eq!(b.window.3, a.window.3 + 8, "window height");
        // A size at or above the images': the radius as it is.
        let large = DeepViewConfig {
            prior_radius_size: Some(48),
            ..fixed.clone()
        };
        let c = draw(&large);
        assert_eq!((c.prior_radius, c.window), (Some(3), a.window));
    }

    /// `auto_planes`: each tuple gets the plane count of the inference rule for its own inputs, clamped to
    /// 8..=planes; without it, always `planes`.
    #[test]
    fn auto_planes_follow_the_inference_rule() {
        let data = TrainData::new(vec![two_plane_scene(4, 4, 96, 0.6)]).unwrap();
        let mut cfg = SampleConfig {
            auto_planes: true,
            ..test_sample(2..=5, 40)
        };
        let model = DeepViewConfig::preset("cpu").unwrap();
        let mut rng = Rng::new(11);
        let s = &data.scenes[0];
        let mut counts = std::collections::BTreeSet::new();
        for _ in 0..20 {
            let k = data.draw_views(&cfg, &mut rng);
            let ex = data.sample(&cfg, &model, k, &mut rng).unwrap();
            let cams: Vec<Camera> = ex.inputs.iter().map(|&i| s.cameras[i]).collect();
            let reference = reference_camera(&cams, &ReferenceOptions::default()).unwrap();
            let want = deepview_geometry::auto_plane_count(&reference, &cams, s.near, s.far, 1.0);
            assert_eq!(ex.depths.len(), want.clamp(8, 40), "inputs {:?}", ex.inputs);
            counts.insert(ex.depths.len());
        }
        assert!(
            counts.len() > 1,
            "the scene's tuples should need different counts: {counts:?}"
        );
        cfg.auto_planes = false;
        let ex = data.sample(&cfg, &model, 3, &mut rng).unwrap();
        assert_eq!(ex.depths.len(), 40);
    }

    /// The training views other than `target` by distance of their centres to its centre (ties: index),
    /// computed here independently of the sampler.
    fn by_distance(s: &TrainScene, target: usize) -> Vec<usize> {
        let t = s.cameras[target].center();
        let mut order: Vec<usize> = s
            .train_views
            .iter()
            .copied()
            .filter(|&v| v != target)
            .collect();
        order.sort_by(|&a, &b| {
            (s.cameras[a].center() - t)
                .length()
                .total_cmp(&(s.cameras[b].center() - t).length())
                .then(a.cmp(&b))
        });
        order
    }

    /// `wide_inputs = 1`: K distinct training views among the target's 3K nearest, never the target, and
    /// not always the K nearest.
    #[test]
    fn wide_inputs_come_from_the_3k_nearest() {
        let data = TrainData::new(vec![two_plane_scene(4, 4, 48, 0.15)]).unwrap();
        let cfg = SampleConfig {
            wide_inputs: 1.0,
            ..test_sample(2..=4, 6)
        };
        let model = DeepViewConfig::preset("cpu").unwrap();
        let s = &data.scenes[0];
        let mut rng = Rng::new(5);
        let mut differs = 0;
        for _ in 0..30 {
            let k = data.draw_views(&cfg, &mut rng);
            let ex = data.sample(&cfg, &model, k, &mut rng).unwrap();
            // The 3K nearest by distance, computed here independently.
            let order = by_distance(s, ex.target);
            let pool = &order[..(3 * k).min(order.len())];
            assert_eq!(ex.inputs.len(), k);
            let mut uniq = ex.inputs.clone();
            uniq.sort();
            uniq.dedup();
            assert_eq!(uniq.len(), k, "{:?}", ex.inputs);
            assert!(
                ex.inputs.iter().all(|v| pool.contains(v)),
                "{:?} not in {pool:?}",
                ex.inputs
            );
            let mut nearest = order[..k].to_vec();
            nearest.sort();
            differs += (uniq != nearest) as usize;
        }
        assert!(
            differs > 10,
            "only {differs} of 30 tuples differ from the K nearest"
        );
    }

    /// `spread_inputs = 1`: K distinct training views spread over the capture (one in each K-th of the
    /// views in name order, near the protocol's `linspace` positions), a target that is none of them,
    /// and over many tuples targets both between the inputs and beyond them, with varied inputs.
    #[test]
    fn spread_inputs_cover_the_capture() {
        // 12 x 2 views, none held out: 24 training views.
        let data = TrainData::new(vec![two_plane_scene(12, 2, 48, 0.1)]).unwrap();
        let cfg = SampleConfig {
            surround_inputs: 1.0,
            spread_inputs: 1.0,
            ..test_sample(3..=3, 6)
        };
        let model = DeepViewConfig::preset("cpu").unwrap();
        let s = &data.scenes[0];
        let n = s.train_views.len();
        assert_eq!(n, 24);
        let mut rng = Rng::new(11);
        let (mut beyond, mut between) = (0, 0);
        let mut sets = std::collections::HashSet::new();
        for _ in 0..60 {
            let ex = data.sample(&cfg, &model, 3, &mut rng).unwrap();
            let pos: Vec<usize> = ex
                .inputs
                .iter()
                .map(|v| s.train_views.iter().position(|t| t == v).unwrap())
                .collect();
            assert_eq!(pos.len(), 3);
            assert!(pos.windows(2).all(|w| w[0] < w[1]), "{pos:?}");
            // linspace(0, 23, 3) = 0, 11.5, 23, each moved by at most a quarter of the spacing (2.9).
            for (p, at) in pos.iter().zip([0.0, 11.5, 23.0]) {
                assert!((*p as f64 - at).abs() <= 3.4, "{pos:?}");
            }
            let t = s.train_views.iter().position(|&v| v == ex.target).unwrap();
            assert!(!pos.contains(&t), "target {t} among the inputs {pos:?}");
            if t < pos[0] || t > pos[2] {
                beyond += 1;
            } else {
                between += 1;
            }
            sets.insert(pos);
        }
        assert!(
            beyond > 0 && between > 20,
            "beyond {beyond}, between {between}"
        );
        assert!(sets.len() > 10, "only {} input sets", sets.len());
    }

    /// The memory budget: a budget over every tuple's estimate draws exactly the tuples drawn without
    /// one; a budget at the median estimate bounds every tuple drawn (fewer planes, down to 8, or
    /// another tuple), and a budget no tuple fits is a clear error, not a panic or an endless loop.
    #[test]
    fn memory_budget_bounds_each_tuple() {
        let data = TrainData::new(vec![two_plane_scene(12, 2, 48, 0.3)]).unwrap();
        let model = DeepViewConfig::preset("cpu").unwrap();
        let mut cfg = SampleConfig {
            spread_inputs: 0.5,
            ..test_sample(3..=3, 32)
        };
        let estimate = |ex: &Example| ex.step_bytes(&model, false);
        let draw = |cfg: &SampleConfig| -> Vec<Example> {
            let mut rng = Rng::new(5);
            (0..40)
                .map(|_| data.sample(cfg, &model, 3, &mut rng).unwrap())
                .collect()
        };
        let free = draw(&cfg);
        let mut needs: Vec<u64> = free.iter().map(estimate).collect();
        needs.sort();
        let tuple = |b: u64| b - STEP_BASE_BYTES;
        assert!(tuple(needs[0]) * 3 / 2 < tuple(needs[39]), "{needs:?}");

        cfg.budget = Some(StepBudget {
            bytes: needs[39],
            recompute: false,
        });
        for (a, b) in free.iter().zip(draw(&cfg)) {
            assert_eq!(
                (&a.inputs, a.target, &a.depths, a.crop_origin),
                (&b.inputs, b.target, &b.depths, b.crop_origin)
            );
        }

        let budget = needs[20];
        cfg.budget = Some(StepBudget {
            bytes: budget,
            recompute: false,
        });
        let bounded = draw(&cfg);
        let fewer = bounded.iter().filter(|e| e.depths.len() < 32).count();
        for ex in &bounded {
            assert!(estimate(ex) <= budget, "{} > {budget}", estimate(ex));
            assert!(ex.depths.len() >= 8);
        }
        assert!(fewer > 0, "no tuple got fewer planes");

        cfg.budget = Some(StepBudget {
            bytes: STEP_BASE_BYTES + 1,
            recompute: false,
        });
        let err = data.sample(&cfg, &model, 3, &mut Rng::new(5)).unwrap_err();
        assert!(err.to_string().contains("memory budget"), "{err}");
    }

    /// `surround_inputs = 1`, K = 4 on a 5x5 grid: distinct views from the 3K nearest, not always the K
    /// nearest, and around every interior target: seen from the target, no angular gap between the
    /// inputs exceeds 180 degrees (the target is inside their convex hull).
    /// The window's context holds every point of the reference image that a ray of an input crop crosses
    /// on some plane (up to the window grown by its own size), contains the window, and its input crops
    /// sample the same image pixels as the window's where the two overlap.
    #[test]
    fn window_context_holds_what_the_input_crops_rays_cross() {
        let data = TrainData::new(vec![two_plane_scene(4, 4, 64, 0.3)]).unwrap();
        let mut cfg = SampleConfig {
            wide_inputs: 0.5,
            window_context: true,
            budget: None,
            ..test_sample(3..=3, 8)
        };
        let model = DeepViewConfig::preset("cpu").unwrap();
        let s = &data.scenes[0];
        let mut rng = Rng::new(5);
        let mut outside_window = 0;
        for _ in 0..20 {
            let ex = data.sample(&cfg, &model, 3, &mut rng).unwrap();
            let c = ex.context.as_ref().expect("a context");
            let (wx0, wy0, ww, wh) = ex.window;
            let (ox, oy) = (c.origin.0 as f64, c.origin.1 as f64);
            assert!(ox + ww as f64 <= c.width as f64 && oy + wh as f64 <= c.height as f64);
            let cams: Vec<Camera> = ex.inputs.iter().map(|&i| s.cameras[i]).collect();
            let reference = reference_camera(&cams, &ReferenceOptions::default()).unwrap();
            for (k, crop) in ex.images.iter().enumerate() {
                for hom in &ex.mpi_to_view[k] {
                    let inv = deepview_net::forward::invert(hom);
                    for (x, y) in [
                        (0.5, 0.5),
                        (crop.width as f64 - 0.5, crop.height as f64 - 0.5),
                    ] {
                        let p = apply(&inv, x, y).unwrap();
                        // In reference pixels; only the reference image and the window's own size around
                        // it are promised.
                        let (rx, ry) = (p.x + wx0 as f64, p.y + wy0 as f64);
                        let in_reference = rx >= 0.0
                            && ry >= 0.0
                            && rx <= reference.width as f64
                            && ry <= reference.height as f64;
                        let near = p.x >= -(ww as f64)
                            && p.y >= -(wh as f64)
                            && p.x <= 2.0 * ww as f64
                            && p.y <= 2.0 * wh as f64;
                        if !(in_reference && near) {
                            continue;
                        }
                        let inside_window =
                            p.x >= 0.0 && p.y >= 0.0 && p.x <= ww as f64 && p.y <= wh as f64;
                        outside_window += usize::from(!inside_window);
                        let (cx, cy) = (p.x + ox, p.y + oy);
                        assert!(
                            cx >= -1e-6
                                && cy >= -1e-6
                                && cx <= c.width as f64 + 1e-6
                                && cy <= c.height as f64 + 1e-6,
                            "({cx}, {cy}) outside the {}x{} context",
                            c.width,
                            c.height
                        );
                    }
                }
                // The same image pixel from the window's crop and the context's crop.
                for hom_pair in ex.mpi_to_view[k].iter().zip(&c.mpi_to_view[k]) {
                    let (hw, hc) = hom_pair;
                    let (px, py) = (ww as f64 / 2.0, wh as f64 / 2.0);
                    let a = apply(hw, px, py).unwrap();
                    let b = apply(hc, px + ox, py + oy).unwrap();
                    let (ax, ay) = (a.x.round() as u32, a.y.round() as u32);
                    let shift = (b - a).round();
                    let (bx, by) = ((ax as f64 + shift.x) as u32, (ay as f64 + shift.y) as u32);
                    if ax < crop.width && ay < crop.height {
                        let ci = &c.images[k];
                        assert!(bx < ci.width && by < ci.height);
                        let ia = ((ay * crop.width + ax) * 3) as usize;
                        let ib = ((by * ci.width + bx) * 3) as usize;
                        assert_eq!(crop.data[ia..ia + 3], ci.data[ib..ib + 3]);
                    }
                }
            }
        }
        assert!(
            outside_window > 20,
            "the rays leave the window only {outside_window} times"
        );
        cfg.window_context = false;
        let ex = data.sample(&cfg, &model, 3, &mut rng).unwrap();
        assert!(ex.context.is_none());
    }

    #[test]
    fn surrounding_inputs_enclose_the_target() {
        let baseline = 0.1;
        let data = TrainData::new(vec![two_plane_scene(5, 5, 48, baseline)]).unwrap();
        let cfg = SampleConfig {
            jitter: false,
            surround_inputs: 1.0,
            ..test_sample(4..=4, 6)
        };
        let model = DeepViewConfig::preset("cpu").unwrap();
        let s = &data.scenes[0];
        let mut rng = Rng::new(11);
        let (mut interior, mut differs) = (0, 0);
        for _ in 0..60 {
            let ex = data.sample(&cfg, &model, 4, &mut rng).unwrap();
            let t = s.cameras[ex.target].center();
            let order = by_distance(s, ex.target);
            let mut uniq = ex.inputs.clone();
            uniq.sort();
            uniq.dedup();
            assert_eq!(uniq.len(), 4, "{:?}", ex.inputs);
            assert!(ex.inputs.iter().all(|v| order[..12].contains(v)));
            let mut nearest = order[..4].to_vec();
            nearest.sort();
            differs += (uniq != nearest) as usize;
            if t.x.abs() < 1.5 * baseline && t.y.abs() < 1.5 * baseline {
                interior += 1;
                let mut angles: Vec<f64> = ex
                    .inputs
                    .iter()
                    .map(|&v| {
                        let d = s.cameras[v].center() - t;
                        d.y.atan2(d.x).to_degrees()
                    })
                    .collect();
                angles.sort_by(f64::total_cmp);
                let gaps = angles
                    .windows(2)
                    .map(|w| w[1] - w[0])
                    .chain([360.0 + angles[0] - angles[3]]);
                let widest = gaps.fold(0.0, f64::max);
                assert!(
                    widest <= 180.0 + 1e-9,
                    "inputs {:?} leave a {widest} degree gap around target {}",
                    ex.inputs,
                    ex.target
                );
            }
        }
        // Edge and corner views of the grid have an empty sector (nothing beyond them): such targets are
        // redrawn, so every tuple renders between its inputs. Drawn uniformly, 16 of the 25 views are on
        // the edge.
        assert_eq!(
            interior, 60,
            "only {interior} of 60 targets inside the grid"
        );
        assert!(
            differs > 20,
            "only {differs} of 60 tuples differ from the 4 nearest"
        );
    }

    /// Colour jitter scales every channel of the target by one gain within the documented range, and each
    /// input by the same gains times its own exposure within +-5%; the tuple itself (views, crop) is the
    /// one drawn without jitter.
    #[test]
    fn colour_jitter_is_a_gain_per_channel_and_view() {
        let data = TrainData::new(vec![two_plane_scene(3, 3, 48, 0.15)]).unwrap();
        let mut cfg = test_sample(3..=3, 6);
        let model = DeepViewConfig::preset("cpu").unwrap();
        for seed in 0..6 {
            let plain = data.sample(&cfg, &model, 3, &mut Rng::new(seed)).unwrap();
            cfg.colour_jitter = true;
            let jit = data.sample(&cfg, &model, 3, &mut Rng::new(seed)).unwrap();
            cfg.colour_jitter = false;
            assert_eq!(
                (plain.inputs.clone(), plain.crop_origin),
                (jit.inputs.clone(), jit.crop_origin)
            );
            // Gains measured on unclamped pixels.
            let gains = |a: &ImageF32, b: &ImageF32| -> [f64; 3] {
                std::array::from_fn(|c| {
                    let (mut num, mut den) = (0.0, 0.0);
                    for (pa, pb) in a.data.chunks_exact(3).zip(b.data.chunks_exact(3)) {
                        if pa[c] > 0.05 && pb[c] < 0.999 {
                            num += pb[c] as f64;
                            den += pa[c] as f64;
                        }
                    }
                    num / den
                })
            };
            let gt = gains(&plain.target_crop, &jit.target_crop);
            for (c, g) in gt.iter().enumerate() {
                assert!(
                    (g.ln()).abs() <= EXPOSURE_LOG + CHANNEL_LOG + 1e-6,
                    "channel {c} gain {g}"
                );
                for (pa, pb) in plain
                    .target_crop
                    .data
                    .chunks_exact(3)
                    .zip(jit.target_crop.data.chunks_exact(3))
                {
                    let want = (pa[c] as f64 * g).min(1.0);
                    assert!((pb[c] as f64 - want).abs() < 1e-4, "{} vs {want}", pb[c]);
                }
            }
            for (a, b) in plain.images.iter().zip(&jit.images) {
                let gi = gains(a, b);
                let view: Vec<f64> = (0..3).map(|c| gi[c] / gt[c]).collect();
                assert!(
                    (view[0] - view[1]).abs() < 1e-4 && (view[0] - view[2]).abs() < 1e-4,
                    "{view:?}"
                );
                assert!(view[0].ln().abs() <= VIEW_LOG + 1e-6, "{view:?}");
            }
        }
    }

    /// The window covers everything the target crop samples on every plane, after the model's shrink;
    /// input crops cover every in-image sample of the window.
    #[test]
    fn window_and_crops_cover_what_is_needed() {
        let data = TrainData::new(vec![two_plane_scene(3, 3, 48, 0.15)]).unwrap();
        let cfg = test_sample(2..=4, 6);
        let model = DeepViewConfig::preset("cpu").unwrap();
        let margin = model.margin_from(0);
        let mut rng = Rng::new(3);
        for _ in 0..20 {
            let k = data.draw_views(&cfg, &mut rng);
            let ex = data.sample(&cfg, &model, k, &mut rng).unwrap();
            assert_eq!(ex.inputs.len(), k);
            assert!(!ex.inputs.contains(&ex.target));
            let (_, _, ww, wh) = ex.window;
            assert!(ww % 2 == 0 && wh % 2 == 0);
            // Target-crop pixel centres land inside the shrunk window (with 1 px for bilinear taps).
            for h in &ex.window_to_target {
                let inv = deepview_net::forward::invert(h);
                for (x, y) in [
                    (0.5, 0.5),
                    (15.5, 0.5),
                    (0.5, 15.5),
                    (15.5, 15.5),
                    (8.0, 8.0),
                ] {
                    let p = apply(&inv, x, y).unwrap();
                    assert!(
                        p.x >= (margin + 1) as f64 - 1e-6 && p.x <= (ww - margin - 1) as f64 + 1e-6,
                        "{p:?} {ww}"
                    );
                    assert!(
                        p.y >= (margin + 1) as f64 - 1e-6 && p.y <= (wh - margin - 1) as f64 + 1e-6,
                        "{p:?} {wh}"
                    );
                }
            }
            // Every window sample that falls inside the full image falls inside the crop.
            let s = &data.scenes[0];
            for (k, &v) in ex.inputs.iter().enumerate() {
                let cam = s.cameras[v];
                let (crop, (ox, oy)) = (&ex.images[k], ex.image_origins[k]);
                for h in &ex.mpi_to_view[k] {
                    for (x, y) in [
                        (0.5, 0.5),
                        (ww as f64 - 0.5, wh as f64 - 0.5),
                        (ww as f64 / 2.0, 0.5),
                        (0.5, wh as f64 / 2.0),
                    ] {
                        let p = apply(h, x, y).unwrap();
                        let q = (p.x + ox as f64, p.y + oy as f64);
                        if q.0 >= 0.0
                            && q.1 >= 0.0
                            && q.0 <= cam.width as f64
                            && q.1 <= cam.height as f64
                        {
                            assert!(
                                p.x >= 0.0
                                    && p.y >= 0.0
                                    && p.x <= crop.width as f64
                                    && p.y <= crop.height as f64
                            );
                        }
                    }
                }
            }
        }
    }
}
