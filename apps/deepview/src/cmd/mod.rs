//! One module per subcommand: `Args` (clap) and `run`.

pub mod args;
pub mod bench;
pub mod compact;
pub mod demo;
pub mod depth;
pub mod diff;
pub mod eval;
pub mod export;
pub mod export_web;
pub mod export_weights;
pub mod hints;
pub mod import;
pub mod infer;
pub mod info;
pub mod method;
pub mod process;
pub mod psv;
pub mod render;
pub mod safety;
pub mod signals;
pub mod synth;
pub mod train;
pub mod view;

use deepview_geometry::Camera;

/// Read a camera JSON file (`{"width","height","fx","fy","cx","cy","camera_from_world":[16]}`).
pub fn read_camera_json(path: &std::path::Path) -> anyhow::Result<Camera> {
    Ok(deepview_data::read_camera_json(path)?)
}

/// Parse a comma-separated list of view indices (no duplicates), checking them against the view count.
pub fn parse_indices(text: &str, views: usize) -> anyhow::Result<Vec<usize>> {
    text.parse::<args::ViewList>()
        .map_err(anyhow::Error::msg)?
        .check(views)
}

/// Where a camera comes from: a camera JSON file, or a view of a dataset.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct CameraSource {
    /// Camera JSON: {"width","height","fx","fy","cx","cy","camera_from_world":[16 numbers, row-major]}.
    #[arg(long, conflicts_with = "scene_dir")]
    pub camera: Option<std::path::PathBuf>,
    /// A dataset folder whose view `--view` gives the camera.
    #[arg(long = "data", value_name = "DIR", requires = "view")]
    pub scene_dir: Option<std::path::PathBuf>,
    /// View index in `--data`.
    #[arg(long)]
    pub view: Option<usize>,
    #[command(flatten)]
    pub scene: deepview_data::SceneArgs,
}

impl CameraSource {
    /// The camera, or `None` when neither `--camera` nor `--data` was given.
    pub fn camera(&self) -> anyhow::Result<Option<Camera>> {
        if self.scene_dir.is_none() {
            // Options of a dataset view, given without the dataset: an error, not a silent other camera.
            let sc = &self.scene;
            let given: Vec<&str> = [
                (self.view.is_some(), "--view"),
                (sc.images.is_some(), "--images"),
                (sc.format.is_some(), "--format"),
                (sc.near.is_some(), "--near"),
                (sc.far.is_some(), "--far"),
                (sc.downscale != 1, "--downscale"),
                (sc.rig != 0, "--rig"),
            ]
            .iter()
            .filter(|g| g.0)
            .map(|g| g.1)
            .collect();
            if !given.is_empty() {
                anyhow::bail!(
                    "{} {} a dataset, but no --data was given: pass --data DIR (the dataset whose view to \
                     use), or --camera FILE, or neither (the MPI's own reference view)",
                    given.join(", "),
                    if given.len() == 1 { "needs" } else { "need" }
                );
            }
        }
        if let Some(p) = &self.camera {
            return Ok(Some(read_camera_json(p)?));
        }
        if let Some(dir) = &self.scene_dir {
            let scene = args::load_scene_noted(dir, &self.scene.load_options())?;
            let v = self.view.unwrap_or(0);
            parse_indices(&v.to_string(), scene.views.len())?;
            return Ok(Some(scene.views[v].camera));
        }
        Ok(None)
    }
}

/// Refuse an MPI folder in another tool's format where a deepview MPI (`mpi.json`) is read, saying how to
/// convert it (instead of "cannot read mpi.json").
pub fn check_deepview_mpi(option: &str, dir: &std::path::Path) -> anyhow::Result<()> {
    use deepview_mpi::interchange::{ImportFormat, detect_format};
    if dir.join("mpi.json").is_file() {
        return Ok(());
    }
    // The folder's own mpi.json given, or nothing there at all.
    if dir.is_file() && dir.file_name().is_some_and(|n| n == "mpi.json") {
        let folder = dir.parent().filter(|p| !p.as_os_str().is_empty());
        anyhow::bail!(
            "{option} {} is an MPI's mpi.json: give the MPI's folder ({})",
            dir.display(),
            folder.map_or(".".into(), |p| p.display().to_string())
        );
    }
    if std::fs::symlink_metadata(dir).is_err() {
        anyhow::bail!("{option} {} does not exist", dir.display());
    }
    match detect_format(dir) {
        Ok(f) if f != ImportFormat::Deepview => anyhow::bail!(
            "{option} {} is an MPI in {f:?} format: convert it first with `deepview import --mpi {} --out \
             DIR`",
            dir.display(),
            dir.display()
        ),
        _ => Ok(()),
    }
}
