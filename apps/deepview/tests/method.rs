//! One MPI-method interface: `deepview infer --method M` writes exactly the MPI that `deepview eval --method
//! M` scores from the same inputs (same plane rule, budget and input views), for the classical `psv-mean`
//! and the learned `deepview`; the old verbs `baseline` and `optimize` are usage errors naming it.

mod common;

use common::{deepview, fails_with, files, s, succeeds, succeeds_err, synth_grid as grid};
use std::path::{Path, PathBuf};

/// `infer --method M --inputs 0,2,6,8` and `eval --method M --targets 4 --inputs 0,2,6,8 --save-mpi` write the
/// same MPI folder, byte for byte (layers and mpi.json with its plane rule).
fn infer_equals_eval(tmp: &Path, scene: &Path, method: &str, extra: &[&str]) -> PathBuf {
    let inferred = tmp.join(format!("infer_{method}"));
    let mut a = vec![
        "infer",
        "--data",
        s(scene),
        "--method",
        method,
        "--inputs",
        "0,2,6,8",
        "--out",
        s(&inferred),
    ];
    a.extend_from_slice(extra);
    succeeds(&deepview(&a));
    let saved = tmp.join(format!("eval_{method}"));
    let mut a = vec![
        "eval",
        "--data",
        s(scene),
        "--method",
        method,
        "--protocol",
        "posed",
        "--targets",
        "4",
        "--inputs",
        "0,2,6,8",
        "--save-mpi",
        s(&saved),
    ];
    a.extend_from_slice(extra);
    let table = succeeds(&deepview(&a));
    assert!(table.contains(&format!("method {method}")), "{table}");
    let scored = saved.join("004_input_Cam004");
    assert!(scored.join("mpi.json").is_file(), "{table}");
    let (x, y) = (files(&inferred), files(&scored));
    assert_eq!(
        x.iter().map(|f| &f.0).collect::<Vec<_>>(),
        y.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    for ((name, a), (_, b)) in x.iter().zip(&y) {
        assert!(a == b, "{method}: {name} differs between infer and eval");
    }
    inferred
}

#[test]
fn infer_writes_the_mpi_eval_scores() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = grid(tmp.path());
    // psv-mean with the plane rule `auto`; deepview with the built-in weights, `auto` planes too.
    let psv = infer_equals_eval(tmp.path(), &scene, "psv-mean", &[]);
    let learned = infer_equals_eval(tmp.path(), &scene, "deepview", &["--max-memory", "1GiB"]);
    let (meta, _) = deepview_mpi::MpiMeta::read(&learned).unwrap();
    assert_eq!(meta.planes_rule.unwrap().rule, "auto");
    // The old alias `baseline` is a usage error naming `infer --method`, and writes nothing.
    let alias = tmp.path().join("alias");
    fails_with(
        &deepview(&[
            "baseline",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--inputs",
            "0,2,6,8",
            "--out",
            s(&alias),
        ]),
        &["hint: `deepview baseline --method M` is now `deepview infer --method M`"],
    );
    assert!(!alias.exists());
    assert!(psv.join("mpi.json").is_file());
}

/// `infer --method optimize` (minutes on real captures) says what it makes before its progress bar,
/// as the learned model does; the bar itself is hidden here, where stderr is not a terminal.
#[test]
fn optimize_says_what_it_makes() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = grid(tmp.path());
    let out = tmp.path().join("opt");
    let o = deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "optimize",
        "--inputs",
        "0,2,6,8",
        "--out",
        s(&out),
    ]);
    let err = succeeds_err(&o);
    let line = err
        .lines()
        .find(|l| l.starts_with("optimizing an MPI of "))
        .unwrap_or_else(|| panic!("no 'optimizing an MPI of' line: {err}"));
    let (meta, _) = deepview_mpi::MpiMeta::read(&out).unwrap();
    assert_eq!(
        line,
        format!(
            "optimizing an MPI of {} planes, {}x{}, from views [0, 2, 6, 8]",
            meta.depths.len(),
            meta.width,
            meta.height
        )
    );
}

/// The default inputs are the same rule everywhere: `nearest:4`, around the target in `eval` and around the
/// cameras' centroid where there is no target; a bad rule is a usage error listing what is allowed.
#[test]
fn one_input_rule_with_one_default() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = grid(tmp.path());
    let by_default = tmp.path().join("default");
    let explicit = tmp.path().join("explicit");
    for (out, inputs) in [(&by_default, None), (&explicit, Some("centroid:4"))] {
        let mut a = vec![
            "infer",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--planes",
            "6",
            "--out",
            s(out),
        ];
        if let Some(i) = inputs {
            a.extend(["--inputs", i]);
        }
        let stdout = succeeds(&deepview(&a));
        // The 4 views nearest the grid's centre (view 4 and, of its 4 equally near neighbours, 1, 3, 5).
        assert!(stdout.contains("views [1, 3, 4, 5]"), "{stdout}");
    }
    assert!(files(&by_default) == files(&explicit));
    // Around a view: nearest:3@0 is view 0 and its two neighbours.
    let around = tmp.path().join("around");
    let stdout = succeeds(&deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "nearest",
        "--inputs",
        "nearest:3@0",
        "--out",
        s(&around),
    ]));
    assert!(stdout.contains("views [0, 1, 3]"), "{stdout}");
    // (What `baseline --method nearest` and `optimize` were: `infer --method nearest|optimize`.)
    for (cmd, method) in [
        ("infer", None),
        ("eval", None),
        ("infer", Some("nearest")),
        ("infer", Some("optimize")),
    ] {
        let mut a = vec![cmd, "--data", s(&scene), "--inputs", "nearest:two"];
        if cmd != "eval" {
            a.extend(["--out", "x"]);
        }
        if let Some(m) = method {
            a.extend(["--method", m]);
        }
        let o = deepview(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{cmd} {method:?}: {err}");
        assert!(
            err.contains("--inputs") && err.contains("centroid:K") && err.contains("all"),
            "{cmd} {method:?}: {err}"
        );
    }
    // More inputs than views: refused, with the flag that fixes it.
    let o = deepview(&[
        "infer",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--inputs",
        "nearest:12",
        "--out",
        s(&tmp.path().join("x")),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("9 are available") && err.contains("--inputs"),
        "{err}"
    );
}
