//! Dataset readers and writers. Every format (LLFF, COLMAP, Spaces, light-field grids, nerfstudio
//! `transforms.json`) loads into one
//! [`Scene`]: a list of views, each an image path and a [`Camera`] in this project's conventions (OpenCV axes,
//! camera-from-world poses, pixel centres at +0.5), plus optional depth bounds.
//!
//! Foreign conventions are converted in exactly one place each (`deepview_geometry::convention`), and
//! every error names the file and the problem.

mod camera_json;
pub mod formats;
pub mod npy;
pub mod pfm;

use deepview_geometry::{Camera, GeometryError};
use deepview_image::{ImageError, ImageF32};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

pub use camera_json::read_camera_json;
pub use formats::colmap::{ColmapModel, read_colmap, write_colmap_text};
pub use formats::lightfield::{
    LightFieldCameras, light_field_cameras, light_field_image_name, write_light_field,
};
pub use formats::llff::{read_poses_bounds, write_llff};
pub use formats::spaces::{spaces_relative_path, write_spaces_models};
pub use formats::transforms::{TRANSFORMS_JSON, write_transforms};

/// Errors of dataset input and output. Every message names the file and the problem.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error("{path}: malformed JSON: {source}")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{}: {msg}", location(.path, *.line))]
    Parse {
        path: PathBuf,
        line: Option<usize>,
        msg: String,
    },
    #[error("{path}: {what}: {source}")]
    Geometry {
        path: PathBuf,
        what: String,
        source: GeometryError,
    },
    #[error("image file {path} (view {view}) does not exist")]
    MissingImage { path: PathBuf, view: String },
    #[error(
        "image {path} is {got:?} (width, height) but its camera from {calibration} says {expected:?}"
    )]
    ImageSize {
        path: PathBuf,
        calibration: PathBuf,
        expected: (u32, u32),
        got: (u32, u32),
    },
    #[error("{path}: {msg}")]
    CountMismatch { path: PathBuf, msg: String },
    #[error(
        "{path}: rig position {rig} is out of range: the file has {count} rig position(s) (0..{count})"
    )]
    RigOutOfRange {
        path: PathBuf,
        rig: usize,
        count: usize,
    },
    #[error("{path}: no depth bounds known for this scene; give its near and far depths{hint}")]
    NoDepthBounds { path: PathBuf, hint: String },
    #[error(
        "{path}: this scene has no depth bounds of its own, so a {given} depth needs a {missing} depth too"
    )]
    HalfDepthBounds {
        path: PathBuf,
        given: &'static str,
        missing: &'static str,
    },
    #[error("{path}: image folder does not exist")]
    NoImageFolder { path: PathBuf },
    #[error(
        "{path}: downscaling by {factor} leaves nothing of view {view}'s {width}x{height} image"
    )]
    DownscaleTooLarge {
        path: PathBuf,
        factor: u32,
        view: String,
        width: u32,
        height: u32,
    },
    #[error("{path}: cannot detect the dataset format; looked for {looked_for}")]
    NotDetected { path: PathBuf, looked_for: String },
    #[error("{path}: {msg}")]
    Invalid { path: PathBuf, msg: String },
}

fn location(path: &Path, line: Option<usize>) -> String {
    match line {
        Some(l) => format!("{}:{l}", path.display()),
        None => path.display().to_string(),
    }
}

impl DataError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        DataError::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn write(path: &Path, source: std::io::Error) -> Self {
        DataError::Write {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn parse(path: &Path, line: Option<usize>, msg: impl Into<String>) -> Self {
        DataError::Parse {
            path: path.into(),
            line,
            msg: msg.into(),
        }
    }
    pub(crate) fn invalid(path: &Path, msg: impl Into<String>) -> Self {
        DataError::Invalid {
            path: path.into(),
            msg: msg.into(),
        }
    }
    pub(crate) fn geometry(path: &Path, what: impl Into<String>, source: GeometryError) -> Self {
        DataError::Geometry {
            path: path.into(),
            what: what.into(),
            source,
        }
    }
}

/// The dataset formats that [`load_scene`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum SceneFormat {
    /// LLFF `poses_bounds.npy` with `images*/` folders.
    Llff,
    /// COLMAP sparse model (text or binary) with `images/`.
    Colmap,
    /// Spaces `models.json`.
    Spaces,
    /// Light-field grid in the HCI layout (`input_CamNNN.png`).
    LightField,
    /// nerfstudio / instant-ngp `transforms.json` (OpenGL camera-to-world per frame).
    Transforms,
}

