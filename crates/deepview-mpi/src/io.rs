//! The MPI folder format: `mpi.json` plus `layer_000.png ...` (RGBA8, straight alpha, far plane first).
//!
//! ```json
//! {"format":"deepview-mpi","version":1,"width":W,"height":H,
//!  "intrinsics":{"fx":..,"fy":..,"cx":..,"cy":..},
//!  "camera_from_world":[16 numbers, row-major],"depths":[far ... near],
//!  "layers":["layer_000.png", ...]}
//! ```

use crate::error::{MpiError, invalid, read_err, write_err};
use crate::mpi::{Mpi, Texel};
use deepview_geometry::{Camera, Intrinsics, Pose};
use deepview_image::{write_atomic, write_png_u8};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::path::Path;

pub const FORMAT: &str = "deepview-mpi";
pub const VERSION: u32 = 1;

/// Serde mirror of `mpi.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MpiMeta {
    pub format: String,
    pub version: u32,
    pub width: u32,
    pub height: u32,
    pub intrinsics: Intrinsics,
    pub camera_from_world: Vec<f64>,
    pub depths: Vec<f64>,
    pub layers: Vec<String>,
    /// How the plane count was chosen (optional: files without it load as before).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub planes_rule: Option<PlanesRule>,
}

/// How an MPI's plane count was chosen, as stored in `mpi.json`:
/// `"planes_rule": {"rule": "auto", "max_disparity_px": 52.3, "max_spacing_px": 1.0, "view": 7}`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct PlanesRule {
    /// `auto` (from the cameras' disparity), `explicit` (`--planes N`) or `weights` (the weights' count).
    pub rule: String,
    /// `auto`: the largest disparity between the near and far planes, reference to farthest input view.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_disparity_px: Option<f64>,
    /// `auto`: the largest disparity allowed between neighbouring planes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_spacing_px: Option<f64>,
    /// `auto`: the dataset's index of that farthest view.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<usize>,
    /// Why the count differs from the rule's (e.g. `"memory budget"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limited_by: Option<String>,
}

impl MpiMeta {
    pub fn new(camera: &Camera, depths: &[f64]) -> Self {
        Self {
            format: FORMAT.into(),
            version: VERSION,
            width: camera.width,
            height: camera.height,
            intrinsics: camera.intrinsics,
            camera_from_world: camera.pose.to_row_major().to_vec(),
            depths: depths.to_vec(),
            layers: (0..depths.len()).map(layer_name).collect(),
            planes_rule: None,
        }
    }

    /// Read and validate `dir/mpi.json` (not the layers).
    pub fn read(dir: &Path) -> Result<(MpiMeta, Camera), MpiError> {
        let path = dir.join("mpi.json");
        // (A byte order mark, which Windows editors write, is not JSON's: read_text drops it.)
        let text = deepview_image::read_text(&path).map_err(read_err(&path))?;
        let meta: MpiMeta = serde_json::from_str(&text).map_err(|source| MpiError::Json {
            path: path.clone(),
            what: "mpi.json",
            source,
        })?;
        let camera = meta.validate(&path)?;
        Ok((meta, camera))
    }

    fn validate(&self, path: &Path) -> Result<Camera, MpiError> {
        if self.format != FORMAT {
            return Err(invalid(
                path,
                format!("\"format\" is {:?}, expected {FORMAT:?}", self.format),
            ));
        }
        if self.version != VERSION {
            return Err(invalid(
                path,
                format!(
                    "unsupported version {} (this build reads {VERSION})",
                    self.version
                ),
            ));
        }
        check_depths(path, &self.depths)?;
        if self.layers.len() != self.depths.len() {
            return Err(invalid(
                path,
                format!(
                    "{} layers but {} depths",
                    self.layers.len(),
                    self.depths.len()
                ),
            ));
        }
        let pose = Pose::from_row_major(&self.camera_from_world)
            .map_err(|e| invalid(path, e.to_string()))?;
        let cam = Camera::new(self.width, self.height, self.intrinsics, pose);
        cam.validate().map_err(|e| invalid(path, e.to_string()))?;
        for (i, l) in self.layers.iter().enumerate() {
            if self.layers[..i].contains(l) {
                return Err(invalid(
                    path,
                    format!("layer name {l:?} is listed twice: every plane has its own file"),
                ));
            }
            if !layer_name_ok(l) {
                return Err(invalid(
                    path,
                    format!(
                        "layer name {l:?} must be a plain file name in the folder: ASCII letters, digits, \
                         '.', '_' and '-', not hidden, not mpi.json or index.html"
                    ),
                ));
            }
        }
        Ok(cam)
    }
}

