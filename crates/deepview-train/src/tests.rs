//! Training tests (release: `cargo test --release -p deepview-train`).

use super::*;
use crate::loss::{Loss, LossKind};
use crate::reduce;
use crate::synthetic::two_plane_scene;
use crate::vgg::Vgg16;
use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor};
use deepview_net::config::DeepViewConfig;
use deepview_net::device::parse_device;
use deepview_net::network::DeepViewModel;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// A tiny network (2 nets, 1 max-pool stage, 8 features: receptive-field margin 6 px per net) so tests
/// run in seconds.
fn tiny_model() -> DeepViewConfig {
    DeepViewConfig {
        name: "tiny".into(),
        views: None,
        train_planes: 4,
        infer_planes: 4,
        updates: 1,
        features_large: 8,
        features_small: 8,
        large_nets: 2,
        unet_nets: 0,
        extra_channels: 4,
        max_pool_stages: 1,
        init_prior: None,
        prior_radius: 0,
        prior_weight: 1.0,
        prior_radius_size: None,
        prior_smoothing: None,
        prior_census: None,
        prior_leave_one_out: None,
        prior_sample_variance: false,
        infer_mpi_scale: None,
    }
}

/// A small, fast setup: the tiny network, L1 loss, 16x16 crops on a 3x3 synthetic rig.
fn small_config(steps: u64, devices: &[&str], batch: usize) -> RunConfig {
    let model = tiny_model();
    let mut train = TrainConfig::defaults(&model);
    train.steps = steps;
    train.batch = batch;
    train.sample = SampleConfig {
        crop: 16,
        views_min: 2,
        views_max: 3,
        planes: 4,
        jitter: true,
        auto_planes: false,
        colour_jitter: false,
        wide_inputs: 0.0,
        surround_inputs: 0.0,
        spread_inputs: 0.0,
        window_context: false,
        budget: None,
    };
    train.loss = LossKind::L1;
    train.checkpoint_every = 1000;
    train.seed = 7;
    train.devices = devices.iter().map(|s| s.to_string()).collect();
    train.data = vec![DataSpec::new(SYNTHETIC_TWO_PLANES, Default::default())];
    RunConfig { model, train }
}

fn small_data() -> TrainData {
    TrainData::new(vec![two_plane_scene(3, 3, 40, 0.12)]).unwrap()
}

/// Give `t` the initial weights of `model` (with the same parameter ids). Runs compared bit for bit must
/// start from the same weights: burn's global RNG (model initialisation) is shared by the tests running
/// concurrently in this process, so a seed alone does not pin the initial weights here.
fn same_start(model: &DeepViewModel, t: &mut Trainer) {
    parameter_values(model); // materialise lazily initialised parameters before cloning
    t.model = model.clone();
}

fn never() -> AtomicBool {
    AtomicBool::new(false)
}

#[test]
fn resume_continues_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let straight = dir.path().join("straight");
    let mut a = Trainer::create(&straight, small_config(4, &["cpu"], 1), small_data()).unwrap();
    let a_init = a.model.clone();
    a.run(&never(), &mut |_| {}).unwrap();
    assert_eq!(a.step, 4);

    let split = dir.path().join("split");
    let mut b = Trainer::create(&split, small_config(2, &["cpu"], 1), small_data()).unwrap();
    same_start(&a_init, &mut b);
    b.run(&never(), &mut |_| {}).unwrap();
    drop(b);
    // A second `create` on a run with checkpoints is refused.
    assert!(Trainer::create(&split, small_config(2, &["cpu"], 1), small_data()).is_err());
    let mut b = Trainer::resume(&split, small_data(), Some(4), None).unwrap();
    assert_eq!(b.step, 2);
    b.run(&never(), &mut |_| {}).unwrap();
    assert_eq!(b.step, 4);

    let (wa, wb) = (parameter_values(&a.model), parameter_values(&b.model));
    assert_eq!(wa.len(), wb.len());
    assert!(
        wa.iter().zip(&wb).all(|(x, y)| x.to_bits() == y.to_bits()),
        "weights differ after resume"
    );
    assert_eq!(a.rng, b.rng);
    // The weights did move.
    let fresh = Trainer::create(
        &dir.path().join("fresh"),
        small_config(1, &["cpu"], 1),
        small_data(),
    )
    .unwrap();
    assert!(
        parameter_values(&fresh.model)
            .iter()
            .zip(&wa)
            .any(|(x, y)| x != y)
    );

    // metrics.jsonl has one line per step, in order, across the resume.
    let text = std::fs::read_to_string(split.join("metrics.jsonl")).unwrap();
    let steps: Vec<u64> = text
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["step"]
                .as_u64()
                .unwrap()
        })
        .collect();
    assert_eq!(steps, vec![1, 2, 3, 4]);
    let cfg: RunConfig =
        serde_json::from_str(&std::fs::read_to_string(split.join("config.json")).unwrap()).unwrap();
    assert_eq!(cfg.model.name, "tiny");
}

#[test]
fn checkpoints_are_pruned_to_the_last_three_and_atomic() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = small_config(5, &["cpu"], 1);
    cfg.train.checkpoint_every = 1;
    cfg.train.sample.planes = 2;
    let mut t = Trainer::create(dir.path(), cfg, small_data()).unwrap();
    t.run(&never(), &mut |_| {}).unwrap();
    let cks: Vec<u64> = list_checkpoints(dir.path())
        .unwrap()
        .into_iter()
        .map(|c| c.0)
        .collect();
    assert_eq!(cks, vec![3, 4, 5]);
    let names: Vec<String> = std::fs::read_dir(dir.path().join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    assert!(names.iter().all(|n| n.starts_with("step-")), "{names:?}");
    for f in ["model.bpk", "optimizer.bpk", "state.json"] {
        assert!(
            dir.path()
                .join("checkpoints/step-0000005")
                .join(f)
                .is_file()
        );
    }
}

#[test]
fn stop_flag_saves_and_returns() {
    let dir = tempfile::tempdir().unwrap();
    let mut t = Trainer::create(dir.path(), small_config(100, &["cpu"], 1), small_data()).unwrap();
    let stop = AtomicBool::new(true);
    let reports = t.run(&stop, &mut |_| {}).unwrap();
    assert!(reports.is_empty());
    assert_eq!(list_checkpoints(dir.path()).unwrap().len(), 1);
}

/// The loop reports its start, each step and each checkpoint; a stop flag set while it runs (as the
/// program's signal handler does) ends it after the current step, with a checkpoint of that step.
#[test]
fn events_report_the_run_and_a_stop_during_it_saves_the_last_step() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let mut cfg = small_config(100, &["cpu"], 1);
    cfg.train.checkpoint_every = 2;
    cfg.train.sample.planes = 2;
    let mut t = Trainer::create(&run, cfg, small_data()).unwrap();
    let stop = AtomicBool::new(false);
    let mut seen = Vec::new();
    let reports = t
        .run(&stop, &mut |e| {
            seen.push(match e {
                TrainEvent::Start { step, total } => format!("start {step}/{total}"),
                TrainEvent::Step { report, .. } => {
                    if report.step == 3 {
                        stop.store(true, Ordering::SeqCst);
                    }
                    format!("step {}", report.step)
                }
                TrainEvent::Checkpoint { step, dir } => {
                    assert!(checkpoint_is_complete(dir));
                    format!("checkpoint {step}")
                }
                TrainEvent::Notice(n) => format!("{n}"),
            })
        })
        .unwrap();
    assert_eq!(reports.len(), 3);
    assert_eq!(
        seen,
        [
            "start 0/100",
            "step 1",
            "step 2",
            "checkpoint 2",
            "step 3",
            "checkpoint 3"
        ]
    );
    drop(t);
    // Resuming says what it removed: the leftovers of an interrupted checkpoint write.
    let leftover = run.join("checkpoints/.tmp-step-0000004-1");
    std::fs::create_dir_all(&leftover).unwrap();
    let mut t = Trainer::resume(&run, small_data(), None, None).unwrap();
    assert_eq!(t.step, 3);
    assert_eq!(t.take_notices(), vec![Notice::Removed(leftover.clone())]);
    assert!(!leftover.exists());
    assert!(t.take_notices().is_empty());
}

