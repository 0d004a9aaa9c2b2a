//! Fuzz tests of the readers of a weights folder a user hands in (issue 28): `config.json` and
//! `model.safetensors` ([`load_model`]), and a training checkpoint's `model.bpk` with its run's
//! `config.json` ([`load_checkpoint`]). The shipped `weights/cpu` and a checkpoint written here are mutated
//! (see `deepview_fuzz`; the safetensors header is also mutated as JSON) and loaded: no input may panic or make
//! the loader allocate absurdly, every error names the file (or the folder holding it), and an accepted
//! model matches its config and has finite weights.
//!
//! Run longer or with another seed: `DEEPVIEW_FUZZ_SECS=60 DEEPVIEW_FUZZ_ITERS=1000000
//! DEEPVIEW_FUZZ_SEED=7 cargo test --release -p deepview-net --test fuzz`.

use deepview_fuzz::{Fuzz, Kind, Rng, Special, mutate_json, mutate_number};
use deepview_net::burn::module::Module;
use deepview_net::burn::tensor::Device;
use deepview_net::config::DeepViewConfig;
use deepview_net::network::DeepViewModel;
use deepview_net::weights::{
    CHECKPOINT_MODEL_FILE, CONFIG_FILE, SHIPPED_CONFIG, SHIPPED_MODEL, WEIGHTS_FILE,
    first_non_finite, load_checkpoint, load_model,
};
use std::path::Path;

/// What a loader accepts: the config's nets, finite weights.
fn check(model: &DeepViewModel, config: &DeepViewConfig) {
    assert_eq!(model.nets.len(), config.nets());
    assert_eq!(first_non_finite(model), None);
}

/// A weights folder (the shipped `weights/cpu`) in `dir`.
fn weights(dir: &Path) {
    std::fs::write(dir.join(CONFIG_FILE), SHIPPED_CONFIG).unwrap();
    std::fs::write(dir.join(WEIGHTS_FILE), SHIPPED_MODEL).unwrap();
}

fn fuzz_weights(file: &str, kind: Kind, iters: usize, special: Option<&Special>) {
    let dir = tempfile::tempdir().unwrap();
    weights(dir.path());
    let path = dir.path().join(file);
    let device = Device::flex();
    Fuzz {
        name: &format!("load_model({file})"),
        file: &path,
        kind,
        seeds: vec![std::fs::read(&path).unwrap()],
        iters,
        needles: vec![dir.path().display().to_string()],
        special,
    }
    .run(|| {
        let (model, config) = load_model(dir.path(), &device).map_err(|e| e.to_string())?;
        check(&model, &config);
        Ok(())
    });
}

/// A mutation of a safetensors file's header (8-byte little-endian length, then JSON: every tensor's
/// dtype, shape and data offsets), the length rewritten to match.
fn safetensors_header(rng: &mut Rng, b: &[u8]) -> Option<Vec<u8>> {
    let n = usize::try_from(u64::from_le_bytes(b.get(..8)?.try_into().ok()?)).ok()?;
    let mut header = b.get(8..8usize.checked_add(n)?)?.to_vec();
    let done = if rng.below(2) == 0 {
        mutate_json(rng, &mut header)
    } else {
        mutate_number(rng, &mut header)
    };
    if !done {
        return None;
    }
    let mut out = (header.len() as u64).to_le_bytes().to_vec();
    out.extend(header);
    out.extend(&b[8 + n..]);
    Some(out)
}

#[test]
fn weights_config_json() {
    fuzz_weights(CONFIG_FILE, Kind::Json, 1500, None);
}

#[test]
fn weights_model_safetensors() {
    fuzz_weights(WEIGHTS_FILE, Kind::Binary, 1500, Some(&safetensors_header));
}

/// A training checkpoint `run/checkpoints/step-0000001` of the shipped model under `root`, with the run's
/// `config.json`.
fn checkpoint(root: &Path) -> std::path::PathBuf {
    let dir = tempfile::tempdir().unwrap();
    weights(dir.path());
    let (model, config) = load_model(dir.path(), &Device::flex()).unwrap();
    let ck = root.join("run/checkpoints/step-0000001");
    std::fs::create_dir_all(&ck).unwrap();
    model.save_file(ck.join(CHECKPOINT_MODEL_FILE)).unwrap();
    let run = serde_json::json!({"model": config, "train": {"steps": 10}});
    std::fs::write(
        root.join("run").join(CONFIG_FILE),
        serde_json::to_vec_pretty(&run).unwrap(),
    )
    .unwrap();
    ck
}

fn fuzz_checkpoint(file: &Path, kind: Kind, iters: usize, ck: &Path, root: &Path) {
    let device = Device::flex();
    Fuzz {
        name: &format!(
            "load_checkpoint({})",
            file.file_name().unwrap().to_string_lossy()
        ),
        file,
        kind,
        seeds: vec![std::fs::read(file).unwrap()],
        iters,
        needles: vec![root.display().to_string()],
        special: None,
    }
    .run(|| {
        let (model, config) = load_checkpoint(ck, &device).map_err(|e| e.to_string())?;
        check(&model, &config);
        Ok(())
    });
}

#[test]
fn checkpoint_run_config_json() {
    let root = tempfile::tempdir().unwrap();
    let ck = checkpoint(root.path());
    let file = root.path().join("run").join(CONFIG_FILE);
    fuzz_checkpoint(&file, Kind::Json, 1500, &ck, root.path());
}

#[test]
fn checkpoint_model_bpk() {
    let root = tempfile::tempdir().unwrap();
    let ck = checkpoint(root.path());
    fuzz_checkpoint(
        &ck.join(CHECKPOINT_MODEL_FILE),
        Kind::Binary,
        1500,
        &ck,
        root.path(),
    );
}

/// Regression: a valid config with a huge architecture (here 65536 features, or 2^63 update nets) made
/// `load_model` build the model it describes before reading the weights: hundreds of GB of random
/// weights (an abort), or a loop over 2^63 nets. It is now refused for describing more parameters than
/// the weights file's bytes can hold.
#[test]
fn a_config_cannot_ask_for_a_huge_model() {
    let dir = tempfile::tempdir().unwrap();
    weights(dir.path());
    let shipped: DeepViewConfig = serde_json::from_slice(SHIPPED_CONFIG).unwrap();
    // Within the config's limits but far more than the file holds: refused by the parameter count;
    // beyond the limits (2^63 update nets): refused by the config's validation.
    for (config, needles) in [
        (
            DeepViewConfig {
                features_large: 1024,
                ..shipped.clone()
            },
            [WEIGHTS_FILE, "parameters"],
        ),
        (
            DeepViewConfig {
                updates: 1 << 63,
                ..shipped.clone()
            },
            [CONFIG_FILE, "updates"],
        ),
    ] {
        let text = serde_json::to_vec(&config).unwrap();
        std::fs::write(dir.path().join(CONFIG_FILE), text).unwrap();
        let e = load_model(dir.path(), &Device::flex())
            .unwrap_err()
            .to_string();
        assert!(needles.iter().all(|n| e.contains(n)), "{e}");
    }
}
