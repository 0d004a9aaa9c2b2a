//! Never destroy a user's data: outputs checked against inputs before any work ([`check_output`]), whole
//! folders written into a temporary sibling and swapped into place ([`OutputDir`]), file outputs whose
//! format follows their extension ([`ImageFormat`]).
//!
//! Every command that writes calls [`check_output`] once per output with all its inputs, before it loads
//! or allocates anything. It refuses (exit 2, naming both) an output that is, contains or lies inside one
//! of the inputs; an output that is or lies inside a training run or a weights folder (unless it is a
//! weights export replacing a weights folder); an output folder that would replace a folder of another
//! kind (a dataset, photos, your home folder: only empty folders and earlier outputs of the same kind are
//! replaced).

use super::signals;
use anyhow::{Context, bail};
use std::path::{Component, Path, PathBuf};

/// What an output is, for recognising the folders it may replace.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// One file (an image, a video, a JSON report).
    File,
    /// An MPI folder (`mpi.json` + layers).
    Mpi,
    /// A weights folder (`config.json` + `model.safetensors`).
    Weights,
    /// A training run (`config.json`, `checkpoints/`, `metrics.jsonl`).
    Run,
    /// A synthetic scene (`synth.json`).
    SynthScene,
    /// An MPI export (LLFF, stereo magnification or compact).
    Export,
    /// A web viewer folder (`index.html` + an MPI).
    Web,
    /// A plane sweep volume (`psv.json` + `psv_NNN.png`).
    Psv,
    /// A folder of video frames (`frame_NNNNN.png`).
    Frames,
    /// A folder of depth maps (`PREFIX_color.png`, `PREFIX_disparity16.png`): written into, never replaced.
    DepthMaps,
    /// A folder of evaluation renders (`NNN_NAME.png`): written into, never replaced.
    Renders,
    /// A folder of evaluation MPIs (`NNN_NAME/`): written into, never replaced.
    Mpis,
    /// The demo's folder.
    Demo,
    /// A scene made by `deepview process` (always a new or empty folder).
    ProcessedScene,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::File => "file",
            Kind::Mpi => "MPI folder",
            Kind::Weights => "weights folder",
            Kind::Run => "training run",
            Kind::SynthScene => "synthetic scene",
            Kind::Export => "MPI export",
            Kind::Web => "web viewer folder",
            Kind::Psv => "plane sweep volume folder",
            Kind::Frames => "folder of video frames",
            Kind::DepthMaps => "folder of depth maps",
            Kind::Renders => "folder of evaluation renders",
            Kind::Mpis => "folder of evaluation MPIs",
            Kind::Demo => "demo folder",
            Kind::ProcessedScene => "new scene folder",
        }
    }

    /// Folders that are written into, file by file, never replaced whole.
    fn written_into(self) -> bool {
        matches!(self, Kind::DepthMaps | Kind::Renders | Kind::Mpis)
    }

    /// Whether an output folder of this kind writes the entry `name` (a file, or a folder with everything
    /// in it): the explicit set of outputs, which alone a command replaces.
    pub fn owns(self, name: &str, is_dir: bool) -> bool {
        let mpi = |n: &str| n == "mpi.json" || numbered(n, "layer_", ".png");
        match (self, is_dir) {
            (Kind::Mpi, false) => mpi(name),
            (Kind::Web, false) => {
                mpi(name)
                    || name == "index.html"
                    || name == deepview_mpi::interchange::compact::META
                    || numbered(name, "tiles_", ".png")
            }
            (Kind::Weights, false) => {
                name == deepview_net::weights::CONFIG_FILE
                    || name == deepview_net::weights::WEIGHTS_FILE
            }
            (Kind::SynthScene, false) => {
                matches!(
                    name,
                    "synth.json" | "models.json" | "poses_bounds.npy" | "transforms.json"
                ) || name == deepview_data::formats::lightfield::GT_DISPARITY
                    || name == deepview_data::formats::lightfield::PARAMETERS
                    || numbered(name, "input_Cam", ".png")
            }
            (Kind::SynthScene, true) => {
                matches!(name, "ground_truth_mpi" | "images" | "sparse")
                    || numbered(name, "images_", "")
                    || numbered(name, "cam_", "")
            }
            (Kind::Export, false) => {
                name == EXPORT_MANIFEST
                    || EXPORT_LISTED.contains(&name)
                    || name == deepview_mpi::interchange::compact::META
                    || name == deepview_mpi::interchange::stereo_mag::SIDECAR
                    || numbered(name, "tiles_", ".png")
                    || numbered(name, "mpi_rgb_", ".png")
                    || numbered(name, "mpi_alpha_", ".png")
            }
            (Kind::Psv, false) => name == "psv.json" || numbered(name, "psv_", ".png"),
            (Kind::DepthMaps, false) => {
                name.ends_with("_color.png") || name.ends_with("_disparity16.png")
            }
            (Kind::Renders, false) => evaluated(name, ".png"),
            (Kind::Mpis, true) => evaluated(name, ""),
            (Kind::Frames, false) => numbered(name, "frame_", ".png"),
            (Kind::Demo, false) => matches!(name, "spiral.gif" | "eval.json" | "eval.md"),
            (Kind::Demo, true) => {
                matches!(name, "scene" | "mpi" | "novel_views" | "depth" | "renders")
            }
            _ => false,
        }
    }

    /// Whether the existing folder `dir` is an earlier output of this kind (which it may replace).
    fn recognises(self, dir: &Path) -> bool {
        let has = |n: &str| dir.join(n).is_file();
        match self {
            Kind::Mpi => has("mpi.json"),
            Kind::Weights => is_weights(dir),
            Kind::Run => deepview_train::is_run_folder(dir),
            Kind::SynthScene => has("synth.json"),
            Kind::Export => {
                has(deepview_mpi::interchange::compact::META)
                    || (has("metadata.txt") && has("mpi.b"))
                    || has("mpi_rgb_00.png")
            }
            Kind::Web => has("index.html"),
            Kind::Psv => has("psv.json"),
            Kind::Frames => has("frame_00000.png"),
            Kind::Demo => has("eval.md") || dir.join("scene").join("synth.json").is_file(),
            Kind::File | Kind::DepthMaps | Kind::Renders | Kind::Mpis | Kind::ProcessedScene => {
                false
            }
        }
    }
}

/// A weights folder: `config.json` + `model.safetensors`.
pub fn is_weights(dir: &Path) -> bool {
    dir.join(deepview_net::weights::CONFIG_FILE).is_file()
        && dir.join(deepview_net::weights::WEIGHTS_FILE).is_file()
}

/// `path` made absolute, symbolic links of its existing part resolved, `.` and `..` of the rest removed.
pub fn resolve(path: &Path) -> PathBuf {
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir()
            .unwrap_or_else(|_| PathBuf::from("/"))
            .join(path)
    };
    // The longest existing prefix, canonicalised, then the remaining components lexically.
    let comps: Vec<Component> = abs.components().collect();
    for split in (0..=comps.len()).rev() {
        let head: PathBuf = comps[..split].iter().collect();
        if let Ok(mut out) = head.canonicalize() {
            for c in &comps[split..] {
                match c {
                    Component::ParentDir => {
                        out.pop();
                    }
                    Component::CurDir => {}
                    c => out.push(c),
                }
            }
            return out;
        }
    }
    abs
}

/// An input of a command: its option and path (`("--data", fern)`).
pub type Input<'a> = (&'a str, &'a Path);

