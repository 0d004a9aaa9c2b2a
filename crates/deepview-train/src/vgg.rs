//! Frozen VGG-16 feature extractor (conv1_1 .. conv3_3) for the training loss.
//!
//! Weights: `vgg16_conv1_1-conv3_3.safetensors` (`scripts/get_vgg16.sh` makes it): float32 tensors
//! `convX_Y.weight` in OIHW layout (burn's `Conv2d` layout too) and `convX_Y.bias`. The file is parsed here
//! directly (8-byte little-endian header length, JSON header, raw data) so every failure names the file and
//! what is wrong with it.
//!
//! Preprocessing (Caffe): RGB -> BGR, values * 255, minus the mean `[103.939, 116.779, 123.68]` (B, G, R).
//! Padding 1, stride 1, ReLU after every conv, 2x2 max-pool (stride 2) between blocks.
//!
//! The parameters never receive gradients (`no_grad`), but gradients do flow through the network to its
//! input, which is what the feature loss needs.

use burn::module::{Module, Param};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::tensor::{Device, Tensor, TensorData};
use deepview_kernels::Act;
use deepview_net::cpu::ops::conv3x3_act;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// File name of the weights inside the data folder's `vgg16/` directory.
pub const VGG_FILE: &str = "vgg16_conv1_1-conv3_3.safetensors";

/// Caffe mean in BGR order, on the 0..255 scale.
pub const CAFFE_MEAN_BGR: [f32; 3] = [103.939, 116.779, 123.68];

/// The layers in order: (name, in channels, out channels).
pub const LAYERS: [(&str, usize, usize); 7] = [
    ("conv1_1", 3, 64),
    ("conv1_2", 64, 64),
    ("conv2_1", 64, 128),
    ("conv2_2", 128, 128),
    ("conv3_1", 128, 256),
    ("conv3_2", 256, 256),
    ("conv3_3", 256, 256),
];

/// Errors reading the VGG weights; every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum VggError {
    #[error(
        "no VGG-16 weights given: the VGG loss needs vgg16_conv1_1-conv3_3.safetensors \
         (`bash scripts/get_vgg16.sh` makes it from public packages); pass its path with \
         --vgg-weights, or train with --loss l1"
    )]
    NotGiven,
    #[error(
        "cannot read VGG-16 weights {path}: {source} (`bash scripts/get_vgg16.sh` makes them from \
         public packages)"
    )]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("VGG-16 weights {path} are truncated or corrupt: {detail}")]
    Corrupt { path: PathBuf, detail: String },
    #[error("VGG-16 weights {path} lack tensor `{name}`")]
    Missing { path: PathBuf, name: String },
    #[error("VGG-16 weights {path}: tensor `{name}` has {detail}")]
    BadTensor {
        path: PathBuf,
        name: String,
        detail: String,
    },
}

/// Where the tests find the weights: `<data>/vgg16/vgg16_conv1_1-conv3_3.safetensors` in the shared
/// data folder (`DEEPVIEW_DATA`, else the repository's `../shared/data`).
pub fn test_weights_path() -> PathBuf {
    deepview_data::data_dir().join("vgg16").join(VGG_FILE)
}

