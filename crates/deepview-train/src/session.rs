//! Opening a run: a new one, one resumed from its latest checkpoint, or one started over from its
//! `config.json` (killed before its first checkpoint). [`open`] makes that decision (rank 0 for every
//! rank), reads the run's files, loads its datasets with the options the run keeps for them, checks the
//! data against the run's settings and returns the [`Trainer`] with what is worth saying.

use crate::checkpoint::{CHECKPOINT_FILES, damaged_checkpoints, list_checkpoints};
use crate::config::{RunConfig, TrainConfig};
use crate::data::TrainData;
use crate::dist::Collective;
use crate::error::TrainError;
use crate::load::{DataSpec, load_data};
use crate::loss::LossKind;
use crate::options::TrainOptions;
use crate::scene::{SYNTHETIC_PROCEDURAL, is_synthetic};
use crate::trainer::Trainer;
use deepview_data::LoadOptions;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// What `deepview train` asks for.
#[derive(Clone, Debug)]
pub struct Request<'a> {
    /// `<runs>/<name>`.
    pub run_dir: &'a Path,
    /// `--data` (may be empty with `--resume`: the run's own list).
    pub data: &'a [PathBuf],
    /// The scene flags (`--images`, `--downscale`, ...).
    pub scene: &'a LoadOptions,
    pub options: &'a TrainOptions,
    pub resume: bool,
}

/// How the run started.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// A new run.
    Fresh,
    /// From its latest complete checkpoint.
    Resumed,
    /// Over from step 0 with its `config.json` (it had no complete checkpoint).
    Restarted,
}

/// An opened run.
pub struct Session {
    pub trainer: Trainer,
    pub start: Start,
    /// Lines for the user (the program prints them on rank 0).
    pub notices: Vec<String>,
}

const FRESH: u64 = 0;
const RESUME: u64 = 1;
const RESTART: u64 = 2;

fn config_err(message: String) -> TrainError {
    TrainError::Refused(message)
}

/// Open the run `request` names (see the module docs); every rank of `comm` calls it.
pub fn open(
    request: &Request<'_>,
    comm: Option<Rc<dyn Collective>>,
) -> Result<Session, TrainError> {
    let run_dir = request.run_dir;
    let opts = request.options;
    let mut notices = Vec::new();
    // `--resume` of a run without config.json (killed before it wrote anything, or never started): with
    // --data (the whole command repeated, as a job script does after a crash) it starts; without, it is
    // an error.
    let started = run_dir.join("config.json").is_file();
    if request.resume && !started && request.data.is_empty() {
        return Err(config_err(format!(
            "--resume: there is no run {} (no config.json); start it without --resume",
            run_dir.display()
        )));
    }
    if request.resume && !started {
        notices.push(format!(
            "--resume: there is no run {} yet (no config.json; stopped before it started?): starting it",
            run_dir.display()
        ));
    }
    // A run killed before its first checkpoint restarts from its config.json; one whose every
    // checkpoint is damaged is refused, naming them, rather than started over.
    let checkpoints = if started {
        list_checkpoints(run_dir)?.len()
    } else {
        0
    };
    if request.resume && started && checkpoints == 0 {
        let damaged = damaged_checkpoints(run_dir);
        if !damaged.is_empty() {
            return Err(config_err(format!(
                "--resume: no checkpoint of {} is complete ({} lack one of {}): move them away to start \
                 the run over from step 0",
                run_dir.display(),
                damaged.join(", "),
                CHECKPOINT_FILES.join(", ")
            )));
        }
    }
    let mut mode = [if !request.resume || !started {
        FRESH
    } else if checkpoints > 0 {
        RESUME
    } else {
        RESTART
    }];
    if let Some(c) = &comm {
        c.broadcast_u64(&mut mode);
    }
    let ranks = comm
        .as_ref()
        .map(|c| format!(" on {} MPI ranks", c.size()))
        .unwrap_or_default();
    if mode[0] == FRESH {
        return fresh(request, comm, notices);
    }
    let mut cfg = RunConfig::read(run_dir).map_err(|e| match mode[0] {
        RESTART => config_err(format!(
            "--resume: the run {} has no checkpoints yet, and its config.json (to start it over from) \
             cannot be used: {e}",
            run_dir.display()
        )),
        _ => e,
    })?;
    check_fixed_on_resume(opts, &cfg)?;
    let on_disk = cfg.clone();
    cfg.train.data = resumed_data(request, &cfg)?;
    opts.adjust_on_resume(&mut cfg.train);
    // Kept for later resumes: the list given now (relative paths read against this folder from then
    // on), or the run's own list as it was written.
    let mut kept = cfg.clone();
    if request.data.is_empty() {
        kept.train.data = on_disk.train.data.clone();
    } else {
        kept.train.base = std::env::current_dir().ok();
    }
    let rank = comm.as_ref().map_or(0, |c| c.rank());
    let data = load_data(&cfg.train.data, cfg.train.holdout_every)?;
    check_views(&data, &cfg.train, mode[0] == RESUME)?;
    check_vgg(&cfg.train.loss, cfg.train.vgg_weights.as_deref(), opts)?;
    if mode[0] == RESUME {
        let mut trainer = Trainer::resume_from(run_dir, cfg, data, comm)?;
        if trainer.step > trainer.config.train.steps {
            return Err(config_err(format!(
                "--steps {} is below the step the run {} has reached ({}): --steps is the new total, \
                 e.g. --steps {}",
                trainer.config.train.steps,
                run_dir.display(),
                trainer.step,
                trainer.step + 1000
            )));
        }
        // What this session changes (--steps, --data, --devices, --keep-checkpoints, --vgg-weights,
        // --validate-every) becomes the run's own, so that a later plain --resume goes on with it (a new
        // total of steps was forgotten before: the next --resume was refused as below the step reached).
        if rank == 0 {
            keep_resumed_config(run_dir, &on_disk, &kept)?;
        }
        notices.extend(trainer.take_notices().iter().map(|n| n.to_string()));
        notices.push(format!(
            "resuming {} at step {} of {}{ranks}",
            run_dir.display(),
            trainer.step,
            trainer.config.train.steps,
        ));
        Ok(Session {
            trainer,
            start: Start::Resumed,
            notices,
        })
    } else {
        notices.push(format!(
            "{} has no complete checkpoint yet: starting it over from step 0 with its config.json",
            run_dir.display()
        ));
        Ok(Session {
            trainer: Trainer::create_on(run_dir, cfg, data, comm)?,
            start: Start::Restarted,
            notices,
        })
    }
}

