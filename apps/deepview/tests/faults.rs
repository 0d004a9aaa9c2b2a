//! Runs that survive faults: `deepview train` killed with SIGKILL at random moments resumes from its
//! last complete checkpoint and ends exactly where an uninterrupted run ends; a full disk or a read-only
//! runs folder stops the run with a clear message and keeps the previous checkpoint; old checkpoints
//! are pruned (`--keep-checkpoints`).
//!
//! `cargo test --release -p deepview --test faults` (about 40 s). The disk tests mount small tmpfs
//! folders when run as root (CI); otherwise they take away write permissions instead.

mod common;

use common::{bin, metric_steps, s, succeeds};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant, SystemTime};

/// A tiny training run: the cpu preset on 8x8 crops with 4 planes, L1 loss, a checkpoint every 2 steps
/// (about 20 steps per second).
fn train_args(runs: &Path, name: &str, steps: u64) -> Vec<String> {
    let steps = steps.to_string();
    [
        "train",
        "--data",
        "synthetic:two-planes",
        "--preset",
        "cpu",
        "--steps",
        &steps,
        "--batch",
        "1",
        "--crop",
        "8",
        "--planes",
        "4",
        "--checkpoint-every",
        "2",
        "--loss",
        "l1",
        "--seed",
        "3",
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

fn run(args: &[String]) -> Output {
    bin().args(args).output().expect("binary runs")
}

fn spawn(args: &[String]) -> Child {
    bin()
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("binary runs")
}

/// xorshift64*, seeded from the clock (or `DEEPVIEW_FAULT_SEED`); the seed is printed so a failure can
/// be replayed.
struct Rng(u64);

impl Rng {
    fn from_env_or_clock() -> Self {
        let seed = std::env::var("DEEPVIEW_FAULT_SEED")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| {
                SystemTime::now()
                    .duration_since(SystemTime::UNIX_EPOCH)
                    .unwrap()
                    .as_nanos() as u64
            });
        eprintln!("fault seed {seed} (replay with DEEPVIEW_FAULT_SEED={seed})");
        Rng(seed | 1)
    }

    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform in `[lo, hi)` milliseconds.
    fn millis(&mut self, lo: u64, hi: u64) -> Duration {
        Duration::from_millis(lo + self.next() % (hi - lo))
    }
}

/// Start `args`, SIGKILL it after `delay` (if it has not finished by then). Returns whether it was
/// killed.
fn kill_after(args: &[String], delay: Duration) -> bool {
    let mut child = spawn(args);
    let start = Instant::now();
    while start.elapsed() < delay {
        if child.try_wait().unwrap().is_some() {
            return false;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let killed = child.try_wait().unwrap().is_none();
    child.kill().ok(); // SIGKILL
    child.wait().unwrap();
    killed
}

fn folder_names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    v.sort();
    v
}

/// Tensor name -> raw little-endian data of a safetensors file (the header's metadata and the order of
/// the tensors may differ between two files of the same weights).
type Tensors = std::collections::BTreeMap<String, Vec<u8>>;

fn safetensors(path: &Path) -> Tensors {
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
            let o = &v["data_offsets"];
            let (a, b) = (
                o[0].as_u64().unwrap() as usize,
                o[1].as_u64().unwrap() as usize,
            );
            (k.clone(), data[a..b].to_vec())
        })
        .collect()
}

/// The exported weights of the run's latest checkpoint (`export-weights`, which loads it).
fn exported_weights(run: &Path, out: &Path) -> Tensors {
    succeeds(
        &bin()
            .args(["export-weights", "--checkpoint", s(run), "--out", s(out)])
            .output()
            .unwrap(),
    );
    safetensors(&out.join("model.safetensors"))
}

/// The state a finished run must be in: `steps` steps, one metrics line per step in order, complete
/// checkpoints only (the last 3, every one loadable), no temporary leftovers.
fn check_finished(run: &Path, steps: u64, tmp: &Path) -> Tensors {
    assert_eq!(
        metric_steps(run),
        (1..=steps).collect::<Vec<_>>(),
        "metrics.jsonl of {}",
        run.display()
    );
    let cks = folder_names(&run.join("checkpoints"));
    let want: Vec<String> = (steps - 4..=steps)
        .step_by(2)
        .map(|n| format!("step-{n:07}"))
        .collect();
    assert_eq!(cks, want, "checkpoints of {}", run.display());
    for ck in &cks {
        let out = tmp.join(format!("export-{ck}"));
        let ck = run.join("checkpoints").join(ck);
        succeeds(
            &bin()
                .args(["export-weights", "--checkpoint", s(&ck), "--out", s(&out)])
                .output()
                .unwrap(),
        );
        let state: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(ck.join("state.json")).unwrap()).unwrap();
        assert!(state["step"].as_u64().unwrap() <= steps);
    }
    let leftovers: Vec<String> = folder_names(run)
        .into_iter()
        .filter(|n| n.contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    exported_weights(run, &tmp.join("final"))
}

