//! SSIM and PSNR against numbers printed by `tests/reference/ssim_reference.py` (scikit-image's
//! `structural_similarity` with the Spaces settings, cross-checked there by a direct 2-D window sum).
//! The images are defined by the same formulas on both sides.

use deepview_image::ImageF32;
use deepview_metrics::{crop_border, psnr, ssim};

type Formula = fn(u32, u32, u32) -> f64;
/// (name, a, b, width, height, channels, crop [left, top, right, bottom])
type Case = (&'static str, Formula, Formula, u32, u32, usize, [u32; 4]);

fn hash_a(x: u32, y: u32, c: u32) -> f64 {
    ((x * x * 7 + y * 13 + c * 29 + x * y * 3) % 251) as f64 / 250.0
}

fn hash_b(x: u32, y: u32, c: u32) -> f64 {
    ((x * 5 + y * y * 11 + c * 17 + x * y) % 241) as f64 / 240.0
}

fn smooth(x: u32, y: u32, c: u32) -> f64 {
    let (x, y, c) = (x as f64, y as f64, c as f64);
    0.5 + 0.35 * (0.31 * x + 0.17 * y + 0.9 * c).sin() * (0.23 * y - 0.13 * x + 0.4 * c).cos()
}

fn noisy(x: u32, y: u32, c: u32) -> f64 {
    let n = ((x * 31 + y * 17 + c * 7) % 13) as f64 - 6.0;
    (smooth(x, y, c) + 0.04 * n / 6.0).clamp(0.0, 1.0)
}

fn shifted(x: u32, y: u32, c: u32) -> f64 {
    smooth(x + 1, y, c)
}

fn make(f: Formula, w: u32, h: u32, ch: usize) -> ImageF32 {
    let mut img = ImageF32::new(w, h, ch);
    for y in 0..h {
        for x in 0..w {
            for c in 0..ch {
                img.pixel_mut(x, y)[c] = f(x, y, c as u32) as f32;
            }
        }
    }
    img
}

fn cases() -> Vec<Case> {
    vec![
        ("hash", hash_a, hash_b, 37, 23, 3, [0, 0, 0, 0]),
        ("smooth_noisy", smooth, noisy, 40, 29, 3, [0, 0, 0, 0]),
        ("smooth_shifted", smooth, shifted, 64, 48, 3, [0, 0, 0, 0]),
        (
            "smooth_noisy_cropped",
            smooth,
            noisy,
            40,
            29,
            3,
            [3, 2, 5, 1],
        ),
        (
            "hash_grey_min_size",
            hash_a,
            hash_b,
            12,
            11,
            1,
            [0, 0, 0, 0],
        ),
    ]
}

/// Printed by `ssim_reference.py` (scikit-image 0.26.0, numpy 2.4.6): (name, SSIM, PSNR dB).
const EXPECTED: [(&str, f64, f64); 5] = [
    ("hash", -0.026720742034, 7.832289499575),
    ("smooth_noisy", 0.969228460969, 32.060990668515),
    ("smooth_shifted", 0.927944644145, 24.646785099771),
    ("smooth_noisy_cropped", 0.969700358763, 32.060544885688),
    ("hash_grey_min_size", -0.058771262746, 8.320526525973),
];

#[test]
fn ssim_and_psnr_match_scikit_image() {
    for ((name, fa, fb, w, h, ch, [l, t, r, b]), (ename, essim, epsnr)) in
        cases().into_iter().zip(EXPECTED)
    {
        assert_eq!(name, ename);
        let a = crop_border(&make(fa, w, h, ch), l, t, r, b).unwrap();
        let bb = crop_border(&make(fb, w, h, ch), l, t, r, b).unwrap();
        let s = ssim(&a, &bb).unwrap();
        let p = psnr(&a, &bb).unwrap();
        assert!(
            (s - essim).abs() < 1e-9,
            "{name}: ssim {s} vs reference {essim}"
        );
        assert!(
            (p - epsnr).abs() < 1e-9,
            "{name}: psnr {p} vs reference {epsnr}"
        );
    }
}
