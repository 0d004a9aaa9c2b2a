//! `deepview train --resume` needs nothing repeated: the run's config.json keeps each dataset with the
//! options it was loaded with.

use crate::common::{deepview, fails_with, grid, s, succeeds, synth_grid};
use std::path::Path;

/// A tiny run on `grid`: the cpu preset, L1 loss, 8x8 crops, 4 planes, a checkpoint every step.
fn train(runs: &Path, name: &str, steps: u32, extra: &[&str]) -> String {
    let steps = steps.to_string();
    let mut args = vec![
        "train",
        "--runs",
        s(runs),
        "--name",
        name,
        "--steps",
        &steps,
        "--quiet",
    ];
    args.extend_from_slice(extra);
    let o = deepview(&args);
    succeeds(&o);
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `train --runs RUNS --name NAME --resume` with `extra`: the output, for the test to judge.
fn resume(runs: &Path, name: &str, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["train", "--runs", s(runs), "--name", name, "--resume"];
    args.extend_from_slice(extra);
    deepview(&args)
}

fn start_args(grid: &Path) -> Vec<&str> {
    vec![
        "--data",
        s(grid),
        "--preset",
        "cpu",
        "--loss",
        "l1",
        "--crop",
        "8",
        "--planes",
        "4",
        "--checkpoint-every",
        "1",
        "--seed",
        "4",
    ]
}

/// The run `name`'s config.json.
fn run_config(runs: &Path, name: &str) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(runs.join(name).join("config.json")).unwrap())
        .unwrap()
}

/// The losses of `metrics.jsonl` by step.
fn losses(run: &Path) -> Vec<(u64, f64)> {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            (v["step"].as_u64().unwrap(), v["loss"].as_f64().unwrap())
        })
        .collect()
}

#[test]
fn resume_reads_the_data_with_the_options_of_the_run() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let runs = tmp.path().join("runs");
    let mut half = start_args(&grid);
    half.extend(["--downscale", "2"]);

    // Two steps straight, at half size.
    train(&runs, "straight", 2, &half);
    let straight = losses(&runs.join("straight"));
    assert_eq!(straight.len(), 2);

    // One step at half size, then resumed with nothing but the name: the same images, so the same step 2.
    train(&runs, "resumed", 1, &half);
    let cfg = run_config(&runs, "resumed");
    let spec = &cfg["train"]["data"][0];
    assert_eq!(spec["path"], s(&grid));
    assert_eq!(spec["downscale"], 2);
    let err = train(&runs, "resumed", 2, &["--resume"]);
    assert!(err.contains("resuming"), "{err}");
    assert_eq!(losses(&runs.join("resumed")), straight);

    // A scene flag that disagrees with the run's is refused; the same value is fine.
    let grid_dir = s(&grid);
    let refused = resume(&runs, "resumed", &["--steps", "3", "--downscale", "4"]);
    fails_with(
        &refused,
        &["--downscale", grid_dir, "cannot change on resume"],
    );
    train(&runs, "resumed", 3, &["--resume", "--downscale", "2"]);

    // A config.json in the old format is refused on resume (exit 2), naming the file, with or without
    // the scene flags, and the run is left as it was: bare dataset paths (from before the load options
    // were kept), and a sampling field missing (from before it existed).
    for (name, edit) in [("old-paths", "data"), ("old-sampling", "window_context")] {
        train(&runs, name, 1, &half);
        let run = runs.join(name);
        let path = run.join("config.json");
        let mut cfg: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        if edit == "data" {
            cfg["train"]["data"] = serde_json::json!([s(&grid)]);
        } else {
            let sample = cfg["train"]["sample"].as_object_mut().unwrap();
            assert!(sample.remove(edit).is_some(), "{edit} not in {cfg}");
        }
        std::fs::write(&path, serde_json::to_string_pretty(&cfg).unwrap()).unwrap();
        let before = std::fs::read(run.join("metrics.jsonl")).unwrap();
        for extra in [&[][..], &["--downscale", "2"][..]] {
            let mut args = vec![
                "train",
                "--runs",
                s(&runs),
                "--name",
                name,
                "--resume",
                "--steps",
                "2",
                "--quiet",
            ];
            args.extend_from_slice(extra);
            // The value or field the old format has wrong is named too.
            let what = if edit == "data" { s(&grid) } else { edit };
            fails_with(
                &deepview(&args),
                &[s(&path), "invalid run configuration", what],
            );
        }
        assert_eq!(std::fs::read(run.join("metrics.jsonl")).unwrap(), before);
        assert_eq!(losses(&run).len(), 1);
    }
}

