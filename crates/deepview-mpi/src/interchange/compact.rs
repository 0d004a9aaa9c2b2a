//! Compact MPI export: every plane cut into `tile x tile` tiles (default 32), fully transparent tiles
//! (alpha 0 everywhere) dropped, the kept tiles packed into atlas pages. Read by the web viewer and by
//! `deepview import`; the round trip reproduces our layer files exactly (dropped tiles are `[0, 0, 0, 0]`,
//! which is what our writer stores for alpha 0).
//!
//! `mpi_compact.json`:
//! ```json
//! {"format":"deepview-mpi-compact","version":1,"width":W,"height":H,
//!  "intrinsics":{"fx":..,"fy":..,"cx":..,"cy":..},"camera_from_world":[16 numbers, row-major],
//!  "depths":[far ... near],"tile":32,"tiles_x":TX,"tiles_y":TY,"page_cols":C,"page_rows":R,
//!  "pages":["tiles_000.png", ...],"planes":[[kept tile indices of plane 0, ascending], ...]}
//! ```
//! Tile index `k` covers pixels `[(k % TX) T, +T) x [(k / TX) T, +T)` of its plane (clipped to the plane at
//! the right and bottom edges). Kept tiles get consecutive slots, plane 0 first; slot `s` lives on page
//! `s / (C R)` at tile position `(s % C, (s / C) % R)`. Pages are straight-alpha RGBA8 PNGs `C T` wide;
//! the last one only as tall as its used rows. Parts of edge tiles outside the plane are zero.

use super::straight::{ExportReport, StraightMpi, check_planes, decode_rgba8};
use crate::error::{MpiError, invalid, read_err, write_err};
use deepview_geometry::{Camera, Intrinsics, Pose};
use deepview_image::{write_atomic, write_png_u8};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub const META: &str = "mpi_compact.json";
pub const FORMAT: &str = "deepview-mpi-compact";
pub const DEFAULT_TILE: u32 = 32;
const MAX_PAGE_TILES: usize = 64;

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CompactMeta {
    pub format: String,
    pub version: u32,
    pub width: u32,
    pub height: u32,
    pub intrinsics: Intrinsics,
    pub camera_from_world: Vec<f64>,
    pub depths: Vec<f64>,
    pub tile: u32,
    pub tiles_x: u32,
    pub tiles_y: u32,
    pub page_cols: u32,
    pub page_rows: u32,
    pub pages: Vec<String>,
    pub planes: Vec<Vec<u32>>,
}

impl CompactMeta {
    /// Read and validate `dir/mpi_compact.json` (not the pages).
    pub fn read(dir: &Path) -> Result<(CompactMeta, Camera), MpiError> {
        let path = dir.join(META);
        let text = deepview_image::read_text(&path).map_err(read_err(&path))?;
        let meta: CompactMeta = serde_json::from_str(&text).map_err(|source| MpiError::Json {
            path: path.clone(),
            what: "JSON for mpi_compact.json",
            source,
        })?;
        let bad = |msg: String| invalid(&path, msg);
        if meta.format != FORMAT || meta.version != 1 {
            return Err(bad(format!(
                "format {:?} version {} (expected {FORMAT:?} version 1)",
                meta.format, meta.version
            )));
        }
        let pose = Pose::from_row_major(&meta.camera_from_world).map_err(|e| bad(e.to_string()))?;
        let camera = Camera::new(meta.width, meta.height, meta.intrinsics, pose);
        camera.validate().map_err(|e| bad(e.to_string()))?;
        if meta.depths.is_empty() || meta.depths.len() != meta.planes.len() {
            return Err(bad(format!(
                "{} depths and {} planes",
                meta.depths.len(),
                meta.planes.len()
            )));
        }
        // The rules every MPI's depths keep, as mpi.json's.
        crate::io::check_depths(&path, &meta.depths)?;
        if meta.tile == 0 || meta.page_cols == 0 || meta.page_rows == 0 {
            return Err(bad("tile, page_cols and page_rows must be positive".into()));
        }
        if meta.tiles_x != meta.width.div_ceil(meta.tile)
            || meta.tiles_y != meta.height.div_ceil(meta.tile)
        {
            return Err(bad(
                "tiles_x / tiles_y do not match the size and tile".into()
            ));
        }
        // The tile arithmetic (here and in the writer) is 32-bit: a plane's bytes must fit in a u32. Checked
        // before anything is allocated from these numbers.
        if meta.width as u64 * meta.height as u64 * 4 > u32::MAX as u64 {
            return Err(bad(format!(
                "{}x{} planes of RGBA8 exceed the format's 4 GiB per plane",
                meta.width, meta.height
            )));
        }
        let n_tiles = meta.tiles_x as u64 * meta.tiles_y as u64;
        for (d, p) in meta.planes.iter().enumerate() {
            if p.iter().any(|&k| k as u64 >= n_tiles) || p.windows(2).any(|w| w[1] <= w[0]) {
                return Err(bad(format!(
                    "plane {d}: tile indices must ascend and be below {n_tiles}"
                )));
            }
        }
        let kept: usize = meta.planes.iter().map(Vec::len).sum();
        let per_page = meta.page_cols as usize * meta.page_rows as usize;
        if meta.pages.len() != kept.div_ceil(per_page) {
            return Err(bad(format!(
                "{kept} tiles need {} pages, the file lists {}",
                kept.div_ceil(per_page),
                meta.pages.len()
            )));
        }
        for name in &meta.pages {
            // Served by the viewer beside its page: the names mpi.json's layers may have.
            if !crate::io::layer_name_ok(name) {
                return Err(bad(format!(
                    "page name {name:?} must be a plain file name in the folder: ASCII letters, digits, \
                     '.', '_' and '-', not hidden, not mpi.json or index.html"
                )));
            }
        }
        Ok((meta, camera))
    }
}

