//! Fuzz tests of every reader of a file a user hands in (issue 28): `.npy` ([`npy::read_npy`]), LLFF's
//! `poses_bounds.npy`, COLMAP text and binary models, `transforms.json`, Spaces `models.json`, camera JSON,
//! and a light field's `gt_disp_lowres.pfm` and `parameters.cfg`. Valid files are written with this crate's
//! writers (COLMAP binary by hand), mutated (see `deepview_fuzz`), and read back: no input may panic, every error
//! names the file (or the scene folder holding it), and what is accepted is consistent (array shapes match
//! their data, loaded cameras are valid: `load_scene` checks them).
//!
//! Run longer or with another seed: `DEEPVIEW_FUZZ_SECS=60 DEEPVIEW_FUZZ_ITERS=1000000
//! DEEPVIEW_FUZZ_SEED=7 cargo test --release -p deepview-data --test fuzz`.

use deepview_data::formats::colmap::{ColmapModel, read_colmap};
use deepview_data::formats::lightfield::{read_disparity_range, write_disparity_range};
use deepview_data::npy::{npy_bytes, read_npy};
use deepview_data::pfm::{Pfm, pfm_bytes, read_pfm};
use deepview_data::{
    LoadOptions, SceneFormat, load_scene, read_camera_json, write_colmap_text, write_light_field,
    write_llff, write_spaces_models, write_transforms,
};
use deepview_fuzz::{Fuzz, Kind};
use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, Pose};
use deepview_image::ImageF32;
use std::path::Path;

/// `n` 12x8 cameras on a line at z = -1, looking along +z.
fn cameras(n: usize) -> Vec<Camera> {
    (0..n)
        .map(|i| {
            let r = DMat3::from_rotation_y(0.05 * i as f64) * DMat3::from_rotation_x(-0.1);
            let centre = DVec3::new(i as f64 * 0.1, 0.0, -1.0);
            Camera::new(
                12,
                8,
                Intrinsics::centred(10.0, 12, 8),
                Pose::from_center(r, centre),
            )
        })
        .collect()
}

fn images(n: usize) -> Vec<ImageF32> {
    (0..n)
        .map(|i| ImageF32::from_data(12, 8, 3, vec![i as f32 / 8.0; 12 * 8 * 3]).unwrap())
        .collect()
}

fn shown(p: &Path) -> String {
    p.display().to_string()
}

/// `load_scene` on `dir` (format given), its error message.
fn load(dir: &Path, format: SceneFormat) -> Result<(), String> {
    load_with(dir, format, None)
}

/// [`load`] with depth bounds given.
fn load_with(dir: &Path, format: SceneFormat, near_far: Option<(f64, f64)>) -> Result<(), String> {
    let opts = LoadOptions {
        format: Some(format),
        near: near_far.map(|b| b.0),
        far: near_far.map(|b| b.1),
        ..Default::default()
    };
    let scene = load_scene(dir, &opts).map_err(|e| e.to_string())?;
    assert!(!scene.views.is_empty());
    for v in &scene.views {
        v.camera.validate().unwrap();
    }
    if let Some((n, f)) = scene.depth_bounds {
        assert!(
            n.is_finite() && f.is_finite() && 0.0 < n && n < f,
            "{n} {f}"
        );
    }
    Ok(())
}