/// One float32 tensor read from a safetensors file.
#[derive(Clone, Debug)]
pub struct RawTensor {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// Read every float32 tensor of a safetensors file (small files only: it is read whole).
pub fn read_safetensors_f32(path: &Path) -> Result<HashMap<String, RawTensor>, VggError> {
    let bytes = std::fs::read(path).map_err(|source| VggError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_safetensors_f32(&bytes, path)
}

fn parse_safetensors_f32(
    bytes: &[u8],
    path: &Path,
) -> Result<HashMap<String, RawTensor>, VggError> {
    let corrupt = |detail: String| VggError::Corrupt {
        path: path.to_path_buf(),
        detail,
    };
    if bytes.len() < 8 {
        return Err(corrupt(format!(
            "{} bytes, shorter than the 8-byte header length",
            bytes.len()
        )));
    }
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
    if n > bytes.len() - 8 {
        return Err(corrupt(format!(
            "header of {n} bytes but the file has {} bytes",
            bytes.len()
        )));
    }
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n])
        .map_err(|e| corrupt(format!("header is not JSON: {e}")))?;
    let obj = header
        .as_object()
        .ok_or_else(|| corrupt("header is not a JSON object".into()))?;
    let data = &bytes[8 + n..];
    let mut out = HashMap::new();
    for (name, info) in obj {
        if name == "__metadata__" {
            continue;
        }
        let bad = |detail: String| VggError::BadTensor {
            path: path.to_path_buf(),
            name: name.clone(),
            detail,
        };
        let dtype = info.get("dtype").and_then(|v| v.as_str()).unwrap_or("?");
        if dtype != "F32" {
            return Err(bad(format!("dtype {dtype}, expected F32")));
        }
        let shape: Vec<usize> = info
            .get("shape")
            .and_then(|v| v.as_array())
            .map(|a| {
                a.iter()
                    .filter_map(|x| x.as_u64().map(|x| x as usize))
                    .collect()
            })
            .ok_or_else(|| bad("no shape".into()))?;
        let offs: Vec<usize> = info
            .get("data_offsets")
            .and_then(|v| v.as_array())
            .map(|a| {
                a.iter()
                    .filter_map(|x| x.as_u64().map(|x| x as usize))
                    .collect()
            })
            .ok_or_else(|| bad("no data_offsets".into()))?;
        if offs.len() != 2 || offs[0] > offs[1] {
            return Err(bad(format!("bad data_offsets {offs:?}")));
        }
        if offs[1] > data.len() {
            return Err(corrupt(format!(
                "tensor `{name}` ends at byte {} of the data section but it has only {} bytes",
                offs[1],
                data.len()
            )));
        }
        let count: usize = shape.iter().product();
        if offs[1] - offs[0] != count * 4 {
            return Err(bad(format!(
                "{} bytes for shape {shape:?}",
                offs[1] - offs[0]
            )));
        }
        let values = data[offs[0]..offs[1]]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        out.insert(
            name.clone(),
            RawTensor {
                shape,
                data: values,
            },
        );
    }
    Ok(out)
}

/// VGG-16 conv1_1 .. conv3_3, frozen.
#[derive(Module, Debug)]
pub struct Vgg16 {
    conv1_1: Conv2d,
    conv1_2: Conv2d,
    conv2_1: Conv2d,
    conv2_2: Conv2d,
    conv3_1: Conv2d,
    conv3_2: Conv2d,
    conv3_3: Conv2d,
    pool: MaxPool2d,
}

/// The three feature maps the loss uses (each after its ReLU).
pub struct VggFeatures {
    /// conv1_2: [n, 64, h, w]
    pub conv1_2: Tensor<4>,
    /// conv2_2: [n, 128, h/2, w/2]
    pub conv2_2: Tensor<4>,
    /// conv3_3: [n, 256, h/4, w/4]
    pub conv3_3: Tensor<4>,
}

