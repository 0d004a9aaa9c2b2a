//! Light-field grids in the HCI 4D benchmark layout: `input_CamNNN.png`, N x N views, row-major, and
//! optionally the scene's disparity range in `parameters.cfg` (HCI's `[meta]` keys `disp_min` and
//! `disp_max`, pixels between neighbouring views) or the ground-truth disparity `gt_disp_lowres.pfm` of the
//! centre view.
//!
//! The folder ships no calibration, so cameras are synthesised: identity rotations, centres on a regular grid
//! (spacing `baseline`) in the plane z = 0, focal length = image width, and principal points shifted
//! off-axis (as in the HCI renders) so that disparity 0 lies at the focus depth `Z0`. Then a point of
//! disparity `d` (pixels between neighbouring views) has inverse depth `1/Z = 1/Z0 + d / (f b)`: planes
//! equally spaced in inverse depth are equally spaced in disparity. With `f b / Z0 = D_INF` pixels, points at
//! infinity have disparity `-D_INF`.
//!
//! Sign (checked against the HCI images by a test): a point of disparity `d` seen at `x` in the centre view
//! appears in the view at grid column `c` at `x - d (c - c_centre)` (rows likewise for `y`), so positive
//! disparity is nearer than the focus plane.

use crate::pfm::{Pfm, read_pfm, write_pfm};
use crate::{DataError, LoadOptions, Scene, SceneFormat, View};
use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, Pose};
use deepview_image::ImageF32;
use std::path::Path;

pub const GT_DISPARITY: &str = "gt_disp_lowres.pfm";
/// The HCI benchmark's scene parameters; its `[meta]` section states the disparity range.
pub const PARAMETERS: &str = "parameters.cfg";
/// Disparity (pixels between neighbouring views) of points at infinity.
pub const D_INF: f64 = 16.0;
/// Disparity range assumed without `parameters.cfg` or ground truth.
pub const DEFAULT_DISPARITY_RANGE: (f64, f64) = (-4.0, 4.0);

/// `input_CamNNN.png` for view `i` (row-major).
pub fn light_field_image_name(i: usize) -> String {
    format!("input_Cam{i:03}.png")
}

/// The synthesised calibration of a light-field grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightFieldCameras {
    pub rows: usize,
    pub cols: usize,
    pub width: u32,
    pub height: u32,
    pub focal: f64,
    pub baseline: f64,
    /// Depth of zero disparity.
    pub focus_depth: f64,
}

/// The default calibration of a `rows x cols` grid of `width x height` views: focal = width, unit baseline,
/// focus depth `focal / D_INF`.
pub fn light_field_cameras(rows: usize, cols: usize, width: u32, height: u32) -> LightFieldCameras {
    let focal = width as f64;
    LightFieldCameras {
        rows,
        cols,
        width,
        height,
        focal,
        baseline: 1.0,
        focus_depth: focal / D_INF,
    }
}

impl LightFieldCameras {
    pub fn disparity_to_depth(&self, d: f64) -> f64 {
        1.0 / (1.0 / self.focus_depth + d / (self.focal * self.baseline))
    }

    pub fn depth_to_disparity(&self, z: f64) -> f64 {
        (1.0 / z - 1.0 / self.focus_depth) * self.focal * self.baseline
    }

    /// Camera centre of grid position `(r, c)`.
    pub fn center(&self, r: usize, c: usize) -> DVec3 {
        let (rc, cc) = (
            (self.rows as f64 - 1.0) / 2.0,
            (self.cols as f64 - 1.0) / 2.0,
        );
        DVec3::new(
            (c as f64 - cc) * self.baseline,
            (r as f64 - rc) * self.baseline,
            0.0,
        )
    }

    pub fn camera(&self, r: usize, c: usize) -> Camera {
        let ctr = self.center(r, c);
        let (w, h) = (self.width as f64, self.height as f64);
        let k = Intrinsics::new(
            self.focal,
            self.focal,
            w / 2.0 + self.focal * ctr.x / self.focus_depth,
            h / 2.0 + self.focal * ctr.y / self.focus_depth,
        );
        Camera::new(
            self.width,
            self.height,
            k,
            Pose::from_center(DMat3::IDENTITY, ctr),
        )
    }

    /// All cameras, row-major.
    pub fn cameras(&self) -> Vec<Camera> {
        (0..self.rows)
            .flat_map(|r| (0..self.cols).map(move |c| self.camera(r, c)))
            .collect()
    }

    /// `(near, far)` depths of a disparity range `(d_min, d_max)`, far clamped to disparity
    /// `-0.9 D_INF`.
    pub fn depth_bounds(&self, d_min: f64, d_max: f64) -> (f64, f64) {
        let d_inf = self.focal * self.baseline / self.focus_depth;
        let far_d = d_min.max(-0.9 * d_inf);
        let near_d = d_max.max(far_d + 1e-3);
        (
            self.disparity_to_depth(near_d),
            self.disparity_to_depth(far_d),
        )
    }
}

