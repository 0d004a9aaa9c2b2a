//! From a folder of photos (or a video) to a posed scene, like nerfstudio's `ns-process-data`: runs COLMAP
//! (CPU SIFT, no display) through feature extraction, matching, mapping and undistortion, and writes a
//! COLMAP scene folder that every `deepview` command reads:
//!
//! ```text
//! SCENE_DIR/images/        undistorted photos (one shared PINHOLE camera)
//! SCENE_DIR/sparse/0/      cameras.bin, images.bin, points3D.bin (depth bounds come from the points)
//! SCENE_DIR/colmap.log     COLMAP's (and ffmpeg's) own output, stage by stage
//! SCENE_DIR/colmap/        database.db and the model before undistortion
//! ```
//!
//! Existing output is never replaced: the scene is built in the sibling folder `SCENE_DIR.incomplete` and
//! renamed into place at the end; after a failure that folder (with its `colmap.log`) is kept for
//! inspection and reused by the next run.

use deepview_data::{DataError, LoadOptions, load_scene, read_colmap};
use std::fmt;
use std::fs::{File, OpenOptions};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The install hint shown when COLMAP cannot be run.
pub const INSTALL_COLMAP: &str = "install it with `apt-get install colmap` (Debian/Ubuntu; `brew install colmap` on macOS) or name the program";

/// Marks a working folder as ours, so that a later run may reuse (clear) it.
const MARKER: &str = ".deepview-process";

#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error("cannot run COLMAP ({program}): {reason}; {INSTALL_COLMAP}")]
    ColmapMissing { program: PathBuf, reason: String },
    #[error(
        "cannot run ffmpeg ({program}): {reason}; install it with `apt-get install ffmpeg` or name the program"
    )]
    FfmpegMissing { program: PathBuf, reason: String },
    #[error("{stage} failed ({status}); the last lines of {log}:\n{tail}")]
    StageFailed {
        stage: Stage,
        status: String,
        log: PathBuf,
        tail: String,
    },
    #[error("{dir}: no images found (looked for .jpg, .jpeg and .png files)")]
    NoImages { dir: PathBuf },
    #[error("{dir}: only {count} image, but COLMAP needs at least 2 overlapping photos")]
    TooFewImages { dir: PathBuf, count: usize },
    #[error(
        "COLMAP registered {registered} of {total} images, but at least 2 are needed; not registered: {missing}. \
         Are these photos of one scene, overlapping, sharp and textured? (COLMAP's log: {log})"
    )]
    NotRegistered {
        registered: usize,
        total: usize,
        missing: String,
        log: PathBuf,
    },
    #[error(
        "{path} already exists and is not empty; choose another output folder or move it away (existing output is \
         never replaced)"
    )]
    OutputExists { path: PathBuf },
    #[error(
        "{path} exists and was not made by `deepview process`; move it away (it is where the scene is built)"
    )]
    WorkFolderTaken { path: PathBuf },
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {msg}")]
    Image { path: PathBuf, msg: String },
    #[error("{0}")]
    Invalid(String),
    #[error("the scene COLMAP made does not load: {0}")]
    Data(#[from] DataError),
}

fn read_err(path: &Path) -> impl FnOnce(std::io::Error) -> ProcessError + '_ {
    move |source| ProcessError::Read {
        path: path.into(),
        source,
    }
}

fn write_err(path: &Path) -> impl FnOnce(std::io::Error) -> ProcessError + '_ {
    move |source| ProcessError::Write {
        path: path.into(),
        source,
    }
}

/// How images are paired for matching.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Matcher {
    /// Exhaustive up to [`ProcessOptions::exhaustive_up_to`] images, else sequential.
    #[default]
    Auto,
    /// Every pair (best for unordered photos; quadratic in the image count).
    Exhaustive,
    /// Neighbours in file-name order (video frames, ordered captures).
    Sequential,
}

