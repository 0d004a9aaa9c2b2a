//! What the integration tests share (`mod common;` in each test crate; `tests/cli` includes it by path):
//! running the binary, checking its successes and failures, a small synthetic scene, files and runs.
#![allow(dead_code)] // each test crate uses some of these

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The binary under test, with the shared data folder of the tests in `DEEPVIEW_DATA` (the VGG weights
/// are passed with `--vgg-weights`).
pub fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_deepview"));
    c.env("DEEPVIEW_DATA", deepview_data::data_dir());
    c
}

pub fn deepview(args: &[&str]) -> Output {
    bin().args(args).output().expect("binary runs")
}

/// [`deepview`] run from `dir`.
pub fn deepview_in(dir: &Path, args: &[&str]) -> Output {
    bin()
        .current_dir(dir)
        .args(args)
        .output()
        .expect("binary runs")
}

pub fn data() -> PathBuf {
    let d = deepview_data::data_dir();
    assert!(
        d.join("llff/fern").is_dir(),
        "shared data missing at {} (set DEEPVIEW_DATA)",
        d.display()
    );
    d
}

/// Asserts a clean failure: exit code 2, no panic or abort, and every `needle` in stderr.
pub fn fails_with(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    for bad in ["panicked", "memory allocation", "RUST_BACKTRACE"] {
        assert!(!err.contains(bad), "{bad}: {err}");
    }
    for n in needles {
        assert!(err.contains(n), "{n:?} not in: {err}");
    }
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A synthetic 3 x 3 light-field grid of `width x height` views (8 planes) with its ground-truth MPI, in
/// `dir/name`.
pub fn grid(dir: &Path, name: &str, width: u32, height: u32) -> PathBuf {
    let out = dir.join(name);
    let (w, h) = (width.to_string(), height.to_string());
    succeeds(&deepview(&[
        "synth",
        "--out",
        s(&out),
        "--grid",
        "3",
        "--width",
        &w,
        "--height",
        &h,
        "--planes",
        "8",
    ]));
    out
}

/// [`grid`] of 96 x 64 views in `dir/grid`.
pub fn synth_grid(dir: &Path) -> PathBuf {
    grid(dir, "grid", 96, 64)
}

/// Asserts success and returns stdout.
pub fn succeeds(out: &Output) -> String {
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Asserts success and returns stderr.
pub fn succeeds_err(out: &Output) -> String {
    succeeds(out);
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Copies the files of `src` (recursively) into a new folder `dst`.
pub fn copy_dir(src: &Path, dst: &Path) -> PathBuf {
    std::fs::create_dir_all(dst).unwrap();
    for f in std::fs::read_dir(src).unwrap() {
        let f = f.unwrap().path();
        let to = dst.join(f.file_name().unwrap());
        if f.is_dir() {
            copy_dir(&f, &to);
        } else {
            std::fs::copy(&f, &to).unwrap();
        }
    }
    dst.to_path_buf()
}

/// The files of a folder (not recursive), by name, with their bytes.
pub fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let p = e.unwrap().path();
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

/// The steps of a run's `metrics.jsonl`, in order.
pub fn metric_steps(run: &Path) -> Vec<u64> {
    let text = std::fs::read_to_string(run.join("metrics.jsonl")).unwrap();
    text.lines()
        .map(|l| {
            let v: serde_json::Value =
                serde_json::from_str(l).unwrap_or_else(|e| panic!("bad metrics line {l:?}: {e}"));
            v["step"].as_u64().unwrap()
        })
        .collect()
}
