//! Network configuration and the paper's presets (Table 1 of the paper, DESIGN.md section 4).

/// The census term of the prior's matching cost ([`DeepViewConfig::prior_census`]).
pub use deepview_mpi::agreement::Census;
/// Semi-global matching penalties of the prior ([`DeepViewConfig::prior_smoothing`]).
pub use deepview_mpi::agreement::Smoothing;
/// A weight [`DeepViewConfig::prior_leave_one_out`] takes, parsed.
pub use deepview_mpi::agreement::parse_leave_one_out;
use serde::{Deserialize, Serialize};

/// Errors of a configuration.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ConfigError {
    #[error(
        "unknown preset {0:?} (known: paper-kalantari, paper-spaces-4view, paper-spaces-12view, cpu, cpu-large)"
    )]
    UnknownPreset(String),
    #[error("invalid network config: {0}")]
    Invalid(String),
}

/// Temperature `s` of the `cpu` preset's agreement prior (the `psv-mean` baseline's default).
pub const CPU_PRIOR_TEMPERATURE: f64 = deepview_mpi::agreement::TEMPERATURE;

/// The architecture and the plane counts of a DeepView model.
///
/// The model is `1 + updates` nets: net 0 (initialisation, on plane sweep volumes) and `updates` update
/// nets (on gradient components). Every net is the same core CNN (see `network.rs`): 2 per-view convs,
/// `max_pool_stages` x (max over views, concat, 2 convs), a final max over views, a conv and a linear
/// conv to `4 + extra_channels` outputs. Nets `0..large_nets` use `features_large` features, the others
/// `features_small` ("64/16"); nets `0..unet_nets` run the core at half resolution (one-level U-Net).
///
/// Memory: the paper discards activations inside each per-iteration net and recomputes them on the
/// backward pass. burn's `.gradient_checkpointing()` does not drop conv activations, so `deepview train
/// --recompute` does it by hand (`deepview-train/src/recompute.rs`: segment-wise VJPs, one net's
/// activations live at a time; gradients equal the full backward).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct DeepViewConfig {
    /// Preset name (informational).
    pub name: String,
    /// A fixed number of input views the weights were trained for, or `None` (any number; the
    /// architecture itself accepts any K).
    pub views: Option<usize>,
    /// Plane counts used for training and (by default) inference.
    pub train_planes: usize,
    pub infer_planes: usize,
    /// Number of update nets (LGD iterations after the initialisation; paper: 3).
    pub updates: usize,
    pub features_large: usize,
    pub features_small: usize,
    /// Nets `0..large_nets` use `features_large`.
    pub large_nets: usize,
    /// Nets `0..unet_nets` run at half resolution (downsample in, bilinear upsample out).
    pub unet_nets: usize,
    /// Channels carried between iterations besides RGBA logits (paper: 4).
    pub extra_channels: usize,
    /// Number of (max over views, concat, 2 convs) stages (DESIGN.md: 3).
    pub max_pool_stages: usize,
    /// **Deviation from the paper (CPU training only):** a classical prior for the initial state. With
    /// `Some(s)`, `M_0 = prior + N_0(PSVs)` where the prior's RGBA logits are `logit(clamp(mean colour))`
    /// and `logit(clamp(alpha))` of the cross-view agreement MPI (the `psv-mean` baseline of
    /// `deepview_mpi::agreement`: mean of the valid PSV samples over views; depth weights = softmax
    /// over planes of `-variance / s`, turned into back-to-front alphas whose visible shares equal the
    /// weights), and 0 for the extra channels. The last conv of every net is zero-initialised, so an
    /// untrained model outputs exactly the agreement MPI and training learns residual corrections (learned
    /// gradient descent refining a classical estimate). It makes training useful within minutes on 2 CPU
    /// cores, where the paper's from-scratch initialisation needs days of GPU time. `None` (the default,
    /// and every `paper-*` preset): the paper's `M_0 = N_0(PSVs)`.
    #[serde(default)]
    pub init_prior: Option<f64>,
    /// Cost aggregation of the agreement prior (with `init_prior`): each plane's colour variance is
    /// averaged over the seen pixels of the `(2r+1) x (2r+1)` window around each pixel before the softmax
    /// over planes (`deepview_mpi::agreement::aggregate_seen`). 0 (the default, and every config written
    /// before it existed): per pixel, exactly `psv-mean`'s MPI.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub prior_radius: usize,
    /// The weight of the window's mean in the aggregated variance (the rest is the pixel's own), in
    /// `0..=1`; default 1.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub prior_weight: f64,
    /// The image size (larger side, pixels) up to which `prior_radius` applies as it is: on larger images
    /// the radius grows in proportion ([`Self::prior_radius_at`]), so the window covers the same share
    /// of the scene as on the images the model was trained on. `None` (the default, and every config
    /// written before it existed): the same radius at every size.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prior_radius_size: Option<u32>,
    /// Semi-global matching of the prior's costs after the window (penalties in logit units;
    /// `deepview_mpi::agreement::smooth_semi_global`): depth that stays on a plane, or one plane away,
    /// from pixel to pixel along 8 image directions is favoured, which fills textureless surfaces from
    /// their textured surroundings. It reaches across the whole image, so inference computes the prior on
    /// the whole image (tiles read it) and training on each window. `None` (the default, and every
    /// config written before it existed): no smoothing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prior_smoothing: Option<Smoothing>,
    /// A census term in the prior's matching cost (`deepview_mpi::agreement::Census`): `weight` times
    /// the fraction of the views' census bits (over the `(2r+1)^2` window of `radius`) that differ is
    /// added to each plane point's colour variance, a cost that ignores the views' differences in
    /// exposure. It needs a window's neighbours, so inference computes the prior on the whole image
    /// (tiles read it). `None` (the default, and every config written before it existed): the
    /// variance alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prior_census: Option<Census>,
    /// Occlusion-robust variance in the prior's matching cost: where three or more views see a plane
    /// point, its colour variance becomes `(1 - b)` times itself plus `b` times the least variance of
    /// the samples left when one view is left out (`deepview_mpi::agreement::leave_one_out_variance`;
    /// `0 < b <= 1`). Per pixel, like the variance. `None` (the default, and every config written
    /// before it existed): the variance of all the views.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prior_leave_one_out: Option<f32>,
    /// The sample variance in the prior's matching cost: the variance (after the leave-one-out blend)
    /// of a point `n >= 2` views see is scaled by `n / (n - 1)`. `false` (the default, and every config
    /// written before it existed): the population variance.
    #[serde(default, skip_serializing_if = "is_false")]
    pub prior_sample_variance: bool,
    /// The MPI grid inference makes by default, in MPI pixels per input pixel along each axis (`infer
    /// --mpi-scale`, which overrides it; 1..=4): a finer grid blurs the plane sweep's samples less, at
    /// about its square in time and memory. `None` (the default, and every config written before it
    /// existed): the inputs' own grid (1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub infer_mpi_scale: Option<f64>,
}

