//! The learned-gradient-descent network of DeepView (Flynn et al., CVPR 2019) on burn: the differentiable
//! forward model ([`forward`]), the network and its presets ([`network`], [`config`]), weights I/O
//! ([`weights`]), devices by name ([`device`]), inference ([`infer`]), the CPU kernels ([`kernels`]) and the whole-image CPU
//! engine ([`engine`]). Training (the loss, VGG, the trainer) is the `deepview-train` crate.

pub mod config;
pub mod device;
pub mod engine;
pub mod forward;
pub mod fused;
pub mod grow;
pub mod infer;
pub mod kernels;
pub mod network;
pub mod renderops;
pub mod weights;

/// burn, re-exported so dependants use the same version (e.g. `deepview_net::burn::tensor::Device::flex()`).
pub use burn;