/// A run killed while writing its first checkpoint has none to resume from and is started over: the
/// temporary folder of that write goes too (it was left behind, found by the fault-injection test).
#[test]
fn starting_over_removes_the_leftovers_of_a_first_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let leftover = run.join("checkpoints/.tmp-step-0000002-7");
    std::fs::create_dir_all(&leftover).unwrap();
    let mut t = Trainer::create(&run, small_config(4, &["cpu"], 1), small_data()).unwrap();
    assert_eq!(t.take_notices(), vec![Notice::Removed(leftover.clone())]);
    assert!(!leftover.exists());
}

/// burn's CPU backend has one random generator per process: trainers created at the same time from
/// the same seed still start from the same weights (their seed-and-draw does not interleave; the
/// `non_finite_loss_skips_the_step` twin failed once in CI when another test's trainer drew between its
/// seed and its draws).
#[test]
fn trainers_created_at_once_start_from_their_seed() {
    let dir = tempfile::tempdir().unwrap();
    let alone = Trainer::create(
        &dir.path().join("alone"),
        small_config(2, &["cpu"], 1),
        small_data(),
    )
    .unwrap();
    let want = parameter_values(&alone.model);
    let got: Vec<Vec<f32>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..6)
            .map(|i| {
                let run = dir.path().join(format!("at-once-{i}"));
                s.spawn(move || {
                    let t =
                        Trainer::create(&run, small_config(2, &["cpu"], 1), small_data()).unwrap();
                    parameter_values(&t.model)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for (i, v) in got.iter().enumerate() {
        assert!(
            v == &want,
            "trainer {i} created alongside others starts elsewhere"
        );
    }
}

#[test]
fn non_finite_loss_skips_the_step() {
    let dir = tempfile::tempdir().unwrap();
    let mut t = Trainer::create(dir.path(), small_config(10, &["cpu"], 2), small_data()).unwrap();
    let before = parameter_values(&t.model);
    let mut batch = t.draw_batch().unwrap();
    batch[1].target_crop.data[5] = f32::NAN;
    let r = t.step_on(batch.clone());
    let msg = r.skipped.expect("skipped");
    assert!(
        msg.contains("non-finite loss") && msg.contains("tuple 1"),
        "{msg}"
    );
    assert_eq!(
        parameter_values(&t.model),
        before,
        "weights touched by a skipped step"
    );
    // The optimizer state is untouched too: the next good step equals a good first step of a twin.
    let mut twin = Trainer::create(
        &dir.path().join("twin"),
        small_config(10, &["cpu"], 2),
        small_data(),
    )
    .unwrap();
    // (The twin's seed gives it `t`'s weights only where nothing else drew meanwhile.)
    same_start(&t.model, &mut twin);
    batch[1].target_crop.data[5] = 0.5;
    assert!(t.step_on(batch.clone()).skipped.is_none());
    assert!(twin.step_on(batch).skipped.is_none());
    assert_eq!(parameter_values(&t.model), parameter_values(&twin.model));
}

/// Two runs of the same small configuration, on one CPU and on `devices`, in `dir`.
fn one_and_replicated(dir: &std::path::Path, devices: &[&str]) -> (Trainer, Trainer) {
    let create = |name: &str, devices: &[&str]| {
        Trainer::create(&dir.join(name), small_config(2, devices, 2), small_data()).unwrap()
    };
    (create("one", &["cpu"]), create("two", devices))
}

/// Largest absolute difference between two parameter lists.
fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max)
}

#[test]
fn two_cpu_replicas_match_one_device() {
    let dir = tempfile::tempdir().unwrap();
    let (mut one, mut two) = one_and_replicated(dir.path(), &["cpu", "cpu"]);
    let start = one.model.clone();
    same_start(&start, &mut two);
    let ra = one.run(&never(), &mut |_| {}).unwrap();
    let rb = two.run(&never(), &mut |_| {}).unwrap();
    for (a, b) in ra.iter().zip(&rb) {
        assert!(
            (a.loss - b.loss).abs() <= 1e-6 * a.loss.abs(),
            "{a:?} vs {b:?}"
        );
    }
    let (wa, wb) = (parameter_values(&one.model), parameter_values(&two.model));
    let max = max_abs_diff(&wa, &wb);
    assert!(max < 1e-6, "replicas diverge from one device by {max}");
    // Two CPU replicas are summed by copies (burn-flex has no collective ops).
    assert_eq!(one.local_reduction(), &LocalReduction::Single);
    assert!(
        matches!(two.local_reduction(), LocalReduction::Copy { why } if why.contains("`cpu`")),
        "{:?}",
        two.local_reduction()
    );
    assert_eq!(two.all_reduce_calls(), 0);
}

/// Run `steps` steps of the small configuration with `batch` tuples per step as `ranks` ranks (threads
/// joined by a [`dist::ThreadGroup`]; rank `r` on `devices[r]` replicas of the CPU) from the weights
/// of `init`, resuming at `resume_at` if given. Returns every rank's final weights and reports.
fn ranks_run(
    dir: &std::path::Path,
    init: &DeepViewModel,
    ranks: usize,
    devices: &[usize],
    batch: usize,
    steps: u64,
    resume_at: Option<u64>,
) -> Vec<(Vec<f32>, Vec<StepReport>)> {
    let group = dist::ThreadGroup::new(ranks);
    std::thread::scope(|scope| {
        let handles: Vec<_> = group
            .into_iter()
            .map(|g| {
                let cpus = vec!["cpu"; devices[g.rank()]];
                scope.spawn(move || {
                    let comm: Rc<dyn Collective> = Rc::new(g);
                    let mut reports = Vec::new();
                    let first = resume_at.unwrap_or(steps);
                    let mut t = Trainer::create_on(
                        dir,
                        small_config(first, &cpus, batch),
                        small_data(),
                        Some(comm.clone()),
                    )
                    .unwrap();
                    same_start(init, &mut t);
                    reports.extend(t.run(&never(), &mut |_| {}).unwrap());
                    if resume_at.is_some() {
                        drop(t);
                        let mut cfg = RunConfig::read(dir).unwrap();
                        cfg.train.steps = steps;
                        let mut t =
                            Trainer::resume_from(dir, cfg, small_data(), Some(comm)).unwrap();
                        assert_eq!(Some(t.step), resume_at);
                        reports.extend(t.run(&never(), &mut |_| {}).unwrap());
                        return (parameter_values(&t.model), reports);
                    }
                    (parameter_values(&t.model), reports)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    })
}

/// Ranks that split a global batch (drawn from one seed on every rank) and all-reduce their gradients
/// end with the weights of one process training on the whole batch: bit for bit with 2 ranks (one sum,
/// in either order), to rounding with 3 (another summation order) and with ranks that split their share
/// across devices; only rank 0 writes, and `resume_from` continues exactly.
#[test]
fn ranks_match_one_process() {
    let dir = tempfile::tempdir().unwrap();
    for (ranks, devices, batch, exact) in [
        (2, vec![1, 1], 2, true),
        (3, vec![1, 1, 1], 3, false),
        (2, vec![2, 1], 3, false),
    ] {
        let one_dir = dir.path().join(format!("one-{ranks}-{batch}"));
        let mut one =
            Trainer::create(&one_dir, small_config(3, &["cpu"], batch), small_data()).unwrap();
        let init = one.model.clone();
        let ra = one.run(&never(), &mut |_| {}).unwrap();
        let wa = parameter_values(&one.model);
        let run_dir = dir.path().join(format!("ranks-{ranks}-{batch}"));
        let out = ranks_run(&run_dir, &init, ranks, &devices, batch, 3, None);
        for (r, (w, reports)) in out.iter().enumerate() {
            let max = max_abs_diff(&wa, w);
            if exact {
                assert!(wa == *w, "rank {r} of {ranks}: differs by {max}");
            }
            assert!(max <= 1e-6, "rank {r} of {ranks}: weights differ by {max}");
            for (a, b) in ra.iter().zip(reports) {
                assert!(
                    (a.loss - b.loss).abs() <= 1e-6 * a.loss.abs(),
                    "{a:?} vs {b:?}"
                );
            }
        }
        // Rank 0 wrote the run: one metrics line per step, the checkpoints.
        let metrics = std::fs::read_to_string(run_dir.join("metrics.jsonl")).unwrap();
        assert_eq!(metrics.lines().count(), 3);
        assert_eq!(list_checkpoints(&run_dir).unwrap().last().unwrap().0, 3);
    }
    // Interrupted after 2 steps and resumed by every rank to 4: as one process straight to 4.
    let mut one = Trainer::create(
        &dir.path().join("one-4"),
        small_config(4, &["cpu"], 2),
        small_data(),
    )
    .unwrap();
    let init = one.model.clone();
    one.run(&never(), &mut |_| {}).unwrap();
    let out = ranks_run(
        &dir.path().join("resumed"),
        &init,
        2,
        &[1, 1],
        2,
        4,
        Some(2),
    );
    for (w, _) in &out {
        assert!(parameter_values(&one.model) == *w, "resumed ranks differ");
    }
    // A batch smaller than the number of ranks: the last rank computes nothing, same result.
    let mut one = Trainer::create(
        &dir.path().join("one-small"),
        small_config(2, &["cpu"], 2),
        small_data(),
    )
    .unwrap();
    let init = one.model.clone();
    one.run(&never(), &mut |_| {}).unwrap();
    let out = ranks_run(&dir.path().join("small"), &init, 3, &[1, 1, 1], 2, 2, None);
    for (w, _) in &out {
        assert!(
            parameter_values(&one.model) == *w,
            "3 ranks on a batch of 2 differ"
        );
    }
}

/// Two runs' reports of the same step (printed): neither skipped, loss and gradient norm within `rel`
/// of each other (relative).
#[cfg(feature = "wgpu")]
fn assert_same_step(a: &metrics::StepReport, b: &metrics::StepReport, rel: f64) {
    eprintln!(
        "loss {} vs {}, grad norm {} vs {}",
        a.loss, b.loss, a.grad_norm, b.grad_norm
    );
    assert!(a.skipped.is_none() && b.skipped.is_none(), "{a:?} vs {b:?}");
    assert!(
        (a.loss - b.loss).abs() <= rel * a.loss.abs(),
        "{a:?} vs {b:?}"
    );
    assert!(
        (a.grad_norm - b.grad_norm).abs() <= rel * a.grad_norm.abs(),
        "{a:?} vs {b:?}"
    );
}

/// Data parallelism over "CPU + one wgpu device" (`--features wgpu`; on a machine without a GPU, Mesa's
/// lavapipe Vulkan driver serves): the same steps as on the CPU alone, up to the other backend's float
/// arithmetic. The device comes from `parse_device("wgpu")` first (burn's fallible options API), so a
/// machine with no adapter fails here with wgpu's reason.
///
/// Tolerance: the wgpu kernels sum in another order (workgroup reductions, fused multiply-adds), so the
/// second example's loss and gradients differ from the CPU's in the last f32 bits (measured on lavapipe:
/// losses and gradient norms to ~1e-7 relative, weights after 2 Adam steps to 7.5e-8 absolute). Adam
/// divides each gradient by its own running magnitude, so that relative error reaches the weights scaled
/// by the learning rate (1.5e-4): 1e-5 absolute (and 1e-5 relative for loss and gradient norm) leaves a
/// margin of ~100x, yet a replica whose gradients were dropped or mis-summed changes the gradient norm
/// (and, through Adam's update direction, the weights) far beyond it.
#[cfg(feature = "wgpu")]
#[test]
fn cpu_and_wgpu_replicas_match_one_device() {
    // Through the trainer's own device parser (initialised once; an error names a missing adapter).
    parse_device("wgpu").unwrap_or_else(|e| {
        panic!("no wgpu device on this machine (needs a GPU or Mesa's lavapipe Vulkan driver): {e}")
    });
    let dir = tempfile::tempdir().unwrap();
    let (mut one, mut two) = one_and_replicated(dir.path(), &["cpu", "wgpu"]);
    // A set with a `cpu` device keeps the copies (burn-flex has no collective ops).
    assert!(
        matches!(two.local_reduction(), LocalReduction::Copy { why } if why.contains("`cpu`")),
        "{:?}",
        two.local_reduction()
    );
    same_start(&one.model, &mut two);
    let w0 = parameter_values(&one.model);
    let ra = one.run(&never(), &mut |_| {}).unwrap();
    let rb = two.run(&never(), &mut |_| {}).unwrap();
    for (a, b) in ra.iter().zip(&rb) {
        assert_same_step(a, b, 1e-5);
    }
    let (wa, wb) = (parameter_values(&one.model), parameter_values(&two.model));
    assert_eq!(wa.len(), wb.len());
    let max = max_abs_diff(&wa, &wb);
    let moved = max_abs_diff(&wa, &w0);
    eprintln!("max |w_cpu - w_cpu+wgpu| = {max:e}; max move = {moved:e}");
    assert!(moved > 1e-4, "the weights hardly moved ({moved})");
    assert!(
        max < 1e-5,
        "cpu+wgpu replicas diverge from one device by {max}"
    );
}

/// Two wgpu replicas on a machine whose only Vulkan driver is Mesa's lavapipe: `wgpu` (the default
/// adapter) and `wgpu:cpu` (the CPU adapter) are two distinct wgpu devices (each its own wgpu device,
/// queue and burn server) on the one lavapipe adapter. Trained for 2 steps with a batch of 2 (one tuple
/// per replica), they end with the weights of `wgpu` alone on the same batches.
///
/// Path: burn's collective ops when cubecl's wgpu runtime reports a transport between its devices,
/// which cubecl 0.11.3 never does ([`reduce`]; `wgpu_collectives_are_refused_by_cubecl` pins that),
/// so here the copies; the test checks which path ran (`local_reduction`, and the trainer's count of
/// `all_reduce` calls: one per parameter and device of each step on the collective path, 0 on copies).
///
/// Tolerance: both runs execute the same lavapipe kernels on the same tuples, and the sum of two
/// gradient sets is the same either way (`a + b`, one addition per value, whether the second set is
/// summed on its own device first and copied, or added in turn on one device; a collective sum of two
/// is the same single addition), so the weights agree bit for bit here (measured: 0). 1e-6 absolute is
/// allowed for a collective on real GPUs (NCCL may reduce in another order with more devices); a
/// replica whose gradients were dropped or mis-summed changes the update by about the learning rate
/// (1.5e-4 per step, Adam), over 100x more.
#[cfg(feature = "wgpu")]
#[test]
fn two_wgpu_replicas_match_one_device() {
    for name in ["wgpu", "wgpu:cpu"] {
        parse_device(name).unwrap_or_else(|e| {
            panic!("no wgpu device `{name}` on this machine (needs a GPU or lavapipe): {e}")
        });
    }
    let dir = tempfile::tempdir().unwrap();
    let create = |name: &str, devices: &[&str]| {
        Trainer::create(
            &dir.path().join(name),
            small_config(2, devices, 2),
            small_data(),
        )
        .unwrap()
    };
    let mut one = create("one", &["wgpu"]);
    let mut two = create("two", &["wgpu", "wgpu:cpu"]);
    same_start(&one.model, &mut two);
    let w0 = parameter_values(&one.model);
    let collective = match two.local_reduction() {
        LocalReduction::Collective => true,
        LocalReduction::Copy { why } => {
            assert!(why.contains("no transport"), "{why}");
            false
        }
        other => panic!("{other:?}"),
    };
    eprintln!("two wgpu replicas: {:?}", two.local_reduction());
    // The same batches for both (the runs share the seed; drawn once here to be sure).
    for _ in 0..2 {
        let batch = one.draw_batch().unwrap();
        let a = one.step_on(batch.clone());
        let b = two.step_on(batch);
        assert_same_step(&a, &b, 1e-6);
    }
    let params = dist::flat_len(&two.model) as u64; // values + one per parameter
    let calls = two.all_reduce_calls();
    eprintln!("all_reduce calls: {calls} (flat length {params})");
    if collective {
        assert!(calls > 0, "the collective path made no all_reduce call");
    } else {
        assert_eq!(calls, 0);
    }
    let (wa, wb) = (parameter_values(&one.model), parameter_values(&two.model));
    let max = max_abs_diff(&wa, &wb);
    let moved = max_abs_diff(&wa, &w0);
    eprintln!("max |w_wgpu - w_wgpu+wgpu:cpu| = {max:e}; max move = {moved:e}");
    assert!(moved > 1e-4, "the weights hardly moved ({moved})");
    assert!(
        max <= 1e-6,
        "two wgpu replicas diverge from one device by {max}"
    );
}

/// A model with a U-Net net (half resolution in, bilinear upsampling out) trains on `wgpu:cpu` (lavapipe)
/// as on the CPU: burn's GPU backends have no backward for bilinear `interpolate` (the `paper-*` presets
/// panicked there, `../shared/GPU.md`), so off the CPU the upsampling is built from slices and sums
/// (`network::upsample2x_bilinear`). Two steps on the same batches from the same weights: losses and
/// gradient norms to 1e-5 relative, weights to 1e-5 absolute (the tolerance of
/// `cpu_and_wgpu_replicas_match_one_device`, whose reasoning holds here: Adam moves each weight by up to
/// the learning rate, 1.5e-4, so a wrong gradient shows far beyond it).
#[cfg(feature = "wgpu")]
#[test]
fn unet_model_trains_on_wgpu_as_on_the_cpu() {
    parse_device("wgpu:cpu").unwrap_or_else(|e| {
        panic!("no wgpu device `wgpu:cpu` on this machine (needs lavapipe): {e}")
    });
    let dir = tempfile::tempdir().unwrap();
    let create = |name: &str, device: &str| {
        let mut c = small_config(2, &[device], 1);
        c.model.unet_nets = 1;
        c.model.updates = 1;
        Trainer::create(&dir.path().join(name), c, small_data()).unwrap()
    };
    let mut one = create("cpu", "cpu");
    let mut two = create("wgpu", "wgpu:cpu");
    let w0 = parameter_values(&one.model);
    two.model = one.model.clone().fork(two.master_device());
    for _ in 0..2 {
        let batch = one.draw_batch().unwrap();
        let a = one.step_on(batch.clone());
        let b = two.step_on(batch);
        assert_same_step(&a, &b, 1e-5);
    }
    let (wa, wb) = (parameter_values(&one.model), parameter_values(&two.model));
    let max = max_abs_diff(&wa, &wb);
    let moved = max_abs_diff(&wa, &w0);
    eprintln!("max |w_cpu - w_wgpu| = {max:e}; max move = {moved:e}");
    assert!(moved > 1e-4, "the weights hardly moved ({moved})");
    assert!(
        max < 1e-5,
        "the U-Net model on wgpu diverges from the CPU by {max}"
    );
}

/// 50 training steps on `wgpu:cpu` (every GPU kernel of ours: composite, prior, warps with their
/// backward, ELU, the nets' input and max over views, Adam) track 50 on the CPU from the same weights on
/// the same batches: every step's loss within 1e-3 relative, the final weights within 1e-4 absolute
/// after moving far more. Every step clips (as real training does: the VGG loss's norms are ~1e5
/// against 8), which the GPU folds into its Adam kernel and the CPU applies to the gradients first.
/// The two sum in different orders (f32), and training carries the differences along; the gradient
/// norms are held to 5e-2 only, since the L1 loss's gradient is the sign of each residual, and the
/// residuals near zero flip with those differences (measured on lavapipe: losses within 3.1e-4, norms
/// 2.4e-2, the weights 6.7e-5 apart after moving 7.7e-3; without clipping 3.2e-6 and 1.2e-5).
#[cfg(feature = "wgpu")]
#[test]
fn fifty_wgpu_steps_track_the_cpu() {
    parse_device("wgpu:cpu").unwrap_or_else(|e| {
        panic!("no wgpu device `wgpu:cpu` on this machine (needs lavapipe): {e}")
    });
    let dir = tempfile::tempdir().unwrap();
    const CLIP: f64 = 0.02;
    let create = |name: &str, device: &str| {
        let mut config = small_config(50, &[device], 1);
        config.train.clip_norm = CLIP;
        Trainer::create(&dir.path().join(name), config, small_data()).unwrap()
    };
    let mut one = create("cpu", "cpu");
    let mut two = create("wgpu", "wgpu:cpu");
    let w0 = parameter_values(&one.model);
    two.model = one.model.clone().fork(two.master_device());
    let (mut worst_loss, mut worst_norm) = (0f64, 0f64);
    for _ in 0..50 {
        let batch = one.draw_batch().unwrap();
        let a = one.step_on(batch.clone());
        let b = two.step_on(batch);
        assert!(a.skipped.is_none() && b.skipped.is_none(), "{a:?} vs {b:?}");
        assert!(
            a.grad_norm > CLIP,
            "a step that did not clip ({})",
            a.grad_norm
        );
        let rel = |x: f64, y: f64| (x - y).abs() / x.abs();
        let (dl, dn) = (rel(a.loss, b.loss), rel(a.grad_norm, b.grad_norm));
        worst_loss = worst_loss.max(dl);
        worst_norm = worst_norm.max(dn);
        assert!(
            dl < 1e-3,
            "step {}: losses {} and {}",
            a.step,
            a.loss,
            b.loss
        );
        assert!(
            dn < 5e-2,
            "step {}: gradient norms {} and {}",
            a.step,
            a.grad_norm,
            b.grad_norm
        );
    }
    let (wa, wb) = (parameter_values(&one.model), parameter_values(&two.model));
    let max = max_abs_diff(&wa, &wb);
    let moved = max_abs_diff(&wa, &w0);
    eprintln!(
        "50 steps: worst relative loss difference {worst_loss:e}, norm difference {worst_norm:e}; max |w_cpu - w_wgpu| = {max:e}; max move = {moved:e}"
    );
    assert!(moved > 1e-3, "the weights hardly moved ({moved})");
    assert!(
        max < 1e-4,
        "after 50 steps the weights on wgpu are {max} from the CPU's"
    );
}

/// burn 0.22.1's collective ops on two wgpu devices (lavapipe's `wgpu` and `wgpu:cpu`), through the
/// code the trainer's collective path runs ([`reduce::collective_sum`]): cubecl 0.11.3 refuses
/// `all_reduce` on its wgpu runtime with a panic on the caller ("Can't use `all_reduce` on wgpu, which
/// has no transport between its devices", cubecl-runtime `src/client.rs:948-958`), which is why wgpu
/// device sets take the copies. If this test fails because the sum comes out, cubecl's wgpu runtime
/// has gained a transport: `reduce::choose` then picks the collective path for wgpu by itself, and
/// `two_wgpu_replicas_match_one_device` checks it.
#[cfg(feature = "wgpu")]
#[test]
fn wgpu_collectives_are_refused_by_cubecl() {
    use burn::nn::{Linear, LinearConfig};
    let a = parse_device("wgpu").unwrap();
    let b = parse_device("wgpu:cpu").unwrap();
    assert_ne!(a, b, "`wgpu` and `wgpu:cpu` must be two devices");
    let (reducer, reduction) =
        reduce::choose(&["wgpu".into(), "wgpu:cpu".into()], &[a.clone(), b.clone()]);
    assert!(
        matches!(&reduction, LocalReduction::Copy { why } if why.contains("no transport")),
        "{reduction:?} {reducer:?}"
    );
    let m: Linear = deepview_net::rng::seeded_module(&a, 3, || LinearConfig::new(3, 2).init(&a));
    let grads = |d: &Device, v: f32| {
        let mut g = GradientsParams::new();
        g.register::<2>(m.weight.id, Tensor::<2>::full([3, 2], v, d));
        g
    };
    let sets = vec![Some(grads(&a, 1.0)), Some(grads(&b, 2.0))];
    let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let (sum, calls) = reduce::collective_sum(&m, sets, &[a.clone(), b.clone()]);
        let w = sum
            .get::<2>(m.weight.id)
            .map(|t| t.into_data().try_to_vec::<f32>());
        (w, calls)
    }));
    let message = match out {
        Ok(r) => {
            panic!("burn's all_reduce on two wgpu devices returned {r:?}: wgpu has collectives now")
        }
        Err(e) => e
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default(),
    };
    eprintln!("all_reduce on wgpu: {message}");
    assert!(
        message.contains("all_reduce") && message.contains("no transport"),
        "{message}"
    );
}

/// Which way the replicas of one process are summed, by device set (without initialising GPUs).
#[test]
fn local_reduction_by_device_set() {
    use deepview_net::device::{DeviceFamily, device_family};
    for (name, family) in [
        ("cpu", Some(DeviceFamily::Cpu)),
        ("wgpu", Some(DeviceFamily::Wgpu)),
        ("wgpu:1", Some(DeviceFamily::Wgpu)),
        ("wgpu:cpu", Some(DeviceFamily::Wgpu)),
        ("cuda:local", Some(DeviceFamily::Cuda)),
        ("tpu", None),
    ] {
        assert_eq!(device_family(name), family, "{name}");
    }
    let cpu = Device::flex().autodiff();
    let names = |n: &[&str]| n.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let (_, r) = reduce::choose(&names(&["cpu"]), std::slice::from_ref(&cpu));
    assert_eq!(r, LocalReduction::Single);
    let (_, r) = reduce::choose(&names(&["cpu", "cpu"]), &[cpu.clone(), cpu.clone()]);
    assert!(
        matches!(&r, LocalReduction::Copy { why } if why.contains("`cpu`")),
        "{r:?}"
    );
    #[cfg(not(feature = "wgpu"))]
    assert!(
        parse_device("wgpu:cpu")
            .unwrap_err()
            .to_string()
            .contains("--features wgpu")
    );
}

#[test]
fn bad_devices_and_configs_are_errors() {
    assert!(parse_device("tpu").is_err());
    assert!(parse_device("cuda:x").is_err());
    #[cfg(not(feature = "cuda"))]
    assert!(
        parse_device("cuda:0")
            .unwrap_err()
            .to_string()
            .contains("--features cuda")
    );
    let mut c = small_config(1, &["cpu"], 1);
    c.train.batch = 0;
    let dir = tempfile::tempdir().unwrap();
    assert!(Trainer::create(dir.path(), c, small_data()).is_err());
}

/// Smoke test: on one tiny synthetic scene the loss must fall by a set factor within a bounded number of
/// steps (the tiny network, L1 loss, a raised learning rate 3e-3 so it fits in ~30 s; measured: the
/// 20-step mean falls from 0.144 to 0.044 in 200 steps).
#[test]
fn overfits_a_tiny_scene() {
    let dir = tempfile::tempdir().unwrap();
    let env = |k: &str, d: f64| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let steps = env("OVERFIT_STEPS", 200.0) as u64;
    let mut cfg = small_config(steps, &["cpu"], 1);
    cfg.train.learning_rate = env("OVERFIT_LR", 3e-3);
    cfg.train.sample.views_min = 3;
    let data = TrainData::new(vec![two_plane_scene(3, 3, 32, 0.12)]).unwrap();
    let mut t = Trainer::create(dir.path(), cfg, data).unwrap();
    let start = Instant::now();
    let reports = t.run(&never(), &mut |_| {}).unwrap();
    let mean = |r: &[StepReport]| r.iter().map(|x| x.loss).sum::<f64>() / r.len() as f64;
    let curve: Vec<String> = reports
        .chunks(20)
        .map(|c| format!("{:.4}", mean(c)))
        .collect();
    let (first, last) = (mean(&reports[..20]), mean(&reports[reports.len() - 20..]));
    eprintln!(
        "overfit: 20-step means {curve:?}, {:.1} s",
        start.elapsed().as_secs_f64()
    );
    assert!(reports.iter().all(|r| r.skipped.is_none()));
    assert!(last < 0.5 * first, "loss fell from {first} to {last} only");
}

/// Throughput on 32x32 crops with 4 views and the VGG loss, batch 1: the `cpu` preset as is, and
/// `paper-spaces-4view` with 8 instead of 64 planes (at 64 planes one tuple needs over 20 GB here; the
/// conv cost is linear in the plane count, so multiply its time by ~8)
/// (`cargo test --release -p deepview-train tests::throughput -- --ignored --nocapture`).
#[test]
#[ignore]
fn throughput() {
    for (preset, planes, steps) in [("cpu", None, 3u64), ("paper-spaces-4view", Some(8), 1)] {
        let dir = tempfile::tempdir().unwrap();
        let model = DeepViewConfig::preset(preset).unwrap();
        let mut train = TrainConfig::defaults(&model);
        train.steps = steps + 1;
        train.sample.views_min = 4;
        train.sample.views_max = 4;
        if let Some(p) = planes {
            train.sample.planes = p;
        }
        let planes = train.sample.planes;
        let data = TrainData::new(vec![two_plane_scene(4, 4, 160, 0.08)]).unwrap();
        let mut t = Trainer::create(dir.path(), RunConfig { model, train }, data).unwrap();
        let warm = t.draw_batch().unwrap();
        t.step_on(warm); // warm-up
        let batches: Vec<_> = (0..steps).map(|_| t.draw_batch().unwrap()).collect();
        let windows: Vec<_> = batches.iter().map(|b| b[0].window).collect();
        let start = Instant::now();
        for b in batches {
            t.step_on(b);
        }
        let dt = start.elapsed().as_secs_f64();
        println!(
            "{preset} ({planes} planes): {:.4} steps/s ({:.2} s/step), windows {windows:?}",
            steps as f64 / dt,
            dt / steps as f64
        );
    }
}

/// Where the time of one step goes (`-- profile_step --ignored --nocapture`; env PROFILE_PRESET).
#[test]
#[ignore]
fn profile_step() {
    let preset = std::env::var("PROFILE_PRESET").unwrap_or("cpu".into());
    let model_cfg = DeepViewConfig::preset(&preset).unwrap();
    let mut train = TrainConfig::defaults(&model_cfg);
    train.sample.views_min = 4;
    train.sample.views_max = 4;
    if let Ok(p) = std::env::var("PROFILE_PLANES") {
        train.sample.planes = p.parse().unwrap();
    }
    let data = TrainData::new(vec![two_plane_scene(4, 4, 160, 0.08)]).unwrap();
    let mut rng = Rng::new(1);
    let ex = data.sample(&train.sample, &model_cfg, 4, &mut rng).unwrap();
    let sizes: Vec<_> = ex.images.iter().map(|i| (i.width, i.height)).collect();
    println!(
        "window {:?}, input crops {sizes:?}, margin {}",
        ex.window,
        model_cfg.margin_from(0)
    );
    let device = Device::flex().autodiff();
    let model =
        deepview_net::rng::seeded_module(&device, 4, || DeepViewModel::new(&model_cfg, &device));
    let loss = Loss::Vgg(Box::new(
        Vgg16::load(&crate::vgg::test_weights_path(), &device).unwrap(),
    ));
    for _ in 0..2 {
        let t0 = Instant::now();
        let l = example_loss(&model, &loss, &ex, &device);
        let v = l.clone().into_scalar::<f32>();
        let t1 = Instant::now();
        let g = l.backward();
        let _ = GradientsParams::from_grads(g, &model);
        let t2 = Instant::now();
        println!(
            "loss {v:.1}: forward+loss {:.2} s, backward {:.2} s",
            (t1 - t0).as_secs_f64(),
            (t2 - t1).as_secs_f64()
        );
    }
}

/// Gradients of every parameter of `model` in visiting order (zeros where `grads` has none).
fn gradient_values(model: &DeepViewModel, grads: &GradientsParams) -> Vec<Vec<f32>> {
    struct Collect<'a>(&'a GradientsParams, Vec<Vec<f32>>);
    impl ModuleVisitor for Collect<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let n = param.val().shape().num_elements();
            self.1.push(match self.0.get::<D>(param.id) {
                Some(g) => g.into_data().convert::<f32>().iter::<f32>().collect(),
                None => vec![0.0; n],
            });
        }
    }
    let mut c = Collect(grads, Vec::new());
    model.visit(&mut c);
    c.1
}

