//! Weights I/O: a directory with `config.json` ([`DeepViewConfig`]) and `model.safetensors` (the
//! [`DeepViewModel`] tensors, named by their module path, e.g. `nets.0.input.1.weight`).
//!
//! Loading checks everything a user can get wrong and names the file and the tensor: unreadable or
//! truncated files, weights saved for another configuration (missing tensors, shape mismatches),
//! non-finite weights, and (with [`check_views`]) a view count the weights were not trained for.

use crate::config::{ConfigError, DeepViewConfig};
use crate::forward::GRADIENT_CHANNELS;
use crate::network::{DeepViewModel, INIT_CHANNELS};
use burn::module::{Module, Param};
use burn::nn::conv::Conv2d;
use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::Device;
use std::path::{Path, PathBuf};

pub const CONFIG_FILE: &str = "config.json";
pub const WEIGHTS_FILE: &str = "model.safetensors";

#[derive(Debug, thiserror::Error)]
pub enum WeightsError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: invalid config: {msg}")]
    Config { path: PathBuf, msg: String },
    #[error("{path}: not a readable safetensors file (truncated or corrupt?): {msg}")]
    Corrupt { path: PathBuf, msg: String },
    #[error("{path}: weights do not match the config in {config}: {msg}")]
    Mismatch {
        path: PathBuf,
        config: PathBuf,
        msg: String,
    },
    #[error(
        "{path} does not load with the model configuration in {config} (edited since the checkpoint was \
         saved?), or is corrupt: {msg}"
    )]
    Unloadable {
        path: PathBuf,
        config: PathBuf,
        msg: String,
    },
    #[error("{path}: tensor {tensor} contains non-finite values (NaN or infinity)")]
    NonFinite { path: PathBuf, tensor: String },
    #[error("{path} is {what}")]
    NotWeights { path: PathBuf, what: &'static str },
    #[error(
        "{checkpoint} is a training checkpoint, and its model configuration, the run's {config}, is \
         missing: keep the checkpoint in its run folder (runs/NAME/config.json beside \
         runs/NAME/checkpoints/step-N), or make a weights folder of it there with `deepview \
         export-weights --checkpoint DIR --out WEIGHTS`"
    )]
    NoRunConfig {
        checkpoint: PathBuf,
        config: PathBuf,
    },
    #[error(
        "these weights were trained for exactly {expected} input views, got {got} (config {config})"
    )]
    WrongViews {
        expected: usize,
        got: usize,
        config: String,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> WeightsError + '_ {
    move |source| WeightsError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Write `bytes` to `path` atomically (temp file in the same directory, then rename).
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), WeightsError> {
    deepview_image::write_atomic_with(path, bytes, deepview_image::Durability::Rename)
        .map_err(io(path))
}

/// Save `model` and `config` into `dir` (created if needed).
pub fn save_model(
    dir: &Path,
    model: &DeepViewModel,
    config: &DeepViewConfig,
) -> Result<(), WeightsError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let weights = dir.join(WEIGHTS_FILE);
    let mut store = SafetensorsStore::from_bytes(None);
    model
        .save_into(&mut store)
        .map_err(|e| WeightsError::Corrupt {
            path: weights.clone(),
            msg: e.to_string(),
        })?;
    let bytes = store
        .get_bytes()
        .map_err(|e| e.to_string())
        .and_then(canonical_safetensors)
        .map_err(|msg| WeightsError::Corrupt {
            path: weights.clone(),
            msg,
        })?;
    write_atomic(&weights, &bytes)?;
    let json = serde_json::to_string_pretty(config).expect("config serialises");
    write_atomic(&dir.join(CONFIG_FILE), json.as_bytes())
}