/// `--max-width W` gives each dataset its own factor: the smallest that brings its images to at most W
/// pixels wide (96 px at 48 -> 2, 40 px -> 1, 100 px -> 3), kept in config.json and used on resume.
#[test]
fn max_width_downscales_each_dataset_by_its_own_factor() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        synth_grid(tmp.path()),
        grid(tmp.path(), "small", 40, 32),
        grid(tmp.path(), "large", 100, 64),
    );
    let runs = tmp.path().join("runs");
    let mut args = start_args(&a);
    // `--data` takes several folders at once (what `--data dir/{a,b}` expands to in a shell).
    args.extend(["--data", s(&b), s(&c), "--max-width", "48"]);
    train(&runs, "mixed", 1, &args);
    let cfg = run_config(&runs, "mixed");
    let factors: Vec<u64> = (0..3)
        .map(|i| cfg["train"]["data"][i]["downscale"].as_u64().unwrap())
        .collect();
    assert_eq!(factors, [2, 1, 3]);
    train(&runs, "mixed", 2, &["--resume"]);
    assert_eq!(losses(&runs.join("mixed")).len(), 2);
    // One rule or the other, not both.
    let mut both = start_args(&a);
    both.extend([
        "--max-width",
        "48",
        "--downscale",
        "2",
        "--name",
        "x",
        "--runs",
        s(&runs),
    ]);
    let mut full = vec!["train"];
    full.extend(both);
    fails_with(&deepview(&full), &["--max-width", "--downscale"]);
}

/// `--init W --preset P` grows the weights into the larger preset: the grown model computes the same
/// MPI, so its first loss (before any update, the same tuple) is the first loss of the weights as they
/// are, up to the training window (a third net widens it, and the gradient components render the views
/// from the window only), and far from a fresh model's; a preset they cannot grow into is refused with
/// exit code 2 before any data is read.
#[test]
fn init_with_a_larger_preset_grows_the_weights() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let runs = tmp.path().join("runs");
    let weights = concat!(env!("CARGO_MANIFEST_DIR"), "/../../weights/cpu");
    let common = [
        "--data",
        s(&grid),
        "--init",
        weights,
        "--loss",
        "l1",
        "--crop",
        "8",
        "--planes",
        "4",
        "--seed",
        "4",
    ];
    train(&runs, "as-is", 1, &common);
    let mut grown_args = common.to_vec();
    grown_args.extend(["--preset", "cpu-large"]);
    train(&runs, "grown", 1, &grown_args);
    let cfg = run_config(&runs, "grown");
    assert_eq!(cfg["model"]["name"], "cpu-large");
    assert_eq!(cfg["model"]["updates"], 2);
    let fresh_args: Vec<&str> = common
        .iter()
        .copied()
        .filter(|a| *a != "--init" && *a != weights)
        .chain(["--preset", "cpu-large"])
        .collect();
    train(&runs, "fresh", 1, &fresh_args);
    let first = |name: &str| losses(&runs.join(name))[0].1;
    let (a, b, c) = (first("as-is"), first("grown"), first("fresh"));
    assert!(
        (a - b).abs() <= 2e-3 * a.abs() && (a - c).abs() > 10.0 * (a - b).abs(),
        "first losses: as is {a}, grown {b}, fresh cpu-large {c}"
    );

    let mut refused_args = vec!["train", "--runs", s(&runs), "--name", "refused"];
    refused_args.extend_from_slice(&common);
    refused_args.extend(["--preset", "paper-kalantari"]);
    fails_with(
        &deepview(&refused_args),
        &["cannot grow", "max-pool stages", "--preset paper-kalantari"],
    );
}

