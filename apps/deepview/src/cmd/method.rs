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
/// model what it infers and a progress bar.
pub struct Reporter {
    kind: MethodKind,
    ids: Vec<usize>,
    weights: Option<String>,
    verbose: bool,
    last: Option<String>,
    bar: Option<indicatif::ProgressBar>,
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
            } if self.verbose && self.kind == MethodKind::Deepview => {
                eprintln!(
                    "inferring a {planes}-plane {width}x{height} MPI from views {:?} (weights {})",
                    self.ids,
                    self.weights.as_deref().unwrap_or("?")
                );
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
                if let Some(bar) = &self.bar {
                    bar.set_length(total as u64);
                    bar.set_position(done as u64);
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