impl SceneFormat {
    pub const ALL: [SceneFormat; 5] = [
        SceneFormat::Llff,
        SceneFormat::Colmap,
        SceneFormat::Spaces,
        SceneFormat::LightField,
        SceneFormat::Transforms,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            SceneFormat::Llff => "llff",
            SceneFormat::Colmap => "colmap",
            SceneFormat::Spaces => "spaces",
            SceneFormat::LightField => "light-field",
            SceneFormat::Transforms => "transforms",
        }
    }
}

impl fmt::Display for SceneFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SceneFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().replace('_', "-").as_str() {
            "llff" => Ok(SceneFormat::Llff),
            "colmap" => Ok(SceneFormat::Colmap),
            "spaces" => Ok(SceneFormat::Spaces),
            "light-field" | "lightfield" | "hci" => Ok(SceneFormat::LightField),
            "transforms" | "transforms.json" | "nerfstudio" | "instant-ngp" => {
                Ok(SceneFormat::Transforms)
            }
            _ => Err(format!(
                "unknown scene format '{s}' (expected llff, colmap, spaces, light-field or transforms)"
            )),
        }
    }
}

/// One input view: a name, its image file and its camera.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    pub name: String,
    pub image_path: PathBuf,
    pub camera: Camera,
}

/// A dataset folder loaded into this project's conventions.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub root: PathBuf,
    pub format: SceneFormat,
    pub views: Vec<View>,
    /// `(near, far)` depths in the views' units, from the files or the options.
    pub depth_bounds: Option<(f64, f64)>,
    /// Light fields: `(rows, cols)` of the grid; views are row-major.
    pub grid: Option<(usize, usize)>,
    /// Spaces: the number of rig positions in `models.json` (1 for other formats).
    pub rig_count: usize,
    /// Images are box-downscaled by this integer factor on load and the cameras are scaled by exactly
    /// `1 / downscale` (sizes rounded down); 1: as on disk. Set by [`LoadOptions::downscale`].
    pub downscale: u32,
}

/// How to load a scene; [`SceneArgs`] builds this from command-line flags.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LoadOptions {
    /// Force a format instead of detecting it from the folder contents.
    pub format: Option<SceneFormat>,
    /// Image folder inside the scene (LLFF: e.g. `images_8`; COLMAP: default `images`).
    pub images: Option<String>,
    /// Spaces rig position.
    pub rig: usize,
    /// Override the near depth bound.
    pub near: Option<f64>,
    /// Override the far depth bound.
    pub far: Option<f64>,
    /// Box-downscale every image by this integer factor (0 and 1: full size; see [`Scene::downscale`]).
    pub downscale: u32,
}

// The scene flags every command shares. (A plain comment: clap would turn a doc comment into the
// `about` text of every command that flattens this.)
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SceneArgs {
    /// Dataset format; detected from the folder contents when omitted.
    #[arg(long, value_enum)]
    pub format: Option<SceneFormat>,
    /// Image folder inside the scene (LLFF: images, images_4, images_8; default: the smallest present).
    #[arg(long)]
    pub images: Option<String>,
    /// Spaces rig position (index into models.json).
    #[arg(long, default_value_t = 0)]
    pub rig: usize,
    /// Near depth bound in scene units (overrides the dataset's bounds).
    #[arg(long)]
    pub near: Option<f64>,
    /// Far depth bound in scene units (overrides the dataset's bounds).
    #[arg(long)]
    pub far: Option<f64>,
    /// Box-downscale every image by this integer factor on load (cameras scaled by exactly 1/N).
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub downscale: u32,
}

impl SceneArgs {
    pub fn load_options(&self) -> LoadOptions {
        LoadOptions {
            format: self.format,
            images: self.images.clone(),
            rig: self.rig,
            near: self.near,
            far: self.far,
            downscale: self.downscale,
        }
    }
}

/// The data folder for tests and benchmarks: env `DEEPVIEW_DATA`, else `<workspace>/../shared/data` (the
/// repository-relative fallback is compiled in, so no command of the program looks here).
pub fn data_dir() -> PathBuf {
    match std::env::var_os("DEEPVIEW_DATA") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    }
}

