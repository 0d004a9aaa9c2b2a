//! Fuzz tests of every reader of an MPI folder a user hands in (issue 28): our folder format (`mpi.json` and
//! the layer PNGs, [`read_mpi`]), and the interchange formats `deepview import` reads ([`read_any`]): LLFF's
//! `metadata.txt` + `mpi.b`, stereo magnification's layers, `intrinsics.txt`, `README` and
//! `deepview_camera.json`, and the compact export's `mpi_compact.json` and tile pages. Valid folders are
//! written with this crate's writers, one file is mutated (see `deepview_fuzz`) and the folder read back: no
//! input may panic, every error names the file (or the folder holding it), and what is accepted is a
//! valid MPI (valid camera, depths positive and decreasing, planes of the camera's size).
//!
//! Run longer or with another seed: `DEEPVIEW_FUZZ_SECS=60 DEEPVIEW_FUZZ_ITERS=1000000
//! DEEPVIEW_FUZZ_SEED=7 cargo test --release -p deepview-mpi --test fuzz`.

use deepview_fuzz::{Fuzz, Kind};
use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths};
use deepview_mpi::interchange::{
    ImportOptions, StraightMpi, compact, llff, read_any, read_straight, stereo_mag,
};
use deepview_mpi::{Mpi, read_mpi, write_mpi};
use std::path::{Path, PathBuf};

/// A 10x6 MPI of 3 planes, partly transparent (so the compact export drops tiles).
fn test_mpi() -> Mpi {
    let r = DMat3::from_rotation_x(0.1) * DMat3::from_rotation_y(-0.2);
    let pose = Pose::from_center(r, DVec3::new(0.5, -1.0, 2.0));
    let cam = Camera::new(10, 6, Intrinsics::new(9.0, 9.5, 5.0, 3.25), pose);
    let depths = plane_depths(2.0, 20.0, 3, PlaneSpacing::InverseDepth).unwrap();
    let mut mpi = Mpi::transparent(cam, depths);
    for d in 0..3 {
        for (i, p) in mpi.plane_mut(d).chunks_exact_mut(4).enumerate() {
            let (x, y) = (i % 10, i / 10);
            let a = if x < 4 && y < 4 {
                0.0
            } else {
                ((i * 37 + d * 11) % 200) as f32 / 255.0 + 0.1
            };
            p[3] = a;
            for k in 0..3 {
                p[k] = (((i * 31 + k * 17 + d) % 256) as f32 / 255.0) * a;
            }
        }
    }
    mpi
}

/// The MPI folders of [`test_mpi`] under `root`: ours (`mpi`) and its exports (`llff`, `stereo` with its
/// sidecar, `stereo-plain` without, `compact` in 4x4 tiles).
fn folders(root: &Path) -> impl Fn(&str) -> PathBuf + '_ {
    let at = |name: &str| root.join(name);
    write_mpi(&at("mpi"), &test_mpi()).unwrap();
    let straight = read_straight(&at("mpi")).unwrap();
    llff::write(&at("llff"), &straight).unwrap();
    stereo_mag::write(&at("stereo"), &straight).unwrap();
    stereo_mag::write(&at("stereo-plain"), &straight).unwrap();
    std::fs::remove_file(at("stereo-plain").join(stereo_mag::SIDECAR)).unwrap();
    compact::write_with_tile(&at("compact"), &straight, 4).unwrap();
    // The unmutated folders read back exactly.
    for name in ["llff", "stereo", "compact"] {
        let (_, back) = read_any(&at(name), &ImportOptions::default()).unwrap();
        assert!(back.planes == straight.planes, "{name}");
    }
    at
}

/// What a reader accepts is a valid MPI.
fn check(camera: &Camera, depths: &[f64], planes: usize, plane_len: impl Fn(usize) -> usize) {
    camera.validate().unwrap();
    assert!(
        !depths.is_empty() && depths.len() == planes,
        "{} depths, {planes} planes",
        depths.len()
    );
    assert!(
        depths.iter().all(|d| d.is_finite() && *d > 0.0),
        "{depths:?}"
    );
    assert!(
        depths.windows(2).all(|w| w[1] < w[0]),
        "depths must decrease: {depths:?}"
    );
    let n = camera.width as usize * camera.height as usize * 4;
    assert!(
        (0..planes).all(|d| plane_len(d) == n),
        "a plane is not {n} values"
    );
}

fn check_straight(m: &StraightMpi) {
    check(&m.camera, &m.depths, m.planes.len(), |d| m.planes[d].len());
}

/// Fuzz `file` of `folder`, read by `read_any` (the interchange formats).
fn fuzz_interchange(name: &str, folder: &Path, file: &str, kind: Kind, iters: usize) {
    let path = folder.join(file);
    Fuzz {
        name: &format!("read_any({name} {file})"),
        file: &path,
        kind,
        seeds: vec![std::fs::read(&path).unwrap()],
        iters,
        needles: vec![folder.display().to_string()],
        special: None,
    }
    .run(|| {
        let (_, m) = read_any(folder, &ImportOptions::default()).map_err(|e| e.to_string())?;
        check_straight(&m);
        Ok(())
    });
}