fn is_false(b: &bool) -> bool {
    !*b
}

fn is_zero(r: &usize) -> bool {
    *r == 0
}

fn one() -> f64 {
    1.0
}

fn is_one(w: &f64) -> bool {
    *w == 1.0
}

impl DeepViewConfig {
    /// The prior's cost aggregation.
    pub fn prior_aggregation(&self) -> deepview_mpi::agreement::Aggregation {
        deepview_mpi::agreement::Aggregation {
            radius: self.prior_radius,
            weight: self.prior_weight,
            smoothing: self.prior_smoothing,
            census: self.prior_census,
            leave_one_out: self.prior_leave_one_out,
            sample_variance: self.prior_sample_variance,
        }
    }

    /// The prior's aggregation radius on images whose larger side is `size` pixels: `prior_radius` up to
    /// `prior_radius_size`, above it `prior_radius * size / prior_radius_size` rounded to the nearest
    /// integer (at most [`MAX_PRIOR_RADIUS`]).
    pub fn prior_radius_at(&self, size: u32) -> usize {
        match self.prior_radius_size {
            Some(base) if base > 0 && size > base && self.prior_radius > 0 => {
                let r = (self.prior_radius as f64 * size as f64 / base as f64).round() as usize;
                r.clamp(self.prior_radius, MAX_PRIOR_RADIUS)
            }
            _ => self.prior_radius,
        }
    }

