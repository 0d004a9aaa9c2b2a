//! Videos of an MPI along a camera path: PNG frames, animated GIF, or MP4 through `ffmpeg`.
//!
//! The format follows the output path: `*.gif` -> GIF (the `image` crate's encoder, looping),
//! `*.mp4` / `*.mov` / `*.mkv` -> raw RGB frames piped to `ffmpeg` (H.264, yuv420p; found on `PATH` or
//! named by `render --ffmpeg`), anything else -> a folder of `frame_00000.png ...`. Frames are the
//! premultiplied render over black, streamed to the output as they are rendered (never held). Every file is
//! written atomically (GIF and MP4 into a temporary file renamed at the end).

use crate::{MediaError, write_err};
use deepview_geometry::Camera;
use deepview_image::{temp_path, write_png_u8};
use deepview_mpi::{MpiU8, render_rgba8_into};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VideoFormat {
    PngFrames,
    Gif,
    Mp4,
}

impl VideoFormat {
    pub fn from_path(path: &Path) -> VideoFormat {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .as_deref()
        {
            Some("gif") => VideoFormat::Gif,
            Some("mp4" | "mov" | "mkv") => VideoFormat::Mp4,
            _ => VideoFormat::PngFrames,
        }
    }
}

/// What was written.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoReport {
    pub format: VideoFormat,
    pub path: PathBuf,
    pub frames: usize,
    pub seconds_rendering: f64,
}

/// A consumer of RGB8 frames.
pub trait FrameSink {
    fn push(&mut self, rgb: &[u8]) -> Result<(), MediaError>;
    fn finish(self: Box<Self>) -> Result<(), MediaError>;
}

/// `frame_00000.png ...` in a folder.
pub struct PngFrames {
    dir: PathBuf,
    width: u32,
    height: u32,
    next: usize,
}

impl PngFrames {
    pub fn new(dir: &Path, width: u32, height: u32) -> Result<Self, MediaError> {
        std::fs::create_dir_all(dir).map_err(write_err(dir))?;
        Ok(Self {
            dir: dir.into(),
            width,
            height,
            next: 0,
        })
    }
}

impl FrameSink for PngFrames {
    fn push(&mut self, rgb: &[u8]) -> Result<(), MediaError> {
        let p = self.dir.join(format!("frame_{:05}.png", self.next));
        write_png_u8(&p, self.width, self.height, 3, rgb)?;
        self.next += 1;
        Ok(())
    }
    fn finish(self: Box<Self>) -> Result<(), MediaError> {
        Ok(())
    }
}

/// How many centiseconds GIF frame `i` lasts at `fps` (see [`GifSink`]'s `frames`), at least 1.
fn gif_delay_cs(i: u64, fps: f64) -> u32 {
    let at = |k: u64| (100.0 * k as f64 / fps).round();
    (at(i + 1) - at(i)).clamp(1.0, 65_535.0) as u32
}

/// Animated, looping GIF, each frame encoded as it comes into a temporary file beside the output (so a
/// long path never holds its frames in memory), renamed into place at the end.
pub struct GifSink {
    path: PathBuf,
    tmp: PathBuf,
    width: u32,
    height: u32,
    fps: f64,
    /// Frames pushed so far: frame `i` lasts from `round(100 i / fps)` to `round(100 (i + 1) / fps)`
    /// centiseconds, so that the animation lasts frames / fps to the centisecond (a fixed rounded
    /// delay made 30 frames/s play at 33).
    frames: u64,
    encoder: Option<image::codecs::gif::GifEncoder<ErrWriter>>,
    error: std::rc::Rc<std::cell::RefCell<Option<std::io::Error>>>,
}

