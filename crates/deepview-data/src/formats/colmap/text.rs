//! COLMAP's text model files: `cameras.txt`, `images.txt`, `points3D.txt` (parsers and the writer).

use super::model::{ColmapCamera, ColmapImage, ColmapPoint, model_params};
use crate::DataError;
use deepview_geometry::convention::pose_to_colmap;
use deepview_geometry::{Camera, DVec3};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// Numbered non-comment lines (1-based line numbers), keeping empty ones (images.txt needs them).
fn lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.starts_with('#'))
}

fn num<T: std::str::FromStr>(
    tok: &str,
    what: &str,
    path: &Path,
    line: usize,
) -> Result<T, DataError> {
    tok.parse()
        .map_err(|_| DataError::parse(path, Some(line), format!("bad {what} {tok:?}")))
}

fn finite(v: f64, what: &str, path: &Path, line: usize) -> Result<f64, DataError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(DataError::parse(
            path,
            Some(line),
            format!("non-finite {what} {v}"),
        ))
    }
}

/// `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]` per line.
pub fn parse_cameras_txt(
    text: &str,
    path: &Path,
) -> Result<BTreeMap<u32, ColmapCamera>, DataError> {
    let mut out = BTreeMap::new();
    for (ln, line) in lines(text).filter(|(_, l)| !l.is_empty()) {
        let t: Vec<&str> = line.split_whitespace().collect();
        if t.len() < 4 {
            return Err(DataError::parse(
                path,
                Some(ln),
                "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]",
            ));
        }
        let model = t[1].to_string();
        let params = t[4..]
            .iter()
            .map(|s| {
                num::<f64>(s, "camera parameter", path, ln)
                    .and_then(|v| finite(v, "camera parameter", path, ln))
            })
            .collect::<Result<Vec<_>, _>>()?;
        match model_params(&model) {
            Some(n) if n == params.len() => {}
            Some(n) => {
                return Err(DataError::parse(
                    path,
                    Some(ln),
                    format!("model {model} needs {n} parameters, got {}", params.len()),
                ));
            }
            None => {
                return Err(DataError::parse(
                    path,
                    Some(ln),
                    format!("unknown camera model {model:?}"),
                ));
            }
        }
        let cam = ColmapCamera {
            id: num(t[0], "camera id", path, ln)?,
            model,
            width: num(t[2], "width", path, ln)?,
            height: num(t[3], "height", path, ln)?,
            params,
        };
        out.insert(cam.id, cam);
    }
    Ok(out)
}

/// Two lines per image: `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then `X Y POINT3D_ID` triples.
pub fn parse_images_txt(text: &str, path: &Path) -> Result<Vec<ColmapImage>, DataError> {
    let mut out = Vec::new();
    let mut it = lines(text);
    while let Some((ln, line)) = it.next() {
        if line.is_empty() {
            continue;
        }
        let t: Vec<&str> = line.split_whitespace().collect();
        if t.len() < 10 {
            return Err(DataError::parse(
                path,
                Some(ln),
                "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME",
            ));
        }
        let mut v = [0.0; 7];
        for k in 0..7 {
            v[k] = finite(
                num(t[1 + k], "pose value", path, ln)?,
                "pose value",
                path,
                ln,
            )?;
        }
        let mut img = ColmapImage {
            id: num(t[0], "image id", path, ln)?,
            qvec: [v[0], v[1], v[2], v[3]],
            tvec: [v[4], v[5], v[6]],
            camera_id: num(t[8], "camera id", path, ln)?,
            // Names may contain spaces.
            name: t[9..].join(" "),
            point3d_ids: Vec::new(),
        };
        if let Some((ln2, pts)) = it.next() {
            let p: Vec<&str> = pts.split_whitespace().collect();
            if !p.len().is_multiple_of(3) {
                return Err(DataError::parse(
                    path,
                    Some(ln2),
                    "points line must hold X Y POINT3D_ID triples",
                ));
            }
            for tri in p.chunks_exact(3) {
                num::<f64>(tri[0], "point x", path, ln2)?;
                num::<f64>(tri[1], "point y", path, ln2)?;
                let id: i64 = num(tri[2], "point3D id", path, ln2)?;
                if id >= 0 {
                    img.point3d_ids.push(id as u64);
                }
            }
        }
        out.push(img);
    }
    Ok(out)
}