/// Refuse an output (`option`, e.g. `--out`) that would overwrite an input or a folder it must not
/// replace; see the module documentation. Inputs that are not paths (`synthetic:…`) are skipped.
pub fn check_output(option: &str, out: &Path, kind: Kind, inputs: &[Input]) -> anyhow::Result<()> {
    // A link to nothing: replacing it would fail at the end (or make its target somewhere unexpected).
    if let Ok(m) = std::fs::symlink_metadata(out)
        && m.file_type().is_symlink()
        && std::fs::metadata(out).is_err()
    {
        let to = std::fs::read_link(out).unwrap_or_default();
        bail!(
            "{option} {} is a symbolic link to {}, which does not exist: remove the link or choose another \
             {option}",
            out.display(),
            to.display()
        );
    }
    // Outputs are written to a temporary and renamed into place, which would replace a pipe, a device
    // or `/dev/stdout` itself (as root, a link of the system's).
    if out.as_os_str() == "-" {
        bail!("{option} -: deepview writes files, not standard output; give a file name");
    }
    let system = |p: &Path| p.starts_with("/dev") || p.starts_with("/proc");
    if system(out) || std::fs::canonicalize(out).is_ok_and(|p| system(&p)) {
        bail!(
            "{option} {} is in /dev or /proc: outputs are written to a temporary and renamed into place, \
             which would replace a link or device of the system's; give a file name",
            out.display()
        );
    }
    if let Ok(m) = std::fs::metadata(out)
        && !m.is_file()
        && !m.is_dir()
    {
        bail!(
            "{option} {} is not a regular file or folder (a pipe, socket or device): outputs are written \
             to a temporary file renamed into place, which would replace it; give a file name",
            out.display()
        );
    }
    // A folder that is replaced whole, named as `.` or `..`: the swap would move the folder the shell
    // is in (and its temporary would be made inside it).
    if kind != Kind::File && !kind.written_into() && kind != Kind::Run && {
        // As typed: `mpi/.` has the file name `mpi` once parsed into components.
        use std::os::unix::ffi::OsStrExt;
        let b = out.as_os_str().as_bytes();
        let b = b.strip_suffix(b"/").unwrap_or(b);
        out.file_name().is_none()
            || b == b"."
            || b == b".."
            || b.ends_with(b"/.")
            || b.ends_with(b"/..")
    } {
        let name = std::fs::canonicalize(out)
            .ok()
            .and_then(|c| c.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_else(|| "NAME".into());
        bail!(
            "{option} {} names a folder by `.` or `..`: a {} is written beside it and swapped into its \
             place, which cannot be done to the folder you are in; name it from its parent (e.g. \
             {option} ../{name})",
            out.display(),
            kind.name()
        );
    }
    // An output through a link, a file or a folder replaced whole: the rename would replace the link
    // (and leave what it names untouched, a folder on another disk empty), and the check of what may
    // be replaced would look at what it names, not the link. (Folders written into follow links.)
    // (Without its trailing slashes: `link/` names what the link names.)
    let unslashed = {
        use std::os::unix::ffi::OsStrExt;
        let b = out.as_os_str().as_bytes();
        let end = b
            .iter()
            .rposition(|&c| c != b'/')
            .map_or(b.len().min(1), |i| i + 1);
        std::path::PathBuf::from(std::ffi::OsStr::from_bytes(&b[..end]))
    };
    if (kind == Kind::File || !(kind.written_into() || kind == Kind::Run))
        && std::fs::symlink_metadata(&unslashed).is_ok_and(|m| m.file_type().is_symlink())
    {
        let to = std::fs::read_link(&unslashed).unwrap_or_default();
        let what = if kind == Kind::File { "file" } else { "folder" };
        bail!(
            "{option} {} is a symbolic link to {}: outputs are written to a temporary renamed into place, \
             which would replace the link; give the {what} it names or another name",
            out.display(),
            to.display()
        );
    }
    let o = resolve(out);
    for (what, input) in inputs {
        if input.to_str().is_some_and(|s| s.starts_with("synthetic:")) {
            continue;
        }
        let i = resolve(input);
        let relation = if o == i {
            "is"
        } else if o.starts_with(&i) {
            "lies inside"
        } else if i.starts_with(&o) {
            "contains"
        } else {
            continue;
        };
        bail!(
            "{option} {} {relation} the input {what} {}: refusing to overwrite an input; choose another {option}",
            out.display(),
            input.display()
        );
    }
    // Runs and weights are never written over by another kind of output, nor written into.
    for a in o.ancestors() {
        let exact = a == o;
        if deepview_train::is_run_folder(a) && !(exact && kind == Kind::Run) {
            bail!(
                "{option} {} {} the training run {}: refusing to overwrite it; choose another {option}",
                out.display(),
                if exact { "is" } else { "lies inside" },
                a.display()
            );
        }
        if (is_weights(a) || deepview_net::weights::is_checkpoint(a))
            && !(exact && kind == Kind::Weights && is_weights(a))
        {
            bail!(
                "{option} {} {} the weights folder {}: refusing to overwrite it; choose another {option}",
                out.display(),
                if exact { "is" } else { "lies inside" },
                a.display()
            );
        }
        // Nor into a dataset (photos, poses) that is not an input either.
        if !exact && a.is_dir() && deepview_data::detect_format(a).is_ok() {
            bail!(
                "{option} {} lies inside the dataset {}: refusing to write into a dataset; choose another \
                 {option}",
                out.display(),
                a.display()
            );
        }
        let mpi_file = kind == Kind::File
            && o.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n == "mpi.json" || n.starts_with("layer_"));
        if !exact && (kind != Kind::File || mpi_file) && a.join("mpi.json").is_file() {
            bail!(
                "{option} {} lies inside the MPI folder {}: choose another {option}",
                out.display(),
                a.display()
            );
        }
    }
    // A folder's own files and subfolders lengthen its paths (the demo's go two levels down).
    check_writable(option, out, &o, if kind == Kind::File { 0 } else { 64 })?;
    match std::fs::metadata(&o) {
        Err(_) => {}
        Ok(m) if kind == Kind::File => {
            if m.is_dir() {
                bail!(
                    "{option} {} is a folder, expected a file name",
                    out.display()
                );
            }
            if let Some(what) = foreign_file(&o) {
                bail!(
                    "{option} {} exists and is not {what}: refusing to replace it; choose another name or \
                     move it away",
                    out.display()
                );
            }
            if let Some(what) = users_media(&o) {
                bail!(
                    "{option} {} exists and is {what} deepview did not write (a photo or video of \
                     yours, or an output of an older deepview): refusing to replace it; choose another \
                     name or move it away",
                    out.display()
                );
            }
        }
        Ok(m) if !m.is_dir() => {
            bail!(
                "{option} {} is a file, expected a folder ({})",
                out.display(),
                kind.name()
            );
        }
        Ok(_) => {
            let empty = std::fs::read_dir(&o)
                .with_context(|| format!("cannot read {}", out.display()))?
                .next()
                .is_none();
            if !empty && kind == Kind::ProcessedScene {
                bail!(
                    "{option} {} already exists and is not empty: choose a new or empty folder (existing \
                     output is never replaced)",
                    out.display()
                );
            }
            let written_into = kind.written_into();
            if !empty && !written_into && !kind.recognises(&o) {
                bail!(
                    "{option} {} exists and is not {} {}: refusing to replace it; choose a new or empty folder",
                    out.display(),
                    if kind.name().starts_with(['M', 'a', 'e', 'i', 'o', 'u']) {
                        "an"
                    } else {
                        "a"
                    },
                    kind.name()
                );
            }
            // Runs are written into (checkpoints, metrics), never replaced whole.
            if !empty && kind != Kind::Run {
                refuse_foreign(option, out, &o, kind)?;
            }
        }
    }
    Ok(())
}

/// Refuse an output that cannot be written (a read-only folder or file system, a file where a folder
/// must be made) now, before the work, rather than after minutes of it: a probe file is made and removed
/// in the folder the output goes into (or in its nearest existing ancestor, where folders will be made).
fn check_writable(option: &str, out: &Path, resolved: &Path, inner: usize) -> anyhow::Result<()> {
    // The system's limit on a path (PATH_MAX, 4096 bytes with its NUL), with room for a temporary's
    // longer name and the `inner` bytes of the paths inside a folder: past it every write would fail,
    // after the work.
    let len = out.as_os_str().len().min(resolved.as_os_str().len());
    if len + deepview_image::TEMP_NAME_EXTRA + inner >= 4096 {
        bail!(
            "{option}: the path is {len} bytes long, more than the system takes (4096 bytes, with room \
             for a temporary beside it); choose a shorter path"
        );
    }
    // A folder on the way that is a link to nothing: creating the folders would fail after the work.
    for a in resolved.ancestors().skip(1) {
        if let Ok(m) = std::fs::symlink_metadata(a)
            && m.file_type().is_symlink()
            && std::fs::metadata(a).is_err()
        {
            let to = std::fs::read_link(a).unwrap_or_default();
            bail!(
                "{option} {}: {} is a symbolic link to {}, which does not exist: remove the link or \
                 create its target",
                out.display(),
                a.display(),
                to.display()
            );
        }
    }
    let Some(existing) = resolved
        .parent()
        .into_iter()
        .flat_map(Path::ancestors)
        .find(|a| a.exists())
    else {
        return Ok(());
    };
    if !existing.is_dir() {
        bail!(
            "{option} {}: {} is a file, so no folder can be made there",
            out.display(),
            existing.display()
        );
    }
    // Probes a killed run left here (`.deepview-probe.PID-TOKEN` of a process that has died) go.
    for e in std::fs::read_dir(existing).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some(pid) = name
            .strip_prefix(".deepview-probe.")
            .and_then(|t| t.split_once('-'))
            .map(|(pid, _)| pid)
            && died(pid)
        {
            let _ = std::fs::remove_file(e.path());
        }
    }
    let probe = existing.join(format!(".deepview-probe.{}", deepview_image::temp_token()));
    // (Registered: a signal between its making and removal removes it too.)
    signals::register(&probe);
    let made = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe);
    if made.is_ok() {
        let _ = std::fs::remove_file(&probe);
    }
    signals::unregister(&probe);
    match made {
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        Err(e) => {
            // Named as the user typed it (not through resolved links like /proc/self).
            let shown = out
                .ancestors()
                .skip(1)
                .find(|a| !a.as_os_str().is_empty() && a.exists())
                .unwrap_or(existing);
            bail!(
                "{option} {}: cannot write in {}: {e}",
                out.display(),
                shown.display()
            )
        }
    }
}

