//! The synthetic scene's ground-truth MPI against exact renders, and rigs written in their own formats.

use deepview_data::{LoadOptions, SceneFormat, data_dir, light_field_cameras, load_scene};
use deepview_geometry::{
    Camera, DMat3, DVec3, PlaneSpacing, Pose, ReferenceOptions, plane_depths, reference_camera,
};
use deepview_image::ImageF32;
use deepview_mpi::{read_mpi, render};
use deepview_synth::{Rig, SynthOptions, SynthScene, synthesize};

/// PSNR of the RGB of `a` (4-channel premultiplied render, opaque here) against `b` (RGB), ignoring a border.
fn psnr(a: &ImageF32, b: &ImageF32, border: u32) -> f64 {
    let (w, h) = (b.width, b.height);
    let mut se = 0.0f64;
    let mut n = 0usize;
    for y in border..h - border {
        for x in border..w - border {
            let p = a.pixel(x, y);
            let q = b.pixel(x, y);
            for k in 0..3 {
                se += ((p[k] - q[k]) as f64).powi(2);
                n += 1;
            }
        }
    }
    10.0 * (1.0 / (se / n as f64)).log10()
}

#[test]
fn ground_truth_mpi_renders_unseen_views_like_the_scene() {
    let lf = light_field_cameras(4, 4, 320, 240);
    let cams = lf.cameras();
    let (near, far) = lf.depth_bounds(-2.0, 2.0);
    let depths = plane_depths(near, far, 32, PlaneSpacing::InverseDepth).unwrap();
    let reference = reference_camera(
        &cams,
        &ReferenceOptions {
            cover: Some((near, far)),
            max_margin: 0.5,
            ..Default::default()
        },
    )
    .unwrap();
    let scene = SynthScene::generate(reference, &depths, 7);
    assert!(
        scene.layers.len() >= 5,
        "background, cards, disc, bars, pane"
    );
    let mpi = scene.ground_truth_mpi(&depths).unwrap();
    // Unseen cameras: between grid positions, slightly rotated, different intrinsics and size.
    let novel = [
        Camera::new(
            300,
            220,
            cams[5].intrinsics,
            Pose::from_center(DMat3::from_rotation_y(0.01), DVec3::new(0.3, -0.2, 0.1)),
        ),
        Camera::new(
            320,
            240,
            cams[0].intrinsics.scaled(1.1, 1.1),
            Pose::from_center(DMat3::from_rotation_x(-0.02), DVec3::new(-0.7, 0.45, -0.3)),
        ),
    ];
    for cam in novel {
        let direct = scene.render(&cam, 1);
        let from_mpi = render(&mpi, &cam);
        // Every pixel is covered (the background is opaque and the reference camera covers the rig).
        assert!(from_mpi.data.chunks_exact(4).all(|p| p[3] > 0.999));
        let p = psnr(&from_mpi, &direct, 2);
        assert!(p >= 40.0, "PSNR {p:.2} dB");
        // And a wrong MPI (planes shifted by one) is clearly worse: the test can fail.
        let mut wrong = mpi.clone();
        wrong.depths = plane_depths(near * 0.9, far * 0.9, 32, PlaneSpacing::InverseDepth).unwrap();
        assert!(psnr(&render(&wrong, &cam), &direct, 2) < p - 5.0);
    }
}

#[test]
fn grid_rig_round_trip_as_light_field() {
    let dir = tempfile::tempdir().unwrap();
    let opts = SynthOptions {
        rig: Rig::Grid {
            side: 3,
            width: 64,
            height: 48,
        },
        planes: 8,
        ..Default::default()
    };
    let out = synthesize(dir.path(), &opts).unwrap();
    let scene = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.format, SceneFormat::LightField);
    assert_eq!(scene.views.len(), 9);
    for (v, c) in scene.views.iter().zip(&out.cameras) {
        assert!(
            v.camera
                .pose
                .translation
                .abs_diff_eq(c.pose.translation, 1e-9)
        );
        assert!((v.camera.intrinsics.cx - c.intrinsics.cx).abs() < 1e-9);
    }
    let img = scene.load_image(4).unwrap();
    let direct = out.scene.render(&out.cameras[4], 1);
    let err = img
        .data
        .iter()
        .zip(&direct.data)
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(err <= 0.5 / 255.0 + 1e-6, "8-bit quantisation only: {err}");
    let gt = read_mpi::<f32>(&dir.path().join("ground_truth_mpi")).unwrap();
    assert_eq!(gt.planes(), 8);
    assert!(dir.path().join("synth.json").is_file());
    // The folder loads with the depth range it was rendered with (written as the light field's
    // disparity range), which is -2..+2 px per grid step: the ground truth's first and last planes.
    let (near, far) = scene.near_far().unwrap();
    assert!(
        (near / out.near_far.0 - 1.0).abs() < 1e-9,
        "{near} vs {:?}",
        out.near_far
    );
    assert!(
        (far / out.near_far.1 - 1.0).abs() < 1e-9,
        "{far} vs {:?}",
        out.near_far
    );
    assert!((gt.depths[0] / far - 1.0).abs() < 1e-6 && (gt.depths[7] / near - 1.0).abs() < 1e-6);
    let lf = light_field_cameras(3, 3, 64, 48);
    assert!((lf.depth_to_disparity(near) - 2.0).abs() < 1e-9);
    assert!((lf.depth_to_disparity(far) + 2.0).abs() < 1e-9);
}