fn tile_is_empty(px: &[u8], w: u32, h: u32, t: u32, tx: u32, ty: u32) -> bool {
    let (x0, y0) = (tx * t, ty * t);
    let (x1, y1) = ((x0 + t).min(w), (y0 + t).min(h));
    (y0..y1).all(|y| (x0..x1).all(|x| px[((y * w + x) * 4 + 3) as usize] == 0))
}

/// Write the compact export of `mpi` in the folder `out` with `tile x tile` tiles.
pub fn write_with_tile(out: &Path, mpi: &StraightMpi, tile: u32) -> Result<ExportReport, MpiError> {
    check_planes(out, mpi)?;
    if tile == 0 {
        return Err(MpiError::Config("tile size must be positive".into()));
    }
    let (w, h) = (mpi.camera.width, mpi.camera.height);
    let (tiles_x, tiles_y) = (w.div_ceil(tile), h.div_ceil(tile));
    let planes: Vec<Vec<u32>> = mpi
        .planes
        .iter()
        .map(|px| {
            (0..tiles_x * tiles_y)
                .filter(|k| !tile_is_empty(px, w, h, tile, k % tiles_x, k / tiles_x))
                .collect()
        })
        .collect();
    let kept: usize = planes.iter().map(Vec::len).sum();
    let cols = kept.clamp(1, MAX_PAGE_TILES);
    let rows = kept.div_ceil(cols).clamp(1, MAX_PAGE_TILES);
    let per_page = cols * rows;
    let n_pages = kept.div_ceil(per_page);
    let page_w = cols as u32 * tile;
    let mut pages: Vec<Vec<u8>> = (0..n_pages)
        .map(|p| {
            let used_rows = (kept - p * per_page).min(per_page).div_ceil(cols);
            vec![0u8; page_w as usize * used_rows * tile as usize * 4]
        })
        .collect();
    let mut slot = 0usize;
    for (d, kept_tiles) in planes.iter().enumerate() {
        let px = &mpi.planes[d];
        for &k in kept_tiles {
            let (tx, ty) = (k % tiles_x, k / tiles_x);
            let page = &mut pages[slot / per_page];
            let local = slot % per_page;
            let (px0, py0) = ((local % cols) as u32 * tile, (local / cols) as u32 * tile);
            let (x0, y0) = (tx * tile, ty * tile);
            let cw = (tile.min(w - x0) * 4) as usize;
            for r in 0..tile.min(h - y0) {
                let src = (((y0 + r) * w + x0) * 4) as usize;
                let dst = (((py0 + r) * page_w + px0) * 4) as usize;
                page[dst..dst + cw].copy_from_slice(&px[src..src + cw]);
            }
            slot += 1;
        }
    }
    std::fs::create_dir_all(out).map_err(write_err(out))?;
    let mut report = ExportReport::default();
    let mut names = Vec::new();
    for (p, bytes) in pages.iter().enumerate() {
        let name = format!("tiles_{p:03}.png");
        let path = out.join(&name);
        let page_h = (bytes.len() / (page_w as usize * 4)) as u32;
        write_png_u8(&path, page_w, page_h, 4, bytes)?;
        report.add(path)?;
        names.push(name);
    }
    let meta = CompactMeta {
        format: FORMAT.into(),
        version: 1,
        width: w,
        height: h,
        intrinsics: mpi.camera.intrinsics,
        camera_from_world: mpi.camera.pose.to_row_major().to_vec(),
        depths: mpi.depths.clone(),
        tile,
        tiles_x,
        tiles_y,
        page_cols: cols as u32,
        page_rows: rows as u32,
        pages: names,
        planes,
    };
    let path = out.join(META);
    write_atomic(
        &path,
        serde_json::to_string(&meta)
            .expect("compact meta serialises")
            .as_bytes(),
    )?;
    report.add(path)?;
    report.tiles = Some((kept, (tiles_x * tiles_y) as usize * mpi.planes.len()));
    Ok(report)
}