/// `bytes` (a safetensors file) with its JSON header's keys in sorted order at every level, so that the
/// same model always gives the same file (burn writes its `__metadata__` map in hash order: two exports
/// of one checkpoint differed). The tensors' data is untouched; the header keeps its length (padded with
/// spaces, as the format allows) or grows to the next multiple of 8.
fn canonical_safetensors(bytes: Vec<u8>) -> Result<Vec<u8>, String> {
    fn write(v: &serde_json::Value, out: &mut String) {
        match v {
            serde_json::Value::Object(map) => {
                let mut entries: Vec<_> = map.iter().collect();
                entries.sort_by(|a, b| a.0.cmp(b.0));
                out.push('{');
                for (i, (k, v)) in entries.into_iter().enumerate() {
                    if i > 0 {
                        out.push(',');
                    }
                    out.push_str(&serde_json::Value::String(k.clone()).to_string());
                    out.push(':');
                    write(v, out);
                }
                out.push('}');
            }
            serde_json::Value::Array(items) => {
                out.push('[');
                for (i, v) in items.iter().enumerate() {
                    if i > 0 {
                        out.push(',');
                    }
                    write(v, out);
                }
                out.push(']');
            }
            other => out.push_str(&other.to_string()),
        }
    }
    let len = bytes
        .get(..8)
        .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
        .ok_or("shorter than its header length")?;
    let end = usize::try_from(len)
        .ok()
        .and_then(|n| n.checked_add(8))
        .filter(|&e| e <= bytes.len())
        .ok_or("header length beyond the file")?;
    let header: serde_json::Value =
        serde_json::from_slice(&bytes[8..end]).map_err(|e| format!("header: {e}"))?;
    let mut text = String::new();
    write(&header, &mut text);
    let padded = if text.len() <= end - 8 {
        end - 8
    } else {
        (text.len() + 8).next_multiple_of(8) - 8
    };
    let mut out = Vec::with_capacity(bytes.len() + padded);
    out.extend_from_slice(&(padded as u64).to_le_bytes());
    out.extend_from_slice(text.as_bytes());
    out.resize(8 + padded, b' ');
    out.extend_from_slice(&bytes[end..]);
    Ok(out)
}

/// The parameter count of the model `config` describes (mirrors `CoreNet::new`: 3x3 convs with biases;
/// net 0 takes the plane sweep volume, update nets the gradient components and the state), in closed form
/// so that absurd counts are computed, not looped over; `None` when it does not even fit in a u128.
pub fn parameter_count(config: &DeepViewConfig) -> Option<u128> {
    let n = |v: usize| v as u128;
    let conv = |i: u128, o: u128| i.checked_mul(o)?.checked_mul(9)?.checked_add(o);
    let sc = n(config.extra_channels).checked_add(4)?;
    let net = |cin: u128, f: u128| -> Option<u128> {
        let stage = conv(2 * f, f)?.checked_add(conv(f, f)?)?;
        [
            conv(cin, f)?,
            conv(f, f)?,
            stage.checked_mul(n(config.max_pool_stages))?,
            conv(f, f)?,
            conv(f, sc)?,
        ]
        .into_iter()
        .try_fold(0u128, u128::checked_add)
    };
    let update_in = n(GRADIENT_CHANNELS).checked_add(sc)?;
    let updates = n(config.updates);
    let large_updates = n(config.large_nets).saturating_sub(1).min(updates);
    let (fl, fs) = (n(config.features_large), n(config.features_small));
    net(n(INIT_CHANNELS), n(config.features(0)))?
        .checked_add(net(update_in, fl)?.checked_mul(large_updates)?)?
        .checked_add(net(update_in, fs)?.checked_mul(updates - large_updates)?)
}

/// Refuse a config describing more parameters than the `len` bytes of the model file `path` can hold (one
/// byte each at the very least), before the model is built: building allocates what the config says.
fn check_model_size(
    config: &DeepViewConfig,
    config_path: &Path,
    path: &Path,
    len: u64,
) -> Result<(), WeightsError> {
    match parameter_count(config) {
        Some(p) if p <= len as u128 => Ok(()),
        p => Err(WeightsError::Mismatch {
            path: path.to_path_buf(),
            config: config_path.to_path_buf(),
            msg: format!(
                "the config describes a model of {} parameters, more than the file's {len} bytes can hold",
                p.map_or("too many".to_string(), |p| p.to_string())
            ),
        }),
    }
}

