//! The training loop: a [`Trainer`] creates or resumes a run, steps (replicas across devices, ranks
//! across processes), checkpoints and logs.

use crate::checkpoint::{
    CheckpointState, adam, checkpoint_is_complete, latest_loadable, list_checkpoints,
    load_checkpoint, prune_checkpoints, remove_leftovers, write_checkpoint,
};
use crate::clip;
use crate::config::RunConfig;
use crate::data::{Example, Rng, TrainData};
use crate::dist::{self, Collective};
use crate::error::{TrainError, io_err, run_err};
use crate::events::{Notice, TrainEvent};
use crate::example::{loss_and_grads_full, parameter_values};
use crate::files::{lock_run, sync_dir, write_atomic};
use crate::loss::{Loss, LossKind};
use crate::metrics::{StepReport, append_metrics, truncate_metrics};
use crate::recompute;
use crate::reduce::{self, LocalReduction, Reducer};
use crate::vgg::Vgg16;
use burn::module::Module;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::Device;
use deepview_net::device::parse_device;
use deepview_net::network::DeepViewModel;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// One replica's work: per-example forward/backward, gradients summed on the replica's device.
fn run_replica(
    model: &DeepViewModel,
    loss: &Loss,
    examples: &[Example],
    device: &Device,
    batch: usize,
    recompute: bool,
) -> (Option<GradientsParams>, Vec<f32>) {
    let inner = device.clone().inner();
    let mut acc: Option<GradientsParams> = None;
    let mut losses = Vec::with_capacity(examples.len());
    for ex in examples {
        // The prior's radius on this tuple's images (the same parameters: a clone shares their ids).
        let sized;
        let model = match ex.prior_radius {
            Some(r) if r != model.prior_radius => {
                sized = DeepViewModel {
                    prior_radius: r,
                    ..model.clone()
                };
                &sized
            }
            _ => model,
        };
        let (v, g) = if recompute {
            recompute::loss_and_grads(model, loss, ex, device, batch)
        } else {
            loss_and_grads_full(model, loss, ex, device, batch)
        };
        losses.push(v);
        let Some(g) = g else {
            return (None, losses);
        };
        acc = Some(match acc {
            None => g,
            Some(a) => clip::sum_on_device(model, vec![a, g], &inner),
        });
    }
    (acc, losses)
}

/// A training run in progress.
pub struct Trainer {
    run_dir: PathBuf,
    pub config: RunConfig,
    pub model: DeepViewModel,
    optim: ModuleOptimizer,
    pub step: u64,
    pub rng: Rng,
    data: TrainData,
    /// Autodiff devices; the first holds the master weights.
    devices: Vec<Device>,
    /// One loss (VGG copy) per device.
    losses: Vec<Loss>,
    /// How the replicas' gradients are summed ([`reduce`]), and what that is.
    reducer: Reducer,
    local_reduction: LocalReduction,
    wall_offset: f64,
    session_start: Instant,
    session_steps: u64,
    /// Time this session spent in [`Trainer::run`]'s `on_event` (the program's validation runs
    /// there): not training, so left out of [`Trainer::steps_per_second`].
    listening: std::time::Duration,
    /// `runs/<name>/.lock`, locked while this trainer lives (released by the system when the process
    /// dies, even by SIGKILL); `None` on ranks other than 0, which do not write the run folder.
    _lock: Option<std::fs::File>,
    /// The other processes of a distributed run ([`dist`]); `None`: this process alone.
    comm: Option<Rc<dyn Collective>>,
    /// Whether this process asked to stop before the current step (Ctrl-C), and whether any rank did
    /// (agreed at the step's reduction, so that every rank stops after the same step).
    stop_requested: bool,
    stop_agreed: bool,
    /// What the run said in passing and nobody has taken yet ([`Trainer::take_notices`]).
    notices: Vec<Notice>,
}

