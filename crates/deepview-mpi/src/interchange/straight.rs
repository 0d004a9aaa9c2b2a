//! The straight-alpha MPI every interchange format converts through (our folder read and written without
//! premultiplying), the export report, and the checks and parsing the format modules share.

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