/// What a resumed session changes (a new total of steps, another data list) becomes the run's own: a
/// later `--resume` with nothing but the name goes on with it (it forgot the new total before, and was
/// refused as below the step reached).
#[test]
fn resume_keeps_what_it_changed() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let runs = tmp.path().join("runs");
    train(&runs, "r", 2, &start_args(&grid));
    let more = ["--resume", "--data", s(&grid), "synthetic:two-planes"];
    train(&runs, "r", 3, &more);
    let cfg = run_config(&runs, "r");
    assert_eq!(cfg["train"]["steps"], 3);
    let data = cfg["train"]["data"].as_array().unwrap();
    assert_eq!(data.len(), 2, "{data:?}");
    assert_eq!(data[1]["path"], "synthetic:two-planes");
    let o = resume(&runs, "r", &["--quiet"]);
    succeeds(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("at step 3 of 3"), "{err}");
    // Nothing ran: no speed or mean loss of zero steps in its summary.
    assert!(
        err.contains("done at step 3 (0 steps this session, 0 skipped)\n"),
        "{err}"
    );
    // A plain resume writes nothing new.
    let again = run_config(&runs, "r");
    assert_eq!(again, cfg);
    assert_eq!(losses(&runs.join("r")).last().unwrap().0, 3);
}

/// `--resume --steps N` below the run's step, and a run whose every checkpoint is damaged, are refused
/// with the reason (they used to say "resuming at step 4 of 2" and exit 0, or start over from step 0).
#[test]
fn resume_refuses_fewer_steps_and_damaged_checkpoints() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let runs = tmp.path().join("runs");
    train(&runs, "r", 3, &start_args(&grid));
    let o = resume(&runs, "r", &["--steps", "2"]);
    fails_with(&o, &["--steps 2", "(3)"]);
    // Every checkpoint loses its model file: refused, naming them; nothing is removed.
    let cks = runs.join("r/checkpoints");
    let mut names = Vec::new();
    for e in std::fs::read_dir(&cks).unwrap() {
        let p = e.unwrap().path();
        for f in std::fs::read_dir(&p).unwrap() {
            let f = f.unwrap().path();
            if f.extension().is_some_and(|x| x == "bpk") {
                std::fs::write(&f, b"").unwrap();
            }
        }
        names.push(p.file_name().unwrap().to_string_lossy().into_owned());
    }
    assert!(!names.is_empty());
    let o = resume(&runs, "r", &["--steps", "5"]);
    let mut needles = vec!["no checkpoint", "complete"];
    needles.extend(names.iter().map(String::as_str));
    fails_with(&o, &needles);
    assert_eq!(std::fs::read_dir(&cks).unwrap().count(), names.len());
}

