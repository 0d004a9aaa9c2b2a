//! MPI interchange: export our folder format to other tools' MPI formats and import them back.
//!
//! All conversions work on the 8-bit straight-alpha bytes of the layer files, so a round trip through any
//! of them reproduces our `layer_NNN.png` pixels exactly (see each module for the foreign layout).
//! - [`llff`]: LLFF's `metadata.txt` + `mpi.b` (what LLFF's viewers read);
//! - [`stereo_mag`]: stereo magnification's `mpi_rgb_NN.png` / `mpi_alpha_NN.png` / `intrinsics.txt`;
//! - [`compact`]: our tiled export without fully transparent tiles (read by the web viewer).

pub mod compact;
pub mod llff;
pub mod stereo_mag;

use crate::error::{MpiError, invalid, read_err};
use crate::io::{MpiMeta, read_layers, write_layers};
use deepview_geometry::Camera;
use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// An MPI as straight-alpha RGBA8 planes (`[D][H][W][4]`, far plane first), exactly as on disk.
#[derive(Clone, Debug, PartialEq)]
pub struct StraightMpi {
    pub camera: Camera,
    pub depths: Vec<f64>,
    pub planes: Vec<Vec<u8>>,
}

impl StraightMpi {
    pub fn plane_len(&self) -> usize {
        self.camera.width as usize * self.camera.height as usize * 4
    }
}

/// Decode a PNG (or any image) file to RGBA8 with its size.
pub(crate) fn decode_rgba8(path: &Path) -> Result<(u32, u32, Vec<u8>), MpiError> {
    let img = deepview_image::decode_file(path)?;
    Ok((img.width(), img.height(), img.into_rgba8().into_raw()))
}

/// Read our MPI folder (`mpi.json` + layers) without premultiplying.
pub fn read_straight(dir: &Path) -> Result<StraightMpi, MpiError> {
    let (meta, camera, planes) = read_layers(dir, |img| img.into_rgba8().into_raw())?;
    Ok(StraightMpi {
        camera,
        depths: meta.depths,
        planes,
    })
}

/// Write our MPI folder from straight-alpha planes (layers first, `mpi.json` last, all atomic).
pub fn write_straight(dir: &Path, mpi: &StraightMpi) -> Result<(), MpiError> {
    if mpi.planes.len() != mpi.depths.len() || mpi.planes.is_empty() {
        return Err(invalid(
            dir,
            format!(
                "{} planes but {} depths",
                mpi.planes.len(),
                mpi.depths.len()
            ),
        ));
    }
    let meta = MpiMeta::new(&mpi.camera, &mpi.depths);
    write_layers(dir, &meta, |d| Cow::Borrowed(&mpi.planes[d][..]))?;
    // Validate what we wrote (depth order, pose) so a bad import fails here, not in a later command.
    MpiMeta::read(dir)?;
    Ok(())
}

/// Formats `deepview export` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    Llff,
    StereoMag,
    Compact,
}

impl FromStr for ExportFormat {
    type Err = MpiError;
    fn from_str(s: &str) -> Result<Self, MpiError> {
        match s {
            "llff" => Ok(ExportFormat::Llff),
            "stereo-mag" | "stereomag" => Ok(ExportFormat::StereoMag),
            "compact" => Ok(ExportFormat::Compact),
            _ => Err(MpiError::Config(format!(
                "unknown export format {s:?} (expected llff, stereo-mag or compact)"
            ))),
        }
    }
}

/// Formats `deepview import` recognises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImportFormat {
    Deepview,
    Llff,
    StereoMag,
    Compact,
}

/// What an export wrote, with any precision the target format could not keep.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExportReport {
    pub files: Vec<PathBuf>,
    /// Total bytes written.
    pub bytes: u64,
    /// Total bytes of the source layer files (for the compact export's saving).
    pub source_bytes: u64,
    pub warnings: Vec<String>,
    /// Compact export: tiles kept / total.
    pub tiles: Option<(usize, usize)>,
}

impl ExportReport {
    pub(crate) fn add(&mut self, path: PathBuf) -> Result<(), MpiError> {
        self.bytes += std::fs::metadata(&path).map_err(read_err(&path))?.len();
        self.files.push(path);
        Ok(())
    }
}

