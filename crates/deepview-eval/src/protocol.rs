//! Evaluation protocols: which views are targets, which are their inputs, and how much border is cropped
//! before scoring.
//!
//! - Spaces (paper section 5, `compute_metrics.py` of the Spaces release), rig position 0, camera indices of
//!   the 16-camera rig: `small_quad` targets 5,6,7 from 2,1,11,10; `medium_quad` 2,4,5,6,7,11 from 3,1,12,10;
//!   `large_quad` 1,2,4,5,6,7,8,10,11 from 3,0,12,9; `dense` 5,7,10,11 from the other 12. Every side is cropped by
//!   16 px, and by 40 px on a side where the target lies on or beyond the edge of the input quad (see
//!   [`spaces_edge_crop`]); crops are in the pixels of the 800-px-wide Spaces images.
//! - Posed captures (LLFF, COLMAP): `--targets every:8` (views with index % 8 == 0) or a list, `--inputs
//!   nearest:4` (the 4 nearest non-target views by camera centre) or a list; 16 px border crop.
//! - Light-field grids (Kalantari et al. 2016): the 4 corner views are the inputs, every other view is a target
//!   (Kalantari: the 60 in-between views of an 8x8 grid); 16 px border crop.

use crate::error::EvalError;
use deepview_data::{Scene, SceneFormat};
use deepview_geometry::{Camera, DMat3, DVec3, camera::orthonormalize};
use deepview_methods::MethodError;
use deepview_methods::inputs::{InputRule, join, parse_count, parse_list};
use deepview_metrics::BorderCrop;
use std::fmt;
use std::str::FromStr;

/// The Spaces protocol's usual border crop, pixels.
pub const SPACES_SMALL_CROP: u32 = 16;
/// The Spaces protocol's crop on a side where the target lies on or beyond the edge of the input quad.
pub const SPACES_BIG_CROP: u32 = 40;
/// Border crop of the other protocols (as the Spaces protocol away from the quad edges).
pub const DEFAULT_CROP: u32 = 16;

/// One evaluated view: the target index, its input indices and the border crop (scene pixels).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ViewSplit {
    pub target: usize,
    pub inputs: Vec<usize>,
    pub crop: BorderCrop,
}

/// The four Spaces configurations (paper Figure 4 and Table 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpacesConfig {
    SmallQuad,
    MediumQuad,
    LargeQuad,
    Dense,
}

impl SpacesConfig {
    pub const ALL: [SpacesConfig; 4] = [
        SpacesConfig::SmallQuad,
        SpacesConfig::MediumQuad,
        SpacesConfig::LargeQuad,
        SpacesConfig::Dense,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            SpacesConfig::SmallQuad => "small_quad",
            SpacesConfig::MediumQuad => "medium_quad",
            SpacesConfig::LargeQuad => "large_quad",
            SpacesConfig::Dense => "dense",
        }
    }

    /// Target camera indices, as in `compute_metrics.py`.
    pub fn targets(&self) -> &'static [usize] {
        match self {
            SpacesConfig::SmallQuad => &[5, 6, 7],
            SpacesConfig::MediumQuad => &[2, 4, 5, 6, 7, 11],
            SpacesConfig::LargeQuad => &[1, 2, 4, 5, 6, 7, 8, 10, 11],
            SpacesConfig::Dense => &[5, 7, 10, 11],
        }
    }

    /// Input camera indices (the quads in the paper's order; dense: the 12 non-target cameras).
    pub fn inputs(&self) -> Vec<usize> {
        match self {
            SpacesConfig::SmallQuad => vec![2, 1, 11, 10],
            SpacesConfig::MediumQuad => vec![3, 1, 12, 10],
            SpacesConfig::LargeQuad => vec![3, 0, 12, 9],
            SpacesConfig::Dense => (0..16).filter(|i| !self.targets().contains(i)).collect(),
        }
    }
}

/// Which views are targets (posed captures and light fields).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TargetRule {
    /// Views whose index is a multiple of n (`every:8`).
    Every(usize),
    /// Explicit indices (`3,11,19`).
    List(Vec<usize>),
}

