//! The DeepView network: an initialisation net on plane sweep volumes and update nets on gradient
//! components (learned gradient descent), all sharing one core architecture (see [`CoreNet`]).
//!
//! Shapes: K views, D planes (back to front), an MPI window of `h x w` pixels (a crop of the reference
//! camera's image). Per-(view, plane) tensors are stacked view-major: index `k * D + d`.
//!
//! ```text
//! M_0     = N_0([PSV_k, valid_k]_k)                         (init input: 4 channels per slice)
//!           (+ agreement_prior(PSVs) with `init_prior`, a CPU-training deviation: see config.rs)
//! M_{n+1} = M_n + N_n([grad_{n,k}, M_n]_k),  n = 1..=updates (update input: 11 + 8 channels)
//! RGBA    = sigmoid(M[0..4]) with colour premultiplied by alpha
//! ```
//!
//! Training windows ([`ModelInputs::shrink`]): after net `n` the state is cropped by
//! [`DeepViewConfig::net_margin`]`(n)` on every side, so a window grown by
//! [`DeepViewConfig::margin_from`]`(0)` around what the loss needs ends with exactly that region and no
//! conv zero-padding effects inside it. The gradient components of iteration `n` render the views from
//! the *current window*, whereas the full-image computation also sees MPI content outside the window
//! through parallax: a ray of an input crop through a window pixel on one plane leaves the window on
//! others when the views' disparity exceeds the margins. Without a [`WindowContext`] the MPI is
//! transparent outside the window (an approximation that grows with the baseline); with one, the views
//! are rendered from the agreement prior's RGBA on the whole region the input crops' rays cross, with the
//! window's current values in place ([`window_gradient_components`]). The prior is what net 0 starts
//! from, so outside the window the update nets see the state's first estimate rather than nothing.
//! Inference (`infer.rs`) has no such approximation: it tiles each net separately and renders the views
//! from the full MPI.

use crate::config::{CPU_PRIOR_TEMPERATURE, DeepViewConfig};
use crate::cpu::ops::{conv3x3_act, core_net_train, fast_device};
use crate::cpu::packed::core_net_inference;
use crate::forward::{
    GRADIENT_CHANNELS, Hom, crop_output, gradient_components, plane_sweep_volume,
};
use burn::module::{Module, Param};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::tensor::activation::sigmoid;
use burn::tensor::module::{avg_pool2d, interpolate};
use burn::tensor::ops::{AvgPoolOptions, InterpolateMode, InterpolateOptions};
use burn::tensor::{Device, Tensor};
use deepview_kernels::Act;

/// Rows and columns `m..` of `s` `[D, C, .., ..]`, `h x w` of them: one kernel on our GPU devices,
/// burn's slices elsewhere.
fn crop_window(s: Tensor<4>, m: usize, h: usize, w: usize) -> Tensor<4> {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if crate::gpu::gpu_kernels(&s.device()) {
        return crate::gpu::crop(s, m, m, h, w);
    }
    s.narrow(3, m, w).narrow(2, m, h)
}

/// Input channels per (view, plane) slice of the initialisation net: PSV RGB + validity.
pub const INIT_CHANNELS: usize = 4;

/// One per-iteration CNN (DESIGN.md section 4).
#[derive(Module, Debug)]
pub struct CoreNet {
    /// Two per-view convs.
    pub input: Vec<Conv2d>,
    /// `2 * stages` convs, each pair after a (max over views, concat) step.
    pub stages: Vec<Conv2d>,
    /// After the final max over views: conv(F) ELU, conv(out) linear.
    pub head: Conv2d,
    pub out: Conv2d,
    /// Run at half resolution (one-level U-Net).
    pub unet: bool,
}

fn conv(i: usize, o: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([i, o], [3, 3])
        .with_padding(PaddingConfig2d::Same)
        .init(device)
}

impl CoreNet {
    pub fn new(
        in_channels: usize,
        features: usize,
        out: usize,
        stages: usize,
        unet: bool,
        device: &Device,
    ) -> Self {
        let f = features;
        let mut st = Vec::new();
        for _ in 0..stages {
            st.push(conv(2 * f, f, device));
            st.push(conv(f, f, device));
        }
        Self {
            input: vec![conv(in_channels, f, device), conv(f, f, device)],
            stages: st,
            head: conv(f, f, device),
            out: conv(f, out, device),
            unet,
        }
    }

    /// `x` `[K*D, C_in, h, w]` (view-major) -> `[D, out, h, w]`. Invariant to the order of the views.
    /// Zero the last conv (weights and bias), so the net outputs 0 until trained (residual nets on a prior).
    /// Net `n` of `config` (the initialisation net for 0, an update net otherwise), randomly initialised
    /// (the model zeroes its output where the config has a prior).
    pub fn of_config(config: &DeepViewConfig, n: usize, device: &Device) -> Self {
        let sc = config.state_channels();
        let cin = if n == 0 {
            INIT_CHANNELS
        } else {
            GRADIENT_CHANNELS + sc
        };
        Self::new(
            cin,
            config.features(n),
            sc,
            config.max_pool_stages,
            config.unet(n),
            device,
        )
    }

    pub fn zero_output(mut self) -> Self {
        let w = self.out.weight.val();
        self.out.weight = Param::from_tensor(w.zeros_like());
        if let Some(b) = self.out.bias.take() {
            self.out.bias = Some(Param::from_tensor(b.val().zeros_like()));
        }
        self
    }

    pub fn forward(&self, x: Tensor<4>, views: usize) -> Tensor<4> {
        let [kd, _, h, w] = x.dims();
        let d = kd / views;
        let x = if self.unet {
            let opts = AvgPoolOptions::new([2, 2]).with_padding_pairs([(0, h % 2), (0, w % 2)]);
            avg_pool2d(x, opts)
        } else {
            x
        };
        if fast_device(&x.device()) {
            let o = if x.is_autodiff() {
                core_net_train(&self.input, &self.stages, &self.head, &self.out, x, views)
            } else {
                core_net_inference(&self.input, &self.stages, &self.head, &self.out, x, views)
            };
            return self.upsample(o, h, w);
        }
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if crate::gpu::gpu_kernels(&x.device()) {
            let mut f = x;
            for c in &self.input {
                f = conv3x3_act(f, c, Act::Elu);
            }
            for pair in self.stages.chunks(2) {
                f = crate::gpu::view_max(f, views, true);
                for c in pair {
                    f = conv3x3_act(f, c, Act::Elu);
                }
            }
            let m = crate::gpu::view_max(f, views, false);
            let o = conv3x3_act(conv3x3_act(m, &self.head, Act::Elu), &self.out, Act::Linear);
            return self.upsample(o, h, w);
        }
        let mut f = x;
        for c in &self.input {
            f = conv3x3_act(f, c, Act::Elu);
        }
        for pair in self.stages.chunks(2) {
            let [_, fc, hh, ww] = f.dims();
            let m = max_over_views(f.clone(), views)
                .reshape([1, d, fc, hh, ww])
                .repeat_dim(0, views);
            f = Tensor::cat(vec![f, m.reshape([kd, fc, hh, ww])], 1);
            for c in pair {
                f = conv3x3_act(f, c, Act::Elu);
            }
        }
        let m = max_over_views(f, views);
        let o = conv3x3_act(conv3x3_act(m, &self.head, Act::Elu), &self.out, Act::Linear);
        self.upsample(o, h, w)
    }

