//! The display of `deepview train`: the trainer's events ([`TrainEvent`]) on stderr.

use deepview_train::TrainEvent;

/// Shows the training loop's events on stderr: a progress bar with the loss and its running mean (unless
/// `--quiet`), skipped steps and notices; nothing on ranks other than the writer.
pub struct Progress {
    bar: Option<indicatif::ProgressBar>,
    writer: bool,
    /// Exponential moving average of the loss of the steps not skipped.
    ema: Option<f64>,
    /// Where the bar is hidden (stderr not a terminal: a log file), a line at the first step, every
    /// [`LOG_EVERY`] after it and at each checkpoint instead: the total steps, and when the last line
    /// was written (`None`: none yet).
    log: (u64, Option<std::time::Instant>),
}

/// How often a hidden bar's progress is written as a line of its own.
const LOG_EVERY: std::time::Duration = std::time::Duration::from_secs(60);

impl Progress {
    pub fn new(bar: bool, writer: bool) -> Self {
        let bar = bar.then(|| {
            let pb = indicatif::ProgressBar::new(0);
            pb.set_style(
                indicatif::ProgressStyle::with_template(
                    "{bar:30.cyan/blue} {pos}/{len} {msg} [{elapsed_precise} < {eta_precise}]",
                )
                .expect("valid template"),
            );
            pb
        });
        Self {
            bar,
            writer,
            ema: None,
            log: (0, None),
        }
    }

    pub fn say(&self, line: String) {
        if !self.writer {
            return;
        }
        // (indicatif's `println` prints nothing where the bar is hidden: stderr not a terminal, as
        // in a log file.)
        match &self.bar {
            Some(pb) if !pb.is_hidden() => pb.println(line),
            _ => eprintln!("{line}"),
        }
    }

    pub fn event(&mut self, e: TrainEvent<'_>) {
        match e {
            TrainEvent::Start { step, total } => {
                if let Some(pb) = &self.bar {
                    pb.set_length(total);
                    pb.set_position(step);
                }
                self.log = (total, None);
            }
            TrainEvent::Step {
                report,
                steps_per_s,
            } => {
                match &report.skipped {
                    Some(why) => self.say(format!("warning: {why}")),
                    None => {
                        self.ema = Some(
                            self.ema
                                .map_or(report.loss, |e| 0.9 * e + 0.1 * report.loss),
                        )
                    }
                }
                if let Some(pb) = &self.bar
                    && pb.is_hidden()
                    && report.skipped.is_none()
                    && self.log.1.is_none_or(|t| t.elapsed() >= LOG_EVERY)
                {
                    self.log.1 = Some(std::time::Instant::now());
                    self.say(format!(
                        "step {}/{}: loss {:.4} (avg {:.4}), {steps_per_s:.2} steps/s",
                        report.step,
                        self.log.0,
                        report.loss,
                        self.ema.unwrap_or(f64::NAN),
                    ));
                }
                if let Some(pb) = &self.bar {
                    pb.set_position(report.step);
                    pb.set_message(format!(
                        "loss {:.4} (avg {:.4}) {steps_per_s:.2} steps/s",
                        report.loss,
                        self.ema.unwrap_or(f64::NAN),
                    ));
                }
            }
            TrainEvent::Checkpoint { step, dir } => {
                if self.bar.as_ref().is_some_and(|pb| pb.is_hidden()) {
                    self.say(format!("checkpoint at step {step}: {}", dir.display()));
                }
            }
            TrainEvent::Notice(n) => self.say(n.to_string()),
        }
    }

    pub fn finish(&mut self) {
        if let Some(pb) = self.bar.take() {
            pb.finish_and_clear();
        }
    }
}
