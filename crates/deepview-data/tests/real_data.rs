//! Every folder of the shared data directory loads, and the cameras agree with the images (photo-consistency
//! of reprojections proves poses, intrinsics and axis conventions). A missing data directory fails loudly.

use deepview_data::{LoadOptions, Scene, SceneFormat, data_dir, load_scene, pfm::read_pfm};
use deepview_geometry::convention::opengl_c2w_to_pose;
use deepview_geometry::{Camera, DVec2};
use deepview_image::ImageF32;
use std::path::PathBuf;

fn data(sub: &str) -> PathBuf {
    let p = data_dir().join(sub);
    assert!(
        p.is_dir(),
        "test data {} is missing: set DEEPVIEW_DATA to the shared data folder (default <workspace>/../shared/data)",
        p.display()
    );
    p
}

fn load(sub: &str) -> Scene {
    load_scene(&data(sub), &LoadOptions::default()).unwrap_or_else(|e| panic!("{sub}: {e}"))
}

/// Bilinear sample of channel-interleaved RGB at continuous pixel `p` (pixel centres at +0.5); `None` outside.
fn sample(img: &ImageF32, p: DVec2) -> Option<[f32; 3]> {
    let (u, v) = (p.x - 0.5, p.y - 0.5);
    if u < 0.0 || v < 0.0 || u > img.width as f64 - 1.0 || v > img.height as f64 - 1.0 {
        return None;
    }
    let (x0, y0) = (u.floor() as u32, v.floor() as u32);
    let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
    let (fx, fy) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
    let mut out = [0.0; 3];
    for c in 0..3 {
        let a = img.pixel(x0, y0)[c] * (1.0 - fx) + img.pixel(x1, y0)[c] * fx;
        let b = img.pixel(x0, y1)[c] * (1.0 - fx) + img.pixel(x1, y1)[c] * fx;
        out[c] = a * (1.0 - fy) + b * fy;
    }
    Some(out)
}

fn sq(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum()
}

