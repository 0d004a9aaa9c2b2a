//! Web viewer for multiplane images.
//!
//! The page ([`INDEX_HTML`], embedded in the binary) is self-contained WebGL2: it fetches `mpi.json` (or the
//! compact export's `mpi_compact.json`) and the layer files next to it, and draws the planes back to front as
//! textured quads at their depths with premultiplied-alpha blending, using the native renderer's
//! conventions (OpenCV axes, pixel centres at +0.5, bilinear sampling of premultiplied texels), so a fixed
//! camera (`?camera=<JSON or base64 JSON of {width,height,fx,fy,cx,cy,camera_from_world}>`) renders what
//! `deepview_mpi::render` renders. It shows the measured frame rate and exposes
//! `window.deepviewStats = {fps, frames, ready, error, ...}`.
//!
//! [`Server`] serves the page, the MPI's JSON and exactly the files that JSON names (anything else: 404),
//! on loopback unless told otherwise. [`export_web`] writes the same page and files as a static folder.

use deepview_mpi::interchange::{ImportFormat, ImportOptions, compact, detect_format, read_any};
use std::path::{Path, PathBuf};

mod server;

pub use server::{MAX_BODY, MAX_CONNECTIONS, MAX_HEAD, Server};

/// The viewer page.
pub const INDEX_HTML: &str = include_str!("../web/index.html");

#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error(transparent)]
    Mpi(#[from] deepview_mpi::MpiError),
    #[error("cannot serve on {addr}: {msg}")]
    Bind { addr: String, msg: String },
    #[error("{path}: {msg}")]
    Invalid { path: PathBuf, msg: String },
    #[error(transparent)]
    Image(#[from] deepview_image::ImageError),
}

/// The files of an MPI folder the viewer needs: the JSON first, then the layers or atlas pages.
///
/// Validates the whole MPI (every layer decoded, sizes checked), so a broken folder is refused up front.
pub fn mpi_files(dir: &Path) -> Result<Vec<String>, ViewerError> {
    let format = detect_format(dir)?;
    let files = match format {
        ImportFormat::Deepview => {
            let (meta, _) = deepview_mpi::MpiMeta::read(dir)?;
            std::iter::once("mpi.json".to_string())
                .chain(meta.layers)
                .collect()
        }
        ImportFormat::Compact => {
            let (meta, _) = compact::CompactMeta::read(dir)?;
            std::iter::once(compact::META.to_string())
                .chain(meta.pages)
                .collect()
        }
        other => {
            return Err(ViewerError::Invalid {
                path: dir.into(),
                msg: format!(
                    "is {} MPI: convert it first with `deepview import`",
                    match other {
                        ImportFormat::Llff => "an LLFF",
                        ImportFormat::StereoMag => "a stereo magnification",
                        _ => "another format's",
                    }
                ),
            });
        }
    };
    // Decode everything once: missing layers and inconsistent sizes fail here with the file's name.
    read_any(dir, &ImportOptions::default())?;
    Ok(files)
}

fn content_type(name: &str) -> &'static str {
    if name.ends_with(".json") {
        "application/json"
    } else if name.ends_with(".png") {
        "image/png"
    } else if name.ends_with(".html") {
        "text/html; charset=utf-8"
    } else {
        "application/octet-stream"
    }
}

/// The answer to `path` (URL path without query): `Some((content type, body))` or `None` for 404.
pub fn route(path: &str, dir: &Path, files: &[String]) -> Option<(&'static str, Vec<u8>)> {
    let name = path.strip_prefix('/')?;
    if name.is_empty() || name == "index.html" {
        return Some((content_type("index.html"), INDEX_HTML.as_bytes().to_vec()));
    }
    // Only the exact names listed in the MPI's JSON (plain file names, validated on start); no decoding,
    // so "..", "%2e%2e", absolute paths and sub-folders never match.
    // The names the JSON lists now, too: an MPI rewritten while it is viewed (another `demo`, a new
    // `infer`) may have more layers than at the start, and a reload of the page must find them.
    let listed = match files.iter().find(|f| f.as_str() == name) {
        Some(f) => f.clone(),
        // (Only a regular file there: not a link out of the folder.)
        None => listed_now(dir)
            .into_iter()
            .find(|f| f == name)
            .filter(|f| std::fs::symlink_metadata(dir.join(f)).is_ok_and(|m| m.is_file()))?,
    };
    let bytes = std::fs::read(dir.join(&listed)).ok()?;
    Some((content_type(&listed), bytes))
}

/// The files the MPI folder's JSON lists at this moment (its names checked as plain file names by the
/// readers); none where it cannot be read.
fn listed_now(dir: &Path) -> Vec<String> {
    if let Ok((meta, _)) = deepview_mpi::MpiMeta::read(dir) {
        return std::iter::once("mpi.json".to_string())
            .chain(meta.layers)
            .collect();
    }
    if let Ok((meta, _)) = compact::CompactMeta::read(dir) {
        return std::iter::once(compact::META.to_string())
            .chain(meta.pages)
            .collect();
    }
    Vec::new()
}

/// Write the viewer page and the MPI's files to `out` as a static site (`index.html` + the MPI files).
pub fn export_web(mpi_dir: &Path, out: &Path) -> Result<Vec<PathBuf>, ViewerError> {
    let files = mpi_files(mpi_dir)?;
    std::fs::create_dir_all(out).map_err(|e| ViewerError::Invalid {
        path: out.into(),
        msg: format!("cannot create: {e}"),
    })?;
    let mut written = Vec::new();
    // Layers first, the JSON after them, the page last: a readable page always has its MPI.
    for name in files.iter().skip(1).chain(files.first()) {
        let src = mpi_dir.join(name);
        let bytes = std::fs::read(&src).map_err(|e| ViewerError::Invalid {
            path: src.clone(),
            msg: format!("cannot read: {e}"),
        })?;
        let dst = out.join(name);
        // Layers of an MPI another program wrote get deepview's mark in the copy, so that the next
        // export replaces the folder it made.
        deepview_image::write_atomic(&dst, &deepview_image::with_mark(bytes))?;
        written.push(dst);
    }
    let index = out.join("index.html");
    deepview_image::write_atomic(&index, INDEX_HTML.as_bytes())?;
    written.push(index);
    Ok(written)
}
