use super::*;
use crate::{LoadOptions, SceneFormat, load_scene};
use deepview_geometry::{Camera, DVec3, Intrinsics};
use deepview_geometry::{DMat3, Pose};
use deepview_image::ImageF32;
use std::path::PathBuf;

fn p() -> PathBuf {
    PathBuf::from("scene").join(TRANSFORMS_JSON)
}

const SHARED: &str = r#"{
    "camera_model": "OPENCV", "fl_x": 100, "fl_y": 101.5, "cx": 31.5, "cy": 24.25, "w": 64, "h": 48,
    "k1": 0, "k2": 0.0, "p1": 0, "p2": 0, "applied_transform": [[1,0,0,0],[0,1,0,0],[0,0,1,0]],
    "frames": [
        {"file_path": "images/a.png", "transform_matrix": [[1,0,0,1],[0,1,0,2],[0,0,1,3],[0,0,0,1]]},
        {"file_path": "images/b", "fl_x": 90, "w": 32, "h": 24, "cx": 16, "cy": 12,
         "transform_matrix": [[0,0,1,0],[0,1,0,0],[-1,0,0,0],[0,0,0,1]]}
    ]
}"#;

#[test]
fn shared_and_per_frame_intrinsics_and_opengl_poses() {
    let f = parse_transforms(SHARED, &p()).unwrap();
    let c = transforms_cameras(&f, &p()).unwrap();
    assert_eq!(c.len(), 2);
    assert_eq!(c[0].size, Some((64, 48)));
    assert_eq!(
        c[0].intrinsics.resolve(64, 48).unwrap(),
        Intrinsics::new(100.0, 101.5, 31.5, 24.25)
    );
    // Frame 1 overrides fl_x, the size and the principal point; fl_y is the shared one.
    assert_eq!(c[1].size, Some((32, 24)));
    assert_eq!(
        c[1].intrinsics.resolve(32, 24).unwrap(),
        Intrinsics::new(90.0, 101.5, 16.0, 12.0)
    );
    // Identity OpenGL rotation: OpenCV y and z flip; the centre is the last column.
    let want = DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0));
    assert!(c[0].pose.rotation.abs_diff_eq(want, 1e-15));
    assert!(
        c[0].pose
            .center()
            .abs_diff_eq(DVec3::new(1.0, 2.0, 3.0), 1e-15)
    );
    // Frame 1 looks along world -x (its OpenGL back axis is world +x)... its OpenCV forward is -x.
    let fwd = c[1].pose.rotation.transpose() * DVec3::Z;
    assert!(fwd.abs_diff_eq(DVec3::new(-1.0, 0.0, 0.0), 1e-15), "{fwd}");
}

#[test]
fn camera_angle_x_form() {
    let text = r#"{"camera_angle_x": 0.6911112070083618, "frames": [
        {"file_path": "./train/r_0", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}]}"#;
    let f = parse_transforms(text, &p()).unwrap();
    let c = transforms_cameras(&f, &p()).unwrap();
    assert_eq!(c[0].size, None);
    let k = c[0].intrinsics.resolve(800, 800).unwrap();
    let want = 0.5 * 800.0 / (0.6911112070083618f64 / 2.0).tan();
    assert!(
        (k.fx - want).abs() < 1e-9 && (k.fy - want).abs() < 1e-9,
        "{k:?}"
    );
    assert!((want - 1111.1110311937682).abs() < 1e-6);
    assert_eq!((k.cx, k.cy), (400.0, 400.0));
}

fn err(text: &str) -> String {
    match parse_transforms(text, &p()) {
        Err(e) => e.to_string(),
        Ok(f) => transforms_cameras(&f, &p()).unwrap_err().to_string(),
    }
}

