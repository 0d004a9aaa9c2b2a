//! What the commands that make, score or render MPIs share: the `--inputs` help and the display of the
//! libraries' progress (the libraries report events; the binary prints them).

use deepview_methods::{MethodEvent, MethodKind};

/// The help text of `--inputs`.
pub const INPUTS_HELP: &str = "Input views: nearest:K (the K views nearest the target; where there is no \
    target, as in infer, nearest the centroid of all camera centres), nearest:K@VIEW (the K nearest view \
    VIEW), centroid:K (the K nearest the centroid of all camera centres), spread:K (K views spread evenly \
    over the others in index order: eval --inputs spread:3 --crop 0 is the few-shot 3-view protocol), \
    all, or a list like 0,3,5. \
    Default: nearest:4 (nearest:K for weights trained for K views). eval never takes a target as an input.";

/// Shows a method's events on stderr: the plane count line (once per distinct line), and for the learned
/// model and `optimize` what they make and a progress bar; where stderr is not a terminal (a log file)
/// the bar is hidden and a line every [`LOG_EVERY`] says how far it is instead.
pub struct Reporter {
    kind: MethodKind,
    ids: Vec<usize>,
    weights: Option<String>,
    verbose: bool,
    last: Option<String>,
    bar: Option<indicatif::ProgressBar>,
    /// When the work started and when the last line of a hidden bar was written.
    log: (std::time::Instant, std::time::Instant),
}

/// How often a hidden progress bar's state is written as a line of its own.
const LOG_EVERY: std::time::Duration = std::time::Duration::from_secs(30);

/// A hidden bar's line: `what: 40% (12 of 30 steps, 1 min 5 s)`.
fn progress_line(what: &str, done: usize, total: usize, elapsed: std::time::Duration) -> String {
    let s = elapsed.as_secs();
    let time = if s >= 60 {
        format!("{} min {} s", s / 60, s % 60)
    } else {
        format!("{s} s")
    };
    let percent = 100 * done / total.max(1);
    format!("{what}: {percent}% ({done} of {total} steps, {time})")
}

impl Reporter {
    /// Events of `kind` making an MPI from the views `ids` with `weights`; `verbose`: also what the
    /// learned model infers, with a progress bar.
    pub fn new(kind: MethodKind, ids: &[usize], weights: Option<String>, verbose: bool) -> Self {
        Self {
            kind,
            ids: ids.to_vec(),
            weights,
            verbose,
            last: None,
            bar: None,
            log: (std::time::Instant::now(), std::time::Instant::now()),
        }
    }

    fn what(&self) -> &'static str {
        match self.kind {
            MethodKind::Optimize => "optimizing",
            _ => "inferring",
        }
    }

    pub fn event(&mut self, event: MethodEvent<'_>) {
        match event {
            MethodEvent::Planes(choice) => {
                if self.last.as_deref() != Some(choice.message.as_str()) {
                    eprintln!("{}", choice.message);
                    self.last = Some(choice.message.clone());
                }
            }
            MethodEvent::Start {
                planes,
                width,
                height,
            } if self.verbose
                && matches!(self.kind, MethodKind::Deepview | MethodKind::Optimize) =>
            {
                let from = match self.kind {
                    MethodKind::Deepview => {
                        format!(" (weights {})", self.weights.as_deref().unwrap_or("?"))
                    }
                    _ => String::new(),
                };
                eprintln!(
                    "{} an MPI of {planes} planes, {width}x{height}, from views {:?}{from}",
                    self.what(),
                    self.ids,
                );
                self.log = (std::time::Instant::now(), std::time::Instant::now());
                let bar = indicatif::ProgressBar::new(1);
                bar.set_style(
                    indicatif::ProgressStyle::with_template(
                        "{bar:40} {percent:>3}% ({elapsed}, eta {eta})",
                    )
                    .expect("valid template"),
                );
                self.bar = Some(bar);
            }
            MethodEvent::Start { .. } => {}
            // Off the CPU, where the device's limits shape the tiles.
            MethodEvent::Plan(plan) if self.verbose && plan.starts_with("tiled") => {
                eprintln!("plan: {plan}")
            }
            MethodEvent::Plan(_) => {}
            MethodEvent::Progress { done, total } => {
                let Some(bar) = &self.bar else { return };
                bar.set_length(total as u64);
                bar.set_position(done as u64);
                if bar.is_hidden() && done < total && self.log.1.elapsed() >= LOG_EVERY {
                    self.log.1 = std::time::Instant::now();
                    eprintln!(
                        "{}",
                        progress_line(self.what(), done, total, self.log.0.elapsed())
                    );
                }
            }
        }
    }

    /// Close the progress bar.
    pub fn finish(&mut self) {
        // Cleared: the command's own "wrote ..." line (on stdout) follows on a line of its own.
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

/// [`deepview_media::render_video`] with a progress bar on stderr.
/// `out` is where it is written (maybe a temporary), `shown` the name the bar gives it.
pub fn video(
    mpi: &deepview_mpi::MpiU8,
    cameras: &[deepview_geometry::Camera],
    (out, shown): (&std::path::Path, &std::path::Path),
    fps: f64,
) -> anyhow::Result<deepview_media::VideoReport> {
    let bar = indicatif::ProgressBar::new(cameras.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} frames ({per_sec}, eta {eta})",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar.set_message(format!("rendering {}", shown.display()));
    let report = deepview_media::render_video(mpi, cameras, out, fps, &mut |done, _| {
        bar.set_position(done as u64)
    })?;
    bar.finish_and_clear();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::progress_line;
    use std::time::Duration;

    #[test]
    fn a_hidden_bar_says_how_far_in_lines() {
        assert_eq!(
            progress_line("optimizing", 120, 301, Duration::from_secs(65)),
            "optimizing: 39% (120 of 301 steps, 1 min 5 s)"
        );
        assert_eq!(
            progress_line("inferring", 0, 66, Duration::from_millis(4_900)),
            "inferring: 0% (0 of 66 steps, 4 s)"
        );
    }
}
