//! COLMAP sparse models, text (`cameras.txt`, `images.txt`, `points3D.txt`) and binary (`.bin`), in the
//! scene folder or `sparse/0/`; images in `images/`.
//!
//! Poses: `qvec = [w, x, y, z]`, `tvec`, `x_cam = R(q) X + t` (converted by `colmap_to_pose`). COLMAP puts
//! the centre of the top-left pixel at (0.5, 0.5), as this project does, so principal points are used as
//! given. Distortion is not modelled: distorted camera models are refused unless their coefficients are 0.

use crate::{DataError, LoadOptions, Scene, SceneFormat, View};
use deepview_geometry::convention::{colmap_to_pose, pose_to_colmap};
use deepview_geometry::{Camera, DVec3, Intrinsics, Pose};
use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    pub model: String,
    pub width: u64,
    pub height: u64,
    pub params: Vec<f64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    pub qvec: [f64; 4],
    pub tvec: [f64; 3],
    pub camera_id: u32,
    pub name: String,
    /// The 3D point ids this image observes (`-1` entries dropped).
    pub point3d_ids: Vec<u64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    pub id: u64,
    pub xyz: [f64; 3],
}

/// A COLMAP sparse model as stored.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    pub cameras: BTreeMap<u32, ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: Vec<ColmapPoint>,
}

/// (id, name, number of parameters) of COLMAP's camera models.
const MODELS: [(i32, &str, usize); 11] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
];

fn model_params(name: &str) -> Option<usize> {
    MODELS.iter().find(|m| m.1 == name).map(|m| m.2)
}

/// The folder holding the model: `root` or `root/sparse/0`.
pub fn model_dir(root: &Path) -> Option<PathBuf> {
    let has = |d: &Path| d.join("cameras.txt").is_file() || d.join("cameras.bin").is_file();
    if has(root) {
        Some(root.into())
    } else {
        let d = root.join("sparse").join("0");
        has(&d).then_some(d)
    }
}

impl ColmapCamera {
    /// Pinhole intrinsics, or an error for models with non-zero distortion.
    pub fn intrinsics(&self, path: &Path) -> Result<Intrinsics, DataError> {
        let p = &self.params;
        let want = model_params(&self.model);
        if want != Some(p.len()) {
            return Err(DataError::invalid(
                path,
                format!(
                    "camera {}: model {} with {} parameters is not supported",
                    self.id,
                    self.model,
                    p.len()
                ),
            ));
        }
        let (k, distortion): (Intrinsics, &[f64]) = match self.model.as_str() {
            "SIMPLE_PINHOLE" => (Intrinsics::new(p[0], p[0], p[1], p[2]), &[]),
            "PINHOLE" => (Intrinsics::new(p[0], p[1], p[2], p[3]), &[]),
            "SIMPLE_RADIAL" | "RADIAL" => (Intrinsics::new(p[0], p[0], p[1], p[2]), &p[3..]),
            "OPENCV" => (Intrinsics::new(p[0], p[1], p[2], p[3]), &p[4..]),
            m => {
                return Err(DataError::invalid(
                    path,
                    format!(
                        "camera {}: camera model {m} is not supported (pinhole only); undistort the images with \
                         `colmap image_undistorter` and load the undistorted model",
                        self.id
                    ),
                ));
            }
        };
        if distortion.iter().any(|&d| d != 0.0) {
            return Err(DataError::invalid(
                path,
                format!(
                    "camera {}: camera model {} has non-zero distortion {distortion:?}; undistort the images with \
                     `colmap image_undistorter` and load the undistorted (PINHOLE) model",
                    self.id, self.model
                ),
            ));
        }
        k.validate()
            .map_err(|e| DataError::geometry(path, format!("camera {}", self.id), e))?;
        Ok(k)
    }
}

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

