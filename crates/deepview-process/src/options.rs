//! What to process and how ([`ProcessOptions`]), and what the pipeline reports ([`Stage`], [`Event`],
//! [`ProcessReport`]).

use std::fmt;
use std::path::PathBuf;
use std::time::Duration;

/// How images are paired for matching.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Matcher {
    /// Exhaustive up to 50 images (`ProcessOptions::exhaustive_up_to`), else sequential.
    #[default]
    Auto,
    /// Every pair (best for unordered photos; quadratic in the image count).
    Exhaustive,
    /// Neighbours in file-name order (video frames, ordered captures).
    Sequential,
}

impl fmt::Display for Matcher {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Matcher::Auto => "auto",
            Matcher::Exhaustive => "exhaustive",
            Matcher::Sequential => "sequential",
        })
    }
}

/// The one camera model shared by all photos during reconstruction (undistorted to PINHOLE at the end).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum CameraModel {
    /// Focal length, principal point and one radial distortion term (phone and compact cameras).
    #[default]
    SimpleRadial,
    /// fx, fy, cx, cy without distortion (already undistorted photos).
    Pinhole,
}

/// Where the photos come from.
#[derive(Clone, Debug, PartialEq)]
pub enum Input {
    /// A folder of photos (.jpg, .jpeg, .png; sub-folders are ignored).
    Photos(PathBuf),
    /// Frames of a video, `fps` per second, extracted with ffmpeg.
    Video { path: PathBuf, fps: f64 },
}

#[derive(Clone, Debug)]
pub struct ProcessOptions {
    pub input: Input,
    /// The scene folder to write (must not exist, or be empty).
    pub out: PathBuf,
    pub matcher: Matcher,
    /// `Matcher::Auto` matches exhaustively up to this many images.
    pub exhaustive_up_to: usize,
    pub camera_model: CameraModel,
    /// Downscale photos whose larger side exceeds this many pixels before COLMAP sees them.
    pub max_size: Option<u32>,
    /// The COLMAP program (default `colmap`, found on PATH).
    pub colmap: PathBuf,
    /// The ffmpeg program (default `ffmpeg`), for [`Input::Video`].
    pub ffmpeg: PathBuf,
}

impl ProcessOptions {
    pub fn new(input: Input, out: impl Into<PathBuf>) -> Self {
        Self {
            input,
            out: out.into(),
            matcher: Matcher::Auto,
            exhaustive_up_to: 50,
            camera_model: CameraModel::default(),
            max_size: None,
            colmap: "colmap".into(),
            ffmpeg: "ffmpeg".into(),
        }
    }
}

/// The stages, in order, for progress reports and error messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Frames,
    Photos,
    Features,
    Matching,
    Mapping,
    Undistortion,
    Scene,
}

impl fmt::Display for Stage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Stage::Frames => "frame extraction (ffmpeg)",
            Stage::Photos => "copying the photos",
            Stage::Features => "COLMAP feature extraction",
            Stage::Matching => "COLMAP matching",
            Stage::Mapping => "COLMAP mapping",
            Stage::Undistortion => "COLMAP undistortion",
            Stage::Scene => "writing the scene",
        })
    }
}

/// What [`process`] reports while it works.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// A stage starts; the text says what it works on.
    Started(Stage, String),
    /// A stage finished after this long.
    Finished(Stage, Duration),
    /// Something the user should know (e.g. images COLMAP could not register).
    Warning(String),
}

/// What [`process`] made.
#[derive(Clone, Debug, PartialEq)]
pub struct ProcessReport {
    pub out: PathBuf,
    /// Input images (after frame extraction).
    pub images: usize,
    /// Names of the registered images, sorted.
    pub registered: Vec<String>,
    /// Names of the images COLMAP left out, sorted.
    pub unregistered: Vec<String>,
    pub points: usize,
    /// `(near, far)` from the points, as every command reads them.
    pub depth_bounds: Option<(f64, f64)>,
    /// The matcher used (never `Auto`).
    pub matcher: Matcher,
    /// `(width, height)` and `(fx, fy, cx, cy)` of the undistorted camera.
    pub size: (u32, u32),
    pub intrinsics: [f64; 4],
    pub log: PathBuf,
    pub elapsed: Duration,
}