    /// [`Self::forward`] with burn's own `conv2d` and `elu` on any device (the reference of the kernels).
    pub fn forward_burn(&self, x: Tensor<4>, views: usize) -> Tensor<4> {
        let [kd, _, h, w] = x.dims();
        let d = kd / views;
        let x = if self.unet {
            let opts = AvgPoolOptions::new([2, 2]).with_padding_pairs([(0, h % 2), (0, w % 2)]);
            avg_pool2d(x, opts)
        } else {
            x
        };
        let act = |c: &Conv2d, x: Tensor<4>| burn::tensor::activation::elu(c.forward(x), 1.0);
        let mut f = x;
        for c in &self.input {
            f = act(c, f);
        }
        for pair in self.stages.chunks(2) {
            let [_, fc, hh, ww] = f.dims();
            let m = max_over_views(f.clone(), views)
                .reshape([1, d, fc, hh, ww])
                .repeat_dim(0, views);
            f = Tensor::cat(vec![f, m.reshape([kd, fc, hh, ww])], 1);
            for c in pair {
                f = act(c, f);
            }
        }
        let m = max_over_views(f, views);
        let o = self.out.forward(act(&self.head, m));
        self.upsample(o, h, w)
    }

    /// The U-Net's bilinear upsampling of the output back to `h x w` (identity without U-Net).
    fn upsample(&self, o: Tensor<4>, h: usize, w: usize) -> Tensor<4> {
        if self.unet {
            let [_, _, hh, ww] = o.dims();
            let up = if fast_device(&o.device()) {
                let opts = InterpolateOptions::new(InterpolateMode::Bilinear)
                    .with_align_corners(false)
                    .with_output_size([2 * hh, 2 * ww]);
                interpolate(o, opts)
            } else {
                // burn's GPU backends have no backward for bilinear interpolation.
                upsample2x_bilinear(o)
            };
            up.narrow(2, 0, h).narrow(3, 0, w)
        } else {
            o
        }
    }
}

/// Bilinear upsampling by 2 of the last two axes (`align_corners = false`, edges clamped: burn's
/// `interpolate` to twice the size) from slices, sums and reshapes only, so that its backward exists on every
/// backend (burn's GPU backends have none for `interpolate`). Along an axis of length n, output 2i is
/// `0.75 x[i] + 0.25 x[i - 1]` and output 2i + 1 is `0.75 x[i] + 0.25 x[i + 1]`, indices clamped to 0..n.
pub fn upsample2x_bilinear(x: Tensor<4>) -> Tensor<4> {
    upsample2x_axis(upsample2x_axis(x, 2), 3)
}

/// [`upsample2x_bilinear`] along one axis (2 or 3).
fn upsample2x_axis(x: Tensor<4>, axis: usize) -> Tensor<4> {
    let dims = x.dims();
    let n = dims[axis];
    let (prev, next) = if n == 1 {
        (x.clone(), x.clone())
    } else {
        let prev = Tensor::cat(
            vec![
                x.clone().narrow(axis, 0, 1),
                x.clone().narrow(axis, 0, n - 1),
            ],
            axis,
        );
        let next = Tensor::cat(
            vec![
                x.clone().narrow(axis, 1, n - 1),
                x.clone().narrow(axis, n - 1, 1),
            ],
            axis,
        );
        (prev, next)
    };
    let centre = x.mul_scalar(0.75);
    let even = centre.clone() + prev.mul_scalar(0.25);
    let odd = centre + next.mul_scalar(0.25);
    // Interleave: [.., n, 1, ..] pairs side by side on a new axis after `axis`, then merged.
    let pair = Tensor::cat(
        vec![
            even.unsqueeze_dim::<5>(axis + 1),
            odd.unsqueeze_dim::<5>(axis + 1),
        ],
        axis + 1,
    );
    let mut out = dims;
    out[axis] = 2 * n;
    pair.reshape(out)
}

/// `[K*D, C, h, w]` -> `[D, C, h, w]`, element-wise maximum over the K views.
pub fn max_over_views(x: Tensor<4>, views: usize) -> Tensor<4> {
    let [kd, c, h, w] = x.dims();
    let d = kd / views;
    x.reshape([views, d * c, h, w])
        .max_dim(0)
        .reshape([d, c, h, w])
}

/// The network state `M` `[D, 4 + extra, h, w]` -> RGBA `[D, 4, h, w]` (sigmoid, colour premultiplied).
pub fn state_to_rgba(state: Tensor<4>) -> Tensor<4> {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if crate::gpu::gpu_kernels(&state.device()) {
        return crate::gpu::state_rgba(state);
    }
    state_to_rgba_burn(state)
}

/// [`state_to_rgba`] with burn's ops (any device; the reference of the GPU kernel).
pub fn state_to_rgba_burn(state: Tensor<4>) -> Tensor<4> {
    let s = sigmoid(state.narrow(1, 0, 4));
    let a = s.clone().narrow(1, 3, 1);
    Tensor::cat(vec![s.narrow(1, 0, 3) * a.clone(), a], 1)
}

use deepview_mpi::agreement::{
    Aggregation, Census, LOGIT_EPS as PRIOR_EPS, SINGLE_VIEW_VARIANCE, Smoothing,
};

/// The cross-view agreement MPI of plane sweep volumes as RGBA *logits* `[D, 4, h, w]` (see
/// `DeepViewConfig::init_prior`), computed exactly like [`deepview_mpi::agreement::agreement_mpi`] (its one definition): per plane and
/// pixel, colour = mean of the valid samples; variance = mean over RGB of the valid samples' variance
/// (`SINGLE_VIEW_VARIANCE` where one view sees the point; no weight where none does); weights =
/// softmax over planes of `-variance / temperature`; alpha `a_d = w_d / sum_{i<=d} w_i` (back to front).
/// Colour and alpha are clamped to `[LOGIT_EPS, 1 - LOGIT_EPS]` and turned into logits. With an active
/// `aggregation` (radius `r`, weight `a`) the variance is first `a` times its mean over the seen pixels of
/// the `(2r+1) x (2r+1)` window around each pixel (clipped at the tensor's border) plus `1 - a` times its
/// own ([`deepview_mpi::agreement::aggregate_seen`]). With a leave-one-out weight `b` the variance of a
/// point three or more views see is first blended with its least leave-one-out variance
/// ([`deepview_mpi::agreement::leave_one_out_variance`]), and with the sample variance scaled by
/// `n / (n - 1)` where `n >= 2` views see. With a census term
/// ([`deepview_mpi::agreement::Census`]) its cost is added to the variance first (where two or more views
/// see the point), and with smoothing the masked logits go through semi-global matching before the
/// softmax; both run on the host.
/// `per_view`: K tensors `[D, 4, h, w]` (PSV RGB, validity) as built by [`DeepViewModel::init_input`].
pub fn agreement_prior_logits(
    per_view: &[Tensor<4>],
    temperature: f64,
    aggregation: Aggregation,
) -> Tensor<4> {
    // Semi-global matching and the census term run on the host (a scan along image paths, bit
    // strings), so such a prior takes burn's ops around them, as does the leave-one-out term (which
    // the fused kernel does not compute).
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if crate::gpu::prior_is_fused(aggregation) && crate::gpu::gpu_kernels(&per_view[0].device()) {
        return crate::gpu::prior(per_view, temperature, aggregation);
    }
    agreement_prior_logits_burn(per_view, temperature, aggregation)
}

