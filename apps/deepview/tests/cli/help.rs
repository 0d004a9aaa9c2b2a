//! Every command's `--help`.

use crate::common::{deepview, succeeds};

/// Every command's `--help` ends with examples in the one scheme (`--data DIR` for a dataset, `--mpi DIR`,
/// `--out`); the old spellings are accepted but not shown.
#[test]
fn every_command_help_shows_examples_in_the_one_scheme() {
    let reads_data = [
        "synth", "psv", "render", "depth", "info", "eval", "optimize", "train", "infer", "baseline",
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
        "optimize",
        "train",
        "infer",
        "export-weights",
        "baseline",
    ];
    for cmd in commands {
        let help = succeeds(&deepview(&[cmd, "--help"]));
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
    }
    for cmd in ["infer", "eval", "baseline", "optimize", "demo"] {
        let help = succeeds(&deepview(&[cmd, "--help"]));
        assert!(
            help.contains("[default: auto]") && help.contains("--max-memory"),
            "{cmd}: {help}"
        );
    }
}
