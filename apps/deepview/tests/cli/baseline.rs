//! `deepview infer --method psv-mean|nearest`: the baselines' MPIs rendered into held-out and input views;
//! `--planes auto`; the old spellings (`deepview baseline`, bare folders, ...) are usage errors.

use crate::common::{deepview, fails_with, s, succeeds, synth_grid};
use std::path::Path;

/// Renders `mpi` into view `view` of `scene` and returns the PSNR (dB) against that view's image.
fn psnr_of_render(tmp: &Path, mpi: &Path, scene: &Path, view: usize, truth: &Path) -> f64 {
    let out = tmp.join(format!("render_v{view}.png"));
    let o = deepview(&[
        "render",
        "--mpi",
        s(mpi),
        "--data",
        s(scene),
        "--view",
        &view.to_string(),
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a = deepview_image::read_image(&out, 3).unwrap();
    let b = deepview_image::read_image(truth, 3).unwrap();
    deepview_metrics::psnr(&a, &b).unwrap()
}

#[test]
fn baseline_mpis_render_held_out_and_input_views() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = synth_grid(tmp.path());

    // psv-mean from the four corners of the 3 x 3 grid, scored on the held-out centre view.
    let psv = tmp.path().join("psv_mpi");
    let o = deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--inputs",
        "0,2,6,8",
        "--planes",
        "12",
        "--out",
        s(&psv),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("psv_mpi") && stdout.contains("12 planes"),
        "{stdout}"
    );
    let mpi = deepview_mpi::read_mpi::<f32>(&psv).unwrap();
    assert_eq!(mpi.planes(), 12);
    let truth = scene.join("input_Cam004.png");
    let psnr = psnr_of_render(tmp.path(), &psv, &scene, 4, &truth);
    // For scale: one corner input reprojected through a single plane (`nearest` of view 0), and the exact
    // ground-truth MPI. Measured: psv-mean 19.5 dB, corner 13.0 dB, ground truth 58.5 dB.
    let corner = tmp.path().join("corner_mpi");
    let o = deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "nearest",
        "--inputs",
        "0",
        "--out",
        s(&corner),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let psnr_corner = psnr_of_render(tmp.path(), &corner, &scene, 4, &truth);
    assert!(
        psnr > 17.0 && psnr > psnr_corner + 4.0,
        "psv-mean PSNR {psnr:.2} dB, corner view {psnr_corner:.2} dB"
    );

    // nearest with the default inputs (the 4 views nearest the grid's centre): the centre view itself, one
    // opaque plane in its camera, so rendering into that camera is an identity warp.
    let near = tmp.path().join("nearest_mpi");
    let o = deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "nearest",
        "--out",
        s(&near),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("view 4"), "{stdout}");
    let mpi = deepview_mpi::read_mpi::<f32>(&near).unwrap();
    assert_eq!(mpi.planes(), 1);
    assert!(mpi.layers.chunks_exact(4).all(|t| t[3] == 1.0));
    // Measured: identical (infinite PSNR); 50 dB allows for the 8-bit round trip of the layer.
    let psnr = psnr_of_render(tmp.path(), &near, &scene, 4, &truth);
    assert!(psnr > 50.0, "nearest PSNR {psnr:.2} dB");

    // Bad flags fail cleanly.
    let bad = tmp.path().join("bad_mpi");
    fails_with(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--planes",
            "0",
            "--out",
            s(&bad),
        ]),
        &["plane", "got 0"],
    );
    fails_with(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "nearest",
            "--inputs",
            "4,9",
            "--out",
            s(&bad),
        ]),
        &["view index 9 out of range", "9 views"],
    );
    // Another method's option is refused when given, even at its default value (`--steps 300` to
    // psv-mean, `--aggregate 0` to nearest had passed as if left out).
    for (method, option, value, owner) in [
        (
            "psv-mean",
            "--steps",
            "300",
            "optimize's gradient descent only",
        ),
        ("nearest", "--aggregate", "0", "psv-mean's agreement only"),
    ] {
        fails_with(
            &deepview(&[
                "infer",
                "--data",
                s(&scene),
                "--method",
                method,
                option,
                value,
                "--out",
                s(&bad),
            ]),
            &[option, owner],
        );
    }
    assert!(!bad.exists());
}

