//! Bad input never destroys data nor aborts (issue 12): outputs that would clobber inputs, interrupted
//! commands (SIGTERM), sizes beyond the memory budget, truncated images, arguments refused where parsed.
//! Every failure must be exit 2 (130 / 143 for signals), no panic, no abort, with the file or option named.

mod common;

use common::{bin, copy_dir, deepview, deepview_in, fails_with as refused, s, succeeds as ok};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

/// A small synthetic light-field scene (3 x 3 views of 64 x 48, 8 planes) with its ground-truth MPI.
fn grid(dir: &Path, name: &str) -> PathBuf {
    common::grid(dir, name, 64, 48)
}

/// Every file under `dir` with its bytes (for "unchanged" checks).
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((p.clone(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// Names in `dir` left by an interrupted write.
fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".deepview-") || n.ends_with(".tmp"))
        .collect()
}

// 1. Outputs never clobber inputs.

#[test]
fn outputs_that_are_or_lie_inside_inputs_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = grid(tmp.path(), "scene");
    let gt = scene.join("ground_truth_mpi");
    let before = snapshot(&scene);
    let (gt_json, gt_layer, psv, synth_json) = (
        format!("{}/mpi.json", s(&gt)),
        format!("{}/layer_000.png", s(&gt)),
        format!("{}/psv", s(&scene)),
        format!("{}/synth.json", s(&scene)),
    );
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (
            vec!["synth", "--data", s(&scene), "--out", s(&scene)],
            vec!["--out", "--data", "refusing"],
        ),
        (
            vec!["synth", "--data", s(&scene), "--out", s(&gt)],
            vec!["lies inside"],
        ),
        (
            vec!["render", "--mpi", s(&gt), "--out", &gt_json],
            vec!["--mpi", "mpi.json"],
        ),
        (
            vec!["render", "--mpi", s(&gt), "--out", &gt_layer],
            vec!["layer_000.png"],
        ),
        (
            vec![
                "infer",
                "--data",
                s(&scene),
                "--method",
                "nearest",
                "--out",
                s(&scene),
            ],
            vec!["--data"],
        ),
        (
            vec![
                "infer",
                "--data",
                s(&scene),
                "--method",
                "nearest",
                "--out",
                s(tmp.path()),
            ],
            vec!["contains"],
        ),
        (
            vec!["psv", "--data", s(&scene), "--planes", "4", "--out", &psv],
            vec!["lies inside"],
        ),
        (
            vec!["depth", "--mpi", s(&gt), "--out", s(&gt)],
            vec!["--mpi"],
        ),
        (
            vec![
                "export",
                "--mpi",
                s(&gt),
                "--out",
                s(&gt),
                "--format",
                "compact",
            ],
            vec!["--mpi"],
        ),
        (
            vec!["import", "--mpi", s(&gt), "--out", s(&gt)],
            vec!["--mpi"],
        ),
        (
            vec!["export-web", "--mpi", s(&gt), "--out", s(&gt)],
            vec!["--mpi"],
        ),
        (
            vec![
                "eval",
                "--data",
                s(&scene),
                "--method",
                "nearest",
                "--out",
                &synth_json,
            ],
            vec!["--data"],
        ),
    ];
    for (args, needles) in &cases {
        refused(&deepview(args), needles);
    }
    // A folder of another kind (here: a dataset that is not an input) is never replaced.
    let other = grid(tmp.path(), "other");
    let other_before = snapshot(&other);
    refused(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "nearest",
            "--out",
            s(&other),
        ]),
        &["not an MPI folder"],
    );
    assert_eq!(snapshot(&other), other_before);
    assert_eq!(snapshot(&scene), before, "an input changed");
}

#[test]
fn runs_and_weights_are_never_overwritten_and_images_follow_their_extension() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    ok(&deepview_in(
        t,
        &[
            "train",
            "--data",
            "synthetic:two-planes",
            "--name",
            "r",
            "--steps",
            "1",
            "--loss",
            "l1",
            "--quiet",
        ],
    ));
    let run = t.join("runs/r");
    let before = snapshot(&run);
    refused(
        &deepview_in(
            t,
            &[
                "export-weights",
                "--checkpoint",
                "runs/r",
                "--out",
                "runs/r",
            ],
        ),
        &["runs/r", "refusing"],
    );
    refused(
        &deepview_in(
            t,
            &[
                "export-weights",
                "--checkpoint",
                "runs/r",
                "--out",
                "runs/r/w",
            ],
        ),
        &["lies inside"],
    );
    ok(&deepview_in(
        t,
        &["export-weights", "--checkpoint", "runs/r", "--out", "w"],
    ));
    // Weights may replace weights, nothing else may.
    ok(&deepview_in(
        t,
        &["export-weights", "--checkpoint", "runs/r", "--out", "w"],
    ));
    let scene = grid(t, "scene");
    let gt = scene.join("ground_truth_mpi");
    refused(
        &deepview_in(
            t,
            &[
                "infer", "--data", "scene", "--method", "nearest", "--out", "w",
            ],
        ),
        &["weights folder"],
    );
    refused(
        &deepview_in(
            t,
            &[
                "infer", "--data", "scene", "--method", "nearest", "--out", "runs/r",
            ],
        ),
        &["training run"],
    );
    refused(
        &deepview_in(
            t,
            &["render", "--mpi", s(&gt), "--out", "runs/r/config.json"],
        ),
        &["training run"],
    );
    assert_eq!(snapshot(&run), before, "the run changed");
    ok(&deepview_in(
        t,
        &[
            "infer",
            "--weights",
            "w",
            "--data",
            "scene",
            "--planes",
            "4",
            "--out",
            "m",
        ],
    ));
    // Image outputs: the format follows the extension; unknown ones are refused.
    ok(&deepview(&[
        "render",
        "--mpi",
        s(&gt),
        "--out",
        s(&t.join("v.jpg")),
    ]));
    let bytes = std::fs::read(t.join("v.jpg")).unwrap();
    assert_eq!(&bytes[..3], &[0xFF, 0xD8, 0xFF], "not a JPEG");
    ok(&deepview(&[
        "render",
        "--mpi",
        s(&gt),
        "--out",
        s(&t.join("v.PNG")),
    ]));
    assert_eq!(&std::fs::read(t.join("v.PNG")).unwrap()[1..4], b"PNG");
    refused(
        &deepview(&["render", "--mpi", s(&gt), "--out", s(&t.join("v.tif"))]),
        &["v.tif", "format"],
    );
    refused(
        &deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--alpha",
            "--out",
            s(&t.join("a.jpg")),
        ]),
        &["--alpha"],
    );
    refused(
        &deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--path",
            "spiral",
            "--frames",
            "2",
            "--out",
            s(&t.join("p.jpg")),
        ]),
        &["p.jpg", "video format"],
    );
}