/// The mean of `x` over the seen pixels (`seen` 1, else 0) of the `(2r+1)^2` window around each pixel,
/// clipped at the border (separable average pools; both sums share the pool's divisor).
fn box_mean_seen_burn(x: Tensor<4>, seen: Tensor<4>, r: usize) -> Tensor<4> {
    let k = 2 * r + 1;
    let pool = |t: Tensor<4>| {
        let t = avg_pool2d(
            t,
            AvgPoolOptions::new([1, k])
                .with_stride([1, 1])
                .with_padding_pairs([(0, 0), (r, r)]),
        );
        avg_pool2d(
            t,
            AvgPoolOptions::new([k, 1])
                .with_stride([1, 1])
                .with_padding_pairs([(r, r), (0, 0)]),
        )
    };
    let num = pool(x * seen.clone());
    let den = pool(seen);
    num / den.clamp_min(1e-12)
}

/// Semi-global matching ([`deepview_mpi::agreement::smooth_semi_global`]) of masked depth logits
/// `[D, 1, h, w]` (unseen: -1e30), on the host; `cap` is the single-view cost.
fn smooth_on_host(masked: Tensor<4>, smoothing: Smoothing, cap: f64) -> Tensor<4> {
    let [d, c, h, w] = masked.dims();
    debug_assert_eq!(c, 1);
    let device = masked.device();
    let mut v: Vec<f32> = masked
        .into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("f32 logits");
    deepview_mpi::agreement::smooth_semi_global(&mut v, w, h, d, smoothing, cap as f32);
    Tensor::from_data(burn::tensor::TensorData::new(v, [d, c, h, w]), &device)
}

/// The census cost ([`deepview_mpi::agreement::census_disagreement`]) of the views' plane sweeps
/// `[D, 4, h, w]` (RGB, validity) as `[D, 1, h, w]`, on the host (planes in parallel).
fn census_on_host(per_view: &[Tensor<4>], census: Census) -> Tensor<4> {
    use rayon::prelude::*;
    let [d, _, h, w] = per_view[0].dims();
    let device = per_view[0].device();
    let hw = h * w;
    let views: Vec<Vec<f32>> = per_view
        .iter()
        .map(|v| {
            v.clone()
                .into_data()
                .convert::<f32>()
                .try_into_vec::<f32>()
                .expect("f32 plane sweeps")
        })
        .collect();
    let k = views.len();
    let mut out = vec![0f32; d * hw];
    out.par_chunks_mut(hw.max(1)).enumerate().for_each_init(
        || {
            (
                Vec::new(),
                deepview_mpi::agreement::CensusScratch::default(),
            )
        },
        |(greys, bits), (p, o)| {
            greys.resize(k * hw, 0f32);
            for (g, v) in greys.chunks_exact_mut(hw).zip(&views) {
                let plane = &v[p * 4 * hw..(p + 1) * 4 * hw];
                for (i, g) in g.iter_mut().enumerate() {
                    *g = deepview_mpi::agreement::grey_level(
                        plane[i],
                        plane[hw + i],
                        plane[2 * hw + i],
                        plane[3 * hw + i],
                    );
                }
            }
            let slices: Vec<&[f32]> = greys.chunks_exact(hw).collect();
            deepview_mpi::agreement::census_disagreement(&slices, w, h, census.radius, bits, o);
        },
    );
    Tensor::from_data(burn::tensor::TensorData::new(out, [d, 1, h, w]), &device)
}

/// [`agreement_prior_logits`] with burn's ops (a loop over the planes; the reference of the GPU kernel).
pub fn agreement_prior_logits_burn(
    per_view: &[Tensor<4>],
    temperature: f64,
    aggregation: Aggregation,
) -> Tensor<4> {
    let costs = prior_costs_burn(per_view, temperature, aggregation);
    prior_from_costs(costs, temperature, aggregation.smoothing)
}

/// The per-plane half of [`agreement_prior_logits_burn`] (each plane on its own; the leave-one-out
/// blend, the sample variance's factor, then the census term, then the single-view variance, as in
/// [`deepview_mpi::agreement::sweep_statistics`]): the mean colour
/// `[D, 3, h, w]`, the masked depth logits `[D, 1, h, w]` (the window's aggregation applied; unseen:
/// -1e30) and the seen mask `[D, 1, h, w]`.
pub fn prior_costs_burn(
    per_view: &[Tensor<4>],
    temperature: f64,
    aggregation: Aggregation,
) -> PriorCosts {
    let valid: Vec<Tensor<4>> = per_view.iter().map(|v| v.clone().narrow(1, 3, 1)).collect();
    let rgb: Vec<Tensor<4>> = per_view
        .iter()
        .zip(&valid)
        .map(|(v, m)| v.clone().narrow(1, 0, 3) * m.clone())
        .collect();
    let count = valid
        .iter()
        .cloned()
        .reduce(|a, b| a + b)
        .expect("at least one view");
    let denom = count.clone().clamp_min(1.0);
    let mean = rgb.iter().cloned().reduce(|a, b| a + b).expect("views") / denom.clone();
    // Two-pass variance of the valid samples (population variance, mean over RGB), from each view's
    // squared deviations from the mean (0 where it does not see).
    let sq: Vec<Tensor<4>> = rgb
        .iter()
        .zip(&valid)
        .map(|(c, m)| (c.clone() - mean.clone() * m.clone()).square())
        .collect();
    let var = sq.iter().cloned().reduce(|a, b| a + b).expect("views") / denom;
    let var = var.mean_dim(1);
    let var = match aggregation.leave_one_out {
        Some(b) => {
            // Each view's squared deviation summed over RGB.
            let dev: Vec<Tensor<4>> = sq.into_iter().map(|s| s.sum_dim(1)).collect();
            let ss = dev.iter().cloned().reduce(|a, b| a + b).expect("views");
            let max_dev = dev.into_iter().reduce(|a, b| a.max_pair(b)).expect("views");
            // deepview_mpi::agreement::leave_one_out_variance where three or more views see.
            let n1 = (count.clone() - 1.0).clamp_min(1.0);
            let loo = (ss - max_dev * count.clone() / n1.clone()).clamp_min(0.0) / (n1 * 3.0);
            let blend = var.clone() * (1.0 - b as f64) + loo * b as f64;
            var.mask_where(count.clone().greater_equal_elem(2.5), blend)
        }
        None => var,
    };
    let var = if aggregation.sample_variance {
        // n / (n - 1) where two or more views see.
        let n1 = (count.clone() - 1.0).clamp_min(1.0);
        let scaled = var.clone() * count.clone() / n1;
        var.mask_where(count.clone().greater_equal_elem(1.5), scaled)
    } else {
        var
    };
    let var = match aggregation.census {
        Some(c) => var + census_on_host(per_view, c) * c.weight as f64,
        None => var,
    };
    let single = count.clone().equal_elem(1.0);
    let var = var.mask_fill(single, SINGLE_VIEW_VARIANCE);
    let seen = count.greater_elem(0.5).float();
    let var = if aggregation.is_active() {
        let a = aggregation.weight;
        box_mean_seen_burn(var.clone(), seen.clone(), aggregation.radius) * a + var * (1.0 - a)
    } else {
        var
    };
    let logit = var.neg() / temperature;
    // Unseen (plane, pixel) pairs get no weight; a ray no view sees at all stays transparent.
    let masked = logit * seen.clone() + (seen.clone().neg().add_scalar(1.0)) * -1e30;
    PriorCosts { mean, masked, seen }
}

