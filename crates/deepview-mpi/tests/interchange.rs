//! Interchange round trips (LLFF, stereo magnification, compact) on a small MPI built here.

use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths};
use deepview_mpi::interchange::{
    self, ExportFormat, ImportFormat, ImportOptions, compact, read_straight,
};
use deepview_mpi::{Mpi, MpiError, write_mpi};
use std::path::Path;

fn reference() -> Camera {
    let r = DMat3::from_rotation_x(0.1) * DMat3::from_rotation_y(-0.2);
    Camera::new(
        70,
        45,
        Intrinsics::new(60.0, 61.0, 35.5, 22.0),
        Pose::from_center(r, DVec3::new(0.5, -1.0, 2.0)),
    )
}

/// A test MPI: 5 planes with pseudo-random texels, the upper-left block of every plane fully transparent
/// (so the compact export drops tiles), and the near plane transparent except for one square.
fn test_mpi() -> Mpi {
    let cam = reference();
    let depths = plane_depths(2.0, 20.0, 5, PlaneSpacing::InverseDepth).unwrap();
    let mut mpi = Mpi::transparent(cam, depths);
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut s = 12345u32;
    for d in 0..5 {
        let plane = mpi.plane_mut(d);
        for y in 0..h {
            for x in 0..w {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                let transparent = (x < 33 && y < 33) || (d == 4 && !(40..50).contains(&x));
                let a = if transparent {
                    0.0
                } else {
                    ((s % 251) as f32 / 250.0).max(0.05)
                };
                let p = &mut plane[(y * w + x) * 4..(y * w + x) * 4 + 4];
                p[3] = a;
                for k in 0..3 {
                    p[k] = (((s >> (8 * k)) % 256) as f32 / 255.0) * a;
                }
            }
        }
    }
    mpi
}

fn write_test_mpi(dir: &Path) {
    write_mpi(dir, &test_mpi()).unwrap();
}

fn assert_same_layers(a: &Path, b: &Path) {
    let (x, y) = (read_straight(a).unwrap(), read_straight(b).unwrap());
    assert_eq!(x.planes.len(), y.planes.len());
    for (d, (p, q)) in x.planes.iter().zip(&y.planes).enumerate() {
        assert!(p == q, "plane {d} differs");
    }
    assert_eq!(
        (x.camera.width, x.camera.height),
        (y.camera.width, y.camera.height)
    );
    for (u, v) in x.depths.iter().zip(&y.depths) {
        assert!((u - v).abs() < 1e-9 * u, "{u} vs {v}");
    }
}