pub(crate) fn load(root: &Path, _opts: &LoadOptions) -> Result<Scene, DataError> {
    let mut n = 0;
    while root.join(light_field_image_name(n)).is_file() {
        n += 1;
    }
    // A gap followed by more views means a missing file, not a smaller grid.
    if n > 0 && (n + 1..n + 1024).any(|i| root.join(light_field_image_name(i)).is_file()) {
        return Err(DataError::MissingImage {
            path: root.join(light_field_image_name(n)),
            view: n.to_string(),
        });
    }
    let side = (n as f64).sqrt().round() as usize;
    if n == 0 || side * side != n {
        return Err(DataError::CountMismatch {
            path: root.into(),
            msg: format!(
                "found {n} consecutive input_CamNNN.png files from input_Cam000.png; a grid needs N x N"
            ),
        });
    }
    if root.join(light_field_image_name(n + 1)).exists() {
        return Err(DataError::CountMismatch {
            path: root.into(),
            msg: format!(
                "{} is missing but later views exist",
                light_field_image_name(n)
            ),
        });
    }
    let first = root.join(light_field_image_name(0));
    let (w, h) = crate::image_size(&first)?;
    let lf = light_field_cameras(side, side, w, h);
    let mut views = Vec::with_capacity(n);
    for (i, camera) in lf.cameras().into_iter().enumerate() {
        let path = root.join(light_field_image_name(i));
        let got = crate::image_size(&path)?;
        if got != (w, h) {
            return Err(DataError::ImageSize {
                path,
                calibration: first.clone(),
                expected: (w, h),
                got,
            });
        }
        views.push(View {
            name: format!("input_Cam{i:03}"),
            image_path: path,
            camera,
        });
    }
    let gt = root.join(GT_DISPARITY);
    let params = root.join(PARAMETERS);
    // A file, or a pipe or device, by the name is read (a pipe is an error, not a file left out); a
    // folder by the name is not the file.
    let there = |p: &Path| std::fs::metadata(p).is_ok_and(|m| !m.is_dir());
    let stated = if there(&params) {
        read_disparity_range(&params)?
    } else {
        None
    };
    let (d_min, d_max) = if let Some(range) = stated {
        range
    } else if there(&gt) {
        let pfm = read_pfm(&gt)?;
        let finite = pfm.data.iter().filter(|v| v.is_finite()).map(|&v| v as f64);
        let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
        if lo > hi {
            return Err(DataError::invalid(&gt, "no finite disparity values"));
        }
        let margin = 0.1 * (hi - lo) + 0.25;
        (lo - margin, hi + margin)
    } else {
        DEFAULT_DISPARITY_RANGE
    };
    Ok(Scene {
        root: root.into(),
        format: SceneFormat::LightField,
        views,
        depth_bounds: Some(lf.depth_bounds(d_min, d_max)),
        grid: Some((side, side)),
        rig_count: 1,
        downscale: 1,
    })
}

/// The disparity range `[meta] disp_min / disp_max` of an HCI `parameters.cfg` (`None` when the file
/// does not state both). Other sections and keys are ignored.
pub fn read_disparity_range(path: &Path) -> Result<Option<(f64, f64)>, DataError> {
    let text = crate::read_text(path)?;
    let (mut section, mut lo, mut hi) = (String::new(), None, None);
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.trim().to_string();
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            return Err(DataError::parse(
                path,
                Some(n + 1),
                format!("expected `key = value` or `[section]`, got {line:?}"),
            ));
        };
        let key = key.trim();
        if section != "meta" || !(key == "disp_min" || key == "disp_max") {
            continue;
        }
        let v: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .ok_or_else(|| {
                DataError::parse(
                    path,
                    Some(n + 1),
                    format!("{key} = {:?} is not a finite number", value.trim()),
                )
            })?;
        if key == "disp_min" {
            lo = Some(v)
        } else {
            hi = Some(v)
        }
    }
    match (lo, hi) {
        (Some(lo), Some(hi)) if lo < hi => Ok(Some((lo, hi))),
        (Some(lo), Some(hi)) => Err(DataError::invalid(
            path,
            format!("disp_min {lo} is not below disp_max {hi}"),
        )),
        _ => Ok(None),
    }
}

/// Write the disparity range `(d_min, d_max)` of a light field as an HCI `parameters.cfg` in `dir`.
pub fn write_disparity_range(dir: &Path, (d_min, d_max): (f64, f64)) -> Result<(), DataError> {
    let path = dir.join(PARAMETERS);
    let text = format!(
        "# Disparity range of the scene in pixels between neighbouring views (HCI 4D light field layout).\n\
         [meta]\ndisp_min = {d_min}\ndisp_max = {d_max}\n"
    );
    deepview_image::write_atomic_with(&path, text.as_bytes(), deepview_image::Durability::Rename)
        .map_err(|e| DataError::write(&path, e))
}