/// [`prior_costs_burn`]'s result (concatenate chunks of planes with [`PriorCosts::cat`]).
#[derive(Clone, Debug)]
pub struct PriorCosts {
    pub mean: Tensor<4>,
    pub masked: Tensor<4>,
    pub seen: Tensor<4>,
}

impl PriorCosts {
    /// Chunks of planes, back to front, as one.
    pub fn cat(chunks: Vec<PriorCosts>) -> PriorCosts {
        let (mut mean, mut masked, mut seen) = (Vec::new(), Vec::new(), Vec::new());
        for c in chunks {
            mean.push(c.mean);
            masked.push(c.masked);
            seen.push(c.seen);
        }
        PriorCosts {
            mean: Tensor::cat(mean, 0),
            masked: Tensor::cat(masked, 0),
            seen: Tensor::cat(seen, 0),
        }
    }
}

/// The across-planes half of [`agreement_prior_logits_burn`]: the optional semi-global matching of the
/// depth logits (on the host), the alphas back to front and the clamped RGBA logits `[D, 4, h, w]`.
pub fn prior_from_costs(
    costs: PriorCosts,
    temperature: f64,
    smoothing: Option<Smoothing>,
) -> Tensor<4> {
    let PriorCosts { mean, masked, seen } = costs;
    let masked = match smoothing {
        Some(smoothing) => smooth_on_host(masked, smoothing, SINGLE_VIEW_VARIANCE / temperature),
        None => masked,
    };
    // `a_d = w_d / sum_{i<=d} w_i = exp(l_d - logsumexp_{i<=d} l_i)`, accumulated in the log domain (f32
    // `exp` of the raw differences would underflow where the f64 baseline does not).
    let d = masked.dims()[0];
    let mut alphas = Vec::with_capacity(d);
    let mut run: Option<(Tensor<4>, Tensor<4>)> = None; // running max m and sum of exp(l_i - m)
    for p in 0..d {
        let l = masked.clone().narrow(0, p, 1);
        let (m, s) = match run {
            None => (l.clone(), l.ones_like()),
            Some((m0, s0)) => {
                let m = m0.clone().max_pair(l.clone());
                let s = s0 * (m0 - m.clone()).exp() + (l.clone() - m.clone()).exp();
                (m, s)
            }
        };
        let lse = m.clone() + s.clone().log();
        alphas.push((l - lse).exp().clamp_max(1.0));
        run = Some((m, s));
    }
    let alpha = Tensor::cat(alphas, 0) * seen;
    let logit_of = |p: Tensor<4>| {
        let p = p.clamp(PRIOR_EPS, 1.0 - PRIOR_EPS);
        (p.clone() / p.neg().add_scalar(1.0)).log()
    };
    Tensor::cat(vec![logit_of(mean), logit_of(alpha)], 1)
}

/// What the model needs: K view images and the plane homographies from the MPI window to each view.
#[derive(Clone, Debug)]
pub struct ModelInputs {
    /// K images `[3, hv_k, wv_k]` (whole views or crops of them), values in 0..1.
    pub images: Vec<Tensor<3>>,
    /// `mpi_to_view[k][d]`: row-major homography from MPI-window pixels of plane `d` (back to front) to
    /// pixels of `images[k]` (use `forward::crop_output`/`crop_source` for window and image crops).
    pub mpi_to_view: Vec<Vec<Hom>>,
    /// MPI window size.
    pub height: usize,
    pub width: usize,
    /// Crop the state by each net's margin after that net (training windows; see the module docs).
    pub shrink: bool,
    /// What the views see outside a training window when the update nets' gradient components render
    /// them (`None`: transparent; see the module docs).
    pub context: Option<WindowContext>,
}

/// The inputs of the MPI around a training window: the region of the reference camera that the rays
/// of the input crops cross on some plane (`width x height`, containing the window at `origin`), and
/// the input images and homographies that compute the agreement prior there
/// ([`DeepViewModel::context_rgba`]).
#[derive(Clone, Debug)]
pub struct WindowContext {
    /// K images `[3, h, w]` covering what the context region sees on every plane.
    pub images: Vec<Tensor<3>>,
    /// `mpi_to_view[k][d]`: context-region pixels of plane `d` to pixels of `images[k]`.
    pub mpi_to_view: Vec<Vec<Hom>>,
    pub width: usize,
    pub height: usize,
    /// Top-left of the model's input window in the context region's pixels.
    pub origin: (usize, usize),
}

/// A context region's RGBA `[D, 4, h, w]` and the window's top-left in it.
#[derive(Clone, Debug)]
pub struct ContextRgba {
    pub rgba: Tensor<4>,
    pub origin: (usize, usize),
}

impl ContextRgba {
    /// On the autodiff device (for a recomputed segment; a constant there).
    pub fn autodiff(&self) -> Self {
        Self {
            rgba: self.rgba.clone().autodiff(),
            origin: self.origin,
        }
    }
}

/// The RGBA that the views are rendered from for a window of `w x h` at `offset` in the model's input
/// window ([`window_rgba`]): the window's own RGBA (transparent outside it), or the context's with the
/// window's values in place; `origin` is the window's place in it.
#[derive(Clone, Debug)]
pub struct WindowRgba {
    pub rgba: Tensor<4>,
    pub origin: (usize, usize),
    pub size: (usize, usize),
}

/// [`WindowRgba`] of the window's `rgba` (once per update, for all views). Without a context the views
/// are rendered from `rgba` alone; with one, from the context's RGBA with the window's values in place,
/// so rays that leave the window see the context's content.
pub fn window_rgba(
    rgba: Tensor<4>,
    (w, h): (usize, usize),
    offset: (usize, usize),
    context: Option<&ContextRgba>,
) -> WindowRgba {
    match context {
        None => WindowRgba {
            rgba,
            origin: (0, 0),
            size: (w, h),
        },
        Some(c) => {
            let (x0, y0) = (c.origin.0 + offset.0, c.origin.1 + offset.1);
            let [d, _, ch, cw] = c.rgba.dims();
            assert!(
                x0 + w <= cw && y0 + h <= ch,
                "the window lies inside its context"
            );
            let full = c
                .rgba
                .clone()
                .slice_assign([0..d, 0..4, y0..y0 + h, x0..x0 + w], rgba);
            WindowRgba {
                rgba: full,
                origin: (x0, y0),
                size: (w, h),
            }
        }
    }
}

