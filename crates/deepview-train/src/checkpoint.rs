//! Checkpoints: `checkpoints/step-N/` with the model, the optimizer state and `state.json`, written
//! into a temporary folder and renamed when complete; listing, loading, pruning, and the leftovers of an
//! interrupted write.

use crate::data::Rng;
use crate::error::{TrainError, io_err, run_err};
use crate::events::Notice;
use crate::files::{record_message, sync_dir, sync_file};
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use burn::tensor::Device;
use deepview_net::config::DeepViewConfig;
use deepview_net::network::DeepViewModel;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// `state.json` of a checkpoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointState {
    pub step: u64,
    pub rng: Rng,
    /// Training wall time up to this checkpoint (seconds, over all sessions).
    pub wall_time_s: f64,
}

/// The files of a complete checkpoint folder.
pub const CHECKPOINT_FILES: [&str; 3] = ["model.bpk", "optimizer.bpk", "state.json"];

/// Whether `dir` holds all the files of a checkpoint (a folder named `step-N` only appears once it is
/// complete, see [`crate::trainer::Trainer::save_checkpoint`]; this also rejects one damaged by hand or by the disk).
pub fn checkpoint_is_complete(dir: &Path) -> bool {
    CHECKPOINT_FILES
        .iter()
        .all(|f| std::fs::metadata(dir.join(f)).is_ok_and(|m| m.is_file() && m.len() > 0))
}

/// What a checkpoint folder holds besides [`CHECKPOINT_FILES`] (names, sorted): files someone else
/// put there, which pruning and replacing a checkpoint must not delete. File browsers' own files
/// (`.DS_Store`, `Thumbs.db`, `desktop.ini`) do not count.
pub(crate) fn foreign_entries(dir: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut out: Vec<String> = entries
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| {
            !CHECKPOINT_FILES.contains(&n.as_str()) && !deepview_image::is_file_browser_clutter(n)
        })
        .collect();
    out.sort();
    out
}

/// Rename the checkpoint folder `done` to the first free `NAME.damaged`, `NAME.damaged.2`, ... (out
/// of [`list_checkpoints`]' sight, its files kept), returning where it went.
fn move_aside(done: &Path) -> Result<PathBuf, TrainError> {
    let name = done.file_name().unwrap_or_default().to_string_lossy();
    let aside = (1..)
        .map(|k| match k {
            1 => done.with_file_name(format!("{name}.damaged")),
            k => done.with_file_name(format!("{name}.damaged.{k}")),
        })
        .find(|p| std::fs::symlink_metadata(p).is_err())
        .expect("a free name");
    std::fs::rename(done, &aside).map_err(io_err(done))?;
    Ok(aside)
}

/// Before a checkpoint is written to `done`: an incomplete `done` (damaged by hand or by the disk)
/// that holds files training did not write, or something that is not a folder, is moved aside to the
/// first free `step-N.damaged[.K]` (never listed as a checkpoint, never removed), and the warning
/// says so; an incomplete folder of training's own files alone is left for [`write_checkpoint`] to
/// replace.
pub(crate) fn set_aside_damaged(done: &Path) -> Result<Option<Notice>, TrainError> {
    let Ok(meta) = std::fs::symlink_metadata(done) else {
        return Ok(None);
    };
    let foreign = if meta.is_dir() {
        if checkpoint_is_complete(done) {
            return Ok(None);
        }
        foreign_entries(done)
    } else {
        vec![]
    };
    if meta.is_dir() && foreign.is_empty() {
        return Ok(None);
    }
    let aside = move_aside(done)?;
    let what = if meta.is_dir() {
        format!("was incomplete and held {}", foreign.join(", "))
    } else {
        "was not a folder".to_string()
    };
    Ok(Some(Notice::Warning(format!(
        "{} {what}, which training did not write: moved to {} (the new checkpoint takes its place)",
        done.display(),
        aside.display()
    ))))
}

/// The old checkpoints already said to be kept by this process (one warning each).
static KEPT_NOTED: std::sync::Mutex<std::collections::BTreeSet<PathBuf>> =
    std::sync::Mutex::new(std::collections::BTreeSet::new());