fn norm(v: &[f32]) -> f64 {
    v.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt()
}

/// The tiny network with `updates` update nets, `unet` U-Net nets and an optional init prior.
fn chain_model(updates: usize, unet: usize, prior: Option<f64>) -> DeepViewConfig {
    DeepViewConfig {
        updates,
        unet_nets: unet,
        large_nets: 1,
        features_small: 6,
        init_prior: prior,
        ..tiny_model()
    }
}

/// Segment-wise recompute gives the ordinary backward's loss (bit for bit: same forward ops) and
/// parameter gradients (to float rounding), on fixed tuples, for chains of 1, 2 and 4 nets, with a U-Net
/// net, the init prior, the window's context and both losses (VGG when its weights are present).
#[test]
fn recompute_gradients_match_full_backward() {
    let device = Device::flex().autodiff();
    let data = TrainData::new(vec![two_plane_scene(3, 3, 48, 0.12)]).unwrap();
    let mut losses = vec![Loss::L1];
    if let Ok(vgg) = Vgg16::load(&crate::vgg::test_weights_path(), &device) {
        losses.push(Loss::Vgg(Box::new(vgg)));
    }
    let cases = [
        chain_model(0, 0, None),
        chain_model(1, 0, Some(0.0005)),
        chain_model(3, 1, None),
    ];
    let mut rng = Rng::new(3);
    for (i, cfg) in cases.iter().enumerate() {
        let model = deepview_net::rng::seeded_module(&device, 5 + i as u64, || {
            DeepViewModel::new(cfg, &device)
        });
        let mut sample = TrainConfig::defaults(cfg).sample;
        sample.crop = 12;
        sample.planes = 3;
        // The last case with the window's context (`--window-context`), which both paths must use alike.
        sample.window_context = i == 2;
        let ex = data.sample(&sample, cfg, 3, &mut rng).unwrap();
        assert_eq!(ex.context.is_some(), i == 2);
        for loss in &losses {
            let (va, ga) = loss_and_grads_full(&model, loss, &ex, &device, 2);
            let (vb, gb) = recompute::loss_and_grads(&model, loss, &ex, &device, 2);
            assert_eq!(va.to_bits(), vb.to_bits(), "loss {va} vs {vb}");
            let (ga, gb) = (
                gradient_values(&model, &ga.unwrap()),
                gradient_values(&model, &gb.unwrap()),
            );
            let total = norm(&ga.concat());
            assert!(total > 0.0);
            let mut worst = 0f64;
            for (a, b) in ga.iter().zip(&gb) {
                let diff: Vec<f32> = a.iter().zip(b).map(|(x, y)| x - y).collect();
                // Relative to the tensor's own norm (to the global one for tensors with ~0 gradient, such
                // as the nets behind a zero-initialised output conv).
                worst = worst.max(norm(&diff) / norm(a).max(1e-3 * total));
            }
            eprintln!(
                "{} nets, {:?} loss: |grad| {total:.3e}, worst relative difference {worst:.2e}",
                cfg.nets(),
                loss.kind()
            );
            assert!(worst < 1e-5, "gradients differ by {worst:.2e} (relative)");
            // Every net gets a gradient (the chain is really followed back to net 0).
            if cfg.init_prior.is_none() {
                let per_net = gradient_values(&model, &recompute_grads(&model, loss, &ex, &device));
                assert!(per_net.iter().all(|g| norm(g) > 0.0));
            }
        }
    }
}

