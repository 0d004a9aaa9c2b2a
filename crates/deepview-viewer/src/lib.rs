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
use std::sync::Arc;

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
                msg: format!("is an {other:?} MPI: convert it first with `deepview import`"),
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

/// A running viewer server (a worker thread answers requests until [`Server::stop`] or drop).
pub struct Server {
    http: Arc<tiny_http::Server>,
    workers: Vec<std::thread::JoinHandle<()>>,
    url: String,
}

impl Server {
    /// Serve the MPI folder `dir` on `host:port` (port 0: any free port).
    pub fn start(dir: &Path, host: &str, port: u16) -> Result<Server, ViewerError> {
        let files = Arc::new(mpi_files(dir)?);
        let addr = format!("{host}:{port}");
        let http = tiny_http::Server::http(&addr).map_err(|e| ViewerError::Bind {
            addr: addr.clone(),
            msg: e.to_string(),
        })?;
        let local = http
            .server_addr()
            .to_ip()
            .ok_or_else(|| ViewerError::Bind {
                addr: addr.clone(),
                msg: "not an IP socket".into(),
            })?;
        let url_host = if local.ip().is_unspecified() {
            "127.0.0.1".to_string()
        } else {
            local.ip().to_string()
        };
        let url_host = if url_host.contains(':') {
            format!("[{url_host}]")
        } else {
            url_host
        };
        let url = format!("http://{url_host}:{}/", local.port());
        let http = Arc::new(http);
        let http_keep = http.clone();
        let dir = Arc::new(dir.to_path_buf());
        // One thread answers requests in arrival order. (tiny_http writes the responses of one keep-alive
        // connection in request order, so several workers holding later requests of a connection while its
        // earlier one waits in the queue could all block; the files are small and local.)
        let workers = vec![std::thread::spawn(move || {
            for req in http.incoming_requests() {
                handle(req, &dir, &files);
            }
        })];
        let http = http_keep;
        Ok(Server { http, workers, url })
    }

    /// `http://host:port/`.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Block until the server stops (it does not stop by itself: for the CLI).
    pub fn wait(mut self) {
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }

    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        for _ in 0..self.workers.len() {
            self.http.unblock();
        }
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.shutdown();
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
    let listed = files.iter().find(|f| f.as_str() == name)?;
    let bytes = std::fs::read(dir.join(listed)).ok()?;
    Some((content_type(listed), bytes))
}

fn handle(req: tiny_http::Request, dir: &Path, files: &[String]) {
    use tiny_http::{Header, Method, Response};
    let method = req.method().clone();
    if method != Method::Get && method != Method::Head {
        let _ = req.respond(Response::from_string("method not allowed").with_status_code(405));
        return;
    }
    let path = req.url().split(['?', '#']).next().unwrap_or("").to_string();
    let header =
        |k: &str, v: &str| Header::from_bytes(k.as_bytes(), v.as_bytes()).expect("valid header");
    match route(&path, dir, files) {
        Some((ct, body)) => {
            let resp = Response::from_data(body)
                .with_header(header("Content-Type", ct))
                .with_header(header("Cache-Control", "no-cache"))
                .with_header(header("X-Content-Type-Options", "nosniff"))
                .with_header(header("Connection", "close"));
            let _ = req.respond(resp);
        }
        None => {
            let _ = req.respond(Response::from_string("404 not found").with_status_code(404));
        }
    }
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
        deepview_image::write_atomic(&dst, &bytes)?;
        written.push(dst);
    }
    let index = out.join("index.html");
    deepview_image::write_atomic(&index, INDEX_HTML.as_bytes())?;
    written.push(index);
    Ok(written)
}