/// The complete checkpoints of a run folder, sorted by step (`checkpoints/step-N` folders holding every
/// file of [`CHECKPOINT_FILES`]; temporary folders of an interrupted write are not listed).
pub fn list_checkpoints(run_dir: &Path) -> Result<Vec<(u64, PathBuf)>, TrainError> {
    let dir = run_dir.join("checkpoints");
    if !dir.is_dir() {
        return Ok(Vec::new());
    }
    let mut out = Vec::new();
    for e in std::fs::read_dir(&dir).map_err(io_err(&dir))? {
        let e = e.map_err(io_err(&dir))?;
        let name = e.file_name().to_string_lossy().to_string();
        if let Some(n) = name
            .strip_prefix("step-")
            .and_then(|s| s.parse::<u64>().ok())
            && checkpoint_is_complete(&e.path())
        {
            out.push((n, e.path()));
        }
    }
    out.sort();
    Ok(out)
}

/// The `checkpoints/step-N` folders of `run_dir` that miss a file of [`CHECKPOINT_FILES`] (or hold an
/// empty one): damaged, and left out of [`list_checkpoints`].
pub fn damaged_checkpoints(run_dir: &Path) -> Vec<String> {
    let dir = run_dir.join("checkpoints");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut out: Vec<String> = entries
        .flatten()
        .filter(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.strip_prefix("step-")
                .is_some_and(|n| n.parse::<u64>().is_ok())
                && !checkpoint_is_complete(&e.path())
        })
        .map(|e| e.path().display().to_string())
        .collect();
    out.sort();
    out
}

pub(crate) type Loaded = (DeepViewModel, ModuleOptimizer, CheckpointState);

/// The latest checkpoint of `run_dir` that loads. The later ones that do not are moved aside
/// (`step-N.damaged`, said in `notices`): left in place they would count as the run's latest, so that
/// pruning would delete the good ones before them and the step they hold would never be written again.
/// Called with the run's lock held.
pub(crate) fn latest_loadable(
    run_dir: &Path,
    model: &DeepViewConfig,
    device: &Device,
    notices: &mut Vec<Notice>,
) -> Result<(u64, Loaded), TrainError> {
    let checkpoints = list_checkpoints(run_dir)?;
    if checkpoints.is_empty() {
        return Err(run_err(
            run_dir,
            "no complete checkpoint to resume from (checkpoints/step-*)",
        ));
    }
    let mut reasons = Vec::new();
    for (step, ck) in checkpoints.iter().rev() {
        match load_checkpoint(ck, *step, model, device) {
            Ok(l) => {
                for (ck, e) in reasons {
                    let note = match move_aside(ck) {
                        Ok(aside) => format!(
                            "skipping checkpoint {}: {e}; moved to {} (its step is trained again)",
                            ck.display(),
                            aside.display()
                        ),
                        Err(m) => format!(
                            "skipping checkpoint {}: {e}; it could not be moved aside ({m})",
                            ck.display()
                        ),
                    };
                    notices.push(Notice::Warning(note));
                }
                return Ok((*step, l));
            }
            Err(e) => reasons.push((ck, e)),
        }
    }
    let reasons: Vec<String> = reasons.iter().map(|(_, e)| e.to_string()).collect();
    Err(run_err(
        run_dir,
        format!("no checkpoint of this run loads ({})", reasons.join("; ")),
    ))
}

/// Load the model, optimizer and state of checkpoint `ck` (the folder of step `step`).
pub(crate) fn load_checkpoint(
    ck: &Path,
    step: u64,
    model: &DeepViewConfig,
    device: &Device,
) -> Result<Loaded, TrainError> {
    let state_path = ck.join("state.json");
    let text = std::fs::read_to_string(&state_path).map_err(io_err(&state_path))?;
    let state: CheckpointState =
        serde_json::from_str(&text).map_err(|e| run_err(&state_path, e))?;
    if state.step != step {
        return Err(run_err(
            &state_path,
            format!("says step {} but the folder is step {step}", state.step),
        ));
    }
    let model_path = ck.join("model.bpk");
    if !model_path.is_file() {
        return Err(run_err(&model_path, "missing"));
    }
    let model = DeepViewModel::new(model, device)
        .try_load_file(&model_path)
        .map_err(|e| {
            run_err(
                &model_path,
                format!(
                    "does not load with the run's model configuration (its config.json edited since \
                     the checkpoint was saved?), or is corrupt: {}",
                    deepview_net::weights::clipped(&e.to_string(), 300)
                ),
            )
        })?;
    let optim_path = ck.join("optimizer.bpk");
    if !optim_path.is_file() {
        return Err(run_err(&optim_path, "missing"));
    }
    let optim = adam()
        .load(&optim_path)
        .map_err(|e| run_err(&optim_path, format!("{e:?}")))?;
    Ok((model, optim, state))
}

