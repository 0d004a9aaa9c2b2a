//! COLMAP's binary model files: `cameras.bin`, `images.bin`, `points3D.bin` (little-endian).

use super::model::{ColmapCamera, ColmapImage, ColmapPoint, MODELS};
use crate::DataError;
use std::collections::BTreeMap;
use std::path::Path;

/// Little-endian reader over a binary model file; errors name the file and the offset.
struct Bin<'a> {
    b: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Bin<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DataError> {
        if self.b.len() - self.pos < n {
            return Err(DataError::invalid(
                self.path,
                format!(
                    "truncated binary file: {what} at byte {} needs {n} bytes, {} left",
                    self.pos,
                    self.b.len() - self.pos
                ),
            ));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u64(&mut self, what: &str) -> Result<u64, DataError> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn i64(&mut self, what: &str) -> Result<i64, DataError> {
        Ok(i64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn i32(&mut self, what: &str) -> Result<i32, DataError> {
        Ok(i32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn f64(&mut self, what: &str) -> Result<f64, DataError> {
        let v = f64::from_le_bytes(self.take(8, what)?.try_into().unwrap());
        if !v.is_finite() {
            return Err(DataError::invalid(
                self.path,
                format!("non-finite {what} {v} at byte {}", self.pos - 8),
            ));
        }
        Ok(v)
    }
    fn count(&mut self, what: &str, item_bytes: usize) -> Result<usize, DataError> {
        let n = self.u64(what)?;
        // A count that cannot fit in the rest of the file is corruption, not a reason to allocate.
        if n as u128 * item_bytes as u128 > (self.b.len() - self.pos) as u128 {
            return Err(DataError::invalid(
                self.path,
                format!("truncated binary file: {what} = {n} does not fit"),
            ));
        }
        Ok(n as usize)
    }
}

pub fn parse_cameras_bin(
    bytes: &[u8],
    path: &Path,
) -> Result<BTreeMap<u32, ColmapCamera>, DataError> {
    let mut r = Bin {
        b: bytes,
        pos: 0,
        path,
    };
    let n = r.count("number of cameras", 24)?;
    let mut out = BTreeMap::new();
    for _ in 0..n {
        let id = r.i32("camera id")? as u32;
        let model_id = r.i32("model id")?;
        let (_, name, np) = *MODELS.iter().find(|m| m.0 == model_id).ok_or_else(|| {
            DataError::invalid(
                path,
                format!("camera {id}: unknown camera model id {model_id}"),
            )
        })?;
        let width = r.u64("width")?;
        let height = r.u64("height")?;
        let params = (0..np)
            .map(|_| r.f64("camera parameter"))
            .collect::<Result<Vec<_>, _>>()?;
        out.insert(
            id,
            ColmapCamera {
                id,
                model: name.into(),
                width,
                height,
                params,
            },
        );
    }
    Ok(out)
}

pub fn parse_images_bin(bytes: &[u8], path: &Path) -> Result<Vec<ColmapImage>, DataError> {
    let mut r = Bin {
        b: bytes,
        pos: 0,
        path,
    };
    let n = r.count("number of images", 64)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = r.i32("image id")? as u32;
        let mut v = [0.0; 7];
        for x in v.iter_mut() {
            *x = r.f64("pose value")?;
        }
        let camera_id = r.i32("camera id")? as u32;
        let rest = &bytes[r.pos..];
        let len = rest
            .iter()
            .position(|&c| c == 0)
            .ok_or_else(|| DataError::invalid(path, format!("image {id}: unterminated name")))?;
        let name = String::from_utf8_lossy(&rest[..len]).into_owned();
        r.pos += len + 1;
        let np = r.count("number of 2D points", 24)?;
        let mut ids = Vec::new();
        for _ in 0..np {
            r.take(16, "2D point")?;
            let pid = r.i64("point3D id")?;
            if pid >= 0 {
                ids.push(pid as u64);
            }
        }
        out.push(ColmapImage {
            id,
            qvec: [v[0], v[1], v[2], v[3]],
            tvec: [v[4], v[5], v[6]],
            camera_id,
            name,
            point3d_ids: ids,
        });
    }
    Ok(out)
}

pub fn parse_points3d_bin(bytes: &[u8], path: &Path) -> Result<Vec<ColmapPoint>, DataError> {
    let mut r = Bin {
        b: bytes,
        pos: 0,
        path,
    };
    let n = r.count("number of points", 51)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = r.u64("point id")?;
        let xyz = [
            r.f64("coordinate")?,
            r.f64("coordinate")?,
            r.f64("coordinate")?,
        ];
        r.take(3 + 8, "colour and error")?;
        let track = r.count("track length", 8)?;
        r.take(track * 8, "track")?;
        out.push(ColmapPoint { id, xyz });
    }
    Ok(out)
}