#[test]
fn npy() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("array.npy");
    let data: Vec<f64> = (0..51).map(|i| i as f64 * 0.25 - 3.0).collect();
    // Version 2, float32, Fortran order; version 3, big-endian float64.
    let with_header = |version: u8, header: &str, payload: Vec<u8>| {
        let mut out = b"\x93NUMPY".to_vec();
        out.extend_from_slice(&[version, 0]);
        out.extend_from_slice(&(header.len() as u32).to_le_bytes());
        out.extend_from_slice(header.as_bytes());
        out.extend(payload);
        out
    };
    let f4: Vec<u8> = (0..6).flat_map(|i| (i as f32).to_le_bytes()).collect();
    let be: Vec<u8> = (0..5).flat_map(|i| (i as f64).to_be_bytes()).collect();
    Fuzz {
        name: "read_npy",
        file: &file,
        kind: Kind::Binary,
        seeds: vec![
            npy_bytes(&[3, 17], &data),
            with_header(
                2,
                "{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3), }\n",
                f4,
            ),
            with_header(
                3,
                "{'descr': '>f8', 'fortran_order': False, 'shape': (5,), }\n",
                be,
            ),
        ],
        iters: 3000,
        needles: vec!["array.npy".into()],
        special: None,
    }
    .run(|| {
        let a = read_npy(&file).map_err(|e| e.to_string())?;
        let count = a.shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
        assert_eq!(
            count,
            Some(a.data.len()),
            "shape {:?} for {} values",
            a.shape,
            a.data.len()
        );
        Ok(())
    });
}

#[test]
fn llff_poses_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let bounds = [(1.0, 5.0), (0.5, 4.0), (2.0, 9.0)];
    write_llff(dir.path(), &cameras(3), &bounds, &images(3), 1).unwrap();
    let file = dir.path().join("poses_bounds.npy");
    Fuzz {
        name: "read_poses_bounds+load_scene(llff)",
        file: &file,
        kind: Kind::Binary,
        seeds: vec![std::fs::read(&file).unwrap()],
        iters: 1500,
        needles: vec![shown(dir.path())],
        special: None,
    }
    .run(|| load(dir.path(), SceneFormat::Llff));
}

/// A COLMAP text model of 3 cameras and 5 points in front of them, in `dir`.
fn colmap_text(dir: &Path) {
    let names: Vec<String> = (0..3).map(|i| format!("image{i:03}.png")).collect();
    let points: Vec<DVec3> = (0..5)
        .map(|i| DVec3::new(0.1 * i as f64 - 0.2, 0.05 * i as f64, 2.0 + i as f64 * 0.5))
        .collect();
    write_colmap_text(dir, &names, &cameras(3), &points).unwrap();
}

/// `read_colmap` then `load_scene` on the model in `dir` (errors name the model's files or folder).
fn colmap(dir: &Path) -> Result<(), String> {
    read_colmap(dir).map_err(|e| e.to_string())?;
    load(dir, SceneFormat::Colmap)
}

fn fuzz_colmap_file(dir: &Path, name: &str, kind: Kind, iters: usize) {
    let file = dir.join(name);
    Fuzz {
        name: &format!("read_colmap({name})+load_scene(colmap)"),
        file: &file,
        kind,
        seeds: vec![std::fs::read(&file).unwrap()],
        iters,
        needles: vec![shown(dir)],
        special: None,
    }
    .run(|| colmap(dir));
}

#[test]
fn colmap_cameras_txt() {
    let dir = tempfile::tempdir().unwrap();
    colmap_text(dir.path());
    fuzz_colmap_file(dir.path(), "cameras.txt", Kind::Text, 2000);
}

#[test]
fn colmap_images_txt() {
    let dir = tempfile::tempdir().unwrap();
    colmap_text(dir.path());
    fuzz_colmap_file(dir.path(), "images.txt", Kind::Text, 2000);
}

#[test]
fn colmap_points3d_txt() {
    let dir = tempfile::tempdir().unwrap();
    colmap_text(dir.path());
    fuzz_colmap_file(dir.path(), "points3D.txt", Kind::Text, 2000);
}