    /// The prior's aggregation radius on images whose larger side is `size` pixels in an MPI with `scale`
    /// MPI pixels per image pixel along each axis (`--mpi-scale`): [`Self::prior_radius_at`] times `scale`,
    /// rounded (at most [`MAX_PRIOR_RADIUS`]), so the window covers the same part of the scene on the
    /// finer grid.
    pub fn prior_radius_on(&self, size: u32, scale: f64) -> usize {
        let r = self.prior_radius_at(size);
        if scale == 1.0 || r == 0 {
            return r;
        }
        ((r as f64 * scale).round() as usize).clamp(1, MAX_PRIOR_RADIUS)
    }

    /// This config with the prior's radius of images whose larger side is `size` pixels
    /// ([`Self::prior_radius_at`]): what the model runs with on them (its margins included).
    pub fn at_image_size(&self, size: u32) -> DeepViewConfig {
        let mut c = self.clone();
        c.prior_radius = self.prior_radius_at(size);
        c
    }
}

/// The largest aggregation radius a config may ask for.
pub const MAX_PRIOR_RADIUS: usize = 64;

/// The MPI grid scales inference takes (`infer_mpi_scale`, `--mpi-scale`): MPI pixels per input pixel
/// along each axis (a coarser grid would alias: downscale the inputs instead).
pub const MPI_SCALES: std::ops::RangeInclusive<f64> = 1.0..=4.0;

/// The largest feature count of a net a config may ask for.
pub const MAX_FEATURES: usize = 1024;
/// The most update nets a config may ask for.
pub const MAX_UPDATES: usize = 16;
/// The most planes a config may ask for (`--planes` takes up to 1024 too).
pub const MAX_PLANES: usize = 1024;

impl DeepViewConfig {
    /// A preset by name: `paper-kalantari`, `paper-spaces-4view`, `paper-spaces-12view`, `cpu`, `cpu-large`.
    pub fn preset(name: &str) -> Result<Self, ConfigError> {
        let paper = |name: &str, views, train, infer, unet| DeepViewConfig {
            name: name.to_string(),
            views: Some(views),
            train_planes: train,
            infer_planes: infer,
            updates: 3,
            features_large: 64,
            features_small: 16,
            large_nets: 2,
            unet_nets: unet,
            extra_channels: 4,
            max_pool_stages: 3,
            init_prior: None,
            prior_radius: 0,
            prior_weight: 1.0,
            prior_radius_size: None,
            prior_smoothing: None,
            prior_census: None,
            prior_leave_one_out: None,
            prior_sample_variance: false,
            infer_mpi_scale: None,
        };
        Ok(match name {
            "paper-kalantari" => paper(name, 4, 28, 28, 0),
            "paper-spaces-4view" => paper(name, 4, 64, 80, 2),
            "paper-spaces-12view" => paper(name, 12, 64, 80, 2),
            // Small enough to train usefully on 2 CPU cores; any number of views. 2 nets, 8 features,
            // 1 max-pool stage (receptive-field margin 6 px per net) and the agreement prior (see
            // `init_prior`). Trained with as many planes as inference uses (32): residuals learned on 8
            // planes transferred badly to 32 (docs/TRAINING.md). A step (VGG loss, 16x16 crop, 2..4
            // views, 32 planes) takes ~1.4 s on 2 free cores; inference of a 560x433 32-plane MPI from
            // 4 views ~1 min of CPU.
            "cpu" => DeepViewConfig {
                name: name.to_string(),
                views: None,
                train_planes: 32,
                infer_planes: 32,
                updates: 1,
                features_large: 8,
                features_small: 8,
                large_nets: 2,
                unet_nets: 0,
                extra_channels: 4,
                max_pool_stages: 1,
                init_prior: Some(CPU_PRIOR_TEMPERATURE),
                prior_radius: 0,
                prior_weight: 1.0,
                prior_radius_size: None,
                prior_smoothing: None,
                prior_census: None,
                prior_leave_one_out: None,
                prior_sample_variance: false,
                infer_mpi_scale: None,
            },
            // The `cpu` preset grown for the fast kernels (issue: generalising model): 12 features and 2
            // update nets (3 nets, the paper has 4), the same prior and plane counts. A training step
            // (VGG loss, 16x16 crop, 4 views, 32 planes) is ~3x the `cpu` preset's.
            "cpu-large" => DeepViewConfig {
                name: name.to_string(),
                views: None,
                train_planes: 32,
                infer_planes: 32,
                updates: 2,
                features_large: 12,
                features_small: 12,
                large_nets: 3,
                unet_nets: 0,
                extra_channels: 4,
                max_pool_stages: 1,
                init_prior: Some(CPU_PRIOR_TEMPERATURE),
                prior_radius: 0,
                prior_weight: 1.0,
                prior_radius_size: None,
                prior_smoothing: None,
                prior_census: None,
                prior_leave_one_out: None,
                prior_sample_variance: false,
                infer_mpi_scale: None,
            },
            other => return Err(ConfigError::UnknownPreset(other.to_string())),
        })
    }

