//! The eval runner: predict every target of a protocol, score it, and report like nerfstudio's `eval`.

use crate::error::EvalError;
use crate::predictor::MpiPredictor;
use crate::protocol::{Protocol, ViewSplit};
use deepview_data::Scene;
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_metrics::{BorderCrop, psnr, quantize_u8, ssim};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// How to run an evaluation.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalOptions {
    /// Box-downscale every image by this integer factor (cameras scaled by exactly `1 / factor`); border crops
    /// are divided by it, rounding up.
    pub downscale: u32,
    /// Depth bounds; default the scene's (`Scene::near_far`).
    pub near_far: Option<(f64, f64)>,
    /// Crop this many pixels from every side instead of the protocol's crop (scene pixels).
    pub crop: Option<u32>,
    /// Round predictions (and ground truth) to 8 bits before scoring, as the Spaces protocol scores saved PNGs.
    pub quantize: bool,
    /// Write `prediction | ground truth | error` images here, one PNG per target.
    pub save_renders: Option<PathBuf>,
    /// Write the MPI each target was rendered from here, one MPI folder per target named like the
    /// renders (`012_name/`), ([`MpiPredictor::last_mpi`]).
    pub save_mpis: Option<PathBuf>,
    /// Recorded in the report (the learned model's weights).
    pub checkpoint: Option<String>,
    /// Print one line per view to stderr as it is scored.
    pub verbose: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            downscale: 1,
            near_far: None,
            crop: None,
            quantize: true,
            save_renders: None,
            save_mpis: None,
            checkpoint: None,
            verbose: false,
        }
    }
}

/// One scored target view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewResult {
    pub target: usize,
    pub target_name: String,
    pub inputs: Vec<usize>,
    pub ssim: f64,
    /// dB; `null` in JSON when the prediction is exact (infinite PSNR).
    pub psnr: f64,
    pub seconds: f64,
    /// Pixels cropped `[left, top, right, bottom]` at the evaluated resolution.
    pub crop: [u32; 4],
    /// Planes of the MPI the prediction was rendered from (methods that make one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub planes: Option<usize>,
}

/// Means and sample standard deviations (n - 1, as nerfstudio's `torch.std`; 0 for one view) over the views.
/// An exact prediction has infinite PSNR, which makes `psnr` infinite and `psnr_std` NaN: both `null` in JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalResults {
    pub ssim: f64,
    pub ssim_std: f64,
    pub psnr: f64,
    pub psnr_std: f64,
    pub seconds_per_view: f64,
    pub num_views: usize,
}

/// The report, shaped like nerfstudio's eval JSON (`method`, `checkpoint`, `results`), plus the protocol, the
/// scene and per-view scores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub method: String,
    pub checkpoint: Option<String>,
    pub protocol: String,
    pub scene: String,
    pub results: EvalResults,
    pub views: Vec<ViewResult>,
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let std = if v.len() > 1 {
        (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (mean, std)
}

impl EvalReport {
    /// A fixed-width table: one row per view, then the mean +- std.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "method {}  protocol {}  scene {}",
            self.method, self.protocol, self.scene
        );
        let _ = writeln!(
            s,
            "{:>6}  {:<24} {:<20} {:>8} {:>8} {:>8}",
            "target", "name", "inputs", "SSIM", "PSNR", "s/view"
        );
        for v in &self.views {
            let ins = v
                .inputs
                .iter()
                .map(|i| i.to_string())
                .collect::<Vec<_>>()
                .join(",");
            let _ = writeln!(
                s,
                "{:>6}  {:<24} {:<20} {:>8.4} {:>8.2} {:>8.2}",
                v.target, v.target_name, ins, v.ssim, v.psnr, v.seconds
            );
        }
        let r = &self.results;
        let _ = writeln!(
            s,
            "{:>6}  {:<24} {:<20} {:>8.4} {:>8.2} {:>8.2}   (std SSIM {:.4}, PSNR {:.2}; {} views)",
            "mean", "", "", r.ssim, r.psnr, r.seconds_per_view, r.ssim_std, r.psnr_std, r.num_views
        );
        s
    }

    /// Write the report as pretty JSON, atomically.
    pub fn write_json(&self, path: &Path) -> Result<(), EvalError> {
        let text = serde_json::to_string_pretty(self)
            .map_err(|e| EvalError::Invalid(format!("cannot serialise the report: {e}")))?;
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(|source| EvalError::Write {
                path: parent.into(),
                source,
            })?;
        }
        deepview_image::write_atomic(path, text.as_bytes())?;
        Ok(())
    }
}