#[test]
fn downscale_on_load_scales_cameras_and_images_together() {
    let full = load("llff/fern");
    let half = load_scene(
        &data("llff/fern"),
        &LoadOptions {
            downscale: 2,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(half.downscale, 2);
    let (a, b) = (full.views[3].camera, half.views[3].camera);
    assert_eq!((b.width, b.height), (a.width / 2, a.height / 2));
    assert_eq!(b.intrinsics, a.intrinsics.scaled(0.5, 0.5));
    assert_eq!(b.pose, a.pose);
    let img = half.load_image(3).unwrap();
    assert_eq!((img.width, img.height), (b.width, b.height));
    assert_eq!(img.data, full.load_image(3).unwrap().downscale(2).data);
    half.check_images().unwrap();
}

#[test]
fn every_data_folder_loads() {
    let fern = load("llff/fern");
    assert_eq!(
        (fern.format, fern.len(), fern.grid, fern.rig_count),
        (SceneFormat::Llff, 20, None, 1)
    );
    // Default: the smallest image folder (images_8, 504x378); focal scaled from the 4032-wide originals.
    assert!(
        fern.views[0]
            .image_path
            .to_string_lossy()
            .contains("images_8")
    );
    let c = fern.views[0].camera;
    assert_eq!((c.width, c.height), (504, 378));
    assert_eq!((c.intrinsics.cx, c.intrinsics.cy), (252.0, 189.0));
    assert!(
        c.intrinsics.fx > 300.0 && c.intrinsics.fx < 600.0,
        "{:?}",
        c.intrinsics
    );
    let (near, far) = fern.near_far().unwrap();
    assert!(near > 0.0 && far > 2.0 * near, "{near} {far}");
    let img = fern.load_image(3).unwrap();
    assert_eq!((img.width, img.height, img.channels), (504, 378, 3));
    let fern4 = load_scene(
        &data("llff/fern"),
        &LoadOptions {
            images: Some("images_4".into()),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(fern4.views[0].camera.width, 1008);
    assert!((fern4.views[0].camera.intrinsics.fx - 2.0 * c.intrinsics.fx).abs() < 1e-9);
    fern.check_images().unwrap();

    let flower = load("llff/flower");
    assert_eq!(flower.len(), 34);
    flower.check_images().unwrap();

    let hci = load("hci/antinous");
    assert_eq!(
        (hci.format, hci.len(), hci.grid),
        (SceneFormat::LightField, 81, Some((9, 9)))
    );
    assert_eq!(
        (hci.views[0].camera.width, hci.views[0].camera.height),
        (512, 512)
    );
    hci.near_far().unwrap();

    let spaces = load("spaces/scene_000");
    assert_eq!(
        (spaces.format, spaces.len(), spaces.rig_count),
        (SceneFormat::Spaces, 16, 1)
    );
    for v in &spaces.views {
        assert_eq!(v.camera.width, 800);
        assert!(
            (460..=500).contains(&v.camera.height),
            "{}",
            v.camera.height
        );
    }
    // The rig is a roughly planar array about 10 cm apart, looking along +z of the world.
    let d01 = (spaces.views[0].camera.center() - spaces.views[1].camera.center()).length();
    assert!(d01 > 0.05 && d01 < 0.2, "{d01}");
    let e = spaces.load_image(0).unwrap_err().to_string();
    assert!(
        e.contains("cam_00/image_000.JPG") && e.contains("does not exist"),
        "{e}"
    );
    assert!(
        spaces
            .near_far()
            .unwrap_err()
            .to_string()
            .contains("near and far")
    );
    let e = load_scene(
        &data("spaces/scene_000"),
        &LoadOptions {
            rig: 1,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("out of range"), "{e}");
}

/// Patches of view `a` swept over depths and reprojected into view `b`: (best error, worst error) per patch.
fn sweep(
    img_a: &ImageF32,
    cam_a: &Camera,
    img_b: &ImageF32,
    cam_b: &Camera,
    near: f64,
    far: f64,
) -> Vec<(f64, f64)> {
    const R: i64 = 5;
    // The most textured patches on a grid (textureless ones match at any depth).
    let mut patches = Vec::new();
    for gy in 1..8 {
        for gx in 1..10 {
            let (cx, cy) = (gx * img_a.width as i64 / 10, gy * img_a.height as i64 / 8);
            let mut vals = Vec::new();
            for dy in -R..=R {
                for dx in -R..=R {
                    vals.push(img_a.pixel((cx + dx) as u32, (cy + dy) as u32)[1] as f64);
                }
            }
            let m = vals.iter().sum::<f64>() / vals.len() as f64;
            let var = vals.iter().map(|v| (v - m).powi(2)).sum::<f64>() / vals.len() as f64;
            patches.push((var, cx, cy));
        }
    }
    patches.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut out = Vec::new();
    for &(_, cx, cy) in patches.iter().take(25) {
        let mut errs = Vec::new();
        for k in 0..64 {
            let inv = 1.0 / far + (1.0 / near - 1.0 / far) * k as f64 / 63.0;
            let mut e = 0.0;
            let mut n = 0;
            for dy in -R..=R {
                for dx in -R..=R {
                    let (x, y) = (cx + dx, cy + dy);
                    let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                    let world = cam_a.unproject(p, 1.0 / inv);
                    if let Some(q) = cam_b.project(world).and_then(|q| sample(img_b, q)) {
                        e += sq(&q, img_a.pixel(x as u32, y as u32));
                        n += 1;
                    }
                }
            }
            if n > (2 * R + 1) * (2 * R + 1) / 2 {
                errs.push(e / n as f64);
            }
        }
        if errs.len() > 32 {
            let best = errs.iter().cloned().fold(f64::INFINITY, f64::min);
            let worst = errs.iter().cloned().fold(0.0, f64::max);
            out.push((best, worst));
        }
    }
    out
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn llff_photo_consistency(sub: &str) {
    let s = load(sub);
    let (near, far) = s.near_far().unwrap();
    let (a, b) = (0, 1);
    let (img_a, img_b) = (s.load_image(a).unwrap(), s.load_image(b).unwrap());
    let (cam_a, cam_b) = (s.views[a].camera, s.views[b].camera);

    // Sanity: the centre pixel of view a at any depth between near and far lands near the image in view b.
    for k in 0..=10 {
        let z = near + (far - near) * k as f64 / 10.0;
        let centre = DVec2::new(cam_a.width as f64 / 2.0, cam_a.height as f64 / 2.0);
        let q = cam_b
            .project(cam_a.unproject(centre, z))
            .expect("in front of view b");
        assert!(
            q.x > -0.25 * cam_b.width as f64
                && q.x < 1.25 * cam_b.width as f64
                && q.y > -0.25 * cam_b.height as f64
                && q.y < 1.25 * cam_b.height as f64,
            "{sub}: centre at depth {z} projects to {q}"
        );
    }

    let good = sweep(&img_a, &cam_a, &img_b, &cam_b, near, far);
    assert!(
        good.len() >= 15,
        "{sub}: only {} usable patches",
        good.len()
    );
    let ratio = median(good.iter().map(|(b, w)| b / w).collect());
    let best_good = median(good.iter().map(|g| g.0).collect());

    // The same sweep with a wrong axis convention (LLFF's [down, right, back] columns read as OpenGL's
    // [right, up, back]: a 90 degree roll of every camera) must match clearly worse.
    let swap = |c: &Camera| -> Camera {
        let rows = deepview_geometry::convention::pose_to_llff_c2w(&c.pose);
        let mut m = [0.0; 16];
        for r in 0..3 {
            m[4 * r..4 * r + 4].copy_from_slice(&rows[r]);
        }
        m[15] = 1.0;
        Camera {
            pose: opengl_c2w_to_pose(&m).unwrap(),
            ..*c
        }
    };
    let bad = sweep(&img_a, &swap(&cam_a), &img_b, &swap(&cam_b), near, far);
    let best_bad = median(bad.iter().map(|g| g.0).collect());
    eprintln!(
        "{sub}: median best/worst {ratio:.3}, best error {best_good:.5} vs wrong axes {best_bad:.5}"
    );
    assert!(
        ratio < 0.25,
        "{sub}: best depth is not much better than the worst (median ratio {ratio})"
    );
    assert!(
        best_good < 0.5 * best_bad,
        "{sub}: correct axes {best_good} not clearly better than wrong {best_bad}"
    );
}

#[test]
fn llff_fern_photo_consistency() {
    llff_photo_consistency("llff/fern");
}

#[test]
fn llff_flower_photo_consistency() {
    llff_photo_consistency("llff/flower");
}

/// HCI disparity sign: warping a corner view into the centre view with the ground-truth disparity must be
/// photo-consistent with our cameras' sign and much worse with the opposite sign.
#[test]
fn hci_disparity_sign_matches_cameras() {
    let root = data("hci/antinous");
    let s = load("hci/antinous");
    let gt = read_pfm(&root.join("gt_disp_lowres.pfm")).unwrap();
    let centre = s.load_image(40).unwrap();
    assert_eq!((gt.width, gt.height), (512, 512));
    let lf = deepview_data::light_field_cameras(9, 9, 512, 512);
    let mut results = Vec::new();
    for corner in [0usize, 8, 72, 80] {
        let img = s.load_image(corner).unwrap();
        let (r, c) = ((corner / 9) as f64 - 4.0, (corner % 9) as f64 - 4.0);
        let (mut e_cam, mut e_plus, mut e_minus, mut n) = (0.0, 0.0, 0.0, 0usize);
        for y in (8..504).step_by(2) {
            for x in (8..504).step_by(2) {
                let d = gt.data[y * 512 + x] as f64;
                let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                let want = centre.pixel(x as u32, y as u32);
                let world = s.views[40].camera.unproject(p, lf.disparity_to_depth(d));
                let via_cam = s.views[corner]
                    .camera
                    .project(world)
                    .and_then(|q| sample(&img, q));
                let plus = sample(&img, p + DVec2::new(c, r) * d);
                let minus = sample(&img, p - DVec2::new(c, r) * d);
                if let (Some(a), Some(b), Some(m)) = (via_cam, plus, minus) {
                    e_cam += sq(&a, want);
                    e_plus += sq(&b, want);
                    e_minus += sq(&m, want);
                    n += 1;
                }
            }
        }
        let (e_cam, e_plus, e_minus) = (e_cam / n as f64, e_plus / n as f64, e_minus / n as f64);
        eprintln!("corner {corner}: cameras {e_cam:.5}, x+d {e_plus:.5}, x-d {e_minus:.5}");
        results.push((e_cam, e_plus, e_minus));
    }
    for (e_cam, e_plus, e_minus) in results {
        let (right, wrong) = if e_plus < e_minus {
            (e_plus, e_minus)
        } else {
            (e_minus, e_plus)
        };
        assert!(
            right < 0.5 * wrong,
            "the disparity sign is ambiguous: {e_plus} vs {e_minus}"
        );
        assert!(
            (e_cam - right).abs() < 0.1 * right + 1e-6,
            "the cameras use the wrong sign: {e_cam} vs {right}"
        );
    }
}

/// Real cameras survive the writers: Spaces models.json and COLMAP text round trips.
#[test]
fn real_cameras_round_trip_through_writers() {
    let spaces = load("spaces/scene_000");
    let dir = tempfile::tempdir().unwrap();
    let paths: Vec<String> = spaces
        .views
        .iter()
        .map(|v| format!("{}.JPG", v.name))
        .collect();
    deepview_data::write_spaces_models(
        &dir.path().join("models.json"),
        &[spaces.cameras()],
        &[paths],
    )
    .unwrap();
    let back = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(back.format, SceneFormat::Spaces);
    for (a, b) in spaces.views.iter().zip(&back.views) {
        assert_eq!(a.name, b.name);
        assert_eq!(
            (a.camera.width, a.camera.height),
            (b.camera.width, b.camera.height)
        );
        assert!((a.camera.intrinsics.fy - b.camera.intrinsics.fy).abs() < 1e-9);
        assert!(
            a.camera
                .pose
                .rotation
                .abs_diff_eq(b.camera.pose.rotation, 1e-12)
        );
        assert!(a.camera.center().abs_diff_eq(b.camera.center(), 1e-12));
    }

    let fern = load("llff/fern");
    let dir = tempfile::tempdir().unwrap();
    let names: Vec<String> = fern
        .views
        .iter()
        .map(|v| format!("{}.png", v.name))
        .collect();
    deepview_data::write_colmap_text(dir.path(), &names, &fern.cameras(), &[]).unwrap();
    let opts = LoadOptions {
        near: Some(1.0),
        far: Some(100.0),
        ..Default::default()
    };
    let back = load_scene(dir.path(), &opts).unwrap();
    assert_eq!(
        (back.format, back.len(), back.near_far().unwrap()),
        (SceneFormat::Colmap, 20, (1.0, 100.0))
    );
    for (a, b) in fern.views.iter().zip(&back.views) {
        assert_eq!(a.camera.intrinsics, b.camera.intrinsics);
        assert!(
            a.camera
                .pose
                .rotation
                .abs_diff_eq(b.camera.pose.rotation, 1e-12)
        );
        assert!(a.camera.center().abs_diff_eq(b.camera.center(), 1e-9));
    }
}