#[test]
fn llff_round_trip_is_exact_on_layers() {
    let dir = tempfile::tempdir().unwrap();
    let (src, llff, back) = (
        dir.path().join("mpi"),
        dir.path().join("llff"),
        dir.path().join("back"),
    );
    // LLFF keeps one focal and a centred principal point: use such a camera so the camera round-trips too.
    let mut mpi = test_mpi();
    mpi.camera.intrinsics = Intrinsics::centred(60.0, 70, 45);
    write_mpi(&src, &mpi).unwrap();
    let rep = interchange::export(&src, &llff, ExportFormat::Llff).unwrap();
    assert!(rep.warnings.is_empty(), "{:?}", rep.warnings);
    // Layout: metadata.txt "H W D focal", four pose columns, "far near"; mpi.b = D*H*W*4 bytes.
    let meta = std::fs::read_to_string(llff.join("metadata.txt")).unwrap();
    let lines: Vec<&str> = meta.lines().collect();
    assert_eq!(lines.len(), 6);
    assert_eq!(lines[0], "45 70 5 60");
    assert_eq!(
        interchange::describe(&llff).unwrap(),
        (ImportFormat::Llff, 70, 45, 5)
    );
    let far_near: Vec<f64> = lines[5].split(' ').map(|v| v.parse().unwrap()).collect();
    assert!((far_near[0] - 20.0).abs() < 1e-9 && (far_near[1] - 2.0).abs() < 1e-12);
    assert_eq!(
        std::fs::metadata(llff.join("mpi.b")).unwrap().len(),
        5 * 45 * 70 * 4
    );
    // The pose lines are OpenGL camera-to-world columns: line 4 is the camera centre, line 3 "back".
    let col = |i: usize| -> DVec3 {
        let v: Vec<f64> = lines[i].split(' ').map(|v| v.parse().unwrap()).collect();
        DVec3::new(v[0], v[1], v[2])
    };
    assert!((col(4) - mpi.camera.center()).length() < 1e-12);
    let forward_world = mpi.camera.pose.rotation.transpose() * DVec3::Z;
    assert!((col(3) + forward_world).length() < 1e-12);
    assert_eq!(
        interchange::detect_format(&llff).unwrap(),
        ImportFormat::Llff
    );
    interchange::import(&llff, &back, &ImportOptions::default()).unwrap();
    assert_same_layers(&src, &back);
    let (a, b) = (
        read_straight(&src).unwrap().camera,
        read_straight(&back).unwrap().camera,
    );
    assert!(
        a.pose.rotation.abs_diff_eq(b.pose.rotation, 1e-12)
            && a.pose.translation.abs_diff_eq(b.pose.translation, 1e-12)
    );
    assert_eq!(a.intrinsics, b.intrinsics);
    // A non-centred principal point is reported.
    let src2 = dir.path().join("mpi2");
    write_test_mpi(&src2);
    let rep = interchange::export(&src2, &dir.path().join("llff2"), ExportFormat::Llff).unwrap();
    assert!(
        rep.warnings.iter().any(|w| w.contains("principal point")),
        "{:?}",
        rep.warnings
    );
    // Truncated mpi.b.
    let bytes = std::fs::read(llff.join("mpi.b")).unwrap();
    std::fs::write(llff.join("mpi.b"), &bytes[..1000]).unwrap();
    let e = interchange::import(&llff, &dir.path().join("x"), &ImportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("mpi.b") && e.contains("1000 bytes"), "{e}");
    std::fs::write(llff.join("metadata.txt"), "45 70 5\n").unwrap();
    let e = interchange::import(&llff, &dir.path().join("x"), &ImportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("metadata.txt"), "{e}");
}

