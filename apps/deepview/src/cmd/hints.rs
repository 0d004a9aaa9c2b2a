//! The flag hints of library errors: the libraries say what is wrong in their own terms, the binary adds
//! which of its options fixes it (printed after the error by `main`).

use super::args::{min_arg, more_memory_hint, total_memory};
use deepview_data::DataError;
use deepview_eval::EvalError;
use deepview_media::MediaError;
use deepview_methods::MethodError;
use deepview_net::weights::WeightsError;
use deepview_process::ProcessError;
use deepview_synth::SynthError;
use deepview_train::TrainError;
use deepview_train::vgg::VggError;

/// The hint for the first error in `e`'s chain that has one.
pub fn hint(e: &anyhow::Error) -> Option<String> {
    e.chain().find_map(|cause| {
        if let Some(e) = cause.downcast_ref::<EvalError>() {
            return eval(e);
        }
        if let Some(e) = cause.downcast_ref::<MethodError>() {
            return method(e);
        }
        if let Some(e) = cause.downcast_ref::<WeightsError>() {
            return weights(e);
        }
        if let Some(e) = cause.downcast_ref::<VggError>() {
            return vgg(e);
        }
        if let Some(e) = cause.downcast_ref::<TrainError>() {
            return train(e);
        }
        if let Some(e) = cause.downcast_ref::<DataError>() {
            return data(e);
        }
        if let Some(deepview_mpi::MpiError::NoPlaneDepths { .. }) =
            cause.downcast_ref::<deepview_mpi::MpiError>()
        {
            return Some("pass --near and --far".into());
        }
        if let Some(e) = cause.downcast_ref::<MediaError>() {
            return media(e);
        }
        if let Some(e) = cause.downcast_ref::<ProcessError>() {
            return process(e);
        }
        if let Some(SynthError::TooFewPlanes(_)) = cause.downcast_ref::<SynthError>() {
            return Some("--planes must be at least 2".into());
        }
        if let Some(e) = cause.downcast_ref::<deepview_geometry::GeometryError>() {
            return geometry(e);
        }
        if let Some(deepview_viewer::ViewerError::Bind { msg, .. }) =
            cause.downcast_ref::<deepview_viewer::ViewerError>()
            && msg.to_ascii_lowercase().contains("in use")
        {
            return Some(
                "another program (perhaps another `deepview view`) serves on that port: pick \
                 another with --port, or --port 0 for any free one"
                    .into(),
            );
        }
        None
    })
}

fn eval(e: &EvalError) -> Option<String> {
    Some(match e {
        EvalError::Method(m) => return method(m),
        EvalError::NotEnoughInputs { available: 0, .. } => NO_INPUT_LEFT.into(),
        EvalError::NotEnoughInputs { wanted, .. } => fewer_inputs(*wanted),
        _ => return None,
    })
}

const NO_INPUT_LEFT: &str =
    "every view is a target, so none is left as an input: choose fewer --targets";

fn fewer_inputs(wanted: usize) -> String {
    format!("ask for fewer than {wanted} inputs (--inputs nearest:K, all, or a list)")
}

fn geometry(e: &deepview_geometry::GeometryError) -> Option<String> {
    match e {
        deepview_geometry::GeometryError::FacingApart { .. } => Some(
            "choose input views that face the same way (infer and eval: --inputs nearest:K@VIEW, \
             the K views nearest one view, or a list like 0,1,2)"
                .into(),
        ),
        _ => None,
    }
}

fn method(e: &MethodError) -> Option<String> {
    Some(match e {
        MethodError::Geometry(g) => return geometry(g),
        MethodError::PlanesOverBudget { need, .. } => match total_memory() {
            Some(t) if *need > t => format!(
                "use fewer planes (--planes) or smaller images (--downscale): it needs more than this \
                 machine's {} of memory",
                super::args::human(t)
            ),
            _ => format!(
                "use fewer planes (--planes), smaller images (--downscale) or --max-memory {}",
                min_arg(*need)
            ),
        },
        MethodError::OverBudget { need, .. } => more_memory_hint(*need, total_memory()),
        // (Not even one plane fits: fewer planes cannot help.)
        MethodError::StateOverBudget { fewer_than, .. } if *fewer_than <= 2 => {
            "use smaller images (--downscale) or far more --max-memory".into()
        }
        MethodError::StateOverBudget { fewer_than, .. } => format!(
            "use fewer than {fewer_than} planes (--planes), smaller images (--downscale) or far more \
             --max-memory"
        ),
        MethodError::PlanesNeedWeights => {
            "--planes weights needs a learned model (--method deepview): use --planes auto or a number"
                .into()
        }
        MethodError::NoPlanes => "--planes takes auto, weights or a count of at least 1".into(),
        MethodError::NoWeights { .. } => {
            "train some with `deepview train`, or pass --weights DIR (default: the built-in weights)".into()
        }
        MethodError::TooFewViews { available: 0, .. } => NO_INPUT_LEFT.into(),
        MethodError::TooFewViews { wanted, .. } => fewer_inputs(*wanted),
        MethodError::Weights(w) => return weights(w),
        _ => return None,
    })
}

