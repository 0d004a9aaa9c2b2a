//! LLFF: `poses_bounds.npy` (N x 17 float64) and image folders `images/`, `images_4/`, `images_8/`, ...
//!
//! Each row is a 3x5 matrix, row-major: a 3x4 camera-to-world matrix whose rotation columns are the camera's
//! [down, right, back] axes (converted by `llff_c2w_to_pose`), then a column `[h, w, focal]` for the
//! full-size images; then `near, far`. The principal point is the image centre; the focal length is scaled
//! to the size of the images actually loaded.

use crate::npy::{read_npy, write_npy};
use crate::{DataError, LoadOptions, Scene, SceneFormat, View, list_images};
use deepview_geometry::convention::{llff_c2w_to_pose, pose_to_llff_c2w};
use deepview_geometry::{Camera, Intrinsics};
use deepview_image::ImageF32;
use std::path::{Path, PathBuf};

pub const POSES_BOUNDS: &str = "poses_bounds.npy";

/// One row of `poses_bounds.npy`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LlffRecord {
    /// Rows of the 3x4 camera-to-world matrix, columns [down, right, back, centre].
    pub c2w: [[f64; 4]; 3],
    /// Full-size image height, width and focal length in pixels.
    pub hwf: [f64; 3],
    pub near: f64,
    pub far: f64,
}

/// Read and check `poses_bounds.npy` (shape N x 17, all values finite).
pub fn read_poses_bounds(path: &Path) -> Result<Vec<LlffRecord>, DataError> {
    let a = read_npy(path)?;
    if a.shape.len() != 2 || a.shape[1] != 17 {
        return Err(DataError::invalid(
            path,
            format!("expected an N x 17 array, got shape {:?}", a.shape),
        ));
    }
    let mut out = Vec::with_capacity(a.shape[0]);
    for (i, row) in a.data.chunks_exact(17).enumerate() {
        if let Some(k) = row.iter().position(|v| !v.is_finite()) {
            return Err(DataError::invalid(
                path,
                format!("row {i}: non-finite value {} at column {k}", row[k]),
            ));
        }
        let mut c2w = [[0.0; 4]; 3];
        for r in 0..3 {
            for c in 0..4 {
                c2w[r][c] = row[r * 5 + c];
            }
        }
        out.push(LlffRecord {
            c2w,
            hwf: [row[4], row[9], row[14]],
            near: row[15],
            far: row[16],
        });
    }
    Ok(out)
}

/// The image folder to use: `opts.images`, else the smallest-resolution `images*` folder with images.
fn choose_image_dir(root: &Path, opts: &LoadOptions) -> Result<PathBuf, DataError> {
    if let Some(name) = &opts.images {
        let d = root.join(name);
        if !d.is_dir() {
            return Err(DataError::NoImageFolder { path: d });
        }
        return Ok(d);
    }
    let rd = std::fs::read_dir(root).map_err(|e| DataError::io(root, e))?;
    let mut best: Option<(u64, PathBuf)> = None;
    let mut candidates = Vec::new();
    for entry in rd {
        let p = entry.map_err(|e| DataError::io(root, e))?.path();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if !p.is_dir() || !(name == "images" || name.starts_with("images_")) {
            continue;
        }
        candidates.push(name);
        if let Some(first) = list_images(&p)?.first() {
            let (w, h) = crate::image_size(first)?;
            let px = w as u64 * h as u64;
            if best
                .as_ref()
                .is_none_or(|(b, bp)| px < *b || (px == *b && p < *bp))
            {
                best = Some((px, p));
            }
        }
    }
    best.map(|b| b.1).ok_or_else(|| {
        DataError::invalid(
            root,
            format!("no image folder with images (looked for images/ and images_*/; found {candidates:?})"),
        )
    })
}

