//! Training data: the datasets of a run ([`DataSpec`]: a folder and how it is loaded) and their loading
//! ([`load_data`]), from dataset folders and the built-in synthetic scenes.

use crate::data::TrainData;
use crate::error::TrainError;
use crate::scene::{SYNTHETIC_PROCEDURAL, SYNTHETIC_TWO_PLANES, TrainScene};
use crate::synthetic;
use deepview_data::LoadOptions;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// One dataset of a run: its folder (or a built-in synthetic scene) and how it is loaded (format, image
/// folder, downscale, rig, depth bounds), so that resuming the run reads the same images.
///
/// In `config.json` an object `{"path": ..., "format": ..., "images": ..., "rig": ..., "near": ...,
/// "far": ..., "downscale": ...}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DataSpec {
    pub path: PathBuf,
    /// How the folder is loaded.
    #[serde(flatten)]
    pub load: LoadOptions,
}

impl DataSpec {
    /// `path` loaded with `load`.
    pub fn new(path: impl Into<PathBuf>, load: LoadOptions) -> Self {
        Self {
            path: path.into(),
            load,
        }
    }
}

/// Load training data: each dataset folder through `deepview_data` with its own load options, or the
/// built-in synthetic scenes.
pub fn load_data(specs: &[DataSpec], holdout_every: usize) -> Result<TrainData, TrainError> {
    let mut scenes = Vec::new();
    let mut procedural = None;
    for spec in specs {
        if spec.path.to_str() == Some(SYNTHETIC_TWO_PLANES) {
            scenes.push(synthetic::two_plane_scene(4, 4, 96, 0.08));
        } else if spec.path.to_str() == Some(SYNTHETIC_PROCEDURAL) {
            procedural = Some(crate::data::Procedural::default());
        } else {
            scenes.push(TrainScene::load(&spec.path, &spec.load, holdout_every)?);
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
    fn specs_keep_their_load_options() {
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
        let json = serde_json::to_value(vec![full.clone()]).unwrap();
        assert_eq!(
            json,
            serde_json::json!([
                {"path": "data/llff/fern", "format": "llff", "images": "images_8", "rig": 0,
                 "near": 1.5, "far": null, "downscale": 2}
            ])
        );
        let back: Vec<DataSpec> = serde_json::from_value(json).unwrap();
        assert_eq!(back, vec![full]);
        // Missing option fields are their defaults.
        let partial: DataSpec = serde_json::from_str(r#"{"path": "x", "downscale": 4}"#).unwrap();
        assert_eq!(
            partial.load,
            LoadOptions {
                downscale: 4,
                ..Default::default()
            }
        );
        // A bare path (runs from before the load options were kept) is refused, not guessed.
        assert!(serde_json::from_str::<DataSpec>(r#""data/llff/flower""#).is_err());
    }
}