fn make_losses(
    kind: LossKind,
    vgg_weights: Option<&Path>,
    devices: &[Device],
) -> Result<Vec<Loss>, TrainError> {
    match kind {
        LossKind::L1 => Ok(devices.iter().map(|_| Loss::L1).collect()),
        LossKind::Vgg | LossKind::VggSsim => {
            let path = vgg_weights.ok_or(crate::vgg::VggError::NotGiven)?;
            let vgg = Vgg16::load(path, &devices[0])?;
            Ok(devices
                .iter()
                .map(|d| {
                    let v = Box::new(vgg.clone().to_device(d));
                    if kind == LossKind::Vgg {
                        Loss::Vgg(v)
                    } else {
                        Loss::VggSsim(v)
                    }
                })
                .collect())
        }
    }
}

impl Trainer {
    /// Start a new run in `run_dir` (created; an error if it already holds checkpoints).
    pub fn create(run_dir: &Path, config: RunConfig, data: TrainData) -> Result<Self, TrainError> {
        Self::create_on(run_dir, config, data, None)
    }

    /// [`Trainer::create`] as one rank of `comm` (every rank calls it; rank 0 writes the run folder and
    /// its initial weights are broadcast to the others).
    pub fn create_on(
        run_dir: &Path,
        config: RunConfig,
        data: TrainData,
        comm: Option<Rc<dyn Collective>>,
    ) -> Result<Self, TrainError> {
        config
            .model
            .validate()
            .map_err(|e| TrainError::Config(e.to_string()))?;
        config.train.validate()?;
        let writer = comm.as_ref().is_none_or(|c| c.rank() == 0);
        let devices = Self::devices(&config.train.devices)?;
        let mut lock = None;
        if writer {
            if !list_checkpoints(run_dir)?.is_empty() {
                return Err(TrainError::HasCheckpoints {
                    path: run_dir.to_path_buf(),
                });
            }
            let checkpoints = run_dir.join("checkpoints");
            if checkpoints.exists() && !checkpoints.is_dir() {
                return Err(run_err(
                    &checkpoints,
                    "is a file, where the run keeps its checkpoints: move it away",
                ));
            }
            std::fs::create_dir_all(&checkpoints).map_err(io_err(&checkpoints))?;
            lock = Some(lock_run(run_dir)?);
            let cfg_path = run_dir.join("config.json");
            write_atomic(
                &cfg_path,
                serde_json::to_string_pretty(&config)
                    .expect("serialisable")
                    .as_bytes(),
            )?;
            let _ = std::fs::remove_file(run_dir.join("metrics.jsonl"));
        }
        // A run killed while writing its first checkpoint is started over here: remove its temporary
        // checkpoint folder (resuming does the same in `resume_from`).
        let mut notices = Vec::new();
        if writer {
            remove_leftovers(run_dir, &mut notices);
        }
        // The initial weights, drawn right after the seed ([`seeded`]: no other trainer draws in between).
        let (model, mut values) = seeded(&devices[0], config.train.seed, || {
            let model = match &config.train.init {
                Some(init) => {
                    let (model, init_config) = deepview_net::weights::load_model(init, &devices[0])
                        .map_err(|e| run_err(init, e))?;
                    if init_config == config.model {
                        model
                    } else {
                        // A larger configuration (`--preset` with `--init`): the trained model grown into it.
                        deepview_net::grow::grow_model(
                            &model,
                            &init_config,
                            &config.model,
                            &devices[0],
                        )
                        .map_err(|e| run_err(init, e))?
                    }
                }
                None => DeepViewModel::new(&config.model, &devices[0]),
            };
            // Materialise lazily initialised parameters now, while the generator is still held.
            let values = parameter_values(&model);
            Ok::<_, TrainError>((model, values))
        })?;
        let model = match &comm {
            Some(c) => {
                // Rank 0's initial weights everywhere.
                c.broadcast_f32(&mut values);
                if c.rank() == 0 {
                    model
                } else {
                    dist::with_parameter_values(model, &values)
                }
            }
            None => model,
        };
        let losses = make_losses(
            config.train.loss,
            config.train.vgg_weights.as_deref(),
            &devices,
        )?;
        let (reducer, local_reduction) = reduce::choose(&config.train.devices, &devices);
        Ok(Self {
            run_dir: run_dir.to_path_buf(),
            rng: Rng::new(config.train.seed),
            config,
            model,
            optim: adam(),
            step: 0,
            data,
            devices,
            losses,
            reducer,
            local_reduction,
            wall_offset: 0.0,
            session_start: Instant::now(),
            session_steps: 0,
            listening: std::time::Duration::ZERO,
            _lock: lock,
            comm,
            stop_requested: false,
            stop_agreed: false,
            notices,
        })
    }

