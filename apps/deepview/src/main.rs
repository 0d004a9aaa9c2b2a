//! `deepview`: view synthesis with multiplane images estimated by learned gradient descent.
//!
//! A thin binary: argument parsing and wiring. The work lives in the library crates.

// Printing never panics. std's `println!` and friends panic when the stream is closed
// (`deepview ... | head -1`, a log reader gone, `2>&1 | tee log` killed), which lost the command's
// work: an evaluation's JSON, a training run at its next line. These shadow them in every module of
// the binary (textual scope: defined before `mod cmd`); a closed stream loses the text, not the work.
macro_rules! println {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($t)*);
    }};
}
macro_rules! print {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = write!(std::io::stdout(), $($t)*);
    }};
}
macro_rules! eprintln {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($t)*);
    }};
}
#[allow(unused_macros)]
macro_rules! eprint {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = write!(std::io::stderr(), $($t)*);
    }};
}

mod cmd;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "deepview", version, about = "DeepView view synthesis: multiplane images by learned gradient descent", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// The network's CPU engine: `kernels` (the fast custom kernels, default) or `burn` (burn's own ops,
    /// the reference: for A/B benchmarks and checks).
    #[arg(long, global = true, value_enum, default_value_t = Engine::Kernels)]
    engine: Engine,
    /// Widest instruction set of the CPU kernels: `auto` (the machine's best, default), `avx512`, `avx2`
    /// or `portable` (for A/B benchmarks, or a machine whose wide units misbehave).
    #[arg(long, global = true, value_enum, default_value_t = IsaArg::Auto)]
    isa: IsaArg,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum Engine {
    Kernels,
    Burn,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum IsaArg {
    Auto,
    Avx512,
    Avx2,
    Portable,
}

#[derive(Subcommand)]
enum Command {
    /// The whole pipeline on a built-in synthetic scene (no files needed): ./deepview-demo/.
    Demo(cmd::demo::Args),
    /// Build a synthetic scene with ground truth and render it through a camera rig.
    Synth(cmd::synth::Args),
    /// Write the plane sweep volume of one view of a scene as images.
    Psv(cmd::psv::Args),
    /// Render an MPI into a camera (JSON file or a scene's view) or along a camera path.
    Render(cmd::render::Args),
    /// Depth from an MPI: false-colour image and 16-bit disparity PNG.
    Depth(cmd::depth::Args),
    /// Benchmarks (rendering speed, ...), printing one JSON line.
    #[command(
        subcommand,
        after_help = "Examples (each subcommand's --help has more):\n  \
        deepview bench render --synthetic 1008x756x32\n  \
        deepview bench net --preset cpu --views 4 --planes 32 --size 575x412\n  \
        deepview bench train --preset cpu --views 4 --planes 32 --crop 16 --vgg-weights VGG16.safetensors\n  \
        deepview bench scenes --count 20"
    )]
    Bench(cmd::bench::BenchCommand),
    /// Print what a dataset folder contains (format, views, cameras, depth bounds).
    Info(cmd::info::Args),
    /// Serve the WebGL2 viewer for an MPI folder on a local web server.
    View(cmd::view::Args),
    /// Write the web viewer and an MPI as a static folder for any web host.
    ExportWeb(cmd::export_web::Args),
    /// Export an MPI to another format: llff, stereo-mag or compact.
    Export(cmd::export::Args),
    /// Import an MPI from LLFF, stereo magnification or compact format (detected).
    Import(cmd::import::Args),
    /// Score a method (nearest, psv-mean, optimize, deepview) on a scene under a protocol: SSIM, PSNR, JSON.
    Eval(cmd::eval::Args),
    /// Train the network (runs/<name>/: config, metrics, checkpoints; --resume; Ctrl-C saves).
    Train(cmd::train::Args),
    /// An MPI from a few posed views: the learned network (tiled, bounded memory) or --method psv-mean,
    /// nearest, optimize.
    Infer(cmd::infer::Args),
    /// Turn a training checkpoint into a weights folder (config.json + model.safetensors).
    ExportWeights(cmd::export_weights::Args),
    /// Fewer planes for faster rendering: empty planes dropped, near-empty neighbours merged.
    Compact(cmd::compact::Args),
    /// How far apart two MPIs are (premultiplied RGBA, 8-bit steps): e.g. a GPU's and the CPU's inference.
    Diff(cmd::diff::Args),
    /// Poses for your own photos (or a video): run COLMAP and write a scene folder every command reads.
    Process(cmd::process::Args),
}

