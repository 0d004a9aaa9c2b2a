//! The learned-gradient-descent network of DeepView (Flynn et al., CVPR 2019) on burn: the differentiable
//! forward model ([`forward`]), the network and its presets ([`network`], [`config`]), weights I/O
//! ([`weights`]) and tiled inference ([`infer`]); training lives in [`train`], [`vgg`] and [`loss`].

pub mod config;
pub mod forward;
pub mod network;

pub mod loss;
pub mod train;
pub mod vgg;
