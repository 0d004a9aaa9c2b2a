//! How to load a scene: [`LoadOptions`], and [`SceneArgs`], the command-line flags that build them.

use crate::SceneFormat;
use serde::{Deserialize, Serialize};

/// How to load a scene; [`SceneArgs`] builds this from command-line flags. Serialised with every field
/// (a training run keeps them in its `config.json`); missing fields read as their defaults.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LoadOptions {
    /// Force a format instead of detecting it from the folder contents.
    pub format: Option<SceneFormat>,
    /// Image folder inside the scene (LLFF: e.g. `images_8`; COLMAP: default `images`).
    pub images: Option<String>,
    /// Spaces rig position.
    pub rig: usize,
    /// Override the near depth bound.
    pub near: Option<f64>,
    /// Override the far depth bound.
    pub far: Option<f64>,
    /// Box-downscale every image by this integer factor (0 and 1: full size; see [`Scene::downscale`](crate::Scene::downscale)).
    pub downscale: u32,
}

// The scene flags every command shares. (A plain comment: clap would turn a doc comment into the
// `about` text of every command that flattens this.)
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SceneArgs {
    /// Dataset format; detected from the folder contents when omitted.
    #[arg(long, value_enum)]
    pub format: Option<SceneFormat>,
    /// Image folder inside the scene (LLFF: images, images_4, images_8; default: the smallest present).
    #[arg(long)]
    pub images: Option<String>,
    /// Spaces rig position (index into models.json).
    #[arg(long, default_value_t = 0)]
    pub rig: usize,
    /// Near depth bound in scene units (overrides the dataset's bounds).
    #[arg(long)]
    pub near: Option<f64>,
    /// Far depth bound in scene units (overrides the dataset's bounds).
    #[arg(long)]
    pub far: Option<f64>,
    /// Box-downscale every image by this integer factor on load (cameras scaled by exactly 1/N; 1: full
    /// size).
    #[arg(long, default_value_t = 1, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub downscale: u32,
}

impl SceneArgs {
    pub fn load_options(&self) -> LoadOptions {
        LoadOptions {
            format: self.format,
            images: self.images.clone(),
            rig: self.rig,
            near: self.near,
            far: self.far,
            downscale: self.downscale,
        }
    }
}