/// Read the model in `dir` (binary when `cameras.bin` and `images.bin` exist, else text). A missing
/// points3D file means no points.
pub fn read_colmap(dir: &Path) -> Result<ColmapModel, DataError> {
    let bin = dir.join("cameras.bin").is_file() && dir.join("images.bin").is_file();
    let model = if bin {
        let p = dir.join("points3D.bin");
        ColmapModel {
            cameras: parse_cameras_bin(
                &crate::read_file(&dir.join("cameras.bin"))?,
                &dir.join("cameras.bin"),
            )?,
            images: parse_images_bin(
                &crate::read_file(&dir.join("images.bin"))?,
                &dir.join("images.bin"),
            )?,
            points: if p.is_file() {
                parse_points3d_bin(&crate::read_file(&p)?, &p)?
            } else {
                Vec::new()
            },
        }
    } else {
        let (c, i, p) = (
            dir.join("cameras.txt"),
            dir.join("images.txt"),
            dir.join("points3D.txt"),
        );
        ColmapModel {
            cameras: parse_cameras_txt(&crate::read_text(&c)?, &c)?,
            images: parse_images_txt(&crate::read_text(&i)?, &i)?,
            points: if p.is_file() {
                parse_points3d_txt(&crate::read_text(&p)?, &p)?
            } else {
                Vec::new()
            },
        }
    };
    Ok(model)
}

/// 1st / 99th percentile of the depths of points seen by the views (all points when the model has no
/// observations), times 0.9 / 1.1. `None` without points in front of any view.
pub fn depth_bounds(model: &ColmapModel, poses: &[Pose]) -> Option<(f64, f64)> {
    let by_id: HashMap<u64, DVec3> = model
        .points
        .iter()
        .map(|p| (p.id, DVec3::from_array(p.xyz)))
        .collect();
    let any_obs = model.images.iter().any(|i| !i.point3d_ids.is_empty());
    let mut depths = Vec::new();
    for (img, pose) in model.images.iter().zip(poses) {
        let mut push = |x: &DVec3| {
            let z = pose.transform_point(*x).z;
            if z > 0.0 {
                depths.push(z);
            }
        };
        if any_obs {
            img.point3d_ids
                .iter()
                .filter_map(|id| by_id.get(id))
                .for_each(&mut push);
        } else {
            by_id.values().for_each(&mut push);
        }
    }
    if depths.is_empty() {
        return None;
    }
    depths.sort_by(f64::total_cmp);
    let pct = |q: f64| depths[((depths.len() - 1) as f64 * q).round() as usize];
    Some((pct(0.01) * 0.9, pct(0.99) * 1.1))
}

pub(crate) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let dir = model_dir(root).ok_or_else(|| {
        DataError::invalid(
            root,
            "no COLMAP model (looked for cameras.txt / cameras.bin here and in sparse/0/)",
        )
    })?;
    let mut model = read_colmap(&dir)?;
    model.images.sort_by(|a, b| a.name.cmp(&b.name));
    let images_dir = match &opts.images {
        Some(name) => root.join(name),
        None if root.join("images").is_dir() => root.join("images"),
        None if dir == root && root.join("../../images").is_dir() => root.join("../../images"),
        None => root.join("images"),
    };
    let images_file = dir.join(if dir.join("images.bin").is_file() {
        "images.bin"
    } else {
        "images.txt"
    });
    let cameras_file = dir.join(if dir.join("cameras.bin").is_file() {
        "cameras.bin"
    } else {
        "cameras.txt"
    });
    let mut views = Vec::with_capacity(model.images.len());
    let mut poses = Vec::with_capacity(model.images.len());
    for img in &model.images {
        let c = model.cameras.get(&img.camera_id).ok_or_else(|| {
            DataError::invalid(
                &images_file,
                format!(
                    "image {} ({}) uses camera {} which cameras file lacks",
                    img.id, img.name, img.camera_id
                ),
            )
        })?;
        let k = c.intrinsics(&cameras_file)?;
        let (w, h) = (u32::try_from(c.width), u32::try_from(c.height));
        let (Ok(w), Ok(h)) = (w, h) else {
            return Err(DataError::invalid(
                &cameras_file,
                format!("camera {}: size {}x{} too large", c.id, c.width, c.height),
            ));
        };
        let pose = colmap_to_pose(img.qvec, img.tvec).map_err(|e| {
            DataError::geometry(&images_file, format!("image {} ({})", img.id, img.name), e)
        })?;
        poses.push(pose);
        views.push(View {
            name: img.name.clone(),
            image_path: images_dir.join(&img.name),
            camera: Camera::new(w, h, k, pose),
        });
    }
    Ok(Scene {
        root: root.into(),
        format: SceneFormat::Colmap,
        views,
        depth_bounds: depth_bounds(&model, &poses),
        grid: None,
        rig_count: 1,
        downscale: 1,
    })
}

