//! The learned-gradient-descent network of DeepView (Flynn et al., CVPR 2019) on burn: the differentiable
//! forward model ([`forward`]), the network and its presets ([`network`], [`config`]), weights I/O
//! ([`weights`]), devices by name ([`device`]), inference ([`infer`]) and the CPU engine ([`cpu`]: the
//! burn extension ops and their backward ([`cpu::ops`]), the packed net ([`cpu::packed`]), the fused net
//! ([`cpu::fused`]), the render ops ([`cpu::renderops`]) and the whole-image engine ([`cpu::engine`])).
//! Training (the loss, VGG, the trainer) is the `deepview-train` crate.

pub mod config;
pub mod cpu;
pub mod device;
pub mod forward;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod gpu;
pub mod grow;
pub mod infer;
pub mod network;
pub mod rng;
pub mod weights;

/// burn, re-exported so dependants use the same version (e.g. `deepview_net::burn::tensor::Device::flex()`).
pub use burn;
