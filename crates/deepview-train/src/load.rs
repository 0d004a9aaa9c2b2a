//! Training data from dataset folders and the built-in synthetic scenes.

use crate::data::{TrainData, TrainScene};
use crate::error::TrainError;
use crate::synthetic;
use std::path::PathBuf;

/// Load training data: dataset folders through `deepview_data`, or `synthetic:two-planes`.
pub fn load_data(
    paths: &[PathBuf],
    opts: &deepview_data::LoadOptions,
    holdout_every: usize,
) -> Result<TrainData, TrainError> {
    let mut scenes = Vec::new();
    for p in paths {
        if p.to_str() == Some("synthetic:two-planes") {
            scenes.push(synthetic::two_plane_scene(4, 4, 96, 0.08));
        } else {
            scenes.push(TrainScene::load(p, opts, holdout_every)?);
        }
    }
    Ok(TrainData::new(scenes)?)
}