/// Read `dir/config.json`.
pub fn load_config(dir: &Path) -> Result<DeepViewConfig, WeightsError> {
    let path = dir.join(CONFIG_FILE);
    let text = std::fs::read(&path).map_err(io(&path))?;
    parse_config(&path, &text)
}

/// A `config.json` from its bytes (`path` names it in errors).
fn parse_config(path: &Path, bytes: &[u8]) -> Result<DeepViewConfig, WeightsError> {
    let config: DeepViewConfig =
        serde_json::from_slice(bytes).map_err(|e| WeightsError::Config {
            path: path.to_path_buf(),
            msg: e.to_string(),
        })?;
    config
        .validate()
        .map_err(|e: ConfigError| WeightsError::Config {
            path: path.to_path_buf(),
            msg: e.to_string(),
        })?;
    Ok(config)
}

/// Whether `dir` is a training checkpoint (`runs/<name>/checkpoints/step-N/model.bpk`) rather than a
/// weights folder.
pub fn is_checkpoint(dir: &Path) -> bool {
    dir.join(CHECKPOINT_MODEL_FILE).is_file() && !dir.join(WEIGHTS_FILE).is_file()
}

/// The model file of a training checkpoint (burnpack, see `train`).
pub const CHECKPOINT_MODEL_FILE: &str = "model.bpk";

/// The model configuration of a training checkpoint folder: the `model` entry of the run's
/// `runs/<name>/config.json`.
pub fn checkpoint_config(dir: &Path) -> Result<DeepViewConfig, WeightsError> {
    let run_config = run_config_path(dir);
    let text = std::fs::read_to_string(&run_config).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            WeightsError::NoRunConfig {
                checkpoint: dir.to_path_buf(),
                config: run_config.clone(),
            }
        } else {
            io(&run_config)(e)
        }
    })?;
    let config_err = |msg: String| WeightsError::Config {
        path: run_config.clone(),
        msg,
    };
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| config_err(e.to_string()))?;
    let model_value = value
        .get("model")
        .cloned()
        .ok_or_else(|| config_err("no `model` entry (not a run's config.json)".into()))?;
    let config: DeepViewConfig =
        serde_json::from_value(model_value).map_err(|e| config_err(e.to_string()))?;
    config.validate().map_err(|e| config_err(e.to_string()))?;
    Ok(config)
}

/// What a folder handed in as weights must be, for [`WeightsError::NotWeights`].
const WEIGHTS_OR_CHECKPOINT: &str = "neither a weights folder (config.json + model.safetensors) nor a training \
    checkpoint (runs/NAME/checkpoints/step-N with model.bpk)";

/// Refuse a folder that is neither weights nor a checkpoint, naming it rather than a file inside it.
fn check_weights_folder(dir: &Path) -> Result<(), WeightsError> {
    if dir.join("checkpoints").is_dir() && !dir.join(WEIGHTS_FILE).is_file() {
        return Err(WeightsError::NotWeights {
            path: dir.to_path_buf(),
            what: "a training run, not weights: pass one of its checkpoints \
                   (checkpoints/step-N), or make weights of it with `deepview export-weights`",
        });
    }
    if is_checkpoint(dir) || dir.join(CONFIG_FILE).is_file() {
        return Ok(());
    }
    Err(WeightsError::NotWeights {
        path: dir.to_path_buf(),
        what: if dir.is_dir() {
            WEIGHTS_OR_CHECKPOINT
        } else {
            "not a folder (weights or a training checkpoint)"
        },
    })
}

/// The run's `config.json` of a checkpoint folder `runs/<name>/checkpoints/step-N`.
fn run_config_path(dir: &Path) -> PathBuf {
    dir.parent()
        .and_then(Path::parent)
        .map(|run| run.join(CONFIG_FILE))
        .unwrap_or_else(|| PathBuf::from(CONFIG_FILE))
}