/// Evaluate `method` on `scene` under `protocol`.
pub fn evaluate(
    scene: &Scene,
    protocol: &Protocol,
    method: &mut MpiPredictor<'_>,
    options: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    let resolved = protocol.resolve(scene)?;
    let splits = resolved.splits(scene)?;
    evaluate_splits(scene, &resolved.to_string(), &splits, method, options)
}

/// Evaluate `method` on explicit view splits (`protocol` only names them in the report).
pub fn evaluate_splits(
    scene: &Scene,
    protocol: &str,
    splits: &[ViewSplit],
    method: &mut MpiPredictor<'_>,
    options: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    if options.downscale == 0 {
        return Err(EvalError::Invalid(
            "downscale factor must be at least 1".into(),
        ));
    }
    let near_far = match options.near_far {
        Some(nf) => nf,
        None => scene.near_far()?,
    };
    for dir in [&options.save_renders, &options.save_mpis]
        .into_iter()
        .flatten()
    {
        std::fs::create_dir_all(dir).map_err(|source| EvalError::Write {
            path: dir.clone(),
            source,
        })?;
    }
    let mut cache: HashMap<usize, (ImageF32, Camera)> = HashMap::new();
    // View `i` loaded into the cache (once), or the protocol's index out of range.
    let load = |cache: &mut HashMap<usize, (ImageF32, Camera)>, i: usize| {
        if i >= scene.views.len() {
            return Err(EvalError::ViewOutOfRange {
                protocol: protocol.into(),
                index: i,
                views: scene.views.len(),
            });
        }
        if let std::collections::hash_map::Entry::Vacant(e) = cache.entry(i) {
            e.insert(load_view(scene, i, options.downscale)?);
        }
        Ok(())
    };
    // Every target's scored region, before any method runs: a crop that leaves too little of an image
    // is an error at once, not after the first view's minutes of work.
    for split in splits {
        let t = split.target;
        load(&mut cache, t)?;
        let gt = &cache[&t].0;
        let crop = scaled_crop(split.crop, options.crop, options.downscale);
        let scored = crop
            .apply(gt)
            .map_err(|e| EvalError::Invalid(format!("view {t}: {e}: a smaller --crop")))?;
        let window = 2 * deepview_metrics::SsimOptions::default().radius as u32 + 1;
        if scored.width < window || scored.height < window {
            return Err(EvalError::Invalid(format!(
                "view {t} ({}): its {}x{} image{} leaves {}x{} pixels to score, less than SSIM's \
                 {window}x{window} window: a smaller --crop{}",
                scene.views[t].name,
                gt.width,
                gt.height,
                if options.downscale > 1 {
                    format!(" (downscaled by {})", options.downscale)
                } else {
                    String::new()
                },
                scored.width,
                scored.height,
                if options.downscale > 1 {
                    " or --downscale"
                } else {
                    ""
                }
            )));
        }
    }
    let mut views = Vec::with_capacity(splits.len());
    let count = splits.len();
    for (k, split) in splits.iter().enumerate() {
        for &i in &split.inputs {
            load(&mut cache, i)?;
        }
        let inputs: Vec<(ImageF32, Camera)> =
            split.inputs.iter().map(|i| cache[i].clone()).collect();
        let (gt, target_cam) = &cache[&split.target];
        let start = Instant::now();
        let pred = method.predict(&inputs, &split.inputs, target_cam, near_far)?;
        let seconds = start.elapsed().as_secs_f64();
        if !pred.is_finite() {
            return Err(EvalError::Invalid(format!(
                "method {}: prediction for view {} has NaN or infinite values",
                method.name(),
                split.target
            )));
        }
        let crop = scaled_crop(split.crop, options.crop, options.downscale);
        let (p, g) = if options.quantize {
            (quantize_u8(&pred.to_rgb()), quantize_u8(gt))
        } else {
            (pred.to_rgb(), gt.clone())
        };
        let (pc, gc) = (crop.apply(&p)?, crop.apply(&g)?);
        let result = ViewResult {
            target: split.target,
            target_name: scene.views[split.target].name.clone(),
            inputs: split.inputs.clone(),
            ssim: ssim(&pc, &gc).map_err(|e| {
                EvalError::Invalid(format!(
                    "view {} ({}x{} after a border crop of {}/{}/{}/{} px; --crop changes it): {e}",
                    scene.views[split.target].name,
                    pc.width,
                    pc.height,
                    crop.left,
                    crop.top,
                    crop.right,
                    crop.bottom
                ))
            })?,
            psnr: psnr(&pc, &gc)?,
            seconds,
            crop: [crop.left, crop.top, crop.right, crop.bottom],
            planes: method.last_mpi().map(|(m, _)| m.depths.len()),
        };
        if options.verbose {
            // (A closed stderr loses the line, not the evaluation.)
            use std::io::Write as _;
            let _ = writeln!(
                std::io::stderr(),
                "[{}/{count}] view {:>4} {:<24} SSIM {:.4}  PSNR {:.2}  {:.2} s",
                k + 1,
                result.target,
                result.target_name,
                result.ssim,
                result.psnr,
                seconds
            );
        }
        if let (true, Some(w)) = (options.verbose, method.last_warning()) {
            use std::io::Write as _;
            let _ = writeln!(
                std::io::stderr(),
                "warning: view {} ({}): {w}; its score says little of the method",
                result.target,
                result.target_name
            );
        }
        let safe: String = result
            .target_name
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let stem = format!("{:03}_{safe}", split.target);
        if let Some(dir) = &options.save_renders {
            let path = dir.join(format!("{stem}.png"));
            deepview_image::write_png(&path, &side_by_side(&p, &g, crop))?;
        }
        if let (Some(dir), Some((mpi, rule))) = (&options.save_mpis, method.last_mpi()) {
            write_mpi_folder(&dir.join(&stem), mpi, rule)?;
        }
        views.push(result);
    }
    let ssims: Vec<f64> = views.iter().map(|v| v.ssim).collect();
    let psnrs: Vec<f64> = views.iter().map(|v| v.psnr).collect();
    let (ssim_mean, ssim_std) = mean_std(&ssims);
    let (psnr_mean, psnr_std) = mean_std(&psnrs);
    Ok(EvalReport {
        method: method.name().into(),
        checkpoint: options.checkpoint.clone(),
        protocol: protocol.into(),
        scene: scene.root.display().to_string(),
        results: EvalResults {
            ssim: ssim_mean,
            ssim_std,
            psnr: psnr_mean,
            psnr_std,
            seconds_per_view: views.iter().map(|v| v.seconds).sum::<f64>()
                / views.len().max(1) as f64,
            num_views: views.len(),
        },
        views,
    })
}