fn run(cli: Cli) -> anyhow::Result<()> {
    deepview_net::cpu::ops::use_burn_ops(cli.engine == Engine::Burn);
    deepview_kernels::set_process_isa(match cli.isa {
        IsaArg::Auto | IsaArg::Avx512 => deepview_kernels::Isa::Avx512,
        IsaArg::Avx2 => deepview_kernels::Isa::Avx2,
        IsaArg::Portable => deepview_kernels::Isa::Portable,
    });
    match cli.command {
        Command::Demo(a) => cmd::demo::run(a),
        Command::Synth(a) => cmd::synth::run(a),
        Command::Psv(a) => cmd::psv::run(a),
        Command::Render(a) => cmd::render::run(a),
        Command::Depth(a) => cmd::depth::run(a),
        Command::Bench(a) => cmd::bench::run(a),
        Command::Info(a) => cmd::info::run(a),
        Command::View(a) => cmd::view::run(a),
        Command::ExportWeb(a) => cmd::export_web::run(a),
        Command::Export(a) => cmd::export::run(a),
        Command::Import(a) => cmd::import::run(a),
        Command::Eval(a) => cmd::eval::run(a),
        Command::Train(a) => cmd::train::run(a),
        Command::Infer(a) => cmd::infer::run(a),
        Command::ExportWeights(a) => cmd::export_weights::run(a),
        Command::Compact(a) => cmd::compact::run(a),
        Command::Diff(a) => cmd::diff::run(a),
        Command::Process(a) => cmd::process::run(a),
    }
}

/// glibc returns every freed block above 128 KiB-32 MiB to the kernel at once, so the network's
/// short-lived tensors (tens of MB each) are page-faulted in afresh at every op: measured on `deepview
/// infer` (fern, images_8, 4 views, 32 planes), 33 s of the 100 s went to the kernel. Keeping blocks up
/// to 32 MiB in the heap and trimming only above 512 MiB of free top memory cut the system time to 8 s.
fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes glibc's thresholds; called once, before any other thread starts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 512 << 20);
        libc::mallopt(libc::M_TOP_PAD, 64 << 20);
    }
}

/// What replaced a spelling of earlier releases that the command line used (they are errors now).
fn old_spelling_hint(e: &clap::Error) -> Option<String> {
    use clap::error::{ContextKind, ContextValue, ErrorKind};
    let value = |kind| match e.get(kind) {
        Some(ContextValue::String(s)) => Some(s.clone()),
        _ => None,
    };
    match e.kind() {
        ErrorKind::InvalidSubcommand => match value(ContextKind::InvalidSubcommand)?.as_str() {
            "baseline" => {
                Some("`deepview baseline --method M` is now `deepview infer --method M`".into())
            }
            "optimize" => {
                Some("`deepview optimize` is now `deepview infer --method optimize`".into())
            }
            _ => None,
        },
        ErrorKind::UnknownArgument => {
            let arg = value(ContextKind::InvalidArg)?;
            let flag = arg.split('=').next().unwrap_or(&arg);
            Some(match flag {
                "--checkpoint" => "the weights of a method are --weights DIR".into(),
                "--weights" => {
                    "training starts from weights with --init DIR (or --init builtin)".into()
                }
                "--scene" | "--cameras" => "a dataset is --data DIR".into(),
                "--run" => {
                    "export-weights takes --checkpoint DIR (a checkpoint or a run folder)".into()
                }
                f if !f.starts_with('-') => format!(
                    "folders are named by their option: --data DIR (a dataset), --mpi DIR, --out DIR, \
                     --checkpoint DIR (export-weights); a bare {f:?} is not accepted"
                ),
                _ => return None,
            })
        }
        _ => None,
    }
}

/// The method options the command line gave (by field name), for `make_method` to refuse another
/// method's option even at its default value.
fn with_given_options(mut cli: Cli, matches: &clap::ArgMatches) -> Cli {
    let options = match &mut cli.command {
        Command::Eval(a) => &mut a.options,
        Command::Infer(a) => &mut a.mpi.options,
        _ => return cli,
    };
    if let Some((_, sub)) = matches.subcommand() {
        options.given = Some(
            sub.ids()
                .filter(|id| {
                    sub.value_source(id.as_str()) == Some(clap::parser::ValueSource::CommandLine)
                })
                .map(|id| id.as_str().to_owned())
                .collect(),
        );
    }
    cli
}

fn main() -> ExitCode {
    tune_allocator();
    // Before any other thread starts: Ctrl-C and SIGTERM clean up unfinished outputs (cmd::signals).
    cmd::signals::install();
    let parsed = Cli::command()
        .try_get_matches()
        .and_then(|m| Cli::from_arg_matches(&m).map(|cli| with_given_options(cli, &m)));
    let cli = match parsed {
        Ok(cli) => cli,
        Err(e) => {
            let hint = old_spelling_hint(&e);
            let _ = e.print();
            if let Some(h) = hint {
                eprintln!("  hint: {h}");
            }
            return ExitCode::from(e.exit_code().clamp(0, 255) as u8);
        }
    };
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if let Some(i) = e.downcast_ref::<cmd::signals::Interrupted>() {
                eprintln!("{i}");
                return ExitCode::from(i.exit_code());
            }
            eprintln!("error: {e}");
            // Library errors often quote their source already; print only causes that add something.
            let mut shown = e.to_string();
            for cause in e.chain().skip(1) {
                let text = cause.to_string();
                if !shown.contains(&text) {
                    eprintln!("  caused by: {text}");
                    shown.push_str(&text);
                }
            }
            // Library errors say what is wrong; the flag that fixes it is the binary's to name.
            if let Some(hint) = cmd::hints::hint(&e) {
                eprintln!("  hint: {hint}");
            }
            ExitCode::from(2)
        }
    }
}