/// The model configuration saved with a weights folder or a training checkpoint folder (or of the
/// built-in weights, named [`BUILTIN`]).
pub fn load_config_any(dir: &Path) -> Result<DeepViewConfig, WeightsError> {
    if is_builtin(dir) {
        return parse_config(&Path::new(SHIPPED_NAME).join(CONFIG_FILE), SHIPPED_CONFIG);
    }
    check_weights_folder(dir)?;
    if is_checkpoint(dir) {
        checkpoint_config(dir)
    } else {
        load_config(dir)
    }
}

/// Load the model of a training checkpoint folder `runs/<name>/checkpoints/step-N` (`model.bpk`; the
/// model configuration is the `model` entry of the run's `runs/<name>/config.json`).
pub fn load_checkpoint(
    dir: &Path,
    device: &Device,
) -> Result<(DeepViewModel, DeepViewConfig), WeightsError> {
    let config = checkpoint_config(dir)?;
    let path = dir.join(CHECKPOINT_MODEL_FILE);
    let len = std::fs::metadata(&path).map_err(io(&path))?.len();
    check_model_size(&config, &run_config_path(dir), &path, len)?;
    // The size matched the configuration, so a failure here is most likely a configuration edited since
    // the checkpoint was saved (tensor shapes that differ at the same total size), else corruption.
    let model = DeepViewModel::new(&config, device)
        .try_load_file(&path)
        .map_err(|e| WeightsError::Unloadable {
            path: path.clone(),
            config: run_config_path(dir),
            msg: clipped(&e.to_string(), 300),
        })?;
    if let Some(tensor) = first_non_finite(&model) {
        return Err(WeightsError::NonFinite { path, tensor });
    }
    Ok((crate::device::weights_layout(model), config))
}

/// `text` cut to at most `max` bytes (at a character boundary), marked with "..." when cut: a loader's
/// error message kept readable.
pub fn clipped(text: &str, max: usize) -> String {
    if text.len() <= max {
        return text.to_string();
    }
    let mut end = max;
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}...", &text[..end])
}

/// Convert a training checkpoint into a weights folder (`config.json` + `model.safetensors`).
pub fn export_checkpoint(checkpoint: &Path, out: &Path) -> Result<DeepViewConfig, WeightsError> {
    if !is_checkpoint(checkpoint) {
        return Err(WeightsError::NotWeights {
            path: checkpoint.to_path_buf(),
            what: "neither a training run (with checkpoints/) nor a training checkpoint \
                   (runs/NAME/checkpoints/step-N with model.bpk)",
        });
    }
    let (model, config) = load_checkpoint(checkpoint, &Device::flex())?;
    save_model(out, &model, &config)?;
    Ok(config)
}

/// Load the model saved in `dir` onto `device`: a weights folder, a training checkpoint folder
/// ([`load_checkpoint`]), or the built-in weights ([`BUILTIN`]).
pub fn load_model(
    dir: &Path,
    device: &Device,
) -> Result<(DeepViewModel, DeepViewConfig), WeightsError> {
    if is_builtin(dir) {
        return load_shipped(device);
    }
    check_weights_folder(dir)?;
    if is_checkpoint(dir) {
        return load_checkpoint(dir, device);
    }
    let config_path = dir.join(CONFIG_FILE);
    let config = std::fs::read(&config_path).map_err(io(&config_path))?;
    let path = dir.join(WEIGHTS_FILE);
    let bytes = std::fs::read(&path).map_err(io(&path))?;
    load_model_bytes(dir, &config, bytes, device)
}

/// The weights shipped with the repository (`weights/cpu`: the trained `cpu` preset, 37 KB), compiled in
/// so that any copy of a program works without the repository.
pub const SHIPPED_CONFIG: &[u8] = include_bytes!("../../../weights/cpu/config.json");
/// The tensors of the shipped weights (see [`SHIPPED_CONFIG`]).
pub const SHIPPED_MODEL: &[u8] = include_bytes!("../../../weights/cpu/model.safetensors");
/// How the shipped weights are named in messages and reports.
pub const SHIPPED_NAME: &str = "built-in weights/cpu";
/// How a user names the shipped weights where a weights folder is asked for (`--weights builtin`,
/// `train --init builtin`), so that an installed program can name them; a folder of that name is
/// `./builtin`.
pub const BUILTIN: &str = "builtin";

