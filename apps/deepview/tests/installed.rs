//! The program carries what it needs except data: a copy of the binary alone in an empty folder, run from
//! another folder with no `DEEPVIEW_*` variables, infers with the weights compiled into it (the
//! repository's `weights/cpu`, read from memory) and trains with the VGG weights it is given, and it does
//! not find VGG weights through the repository it was built in even though they are there.

mod common;

use common::{files, s, succeeds};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

#[test]
fn a_copied_binary_infers_and_trains_from_another_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let bin: PathBuf = tmp.path().join("bin/deepview");
    std::fs::create_dir_all(bin.parent().unwrap()).unwrap();
    std::fs::copy(env!("CARGO_BIN_EXE_deepview"), &bin).unwrap();
    let work = tmp.path().join("work");
    std::fs::create_dir_all(&work).unwrap();
    let run = |args: &[&str]| -> Output {
        Command::new(&bin)
            .current_dir(&work)
            .env_remove("DEEPVIEW_DATA")
            .args(args)
            .output()
            .expect("binary runs")
    };
    succeeds(&run(&[
        "synth", "--out", "grid", "--grid", "3", "--width", "96", "--height", "64", "--planes", "8",
    ]));
    // The built-in weights are the repository's weights/cpu.
    succeeds(&run(&[
        "infer", "--data", "grid", "--inputs", "0,2,6,8", "--out", "a",
    ]));
    let repo_weights = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../weights/cpu");
    succeeds(&run(&[
        "infer",
        "--data",
        "grid",
        "--inputs",
        "0,2,6,8",
        "--weights",
        s(&repo_weights),
        "--out",
        "b",
    ]));
    assert!(files(&work.join("a")) == files(&work.join("b")));
    // `builtin` names them where a weights folder is asked for: for a method, and to fine-tune.
    succeeds(&run(&[
        "infer",
        "--data",
        "grid",
        "--inputs",
        "0,2,6,8",
        "--weights",
        "builtin",
        "--out",
        "c",
    ]));
    assert!(files(&work.join("a")) == files(&work.join("c")));
    succeeds(&run(&[
        "train", "--data", "grid", "--init", "builtin", "--name", "ft", "--steps", "2", "--crop",
        "8", "--planes", "4", "--loss", "l1", "--quiet",
    ]));
    let cfg = std::fs::read_to_string(work.join("runs/ft/config.json")).unwrap();
    assert!(cfg.contains("\"init\": \"builtin\""), "{cfg}");

    // Training with the VGG loss needs its weights named: without them, a clear error before any work.
    let train = [
        "train",
        "--data",
        "synthetic:two-planes",
        "--name",
        "r",
        "--steps",
        "2",
        "--crop",
        "8",
    ];
    let train: Vec<&str> = train
        .iter()
        .copied()
        .chain(["--planes", "4", "--quiet"])
        .collect();
    let vgg = deepview_data::data_dir().join("vgg16/vgg16_conv1_1-conv3_3.safetensors");
    assert!(
        vgg.is_file(),
        "VGG weights missing at {} (set DEEPVIEW_DATA)",
        vgg.display()
    );
    // The environment variable of earlier releases, DEEPVIEW_VGG_WEIGHTS, is not read (nor named).
    let o = Command::new(&bin)
        .current_dir(&work)
        .env_remove("DEEPVIEW_DATA")
        .env("DEEPVIEW_VGG_WEIGHTS", &vgg)
        .args(&train)
        .output()
        .expect("binary runs");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--vgg-weights") && err.contains("--loss l1"),
        "{err}"
    );
    assert!(!err.contains("DEEPVIEW_VGG_WEIGHTS"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!work.join("runs/r/config.json").exists());
    let with: Vec<&str> = train
        .iter()
        .copied()
        .chain(["--vgg-weights", s(&vgg)])
        .collect();
    succeeds(&run(&with));
    assert!(work.join("runs/r/config.json").is_file());
    // The run keeps the file it was given: --resume needs no --vgg-weights.
    succeeds(&run(&[
        "train", "--name", "r", "--resume", "--steps", "3", "--quiet",
    ]));
    assert_eq!(common::metric_steps(&work.join("runs/r")), [1, 2, 3]);
}
