//! Loading a `transforms.json` scene: image paths (with `--images` folders and missing extensions), depth
//! bounds, and the cameras scaled to the images found.

use super::file::{TRANSFORMS_JSON, TransformsFile, parse_transforms, transforms_cameras};
use crate::{DataError, LoadOptions, Scene, SceneFormat, View};
use deepview_geometry::{Camera, DVec3};
use std::path::{Component, Path, PathBuf};

/// `file_path` relative to `base`, with `--images FOLDER` replacing its first folder, and an image
/// extension tried when it has none (or the file is missing).
fn image_path(base: &Path, file_path: &str, images: Option<&str>) -> Option<PathBuf> {
    let rel = Path::new(file_path);
    let rel: PathBuf = match images {
        None => rel
            .components()
            .filter(|c| *c != Component::CurDir)
            .collect(),
        Some(folder) => {
            let parts: Vec<Component> = rel
                .components()
                .filter(|c| *c != Component::CurDir)
                .collect();
            let mut p = PathBuf::from(folder);
            let skip = usize::from(parts.len() > 1);
            p.extend(parts.iter().skip(skip));
            p
        }
    };
    let full = base.join(&rel);
    if full.is_file() {
        return Some(full);
    }
    ["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"]
        .iter()
        .map(|ext| {
            let mut s = full.clone().into_os_string();
            s.push(".");
            s.push(ext);
            PathBuf::from(s)
        })
        .find(|p| p.is_file())
}

/// Depth bounds from `near`/`far`, else from the `aabb` corners if they are in front of every camera.
pub fn transforms_depth_bounds(file: &TransformsFile, cameras: &[Camera]) -> Option<(f64, f64)> {
    if let (Some(n), Some(f)) = (file.near, file.far) {
        return Some((n, f));
    }
    let [lo, hi] = file.aabb?;
    let mut near = f64::INFINITY;
    let mut far: f64 = 0.0;
    for c in cameras {
        for k in 0..8 {
            let x = DVec3::new(
                if k & 1 == 0 { lo[0] } else { hi[0] },
                if k & 2 == 0 { lo[1] } else { hi[1] },
                if k & 4 == 0 { lo[2] } else { hi[2] },
            );
            let z = c.pose.transform_point(x).z;
            if !(z > 0.0 && z.is_finite()) {
                return None;
            }
            near = near.min(z);
            far = far.max(z);
        }
    }
    (near < far).then_some((near, far))
}

/// The JSON file of a scene path: the path itself when it is a `.json` file, else `transforms.json` in it.
pub fn transforms_path(root: &Path) -> PathBuf {
    if root.is_file() {
        root.into()
    } else {
        root.join(TRANSFORMS_JSON)
    }
}

pub(crate) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let json = transforms_path(root);
    let base = json.parent().unwrap_or(Path::new(".")).to_path_buf();
    let file = parse_transforms(&crate::read_text(&json)?, &json)?;
    let cams = transforms_cameras(&file, &json)?;
    if let Some(folder) = &opts.images
        && !base.join(folder).is_dir()
    {
        return Err(DataError::NoImageFolder {
            path: base.join(folder),
        });
    }
    let mut views = Vec::with_capacity(cams.len());
    let mut seen: std::collections::HashMap<PathBuf, usize> = std::collections::HashMap::new();
    for (i, c) in cams.iter().enumerate() {
        let path = image_path(&base, &c.file_path, opts.images.as_deref()).ok_or_else(|| {
            let tried = image_path_display(&base, &c.file_path, opts.images.as_deref());
            DataError::MissingImage {
                path: tried,
                view: format!("frame {i} of {}", json.display()),
            }
        })?;
        // One photo listed twice would be used as two distinct inputs (and be its own nearest view).
        let key = path.canonicalize().unwrap_or_else(|_| path.clone());
        if let Some(first) = seen.insert(key, i) {
            return Err(DataError::invalid(
                &json,
                format!(
                    "frames {first} and {i} both name the image {}: list each photo once",
                    c.file_path
                ),
            ));
        }
        let got = crate::image_size(&path)?;
        let (w, h) = c.size.unwrap_or(got);
        let k = c
            .intrinsics
            .resolve(w, h)
            .map_err(|e| DataError::invalid(&json, format!("frame {i} ({}): {e}", c.file_path)))?;
        // A downscaled copy: scale the intrinsics to the image found; LLFF-style rounding of 1 px allowed.
        let k = if got == (w, h) {
            k
        } else {
            let (sx, sy) = (got.0 as f64 / w as f64, got.1 as f64 / h as f64);
            if (got.1 as f64 - h as f64 * sx).abs() > 1.0 {
                return Err(DataError::ImageSize {
                    path: path.clone(),
                    calibration: json.clone(),
                    expected: (w, h),
                    got,
                });
            }
            k.scaled(sx, sy)
        };
        let name = Path::new(&c.file_path)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("frame{i:03}"));
        views.push(View {
            name,
            image_path: path,
            camera: Camera::new(got.0, got.1, k, c.pose),
        });
    }
    let cameras: Vec<Camera> = views.iter().map(|v| v.camera).collect();
    Ok(Scene {
        root: root.into(),
        format: SceneFormat::Transforms,
        views,
        depth_bounds: transforms_depth_bounds(&file, &cameras),
        grid: None,
        rig_count: 1,
        downscale: 1,
    })
}

fn image_path_display(base: &Path, file_path: &str, images: Option<&str>) -> PathBuf {
    let rel = Path::new(file_path);
    match images {
        None => base.join(rel),
        Some(folder) => {
            let parts: Vec<Component> = rel
                .components()
                .filter(|c| *c != Component::CurDir)
                .collect();
            let mut p = base.join(folder);
            p.extend(parts.iter().skip(usize::from(parts.len() > 1)));
            p
        }
    }
}
