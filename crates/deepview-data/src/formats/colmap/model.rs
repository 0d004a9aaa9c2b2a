//! A COLMAP sparse model as stored: cameras, images and points, and COLMAP's camera models.

use crate::DataError;
use deepview_geometry::Intrinsics;
use std::collections::BTreeMap;
use std::path::Path;

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    pub model: String,
    pub width: u64,
    pub height: u64,
    pub params: Vec<f64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    pub qvec: [f64; 4],
    pub tvec: [f64; 3],
    pub camera_id: u32,
    pub name: String,
    /// The 3D point ids this image observes (`-1` entries dropped).
    pub point3d_ids: Vec<u64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    pub id: u64,
    pub xyz: [f64; 3],
}

/// A COLMAP sparse model as stored.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    pub cameras: BTreeMap<u32, ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: Vec<ColmapPoint>,
}

/// (id, name, number of parameters) of COLMAP's camera models.
pub(super) const MODELS: [(i32, &str, usize); 11] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
];

pub(super) fn model_params(name: &str) -> Option<usize> {
    MODELS.iter().find(|m| m.1 == name).map(|m| m.2)
}

impl ColmapCamera {
    /// Pinhole intrinsics, or an error for models with non-zero distortion.
    pub fn intrinsics(&self, path: &Path) -> Result<Intrinsics, DataError> {
        let p = &self.params;
        let want = model_params(&self.model);
        if want != Some(p.len()) {
            return Err(DataError::invalid(
                path,
                format!(
                    "camera {}: model {} with {} parameters is not supported",
                    self.id,
                    self.model,
                    p.len()
                ),
            ));
        }
        let (k, distortion): (Intrinsics, &[f64]) = match self.model.as_str() {
            "SIMPLE_PINHOLE" => (Intrinsics::new(p[0], p[0], p[1], p[2]), &[]),
            "PINHOLE" => (Intrinsics::new(p[0], p[1], p[2], p[3]), &[]),
            "SIMPLE_RADIAL" | "RADIAL" => (Intrinsics::new(p[0], p[0], p[1], p[2]), &p[3..]),
            "OPENCV" => (Intrinsics::new(p[0], p[1], p[2], p[3]), &p[4..]),
            m => {
                return Err(DataError::invalid(
                    path,
                    format!(
                        "camera {}: camera model {m} is not supported (pinhole only); undistort the images with \
                         `colmap image_undistorter` and load the undistorted model",
                        self.id
                    ),
                ));
            }
        };
        if distortion.iter().any(|&d| d != 0.0) {
            return Err(DataError::invalid(
                path,
                format!(
                    "camera {}: camera model {} has non-zero distortion {distortion:?}; undistort the images with \
                     `colmap image_undistorter` and load the undistorted (PINHOLE) model",
                    self.id, self.model
                ),
            ));
        }
        k.validate()
            .map_err(|e| DataError::geometry(path, format!("camera {}", self.id), e))?;
        Ok(k)
    }
}