fn recompute_grads(m: &DeepViewModel, l: &Loss, ex: &Example, d: &Device) -> GradientsParams {
    recompute::loss_and_grads(m, l, ex, d, 1).1.unwrap()
}

/// The recompute path keeps exact resume, the non-finite skip and the replica sum working (a 3-net
/// chain, so `TrainConfig::defaults` turns recompute on).
#[test]
fn recompute_training_resumes_skips_and_splits() {
    let config = |steps, devices: &[&str], batch| {
        let mut c = small_config(steps, devices, batch);
        c.model = chain_model(2, 0, None);
        c.train = TrainConfig {
            recompute: TrainConfig::defaults(&c.model).recompute,
            ..c.train
        };
        assert!(c.train.recompute);
        c
    };
    let dir = tempfile::tempdir().unwrap();
    let mut a =
        Trainer::create(&dir.path().join("a"), config(3, &["cpu"], 2), small_data()).unwrap();
    let init = a.model.clone();
    a.run(&never(), &mut |_| {}).unwrap();
    let split = dir.path().join("b");
    let mut b = Trainer::create(&split, config(2, &["cpu"], 2), small_data()).unwrap();
    same_start(&init, &mut b);
    b.run(&never(), &mut |_| {}).unwrap();
    drop(b);
    let mut b = Trainer::resume(&split, small_data(), Some(3), None).unwrap();
    assert!(b.config.train.recompute);
    b.run(&never(), &mut |_| {}).unwrap();
    let (wa, wb) = (parameter_values(&a.model), parameter_values(&b.model));
    assert!(wa.iter().zip(&wb).all(|(x, y)| x.to_bits() == y.to_bits()));
    assert_ne!(wa, parameter_values(&init));

    // Two replicas vs one device on the same batch, and a NaN target skipping the step.
    let mut one = Trainer::create(
        &dir.path().join("one"),
        config(9, &["cpu"], 2),
        small_data(),
    )
    .unwrap();
    let mut two = Trainer::create(
        &dir.path().join("two"),
        config(9, &["cpu", "cpu"], 2),
        small_data(),
    )
    .unwrap();
    same_start(&init, &mut one);
    same_start(&init, &mut two);
    let mut batch = one.draw_batch().unwrap();
    let good = batch[1].target_crop.data[5];
    batch[1].target_crop.data[5] = f32::NAN;
    let r = one.step_on(batch.clone());
    assert!(r.skipped.expect("skipped").contains("tuple 1"));
    assert_eq!(parameter_values(&one.model), parameter_values(&init));
    batch[1].target_crop.data[5] = good;
    let (ra, rb) = (one.step_on(batch.clone()), two.step_on(batch));
    assert!(ra.skipped.is_none() && rb.skipped.is_none());
    assert!((ra.loss - rb.loss).abs() <= 1e-6 * ra.loss.abs());
    assert!((ra.grad_norm - rb.grad_norm).abs() <= 1e-5 * ra.grad_norm);
    let max = parameter_values(&one.model)
        .iter()
        .zip(&parameter_values(&two.model))
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    assert!(max < 1e-6, "replicas diverge from one device by {max}");
}