/// `--validate-every N` scores the held-out views of the posed real datasets (both protocols) at the
/// checkpoints past each multiple of N, into validation.jsonl; light-field grids and procedural scenes are
/// not in it; the scores are those `eval --method deepview --weights CK` gives for that checkpoint.
#[test]
fn validation_scores_checkpoints_into_validation_jsonl() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let runs = tmp.path().join("runs");
    let fern = crate::common::data().join("llff/fern");
    let err = train(
        &runs,
        "v",
        4,
        &[
            "--data",
            s(&fern),
            s(&grid),
            "synthetic:procedural",
            "--images",
            "images_8",
            "--loss",
            "l1",
            "--crop",
            "8",
            "--planes",
            "4",
            "--checkpoint-every",
            "2",
            "--validate-every",
            "3",
        ],
    );
    assert!(err.contains("validation at step 4 (1 scene)"), "{err}");
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(runs.join("v/validation.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // The first checkpoint (step 2), then the first past 3 (step 4).
    let steps: Vec<u64> = lines.iter().map(|l| l["step"].as_u64().unwrap()).collect();
    assert_eq!(steps, [2, 2, 4, 4]);
    for l in &lines {
        assert!(l["scene"].as_str().unwrap().ends_with("llff/fern"));
        let ssim = l["ssim"].as_f64().unwrap();
        assert!(ssim > 0.0 && ssim <= 1.0, "{l}");
    }
    // The same number as eval of that checkpoint under the same protocol.
    let ck = runs.join("v/checkpoints/step-0000004");
    let o = crate::common::deepview(&[
        "eval",
        "--data",
        s(&fern),
        "--images",
        "images_8",
        "--downscale",
        "2",
        "--method",
        "deepview",
        "--weights",
        s(&ck),
        "--inputs",
        "spread:3",
        "--crop",
        "0",
    ]);
    let table = succeeds(&o);
    let want = lines[3]["ssim"].as_f64().unwrap();
    assert!(
        table.contains(&format!("{want:.4}")),
        "validation {want:.4} not in eval's table:\n{table}"
    );
    // --validate-every is kept in the run's config: a resume goes on validating (its first checkpoint).
    let err = train(&runs, "v", 6, &["--resume"]);
    assert!(err.contains("validation at step 6"), "{err}");
    let steps: Vec<u64> = std::fs::read_to_string(runs.join("v/validation.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["step"]
                .as_u64()
                .unwrap()
        })
        .collect();
    assert_eq!(steps, [2, 2, 4, 4, 6, 6]);
}

/// A run started with a relative `--data` resumes on the same dataset from any folder (it was read against
/// the current folder, so a resume elsewhere trained on another scene of the same name without a word).
#[test]
fn resume_elsewhere_reads_the_datasets_the_run_started_with() {
    use crate::common::deepview_in;
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    let grid_a = grid(&a, "scene", 64, 48);
    assert!(grid_a.is_dir());
    // B has a different scene of the same name: 2x2 views, too few for the run's 3 inputs.
    succeeds(&deepview_in(
        &b,
        &[
            "synth", "--out", "scene", "--grid", "2", "--width", "32", "--height", "24",
            "--planes", "4",
        ],
    ));
    let start = [
        "train",
        "--data",
        "scene",
        "--name",
        "r",
        "--steps",
        "2",
        "--loss",
        "l1",
        "--crop",
        "8",
        "--planes",
        "4",
        "--views",
        "3",
        "--checkpoint-every",
        "1",
        "--quiet",
    ];
    succeeds(&deepview_in(&a, &start));
    let runs = a.join("runs");
    let o = deepview_in(
        &b,
        &[
            "train",
            "--runs",
            s(&runs),
            "--name",
            "r",
            "--resume",
            "--steps",
            "3",
            "--quiet",
        ],
    );
    succeeds(&o);
    assert_eq!(losses(&runs.join("r")).len(), 3);
}

/// A file standing where a run keeps its checkpoints is named as such (the error was "File exists"
/// about the run folder), and nothing of the run is changed.
#[test]
fn a_file_in_place_of_the_checkpoints_folder_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let g = synth_grid(tmp.path());
    let runs = tmp.path().join("runs");
    train(&runs, "r", 1, &start_args(&g));
    let ck = runs.join("r").join("checkpoints");
    std::fs::remove_dir_all(&ck).unwrap();
    std::fs::write(&ck, "a file").unwrap();
    let o = resume(&runs, "r", &["--steps", "2", "--quiet"]);
    fails_with(&o, &["checkpoints", "is a file"]);
    assert_eq!(std::fs::read_to_string(&ck).unwrap(), "a file");
}