/// Whether `dir` names the built-in weights ([`BUILTIN`]).
pub fn is_builtin(dir: &Path) -> bool {
    dir.as_os_str() == BUILTIN
}

/// Load the shipped weights ([`SHIPPED_CONFIG`], [`SHIPPED_MODEL`]) from memory onto `device`.
pub fn load_shipped(device: &Device) -> Result<(DeepViewModel, DeepViewConfig), WeightsError> {
    load_model_bytes(
        Path::new(SHIPPED_NAME),
        SHIPPED_CONFIG,
        SHIPPED_MODEL.to_vec(),
        device,
    )
}

/// Load a model from the bytes of a weights folder's `config.json` and `model.safetensors`, checked as
/// [`load_model`] checks files; `dir` names the folder in errors.
pub fn load_model_bytes(
    dir: &Path,
    config: &[u8],
    bytes: Vec<u8>,
    device: &Device,
) -> Result<(DeepViewModel, DeepViewConfig), WeightsError> {
    let config = parse_config(&dir.join(CONFIG_FILE), config)?;
    let path = dir.join(WEIGHTS_FILE);
    check_model_size(&config, &dir.join(CONFIG_FILE), &path, bytes.len() as u64)?;
    let mut model = DeepViewModel::new(&config, device);
    let mut store = SafetensorsStore::from_bytes(Some(bytes))
        .allow_partial(true)
        .validate(false);
    let result = model
        .load_from(&mut store)
        .map_err(|e| WeightsError::Corrupt {
            path: path.clone(),
            msg: e.to_string(),
        })?;
    let mismatch = |msg: String| WeightsError::Mismatch {
        path: path.clone(),
        config: dir.join(CONFIG_FILE),
        msg,
    };
    if let Some(e) = result.errors.first() {
        return Err(mismatch(match e {
            burn::store::ApplyError::ShapeMismatch {
                path,
                expected,
                found,
            } => format!(
                "tensor {path} is {:?} in the file but {:?} in the model config.json describes",
                found.as_slice(),
                expected.as_slice()
            ),
            e => e.to_string(),
        }));
    }
    if let Some((name, _)) = result.missing.first() {
        return Err(mismatch(format!(
            "tensor {name} is missing ({} missing in all)",
            result.missing.len()
        )));
    }
    if let Some(name) = result.unused.first() {
        return Err(mismatch(format!(
            "the file has tensor {name} that the config has no place for"
        )));
    }
    if let Some(tensor) = first_non_finite(&model) {
        return Err(WeightsError::NonFinite { path, tensor });
    }
    Ok((crate::device::weights_layout(model), config))
}

/// Refuse a view count that weights trained for a fixed number of views cannot take.
pub fn check_views(config: &DeepViewConfig, views: usize) -> Result<(), WeightsError> {
    match config.views {
        Some(k) if k != views => Err(WeightsError::WrongViews {
            expected: k,
            got: views,
            config: config.name.clone(),
        }),
        _ => Ok(()),
    }
}

fn param_non_finite<const D: usize>(p: &Param<burn::tensor::Tensor<D>>) -> bool {
    let v = p.val();
    let finite: bool = v.is_finite().all().into_scalar();
    !finite
}

fn conv_non_finite(c: &Conv2d, name: &str) -> Option<String> {
    if param_non_finite(&c.weight) {
        return Some(format!("{name}.weight"));
    }
    match &c.bias {
        Some(b) if param_non_finite(b) => Some(format!("{name}.bias")),
        _ => None,
    }
}