impl Matcher {
    fn colmap_command(self) -> &'static str {
        match self {
            Matcher::Sequential => "sequential_matcher",
            _ => "exhaustive_matcher",
        }
    }
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

impl CameraModel {
    fn colmap_name(self) -> &'static str {
        match self {
            CameraModel::SimpleRadial => "SIMPLE_RADIAL",
            CameraModel::Pinhole => "PINHOLE",
        }
    }
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

/// Image files (jpg, jpeg, png; case-insensitive, not hidden) directly in `dir`, sorted by name.
pub fn list_photos(dir: &Path) -> Result<Vec<PathBuf>, ProcessError> {
    let rd = std::fs::read_dir(dir).map_err(read_err(dir))?;
    let mut out = Vec::new();
    for entry in rd {
        let p = entry.map_err(read_err(dir))?.path();
        let ext = p
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let hidden = p
            .file_name()
            .is_none_or(|n| n.to_string_lossy().starts_with('.'));
        if !hidden && p.is_file() && matches!(ext.as_str(), "png" | "jpg" | "jpeg") {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}

/// Runs programs with their output appended to the log.
struct Runner {
    log: PathBuf,
}

impl Runner {
    fn open(&self) -> Result<File, ProcessError> {
        OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.log)
            .map_err(write_err(&self.log))
    }

    /// The last `n` non-empty lines of the log.
    fn tail(&self, n: usize) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
        lines[lines.len().saturating_sub(n)..].join("\n")
    }

    /// Run `cmd` for `stage`; `missing` builds the error when the program cannot be started.
    fn run(
        &self,
        stage: Stage,
        mut cmd: Command,
        missing: impl FnOnce(String) -> ProcessError,
    ) -> Result<(), ProcessError> {
        let mut f = self.open()?;
        let line = format!("{cmd:?}").replace('"', "");
        writeln!(f, "\n===== {stage}: {line}").map_err(write_err(&self.log))?;
        let out = f.try_clone().map_err(write_err(&self.log))?;
        let err = f.try_clone().map_err(write_err(&self.log))?;
        let status = cmd
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(err)
            .status()
            .map_err(|e| missing(e.to_string()))?;
        if status.success() {
            Ok(())
        } else {
            Err(ProcessError::StageFailed {
                stage,
                status: status.to_string(),
                log: self.log.clone(),
                tail: self.tail(15),
            })
        }
    }
}

fn colmap_command(program: &Path, sub: &str) -> Command {
    let mut c = Command::new(program);
    c.arg(sub)
        .env("QT_QPA_PLATFORM", "offscreen")
        .args(["--log_to_stderr", "1"]);
    c
}