    /// Continue the run in `run_dir` from its latest checkpoint. `steps` overrides the total number of
    /// steps, `devices` the devices (neither changes the result of a step on CPU).
    pub fn resume(
        run_dir: &Path,
        data: TrainData,
        steps: Option<u64>,
        devices: Option<Vec<String>>,
    ) -> Result<Self, TrainError> {
        let mut config = RunConfig::read(run_dir)?;
        if let Some(s) = steps {
            config.train.steps = s;
        }
        if let Some(d) = devices {
            config.train.devices = d;
        }
        Self::resume_from(run_dir, config, data, None)
    }

    /// Continue the run in `run_dir`, whose `config.json` is `config` (with what may change on resume
    /// changed: [`crate::TrainOptions::adjust_on_resume`]), from its latest checkpoint, as one rank of
    /// `comm`: rank 0 chooses the checkpoint (its latest one that loads), every rank loads that one (the
    /// runs folder must be visible to every rank), and the ranks check that they hold the same weights.
    pub fn resume_from(
        run_dir: &Path,
        config: RunConfig,
        data: TrainData,
        comm: Option<Rc<dyn Collective>>,
    ) -> Result<Self, TrainError> {
        let cfg_path = run_dir.join("config.json");
        config
            .model
            .validate()
            .map_err(|e| TrainError::Config(format!("{}: {e}", cfg_path.display())))?;
        config.train.validate()?;
        let rank = comm.as_ref().map_or(0, |c| c.rank());
        let devices = Self::devices(&config.train.devices)?;
        let mut lock = None;
        let mut notices = Vec::new();
        let loaded = if rank == 0 {
            let found = lock_run(run_dir).and_then(|l| {
                lock = Some(l);
                latest_loadable(run_dir, &config.model, &devices[0], &mut notices)
            });
            if let Some(c) = &comm {
                let mut step = [found.as_ref().map_or(u64::MAX, |f| f.0)];
                c.broadcast_u64(&mut step);
            }
            found?
        } else {
            let c = comm.as_ref().expect("rank > 0 has a communicator");
            let mut step = [0];
            c.broadcast_u64(&mut step);
            let step = step[0];
            let rank_err = |message: String| TrainError::Rank { rank, message };
            if step == u64::MAX {
                return Err(rank_err("rank 0 found no checkpoint to resume from".into()));
            }
            let ck = run_dir.join("checkpoints").join(format!("step-{step:07}"));
            let l = load_checkpoint(&ck, step, &config.model, &devices[0]).map_err(|e| {
                rank_err(format!(
                    "cannot load the checkpoint rank 0 resumes from ({e}); the runs folder must be \
                     shared by all ranks"
                ))
            })?;
            (step, l)
        };
        let (step, (model, optim, state)) = loaded;
        let losses = make_losses(
            config.train.loss,
            config.train.vgg_weights.as_deref(),
            &devices,
        )?;
        let (reducer, local_reduction) = reduce::choose(&config.train.devices, &devices);
        let mut trainer = Self {
            run_dir: run_dir.to_path_buf(),
            config,
            model,
            optim,
            step,
            rng: state.rng,
            data,
            devices,
            losses,
            reducer,
            local_reduction,
            wall_offset: state.wall_time_s,
            session_start: Instant::now(),
            session_steps: 0,
            listening: std::time::Duration::ZERO,
            _lock: lock,
            comm,
            stop_requested: false,
            stop_agreed: false,
            notices,
        };
        trainer.check_replicas()?;
        if trainer.is_writer() {
            remove_leftovers(&trainer.run_dir, &mut trainer.notices);
            truncate_metrics(&trainer.run_dir, trainer.step)?;
        }
        Ok(trainer)
    }