impl FromStr for TargetRule {
    type Err = EvalError;
    fn from_str(s: &str) -> Result<Self, EvalError> {
        match parse_count(s, "every:")? {
            Some(n) => Ok(TargetRule::Every(n)),
            None => Ok(TargetRule::List(parse_list(s)?)),
        }
    }
}

impl fmt::Display for TargetRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TargetRule::Every(n) => write!(f, "every:{n}"),
            TargetRule::List(v) => f.write_str(&join(v)),
        }
    }
}

/// An evaluation protocol.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Protocol {
    /// Chosen from the scene format: light fields -> `LightField`, LLFF / COLMAP -> `posed` with `every:8` and
    /// `nearest:4`; Spaces scenes must name one of the four configurations.
    Auto,
    /// `auto` with `--targets` / `--inputs`: the scene's protocol with those rules (a light field with
    /// `--targets` alone keeps its corner inputs; with `--inputs` it is evaluated as posed).
    AutoWith {
        targets: Option<TargetRule>,
        inputs: Option<InputRule>,
    },
    Spaces(SpacesConfig),
    Posed {
        targets: TargetRule,
        inputs: InputRule,
    },
    /// Corner views in; `targets` defaults to every non-corner view.
    LightField {
        targets: Option<TargetRule>,
    },
}

impl Protocol {
    /// A protocol from its name and the optional `--targets` / `--inputs` rules.
    pub fn from_name(
        name: &str,
        targets: Option<TargetRule>,
        inputs: Option<InputRule>,
    ) -> Result<Self, EvalError> {
        let key = name.trim().to_ascii_lowercase().replace('-', "_");
        let fixed = |p: Protocol| -> Result<Protocol, EvalError> {
            if targets.is_some() || inputs.is_some() {
                return Err(MethodError::BadRule {
                    rule: name.into(),
                    msg: "this protocol fixes its views; target and input rules apply to posed and light-field".into(),
                }
                .into());
            }
            Ok(p)
        };
        match key.as_str() {
            "small_quad" => fixed(Protocol::Spaces(SpacesConfig::SmallQuad)),
            "medium_quad" => fixed(Protocol::Spaces(SpacesConfig::MediumQuad)),
            "large_quad" => fixed(Protocol::Spaces(SpacesConfig::LargeQuad)),
            "dense" => fixed(Protocol::Spaces(SpacesConfig::Dense)),
            "auto" if targets.is_none() && inputs.is_none() => Ok(Protocol::Auto),
            "auto" => Ok(Protocol::AutoWith { targets, inputs }),
            "posed" => Ok(Protocol::Posed {
                targets: targets.unwrap_or(TargetRule::Every(8)),
                inputs: inputs.unwrap_or_default(),
            }),
            "light_field" | "lightfield" | "kalantari" => {
                if inputs.is_some() {
                    return Err(MethodError::BadRule {
                        rule: name.into(),
                        msg: "the light-field protocol's inputs are the 4 corner views; an input rule does not apply".into(),
                    }
                    .into());
                }
                Ok(Protocol::LightField { targets })
            }
            _ => Err(EvalError::UnknownProtocol(name.into())),
        }
    }

    /// The protocol `Auto` stands for in `scene` (other protocols are returned unchanged).
    pub fn resolve(&self, scene: &Scene) -> Result<Protocol, EvalError> {
        match (self, scene.format) {
            (Protocol::Auto, SceneFormat::Spaces) => Err(EvalError::WrongScene {
                protocol: "auto".into(),
                scene: scene.root.display().to_string(),
                msg: "a Spaces scene needs an explicit protocol: small_quad, medium_quad, large_quad or dense".into(),
            }),
            (Protocol::Auto, SceneFormat::LightField) => Ok(Protocol::LightField { targets: None }),
            (Protocol::Auto, _) => Ok(Protocol::Posed { targets: TargetRule::Every(8), inputs: InputRule::default() }),
            (Protocol::AutoWith { .. }, SceneFormat::Spaces) => Err(EvalError::WrongScene {
                protocol: "auto".into(),
                scene: scene.root.display().to_string(),
                msg: "a Spaces scene needs an explicit protocol: small_quad, medium_quad, large_quad or dense \
                      (or posed, for --targets / --inputs)"
                    .into(),
            }),
            // An input rule is the posed protocol's (the light field's inputs are its corners).
            (Protocol::AutoWith { targets, inputs: None }, SceneFormat::LightField) => {
                Ok(Protocol::LightField { targets: targets.clone() })
            }
            (Protocol::AutoWith { targets, inputs }, _) => Ok(Protocol::Posed {
                targets: targets.clone().unwrap_or(TargetRule::Every(8)),
                inputs: inputs.clone().unwrap_or_default(),
            }),
            (p, _) => Ok(p.clone()),
        }
    }