/// Check that `program` runs (`colmap help`), before any long work.
fn check_colmap(program: &Path) -> Result<(), ProcessError> {
    let missing = |reason: String| ProcessError::ColmapMissing {
        program: program.into(),
        reason,
    };
    let out = Command::new(program)
        .arg("help")
        .env("QT_QPA_PLATFORM", "offscreen")
        .stdin(Stdio::null())
        .output()
        .map_err(|e| missing(e.to_string()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !text.contains("COLMAP") {
        return Err(missing(format!(
            "`{} help` did not print COLMAP's help ({})",
            program.display(),
            out.status
        )));
    }
    Ok(())
}

/// The folder the scene is built in, beside `out`: cleared when it is ours, refused otherwise.
fn work_folder(out: &Path) -> Result<PathBuf, ProcessError> {
    let name = out.file_name().ok_or_else(|| {
        ProcessError::Invalid(format!("the output {} has no folder name", out.display()))
    })?;
    let mut work_name = name.to_os_string();
    work_name.push(".incomplete");
    let work = out.with_file_name(work_name);
    if work.exists() {
        if !work.join(MARKER).is_file() {
            return Err(ProcessError::WorkFolderTaken { path: work });
        }
        std::fs::remove_dir_all(&work).map_err(write_err(&work))?;
    }
    std::fs::create_dir_all(&work).map_err(write_err(&work))?;
    std::fs::write(work.join(MARKER), "built by deepview process\n").map_err(write_err(&work))?;
    Ok(work)
}

fn out_is_free(out: &Path) -> Result<(), ProcessError> {
    let taken = match std::fs::read_dir(out) {
        Ok(mut rd) => rd.next().is_some(),
        Err(_) => out.exists(),
    };
    if taken {
        Err(ProcessError::OutputExists { path: out.into() })
    } else {
        Ok(())
    }
}

/// Copy (or downscale into) `dst` the photos of `src`; returns their file names.
fn copy_photos(
    photos: &[PathBuf],
    dst: &Path,
    max_size: Option<u32>,
) -> Result<Vec<String>, ProcessError> {
    let mut names = Vec::with_capacity(photos.len());
    for p in photos {
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let target = dst.join(&name);
        let resize = match max_size {
            None => None,
            Some(m) => {
                let (w, h) = image::image_dimensions(p).map_err(|e| ProcessError::Image {
                    path: p.clone(),
                    msg: e.to_string(),
                })?;
                (w.max(h) > m).then_some(m)
            }
        };
        match resize {
            None => {
                std::fs::copy(p, &target).map_err(write_err(&target))?;
            }
            Some(m) => {
                let img = image::open(p).map_err(|e| ProcessError::Image {
                    path: p.clone(),
                    msg: format!("cannot decode: {e}"),
                })?;
                let img = img.resize(m, m, image::imageops::FilterType::Lanczos3);
                let ext = target
                    .extension()
                    .map(|e| e.to_string_lossy().to_ascii_lowercase())
                    .unwrap_or_default();
                let result = if ext == "png" {
                    img.save(&target)
                } else {
                    let f = File::create(&target).map_err(write_err(&target))?;
                    let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(
                        std::io::BufWriter::new(f),
                        95,
                    );
                    enc.encode_image(&img.to_rgb8())
                };
                result.map_err(|e| ProcessError::Image {
                    path: target.clone(),
                    msg: format!("cannot write: {e}"),
                })?;
            }
        }
        names.push(name);
    }
    Ok(names)
}

/// The model folder under `sparse` with the most registered images, and their names.
fn best_model(sparse: &Path) -> Result<Option<(PathBuf, Vec<String>)>, ProcessError> {
    let mut best: Option<(PathBuf, Vec<String>)> = None;
    let Ok(rd) = std::fs::read_dir(sparse) else {
        return Ok(None);
    };
    let mut dirs: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("images.bin").is_file())
        .collect();
    dirs.sort();
    for d in dirs {
        let model = read_colmap(&d)?;
        let mut names: Vec<String> = model.images.iter().map(|i| i.name.clone()).collect();
        names.sort();
        if best.as_ref().is_none_or(|b| names.len() > b.1.len()) {
            best = Some((d, names));
        }
    }
    Ok(best)
}

fn rename(from: &Path, to: &Path) -> Result<(), ProcessError> {
    std::fs::rename(from, to).map_err(|e| ProcessError::Write {
        path: to.into(),
        source: std::io::Error::new(e.kind(), format!("moving {} here: {e}", from.display())),
    })
}

fn list(names: &[String]) -> String {
    const SHOW: usize = 20;
    let mut s = names
        .iter()
        .take(SHOW)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > SHOW {
        s.push_str(&format!(" and {} more", names.len() - SHOW));
    }
    if s.is_empty() { "none".into() } else { s }
}

/// Run the whole pipeline; `progress` hears of every stage. See the crate documentation for the output.
pub fn process(
    opts: &ProcessOptions,
    progress: &mut dyn FnMut(Event),
) -> Result<ProcessReport, ProcessError> {
    let t0 = Instant::now();
    let out = &opts.out;
    out_is_free(out)?;
    // Fail fast on empty folders and missing tools, before any long work.
    let photos = match &opts.input {
        Input::Photos(dir) => {
            let p = list_photos(dir)?;
            match p.len() {
                0 => return Err(ProcessError::NoImages { dir: dir.clone() }),
                1 => {
                    return Err(ProcessError::TooFewImages {
                        dir: dir.clone(),
                        count: 1,
                    });
                }
                _ => Some(p),
            }
        }
        Input::Video { path, fps } => {
            if !path.is_file() {
                return Err(ProcessError::Read {
                    path: path.clone(),
                    source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such video file"),
                });
            }
            if !(fps.is_finite() && *fps > 0.0) {
                return Err(ProcessError::Invalid(format!(
                    "the frame rate must be a positive number (got {fps})"
                )));
            }
            None
        }
    };
    check_colmap(&opts.colmap)?;
    let work = work_folder(out)?;
    let runner = Runner {
        log: work.join("colmap.log"),
    };
    let colmap_dir = work.join("colmap");
    let input = colmap_dir.join("input");
    std::fs::create_dir_all(&input).map_err(write_err(&input))?;
    let timed = |stage: Stage,
                 what: String,
                 progress: &mut dyn FnMut(Event),
                 f: &mut dyn FnMut() -> Result<(), ProcessError>| {
        progress(Event::Started(stage, what));
        let t = Instant::now();
        f()?;
        progress(Event::Finished(stage, t.elapsed()));
        Ok::<(), ProcessError>(())
    };

    // 1. Photos: copied (or downscaled), or frames extracted from the video.
    let mut names = Vec::new();
    match (&opts.input, &photos) {
        (Input::Video { path, fps }, _) => {
            let frames = colmap_dir.join("frames");
            std::fs::create_dir_all(&frames).map_err(write_err(&frames))?;
            timed(
                Stage::Frames,
                format!("{} at {fps} frames per second", path.display()),
                progress,
                &mut || {
                    let mut c = Command::new(&opts.ffmpeg);
                    c.args(["-hide_banner", "-nostdin", "-loglevel", "error", "-i"])
                        .arg(path)
                        .args(["-vf", &format!("fps={fps}"), "-q:v", "2"])
                        .arg(frames.join("frame_%05d.jpg"));
                    runner.run(Stage::Frames, c, |reason| ProcessError::FfmpegMissing {
                        program: opts.ffmpeg.clone(),
                        reason,
                    })
                },
            )?;
            let p = list_photos(&frames)?;
            if p.len() < 2 {
                return Err(ProcessError::TooFewImages {
                    dir: frames,
                    count: p.len(),
                });
            }
            timed(
                Stage::Photos,
                format!("{} frames", p.len()),
                progress,
                &mut || {
                    names = copy_photos(&p, &input, opts.max_size)?;
                    Ok(())
                },
            )?;
            std::fs::remove_dir_all(&frames).map_err(write_err(&frames))?;
        }
        (Input::Photos(dir), Some(p)) => {
            let what = match opts.max_size {
                Some(m) => format!("{} photos from {}, at most {m} px", p.len(), dir.display()),
                None => format!("{} photos from {}", p.len(), dir.display()),
            };
            timed(Stage::Photos, what, progress, &mut || {
                names = copy_photos(p, &input, opts.max_size)?;
                Ok(())
            })?;
        }
        (Input::Photos(_), None) => unreachable!("photos are listed above"),
    }

    // 2. COLMAP: features, matches, mapping, undistortion.
    let db = colmap_dir.join("database.db");
    let missing = |reason: String| ProcessError::ColmapMissing {
        program: opts.colmap.clone(),
        reason,
    };
    timed(
        Stage::Features,
        format!(
            "SIFT on the CPU, one shared {} camera",
            opts.camera_model.colmap_name()
        ),
        progress,
        &mut || {
            let mut c = colmap_command(&opts.colmap, "feature_extractor");
            c.arg("--database_path")
                .arg(&db)
                .arg("--image_path")
                .arg(&input)
                .args(["--ImageReader.single_camera", "1"])
                .args([
                    "--ImageReader.camera_model",
                    opts.camera_model.colmap_name(),
                ])
                .args(["--SiftExtraction.use_gpu", "0"]);
            runner.run(Stage::Features, c, missing)
        },
    )?;
    let matcher = match opts.matcher {
        Matcher::Auto if names.len() <= opts.exhaustive_up_to => Matcher::Exhaustive,
        Matcher::Auto => Matcher::Sequential,
        m => m,
    };
    timed(
        Stage::Matching,
        format!("{matcher}, {} images", names.len()),
        progress,
        &mut || {
            let mut c = colmap_command(&opts.colmap, matcher.colmap_command());
            c.arg("--database_path")
                .arg(&db)
                .args(["--SiftMatching.use_gpu", "0"]);
            runner.run(Stage::Matching, c, missing)
        },
    )?;
    let sparse = colmap_dir.join("sparse");
    std::fs::create_dir_all(&sparse).map_err(write_err(&sparse))?;
    let not_registered = |registered: &[String]| {
        let missing: Vec<String> = names
            .iter()
            .filter(|n| !registered.contains(n))
            .cloned()
            .collect();
        missing
    };
    let mapped = timed(
        Stage::Mapping,
        "incremental structure from motion".into(),
        progress,
        &mut || {
            let mut c = colmap_command(&opts.colmap, "mapper");
            c.arg("--database_path")
                .arg(&db)
                .arg("--image_path")
                .arg(&input)
                .arg("--output_path")
                .arg(&sparse);
            runner.run(Stage::Mapping, c, missing)
        },
    );
    let best = best_model(&sparse)?;
    // The mapper fails when it cannot start a model at all: say which images, not just "failed".
    let (model_dir, registered) = match (mapped, best) {
        (Ok(()), Some(b)) => b,
        (Err(ProcessError::StageFailed { .. }), None) | (Ok(()), None) => {
            return Err(ProcessError::NotRegistered {
                registered: 0,
                total: names.len(),
                missing: list(&names),
                log: runner.log.clone(),
            });
        }
        (Err(e), _) => return Err(e),
    };
    let unregistered = not_registered(&registered);
    if registered.len() < 2 {
        return Err(ProcessError::NotRegistered {
            registered: registered.len(),
            total: names.len(),
            missing: list(&unregistered),
            log: runner.log.clone(),
        });
    }
    if !unregistered.is_empty() {
        progress(Event::Warning(format!(
            "COLMAP registered {} of {} images; left out (not in the scene): {}",
            registered.len(),
            names.len(),
            list(&unregistered)
        )));
    }
    let undistorted = colmap_dir.join("undistorted");
    timed(
        Stage::Undistortion,
        format!("{} images to one PINHOLE camera", registered.len()),
        progress,
        &mut || {
            let mut c = colmap_command(&opts.colmap, "image_undistorter");
            c.arg("--image_path")
                .arg(&input)
                .arg("--input_path")
                .arg(&model_dir)
                .arg("--output_path")
                .arg(&undistorted)
                .args(["--output_type", "COLMAP"]);
            runner.run(Stage::Undistortion, c, missing)
        },
    )?;

    // 3. The scene folder: images/, sparse/0/, checked by loading it as every command will.
    let mut report = None;
    timed(
        Stage::Scene,
        out.display().to_string(),
        progress,
        &mut || {
            rename(&undistorted.join("images"), &work.join("images"))?;
            let model0 = work.join("sparse").join("0");
            std::fs::create_dir_all(work.join("sparse")).map_err(write_err(&work))?;
            rename(&undistorted.join("sparse"), &model0)?;
            std::fs::remove_dir_all(&undistorted).map_err(write_err(&undistorted))?;
            std::fs::remove_dir_all(&input).map_err(write_err(&input))?;
            let scene = load_scene(&work, &LoadOptions::default())?;
            scene.check_images()?;
            let model = read_colmap(&model0)?;
            let c = scene.views[0].camera;
            report = Some(ProcessReport {
                out: out.clone(),
                images: names.len(),
                registered: registered.clone(),
                unregistered: unregistered.clone(),
                points: model.points.len(),
                depth_bounds: scene.depth_bounds,
                matcher,
                size: (c.width, c.height),
                intrinsics: [
                    c.intrinsics.fx,
                    c.intrinsics.fy,
                    c.intrinsics.cx,
                    c.intrinsics.cy,
                ],
                log: out.join("colmap.log"),
                elapsed: Duration::ZERO,
            });
            std::fs::remove_file(work.join(MARKER)).map_err(write_err(&work))?;
            // Rename into place; an `out` that appeared meanwhile is left alone (the scene stays in `work`).
            out_is_free(out)?;
            if out.is_dir() {
                std::fs::remove_dir(out).map_err(write_err(out))?;
            }
            rename(&work, out)
        },
    )?;
    let mut report = report.expect("set by the last stage");
    if report.depth_bounds.is_none() {
        progress(Event::Warning(
            "the model has no 3D points in front of the cameras: the scene has no depth bounds (give them to the \
             other commands)"
                .into(),
        ));
    }
    report.elapsed = t0.elapsed();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_colmap_says_how_to_install_it() {
        let dir = tempfile::tempdir().unwrap();
        for n in ["a.png", "b.png"] {
            image::RgbImage::new(4, 4).save(dir.path().join(n)).unwrap();
        }
        let mut o = ProcessOptions::new(Input::Photos(dir.path().into()), dir.path().join("out"));
        o.colmap = "/nonexistent/colmap".into();
        let e = process(&o, &mut |_| {}).unwrap_err().to_string();
        assert!(
            e.contains("/nonexistent/colmap") && e.contains("apt-get install colmap"),
            "{e}"
        );
        assert!(!dir.path().join("out").exists());
        assert!(!dir.path().join("out.incomplete").exists());
    }

    #[test]
    fn existing_output_is_refused_and_left_alone() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("scene");
        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("keep.txt"), "mine").unwrap();
        let o = ProcessOptions::new(Input::Photos(dir.path().into()), &out);
        let e = process(&o, &mut |_| {}).unwrap_err().to_string();
        assert!(e.contains("already exists") && e.contains("scene"), "{e}");
        assert_eq!(
            std::fs::read_to_string(out.join("keep.txt")).unwrap(),
            "mine"
        );
        // A folder in the working folder's place that is not ours is not touched either.
        let taken = dir.path().join("other.incomplete");
        std::fs::create_dir(&taken).unwrap();
        let e = work_folder(&dir.path().join("other"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("other.incomplete"), "{e}");
        assert!(taken.is_dir());
    }

    #[test]
    fn photo_listing_and_downscaling() {
        let dir = tempfile::tempdir().unwrap();
        let src = dir.path().join("src");
        std::fs::create_dir(&src).unwrap();
        image::RgbImage::new(40, 20)
            .save(src.join("b.png"))
            .unwrap();
        image::RgbImage::new(10, 30)
            .save(src.join("a.JPG"))
            .unwrap();
        std::fs::write(src.join("notes.txt"), "x").unwrap();
        std::fs::write(src.join(".hidden.png"), "x").unwrap();
        let p = list_photos(&src).unwrap();
        let names: Vec<_> = p
            .iter()
            .map(|p| p.file_name().unwrap().to_owned())
            .collect();
        assert_eq!(names, ["a.JPG", "b.png"]);
        let dst = dir.path().join("dst");
        std::fs::create_dir(&dst).unwrap();
        assert_eq!(copy_photos(&p, &dst, Some(20)).unwrap(), ["a.JPG", "b.png"]);
        assert_eq!(
            image::image_dimensions(dst.join("b.png")).unwrap(),
            (20, 10)
        );
        assert_eq!(image::image_dimensions(dst.join("a.JPG")).unwrap().1, 20);
    }
}
