//! `mpirun -np N deepview train ...` (feature `openmpi`; needs Open MPI's `mpirun`): N ranks end with the
//! weights of one process on the same global batch, an error or a killed rank stops the whole job, and
//! the run resumes on N ranks.
//!
//! `cargo test --release -p deepview --features openmpi --test mpi` (about 30 s; VGG weights passed with
//! `--vgg-weights` from the data folder, `DEEPVIEW_DATA`).
#![cfg(feature = "openmpi")]

mod common;

use common::{metric_steps, s, succeeds_err};
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_deepview");

fn mpirun(np: usize, args: &[&str]) -> Command {
    let mut c = Command::new("mpirun");
    c.args([
        "--allow-run-as-root",
        "--oversubscribe",
        "-np",
        &np.to_string(),
        BIN,
    ])
    .args(args);
    c
}

/// Run `c`, failing the test (after killing it) if it takes longer than `limit`.
fn output_within(mut c: Command, limit: Duration) -> Output {
    let mut child = c
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            child.kill().ok();
            panic!("still running after {limit:?} (ranks hang?)");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// name -> f32 values of a safetensors file.
fn weights(path: &Path) -> std::collections::BTreeMap<String, Vec<f32>> {
    let bytes = std::fs::read(path).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let data = &bytes[8 + n..];
    header
        .as_object()
        .unwrap()
        .iter()
        .filter(|(k, _)| *k != "__metadata__")
        .map(|(k, v)| {
            assert_eq!(v["dtype"], "F32");
            let o = &v["data_offsets"];
            let (a, b) = (
                o[0].as_u64().unwrap() as usize,
                o[1].as_u64().unwrap() as usize,
            );
            let values = data[a..b]
                .chunks(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
                .collect();
            (k.clone(), values)
        })
        .collect()
}

fn exported(run: &Path) -> std::collections::BTreeMap<String, Vec<f32>> {
    let out = run.with_extension("weights");
    let o = Command::new(BIN)
        .args(["export-weights", "--checkpoint", s(run), "--out", s(&out)])
        .output()
        .unwrap();
    succeeds_err(&o);
    weights(&out.join("model.safetensors"))
}

fn max_abs_diff(
    a: &std::collections::BTreeMap<String, Vec<f32>>,
    b: &std::collections::BTreeMap<String, Vec<f32>>,
) -> f32 {
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    a.iter()
        .flat_map(|(k, va)| va.iter().zip(&b[k]).map(|(x, y)| (x - y).abs()))
        .fold(0.0, f32::max)
}

/// The judged commands: `--steps 3 --batch B --crop 16 --planes 8 --seed 5` (VGG loss) on 2 and 3
/// ranks end within 1e-5 of one process with the same `--batch`.
#[test]
fn ranks_end_with_the_weights_of_one_process() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    let vgg = deepview_data::data_dir().join("vgg16/vgg16_conv1_1-conv3_3.safetensors");
    let common = |batch: &'static str, name: &str| -> Vec<String> {
        [
            "train",
            "--data",
            "synthetic:two-planes",
            "--preset",
            "cpu",
            "--steps",
            "3",
            "--batch",
            batch,
            "--crop",
            "16",
            "--planes",
            "8",
            "--seed",
            "5",
            "--quiet",
            "--runs",
            s(&runs),
            "--name",
            name,
            "--vgg-weights",
            s(&vgg),
        ]
        .iter()
        .map(|a| a.to_string())
        .collect()
    };
    for (batch, nps) in [("2", &[2usize, 3][..]), ("3", &[3][..])] {
        let one = format!("one-b{batch}");
        let o = Command::new(BIN)
            .args(common(batch, &one))
            .output()
            .unwrap();
        succeeds_err(&o);
        let reference = exported(&runs.join(&one));
        for &np in nps {
            let name = format!("np{np}-b{batch}");
            let args = common(batch, &name);
            let args: Vec<&str> = args.iter().map(|a| a.as_str()).collect();
            let err = succeeds_err(&output_within(mpirun(np, &args), Duration::from_secs(120)));
            assert!(err.contains(&format!("on each of {np} MPI ranks")), "{err}");
            let run = runs.join(&name);
            let max = max_abs_diff(&reference, &exported(&run));
            eprintln!("-np {np} --batch {batch}: max abs weight difference {max:e}");
            assert!(
                max <= 1e-5,
                "-np {np} --batch {batch}: weights differ by {max}"
            );
            // Only rank 0 wrote: one metrics line per step.
            assert_eq!(metric_steps(&run), [1, 2, 3]);
        }
    }
}

fn small(runs: &Path, name: &str, steps: &str) -> Vec<String> {
    [
        "train",
        "--data",
        "synthetic:two-planes",
        "--preset",
        "cpu",
        "--steps",
        steps,
        "--batch",
        "2",
        "--crop",
        "8",
        "--planes",
        "4",
        "--checkpoint-every",
        "2",
        "--loss",
        "l1",
        "--quiet",
        "--runs",
        s(runs),
        "--name",
        name,
    ]
    .iter()
    .map(|a| a.to_string())
    .collect()
}

#[test]
fn an_error_on_a_rank_stops_all_ranks_with_the_rank_and_the_reason() {
    let tmp = tempfile::tempdir().unwrap();
    let mut args = small(tmp.path(), "bad", "4");
    args.extend(["--devices".into(), "cuda:local".into()]);
    let args: Vec<&str> = args.iter().map(|a| a.as_str()).collect();
    let out = output_within(mpirun(2, &args), Duration::from_secs(60));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("error: rank "), "{err}");
    assert!(err.contains(" of 2: device `cuda:local`"), "{err}");
    assert!(err.contains("stopping all ranks"), "{err}");
}

/// A rank killed with SIGKILL (a lost node) ends the job; `--resume` on the ranks continues from the
/// last complete checkpoint, with each step once in the metrics.
#[test]
fn a_killed_rank_ends_the_job_and_the_run_resumes_on_all_ranks() {
    let tmp = tempfile::tempdir().unwrap();
    let args = small(tmp.path(), "k", "1000");
    let run = tmp.path().join("k");
    let argv: Vec<&str> = args.iter().map(|a| a.as_str()).collect();
    let mut job = mpirun(2, &argv)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !run.join("checkpoints/step-0000006").is_dir() {
        assert!(start.elapsed() < Duration::from_secs(60), "no checkpoint");
        std::thread::sleep(Duration::from_millis(10));
    }
    // The ranks are mpirun's children: kill the last one.
    let pgrep = Command::new("pgrep")
        .args(["-P", &job.id().to_string()])
        .output()
        .unwrap();
    let pids = String::from_utf8_lossy(&pgrep.stdout).to_string();
    let rank = pids
        .lines()
        .last()
        .expect("a rank process")
        .trim()
        .to_string();
    assert!(
        Command::new("kill")
            .args(["-9", &rank])
            .status()
            .unwrap()
            .success()
    );
    let start = Instant::now();
    let status = loop {
        if let Some(st) = job.try_wait().unwrap() {
            break st;
        }
        if start.elapsed() > Duration::from_secs(60) {
            job.kill().ok();
            panic!("the job goes on after one rank was killed");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(!status.success());
    let mut resume = small(tmp.path(), "k", "40");
    resume.push("--resume".into());
    let resume: Vec<&str> = resume.iter().map(|a| a.as_str()).collect();
    let err = succeeds_err(&output_within(mpirun(2, &resume), Duration::from_secs(120)));
    assert!(err.contains("on 2 MPI ranks"), "{err}");
    assert_eq!(metric_steps(&run), (1..=40).collect::<Vec<_>>());
    exported(&run);
}