/// Write a light field: `images` (row-major, `rows * cols`, `rows == cols` for the HCI layout) as
/// `input_CamNNN.png`, and the centre view's disparity as `gt_disp_lowres.pfm` when given.
pub fn write_light_field(
    dir: &Path,
    rows: usize,
    cols: usize,
    images: &[ImageF32],
    disparity: Option<&Pfm>,
) -> Result<(), DataError> {
    if images.len() != rows * cols || rows != cols {
        return Err(DataError::CountMismatch {
            path: dir.into(),
            msg: format!(
                "{} images for a {rows} x {cols} grid (the HCI layout needs a square grid)",
                images.len()
            ),
        });
    }
    for (i, img) in images.iter().enumerate() {
        crate::write_image(&dir.join(light_field_image_name(i)), img)?;
    }
    if let Some(d) = disparity {
        write_pfm(&dir.join(GT_DISPARITY), d)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::DVec2;

    #[test]
    fn disparity_matches_camera_geometry() {
        let lf = light_field_cameras(5, 5, 64, 48);
        let cams = lf.cameras();
        let centre = cams[12];
        assert_eq!(centre.intrinsics, Intrinsics::centred(64.0, 64, 48));
        for d in [-3.0, 0.0, 1.5, 4.0] {
            let z = lf.disparity_to_depth(d);
            assert!((lf.depth_to_disparity(z) - d).abs() < 1e-12);
            let x = DVec2::new(20.5, 30.25);
            let world = centre.unproject(x, z);
            for r in 0..5 {
                for c in 0..5 {
                    let p = cams[r * 5 + c].project(world).unwrap();
                    let want = x - DVec2::new(c as f64 - 2.0, r as f64 - 2.0) * d;
                    assert!((p - want).length() < 1e-9, "d {d} ({r},{c}): {p} vs {want}");
                }
            }
        }
        let (near, far) = lf.depth_bounds(-4.0, 4.0);
        assert!(
            (lf.depth_to_disparity(near) - 4.0).abs() < 1e-9
                && (lf.depth_to_disparity(far) + 4.0).abs() < 1e-9
        );
        assert!(lf.depth_bounds(-100.0, 0.0).1.is_finite());
    }

    #[test]
    fn write_then_load() {
        let dir = tempfile::tempdir().unwrap();
        let imgs: Vec<ImageF32> = (0..9).map(|_| ImageF32::new(8, 6, 3)).collect();
        let disp = Pfm {
            width: 8,
            height: 6,
            channels: 1,
            data: vec![1.0; 48],
        };
        write_light_field(dir.path(), 3, 3, &imgs, Some(&disp)).unwrap();
        let s = crate::load_scene(dir.path(), &LoadOptions::default()).unwrap();
        assert_eq!(
            (s.format, s.grid, s.len()),
            (SceneFormat::LightField, Some((3, 3)), 9)
        );
        let lf = light_field_cameras(3, 3, 8, 6);
        let (near, far) = s.near_far().unwrap();
        // Disparity exactly 1 everywhere, margin 0.25 px.
        assert!((lf.depth_to_disparity(near) - 1.25).abs() < 1e-9);
        assert!((lf.depth_to_disparity(far) - 0.75).abs() < 1e-9);
        // A stated range (`parameters.cfg`) wins over the ground truth, exactly as stated.
        write_disparity_range(dir.path(), (-2.5, 1.5)).unwrap();
        let s = crate::load_scene(dir.path(), &LoadOptions::default()).unwrap();
        let (near, far) = s.near_far().unwrap();
        assert!((lf.depth_to_disparity(near) - 1.5).abs() < 1e-9);
        assert!((lf.depth_to_disparity(far) + 2.5).abs() < 1e-9);
        std::fs::remove_file(dir.path().join("input_Cam008.png")).unwrap();
        let e = crate::load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("found 8") && e.contains("N x N"), "{e}");
    }

    #[test]
    fn parameters_cfg_states_the_disparity_range() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(PARAMETERS);
        // HCI's own layout: other sections and keys around the two that matter.
        std::fs::write(
            &p,
            "[intrinsics]\nfocal_length_mm = 100\n\n[meta]\ndisp_min = -1.75\nfrustum_disp_min = -3\n\
             disp_max = 0.5\n",
        )
        .unwrap();
        assert_eq!(read_disparity_range(&p).unwrap(), Some((-1.75, 0.5)));
        // The keys outside [meta] do not count.
        std::fs::write(&p, "[extrinsics]\ndisp_min = -1\ndisp_max = 1\n").unwrap();
        assert_eq!(read_disparity_range(&p).unwrap(), None);
        for (text, expect) in [
            (
                "[meta]\ndisp_min = -1\ndisp_max = abc\n",
                "parameters.cfg:3:",
            ),
            (
                "[meta]\ndisp_min = inf\ndisp_max = 1\n",
                "not a finite number",
            ),
            ("[meta]\ndisp_min = 2\ndisp_max = 1\n", "is not below"),
            ("[meta]\njunk\n", "parameters.cfg:2:"),
        ] {
            std::fs::write(&p, text).unwrap();
            let e = read_disparity_range(&p).unwrap_err().to_string();
            assert!(
                e.contains(expect) && e.contains("parameters.cfg"),
                "{text:?}: {e}"
            );
        }
    }
}