/// Every command that writes a folder, run twice into the same `--out`: the second run replaces its own
/// earlier output, but once a user's file, subfolder or dataset sits in that folder, it refuses (exit 2,
/// naming what it would delete) and leaves everything as it was.
#[test]
fn rerunning_a_command_never_deletes_files_it_did_not_write() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let scene = grid(t, "scene");
    let gt = scene.join("ground_truth_mpi");
    ok(&deepview_in(
        t,
        &[
            "train",
            "--data",
            "synthetic:two-planes",
            "--name",
            "r",
            "--steps",
            "1",
            "--loss",
            "l1",
            "--quiet",
        ],
    ));
    let run = t.join("runs/r");
    let commands: Vec<(&str, Vec<&str>)> = vec![
        (
            "infer",
            vec![
                "infer",
                "--data",
                s(&scene),
                "--method",
                "psv-mean",
                "--planes",
                "4",
            ],
        ),
        (
            "infer-nearest",
            vec!["infer", "--data", s(&scene), "--method", "nearest"],
        ),
        (
            "render",
            vec![
                "render",
                "--mpi",
                s(&gt),
                "--path",
                "spiral",
                "--frames",
                "2",
            ],
        ),
        (
            "export-llff",
            vec!["export", "--mpi", s(&gt), "--format", "llff"],
        ),
        (
            "export-stereo",
            vec!["export", "--mpi", s(&gt), "--format", "stereo-mag"],
        ),
        (
            "export-compact",
            vec!["export", "--mpi", s(&gt), "--format", "compact"],
        ),
        ("export-web", vec!["export-web", "--mpi", s(&gt)]),
        (
            "export-weights",
            vec!["export-weights", "--checkpoint", s(&run)],
        ),
        ("import", vec!["import", "--mpi", s(&gt)]),
        ("psv", vec!["psv", "--data", s(&scene), "--planes", "4"]),
        (
            "synth",
            vec![
                "synth", "--width", "32", "--height", "24", "--grid", "2", "--planes", "4",
            ],
        ),
        (
            "synth-transforms",
            vec![
                "synth",
                "--width",
                "32",
                "--height",
                "24",
                "--grid",
                "2",
                "--planes",
                "4",
                "--out-format",
                "transforms",
            ],
        ),
    ];
    for (name, args) in &commands {
        let out = t.join(format!("out-{name}"));
        let mut full = args.clone();
        full.extend(["--out", s(&out)]);
        ok(&deepview(&full));
        // Its own earlier output is replaced.
        ok(&deepview(&full));
        // A user's note, a subfolder and a dataset's poses beside the output are never deleted, nor
        // files named like those another tool's format has, which an export writes (an export deleted a
        // user's README; one LLFF itself wrote would have gone the same way).
        for (extra, is_dir) in [
            ("notes.txt", false),
            ("photos", true),
            ("poses_bounds.npy", false),
            ("README", false),
            ("intrinsics.txt", false),
            ("metadata.txt", false),
            ("mpi.b", false),
        ] {
            let p = out.join(extra);
            // The output's own file of that name (an export's metadata.txt), put back afterwards.
            let own = std::fs::read(&p).ok();
            if is_dir {
                std::fs::create_dir(&p).unwrap();
                std::fs::write(p.join("IMG_0001.JPG"), b"a photo").unwrap();
            } else {
                std::fs::write(&p, b"mine").unwrap();
            }
            let before = snapshot(&out);
            let shown = if is_dir {
                format!("{extra}/")
            } else {
                extra.to_string()
            };
            let r = deepview(&full);
            // A synthetic scene in LLFF's format writes poses_bounds.npy itself: the one file it owns.
            if name.starts_with("synth") && extra == "poses_bounds.npy" {
                ok(&r);
                continue;
            }
            refused(&r, &["--out", &shown, "refusing"]);
            assert_eq!(snapshot(&out), before, "{name}: the folder changed");
            assert!(leftovers(t).is_empty(), "{name}: {:?}", leftovers(t));
            if is_dir {
                std::fs::remove_dir_all(&p).unwrap();
            } else if let Some(own) = &own {
                std::fs::write(&p, own).unwrap();
            } else {
                std::fs::remove_file(&p).unwrap();
            }
        }
        // Nor a note inside a subfolder the command writes (the synthetic scene's ground-truth MPI and
        // images): the whole subfolder goes when the output is replaced.
        let subs: Vec<PathBuf> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_dir())
            .collect();
        for sub in subs {
            let note = sub.join("notes.txt");
            std::fs::write(&note, b"mine").unwrap();
            let before = snapshot(&out);
            let shown = format!("{}/notes.txt", sub.file_name().unwrap().to_string_lossy());
            refused(&deepview(&full), &["--out", &shown, "refusing"]);
            assert_eq!(snapshot(&out), before, "{name}: the folder changed");
            std::fs::remove_file(&note).unwrap();
        }
        // With them moved away, it replaces its output again.
        ok(&deepview(&full));
        // An output folder given through a symbolic link is refused (the swap replaced the link with a
        // folder and left the one it names empty).
        let target = t.join(format!("target-{name}"));
        std::fs::create_dir(&target).unwrap();
        let link = t.join(format!("link-{name}"));
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let slashed = format!("{}/", s(&link));
        for out in [s(&link), slashed.as_str()] {
            let mut via = args.clone();
            via.extend(["--out", out]);
            refused(
                &deepview(&via),
                &["--out", "symbolic link", "give the folder it names"],
            );
        }
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(std::fs::read_dir(&target).unwrap().count(), 0, "{name}");
    }
}