/// Write `now` over the run's config.json (atomically) where it differs from what was read, `before`.
fn keep_resumed_config(
    run_dir: &Path,
    before: &RunConfig,
    now: &RunConfig,
) -> Result<(), TrainError> {
    let text = |c: &RunConfig| serde_json::to_string_pretty(c).expect("serialisable");
    let now_text = text(now);
    if now_text != text(before) {
        crate::files::write_atomic(&run_dir.join("config.json"), now_text.as_bytes())?;
    }
    Ok(())
}

/// A new run from the options.
fn fresh(
    request: &Request<'_>,
    comm: Option<Rc<dyn Collective>>,
    mut notices: Vec<String>,
) -> Result<Session, TrainError> {
    let (run_dir, opts) = (request.run_dir, request.options);
    if request.data.is_empty() {
        return Err(config_err(
            "no training data: pass --data DIR (repeatable)".into(),
        ));
    }
    let model = opts.model()?;
    let specs = request
        .data
        .iter()
        .map(|p| data_spec(p, request.scene, opts.max_width))
        .collect::<Result<_, _>>()?;
    let train = opts.config(&model, specs);
    for d in &train.devices {
        deepview_net::device::parse_device(d)?;
    }
    let data = load_data(&train.data, train.holdout_every)?;
    check_views(&data, &train, false)?;
    check_vgg(&train.loss, train.vgg_weights.as_deref(), opts)?;
    let views: usize = data.scenes.iter().map(|s| s.train_views.len()).sum();
    notices.push(format!(
        "training {} ({} preset) on {} scene(s), {views} training views{}, devices {:?}{}",
        run_dir.display(),
        model.name,
        data.scenes.len(),
        data.procedural_note(),
        train.devices,
        comm.as_ref()
            .map(|c| format!(
                " on each of {} MPI ranks (the global batch split across them)",
                c.size()
            ))
            .unwrap_or_default()
    ));
    let writer = comm.as_ref().is_none_or(|c| c.rank() == 0);
    let existed = run_dir.exists();
    match Trainer::create_on(run_dir, RunConfig { model, train }, data, comm) {
        Ok(trainer) => Ok(Session {
            trainer,
            start: Start::Fresh,
            notices,
        }),
        Err(e) => {
            // A run that failed to start (unreadable --init weights, ...) leaves no folder behind;
            // but a folder another process is training (it made the folder after `existed` was
            // read, and holds its lock) is that process's: removed only with the lock held here.
            if !existed
                && writer
                && !matches!(e, TrainError::Busy { .. })
                && let Ok(_lock) = crate::files::lock_run(run_dir)
                && list_checkpoints(run_dir).is_ok_and(|c| c.is_empty())
            {
                let _ = std::fs::remove_dir_all(run_dir);
            }
            Err(e)
        }
    }
}