    fn devices(names: &[String]) -> Result<Vec<Device>, TrainError> {
        names
            .iter()
            .map(|n| Ok(parse_device(n)?.autodiff()))
            .collect()
    }

    pub fn run_dir(&self) -> &Path {
        &self.run_dir
    }

    /// What the run said in passing since the last call (on resume: checkpoints skipped because they
    /// do not load, leftovers of an interrupted run removed; after a checkpoint: old ones that cannot
    /// be removed). [`Trainer::run`] reports them as [`TrainEvent::Notice`] as they come.
    pub fn take_notices(&mut self) -> Vec<Notice> {
        std::mem::take(&mut self.notices)
    }

    /// Whether this process writes the run folder and prints (rank 0, or a run without ranks).
    pub fn is_writer(&self) -> bool {
        self.comm.as_ref().is_none_or(|c| c.rank() == 0)
    }

    /// How this process sums the gradients of its replicas (`--devices`): burn's collective ops or
    /// copies to the first device ([`reduce`]).
    pub fn local_reduction(&self) -> &LocalReduction {
        &self.local_reduction
    }

    /// The autodiff device of the master weights (the first of `--devices`).
    pub fn master_device(&self) -> &Device {
        &self.devices[0]
    }

    /// How many burn `all_reduce` calls this trainer has made to sum its replicas (0 unless
    /// [`LocalReduction::Collective`]).
    pub fn all_reduce_calls(&self) -> u64 {
        self.reducer.all_reduce_calls()
    }

    /// `(rank, number of ranks)`: `(0, 1)` without a communicator.
    pub fn rank(&self) -> (usize, usize) {
        self.comm.as_ref().map_or((0, 1), |c| (c.rank(), c.size()))
    }

    /// With ranks: an error on every rank unless all hold bit-identical weights.
    pub fn check_replicas(&self) -> Result<(), TrainError> {
        let Some(c) = &self.comm else {
            return Ok(());
        };
        let h = dist::hash_values(&parameter_values(&self.model));
        let mut root = [h];
        c.broadcast_u64(&mut root);
        let mut differ = [(root[0] != h) as u8 as f32];
        c.all_reduce_sum(&mut differ);
        if differ[0] > 0.0 {
            return Err(TrainError::Rank {
                rank: c.rank(),
                message: format!(
                    "the weights of {} rank(s) differ from rank 0's at step {} (replicas out of sync{})",
                    differ[0],
                    self.step,
                    if root[0] != h {
                        ", this one among them"
                    } else {
                        ""
                    }
                ),
            });
        }
        Ok(())
    }

    /// Steps per second in this session, the time spent in [`Trainer::run`]'s `on_event` (validation)
    /// left out.
    pub fn steps_per_second(&self) -> f64 {
        let training = self.session_start.elapsed().saturating_sub(self.listening);
        self.session_steps as f64 / training.as_secs_f64().max(1e-9)
    }

    /// Total training wall time (all sessions).
    pub fn wall_time(&self) -> f64 {
        self.wall_offset + self.session_start.elapsed().as_secs_f64()
    }