/// Folders that commands write into (depth maps, evaluation renders and MPIs) hold only such files, a
/// dataset is never written into, a dataset view's options need the dataset, and cameras no real camera
/// has are refused (issue 28's probe: each of these exited 0, overwrote a user's file or rendered black).
#[test]
fn written_into_folders_datasets_views_and_absurd_cameras() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let scene = grid(t, "scene");
    let gt = scene.join("ground_truth_mpi");
    let notes = t.join("notes");
    std::fs::create_dir(&notes).unwrap();
    std::fs::write(notes.join("depth_color.png"), b"my notes").unwrap();
    std::fs::write(notes.join("todo.txt"), b"keep").unwrap();
    let before = snapshot(&notes);
    refused(
        &deepview(&["depth", "--mpi", s(&gt), "--out", s(&notes)]),
        &["--out", "todo.txt", "refusing"],
    );
    refused(
        &deepview(&[
            "eval",
            "--data",
            s(&scene),
            "--method",
            "nearest",
            "--targets",
            "4",
            "--save-renders",
            s(&notes),
        ]),
        &["--save-renders", "todo.txt"],
    );
    assert_eq!(snapshot(&notes), before);
    // Their own earlier output is fine: depth twice into one folder, renders twice.
    let d = t.join("d");
    ok(&deepview(&["depth", "--mpi", s(&gt), "--out", s(&d)]));
    ok(&deepview(&[
        "depth",
        "--mpi",
        s(&gt),
        "--out",
        s(&d),
        "--prefix",
        "again",
    ]));
    let r = t.join("r");
    for _ in 0..2 {
        ok(&deepview(&[
            "eval",
            "--data",
            s(&scene),
            "--method",
            "nearest",
            "--targets",
            "4",
            "--save-renders",
            s(&r),
        ]));
    }
    // A dataset (not an input) is never an output nor holds one.
    let other = grid(t, "other");
    let other_before = snapshot(&other);
    refused(
        &deepview(&["depth", "--mpi", s(&gt), "--out", s(&other)]),
        &["--out", "refusing"],
    );
    refused(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "nearest",
            "--out",
            s(&other.join("mpi")),
        ]),
        &["lies inside the dataset"],
    );
    assert_eq!(snapshot(&other), other_before);
    // --view (or any dataset option) without --data: refused, not the MPI's own view.
    for extra in [["--view", "1"], ["--near", "1"], ["--downscale", "2"]] {
        let mut args = vec!["render", "--mpi", s(&gt), "--out"];
        let out = t.join("v.png");
        args.push(s(&out));
        args.extend(extra);
        refused(&deepview(&args), &[extra[0], "--data"]);
        assert!(!out.exists());
    }
    // A camera no real camera is: refused, naming the field.
    let cam = t.join("cam.json");
    let good = ok(&deepview(&["info", "--data", s(&scene), "--camera", "0"]));
    let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
    v["cx"] = serde_json::json!(1e300);
    std::fs::write(&cam, v.to_string()).unwrap();
    refused(
        &deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--camera",
            s(&cam),
            "--out",
            s(&t.join("x.png")),
        ]),
        &["cam.json", "cx"],
    );
    // --near/--far on an import that carries its own depths: refused, not ignored.
    let sm = t.join("sm");
    ok(&deepview(&[
        "export",
        "--mpi",
        s(&gt),
        "--format",
        "stereo-mag",
        "--out",
        s(&sm),
    ]));
    refused(
        &deepview(&[
            "import",
            "--mpi",
            s(&sm),
            "--near",
            "10",
            "--far",
            "1",
            "--out",
            s(&t.join("im")),
        ]),
        &["--near/--far", "carries its own"],
    );
}

// 2. Whole-folder atomicity and signals.

/// Send SIGTERM to `child`.
fn sigterm(child: &std::process::Child) {
    // SAFETY: kill(2) on the pid of a child this test started.
    unsafe {
        libc::kill(child.id() as i32, libc::SIGTERM);
    }
}

/// Start `args`, send SIGTERM `after` the command first prints a line containing `marker` on stderr
/// (none: after its start), return the exit code. A marker the job prints before its long part keeps a
/// fast machine from finishing the job before the signal.
fn terminate(args: &[&str], marker: Option<&str>, after: Duration) -> Option<i32> {
    use std::io::{BufRead, Read};
    let mut child = bin()
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stderr = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    if let Some(marker) = marker {
        loop {
            let mut line = String::new();
            let n = stderr.read_line(&mut line).unwrap();
            assert!(n > 0, "{marker:?} never printed: {seen}");
            seen.push_str(&line);
            if line.contains(marker) {
                break;
            }
        }
    }
    std::thread::sleep(after);
    sigterm(&child);
    stderr.read_to_string(&mut seen).unwrap();
    let status = child.wait().unwrap();
    assert!(!seen.contains("panicked"), "{seen}");
    status.code()
}

#[test]
fn sigterm_leaves_the_old_mpi_folder_intact() {
    let tmp = tempfile::tempdir().unwrap();
    let data = deepview_data::data_dir().join("llff/fern");
    let out = tmp.path().join("mpi");
    let base = |planes: &str| {
        vec![
            "infer".to_string(),
            "--data".into(),
            s(&data).into(),
            "--images".into(),
            "images_8".into(),
            "--method".into(),
            "psv-mean".into(),
            "--planes".into(),
            planes.into(),
            "--out".into(),
            s(&out).into(),
        ]
    };
    let args: Vec<String> = base("8");
    ok(&deepview(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
    ));
    let before = snapshot(&out);
    // Interrupted at several moments (loading, sweeping, writing): the old folder or a whole new one.
    let args: Vec<String> = base("40");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let started = Instant::now();
    let mut replaced = 0;
    for ms in [150, 600, 1200, 1800] {
        let code = terminate(&args, None, Duration::from_millis(ms));
        assert!(matches!(code, Some(143) | Some(0)), "exit {code:?}");
        let mpi = deepview_mpi::read_mpi::<u8>(&out).expect("the MPI folder still loads");
        if code == Some(143) {
            assert!(mpi.depths.len() == 8 || mpi.depths.len() == 40);
        }
        if mpi.depths.len() == 8 {
            assert_eq!(snapshot(&out), before, "the old folder changed");
        } else {
            replaced += 1;
        }
        assert!(
            leftovers(tmp.path()).is_empty(),
            "{:?}",
            leftovers(tmp.path())
        );
    }
    eprintln!(
        "{replaced} of 4 runs finished first ({:.1?})",
        started.elapsed()
    );
}