/// Gradient components (`[D, GRADIENT_CHANNELS, h, w]`) of one view on a window ([`window_rgba`]),
/// `mpi_to_view` relative to the window.
pub fn window_gradient_components(
    win: &WindowRgba,
    image: Tensor<3>,
    mpi_to_view: &[Hom],
) -> Tensor<4> {
    let (x0, y0) = win.origin;
    let (w, h) = win.size;
    if (x0, y0) == (0, 0) {
        return gradient_components(win.rgba.clone(), image, mpi_to_view, (0, 0, w, h));
    }
    let homs: Vec<Hom> = mpi_to_view
        .iter()
        .map(|m| crop_output(m, -(x0 as f64), -(y0 as f64)))
        .collect();
    gradient_components(win.rgba.clone(), image, &homs, (x0, y0, w, h))
}

impl ModelInputs {
    pub fn views(&self) -> usize {
        self.images.len()
    }
    pub fn planes(&self) -> usize {
        self.mpi_to_view.first().map_or(0, |h| h.len())
    }
}

/// The model's result on a window.
#[derive(Clone, Debug)]
pub struct ModelOutput {
    /// Premultiplied RGBA MPI `[D, 4, h, w]`, plane 0 the farthest.
    pub rgba: Tensor<4>,
    /// The final state `M_N` `[D, 4 + extra, h, w]`.
    pub state: Tensor<4>,
    /// Top-left of the output in the input window's pixels (non-zero with `shrink`): the output covers
    /// `[x0, x0 + w) x [y0, y0 + h)` of the window.
    pub offset: (usize, usize),
}

/// The whole learned-gradient-descent model.
#[derive(Module, Debug)]
pub struct DeepViewModel {
    pub nets: Vec<CoreNet>,
    /// Carried in the module as constants: RGBA + extra channels, views fixed by the weights (0 = any).
    pub state_channels: usize,
    pub fixed_views: usize,
    /// Temperature of the agreement prior added to net 0's output (0 = no prior; see config.rs).
    pub prior_temperature: f64,
    /// Cost aggregation radius of the prior (`DeepViewConfig::prior_radius`; 0 = per pixel).
    pub prior_radius: usize,
    /// The weight of the window's mean in the aggregated variance (`DeepViewConfig::prior_weight`).
    pub prior_weight: f64,
    /// Semi-global matching of the prior's costs (`DeepViewConfig::prior_smoothing`).
    #[module(skip)]
    pub prior_smoothing: Option<deepview_mpi::agreement::Smoothing>,
    /// The census term of the prior's matching cost (`DeepViewConfig::prior_census`).
    #[module(skip)]
    pub prior_census: Option<deepview_mpi::agreement::Census>,
    /// The leave-one-out weight of the prior's variance (`DeepViewConfig::prior_leave_one_out`).
    #[module(skip)]
    pub prior_leave_one_out: Option<f32>,
    /// The sample variance in the prior (`DeepViewConfig::prior_sample_variance`).
    #[module(skip)]
    pub prior_sample_variance: bool,
}

impl DeepViewModel {
    pub fn new(config: &DeepViewConfig, device: &Device) -> Self {
        let sc = config.state_channels();
        let nets = (0..config.nets())
            .map(|n| {
                let net = CoreNet::of_config(config, n, device);
                if config.init_prior.is_some() {
                    net.zero_output()
                } else {
                    net
                }
            })
            .collect();
        Self {
            nets,
            state_channels: sc,
            fixed_views: config.views.unwrap_or(0),
            prior_temperature: config.init_prior.unwrap_or(0.0),
            prior_radius: if config.init_prior.is_some() {
                config.prior_radius
            } else {
                0
            },
            prior_weight: config.prior_weight,
            prior_smoothing: if config.init_prior.is_some() {
                config.prior_smoothing
            } else {
                None
            },
            prior_census: if config.init_prior.is_some() {
                config.prior_census
            } else {
                None
            },
            prior_leave_one_out: if config.init_prior.is_some() {
                config.prior_leave_one_out
            } else {
                None
            },
            prior_sample_variance: config.init_prior.is_some() && config.prior_sample_variance,
        }
    }

    /// Whether the prior's costs need more than a window around each pixel (semi-global matching's
    /// paths) or a neighbourhood the fused GPU kernel does not compute (the census term): inference
    /// then computes the prior on the whole image, on the host, and tiles read their regions.
    pub fn prior_needs_whole_image(&self) -> bool {
        (self.prior_temperature > 0.0 && self.prior_smoothing.is_some())
            || self.active_census().is_some()
    }

    /// The census term the prior computes (none without the prior).
    pub fn active_census(&self) -> Option<deepview_mpi::agreement::Census> {
        self.prior_census.filter(|_| self.prior_temperature > 0.0)
    }

    /// The prior's cost aggregation.
    pub fn prior_aggregation(&self) -> Aggregation {
        Aggregation {
            radius: self.prior_radius,
            weight: self.prior_weight,
            smoothing: self.prior_smoothing,
            census: self.prior_census,
            leave_one_out: self.prior_leave_one_out,
            sample_variance: self.prior_sample_variance,
        }
    }

    /// Input of the initialisation net for one view on a region of the window: `[D, 4, h, w]` (PSV and
    /// validity). `mpi_to_view` is relative to the window; `region = (x0, y0, w, h)`.
    pub fn init_input(
        image: Tensor<3>,
        mpi_to_view: &[Hom],
        region: (usize, usize, usize, usize),
    ) -> Tensor<4> {
        let (x0, y0, w, h) = region;
        let homs: Vec<Hom> = mpi_to_view
            .iter()
            .map(|m| crop_output(m, x0 as f64, y0 as f64))
            .collect();
        plane_sweep_volume(image, &homs, h, w)
    }

    /// Run net `n` on per-view inputs (each `[D, C, h, w]`); update nets also get the state `[D, S, h, w]`
    /// concatenated. Returns the net's output `[D, S, h, w]` (the state for n = 0, the update otherwise).
    /// With a prior (`prior_temperature > 0`), net 0's output includes the agreement prior's logits.
    pub fn run_net(
        &self,
        n: usize,
        per_view: Vec<Tensor<4>>,
        state: Option<Tensor<4>>,
    ) -> Tensor<4> {
        self.run_net_with_prior(n, per_view, state, None)
    }