    /// Bound each tuple's training step to `bytes` ([`crate::data::SampleConfig::budget`]; `None`: no
    /// bound). With ranks, every rank takes rank 0's bound, so that all of them draw the same batches.
    pub fn set_memory_budget(&mut self, bytes: Option<u64>) {
        let mut v = [bytes.map_or(u64::MAX, |b| b)];
        if let Some(c) = &self.comm {
            c.broadcast_u64(&mut v);
        }
        self.config.train.sample.budget = (v[0] != u64::MAX).then_some(crate::data::StepBudget {
            bytes: v[0],
            recompute: self.config.train.recompute,
        });
    }

    /// Draw a batch with the run's RNG.
    pub fn draw_batch(&mut self) -> Result<Vec<Example>, TrainError> {
        let t = &self.config.train;
        let k = self.data.draw_views(&t.sample, &mut self.rng);
        (0..t.batch)
            .map(|_| {
                self.data
                    .sample(&t.sample, &self.config.model, k, &mut self.rng)
                    .map_err(TrainError::from)
            })
            .collect()
    }

    /// One training step on a freshly drawn batch.
    pub fn train_step(&mut self) -> Result<StepReport, TrainError> {
        let batch = self.draw_batch()?;
        Ok(self.step_on(batch))
    }

    /// One training step on a given batch (the step counter advances even when the step is skipped).
    /// With ranks, `batch` is the global batch (the same on every rank) and this rank computes its
    /// share of it ([`dist`]).
    pub fn step_on(&mut self, batch: Vec<Example>) -> StepReport {
        self.step += 1;
        self.session_steps += 1;
        let n = batch.len();
        let views = batch.first().map_or(0, |e| e.inputs.len());
        let planes = batch.iter().map(|e| e.depths.len()).max().unwrap_or(0);
        let step_mib = batch
            .iter()
            .map(|e| e.step_bytes(&self.config.model, self.config.train.recompute) >> 20)
            .max()
            .unwrap_or(0);
        let (rank, size) = self.rank();
        let mine = dist::share(n, rank, size);
        let local = &batch[mine.clone()];
        let m = local.len();
        let nd = self.devices.len().min(m.max(1));
        let recompute = self.config.train.recompute;
        let ranges: Vec<std::ops::Range<usize>> =
            (0..nd).map(|i| i * m / nd..(i + 1) * m / nd).collect();
        let results: Vec<(Option<GradientsParams>, Vec<f32>)> = if nd == 1 {
            vec![run_replica(
                &self.model,
                &self.losses[0],
                local,
                &self.devices[0],
                n,
                recompute,
            )]
        } else {
            std::thread::scope(|scope| {
                let handles: Vec<_> = ranges
                    .iter()
                    .enumerate()
                    .map(|(i, r)| {
                        let chunk = &local[r.clone()];
                        let device = self.devices[i].clone();
                        let model = if i == 0 {
                            self.model.clone()
                        } else {
                            self.model.clone().fork(&device)
                        };
                        let loss = self.losses[i].clone();
                        scope
                            .spawn(move || run_replica(&model, &loss, chunk, &device, n, recompute))
                    })
                    .collect();
                handles
                    .into_iter()
                    .map(|h| h.join().expect("replica thread panicked"))
                    .collect()
            })
        };
        // The loss of every tuple of the batch at its index (0 where another rank computed it, or where
        // a replica stopped after a non-finite loss).
        let mut losses = vec![0.0f32; n];
        for (r, (_, l)) in ranges.iter().zip(&results) {
            losses[mine.start + r.start..][..l.len()].copy_from_slice(l);
        }
        // Within the process first (burn's all_reduce or copies, [`reduce`]), then across ranks.
        let main = self.devices[0].clone().inner();
        let sets: Vec<Option<GradientsParams>> = results.into_iter().map(|r| r.0).collect();
        let mut grads = self.reducer.reduce(&self.model, sets, &main);
        if let Some(c) = &self.comm {
            // One reduction: gradient sums, has-gradient flags, the tuples' losses, the stop flag.
            let mut flat = dist::flatten_grads(&self.model, Some(&grads));
            let g = flat.len();
            flat.extend_from_slice(&losses);
            flat.push(self.stop_requested as u8 as f32);
            c.all_reduce_sum(&mut flat);
            self.stop_agreed = flat[g + n] > 0.0;
            losses.copy_from_slice(&flat[g..g + n]);
            grads = dist::unflatten_grads(&self.model, &flat[..g], &main);
        }
        let mean = losses.iter().map(|&v| v as f64).sum::<f64>() / n.max(1) as f64;
        let mut report = StepReport {
            step: self.step,
            loss: mean,
            grad_norm: f64::NAN,
            views,
            planes,
            step_mib,
            skipped: None,
        };
        if let Some(i) = losses.iter().position(|v| !v.is_finite()) {
            let ex = &batch[i];
            let on_rank = if size > 1 {
                let r = (0..size)
                    .find(|&r| dist::share(n, r, size).contains(&i))
                    .unwrap_or(0);
                format!(", rank {r}")
            } else {
                String::new()
            };
            report.skipped = Some(format!(
                "step {}: non-finite loss ({}) on tuple {i} (scene {}, target view {}, inputs {:?}{on_rank}); step \
                 skipped, weights unchanged",
                self.step,
                losses[i],
                self.data.scene_name(ex.scene),
                ex.target,
                ex.inputs
            ));
            return report;
        }
        let norm = clip::global_norm(&self.model, &grads);
        report.grad_norm = norm;
        if !norm.is_finite() {
            report.skipped = Some(format!(
                "step {}: non-finite gradient norm ({norm}); step skipped, weights unchanged",
                self.step
            ));
            return report;
        }
        // Clipping: folded into the step where Adam is our GPU kernel, else the gradients scaled first.
        let factor = clip::clip_factor(norm, self.config.train.clip_norm);
        let in_step = crate::adam::scales_gradients(&self.devices[0]);
        let grads = match factor {
            Some(f) if !in_step => clip::scale(&self.model, grads, f),
            _ => grads,
        };
        let model = self.model.clone();
        let lr = self.config.train.learning_rate;
        let scale = if in_step { factor.unwrap_or(1.0) } else { 1.0 };
        self.model = crate::adam::with_gradient_scale(scale, || self.optim.step(lr, model, grads));
        report
    }