/// An evaluation saving renders and MPIs, stopped after its first view: the earlier run's renders,
/// MPIs and report stay as they were (not some views new and some old), nothing is left behind, and
/// the next run is not blocked. Depth maps: the pair is replaced together.
#[test]
fn sigterm_of_eval_leaves_the_earlier_renders_mpis_and_report() {
    let tmp = tempfile::tempdir().unwrap();
    let data = deepview_data::data_dir().join("llff/fern");
    let (renders, mpis, report) = (
        tmp.path().join("renders"),
        tmp.path().join("mpis"),
        tmp.path().join("r.json"),
    );
    let args = |planes: &'static str| {
        vec![
            "eval",
            "--data",
            s(&data),
            "--images",
            "images_8",
            "--method",
            "psv-mean",
            "--targets",
            "every:8",
            "--planes",
            planes,
            "--save-renders",
            s(&renders),
            "--save-mpi",
            s(&mpis),
            "--out",
            s(&report),
        ]
    };
    ok(&deepview(&args("8")));
    let before = (
        snapshot(&renders),
        snapshot(&mpis),
        std::fs::read(&report).unwrap(),
    );
    assert_eq!(before.0.len(), 3, "a render per target");
    // Stopped while the second of three views is made.
    let code = terminate(&args("16"), Some("[1/3]"), Duration::ZERO);
    assert_eq!(code, Some(143));
    let after = (
        snapshot(&renders),
        snapshot(&mpis),
        std::fs::read(&report).unwrap(),
    );
    assert!(after == before, "the earlier evaluation's files changed");
    for dir in [tmp.path(), renders.as_path(), mpis.as_path()] {
        assert!(leftovers(dir).is_empty(), "{:?}", leftovers(dir));
        let hidden: Vec<_> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with('.'))
            .collect();
        assert!(hidden.is_empty(), "{hidden:?} in {}", dir.display());
    }
    ok(&deepview(&args("16")));
    assert!(snapshot(&mpis) != before.1);
}

#[test]
fn an_eval_report_that_cannot_be_written_keeps_the_earlier_renders() {
    use std::io::BufRead;
    let tmp = tempfile::tempdir().unwrap();
    let data = deepview_data::data_dir().join("llff/fern");
    let (renders, report) = (tmp.path().join("renders"), tmp.path().join("r.json"));
    let args = |planes: &'static str| {
        vec![
            "eval",
            "--data",
            s(&data),
            "--images",
            "images_8",
            "--method",
            "psv-mean",
            "--targets",
            "every:2",
            "--planes",
            planes,
            "--save-renders",
            s(&renders),
            "--out",
            s(&report),
        ]
    };
    ok(&deepview(&args("8")));
    let before = snapshot(&renders);
    // While the second run evaluates (nine of its ten views still to come), its report's name becomes
    // a folder, which no file replaces.
    let mut child = bin()
        .args(args("16"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stderr = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    while !seen.contains("[1/10]") {
        let n = stderr.read_line(&mut seen).unwrap();
        assert!(n > 0, "[1/10] never printed: {seen}");
    }
    std::fs::remove_file(&report).unwrap();
    std::fs::create_dir(&report).unwrap();
    std::fs::write(report.join("keep.txt"), "mine").unwrap();
    std::io::Read::read_to_string(&mut stderr, &mut seen).unwrap();
    let code = child.wait().unwrap().code();
    assert_eq!(code, Some(2), "{seen}");
    assert!(
        seen.contains("r.json") && !seen.contains("panicked"),
        "{seen}"
    );
    assert!(
        snapshot(&renders) == before,
        "the renders changed without their report"
    );
    assert_eq!(
        std::fs::read_to_string(report.join("keep.txt")).unwrap(),
        "mine"
    );
    let hidden: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(hidden.is_empty(), "{hidden:?}");
}

#[test]
fn the_longest_names_are_written_and_impossible_paths_refused_before_the_work() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let scene = grid(t, "scene");
    // Names of 255 bytes, the most a file system takes: their temporaries must fit too.
    let folder = t.join("m".repeat(255));
    let report = t.join(format!("{}.json", "r".repeat(250)));
    ok(&deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "nearest",
        "--out",
        s(&folder),
    ]));
    assert!(folder.join("mpi.json").is_file());
    let eval = |out: &Path| {
        deepview(&[
            "eval",
            "--data",
            s(&scene),
            "--method",
            "nearest",
            "--targets",
            "4",
            "--out",
            s(out),
        ])
    };
    ok(&eval(&report));
    ok(&eval(&report));
    assert!(
        std::fs::read_to_string(&report)
            .unwrap()
            .contains("results")
    );
    let names: Vec<_> = std::fs::read_dir(t).unwrap().collect();
    assert_eq!(names.len(), 3, "{names:?}");
    // A path longer than the system takes, and a folder on the way that is a link to nothing: refused
    // at once, naming the problem (not after the evaluation, as a failure to write).
    let deep = t.join(vec!["d".repeat(200); 21].join("/")).join("r.json");
    refused(&eval(&deep), &["--out", "4096 bytes"]);
    std::os::unix::fs::symlink(t.join("nowhere"), t.join("gone")).unwrap();
    refused(
        &eval(&t.join("gone/r.json")),
        &["gone", "symbolic link", "nowhere"],
    );
    refused(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "nearest",
            "--out",
            s(&t.join("gone/m")),
        ]),
        &["gone", "symbolic link"],
    );
    assert!(!t.join("nowhere").exists());
}

