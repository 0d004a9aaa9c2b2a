use super::*;
use crate::load_scene;
use deepview_geometry::convention::pose_to_colmap;
use deepview_geometry::{DMat3, Intrinsics};

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
        e.contains("OPENCV") && e.contains("colmap image_undistorter") && e.contains("cameras.txt"),
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

#[test]
fn a_photo_listed_twice_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (mut names, cams, pts) = scene_cameras();
    names[2] = names[0].clone();
    write_colmap_text(&dir.path().join("sparse/0"), &names, &cams, &pts).unwrap();
    let e = load_scene(dir.path(), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("images.txt") && e.contains("both name the photo") && e.contains(&names[0]),
        "{e}"
    );
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