impl GifSink {
    pub fn new(path: &Path, width: u32, height: u32, fps: f64) -> Result<Self, MediaError> {
        use image::codecs::gif::{GifEncoder, Repeat};
        // A GIF frame lasts a whole number of centiseconds, up to 65535; browsers play frames of 0 or 1
        // cs at 10 cs, so 2 cs (50 frames/s) is the shortest that plays as written.
        if !(fps.is_finite() && (1.0 / 655.35..=50.0).contains(&fps)) {
            return Err(MediaError::Config(format!(
                "{}: a GIF plays 0.0016 to 50 frames per second (browsers slow shorter frames to 10 \
                 per second), got {fps}: choose another frame rate (--fps, or a camera path's \
                 \"seconds\") or write an MP4",
                path.display()
            )));
        }
        let tmp = temp_path(path);
        let file = std::fs::File::create(&tmp).map_err(write_err(path))?;
        // Held while it is written: a run that finds it meanwhile leaves it alone.
        deepview_image::lock_file(&file);
        let error = std::rc::Rc::new(std::cell::RefCell::new(None));
        let writer = ErrWriter {
            inner: std::io::BufWriter::new(file),
            error: error.clone(),
        };
        let mut enc = GifEncoder::new_with_speed(writer, 10);
        if let Err(e) = enc.set_repeat(Repeat::Infinite) {
            let _ = std::fs::remove_file(&tmp);
            return Err(deepview_image::ImageError::Encode {
                path: path.into(),
                source: e,
            }
            .into());
        }
        Ok(Self {
            path: path.into(),
            tmp,
            width,
            height,
            fps,
            frames: 0,
            encoder: Some(enc),
            error,
        })
    }

    fn enc_err(&self, e: image::ImageError) -> MediaError {
        deepview_image::ImageError::Encode {
            path: self.path.clone(),
            source: e,
        }
        .into()
    }
}

impl FrameSink for GifSink {
    fn push(&mut self, rgb: &[u8]) -> Result<(), MediaError> {
        let rgba: Vec<u8> = rgb
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect();
        let buf =
            image::RgbaImage::from_raw(self.width, self.height, rgba).expect("frame size matches");
        let delay = image::Delay::from_numer_denom_ms(10 * gif_delay_cs(self.frames, self.fps), 1);
        self.frames += 1;
        let frame = image::Frame::from_parts(buf, 0, 0, delay);
        let enc = self.encoder.as_mut().expect("open until finish");
        enc.encode_frame(frame).map_err(|e| self.enc_err(e))
    }
    fn finish(mut self: Box<Self>) -> Result<(), MediaError> {
        // Dropping the encoder writes the GIF trailer and flushes the file.
        drop(self.encoder.take());
        if let Some(e) = self.error.borrow_mut().take() {
            let _ = std::fs::remove_file(&self.tmp);
            return Err(write_err(&self.path)(e));
        }
        // deepview's mark, a comment extension before the trailer (`deepview_image::GIF_MARK`).
        if let Err(e) = mark_gif(&self.tmp) {
            let _ = std::fs::remove_file(&self.tmp);
            return Err(write_err(&self.path)(e));
        }
        std::fs::rename(&self.tmp, &self.path).map_err(write_err(&self.path))
    }
}

impl Drop for GifSink {
    fn drop(&mut self) {
        // Not finished (an error): no half-written GIF is left behind.
        if self.encoder.is_some() {
            drop(self.encoder.take());
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// Put [`deepview_image::GIF_MARK`] before the trailer (the last byte, `;`) of the GIF at `path`.
fn mark_gif(path: &Path) -> std::io::Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)?;
    let mut last = [0u8; 1];
    f.seek(SeekFrom::End(-1))?;
    f.read_exact(&mut last)?;
    if last != [0x3B] {
        return Err(std::io::Error::other(
            "the GIF does not end with its trailer",
        ));
    }
    f.seek(SeekFrom::End(-1))?;
    f.write_all(&deepview_image::GIF_MARK)?;
    f.write_all(&[0x3B])?;
    f.sync_all()
}

/// A buffered file that remembers its first write error (the GIF encoder writes its trailer on drop).
struct ErrWriter {
    inner: std::io::BufWriter<std::fs::File>,
    error: std::rc::Rc<std::cell::RefCell<Option<std::io::Error>>>,
}

impl ErrWriter {
    fn keep<T>(&self, r: std::io::Result<T>) -> std::io::Result<T> {
        if let Err(e) = &r {
            let mut slot = self.error.borrow_mut();
            if slot.is_none() {
                *slot = Some(std::io::Error::new(e.kind(), e.to_string()));
            }
        }
        r
    }
}

impl Write for ErrWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let r = self.inner.write(buf);
        self.keep(r)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        let r = self.inner.flush();
        self.keep(r)
    }
}