#[test]
fn sigterm_of_infer_leaves_the_old_mpi_and_train_resumes_from_its_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let scene = grid(t, "scene");
    let out = t.join("mpi");
    ok(&deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "nearest",
        "--out",
        s(&out),
    ]));
    let before = snapshot(&out);
    let data = deepview_data::data_dir().join("llff/fern");
    // 64 planes take several seconds: stopped just after the network starts, it must not finish first.
    let code = terminate(
        &[
            "infer",
            "--data",
            s(&data),
            "--images",
            "images_8",
            "--planes",
            "64",
            "--out",
            s(&out),
        ],
        Some("inferring an MPI of 64 planes"),
        Duration::from_millis(300),
    );
    assert_eq!(code, Some(143));
    assert_eq!(snapshot(&out), before, "the old MPI changed");
    assert!(leftovers(t).is_empty(), "{:?}", leftovers(t));

    // train: SIGTERM saves a checkpoint and exits 143; --resume continues from it.
    let runs = t.join("runs");
    let child = bin()
        .args([
            "train",
            "--data",
            "synthetic:two-planes",
            "--name",
            "k",
            "--runs",
            s(&runs),
            "--steps",
            "1000",
            "--loss",
            "l1",
            "--quiet",
            "--checkpoint-every",
            "1000",
        ])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for the first step, then stop it.
    let metrics = runs.join("k/metrics.jsonl");
    let start = Instant::now();
    while !std::fs::read_to_string(&metrics).is_ok_and(|m| !m.is_empty()) {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no training step"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    sigterm(&child);
    let status = child.wait_with_output().unwrap().status;
    assert_eq!(status.code(), Some(143));
    let checkpoints: Vec<_> = std::fs::read_dir(runs.join("k/checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("step-"))
        .collect();
    assert_eq!(checkpoints.len(), 1, "{checkpoints:?}");
    let step: u64 = checkpoints[0]["step-".len()..].parse().unwrap();
    assert!(step >= 1);
    let o = deepview(&[
        "train",
        "--name",
        "k",
        "--runs",
        s(&runs),
        "--resume",
        "--steps",
        &(step + 1).to_string(),
        "--quiet",
    ]);
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("resuming") && err.contains(&format!("at step {step}")),
        "{err}"
    );
}

#[test]
fn failed_commands_leave_no_output_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = grid(tmp.path(), "scene");
    let out = tmp.path().join("a/b/mpi");
    // Fails after the checks (view 99 does not exist): nothing is created.
    refused(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "nearest",
            "--inputs",
            "99",
            "--out",
            s(&out),
        ]),
        &["99"],
    );
    assert!(!tmp.path().join("a").exists());
    refused(
        &deepview(&[
            "export",
            "--mpi",
            s(&scene),
            "--out",
            s(&out),
            "--format",
            "llff",
        ]),
        &["mpi.json"],
    );
    assert!(!tmp.path().join("a").exists());
    // A device this build lacks, or no device at all: `demo --device` as `infer --device`.
    for (device, says) in [("tpu", "unknown device"), ("cuda:0", "--features cuda")] {
        refused(
            &deepview(&[
                "demo",
                "--no-optimize",
                "--device",
                device,
                "--out",
                s(&out),
            ]),
            &[device, says],
        );
        assert!(!tmp.path().join("a").exists());
    }
    assert!(leftovers(tmp.path()).is_empty());
}

// 3. Sizes checked before work.

#[test]
fn huge_sizes_are_refused_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let scene = grid(t, "scene");
    let gt = scene.join("ground_truth_mpi");
    let big = t.join("big.json");
    std::fs::write(
        &big,
        r#"{"width":100000,"height":100000,"fx":1e5,"fy":1e5,"cx":5e4,"cy":5e4,
            "camera_from_world":[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}"#,
    )
    .unwrap();
    let fern = deepview_data::data_dir().join("llff/fern");
    let o = |name: &str| t.join(name).to_string_lossy().into_owned();
    let cases: Vec<Vec<String>> = vec![
        vec![
            "render".into(),
            "--mpi".into(),
            s(&gt).into(),
            "--camera".into(),
            s(&big).into(),
            "--out".into(),
            o("r.png"),
        ],
        vec![
            "depth".into(),
            "--mpi".into(),
            s(&gt).into(),
            "--camera".into(),
            s(&big).into(),
            "--out".into(),
            o("d"),
        ],
        vec![
            "bench".into(),
            "render".into(),
            "--synthetic".into(),
            "64x48x4".into(),
            "--camera".into(),
            s(&big).into(),
        ],
        vec![
            "bench".into(),
            "render".into(),
            "--synthetic".into(),
            "100000x100000x32".into(),
        ],
        vec![
            "synth".into(),
            "--width".into(),
            "10000000".into(),
            "--out".into(),
            o("s"),
        ],
        vec![
            "psv".into(),
            "--data".into(),
            s(&fern).into(),
            "--images".into(),
            "images_8".into(),
            "--planes".into(),
            "10000000".into(),
            "--out".into(),
            o("p"),
        ],
        vec![
            "infer".into(),
            "--data".into(),
            s(&fern).into(),
            "--images".into(),
            "images_8".into(),
            "--method".into(),
            "psv-mean".into(),
            "--planes".into(),
            "10000000".into(),
            "--out".into(),
            o("b"),
        ],
        vec![
            "infer".into(),
            "--method".into(),
            "optimize".into(),
            "--data".into(),
            s(&fern).into(),
            "--images".into(),
            "images_8".into(),
            "--planes".into(),
            "10000000".into(),
            "--out".into(),
            o("op"),
        ],
        vec![
            "eval".into(),
            "--data".into(),
            s(&scene).into(),
            "--method".into(),
            "psv-mean".into(),
            "--planes".into(),
            "10000000".into(),
        ],
        vec![
            "infer".into(),
            "--data".into(),
            s(&scene).into(),
            "--planes".into(),
            "10000000".into(),
            "--out".into(),
            o("i"),
        ],
        vec![
            "render".into(),
            "--mpi".into(),
            s(&gt).into(),
            "--path".into(),
            "spiral".into(),
            "--frames".into(),
            "100000000000".into(),
            "--out".into(),
            o("f.gif"),
        ],
    ];
    for args in &cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let start = Instant::now();
        let out = deepview(&args);
        refused(&out, &["--max-memory"]);
        // Before the work: seconds (process start and the scene's loading included, on 2 cores
        // beside other tests), where doing it would take minutes or run out of memory.
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "{args:?} took {:?}",
            start.elapsed()
        );
        assert!(leftovers(t).is_empty());
    }
    // The minimum the message names is enough.
    let out = deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--planes",
        "64",
        "--max-memory",
        "1MiB",
        "--out",
        &o("m"),
    ]);
    refused(&out, &["--max-memory"]);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    let min = err
        .split("--max-memory ")
        .last()
        .unwrap()
        .trim()
        .to_string();
    ok(&deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--planes",
        "64",
        "--max-memory",
        &min,
        "--out",
        &o("m"),
    ]));
    // A long path streams its frames: a GIF of many frames within a small budget.
    ok(&deepview(&[
        "render",
        "--mpi",
        s(&gt),
        "--path",
        "circle",
        "--frames",
        "40",
        "--max-memory",
        "64MiB",
        "--out",
        &o("c.gif"),
    ]));
    let gif = std::fs::read(t.join("c.gif")).unwrap();
    assert_eq!(&gif[..3], b"GIF");
    assert_eq!(*gif.last().unwrap(), 0x3B, "GIF trailer");
}