/// Write an MPI folder at `dir` whole or not at all: into a temporary sibling, renamed when complete.
fn write_mpi_folder(
    dir: &Path,
    mpi: &deepview_mpi::Mpi,
    rule: Option<&deepview_mpi::PlanesRule>,
) -> Result<(), EvalError> {
    let name = dir.file_name().unwrap_or_default().to_string_lossy();
    let tmp = dir.with_file_name(format!(".{name}.tmp-{}", std::process::id()));
    let old = dir.with_file_name(format!(".{name}.old-{}", std::process::id()));
    let write_err = |source| EvalError::Write {
        path: dir.to_path_buf(),
        source,
    };
    // An earlier run's MPI of this target is replaced; a folder holding anything else is not.
    if dir.exists() {
        let foreign = std::fs::read_dir(dir)
            .map_err(write_err)?
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .find(|n| n != "mpi.json" && !(n.starts_with("layer_") && n.ends_with(".png")));
        if let Some(f) = foreign {
            return Err(EvalError::Invalid(format!(
                "{} holds {f}, which is not part of an MPI: refusing to replace it",
                dir.display()
            )));
        }
    }
    let written = deepview_mpi::write_mpi_with(&tmp, mpi, rule)
        .map_err(EvalError::from)
        .and_then(|()| {
            if dir.exists() {
                std::fs::rename(dir, &old).map_err(write_err)?;
            }
            std::fs::rename(&tmp, dir).map_err(write_err)
        });
    if written.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
        if old.exists() && !dir.exists() {
            let _ = std::fs::rename(&old, dir);
        }
    }
    let _ = std::fs::remove_dir_all(&old);
    written
}