/// What the existing file `path` should be, from its extension, when its content is not that (a user's
/// notes named `view.png`); `None` when it may be replaced: content of its kind, an empty file, or an
/// extension of no known kind.
fn foreign_file(path: &Path) -> Option<&'static str> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    let (what, ok): (&str, fn(&[u8]) -> bool) = match ext.as_str() {
        "png" => ("a PNG image", |b| b.starts_with(b"\x89PNG\r\n\x1a\n")),
        "jpg" | "jpeg" => ("a JPEG image", |b| b.starts_with(&[0xFF, 0xD8, 0xFF])),
        "gif" => ("a GIF animation", |b| b.starts_with(b"GIF8")),
        "mp4" | "mov" | "m4v" => ("an MP4 video", |b| b.len() >= 8 && &b[4..8] == b"ftyp"),
        // The JSON files deepview writes are evaluation reports.
        "json" => ("an evaluation report", |b| {
            serde_json::from_slice::<serde_json::Value>(b)
                .ok()
                .is_some_and(|v| v.get("results").is_some())
        }),
        _ => return None,
    };
    let mut head = Vec::with_capacity(16);
    let f = std::fs::File::open(path).ok()?;
    let limit = if ext == "json" { 16 << 20 } else { 4096 };
    std::io::Read::read_to_end(&mut std::io::Read::take(f, limit), &mut head).ok()?;
    (!head.is_empty() && !ok(&head)).then_some(what)
}

/// What the existing image or video `path` is where deepview did not write it (no
/// [`deepview_image::MARK`]): a user's photo or video named like an output. `None` for anything
/// else (an empty file, deepview's own output, a file of another kind).
fn users_media(path: &Path) -> Option<&'static str> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    let what = match ext.as_str() {
        "png" => "a PNG image",
        "jpg" | "jpeg" => "a JPEG image",
        "gif" => "a GIF animation",
        "mp4" | "mov" | "m4v" | "mkv" => "a video",
        _ => return None,
    };
    let len = std::fs::metadata(path).ok()?.len();
    (len > 0 && !deepview_image::written_by_deepview(path)).then_some(what)
}

/// Whether the file `path`, named like one an output writes, may be what deepview wrote: images (and
/// videos) carry its mark ([`deepview_image::written_by_deepview`]), a web viewer's `index.html` is
/// deepview's viewer; other files are taken by their names.
fn written_here(path: &Path) -> bool {
    if path.file_name().is_some_and(|n| n == "index.html") {
        let mut head = Vec::new();
        let read = std::fs::File::open(path)
            .and_then(|f| std::io::Read::read_to_end(&mut std::io::Read::take(f, 4096), &mut head));
        return read.is_ok() && head.windows(VIEWER_TITLE.len()).any(|w| w == VIEWER_TITLE);
    }
    users_media(path).is_none()
}

/// The file in which `export` lists the files it wrote that can carry no mark of their own (another
/// tool's formats: `README`, `intrinsics.txt`, `metadata.txt`, `mpi.b`), with their sizes and hashes:
/// only those listed, unchanged, are its own (a user's `README` in an export folder, or an MPI that LLFF
/// itself wrote, are not replaced).
pub const EXPORT_MANIFEST: &str = "deepview_export.json";

/// The names an export writes that are its own only where [`EXPORT_MANIFEST`] lists them.
const EXPORT_LISTED: [&str; 4] = ["metadata.txt", "mpi.b", "intrinsics.txt", "README"];

/// FNV-1a (64 bits) of a file's bytes, streamed.
fn file_hash(path: &Path) -> std::io::Result<(u64, u64)> {
    use std::io::Read;
    let mut f = std::fs::File::open(path)?;
    let mut buf = vec![0u8; 1 << 16];
    let (mut h, mut len) = (0xcbf2_9ce4_8422_2325u64, 0u64);
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            return Ok((len, h));
        }
        len += n as u64;
        for &b in &buf[..n] {
            h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    }
}

/// Write [`EXPORT_MANIFEST`] into the export folder `dir` for the files of `written` it must list.
pub fn write_export_manifest(dir: &Path, written: &[PathBuf]) -> anyhow::Result<()> {
    let mut files = serde_json::Map::new();
    for path in written {
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
            continue;
        };
        if EXPORT_LISTED.contains(&name) {
            let (bytes, hash) =
                file_hash(path).with_context(|| format!("cannot read {}", path.display()))?;
            files.insert(
                name.into(),
                serde_json::json!({ "bytes": bytes, "fnv1a64": format!("{hash:016x}") }),
            );
        }
    }
    let json = serde_json::json!({ "written_by": "deepview export", "files": files });
    let path = dir.join(EXPORT_MANIFEST);
    deepview_image::write_atomic(&path, serde_json::to_string_pretty(&json)?.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Whether the export folder `dir`'s manifest lists its file `name` as it is now.
fn listed_in_manifest(dir: &Path, name: &str) -> bool {
    let listed = || -> Option<bool> {
        let text = deepview_image::read_text(&dir.join(EXPORT_MANIFEST)).ok()?;
        let json: serde_json::Value = serde_json::from_str(&text).ok()?;
        let entry = json.get("files")?.get(name)?;
        let (bytes, hash) = file_hash(&dir.join(name)).ok()?;
        Some(
            entry.get("bytes")?.as_u64()? == bytes
                && entry.get("fnv1a64")?.as_str()? == format!("{hash:016x}"),
        )
    };
    listed().unwrap_or(false)
}

/// The title of deepview's web viewer (`crates/deepview-viewer/web/index.html`), in its first lines.
const VIEWER_TITLE: &[u8] = b"<title>deepview MPI viewer</title>";

/// How [`foreign_entries`] names a file it counts as foreign for want of deepview's mark.
const UNMARKED: &str = " (a file deepview did not write)";

/// How [`foreign_entries`] names an export's file that its [`EXPORT_MANIFEST`] does not list as it is.
const UNLISTED: &str = " (not listed as it is in deepview_export.json: not written by this deepview, or \
     edited since)";

/// Refuse to replace the existing folder `dir` (`out` as the user typed it) when it holds anything the
/// command did not write there: a user's notes, a subfolder, photos kept beside an MPI, photos named
/// like its own images.
fn refuse_foreign(option: &str, out: &Path, dir: &Path, kind: Kind) -> anyhow::Result<()> {
    let foreign = foreign_entries(dir, kind)
        .with_context(|| format!("cannot read {option} {}", out.display()))?;
    if foreign.is_empty() {
        return Ok(());
    }
    let shown: Vec<&str> = foreign.iter().take(4).map(String::as_str).collect();
    let more = match foreign.len() - shown.len() {
        0 => String::new(),
        n => format!(" and {n} more"),
    };
    let what = if kind.written_into() {
        "refusing to write into it, which could overwrite them"
    } else {
        "refusing to replace it, which would delete them"
    };
    let older = if foreign
        .iter()
        .any(|f| f.ends_with(UNMARKED) || f.ends_with(UNLISTED))
    {
        " (outputs of an older deepview carry no mark and are refused once)"
    } else {
        ""
    };
    bail!(
        "{option} {} holds files that {} {} does not have ({}{more}): {what}; move them away or choose \
         a new or empty folder{older}",
        out.display(),
        if kind.name().starts_with(['M', 'a', 'e', 'i', 'o', 'u']) {
            "an"
        } else {
            "a"
        },
        kind.name(),
        shown.join(", ")
    )
}

/// The entries of the existing folder `dir` (paths relative to it, folders with a trailing `/`) that an
/// output of `kind` does not write: what replacing the folder would destroy. Leftovers of interrupted
/// atomic writes of its own files count as its own. The subfolders it writes are checked the same way,
/// entry by entry (a user's notes inside the demo's `renders/` would go with the folder).
pub fn foreign_entries(dir: &Path, kind: Kind) -> std::io::Result<Vec<String>> {
    let mut foreign = Vec::new();
    foreign_within(dir, Part::Of(kind), "", 0, &mut foreign)?;
    foreign.sort();
    Ok(foreign)
}

/// What an output folder, or one of the subfolders it writes, holds of its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Part {
    /// An output of this kind.
    Of(Kind),
    /// The demo's `novel_views/`: `view_NN.png` and `view_NN_ground_truth.png`.
    NovelViews,
    /// A synthetic scene's image folder (`images/`, `images_N/`): `imageNNN.png`.
    Images,
    /// A synthetic scene's `sparse/`: the model folder `0/`.
    Sparse,
    /// `sparse/0/`: COLMAP's text model.
    SparseModel,
    /// A synthetic Spaces scene's `cam_NN/`: `image_NNN.png`.
    SpacesCam,
}