/// Fuzz `file` of our folder format, read by `read_mpi` (f32 and u8) and `read_straight`.
fn fuzz_folder(file: &str, kind: Kind, iters: usize) {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("mpi");
    let path = dir.join(file);
    Fuzz {
        name: &format!("read_mpi({file})"),
        file: &path,
        kind,
        seeds: vec![std::fs::read(&path).unwrap()],
        iters,
        needles: vec![dir.display().to_string()],
        special: None,
    }
    .run(|| {
        let m = read_mpi::<f32>(&dir).map_err(|e| e.to_string())?;
        check(&m.camera, &m.depths, m.depths.len(), |_| m.plane_len());
        assert_eq!(m.layers.len(), m.plane_len() * m.depths.len());
        let m = read_mpi::<u8>(&dir).map_err(|e| e.to_string())?;
        assert_eq!(m.layers.len(), m.plane_len() * m.depths.len());
        check_straight(&read_straight(&dir).map_err(|e| e.to_string())?);
        Ok(())
    });
}

#[test]
fn mpi_json() {
    fuzz_folder("mpi.json", Kind::Json, 4000);
}

#[test]
fn mpi_layer_png() {
    fuzz_folder("layer_001.png", Kind::Binary, 3000);
}

#[test]
fn llff_metadata_txt() {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("llff");
    fuzz_interchange("llff", &dir, "metadata.txt", Kind::Text, 3000);
}

#[test]
fn llff_mpi_b() {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("llff");
    fuzz_interchange("llff", &dir, "mpi.b", Kind::Binary, 2000);
}

#[test]
fn stereo_mag_sidecar_json() {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("stereo");
    fuzz_interchange("stereo-mag", &dir, stereo_mag::SIDECAR, Kind::Json, 3000);
}

#[test]
fn stereo_mag_intrinsics_txt() {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("stereo-plain");
    fuzz_interchange("stereo-mag", &dir, "intrinsics.txt", Kind::Text, 3000);
}

#[test]
fn stereo_mag_readme() {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("stereo-plain");
    fuzz_interchange("stereo-mag", &dir, "README", Kind::Text, 3000);
}

#[test]
fn stereo_mag_layer_pngs() {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("stereo");
    fuzz_interchange("stereo-mag", &dir, "mpi_alpha_01.png", Kind::Binary, 1500);
    fuzz_interchange("stereo-mag", &dir, "mpi_rgb_02.png", Kind::Binary, 1500);
}

#[test]
fn compact_json() {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("compact");
    fuzz_interchange("compact", &dir, compact::META, Kind::Json, 4000);
}

/// Regression (found by `stereo_mag_readme`): a near depth whose inverse overflows (`1e-320`) passes
/// `plane_depths` but gives planes at depth 0; LLFF's `far near` line feeds the same function.
#[test]
fn tiny_near_depths_are_refused() {
    let root = tempfile::tempdir().unwrap();
    let at = folders(root.path());
    let readme = at("stereo-plain").join("README");
    std::fs::write(&readme, "--min_depth=1e-320 --max_depth=20").unwrap();
    let e = read_any(&at("stereo-plain"), &ImportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("stereo-plain") && e.contains("positive"), "{e}");
    let meta = at("llff").join("metadata.txt");
    let text = std::fs::read_to_string(&meta).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[5] = "20 1e-320";
    std::fs::write(&meta, lines.join("\n")).unwrap();
    let e = read_any(&at("llff"), &ImportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("metadata.txt") && e.contains("positive"), "{e}");
}

/// Regression: the compact reader sized its planes from the header alone (`width x height x 4` bytes per
/// plane, the first plane cloned into the others), so a few bytes of JSON could ask for tens of GiB; its
/// 32-bit tile arithmetic also wrapped for planes over 4 GiB. Found by reading the code for this fuzz
/// test (random mutation rarely keeps `tiles_x`/`tiles_y` consistent with a huge size).
#[test]
fn compact_header_cannot_ask_for_huge_planes() {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("compact");
    let path = dir.join(compact::META);
    let mut meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    for (k, v) in [
        ("width", 65536),
        ("height", 65536),
        ("tile", 65536),
        ("tiles_x", 1),
        ("tiles_y", 1),
    ] {
        meta[k] = v.into();
    }
    meta["planes"] = serde_json::json!([[], [], []]);
    meta["pages"] = serde_json::json!([]);
    // A camera that such a size may have (else the camera, not the size, is refused first).
    meta["intrinsics"] =
        serde_json::json!({"fx": 65536.0, "fy": 65536.0, "cx": 32768.0, "cy": 32768.0});
    std::fs::write(&path, meta.to_string()).unwrap();
    let e = read_any(&dir, &ImportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains(compact::META) && e.contains("4 GiB"), "{e}");
}

#[test]
fn compact_page_png() {
    let root = tempfile::tempdir().unwrap();
    let dir = folders(root.path())("compact");
    fuzz_interchange("compact", &dir, "tiles_000.png", Kind::Binary, 3000);
}
