//! SSIM (Wang et al. 2004) with a Gaussian window, as the Spaces / DeepView evaluation computes it.
//!
//! Per channel, with `G` the normalised 11x11 Gaussian (sigma 1.5) and `*` 'valid' filtering:
//! `mu_x = G*x`, `s_x = G*(x x) - mu_x^2`, `s_xy = G*(x y) - mu_x mu_y` (population covariance, no
//! `N/(N-1)` factor), `S = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x + s_y + C2))` with
//! `C1 = (K1 L)^2`, `C2 = (K2 L)^2`; the score is the mean of `S` over the valid window positions, then the mean
//! over R, G, B.
//!
//! Which implementation this matches: the Spaces protocol uses scikit-image's `compare_ssim` with
//! `gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1`. scikit-image filters with
//! `scipy.ndimage.gaussian_filter` (truncate 3.5, so radius `int(3.5 * 1.5 + 0.5) = 5`, an 11-tap kernel) in
//! 'reflect' mode and then drops `(11 - 1) / 2 = 5` pixels on every side before averaging, which leaves exactly
//! the window positions that lie inside the image: 'valid' filtering. TF's `tf.image.ssim` (what DeepView was
//! trained with) uses the same 11-tap kernel `exp(-k^2 / (2 sigma^2))`, k = -5..5, normalised, 'VALID' padding,
//! population covariance and K1 0.01 / K2 0.03, so both give the same number up to float rounding; we follow
//! scikit-image's float64 arithmetic (old `compare_ssim` converted to float64).

use crate::{MetricsError, check_sizes};
use deepview_image::ImageF32;
use rayon::prelude::*;

/// SSIM parameters; `Default` is the Spaces protocol.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SsimOptions {
    /// Standard deviation of the Gaussian window, pixels.
    pub sigma: f64,
    /// Window radius: the window is `2 radius + 1` pixels wide (5 -> 11x11; scikit-image: `int(3.5 sigma + 0.5)`).
    pub radius: usize,
    pub k1: f64,
    pub k2: f64,
    /// Dynamic range of the values (1 for images in 0..1).
    pub data_range: f64,
}

impl Default for SsimOptions {
    fn default() -> Self {
        Self {
            sigma: 1.5,
            radius: 5,
            k1: 0.01,
            k2: 0.03,
            data_range: 1.0,
        }
    }
}

impl SsimOptions {
    fn validate(&self) -> Result<(), MetricsError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !(ok(self.sigma) && ok(self.k1) && ok(self.k2) && ok(self.data_range)) {
            return Err(MetricsError::BadOptions(format!(
                "{self:?}: sigma, K1, K2 and data range must be positive"
            )));
        }
        Ok(())
    }

    pub fn window_size(&self) -> usize {
        2 * self.radius + 1
    }
}

/// The normalised 1-D Gaussian taps `exp(-k^2 / (2 sigma^2))`, `k = -radius..=radius`, summing to 1.
pub fn gaussian_window(sigma: f64, radius: usize) -> Vec<f64> {
    let r = radius as f64;
    let taps: Vec<f64> = (0..2 * radius + 1)
        .map(|i| {
            let k = i as f64 - r;
            (-0.5 * k * k / (sigma * sigma)).exp()
        })
        .collect();
    let sum: f64 = taps.iter().sum();
    taps.into_iter().map(|t| t / sum).collect()
}

/// SSIM of two images with the Spaces protocol settings, mean over R, G, B (see the module docs).
///
/// Images must have the same size; with 3 or more channels the first three are compared (alpha ignored),
/// otherwise the channel counts must be equal. Crop borders first with [`crate::crop_border`].
pub fn ssim(a: &ImageF32, b: &ImageF32) -> Result<f64, MetricsError> {
    ssim_with(a, b, &SsimOptions::default())
}

/// [`ssim`] with explicit options.
pub fn ssim_with(a: &ImageF32, b: &ImageF32, options: &SsimOptions) -> Result<f64, MetricsError> {
    let per = ssim_per_channel(a, b, options)?;
    Ok(per.iter().sum::<f64>() / per.len() as f64)
}

/// The SSIM of each compared channel.
pub fn ssim_per_channel(
    a: &ImageF32,
    b: &ImageF32,
    options: &SsimOptions,
) -> Result<Vec<f64>, MetricsError> {
    let n = check_sizes(a, b)?;
    options.validate()?;
    let win = options.window_size();
    if (a.width as usize) < win || (a.height as usize) < win {
        return Err(MetricsError::TooSmall(a.width, a.height, win));
    }
    let g = gaussian_window(options.sigma, options.radius);
    Ok((0..n)
        .into_par_iter()
        .map(|c| channel_ssim(a, b, c, &g, options))
        .collect())
}