// 4. Every image decoded completely or refused.

#[test]
fn mpis_announcing_more_than_they_hold_are_refused_before_they_are_read() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let scene = grid(t, "scene");
    let gt = scene.join("ground_truth_mpi");
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(gt.join("mpi.json")).unwrap()).unwrap();
    // An mpi.json of the same scene edited by hand: `edit` changes its fields.
    let variant = |name: &str, edit: &dyn Fn(&mut serde_json::Value)| {
        let dir = copy_dir(&gt, &t.join(name));
        let mut m = meta.clone();
        edit(&mut m);
        std::fs::write(dir.join("mpi.json"), serde_json::to_vec(&m).unwrap()).unwrap();
        dir
    };
    // 40 planes of 8000 x 8000 (10 GB of 8-bit texels), whose layers are links to one small file.
    let big = variant("big", &|m| {
        m["width"] = 8000.into();
        m["height"] = 8000.into();
        m["intrinsics"] =
            serde_json::json!({"fx": 8000.0, "fy": 8000.0, "cx": 4000.0, "cy": 4000.0});
        let depths: Vec<f64> = (0..40).map(|i| 100.0 - 2.0 * i as f64).collect();
        m["depths"] = depths.into();
        m["layers"] = (0..40)
            .map(|i| format!("l{i}.png"))
            .collect::<Vec<_>>()
            .into();
    });
    for i in 0..40 {
        std::os::unix::fs::symlink(gt.join("layer_000.png"), big.join(format!("l{i}.png")))
            .unwrap();
    }
    let o = |n: &str| t.join(n).to_string_lossy().into_owned();
    let commands: Vec<Vec<String>> = vec![
        vec![
            "export".into(),
            "--mpi".into(),
            s(&big).into(),
            "--out".into(),
            o("e"),
            "--format".into(),
            "llff".into(),
        ],
        vec![
            "compact".into(),
            "--mpi".into(),
            s(&big).into(),
            "--out".into(),
            o("c"),
        ],
        vec!["diff".into(), s(&big).into(), s(&gt).into()],
        vec![
            "export-web".into(),
            "--mpi".into(),
            s(&big).into(),
            "--out".into(),
            o("w"),
        ],
        vec![
            "view".into(),
            "--mpi".into(),
            s(&big).into(),
            "--port".into(),
            "0".into(),
        ],
        vec![
            "import".into(),
            "--mpi".into(),
            s(&big).into(),
            "--out".into(),
            o("i"),
        ],
    ];
    for mut c in commands {
        c.extend(["--max-memory".into(), "2GiB".into()]);
        let args: Vec<&str> = c.iter().map(String::as_str).collect();
        let started = Instant::now();
        refused(
            &deepview(&args),
            &["needs about", "big: 40 planes of 8000x8000", "2.0 GiB"],
        );
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "{c:?} read the planes first"
        );
    }
    // Metadata whose numbers no capture has: refused by every reader, naming the file.
    type Edit<'a> = Box<dyn Fn(&mut serde_json::Value) + 'a>;
    let bad: Vec<(&str, Edit, &str)> = vec![
        (
            "tiny",
            Box::new(|m| {
                m["depths"] = meta["depths"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|d| d.as_f64().unwrap() * 1e-300)
                    .collect::<Vec<_>>()
                    .into()
            }),
            "the depths deepview works with",
        ),
        (
            "close",
            Box::new(|m| {
                let d = m["depths"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .enumerate()
                    .map(|(i, _)| 10.0 - i as f64 * 1e-9)
                    .collect::<Vec<_>>();
                m["depths"] = d.into();
            }),
            "less than a millionth apart",
        ),
        (
            "page",
            Box::new(|m| m["layers"][0] = "index.html".into()),
            "index.html",
        ),
        (
            "space",
            Box::new(|m| m["layers"][0] = "layer 000.png".into()),
            "layer 000.png",
        ),
    ];
    for (name, edit, needle) in bad {
        let dir = variant(name, &*edit);
        let out = deepview(&[
            "render",
            "--mpi",
            s(&dir),
            "--out",
            &o(&format!("{name}.png")),
        ]);
        refused(&out, &[needle, "mpi.json"]);
    }
    // A byte order mark before the JSON is no error.
    let bom = variant("bom", &|_| {});
    let mut text = b"\xEF\xBB\xBF".to_vec();
    text.extend(std::fs::read(bom.join("mpi.json")).unwrap());
    std::fs::write(bom.join("mpi.json"), text).unwrap();
    ok(&deepview(&[
        "render",
        "--mpi",
        s(&bom),
        "--out",
        &o("bom.png"),
    ]));
    // MPIs the readers would refuse are not made either.
    refused(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--planes",
            "4100",
            "--out",
            &o("p4100"),
        ]),
        &["at most 4096"],
    );
    refused(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--near",
            "4",
            "--far",
            "4.00002",
            "--out",
            &o("pclose"),
        ]),
        &["less than a millionth apart"],
    );
    // The learned method says so too (not that the planes are over the memory budget).
    refused(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--near",
            "4",
            "--far",
            "4.00002",
            "--out",
            &o("lclose"),
        ]),
        &["less than a millionth apart"],
    );
    assert!(!t.join("p4100").exists() && !t.join("pclose").exists() && !t.join("lclose").exists());
    // Depth bounds no scene has.
    refused(
        &deepview(&[
            "infer",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--near",
            "1e-300",
            "--far",
            "1e-299",
            "--out",
            &o("n"),
        ]),
        &["lie outside", "--near/--far"],
    );
}