/// The plane depths of a valid MPI, whatever file they come from ([`deepview_geometry::check_plane_depths`]).
/// Errors name `path`.
pub(crate) fn check_depths(path: &Path, depths: &[f64]) -> Result<(), MpiError> {
    deepview_geometry::check_plane_depths(depths).map_err(|e| invalid(path, e))
}

/// A layer file name an MPI folder may list: plain ASCII (letters, digits, `.`, `_`, `-`), not hidden,
/// and none of the folder's other files: names a browser can fetch as they are (the viewer serves them)
/// and no other tool's file.
pub(crate) fn layer_name_ok(l: &str) -> bool {
    !l.is_empty()
        && l.len() <= 200
        && !l.starts_with(['.', '-'])
        && l.bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'))
        && !["mpi.json", "index.html", "mpi_compact.json"]
            .iter()
            .any(|n| l.eq_ignore_ascii_case(n))
}

pub fn layer_name(i: usize) -> String {
    format!("layer_{i:03}.png")
}

/// The one reader of the folder format: `mpi.json` validated, then every layer decoded (in parallel), its
/// size checked against `mpi.json` and turned into a plane by `convert`, which writes it into its slot
/// of `out` (`[planes][H][W][4]`, `slot` texels per plane). The first bad layer (in plane order) is the
/// error.
pub(crate) fn read_layers_into<T: Send>(
    dir: &Path,
    slot: impl Fn(&Camera) -> usize,
    out: &mut Vec<T>,
    fill: impl Fn(usize) -> Vec<T>,
    convert: impl Fn(image::DynamicImage, &mut [T]) + Sync,
) -> Result<(MpiMeta, Camera), MpiError> {
    let (meta, camera) = MpiMeta::read(dir)?;
    let (w, h) = (camera.width, camera.height);
    let len = slot(&camera);
    *out = fill(len * meta.layers.len());
    let results: Vec<Result<(), MpiError>> = out
        .par_chunks_mut(len.max(1))
        .zip(meta.layers.par_iter())
        .map(|(plane, name)| {
            let path = dir.join(name);
            // The header first: a layer announcing another size is refused before it is decoded.
            let (lw, lh) = deepview_image::image_size(&path)?;
            if (lw, lh) != (w, h) {
                return Err(invalid(
                    &path,
                    format!("layer is {lw}x{lh} but mpi.json says {w}x{h}"),
                ));
            }
            let img = deepview_image::decode_file(&path)?;
            if (img.width(), img.height()) != (w, h) {
                return Err(invalid(
                    &path,
                    format!(
                        "layer is {}x{} but mpi.json says {w}x{h}",
                        img.width(),
                        img.height()
                    ),
                ));
            }
            convert(img, plane);
            Ok(())
        })
        .collect();
    results.into_iter().collect::<Result<(), _>>()?;
    Ok((meta, camera))
}

/// [`read_layers_into`] giving each plane as its own value `P` (the compact and interchange readers).
pub(crate) fn read_layers<P: Send>(
    dir: &Path,
    convert: impl Fn(image::DynamicImage) -> P + Sync,
) -> Result<(MpiMeta, Camera, Vec<P>), MpiError> {
    let mut slots: Vec<Option<P>> = Vec::new();
    let (meta, camera) = read_layers_into(
        dir,
        |_| 1,
        &mut slots,
        |n| (0..n).map(|_| None).collect(),
        |img, slot| slot[0] = Some(convert(img)),
    )?;
    let planes = slots
        .into_iter()
        .map(|p| p.expect("every layer read"))
        .collect();
    Ok((meta, camera, planes))
}

