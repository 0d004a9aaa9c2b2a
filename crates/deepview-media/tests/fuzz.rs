//! Fuzz test of the reader of a nerfstudio `camera_path.json` a user hands in (issue 28):
//! [`read_camera_path`]. Valid files (this crate's writer, and one as nerfstudio writes it) are mutated
//! (see `deepview_fuzz`) and read back: no input may panic, every error names the file, and every accepted
//! path has valid cameras (positive finite focal lengths, a rigid pose) and a positive duration.
//!
//! Run longer or with another seed: `DEEPVIEW_FUZZ_SECS=60 DEEPVIEW_FUZZ_ITERS=1000000
//! DEEPVIEW_FUZZ_SEED=7 cargo test --release -p deepview-media --test fuzz`.

use deepview_fuzz::{Fuzz, Kind};
use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, Pose};
use deepview_media::camera_path::{read_camera_path, write_camera_path};

/// A nerfstudio export: extra keys, 4x4 matrices with `-0.0`, integers where floats are expected.
const NERFSTUDIO: &str = r#"{
  "keyframes": [{"matrix": "[1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]", "fov": 50, "aspect": 1.5}],
  "camera_type": "perspective",
  "render_height": 48,
  "render_width": 72,
  "camera_path": [
    {"camera_to_world": [1, 0, 0, 0.1, 0, 1, 0, 0, 0, 0, 1, 2, 0, 0, 0, 1], "fov": 50, "aspect": 1.5},
    {"camera_to_world": [0.9950041652780258, 0, 0.09983341664682815, 0.2, 0, 1, 0, -0.0,
                         -0.09983341664682815, 0, 0.9950041652780258, 2, 0, 0, 0, 1], "fov": 49.5}
  ],
  "fps": 24,
  "seconds": 2,
  "smoothness_value": 0.5,
  "is_cycle": false,
  "crop": null
}"#;

#[test]
fn camera_path_json() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("camera_path.json");
    let cams: Vec<Camera> = (0..3)
        .map(|i| {
            let r = DMat3::from_rotation_y(0.1 * i as f64);
            let pose = Pose::from_center(r, DVec3::new(0.1 * i as f64, 0.0, -2.0));
            Camera::new(64, 48, Intrinsics::centred(55.0, 64, 48), pose)
        })
        .collect();
    write_camera_path(&file, &cams, 1.5).unwrap();
    Fuzz {
        name: "read_camera_path",
        file: &file,
        kind: Kind::Json,
        seeds: vec![
            std::fs::read(&file).unwrap(),
            NERFSTUDIO.as_bytes().to_vec(),
        ],
        iters: 4000,
        needles: vec!["camera_path.json".into()],
        special: None,
    }
    .run(|| {
        let path = read_camera_path(&file).map_err(|e| e.to_string())?;
        assert!(!path.cameras.is_empty());
        assert!(
            path.seconds.is_finite() && path.seconds > 0.0,
            "{}",
            path.seconds
        );
        for c in &path.cameras {
            c.validate()
                .unwrap_or_else(|e| panic!("accepted an invalid camera: {e}: {c:?}"));
        }
        Ok(())
    });
}

/// Regression (found by `camera_path_json` with `DEEPVIEW_FUZZ_SEED=2`): a fov of `1e-320` degrees is in
/// (0, 180) but its focal length is infinite; the path was accepted with invalid cameras.
#[test]
fn a_subnormal_fov_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("camera_path.json");
    std::fs::write(
        &file,
        NERFSTUDIO.replace("\"fov\": 49.5", "\"fov\": 1e-320"),
    )
    .unwrap();
    let e = read_camera_path(&file).unwrap_err().to_string();
    assert!(
        e.contains("camera_path.json") && e.contains("camera_path[1].fov"),
        "{e}"
    );
}