impl Drop for ErrWriter {
    fn drop(&mut self) {
        let r = self.inner.flush();
        let _ = self.keep(r);
    }
}

/// MP4 (or any container ffmpeg knows by extension) from raw RGB frames piped to `ffmpeg`.
pub struct Mp4Sink {
    path: PathBuf,
    tmp: PathBuf,
    /// The temporary, made and locked here before ffmpeg writes it (in place: the lock stays): a run
    /// that finds it meanwhile leaves it alone.
    _lock: std::fs::File,
    child: Child,
    /// Renamed into place: nothing left to clean up.
    finished: bool,
}

/// The ffmpeg program [`set_ffmpeg_program`] named (`render --ffmpeg`), else `ffmpeg` on `PATH`.
static FFMPEG: std::sync::OnceLock<String> = std::sync::OnceLock::new();

/// Use `program` for MP4 output in this process (once; later calls keep the first).
pub fn set_ffmpeg_program(program: &str) {
    let _ = FFMPEG.set(program.to_string());
}

/// The ffmpeg program ([`set_ffmpeg_program`]), else `ffmpeg` (searched on `PATH`).
pub fn ffmpeg_program() -> String {
    FFMPEG.get().cloned().unwrap_or_else(|| "ffmpeg".into())
}

impl Mp4Sink {
    pub fn new(
        path: &Path,
        width: u32,
        height: u32,
        fps: f64,
        program: &str,
    ) -> Result<Self, MediaError> {
        // H.264 in yuv420p takes even sizes only: an odd frame (an MPI of 707x505 on the 1.25x grid)
        // loses its last column or row in the video.
        let crop = format!("crop={}:{}:0:0", width & !1, height & !1);
        if width < 2 || height < 2 {
            return Err(MediaError::OddFrameSize { width, height });
        }
        if !(fps.is_finite() && (1e-3..=1000.0).contains(&fps)) {
            return Err(MediaError::Config(format!(
                "{}: a video plays 0.001 to 1000 frames per second (got {fps:e})",
                path.display()
            )));
        }
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("mp4");
        let tmp = temp_path(path).with_extension(format!("tmp.{ext}"));
        let lock = std::fs::File::create(&tmp)
            .map_err(|e| MediaError::Ffmpeg(format!("cannot write {}: {e}", tmp.display())))?;
        deepview_image::lock_file(&lock);
        let child = deepview_image::child::die_with_parent(&mut Command::new(program))
            .args(["-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s"])
            .arg(format!("{width}x{height}"))
            .arg("-r")
            .arg(format!("{fps}"))
            .args(["-i", "-", "-an", "-vf", &crop, "-c:v", "libx264", "-pix_fmt", "yuv420p"])
            .args(["-movflags", "+faststart", "-metadata", "comment=deepview"])
            .arg(deepview_image::ffmpeg_file_arg(&tmp))
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| {
                let _ = std::fs::remove_file(&tmp);
                if e.kind() == std::io::ErrorKind::NotFound {
                    MediaError::Ffmpeg(format!(
                        "cannot write {}: `{program}` was not found on PATH; install ffmpeg (e.g. apt-get install \
                         ffmpeg), name it with --ffmpeg, or write a .gif or a folder of PNG frames instead",
                        path.display()
                    ))
                } else {
                    MediaError::Ffmpeg(format!("cannot start `{program}` for {}: {e}", path.display()))
                }
            })?;
        Ok(Self {
            path: path.into(),
            tmp,
            _lock: lock,
            child,
            finished: false,
        })
    }
}

