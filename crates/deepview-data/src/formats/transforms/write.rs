//! Writing a `transforms.json` scene (PINHOLE cameras, the images as PNG files).

use super::file::{TRANSFORMS_JSON, TransformsFile, TransformsFrame, TransformsIntrinsics};
use crate::DataError;
use deepview_geometry::Camera;
use deepview_geometry::convention::pose_to_opengl_c2w;
use deepview_image::ImageF32;
use std::path::Path;

/// The `transforms.json` of `cameras` (PINHOLE; intrinsics shared when all cameras agree, else per frame),
/// with `file_paths` as the frames' images and optional `near`/`far`.
pub fn transforms_file(
    file_paths: &[String],
    cameras: &[Camera],
    near_far: Option<(f64, f64)>,
) -> TransformsFile {
    let intr = |c: &Camera| TransformsIntrinsics {
        fl_x: Some(c.intrinsics.fx),
        fl_y: Some(c.intrinsics.fy),
        cx: Some(c.intrinsics.cx),
        cy: Some(c.intrinsics.cy),
        w: Some(c.width as f64),
        h: Some(c.height as f64),
        ..Default::default()
    };
    let shared = cameras
        .first()
        .filter(|c0| {
            cameras.iter().all(|c| {
                c.intrinsics == c0.intrinsics && (c.width, c.height) == (c0.width, c0.height)
            })
        })
        .map(intr);
    let frames = file_paths
        .iter()
        .zip(cameras)
        .map(|(p, c)| {
            let m = pose_to_opengl_c2w(&c.pose);
            TransformsFrame {
                file_path: Some(p.clone()),
                transform_matrix: Some(m.chunks_exact(4).map(<[f64]>::to_vec).collect()),
                intrinsics: if shared.is_some() {
                    TransformsIntrinsics::default()
                } else {
                    intr(c)
                },
            }
        })
        .collect();
    TransformsFile {
        intrinsics: TransformsIntrinsics {
            camera_model: Some("PINHOLE".into()),
            ..shared.unwrap_or_default()
        },
        frames: Some(frames),
        aabb: None,
        near: near_far.map(|b| b.0),
        far: near_far.map(|b| b.1),
    }
}

/// Write a nerfstudio scene: `dir/transforms.json` and the images as `dir/images/imageNNN.png`.
pub fn write_transforms(
    dir: &Path,
    cameras: &[Camera],
    images: &[ImageF32],
    near_far: Option<(f64, f64)>,
) -> Result<(), DataError> {
    let json = dir.join(TRANSFORMS_JSON);
    if cameras.len() != images.len() {
        return Err(DataError::CountMismatch {
            path: json,
            msg: format!(
                "{} cameras but {} images (must agree)",
                cameras.len(),
                images.len()
            ),
        });
    }
    let paths: Vec<String> = (0..cameras.len())
        .map(|i| format!("images/{}", crate::view_file_name(i, cameras.len())))
        .collect();
    for (i, (p, (img, cam))) in paths.iter().zip(images.iter().zip(cameras)).enumerate() {
        if (img.width, img.height) != (cam.width, cam.height) {
            return Err(DataError::invalid(
                &json,
                format!(
                    "image {i} is {}x{} but its camera is {}x{}",
                    img.width, img.height, cam.width, cam.height
                ),
            ));
        }
        crate::write_image(&dir.join(p), img)?;
    }
    let text = serde_json::to_string_pretty(&transforms_file(&paths, cameras, near_far))
        .expect("transforms.json serialises");
    crate::write_bytes(&json, text.as_bytes())
}