#[test]
fn stereo_mag_round_trip_is_exact_on_layers() {
    let dir = tempfile::tempdir().unwrap();
    let (src, sm, back) = (
        dir.path().join("mpi"),
        dir.path().join("sm"),
        dir.path().join("back"),
    );
    write_test_mpi(&src);
    interchange::export(&src, &sm, ExportFormat::StereoMag).unwrap();
    for name in [
        "mpi_rgb_00.png",
        "mpi_alpha_04.png",
        "intrinsics.txt",
        "README",
    ] {
        assert!(sm.join(name).is_file(), "{name}");
    }
    // Plane 00 is the farthest: the alpha of our layer 0 is in mpi_alpha_00.png.
    let ours = read_straight(&src).unwrap();
    let a0 = image::open(sm.join("mpi_alpha_00.png"))
        .unwrap()
        .into_luma8()
        .into_raw();
    assert!(
        a0.iter()
            .zip(ours.planes[0].chunks_exact(4))
            .all(|(a, p)| *a == p[3])
    );
    interchange::import(&sm, &back, &ImportOptions::default()).unwrap();
    assert_same_layers(&src, &back);
    assert_eq!(read_straight(&back).unwrap().camera, ours.camera);
    // Without the sidecar: depths from the README flags, identity pose, intrinsics from intrinsics.txt.
    std::fs::remove_file(sm.join("deepview_camera.json")).unwrap();
    let back2 = dir.path().join("back2");
    interchange::import(&sm, &back2, &ImportOptions::default()).unwrap();
    assert_same_layers(&src, &back2);
    assert_eq!(
        read_straight(&back2).unwrap().camera.intrinsics,
        ours.camera.intrinsics
    );
    // Without README either: a clear request for near/far, then explicit bounds work.
    std::fs::remove_file(sm.join("README")).unwrap();
    let e = interchange::import(&sm, &dir.path().join("x"), &ImportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("near and far depths"), "{e}");
    interchange::import(
        &sm,
        &dir.path().join("x"),
        &ImportOptions {
            near_far: Some((2.0, 20.0)),
        },
    )
    .unwrap();
    // A missing alpha layer is named.
    std::fs::remove_file(sm.join("mpi_alpha_02.png")).unwrap();
    let e = interchange::import(
        &sm,
        &dir.path().join("y"),
        &ImportOptions {
            near_far: Some((2.0, 20.0)),
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("mpi_alpha_02.png"), "{e}");
    // A missing colour layer before others is a gap, not the end of the planes.
    std::fs::remove_file(sm.join("mpi_rgb_02.png")).unwrap();
    let e = interchange::import(
        &sm,
        &dir.path().join("z"),
        &ImportOptions {
            near_far: Some((2.0, 20.0)),
        },
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("mpi_rgb_02.png") && e.contains("mpi_alpha_03.png") && e.contains("gap"),
        "{e}"
    );
    // And what `describe` reports of the folders, before any layer is decoded.
    let (f, w, h, d) = interchange::describe(&src).unwrap();
    assert_eq!((f, w, h, d), (ImportFormat::Deepview, 70, 45, 5));
}

#[test]
fn compact_round_trip_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    let (src, cp, back) = (
        dir.path().join("mpi"),
        dir.path().join("compact"),
        dir.path().join("back"),
    );
    write_test_mpi(&src);
    let rep = interchange::export(&src, &cp, ExportFormat::Compact).unwrap();
    // 70x45 with 32x32 tiles: 3x2 tiles per plane; tile (0,0) is transparent everywhere (33x33 block), and the
    // near plane only has content in columns 40..50 (tiles x = 1, y = 0..1).
    let (kept, total) = rep.tiles.unwrap();
    assert_eq!(total, 5 * 6);
    assert_eq!(kept, 4 * 5 + 2);
    assert_eq!(
        interchange::describe(&cp).unwrap(),
        (ImportFormat::Compact, 70, 45, 5)
    );
    let (meta, _) = compact::CompactMeta::read(&cp).unwrap();
    assert_eq!(meta.planes[4], vec![1, 4]);
    assert_eq!(meta.planes[0], vec![1, 2, 3, 4, 5]);
    // Noise texels do not compress, so the files are about as large as the layers' (the dropped tiles are
    // all zero and cheap in PNG too); the saving is in decoded texels uploaded by the viewer: 22 of 30 tiles.
    assert!(rep.bytes > 0 && rep.source_bytes > 0);
    assert_eq!(
        interchange::detect_format(&cp).unwrap(),
        ImportFormat::Compact
    );
    interchange::import(&cp, &back, &ImportOptions::default()).unwrap();
    assert_same_layers(&src, &back);
    assert_eq!(
        read_straight(&back).unwrap().camera,
        read_straight(&src).unwrap().camera
    );
    // Several pages and an odd tile size also round-trip.
    let ours = read_straight(&src).unwrap();
    let cp2 = dir.path().join("compact2");
    compact::write_with_tile(&cp2, &ours, 1).unwrap();
    let (m2, _) = compact::CompactMeta::read(&cp2).unwrap();
    assert!(m2.pages.len() > 1, "{}", m2.pages.len());
    assert_eq!(compact::read(&cp2).unwrap().planes, ours.planes);
    // A missing page is named.
    std::fs::remove_file(cp2.join("tiles_001.png")).unwrap();
    let e = compact::read(&cp2).unwrap_err().to_string();
    assert!(e.contains("tiles_001.png"), "{e}");
}

#[test]
fn bad_mpi_folders_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("mpi");
    write_test_mpi(&src);
    std::fs::remove_file(src.join("layer_003.png")).unwrap();
    for f in [
        ExportFormat::Llff,
        ExportFormat::StereoMag,
        ExportFormat::Compact,
    ] {
        let e = interchange::export(&src, &dir.path().join("out"), f).unwrap_err();
        assert!(e.to_string().contains("layer_003.png"), "{e}");
    }
    write_test_mpi(&src);
    deepview_image::write_png_u8(&src.join("layer_002.png"), 4, 4, 4, &[0; 64]).unwrap();
    let e = interchange::export(&src, &dir.path().join("out"), ExportFormat::Compact)
        .unwrap_err()
        .to_string();
    assert!(e.contains("layer_002.png") && e.contains("4x4"), "{e}");
    let e = interchange::detect_format(dir.path())
        .unwrap_err()
        .to_string();
    assert!(e.contains("no known MPI format"), "{e}");
    let e: MpiError = "webm".parse::<ExportFormat>().unwrap_err();
    assert!(e.to_string().contains("llff"));
}
