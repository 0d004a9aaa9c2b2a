//! COLMAP sparse models, text (`cameras.txt`, `images.txt`, `points3D.txt`) and binary (`.bin`), in the
//! scene folder or `sparse/0/`; images in `images/`.
//!
//! Poses: `qvec = [w, x, y, z]`, `tvec`, `x_cam = R(q) X + t` (converted by `colmap_to_pose`). COLMAP puts
//! the centre of the top-left pixel at (0.5, 0.5), as this project does, so principal points are used as
//! given. Distortion is not modelled: distorted camera models are refused unless their coefficients are 0.
//!
//! - [`model`]: the model as stored;
//! - [`text`]: the text files' parsers and the text writer;
//! - [`binary`]: the `.bin` files' parsers;
//! - this module: finding and reading a model folder, and loading it as a [`Scene`].

mod binary;
mod model;
mod text;

pub use binary::{parse_cameras_bin, parse_images_bin, parse_points3d_bin};
pub use model::{ColmapCamera, ColmapImage, ColmapModel, ColmapPoint};
pub use text::{
    parse_cameras_txt, parse_images_txt, parse_points3d_txt, write_colmap_text,
    write_colmap_text_observed,
};

use crate::{DataError, LoadOptions, Scene, SceneFormat, View};
use deepview_geometry::convention::colmap_to_pose;
use deepview_geometry::{Camera, DVec3, Pose};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The folder holding the model: `root` or `root/sparse/0`.
pub fn model_dir(root: &Path) -> Option<PathBuf> {
    let has = |d: &Path| d.join("cameras.txt").is_file() || d.join("cameras.bin").is_file();
    if has(root) {
        Some(root.into())
    } else {
        let d = root.join("sparse").join("0");
        has(&d).then_some(d)
    }
}

/// Read the model in `dir` (binary when `cameras.bin` and `images.bin` exist, else text). A missing
/// points3D file means no points.
pub fn read_colmap(dir: &Path) -> Result<ColmapModel, DataError> {
    let bin = dir.join("cameras.bin").is_file() && dir.join("images.bin").is_file();
    let model = if bin {
        let p = dir.join("points3D.bin");
        ColmapModel {
            cameras: parse_cameras_bin(
                &crate::read_file(&dir.join("cameras.bin"))?,
                &dir.join("cameras.bin"),
            )?,
            images: parse_images_bin(
                &crate::read_file(&dir.join("images.bin"))?,
                &dir.join("images.bin"),
            )?,
            points: if p.is_file() {
                parse_points3d_bin(&crate::read_file(&p)?, &p)?
            } else {
                Vec::new()
            },
        }
    } else {
        let (c, i, p) = (
            dir.join("cameras.txt"),
            dir.join("images.txt"),
            dir.join("points3D.txt"),
        );
        ColmapModel {
            cameras: parse_cameras_txt(&crate::read_text(&c)?, &c)?,
            images: parse_images_txt(&crate::read_text(&i)?, &i)?,
            points: if p.is_file() {
                parse_points3d_txt(&crate::read_text(&p)?, &p)?
            } else {
                Vec::new()
            },
        }
    };
    Ok(model)
}

/// 1st / 99th percentile of the depths of points seen by the views (all points when the model has no
/// observations), times 0.9 / 1.1. `None` without points in front of any view.
pub fn depth_bounds(model: &ColmapModel, poses: &[Pose]) -> Option<(f64, f64)> {
    let by_id: HashMap<u64, DVec3> = model
        .points
        .iter()
        .map(|p| (p.id, DVec3::from_array(p.xyz)))
        .collect();
    let any_obs = model.images.iter().any(|i| !i.point3d_ids.is_empty());
    let mut depths = Vec::new();
    for (img, pose) in model.images.iter().zip(poses) {
        let mut push = |x: &DVec3| {
            let z = pose.transform_point(*x).z;
            if z > 0.0 {
                depths.push(z);
            }
        };
        if any_obs {
            img.point3d_ids
                .iter()
                .filter_map(|id| by_id.get(id))
                .for_each(&mut push);
        } else {
            by_id.values().for_each(&mut push);
        }
    }
    if depths.is_empty() {
        return None;
    }
    depths.sort_by(f64::total_cmp);
    let pct = |q: f64| depths[((depths.len() - 1) as f64 * q).round() as usize];
    Some((pct(0.01) * 0.9, pct(0.99) * 1.1))
}

pub(crate) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let dir = model_dir(root).ok_or_else(|| {
        DataError::invalid(
            root,
            "no COLMAP model (looked for cameras.txt / cameras.bin here and in sparse/0/)",
        )
    })?;
    let mut model = read_colmap(&dir)?;
    model.images.sort_by(|a, b| a.name.cmp(&b.name));
    let images_file = dir.join(if dir.join("images.bin").is_file() {
        "images.bin"
    } else {
        "images.txt"
    });
    // One photo listed twice would be two distinct inputs (and its own nearest view); an image id twice
    // is a damaged model.
    let mut ids: Vec<_> = model.images.iter().map(|i| i.id).collect();
    ids.sort_unstable();
    if let Some(w) = ids.windows(2).find(|w| w[0] == w[1]) {
        return Err(DataError::invalid(
            &images_file,
            format!(
                "image id {} is listed twice: every image has its own id",
                w[0]
            ),
        ));
    }
    if let Some(w) = model.images.windows(2).find(|w| w[0].name == w[1].name) {
        return Err(DataError::invalid(
            &images_file,
            format!(
                "images {} and {} both name the photo {}: list each photo once",
                w[0].id, w[1].id, w[0].name
            ),
        ));
    }
    let images_dir = match &opts.images {
        Some(name) => root.join(name),
        None if root.join("images").is_dir() => root.join("images"),
        None if dir == root && root.join("../../images").is_dir() => root.join("../../images"),
        None => root.join("images"),
    };
    let cameras_file = dir.join(if dir.join("cameras.bin").is_file() {
        "cameras.bin"
    } else {
        "cameras.txt"
    });
    let mut views = Vec::with_capacity(model.images.len());
    let mut poses = Vec::with_capacity(model.images.len());
    for img in &model.images {
        let c = model.cameras.get(&img.camera_id).ok_or_else(|| {
            DataError::invalid(
                &images_file,
                format!(
                    "image {} ({}) uses camera {} which cameras file lacks",
                    img.id, img.name, img.camera_id
                ),
            )
        })?;
        let k = c.intrinsics(&cameras_file)?;
        let (w, h) = (u32::try_from(c.width), u32::try_from(c.height));
        let (Ok(w), Ok(h)) = (w, h) else {
            return Err(DataError::invalid(
                &cameras_file,
                format!("camera {}: size {}x{} too large", c.id, c.width, c.height),
            ));
        };
        let pose = colmap_to_pose(img.qvec, img.tvec).map_err(|e| {
            DataError::geometry(&images_file, format!("image {} ({})", img.id, img.name), e)
        })?;
        poses.push(pose);
        views.push(View {
            name: img.name.clone(),
            image_path: images_dir.join(&img.name),
            camera: Camera::new(w, h, k, pose),
        });
    }
    Ok(Scene {
        root: root.into(),
        format: SceneFormat::Colmap,
        views,
        depth_bounds: depth_bounds(&model, &poses),
        grid: None,
        rig_count: 1,
        downscale: 1,
    })
}

#[cfg(test)]
mod tests;
