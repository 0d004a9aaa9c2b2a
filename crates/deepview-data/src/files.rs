//! File helpers of the format readers and writers (errors naming the file).

use crate::DataError;
use deepview_image::ImageF32;
use std::path::{Path, PathBuf};

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
    let text = std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
    // Editors on some systems start UTF-8 files with a byte-order mark: not part of the content.
    Ok(match text.strip_prefix('\u{feff}') {
        Some(rest) => rest.to_string(),
        None => text,
    })
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
