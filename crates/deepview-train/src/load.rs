//! Training data: the datasets of a run ([`DataSpec`]: a folder and how it is loaded) and their loading
//! ([`load_data`]), from dataset folders and the built-in synthetic scenes.

use crate::data::TrainData;
use crate::error::TrainError;
use crate::scene::TrainScene;
use crate::synthetic;
use deepview_data::LoadOptions;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// The built-in analytic scene (a 4 x 4 rig looking at two planes).
pub const SYNTHETIC_TWO_PLANES: &str = "synthetic:two-planes";

/// Procedural 3D scenes made on the fly, one per tuple, from a seed ([`crate::data::Procedural`]).
pub const SYNTHETIC_PROCEDURAL: &str = "synthetic:procedural";

/// Whether `path` names a built-in synthetic dataset rather than a folder.
pub fn is_synthetic(path: &std::path::Path) -> bool {
    path.to_str()
        .is_some_and(|p| p == SYNTHETIC_TWO_PLANES || p == SYNTHETIC_PROCEDURAL)
}

/// One dataset of a run: its folder (or [`SYNTHETIC_TWO_PLANES`]) and how it is loaded (format, image
/// folder, downscale, rig, depth bounds), so that resuming the run reads the same images.
///
/// In `config.json` an object `{"path": ..., "format": ..., "images": ..., "rig": ..., "near": ...,
/// "far": ..., "downscale": ...}`; runs from before the load options were kept have the bare path, read
/// as `load: None` (the caller's options then apply).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(from = "SpecRepr", into = "SpecRepr")]
pub struct DataSpec {
    pub path: PathBuf,
    /// How the folder is loaded; `None`: not recorded (older runs).
    pub load: Option<LoadOptions>,
}

impl DataSpec {
    /// `path` loaded with `load`.
    pub fn new(path: impl Into<PathBuf>, load: LoadOptions) -> Self {
        Self {
            path: path.into(),
            load: Some(load),
        }
    }

    /// The options this dataset loads with: its own, else `fallback`.
    pub fn options<'a>(&'a self, fallback: &'a LoadOptions) -> &'a LoadOptions {
        self.load.as_ref().unwrap_or(fallback)
    }
}

/// The `config.json` forms of a [`DataSpec`].
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum SpecRepr {
    Path(PathBuf),
    Full {
        path: PathBuf,
        #[serde(flatten)]
        load: LoadOptions,
    },
}

impl From<SpecRepr> for DataSpec {
    fn from(r: SpecRepr) -> Self {
        match r {
            SpecRepr::Path(path) => Self { path, load: None },
            SpecRepr::Full { path, load } => Self {
                path,
                load: Some(load),
            },
        }
    }
}

impl From<DataSpec> for SpecRepr {
    fn from(s: DataSpec) -> Self {
        match s.load {
            None => SpecRepr::Path(s.path),
            Some(load) => SpecRepr::Full { path: s.path, load },
        }
    }
}

/// Load training data: each dataset folder through `deepview_data` with its own load options (or
/// `fallback` where it has none), or the built-in [`SYNTHETIC_TWO_PLANES`].
pub fn load_data(
    specs: &[DataSpec],
    fallback: &LoadOptions,
    holdout_every: usize,
) -> Result<TrainData, TrainError> {
    let mut scenes = Vec::new();
    let mut procedural = None;
    for spec in specs {
        if spec.path.to_str() == Some(SYNTHETIC_TWO_PLANES) {
            scenes.push(synthetic::two_plane_scene(4, 4, 96, 0.08));
        } else if spec.path.to_str() == Some(SYNTHETIC_PROCEDURAL) {
            procedural = Some(crate::data::Procedural::default());
        } else {
            scenes.push(TrainScene::load(
                &spec.path,
                spec.options(fallback),
                holdout_every,
            )?);
        }
    }
    Ok(match procedural {
        Some(p) => TrainData::with_procedural(scenes, p),
        None => TrainData::new(scenes)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_data::SceneFormat;

    #[test]
    fn specs_keep_their_load_options_and_old_bare_paths_still_read() {
        let full = DataSpec::new(
            "data/llff/fern",
            LoadOptions {
                format: Some(SceneFormat::Llff),
                images: Some("images_8".into()),
                rig: 0,
                near: Some(1.5),
                far: None,
                downscale: 2,
            },
        );
        let old = DataSpec {
            path: "data/llff/flower".into(),
            load: None,
        };
        let json = serde_json::to_value(vec![full.clone(), old.clone()]).unwrap();
        assert_eq!(
            json,
            serde_json::json!([
                {"path": "data/llff/fern", "format": "llff", "images": "images_8", "rig": 0,
                 "near": 1.5, "far": null, "downscale": 2},
                "data/llff/flower"
            ])
        );
        let back: Vec<DataSpec> = serde_json::from_value(json).unwrap();
        assert_eq!(back, vec![full.clone(), old.clone()]);
        // Missing option fields are their defaults.
        let partial: DataSpec = serde_json::from_str(r#"{"path": "x", "downscale": 4}"#).unwrap();
        assert_eq!(
            partial.load,
            Some(LoadOptions {
                downscale: 4,
                ..Default::default()
            })
        );
        let fallback = LoadOptions {
            downscale: 8,
            ..Default::default()
        };
        assert_eq!(old.options(&fallback), &fallback);
        assert_eq!(full.options(&fallback).downscale, 2);
    }
}
