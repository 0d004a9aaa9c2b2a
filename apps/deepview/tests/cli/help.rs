//! Every command's `--help`, and the spellings of earlier releases, now usage errors.

use crate::common::{deepview, fails_with, s, succeeds};

/// Every command's `--help` ends with examples in the one scheme (`--data DIR` for a dataset, `--mpi DIR`,
/// `--out`); the old spellings (`--scene`, `--cameras`, bare folders) are errors and not shown.
#[test]
fn every_command_help_shows_examples_in_the_one_scheme() {
    let reads_data = [
        "synth", "psv", "render", "depth", "info", "eval", "train", "infer",
    ];
    let commands = [
        "demo",
        "synth",
        "psv",
        "render",
        "depth",
        "info",
        "view",
        "export-web",
        "export",
        "import",
        "eval",
        "train",
        "infer",
        "export-weights",
        "compact",
        "diff",
        "process",
        "bench",
        "bench render",
        "bench net",
        "bench train",
        "bench scenes",
    ];
    for cmd in commands {
        let mut args: Vec<&str> = cmd.split(' ').collect();
        args.push("--help");
        let help = succeeds(&deepview(&args));
        let at = help
            .find("Example")
            .unwrap_or_else(|| panic!("{cmd} --help has no example: {help}"));
        let examples = &help[at..];
        assert!(
            examples.contains(&format!("deepview {cmd} ")),
            "{cmd}: {examples}"
        );
        if reads_data.contains(&cmd) {
            assert!(
                examples.contains("--data ") && help.contains("--data"),
                "{cmd}: {help}"
            );
            assert!(
                help.contains("--downscale") && help.contains("--images"),
                "{cmd}"
            );
        }
        assert!(!help.contains("--scene"), "{cmd}: {help}");
        assert!(!help.contains("--cameras"), "{cmd}: {help}");
    }
    for cmd in ["infer", "eval", "demo"] {
        let help = succeeds(&deepview(&[cmd, "--help"]));
        assert!(
            help.contains("[default: auto]") && help.contains("--max-memory"),
            "{cmd}: {help}"
        );
    }
}

/// The options and values of earlier releases are usage errors (exit 2, no panic), before any work: each
/// names the one spelling, most with a hint line. (`deepview baseline` / `optimize` and bare folders:
/// `baseline.rs`; `render --scene`: `render.rs`; old run configs: `train.rs`.)
#[test]
fn old_option_spellings_are_usage_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let (data, weights, out) = (t.join("scene"), t.join("weights"), t.join("out"));
    std::fs::create_dir_all(&data).unwrap();
    std::fs::create_dir_all(&weights).unwrap();
    let (d, w, o) = (s(&data), s(&weights), s(&out));
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        // `--checkpoint` for the weights of the learned model.
        (
            vec!["infer", "--data", d, "--checkpoint", w, "--out", o],
            vec![
                "'--checkpoint'",
                "hint: the weights of a method are --weights DIR",
            ],
        ),
        (
            vec![
                "eval",
                "--data",
                d,
                "--method",
                "deepview",
                "--checkpoint",
                w,
            ],
            vec![
                "'--checkpoint'",
                "hint: the weights of a method are --weights DIR",
            ],
        ),
        (
            vec!["demo", "--checkpoint", w, "--out", o],
            vec![
                "'--checkpoint'",
                "hint: the weights of a method are --weights DIR",
            ],
        ),
        // `synth --cameras`.
        (
            vec!["synth", "--cameras", d, "--out", o],
            vec!["'--cameras'", "hint: a dataset is --data DIR"],
        ),
        // Method names.
        (
            vec!["infer", "--data", d, "--method", "psvmean", "--out", o],
            vec!["'psvmean'", "psv-mean"],
        ),
        (
            vec!["eval", "--data", d, "--method", "psv_mean"],
            vec!["'psv_mean'", "psv-mean"],
        ),
        (
            vec!["infer", "--data", d, "--method", "optimise", "--out", o],
            vec!["'optimise'", "optimize"],
        ),
        // `train --weights` (now only `--init`).
        (
            vec!["train", "--data", d, "--name", "r", "--weights", w],
            vec!["'--weights'"],
        ),
        // export-weights: a bare checkpoint, `--run`.
        (
            vec!["export-weights", w, "--out", o],
            vec!["hint: folders are named by their option"],
        ),
        (
            vec!["export-weights", "--run", w, "--out", o],
            vec!["'--run'", "hint: export-weights takes --checkpoint DIR"],
        ),
    ];
    for (args, needles) in &cases {
        let r = crate::common::deepview_in(t, args);
        fails_with(&r, needles);
        assert!(!out.exists(), "{args:?} wrote {o}");
        assert!(!t.join("runs").exists(), "{args:?} started a run");
    }
}