fn check_fixed_on_resume(opts: &TrainOptions, cfg: &RunConfig) -> Result<(), TrainError> {
    let fixed = opts.fixed_on_resume(cfg);
    if fixed.is_empty() {
        return Ok(());
    }
    Err(config_err(format!(
        "--resume keeps the run's own {}: {} {} from the run's config.json and cannot change on \
         resume (only --steps, --devices, --data, --keep-checkpoints, --vgg-weights and --validate-every can); start a new \
         --name instead",
        if fixed.len() == 1 {
            "setting"
        } else {
            "settings"
        },
        fixed.join(", "),
        if fixed.len() == 1 {
            "differs"
        } else {
            "differ"
        }
    )))
}

/// Refuse a VGG loss without readable VGG weights before the run starts.
fn check_vgg(loss: &LossKind, path: Option<&Path>, opts: &TrainOptions) -> Result<(), TrainError> {
    if *loss == LossKind::L1 {
        return Ok(());
    }
    let Some(path) = path else {
        return Err(crate::vgg::VggError::NotGiven.into());
    };
    if !path.is_file() {
        let from = if opts.vgg_weights.is_some() {
            "--vgg-weights"
        } else {
            "the run's config.json"
        };
        // (A resumed run keeps its loss: --loss l1 is for a new one.)
        return Err(config_err(format!(
            "the VGG-16 weights {} ({from}) are not a readable file: pass --vgg-weights FILE \
             (vgg16_conv1_1-conv3_3.safetensors){}",
            path.display(),
            if opts.vgg_weights.is_some() {
                ", or train with --loss l1"
            } else {
                ""
            }
        )));
    }
    Ok(())
}

/// `--downscale` 0 and 1 both mean full size.
fn normalised(o: &LoadOptions) -> LoadOptions {
    LoadOptions {
        downscale: o.downscale.max(1),
        ..o.clone()
    }
}

/// The scene flags given on the command line (those that differ from their defaults) whose values in
/// `given` differ from `other`.
fn scene_flags_differing(given: &LoadOptions, other: &LoadOptions) -> Vec<&'static str> {
    let (g, o) = (normalised(given), normalised(other));
    [
        (g.format.is_some() && g.format != o.format, "--format"),
        (g.images.is_some() && g.images != o.images, "--images"),
        (g.rig != 0 && g.rig != o.rig, "--rig"),
        (g.near.is_some() && g.near != o.near, "--near"),
        (g.far.is_some() && g.far != o.far, "--far"),
        (
            g.downscale != 1 && g.downscale != o.downscale,
            "--downscale",
        ),
    ]
    .iter()
    .filter(|f| f.0)
    .map(|f| f.1)
    .collect()
}

/// A dataset loaded with the scene flags `opts`; with `--max-width W`, downscaled by the smallest
/// integer factor that brings its images to at most `W` pixels wide.
pub fn data_spec(
    path: &Path,
    opts: &LoadOptions,
    max_width: Option<u32>,
) -> Result<DataSpec, TrainError> {
    let mut load = opts.clone();
    if let Some(w) = max_width
        && !is_synthetic(path)
    {
        let scene = deepview_data::load_scene(path, &load)
            .map_err(|e| config_err(format!("--data {}: {e}", path.display())))?;
        let width = scene.views.first().map_or(0, |v| v.camera.width);
        load.downscale = width.div_ceil(w.max(1)).max(1);
    }
    Ok(DataSpec::new(path, load))
}