pub(crate) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let npy = root.join(POSES_BOUNDS);
    let records = read_poses_bounds(&npy)?;
    // The depth bounds come from every row (the smallest near, the largest far) unless given: a
    // row whose bounds are not bounds is named, not averaged away.
    if (opts.near.is_none() || opts.far.is_none())
        && let Some((i, r)) = records
            .iter()
            .enumerate()
            .find(|(_, r)| !(r.near > 0.0 && r.far > r.near))
    {
        return Err(DataError::invalid(
            &npy,
            format!(
                "row {i}: near {}, far {} (its last two columns) are not depth bounds (need \
                 0 < near < far); fix the file, or pass --near and --far",
                r.near, r.far
            ),
        ));
    }
    let dir = choose_image_dir(root, opts)?;
    let files = list_images(&dir)?;
    if files.len() != records.len() {
        return Err(DataError::CountMismatch {
            path: npy,
            msg: format!(
                "{} camera rows but {} image files in {} (they are matched in name order){}",
                records.len(),
                files.len(),
                dir.display(),
                crate::files::image_count_note(&dir, &files)
            ),
        });
    }
    // The views' common size (the most frequent one): a view of another size is the one named.
    let sizes = files
        .iter()
        .map(|f| crate::image_size(f))
        .collect::<Result<Vec<_>, _>>()?;
    let common = sizes
        .iter()
        .max_by_key(|s| {
            (
                sizes.iter().filter(|t| t == s).count(),
                std::cmp::Reverse(sizes.iter().position(|t| t == *s)),
            )
        })
        .copied();
    let mut views = Vec::with_capacity(files.len());
    for (i, ((rec, file), &(w, h))) in records.iter().zip(&files).zip(&sizes).enumerate() {
        let [full_h, full_w, focal] = rec.hwf;
        if !(full_h > 0.0 && full_w > 0.0 && focal > 0.0) {
            return Err(DataError::invalid(
                &npy,
                format!("row {i}: bad [h, w, focal] = {:?}", rec.hwf),
            ));
        }
        let (sx, sy) = (w as f64 / full_w, h as f64 / full_h);
        // Downsampled folders round sizes; anything else means the images do not belong to the poses.
        let expected_h = (full_h * sx).round() as u32;
        let odd = common.filter(|&c| c != (w, h));
        if odd.is_some() || (h as f64 - full_h * sx).abs() > 1.0 {
            return Err(DataError::ImageSize {
                path: file.clone(),
                calibration: npy.clone(),
                expected: odd.unwrap_or((w, expected_h)),
                got: (w, h),
            });
        }
        let pose = llff_c2w_to_pose(rec.c2w)
            .map_err(|e| DataError::geometry(&npy, format!("row {i}"), e))?;
        let intr = Intrinsics::new(focal * sx, focal * sy, w as f64 / 2.0, h as f64 / 2.0);
        let name = file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        views.push(View {
            name,
            image_path: file.clone(),
            camera: Camera::new(w, h, intr, pose),
        });
    }
    let near = records.iter().map(|r| r.near).fold(f64::INFINITY, f64::min);
    let far = records
        .iter()
        .map(|r| r.far)
        .fold(f64::NEG_INFINITY, f64::max);
    Ok(Scene {
        root: root.into(),
        format: SceneFormat::Llff,
        views,
        depth_bounds: Some((near, far)),
        grid: None,
        rig_count: 1,
        downscale: 1,
    })
}

/// Whether `cam` fits LLFF's `poses_bounds.npy`: one focal length (`fx == fy`) and a centred principal
/// point.
pub fn llff_representable(cam: &Camera) -> bool {
    let k = &cam.intrinsics;
    let (w, h) = (cam.width as f64, cam.height as f64);
    (k.fx - k.fy).abs() <= 1e-9 * k.fx
        && (k.cx - w / 2.0).abs() <= 1e-9 * w
        && (k.cy - h / 2.0).abs() <= 1e-9 * h
}