/// Memory and time of one tuple's forward + backward with and without recompute on a chain of
/// `RC_UPDATES` (default 3) update nets (paper-kalantari architecture, `RC_FEATURES` (64) / 16 features,
/// `RC_PLANES` (4) planes, 4 views, 16x16 crops, VGG loss). `RC_MODE`: `full`, `recompute` or `both`
/// (alternating, for timing); peak RSS per mode from separate processes, e.g.
/// `RC_MODE=full /usr/bin/time -v cargo test --release -p deepview-train recompute_bench -- --ignored --nocapture`
/// (subtract the same command's RSS with `RC_REPS=0` for the baseline).
#[test]
#[ignore]
fn recompute_bench() {
    let env = |k: &str, d: usize| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let mode = std::env::var("RC_MODE").unwrap_or("both".into());
    let mut cfg = DeepViewConfig::preset("paper-kalantari").unwrap();
    cfg.updates = env("RC_UPDATES", 3);
    cfg.features_large = env("RC_FEATURES", 64);
    let mut sample = TrainConfig::defaults(&cfg).sample;
    sample.crop = 16;
    sample.planes = env("RC_PLANES", 4);
    let data = TrainData::new(vec![two_plane_scene(4, 4, 96, 0.08)]).unwrap();
    let ex = data.sample(&sample, &cfg, 4, &mut Rng::new(1)).unwrap();
    let device = Device::flex().autodiff();
    let model = deepview_net::rng::seeded_module(&device, 9, || DeepViewModel::new(&cfg, &device));
    let loss = Loss::Vgg(Box::new(
        Vgg16::load(&crate::vgg::test_weights_path(), &device).unwrap(),
    ));
    let modes: Vec<bool> = match mode.as_str() {
        "full" => vec![false],
        "recompute" => vec![true],
        _ => vec![false, true],
    };
    for rep in 0..env("RC_REPS", 2) {
        for &rc in &modes {
            let t = Instant::now();
            let (v, g) = if rc {
                recompute::loss_and_grads(&model, &loss, &ex, &device, 1)
            } else {
                loss_and_grads_full(&model, &loss, &ex, &device, 1)
            };
            let n = clip::global_norm(&model, &g.unwrap());
            println!(
                "{} nets, window {:?}, rep {rep}, recompute {rc}: loss {v:.1}, |grad| {n:.1}, {:.2} s",
                cfg.nets(),
                ex.window,
                t.elapsed().as_secs_f64()
            );
        }
    }
}