    /// This protocol for a method that needs exactly `views` inputs (learned weights trained for a fixed
    /// count): the posed protocol's default `nearest:4` takes that count instead ([`InputRule::default_for`]).
    /// Call it only when the inputs were not given explicitly.
    pub fn with_default_inputs(self, views: Option<usize>) -> Self {
        match self {
            Protocol::Posed {
                targets,
                inputs: InputRule::Nearest(_),
            } => Protocol::Posed {
                targets,
                inputs: InputRule::default_for(views),
            },
            p => p,
        }
    }

    /// The view splits of this protocol in `scene`, with border crops in scene pixels.
    pub fn splits(&self, scene: &Scene) -> Result<Vec<ViewSplit>, EvalError> {
        let protocol = self.resolve(scene)?;
        let name = protocol.to_string();
        let n = scene.views.len();
        let cams = scene.cameras();
        let check = |i: usize| -> Result<usize, EvalError> {
            if i < n {
                Ok(i)
            } else {
                Err(EvalError::ViewOutOfRange {
                    protocol: name.clone(),
                    index: i,
                    views: n,
                })
            }
        };
        let wrong = |msg: String| EvalError::WrongScene {
            protocol: name.clone(),
            scene: scene.root.display().to_string(),
            msg,
        };
        let splits = match &protocol {
            Protocol::Auto | Protocol::AutoWith { .. } => unreachable!("resolved above"),
            Protocol::Spaces(cfg) => {
                if n != 16 {
                    return Err(wrong(format!(
                        "the Spaces protocols index the 16 cameras of one rig position; the scene has {n} views"
                    )));
                }
                let inputs = cfg.inputs();
                let input_cams: Vec<Camera> = inputs.iter().map(|&i| cams[i]).collect();
                cfg.targets()
                    .iter()
                    .map(|&t| ViewSplit {
                        target: t,
                        inputs: inputs.clone(),
                        crop: spaces_edge_crop(
                            &cams[t],
                            &input_cams,
                            SPACES_SMALL_CROP,
                            SPACES_BIG_CROP,
                        ),
                    })
                    .collect()
            }
            Protocol::Posed { targets, inputs } => {
                let target_set: Vec<usize> = match targets {
                    TargetRule::Every(k) => (0..n).filter(|i| i % k == 0).collect(),
                    TargetRule::List(v) => v.iter().map(|&i| check(i)).collect::<Result<_, _>>()?,
                };
                let mut out = Vec::with_capacity(target_set.len());
                for &t in &target_set {
                    let ins = inputs
                        .select(&cams, Some(t), &target_set)
                        .map_err(|e| match e {
                            MethodError::TooFewViews {
                                wanted, available, ..
                            } => EvalError::NotEnoughInputs {
                                protocol: name.clone(),
                                target: t,
                                wanted,
                                available,
                            },
                            MethodError::ViewIndex { index, views } => EvalError::ViewOutOfRange {
                                protocol: name.clone(),
                                index,
                                views,
                            },
                            e => e.into(),
                        })?;
                    out.push(ViewSplit {
                        target: t,
                        inputs: ins,
                        crop: BorderCrop::uniform(DEFAULT_CROP),
                    });
                }
                out
            }
            Protocol::LightField { targets } => {
                let (rows, cols) = scene.grid.ok_or_else(|| {
                    wrong("the light-field protocol needs a light-field grid scene".into())
                })?;
                if rows < 2 || cols < 2 || rows * cols != n {
                    return Err(wrong(format!(
                        "grid {rows}x{cols} does not fit {n} views (need at least 2x2)"
                    )));
                }
                let corners = vec![0, cols - 1, (rows - 1) * cols, rows * cols - 1];
                let candidates: Vec<usize> = match targets {
                    None => (0..n).filter(|i| !corners.contains(i)).collect(),
                    Some(TargetRule::Every(k)) => (0..n)
                        .filter(|i| i % k == 0 && !corners.contains(i))
                        .collect(),
                    Some(TargetRule::List(v)) => {
                        for &i in v {
                            check(i)?;
                            if corners.contains(&i) {
                                return Err(wrong(format!(
                                    "view {i} is a corner (input) view, not a target"
                                )));
                            }
                        }
                        v.clone()
                    }
                };
                candidates
                    .into_iter()
                    .map(|t| ViewSplit {
                        target: t,
                        inputs: corners.clone(),
                        crop: BorderCrop::uniform(DEFAULT_CROP),
                    })
                    .collect()
            }
        };
        if splits.is_empty() {
            return Err(EvalError::NoTargets {
                protocol: name,
                scene: scene.root.display().to_string(),
            });
        }
        Ok(splits)
    }
}

