//! The datasets of a training run: how each is loaded (its scene options, `--max-width`), the run's own
//! list on resume (read against the folder the run started from), and the checks before a run starts.

use super::Args;
use anyhow::{Context, bail};
use deepview_data::LoadOptions;
use deepview_train::{DataSpec, RunConfig, is_synthetic};
use std::path::{Path, PathBuf};

/// `--downscale` 0 and 1 both mean full size.
pub(super) fn normalised(o: &LoadOptions) -> LoadOptions {
    LoadOptions {
        downscale: o.downscale.max(1),
        ..o.clone()
    }
}

/// The scene flags given on the command line (those that differ from their defaults), with their values
/// in `opts` and in `other`.
pub(super) fn scene_flags_differing(given: &LoadOptions, other: &LoadOptions) -> Vec<&'static str> {
    let (g, o) = (normalised(given), normalised(other));
    [
        (g.format.is_some() && g.format != o.format, "--format"),
        (g.images.is_some() && g.images != o.images, "--images"),
        (g.rig != 0 && g.rig != o.rig, "--rig"),
        (g.near.is_some() && g.near != o.near, "--near"),
        (g.far.is_some() && g.far != o.far, "--far"),
        (
            g.downscale != 1 && g.downscale != o.downscale,
            "--downscale",
        ),
    ]
    .iter()
    .filter(|f| f.0)
    .map(|f| f.1)
    .collect()
}

/// A dataset loaded with the scene flags `opts`; with `--max-width W`, downscaled by the smallest
/// integer factor that brings its images to at most `W` pixels wide.
pub(super) fn data_spec(
    path: &Path,
    opts: &LoadOptions,
    max_width: Option<u32>,
) -> anyhow::Result<DataSpec> {
    let mut load = opts.clone();
    if let Some(w) = max_width
        && !is_synthetic(path)
    {
        let scene = deepview_data::load_scene(path, &load)
            .with_context(|| format!("--data {}", path.display()))?;
        let width = scene.views.first().map_or(0, |v| v.camera.width);
        load.downscale = width.div_ceil(w.max(1)).max(1);
    }
    Ok(DataSpec::new(path, load))
}

/// The datasets of a run resumed (or started over) from its config.json: `--data` if given, else the
/// run's own; each loads with the options the run keeps for it (a scene flag given now must agree with
/// them), or, for runs whose config.json has bare paths (older ones) and data the run did not have,
/// with the scene flags given now.
pub(super) fn resumed_data(
    args: &Args,
    cfg: &RunConfig,
    opts: &LoadOptions,
) -> anyhow::Result<Vec<DataSpec>> {
    let paths: Vec<PathBuf> = if args.data.is_empty() {
        cfg.train.data.iter().map(|d| d.path.clone()).collect()
    } else {
        args.data.clone()
    };
    // Relative paths of the run's own list are read against the folder it was started from.
    let here = std::env::current_dir().ok();
    let resolve = |p: &Path| match &cfg.train.base {
        Some(b) if args.data.is_empty() && p.is_relative() && here.as_ref() != Some(b) => {
            if !deepview_train::is_synthetic(p) {
                return b.join(p);
            }
            p.to_path_buf()
        }
        _ => p.to_path_buf(),
    };
    paths
        .into_iter()
        .map(|given| {
            let path = resolve(&given);
            let kept = cfg
                .train
                .data
                .iter()
                .find(|d| d.path == given)
                .and_then(|d| d.load.clone());
            match kept {
                Some(load) => {
                    let differ = scene_flags_differing(opts, &load);
                    if !differ.is_empty() {
                        bail!(
                            "--resume loads {} as the run first did (its config.json): {} differ and cannot \
                             change on resume; start a new --name instead",
                            path.display(),
                            differ.join(", ")
                        );
                    }
                    Ok(DataSpec::new(path, load))
                }
                None => data_spec(&path, opts, args.max_width),
            }
        })
        .collect()
}

/// Every scene must have more training views than the largest input count (the target is one of them).
pub(super) fn check_views(
    data: &deepview_train::TrainData,
    views_max: usize,
    crop: usize,
) -> anyhow::Result<()> {
    // Every view must hold a target crop (checked now, not at the first step, after the run was made).
    let mut sizes: Vec<(String, u32, u32)> = data
        .scenes
        .iter()
        .flat_map(|s| {
            s.cameras
                .iter()
                .map(|c| (s.name.clone(), c.width, c.height))
        })
        .collect();
    if let Some(p) = &data.procedural {
        sizes.push((
            deepview_train::SYNTHETIC_PROCEDURAL.into(),
            p.options.width,
            p.options.height,
        ));
    }
    if let Some((name, w, h)) = sizes.iter().find(|(_, w, h)| (*w.min(h) as usize) < crop) {
        bail!(
            "--crop {crop}: the scene {name} has {w}x{h} views, smaller than the crop; use a smaller --crop"
        );
    }
    for s in &data.scenes {
        let n = s.train_views.len();
        if views_max + 1 > n {
            bail!(
                "--views {views_max}: the scene {} has {n} training views, so at most {} inputs besides the \
                 target; use fewer --views (or a smaller --holdout-every)",
                s.name,
                n.saturating_sub(1)
            );
        }
    }
    Ok(())
}