impl Part {
    fn owns(self, name: &str, is_dir: bool) -> bool {
        match (self, is_dir) {
            (Part::Of(kind), _) => kind.owns(name, is_dir),
            (Part::NovelViews, false) => {
                numbered(name, "view_", ".png") || numbered(name, "view_", "_ground_truth.png")
            }
            (Part::Images, false) => numbered(name, "image", ".png"),
            (Part::Sparse, true) => name == "0",
            (Part::SparseModel, false) => {
                matches!(name, "cameras.txt" | "images.txt" | "points3D.txt")
            }
            (Part::SpacesCam, false) => numbered(name, "image_", ".png"),
            _ => false,
        }
    }

    /// What the subfolder `name` (one this part owns) may hold.
    fn inner(self, name: &str) -> Option<Part> {
        Some(match self {
            Part::Of(Kind::Demo) => match name {
                "scene" => Part::Of(Kind::SynthScene),
                "mpi" => Part::Of(Kind::Mpi),
                "novel_views" => Part::NovelViews,
                "depth" => Part::Of(Kind::DepthMaps),
                "renders" => Part::Of(Kind::Renders),
                _ => return None,
            },
            Part::Of(Kind::SynthScene) => match name {
                "ground_truth_mpi" => Part::Of(Kind::Mpi),
                "sparse" => Part::Sparse,
                n if n.starts_with("cam_") => Part::SpacesCam,
                _ => Part::Images,
            },
            // Each evaluated view's MPI folder.
            Part::Of(Kind::Mpis) => Part::Of(Kind::Mpi),
            Part::Sparse => Part::SparseModel,
            _ => return None,
        })
    }
}

fn foreign_within(
    dir: &Path,
    part: Part,
    prefix: &str,
    depth: usize,
    foreign: &mut Vec<String>,
) -> std::io::Result<()> {
    // Errors name the folder (a subfolder that cannot be read, not only the output).
    let named =
        |e: std::io::Error| std::io::Error::new(e.kind(), format!("{}: {e}", dir.display()));
    // A web viewer folder copies its MPI's layers under their own names (`plane0.png`, as the MPI's
    // mpi.json lists them): those its own mpi.json lists are its own too, where they carry deepview's
    // mark (a listed file of another kind, `thesis.pdf`, is not).
    let listed: Vec<String> = match part {
        Part::Of(Kind::Web) => deepview_mpi::MpiMeta::read(dir)
            .map(|(meta, _)| meta.layers)
            .unwrap_or_default(),
        _ => Vec::new(),
    };
    for e in std::fs::read_dir(dir).map_err(named)? {
        let e = e.map_err(named)?;
        let name = e.file_name().to_string_lossy().into_owned();
        let is_dir = e.file_type().map_err(named)?.is_dir();
        let mut working = false;
        let own = match deepview_image::parse_temp(&name) {
            // `.NAME.TOKEN.tmp`: an interrupted write of one of its own files.
            Some(t) if t.folder.is_none() => !is_dir && t.ext.is_none() && part.owns(t.stem, false),
            // `.NAME.deepview-tmp.TOKEN/`: the folder another run is writing one of its files or
            // folders in (`depth` stages its pair so), or one a killed run left.
            Some(t) => {
                working = is_dir
                    && t.folder == Some("tmp")
                    && (part.owns(t.stem, false) || part.owns(t.stem, true));
                working
            }
            None => {
                part.owns(&name, is_dir)
                    || (!is_dir
                        && listed.contains(&name)
                        && deepview_image::written_by_deepview(&e.path()))
                    || (!is_dir && deepview_image::is_file_browser_clutter(&name))
            }
        };
        let shown = format!("{prefix}{name}");
        // An image named like one of its own that deepview did not write (no mark): a user's photo
        // kept under such a name, or an older deepview's output (refused once).
        let unlisted = own
            && !is_dir
            && !working
            && matches!(part, Part::Of(Kind::Export))
            && EXPORT_LISTED.contains(&name.as_str())
            && !listed_in_manifest(dir, &name);
        let unmarked = own && !is_dir && !working && !written_here(&e.path());
        if unlisted {
            foreign.push(format!("{shown}{UNLISTED}"));
        } else if unmarked {
            foreign.push(format!("{shown}{UNMARKED}"));
        } else if !own {
            foreign.push(if is_dir { format!("{shown}/") } else { shown });
        } else if is_dir && !working {
            // Every folder an output writes is known (`Part::inner`); the depth bound is a guard.
            match part.inner(&name).filter(|_| depth < 8) {
                Some(inner) => {
                    foreign_within(&e.path(), inner, &format!("{shown}/"), depth + 1, foreign)?
                }
                None => foreign.push(format!("{shown}/")),
            }
        }
    }
    Ok(())
}

/// `name` is an evaluated view's file or folder: `NNN_NAME` + `suffix`, NAME of `[A-Za-z0-9_]`.
fn evaluated(name: &str, suffix: &str) -> bool {
    name.strip_suffix(suffix)
        .and_then(|n| n.split_once('_'))
        .is_some_and(|(d, rest)| {
            d.len() >= 3
                && d.bytes().all(|b| b.is_ascii_digit())
                && rest.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_')
        })
}

/// `name` is `prefix` + ASCII digits + `suffix`.
fn numbered(name: &str, prefix: &str, suffix: &str) -> bool {
    name.strip_prefix(prefix)
        .and_then(|n| n.strip_suffix(suffix))
        .is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
}

/// Run names and file-name prefixes: one plain path component (`--name`, `--prefix`).
pub fn parse_component(s: &str) -> Result<String, String> {
    // Also no control characters, no leading '-' or '.', not only spaces, no name of this program's
    // temporaries, and short enough for every file system.
    let temp_like = s.ends_with(".tmp") || s.ends_with(".incomplete") || s.contains(".deepview-");
    let ok = !s.is_empty()
        && s != "."
        && s != ".."
        && !s.contains(['/', '\\', '\0'])
        && !s.chars().any(char::is_control)
        && !s.starts_with(['-', '.'])
        && !s.trim().is_empty()
        && !temp_like
        && s.len() <= 200
        && Path::new(s).components().count() == 1;
    if ok {
        Ok(s.to_string())
    } else {
        Err(format!(
            "{s:?} must be a plain file name of at most 200 bytes: no '/', control characters or leading \
             '-' or '.', not blank, not ending in .tmp or .incomplete"
        ))
    }
}

pub(super) fn sibling(out: &Path, tag: &str) -> PathBuf {
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    out.with_file_name(format!(
        ".{}.deepview-{tag}.{}",
        deepview_image::temp_stem(&name),
        deepview_image::temp_token()
    ))
}

/// A temporary sibling folder of `out` to write in (`.NAME.deepview-TAG.TOKEN`, a name no other process
/// makes: [`deepview_image::temp_token`]), created empty and locked ([`deepview_image::TempLock`]); one
/// of that name is this process's own leftover, removed first.
pub(super) fn make_temp_dir(
    out: &Path,
    tag: &str,
) -> anyhow::Result<(PathBuf, Option<deepview_image::TempLock>)> {
    let tmp = sibling(out, tag);
    if std::fs::symlink_metadata(&tmp).is_ok() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    signals::register(&tmp);
    if let Err(e) = std::fs::create_dir(&tmp) {
        signals::unregister(&tmp);
        return Err(e).with_context(|| format!("cannot create {}", tmp.display()));
    }
    let lock = deepview_image::lock_temp(&tmp);
    Ok((tmp, lock))
}