impl Vgg16 {
    /// Load the weights file at `path` onto `device` (parameters frozen).
    pub fn load(path: &Path, device: &Device) -> Result<Self, VggError> {
        let mut tensors = read_safetensors_f32(path)?;
        let mut take = |name: &str, cin: usize, cout: usize| -> Result<Conv2d, VggError> {
            let mut get = |key: String, shape: Vec<usize>| -> Result<RawTensor, VggError> {
                let t = tensors.remove(&key).ok_or_else(|| VggError::Missing {
                    path: path.into(),
                    name: key.clone(),
                })?;
                if t.shape != shape {
                    return Err(VggError::BadTensor {
                        path: path.into(),
                        name: key,
                        detail: format!("shape {:?}, expected {shape:?}", t.shape),
                    });
                }
                if !t.data.iter().all(|v| v.is_finite()) {
                    return Err(VggError::BadTensor {
                        path: path.into(),
                        name: key,
                        detail: "non-finite values".into(),
                    });
                }
                Ok(t)
            };
            let w = get(format!("{name}.weight"), vec![cout, cin, 3, 3])?;
            let b = get(format!("{name}.bias"), vec![cout])?;
            let mut conv = Conv2dConfig::new([cin, cout], [3, 3])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(device);
            conv.weight = Param::from_tensor(Tensor::<4>::from_data(
                TensorData::new(w.data, w.shape),
                device,
            ));
            conv.bias = Some(Param::from_tensor(Tensor::<1>::from_data(
                TensorData::new(b.data, b.shape),
                device,
            )));
            Ok(conv)
        };
        let vgg = Vgg16 {
            conv1_1: take("conv1_1", 3, 64)?,
            conv1_2: take("conv1_2", 64, 64)?,
            conv2_1: take("conv2_1", 64, 128)?,
            conv2_2: take("conv2_2", 128, 128)?,
            conv3_1: take("conv3_1", 128, 256)?,
            conv3_2: take("conv3_2", 256, 256)?,
            conv3_3: take("conv3_3", 256, 256)?,
            pool: MaxPool2dConfig::new([2, 2]).with_strides([2, 2]).init(),
        };
        Ok(deepview_net::device::weights_layout(vgg.no_grad()))
    }

    /// Caffe preprocessing of `rgb` ([n, 3, h, w], RGB in 0..1): BGR, * 255, minus the mean.
    pub fn preprocess(rgb: Tensor<4>) -> Tensor<4> {
        let device = rgb.device();
        let [r, g, b] = [0, 1, 2].map(|c| rgb.clone().narrow(1, c, 1));
        let bgr = Tensor::cat(vec![b, g, r], 1) * 255.0;
        let mean = Tensor::<1>::from_floats(CAFFE_MEAN_BGR, &device).reshape([1, 3, 1, 1]);
        bgr - mean
    }

    /// Features of `rgb` ([n, 3, h, w], RGB in 0..1; h and w multiples of 4).
    pub fn features(&self, rgb: Tensor<4>) -> VggFeatures {
        self.features_preprocessed(Self::preprocess(rgb))
    }

    /// Features of an input already preprocessed ([`Vgg16::preprocess`]).
    pub fn features_preprocessed(&self, x: Tensor<4>) -> VggFeatures {
        let x = conv3x3_act(x, &self.conv1_1, Act::Relu);
        let conv1_2 = conv3x3_act(x, &self.conv1_2, Act::Relu);
        let x = self.pool.forward(conv1_2.clone());
        let x = conv3x3_act(x, &self.conv2_1, Act::Relu);
        let conv2_2 = conv3x3_act(x, &self.conv2_2, Act::Relu);
        let x = self.pool.forward(conv2_2.clone());
        let x = conv3x3_act(x, &self.conv3_1, Act::Relu);
        let x = conv3x3_act(x, &self.conv3_2, Act::Relu);
        let conv3_3 = conv3x3_act(x, &self.conv3_3, Act::Relu);
        VggFeatures {
            conv1_2,
            conv2_2,
            conv3_3,
        }
    }

