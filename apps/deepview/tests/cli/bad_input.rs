//! Bad input across commands (render, psv, info): clear errors and exit code 2.

use crate::common::{deepview, fails_with, s, synth_grid};

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
            "--data",
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
            "--data",
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
            "--data",
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
    fails_with(
        &deepview(&["info", "--data", s(&llff)]),
        &["poses_bounds.npy"],
    );
    let colmap = tmp.path().join("colmap");
    std::fs::create_dir_all(colmap.join("sparse/0")).unwrap();
    std::fs::write(
        colmap.join("sparse/0/cameras.txt"),
        "1 PINHOLE 10 10 not-a-number 5 5 5\n",
    )
    .unwrap();
    std::fs::write(colmap.join("sparse/0/images.txt"), "").unwrap();
    fails_with(&deepview(&["info", "--data", s(&colmap)]), &["cameras.txt"]);

    // Out-of-range view.
    deepview_image::write_png(
        &scene.join("input_Cam002.png"),
        &deepview_image::ImageF32::new(96, 64, 3),
    )
    .unwrap();
    fails_with(
        &deepview(&[
            "psv",
            "--data",
            s(&scene),
            "--view",
            "99",
            "--out",
            s(&tmp.path().join("p")),
        ]),
        &["out of range"],
    );
}