/// COLMAP's binary model files (`cameras.bin`, `images.bin`, `points3D.bin`) of `model`.
fn colmap_binary(dir: &Path, model: &ColmapModel) {
    let mut cams = (model.cameras.len() as u64).to_le_bytes().to_vec();
    for c in model.cameras.values() {
        assert_eq!(c.model, "PINHOLE");
        cams.extend((c.id as i32).to_le_bytes());
        cams.extend(1i32.to_le_bytes());
        cams.extend(c.width.to_le_bytes());
        cams.extend(c.height.to_le_bytes());
        c.params.iter().for_each(|p| cams.extend(p.to_le_bytes()));
    }
    let mut imgs = (model.images.len() as u64).to_le_bytes().to_vec();
    for im in &model.images {
        imgs.extend((im.id as i32).to_le_bytes());
        im.qvec
            .iter()
            .chain(&im.tvec)
            .for_each(|v| imgs.extend(v.to_le_bytes()));
        imgs.extend((im.camera_id as i32).to_le_bytes());
        imgs.extend(im.name.bytes().chain([0]));
        imgs.extend((im.point3d_ids.len() as u64 + 1).to_le_bytes());
        for (k, id) in im
            .point3d_ids
            .iter()
            .map(|&id| id as i64)
            .chain([-1])
            .enumerate()
        {
            imgs.extend((k as f64 + 0.5).to_le_bytes());
            imgs.extend(2.5f64.to_le_bytes());
            imgs.extend(id.to_le_bytes());
        }
    }
    let mut pts = (model.points.len() as u64).to_le_bytes().to_vec();
    for p in &model.points {
        pts.extend(p.id.to_le_bytes());
        p.xyz.iter().for_each(|v| pts.extend(v.to_le_bytes()));
        pts.extend([128, 64, 32]);
        pts.extend(0.5f64.to_le_bytes());
        pts.extend(2u64.to_le_bytes());
        [(1i32, 0i32), (2, 0)].iter().for_each(|(i, k)| {
            pts.extend(i.to_le_bytes());
            pts.extend(k.to_le_bytes());
        });
    }
    for (name, bytes) in [
        ("cameras.bin", cams),
        ("images.bin", imgs),
        ("points3D.bin", pts),
    ] {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
}

/// A binary COLMAP model equal to the text one of [`colmap_text`] (checked), in `dir`.
fn colmap_bin_model(dir: &Path) {
    let text = tempfile::tempdir().unwrap();
    colmap_text(text.path());
    let model = read_colmap(text.path()).unwrap();
    colmap_binary(dir, &model);
    assert_eq!(read_colmap(dir).unwrap(), model);
}

#[test]
fn colmap_cameras_bin() {
    let dir = tempfile::tempdir().unwrap();
    colmap_bin_model(dir.path());
    fuzz_colmap_file(dir.path(), "cameras.bin", Kind::Binary, 2000);
}

#[test]
fn colmap_images_bin() {
    let dir = tempfile::tempdir().unwrap();
    colmap_bin_model(dir.path());
    fuzz_colmap_file(dir.path(), "images.bin", Kind::Binary, 2000);
}

#[test]
fn colmap_points3d_bin() {
    let dir = tempfile::tempdir().unwrap();
    colmap_bin_model(dir.path());
    fuzz_colmap_file(dir.path(), "points3D.bin", Kind::Binary, 2000);
}

#[test]
fn transforms_json() {
    let dir = tempfile::tempdir().unwrap();
    write_transforms(dir.path(), &cameras(3), &images(3), Some((0.5, 9.0))).unwrap();
    let file = dir.path().join("transforms.json");
    let written = std::fs::read(&file).unwrap();
    // instant-ngp style: a field of view instead of focal lengths, per-frame principal points, an aabb
    // instead of near/far, 3-row matrices.
    let mut v: serde_json::Value = serde_json::from_slice(&written).unwrap();
    let o = v.as_object_mut().unwrap();
    for k in ["fl_x", "fl_y", "near", "far", "camera_model"] {
        o.remove(k);
    }
    o.insert("camera_angle_x".into(), serde_json::json!(1.1));
    o.insert("aabb".into(), serde_json::json!([[-1, -1, 2], [1, 1, 4]]));
    for f in o["frames"].as_array_mut().unwrap() {
        f["cx"] = serde_json::json!(6.25);
        f["transform_matrix"].as_array_mut().unwrap().pop();
    }
    Fuzz {
        name: "load_scene(transforms.json)",
        file: &file,
        kind: Kind::Json,
        seeds: vec![written, serde_json::to_vec(&v).unwrap()],
        iters: 1500,
        needles: vec![shown(dir.path())],
        special: None,
    }
    .run(|| load(dir.path(), SceneFormat::Transforms));
}

#[test]
fn spaces_models_json() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("models.json");
    let rigs = vec![cameras(3), cameras(3)];
    let paths: Vec<Vec<String>> = (0..2)
        .map(|r| {
            (0..3)
                .map(|i| deepview_data::spaces_relative_path(i, r))
                .collect()
        })
        .collect();
    write_spaces_models(&file, &rigs, &paths).unwrap();
    Fuzz {
        name: "load_scene(models.json)",
        file: &file,
        kind: Kind::Json,
        seeds: vec![std::fs::read(&file).unwrap()],
        iters: 1500,
        needles: vec![shown(dir.path())],
        special: None,
    }
    // Spaces files carry no depth bounds: give them.
    .run(|| load_with(dir.path(), SceneFormat::Spaces, Some((1.0, 10.0))));
}