/// Folders created for an output (deepest last), removed again when they stay empty after a failure.
#[derive(Default)]
pub struct CreatedDirs(Vec<PathBuf>);

impl CreatedDirs {
    /// Create `dir` and its missing parents, remembering which were made.
    pub fn create(dir: &Path) -> anyhow::Result<Self> {
        let mut missing: Vec<PathBuf> = dir
            .ancestors()
            .filter(|a| !a.as_os_str().is_empty())
            .take_while(|a| !a.exists())
            .map(Path::to_path_buf)
            .collect();
        missing.reverse();
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        Ok(Self(missing))
    }

    /// Create the parent folder of the file `file`.
    pub fn parent_of(file: &Path) -> anyhow::Result<Self> {
        match file.parent().filter(|p| !p.as_os_str().is_empty()) {
            Some(p) => Self::create(p),
            None => Ok(Self::default()),
        }
    }

    /// Remove the created folders that are empty (after a failure).
    pub fn remove_empty(&mut self) {
        for d in self.0.drain(..).rev() {
            let _ = std::fs::remove_dir(&d);
        }
    }

    /// Keep them (success).
    pub fn keep(mut self) {
        self.0.clear();
    }
}

impl Drop for CreatedDirs {
    fn drop(&mut self) {
        self.remove_empty();
    }
}

/// Write an output file with `write` (itself atomic, e.g. `write_png`), creating its folder; on failure the
/// folders it created are removed again.
pub fn write_file<T>(
    out: &Path,
    write: impl FnOnce(&Path) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    remove_stale_files(out);
    let dirs = CreatedDirs::parent_of(out)?;
    let tmp = deepview_image::temp_path(out);
    signals::register(&tmp);
    let r = write(out);
    signals::unregister(&tmp);
    let v = r?;
    dirs.keep();
    Ok(v)
}

/// A whole output folder written into a temporary sibling (`.NAME.deepview-tmp.PID`) and swapped into
/// place by [`OutputDir::commit`]: an interrupted or failed command leaves the old folder (or none) as it
/// was. Dropped without a commit (an error), the temporary is removed; a signal removes it too
/// ([`signals`]); a temporary left by a killed process is removed the next time.
pub struct OutputDir {
    option: &'static str,
    out: PathBuf,
    kind: Kind,
    tmp: PathBuf,
    /// Held until the output is in place or removed.
    lock: Option<deepview_image::TempLock>,
    dirs: CreatedDirs,
    done: bool,
}

impl OutputDir {
    /// Start writing the folder `out` of `kind` (checked with [`check_output`] beforehand; checked again
    /// here, just before the work is written, for files that appeared in it since).
    pub fn new(out: &Path, kind: Kind) -> anyhow::Result<Self> {
        Self::for_option("--out", out, kind)
    }

    /// [`OutputDir::new`] for an output given by `option` (named in its errors).
    pub fn for_option(option: &'static str, out: &Path, kind: Kind) -> anyhow::Result<Self> {
        if out.is_dir() {
            refuse_foreign(option, out, out, kind)?;
        }
        let parent = match out.parent().filter(|p| !p.as_os_str().is_empty()) {
            Some(p) => p.to_path_buf(),
            None => PathBuf::from("."),
        };
        let dirs = CreatedDirs::create(&parent)?;
        remove_stale(out);
        let (tmp, lock) = make_temp_dir(out, "tmp")?;
        Ok(Self {
            option,
            out: out.to_path_buf(),
            kind,
            tmp,
            lock,
            dirs,
            done: false,
        })
    }

    /// The temporary folder to write into.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// Put the finished folder in place of `out` (the old folder, if any, is removed after the swap).
    pub fn commit(self) -> anyhow::Result<()> {
        commit_together(vec![self], || Ok(()))
    }

    /// The swap of [`OutputDir::commit`], run inside [`signals::publish`]: returns where the earlier
    /// output now is (registered as superseded before the registry is let go: a signal from then on
    /// removes it and says the new output is in place).
    fn swap_in(&self) -> anyhow::Result<Option<PathBuf>> {
        let (tmp, out, kind, option) = (&self.tmp, &self.out, self.kind, self.option);
        if !out.exists() {
            match std::fs::rename(tmp, out) {
                Ok(()) => return Ok(None),
                // Another run made `out` meanwhile (two runs of one command at once): replaced
                // below like any earlier output of this kind, if it is one.
                Err(_) if out.is_dir() => {}
                Err(e) => {
                    return Err(e).with_context(|| {
                        format!("cannot rename {} to {}", tmp.display(), out.display())
                    });
                }
            }
        }
        refuse_foreign(option, out, out, kind)?;
        let old = swap(tmp, out).with_context(|| format!("cannot replace {}", out.display()))?;
        if let Some(old) = &old {
            signals::superseded(old);
        }
        Ok(old)
    }

    /// Undo [`OutputDir::swap_in`] (it returned `old`): the earlier output back at `out`, the new one
    /// back in the temporary (removed when `self` is dropped). Best effort: it runs on a failure.
    fn swap_back(&self, old: Option<&Path>) {
        let (tmp, out) = (&self.tmp, &self.out);
        match old {
            // Exchanged: exchange again.
            Some(old) if old == tmp.as_path() => {
                let _ = swap(tmp, out);
            }
            // Moved aside: the new one out of the way, the old one back.
            Some(old) => {
                if std::fs::rename(out, tmp).is_ok() {
                    let _ = std::fs::rename(old, out);
                }
            }
            // There was none: the new one out of the way.
            None => {
                let _ = std::fs::rename(out, tmp);
            }
        }
        if let Some(old) = old {
            signals::unregister_superseded(old);
        }
    }

    /// After the swap: the earlier output (at `old`) removed, the folders made kept.
    fn finish(mut self, old: Option<PathBuf>) {
        self.done = true;
        self.lock = None;
        if let Some(old) = old {
            if let Err(e) = std::fs::remove_dir_all(&old) {
                eprintln!(
                    "warning: {} is in place, but the earlier output could not be removed completely \
                     ({e}); what is left of it is in {}: remove it by hand",
                    self.out.display(),
                    old.display()
                );
            }
            signals::unregister_superseded(&old);
        }
        std::mem::take(&mut self.dirs).keep();
    }
}

/// Publish the finished folders `dirs` and `last` (a small file written atomically, e.g. a report) at
/// one moment: a signal comes before all of them or after all of them, never between (an `eval`
/// stopped there left its report and renders from the new run and its MPIs from the old one). Every
/// folder is checked before any goes in; a swap or `last` that fails puts the folders already in
/// back, so that a failure too leaves every earlier output as it was.
pub fn commit_together(
    dirs: Vec<OutputDir>,
    last: impl FnOnce() -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let tmps: Vec<PathBuf> = dirs.iter().map(|d| d.tmp.clone()).collect();
    let olds = signals::publish_all(&tmps, || {
        for d in dirs.iter().filter(|d| d.out.is_dir()) {
            refuse_foreign(d.option, &d.out, &d.out, d.kind)?;
        }
        let mut olds = Vec::new();
        let undo = |olds: &[Option<PathBuf>]| {
            for (d, old) in dirs.iter().zip(olds) {
                d.swap_back(old.as_deref());
            }
        };
        for d in &dirs {
            match d.swap_in() {
                Ok(old) => olds.push(old),
                Err(e) => {
                    undo(&olds);
                    return Err(e);
                }
            }
        }
        if let Err(e) = last() {
            undo(&olds);
            return Err(e);
        }
        Ok(olds)
    })?;
    for (dir, old) in dirs.into_iter().zip(olds) {
        dir.finish(old);
    }
    Ok(())
}

impl Drop for OutputDir {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_dir_all(&self.tmp);
            signals::unregister(&self.tmp);
        }
    }
}

/// Swap the new folder `new` into `out`; returns where the old folder now is (to be removed).
fn swap(new: &Path, out: &Path) -> std::io::Result<Option<PathBuf>> {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use std::os::unix::ffi::OsStrExt;
        let a = std::ffi::CString::new(new.as_os_str().as_bytes())?;
        let b = std::ffi::CString::new(out.as_os_str().as_bytes())?;
        // SAFETY: two valid NUL-terminated paths; RENAME_EXCHANGE swaps them atomically.
        let r = unsafe {
            libc::renameat2(
                libc::AT_FDCWD,
                a.as_ptr(),
                libc::AT_FDCWD,
                b.as_ptr(),
                libc::RENAME_EXCHANGE,
            )
        };
        if r == 0 {
            return Ok(Some(new.to_path_buf()));
        }
        let e = std::io::Error::last_os_error();
        if !matches!(e.raw_os_error(), Some(libc::EINVAL | libc::ENOSYS)) {
            return Err(e);
        }
    }
    // No atomic exchange on this file system: the old folder aside, the new one in, the old one removed
    // (a crash in between leaves `.NAME.deepview-old.PID`, put back by the next run).
    let old = sibling(out, "old");
    std::fs::rename(out, &old)?;
    if let Err(e) = std::fs::rename(new, out) {
        let _ = std::fs::rename(&old, out);
        return Err(e);
    }
    Ok(Some(old))
}