/// The module path of the first tensor with a NaN or infinity.
pub fn first_non_finite(model: &DeepViewModel) -> Option<String> {
    for (n, net) in model.nets.iter().enumerate() {
        let convs = net
            .input
            .iter()
            .enumerate()
            .map(|(i, c)| (c, format!("nets.{n}.input.{i}")))
            .chain(
                net.stages
                    .iter()
                    .enumerate()
                    .map(|(i, c)| (c, format!("nets.{n}.stages.{i}"))),
            )
            .chain([
                (&net.head, format!("nets.{n}.head")),
                (&net.out, format!("nets.{n}.out")),
            ]);
        for (c, name) in convs {
            if let Some(t) = conv_non_finite(c, &name) {
                return Some(t);
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Long loader errors are cut to a bounded message, never inside a character.
    #[test]
    fn clipped_cuts_at_a_character_boundary() {
        assert_eq!(clipped("short", 300), "short");
        let long = "é".repeat(200); // 400 bytes
        let c = clipped(&long, 301);
        assert!(c.ends_with("...") && c.len() <= 303, "{}", c.len());
        assert_eq!(c.trim_end_matches("...").chars().count(), 150);
    }
    use burn::tensor::Tensor;

    fn cfg() -> DeepViewConfig {
        DeepViewConfig {
            features_large: 4,
            features_small: 3,
            updates: 1,
            // Random output convs (with the prior they start at zero and outputs would not depend on them).
            init_prior: None,
            ..DeepViewConfig::preset("cpu").unwrap()
        }
    }

    /// The closed-form count that guards model building equals the built model's.
    #[test]
    fn parameter_count_is_the_models() {
        let dev = Device::flex();
        let odd = DeepViewConfig {
            large_nets: 2,
            updates: 3,
            features_large: 5,
            features_small: 3,
            extra_channels: 1,
            max_pool_stages: 2,
            ..cfg()
        };
        let presets = ["cpu", "cpu-large", "paper-kalantari", "paper-spaces-4view"];
        let presets = presets.map(|p| DeepViewConfig::preset(p).unwrap());
        for c in [cfg(), odd].into_iter().chain(presets) {
            let built = crate::rng::module(|| DeepViewModel::new(&c, &dev)).num_params() as u128;
            assert_eq!(parameter_count(&c), Some(built), "{c:?}");
        }
        let huge = DeepViewConfig {
            features_large: usize::MAX,
            ..cfg()
        };
        assert_eq!(parameter_count(&huge), None);
    }

    /// A checkpoint folder copied out of its run (no `config.json` two levels up) is refused with an
    /// error that names the checkpoint and the run's config file it needs, not only a missing file.
    #[test]
    fn a_checkpoint_out_of_its_run_names_the_config_it_needs() {
        let root = tempfile::tempdir().unwrap();
        let ck = root.path().join("copied").join("step-0000500");
        std::fs::create_dir_all(&ck).unwrap();
        std::fs::write(ck.join(CHECKPOINT_MODEL_FILE), b"not read").unwrap();
        let want = root.path().join("config.json");
        for err in [
            load_config_any(&ck).unwrap_err(),
            load_checkpoint(&ck, &Device::flex()).unwrap_err(),
        ] {
            match &err {
                WeightsError::NoRunConfig { checkpoint, config } => {
                    assert_eq!((checkpoint, config), (&ck, &want));
                }
                other => panic!("expected NoRunConfig, got {other:?}"),
            }
            let msg = err.to_string();
            assert!(
                msg.contains("training checkpoint") && msg.contains("export-weights"),
                "{msg}"
            );
        }
        // With the run's config.json in place the same folder gets past that check (to the model file).
        std::fs::write(&want, b"{}").unwrap();
        assert!(matches!(
            load_config_any(&ck).unwrap_err(),
            WeightsError::Config { .. }
        ));
    }

    #[test]
    fn round_trip_gives_identical_outputs() {
        let dev = Device::flex();
        let dir = tempfile::tempdir().unwrap();
        let model = crate::rng::module(|| DeepViewModel::new(&cfg(), &dev));
        save_model(dir.path(), &model, &cfg()).unwrap();
        let (loaded, c2) = load_model(dir.path(), &dev).unwrap();
        assert_eq!(c2, cfg());
        let inputs = crate::network::synthetic_inputs(2, 3, 12, 14, &dev);
        let a = model.forward(&inputs).rgba;
        let b = loaded.forward(&inputs).rgba;
        let d: f32 = (a - b).abs().max().into_scalar();
        assert_eq!(d, 0.0);
    }

    /// The same model saves to the same bytes (burn's metadata map came out in hash order: two
    /// exports of one checkpoint differed), and the file still loads.
    #[test]
    fn saving_is_byte_reproducible() {
        let dev = Device::flex();
        let model = crate::rng::module(|| DeepViewModel::new(&cfg(), &dev));
        let files: Vec<Vec<u8>> = (0..8)
            .map(|_| {
                let dir = tempfile::tempdir().unwrap();
                save_model(dir.path(), &model, &cfg()).unwrap();
                load_model(dir.path(), &dev).unwrap();
                std::fs::read(dir.path().join(WEIGHTS_FILE)).unwrap()
            })
            .collect();
        assert!(files.iter().all(|f| *f == files[0]));
        // Keys sorted at every level, data and its offsets untouched, the header padded in place.
        let header = br#"{"b":{"z":1,"a":[2,{"y":3,"x":4}]},"a":"s"}  "#;
        let mut file = (header.len() as u64).to_le_bytes().to_vec();
        file.extend_from_slice(header);
        file.extend_from_slice(&[1, 2, 3]);
        let out = canonical_safetensors(file.clone()).unwrap();
        assert_eq!(out.len(), file.len());
        assert_eq!(
            &out[8..8 + header.len()],
            br#"{"a":"s","b":{"a":[2,{"x":4,"y":3}],"z":1}}  "#
        );
        assert_eq!(&out[8 + header.len()..], &[1, 2, 3]);
        assert!(canonical_safetensors(vec![200, 0, 0, 0, 0, 0, 0, 0, b'{']).is_err());
    }

    #[test]
    fn checkpoint_loads_and_exports_with_identical_outputs() {
        let dev = Device::flex();
        let run = tempfile::tempdir().unwrap();
        let ck = run.path().join("checkpoints").join("step-0000001");
        std::fs::create_dir_all(&ck).unwrap();
        let model = crate::rng::module(|| DeepViewModel::new(&cfg(), &dev));
        model
            .clone()
            .save_file(ck.join(CHECKPOINT_MODEL_FILE))
            .unwrap();
        // No run config yet: the error names the file.
        let e = load_model(&ck, &dev).unwrap_err().to_string();
        assert!(e.contains(CONFIG_FILE), "{e}");
        let run_cfg = serde_json::json!({ "model": cfg(), "train": {} });
        std::fs::write(run.path().join(CONFIG_FILE), run_cfg.to_string()).unwrap();
        assert!(is_checkpoint(&ck));
        let (loaded, c) = load_model(&ck, &dev).unwrap();
        assert_eq!(c, cfg());
        let out = run.path().join("exported");
        export_checkpoint(&ck, &out).unwrap();
        let (exported, _) = load_model(&out, &dev).unwrap();
        let inputs = crate::network::synthetic_inputs(2, 3, 12, 14, &dev);
        let a = model.forward(&inputs).rgba;
        for m in [loaded, exported] {
            let d: f32 = (a.clone() - m.forward(&inputs).rgba)
                .abs()
                .max()
                .into_scalar();
            assert_eq!(d, 0.0);
        }
    }

    #[test]
    fn truncated_file_is_refused() {
        let dev = Device::flex();
        let dir = tempfile::tempdir().unwrap();
        save_model(
            dir.path(),
            &crate::rng::module(|| DeepViewModel::new(&cfg(), &dev)),
            &cfg(),
        )
        .unwrap();
        let p = dir.path().join(WEIGHTS_FILE);
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
        let e = load_model(dir.path(), &dev).unwrap_err();
        assert!(matches!(e, WeightsError::Corrupt { .. }), "{e}");
        assert!(e.to_string().contains(WEIGHTS_FILE));
        std::fs::remove_file(&p).unwrap();
        assert!(matches!(
            load_model(dir.path(), &dev).unwrap_err(),
            WeightsError::Io { .. }
        ));
    }

    #[test]
    fn weights_of_another_config_name_the_tensor() {
        let dev = Device::flex();
        let dir = tempfile::tempdir().unwrap();
        save_model(
            dir.path(),
            &crate::rng::module(|| DeepViewModel::new(&cfg(), &dev)),
            &cfg(),
        )
        .unwrap();
        // Same files, but the config now asks for more features.
        let other = DeepViewConfig {
            features_large: 5,
            ..cfg()
        };
        std::fs::write(
            dir.path().join(CONFIG_FILE),
            serde_json::to_string(&other).unwrap(),
        )
        .unwrap();
        let e = load_model(dir.path(), &dev).unwrap_err().to_string();
        assert!(
            e.contains("nets.0.input.0.weight") || e.contains("nets.0."),
            "{e}"
        );
        // In words, not the loader's Debug text (`ShapeMismatch { .., dims: .. }`).
        assert!(
            e.contains("in the file but")
                && e.contains("config.json describes")
                && !e.contains("dims"),
            "{e}"
        );
        // More nets than the file has: a missing tensor is named.
        let more = DeepViewConfig {
            updates: 2,
            ..cfg()
        };
        std::fs::write(
            dir.path().join(CONFIG_FILE),
            serde_json::to_string(&more).unwrap(),
        )
        .unwrap();
        let e = load_model(dir.path(), &dev).unwrap_err().to_string();
        assert!(e.contains("nets.2."), "{e}");
    }

    #[test]
    fn nan_weights_are_refused() {
        let dev = Device::flex();
        let dir = tempfile::tempdir().unwrap();
        let mut model = crate::rng::module(|| DeepViewModel::new(&cfg(), &dev));
        let w = model.nets[1].head.weight.val();
        let bad = w.clone().mask_fill(w.ones_like().equal_elem(1.0), f32::NAN);
        model.nets[1].head.weight = Param::from_tensor(bad);
        save_model(dir.path(), &model, &cfg()).unwrap();
        let e = load_model(dir.path(), &dev).unwrap_err();
        assert!(
            matches!(&e, WeightsError::NonFinite { tensor, .. } if tensor == "nets.1.head.weight"),
            "{e}"
        );
        let _ = Tensor::<1>::zeros([1], &dev);
    }

    #[test]
    fn fixed_view_count_is_checked() {
        let k = DeepViewConfig::preset("paper-kalantari").unwrap();
        assert!(check_views(&k, 4).is_ok());
        let e = check_views(&k, 3).unwrap_err().to_string();
        assert!(e.contains("exactly 4") && e.contains("got 3"), "{e}");
        assert!(check_views(&DeepViewConfig::preset("cpu").unwrap(), 7).is_ok());
        // A corrupt config file is reported with its path.
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(CONFIG_FILE), "{ not json").unwrap();
        let e = load_config(dir.path()).unwrap_err().to_string();
        assert!(e.contains(CONFIG_FILE), "{e}");
    }

    /// The compiled-in weights are the repository's `weights/cpu` and load from memory.
    #[test]
    fn shipped_weights_are_the_repository_files() {
        let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../weights/cpu");
        assert!(std::fs::read(repo.join(CONFIG_FILE)).unwrap() == SHIPPED_CONFIG);
        assert!(std::fs::read(repo.join(WEIGHTS_FILE)).unwrap() == SHIPPED_MODEL);
        let dev = Device::flex();
        let (a, ca) = load_shipped(&dev).unwrap();
        let (b, cb) = load_model(&repo, &dev).unwrap();
        assert_eq!(ca, cb);
        let x = a.nets[0].head.weight.val().into_data();
        let y = b.nets[0].head.weight.val().into_data();
        assert_eq!(x, y);
    }
}
