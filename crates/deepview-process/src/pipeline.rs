//! The pipeline: photos (or video frames), COLMAP's stages, the scene folder checked and moved into place.

use crate::error::write_err;
use crate::frames::extract_frames;
use crate::layout::{MARKER, out_is_free, rename, work_folder};
use crate::photos::{copy_photos, list_photos, photo_dimensions};
use crate::runner::Runner;
use crate::{Event, Input, Matcher, ProcessError, ProcessOptions, ProcessReport, Stage, colmap};
use deepview_data::{LoadOptions, load_scene, read_colmap};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Run the whole pipeline; `progress` hears of every stage. See the crate documentation for the output.
pub fn process(
    opts: &ProcessOptions,
    progress: &mut dyn FnMut(Event),
) -> Result<ProcessReport, ProcessError> {
    let t0 = Instant::now();
    let out = &opts.out;
    out_is_free(out)?;
    // Fail fast on empty folders and missing tools, before any long work.
    let photos = match &opts.input {
        Input::Photos(dir) => {
            let p = list_photos(dir)?;
            let skipped = crate::photos::skipped_note(dir);
            // (Said before any refusal below: why a folder has fewer photos than its user thinks.)
            if !p.is_empty()
                && let Some(note) = skipped.strip_prefix("; ")
            {
                progress(Event::Warning(format!("{}: {note}", dir.display())));
            }
            match p.len() {
                0 => {
                    return Err(ProcessError::NoImages {
                        dir: dir.clone(),
                        skipped,
                    });
                }
                1 => {
                    return Err(ProcessError::TooFewImages {
                        dir: dir.clone(),
                        count: 1,
                    });
                }
                n => {
                    // Files that are not images (a text file named .jpg, a download cut off in its
                    // header) are left out by COLMAP, which aborts when too few are left: name them
                    // first. Their headers are read; the format is found from the content.
                    let (mut good, mut bad) = (Vec::with_capacity(n), Vec::new());
                    for f in p {
                        match photo_dimensions(&f) {
                            Ok(_) => good.push(f),
                            Err(e) => {
                                let name = f.file_name().unwrap_or_default().to_string_lossy();
                                bad.push(format!("{name} ({e})"));
                            }
                        }
                    }
                    if good.len() < 2 {
                        let more = match bad.len().saturating_sub(4) {
                            0 => String::new(),
                            k => format!(" and {k} more"),
                        };
                        return Err(ProcessError::UnreadableImages {
                            dir: dir.clone(),
                            readable: good.len(),
                            total: n,
                            unreadable: format!("{}{more}", bad[..bad.len().min(4)].join(", ")),
                        });
                    }
                    // The unreadable ones are left out, and said so (COLMAP would drop them with
                    // no reason given).
                    for b in &bad {
                        progress(Event::Warning(format!(
                            "{}: not an image, left out: {b}",
                            dir.display()
                        )));
                    }
                    Some(good)
                }
            }
        }
        Input::Video { path, fps } => {
            if !path.is_file() {
                return Err(ProcessError::Read {
                    path: path.clone(),
                    source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such video file"),
                });
            }
            if !(fps.is_finite() && *fps > 0.0) {
                return Err(ProcessError::Invalid(format!(
                    "the frame rate must be a positive number (got {fps})"
                )));
            }
            None
        }
    };
    colmap::check_colmap(&opts.colmap)?;
    if matches!(opts.input, Input::Video { .. }) {
        crate::frames::check_ffmpeg(&opts.ffmpeg)?;
    }
    // Held until the scene is in place (or its working folder removed).
    let (work, _lock) = work_folder(out)?;
    match build(opts, photos.as_deref(), &work, t0, progress) {
        Ok(r) => Ok(r),
        Err(e) => Err(discard_work(&work, out, e)),
    }
}

/// After a failure: the working folder removed (a scene is never left half-built), COLMAP's log kept beside
/// the output as `OUT.colmap.log` and named in the error instead of the log inside the removed folder.
/// Only errors that name the log keep it (a failed stage, images COLMAP did not register): a video with
/// too few frames leaves nothing behind. An existing file of that name is never replaced (it may be the
/// user's): the log then takes the first free `OUT.colmap.N.log`.
fn discard_work(work: &Path, out: &Path, e: ProcessError) -> ProcessError {
    let log = work.join("colmap.log");
    let names_log = matches!(
        &e,
        ProcessError::StageFailed { log: l, .. } | ProcessError::NotRegistered { log: l, .. } if *l == log
    );
    let kept = if names_log && log.is_file() {
        keep_log(&log, out)
    } else {
        None
    };
    let _ = std::fs::remove_dir_all(work);
    let relog = |l: PathBuf| match &kept {
        Some(k) if l == log => k.clone(),
        _ => l,
    };
    match e {
        ProcessError::StageFailed {
            stage,
            status,
            log: l,
            tail,
        } => ProcessError::StageFailed {
            stage,
            status,
            log: relog(l),
            tail,
        },
        ProcessError::NotRegistered {
            registered,
            total,
            missing,
            log: l,
        } => ProcessError::NotRegistered {
            registered,
            total,
            missing,
            log: relog(l),
        },
        e => e,
    }
}