/// The temporaries in the folder `dir` ([`deepview_image::parse_temp`]) whose writers no longer run
/// (killed with SIGKILL, which leaves no time to clean up) and that `pick` chooses (given the parsed
/// name and whether it is a folder), as (a folder's tag, the path). A temporary a running process holds stays,
/// whatever its process id says (another PID namespace's).
fn stale_in(
    dir: &Path,
    pick: impl Fn(&deepview_image::TempName, bool) -> bool,
) -> Vec<(Option<String>, PathBuf)> {
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut stale = Vec::new();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(t) = deepview_image::parse_temp(&name) else {
            continue;
        };
        let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
        if pick(&t, is_dir) && died(t.pid) && !deepview_image::is_held(&e.path()) {
            stale.push((t.folder.map(str::to_string), e.path()));
        }
    }
    stale
}

/// `out`'s name as its temporaries carry it.
fn stem_of(out: &Path) -> Option<String> {
    Some(deepview_image::temp_stem(
        &out.file_name()?.to_string_lossy(),
    ))
}

/// Whether `pid` names a process that no longer runs (false where `/proc` cannot tell). A killed
/// process its parent has not waited for yet (a zombie, state `Z` in `/proc/PID/stat`) runs no more.
fn died(pid: &str) -> bool {
    Path::new("/proc/self").exists()
        && pid.parse::<u32>().is_ok_and(|p| {
            if p == std::process::id() {
                return false;
            }
            match std::fs::read_to_string(format!("/proc/{p}/stat")) {
                // `PID (COMM) STATE ...`: COMM may hold spaces and parentheses, the state follows
                // the last `)`.
                Ok(stat) => stat
                    .rsplit_once(')')
                    .and_then(|(_, rest)| rest.split_whitespace().next())
                    .is_some_and(|state| state == "Z" || state == "X"),
                Err(_) => !Path::new("/proc").join(p.to_string()).exists(),
            }
        })
}

/// Remove the temporary files of `out` (`.NAME.TOKEN.tmp`, and a video sink's `.NAME.TOKEN.tmp.EXT`)
/// that killed runs left.
fn remove_stale_files(out: &Path) {
    let (Some(parent), Some(stem)) = (out.parent(), stem_of(out)) else {
        return;
    };
    for (_, path) in stale_in(parent, |t, is_dir| {
        !is_dir && t.folder.is_none() && t.stem == stem
    }) {
        let _ = std::fs::remove_file(path);
    }
}

/// Remove the temporary folders of `out` that killed runs left, and put back an old folder that a crash
/// left aside.
pub(super) fn remove_stale(out: &Path) {
    let (Some(parent), Some(stem)) = (out.parent(), stem_of(out)) else {
        return;
    };
    for (tag, path) in stale_in(parent, |t, _| t.folder.is_some() && t.stem == stem) {
        if tag.as_deref() == Some("old") && !out.exists() {
            let _ = std::fs::rename(&path, out);
        } else {
            let _ = std::fs::remove_dir_all(&path);
        }
    }
}

/// Remove the working folders (`.NAME.deepview-tmp.TOKEN/`) that killed runs left inside the folder
/// `dir` of `kind` for any of its files (`depth` stages each pair of maps so, whatever its `--prefix`).
pub(super) fn remove_stale_inside(dir: &Path, kind: Kind) {
    for (_, path) in stale_in(dir, |t, is_dir| {
        is_dir && t.folder == Some("tmp") && kind.owns(t.stem, false)
    }) {
        let _ = std::fs::remove_dir_all(path);
    }
}

/// The format of an image output, from its extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    Png,
    Jpeg,
}

