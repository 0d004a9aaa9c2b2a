//! The real binary, run as a user would: outputs, and clear errors with exit code 2 on bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn deepview(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_deepview"))
        .args(args)
        .output()
        .expect("binary runs")
}

fn data() -> PathBuf {
    let d = deepview_data::data_dir();
    assert!(
        d.join("llff/fern").is_dir(),
        "shared data missing at {} (set DEEPVIEW_DATA)",
        d.display()
    );
    d
}

/// Asserts a clean failure: exit code 2, no panic, and every `needle` in stderr.
fn fails_with(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not in: {err}");
    }
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn synth_grid(dir: &Path) -> PathBuf {
    let out = dir.join("grid");
    let o = deepview(&[
        "synth",
        "--out",
        s(&out),
        "--grid",
        "3",
        "--width",
        "96",
        "--height",
        "64",
        "--planes",
        "8",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

#[test]
fn synth_then_render_ground_truth_into_a_view() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = synth_grid(tmp.path());
    let view = tmp.path().join("v4.png");
    let gt = scene.join("ground_truth_mpi");
    let o = deepview(&[
        "render",
        "--mpi",
        s(&gt),
        "--scene",
        s(&scene),
        "--view",
        "4",
        "--out",
        s(&view),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a = deepview_image::read_image(&view, 3).unwrap();
    let b = deepview_image::read_image(&scene.join("input_Cam004.png"), 3).unwrap();
    let mse: f64 = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / a.data.len() as f64;
    let psnr = -10.0 * mse.log10();
    assert!(psnr > 38.0, "PSNR {psnr:.2}");
    // Depth maps and a camera JSON render work on the same MPI.
    let depth = tmp.path().join("depth");
    assert!(
        deepview(&["depth", "--mpi", s(&gt), "--out", s(&depth)])
            .status
            .success()
    );
    assert!(
        depth.join("depth_color.png").is_file() && depth.join("depth_disparity16.png").is_file()
    );
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(gt.join("mpi.json")).unwrap()).unwrap();
    let cam = serde_json::json!({"width": 40, "height": 30, "fx": 50.0, "fy": 50.0, "cx": 20.0, "cy": 15.0,
        "camera_from_world": meta["camera_from_world"]});
    let cam_path = tmp.path().join("cam.json");
    std::fs::write(&cam_path, cam.to_string()).unwrap();
    let out = tmp.path().join("c.png");
    assert!(
        deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--camera",
            s(&cam_path),
            "--out",
            s(&out)
        ])
        .status
        .success()
    );
    assert_eq!(deepview_image::image_size(&out).unwrap(), (40, 30));
    let o = deepview(&["bench", "render", "--mpi", s(&gt), "--repeats", "2"]);
    let line: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(line["fps"].as_f64().unwrap() > 0.0 && line["planes"] == 8);
    // `info --camera N` writes view N's camera JSON: rendering into it equals `--scene S --view N`.
    let o = deepview(&["info", s(&scene), "--camera", "4"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cam4 = tmp.path().join("cam4.json");
    std::fs::write(&cam4, &o.stdout).unwrap();
    let via_json = tmp.path().join("v4_json.png");
    let o = deepview(&[
        "render",
        "--mpi",
        s(&gt),
        "--camera",
        s(&cam4),
        "--out",
        s(&via_json),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read(&via_json).unwrap(),
        std::fs::read(&view).unwrap()
    );
    fails_with(
        &deepview(&["info", s(&scene), "--camera", "99"]),
        &["view 99 is out of range", "9 views"],
    );
}

#[test]
fn psv_of_a_fern_view_onto_its_own_camera_is_the_image() {
    let tmp = tempfile::tempdir().unwrap();
    let fern = data().join("llff/fern");
    let out = tmp.path().join("psv");
    let o = deepview(&[
        "psv",
        s(&fern),
        "--images",
        "images_8",
        "--view",
        "5",
        "--planes",
        "4",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = deepview_image::read_image(&fern.join("images_8/image005.png"), 3).unwrap();
    for d in 0..4 {
        let plane = deepview_image::read_image(&out.join(format!("psv_{d:03}.png")), 4).unwrap();
        assert_eq!(plane.to_rgb(), img, "plane {d}");
        assert!(plane.data.chunks_exact(4).all(|p| p[3] == 1.0));
    }
}

#[test]
fn bad_input_gives_clear_errors_and_exit_code_2() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = synth_grid(tmp.path());
    let gt = scene.join("ground_truth_mpi");
    let out = tmp.path().join("o.png");

    // A missing layer of an MPI.
    let broken = tmp.path().join("broken_mpi");
    std::fs::create_dir_all(&broken).unwrap();
    for f in std::fs::read_dir(&gt).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, broken.join(f.file_name().unwrap())).unwrap();
    }
    std::fs::remove_file(broken.join("layer_003.png")).unwrap();
    fails_with(
        &deepview(&["render", "--mpi", s(&broken), "--out", s(&out)]),
        &["layer_003.png"],
    );

    // Zero planes.
    let json = std::fs::read_to_string(gt.join("mpi.json")).unwrap();
    let mut meta: serde_json::Value = serde_json::from_str(&json).unwrap();
    meta["depths"] = serde_json::json!([]);
    meta["layers"] = serde_json::json!([]);
    std::fs::write(broken.join("mpi.json"), meta.to_string()).unwrap();
    fails_with(
        &deepview(&["render", "--mpi", s(&broken), "--out", s(&out)]),
        &["mpi.json", "zero planes"],
    );
    fails_with(
        &deepview(&[
            "psv",
            s(&scene),
            "--planes",
            "0",
            "--out",
            s(&tmp.path().join("p")),
        ]),
        &["plane"],
    );

    // Malformed camera JSON, and a non-finite pose value.
    let cam = tmp.path().join("cam.json");
    std::fs::write(&cam, "{\"width\": 10,").unwrap();
    fails_with(
        &deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--camera",
            s(&cam),
            "--out",
            s(&out),
        ]),
        &["cam.json"],
    );
    std::fs::write(
        &cam,
        r#"{"width":10,"height":10,"fx":10,"fy":10,"cx":5,"cy":5,"camera_from_world":[1,0,0,1e999,0,1,0,0,0,0,1,0,0,0,0,1]}"#,
    )
    .unwrap();
    fails_with(
        &deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--camera",
            s(&cam),
            "--out",
            s(&out),
        ]),
        &["cam.json", "out of range"],
    );

    // A missing image, and an image of the wrong size.
    std::fs::remove_file(scene.join("input_Cam002.png")).unwrap();
    fails_with(
        &deepview(&[
            "psv",
            s(&scene),
            "--view",
            "2",
            "--out",
            s(&tmp.path().join("p")),
        ]),
        &["input_Cam002.png"],
    );
    deepview_image::write_png(
        &scene.join("input_Cam002.png"),
        &deepview_image::ImageF32::new(50, 20, 3),
    )
    .unwrap();
    fails_with(
        &deepview(&[
            "psv",
            s(&scene),
            "--view",
            "2",
            "--out",
            s(&tmp.path().join("p")),
        ]),
        &["input_Cam002.png"],
    );

    // A malformed npy (LLFF) and a malformed COLMAP model.
    let llff = tmp.path().join("llff");
    std::fs::create_dir_all(llff.join("images")).unwrap();
    std::fs::write(llff.join("poses_bounds.npy"), b"\x93NUMPY\x01\x00garbage").unwrap();
    fails_with(&deepview(&["info", s(&llff)]), &["poses_bounds.npy"]);
    let colmap = tmp.path().join("colmap");
    std::fs::create_dir_all(colmap.join("sparse/0")).unwrap();
    std::fs::write(
        colmap.join("sparse/0/cameras.txt"),
        "1 PINHOLE 10 10 not-a-number 5 5 5\n",
    )
    .unwrap();
    std::fs::write(colmap.join("sparse/0/images.txt"), "").unwrap();
    fails_with(&deepview(&["info", s(&colmap)]), &["cameras.txt"]);

    // Out-of-range view.
    deepview_image::write_png(
        &scene.join("input_Cam002.png"),
        &deepview_image::ImageF32::new(96, 64, 3),
    )
    .unwrap();
    fails_with(
        &deepview(&[
            "psv",
            s(&scene),
            "--view",
            "99",
            "--out",
            s(&tmp.path().join("p")),
        ]),
        &["out of range"],
    );
}