    /// [`Self::run_net`] with net 0's agreement prior given (its RGBA logits `[D, 4, h, w]` on the same
    /// region: the tiled inference cuts a smoothed prior, which reaches across the whole image, out of
    /// the whole image's) instead of computed from the inputs; `None`: computed.
    pub fn run_net_with_prior(
        &self,
        n: usize,
        per_view: Vec<Tensor<4>>,
        state: Option<Tensor<4>>,
        given: Option<Tensor<4>>,
    ) -> Tensor<4> {
        let k = per_view.len();
        // The prior as a state: its RGBA logits and zeros for the extra channels.
        let as_state = |p: Tensor<4>| {
            let [d, c, h, w] = p.dims();
            let extra = self.state_channels - c;
            if extra == 0 {
                p
            } else {
                let device = p.device();
                Tensor::cat(vec![p, Tensor::zeros([d, extra, h, w], &device)], 1)
            }
        };
        let with_prior = n == 0 && self.prior_temperature > 0.0;
        let given = given.filter(|_| with_prior).map(as_state);
        let prior_state = |per_view: &[Tensor<4>]| {
            as_state(agreement_prior_logits(
                per_view,
                self.prior_temperature,
                self.prior_aggregation(),
            ))
        };
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if crate::gpu::gpu_kernels(&per_view[0].device()) {
            // A given prior, or one the fused kernel cannot compute (smoothed, with a census term or
            // the leave-one-out variance), is added beside the fused input (see
            // `agreement_prior_logits`); otherwise the fused kernel computes it.
            let separate = match given {
                Some(p) => Some(p),
                None => (with_prior && !crate::gpu::prior_is_fused(self.prior_aggregation()))
                    .then(|| prior_state(&per_view)),
            };
            let prior = (with_prior && separate.is_none()).then_some((
                self.prior_temperature,
                self.state_channels,
                self.prior_aggregation(),
            ));
            let (x, prior) = crate::gpu::net_input(per_view, state, prior);
            let out = self.nets[n].forward(x, k);
            return match prior.or(separate) {
                Some(p) => p + out,
                None => out,
            };
        }
        let prior = match given {
            Some(p) => Some(p),
            None => with_prior.then(|| prior_state(&per_view)),
        };
        let x = per_view
            .into_iter()
            .map(|v| match &state {
                Some(s) => Tensor::cat(vec![v, s.clone()], 1),
                None => v,
            })
            .collect();
        let out = self.nets[n].forward(Tensor::cat(x, 0), k);
        match prior {
            Some(p) => p + out,
            None => out,
        }
    }

    /// Temperature of the agreement prior that fills a window's context: the model's own, or
    /// `psv-mean`'s default ([`CPU_PRIOR_TEMPERATURE`]) for a model without a prior.
    pub fn context_temperature(&self) -> f64 {
        if self.prior_temperature > 0.0 {
            self.prior_temperature
        } else {
            CPU_PRIOR_TEMPERATURE
        }
    }

    /// The agreement prior's RGBA on a window's context region (no parameters: nothing to
    /// differentiate).
    pub fn context_rgba(&self, context: &WindowContext) -> ContextRgba {
        let (w, h) = (context.width, context.height);
        let per_view: Vec<Tensor<4>> = context
            .images
            .iter()
            .zip(&context.mpi_to_view)
            .map(|(im, homs)| Self::init_input(im.clone(), homs, (0, 0, w, h)))
            .collect();
        ContextRgba {
            rgba: state_to_rgba(agreement_prior_logits(
                &per_view,
                self.context_temperature(),
                self.prior_aggregation(),
            )),
            origin: context.origin,
        }
    }

    /// The whole model on a window (see [`ModelInputs`]).
    pub fn forward(&self, inputs: &ModelInputs) -> ModelOutput {
        let k = inputs.views();
        let context = inputs.context.as_ref().map(|c| self.context_rgba(c));
        let (mut w, mut h) = (inputs.width, inputs.height);
        let mut homs = inputs.mpi_to_view.clone();
        let mut offset = (0usize, 0usize);
        let mut state: Option<Tensor<4>> = None;
        for n in 0..self.nets.len() {
            // The current MPI's RGBA, once for all views.
            let win = state
                .as_ref()
                .map(|s| window_rgba(state_to_rgba(s.clone()), (w, h), offset, context.as_ref()));
            let per_view: Vec<Tensor<4>> = (0..k)
                .map(|v| match &win {
                    None => Self::init_input(inputs.images[v].clone(), &homs[v], (0, 0, w, h)),
                    Some(win) => {
                        window_gradient_components(win, inputs.images[v].clone(), &homs[v])
                    }
                })
                .collect();
            let out = self.run_net(n, per_view, state.clone());
            let mut s = match state {
                None => out,
                Some(s) => s + out,
            };
            if inputs.shrink {
                let m = self.margin(n);
                let m = m
                    .min((w.saturating_sub(1)) / 2)
                    .min((h.saturating_sub(1)) / 2)
                    & !1;
                if m > 0 {
                    w -= 2 * m;
                    h -= 2 * m;
                    s = crop_window(s, m, h, w);
                    offset = (offset.0 + m, offset.1 + m);
                    for hv in homs.iter_mut() {
                        for hom in hv.iter_mut() {
                            *hom = crop_output(hom, m as f64, m as f64);
                        }
                    }
                }
            }
            state = Some(s);
        }
        let state = state.expect("at least one net");
        ModelOutput {
            rgba: state_to_rgba(state.clone()),
            state,
            offset,
        }
    }

    /// Receptive-field margin of net `n` (same rule as [`DeepViewConfig::net_margin`]).
    pub fn margin(&self, n: usize) -> usize {
        let prior = if n == 0 && self.prior_temperature > 0.0 {
            self.prior_radius
        } else {
            0
        };
        self.conv_margin(n).max(prior).next_multiple_of(2)
    }

    /// The receptive-field margin of net `n`'s convolutions alone (without the prior's aggregation:
    /// the CPU engine aggregates on whole planes).
    pub fn conv_margin(&self, n: usize) -> usize {
        let r = self.nets[n].input.len() + self.nets[n].stages.len() + 2;
        let m = if self.nets[n].unet { 2 * r + 4 } else { r };
        m.next_multiple_of(2)
    }

    /// Sum of the margins of nets `from..`.
    pub fn margin_from(&self, from: usize) -> usize {
        (from..self.nets.len()).map(|n| self.margin(n)).sum()
    }
}

/// Synthetic inputs for tests and benchmarks: K cameras on a small circle around a reference camera
/// looking down +z, random images, planes between depth 1 and 10.
pub fn synthetic_inputs(
    views: usize,
    planes: usize,
    h: usize,
    w: usize,
    device: &Device,
) -> ModelInputs {
    synthetic_inputs_with_baseline(views, planes, h, w, 0.05, device)
}

