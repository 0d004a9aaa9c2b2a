//! MPI interchange: export our folder format to other tools' MPI formats and import them back.
//!
//! All conversions work on the 8-bit straight-alpha bytes of the layer files, so a round trip through any
//! of them reproduces our `layer_NNN.png` pixels exactly (see each module for the foreign layout).
//! - [`llff`]: LLFF's `metadata.txt` + `mpi.b` (what LLFF's viewers read);
//! - [`stereo_mag`]: stereo magnification's `mpi_rgb_NN.png` / `mpi_alpha_NN.png` / `intrinsics.txt`;
//! - [`compact`]: our tiled export without fully transparent tiles (read by the web viewer);
//! - `straight`: the straight-alpha MPI they all convert through ([`StraightMpi`]) and their shared checks.

pub mod compact;
pub mod llff;
pub mod stereo_mag;

mod straight;

pub use straight::{ExportReport, StraightMpi, read_straight, write_straight};

use crate::error::{MpiError, invalid, read_err};
use crate::io::MpiMeta;
use std::path::Path;
use std::str::FromStr;

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
    if std::fs::symlink_metadata(dir).is_err() {
        return Err(invalid(dir, "does not exist"));
    }
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

/// The format, width, height and plane count of the MPI folder `dir`, from its metadata or image headers
/// alone (nothing decoded): what reading it will take, known before it is read.
pub fn describe(dir: &Path) -> Result<(ImportFormat, u32, u32, usize), MpiError> {
    let format = detect_format(dir)?;
    let (w, h, d) = match format {
        ImportFormat::Deepview => {
            let (meta, cam) = MpiMeta::read(dir)?;
            (cam.width, cam.height, meta.layers.len())
        }
        ImportFormat::Compact => {
            let (meta, cam) = compact::CompactMeta::read(dir)?;
            (cam.width, cam.height, meta.planes.len())
        }
        ImportFormat::Llff => llff::size(dir)?,
        ImportFormat::StereoMag => {
            let (w, h) = deepview_image::image_size(&dir.join("mpi_rgb_00.png"))?;
            let d = (0..)
                .take_while(|&i| dir.join(format!("mpi_rgb_{i:02}.png")).is_file())
                .count();
            (w, h, d)
        }
    };
    Ok((format, w, h, d))
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