/// What [`detect_format`] looks for, for error messages.
pub const DETECTION_RULES: &str = "poses_bounds.npy (LLFF), models.json (Spaces), cameras.txt / cameras.bin / \
     sparse/0/ (COLMAP), input_Cam000.png (light field), transforms.json (nerfstudio)";

/// Detect the format of a dataset folder from its contents.
pub fn detect_format(path: &Path) -> Result<SceneFormat, DataError> {
    // A nerfstudio / instant-ngp JSON given as a file (e.g. Blender's transforms_train.json).
    if path.is_file()
        && path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        return Ok(SceneFormat::Transforms);
    }
    if !path.is_dir() {
        return Err(DataError::invalid(
            path,
            "is not a folder (expected a dataset folder)",
        ));
    }
    let has = |p: &str| path.join(p).exists();
    if has("poses_bounds.npy") {
        Ok(SceneFormat::Llff)
    } else if has("models.json") {
        Ok(SceneFormat::Spaces)
    } else if has("cameras.txt") || has("cameras.bin") || has("sparse/0") {
        Ok(SceneFormat::Colmap)
    } else if has("input_Cam000.png") {
        Ok(SceneFormat::LightField)
    } else if has(TRANSFORMS_JSON) {
        Ok(SceneFormat::Transforms)
    } else {
        Err(DataError::NotDetected {
            path: path.into(),
            looked_for: DETECTION_RULES.into(),
        })
    }
}

/// Load a dataset folder (format detected unless `opts.format` is set).
pub fn load_scene(path: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let format = match opts.format {
        Some(f) => f,
        None => detect_format(path)?,
    };
    let mut scene = match format {
        SceneFormat::Llff => formats::llff::load(path, opts)?,
        SceneFormat::Colmap => formats::colmap::load(path, opts)?,
        SceneFormat::Spaces => formats::spaces::load(path, opts)?,
        SceneFormat::LightField => formats::lightfield::load(path, opts)?,
        SceneFormat::Transforms => formats::transforms::load(path, opts)?,
    };
    if scene.views.is_empty() {
        return Err(DataError::invalid(path, "the scene has no views"));
    }
    let factor = opts.downscale.max(1);
    if factor > 1 {
        for v in &mut scene.views {
            let c = v.camera;
            let (w, h) = (c.width / factor, c.height / factor);
            if w == 0 || h == 0 {
                return Err(DataError::DownscaleTooLarge {
                    path: path.into(),
                    factor,
                    view: v.name.clone(),
                    width: c.width,
                    height: c.height,
                });
            }
            let s = 1.0 / factor as f64;
            v.camera = Camera::new(w, h, c.intrinsics.scaled(s, s), c.pose);
        }
        scene.downscale = factor;
    }
    for v in &scene.views {
        v.camera
            .validate()
            .map_err(|e| DataError::geometry(path, format!("camera of view {}", v.name), e))?;
    }
    scene.depth_bounds = match (opts.near, opts.far, scene.depth_bounds) {
        (Some(n), Some(f), _) => Some((n, f)),
        (Some(n), None, Some((_, f))) => Some((n, f)),
        (None, Some(f), Some((n, _))) => Some((n, f)),
        (None, None, b) => b,
        (n, _, None) => {
            let (given, missing) = if n.is_some() {
                ("near", "far")
            } else {
                ("far", "near")
            };
            return Err(DataError::HalfDepthBounds {
                path: path.into(),
                given,
                missing,
            });
        }
    };
    if let Some((n, f)) = scene.depth_bounds
        && !(n.is_finite() && f.is_finite() && n > 0.0 && f > n)
    {
        return Err(DataError::invalid(
            path,
            format!("invalid depth bounds near {n}, far {f} (need 0 < near < far, finite)"),
        ));
    }
    Ok(scene)
}

impl Scene {
    /// Number of views.
    pub fn len(&self) -> usize {
        self.views.len()
    }

    pub fn is_empty(&self) -> bool {
        self.views.is_empty()
    }

    pub fn cameras(&self) -> Vec<Camera> {
        self.views.iter().map(|v| v.camera).collect()
    }

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

    fn view(&self, i: usize) -> Result<&View, DataError> {
        self.views.get(i).ok_or_else(|| {
            DataError::invalid(
                &self.root,
                format!(
                    "view {i} out of range (the scene has {} views)",
                    self.views.len()
                ),
            )
        })
    }

