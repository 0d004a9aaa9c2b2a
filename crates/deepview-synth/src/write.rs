//! Rendering a synthetic scene through a rig and writing it in the rig's own dataset format.

use crate::scene::SynthScene;
use deepview_data::{
    DataError, LoadOptions, SceneFormat, light_field_cameras, load_scene,
    write_colmap_text_observed, write_disparity_range, write_light_field, write_llff,
    write_spaces_models, write_transforms,
};
use deepview_geometry::{
    Camera, DVec2, DVec3, PlaneSpacing, ReferenceOptions, plane_depths, reference_camera,
};
use deepview_image::{ImageF32, write_atomic};
use deepview_mpi::{Mpi, write_mpi};
use serde::Serialize;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Mpi(#[from] deepview_mpi::MpiError),
    #[error(transparent)]
    Image(#[from] deepview_image::ImageError),
    #[error("{0}")]
    Invalid(String),
    #[error("a synthetic scene needs at least 2 planes (got {0})")]
    TooFewPlanes(usize),
}

/// Which cameras to render through.
#[derive(Clone, Debug, PartialEq)]
pub enum Rig {
    /// A generated `n x n` light-field grid of `width x height` views (HCI layout on disk).
    Grid {
        side: usize,
        width: u32,
        height: u32,
    },
    /// The cameras of a dataset folder (Spaces `models.json`, LLFF, COLMAP or light field); the output is
    /// written in the same format.
    Dataset { path: PathBuf, options: LoadOptions },
}

#[derive(Clone, Debug)]
pub struct SynthOptions {
    pub rig: Rig,
    pub seed: u64,
    /// Planes of the ground-truth MPI (the scene's layers sit on some of them).
    pub planes: usize,
    /// Depth range; default: the rig's own bounds, else 1..10 (Spaces' models.json has none).
    pub near_far: Option<(f64, f64)>,
    /// Rays per pixel side for the images (1 = one ray through the pixel centre).
    pub supersample: u32,
}

impl Default for SynthOptions {
    fn default() -> Self {
        Self {
            rig: Rig::Grid {
                side: 4,
                width: 256,
                height: 192,
            },
            seed: 1,
            planes: 32,
            near_far: None,
            supersample: 1,
        }
    }
}

/// What [`synthesize`] made.
#[derive(Clone, Debug)]
pub struct SynthOutput {
    pub format: SceneFormat,
    pub cameras: Vec<Camera>,
    pub ground_truth: Mpi,
    pub scene: SynthScene,
    pub near_far: (f64, f64),
}

#[derive(Serialize)]
struct SynthInfo<'a> {
    generator: &'static str,
    seed: u64,
    format: String,
    near: f64,
    far: f64,
    planes: usize,
    layer_depths: Vec<f64>,
    views: usize,
    ground_truth_mpi: &'a str,
}

/// Disparities of a grid rig's scenes: -2..+2 px per grid step, as in the HCI benchmark scenes.
pub const GRID_DISPARITY: (f64, f64) = (-2.0, 2.0);

/// Build a scene, render it through the rig and write `out` as a dataset of the rig's format, with
/// `out/ground_truth_mpi/` (the exact MPI) and `out/synth.json` (how it was made).
pub fn synthesize(out: &Path, options: &SynthOptions) -> Result<SynthOutput, SynthError> {
    synthesize_as(out, options, None)
}