impl Drop for Mp4Sink {
    /// A sink dropped unfinished (a frame failed, ffmpeg stopped early): stop ffmpeg and remove its
    /// temporary file, leaving nothing behind.
    fn drop(&mut self) {
        if !self.finished {
            drop(self.child.stdin.take());
            let _ = self.child.kill();
            let _ = self.child.wait();
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

impl FrameSink for Mp4Sink {
    fn push(&mut self, rgb: &[u8]) -> Result<(), MediaError> {
        let stdin = self.child.stdin.as_mut().expect("stdin is piped");
        if let Err(e) = stdin.write_all(rgb) {
            // ffmpeg ended early: say how, with what it printed.
            drop(self.child.stdin.take());
            let mut stderr = String::new();
            if let Some(mut err) = self.child.stderr.take() {
                let _ = std::io::Read::read_to_string(&mut err, &mut stderr);
            }
            let status = self
                .child
                .wait()
                .map(|s| s.to_string())
                .unwrap_or_else(|w| w.to_string());
            let said = stderr.trim();
            return Err(MediaError::Ffmpeg(format!(
                "ffmpeg stopped accepting frames for {} ({e}; ffmpeg: {status}){}",
                self.path.display(),
                if said.is_empty() {
                    String::new()
                } else {
                    let lines: Vec<&str> = said.lines().collect();
                    format!(": {}", lines[lines.len().saturating_sub(5)..].join(" | "))
                }
            )));
        }
        Ok(())
    }
    fn finish(mut self: Box<Self>) -> Result<(), MediaError> {
        drop(self.child.stdin.take());
        let mut stderr = String::new();
        if let Some(mut e) = self.child.stderr.take() {
            let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
        }
        // Any error from here on leaves the cleanup to Drop (finished stays false).
        let status = self
            .child
            .wait()
            .map_err(|e| MediaError::Ffmpeg(format!("waiting for ffmpeg: {e}")))?;
        if !status.success() {
            return Err(MediaError::Ffmpeg(format!(
                "ffmpeg failed writing {} ({status}): {}",
                self.path.display(),
                stderr.trim()
            )));
        }
        // A program that exits 0 without writing (a stand-in for ffmpeg) is not a video.
        if std::fs::metadata(&self.tmp).map_or(0, |m| m.len()) == 0 {
            return Err(MediaError::Ffmpeg(format!(
                "ffmpeg exited successfully but wrote nothing for {} (is --ffmpeg a real ffmpeg?)",
                self.path.display()
            )));
        }
        std::fs::rename(&self.tmp, &self.path).map_err(write_err(&self.path))?;
        self.finished = true;
        Ok(())
    }
}

/// Open the sink for `out` (format from its extension).
pub fn open_sink(
    out: &Path,
    width: u32,
    height: u32,
    fps: f64,
) -> Result<Box<dyn FrameSink>, MediaError> {
    Ok(match VideoFormat::from_path(out) {
        VideoFormat::PngFrames => Box::new(PngFrames::new(out, width, height)?),
        VideoFormat::Gif => Box::new(GifSink::new(out, width, height, fps)?),
        VideoFormat::Mp4 => Box::new(Mp4Sink::new(out, width, height, fps, &ffmpeg_program())?),
    })
}

/// Render `mpi` into every camera of `cameras` (all of one size) and write the video `out` at `fps`,
/// calling `progress(done, total)` after every frame.
pub fn render_video(
    mpi: &MpiU8,
    cameras: &[Camera],
    out: &Path,
    fps: f64,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<VideoReport, MediaError> {
    let first = cameras
        .first()
        .ok_or_else(|| MediaError::Config("the camera path has no cameras".into()))?;
    if !(fps.is_finite() && fps > 0.0) {
        return Err(MediaError::Config(format!(
            "fps must be positive (got {fps})"
        )));
    }
    let (w, h) = (first.width, first.height);
    if let Some(c) = cameras.iter().find(|c| (c.width, c.height) != (w, h)) {
        return Err(MediaError::Config(format!(
            "all cameras of a video must share one size ({w}x{h} vs {}x{})",
            c.width, c.height
        )));
    }
    let mut sink = open_sink(out, w, h, fps)?;
    let start = std::time::Instant::now();
    let (mut scratch, mut rgba, mut rgb) = (Vec::new(), Vec::new(), Vec::new());
    for (i, cam) in cameras.iter().enumerate() {
        render_rgba8_into(mpi, cam, &mut scratch, &mut rgba);
        rgb.clear();
        rgb.extend(rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]));
        sink.push(&rgb)?;
        progress(i + 1, cameras.len());
    }
    sink.finish()?;
    Ok(VideoReport {
        format: VideoFormat::from_path(out),
        path: out.into(),
        frames: cameras.len(),
        seconds_rendering: start.elapsed().as_secs_f64(),
    })
}