/// Read an MPI folder as premultiplied texels `T`: `read_mpi::<f32>` converts the straight alpha on disk
/// exactly, `read_mpi::<u8>` rounds to 8 bits (for rendering). Each layer is decoded straight into its
/// place in the MPI: the peak memory is the MPI and a layer per thread.
pub fn read_mpi<T: Texel>(dir: &Path) -> Result<Mpi<T>, MpiError> {
    let mut layers = Vec::new();
    let (meta, camera) = read_layers_into(
        dir,
        |c| c.width as usize * c.height as usize * 4,
        &mut layers,
        |n| vec![T::default(); n],
        |img, plane| plane.copy_from_slice(&T::premultiplied(img)),
    )?;
    Ok(Mpi {
        camera,
        depths: meta.depths,
        layers,
    })
}

/// Straight-alpha RGBA8 bytes of one premultiplied f32 plane.
pub fn plane_to_straight_rgba8(plane: &[f32]) -> Vec<u8> {
    plane
        .chunks_exact(4)
        .flat_map(|p| {
            let a = p[3].clamp(0.0, 1.0);
            let a8 = (a * 255.0 + 0.5) as u8;
            if a8 == 0 {
                return [0, 0, 0, 0];
            }
            let s = |v: f32| deepview_image::to_u8(v / a);
            [s(p[0]), s(p[1]), s(p[2]), a8]
        })
        .collect()
}

/// Write an MPI folder (creating it). Every file is written atomically; `mpi.json` last, so a folder with
/// a readable `mpi.json` always has all its layers.
pub fn write_mpi(dir: &Path, mpi: &Mpi) -> Result<(), MpiError> {
    write_mpi_with(dir, mpi, None)
}

/// [`write_mpi`], recording how the plane count was chosen in `mpi.json`.
pub fn write_mpi_with(
    dir: &Path,
    mpi: &Mpi,
    planes_rule: Option<&PlanesRule>,
) -> Result<(), MpiError> {
    if mpi.depths.is_empty() {
        return Err(invalid(dir, "refusing to write an MPI with zero planes"));
    }
    let meta = MpiMeta {
        planes_rule: planes_rule.cloned(),
        ..MpiMeta::new(&mpi.camera, &mpi.depths)
    };
    write_layers(dir, &meta, |d| {
        Cow::Owned(plane_to_straight_rgba8(mpi.plane(d)))
    })
}

