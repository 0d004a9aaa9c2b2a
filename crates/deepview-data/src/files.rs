//! File helpers of the format readers and writers (errors naming the file).

use crate::DataError;
use deepview_image::ImageF32;
use std::path::{Path, PathBuf};

/// Image size from the header; files whose extension lies about their format are decoded instead.
pub(crate) fn image_size(path: &Path) -> Result<(u32, u32), DataError> {
    match deepview_image::image_size(path) {
        Ok(s) => Ok(s),
        // (The decoder's error names the file's real format, or why it cannot be read.)
        Err(_) => match deepview_image::read_image(path, 3) {
            Ok(img) => Ok((img.width, img.height)),
            Err(e) => Err(e.into()),
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

/// Photo, raw and other image formats that are not read as views (files named `.png`, `.jpg` or
/// `.jpeg` are).
const UNREAD_PHOTOS: &[&str] = &[
    "heic", "heif", "avif", "webp", "tif", "tiff", "dng", "raw", "cr2", "cr3", "nef", "arw", "orf",
    "rw2", "raf", "bmp", "exr", "gif",
];

/// The names of `dir`'s files in formats deepview does not read as photos ([`UNREAD_PHOTOS`]: an
/// iPhone's HEIC, raw files, TIFF, ...), sorted.
pub fn unread_photos(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .map(|e| e.to_string_lossy().to_ascii_lowercase())
                    .is_some_and(|e| UNREAD_PHOTOS.contains(&e.as_str()))
        })
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    names.sort();
    names
}

/// Why a folder's image count may not be what its user expects: its files with an image
/// extension deepview does not read, and the names that appear with two extensions (the
/// `listed` files of [`list_images`] share a stem). Empty where there is neither; otherwise
/// starts with "; ".
pub(crate) fn image_count_note(dir: &Path, listed: &[PathBuf]) -> String {
    let mut unread = unread_photos(dir);
    let mut note = String::new();
    if !unread.is_empty() {
        let more = unread.len().saturating_sub(5);
        unread.truncate(5);
        note += &format!(
            "; not read: {}{} (deepview reads PNG and JPEG views)",
            unread.join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        );
    }
    let stems: Vec<_> = listed.iter().map(|p| p.with_extension("")).collect();
    if let Some(i) = (1..stems.len()).find(|&i| stems[..i].contains(&stems[i])) {
        let first = stems[..i].iter().position(|s| s == &stems[i]).unwrap_or(0);
        let name = |p: &PathBuf| {
            p.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default()
        };
        note += &format!(
            "; {} and {} are one view twice?",
            name(&listed[first]),
            name(&listed[i])
        );
    }
    note
}

/// A dataset's file: a pipe, socket or device in its place is refused (reading a pipe waited for a
/// writer for ever, `/dev/zero` filled the memory). No size bound: COLMAP models of large captures run
/// to hundreds of MiB.
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>, DataError> {
    deepview_image::refuse_special(path, "a dataset file").map_err(|e| DataError::io(path, e))?;
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

/// [`read_file`] as UTF-8 text, without a byte-order mark.
pub(crate) fn read_text(path: &Path) -> Result<String, DataError> {
    deepview_image::refuse_special(path, "a dataset file").map_err(|e| DataError::io(path, e))?;
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

/// The file name of view `i` of `n` that the writers give (`image007.png`): zero-padded to the digits
/// of `n - 1` (at least 3), so that the readers' name order is the views' order (`image1000.png`
/// sorted before `image101.png` in a scene of 1,001 views).
pub fn view_file_name(i: usize, n: usize) -> String {
    let digits = n.saturating_sub(1).max(1).ilog10() as usize + 1;
    format!("image{i:0width$}.png", width = digits.max(3))
}

#[cfg(test)]
mod tests {
    /// The writers' view names sort in the views' order, past 1,000 views too.
    #[test]
    fn view_names_sort_in_view_order() {
        assert_eq!(super::view_file_name(0, 1), "image000.png");
        assert_eq!(super::view_file_name(7, 41), "image007.png");
        for n in [9, 41, 1000, 1001, 12345] {
            let names: Vec<String> = (0..n).map(|i| super::view_file_name(i, n)).collect();
            let mut sorted = names.clone();
            sorted.sort();
            assert_eq!(names, sorted, "{n} views");
        }
        assert_eq!(super::view_file_name(5, 1001), "image0005.png");
    }
}