/// Write an LLFF scene: `poses_bounds.npy` (full size = camera size x `factor`) and the images as
/// `images_<factor>/imageNNN.png` (`images/` when `factor == 1`). LLFF stores one focal length and a centred
/// principal point, so cameras must have `fx == fy` and `(cx, cy) = (w/2, h/2)`.
pub fn write_llff(
    dir: &Path,
    cameras: &[Camera],
    bounds: &[(f64, f64)],
    images: &[ImageF32],
    factor: u32,
) -> Result<(), DataError> {
    let npy = dir.join(POSES_BOUNDS);
    if cameras.len() != bounds.len() || cameras.len() != images.len() || factor == 0 {
        return Err(DataError::CountMismatch {
            path: npy,
            msg: format!(
                "{} cameras, {} bounds, {} images (must agree), factor {factor}",
                cameras.len(),
                bounds.len(),
                images.len()
            ),
        });
    }
    let folder = if factor == 1 {
        "images".to_string()
    } else {
        format!("images_{factor}")
    };
    let mut rows = Vec::with_capacity(cameras.len() * 17);
    for (i, ((cam, &(near, far)), img)) in cameras.iter().zip(bounds).zip(images).enumerate() {
        let k = &cam.intrinsics;
        let (w, h) = (cam.width as f64, cam.height as f64);
        if !llff_representable(cam) {
            return Err(DataError::invalid(
                &npy,
                format!(
                    "camera {i}: LLFF needs fx == fy and a centred principal point, got {k:?} for {w}x{h}"
                ),
            ));
        }
        if (img.width, img.height) != (cam.width, cam.height) {
            return Err(DataError::invalid(
                &npy,
                format!(
                    "image {i} is {}x{} but its camera is {}x{}",
                    img.width, img.height, cam.width, cam.height
                ),
            ));
        }
        let c2w = pose_to_llff_c2w(&cam.pose);
        let f = factor as f64;
        let hwf = [h * f, w * f, k.fx * f];
        for r in 0..3 {
            rows.extend_from_slice(&c2w[r]);
            rows.push(hwf[r]);
        }
        rows.push(near);
        rows.push(far);
    }
    for (i, img) in images.iter().enumerate() {
        crate::write_image(
            &dir.join(&folder)
                .join(crate::view_file_name(i, images.len())),
            img,
        )?;
    }
    write_npy(&npy, &[cameras.len(), 17], &rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load_scene;
    use deepview_geometry::{DMat3, DVec3, Pose};

    fn cams(n: usize) -> Vec<Camera> {
        (0..n)
            .map(|i| {
                let r = DMat3::from_rotation_y(0.05 * i as f64) * DMat3::from_rotation_x(-0.1);
                Camera::new(
                    12,
                    8,
                    Intrinsics::centred(10.0, 12, 8),
                    Pose::from_center(r, DVec3::new(i as f64 * 0.1, 0.0, -1.0)),
                )
            })
            .collect()
    }

    fn images(n: usize) -> Vec<ImageF32> {
        (0..n)
            .map(|i| ImageF32::from_data(12, 8, 3, vec![i as f32 / 8.0; 12 * 8 * 3]).unwrap())
            .collect()
    }

    #[test]
    fn write_then_load_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let c = cams(3);
        write_llff(
            dir.path(),
            &c,
            &[(1.0, 5.0), (0.5, 4.0), (2.0, 9.0)],
            &images(3),
            4,
        )
        .unwrap();
        let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
        assert_eq!(s.format, SceneFormat::Llff);
        assert_eq!(s.depth_bounds, Some((0.5, 9.0)));
        for (v, c) in s.views.iter().zip(&c) {
            assert_eq!((v.camera.width, v.camera.height), (12, 8));
            assert!((v.camera.intrinsics.fx - 10.0).abs() < 1e-12);
            assert!(v.camera.pose.rotation.abs_diff_eq(c.pose.rotation, 1e-12));
            assert!(v.camera.center().abs_diff_eq(c.center(), 1e-12));
        }
        assert!((s.load_image(2).unwrap().data[0] - 2.0 / 8.0).abs() < 1.0 / 255.0);
    }

    #[test]
    fn count_mismatch_non_finite_and_size_errors() {
        let dir = tempfile::tempdir().unwrap();
        write_llff(dir.path(), &cams(3), &[(1.0, 5.0); 3], &images(3), 8).unwrap();
        // One image too many.
        crate::write_image(&dir.path().join("images_8/image999.png"), &images(1)[0]).unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("poses_bounds.npy") && e.contains("3 camera rows but 4 image files"),
            "{e}"
        );
        std::fs::remove_file(dir.path().join("images_8/image999.png")).unwrap();
        // An image of the wrong size.
        crate::write_image(
            &dir.path().join("images_8/image001.png"),
            &ImageF32::new(12, 5, 3),
        )
        .unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("image001.png") && e.contains("poses_bounds.npy"),
            "{e}"
        );
        crate::write_image(&dir.path().join("images_8/image001.png"), &images(1)[0]).unwrap();
        assert!(load_scene(dir.path(), &LoadOptions::default()).is_ok());
        // The first view a row short (within the poses' rounding of a downsampled folder): it is
        // the one named, with the others' size.
        crate::write_image(
            &dir.path().join("images_8/image000.png"),
            &ImageF32::new(12, 7, 3),
        )
        .unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("image000.png is (12, 7)") && e.contains("says (12, 8)"),
            "{e}"
        );
        crate::write_image(&dir.path().join("images_8/image000.png"), &images(1)[0]).unwrap();
        // A view in a format deepview does not read, and one name twice: the count says why.
        std::fs::rename(
            dir.path().join("images_8/image002.png"),
            dir.path().join("images_8/image002.tif"),
        )
        .unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("3 camera rows but 2 image files") && e.contains("not read: image002.tif"),
            "{e}"
        );
        std::fs::remove_file(dir.path().join("images_8/image002.tif")).unwrap();
        crate::write_image(&dir.path().join("images_8/image002.png"), &images(1)[0]).unwrap();
        crate::write_image(&dir.path().join("images_8/image001.jpg"), &images(1)[0]).unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("3 camera rows but 4 image files")
                && e.contains("image001.jpg and image001.png are one view twice?"),
            "{e}"
        );
        std::fs::remove_file(dir.path().join("images_8/image001.jpg")).unwrap();
        // A view with transparent pixels: composited onto white where it is read.
        let mut holes = ImageF32::new(12, 8, 4);
        holes.data.iter_mut().for_each(|v| *v = 0.25);
        (0..96).for_each(|p| holes.data[4 * p + 3] = 1.0);
        holes.data[3] = 0.0;
        deepview_image::write_png(&dir.path().join("images_8/image001.png"), &holes).unwrap();
        let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
        let img = s.load_image(1).unwrap();
        assert_eq!(
            &img.data[..6],
            &[1.0, 1.0, 1.0, 64.0 / 255.0, 64.0 / 255.0, 64.0 / 255.0]
        );
        crate::write_image(&dir.path().join("images_8/image001.png"), &images(1)[0]).unwrap();
        // One row's bounds reversed: named, unless --near and --far replace them.
        let npy = dir.path().join(POSES_BOUNDS);
        let good = crate::npy::read_npy(&npy).unwrap();
        let mut a = good.clone();
        (a.data[17 + 15], a.data[17 + 16]) = (5.0, 1.0);
        crate::npy::write_npy(&npy, &a.shape, &a.data).unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("poses_bounds.npy") && e.contains("row 1: near 5, far 1"),
            "{e}"
        );
        let given = LoadOptions {
            near: Some(1.0),
            far: Some(5.0),
            ..Default::default()
        };
        assert_eq!(
            load_scene(dir.path(), &given).unwrap().depth_bounds,
            Some((1.0, 5.0))
        );
        crate::npy::write_npy(&npy, &good.shape, &good.data).unwrap();
        // A NaN in the poses.
        let mut a = crate::npy::read_npy(&npy).unwrap();
        a.data[17 + 3] = f64::NAN;
        crate::npy::write_npy(&npy, &a.shape, &a.data).unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("poses_bounds.npy") && e.contains("row 1") && e.contains("non-finite"),
            "{e}"
        );
        // Wrong shape.
        crate::npy::write_npy(&npy, &[3, 16], &[0.0; 48]).unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("poses_bounds.npy") && e.contains("N x 17"),
            "{e}"
        );
        // Truncated.
        let b = crate::npy::npy_bytes(&[3, 17], &[0.0; 51]);
        std::fs::write(&npy, &b[..b.len() - 3]).unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("poses_bounds.npy") && e.contains("truncated"),
            "{e}"
        );
    }

    #[test]
    fn missing_image_file_at_load_image() {
        let dir = tempfile::tempdir().unwrap();
        write_llff(dir.path(), &cams(2), &[(1.0, 5.0); 2], &images(2), 1).unwrap();
        let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
        std::fs::remove_file(&s.views[1].image_path).unwrap();
        let e = s.load_image(1).unwrap_err().to_string();
        assert!(
            e.contains("image001.png") && e.contains("does not exist"),
            "{e}"
        );
    }
}
