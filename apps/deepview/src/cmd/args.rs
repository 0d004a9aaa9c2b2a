//! The flags every command spells the same way: `--data DIR` (a dataset), `--mpi DIR`, `--planes
//! auto|weights|N`, `--max-memory auto|SIZE`, and the rules behind them (plane count from the scene, memory
//! budget from the machine).

use anyhow::{Context, bail};
use deepview_geometry::{
    AUTO_MAX_SPACING_PX, AUTO_PLANES_MIN, Camera, ReferenceOptions, auto_planes, reference_camera,
};
use deepview_mpi::PlanesRule;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// `--data DIR`: a dataset folder. The bare positional folder of earlier releases is still accepted (hidden,
/// for one release).
#[derive(clap::Args, Debug, Clone)]
pub struct DataArg {
    /// Dataset folder (LLFF, COLMAP, Spaces or light-field grid; the format is detected).
    #[arg(
        long = "data",
        value_name = "DIR",
        required_unless_present = "data_positional"
    )]
    pub data: Option<PathBuf>,
    /// The dataset folder as a bare argument (the old spelling; use --data).
    #[arg(hide = true, value_name = "DIR", conflicts_with = "data")]
    pub data_positional: Option<PathBuf>,
}

impl DataArg {
    pub fn path(&self) -> &Path {
        self.data
            .as_deref()
            .or(self.data_positional.as_deref())
            .expect("clap requires --data")
    }
}

/// `--mpi DIR`: an MPI folder; the bare positional folder of earlier releases is still accepted (hidden).
#[derive(clap::Args, Debug, Clone)]
pub struct MpiArg {
    /// MPI folder (mpi.json + layer_NNN.png, or a compact export).
    #[arg(
        long = "mpi",
        value_name = "DIR",
        required_unless_present = "mpi_positional"
    )]
    pub mpi: Option<PathBuf>,
    /// The MPI folder as a bare argument (the old spelling; use --mpi).
    #[arg(hide = true, value_name = "DIR", conflicts_with = "mpi")]
    pub mpi_positional: Option<PathBuf>,
}

impl MpiArg {
    pub fn path(&self) -> &Path {
        self.mpi
            .as_deref()
            .or(self.mpi_positional.as_deref())
            .expect("clap requires --mpi")
    }
}

/// `--out DIR` with the bare second positional of earlier releases still accepted (hidden).
#[derive(clap::Args, Debug, Clone)]
pub struct OutArg {
    /// Output folder (created).
    #[arg(
        long = "out",
        value_name = "DIR",
        required_unless_present = "out_positional"
    )]
    pub out: Option<PathBuf>,
    /// The output folder as a bare argument (the old spelling; use --out).
    #[arg(hide = true, value_name = "OUT", conflicts_with = "out")]
    pub out_positional: Option<PathBuf>,
}

impl OutArg {
    pub fn path(&self) -> &Path {
        self.out
            .as_deref()
            .or(self.out_positional.as_deref())
            .expect("clap requires --out")
    }
}

/// The help text of `--planes` where it takes `auto`.
pub const PLANES_HELP: &str = "Number of MPI planes, equally spaced in inverse depth between near and far: \
    `auto` (default) chooses them from the cameras so that neighbouring planes are at most 1 px of disparity \
    apart between the reference camera and the input view farthest from it (clamped to 8..=256 and to what \
    --max-memory allows); `weights` takes the learned model's own inference count; a number is used as given.";

/// `--planes auto | weights | N`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PlanesArg {
    /// From the cameras' disparity ([`deepview_geometry::auto_plane_count`]).
    #[default]
    Auto,
    /// The weights' `infer_planes` (learned model only).
    Weights,
    /// Exactly this many.
    Count(usize),
}

impl FromStr for PlanesArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "weights" => Ok(Self::Weights),
            t => t
                .parse::<usize>()
                .map(Self::Count)
                .map_err(|_| format!("{s:?} is not a plane count (use auto, weights or a number)")),
        }
    }
}