/// Every run committed in the repository (`runs/*/config.json`) reads in the current format and writes
/// back unchanged (they were migrated when the readers of older formats went).
#[test]
fn committed_run_configs_load() {
    let runs = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../runs");
    let mut n = 0;
    for entry in std::fs::read_dir(&runs).unwrap() {
        let path = entry.unwrap().path().join("config.json");
        let Ok(text) = std::fs::read_to_string(&path) else {
            continue;
        };
        let value: serde_json::Value = serde_json::from_str(&text).unwrap();
        if value.get("train").is_none() {
            continue; // a weights folder's config
        }
        let cfg: RunConfig =
            serde_json::from_value(value).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let again: RunConfig = serde_json::from_str(&serde_json::to_string(&cfg).unwrap()).unwrap();
        assert_eq!(again, cfg, "{}", path.display());
        n += 1;
    }
    assert!(n >= 5, "only {n} run configs under {}", runs.display());
}

/// The training path (a tuple's window, shrinking nets, the context, the render into the target crop)
/// computes what inference computes on the whole image, for the demo's input pattern (the four corners
/// of a 4x4 rig around an interior target): with the initialisation net's output zeroed the state
/// entering the update net is the agreement prior, which the context holds exactly, so the crop rendered
/// from the training window must equal the crop of the full-image MPI's render.
#[test]
fn training_tuple_renders_what_the_full_image_model_renders() {
    use deepview_geometry::{ReferenceOptions, plane_homography, reference_camera};
    use deepview_net::forward::{Hom, crop_output, crop_source, image_tensor, invert, render_view};
    use deepview_net::network::{CoreNet, ModelInputs};
    let dev = Device::flex();
    let data = TrainData::new(vec![two_plane_scene(4, 4, 72, 0.1)]).unwrap();
    let s = &data.scenes[0];
    // Per pixel, and with an aggregated prior reaching past the convolutions (net 0's margin 6 -> 10);
    // on the inputs' grid and on a finer one (the weights' `infer_mpi_scale`, which training takes).
    for (radius, scale) in [(0, 1.0), (9, 1.0), (0, 1.5), (9, 1.5)] {
        let cfg = DeepViewConfig {
            prior_radius: radius,
            ..DeepViewConfig::preset("cpu").unwrap()
        };
        // Fixed weights, drawn under the generator's lock (other tests draw too, some of them
        // comparing two trainers' seeded weights).
        let model = crate::trainer::seeded(&dev, 12 + radius as u64, || {
            let mut model = DeepViewModel::new(&cfg, &dev);
            model.nets[1] = CoreNet::of_config(&cfg, 1, &dev);
            // An update large enough to matter (random output convs start small).
            let out = &mut model.nets[1].out;
            out.weight = Param::from_tensor(out.weight.val() * 30.0);
            deepview_net::rng::materialize(&model);
            model
        });
        let (target, inputs, crop) = (5usize, vec![0usize, 3, 12, 15], 12usize);
        let depths = data::jittered_depths(s.near, s.far, 8, 0.0);
        let crop_origin = (30u32, 28u32);
        let tcam = s.cameras[target];
        // Inference: the whole reference image, rendered into the target view's crop.
        let cams: Vec<_> = inputs.iter().map(|&i| s.cameras[i]).collect();
        let reference = reference_camera(
            &cams,
            &ReferenceOptions {
                scale,
                ..Default::default()
            },
        )
        .unwrap();
        let tensor = |im: &deepview_image::ImageF32| {
            image_tensor(
                &im.data,
                im.width as usize,
                im.height as usize,
                im.channels,
                &dev,
            )
        };
        let full = model.forward(&ModelInputs {
            images: inputs.iter().map(|&i| tensor(&s.images[i])).collect(),
            mpi_to_view: cams
                .iter()
                .map(|c| {
                    depths
                        .iter()
                        .map(|&d| plane_homography(&reference, c, d).to_row_major())
                        .collect()
                })
                .collect(),
            height: reference.height as usize,
            width: reference.width as usize,
            shrink: false,
            context: None,
        });
        let to_crop: Vec<Hom> = depths
            .iter()
            .map(|&d| {
                let h = plane_homography(&reference, &tcam, d).to_row_major();
                invert(&crop_source(&h, crop_origin.0 as f64, crop_origin.1 as f64))
            })
            .collect();
        let expected = render_view(full.rgba, &to_crop, crop, crop).render;
        // Training: the tuple's window, with and without its context.
        let render = |with_context: bool| {
            let ex = data
                .example_with_inputs(
                    0,
                    target,
                    inputs.clone(),
                    depths.clone(),
                    crop_origin,
                    crop,
                    cfg.margin_from(0),
                    with_context,
                    scale,
                )
                .unwrap();
            let out = model.forward(&crate::example::example_inputs(&ex, &dev));
            let (ox, oy) = out.offset;
            let homs: Vec<Hom> = ex
                .window_to_target
                .iter()
                .map(|h| invert(&crop_output(h, ox as f64, oy as f64)))
                .collect();
            render_view(out.rgba, &homs, crop, crop).render
        };
        let diff = |a: Tensor<3>| -> f32 { (a - expected.clone()).abs().max().into_scalar() };
        let with = diff(render(true));
        let without = diff(render(false));
        // Measured: 1.2e-6 with the context, 5.6e-4 without (the rays of the corners leave the window).
        assert!(
            with < 1e-5,
            "radius {radius}, scale {scale}, with the context: {with} (without: {without})"
        );
        // Without the context the update net's rays leave the window (and with radius 9 cross its
        // border's clipped aggregation): only the per-pixel case's margin is pinned by this.
        if radius == 0 && scale == 1.0 {
            assert!(
                without > 100.0 * with,
                "without the context: {without} (with: {with})"
            );
        }
    }
}