/// Move `log` beside `out` under the first name of `OUT.colmap.log`, `OUT.colmap.2.log`, ... that does
/// not exist, without ever replacing a file (a hard link made only where the name is free, then the
/// original removed with the working folder). Returns where it was kept, if it was.
fn keep_log(log: &Path, out: &Path) -> Option<PathBuf> {
    let base = out.file_name().unwrap_or_default().to_os_string();
    for n in 1..1000 {
        let mut name = base.clone();
        name.push(if n == 1 {
            ".colmap.log".to_string()
        } else {
            format!(".colmap.{n}.log")
        });
        let kept = out.with_file_name(name);
        match std::fs::hard_link(log, &kept) {
            Ok(()) => return Some(kept),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            // No hard links here: a rename, still only onto a free name (a race with another
            // process making the same name in between is the only way to replace one).
            Err(_) if std::fs::symlink_metadata(&kept).is_err() => {
                return std::fs::rename(log, &kept).is_ok().then_some(kept);
            }
            Err(_) => continue,
        }
    }
    None
}

/// The work of [`process`] in its working folder `work`.
fn build(
    opts: &ProcessOptions,
    photos: Option<&[PathBuf]>,
    work: &Path,
    t0: Instant,
    progress: &mut dyn FnMut(Event),
) -> Result<ProcessReport, ProcessError> {
    let out = &opts.out;
    let work = work.to_path_buf();
    let runner = Runner {
        log: work.join("colmap.log"),
    };
    let colmap_dir = work.join("colmap");
    let input = colmap_dir.join("input");
    std::fs::create_dir_all(&input).map_err(write_err(&input))?;
    let timed = |stage: Stage,
                 what: String,
                 progress: &mut dyn FnMut(Event),
                 f: &mut dyn FnMut() -> Result<(), ProcessError>| {
        progress(Event::Started(stage, what));
        let t = Instant::now();
        f()?;
        progress(Event::Finished(stage, t.elapsed()));
        Ok::<(), ProcessError>(())
    };

    // 1. Photos: copied (or downscaled), or frames extracted from the video.
    let mut names = Vec::new();
    match (&opts.input, photos) {
        (Input::Video { path, fps }, _) => {
            let frames = colmap_dir.join("frames");
            std::fs::create_dir_all(&frames).map_err(write_err(&frames))?;
            timed(
                Stage::Frames,
                format!("{} at {fps} frames per second", path.display()),
                progress,
                &mut || extract_frames(&runner, &opts.ffmpeg, path, *fps, &frames),
            )?;
            let p = list_photos(&frames)?;
            if p.len() < 2 {
                return Err(ProcessError::TooFewFrames {
                    video: path.clone(),
                    fps: *fps,
                    count: p.len(),
                });
            }
            timed(
                Stage::Photos,
                format!("{} frames", p.len()),
                progress,
                &mut || {
                    names = copy_photos(&p, &input, opts.max_size)?;
                    Ok(())
                },
            )?;
            std::fs::remove_dir_all(&frames).map_err(write_err(&frames))?;
        }
        (Input::Photos(dir), Some(p)) => {
            let what = match opts.max_size {
                Some(m) => format!("{} photos from {}, at most {m} px", p.len(), dir.display()),
                None => format!("{} photos from {}", p.len(), dir.display()),
            };
            timed(Stage::Photos, what, progress, &mut || {
                names = copy_photos(p, &input, opts.max_size)?;
                Ok(())
            })?;
        }
        (Input::Photos(_), None) => unreachable!("photos are listed above"),
    }

    // 2. COLMAP: features, matches, mapping, undistortion. Photos of one size share one camera; photos
    // of several sizes (two phones, a cropped photo) get one camera each, and the event says so.
    let sizes: std::collections::BTreeSet<(u32, u32)> = names
        .iter()
        .filter_map(|n| photo_dimensions(&input.join(n)).ok())
        .collect();
    let shared = sizes.len() <= 1;
    let db = colmap_dir.join("database.db");
    timed(
        Stage::Features,
        if shared {
            format!(
                "SIFT on the CPU, one shared {} camera",
                opts.camera_model.colmap_name()
            )
        } else {
            format!(
                "SIFT on the CPU, one {} camera per photo: the photos have {} sizes ({})",
                opts.camera_model.colmap_name(),
                sizes.len(),
                sizes
                    .iter()
                    .take(4)
                    .map(|(w, h)| format!("{w}x{h}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        },
        progress,
        &mut || {
            colmap::extract_features(
                &runner,
                &opts.colmap,
                opts.camera_model,
                shared,
                &db,
                &input,
            )
        },
    )?;
    let matcher = match opts.matcher {
        Matcher::Auto if names.len() <= opts.exhaustive_up_to => Matcher::Exhaustive,
        Matcher::Auto => Matcher::Sequential,
        m => m,
    };
    timed(
        Stage::Matching,
        format!("{matcher}, {} images", names.len()),
        progress,
        &mut || colmap::match_features(&runner, &opts.colmap, matcher, &db),
    )?;
    let sparse = colmap_dir.join("sparse");
    std::fs::create_dir_all(&sparse).map_err(write_err(&sparse))?;
    let not_registered = |registered: &[String]| {
        let missing: Vec<String> = names
            .iter()
            .filter(|n| !registered.contains(n))
            .cloned()
            .collect();
        missing
    };
    let mapped = timed(
        Stage::Mapping,
        "incremental structure from motion".into(),
        progress,
        &mut || colmap::map(&runner, &opts.colmap, &db, &input, &sparse),
    );
    let best = colmap::best_model(&sparse)?;
    // The mapper fails when it cannot start a model at all: say which images, not just "failed".
    let (model_dir, registered) = match (mapped, best) {
        (Ok(()), Some(b)) => b,
        (Err(ProcessError::StageFailed { .. }), None) | (Ok(()), None) => {
            return Err(ProcessError::NotRegistered {
                registered: 0,
                total: names.len(),
                missing: list(&names),
                log: runner.log.clone(),
            });
        }
        (Err(e), _) => return Err(e),
    };
    let unregistered = not_registered(&registered);
    if registered.len() < 2 {
        return Err(ProcessError::NotRegistered {
            registered: registered.len(),
            total: names.len(),
            missing: list(&unregistered),
            log: runner.log.clone(),
        });
    }
    if !unregistered.is_empty() {
        progress(Event::Warning(format!(
            "COLMAP registered {} of {} images; left out (not in the scene): {}",
            registered.len(),
            names.len(),
            list(&unregistered)
        )));
    }
    let undistorted = colmap_dir.join("undistorted");
    timed(
        Stage::Undistortion,
        if shared {
            format!("{} images to one PINHOLE camera", registered.len())
        } else {
            format!(
                "{} images to PINHOLE cameras, one per photo",
                registered.len()
            )
        },
        progress,
        &mut || colmap::undistort(&runner, &opts.colmap, &input, &model_dir, &undistorted),
    )?;

    // 3. The scene folder: images/, sparse/0/, checked by loading it as every command will.
    let mut report = None;
    timed(
        Stage::Scene,
        out.display().to_string(),
        progress,
        &mut || {
            rename(&undistorted.join("images"), &work.join("images"))?;
            let model0 = work.join("sparse").join("0");
            std::fs::create_dir_all(work.join("sparse")).map_err(write_err(&work))?;
            rename(&undistorted.join("sparse"), &model0)?;
            std::fs::remove_dir_all(&undistorted).map_err(write_err(&undistorted))?;
            std::fs::remove_dir_all(&input).map_err(write_err(&input))?;
            let scene = load_scene(&work, &LoadOptions::default())?;
            scene.check_images()?;
            let model = read_colmap(&model0)?;
            let c = scene.views[0].camera;
            report = Some(ProcessReport {
                out: out.clone(),
                images: names.len(),
                registered: registered.clone(),
                unregistered: unregistered.clone(),
                points: model.points.len(),
                depth_bounds: scene.depth_bounds,
                matcher,
                size: (c.width, c.height),
                intrinsics: [
                    c.intrinsics.fx,
                    c.intrinsics.fy,
                    c.intrinsics.cx,
                    c.intrinsics.cy,
                ],
                log: out.join("colmap.log"),
                elapsed: Duration::ZERO,
            });
            std::fs::remove_file(work.join(MARKER)).map_err(write_err(&work))?;
            // Rename into place; an `out` that appeared meanwhile is left alone (the scene stays in `work`).
            out_is_free(out)?;
            if out.is_dir() {
                std::fs::remove_dir(out).map_err(write_err(out))?;
            }
            rename(&work, out)
        },
    )?;
    let mut report = report.expect("set by the last stage");
    if report.depth_bounds.is_none() {
        progress(Event::Warning(
            "the model has no 3D points in front of the cameras: the scene has no depth bounds (give them to the \
             other commands)"
                .into(),
        ));
    }
    report.elapsed = t0.elapsed();
    Ok(report)
}

/// Up to 20 names, comma-separated, then how many more.
fn list(names: &[String]) -> String {
    const SHOW: usize = 20;
    let mut s = names
        .iter()
        .take(SHOW)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > SHOW {
        s.push_str(&format!(" and {} more", names.len() - SHOW));
    }
    if s.is_empty() { "none".into() } else { s }
}