impl ImageFormat {
    /// `.png` or `.jpg`/`.jpeg` (any case); anything else is refused.
    pub fn of(option: &str, path: &Path) -> anyhow::Result<Self> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("png") => Ok(Self::Png),
            Some("jpg" | "jpeg") => Ok(Self::Jpeg),
            _ => bail!(
                "{option} {}: unknown image format (use a .png or .jpg/.jpeg name)",
                path.display()
            ),
        }
    }

    /// Write `img` in this format (atomically).
    pub fn write(self, path: &Path, img: &deepview_image::ImageF32) -> anyhow::Result<()> {
        match self {
            Self::Png => deepview_image::write_png(path, img)?,
            Self::Jpeg => deepview_image::write_jpeg(path, img, 92)?,
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file as deepview writes it: images carry its mark ([`deepview_image::MARK`]).
    fn marked(p: &Path) {
        match p.extension().and_then(|e| e.to_str()) {
            Some("png") => deepview_image::write_png_u8(p, 1, 1, 3, &[0, 0, 0]).unwrap(),
            Some("gif") => {
                let gif = [&b"GIF89a"[..], &deepview_image::GIF_MARK, b";"].concat();
                std::fs::write(p, gif).unwrap()
            }
            _ => std::fs::write(p, b"x").unwrap(),
        }
    }

    /// Outputs published together are all swapped in after the first one (a report) is written, the
    /// earlier folders removed; where the report cannot be written, no folder is swapped.
    #[test]
    fn outputs_published_together_go_in_together_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let (r, m) = (dir.path().join("renders"), dir.path().join("mpis"));
        let report = dir.path().join("r.json");
        let make = |text: &str| {
            let a = OutputDir::new(&r, Kind::Renders).unwrap();
            marked(&a.path().join("000_a.png"));
            let b = OutputDir::new(&m, Kind::Mpis).unwrap();
            std::fs::create_dir(b.path().join("000_a")).unwrap();
            std::fs::write(b.path().join("000_a/mpi.json"), text).unwrap();
            vec![a, b]
        };
        commit_together(make("one"), || Ok(std::fs::write(&report, "one")?)).unwrap();
        let read = |p: &Path| std::fs::read_to_string(p).unwrap();
        assert_eq!(read(&m.join("000_a/mpi.json")), "one");
        let e = commit_together(make("two"), || anyhow::bail!("disk full")).unwrap_err();
        assert!(e.to_string().contains("disk full"));
        assert_eq!(
            (read(&report), read(&m.join("000_a/mpi.json"))),
            ("one".into(), "one".into())
        );
        assert!(r.join("000_a.png").is_file());
        // A file of the user's that appears in the second folder meanwhile: refused before any
        // folder goes in.
        let dirs = make("two");
        std::fs::write(m.join("notes.txt"), "mine").unwrap();
        let e = commit_together(dirs, || Ok(std::fs::write(&report, "two")?)).unwrap_err();
        assert!(format!("{e:#}").contains("notes.txt"), "{e:#}");
        assert_eq!(
            (read(&report), read(&m.join("000_a/mpi.json"))),
            ("one".into(), "one".into())
        );
        std::fs::remove_file(m.join("notes.txt")).unwrap();
        commit_together(make("three"), || Ok(std::fs::write(&report, "three")?)).unwrap();
        assert_eq!(read(&m.join("000_a/mpi.json")), "three");
        assert_eq!(read(&report), "three");
        // Nothing left beside them: no temporaries, no earlier folders.
        let mut names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["mpis", "r.json", "renders"]);
    }

    /// The probe of a killed run (its writability check) is removed by the next run's check; a
    /// running process's probe is left.
    #[test]
    fn a_killed_runs_probe_goes_at_the_next_check() {
        let dir = tempfile::tempdir().unwrap();
        let mut child = std::process::Command::new("true").spawn().unwrap();
        child.wait().unwrap();
        let dead = dir
            .path()
            .join(format!(".deepview-probe.{}-0badc0de", child.id()));
        let live = dir
            .path()
            .join(format!(".deepview-probe.{}-0badc0de", std::process::id()));
        std::fs::write(&dead, "").unwrap();
        std::fs::write(&live, "").unwrap();
        let out = dir.path().join("mpi");
        check_output("--out", &out, Kind::Mpi, &[]).unwrap();
        assert!(!dead.exists() && live.exists());
    }

    /// A process killed but not yet waited for (a zombie) has died; a running one has not.
    #[test]
    fn a_killed_process_not_yet_waited_for_has_died() {
        let mut child = std::process::Command::new("sleep")
            .arg("60")
            .spawn()
            .unwrap();
        let pid = child.id().to_string();
        assert!(!died(&pid));
        child.kill().unwrap();
        // Until it is a zombie (the kill is asynchronous), announced by /proc; then reaped.
        let stat = format!("/proc/{pid}/stat");
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
        while !std::fs::read_to_string(&stat).is_ok_and(|s| s.contains(") Z")) {
            assert!(
                std::time::Instant::now() < deadline,
                "the killed child never became a zombie"
            );
            std::thread::yield_now();
        }
        assert!(died(&pid));
        child.wait().unwrap();
        assert!(died(&pid));
        assert!(!died(&std::process::id().to_string()));
    }

    /// A replaced folder named `.` or `..` is refused (its swap would move the folder one is in);
    /// folders written into (depth maps) may be.
    #[test]
    fn a_replaced_folder_is_not_named_by_dots() {
        for out in [".", "..", "./.", "a/..", "mpi/.", "mpi/./", "mpi/.."] {
            let e = check_output("--out", Path::new(out), Kind::Web, &[]).unwrap_err();
            assert!(
                format!("{e:#}").contains("name it from its parent"),
                "{out}: {e:#}"
            );
        }
        let dir = tempfile::tempdir().unwrap();
        check_output("--out", &dir.path().join("."), Kind::DepthMaps, &[]).unwrap();
    }

    /// A single file's output that is a link is refused (the rename would replace the link): the file
    /// it names and the link stay.
    #[test]
    fn a_file_output_through_a_link_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("notes.txt");
        std::fs::write(&target, "mine").unwrap();
        let link = dir.path().join("report.json");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let e = check_output("--out", &link, Kind::File, &[]).unwrap_err();
        assert!(format!("{e:#}").contains("is a symbolic link to"), "{e:#}");
    }

    /// Files named like an output's own images but without deepview's mark (a user's photos saved as
    /// `0001_beach.png` in what looks like a folder of evaluation renders) are not its own: replacing
    /// the folder would delete them. Marked ones are.
    #[test]
    fn images_named_like_its_own_without_the_mark_are_foreign() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        marked(&d.join("000_image000.png"));
        assert!(foreign_entries(d, Kind::Renders).unwrap().is_empty());
        let photo = "../shared/data/llff/fern/images_8/image001.png";
        let photo = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../..")
            .join(photo);
        std::fs::copy(&photo, d.join("0001_beach.png")).unwrap();
        assert_eq!(
            foreign_entries(d, Kind::Renders).unwrap(),
            ["0001_beach.png (a file deepview did not write)"]
        );
        // Inside an evaluation MPI too, and an empty file is not an image.
        let mpis = d.join("mpis");
        std::fs::create_dir_all(mpis.join("0001_trip")).unwrap();
        std::fs::write(mpis.join("0001_trip/mpi.json"), "{}").unwrap();
        std::fs::write(mpis.join("0001_trip/layer_001.png"), "").unwrap();
        assert!(foreign_entries(&mpis, Kind::Mpis).unwrap().is_empty());
        std::fs::copy(&photo, mpis.join("0001_trip/layer_000.png")).unwrap();
        assert_eq!(
            foreign_entries(&mpis, Kind::Mpis).unwrap(),
            ["0001_trip/layer_000.png (a file deepview did not write)"]
        );
        let e = check_output("--save-mpi", &mpis, Kind::Mpis, &[]).unwrap_err();
        assert!(format!("{e:#}").contains("refused once"), "{e:#}");
        // A web page of the user's named index.html is not the viewer.
        let web = d.join("web");
        std::fs::create_dir(&web).unwrap();
        std::fs::write(web.join("index.html"), "<h1>mine</h1>").unwrap();
        assert_eq!(
            foreign_entries(&web, Kind::Web).unwrap(),
            ["index.html (a file deepview did not write)"]
        );
        let viewer = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../crates/deepview-viewer/web/index.html");
        std::fs::copy(viewer, web.join("index.html")).unwrap();
        assert!(foreign_entries(&web, Kind::Web).unwrap().is_empty());
    }

    #[test]
    fn components_and_relations() {
        assert!(parse_component("fern").is_ok());
        assert!(parse_component("gen19 large-v2").is_ok());
        let long = "x".repeat(201);
        for bad in [
            "",
            ".",
            "..",
            "../x",
            "a/b",
            "/abs",
            "a\nb",
            "\t",
            "   ",
            "-x",
            ".hidden",
            "r.tmp",
            "r.incomplete",
            ".r.deepview-tmp.1",
            &long,
        ] {
            assert!(parse_component(bad).is_err(), "{bad}");
        }
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("data");
        std::fs::create_dir(&d).unwrap();
        let input = [("--data", d.as_path())];
        for out in [
            d.clone(),
            d.join("x"),
            dir.path().to_path_buf(),
            d.join("a/../b"),
        ] {
            let e = check_output("--out", &out, Kind::Mpi, &input).unwrap_err();
            assert!(e.to_string().contains("refusing"), "{e}");
        }
        check_output("--out", &dir.path().join("new"), Kind::Mpi, &input).unwrap();
        // A folder that cannot be written in, or a file standing where a folder must be made.
        let e = check_output("--out", Path::new("/sys/deepview/mpi"), Kind::Mpi, &[]).unwrap_err();
        assert!(e.to_string().contains("cannot write in /sys"), "{e}");
        // Nor in /dev or /proc, where the rename would replace the system's links and devices.
        for out in ["/proc/deepview/mpi", "/dev/stdout", "/dev/null"] {
            let e = check_output("--out", Path::new(out), Kind::File, &[]).unwrap_err();
            assert!(e.to_string().contains("is in /dev or /proc"), "{e}");
        }
        std::fs::write(dir.path().join("f"), b"x").unwrap();
        let e = check_output("--out", &dir.path().join("f/a/mpi"), Kind::Mpi, &[]).unwrap_err();
        assert!(e.to_string().contains("is a file"), "{e}");
        // A non-empty folder of another kind is not replaced; an empty one is.
        std::fs::write(d.join("photo.jpg"), b"x").unwrap();
        let e = check_output("--out", &d, Kind::Mpi, &[]).unwrap_err();
        assert!(e.to_string().contains("not an MPI folder"), "{e}");
        std::fs::create_dir(dir.path().join("empty")).unwrap();
        check_output("--out", &dir.path().join("empty"), Kind::Mpi, &[]).unwrap();
        // A link to nothing is named as such (the rename at the end failed with "Not a directory").
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(dir.path().join("gone"), &link).unwrap();
        for kind in [Kind::Mpi, Kind::File] {
            let e = check_output("--out", &link, kind, &[]).unwrap_err();
            assert!(e.to_string().contains("does not exist"), "{e}");
        }
    }

    /// A folder an output replaces is checked down through the subfolders it writes: a user's file
    /// inside the demo's `renders/` or a synthetic scene's `images/` would be deleted with the folder.
    #[test]
    fn subfolders_of_an_earlier_output_are_checked_too() {
        let dir = tempfile::tempdir().unwrap();
        let put = |rel: &str| {
            let p = dir.path().join(rel);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            marked(&p);
        };
        // An earlier demo: every file one that the demo writes.
        for f in [
            "demo/eval.md",
            "demo/eval.json",
            "demo/spiral.gif",
            "demo/scene/synth.json",
            "demo/scene/input_Cam003.png",
            "demo/scene/parameters.cfg",
            "demo/scene/ground_truth_mpi/mpi.json",
            "demo/scene/ground_truth_mpi/layer_007.png",
            "demo/mpi/mpi.json",
            "demo/mpi/layer_000.png",
            "demo/novel_views/view_05.png",
            "demo/novel_views/view_05_ground_truth.png",
            "demo/depth/depth_color.png",
            "demo/renders/005_input_Cam005.png",
            "demo/novel_views/.DS_Store",
            "scene/synth.json",
            "scene/images_4/image000.png",
            "scene/sparse/0/cameras.txt",
            "scene/sparse/0/points3D.txt",
            "scene/cam_03/image_000.png",
            "scene/ground_truth_mpi/mpi.json",
        ] {
            put(f);
        }
        let demo = dir.path().join("demo");
        let scene = dir.path().join("scene");
        assert_eq!(
            foreign_entries(&demo, Kind::Demo).unwrap(),
            Vec::<String>::new()
        );
        assert_eq!(
            foreign_entries(&scene, Kind::SynthScene).unwrap(),
            Vec::<String>::new()
        );
        check_output("--out", &demo, Kind::Demo, &[]).unwrap();
        check_output("--out", &scene, Kind::SynthScene, &[]).unwrap();
        // The user's files inside them.
        for f in [
            "demo/renders/mine.png",
            "demo/novel_views/holiday.png",
            "demo/scene/ground_truth_mpi/notes.txt",
            "demo/mpi/extra/layer_000.png",
            "scene/images_4/notes.txt",
            "scene/sparse/0/project.ini",
            "scene/cam_03/notes.txt",
        ] {
            put(f);
        }
        assert_eq!(
            foreign_entries(&demo, Kind::Demo).unwrap(),
            [
                "mpi/extra/",
                "novel_views/holiday.png",
                "renders/mine.png",
                "scene/ground_truth_mpi/notes.txt"
            ]
        );
        assert_eq!(
            foreign_entries(&scene, Kind::SynthScene).unwrap(),
            [
                "cam_03/notes.txt",
                "images_4/notes.txt",
                "sparse/0/project.ini"
            ]
        );
        for (out, kind) in [(&demo, Kind::Demo), (&scene, Kind::SynthScene)] {
            let e = check_output("--out", out, kind, &[])
                .unwrap_err()
                .to_string();
            assert!(e.contains("refusing to replace it"), "{e}");
        }
        let e = check_output("--out", &demo, Kind::Demo, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("renders/mine.png"), "{e}");
    }

    #[test]
    fn single_files_replace_only_files_of_their_kind() {
        let dir = tempfile::tempdir().unwrap();
        let p = |n: &str| dir.path().join(n);
        std::fs::write(p("notes.png"), b"my notes").unwrap();
        let img = deepview_image::ImageF32::new(4, 3, 3);
        // deepview's own PNG and JPEG (marked), and the same pixels saved by another program.
        deepview_image::write_png(&p("v.png"), &img).unwrap();
        deepview_image::write_jpeg(&p("v.jpg"), &img, 90).unwrap();
        let data = deepview_data::data_dir();
        std::fs::copy(data.join("llff/fern/images_8/image000.png"), p("photo.png")).unwrap();
        std::fs::copy(data.join("colmap/room/images/img001.JPG"), p("photo.jpg")).unwrap();
        std::fs::write(p("clip.mp4"), b"\0\0\0\x18ftypisom\0\0\x02\0isomiso2").unwrap();
        std::fs::write(p("r.json"), b"  {\"results\": {\"ssim\": 1}}").unwrap();
        std::fs::write(p("todo.json"), b"buy milk").unwrap();
        std::fs::write(p("empty.gif"), b"").unwrap();
        for bad in ["notes.png", "todo.json"] {
            let e = check_output("--out", &p(bad), Kind::File, &[]).unwrap_err();
            assert!(e.to_string().contains("refusing to replace"), "{e}");
        }
        for (photo, what) in [
            ("photo.png", "a PNG image"),
            ("photo.jpg", "a JPEG image"),
            ("clip.mp4", "a video"),
        ] {
            let e = check_output("--out", &p(photo), Kind::File, &[]).unwrap_err();
            assert!(
                e.to_string()
                    .contains(&format!("is {what} deepview did not write")),
                "{e}"
            );
        }
        for good in ["v.png", "v.jpg", "r.json", "empty.gif", "new.png"] {
            check_output("--out", &p(good), Kind::File, &[]).unwrap();
        }
    }

    #[test]
    fn output_dir_swaps_or_cleans_up() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("sub/mpi");
        // A failure leaves nothing, not even the parent it created.
        {
            let o = OutputDir::new(&out, Kind::Mpi).unwrap();
            marked(&o.path().join("layer_000.png"));
        }
        assert!(!dir.path().join("sub").exists());
        let o = OutputDir::new(&out, Kind::Mpi).unwrap();
        marked(&o.path().join("layer_000.png"));
        o.commit().unwrap();
        let o = OutputDir::new(&out, Kind::Mpi).unwrap();
        std::fs::write(o.path().join("mpi.json"), b"2").unwrap();
        o.commit().unwrap();
        assert!(!out.join("layer_000.png").exists() && out.join("mpi.json").is_file());
        let names: Vec<_> = std::fs::read_dir(dir.path().join("sub"))
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["mpi"]);
    }

    #[test]
    fn an_output_another_run_made_meanwhile_is_replaced_if_it_is_one() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("mpi");
        let write = |o: &OutputDir, text: &str| {
            std::fs::write(o.path().join("mpi.json"), text).unwrap();
        };
        // Both runs start before the output exists; the other one finishes first.
        let ours = OutputDir::new(&out, Kind::Mpi).unwrap();
        write(&ours, "ours");
        // (The other run's output is made by hand: in one process both would share a temporary.)
        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("mpi.json"), "theirs").unwrap();
        marked(&out.join("layer_000.png"));
        ours.commit().unwrap();
        assert_eq!(
            std::fs::read_to_string(out.join("mpi.json")).unwrap(),
            "ours"
        );
        assert!(!out.join("layer_000.png").exists());
        // Not when what appeared holds a user's file: then nothing is replaced.
        let ours = OutputDir::new(&out, Kind::Mpi).unwrap();
        write(&ours, "third");
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        let e = ours.commit().unwrap_err();
        assert!(format!("{e:#}").contains("notes.txt"), "{e:#}");
        assert_eq!(
            std::fs::read_to_string(out.join("notes.txt")).unwrap(),
            "mine"
        );
        assert_eq!(
            std::fs::read_to_string(out.join("mpi.json")).unwrap(),
            "ours"
        );
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["mpi"]);
    }

    #[test]
    fn working_folders_of_a_folders_files_are_its_own_and_stale_ones_go() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        marked(&d.join("depth_color.png"));
        let live = format!(".other_color.png.deepview-tmp.{}", std::process::id());
        // A process that has ended: its id names no process now (ids are not reused this soon).
        let mut child = std::process::Command::new("true").spawn().unwrap();
        child.wait().unwrap();
        let dead = format!(".p1_color.png.deepview-tmp.{}", child.id());
        for f in [&live, &dead] {
            std::fs::create_dir(d.join(f)).unwrap();
            marked(&d.join(f).join("p_color.png"));
        }
        assert!(foreign_entries(d, Kind::DepthMaps).unwrap().is_empty());
        // A working folder of a file the kind does not write is not.
        std::fs::create_dir(d.join(".notes.txt.deepview-tmp.1")).unwrap();
        assert_eq!(
            foreign_entries(d, Kind::DepthMaps).unwrap(),
            [".notes.txt.deepview-tmp.1/"]
        );
        remove_stale_inside(d, Kind::DepthMaps);
        assert!(
            d.join(&live).is_dir(),
            "a running process's folder was removed"
        );
        assert!(!d.join(&dead).exists(), "a killed run's folder stayed");
        assert!(d.join(".notes.txt.deepview-tmp.1").is_dir());
    }

    #[test]
    fn a_temporary_a_running_process_holds_is_left_alone_whatever_its_process_id() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("mpi");
        let mut child = std::process::Command::new("true").spawn().unwrap();
        child.wait().unwrap();
        // Another PID namespace's run: its process id names no process here. And a killed run's.
        let theirs = dir
            .path()
            .join(format!(".mpi.deepview-tmp.{}-0badcafe", child.id()));
        let killed = dir
            .path()
            .join(format!(".mpi.deepview-tmp.{}-12345678", child.id()));
        let killed_file = dir.path().join(format!(".mpi.{}-12345678.tmp", child.id()));
        for d in [&theirs, &killed] {
            std::fs::create_dir(d).unwrap();
        }
        std::fs::write(&killed_file, "x").unwrap();
        let lock = deepview_image::lock_temp(&theirs).unwrap();
        let ours = OutputDir::new(&out, Kind::Mpi).unwrap();
        assert!(theirs.is_dir(), "a running process's temporary was removed");
        assert!(!killed.exists(), "a killed run's temporary stayed");
        // (Files are the file outputs' business: `write_file` clears them.)
        assert!(killed_file.exists());
        remove_stale_files(&out);
        assert!(!killed_file.exists());
        std::fs::write(ours.path().join("mpi.json"), "ours").unwrap();
        ours.commit().unwrap();
        assert_eq!(
            std::fs::read_to_string(out.join("mpi.json")).unwrap(),
            "ours"
        );
        assert!(theirs.is_dir());
        // Once their run ends (the lock goes with it), the next run clears it.
        drop(lock);
        drop(OutputDir::new(&out, Kind::Mpi).unwrap());
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["mpi"]);
    }
}