    /// Write a checkpoint of the current state and prune old ones. Returns its folder.
    ///
    /// The files go into `checkpoints/.tmp-step-N-PID/`, are flushed to disk, and the folder is renamed
    /// to `step-N` (a process killed at any moment leaves either no `step-N` or a complete one; the
    /// temporary folder is removed on the next `--resume`). A failed write (disk full, read-only
    /// folder) removes the temporary folder and is a [`TrainError::Write`] naming the checkpoint that is
    /// kept. Old checkpoints beyond `keep_checkpoints` are renamed to `.old-step-N` and then removed, so
    /// a kill during the removal never leaves a damaged `step-N`.
    ///
    /// With ranks every rank calls it (the ranks first check that their weights agree); only rank 0
    /// writes.
    pub fn save_checkpoint(&mut self) -> Result<PathBuf, TrainError> {
        let dir = self.run_dir.join("checkpoints");
        let done = dir.join(format!("step-{:07}", self.step));
        self.check_replicas()?;
        if !self.is_writer() {
            return Ok(done);
        }
        if checkpoint_is_complete(&done) {
            // Already written (a run resumed at a checkpoint it had saved but maybe not pruned after,
            // when it was killed in between): prune now.
            prune_checkpoints(
                &self.run_dir,
                self.config.train.keep_checkpoints,
                &mut self.notices,
            );
            return Ok(done);
        }
        match crate::checkpoint::set_aside_damaged(&done) {
            Ok(notice) => self.notices.extend(notice),
            Err(e) => return Err(self.write_error(format!("the checkpoint {}", done.display()), e)),
        }
        let tmp = dir.join(format!(".tmp-step-{:07}-{}", self.step, std::process::id()));
        let state = CheckpointState {
            step: self.step,
            rng: self.rng,
            wall_time_s: self.wall_time(),
        };
        if let Err(e) = write_checkpoint(&self.model, &self.optim, &state, &dir, &tmp, &done) {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(self.write_error(format!("the checkpoint {}", done.display()), e));
        }
        sync_dir(&dir);
        prune_checkpoints(
            &self.run_dir,
            self.config.train.keep_checkpoints,
            &mut self.notices,
        );
        Ok(done)
    }