#[test]
fn truncated_and_corrupt_images_are_refused_with_their_name() {
    let tmp = tempfile::tempdir().unwrap();
    let src = deepview_data::data_dir().join("colmap/room");
    let room = tmp.path().join("room");
    copy_dir(&src, &room);
    let mut names: Vec<String> = std::fs::read_dir(room.join("images"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    // A good JPEG decodes; one cut short (or damaged in the middle) is refused, naming the file.
    let scene = deepview_data::load_scene(&room, &Default::default()).unwrap();
    let view = scene.views[0].image_path.clone();
    let bytes = std::fs::read(&view).unwrap();
    ok(&deepview(&[
        "infer",
        "--data",
        s(&room),
        "--method",
        "nearest",
        "--inputs",
        "0",
        "--out",
        s(&tmp.path().join("m")),
    ]));
    let name = view.file_name().unwrap().to_str().unwrap().to_string();
    for cut in [bytes.len() * 2 / 3, bytes.len() - 2] {
        std::fs::write(&view, &bytes[..cut]).unwrap();
        let out = deepview(&[
            "infer",
            "--data",
            s(&room),
            "--method",
            "nearest",
            "--inputs",
            "0",
            "--out",
            s(&tmp.path().join("m2")),
        ]);
        refused(&out, &[&name, "JPEG"]);
    }
    // A truncated PNG layer of an MPI.
    let scene = grid(tmp.path(), "scene");
    let layer = scene.join("ground_truth_mpi/layer_003.png");
    let png = std::fs::read(&layer).unwrap();
    std::fs::write(&layer, &png[..png.len() - 20]).unwrap();
    refused(
        &deepview(&[
            "render",
            "--mpi",
            s(&scene.join("ground_truth_mpi")),
            "--out",
            s(&tmp.path().join("x.png")),
        ]),
        &["layer_003.png"],
    );
    refused(
        &deepview(&[
            "export",
            "--mpi",
            s(&scene.join("ground_truth_mpi")),
            "--out",
            s(&tmp.path().join("e")),
            "--format",
            "llff",
        ]),
        &["layer_003.png"],
    );
    assert!(!tmp.path().join("e").exists());
}

// 5. Arguments validated where parsed.

#[test]
fn bad_arguments_are_usage_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let scene = grid(t, "scene");
    let gt = scene.join("ground_truth_mpi");
    let sc = s(&scene);
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec![
                "infer", "--data", sc, "--method", "nearest", "--inputs", "0,2,0", "--out", "x",
            ],
            "twice",
        ),
        (
            vec!["infer", "--data", sc, "--inputs", "1,1", "--out", "x"],
            "twice",
        ),
        (
            vec![
                "infer", "--data", sc, "--method", "nearest", "--inputs", "0,a", "--out", "x",
            ],
            "not a view index",
        ),
        (
            vec![
                "train", "--data", sc, "--name", "x", "--views", "9", "--steps", "1",
            ],
            "--views 9",
        ),
        (
            vec![
                "train",
                "--data",
                "synthetic:two-planes",
                "--name",
                "x",
                "--holdout-every",
                "1",
            ],
            "--holdout-every",
        ),
        (
            vec!["train", "--data", "synthetic:nope", "--name", "x"],
            "unknown synthetic scene",
        ),
        (
            vec![
                "train",
                "--data",
                "synthetic:two-planes",
                "--name",
                "../../x",
            ],
            "--name",
        ),
        (
            vec!["train", "--data", "synthetic:two-planes", "--name", "/abs"],
            "--name",
        ),
        (
            vec!["train", "--data", "synthetic:two-planes", "--name", ""],
            "--name",
        ),
        (vec!["train", "--name", "missing", "--resume"], "no run"),
        (
            vec![
                "train",
                "--data",
                "synthetic:two-planes",
                "--name",
                "x",
                "--max-memory",
                "lots",
            ],
            "--max-memory",
        ),
        (
            vec![
                "train",
                "--data",
                "synthetic:two-planes",
                "--name",
                "x",
                "--steps",
                "1",
                "--loss",
                "l1",
                "--max-memory",
                "1MiB",
            ],
            "--max-memory 1MiB",
        ),
        (
            vec!["synth", "--supersample", "0", "--out", "x"],
            "--supersample",
        ),
        (vec!["synth", "--width", "-5", "--out", "x"], "-5"),
        (vec!["synth", "--data", "gird", "--out", "x"], "--data"),
        (
            vec!["bench", "render", "--synthetic", "8x8x2", "--repeats", "0"],
            "--repeats",
        ),
        (vec!["bench", "net", "--repeats", "0"], "--repeats"),
        (
            vec![
                "infer",
                "--data",
                sc,
                "--method",
                "psv-mean",
                "--max-memory",
                "lots",
                "--out",
                "x",
            ],
            "--max-memory",
        ),
        (
            vec![
                "infer",
                "--data",
                sc,
                "--method",
                "psv-mean",
                "--max-memory=-1GiB",
                "--out",
                "x",
            ],
            "--max-memory",
        ),
        (
            vec![
                "infer",
                "--data",
                sc,
                "--method",
                "psv-mean",
                "--max-memory",
                "0",
                "--out",
                "x",
            ],
            "--max-memory",
        ),
        (
            vec![
                "render",
                "--mpi",
                s(&gt),
                "--path",
                "spiral",
                "--frames",
                "0",
                "--out",
                "x.gif",
            ],
            "--frames",
        ),
        (
            vec![
                "render",
                "--mpi",
                s(&gt),
                "--path",
                "spiral",
                "--fps",
                "0",
                "--out",
                "x.gif",
            ],
            "--fps",
        ),
        (
            vec![
                "depth",
                "--mpi",
                s(&gt),
                "--out",
                "d",
                "--prefix",
                "../../x",
            ],
            "--prefix",
        ),
    ];
    for (args, needle) in &cases {
        refused(&deepview_in(t, args), &[needle]);
    }
    assert!(!t.join("x").exists() && !t.join("runs/x").exists());
    assert!(!t.parent().unwrap().join("x_color.png").exists());

    // --resume: a run without checkpoints, and options that cannot change.
    std::fs::create_dir_all(t.join("runs/empty/checkpoints")).unwrap();
    std::fs::write(t.join("runs/empty/config.json"), "{}").unwrap();
    refused(
        &deepview_in(t, &["train", "--name", "empty", "--resume"]),
        &["no checkpoints"],
    );
    ok(&deepview_in(
        t,
        &[
            "train",
            "--data",
            "synthetic:two-planes",
            "--name",
            "r",
            "--steps",
            "1",
            "--loss",
            "l1",
            "--quiet",
        ],
    ));
    refused(
        &deepview_in(
            t,
            &[
                "train", "--name", "r", "--resume", "--steps", "2", "--lr", "0.1", "--crop", "16",
            ],
        ),
        &["--crop, --lr", "cannot change on resume"],
    );
    // info exits 2 when it reports a problem (a missing image), after printing the report.
    let room = t.join("room");
    copy_dir(&deepview_data::data_dir().join("colmap/room"), &room);
    let first = std::fs::read_dir(room.join("images"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    std::fs::remove_file(&first).unwrap();
    let out = deepview(&["info", "--data", s(&room)]);
    refused(
        &out,
        &["problem", first.file_name().unwrap().to_str().unwrap()],
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("images       problem"));
}

/// A file output's temporaries left by killed processes (SIGKILL leaves no time to clean up) are removed
/// by the next run writing that file; a running process's, and anything else, are not.
#[test]
fn killed_runs_temporary_files_are_removed_by_the_next_run() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = grid(tmp.path(), "scene");
    let out = tmp.path().join("r.json");
    let dead = tmp.path().join(".r.json.4000000000.tmp");
    let live = tmp
        .path()
        .join(format!(".r.json.{}.tmp", std::process::id()));
    let other = tmp.path().join(".x.gif.4000000000.tmp");
    let note = tmp.path().join(".r.json.notes");
    for f in [&dead, &live, &other, &note] {
        std::fs::write(f, b"x").unwrap();
    }
    ok(&deepview(&[
        "eval",
        "--data",
        s(&scene),
        "--method",
        "nearest",
        "--out",
        s(&out),
    ]));
    assert!(out.is_file());
    assert!(!dead.exists());
    for f in [&live, &other, &note] {
        assert!(f.exists(), "{}", f.display());
    }
}