impl std::fmt::Display for PlanesArg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Auto => f.write_str("auto"),
            Self::Weights => f.write_str("weights"),
            Self::Count(n) => write!(f, "{n}"),
        }
    }
}

/// A chosen plane count and how it was chosen (for `mpi.json` and the log line).
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneChoice {
    pub count: usize,
    pub rule: PlanesRule,
    /// The line printed to stderr.
    pub message: String,
}

/// The reference camera every method places its MPI in: the inputs' centroid, covering them between
/// near and far.
pub fn mpi_reference(cameras: &[Camera], near_far: (f64, f64)) -> anyhow::Result<Camera> {
    Ok(reference_camera(
        cameras,
        &ReferenceOptions {
            cover: Some(near_far),
            ..Default::default()
        },
    )?)
}

/// Resolve `--planes` for an MPI in `reference` from input cameras `views` (whose dataset indices are
/// `view_ids`, for the message). `weights`: the learned model's count, when there is one. `fits(n)`: whether
/// `n` planes fit the memory budget; `auto` takes the largest count up to the rule's that fits (at least
/// [`AUTO_PLANES_MIN`]). An explicit count is used as given.
pub fn choose_planes(
    arg: PlanesArg,
    reference: &Camera,
    views: &[Camera],
    view_ids: &[usize],
    near_far: (f64, f64),
    weights: Option<usize>,
    fits: &mut dyn FnMut(usize) -> bool,
    minimum: &mut dyn FnMut(usize) -> u64,
) -> anyhow::Result<PlaneChoice> {
    // Any count is checked against the budget before anything is allocated.
    let mut refuse = |n: usize, how: &str| -> anyhow::Error {
        let need = minimum(n);
        anyhow::anyhow!(
            "{n} planes ({how}) do not fit the memory budget: they need at least {}; use fewer planes, \
             smaller images (--downscale) or --max-memory {}",
            human(need),
            min_arg(need)
        )
    };
    let simple = |count: usize, rule: &str, message: String| PlaneChoice {
        count,
        rule: PlanesRule {
            rule: rule.into(),
            max_disparity_px: None,
            max_spacing_px: None,
            view: None,
            limited_by: None,
        },
        message,
    };
    match arg {
        PlanesArg::Count(0) => bail!("--planes: an MPI needs at least one plane (got 0)"),
        PlanesArg::Count(n) if !fits(n) => Err(refuse(n, "--planes")),
        PlanesArg::Count(n) => Ok(simple(n, "explicit", format!("planes: {n} (--planes)"))),
        PlanesArg::Weights => match weights {
            Some(n) if !fits(n) => Err(refuse(n, "--planes weights")),
            Some(n) => Ok(simple(
                n,
                "weights",
                format!("planes: weights -> {n} (the weights' inference plane count)"),
            )),
            None => bail!("--planes weights needs a learned model (use auto or a number)"),
        },
        PlanesArg::Auto => {
            let auto = auto_planes(
                reference,
                views,
                near_far.0,
                near_far.1,
                AUTO_MAX_SPACING_PX,
            );
            let view = match view_ids.get(auto.view) {
                Some(i) => format!("view {i}"),
                None => format!("input {}", auto.view),
            };
            let mut count = auto.count;
            let mut limited_by = None;
            let least = AUTO_PLANES_MIN.min(count);
            if !fits(least) {
                return Err(refuse(least, "the fewest --planes auto takes"));
            }
            if !fits(count) {
                // The largest count in [MIN, count) that fits (fitting is monotone in the count).
                let (mut lo, mut hi) = (AUTO_PLANES_MIN, count);
                while lo + 1 < hi {
                    let mid = (lo + hi) / 2;
                    if fits(mid) { lo = mid } else { hi = mid }
                }
                count = lo.min(auto.count);
                limited_by = Some("memory budget".to_string());
            }
            let mut message = format!(
                "planes: auto -> {count} (max disparity {:.1} px between reference and {view}",
                auto.max_disparity_px
            );
            if limited_by.is_some() {
                message += &format!("; the rule's {} planes do not fit --max-memory", auto.count);
            }
            message.push(')');
            Ok(PlaneChoice {
                count,
                rule: PlanesRule {
                    rule: "auto".into(),
                    max_disparity_px: Some((auto.max_disparity_px * 1000.0).round() / 1000.0),
                    max_spacing_px: Some(auto.max_spacing_px),
                    view: view_ids.get(auto.view).copied(),
                    limited_by,
                },
                message,
            })
        }
    }
}