#[test]
fn errors_name_the_file_and_the_problem() {
    let frame =
        r#""file_path": "a.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]"#;
    let cases = [
        ("{\"frames\": [".to_string(), "malformed JSON"),
        ("{\"fl_x\": 10}".to_string(), "missing \"frames\""),
        ("{\"fl_x\": 10, \"frames\": []}".to_string(), "empty"),
        (
            r#"{"fl_x": 10, "frames": [{"file_path": "a.png"}]}"#.to_string(),
            "frame 0 (a.png): missing \"transform_matrix\"",
        ),
        (
            r#"{"fl_x": 10, "frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0]]}]}"#
                .to_string(),
            "missing \"file_path\"",
        ),
        (format!("{{\"frames\": [{{{frame}}}]}}"), "fl_x"),
        (
            format!("{{\"fl_x\": 1e999, \"frames\": [{{{frame}}}]}}"),
            "malformed JSON",
        ),
        (
            r#"{"fl_x": 10, "frames": [{"file_path": "a", "transform_matrix": [[1,0,0],[0,1,0],[0,0,1]]}]}"#
                .to_string(),
            "4 rows of 4",
        ),
        (
            r#"{"fl_x": 10, "frames": [{"file_path": "a", "transform_matrix": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}"#
                .to_string(),
            "orthonormal",
        ),
        (
            format!("{{\"fl_x\": 10, \"k1\": -0.1, \"p2\": 0.01, \"frames\": [{{{frame}}}]}}"),
            "non-zero distortion (k1 = -0.1, p2 = 0.01)",
        ),
        (
            format!(
                "{{\"fl_x\": 10, \"camera_model\": \"OPENCV_FISHEYE\", \"frames\": [{{{frame}}}]}}"
            ),
            "OPENCV_FISHEYE is not supported",
        ),
        (
            format!("{{\"fl_x\": 10, \"w\": 10.5, \"h\": 4, \"frames\": [{{{frame}}}]}}"),
            "\"w\" = 10.5",
        ),
        (
            format!("{{\"fl_x\": -10, \"w\": 10, \"h\": 4, \"frames\": [{{{frame}}}]}}"),
            "focal lengths must be positive",
        ),
        (
            format!("{{\"camera_angle_x\": 4, \"w\": 10, \"h\": 4, \"frames\": [{{{frame}}}]}}"),
            "camera_angle_x = 4",
        ),
    ];
    for (text, needle) in cases {
        let e = err(&text);
        assert!(e.contains(needle), "{needle:?} not in {e:?}");
        assert!(e.contains("transforms.json"), "{e}");
    }
}

fn cams() -> Vec<Camera> {
    (0..3)
        .map(|i| {
            let r = DMat3::from_rotation_y(0.1 * i as f64) * DMat3::from_rotation_x(0.05);
            Camera::new(
                16,
                12,
                Intrinsics::new(20.0, 21.0, 8.5, 6.25),
                Pose::from_center(r, DVec3::new(0.2 * i as f64, 0.1, -1.0)),
            )
        })
        .collect()
}

fn images(n: usize, w: u32, h: u32) -> Vec<ImageF32> {
    (0..n)
        .map(|i| ImageF32::from_data(w, h, 3, vec![i as f32 / 4.0; (w * h * 3) as usize]).unwrap())
        .collect()
}

