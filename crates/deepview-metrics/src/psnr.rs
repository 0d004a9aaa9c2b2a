//! Mean squared error and PSNR over the compared channels (RGB).

use crate::{MetricsError, check_sizes};
use deepview_image::ImageF32;
use rayon::prelude::*;

/// Mean squared error over all pixels and the compared channels (RGB; see [`crate::ssim`]), in f64.
pub fn mse(a: &ImageF32, b: &ImageF32) -> Result<f64, MetricsError> {
    let n = check_sizes(a, b)?;
    let (ca, cb) = (a.channels, b.channels);
    // Chunk sums in parallel, added in order (deterministic, unlike a parallel reduction).
    let chunks: Vec<f64> = a
        .data
        .par_chunks(ca * 4096)
        .zip(b.data.par_chunks(cb * 4096))
        .map(|(pa, pb)| {
            let mut s = 0.0f64;
            for (x, y) in pa.chunks_exact(ca).zip(pb.chunks_exact(cb)) {
                for c in 0..n {
                    let d = x[c] as f64 - y[c] as f64;
                    s += d * d;
                }
            }
            s
        })
        .collect();
    let sum: f64 = chunks.iter().sum();
    Ok(sum / (a.width as f64 * a.height as f64 * n as f64))
}

/// PSNR in dB for data range 1: `10 log10(1 / mse)`; `f64::INFINITY` for identical images.
pub fn psnr(a: &ImageF32, b: &ImageF32) -> Result<f64, MetricsError> {
    let m = mse(a, b)?;
    Ok(if m == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * m.log10()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_of_a_constant_offset() {
        // Every RGB value off by 0.1: mse = 0.01, psnr = 20 dB exactly; alpha is ignored.
        let a =
            ImageF32::from_data(5, 4, 4, (0..80).map(|i| (i % 7) as f32 / 10.0).collect()).unwrap();
        let mut b = a.clone();
        for (i, v) in b.data.iter_mut().enumerate() {
            *v = if i % 4 == 3 { 0.0 } else { *v + 0.1 };
        }
        let p = psnr(&a, &b).unwrap();
        assert!((p - 20.0).abs() < 1e-5, "{p}");
        assert_eq!(psnr(&a, &a).unwrap(), f64::INFINITY);
    }

    #[test]
    fn mismatches_are_errors() {
        let a = ImageF32::new(4, 4, 3);
        assert_eq!(
            mse(&a, &ImageF32::new(4, 5, 3)),
            Err(MetricsError::SizeMismatch(4, 4, 4, 5))
        );
        assert_eq!(
            mse(&a, &ImageF32::new(4, 4, 1)),
            Err(MetricsError::ChannelMismatch(3, 1))
        );
        assert_eq!(
            mse(&ImageF32::new(0, 4, 3), &ImageF32::new(0, 4, 3)),
            Err(MetricsError::Empty)
        );
    }
}
