//! `deepview render`: ground truth into a dataset view or a camera, and bad MPI files and flags.

use crate::common::{copy_dir, deepview, fails_with, s, succeeds, synth_grid};
use std::path::Path;

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
        "--data",
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
    // A 40x30 camera JSON with the pose `camera_from_world`, and a render of the MPI into one.
    let write_cam = |name: &str, camera_from_world: serde_json::Value| {
        let cam = serde_json::json!({"width": 40, "height": 30, "fx": 50.0, "fy": 50.0, "cx": 20.0,
            "cy": 15.0, "camera_from_world": camera_from_world});
        let path = tmp.path().join(name);
        std::fs::write(&path, cam.to_string()).unwrap();
        path
    };
    let render_to = |camera: &Path, out: &Path| {
        deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--camera",
            s(camera),
            "--out",
            s(out),
        ])
    };
    let cam_path = write_cam("cam.json", meta["camera_from_world"].clone());
    let out = tmp.path().join("c.png");
    assert!(render_to(&cam_path, &out).status.success());
    assert_eq!(deepview_image::image_size(&out).unwrap(), (40, 30));
    // The same camera turned round (rows 0 and 2 of camera-from-world negated: 180 degrees about
    // its y axis) sees none of the MPI: written, with a warning saying so.
    let m = meta["camera_from_world"].as_array().unwrap();
    let away: Vec<f64> = (0..16)
        .map(|i| {
            let v = m[i].as_f64().unwrap();
            if i / 4 == 0 || i / 4 == 2 { -v } else { v }
        })
        .collect();
    let away_path = write_cam("away.json", away.into());
    let render_err = |camera: &Path, out: &Path| {
        let o = render_to(camera, out);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let err = render_err(&away_path, &tmp.path().join("away.png"));
    assert!(
        err.contains("warning: the MPI covers 0.0% of this view"),
        "{err}"
    );
    let err = render_err(&cam_path, &out);
    assert!(!err.contains("warning"), "{err}");
    // A render named like a photo of the user's is refused, the photo untouched; deepview's own
    // render (c.png, just written again above) is replaced.
    let photo = tmp.path().join("photo.png");
    let original = deepview_data::data_dir().join("llff/fern/images_8/image000.png");
    std::fs::copy(&original, &photo).unwrap();
    fails_with(
        &render_to(&cam_path, &photo),
        &["photo.png exists and is a PNG image deepview did not write"],
    );
    assert_eq!(
        std::fs::read(&photo).unwrap(),
        std::fs::read(&original).unwrap()
    );
    let o = deepview(&["bench", "render", "--mpi", s(&gt), "--repeats", "2"]);
    let line: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(line["fps"].as_f64().unwrap() > 0.0 && line["planes"] == 8);
    // `info --camera N` writes view N's camera JSON: rendering into it equals `--data S --view N`.
    let o = deepview(&["info", "--data", s(&scene), "--camera", "4"]);
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
        &deepview(&["info", "--data", s(&scene), "--camera", "99"]),
        &["view 99 is out of range", "9 views"],
    );
    // The old spellings, a bare dataset folder and `render --scene`, are usage errors naming `--data`.
    fails_with(
        &deepview(&["info", s(&scene), "--camera", "4"]),
        &["hint: folders are named by their option", "--data DIR"],
    );
    let old = tmp.path().join("v4_old.png");
    fails_with(
        &deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--scene",
            s(&scene),
            "--view",
            "4",
            "--out",
            s(&old),
        ]),
        &["'--scene'", "hint: a dataset is --data DIR"],
    );
    assert!(!old.exists());
}

#[test]
fn bad_mpi_files_and_flags_give_clear_errors_and_exit_code_2() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let grid = synth_grid(t);
    let gt = grid.join("ground_truth_mpi");
    let out = t.join("o.png");
    let render = |mpi: &Path| deepview(&["render", "--mpi", s(mpi), "--out", s(&out)]);
    succeeds(&render(&gt));

    // Truncated mpi.json.
    let bad = copy_dir(&gt, &t.join("mpi_truncated"));
    let text = std::fs::read_to_string(gt.join("mpi.json")).unwrap();
    std::fs::write(bad.join("mpi.json"), &text[..text.len() / 2]).unwrap();
    fails_with(&render(&bad), &["mpi.json", "not valid mpi.json", "EOF"]);

    // A layer PNG of the wrong size.
    let bad = copy_dir(&gt, &t.join("mpi_layer_size"));
    deepview_image::write_png(
        &bad.join("layer_002.png"),
        &deepview_image::ImageF32::new(50, 20, 4),
    )
    .unwrap();
    fails_with(&render(&bad), &["layer_002.png", "50x20", "mpi.json says"]);

    // Too few planes for a synthetic scene.
    for planes in ["0", "1"] {
        let o = deepview(&[
            "synth",
            "--out",
            s(&t.join(format!("synth_{planes}"))),
            "--grid",
            "2",
            "--width",
            "16",
            "--height",
            "16",
            "--planes",
            planes,
        ]);
        fails_with(&o, &["--planes", "at least 2", &format!("got {planes}")]);
    }
}