/// [`write_with_tile`] with 32 x 32 tiles.
pub fn write(out: &Path, mpi: &StraightMpi) -> Result<ExportReport, MpiError> {
    write_with_tile(out, mpi, DEFAULT_TILE)
}

/// Read a compact export back into full straight-alpha planes.
pub fn read(dir: &Path) -> Result<StraightMpi, MpiError> {
    let (meta, camera) = CompactMeta::read(dir)?;
    // 64-bit arithmetic: the header's numbers are checked against each other, not against overflow.
    let (w, h, t) = (meta.width as u64, meta.height as u64, meta.tile as u64);
    let (cols, rows) = (meta.page_cols as u64, meta.page_rows as u64);
    let per_page = cols * rows;
    let page_w = cols * t;
    let mut pages = Vec::with_capacity(meta.pages.len());
    for name in &meta.pages {
        let path = dir.join(name);
        let (pw, ph, px) = decode_rgba8(&path)?;
        let ph = ph as u64;
        if pw as u64 != page_w || !ph.is_multiple_of(t) || ph > rows * t {
            return Err(invalid(
                &path,
                format!("page is {pw}x{ph}, expected {page_w} wide and a multiple of {t} tall"),
            ));
        }
        pages.push((ph, px));
    }
    // One allocation per plane (zeroed lazily), not a clone of the first: only the kept tiles are touched.
    let plane_len = (w * h * 4) as usize;
    let mut planes: Vec<Vec<u8>> = (0..meta.depths.len())
        .map(|_| vec![0u8; plane_len])
        .collect();
    let mut slot = 0u64;
    let index = |v: u64| v as usize;
    for (d, kept) in meta.planes.iter().enumerate() {
        for &k in kept {
            let (tx, ty) = (
                k as u64 % meta.tiles_x as u64,
                k as u64 / meta.tiles_x as u64,
            );
            let (ph, page) = &pages[index(slot / per_page)];
            let local = slot % per_page;
            let (px0, py0) = ((local % cols) * t, (local / cols) * t);
            if py0 + t > *ph {
                return Err(invalid(
                    dir.join(&meta.pages[index(slot / per_page)]),
                    format!("too short for tile slot {local}"),
                ));
            }
            let (x0, y0) = (tx * t, ty * t);
            let cw = index(t.min(w - x0) * 4);
            for r in 0..t.min(h - y0) {
                let dst = index(((y0 + r) * w + x0) * 4);
                let src = index(((py0 + r) * page_w + px0) * 4);
                planes[d][dst..dst + cw].copy_from_slice(&page[src..src + cw]);
            }
            slot += 1;
        }
    }
    Ok(StraightMpi {
        camera,
        depths: meta.depths,
        planes,
    })
}