/// [`synthesize`], writing the dataset as `write_format` instead of the rig's own format: any rig can be
/// written as nerfstudio `transforms.json` ([`SceneFormat::Transforms`]).
pub fn synthesize_as(
    out: &Path,
    options: &SynthOptions,
    write_format: Option<SceneFormat>,
) -> Result<SynthOutput, SynthError> {
    if options.planes < 2 {
        return Err(SynthError::TooFewPlanes(options.planes));
    }
    std::fs::create_dir_all(out).map_err(|e| DataError::Write {
        path: out.into(),
        source: e,
    })?;
    let (format, cameras, rig_bounds, source) = match &options.rig {
        Rig::Grid {
            side,
            width,
            height,
        } => {
            if *side < 2 {
                return Err(SynthError::Invalid(
                    "a grid rig needs at least 2 x 2 views".into(),
                ));
            }
            let lf = light_field_cameras(*side, *side, *width, *height);
            (
                SceneFormat::LightField,
                lf.cameras(),
                Some(lf.depth_bounds(GRID_DISPARITY.0, GRID_DISPARITY.1)),
                None,
            )
        }
        Rig::Dataset { path, options } => {
            let scene = load_scene(path, options)?;
            (
                scene.format,
                scene.cameras(),
                scene.depth_bounds,
                Some(scene),
            )
        }
    };
    let format = match write_format {
        None => format,
        Some(f) if f == format || f == SceneFormat::Transforms => f,
        Some(f) => {
            return Err(SynthError::Invalid(format!(
                "a {format} rig can be written as {format} or transforms, not {f}"
            )));
        }
    };
    let (near, far) = options.near_far.or(rig_bounds).unwrap_or((1.0, 10.0));
    // A COLMAP model's bounds come from its points' depths times 0.9 / 1.1 (colmap_read_depths): bounds
    // closer than that margin cannot be written.
    let (lo, hi) = colmap_read_depths(near, far);
    if format == SceneFormat::Colmap && hi <= lo * (1.0 + 1e-9) {
        return Err(SynthError::Invalid(format!(
            "a colmap scene reads its depth bounds from its points (their depths times 0.9 and 1.1), which \
             cannot give bounds as close as {near}..{far} (far must exceed {:.4} x near): give a wider \
             --near/--far, or --out-format transforms",
            1.1 / 0.9
        )));
    }
    let depths = plane_depths(near, far, options.planes, PlaneSpacing::InverseDepth)
        .map_err(|e| SynthError::Invalid(e.to_string()))?;
    let reference = reference_camera(
        &cameras,
        &ReferenceOptions {
            cover: Some((near, far)),
            max_margin: 0.5,
            ..Default::default()
        },
    )
    .map_err(|e| SynthError::Invalid(e.to_string()))?;
    let scene = SynthScene::generate(reference, &depths, options.seed);
    let images: Vec<ImageF32> = cameras
        .iter()
        .map(|c| scene.render(c, options.supersample))
        .collect();

    match format {
        SceneFormat::Transforms => {
            write_transforms(out, &cameras, &images, Some((near, far)))?;
        }
        SceneFormat::LightField => {
            let side = (cameras.len() as f64).sqrt().round() as usize;
            write_light_field(out, side, side, &images, None)?;
            // The scene's depth range as the light field's disparity range, so that loading the folder
            // gets the bounds it was rendered with (a grid rig's cameras are the loader's own).
            let lf = light_field_cameras(side, side, cameras[0].width, cameras[0].height);
            let range = (lf.depth_to_disparity(far), lf.depth_to_disparity(near));
            write_disparity_range(out, range)?;
        }
        SceneFormat::Llff => {
            let src = source.as_ref().expect("dataset rig");
            // Keep the source's resolution folder: factor = full size / loaded size.
            let factor = src
                .views
                .first()
                .and_then(|v| v.image_path.parent())
                .and_then(|p| p.file_name())
                .and_then(|n| n.to_str())
                .and_then(|n| n.strip_prefix("images_"))
                .and_then(|f| f.parse().ok())
                .unwrap_or(1);
            let bounds = vec![(near, far); cameras.len()];
            write_llff(out, &cameras, &bounds, &images, factor)?;
        }
        SceneFormat::Colmap => {
            let names: Vec<String> = (0..cameras.len())
                .map(|i| deepview_data::view_file_name(i, cameras.len()))
                .collect();
            let sparse = out.join("sparse").join("0");
            std::fs::create_dir_all(&sparse).map_err(|e| DataError::Write {
                path: sparse.clone(),
                source: e,
            })?;
            let (points, owner) = colmap_points(&scene.sample_points(2000), &cameras, near, far);
            write_colmap_text_observed(&sparse, &names, &cameras, &points, |v, p| {
                match owner[p] {
                    Some(o) => o == v,
                    None => within_read_bounds(&cameras[v], points[p], near, far),
                }
            })?;
            let img_dir = out.join("images");
            for (name, img) in names.iter().zip(&images) {
                write_image(&img_dir.join(name), img)?;
            }
        }
        SceneFormat::Spaces => {
            let paths: Vec<String> = (0..cameras.len())
                .map(|i| format!("cam_{i:02}/image_000.png"))
                .collect();
            write_spaces_models(
                &out.join("models.json"),
                std::slice::from_ref(&cameras),
                std::slice::from_ref(&paths),
            )?;
            for (p, img) in paths.iter().zip(&images) {
                write_image(&out.join(p), img)?;
            }
        }
    }
    let ground_truth = scene
        .ground_truth_mpi(&depths)
        .map_err(SynthError::Invalid)?;
    write_mpi(&out.join("ground_truth_mpi"), &ground_truth)?;
    let info = SynthInfo {
        generator: "deepview synth",
        seed: options.seed,
        format: format.to_string(),
        near,
        far,
        planes: options.planes,
        layer_depths: scene.layers.iter().map(|l| l.depth).collect(),
        views: cameras.len(),
        ground_truth_mpi: "ground_truth_mpi",
    };
    let json = serde_json::to_string_pretty(&info).expect("serialises");
    write_atomic(&out.join("synth.json"), json.as_bytes())?;
    Ok(SynthOutput {
        format,
        cameras,
        ground_truth,
        scene,
        near_far: (near, far),
    })
}