/// `human(bytes)`: e.g. `1.5 GiB`, `12.0 MiB`.
pub fn human(bytes: u64) -> String {
    if bytes >= 1 << 30 {
        gib(bytes)
    } else {
        format!("{:.1} MiB", bytes as f64 / (1u64 << 20) as f64)
    }
}

/// The smallest `--max-memory` value (whole MiB, rounded up) that is at least `bytes`.
pub fn min_arg(bytes: u64) -> String {
    format!("{}MiB", bytes.div_ceil(1 << 20).max(1))
}

/// Refuse work estimated at `need` bytes that does not fit `budget`, before anything is allocated; the
/// message names the one `--max-memory` that does fit.
pub fn check_memory(what: &str, need: u64, budget: u64) -> anyhow::Result<()> {
    if need > budget {
        bail!(
            "{what} needs about {} of memory but the budget is {}: make it smaller or pass --max-memory {}",
            human(need),
            human(budget),
            min_arg(need)
        );
    }
    Ok(())
}

/// Worker threads (per-thread scratch in the estimates).
fn threads() -> u64 {
    rayon::current_num_threads().max(1) as u64
}

fn px(w: u32, h: u32) -> u64 {
    w as u64 * h as u64
}

/// Bytes of an MPI of `planes` planes of `w x h` read as f32 premultiplied texels (layer decoding
/// included), `u8`: as 8-bit texels.
pub fn mpi_bytes(w: u32, h: u32, planes: usize, u8: bool) -> u64 {
    let texel = if u8 { 4 } else { 16 };
    px(w, h)
        .saturating_mul(planes as u64)
        .saturating_mul(texel)
        .saturating_add(px(w, h).saturating_mul(20).saturating_mul(threads()))
}

/// Bytes of rendering one `w x h` image from an MPI (f32 accumulation, output conversion, PNG encoding).
pub fn render_bytes(camera: &Camera) -> u64 {
    px(camera.width, camera.height).saturating_mul(48)
}

/// Bytes of a camera path video's frames of `camera`'s size: each frame is streamed to the output, so a
/// few frame buffers whatever the count, plus the cameras themselves.
pub fn video_bytes(camera: &Camera, frames: usize) -> u64 {
    px(camera.width, camera.height)
        .saturating_mul(24)
        .saturating_add((frames as u64).saturating_mul(std::mem::size_of::<Camera>() as u64))
}

/// Bytes of a depth map from an MPI into `camera` (depth, disparity, colour, 16-bit output).
pub fn depth_bytes(camera: &Camera) -> u64 {
    px(camera.width, camera.height).saturating_mul(40)
}

/// Bytes of `deepview synth`: every view's image (f32 RGB, held until written) and the ground-truth MPI in
/// a reference camera up to twice the views' size on each side (f32 RGBA).
pub fn synth_bytes(views: &[(u32, u32)], planes: usize) -> u64 {
    let images: u64 = views
        .iter()
        .map(|&(w, h)| px(w, h).saturating_mul(12))
        .fold(0, u64::saturating_add);
    let largest = views.iter().map(|&(w, h)| px(w, h)).max().unwrap_or(0);
    images.saturating_add(
        largest
            .saturating_mul(4)
            .saturating_mul(planes as u64)
            .saturating_mul(16),
    )
}