/// View `i`'s RGB image and camera at `1 / downscale` resolution.
fn load_view(scene: &Scene, i: usize, downscale: u32) -> Result<(ImageF32, Camera), EvalError> {
    let img = scene.load_image(i)?;
    let cam = scene.views[i].camera;
    if downscale == 1 {
        return Ok((img, cam));
    }
    if img.width / downscale == 0 || img.height / downscale == 0 {
        return Err(deepview_data::DataError::DownscaleTooLarge {
            path: scene.root.clone(),
            factor: downscale,
            view: scene.views[i].name.clone(),
            width: img.width,
            height: img.height,
        }
        .into());
    }
    let small = img.downscale(downscale);
    let s = 1.0 / downscale as f64;
    Ok((
        small.clone(),
        Camera::new(
            small.width,
            small.height,
            cam.intrinsics.scaled(s, s),
            cam.pose,
        ),
    ))
}

/// The protocol's crop (or the uniform override) at the evaluated resolution, rounded up.
fn scaled_crop(protocol: BorderCrop, uniform: Option<u32>, downscale: u32) -> BorderCrop {
    let c = uniform.map(BorderCrop::uniform).unwrap_or(protocol);
    let s = |v: u32| v.div_ceil(downscale);
    BorderCrop {
        left: s(c.left),
        top: s(c.top),
        right: s(c.right),
        bottom: s(c.bottom),
    }
}

/// `prediction | ground truth | error` side by side; the error panel is the mean absolute RGB error x4 in the
/// turbo colour map, and pixels outside the scored region are dimmed in all three panels.
fn side_by_side(pred: &ImageF32, gt: &ImageF32, crop: BorderCrop) -> ImageF32 {
    let (w, h) = (pred.width, pred.height);
    let mut out = ImageF32::new(w * 3, h, 3);
    for y in 0..h {
        for x in 0..w {
            let inside =
                x >= crop.left && y >= crop.top && x + crop.right < w && y + crop.bottom < h;
            let dim = if inside { 1.0 } else { 0.4 };
            let (p, g) = (pred.pixel(x, y), gt.pixel(x, y));
            let err = (0..3).map(|c| (p[c] - g[c]).abs()).sum::<f32>() / 3.0;
            let e = deepview_mpi::turbo((4.0 * err).min(1.0));
            for c in 0..3 {
                out.pixel_mut(x, y)[c] = p[c] * dim;
                out.pixel_mut(x + w, y)[c] = g[c] * dim;
                out.pixel_mut(x + 2 * w, y)[c] = e[c] * dim;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crops_scale_with_downscale_rounding_up() {
        let c = BorderCrop {
            left: 40,
            top: 16,
            right: 16,
            bottom: 15,
        };
        assert_eq!(
            scaled_crop(c, None, 2),
            BorderCrop {
                left: 20,
                top: 8,
                right: 8,
                bottom: 8
            }
        );
        assert_eq!(scaled_crop(c, Some(5), 2), BorderCrop::uniform(3));
        assert_eq!(scaled_crop(c, None, 1), c);
    }

    #[test]
    fn sample_standard_deviation() {
        let (m, s) = mean_std(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(m, 2.5);
        assert!((s - (5.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(mean_std(&[0.7]), (0.7, 0.0));
    }
}