/// The datasets of a run resumed (or started over) from its config.json: `--data` if given, else the
/// run's own; each loads with the options the run keeps for it (a scene flag given now must agree with
/// them), or, for data the run did not have, with the scene flags given now.
fn resumed_data(request: &Request<'_>, cfg: &RunConfig) -> Result<Vec<DataSpec>, TrainError> {
    let given = !request.data.is_empty();
    let paths: Vec<PathBuf> = if given {
        request.data.to_vec()
    } else {
        cfg.train.data.iter().map(|d| d.path.clone()).collect()
    };
    // Relative paths of the run's own list are read against the folder it was started from.
    let here = std::env::current_dir().ok();
    let resolve = |p: &Path| match &cfg.train.base {
        Some(b) if !given && p.is_relative() && here.as_ref() != Some(b) && !is_synthetic(p) => {
            b.join(p)
        }
        _ => p.to_path_buf(),
    };
    paths
        .into_iter()
        .map(|named| {
            let path = resolve(&named);
            let kept = cfg
                .train
                .data
                .iter()
                .find(|d| d.path == named)
                .map(|d| d.load.clone());
            match kept {
                Some(load) => {
                    let differ = scene_flags_differing(request.scene, &load);
                    if !differ.is_empty() {
                        return Err(config_err(format!(
                            "--resume loads {} as the run first did (its config.json): {} differ and \
                             cannot change on resume; start a new --name instead",
                            path.display(),
                            differ.join(", ")
                        )));
                    }
                    Ok(DataSpec::new(path, load))
                }
                None => data_spec(&path, request.scene, request.options.max_width),
            }
        })
        .collect()
}

/// Every view must hold a target crop, and every scene must have more training views than the largest
/// input count (the target is one of them): checked now, not at the first step.
pub fn check_views(
    data: &TrainData,
    train: &TrainConfig,
    resuming: bool,
) -> Result<(), TrainError> {
    let (views_max, crop) = (train.sample.views_max, train.sample.crop);
    let mut sizes: Vec<(String, u32, u32)> = data
        .scenes
        .iter()
        .flat_map(|s| {
            s.cameras
                .iter()
                .map(|c| (s.name.clone(), c.width, c.height))
        })
        .collect();
    if let Some(p) = &data.procedural {
        sizes.push((
            SYNTHETIC_PROCEDURAL.into(),
            p.options.width,
            p.options.height,
        ));
    }
    if let Some((name, w, h)) = sizes.iter().find(|(_, w, h)| (*w.min(h) as usize) < crop) {
        return Err(config_err(format!(
            "--crop {crop}: the scene {name} has {w}x{h} views, smaller than the crop; use a smaller --crop"
        )));
    }
    // The scene with the fewest training views decides what fits.
    let Some(s) = data.scenes.iter().min_by_key(|s| s.train_views.len()) else {
        return Ok(());
    };
    let n = s.train_views.len();
    if views_max + 1 > n {
        let (lo, total) = (train.sample.views_min, s.cameras.len());
        let asked = if lo == views_max {
            format!("--views {views_max}")
        } else {
            format!("--views {lo}..{views_max}")
        };
        // Held-out views are named only where the scene has some, and --holdout-every 0 only where
        // keeping them would be enough.
        let held = match total - n {
            0 => String::new(),
            1 => "1 more is held out: never trained on".to_string(),
            h => format!("{h} more are held out: never trained on"),
        };
        let holdout = match held.is_empty() {
            true => String::new(),
            false if total > views_max && !resuming => {
                format!(" ({held}; --holdout-every 0 keeps them all)")
            }
            false => format!(" ({held})"),
        };
        let fix = match (n, resuming) {
            (0 | 1, _) => "a scene needs at least 2 training views".to_string(),
            (_, true) => "the run's --views is its own on --resume: resume with --data of scenes \
                          that have more views, or start a new --name"
                .to_string(),
            (_, false) if lo < n - 1 => format!("pass --views {lo}..{}", n - 1),
            (_, false) => format!("pass --views {}", n - 1),
        };
        return Err(config_err(format!(
            "{asked} (inputs per tuple): the scene {} has {n} training views{holdout}, so at most {} \
             inputs besides the target; {fix}",
            s.name,
            n.saturating_sub(1)
        )));
    }
    Ok(())
}