/// `--planes auto` (the default): the count from the cameras' disparity, printed and stored in mpi.json;
/// clamped by the memory budget; an explicit count wins. The old spellings (`deepview baseline`, bare
/// folders) are usage errors with a hint.
#[test]
fn planes_auto_follows_the_scene_and_old_spellings_are_usage_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = synth_grid(tmp.path());
    // A wider stated disparity range than the grid's own +-2 px (HCI `parameters.cfg`): enough planes
    // (17) for the memory budget to cut the count below the rule's.
    std::fs::write(
        scene.join("parameters.cfg"),
        "[meta]\ndisp_min = -4\ndisp_max = 4\n",
    )
    .unwrap();
    let mpi = tmp.path().join("psv_auto");
    let o = deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--inputs",
        "0,2,6,8",
        "--out",
        s(&mpi),
    ]);
    succeeds(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("planes: auto -> ") && err.contains("memory budget: "),
        "{err}"
    );
    let (meta, _) = deepview_mpi::MpiMeta::read(&mpi).unwrap();
    let rule = meta.planes_rule.unwrap();
    let disparity = rule.max_disparity_px.unwrap();
    assert!(disparity > 1.0, "{disparity}");
    assert!([0, 2, 6, 8].contains(&rule.view.unwrap()));
    let planes = ((disparity - 1e-9).ceil() as usize + 1).clamp(8, 256);
    assert_eq!(meta.depths.len(), planes);
    assert!(err.contains(&format!("auto -> {planes} ")), "{err}");

    // A budget too small even for the smallest count is refused, naming the budget that fits; with that
    // budget, fewer planes than the rule's, and mpi.json says why.
    let small = tmp.path().join("psv_small");
    let run = |budget: &str| {
        deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--inputs",
            "0,2,6,8",
            "--max-memory",
            budget,
            "--out",
            s(&small),
        ])
    };
    let o = run("1MiB");
    fails_with(&o, &["8 planes", "--max-memory"]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    let least = err
        .rsplit("--max-memory ")
        .next()
        .unwrap()
        .trim()
        .to_string();
    succeeds(&run(&least));
    let (meta, _) = deepview_mpi::MpiMeta::read(&small).unwrap();
    assert!(meta.depths.len() >= 8 && meta.depths.len() < planes);
    assert_eq!(
        meta.planes_rule.unwrap().limited_by.as_deref(),
        Some("memory budget")
    );
    fails_with(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--planes",
            "weights",
            "--out",
            s(&small),
        ]),
        &["--planes weights needs a learned model"],
    );

    // An explicit count wins over the rule.
    let explicit = tmp.path().join("psv_explicit");
    succeeds(&deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--planes",
        "6",
        "--out",
        s(&explicit),
    ]));
    assert_eq!(
        deepview_mpi::read_mpi::<f32>(&explicit).unwrap().planes(),
        6
    );
    let (meta, _) = deepview_mpi::MpiMeta::read(&explicit).unwrap();
    assert_eq!(meta.planes_rule.unwrap().rule, "explicit");
    let llff_new = tmp.path().join("llff_new");
    succeeds(&deepview(&[
        "export",
        "--mpi",
        s(&explicit),
        "--out",
        s(&llff_new),
        "--format",
        "llff",
    ]));
    assert!(llff_new.join("mpi.b").is_file());
    let back = tmp.path().join("back");
    succeeds(&deepview(&[
        "import",
        "--mpi",
        s(&llff_new),
        "--out",
        s(&back),
    ]));
    assert_eq!(deepview_mpi::read_mpi::<f32>(&back).unwrap().planes(), 6);

    // The old spellings are usage errors (exit 2) whose hint names the new one, and write nothing: the
    // verbs `baseline` and `optimize`, a bare dataset folder, a bare MPI folder and output.
    let old = tmp.path().join("psv_old");
    let folders = "folders are named by their option";
    let old_spellings: Vec<(Vec<&str>, &str)> = vec![
        (
            vec![
                "baseline",
                "--data",
                s(&scene),
                "--method",
                "psv-mean",
                "--planes",
                "6",
                "--out",
                s(&old),
            ],
            "`deepview baseline --method M` is now `deepview infer --method M`",
        ),
        (
            vec![
                "optimize",
                "--data",
                s(&scene),
                "--planes",
                "6",
                "--out",
                s(&old),
            ],
            "`deepview optimize` is now `deepview infer --method optimize`",
        ),
        (
            vec![
                "baseline",
                s(&scene),
                "--method",
                "psv-mean",
                "--planes",
                "6",
                "--out",
                s(&old),
            ],
            "is now `deepview infer --method M`",
        ),
        (
            vec![
                "infer",
                s(&scene),
                "--method",
                "psv-mean",
                "--planes",
                "6",
                "--out",
                s(&old),
            ],
            folders,
        ),
        (
            vec!["export", s(&explicit), s(&old), "--format", "llff"],
            folders,
        ),
        (
            vec!["export", "--mpi", s(&explicit), s(&old), "--format", "llff"],
            folders,
        ),
        (vec!["import", s(&llff_new), "--out", s(&old)], folders),
    ];
    for (args, hint) in &old_spellings {
        let o = deepview(args);
        fails_with(&o, &["hint: ", hint]);
        assert!(!old.exists(), "{args:?} wrote {}", old.display());
    }
    // Both spellings at once is an error too: the bare folder is refused, with the same hint.
    fails_with(
        &deepview(&["info", s(&scene), "--data", s(&scene)]),
        &["unexpected argument", folders],
    );
}
