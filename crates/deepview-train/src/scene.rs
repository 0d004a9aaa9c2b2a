//! Training scenes ([`TrainScene`]: cameras, decoded images, depth bounds, and the views used for
//! training after a [`Holdout`] rule) and the errors of building training data ([`DataError`]).

use deepview_geometry::Camera;
use deepview_image::ImageF32;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The built-in analytic scene (a 4 x 4 rig looking at two planes).
pub const SYNTHETIC_TWO_PLANES: &str = "synthetic:two-planes";

/// Procedural 3D scenes made on the fly, one per tuple, from a seed ([`crate::data::Procedural`]).
pub const SYNTHETIC_PROCEDURAL: &str = "synthetic:procedural";

/// Whether `path` names a built-in synthetic dataset rather than a folder.
pub fn is_synthetic(path: &std::path::Path) -> bool {
    path.to_str()
        .is_some_and(|p| p == SYNTHETIC_TWO_PLANES || p == SYNTHETIC_PROCEDURAL)
}

/// Errors building training data.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("cannot load training scene {path}: {source}")]
    Scene {
        path: PathBuf,
        source: deepview_data::DataError,
    },
    #[error("training scene {path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("no training data: {0}")]
    Empty(String),
    #[error("geometry error in scene {scene}: {source}")]
    Geometry {
        scene: String,
        source: deepview_geometry::GeometryError,
    },
}

/// Which views of a scene are held out (never used in training).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Holdout {
    /// None.
    Nothing,
    /// Every n-th view (`index % n == 0`): the general protocol for posed captures.
    EveryNth(usize),
}

/// A scene ready for sampling: cameras, decoded images (cached in memory), depth bounds.
#[derive(Clone, Debug)]
pub struct TrainScene {
    pub name: String,
    pub cameras: Vec<Camera>,
    pub images: Vec<ImageF32>,
    pub near: f64,
    pub far: f64,
    /// Views used for training (targets and inputs).
    pub train_views: Vec<usize>,
}

impl TrainScene {
    /// A scene from cameras and RGB images (e.g. a synthetic scene), with a holdout rule.
    pub fn new(
        name: &str,
        cameras: Vec<Camera>,
        images: Vec<ImageF32>,
        near: f64,
        far: f64,
        holdout: Holdout,
    ) -> Result<Self, DataError> {
        let invalid = |message: String| DataError::Invalid {
            path: PathBuf::from(name),
            message,
        };
        if cameras.len() != images.len() {
            return Err(invalid(format!(
                "{} cameras but {} images",
                cameras.len(),
                images.len()
            )));
        }
        for (i, (c, im)) in cameras.iter().zip(&images).enumerate() {
            if (c.width, c.height) != (im.width, im.height) || im.channels != 3 {
                return Err(invalid(format!(
                    "view {i}: camera {}x{} but image {}x{}x{}",
                    c.width, c.height, im.width, im.height, im.channels
                )));
            }
        }
        if !(near > 0.0 && far > near && far.is_finite()) {
            return Err(invalid(format!("bad depth bounds near {near}, far {far}")));
        }
        let train_views: Vec<usize> = (0..cameras.len())
            .filter(|i| match holdout {
                Holdout::Nothing => true,
                Holdout::EveryNth(n) => n == 0 || i % n != 0,
            })
            .collect();
        if train_views.len() < 2 {
            return Err(invalid(format!(
                "{} training views after holding out evaluation views; need at least 2 (one input, one target)",
                train_views.len()
            )));
        }
        Ok(Self {
            name: name.to_string(),
            cameras,
            images,
            near,
            far,
            train_views,
        })
    }

    /// Load a dataset folder with `deepview_data` and decode every image. LLFF, COLMAP and light fields
    /// hold out every `holdout_every`-th view; Spaces holds out nothing (its test scenes are separate).
    pub fn load(
        path: &Path,
        opts: &deepview_data::LoadOptions,
        holdout_every: usize,
    ) -> Result<Self, DataError> {
        let scene_err = |source| DataError::Scene {
            path: path.to_path_buf(),
            source,
        };
        let scene = deepview_data::load_scene(path, opts).map_err(scene_err)?;
        let (near, far) = scene.near_far().map_err(scene_err)?;
        let images = (0..scene.len())
            .map(|i| scene.load_image(i))
            .collect::<Result<Vec<_>, _>>()
            .map_err(scene_err)?;
        let holdout = match scene.format {
            deepview_data::SceneFormat::Spaces => Holdout::Nothing,
            _ if holdout_every > 1 => Holdout::EveryNth(holdout_every),
            _ => Holdout::Nothing,
        };
        Self::new(
            &path.display().to_string(),
            scene.cameras(),
            images,
            near,
            far,
            holdout,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::two_plane_scene;

    #[test]
    fn holdout_every_8th() {
        let s = two_plane_scene(3, 3, 24, 0.1);
        let t = TrainScene::new(
            "t",
            s.cameras,
            s.images,
            s.near,
            s.far,
            Holdout::EveryNth(8),
        )
        .unwrap();
        assert_eq!(t.train_views, vec![1, 2, 3, 4, 5, 6, 7]);
    }
}