    /// View `i`'s image as RGB (box-downscaled by [`Scene::downscale`]); an error if the file is missing or its size differs from the camera's.
    pub fn load_image(&self, i: usize) -> Result<ImageF32, DataError> {
        self.check_image(i)?;
        let v = &self.views[i];
        let img = deepview_image::read_image(&v.image_path, 3)?.downscale(self.downscale.max(1));
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

    /// `(near, far)`: the dataset's or the options' bounds, or an error asking for them.
    pub fn near_far(&self) -> Result<(f64, f64), DataError> {
        self.depth_bounds.ok_or_else(|| DataError::NoDepthBounds {
            path: self.root.clone(),
            hint: match self.format {
                SceneFormat::Spaces => {
                    " (Spaces models.json carries no depth bounds; the paper's scenes \
                                        span roughly 0.7 m to 100 m)"
                        .into()
                }
                SceneFormat::Colmap => {
                    " (the COLMAP model has no 3D points to derive them from)".into()
                }
                SceneFormat::Transforms => {
                    " (transforms.json has no \"near\"/\"far\", and no \"aabb\" in front of every camera)"
                        .into()
                }
                _ => String::new(),
            },
        })
    }
}

/// Image size from the header; files whose extension lies about their format are decoded instead.
pub(crate) fn image_size(path: &Path) -> Result<(u32, u32), DataError> {
    match deepview_image::image_size(path) {
        Ok(s) => Ok(s),
        Err(e) => match deepview_image::read_image(path, 3) {
            Ok(img) => Ok((img.width, img.height)),
            Err(_) => Err(e.into()),
        },
    }
}

/// Sorted file names in `dir` whose extension is an image type (png, jpg, jpeg; case-insensitive).
pub(crate) fn list_images(dir: &Path) -> Result<Vec<PathBuf>, DataError> {
    let rd = std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))?;
    let mut out = Vec::new();
    for entry in rd {
        let entry = entry.map_err(|e| DataError::io(dir, e))?;
        let p = entry.path();
        let ext = p
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let hidden = p
            .file_name()
            .map(|n| n.to_string_lossy().starts_with('.'))
            .unwrap_or(true);
        if !hidden && p.is_file() && matches!(ext.as_str(), "png" | "jpg" | "jpeg") {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}

pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>, DataError> {
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

pub(crate) fn read_text(path: &Path) -> Result<String, DataError> {
    std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))
}

pub(crate) fn write_bytes(path: &Path, bytes: &[u8]) -> Result<(), DataError> {
    if let Some(parent) = path.parent()
        && !parent.as_os_str().is_empty()
    {
        std::fs::create_dir_all(parent).map_err(|e| DataError::write(parent, e))?;
    }
    deepview_image::write_atomic(path, bytes).map_err(DataError::from)
}

pub(crate) fn write_image(path: &Path, img: &ImageF32) -> Result<(), DataError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| DataError::write(parent, e))?;
    }
    deepview_image::write_png(path, &img.to_rgb()).map_err(DataError::from)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_names_round_trip() {
        for f in SceneFormat::ALL {
            assert_eq!(f.to_string().parse::<SceneFormat>().unwrap(), f);
            let j = serde_json::to_string(&f).unwrap();
            assert_eq!(j, format!("\"{f}\""));
            assert_eq!(serde_json::from_str::<SceneFormat>(&j).unwrap(), f);
            assert_eq!(
                <SceneFormat as clap::ValueEnum>::from_str(f.name(), false).unwrap(),
                f
            );
        }
        assert!("nope".parse::<SceneFormat>().is_err());
    }

    #[test]
    fn undetectable_folder_lists_what_was_looked_for() {
        let dir = tempfile::tempdir().unwrap();
        let e = load_scene(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("poses_bounds.npy")
                && e.contains("models.json")
                && e.contains("input_Cam000.png"),
            "{e}"
        );
        assert!(e.contains(&dir.path().display().to_string()), "{e}");
    }

    #[test]
    fn scene_args_parse() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            scene: SceneArgs,
        }
        let c = Cli::parse_from([
            "x",
            "--format",
            "light-field",
            "--rig",
            "2",
            "--near",
            "1.5",
            "--images",
            "images_4",
        ]);
        let o = c.scene.load_options();
        assert_eq!(o.format, Some(SceneFormat::LightField));
        assert_eq!((o.rig, o.near, o.far), (2, Some(1.5), None));
        assert_eq!(o.images.as_deref(), Some("images_4"));
    }
}
