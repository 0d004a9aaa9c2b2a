//! The flags every command spells the same way: `--data DIR` (a dataset), `--mpi DIR`, `--max-memory
//! auto|SIZE` and the memory budget behind it (the plane rule of `--planes` is `deepview_methods::Planes`).

use anyhow::{Context, bail};
use deepview_geometry::Camera;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// `--data DIR`: a dataset folder.
#[derive(clap::Args, Debug, Clone)]
pub struct DataArg {
    /// Dataset folder (LLFF, COLMAP, Spaces, light-field grid or transforms.json; the format is detected).
    #[arg(long = "data", value_name = "DIR")]
    pub data: PathBuf,
}

impl DataArg {
    pub fn path(&self) -> &Path {
        &self.data
    }
}

/// `--mpi DIR`: an MPI folder.
#[derive(clap::Args, Debug, Clone)]
pub struct MpiArg {
    /// MPI folder (mpi.json + layer_NNN.png; `view` and `export-web` also read a compact export, and
    /// `deepview import` converts the other formats).
    #[arg(long = "mpi", value_name = "DIR")]
    pub mpi: PathBuf,
}

impl MpiArg {
    pub fn path(&self) -> &Path {
        &self.mpi
    }
}

/// `--out DIR`: an output folder.
#[derive(clap::Args, Debug, Clone)]
pub struct OutArg {
    /// Output folder (created).
    #[arg(long = "out", value_name = "DIR")]
    pub out: PathBuf,
}

impl OutArg {
    pub fn path(&self) -> &Path {
        &self.out
    }
}

pub use deepview_methods::human;

/// The smallest `--max-memory` value (whole MiB, rounded up) that is at least `bytes`.
/// A scene the user named (`--data` and the scene options), with a note on stderr where `--images`
/// does not apply: light fields keep their images as `input_CamNNN.png` (the loader lets it pass for
/// training runs that list LLFF scenes and grids together).
pub fn load_scene_noted(
    data: &Path,
    load: &deepview_data::LoadOptions,
) -> Result<deepview_data::Scene, deepview_data::DataError> {
    let scene = deepview_data::load_scene(data, load)?;
    if let Some(images) = &load.images
        && scene.format == deepview_data::SceneFormat::LightField
    {
        eprintln!(
            "note: --images {images} is ignored: {} is a light field, whose images are its \
             input_CamNNN.png files",
            data.display()
        );
    }
    Ok(scene)
}

pub fn min_arg(bytes: u64) -> String {
    format!("{}MiB", bytes.div_ceil(1 << 20).max(1))
}

/// What to do about work that needs `need` bytes beyond the budget: the `--max-memory` that fits, when this
/// machine has that much memory (`total`: its physical memory, `None` when unknown), else that it cannot.
pub fn more_memory_hint(need: u64, total: Option<u64>) -> String {
    match total {
        Some(t) if need > t => format!(
            "that is more than this machine's {} of memory: make it smaller",
            human(t)
        ),
        _ => format!("make it smaller or pass --max-memory {}", min_arg(need)),
    }
}

/// Refuse work estimated at `need` bytes that does not fit `budget`, before anything is allocated; the
/// message names the one `--max-memory` that does fit.
pub fn check_memory(what: &str, need: u64, budget: u64) -> anyhow::Result<()> {
    if need > budget {
        bail!(
            "{what} needs about {} of memory but the budget is {}: {}",
            human(need),
            human(budget),
            more_memory_hint(need, total_memory())
        );
    }
    Ok(())
}

fn px(w: u32, h: u32) -> u64 {
    w as u64 * h as u64
}

pub use deepview_methods::planes::mpi_bytes;

/// Refuse, before anything is decoded, MPI folders (any format `import` reads) whose planes would not
/// fit `budget`: `copies` copies of each, as f32 texels or (`u8`) 8-bit ones. A 1 KB mpi.json or
/// mpi_compact.json can announce planes of tens of GB.
pub fn check_mpis_fit(
    what: &str,
    dirs: &[&std::path::Path],
    u8: bool,
    copies: u64,
    budget: u64,
) -> anyhow::Result<()> {
    let mut need = 0u64;
    let mut sizes = Vec::new();
    for dir in dirs {
        let (_, w, h, d) = deepview_mpi::interchange::describe(dir)?;
        // The texels, with a layer's decoding per thread (`mpi_bytes`; these commands only decode,
        // convert and write: no renderer's scratch).
        need = need.saturating_add(mpi_bytes(w, h, d, u8).saturating_mul(copies));
        sizes.push(format!("{}: {d} planes of {w}x{h}", dir.display()));
    }
    check_memory(&format!("{what} {}", sizes.join(" and ")), need, budget)
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
    parse_bytes(s)
        .map(|_| s.to_string())
        .map_err(|e| e.to_string())
}

