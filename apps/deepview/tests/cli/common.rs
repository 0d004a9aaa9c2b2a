//! What every command's tests share: running the binary, checking its failures, a small synthetic scene.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn deepview(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_deepview"))
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

/// Asserts a clean failure: exit code 2, no panic, and every `needle` in stderr.
pub fn fails_with(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not in: {err}");
    }
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

pub fn synth_grid(dir: &Path) -> PathBuf {
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