#[test]
fn real_spaces_rig_round_trip() {
    let rig = data_dir().join("spaces/scene_000");
    assert!(
        rig.join("models.json").is_file(),
        "data missing: {} (set DEEPVIEW_DATA)",
        rig.display()
    );
    let dir = tempfile::tempdir().unwrap();
    let opts = SynthOptions {
        rig: Rig::Dataset {
            path: rig.clone(),
            options: LoadOptions::default(),
        },
        planes: 16,
        ..Default::default()
    };
    let out = synthesize(dir.path(), &opts).unwrap();
    assert_eq!(out.format, SceneFormat::Spaces);
    let original = load_scene(&rig, &LoadOptions::default()).unwrap();
    let written = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(written.views.len(), 16);
    for (a, b) in original.views.iter().zip(&written.views) {
        assert_eq!(
            (a.camera.width, a.camera.height),
            (b.camera.width, b.camera.height)
        );
        assert!(
            a.camera
                .pose
                .rotation
                .abs_diff_eq(b.camera.pose.rotation, 1e-9)
        );
        assert!(a.camera.center().abs_diff_eq(b.camera.center(), 1e-9));
        assert!((a.camera.intrinsics.fy - b.camera.intrinsics.fy).abs() < 1e-9);
    }
    // The ground-truth MPI reproduces a rig view it was not fitted to (it was never fitted to any).
    let img = written.load_image(9).unwrap();
    let from_mpi = render(&out.ground_truth, &written.views[9].camera);
    let p = psnr(&from_mpi, &img, 4);
    assert!(p >= 38.0, "PSNR {p:.2}");
}

#[test]
fn llff_rig_round_trip() {
    let rig = data_dir().join("llff/fern");
    assert!(
        rig.join("poses_bounds.npy").is_file(),
        "data missing: {}",
        rig.display()
    );
    let dir = tempfile::tempdir().unwrap();
    let load = LoadOptions {
        images: Some("images_8".into()),
        ..Default::default()
    };
    let opts = SynthOptions {
        rig: Rig::Dataset {
            path: rig.clone(),
            options: load.clone(),
        },
        planes: 8,
        ..Default::default()
    };
    synthesize(dir.path(), &opts).unwrap();
    let original = load_scene(&rig, &load).unwrap();
    let written = load_scene(dir.path(), &load).unwrap();
    assert_eq!(written.format, SceneFormat::Llff);
    assert_eq!(original.views.len(), written.views.len());
    for (a, b) in original.views.iter().zip(&written.views) {
        assert!(
            a.camera
                .pose
                .rotation
                .abs_diff_eq(b.camera.pose.rotation, 1e-9)
        );
        assert!(a.camera.center().abs_diff_eq(b.camera.center(), 1e-9));
        assert!((a.camera.intrinsics.fx - b.camera.intrinsics.fx).abs() < 1e-6);
    }
    written.load_image(3).unwrap();
}

#[test]
fn colmap_rig_round_trip() {
    // A COLMAP rig made from grid cameras, then a synthetic scene written through it.
    let rig_dir = tempfile::tempdir().unwrap();
    let cams = light_field_cameras(2, 3, 48, 32).cameras();
    let names: Vec<String> = (0..cams.len()).map(|i| format!("v{i}.png")).collect();
    let sparse = rig_dir.path().join("sparse/0");
    std::fs::create_dir_all(&sparse).unwrap();
    deepview_data::write_colmap_text(&sparse, &names, &cams, &[]).unwrap();
    for n in &names {
        deepview_image::write_png(
            &rig_dir.path().join("images").join(n),
            &ImageF32::new(48, 32, 3),
        )
        .unwrap_or_else(|_| {
            std::fs::create_dir_all(rig_dir.path().join("images")).unwrap();
            deepview_image::write_png(
                &rig_dir.path().join("images").join(n),
                &ImageF32::new(48, 32, 3),
            )
            .unwrap();
        });
    }
    let dir = tempfile::tempdir().unwrap();
    let load = LoadOptions {
        near: Some(2.0),
        far: Some(20.0),
        ..Default::default()
    };
    let opts = SynthOptions {
        rig: Rig::Dataset {
            path: rig_dir.path().into(),
            options: load,
        },
        planes: 8,
        ..Default::default()
    };
    let out = synthesize(dir.path(), &opts).unwrap();
    assert_eq!(out.near_far, (2.0, 20.0));
    // The written COLMAP model has 3D points, so it carries its own depth bounds.
    let written = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(written.format, SceneFormat::Colmap);
    // It reads back with the bounds it was rendered with (the reader's percentile rule, given the
    // depths it turns into them), surface points besides.
    let (n, f) = written.near_far().unwrap();
    assert!(
        (n - 2.0).abs() < 1e-9 && (f - 20.0).abs() < 1e-8,
        "read back as {n}..{f}"
    );
    let model = deepview_data::read_colmap(&dir.path().join("sparse/0")).unwrap();
    assert!(
        model.points.len() > 2 * cams.len() + 100,
        "{}",
        model.points.len()
    );
    // Bounds closer than the reader's 0.9 / 1.1 margins cannot be written: refused, not written wrong.
    let narrow = SynthOptions {
        near_far: Some((20.0, 23.0)),
        ..opts.clone()
    };
    let other = tempfile::tempdir().unwrap();
    let e = synthesize(other.path(), &narrow).unwrap_err().to_string();
    assert!(e.contains("far must exceed 1.2222 x near"), "{e}");
    for (a, b) in cams.iter().zip(&written.views) {
        assert!(
            a.pose
                .translation
                .abs_diff_eq(b.camera.pose.translation, 1e-9)
        );
    }
    written.load_image(5).unwrap();
}