/// Parse a byte count with an optional unit (B, K/KB/KiB, M/MB/MiB, G/GB/GiB; binary multiples).
pub fn parse_bytes(text: &str) -> anyhow::Result<u64> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let value: f64 = num
        .parse()
        .with_context(|| format!("{text:?} is not a memory size (e.g. 2GiB)"))?;
    let mult: u64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "k" | "kb" | "kib" => 1 << 10,
        "m" | "mb" | "mib" => 1 << 20,
        "g" | "gb" | "gib" => 1 << 30,
        "t" | "tb" | "tib" => 1 << 40,
        u => bail!("unknown memory unit {u:?} in {text:?} (use B, KiB, MiB or GiB)"),
    };
    if !value.is_finite() || value <= 0.0 {
        bail!("memory size must be positive, got {text:?}");
    }
    Ok((value * mult as f64) as u64)
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

/// A count of at least one (`--repeats`, `--frames`, ...) and a finite number above zero (`--fps`, `--lr`,
/// ...): the parsers of the training options, shared by every command.
pub use deepview_train::options::{parse_positive, parse_positive_f64};

/// A plane count of a benchmark's MPI: 1 to [`deepview_geometry::MAX_PLANES`].
pub fn parse_plane_count(s: &str) -> Result<usize, String> {
    let n = parse_positive(s)?;
    if n > deepview_geometry::MAX_PLANES {
        return Err(format!(
            "{n} planes: deepview makes MPIs of at most {}",
            deepview_geometry::MAX_PLANES
        ));
    }
    Ok(n)
}

/// The most input views a benchmark makes (the synthetic views are made before the memory of the
/// whole run can be told).
pub const BENCH_MAX_VIEWS: usize = 256;

/// An input view count of a benchmark: 1 to [`BENCH_MAX_VIEWS`].
pub fn parse_view_count(s: &str) -> Result<usize, String> {
    let n = parse_positive(s)?;
    if n > BENCH_MAX_VIEWS {
        return Err(format!(
            "{n} views: a benchmark takes at most {BENCH_MAX_VIEWS}"
        ));
    }
    Ok(n)
}

/// The help text of `--max-memory`.
pub const MEMORY_HELP: &str = "Memory budget, e.g. 2GiB, 512MiB, 1500000000, or auto (default): three \
    quarters of the memory available now (MemAvailable in /proc/meminfo), leaving at least 1 GiB free; 2 GiB \
    when that cannot be read. More than the machine's memory is refused. Inference keeps its state between \
    the nets in f32 when that fits, else in half floats, else runs in tiles (many times slower).";

/// Bytes of `MemAvailable` in `/proc/meminfo`.
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    parse_mem_available(&text)
}

/// A kB field of `/proc/self/status` (`VmRSS`, `VmHWM`, ...).
pub fn proc_status_kb(key: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s
        .lines()
        .find(|l| l.strip_prefix(key).is_some_and(|r| r.starts_with(':')))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Bytes this process holds in memory now (`VmRSS`).
pub fn resident_bytes() -> Option<u64> {
    proc_status_kb("VmRSS").map(|kb| kb * 1024)
}

/// Bytes of physical memory (`MemTotal` in `/proc/meminfo`).
pub fn total_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    parse_meminfo(&text, "MemTotal:")
}

fn parse_mem_available(meminfo: &str) -> Option<u64> {
    parse_meminfo(meminfo, "MemAvailable:")
}

/// The value of the `/proc/meminfo` field `key` (with its colon) in bytes.
fn parse_meminfo(meminfo: &str, key: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with(key))?;
    let mut it = line[key.len()..].split_whitespace();
    let value: u64 = it.next()?.parse().ok()?;
    match it.next().map(str::to_ascii_lowercase).as_deref() {
        Some("kb") => Some(value * 1024),
        None | Some("b") => Some(value),
        _ => None,
    }
}

/// The fallback budget when the available memory cannot be read.
pub const FALLBACK_BUDGET: u64 = 2 << 30;

/// Memory the default budget leaves to everything else: at least this much of `MemAvailable`, and at least
/// a quarter of it.
pub const DEFAULT_HEADROOM: u64 = 1 << 30;

/// The default budget out of `available` bytes: three quarters of it, leaving at least [`DEFAULT_HEADROOM`]
/// (half of it on a machine with less than twice that available). Measured on a wide capture (issue 27,
/// 1004x753 photos at half resolution, 2 cores): with the old fixed 3 GiB cap the learned model got 101-135
/// planes instead of the rule's 196-256 and took the tiled path at 854-1056 s per view; with 12 GiB it ran
/// the rule's planes on the whole-image engine in 48-66 s per view.
pub fn default_budget(available: u64) -> u64 {
    if available < 2 * DEFAULT_HEADROOM {
        available / 2
    } else {
        (available / 4 * 3).min(available - DEFAULT_HEADROOM)
    }
}

/// A memory size in GiB, or in MiB under 1 GiB (a 10 MiB budget is not "0.0 GiB").
fn gib(bytes: u64) -> String {
    if bytes < 1 << 30 {
        format!("{:.1} MiB", bytes as f64 / (1u64 << 20) as f64)
    } else {
        format!("{:.1} GiB", bytes as f64 / (1u64 << 30) as f64)
    }
}

