//! The scene every format loads into: [`SceneFormat`], [`View`] and [`Scene`].

use crate::DataError;
use deepview_geometry::Camera;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

/// The dataset formats that [`load_scene`](crate::load_scene) reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum SceneFormat {
    /// LLFF `poses_bounds.npy` with `images*/` folders.
    Llff,
    /// COLMAP sparse model (text or binary) with `images/`.
    Colmap,
    /// Spaces `models.json`.
    Spaces,
    /// Light-field grid in the HCI layout (`input_CamNNN.png`).
    LightField,
    /// nerfstudio / instant-ngp `transforms.json` (OpenGL camera-to-world per frame).
    Transforms,
}

impl SceneFormat {
    pub const ALL: [SceneFormat; 5] = [
        SceneFormat::Llff,
        SceneFormat::Colmap,
        SceneFormat::Spaces,
        SceneFormat::LightField,
        SceneFormat::Transforms,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            SceneFormat::Llff => "llff",
            SceneFormat::Colmap => "colmap",
            SceneFormat::Spaces => "spaces",
            SceneFormat::LightField => "light-field",
            SceneFormat::Transforms => "transforms",
        }
    }
}

impl fmt::Display for SceneFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SceneFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().replace('_', "-").as_str() {
            "llff" => Ok(SceneFormat::Llff),
            "colmap" => Ok(SceneFormat::Colmap),
            "spaces" => Ok(SceneFormat::Spaces),
            "light-field" | "lightfield" | "hci" => Ok(SceneFormat::LightField),
            "transforms" | "transforms.json" | "nerfstudio" | "instant-ngp" => {
                Ok(SceneFormat::Transforms)
            }
            _ => Err(format!(
                "unknown scene format '{s}' (expected llff, colmap, spaces, light-field or transforms)"
            )),
        }
    }
}

/// One input view: a name, its image file and its camera.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    pub name: String,
    pub image_path: PathBuf,
    pub camera: Camera,
}

/// A dataset folder loaded into this project's conventions.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub root: PathBuf,
    pub format: SceneFormat,
    pub views: Vec<View>,
    /// `(near, far)` depths in the views' units, from the files or the options.
    pub depth_bounds: Option<(f64, f64)>,
    /// Light fields: `(rows, cols)` of the grid; views are row-major.
    pub grid: Option<(usize, usize)>,
    /// Spaces: the number of rig positions in `models.json` (1 for other formats).
    pub rig_count: usize,
    /// Images are box-downscaled by this integer factor on load and the cameras are scaled by exactly
    /// `1 / downscale` (sizes rounded down); 1: as on disk. Set by [`LoadOptions::downscale`](crate::LoadOptions::downscale).
    pub downscale: u32,
}

impl Scene {
    /// Number of views.
    pub fn len(&self) -> usize {
        self.views.len()
    }

    pub fn is_empty(&self) -> bool {
        self.views.is_empty()
    }

    pub fn cameras(&self) -> Vec<Camera> {
        self.views.iter().map(|v| v.camera).collect()
    }

    pub(crate) fn view(&self, i: usize) -> Result<&View, DataError> {
        self.views.get(i).ok_or_else(|| {
            DataError::invalid(
                &self.root,
                format!(
                    "view {i} out of range (the scene has {} views)",
                    self.views.len()
                ),
            )
        })
    }

    /// `(near, far)`: the dataset's or the options' bounds, or an error asking for `--near/--far`.
    pub fn near_far(&self) -> Result<(f64, f64), DataError> {
        self.depth_bounds.ok_or_else(|| DataError::NoDepthBounds {
            path: self.root.clone(),
            hint: match self.format {
                SceneFormat::Spaces => {
                    " (Spaces models.json carries no depth bounds; the paper's scenes \
                                        span roughly 0.7 m to 100 m)"
                        .into()
                }
                SceneFormat::Colmap => {
                    " (the COLMAP model has no 3D points to derive them from)".into()
                }
                SceneFormat::Transforms => {
                    " (transforms.json has no \"near\"/\"far\", and no \"aabb\" in front of every camera)"
                        .into()
                }
                _ => String::new(),
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_names_round_trip() {
        for f in SceneFormat::ALL {
            assert_eq!(f.to_string().parse::<SceneFormat>().unwrap(), f);
            let j = serde_json::to_string(&f).unwrap();
            assert_eq!(j, format!("\"{f}\""));
            assert_eq!(serde_json::from_str::<SceneFormat>(&j).unwrap(), f);
            assert_eq!(
                <SceneFormat as clap::ValueEnum>::from_str(f.name(), false).unwrap(),
                f
            );
        }
        assert!("nope".parse::<SceneFormat>().is_err());
    }
}