#[test]
fn killed_at_random_moments_the_run_resumes_and_ends_like_an_uninterrupted_one() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    let steps = 24;
    // The reference: one uninterrupted run. Its length (start-up included) bounds the kill moments, so
    // that they land within a run however fast training is on this machine.
    let t0 = Instant::now();
    succeeds(&run(&train_args(&runs, "straight", steps)));
    let span = (t0.elapsed().as_millis() as u64).max(100);
    let straight = check_finished(&runs.join("straight"), steps, &tmp.path().join("straight"));

    let mut rng = Rng::from_env_or_clock();
    // Each trial: a new run killed once at a random moment (start-up, a step, a checkpoint write or
    // the end), then `--resume` until done.
    let trials = 10;
    let mut killed = 0;
    for trial in 0..trials {
        let name = format!("trial-{trial}");
        let mut args = train_args(&runs, &name, steps);
        killed += kill_after(&args, rng.millis(0, span + span / 10)) as usize;
        args.push("--resume".into());
        succeeds(&run(&args));
        let w = check_finished(&runs.join(&name), steps, &tmp.path().join(&name));
        assert!(
            w == straight,
            "trial {trial}: weights differ from the uninterrupted run"
        );
    }
    // One run killed again and again while it resumes (kills during resumes, torn metrics lines,
    // checkpoints written by earlier sessions), then finished.
    let name = "chain";
    let mut args = train_args(&runs, name, steps);
    args.push("--resume".into());
    let mut chain = 0;
    for _ in 0..12 {
        chain += kill_after(&args, rng.millis(10, (span / 4).max(20))) as usize;
    }
    succeeds(&run(&args));
    let w = check_finished(&runs.join(name), steps, &tmp.path().join(name));
    assert!(
        w == straight,
        "chain: weights differ from the uninterrupted run"
    );
    eprintln!(
        "{killed} of {trials} trials and {chain} of 12 chained sessions were killed mid-run (an \
         uninterrupted run takes {span} ms)"
    );
    assert!(killed + chain >= 10, "too few kills landed mid-run");
}

#[test]
fn a_run_killed_before_its_config_json_starts_on_resume() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    // What a run killed inside `Trainer::create` leaves: an empty checkpoints/, the lock file and the
    // temporary file of config.json (the rename not yet done).
    let make = |name: &str| {
        let run = runs.join(name);
        std::fs::create_dir_all(run.join("checkpoints")).unwrap();
        std::fs::write(run.join(".lock"), b"").unwrap();
        std::fs::write(run.join(".config.json.4242.tmp"), b"{\"model\": ").unwrap();
        run
    };
    let run_dir = make("k");
    let mut args = train_args(&runs, "k", 6);
    args.push("--resume".into());
    succeeds(&run(&args));
    check_finished(&run_dir, 6, &tmp.path().join("k"));
    // A folder holding anything else is not taken for a run.
    let other = make("other");
    std::fs::write(other.join("notes.txt"), b"mine").unwrap();
    let mut args = train_args(&runs, "other", 4);
    args.push("--resume".into());
    let out = run(&args);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("is not a training run"));
    assert_eq!(std::fs::read(other.join("notes.txt")).unwrap(), b"mine");
}

#[test]
fn keep_checkpoints_prunes_old_ones() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    let mut args = train_args(&runs, "k", 10);
    args.extend(["--keep-checkpoints".into(), "2".into()]);
    succeeds(&run(&args));
    assert_eq!(
        folder_names(&runs.join("k/checkpoints")),
        ["step-0000008", "step-0000010"]
    );
    // On resume the option overrides the run's setting.
    let mut args = train_args(&runs, "k", 14);
    args.extend(["--resume".into(), "--keep-checkpoints".into(), "1".into()]);
    succeeds(&run(&args));
    assert_eq!(folder_names(&runs.join("k/checkpoints")), ["step-0000014"]);
    assert_eq!(metric_steps(&runs.join("k")), (1..=14).collect::<Vec<_>>());
    // A checkpoint folder holding a file of the user's is kept, and the warning names the file.
    let note = runs.join("k/checkpoints/step-0000014/notes.txt");
    std::fs::write(&note, b"mine").unwrap();
    let mut args = train_args(&runs, "k", 18);
    args.extend(["--resume".into(), "--keep-checkpoints".into(), "1".into()]);
    let out = run(&args);
    succeeds(&out);
    assert_eq!(std::fs::read(&note).unwrap(), b"mine");
    assert_eq!(
        folder_names(&runs.join("k/checkpoints")),
        ["step-0000014", "step-0000018"]
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("notes.txt"), "{err}");
    // Said once, not at every checkpoint after it (16 and 18).
    assert_eq!(err.matches("kept the old checkpoint").count(), 1, "{err}");
}