/// Write a COLMAP text model into `dir`: one PINHOLE camera per view, `images.txt` with the observations of
/// `points` that project inside each image, and `points3D.txt` with their tracks.
pub fn write_colmap_text(
    dir: &Path,
    names: &[String],
    cameras: &[Camera],
    points: &[DVec3],
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
            if let Some(p) = c.project(*x)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load_scene;
    use deepview_geometry::DMat3;

    const CAMERAS: &str = "# comment\n1 PINHOLE 64 48 50 51 32 24\n2 SIMPLE_PINHOLE 64 48 50 32.5 24\n3 SIMPLE_RADIAL 64 48 50 32 24 0\n";
    const IMAGES: &str = "# c\n1 1 0 0 0 0 0 2 1 b.png\n10 20 1\n2 0.7071067811865476 0 0.7071067811865476 0 1 0 0 2 a.png\n\n";
    const POINTS: &str = "1 0 0 1 255 0 0 0.5 1 0\n2 0 0 10 1 2 3 0.1\n";

    fn p(name: &str) -> PathBuf {
        PathBuf::from("model").join(name)
    }

    #[test]
    fn text_parsers_in_memory() {
        let cams = parse_cameras_txt(CAMERAS, &p("cameras.txt")).unwrap();
        assert_eq!(cams.len(), 3);
        assert_eq!(
            cams[&2].intrinsics(&p("c")).unwrap(),
            Intrinsics::new(50.0, 50.0, 32.5, 24.0)
        );
        assert_eq!(
            cams[&3].intrinsics(&p("c")).unwrap(),
            Intrinsics::new(50.0, 50.0, 32.0, 24.0)
        );
        let imgs = parse_images_txt(IMAGES, &p("images.txt")).unwrap();
        assert_eq!(imgs.len(), 2);
        assert_eq!(imgs[0].point3d_ids, vec![1]);
        assert_eq!(imgs[1].name, "a.png");
        assert!(imgs[1].point3d_ids.is_empty());
        // Image 2: 90 degrees about y, x_cam = R X + t.
        let pose = colmap_to_pose(imgs[1].qvec, imgs[1].tvec).unwrap();
        assert!(
            pose.rotation
                .abs_diff_eq(DMat3::from_rotation_y(std::f64::consts::FRAC_PI_2), 1e-12)
        );
        let pts = parse_points3d_txt(POINTS, &p("points3D.txt")).unwrap();
        assert_eq!(pts[1].xyz, [0.0, 0.0, 10.0]);
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let cases = [
            (
                parse_cameras_txt("# c\n1 PINHOLE 64 48 50 51 32\n", &p("cameras.txt")).err(),
                "cameras.txt:2",
                "needs 4",
            ),
            (
                parse_cameras_txt("1 PINHOLE 64 x 50 51 32 1\n", &p("cameras.txt")).err(),
                "cameras.txt:1",
                "height",
            ),
            (
                parse_cameras_txt("1 WEIRD 64 48 1\n", &p("cameras.txt")).err(),
                "cameras.txt:1",
                "WEIRD",
            ),
            (
                parse_images_txt("1 1 0 0 0 0 0 nan 1 a.png\n\n", &p("images.txt")).err(),
                "images.txt:1",
                "non-finite",
            ),
            (
                parse_images_txt("1 1 0 0 0 0 0 1 a.png\n\n", &p("images.txt")).err(),
                "images.txt:1",
                "expected",
            ),
            (
                parse_images_txt("1 1 0 0 0 0 0 0 1 a.png\n1 2\n", &p("images.txt")).err(),
                "images.txt:2",
                "triples",
            ),
            (
                parse_points3d_txt("1 0 0\n", &p("points3D.txt")).err(),
                "points3D.txt:1",
                "expected",
            ),
        ];
        for (e, loc, want) in cases {
            let e = e.expect("must fail").to_string();
            assert!(e.contains(loc) && e.contains(want), "{loc} {want}: {e}");
        }
    }

    #[test]
    fn distorted_models_are_refused() {
        let cams = parse_cameras_txt(
            "4 OPENCV 64 48 50 51 32 24 0.1 0 0 0\n5 OPENCV_FISHEYE 64 48 50 51 32 24 0 0 0 0\n",
            &p("cameras.txt"),
        )
        .unwrap();
        let e = cams[&4]
            .intrinsics(&p("cameras.txt"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("OPENCV")
                && e.contains("colmap image_undistorter")
                && e.contains("cameras.txt"),
            "{e}"
        );
        let e = cams[&5]
            .intrinsics(&p("cameras.txt"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("OPENCV_FISHEYE") && e.contains("colmap image_undistorter"),
            "{e}"
        );
    }

    fn scene_cameras() -> (Vec<String>, Vec<Camera>, Vec<DVec3>) {
        let cams: Vec<Camera> = (0..3)
            .map(|i| {
                let r = DMat3::from_rotation_y(0.05 * i as f64 - 0.05)
                    * DMat3::from_rotation_x(0.01 * i as f64);
                Camera::new(
                    40,
                    30,
                    Intrinsics::new(35.0, 36.0, 20.5, 14.75),
                    Pose::from_center(r, DVec3::new(0.2 * i as f64, 0.0, 0.0)),
                )
            })
            .collect();
        // Points at depths 2..8 in front of the rig.
        let pts = (0..200)
            .map(|i| {
                DVec3::new(
                    (i % 7) as f64 * 0.2 - 0.6,
                    (i % 5) as f64 * 0.2 - 0.4,
                    2.0 + (i as f64) * 0.03,
                )
            })
            .collect();
        ((0..3).map(|i| format!("img{i}.png")).collect(), cams, pts)
    }

    #[test]
    fn text_writer_round_trip_and_bounds() {
        let dir = tempfile::tempdir().unwrap();
        let (names, cams, pts) = scene_cameras();
        write_colmap_text(&dir.path().join("sparse/0"), &names, &cams, &pts).unwrap();
        let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
        assert_eq!((s.format, s.len()), (SceneFormat::Colmap, 3));
        for (v, c) in s.views.iter().zip(&cams) {
            assert_eq!(v.camera.intrinsics, c.intrinsics);
            assert!(v.camera.pose.rotation.abs_diff_eq(c.pose.rotation, 1e-12));
            assert!(
                v.camera
                    .pose
                    .translation
                    .abs_diff_eq(c.pose.translation, 1e-12)
            );
            assert_eq!(v.image_path, dir.path().join("images").join(&v.name));
        }
        let (near, far) = s.near_far().unwrap();
        // Depths run from about 2 to 8; the 1st/99th percentiles with 0.9 / 1.1 margins.
        assert!(near > 1.7 && near < 2.1, "{near}");
        assert!(far > 8.0 && far < 9.2, "{far}");
        // Without points: no bounds, and a clear error.
        write_colmap_text(&dir.path().join("sparse/0"), &names, &cams, &[]).unwrap();
        let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
        let e = s.near_far().unwrap_err().to_string();
        assert!(e.contains("near and far") && e.contains("3D points"), "{e}");
    }

    // A tiny binary model writer for fixtures.
    fn write_bin(dir: &Path, names: &[String], cams: &[Camera], pts: &[DVec3]) {
        let mut c = (cams.len() as u64).to_le_bytes().to_vec();
        let mut im = (cams.len() as u64).to_le_bytes().to_vec();
        for (i, (cam, name)) in cams.iter().zip(names).enumerate() {
            c.extend((i as i32 + 1).to_le_bytes());
            c.extend(1i32.to_le_bytes());
            c.extend((cam.width as u64).to_le_bytes());
            c.extend((cam.height as u64).to_le_bytes());
            let k = cam.intrinsics;
            for v in [k.fx, k.fy, k.cx, k.cy] {
                c.extend(v.to_le_bytes());
            }
            let (q, t) = pose_to_colmap(&cam.pose);
            im.extend((i as i32 + 1).to_le_bytes());
            for v in q.iter().chain(&t) {
                im.extend(v.to_le_bytes());
            }
            im.extend((i as i32 + 1).to_le_bytes());
            im.extend(name.as_bytes());
            im.push(0);
            im.extend((pts.len() as u64 + 1).to_le_bytes());
            for pid in 0..=pts.len() {
                im.extend(1.5f64.to_le_bytes());
                im.extend(2.5f64.to_le_bytes());
                // One unmatched observation (-1) besides the real ones.
                im.extend((if pid == pts.len() { -1 } else { pid as i64 + 1 }).to_le_bytes());
            }
        }
        let mut p = (pts.len() as u64).to_le_bytes().to_vec();
        for (pid, x) in pts.iter().enumerate() {
            p.extend((pid as u64 + 1).to_le_bytes());
            for v in x.to_array() {
                p.extend(v.to_le_bytes());
            }
            p.extend([1u8, 2, 3]);
            p.extend(0.5f64.to_le_bytes());
            p.extend(2u64.to_le_bytes());
            p.extend([1i32, 0, 2, 0].iter().flat_map(|v| v.to_le_bytes()));
        }
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join("cameras.bin"), c).unwrap();
        std::fs::write(dir.join("images.bin"), im).unwrap();
        std::fs::write(dir.join("points3D.bin"), p).unwrap();
    }

    #[test]
    fn binary_model_matches_text_model() {
        let (names, cams, pts) = scene_cameras();
        let tdir = tempfile::tempdir().unwrap();
        write_colmap_text(tdir.path(), &names, &cams, &pts).unwrap();
        let bdir = tempfile::tempdir().unwrap();
        write_bin(bdir.path(), &names, &cams, &pts);
        let t = load_scene(tdir.path(), &LoadOptions::default()).unwrap();
        let b = load_scene(bdir.path(), &LoadOptions::default()).unwrap();
        assert_eq!(b.len(), 3);
        for (vb, vt) in b.views.iter().zip(&t.views) {
            assert_eq!(vb.name, vt.name);
            assert_eq!(vb.camera.intrinsics, vt.camera.intrinsics);
            assert!(
                vb.camera
                    .pose
                    .rotation
                    .abs_diff_eq(vt.camera.pose.rotation, 1e-12)
            );
            assert!(
                vb.camera
                    .pose
                    .translation
                    .abs_diff_eq(vt.camera.pose.translation, 1e-12)
            );
        }
        assert!(b.depth_bounds.is_some());
        // Truncated binary files are refused with the file name.
        let bytes = std::fs::read(bdir.path().join("images.bin")).unwrap();
        std::fs::write(bdir.path().join("images.bin"), &bytes[..bytes.len() - 5]).unwrap();
        let e = load_scene(bdir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("images.bin") && e.contains("truncated"), "{e}");
    }
}
