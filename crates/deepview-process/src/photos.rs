//! The input photos: listing a folder's images, copying (or downscaling) them for COLMAP.

use crate::ProcessError;
use crate::error::{read_err, write_err};
use std::fs::File;
use std::path::{Path, PathBuf};

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

/// A photo's size from its header, its format from its content (as COLMAP reads it), not its extension:
/// a JPEG saved as `.png` is still a photo.
pub(crate) fn photo_dimensions(path: &Path) -> image::ImageResult<(u32, u32)> {
    photo_reader(path)?.into_dimensions()
}

/// A reader of the photo `path` in the format its content has.
fn photo_reader(path: &Path) -> image::ImageResult<image::ImageReader<std::io::BufReader<File>>> {
    image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(image::ImageError::IoError)
}

/// Copy (or downscale into) `dst` the photos of `src`; returns their file names.
pub(crate) fn copy_photos(
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
                let (w, h) = photo_dimensions(p).map_err(|e| ProcessError::Image {
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
                let img =
                    photo_reader(p)
                        .and_then(|r| r.decode())
                        .map_err(|e| ProcessError::Image {
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

#[cfg(test)]
mod tests {
    use super::*;

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