fn vgg(e: &VggError) -> Option<String> {
    match e {
        VggError::NotGiven => Some(
            "pass --vgg-weights FILE (vgg16_conv1_1-conv3_3.safetensors; `deepview train` also takes \
             --loss l1, which needs none)"
                .into(),
        ),
        _ => None,
    }
}

fn train(e: &TrainError) -> Option<String> {
    Some(match e {
        // Transparent: the VGG error itself is not in the chain.
        TrainError::Vgg(v) => return vgg(v),
        TrainError::HasCheckpoints { .. } => {
            "pass --resume to continue it, or choose another --name".into()
        }
        TrainError::Write { kept: Some(_), .. } => {
            "free space or fix the folder, then continue the run with --resume".into()
        }
        TrainError::Write { kept: None, .. } => {
            "free space or fix the folder, then start the run again (--resume starts it over)"
                .into()
        }
        _ => return None,
    })
}

fn weights(e: &WeightsError) -> Option<String> {
    match e {
        WeightsError::WrongViews { expected, .. } => Some(format!(
            "pass --inputs nearest:{expected} (or a list of {expected} views)"
        )),
        _ => None,
    }
}

fn data(e: &DataError) -> Option<String> {
    Some(match e {
        DataError::NoDepthBounds { .. } => "pass --near and --far".into(),
        DataError::HalfDepthBounds { missing, .. } => format!("pass --{missing} too"),
        DataError::NoImageFolder { .. } => {
            "--images names a folder inside the dataset folder (e.g. images_8)".into()
        }
        DataError::DownscaleTooLarge { .. } => "use a smaller --downscale".into(),
        // An MPI is not a dataset (its layers are not photos to pose).
        DataError::NotDetected { path, .. } if path.join("mpi.json").is_file() => format!(
            "it is an MPI folder, not a dataset: render it with `deepview render --mpi {0} --out \
             view.png` or look around it with `deepview view --mpi {0}`",
            path.display()
        ),
        // A folder of photos with no poses yet.
        DataError::NotDetected { path, .. }
            if deepview_process::list_photos(path).is_ok_and(|p| p.len() >= 2) =>
        {
            {
                // The scene beside the folder (`.` and `..` named by their real names).
                let data = path.to_string_lossy().trim_end_matches('/').to_string();
                let out = match path.file_name() {
                    Some(_) => format!("{data}_scene"),
                    None => std::fs::canonicalize(path)
                        .ok()
                        .and_then(|c| {
                            let name = c.file_name()?.to_string_lossy().into_owned();
                            Some(
                                c.with_file_name(format!("{name}_scene"))
                                    .display()
                                    .to_string(),
                            )
                        })
                        .unwrap_or_else(|| "SCENE".into()),
                };
                let quote = |s: &str| {
                    if s.contains(' ') {
                        format!("'{s}'")
                    } else {
                        s.to_string()
                    }
                };
                format!(
                    "it holds photos without camera poses: make a scene of them first with \
                     `deepview process --data {} --out {}`",
                    quote(&data),
                    quote(&out)
                )
            }
        }
        _ => return None,
    })
}

fn media(e: &MediaError) -> Option<String> {
    Some(match e {
        MediaError::OddFrameSize { .. } => {
            "an MP4's frames are at least 2x2 pixels: give a larger --camera-path render size, or make \
            --out a .gif or a folder"
                .into()
        }
        _ => return None,
    })
}

fn process(e: &ProcessError) -> Option<String> {
    Some(match e {
        ProcessError::ColmapMissing { .. } => "or pass --colmap PATH".into(),
        ProcessError::FfmpegMissing { .. } => "or pass --ffmpeg PATH".into(),
        ProcessError::OutputExists { .. } => "choose another --out".into(),
        _ => return None,
    })
}