/// A `depth` pair goes into its folder under an flock of the folder, so that two runs into one folder
/// never pair one's colour map with the other's disparity: while the folder is locked (here by the
/// test, as by another run's publish), a run with both maps staged publishes neither; unlocked, both.
#[test]
fn a_depth_pair_waits_for_the_folders_lock() {
    use std::os::fd::AsRawFd;
    let tmp = tempfile::tempdir().unwrap();
    let gt = grid(tmp.path(), "scene").join("ground_truth_mpi");
    let out = tmp.path().join("d");
    std::fs::create_dir(&out).unwrap();
    let folder = std::fs::File::open(&out).unwrap();
    // SAFETY: flock on a descriptor the test owns.
    assert_eq!(unsafe { libc::flock(folder.as_raw_fd(), libc::LOCK_EX) }, 0);
    let mut run = bin()
        .args(["depth", "--mpi", s(&gt), "--out", s(&out)])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Both maps staged (the run announces it by its staging folder holding both files).
    let staged = || {
        std::fs::read_dir(&out).unwrap().flatten().any(|e| {
            let p = e.path();
            e.file_name().to_string_lossy().contains(".deepview-tmp")
                && p.join("depth_color.png").is_file()
                && p.join("depth_disparity16.png").is_file()
        })
    };
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    while !staged() {
        assert!(
            std::time::Instant::now() < deadline,
            "the maps were never staged"
        );
        assert!(
            run.try_wait().unwrap().is_none(),
            "depth ended without staging"
        );
        std::thread::yield_now();
    }
    assert!(!out.join("depth_color.png").exists() && !out.join("depth_disparity16.png").exists());
    drop(folder);
    assert!(run.wait().unwrap().success());
    assert!(out.join("depth_color.png").is_file() && out.join("depth_disparity16.png").is_file());
}

/// A web viewer folder of an MPI whose layers have their own names (`plane0.png`, as its mpi.json
/// lists them) is replaced by the next export-web (it was refused as holding files the viewer does
/// not have); a file its mpi.json does not list still is refused.
#[test]
fn export_web_replaces_its_own_folder_whatever_the_layers_are_called() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let gt = grid(t, "scene").join("ground_truth_mpi");
    let mpi = copy_dir(&gt, &t.join("named"));
    let text = std::fs::read_to_string(mpi.join("mpi.json")).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let layers: Vec<String> = json["layers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l.as_str().unwrap().to_string())
        .collect();
    for (i, l) in layers.iter().enumerate() {
        std::fs::rename(mpi.join(l), mpi.join(format!("plane{i}.png"))).unwrap();
    }
    json["layers"] = (0..layers.len())
        .map(|i| serde_json::Value::from(format!("plane{i}.png")))
        .collect();
    std::fs::write(mpi.join("mpi.json"), json.to_string()).unwrap();
    let web = t.join("web");
    let args = ["export-web", "--mpi", s(&mpi), "--out", s(&web)];
    ok(&deepview(&args));
    ok(&deepview(&args));
    assert!(web.join("plane0.png").is_file());
    std::fs::write(web.join("plane99.png"), b"mine").unwrap();
    refused(&deepview(&args), &["plane99.png", "refusing"]);
    assert_eq!(std::fs::read(web.join("plane99.png")).unwrap(), b"mine");
    std::fs::remove_file(web.join("plane99.png")).unwrap();
    // A user's file that the folder's mpi.json is edited to list is not its own (no mark).
    let text = std::fs::read_to_string(web.join("mpi.json")).unwrap();
    let mut edited: serde_json::Value = serde_json::from_str(&text).unwrap();
    edited["layers"][0] = "thesis.pdf".into();
    std::fs::write(web.join("mpi.json"), edited.to_string()).unwrap();
    std::fs::write(web.join("thesis.pdf"), b"mine").unwrap();
    refused(&deepview(&args), &["thesis.pdf", "refusing"]);
    assert_eq!(std::fs::read(web.join("thesis.pdf")).unwrap(), b"mine");
}
