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

/// The files of `dir` that look like photos in formats that are not read (an iPhone's HEIC, raw
/// files: [`deepview_data::unread_photos`]): "; skipped N photo(s) in formats deepview does not
/// read: NAMES (convert them to JPEG first)", or an empty string.
pub fn skipped_note(dir: &Path) -> String {
    let mut names = deepview_data::unread_photos(dir);
    if names.is_empty() {
        return String::new();
    }
    let n = names.len();
    let more = n.saturating_sub(4);
    names.truncate(4);
    format!(
        "; skipped {n} photo{} in formats deepview does not read: {}{} (convert them to JPEG first)",
        if n == 1 { "" } else { "s" },
        names.join(", "),
        if more > 0 {
            format!(" and {more} more")
        } else {
            String::new()
        }
    )
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
    let mut names: Vec<String> = Vec::with_capacity(photos.len());
    for p in photos {
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        // A name that is not UTF-8 is written with U+FFFD in place of its odd bytes (COLMAP's lists are
        // text): two such names can become one, and one photo would overwrite the other.
        if let Some(first) = names.iter().position(|n| *n == name) {
            return Err(ProcessError::Invalid(format!(
                "{} and {} have the same name once their bytes that are not UTF-8 are replaced ({name}): \
                 rename one of them",
                photos[first].display(),
                p.display()
            )));
        }
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
                let decode_err = |e: image::ImageError| ProcessError::Image {
                    path: p.clone(),
                    msg: format!("cannot decode: {e}"),
                };
                let mut decoder = photo_reader(p)
                    .and_then(|r| r.into_decoder())
                    .map_err(decode_err)?;
                // The photo's EXIF goes with it: COLMAP takes its focal-length prior from there
                // (without it, a guess of 1.2 times the width).
                let exif = image::ImageDecoder::exif_metadata(&mut decoder)
                    .ok()
                    .flatten();
                let img = image::DynamicImage::from_decoder(decoder).map_err(decode_err)?;
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
                    if let Some(exif) = exif.filter(|e| !e.is_empty()) {
                        let _ = image::ImageEncoder::set_exif_metadata(&mut enc, exif);
                    }
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

    /// Two names that differ only in bytes that are not UTF-8 are refused, naming both (one photo
    /// overwrote the other, and the run said a photo was "left out").
    #[test]
    fn names_that_become_one_are_refused() {
        use std::os::unix::ffi::OsStrExt;
        let dir = tempfile::tempdir().unwrap();
        let (src, dst) = (dir.path().join("src"), dir.path().join("dst"));
        std::fs::create_dir(&src).unwrap();
        std::fs::create_dir(&dst).unwrap();
        let names = [&b"a\xff.png"[..], &b"a\xfe.png"[..]];
        for n in names {
            image::RgbImage::new(4, 4)
                .save(src.join(std::ffi::OsStr::from_bytes(n)))
                .unwrap();
        }
        let p = list_photos(&src).unwrap();
        assert_eq!(p.len(), 2);
        let e = copy_photos(&p, &dst, None).unwrap_err().to_string();
        assert!(
            e.contains("have the same name") && e.contains("rename one"),
            "{e}"
        );
    }

    /// Photos in formats that are not read are named (a few, then a count); other files are not.
    #[test]
    fn photos_in_other_formats_are_named() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(skipped_note(dir.path()), "");
        std::fs::write(dir.path().join("notes.txt"), "x").unwrap();
        std::fs::write(dir.path().join("a.jpg"), "x").unwrap();
        assert_eq!(skipped_note(dir.path()), "");
        for n in ["e.HEIC", "b.heic", "c.dng", "d.webp", "f.TIF"] {
            std::fs::write(dir.path().join(n), "x").unwrap();
        }
        assert_eq!(
            skipped_note(dir.path()),
            "; skipped 5 photos in formats deepview does not read: b.heic, c.dng, d.webp, e.HEIC \
             and 1 more (convert them to JPEG first)"
        );
    }

    /// A downscaled JPEG keeps its EXIF (COLMAP's focal-length prior comes from there).
    #[test]
    fn downscaled_photos_keep_their_exif() {
        let dir = tempfile::tempdir().unwrap();
        let src = dir.path().join("src");
        std::fs::create_dir(&src).unwrap();
        // A little-endian TIFF block with one tag: FocalLengthIn35mmFilm (0xA405, SHORT) = 26.
        let exif: Vec<u8> = [
            &b"II*\0\x08\0\0\0"[..],
            &[1, 0],
            &[0x05, 0xA4, 3, 0, 1, 0, 0, 0, 26, 0, 0, 0],
            &[0, 0, 0, 0],
        ]
        .concat();
        let f = File::create(src.join("p.jpg")).unwrap();
        let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(f, 90);
        image::ImageEncoder::set_exif_metadata(&mut enc, exif.clone()).unwrap();
        enc.encode_image(&image::RgbImage::new(64, 48)).unwrap();
        let dst = dir.path().join("dst");
        std::fs::create_dir(&dst).unwrap();
        copy_photos(&list_photos(&src).unwrap(), &dst, Some(32)).unwrap();
        assert_eq!(
            image::image_dimensions(dst.join("p.jpg")).unwrap(),
            (32, 24)
        );
        let mut d = photo_reader(&dst.join("p.jpg"))
            .unwrap()
            .into_decoder()
            .unwrap();
        let got = image::ImageDecoder::exif_metadata(&mut d).unwrap().unwrap();
        assert!(got.ends_with(&exif[8..]), "{got:?}");
    }
}