/// `compact` writes an MPI with fewer planes that renders the same reference view (to 8-bit rounding of
/// the written layers), and `eval --compact` scores the compacted MPI.
#[test]
fn compact_keeps_the_reference_view_with_fewer_planes() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = synth_grid(tmp.path());
    let mpi = tmp.path().join("mpi");
    succeeds(&deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--inputs",
        "0,2,6,8",
        "--planes",
        "16",
        "--out",
        s(&mpi),
    ]));
    let small = tmp.path().join("small");
    let out = succeeds(&deepview(&[
        "compact",
        "--mpi",
        s(&mpi),
        "--out",
        s(&small),
        "--merge-coverage",
        "1",
        "--max-run",
        "4",
    ]));
    assert!(out.contains("of 16"), "{out}");
    let a = deepview_mpi::read_mpi::<f32>(&mpi).unwrap();
    let b = deepview_mpi::read_mpi::<f32>(&small).unwrap();
    // Runs of at most 4 planes, each covering at most the whole image.
    assert!(
        b.planes() >= a.planes().div_ceil(4) && b.planes() < a.planes(),
        "{} planes",
        b.planes()
    );
    assert!(b.depths.windows(2).all(|w| w[0] > w[1]));
    let (ra, rb) = (
        deepview_mpi::render(&a, &a.camera),
        deepview_mpi::render(&b, &a.camera),
    );
    let diff = ra
        .data
        .iter()
        .zip(&rb.data)
        .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
    assert!(diff < 4.0 / 255.0, "reference view changed by {diff}");
    // Its output is an MPI like any other: refused over a dataset, scored by eval.
    fails_with(
        &deepview(&["compact", "--mpi", s(&mpi), "--out", s(&scene)]),
        &["--out"],
    );
    // A compact *export* (tiles) is another format: the commands that read our MPI folders say how to
    // convert it, instead of "cannot read mpi.json".
    let tiles = tmp.path().join("tiles");
    succeeds(&deepview(&[
        "export",
        "--mpi",
        s(&mpi),
        "--out",
        s(&tiles),
        "--format",
        "compact",
    ]));
    let again = tmp.path().join("again");
    for args in [
        vec!["compact", "--mpi", s(&tiles), "--out", s(&again)],
        vec![
            "export",
            "--mpi",
            s(&tiles),
            "--out",
            s(&again),
            "--format",
            "llff",
        ],
        vec!["diff", s(&tiles), s(&mpi)],
        vec!["bench", "render", "--mpi", s(&tiles)],
    ] {
        fails_with(
            &deepview(&args),
            &["Compact format", "deepview import --mpi"],
        );
    }
    assert!(!again.exists());
    let e = succeeds(&deepview(&[
        "eval",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--targets",
        "4",
        "--inputs",
        "0,2,6,8",
        "--compact",
    ]));
    assert!(e.contains("mean"), "{e}");
    // `infer --compact` writes the compacted MPI at once.
    let direct = tmp.path().join("direct");
    let out = succeeds(&deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--inputs",
        "0,2,6,8",
        "--planes",
        "16",
        "--compact",
        "--merge-coverage",
        "1",
        "--out",
        s(&direct),
    ]));
    assert!(out.contains("compacted from 16 planes"), "{out}");
    let c = deepview_mpi::read_mpi::<f32>(&direct).unwrap();
    assert!(c.planes() >= 4 && c.planes() < 16, "{} planes", c.planes());
}

/// An MP4 named with a colon in the current folder is written (ffmpeg read `.a:` of its relative
/// temporary as a protocol: "Protocol not found"); a GIF over 50 frames/s, which browsers slow to 10,
/// is refused before any work.
#[test]
fn video_names_with_a_colon_and_gif_frame_rates() {
    if std::process::Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_err()
    {
        eprintln!("ffmpeg not on PATH: the MP4 case is not exercised");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let gt = synth_grid(tmp.path()).join("ground_truth_mpi");
    succeeds(&crate::common::deepview_in(
        tmp.path(),
        &[
            "render",
            "--mpi",
            s(&gt),
            "--path",
            "swing",
            "--frames",
            "3",
            "--out",
            "a:b.mp4",
        ],
    ));
    assert!(std::fs::metadata(tmp.path().join("a:b.mp4")).unwrap().len() > 100);
    let gif = tmp.path().join("fast.gif");
    fails_with(
        &deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--path",
            "swing",
            "--frames",
            "3",
            "--fps",
            "60",
            "--out",
            s(&gif),
        ]),
        &["fast.gif", "0.0016 to 50 frames per second", "--fps"],
    );
    assert!(!gif.exists());
}