pub(crate) fn adam() -> ModuleOptimizer {
    crate::adam::DeepviewAdam::new().module_optimizer()
}

pub(crate) fn write_checkpoint(
    model: &DeepViewModel,
    optim: &ModuleOptimizer,
    state: &CheckpointState,
    dir: &Path,
    tmp: &Path,
    done: &Path,
) -> Result<(), TrainError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    if tmp.exists() {
        std::fs::remove_dir_all(tmp).map_err(io_err(tmp))?;
    }
    std::fs::create_dir(tmp).map_err(io_err(tmp))?;
    let model_path = tmp.join("model.bpk");
    model
        .clone()
        .save_file(&model_path)
        .map_err(|e| run_err(&model_path, record_message(&e)))?;
    sync_file(&model_path)?;
    let optim_path = tmp.join("optimizer.bpk");
    optim
        .save(&optim_path)
        .map_err(|e| run_err(&optim_path, record_message(&e)))?;
    sync_file(&optim_path)?;
    let state_path = tmp.join("state.json");
    let bytes = serde_json::to_string_pretty(state).expect("serialisable");
    std::fs::File::create(&state_path)
        .and_then(|mut f| {
            f.write_all(bytes.as_bytes())?;
            f.sync_all()
        })
        .map_err(io_err(&state_path))?;
    sync_dir(tmp);
    if done.exists() {
        // A `step-N` of training's own files, some missing (damaged by hand or by the disk): replace
        // it (one holding anything else was set aside first, [`set_aside_damaged`]).
        let stale = dir.join(format!(
            ".old-step-{:07}-{}",
            state.step,
            std::process::id()
        ));
        std::fs::rename(done, &stale).map_err(io_err(done))?;
        let _ = std::fs::remove_dir_all(&stale);
    }
    std::fs::rename(tmp, done).map_err(io_err(done))
}

/// Remove all but the last `keep` checkpoints (failures are warnings in `notices`: the new checkpoint
/// is complete either way). A checkpoint folder holding anything besides its own files is kept, with a
/// warning: those files are the user's.
pub(crate) fn prune_checkpoints(run_dir: &Path, keep: usize, notices: &mut Vec<Notice>) {
    let Ok(all) = list_checkpoints(run_dir) else {
        return;
    };
    let keep = keep.max(1);
    for (step, p) in all.iter().take(all.len().saturating_sub(keep)) {
        let foreign = foreign_entries(p);
        if !foreign.is_empty() {
            let first = KEPT_NOTED
                .lock()
                .map(|mut k| k.insert(p.clone()))
                .unwrap_or(true);
            if first {
                notices.push(Notice::Warning(format!(
                    "kept the old checkpoint {}: it also holds {}, which training did not write",
                    p.display(),
                    foreign.join(", ")
                )));
            }
            continue;
        }
        let trash = p.with_file_name(format!(".old-step-{step:07}-{}", std::process::id()));
        let r = std::fs::rename(p, &trash).and_then(|_| std::fs::remove_dir_all(&trash));
        if let Err(e) = r {
            notices.push(Notice::Warning(format!(
                "cannot remove the old checkpoint {}: {e}",
                p.display()
            )));
        }
    }
}

/// Remove what a killed process left behind: temporary checkpoint folders (`.tmp-step-*`),
/// half-removed old ones (`.old-step-*`) and temporary files of atomic writes; each one said in
/// `notices`.
pub(crate) fn remove_leftovers(run_dir: &Path, notices: &mut Vec<Notice>) {
    let mut remove = |dir: &Path, is_leftover: &dyn Fn(&str) -> bool| {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().to_string();
            if !is_leftover(&name) {
                continue;
            }
            let p = e.path();
            let r = if p.is_dir() {
                std::fs::remove_dir_all(&p)
            } else {
                std::fs::remove_file(&p)
            };
            notices.push(match r {
                Ok(()) => Notice::Removed(p),
                Err(err) => Notice::Warning(format!("cannot remove {}: {err}", p.display())),
            });
        }
    };
    remove(&run_dir.join("checkpoints"), &|n| {
        n.starts_with(".tmp-step-") || n.starts_with(".old-step-")
    });
    remove(run_dir, &|n| {
        deepview_image::is_temp_of(n, "metrics.jsonl")
            || deepview_image::is_temp_of(n, "config.json")
    });
}