fn write_image(path: &Path, img: &ImageF32) -> Result<(), SynthError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| DataError::Write {
            path: dir.into(),
            source: e,
        })?;
    }
    deepview_image::write_png(path, img)?;
    Ok(())
}

/// The depths a COLMAP reader turns into `near..far`: it takes the 1st / 99th percentile of the depths
/// of the observed points times 0.9 / 1.1 (`deepview_data::formats::colmap::depth_bounds`).
fn colmap_read_depths(near: f64, far: f64) -> (f64, f64) {
    (near / 0.9, far / 1.1)
}

/// Whether view `camera` may observe `point`: strictly between the depths of [`colmap_read_depths`].
fn within_read_bounds(camera: &Camera, point: DVec3, near: f64, far: f64) -> bool {
    let (lo, hi) = colmap_read_depths(near, far);
    let z = camera.pose.transform_point(point).z;
    z > lo * (1.0 + 1e-9) && z < hi * (1.0 - 1e-9)
}

/// The points of a synthetic COLMAP model, and the view that owns each (`None`: a surface point, seen by
/// every view that has it in frame within the bounds). Beside the surface points, each view gets points
/// of its own at exactly the two depths of [`colmap_read_depths`], more than 2% of its observations
/// each, so that the reader's percentiles land on them and the model reads back as `near..far`.
fn colmap_points(
    surface: &[DVec3],
    cameras: &[Camera],
    near: f64,
    far: f64,
) -> (Vec<DVec3>, Vec<Option<usize>>) {
    let (lo, hi) = colmap_read_depths(near, far);
    let mut points = surface.to_vec();
    let mut owner = vec![None; surface.len()];
    for (v, c) in cameras.iter().enumerate() {
        let seen = surface
            .iter()
            .filter(|&&x| {
                within_read_bounds(c, x, near, far)
                    && c.project(x).is_some_and(|p| {
                        p.x >= 0.0 && p.y >= 0.0 && p.x < c.width as f64 && p.y < c.height as f64
                    })
            })
            .count();
        let k = seen.div_ceil(50) + 2;
        for i in 0..k {
            let px = DVec2::new(
                (i as f64 + 0.5) / k as f64 * c.width as f64,
                c.height as f64 / 2.0,
            );
            for z in [lo, hi] {
                points.push(c.unproject(px, z));
                owner.push(Some(v));
            }
        }
    }
    (points, owner)
}