#[test]
fn camera_json() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("camera.json");
    let cam = cameras(2)[1];
    Fuzz {
        name: "read_camera_json",
        file: &file,
        kind: Kind::Json,
        seeds: vec![serde_json::to_vec_pretty(&cam.to_json()).unwrap()],
        iters: 2000,
        needles: vec!["camera.json".into()],
        special: None,
    }
    .run(|| {
        let c = read_camera_json(&file).map_err(|e| e.to_string())?;
        c.validate().unwrap();
        Ok(())
    });
}

/// A 2x2 light field of 12x8 views in `dir`, with its ground-truth disparity.
fn light_field(dir: &Path) {
    let disparity = Pfm {
        width: 6,
        height: 4,
        channels: 1,
        data: (0..24).map(|i| i as f32 * 0.25 - 2.0).collect(),
    };
    write_light_field(dir, 2, 2, &images(4), Some(&disparity)).unwrap();
}

#[test]
fn light_field_pfm() {
    let dir = tempfile::tempdir().unwrap();
    light_field(dir.path());
    let file = dir.path().join("gt_disp_lowres.pfm");
    let rgb = Pfm {
        width: 3,
        height: 2,
        channels: 3,
        data: (0..18).map(|i| i as f32).collect(),
    };
    let mut big_endian = b"Pf\n2 1\n1.0\n".to_vec();
    big_endian.extend([1.5f32, -0.5].iter().flat_map(|v| v.to_be_bytes()));
    Fuzz {
        name: "read_pfm+load_scene(light field)",
        file: &file,
        kind: Kind::Binary,
        seeds: vec![std::fs::read(&file).unwrap(), pfm_bytes(&rgb), big_endian],
        iters: 1000,
        needles: vec![shown(dir.path())],
        special: None,
    }
    .run(|| {
        let p = read_pfm(&file).map_err(|e| e.to_string())?;
        let n = p
            .width
            .checked_mul(p.height)
            .and_then(|n| n.checked_mul(p.channels));
        assert_eq!(
            n,
            Some(p.data.len()),
            "{}x{}x{}",
            p.width,
            p.height,
            p.channels
        );
        load(dir.path(), SceneFormat::LightField)
    });
}

#[test]
fn light_field_parameters_cfg() {
    let dir = tempfile::tempdir().unwrap();
    light_field(dir.path());
    write_disparity_range(dir.path(), (-1.5, 2.25)).unwrap();
    let file = dir.path().join("parameters.cfg");
    let hci = "[intrinsics]\nfocal_length_mm = 100\n\n[meta]\ndisp_min = -2.5\ndisp_max = 1.75\nnum_cams_x = 9\n";
    Fuzz {
        name: "read_disparity_range+load_scene(light field)",
        file: &file,
        kind: Kind::Text,
        seeds: vec![std::fs::read(&file).unwrap(), hci.as_bytes().to_vec()],
        iters: 800,
        needles: vec![shown(dir.path())],
        special: None,
    }
    .run(|| {
        if let Some((lo, hi)) = read_disparity_range(&file).map_err(|e| e.to_string())? {
            assert!(lo.is_finite() && hi.is_finite() && lo < hi, "{lo} {hi}");
        }
        load(dir.path(), SceneFormat::LightField)
    });
}