    /// conv1_1 after ReLU (for tests).
    pub fn conv1_1(&self, rgb: Tensor<4>) -> Tensor<4> {
        conv3x3_act(Self::preprocess(rgb), &self.conv1_1, Act::Relu)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn weights() -> Option<PathBuf> {
        let p = test_weights_path();
        if p.exists() {
            Some(p)
        } else {
            eprintln!(
                "SKIP: VGG weights not found at {} (set DEEPVIEW_DATA)",
                p.display()
            );
            None
        }
    }

    /// conv1_1 at a few pixels, computed by a scalar loop straight from the file's bytes.
    #[test]
    fn conv1_1_matches_scalar_loop() {
        let Some(path) = weights() else { return };
        let bytes = std::fs::read(&path).unwrap();
        // Independent parse of the header: find conv1_1.weight/bias offsets by hand.
        let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
        let read = |name: &str| -> Vec<f32> {
            let o = header[name]["data_offsets"].as_array().unwrap();
            let (a, b) = (
                o[0].as_u64().unwrap() as usize,
                o[1].as_u64().unwrap() as usize,
            );
            bytes[8 + n + a..8 + n + b]
                .chunks(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
                .collect()
        };
        let (w, bias) = (read("conv1_1.weight"), read("conv1_1.bias"));
        let (h, wd) = (7usize, 9usize);
        let img: Vec<f32> = (0..3 * h * wd)
            .map(|i| ((i * 37 % 101) as f32) / 100.0)
            .collect(); // CHW, RGB
        let device = Device::flex();
        let vgg = Vgg16::load(&path, &device).unwrap();
        let x = Tensor::<4>::from_data(TensorData::new(img.clone(), [1, 3, h, wd]), &device);
        let out = vgg.conv1_1(x).into_data().try_to_vec::<f32>().unwrap();
        let mean = CAFFE_MEAN_BGR;
        for &(oy, ox, oc) in &[(0usize, 0usize, 0usize), (3, 4, 17), (6, 8, 63), (2, 0, 5)] {
            let mut acc = bias[oc] as f64;
            for ic in 0..3 {
                // Input channel ic of the network is BGR: B = RGB channel 2.
                let src = 2 - ic;
                for ky in 0..3 {
                    for kx in 0..3 {
                        let (y, x) = (oy as i64 + ky as i64 - 1, ox as i64 + kx as i64 - 1);
                        if y < 0 || x < 0 || y >= h as i64 || x >= wd as i64 {
                            continue;
                        }
                        let v = img[src * h * wd + y as usize * wd + x as usize] as f64 * 255.0
                            - mean[ic] as f64;
                        acc += w[((oc * 3 + ic) * 3 + ky) * 3 + kx] as f64 * v;
                    }
                }
            }
            let expect = acc.max(0.0);
            let got = out[oc * h * wd + oy * wd + ox] as f64;
            assert!(
                (got - expect).abs() < 1e-3 * (1.0 + expect.abs()),
                "({oy},{ox},{oc}): {got} vs {expect}"
            );
        }
    }

    #[test]
    fn feature_shapes_and_frozen() {
        let Some(path) = weights() else { return };
        let device = Device::flex().autodiff();
        let vgg = Vgg16::load(&path, &device).unwrap();
        let f = vgg.features(Tensor::<4>::zeros([2, 3, 40, 40], &device));
        assert_eq!(f.conv1_2.dims(), [2, 64, 40, 40]);
        assert_eq!(f.conv2_2.dims(), [2, 128, 20, 20]);
        assert_eq!(f.conv3_3.dims(), [2, 256, 10, 10]);
        assert_eq!(vgg.num_params(), 1_735_488);
    }

    #[test]
    fn errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("nope.safetensors");
        let e = Vgg16::load(&missing, &Device::flex())
            .unwrap_err()
            .to_string();
        assert!(e.contains("nope.safetensors"), "{e}");
        let Some(path) = weights() else { return };
        let bytes = std::fs::read(&path).unwrap();
        let cut = dir.path().join("cut.safetensors");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let e = Vgg16::load(&cut, &Device::flex()).unwrap_err();
        assert!(matches!(e, VggError::Corrupt { .. }), "{e}");
        assert!(e.to_string().contains("cut.safetensors"), "{e}");
        std::fs::write(&cut, &bytes[..5]).unwrap();
        assert!(matches!(
            Vgg16::load(&cut, &Device::flex()).unwrap_err(),
            VggError::Corrupt { .. }
        ));
    }
}