/// A tmpfs of `size` mounted on `dir` while it lives (root only).
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(dir: &Path, size: &str) -> Option<Tmpfs> {
        std::fs::create_dir_all(dir).unwrap();
        let ok = Command::new("mount")
            .args([
                "-t",
                "tmpfs",
                "-o",
                &format!("size={size}"),
                "tmpfs",
                s(dir),
            ])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|st| st.success());
        ok.then(|| Tmpfs(dir.to_path_buf()))
    }

    /// Remount with `opts`; retried, as a read-only remount is refused (busy) while a file is open for
    /// writing (the trainer writing a checkpoint at that moment).
    fn remount(&self, opts: &str) {
        for _ in 0..200 {
            let st = Command::new("mount")
                .args(["-o", &format!("remount,{opts}"), s(&self.0)])
                .stderr(Stdio::null())
                .status()
                .unwrap();
            if st.success() {
                return;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        panic!("cannot remount {} with {opts}", self.0.display());
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").args(["-l", s(&self.0)]).status();
    }
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

/// Asserts a failed run that says why and which checkpoint is kept.
fn fails_keeping(out: &Output, needles: &[&str], kept: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles.iter().chain(&[kept, "is kept", "--resume"]) {
        assert!(err.contains(n), "{n:?} not in: {err}");
    }
}

#[test]
fn a_full_disk_fails_the_step_and_keeps_the_previous_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    // 300 KiB: room for two checkpoints of the cpu preset (132 KiB each), not a third.
    let Some(fs) = Tmpfs::mount(&runs, "300k") else {
        eprintln!("skipped: cannot mount a tmpfs here (not root, or no permission)");
        return;
    };
    let args = train_args(&runs, "full", 20);
    let out = run(&args);
    fails_keeping(&out, &["No space left on device"], "step-0000004");
    let run_dir = runs.join("full");
    assert_eq!(
        folder_names(&run_dir.join("checkpoints")),
        ["step-0000002", "step-0000004"],
        "the failed checkpoint's temporary folder is removed"
    );
    // Free space: --resume continues from step 4 and finishes.
    fs.remount("size=4m");
    let mut resume = args.clone();
    resume.push("--resume".into());
    succeeds(&run(&resume));
    check_finished(&run_dir, 20, tmp.path());
}

#[test]
fn a_runs_folder_that_turns_read_only_fails_the_step_and_keeps_the_previous_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    let fs = Tmpfs::mount(&runs, "4m");
    if fs.is_none() && is_root() {
        eprintln!("skipped: root without permission to mount (write permissions do not bind root)");
        return;
    }
    let args = train_args(&runs, "ro", 200);
    let run_dir = runs.join("ro");
    let child = bin()
        .args(&args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !run_dir.join("checkpoints/step-0000004").is_dir() {
        assert!(start.elapsed() < Duration::from_secs(60), "no checkpoint");
        std::thread::sleep(Duration::from_millis(5));
    }
    let make_writable = |writable: bool| match &fs {
        Some(fs) => fs.remount(if writable { "rw" } else { "ro" }),
        None => {
            use std::os::unix::fs::PermissionsExt;
            let (dir_mode, file_mode) = if writable {
                (0o755, 0o644)
            } else {
                (0o555, 0o444)
            };
            for p in [run_dir.join("checkpoints"), run_dir.clone()] {
                std::fs::set_permissions(&p, std::fs::Permissions::from_mode(dir_mode)).unwrap();
            }
            std::fs::set_permissions(
                run_dir.join("metrics.jsonl"),
                std::fs::Permissions::from_mode(file_mode),
            )
            .unwrap();
        }
    };
    make_writable(false);
    let out = child.wait_with_output().unwrap();
    let kept = list_complete(&run_dir).pop().expect("a checkpoint");
    make_writable(true);
    let needle = if fs.is_some() {
        "Read-only file system"
    } else {
        "Permission denied"
    };
    fails_keeping(&out, &[needle], &kept);
    let mut resume = args.clone();
    resume[6] = "30".into(); // --steps: finish soon
    assert_eq!(args[5], "--steps");
    resume.push("--resume".into());
    let out = run(&resume);
    succeeds(&out);
    let err = String::from_utf8_lossy(&out.stderr);
    let at = kept.trim_start_matches("step-").parse::<u64>().unwrap();
    assert!(
        err.contains(&format!(
            "resuming {} at step {at} of 30",
            run_dir.display()
        )),
        "{err}"
    );
    check_finished(&run_dir, 30, tmp.path());
}

fn list_complete(run: &Path) -> Vec<String> {
    folder_names(&run.join("checkpoints"))
        .into_iter()
        .filter(|n| n.starts_with("step-"))
        .collect()
}