/// Mean SSIM of channel `c`: a horizontal then a vertical 'valid' pass over the five moments
/// `[x, y, x x, y y, x y]`, rows in parallel.
fn channel_ssim(a: &ImageF32, b: &ImageF32, c: usize, g: &[f64], o: &SsimOptions) -> f64 {
    let (w, h) = (a.width as usize, a.height as usize);
    let taps = g.len();
    let ow = w + 1 - taps;
    let oh = h + 1 - taps;
    let (ca, cb) = (a.channels, b.channels);

    // Horizontal pass: [h][ow] moments.
    let mut horiz = vec![[0.0f64; 5]; ow * h];
    horiz.par_chunks_mut(ow).enumerate().for_each(|(y, out)| {
        let row_a: Vec<f64> = (0..w)
            .map(|x| a.data[(y * w + x) * ca + c] as f64)
            .collect();
        let row_b: Vec<f64> = (0..w)
            .map(|x| b.data[(y * w + x) * cb + c] as f64)
            .collect();
        for (x, m) in out.iter_mut().enumerate() {
            let mut s = [0.0f64; 5];
            for (k, &gk) in g.iter().enumerate() {
                let (p, q) = (row_a[x + k], row_b[x + k]);
                s[0] += gk * p;
                s[1] += gk * q;
                s[2] += gk * p * p;
                s[3] += gk * q * q;
                s[4] += gk * p * q;
            }
            *m = s;
        }
    });

    let c1 = (o.k1 * o.data_range).powi(2);
    let c2 = (o.k2 * o.data_range).powi(2);
    // Vertical pass fused with the SSIM formula; sum per output row, the rows summed in order (a parallel
    // reduction's order depends on work stealing: scores would differ in the last digit between runs).
    let rows: Vec<f64> = (0..oh)
        .into_par_iter()
        .map(|y| {
            let mut row_sum = 0.0f64;
            for x in 0..ow {
                let mut s = [0.0f64; 5];
                for (k, &gk) in g.iter().enumerate() {
                    let m = &horiz[(y + k) * ow + x];
                    for i in 0..5 {
                        s[i] += gk * m[i];
                    }
                }
                let [ux, uy, uxx, uyy, uxy] = s;
                let vx = uxx - ux * ux;
                let vy = uyy - uy * uy;
                let vxy = uxy - ux * uy;
                let num = (2.0 * ux * uy + c1) * (2.0 * vxy + c2);
                let den = (ux * ux + uy * uy + c1) * (vx + vy + c2);
                row_sum += num / den;
            }
            row_sum
        })
        .collect();
    rows.iter().sum::<f64>() / (ow * oh) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(w: u32, h: u32, ch: usize, seed: u32) -> ImageF32 {
        let mut img = ImageF32::new(w, h, ch);
        for y in 0..h {
            for x in 0..w {
                for c in 0..ch {
                    let v = (x * x * 7 + y * 13 + c as u32 * 29 + x * y * 3 + seed * 101) % 251;
                    img.pixel_mut(x, y)[c] = v as f32 / 250.0;
                }
            }
        }
        img
    }

    #[test]
    fn window_matches_scipy_taps() {
        let g = gaussian_window(1.5, 5);
        assert_eq!(g.len(), 11);
        assert!((g.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        // scipy.ndimage._gaussian_kernel1d(1.5, 0, 5) centre and end taps.
        assert!((g[5] - 0.26601172486179436).abs() < 1e-15, "{}", g[5]);
        assert!((g[0] - 0.00102838008447911).abs() < 1e-15, "{}", g[0]);
    }

    #[test]
    fn identical_images_score_one() {
        let a = pattern(31, 19, 3, 0);
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
        // Constant images too (both variances 0; the constants keep it defined).
        let k = ImageF32::from_data(12, 12, 3, vec![0.3; 432]).unwrap();
        assert!((ssim(&k, &k).unwrap() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn constant_images_have_analytic_ssim() {
        // Constant a, b: S = (2ab + C1) / (a^2 + b^2 + C1) everywhere (the contrast term is C2 / C2).
        let (va, vb) = (0.25f32, 0.75f32);
        let a = ImageF32::from_data(11, 13, 3, vec![va; 11 * 13 * 3]).unwrap();
        let b = ImageF32::from_data(11, 13, 3, vec![vb; 11 * 13 * 3]).unwrap();
        let c1 = 1e-4;
        let (x, y) = (va as f64, vb as f64);
        let expected = (2.0 * x * y + c1) / (x * x + y * y + c1);
        assert!((ssim(&a, &b).unwrap() - expected).abs() < 1e-12);
    }

    #[test]
    fn symmetric_and_alpha_ignored() {
        let a = pattern(20, 17, 4, 0);
        let b = pattern(20, 17, 3, 1);
        let s = ssim(&a, &b).unwrap();
        assert!((s - ssim(&b, &a).unwrap()).abs() < 1e-14);
        assert!((s - ssim(&a.to_rgb(), &b).unwrap()).abs() < 1e-14);
        assert!(s < 0.5);
    }

    #[test]
    fn errors() {
        let a = pattern(10, 20, 3, 0);
        assert_eq!(ssim(&a, &a), Err(MetricsError::TooSmall(10, 20, 11)));
        let b = pattern(12, 12, 3, 0);
        assert!(matches!(
            ssim(&b, &pattern(12, 13, 3, 0)),
            Err(MetricsError::SizeMismatch(..))
        ));
        let bad = SsimOptions {
            sigma: 0.0,
            ..Default::default()
        };
        assert!(matches!(
            ssim_with(&b, &b, &bad),
            Err(MetricsError::BadOptions(_))
        ));
    }
}