impl fmt::Display for Protocol {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Protocol::Auto => f.write_str("auto"),
            Protocol::AutoWith { targets, inputs } => {
                f.write_str("auto")?;
                if let Some(t) = targets {
                    write!(f, "(targets {t})")?;
                }
                if let Some(i) = inputs {
                    write!(f, "(inputs {i})")?;
                }
                Ok(())
            }
            Protocol::Spaces(c) => f.write_str(c.name()),
            Protocol::Posed { targets, inputs } => {
                write!(f, "posed(targets {targets}, inputs {inputs})")
            }
            Protocol::LightField { targets: None } => {
                f.write_str("light-field(corners in, all other views out)")
            }
            Protocol::LightField { targets: Some(t) } => {
                write!(f, "light-field(corners in, targets {t})")
            }
        }
    }
}

/// The Spaces border crop of a target: `small` px on every side, `big` px on each side where the target lies on
/// or beyond the edge of the inputs' quad.
///
/// The rule, reconstructed from the crop table of `compute_metrics.py` (which lists, per configuration, the views
/// cropped more on the left, top, right or bottom): express the camera centres in the rig plane, in the axes of
/// the inputs' average camera orientation (x right, y down, as image axes), relative to their centroid. The quad is
/// the inputs' bounding box there. A target whose x is at or left of the box's left edge (within a tolerance of
/// 10% of the box's larger side) gets `big` on its left border, and likewise for right (x), top and bottom (y):
/// such a target sees beyond the inputs' union on that side, where no method has data. On the real calibration of
/// scene 000 this reproduces the table exactly (see tests): e.g. `small_quad` view 5 left, 7 right; `large_quad`
/// views 1, 2 top, 4 left, 8 right, 10, 11 bottom; `dense` nothing.
pub fn spaces_edge_crop(target: &Camera, inputs: &[Camera], small: u32, big: u32) -> BorderCrop {
    let mut crop = BorderCrop::uniform(small);
    if inputs.is_empty() {
        return crop;
    }
    let n = inputs.len() as f64;
    let centroid = inputs.iter().fold(DVec3::ZERO, |a, c| a + c.center()) / n;
    let rot =
        orthonormalize(inputs.iter().fold(DMat3::ZERO, |a, c| a + c.pose.rotation) * (1.0 / n));
    let plane = |c: &Camera| rot * (c.center() - centroid);
    let pts: Vec<DVec3> = inputs.iter().map(plane).collect();
    let (x0, x1) = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.x), b.max(p.x))
        });
    let (y0, y1) = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.y), b.max(p.y))
        });
    let tol = 0.1 * (x1 - x0).max(y1 - y0);
    let t = plane(target);
    if t.x <= x0 + tol {
        crop.left = big;
    }
    if t.x >= x1 - tol {
        crop.right = big;
    }
    if t.y <= y0 + tol {
        crop.top = big;
    }
    if t.y >= y1 - tol {
        crop.bottom = big;
    }
    crop
}
