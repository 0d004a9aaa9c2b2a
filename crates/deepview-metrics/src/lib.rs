//! Image quality metrics for view synthesis: SSIM exactly as the Spaces evaluation computes it, PSNR, and
//! the border cropping and 8-bit quantisation that come before them.
//!
//! The Spaces protocol (`code/compute_metrics.py` of the Spaces dataset release, used for the DeepView paper's
//! tables) calls scikit-image's `compare_ssim(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
//! data_range=1.0)` on each of R, G, B of 8-bit PNGs divided by 255, after cropping the borders, and averages
//! the three scores. [`ssim`] reproduces that computation (see [`ssim`] for why it also equals TF's
//! `tf.image.ssim`); `tests/reference/ssim_reference.py` checks it against scikit-image itself.

mod crop;
mod psnr;
mod ssim;

pub use crop::{BorderCrop, crop_border, quantize_u8};
pub use psnr::{mse, psnr};
pub use ssim::{SsimOptions, gaussian_window, ssim, ssim_per_channel, ssim_with};

/// Errors of metric inputs; messages name the problem and the sizes involved.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MetricsError {
    #[error("image sizes differ: {0}x{1} vs {2}x{3}")]
    SizeMismatch(u32, u32, u32, u32),
    #[error("channel counts are incompatible: {0} vs {1} (need both >= 3, or equal)")]
    ChannelMismatch(usize, usize),
    #[error("image {0}x{1} is smaller than the {2}x{2} SSIM window")]
    TooSmall(u32, u32, usize),
    #[error(
        "border crop (left {left}, top {top}, right {right}, bottom {bottom}) leaves nothing of a {width}x{height} image"
    )]
    CropTooLarge {
        left: u32,
        top: u32,
        right: u32,
        bottom: u32,
        width: u32,
        height: u32,
    },
    #[error("image has no pixels")]
    Empty,
    #[error("invalid SSIM options: {0}")]
    BadOptions(String),
}

/// How many leading channels two images are compared on: RGB (3) when both have at least three channels
/// (alpha or validity channels are ignored), otherwise all of them when the counts agree (grey images).
pub(crate) fn compared_channels(a: usize, b: usize) -> Result<usize, MetricsError> {
    if a >= 3 && b >= 3 {
        Ok(3)
    } else if a == b && a > 0 {
        Ok(a)
    } else {
        Err(MetricsError::ChannelMismatch(a, b))
    }
}

pub(crate) fn check_sizes(
    a: &deepview_image::ImageF32,
    b: &deepview_image::ImageF32,
) -> Result<usize, MetricsError> {
    if a.width != b.width || a.height != b.height {
        return Err(MetricsError::SizeMismatch(
            a.width, a.height, b.width, b.height,
        ));
    }
    if a.width == 0 || a.height == 0 {
        return Err(MetricsError::Empty);
    }
    compared_channels(a.channels, b.channels)
}