/// Time spent in `on_event` (the program validates there) is not training: `steps_per_second` leaves
/// it out. With `held` seconds held in the callback, the speed is at least steps / (elapsed - held)
/// for the session's time `wall_time` reads after it (it would be steps / elapsed, below that,
/// counting it: `wall_time` runs on the same clock from the same start, microseconds later).
#[test]
fn time_in_the_event_callback_is_not_counted_in_the_speed() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = small_config(4, &["cpu"], 1);
    cfg.train.checkpoint_every = 2;
    cfg.train.sample.planes = 2;
    let mut t = Trainer::create(dir.path(), cfg, small_data()).unwrap();
    let pause = std::time::Duration::from_millis(400);
    let mut held = std::time::Duration::ZERO;
    t.run(&never(), &mut |e| {
        if let TrainEvent::Checkpoint { .. } = e {
            std::thread::sleep(pause);
            held += pause;
        }
    })
    .unwrap();
    let speed = t.steps_per_second();
    let elapsed = t.wall_time();
    assert_eq!(held, pause * 3, "checkpoints at 2, 4 and the end");
    let bound = 4.0 / (elapsed - held.as_secs_f64());
    assert!(speed >= bound, "{speed} steps/s, at least {bound} expected");
}

/// A checkpoint that does not load (truncated) is skipped at resume and moved aside, so that its step
/// is written again and pruning keeps the good checkpoints: left in place it counted as the latest,
/// was "saved" again untouched and pruning deleted the only checkpoint that loaded.
#[test]
fn a_checkpoint_that_does_not_load_is_moved_aside_and_written_again() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let mut cfg = small_config(4, &["cpu"], 1);
    cfg.train.checkpoint_every = 2;
    cfg.train.keep_checkpoints = 2;
    cfg.train.sample.planes = 2;
    Trainer::create(&run, cfg, small_data())
        .unwrap()
        .run(&never(), &mut |_| {})
        .unwrap();
    let cks = run.join("checkpoints");
    let steps = |run: &std::path::Path| -> Vec<u64> {
        list_checkpoints(run)
            .unwrap()
            .into_iter()
            .map(|c| c.0)
            .collect()
    };
    assert_eq!(steps(&run), [2, 4]);
    let model = cks.join("step-0000004/model.bpk");
    std::fs::OpenOptions::new()
        .write(true)
        .open(&model)
        .unwrap()
        .set_len(1000)
        .unwrap();
    // Keep one checkpoint from now on.
    let cfg_path = run.join("config.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&cfg_path).unwrap()).unwrap();
    json["train"]["keep_checkpoints"] = 1.into();
    std::fs::write(&cfg_path, json.to_string()).unwrap();
    let mut t = Trainer::resume(&run, small_data(), Some(4), None).unwrap();
    assert_eq!(t.step, 2);
    let notices: Vec<String> = t.take_notices().iter().map(|n| n.to_string()).collect();
    assert!(
        notices
            .iter()
            .any(|n| n.contains("step-0000004") && n.contains("moved to")),
        "{notices:?}"
    );
    let aside = cks.join("step-0000004.damaged");
    assert_eq!(
        std::fs::metadata(aside.join("model.bpk")).unwrap().len(),
        1000
    );
    assert_eq!(steps(&run), [2]);
    t.run(&never(), &mut |_| {}).unwrap();
    drop(t);
    assert_eq!(steps(&run), [4]);
    let again = Trainer::resume(&run, small_data(), Some(4), None).unwrap();
    assert_eq!(
        again.step, 4,
        "the step's checkpoint was written again and loads"
    );
}