/// Bytes of the plane sweep volume of `image` into `reference` with `planes` planes (f32 RGBA).
pub fn psv_bytes(reference: &Camera, image: &Camera, planes: usize) -> u64 {
    px(reference.width, reference.height)
        .saturating_mul(planes as u64)
        .saturating_mul(16)
        .saturating_add(px(image.width, image.height).saturating_mul(16))
}

/// `--max-memory` as parsed by clap: `auto` or a positive size.
pub fn parse_memory(s: &str) -> Result<String, String> {
    if s.trim().eq_ignore_ascii_case("auto") {
        return Ok(s.to_string());
    }
    super::infer::parse_bytes(s)
        .map(|_| s.to_string())
        .map_err(|e| e.to_string())
}

/// A list of view indices, `0,3,5`: numbers, at least one, no duplicates (checked against the scene's
/// view count by [`ViewList::check`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ViewList(pub Vec<usize>);

impl FromStr for ViewList {
    type Err = String;
    fn from_str(text: &str) -> Result<Self, String> {
        let mut out = Vec::new();
        for part in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let i: usize = part
                .parse()
                .map_err(|_| format!("{part:?} is not a view index"))?;
            if out.contains(&i) {
                return Err(format!("view {i} is given twice in {text:?}"));
            }
            out.push(i);
        }
        if out.is_empty() {
            return Err("no view indices given".into());
        }
        Ok(Self(out))
    }
}

impl ViewList {
    /// The indices, each checked against a scene of `views` views.
    pub fn check(&self, views: usize) -> anyhow::Result<Vec<usize>> {
        if let Some(&i) = self.0.iter().find(|&&i| i >= views) {
            bail!(
                "view index {i} out of range: the scene has {views} views (0..{})",
                views.saturating_sub(1)
            );
        }
        Ok(self.0.clone())
    }
}

/// A count of at least one (`--repeats`, `--frames`, `--supersample`, ...).
pub fn parse_positive(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(_) => Err(format!("{s:?} is not a positive whole number")),
    }
}

/// A finite number above zero (`--fps`, `--radius`, `--lr`, ...).
pub fn parse_positive_f64(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(_) => Err(format!("{s:?} must be a finite number above 0")),
        Err(_) => Err(format!("{s:?} is not a number")),
    }
}

/// The help text of `--max-memory`.
pub const MEMORY_HELP: &str = "Memory budget, e.g. 2GiB, 512MiB, 1500000000, or auto (default): half of the \
    memory available now (MemAvailable in /proc/meminfo), at most 3 GiB; 2 GiB when that cannot be read.";

/// Bytes of `MemAvailable` in `/proc/meminfo`.
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    parse_mem_available(&text)
}

fn parse_mem_available(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let mut it = line["MemAvailable:".len()..].split_whitespace();
    let value: u64 = it.next()?.parse().ok()?;
    match it.next().map(str::to_ascii_lowercase).as_deref() {
        Some("kb") => Some(value * 1024),
        None | Some("b") => Some(value),
        _ => None,
    }
}

/// The fallback budget when the available memory cannot be read.
pub const FALLBACK_BUDGET: u64 = 2 << 30;

/// The most the default budget takes. A larger budget only buys the tiled inference larger tiles, not speed
/// (measured: fern `images_8`, 33 planes, 4 views: 3 min 37 s and 1.7 GB peak RSS with 2 GiB, 4 min 1 s and
/// 5.6 GB with 11.5 GiB), and 3 GiB keeps `infer --images images_4 --planes 64` on fern under 4 GiB peak
/// RSS (2.73 GB measured, BENCHMARKS.md).
pub const MAX_DEFAULT_BUDGET: u64 = 3 << 30;

fn gib(bytes: u64) -> String {
    format!("{:.1} GiB", bytes as f64 / (1u64 << 30) as f64)
}