/// The budget of `--max-memory` (`None` or `auto`: [`default_budget`] of `MemAvailable`;
/// [`FALLBACK_BUDGET`] when unknown), and the line saying where it came from.
pub fn memory_budget_of(
    arg: Option<&str>,
    available: Option<u64>,
    total: Option<u64>,
) -> anyhow::Result<(u64, String)> {
    match arg.map(str::trim) {
        Some(t) if !t.eq_ignore_ascii_case("auto") => {
            let b = parse_bytes(t).context("--max-memory")?;
            // More than the machine has would end in an allocation abort, not in a clear error.
            if let Some(total) = total.filter(|&m| b > m) {
                bail!(
                    "--max-memory {t} is more than this machine's {} of memory: pass at most that, e.g. \
                     {} (half of what is free now)",
                    gib(total),
                    min_arg(available.unwrap_or(total).min(total) / 2)
                );
            }
            let warn = match available {
                Some(a) if b > a => format!(
                    "; only {} is available now, so the run may be stopped for memory",
                    gib(a)
                ),
                _ => String::new(),
            };
            Ok((
                b,
                format!("memory budget: {} (--max-memory {t}{warn})", gib(b)),
            ))
        }
        _ => Ok(match available {
            Some(a) if a > 0 => {
                let b = default_budget(a);
                (
                    b,
                    format!(
                        "memory budget: {} (of the {} available now; --max-memory to change)",
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
    let (bytes, line) = memory_budget_of(arg, available_memory(), total_memory())?;
    eprintln!("{line}");
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_lists_and_sizes() {
        assert_eq!(min_arg((1 << 20) + 1), "2MiB");
        assert!("1,2,1".parse::<ViewList>().is_err());
        assert_eq!(
            "3, 1".parse::<ViewList>().unwrap().check(4).unwrap(),
            [3, 1]
        );
        assert!("3,4".parse::<ViewList>().unwrap().check(4).is_err());
        assert_eq!(parse_bytes("2GiB").unwrap(), 2 << 30);
        assert_eq!(parse_bytes("512 MiB").unwrap(), 512 << 20);
        assert_eq!(parse_bytes("1000").unwrap(), 1000);
        assert_eq!(parse_bytes("1.5g").unwrap(), 3 << 29);
        assert!(parse_bytes("lots").is_err());
        assert!(parse_bytes("2XB").is_err());
        assert!(parse_bytes("0").is_err());
    }

    #[test]
    fn memory_budget_from_meminfo() {
        let info = "MemTotal:       24000000 kB\nMemFree:  100 kB\nMemAvailable:   20971520 kB\n";
        assert_eq!(parse_mem_available(info), Some(20971520 * 1024));
        assert_eq!(parse_mem_available("MemTotal: 5 kB\n"), None);
        let (b, line) = memory_budget_of(None, Some(4 << 30), None).unwrap();
        assert_eq!(b, 3 << 30);
        assert!(
            line.contains("3.0 GiB") && line.contains("4.0 GiB available"),
            "{line}"
        );
        let (b, _) = memory_budget_of(Some("auto"), Some(20 << 30), None).unwrap();
        assert_eq!(b, 15 << 30);
        // Small machines keep at least 1 GiB free, tiny ones half.
        assert_eq!(default_budget(3 << 30), 2 << 30);
        assert_eq!(default_budget(1 << 30), 1 << 29);
        assert_eq!(
            memory_budget_of(None, None, None).unwrap().0,
            FALLBACK_BUDGET
        );
        assert_eq!(
            memory_budget_of(Some("512MiB"), Some(8 << 30), Some(16 << 30))
                .unwrap()
                .0,
            512 << 20
        );
        assert!(memory_budget_of(Some("lots"), None, None).is_err());
        // A small budget is said in MiB, not as "0.0 GiB".
        let (_, line) = memory_budget_of(Some("10MiB"), Some(8 << 30), Some(16 << 30)).unwrap();
        assert!(line.contains("memory budget: 10.0 MiB"), "{line}");
        // Beyond the machine: refused, naming a value that fits; beyond what is free: a warning.
        let e = memory_budget_of(Some("64GiB"), Some(8 << 30), Some(16 << 30)).unwrap_err();
        assert!(
            e.to_string().contains("16.0 GiB") && e.to_string().contains("4096MiB"),
            "{e}"
        );
        let (b, line) = memory_budget_of(Some("12GiB"), Some(8 << 30), Some(16 << 30)).unwrap();
        assert_eq!(b, 12 << 30);
        assert!(line.contains("only 8.0 GiB"), "{line}");
        assert!(more_memory_hint(32 << 30, Some(16 << 30)).contains("more than this machine"));
        assert!(more_memory_hint(8 << 30, Some(16 << 30)).contains("--max-memory 8192MiB"));
    }
}