#[test]
fn write_then_load_round_trip_and_downscaled_folder() {
    let dir = tempfile::tempdir().unwrap();
    let c = cams();
    write_transforms(dir.path(), &c, &images(3, 16, 12), Some((0.5, 8.0))).unwrap();
    let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(s.format, SceneFormat::Transforms);
    assert_eq!(s.depth_bounds, Some((0.5, 8.0)));
    assert_eq!(s.calibration_path(), dir.path().join(TRANSFORMS_JSON));
    for (v, c) in s.views.iter().zip(&c) {
        assert_eq!(v.camera.intrinsics, c.intrinsics);
        assert!(v.camera.pose.rotation.abs_diff_eq(c.pose.rotation, 1e-12));
        assert!(v.camera.center().abs_diff_eq(c.center(), 1e-12));
    }
    assert!((s.load_image(2).unwrap().data[0] - 0.5).abs() < 1.0 / 255.0);
    // The JSON file itself can be given.
    let s2 = load_scene(&dir.path().join(TRANSFORMS_JSON), &LoadOptions::default()).unwrap();
    assert_eq!(s2.views[1].camera, s.views[1].camera);
    // A half-size copy in images_2/: intrinsics scale with the images.
    for (i, img) in images(3, 8, 6).iter().enumerate() {
        crate::write_image(&dir.path().join(format!("images_2/image{i:03}.png")), img).unwrap();
    }
    let opts = LoadOptions {
        images: Some("images_2".into()),
        ..Default::default()
    };
    let s = load_scene(dir.path(), &opts).unwrap();
    assert_eq!((s.views[0].camera.width, s.views[0].camera.height), (8, 6));
    assert_eq!(
        s.views[0].camera.intrinsics,
        Intrinsics::new(10.0, 10.5, 4.25, 3.125)
    );
    s.check_images().unwrap();
    // A wrongly sized image, a missing one, a missing folder.
    crate::write_image(
        &dir.path().join("images_2/image001.png"),
        &images(1, 8, 3)[0],
    )
    .unwrap();
    let e = load_scene(dir.path(), &opts).unwrap_err().to_string();
    assert!(
        e.contains("image001.png") && e.contains("transforms.json"),
        "{e}"
    );
    std::fs::remove_file(dir.path().join("images_2/image001.png")).unwrap();
    let e = load_scene(dir.path(), &opts).unwrap_err().to_string();
    assert!(
        e.contains("image001.png") && e.contains("does not exist") && e.contains("frame 1"),
        "{e}"
    );
    let opts = LoadOptions {
        images: Some("images_9".into()),
        ..Default::default()
    };
    let e = load_scene(dir.path(), &opts).unwrap_err().to_string();
    assert!(
        e.contains("images_9") && e.contains("does not exist"),
        "{e}"
    );
}

#[test]
fn bounds_from_aabb_or_required() {
    let dir = tempfile::tempdir().unwrap();
    let c = cams();
    write_transforms(dir.path(), &c, &images(3, 16, 12), None).unwrap();
    let e = load_scene(dir.path(), &LoadOptions::default())
        .unwrap()
        .near_far()
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("near and far") && e.contains("transforms.json"),
        "{e}"
    );
    // An aabb in front of the cameras (they look along +z of the world, roughly).
    let json = dir.path().join(TRANSFORMS_JSON);
    let mut f = parse_transforms(&std::fs::read_to_string(&json).unwrap(), &json).unwrap();
    f.aabb = Some([[-0.5, -0.5, 1.0], [0.5, 0.5, 3.0]]);
    std::fs::write(&json, serde_json::to_string(&f).unwrap()).unwrap();
    let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    let (n, fa) = s.near_far().unwrap();
    assert!(n > 1.0 && n < 2.2 && fa > 3.5 && fa < 4.5, "{n} {fa}");
    // An aabb around the cameras gives no bounds.
    f.aabb = Some([[-5.0; 3], [5.0; 3]]);
    std::fs::write(&json, serde_json::to_string(&f).unwrap()).unwrap();
    let s = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(s.depth_bounds, None);
}

#[test]
fn a_photo_listed_twice_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    write_transforms(dir.path(), &cams(), &images(3, 16, 12), Some((0.5, 8.0))).unwrap();
    let json = dir.path().join(TRANSFORMS_JSON);
    let mut f = parse_transforms(&std::fs::read_to_string(&json).unwrap(), &json).unwrap();
    // Frame 2 names frame 0's photo, spelled differently.
    let frames = f.frames.as_mut().unwrap();
    let first = frames[0].file_path.clone().unwrap();
    frames[2].file_path = Some(format!("./{first}"));
    std::fs::write(&json, serde_json::to_string(&f).unwrap()).unwrap();
    let e = load_scene(dir.path(), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("transforms.json") && e.contains("frames 0 and 2") && e.contains(&first),
        "{e}"
    );
}