/// The budget of `--max-memory` (`None` or `auto`: half of `MemAvailable`, at most [`MAX_DEFAULT_BUDGET`];
/// [`FALLBACK_BUDGET`] when unknown), and the line saying where it came from.
pub fn memory_budget_of(
    arg: Option<&str>,
    available: Option<u64>,
) -> anyhow::Result<(u64, String)> {
    match arg.map(str::trim) {
        Some(t) if !t.eq_ignore_ascii_case("auto") => {
            let b = super::infer::parse_bytes(t).context("--max-memory")?;
            Ok((b, format!("memory budget: {} (--max-memory {t})", gib(b))))
        }
        _ => Ok(match available {
            Some(a) if a > 0 => {
                let b = (a / 2).min(MAX_DEFAULT_BUDGET);
                let how = if b < a / 2 { "at most 3 GiB, " } else { "" };
                (
                    b,
                    format!(
                        "memory budget: {} ({how}half of the {} available; --max-memory to change)",
                        gib(b),
                        gib(a)
                    ),
                )
            }
            _ => (
                FALLBACK_BUDGET,
                format!(
                    "memory budget: {} (available memory unknown; --max-memory to change)",
                    gib(FALLBACK_BUDGET)
                ),
            ),
        }),
    }
}

/// [`memory_budget_of`] on this machine, printed to stderr.
pub fn memory_budget(arg: Option<&str>) -> anyhow::Result<u64> {
    let (bytes, line) = memory_budget_of(arg, available_memory())?;
    eprintln!("{line}");
    Ok(bytes)
}

/// A simple estimate for the classical methods: the largest plane count whose `fixed + count * per_plane`
/// bytes fit `budget`.
pub fn fits_estimate(fixed: u64, per_plane: u64, budget: u64) -> impl FnMut(usize) -> bool {
    move |n| fixed.saturating_add(per_plane.saturating_mul(n as u64)) <= budget
}

/// Bytes per plane of a `psv-mean` MPI in `reference` (f32 RGBA texels, agreement logits, alphas) and the
/// fixed part (`inputs` RGB f32 images, per-thread running sums).
pub fn psv_mean_bytes(reference: &Camera, inputs: &[Camera]) -> (u64, u64) {
    let px = reference.width as u64 * reference.height as u64;
    let input_px: u64 = inputs
        .iter()
        .map(|c| c.width as u64 * c.height as u64)
        .sum();
    let threads = rayon::current_num_threads() as u64;
    (12 * input_px + 56 * px * threads, 24 * px)
}