/// Counts no benchmark can run are refused before any work (4097 planes was a panic, a million views
/// 40 s and 9 GB of synthetic views before a refusal), and an `mpi.json` that is a pipe is an error
/// at once, not a wait for a writer.
#[test]
fn odd_inputs_are_refused_at_once_saying_what_to_do() {
    fails_with(
        &deepview(&["bench", "net", "--size", "8x8", "--planes", "4097"]),
        &["--planes", "4097 planes", "at most 4096"],
    );
    fails_with(
        &deepview(&["bench", "net", "--size", "32x24", "--views", "1000000"]),
        &["--views", "at most 256"],
    );
    fails_with(
        &deepview(&["bench", "train", "--planes", "5000"]),
        &["at most 4096"],
    );
    let tmp = tempfile::tempdir().unwrap();
    let mpi = tmp.path().join("mpi");
    std::fs::create_dir(&mpi).unwrap();
    let made = std::process::Command::new("mkfifo")
        .arg(mpi.join("mpi.json"))
        .status()
        .unwrap();
    assert!(made.success());
    let out = tmp.path().join("o.png");
    fails_with(
        &deepview(&["render", "--mpi", s(&mpi), "--out", s(&out)]),
        &["mpi.json", "not a regular file"],
    );
    // A pipe in place of a dataset's file, or of an imported MPI's, is refused at once (each waited for
    // a writer for ever). Under `timeout`, so that a regression fails instead of hanging the suite.
    let scene = crate::common::synth_grid(tmp.path());
    let fifo = |p: &std::path::Path| {
        let _ = std::fs::remove_file(p);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        let made = std::process::Command::new("mkfifo")
            .arg(p)
            .status()
            .unwrap();
        assert!(made.success());
    };
    let timed = |args: &[&str]| {
        std::process::Command::new("timeout")
            .arg("120")
            .arg(env!("CARGO_BIN_EXE_deepview"))
            .args(args)
            .output()
            .unwrap()
    };
    let sm = tmp.path().join("sm");
    crate::common::succeeds(&deepview(&[
        "export",
        "--mpi",
        s(&scene.join("ground_truth_mpi")),
        "--format",
        "stereo-mag",
        "--out",
        s(&sm),
    ]));
    std::fs::remove_file(sm.join("deepview_camera.json")).unwrap();
    for (i, file) in [
        "transforms.json",
        "poses_bounds.npy",
        "models.json",
        "sparse/0/images.txt",
        "parameters.cfg",
        "README",
        "intrinsics.txt",
    ]
    .into_iter()
    .enumerate()
    {
        let dir = if i >= 5 {
            sm.clone()
        } else {
            tmp.path().join(format!("fifo-{i}"))
        };
        match file {
            "sparse/0/images.txt" => {
                std::fs::create_dir_all(dir.join("sparse/0")).unwrap();
                std::fs::write(dir.join("sparse/0/cameras.txt"), "").unwrap();
            }
            "parameters.cfg" => {
                crate::common::copy_dir(&scene, &dir);
            }
            _ => {}
        }
        fifo(&dir.join(file));
        let o = if i >= 5 {
            timed(&[
                "import",
                "--mpi",
                s(&dir),
                "--out",
                s(&tmp.path().join("imp")),
            ])
        } else {
            timed(&["info", "--data", s(&dir)])
        };
        fails_with(
            &o,
            &[file.rsplit('/').next().unwrap(), "not a regular file"],
        );
        if i >= 5 {
            std::fs::remove_file(dir.join(file)).unwrap();
            std::fs::write(dir.join(file), "").unwrap();
        }
    }
    // --alpha with a camera path (its frames are RGB) is refused, not ignored.
    let frames = tmp.path().join("frames");
    fails_with(
        &deepview(&[
            "render",
            "--mpi",
            s(&scene.join("ground_truth_mpi")),
            "--path",
            "spiral",
            "--frames",
            "3",
            "--alpha",
            "--out",
            s(&frames),
        ]),
        &["--alpha", "leave --alpha out"],
    );
    assert!(!frames.exists());
    // A light-field rig at another size would read back with other cameras (its reader derives them
    // from the image size): refused, where it wrote a dataset whose views did not match its images.
    let small = tmp.path().join("small-rig");
    fails_with(
        &deepview(&[
            "synth",
            "--data",
            s(&scene),
            "--downscale",
            "2",
            "--out",
            s(&small),
        ]),
        &["cannot hold this rig's cameras", "--out-format transforms"],
    );
    assert!(!small.exists());
    // Another format than the rig's own (or transforms) is refused as such, before any check of what
    // that format would need of the views (the hint was about --downscale).
    fails_with(
        &deepview(&[
            "synth",
            "--data",
            s(&scene),
            "--out-format",
            "llff",
            "--out",
            s(&small),
        ]),
        &["can be written as light-field or transforms", "not llff"],
    );
    assert!(!small.exists());
    // A dataset view's options with a path, and a --path's options with a camera path file or with
    // one view, are refused, not ignored.
    let gt_mpi = scene.join("ground_truth_mpi");
    let cam_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../docs/examples/fern_camera_path.json");
    for (args, needles) in [
        (
            vec!["--path", "spiral", "--view", "3", "--near", "5"],
            vec!["--view, --near need a dataset"],
        ),
        (
            vec![
                "--camera-path",
                s(&cam_path),
                "--frames",
                "5",
                "--fps",
                "60",
            ],
            vec!["--frames, --fps shape a --path only", "leave them out"],
        ),
        (vec!["--radius", "0.1"], vec!["--path"]),
        (
            vec!["--data", s(&scene), "--view", "3", "--frames", "90"],
            vec!["--frames shapes a --path", "leave it out"],
        ),
    ] {
        let mut full = vec!["render", "--mpi", s(&gt_mpi), "--out", s(&frames)];
        full.extend(args);
        fails_with(&deepview(&full), &needles);
        assert!(!frames.exists());
    }
    // An MPI where a dataset is expected, an MPI's mpi.json for its folder, a folder not there.
    let gt = scene.join("ground_truth_mpi");
    fails_with(
        &deepview(&["info", "--data", s(&gt)]),
        &["it is an MPI folder", "deepview render --mpi"],
    );
    fails_with(
        &deepview(&["render", "--mpi", s(&gt.join("mpi.json")), "--out", s(&out)]),
        &["is an MPI's mpi.json: give the MPI's folder"],
    );
    // A --near beyond the dataset's far bound says where each came from.
    let fern = crate::common::data().join("llff/fern");
    fails_with(
        &deepview(&["info", "--data", s(&fern), "--near", "1000"]),
        &["--near 1000, far 80.0021 (the dataset's)", "give --far too"],
    );
    // A device no build has is an error for every method (psv-mean ignored it).
    let o = deepview(&[
        "eval",
        "--data",
        s(&fern),
        "--images",
        "images_8",
        "--method",
        "psv-mean",
        "--device",
        "foo",
        "--targets",
        "0",
    ]);
    fails_with(&o, &["device `foo`", "unknown device"]);
    // An export the format cannot hold names the output, not the temporary folder it is written in.
    let one = tmp.path().join("one_plane");
    std::fs::create_dir(&one).unwrap();
    let mut meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(gt.join("mpi.json")).unwrap()).unwrap();
    meta["depths"] = serde_json::json!([meta["depths"][0]]);
    meta["layers"] = serde_json::json!([meta["layers"][0]]);
    std::fs::write(one.join("mpi.json"), meta.to_string()).unwrap();
    let layer = meta["layers"][0].as_str().unwrap();
    std::fs::copy(gt.join(layer), one.join(layer)).unwrap();
    let exported = tmp.path().join("exported");
    let o = deepview(&[
        "export",
        "--mpi",
        s(&one),
        "--out",
        s(&exported),
        "--format",
        "llff",
    ]);
    fails_with(&o, &["exported: LLFF's format needs at least 2 planes"]);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("deepview-tmp"));
    assert!(!exported.exists());
    // Dataset options given to a generated grid are refused, not ignored.
    let grid = tmp.path().join("odd_grid");
    fails_with(
        &deepview(&[
            "synth",
            "--grid",
            "2",
            "--width",
            "16",
            "--height",
            "16",
            "--downscale",
            "4",
            "--images",
            "foo",
            "--out",
            s(&grid),
        ]),
        &["--images, --downscale shape the cameras read from a dataset"],
    );
    assert!(!grid.exists());
    for cmd in ["render", "view", "diff"] {
        let missing = tmp.path().join("no_such_mpi");
        let args: Vec<&str> = match cmd {
            "diff" => vec!["diff", s(&missing), s(&gt)],
            c => vec![c, "--mpi", s(&missing), "--out", s(&out)],
        };
        let args: Vec<&str> = if cmd == "view" {
            args[..3].to_vec()
        } else {
            args
        };
        fails_with(&deepview(&args), &["no_such_mpi", "does not exist"]);
    }
}