/// `POINT3D_ID X Y Z R G B ERROR TRACK[]` per line.
pub fn parse_points3d_txt(text: &str, path: &Path) -> Result<Vec<ColmapPoint>, DataError> {
    let mut out = Vec::new();
    for (ln, line) in lines(text).filter(|(_, l)| !l.is_empty()) {
        let t: Vec<&str> = line.split_whitespace().collect();
        if t.len() < 8 {
            return Err(DataError::parse(
                path,
                Some(ln),
                "expected POINT3D_ID X Y Z R G B ERROR TRACK[]",
            ));
        }
        let mut xyz = [0.0; 3];
        for k in 0..3 {
            xyz[k] = finite(
                num(t[1 + k], "coordinate", path, ln)?,
                "coordinate",
                path,
                ln,
            )?;
        }
        out.push(ColmapPoint {
            id: num(t[0], "point id", path, ln)?,
            xyz,
        });
    }
    Ok(out)
}

/// Write a COLMAP text model into `dir`: one PINHOLE camera per view, `images.txt` with the observations of
/// `points` that project inside each image, and `points3D.txt` with their tracks.
pub fn write_colmap_text(
    dir: &Path,
    names: &[String],
    cameras: &[Camera],
    points: &[DVec3],
) -> Result<(), DataError> {
    write_colmap_text_observed(dir, names, cameras, points, |_, _| true)
}

/// [`write_colmap_text`] where view `v` observes point `p` only when `observes(v, p)` (and the point
/// projects into its frame): a synthetic scene chooses which observations its depth bounds come from.
pub fn write_colmap_text_observed(
    dir: &Path,
    names: &[String],
    cameras: &[Camera],
    points: &[DVec3],
    observes: impl Fn(usize, usize) -> bool,
) -> Result<(), DataError> {
    if names.len() != cameras.len() {
        return Err(DataError::CountMismatch {
            path: dir.join("images.txt"),
            msg: format!("{} names for {} cameras", names.len(), cameras.len()),
        });
    }
    let mut cams = String::from(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n",
    );
    let mut imgs = String::from(
        "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n",
    );
    let mut tracks: Vec<Vec<(usize, usize)>> = vec![Vec::new(); points.len()];
    for (i, (name, c)) in names.iter().zip(cameras).enumerate() {
        let k = &c.intrinsics;
        let _ = writeln!(
            cams,
            "{} PINHOLE {} {} {:?} {:?} {:?} {:?}",
            i + 1,
            c.width,
            c.height,
            k.fx,
            k.fy,
            k.cx,
            k.cy
        );
        let (q, t) = pose_to_colmap(&c.pose);
        let _ = writeln!(
            imgs,
            "{} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {} {name}",
            i + 1,
            q[0],
            q[1],
            q[2],
            q[3],
            t[0],
            t[1],
            t[2],
            i + 1
        );
        let mut obs = Vec::new();
        for (pid, x) in points.iter().enumerate() {
            if observes(i, pid)
                && let Some(p) = c.project(*x)
                && p.x >= 0.0
                && p.y >= 0.0
                && p.x < c.width as f64
                && p.y < c.height as f64
            {
                tracks[pid].push((i + 1, obs.len()));
                obs.push(format!("{:?} {:?} {}", p.x, p.y, pid + 1));
            }
        }
        let _ = writeln!(imgs, "{}", obs.join(" "));
    }
    let mut pts = String::from(
        "# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n",
    );
    for (pid, (x, tr)) in points.iter().zip(&tracks).enumerate() {
        let tr: Vec<String> = tr.iter().map(|(i, k)| format!("{i} {k}")).collect();
        let _ = writeln!(
            pts,
            "{} {:?} {:?} {:?} 128 128 128 0 {}",
            pid + 1,
            x.x,
            x.y,
            x.z,
            tr.join(" ")
        );
    }
    crate::write_bytes(&dir.join("cameras.txt"), cams.as_bytes())?;
    crate::write_bytes(&dir.join("images.txt"), imgs.as_bytes())?;
    crate::write_bytes(&dir.join("points3D.txt"), pts.as_bytes())
}
