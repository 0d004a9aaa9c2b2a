//! Closed output streams (`deepview ... | head -1`, a log reader gone) lose text, not work: every
//! command still does its job and exits 0; outputs are never pipes, devices or `-`.

use crate::common::{bin, fails_with, s, succeeds, synth_grid};
use std::process::{Output, Stdio};

/// `deepview args` with stdout (`out`) and/or stderr (`err`) a pipe whose reader is already gone: every
/// write to it fails (EPIPE), deterministically.
fn closed(args: &[&str], out: bool, err: bool) -> Output {
    let pipe = || {
        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        Stdio::from(writer)
    };
    let mut c = bin();
    c.args(args);
    c.stdout(if out { pipe() } else { Stdio::piped() });
    c.stderr(if err { pipe() } else { Stdio::piped() });
    c.output().expect("binary runs")
}

#[test]
fn closed_streams_lose_text_not_work() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let check = |o: &Output, what: &str| {
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(0), "{what}: {err}");
        assert!(!err.contains("panicked"), "{what}: {err}");
    };
    // Text on stdout only.
    let o = closed(&["info", "--data", s(&grid), "--camera", "0"], true, false);
    check(&o, "info --camera");
    // An evaluation prints its table, then writes its JSON: the JSON is written.
    let json = tmp.path().join("eval.json");
    let args = [
        "eval",
        "--data",
        s(&grid),
        "--method",
        "psv-mean",
        "--out",
        s(&json),
    ];
    for (out, err) in [(true, false), (false, true), (true, true)] {
        let _ = std::fs::remove_file(&json);
        let o = closed(&args, out, err);
        check(
            &o,
            &format!("eval, stdout closed {out}, stderr closed {err}"),
        );
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert!(report.is_object() || report.is_array());
    }
    // The learned model's inference with both closed: the MPI is written.
    let mpi = tmp.path().join("mpi");
    let o = closed(
        &[
            "infer",
            "--data",
            s(&grid),
            "--planes",
            "8",
            "--out",
            s(&mpi),
        ],
        true,
        true,
    );
    check(&o, "infer");
    assert!(mpi.join("mpi.json").is_file());
}

#[test]
fn outputs_are_never_pipes_devices_or_dashes() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let eval = |out: &str| {
        bin()
            .args([
                "eval",
                "--data",
                s(&grid),
                "--method",
                "nearest",
                "--out",
                out,
            ])
            .output()
            .unwrap()
    };
    fails_with(&eval("-"), &["--out -", "not standard output"]);
    fails_with(&eval("/dev/null"), &["/dev/null", "give a file name"]);
    fails_with(&eval("/dev/stdout"), &["/dev/stdout", "give a file name"]);
    let fifo = tmp.path().join("fifo");
    assert!(
        std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    fails_with(&eval(s(&fifo)), &["not a regular file", "pipe"]);
    {
        use std::os::unix::fs::FileTypeExt as _;
        assert!(
            std::fs::symlink_metadata(&fifo)
                .unwrap()
                .file_type()
                .is_fifo()
        );
    }
    // A link to a device is refused too.
    let link = tmp.path().join("null.json");
    std::os::unix::fs::symlink("/dev/null", &link).unwrap();
    fails_with(&eval(s(&link)), &["null.json", "give a file name"]);
    succeeds(&eval(s(&tmp.path().join("ok.json"))));
}