/// Export the MPI folder `mpi_dir` to `out` in `format`.
pub fn export(mpi_dir: &Path, out: &Path, format: ExportFormat) -> Result<ExportReport, MpiError> {
    let mpi = read_straight(mpi_dir)?;
    let mut report = match format {
        ExportFormat::Llff => llff::write(out, &mpi)?,
        ExportFormat::StereoMag => stereo_mag::write(out, &mpi)?,
        ExportFormat::Compact => compact::write(out, &mpi)?,
    };
    let (meta, _) = MpiMeta::read(mpi_dir)?;
    for name in &meta.layers {
        let p = mpi_dir.join(name);
        report.source_bytes += std::fs::metadata(&p).map_err(read_err(&p))?.len();
    }
    Ok(report)
}

/// Which format the folder `dir` holds.
pub fn detect_format(dir: &Path) -> Result<ImportFormat, MpiError> {
    if !dir.is_dir() {
        return Err(invalid(dir, "not a folder"));
    }
    let has = |n: &str| dir.join(n).is_file();
    if has("mpi.json") {
        Ok(ImportFormat::Deepview)
    } else if has(compact::META) {
        Ok(ImportFormat::Compact)
    } else if has("metadata.txt") && has("mpi.b") {
        Ok(ImportFormat::Llff)
    } else if has("mpi_rgb_00.png") {
        Ok(ImportFormat::StereoMag)
    } else {
        Err(invalid(
            dir,
            format!(
                "no known MPI format: looked for mpi.json (deepview), {} (compact), metadata.txt + mpi.b (LLFF), \
                 mpi_rgb_00.png (stereo magnification)",
                compact::META
            ),
        ))
    }
}

/// Options of [`import`] for formats that do not store everything.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImportOptions {
    /// Stereo magnification stores no depths: near / far plane depths when there is no sidecar or README.
    pub near_far: Option<(f64, f64)>,
}

/// Read any supported MPI folder as straight-alpha planes.
pub fn read_any(dir: &Path, opts: &ImportOptions) -> Result<(ImportFormat, StraightMpi), MpiError> {
    let format = detect_format(dir)?;
    let mpi = match format {
        ImportFormat::Deepview => read_straight(dir)?,
        ImportFormat::Compact => compact::read(dir)?,
        ImportFormat::Llff => llff::read(dir)?,
        ImportFormat::StereoMag => stereo_mag::read(dir, opts.near_far)?,
    };
    Ok((format, mpi))
}

/// Import the MPI folder `input` (format detected) into our format at `out`.
pub fn import(input: &Path, out: &Path, opts: &ImportOptions) -> Result<ImportFormat, MpiError> {
    let (format, mpi) = read_any(input, opts)?;
    write_straight(out, &mpi)?;
    Ok(format)
}

/// Straight RGBA8 planes must be as many as depths and each `W x H x 4`.
pub(crate) fn check_planes(path: &Path, mpi: &StraightMpi) -> Result<(), MpiError> {
    if mpi.planes.len() != mpi.depths.len() {
        return Err(invalid(
            path,
            format!(
                "{} planes but {} depths",
                mpi.planes.len(),
                mpi.depths.len()
            ),
        ));
    }
    if let Some(d) = mpi.planes.iter().position(|p| p.len() != mpi.plane_len()) {
        return Err(invalid(path, format!("plane {d} has the wrong size")));
    }
    Ok(())
}

/// Relative deviation of `depths` (far to near) from equal spacing in inverse depth.
pub(crate) fn inverse_depth_spacing_error(depths: &[f64]) -> f64 {
    let n = depths.len();
    if n < 3 {
        return 0.0;
    }
    let (a, b) = (1.0 / depths[0], 1.0 / depths[n - 1]);
    (0..n)
        .map(|i| {
            let expect = a + (b - a) * i as f64 / (n - 1) as f64;
            ((1.0 / depths[i] - expect) / (b - a)).abs()
        })
        .fold(0.0, f64::max)
}

/// Parse whitespace-separated numbers of one line.
pub(crate) fn numbers(
    path: &Path,
    line_no: usize,
    line: &str,
    expect: usize,
) -> Result<Vec<f64>, MpiError> {
    let v: Result<Vec<f64>, _> = line.split_whitespace().map(f64::from_str).collect();
    let v = v.map_err(|e| invalid(path, format!("line {}: {e} in {line:?}", line_no + 1)))?;
    if v.len() < expect || !v.iter().all(|x| x.is_finite()) {
        return Err(invalid(
            path,
            format!(
                "line {}: expected {expect} finite numbers, got {line:?}",
                line_no + 1
            ),
        ));
    }
    Ok(v)
}