/// The one writer of the folder format: `dir` created, the layers (straight-alpha RGBA8 bytes of plane
/// `d` from `straight`) written in parallel, then `mpi.json`; every file atomically.
pub(crate) fn write_layers<'a>(
    dir: &Path,
    meta: &MpiMeta,
    straight: impl Fn(usize) -> Cow<'a, [u8]> + Sync,
) -> Result<(), MpiError> {
    std::fs::create_dir_all(dir).map_err(write_err(dir))?;
    meta.layers
        .par_iter()
        .enumerate()
        .try_for_each(|(d, name)| {
            write_png_u8(&dir.join(name), meta.width, meta.height, 4, &straight(d))
        })?;
    let json = serde_json::to_string_pretty(meta).expect("mpi.json serialises");
    write_atomic(&dir.join("mpi.json"), json.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small_mpi() -> Mpi {
        let cam = Camera::new(5, 4, Intrinsics::new(5.0, 5.0, 2.5, 2.0), Pose::IDENTITY);
        let mut mpi = Mpi::transparent(cam, vec![4.0, 2.0, 1.0]);
        for (i, p) in mpi.layers.chunks_exact_mut(4).enumerate() {
            let a = ((i * 53) % 256) as f32 / 255.0;
            p[3] = a;
            for k in 0..3 {
                p[k] = (((i * 31 + k * 17) % 256) as f32 / 255.0) * a;
            }
        }
        mpi
    }

    #[test]
    fn planes_rule_is_optional_and_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let mpi = small_mpi();
        write_mpi(dir.path(), &mpi).unwrap();
        let (meta, _) = MpiMeta::read(dir.path()).unwrap();
        assert_eq!(meta.planes_rule, None);
        let text = std::fs::read_to_string(dir.path().join("mpi.json")).unwrap();
        assert!(!text.contains("planes_rule"), "{text}");
        let rule = PlanesRule {
            rule: "auto".into(),
            max_disparity_px: Some(52.3),
            max_spacing_px: Some(1.0),
            view: Some(7),
            limited_by: None,
        };
        write_mpi_with(dir.path(), &mpi, Some(&rule)).unwrap();
        let (meta, _) = MpiMeta::read(dir.path()).unwrap();
        assert_eq!(meta.planes_rule, Some(rule));
        assert_eq!(read_mpi::<f32>(dir.path()).unwrap().depths, mpi.depths);
    }

    #[test]
    fn write_read_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let mpi = small_mpi();
        write_mpi(dir.path(), &mpi).unwrap();
        let back = read_mpi::<f32>(dir.path()).unwrap();
        assert_eq!(back.camera, mpi.camera);
        assert_eq!(back.depths, mpi.depths);
        for (a, b) in back.layers.iter().zip(&mpi.layers) {
            assert!((a - b).abs() <= 1.0 / 255.0 + 1e-6, "{a} vs {b}");
        }
        // Writing what we read reproduces the files byte for byte (8-bit straight alpha is a fixed point).
        let dir2 = tempfile::tempdir().unwrap();
        write_mpi(dir2.path(), &back).unwrap();
        for name in [
            "layer_000.png",
            "layer_001.png",
            "layer_002.png",
            "mpi.json",
        ] {
            let a = std::fs::read(dir.path().join(name)).unwrap();
            let b = std::fs::read(dir2.path().join(name)).unwrap();
            if name.ends_with(".png") {
                let ia = image::load_from_memory(&a).unwrap().into_rgba8();
                let ib = image::load_from_memory(&b).unwrap().into_rgba8();
                assert_eq!(ia, ib, "{name}");
            } else {
                assert_eq!(a, b);
            }
        }
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("mpi.json")).unwrap()).unwrap();
        assert_eq!(json["format"], "deepview-mpi");
        assert_eq!(json["layers"][0], "layer_000.png");
        assert_eq!(json["camera_from_world"].as_array().unwrap().len(), 16);
    }

    #[test]
    fn bad_folders_give_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_mpi::<f32>(dir.path()).unwrap_err().to_string();
        assert!(e.contains("mpi.json"), "{e}");
        write_mpi(dir.path(), &small_mpi()).unwrap();
        std::fs::remove_file(dir.path().join("layer_001.png")).unwrap();
        let e = read_mpi::<f32>(dir.path()).unwrap_err().to_string();
        assert!(e.contains("layer_001.png"), "{e}");
        let e = read_mpi::<u8>(dir.path()).unwrap_err().to_string();
        assert!(e.contains("layer_001.png"), "{e}");

        let json_path = dir.path().join("mpi.json");
        let good = std::fs::read_to_string(&json_path).unwrap();
        let cases = [
            (
                good.replace("\"depths\": [", "\"depths\": [\n    \"x\","),
                "mpi.json",
            ),
            ("{not json".to_string(), "mpi.json"),
            (good.replace("deepview-mpi", "other"), "format"),
        ];
        for (text, needle) in cases {
            std::fs::write(&json_path, text).unwrap();
            let e = read_mpi::<f32>(dir.path()).unwrap_err().to_string();
            assert!(e.contains(needle), "{e}");
        }
        // Zero planes and mismatched counts.
        let mut meta: MpiMeta = serde_json::from_str(&good).unwrap();
        meta.depths.clear();
        meta.layers.clear();
        std::fs::write(&json_path, serde_json::to_string(&meta).unwrap()).unwrap();
        assert!(
            read_mpi::<f32>(dir.path())
                .unwrap_err()
                .to_string()
                .contains("zero planes")
        );
        // Non-finite pose (JSON has no NaN literal; a huge number overflows to inf in f64 parsing).
        let mut meta: MpiMeta = serde_json::from_str(&good).unwrap();
        meta.layers.pop();
        std::fs::write(&json_path, serde_json::to_string(&meta).unwrap()).unwrap();
        assert!(
            read_mpi::<f32>(dir.path())
                .unwrap_err()
                .to_string()
                .contains("2 layers but 3 depths")
        );
        std::fs::write(&json_path, good.replacen("1.0", "1e999", 1)).unwrap();
        assert!(read_mpi::<f32>(dir.path()).is_err());
        // Layer of the wrong size.
        std::fs::write(&json_path, &good).unwrap();
        write_png_u8(&dir.path().join("layer_001.png"), 3, 3, 4, &[0; 36]).unwrap();
        let e = read_mpi::<f32>(dir.path()).unwrap_err().to_string();
        assert!(e.contains("layer_001.png") && e.contains("3x3"), "{e}");
    }
}
