//! `deepview demo`: the README's first command.

use crate::common::{deepview, fails_with, s, succeeds};

/// The README's first command: the whole pipeline on the built-in scene (the slow `optimize` baseline
/// skipped). Everything it announces is there, every method is scored, and the shipped model beats both
/// baselines on the held-out views (the scene is deterministic, and none of the training scenes is it;
/// BENCHMARKS.md has the figures, `optimize` included).
#[test]
fn demo_makes_everything_it_announces() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("demo");
    let stdout = succeeds(&deepview(&["demo", "--out", s(&out), "--no-optimize"]));
    for f in [
        "mpi/mpi.json",
        "mpi/layer_007.png",
        "scene/ground_truth_mpi/mpi.json",
        "novel_views/view_05.png",
        "novel_views/view_10_ground_truth.png",
        "depth/depth_color.png",
        "depth/depth_disparity16.png",
        "spiral.gif",
        "eval.json",
        "eval.md",
    ] {
        assert!(out.join(f).is_file(), "{f} missing; stdout: {stdout}");
    }
    // `--planes auto`: the count follows the grid's disparity and is recorded in mpi.json.
    let mpi = deepview_mpi::read_mpi::<f32>(&out.join("mpi")).unwrap();
    let (meta, _) = deepview_mpi::MpiMeta::read(&out.join("mpi")).unwrap();
    let rule = meta.planes_rule.expect("planes_rule in mpi.json");
    assert_eq!(rule.rule, "auto");
    let disparity = rule.max_disparity_px.unwrap();
    assert_eq!(
        mpi.planes(),
        ((disparity - 1e-9).ceil() as usize + 1).clamp(8, 256),
        "{disparity} px"
    );
    let reports: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).unwrap()).unwrap();
    let ssim = |method: &str| {
        reports
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["method"] == method)
            .unwrap_or_else(|| panic!("no {method} in eval.json"))["results"]["ssim"]
            .as_f64()
            .unwrap()
    };
    let (nearest, psv, learned) = (ssim("nearest"), ssim("psv-mean"), ssim("deepview"));
    assert!(
        learned > psv && psv > nearest,
        "deepview {learned} vs nearest {nearest}, psv-mean {psv}"
    );
    // It says how to look at the MPI in the browser.
    let view_hint = format!("-- view --mpi {}", out.join("mpi").display());
    assert!(stdout.contains(&view_hint), "{view_hint:?} not in {stdout}");
    // It replaces its own earlier output (every file in every subfolder is one it writes), but not a
    // user's file inside one of them.
    let note = out.join("renders").join("notes.txt");
    std::fs::write(&note, "mine").unwrap();
    fails_with(
        &deepview(&["demo", "--out", s(&out), "--no-optimize"]),
        &["renders/notes.txt", "refusing"],
    );
    assert_eq!(std::fs::read_to_string(&note).unwrap(), "mine");
    std::fs::remove_file(&note).unwrap();
    succeeds(&deepview(&["demo", "--out", s(&out), "--no-optimize"]));
}

/// Weights for a fixed number of views other than the demo's four: the error says so in the demo's
/// terms (no hint to pass `--inputs`, which the demo does not take), and nothing is left behind.
#[test]
fn demo_names_weights_for_another_view_count() {
    let tmp = tempfile::tempdir().unwrap();
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../weights/cpu");
    let weights = tmp.path().join("five");
    std::fs::create_dir(&weights).unwrap();
    std::fs::copy(
        shipped.join("model.safetensors"),
        weights.join("model.safetensors"),
    )
    .unwrap();
    let config = std::fs::read_to_string(shipped.join("config.json")).unwrap();
    assert!(config.contains("\"views\": null"), "{config}");
    std::fs::write(
        weights.join("config.json"),
        config.replace("\"views\": null", "\"views\": 5"),
    )
    .unwrap();
    let out = tmp.path().join("demo");
    let run = deepview(&[
        "demo",
        "--out",
        s(&out),
        "--no-optimize",
        "--weights",
        s(&weights),
    ]);
    fails_with(&run, &["exactly 5 input views", "4 corner views"]);
    assert!(!String::from_utf8_lossy(&run.stderr).contains("--inputs"));
    assert!(!out.exists());
}