/// Too many input views for a scene: the error counts its training views, mentions held-out views only
/// when some are held out, and names a --views that fits.
#[test]
fn too_many_views_names_a_count_that_fits() {
    let tmp = tempfile::tempdir().unwrap();
    let g = synth_grid(tmp.path());
    let runs = tmp.path().join("runs");
    let start = |name: &str, extra: &[&str]| {
        let mut args = vec!["train", "--runs", s(&runs), "--name", name, "--quiet"];
        args.extend(start_args(&g));
        args.extend_from_slice(extra);
        deepview(&args)
    };
    // 9 views, views 0 and 8 held out (every 8th): 7 to train on.
    let o = start("a", &["--views", "7"]);
    fails_with(
        &o,
        &[
            "has 7 training views",
            "--holdout-every 0",
            "pass --views 6",
        ],
    );
    let o = start("b", &["--views", "9", "--holdout-every", "0"]);
    fails_with(&o, &["has 9 training views,", "pass --views 8"]);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("held out"));
    // The count it names fits.
    train(
        &runs,
        "c",
        1,
        &[&start_args(&g)[..], &["--views", "6"]].concat(),
    );
    // A range is quoted as given and kept a range.
    let o = start("d", &["--views", "2..7"]);
    fails_with(&o, &["--views 2..7", "pass --views 2..6"]);
    // On --resume --views is the run's own: the message says what can change instead. A 2 x 2 grid
    // has 3 training views (view 0 held out).
    let small = tmp.path().join("small");
    succeeds(&deepview(&[
        "synth",
        "--out",
        s(&small),
        "--grid",
        "2",
        "--width",
        "48",
        "--height",
        "32",
    ]));
    let o = resume(&runs, "c", &["--steps", "2", "--data", s(&small)]);
    fails_with(
        &o,
        &[
            "--views 6",
            "has 3 training views (1 more is held out",
            "start a new --name",
        ],
    );
    assert!(!String::from_utf8_lossy(&o.stderr).contains("--holdout-every 0"));
}

/// A damaged checkpoint is replaced when training reaches its step again; one that also holds a file
/// of the user's is moved aside whole (the file kept, a warning naming it) and training goes on.
#[test]
fn a_damaged_checkpoint_holding_a_users_file_is_set_aside() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let runs = tmp.path().join("runs");
    train(&runs, "r", 3, &start_args(&grid));
    let cks = runs.join("r/checkpoints");
    let (step2, step3) = (cks.join("step-0000002"), cks.join("step-0000003"));
    for ck in [&step2, &step3] {
        std::fs::write(ck.join("model.bpk"), b"").unwrap();
    }
    std::fs::write(step2.join("notes.txt"), b"mine").unwrap();
    let o = resume(&runs, "r", &["--steps", "4"]);
    let err = crate::common::succeeds_err(&o);
    assert!(
        err.contains("notes.txt") && err.contains("step-0000002.damaged"),
        "{err}"
    );
    let aside = cks.join("step-0000002.damaged");
    assert_eq!(std::fs::read(aside.join("notes.txt")).unwrap(), b"mine");
    // Both damaged checkpoints were written again, complete; the one of training's own files alone
    // in place.
    for ck in [&step2, &step3] {
        assert!(std::fs::metadata(ck.join("model.bpk")).unwrap().len() > 0);
    }
    assert!(!cks.join("step-0000003.damaged").exists());
    // The folder set aside is no checkpoint: the run resumes from its last one.
    succeeds(&resume(&runs, "r", &["--steps", "5", "--quiet"]));
    assert!(aside.join("notes.txt").is_file());
}

/// Two new runs of one name started at once: one trains, the other is refused, and the run's folder
/// is never removed by the one refused (it removed the folder the other had just made in 2 of 14
/// tries before). Eight pairs; every pair must leave the run with its checkpoints.
#[test]
fn two_new_runs_of_one_name_at_once_keep_the_one_that_trains() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let runs = tmp.path().join("runs");
    for pair in 0..8 {
        let name = format!("race{pair}");
        let spawn = || {
            let mut args = vec![
                "train",
                "--runs",
                s(&runs),
                "--name",
                &name,
                "--steps",
                "2",
                "--quiet",
            ];
            args.extend(start_args(&grid));
            crate::common::bin()
                .args(&args)
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap()
        };
        let (a, b) = (spawn(), spawn());
        let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
        let said = format!(
            "{}\n{}",
            String::from_utf8_lossy(&a.stderr),
            String::from_utf8_lossy(&b.stderr)
        );
        assert!(
            a.status.success() || b.status.success(),
            "pair {pair}: neither trained:\n{said}"
        );
        let checkpoints = runs.join(&name).join("checkpoints");
        let n = std::fs::read_dir(&checkpoints).map_or(0, |d| d.count());
        assert!(
            n > 0,
            "pair {pair}: {} has no checkpoints:\n{said}",
            checkpoints.display()
        );
    }
}