    /// A [`TrainError::Write`] for a failed write of `what` at the current step.
    fn write_error(&self, what: String, source: TrainError) -> TrainError {
        let kept = list_checkpoints(&self.run_dir)
            .ok()
            .and_then(|mut v| v.pop());
        TrainError::Write {
            step: self.step,
            what,
            source: Box::new(source),
            kept,
        }
    }

    /// Train until `config.train.steps` or until `stop` is set (the program sets it on Ctrl-C or
    /// SIGTERM), checkpointing every `checkpoint_every` steps and at the end; `on_event` hears of each
    /// step, checkpoint and notice ([`TrainEvent`]). Returns the reports of this session's steps.
    pub fn run(
        &mut self,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(TrainEvent<'_>),
    ) -> Result<Vec<StepReport>, TrainError> {
        let total = self.config.train.steps;
        let writer = self.is_writer();
        self.tell_notices(on_event);
        self.tell(
            on_event,
            TrainEvent::Start {
                step: self.step,
                total,
            },
        );
        let mut reports = Vec::new();
        // With ranks, a stop (Ctrl-C on any rank) is agreed at the next step's reduction so that all
        // ranks stop after the same step.
        let stopping = |t: &Self| match t.comm {
            Some(_) => t.stop_agreed,
            None => stop.load(Ordering::SeqCst),
        };
        while self.step < total && !stopping(self) {
            self.stop_requested = stop.load(Ordering::SeqCst);
            let r = self.train_step()?;
            if writer {
                append_metrics(&self.run_dir, &r, self.steps_per_second(), self.wall_time())
                    .map_err(|e| self.write_error("metrics.jsonl".into(), e))?;
            }
            let steps_per_s = self.steps_per_second();
            self.tell(
                on_event,
                TrainEvent::Step {
                    report: &r,
                    steps_per_s,
                },
            );
            if self.step.is_multiple_of(self.config.train.checkpoint_every) {
                self.checkpoint_and_tell(on_event)?;
            }
            reports.push(r);
        }
        self.checkpoint_and_tell(on_event)?;
        Ok(reports)
    }

    /// [`Trainer::save_checkpoint`], then tell `on_event` (the checkpoint, and the notices).
    fn checkpoint_and_tell(
        &mut self,
        on_event: &mut dyn FnMut(TrainEvent<'_>),
    ) -> Result<(), TrainError> {
        let dir = self.save_checkpoint()?;
        if self.is_writer() {
            let step = self.step;
            self.tell(on_event, TrainEvent::Checkpoint { step, dir: &dir });
        }
        self.tell_notices(on_event);
        Ok(())
    }

    fn tell_notices(&mut self, on_event: &mut dyn FnMut(TrainEvent<'_>)) {
        for n in self.take_notices() {
            self.tell(on_event, TrainEvent::Notice(&n));
        }
    }

    /// `on_event(e)`, its time counted in `listening`.
    fn tell(&mut self, on_event: &mut dyn FnMut(TrainEvent<'_>), e: TrainEvent<'_>) {
        let t = Instant::now();
        on_event(e);
        self.listening += t.elapsed();
    }
}

// burn's CPU backend has one generator per process, not per device: two trainers created at once
// would otherwise interleave their draws and start from weights their seed does not give.
pub(crate) use deepview_net::rng::seeded;