/// Bytes per plane of the `optimize` baseline: Adam's logits, moments and gradients (16 f32 per texel) at the
/// working resolution (`max_width`), plus the full-size result.
pub fn optimize_bytes(reference: &Camera, inputs: &[Camera], max_width: u32) -> (u64, u64) {
    let f = reference.width.div_ceil(max_width.max(1)).max(1) as u64;
    let px = reference.width as u64 * reference.height as u64;
    let small = px / (f * f);
    let (fixed, _) = psv_mean_bytes(reference, inputs);
    (fixed, 64 * small + 16 * px)
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::{DMat3, DVec3, Intrinsics, Pose};

    #[test]
    fn planes_arg_parses() {
        assert_eq!("auto".parse::<PlanesArg>().unwrap(), PlanesArg::Auto);
        assert_eq!("Weights".parse::<PlanesArg>().unwrap(), PlanesArg::Weights);
        assert_eq!("48".parse::<PlanesArg>().unwrap(), PlanesArg::Count(48));
        assert!("many".parse::<PlanesArg>().is_err());
    }

    fn cam(x: f64) -> Camera {
        Camera::new(
            640,
            480,
            Intrinsics::new(500.0, 500.0, 320.0, 240.0),
            Pose::from_center(DMat3::IDENTITY, DVec3::new(x, 0.0, 0.0)),
        )
    }

    #[test]
    fn auto_planes_follow_disparity_and_memory() {
        // 500 * 0.2 * (1/2 - 1/50) = 48 px: 49 planes.
        let reference = cam(0.0);
        let views = [cam(-0.1), cam(0.2)];
        let c = choose_planes(
            PlanesArg::Auto,
            &reference,
            &views,
            &[3, 7],
            (2.0, 50.0),
            Some(32),
            &mut |_| true,
            &mut |_| 0,
        )
        .unwrap();
        assert_eq!(c.count, 49);
        assert_eq!(c.rule.view, Some(7));
        assert_eq!(c.rule.rule, "auto");
        assert!(c.message.contains("auto -> 49") && c.message.contains("48.0 px"));
        assert!(c.message.contains("view 7"), "{}", c.message);
        // A budget for 20 planes.
        let c = choose_planes(
            PlanesArg::Auto,
            &reference,
            &views,
            &[3, 7],
            (2.0, 50.0),
            None,
            &mut |n| n <= 20,
            &mut |n| n as u64,
        )
        .unwrap();
        assert_eq!(
            (c.count, c.rule.limited_by.as_deref()),
            (20, Some("memory budget"))
        );
        // Explicit counts and the weights' count are used as given when they fit, refused with the
        // minimum budget when they do not.
        let explicit = |arg, fit: usize| {
            choose_planes(
                arg,
                &reference,
                &views,
                &[3, 7],
                (2.0, 50.0),
                Some(32),
                &mut |n| n <= fit,
                &mut |n| n as u64 * (1 << 20),
            )
        };
        assert_eq!(explicit(PlanesArg::Count(5), 100).unwrap().count, 5);
        assert_eq!(explicit(PlanesArg::Weights, 100).unwrap().count, 32);
        assert!(explicit(PlanesArg::Count(0), 100).is_err());
        let e = explicit(PlanesArg::Count(100000), 100)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--max-memory 100000MiB"), "{e}");
        let e = explicit(PlanesArg::Auto, 2).unwrap_err().to_string();
        assert!(e.contains("--max-memory 8MiB"), "{e}");
        let no_weights = choose_planes(
            PlanesArg::Weights,
            &reference,
            &views,
            &[],
            (2.0, 50.0),
            None,
            &mut |_| true,
            &mut |_| 0,
        );
        assert!(no_weights.is_err());
        assert_eq!(min_arg((1 << 20) + 1), "2MiB");
        assert!("1,2,1".parse::<ViewList>().is_err());
        assert_eq!(
            "3, 1".parse::<ViewList>().unwrap().check(4).unwrap(),
            [3, 1]
        );
        assert!("3,4".parse::<ViewList>().unwrap().check(4).is_err());
    }

    #[test]
    fn memory_budget_from_meminfo() {
        let info = "MemTotal:       24000000 kB\nMemFree:  100 kB\nMemAvailable:   20971520 kB\n";
        assert_eq!(parse_mem_available(info), Some(20971520 * 1024));
        assert_eq!(parse_mem_available("MemTotal: 5 kB\n"), None);
        let (b, line) = memory_budget_of(None, Some(4 << 30)).unwrap();
        assert_eq!(b, 2 << 30);
        assert!(line.contains("2.0 GiB") && line.contains("half"), "{line}");
        let (b, line) = memory_budget_of(Some("auto"), Some(20 << 30)).unwrap();
        assert_eq!(b, MAX_DEFAULT_BUDGET);
        assert!(
            line.contains("3.0 GiB") && line.contains("at most"),
            "{line}"
        );
        assert_eq!(memory_budget_of(None, None).unwrap().0, FALLBACK_BUDGET);
        assert_eq!(
            memory_budget_of(Some("512MiB"), Some(8 << 30)).unwrap().0,
            512 << 20
        );
        assert!(memory_budget_of(Some("lots"), None).is_err());
    }
}