/// [`synthetic_inputs`] with the cameras on a circle of radius `baseline` (the reference's focal length
/// is `w` pixels: `baseline * w` px of disparity at depth 1).
pub fn synthetic_inputs_with_baseline(
    views: usize,
    planes: usize,
    h: usize,
    w: usize,
    baseline: f64,
    device: &Device,
) -> ModelInputs {
    use burn::tensor::Distribution;
    use deepview_geometry::{
        Camera, DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths, plane_homography,
    };
    let reference = Camera::new(
        w as u32,
        h as u32,
        Intrinsics::centred(w as f64, w as u32, h as u32),
        Pose::IDENTITY,
    );
    let depths = plane_depths(1.0, 10.0, planes, PlaneSpacing::InverseDepth).expect("valid depths");
    let mut images = Vec::new();
    let mut mpi_to_view = Vec::new();
    for k in 0..views {
        let t = k as f64 / views as f64 * std::f64::consts::TAU;
        let cam = Camera::new(
            w as u32,
            h as u32,
            reference.intrinsics,
            Pose::from_center(
                DMat3::IDENTITY,
                DVec3::new(baseline * t.cos(), baseline * t.sin(), 0.0),
            ),
        );
        images.push(crate::rng::random::<3, _>(
            [3, h, w],
            Distribution::Uniform(0.0, 1.0),
            device,
        ));
        mpi_to_view.push(
            depths
                .iter()
                .map(|&d| plane_homography(&reference, &cam, d).to_row_major())
                .collect(),
        );
    }
    ModelInputs {
        images,
        mpi_to_view,
        height: h,
        width: w,
        shrink: false,
        context: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small_config() -> DeepViewConfig {
        DeepViewConfig {
            features_large: 6,
            features_small: 4,
            updates: 2,
            unet_nets: 1,
            init_prior: None,
            ..DeepViewConfig::preset("cpu").unwrap()
        }
    }

    fn max_diff(a: Tensor<4>, b: Tensor<4>) -> f32 {
        (a - b).abs().max().into_scalar()
    }

    /// The U-Net's upsampling from slices and sums (used where burn's `interpolate` has no backward)
    /// equals burn's bilinear `interpolate` to twice the size, outputs and input gradients, on sizes of 1,
    /// odd and even; and on a ramp it gives the analytic sample positions `(j + 0.5) / 2 - 0.5`.
    #[test]
    fn upsample2x_bilinear_is_burns_interpolate() {
        let ad = Device::flex().autodiff();
        for [n, c, h, w] in [
            [1, 1, 1, 1],
            [2, 3, 1, 4],
            [1, 2, 5, 7],
            [3, 1, 6, 2],
            [1, 4, 9, 8],
        ] {
            let x = crate::rng::random::<4, _>(
                [n, c, h, w],
                burn::tensor::Distribution::Uniform(-1.0, 1.0),
                &ad,
            );
            let seed = crate::rng::random::<4, _>(
                [n, c, 2 * h, 2 * w],
                burn::tensor::Distribution::Uniform(-1.0, 1.0),
                &ad,
            );
            let xa = x.clone().require_grad();
            let ya = upsample2x_bilinear(xa.clone());
            let xb = x.clone().require_grad();
            let opts = InterpolateOptions::new(InterpolateMode::Bilinear)
                .with_align_corners(false)
                .with_output_size([2 * h, 2 * w]);
            let yb = interpolate(xb.clone(), opts);
            assert_eq!(ya.dims(), [n, c, 2 * h, 2 * w]);
            let e = max_diff(ya.clone().inner(), yb.clone().inner());
            assert!(e < 1e-6, "{n}x{c}x{h}x{w} output: {e}");
            let ga = (ya * seed.clone()).sum().backward();
            let gb = (yb * seed).sum().backward();
            let e = max_diff(xa.grad(&ga).unwrap(), xb.grad(&gb).unwrap());
            assert!(e < 1e-5, "{n}x{c}x{h}x{w} gradient: {e}");
        }
        // A ramp along the columns: interior outputs sample at (j + 0.5) / 2 - 0.5, clamped to 0..w-1.
        let w = 6;
        let ramp: Vec<f32> = (0..w).map(|i| i as f32).collect();
        let x = Tensor::<1>::from_floats(ramp.as_slice(), &Device::flex()).reshape([1, 1, 1, w]);
        let y = upsample2x_bilinear(x)
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        for (j, v) in y.iter().take(2 * w).enumerate() {
            let expect = ((j as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, (w - 1) as f32);
            assert!(
                (v - expect).abs() < 1e-6,
                "column {j}: {v} against {expect}"
            );
        }
    }

    /// The kernels (fused inference on `flex`, per-layer op with its backward under autodiff) against
    /// burn's conv2d + ELU: outputs, and gradients of the input and of every weight, on odd sizes, 1 and
    /// 12 views, U-Net nets and 64 features.
    #[test]
    fn kernels_match_burn_ops() {
        let ad = Device::flex().autodiff();
        // With many features and views, a feature of two views can agree to f32 rounding somewhere,
        // and the max over views may then pick either (both right): its gradient then flows through
        // the other view and spreads over the receptive field. Gradients are compared where that has
        // negligible probability (8 features with 12 views, or one view; a 12-view U-Net with 16 features
        // failed 1 run in 6 by such a tie, at 3e-3); outputs everywhere.
        for (case_seed, (cin, f, stages, unet, k, d, h, w, grads)) in [
            (4, 8, 1, false, 4, 3, 17, 23, true),
            (19, 8, 1, false, 1, 2, 9, 12, true),
            (19, 8, 1, false, 12, 2, 15, 11, true),
            (19, 16, 3, true, 12, 2, 15, 11, false),
            (4, 64, 3, true, 1, 2, 13, 18, true),
            (19, 64, 3, false, 1, 2, 13, 18, true),
            (4, 64, 3, true, 4, 2, 13, 18, false),
            (11, 5, 2, false, 3, 1, 1, 3, true),
        ]
        .into_iter()
        .enumerate()
        {
            // Fixed draws (under the generator's lock: other tests draw too), so a near-tie of
            // the max over views or an ELU input at its kink is there every run or never.
            let (net, x, seed) = crate::rng::seeded(&ad, 40 + case_seed as u64, || {
                let net = crate::rng::module(|| CoreNet::new(cin, f, 8, stages, unet, &ad));
                crate::rng::materialize(&net);
                let x = crate::rng::random::<4, _>(
                    [k * d, cin, h, w],
                    burn::tensor::Distribution::Uniform(-1.0, 1.0),
                    &ad,
                );
                let seed = crate::rng::random::<4, _>(
                    [d, 8, h, w],
                    burn::tensor::Distribution::Uniform(-1.0, 1.0),
                    &ad,
                );
                (net, x, seed)
            });
            let rel = |a: Tensor<4>, b: Tensor<4>| {
                let s: f32 = b.clone().abs().max().into_scalar();
                let e: f32 = (a - b).abs().max().into_scalar();
                e / s.max(1e-6)
            };
            // Inference: fused engine on the plain device.
            let plain = net.valid();
            let fused = plain.forward(x.clone().inner(), k);
            let reference = plain.forward_burn(x.clone().inner(), k);
            assert_eq!(fused.dims(), [d, 8, h, w]);
            let e = rel(fused, reference.clone());
            assert!(e < 1e-5, "fused {cin} {f} {unet} {k}x{d} {h}x{w}: {e}");
            // Training: the fused core-net op with its own backward (burn's pooling and upsampling
            // around it for U-Net nets).
            let xa = x.clone().require_grad();
            let ya = net.forward(xa.clone(), k);
            let e = rel(ya.clone().inner(), reference);
            assert!(e < 1e-5, "training forward: {e}");
            if !grads {
                continue;
            }
            let ga = (ya * seed.clone()).sum().backward();
            let xb = x.clone().require_grad();
            let gb = (net.forward_burn(xb.clone(), k) * seed).sum().backward();
            let case = format!("{cin} {f} {unet} {k}x{d} {h}x{w}");
            let e = rel(xa.grad(&ga).unwrap(), xb.grad(&gb).unwrap());
            assert!(e < 1e-4, "input gradient {case}: {e}");
            for (i, c) in net
                .input
                .iter()
                .chain(&net.stages)
                .chain([&net.head, &net.out])
                .enumerate()
            {
                let e = rel(c.weight.grad(&ga).unwrap(), c.weight.grad(&gb).unwrap());
                assert!(e < 1e-4, "conv {i} weight gradient {case}: {e}");
                let b = c.bias.as_ref().expect("bias");
                let (ba, bb): (Tensor<1>, Tensor<1>) = (b.grad(&ga).unwrap(), b.grad(&gb).unwrap());
                let e = rel(ba.reshape([1, 1, 1, -1]), bb.reshape([1, 1, 1, -1]));
                assert!(e < 1e-4, "conv {i} bias gradient {case}: {e}");
            }
        }
    }

    #[test]
    fn order_invariant_in_views() {
        let dev = Device::flex();
        let model = crate::rng::module(|| DeepViewModel::new(&small_config(), &dev));
        let inputs = synthetic_inputs(4, 5, 17, 21, &dev);
        let out = model.forward(&inputs);
        assert_eq!(out.rgba.dims(), [5, 4, 17, 21]);
        let mut perm = inputs.clone();
        let order = [2, 0, 3, 1];
        perm.images = order.iter().map(|&i| inputs.images[i].clone()).collect();
        perm.mpi_to_view = order
            .iter()
            .map(|&i| inputs.mpi_to_view[i].clone())
            .collect();
        let out2 = model.forward(&perm);
        assert!(max_diff(out.rgba.clone(), out2.rgba) < 1e-5);
        // The output is a valid premultiplied MPI.
        let v: Vec<f32> = out.rgba.into_data().try_to_vec().unwrap();
        assert!(v.iter().all(|x| (0.0..=1.0).contains(x)));
    }

    #[test]
    fn any_view_count_plane_count_and_size() {
        let dev = Device::flex();
        let model = crate::rng::module(|| DeepViewModel::new(&small_config(), &dev));
        for (k, d, h, w) in [(2, 3, 16, 16), (5, 4, 13, 19), (3, 1, 9, 30)] {
            let out = model.forward(&synthetic_inputs(k, d, h, w, &dev));
            assert_eq!(out.rgba.dims(), [d, 4, h, w]);
            let s: f32 = out.rgba.sum().into_scalar();
            assert!(s.is_finite());
        }
    }

    #[test]
    fn shrinking_window_crops_by_the_margins() {
        let dev = Device::flex();
        let cfg = small_config();
        let model = crate::rng::module(|| DeepViewModel::new(&cfg, &dev));
        let total = cfg.margin_from(0);
        assert_eq!(total, model.margin_from(0));
        let (h, w) = (2 * total + 6, 2 * total + 8);
        let mut inputs = synthetic_inputs(2, 3, h, w, &dev);
        inputs.shrink = true;
        let out = model.forward(&inputs);
        assert_eq!(out.rgba.dims(), [3, 4, 6, 8]);
        assert_eq!(out.offset, (total, total));
    }

    /// With the initialisation net's output zeroed, the state entering the update net is the agreement
    /// prior everywhere, which is what a window's context holds: the training window with its context
    /// then computes exactly the full-image MPI on its output region, although the views' rays leave the
    /// window (19 px of disparity against 6 px margins). Without the context it does not.
    #[test]
    fn window_context_makes_the_training_window_exact() {
        let dev = Device::flex();
        let cfg = DeepViewConfig::preset("cpu").unwrap();
        assert!(cfg.init_prior.is_some() && cfg.updates == 1);
        let (big_w, big_h, d) = (64, 60, 6);
        // Fixed draws, under the generator's lock (other tests draw too).
        let (model, full_inputs) = crate::rng::seeded(&dev, 21, || {
            let mut model = crate::rng::module(|| DeepViewModel::new(&cfg, &dev));
            // A random update net (the prior's presets start with zeroed outputs).
            model.nets[1] = CoreNet::of_config(&cfg, 1, &dev);
            crate::rng::materialize(&model);
            let inputs = synthetic_inputs_with_baseline(3, d, big_h, big_w, 0.3, &dev);
            (model, inputs)
        });
        let full = model.forward(&full_inputs).rgba;
        let (x0, y0, w, h) = (18usize, 14usize, 30usize, 34usize);
        let window = |context: bool| ModelInputs {
            images: full_inputs.images.clone(),
            mpi_to_view: full_inputs
                .mpi_to_view
                .iter()
                .map(|hv| {
                    hv.iter()
                        .map(|m| crop_output(m, x0 as f64, y0 as f64))
                        .collect()
                })
                .collect(),
            width: w,
            height: h,
            shrink: true,
            context: context.then(|| WindowContext {
                images: full_inputs.images.clone(),
                mpi_to_view: full_inputs.mpi_to_view.clone(),
                width: big_w,
                height: big_h,
                origin: (x0, y0),
            }),
        };
        let total = model.margin_from(0);
        let expected =
            full.narrow(2, y0 + total, h - 2 * total)
                .narrow(3, x0 + total, w - 2 * total);
        let with = model.forward(&window(true));
        assert_eq!(with.offset, (total, total));
        // f32 rounding of the shifted homographies, amplified by random images and weights: 12 runs gave
        // 3e-5..1.2e-4 with the context, 0.9e-3..2.3e-3 without (at least 7.6x apart).
        let e = max_diff(with.rgba, expected.clone());
        assert!(e < 5e-4, "with the context: {e}");
        let e0 = max_diff(model.forward(&window(false)).rgba, expected);
        assert!(e0 > 3.0 * e, "without the context: {e0} (with: {e})");
    }

    #[test]
    fn unet_net_is_translation_equivariant_by_even_shifts() {
        // The property tiled inference relies on: a U-Net core net's output on a crop (at an even offset,
        // away from the crop border by its margin) equals the crop of its output.
        let dev = Device::flex();
        let net = crate::rng::module(|| CoreNet::new(3, 5, 8, 2, true, &dev));
        let x = crate::rng::random::<4, _>(
            [6, 3, 60, 66],
            burn::tensor::Distribution::Uniform(-1.0, 1.0),
            &dev,
        );
        let full = net.forward(x.clone(), 2);
        let m = 2 * (2 + 4 + 2) + 4;
        let (x0, y0) = (2usize, 4usize);
        let (h, w) = (60 - y0, 66 - x0 - 1);
        let crop = net.forward(x.narrow(2, y0, h).narrow(3, x0, w), 2);
        let a = full
            .narrow(2, y0 + m, h - 2 * m)
            .narrow(3, x0 + m, w - 2 * m);
        let b = crop.narrow(2, m, h - 2 * m).narrow(3, m, w - 2 * m);
        assert!(max_diff(a, b) < 1e-5);
    }
}