    /// Validate the configuration (see the limits below).
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |m: &str| Err(ConfigError::Invalid(m.to_string()));
        if self.features_large == 0 || self.features_small == 0 {
            return bad("feature counts must be positive");
        }
        if self.train_planes == 0 || self.infer_planes == 0 {
            return bad("plane counts must be positive");
        }
        if self.views == Some(0) {
            return bad("a fixed view count must be positive");
        }
        // It divides colour variances (0..1) into logits: below 1e-6 they leave f32's range and the
        // MPI comes out transparent (1e-308 did, without an error).
        if let Some(s) = self.init_prior
            && !(s.is_finite() && (1e-6..=1e6).contains(&s))
        {
            return bad("the init prior's temperature must lie in 1e-6..1e6");
        }
        if self.prior_radius > MAX_PRIOR_RADIUS {
            return bad(&format!(
                "the prior's aggregation radius {} is above {MAX_PRIOR_RADIUS}",
                self.prior_radius
            ));
        }
        if !(0.0..=1.0).contains(&self.prior_weight) {
            return bad(&format!(
                "the prior's aggregation weight {} is not within 0..=1",
                self.prior_weight
            ));
        }
        if self.prior_radius_size == Some(0) {
            return bad("the prior's radius size must be positive");
        }
        if self.prior_radius > 0 && self.init_prior.is_none() {
            return bad("an aggregation radius needs the agreement prior (init_prior)");
        }
        if let Some(s) = self.prior_smoothing {
            if !s.is_valid() {
                return bad(&format!(
                    "the prior's smoothing penalties ({}, {}) must be finite with 0 <= p1 <= p2",
                    s.p1, s.p2
                ));
            }
            if self.init_prior.is_none() {
                return bad("prior smoothing needs the agreement prior (init_prior)");
            }
        }
        if let Some(c) = self.prior_census {
            if !c.is_valid() {
                return bad(&format!(
                    "the prior's census term (weight {}, radius {}) needs a finite weight > 0 and a \
                     radius from 1 to {}",
                    c.weight,
                    c.radius,
                    Census::MAX_RADIUS
                ));
            }
            if self.init_prior.is_none() {
                return bad("a census term needs the agreement prior (init_prior)");
            }
        }
        if let Some(b) = self.prior_leave_one_out {
            if !deepview_mpi::agreement::leave_one_out_weight_is_valid(b) {
                return bad(&format!(
                    "the prior's leave-one-out weight {b} must be above 0 and at most 1"
                ));
            }
            if self.init_prior.is_none() {
                return bad("a leave-one-out weight needs the agreement prior (init_prior)");
            }
        }
        if let Some(s) = self.infer_mpi_scale
            && !MPI_SCALES.contains(&s)
        {
            return bad(&format!(
                "the inference MPI scale {s} is not within 1..=4 (MPI pixels per input pixel)"
            ));
        }
        if self.prior_sample_variance && self.init_prior.is_none() {
            return bad("the sample variance needs the agreement prior (init_prior)");
        }
        if self.max_pool_stages == 0 {
            return bad("at least one max-pool stage is needed");
        }
        // Beyond these no machine builds the model (the paper's largest preset: 64 features, 3 updates, 4
        // pool stages, 128 planes): a config asking for more is damaged, not ambitious.
        let limits = [
            (self.features_large, MAX_FEATURES, "features_large"),
            (self.features_small, MAX_FEATURES, "features_small"),
            (self.updates, MAX_UPDATES, "updates"),
            (self.large_nets, MAX_UPDATES + 1, "large_nets"),
            (self.unet_nets, MAX_UPDATES + 1, "unet_nets"),
            (self.extra_channels, MAX_FEATURES, "extra_channels"),
            (self.max_pool_stages, 8, "max_pool_stages"),
            (self.train_planes, MAX_PLANES, "train_planes"),
            (self.infer_planes, MAX_PLANES, "infer_planes"),
            (self.views.unwrap_or(1), 64, "views"),
        ];
        if let Some((v, max, name)) = limits.iter().find(|(v, max, _)| v > max) {
            return Err(ConfigError::Invalid(format!(
                "{name} {v} is more than {max}"
            )));
        }
        Ok(())
    }

    /// Total number of nets (initialisation + updates).
    pub fn nets(&self) -> usize {
        1 + self.updates
    }

    /// Channels of the MPI state `M_n`: RGBA logits and the extra channels.
    pub fn state_channels(&self) -> usize {
        4 + self.extra_channels
    }

    pub fn features(&self, net: usize) -> usize {
        if net < self.large_nets {
            self.features_large
        } else {
            self.features_small
        }
    }

    pub fn unet(&self, net: usize) -> bool {
        net < self.unet_nets
    }

    /// Number of 3x3 convolutions in one core net.
    pub fn convs_per_net(&self) -> usize {
        2 + 2 * self.max_pool_stages + 2
    }

    /// Receptive-field radius of net `net` in MPI pixels (how far an output pixel sees), rounded up to
    /// an even number so crops by it keep the U-Net's 2x2 grid aligned. U-Net nets: `2 r + 4`
    /// (downsampling by 2 and the bilinear upsample's extra texel on each side).
    /// Net 0 with an aggregated prior reaches at least the aggregation radius (its output's prior at a
    /// pixel reads the variances `prior_radius` away; its convolutions, their own margin).
    pub fn net_margin(&self, net: usize) -> usize {
        let r = self.convs_per_net();
        let m = if self.unet(net) { 2 * r + 4 } else { r };
        let prior = if net == 0 && self.init_prior.is_some() {
            self.prior_radius
        } else {
            0
        };
        m.max(prior).next_multiple_of(2)
    }

    /// Sum of [`Self::net_margin`] over nets `from..`.
    pub fn margin_from(&self, from: usize) -> usize {
        (from..self.nets()).map(|n| self.net_margin(n)).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Smoothing penalties round-trip through config.json, configs without them load without, and bad
    /// ones (or smoothing without the prior) are refused.
    #[test]
    fn prior_smoothing_in_the_config() {
        let cpu = DeepViewConfig::preset("cpu").unwrap();
        assert!(cpu.init_prior.is_some() && cpu.prior_smoothing.is_none());
        let cfg = DeepViewConfig {
            prior_smoothing: Some(Smoothing { p1: 2.0, p2: 64.0 }),
            ..cpu.clone()
        };
        cfg.validate().unwrap();
        assert_eq!(cfg.prior_aggregation().smoothing, cfg.prior_smoothing);
        let json = serde_json::to_string(&cfg).unwrap();
        assert!(
            json.contains("\"prior_smoothing\":{\"p1\":2.0,\"p2\":64.0}"),
            "{json}"
        );
        assert_eq!(serde_json::from_str::<DeepViewConfig>(&json).unwrap(), cfg);
        assert!(
            !serde_json::to_string(&cpu)
                .unwrap()
                .contains("prior_smoothing")
        );
        for (p1, p2) in [
            (64.0, 2.0),
            (-1.0, 2.0),
            (1.0, f32::INFINITY),
            (f32::NAN, 1.0),
        ] {
            let bad = DeepViewConfig {
                prior_smoothing: Some(Smoothing { p1, p2 }),
                ..cpu.clone()
            };
            assert!(bad.validate().is_err(), "({p1}, {p2})");
        }
        // The prior's temperature: where f32 logits still hold the variances it divides.
        for (t, fine) in [
            (1e-308, false),
            (1e-7, false),
            (0.0, false),
            (1e-6, true),
            (0.0007, true),
            (1e7, false),
        ] {
            let c = DeepViewConfig {
                init_prior: Some(t),
                ..cpu.clone()
            };
            assert_eq!(c.validate().is_ok(), fine, "{t}");
        }
        let without_prior = DeepViewConfig {
            init_prior: None,
            ..cfg
        };
        assert!(without_prior.validate().is_err());
    }

    /// The census term round-trips through config.json (absent when off, so older configs load as
    /// before), reaches the prior's aggregation, and bad ones (or one without the prior) are refused.
    #[test]
    fn prior_census_in_the_config() {
        let cpu = DeepViewConfig::preset("cpu").unwrap();
        assert!(cpu.prior_census.is_none());
        let cfg = DeepViewConfig {
            prior_census: Some(Census {
                weight: 0.03,
                radius: 2,
            }),
            ..cpu.clone()
        };
        cfg.validate().unwrap();
        assert_eq!(cfg.prior_aggregation().census, cfg.prior_census);
        let json = serde_json::to_string(&cfg).unwrap();
        assert!(
            json.contains("\"prior_census\":{\"weight\":0.03,\"radius\":2}"),
            "{json}"
        );
        assert_eq!(serde_json::from_str::<DeepViewConfig>(&json).unwrap(), cfg);
        assert!(
            !serde_json::to_string(&cpu)
                .unwrap()
                .contains("prior_census")
        );
        // A config that omits the radius gets the 5x5 window.
        let short = json.replace(",\"radius\":2", "");
        assert!(!short.contains("radius\":2}"), "{short}");
        assert_eq!(serde_json::from_str::<DeepViewConfig>(&short).unwrap(), cfg);
        for (weight, radius) in [(-0.1, 2), (0.0, 2), (f32::NAN, 2), (0.03, 0), (0.03, 4)] {
            let bad = DeepViewConfig {
                prior_census: Some(Census { weight, radius }),
                ..cpu.clone()
            };
            assert!(bad.validate().is_err(), "({weight}, {radius})");
        }
        let without_prior = DeepViewConfig {
            init_prior: None,
            ..cfg
        };
        assert!(without_prior.validate().is_err());
    }

    /// The leave-one-out weight round-trips through config.json (absent when off), reaches the prior's
    /// aggregation, and bad ones (or one without the prior) are refused.
    #[test]
    fn prior_leave_one_out_in_the_config() {
        let cpu = DeepViewConfig::preset("cpu").unwrap();
        assert!(cpu.prior_leave_one_out.is_none());
        let cfg = DeepViewConfig {
            prior_leave_one_out: Some(0.75),
            ..cpu.clone()
        };
        cfg.validate().unwrap();
        assert_eq!(cfg.prior_aggregation().leave_one_out, Some(0.75));
        assert!(!cfg.prior_aggregation().sample_variance);
        let sampled = DeepViewConfig {
            prior_sample_variance: true,
            ..cfg.clone()
        };
        assert!(sampled.prior_aggregation().sample_variance);
        let json = serde_json::to_string(&sampled).unwrap();
        assert!(json.contains("\"prior_sample_variance\":true"), "{json}");
        assert_eq!(
            serde_json::from_str::<DeepViewConfig>(&json).unwrap(),
            sampled
        );
        assert!(
            DeepViewConfig {
                init_prior: None,
                ..sampled
            }
            .validate()
            .is_err()
        );
        let json = serde_json::to_string(&cfg).unwrap();
        assert!(!json.contains("sample_variance"), "{json}");
        assert!(json.contains("\"prior_leave_one_out\":0.75"), "{json}");
        assert_eq!(serde_json::from_str::<DeepViewConfig>(&json).unwrap(), cfg);
        assert!(
            !serde_json::to_string(&cpu)
                .unwrap()
                .contains("leave_one_out")
        );
        for b in [0.0, -0.5, 1.5, f32::NAN, f32::INFINITY] {
            let bad = DeepViewConfig {
                prior_leave_one_out: Some(b),
                ..cpu.clone()
            };
            assert!(bad.validate().is_err(), "{b}");
        }
        let without_prior = DeepViewConfig {
            init_prior: None,
            ..cfg
        };
        assert!(without_prior.validate().is_err());
    }

    /// The radius grows in proportion above `prior_radius_size` (rounded to the nearest integer, capped),
    /// never below `prior_radius`, and configs without the field load as before.
    #[test]
    fn prior_radius_grows_with_the_image_size() {
        let cfg = DeepViewConfig {
            prior_radius: 5,
            prior_radius_size: Some(512),
            ..DeepViewConfig::preset("cpu").unwrap()
        };
        // 5 * 996 / 512 = 9.73, 5 * 1008 / 512 = 9.84, 5 * 600 / 512 = 5.86, 5 * 563 / 512 = 5.498.
        for (size, want) in [
            (100, 5),
            (512, 5),
            (563, 5),
            (600, 6),
            (996, 10),
            (1008, 10),
            (4096, 40),
        ] {
            assert_eq!(cfg.prior_radius_at(size), want, "size {size}");
        }
        assert_eq!(cfg.prior_radius_at(100_000), MAX_PRIOR_RADIUS);
        // On a finer MPI grid (`--mpi-scale`) the radius scales with it: 5 * 1.5 = 7.5 -> 8 at 504 px,
        // 10 * 1.5 at 996 px, capped; at scale 1 it is the image size's.
        for (size, scale, want) in [
            (504, 1.5, 8),
            (996, 1.5, 15),
            (996, 1.0, 10),
            (4096, 2.0, 64),
        ] {
            assert_eq!(
                cfg.prior_radius_on(size, scale),
                want,
                "size {size} scale {scale}"
            );
        }
        let unsized_cfg = DeepViewConfig {
            prior_radius: 2,
            prior_radius_size: None,
            ..DeepViewConfig::preset("cpu").unwrap()
        };
        assert_eq!(unsized_cfg.prior_radius_on(48, 1.0), 2);
        assert_eq!(unsized_cfg.prior_radius_on(48, 1.5), 3);
        let no_prior = DeepViewConfig {
            prior_radius: 0,
            ..unsized_cfg
        };
        assert_eq!(no_prior.prior_radius_on(48, 2.0), 0);
        assert_eq!(cfg.at_image_size(996).prior_radius, 10);
        assert_eq!(cfg.at_image_size(996).prior_radius_size, Some(512));
        let fixed = DeepViewConfig {
            prior_radius_size: None,
            prior_smoothing: None,
            prior_census: None,
            ..cfg.clone()
        };
        assert_eq!(fixed.prior_radius_at(4096), 5);
        let json = serde_json::to_string(&cfg).unwrap();
        assert!(json.contains("\"prior_radius_size\":512"), "{json}");
        assert_eq!(serde_json::from_str::<DeepViewConfig>(&json).unwrap(), cfg);
        let old = serde_json::to_string(&fixed).unwrap();
        assert!(!old.contains("prior_radius_size"), "{old}");
        assert_eq!(serde_json::from_str::<DeepViewConfig>(&old).unwrap(), fixed);
        let zero = DeepViewConfig {
            prior_radius_size: Some(0),
            ..cfg
        };
        assert!(
            zero.validate()
                .unwrap_err()
                .to_string()
                .contains("radius size")
        );
    }

    #[test]
    fn presets_are_valid_and_serde_round_trips() {
        for name in [
            "paper-kalantari",
            "paper-spaces-4view",
            "paper-spaces-12view",
            "cpu",
            "cpu-large",
        ] {
            let c = DeepViewConfig::preset(name).unwrap();
            c.validate().unwrap();
            let s = serde_json::to_string(&c).unwrap();
            assert_eq!(serde_json::from_str::<DeepViewConfig>(&s).unwrap(), c);
        }
        let k = DeepViewConfig::preset("paper-kalantari").unwrap();
        assert_eq!(
            (k.views, k.train_planes, k.unet_nets, k.nets()),
            (Some(4), 28, 0, 4)
        );
        let s = DeepViewConfig::preset("paper-spaces-12view").unwrap();
        assert_eq!(
            (
                s.views,
                s.train_planes,
                s.infer_planes,
                s.features(1),
                s.features(2)
            ),
            (Some(12), 64, 80, 64, 16)
        );
        assert!(s.unet(1) && !s.unet(2));
        assert_eq!(s.net_margin(0), 24);
        assert_eq!(s.net_margin(2), 10);
        assert!(DeepViewConfig::preset("nope").is_err());
    }

    #[test]
    fn prior_is_optional_in_json_and_validated() {
        // A config written before `init_prior` existed loads with the paper's behaviour.
        let mut v = serde_json::to_value(DeepViewConfig::preset("cpu").unwrap()).unwrap();
        v.as_object_mut().unwrap().remove("init_prior");
        let c: DeepViewConfig = serde_json::from_value(v).unwrap();
        assert_eq!(c.init_prior, None);
        assert_eq!(
            DeepViewConfig::preset("cpu").unwrap().init_prior,
            Some(CPU_PRIOR_TEMPERATURE)
        );
        for name in [
            "paper-kalantari",
            "paper-spaces-4view",
            "paper-spaces-12view",
        ] {
            assert_eq!(DeepViewConfig::preset(name).unwrap().init_prior, None);
        }
        let bad = DeepViewConfig {
            init_prior: Some(0.0),
            ..c
        };
        assert!(bad.validate().is_err());
    }
}
