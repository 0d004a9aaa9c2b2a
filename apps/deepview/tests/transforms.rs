//! nerfstudio `transforms.json` against an independent conversion of fern's LLFF poses.
//!
//! The conversion below is what a user's script would do, in plain arithmetic on the columns of
//! `poses_bounds.npy` (no project conversion code): LLFF's [down, right, back] rotation columns become
//! OpenGL's [right, up, back] = [right, -down, back].

mod common;

use common::deepview;
use std::path::Path;
use std::process::Output;

/// `deepview info --data DIR ARGS`.
fn info(dir: &Path, args: &[&str]) -> Output {
    deepview(&[&["info", "--data", dir.to_str().unwrap()], args].concat())
}

/// `transforms.json` for fern `images_8`, from the raw numbers of `poses_bounds.npy`.
fn independent_transforms(npy: &Path, angle_form: bool) -> String {
    let a = deepview_data::npy::read_npy(npy).unwrap();
    assert_eq!(a.shape[1], 17);
    let (w, h) = (504.0, 378.0);
    let mut frames = Vec::new();
    let mut fl = 0.0;
    let (mut near, mut far) = (f64::INFINITY, 0.0f64);
    for (i, row) in a.data.chunks_exact(17).enumerate() {
        let m = |r: usize, c: usize| row[r * 5 + c];
        // Columns: 0 down, 1 right, 2 back, 3 centre; column 4 is [H, W, focal] at full size.
        let (full_w, focal) = (m(1, 4), m(2, 4));
        fl = focal * w / full_w;
        near = near.min(row[15]);
        far = far.max(row[16]);
        let mut t = [[0.0; 4]; 4];
        for r in 0..3 {
            t[r] = [m(r, 1), -m(r, 0), m(r, 2), m(r, 3)];
        }
        t[3] = [0.0, 0.0, 0.0, 1.0];
        // Every other frame without its extension, as Blender-style files write them.
        let file = if i % 2 == 0 {
            format!("images_8/image{i:03}")
        } else {
            format!("./images_8/image{i:03}.png")
        };
        frames.push(serde_json::json!({"file_path": file, "transform_matrix": t}));
    }
    let mut top = if angle_form {
        serde_json::json!({"camera_angle_x": 2.0 * (0.5 * w / fl).atan()})
    } else {
        serde_json::json!({
            "camera_model": "OPENCV", "fl_x": fl, "fl_y": fl, "cx": w / 2.0, "cy": h / 2.0,
            "w": w, "h": h, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        })
    };
    top["frames"] = serde_json::Value::Array(frames);
    top["near"] = near.into();
    top["far"] = far.into();
    serde_json::to_string_pretty(&top).unwrap()
}

#[test]
fn transforms_from_fern_poses_load_to_the_llff_cameras() {
    let fern = deepview_data::data_dir().join("llff/fern");
    assert!(fern.is_dir(), "shared data missing (set DEEPVIEW_DATA)");
    let opts = deepview_data::LoadOptions {
        images: Some("images_8".into()),
        ..Default::default()
    };
    let llff = deepview_data::load_scene(&fern, &opts).unwrap();
    for angle_form in [false, true] {
        let tmp = tempfile::tempdir().unwrap();
        std::os::unix::fs::symlink(fern.join("images_8"), tmp.path().join("images_8")).unwrap();
        std::fs::write(
            tmp.path().join("transforms.json"),
            independent_transforms(&fern.join("poses_bounds.npy"), angle_form),
        )
        .unwrap();
        let ns = deepview_data::load_scene(tmp.path(), &Default::default()).unwrap();
        assert_eq!(ns.format, deepview_data::SceneFormat::Transforms);
        assert_eq!(ns.len(), llff.len());
        assert_eq!(ns.depth_bounds, llff.depth_bounds);
        for (a, b) in ns.views.iter().zip(&llff.views) {
            assert_eq!(a.name, b.name);
            assert_eq!((a.camera.width, a.camera.height), (504, 378));
            let (ka, kb) = (a.camera.intrinsics, b.camera.intrinsics);
            for (x, y) in [
                (ka.fx, kb.fx),
                (ka.fy, kb.fy),
                (ka.cx, kb.cx),
                (ka.cy, kb.cy),
            ] {
                assert!((x - y).abs() < 1e-9, "{}: {ka:?} vs {kb:?}", a.name);
            }
            let (ma, mb) = (a.camera.pose.to_row_major(), b.camera.pose.to_row_major());
            for (x, y) in ma.iter().zip(&mb) {
                assert!((x - y).abs() < 1e-9, "{}: {ma:?} vs {mb:?}", a.name);
            }
        }
        ns.check_images().unwrap();
        if angle_form {
            continue;
        }
        // The binary prints the same camera JSON for both folders.
        for n in ["0", "7", "19"] {
            let a = info(tmp.path(), &["--camera", n]);
            let b = info(&fern, &["--images", "images_8", "--camera", n]);
            assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
            assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
            let ja: serde_json::Value = serde_json::from_slice(&a.stdout).unwrap();
            let jb: serde_json::Value = serde_json::from_slice(&b.stdout).unwrap();
            let nums = |j: &serde_json::Value| -> Vec<f64> {
                let mut v: Vec<f64> = ["width", "height", "fx", "fy", "cx", "cy"]
                    .iter()
                    .map(|k| j[k].as_f64().unwrap())
                    .collect();
                v.extend(
                    j["camera_from_world"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|x| x.as_f64().unwrap()),
                );
                v
            };
            let (va, vb) = (nums(&ja), nums(&jb));
            assert_eq!(va.len(), 22);
            for (x, y) in va.iter().zip(&vb) {
                assert!((x - y).abs() < 1e-9, "camera {n}: {ja} vs {jb}");
            }
        }
        // The summary names the format; a distorted camera is refused through the binary, exit code 2.
        let o = info(tmp.path(), &[]);
        assert!(String::from_utf8_lossy(&o.stdout).contains("transforms"));
        let json = tmp.path().join("transforms.json");
        let text = std::fs::read_to_string(&json)
            .unwrap()
            .replace("\"k1\": 0.0", "\"k1\": -0.02");
        std::fs::write(&json, text).unwrap();
        let o = info(tmp.path(), &[]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(
            err.contains("transforms.json")
                && err.contains("k1 = -0.02")
                && err.contains("undistort"),
            "{err}"
        );
        std::fs::write(&json, "{\"frames\": [").unwrap();
        let o = info(tmp.path(), &[]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(
            err.contains("transforms.json") && err.contains("malformed JSON"),
            "{err}"
        );
    }
}

#[test]
fn synth_writes_transforms_that_load_back() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("grid_ns");
    let o = deepview(&[
        "synth",
        "--out",
        out.to_str().unwrap(),
        "--grid",
        "2",
        "--width",
        "48",
        "--height",
        "32",
        "--planes",
        "4",
        "--out-format",
        "transforms",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = deepview_data::load_scene(&out, &Default::default()).unwrap();
    assert_eq!(s.format, deepview_data::SceneFormat::Transforms);
    assert_eq!(s.len(), 4);
    s.check_images().unwrap();
    let lf = deepview_data::light_field_cameras(2, 2, 48, 32).cameras();
    for (v, c) in s.views.iter().zip(&lf) {
        assert_eq!(v.camera.intrinsics, c.intrinsics);
        assert!(v.camera.pose.rotation.abs_diff_eq(c.pose.rotation, 1e-12));
        assert!(v.camera.center().abs_diff_eq(c.center(), 1e-12));
    }
    assert!(s.depth_bounds.is_some());
}
