//! A scene's image files: existence and size checks against the cameras, and loading (downscaled).

use crate::{DataError, Scene, SceneFormat, formats, image_size};
use deepview_image::ImageF32;
use std::path::PathBuf;

impl Scene {
    /// The calibration file the cameras came from (for messages).
    pub fn calibration_path(&self) -> PathBuf {
        match self.format {
            SceneFormat::Llff => self.root.join("poses_bounds.npy"),
            SceneFormat::Spaces => self.root.join("models.json"),
            SceneFormat::Colmap => {
                formats::colmap::model_dir(&self.root).unwrap_or(self.root.clone())
            }
            SceneFormat::LightField => self.root.clone(),
            SceneFormat::Transforms => formats::transforms::transforms_path(&self.root),
        }
    }

    /// Check that view `i`'s image file exists and has its camera's size (reads the header only).
    pub fn check_image(&self, i: usize) -> Result<(), DataError> {
        let v = self.view(i)?;
        if v.image_path.is_dir() {
            return Err(DataError::invalid(
                &v.image_path,
                format!("is a folder, not the image of view {}", v.name),
            ));
        }
        if !v.image_path.is_file() {
            return Err(DataError::MissingImage {
                path: v.image_path.clone(),
                view: v.name.clone(),
            });
        }
        let got = image_size(&v.image_path)?;
        let f = self.downscale.max(1);
        if (got.0 / f, got.1 / f) != (v.camera.width, v.camera.height) {
            return Err(DataError::ImageSize {
                path: v.image_path.clone(),
                calibration: self.calibration_path(),
                expected: (v.camera.width * f, v.camera.height * f),
                got,
            });
        }
        Ok(())
    }

    /// Check every view's image (exists, size matches the camera).
    pub fn check_images(&self) -> Result<(), DataError> {
        (0..self.views.len()).try_for_each(|i| self.check_image(i))
    }

    /// View `i`'s image as RGB (box-downscaled by [`Scene::downscale`]); an error if the file is missing or its size differs from the camera's.
    pub fn load_image(&self, i: usize) -> Result<ImageF32, DataError> {
        self.check_image(i)?;
        let v = &self.views[i];
        let img = deepview_image::read_photo(&v.image_path)?.downscale(self.downscale.max(1));
        if (img.width, img.height) != (v.camera.width, v.camera.height) {
            return Err(DataError::ImageSize {
                path: v.image_path.clone(),
                calibration: self.calibration_path(),
                expected: (v.camera.width, v.camera.height),
                got: (img.width, img.height),
            });
        }
        Ok(img)
    }
}
