#!/usr/bin/env python3
"""Reference SSIM / PSNR numbers for crates/deepview-metrics/tests/reference_values.rs.

Run once by hand to (re)generate the fixture numbers; CI does not run it:

    python3 -m venv /tmp/ssimref && /tmp/ssimref/bin/pip install numpy scikit-image
    /tmp/ssimref/bin/python crates/deepview-metrics/tests/reference/ssim_reference.py

The test images are defined by formulas that the Rust test implements identically (values computed in float64,
stored as float32 like `ImageF32`, then scored in float64). Two independent computations are printed:
  * `direct`: this file's own SSIM, a full 2-D 11x11 window sum at every valid position (no separable filter);
  * `skimage`: scikit-image's `structural_similarity(gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1.0)` per channel, mean over channels -- the call the Spaces
    protocol (`compute_metrics.py`) makes through the older name `compare_ssim`.
The script asserts that both agree to 1e-9 and prints the skimage value as the fixture.
"""

import math

import numpy as np

try:
    from skimage.metrics import structural_similarity
except ImportError:  # pragma: no cover
    structural_similarity = None


def hash_a(x, y, c):
    return ((x * x * 7 + y * 13 + c * 29 + x * y * 3) % 251) / 250.0


def hash_b(x, y, c):
    return ((x * 5 + y * y * 11 + c * 17 + x * y) % 241) / 240.0


def smooth(x, y, c):
    return 0.5 + 0.35 * math.sin(0.31 * x + 0.17 * y + 0.9 * c) * math.cos(0.23 * y - 0.13 * x + 0.4 * c)


def noisy(x, y, c):
    v = smooth(x, y, c) + 0.04 * (((x * 31 + y * 17 + c * 7) % 13) - 6) / 6.0
    return min(max(v, 0.0), 1.0)


def shifted(x, y, c):
    return smooth(x + 1, y, c)


def make(f, w, h, ch):
    img = np.zeros((h, w, ch), dtype=np.float64)
    for y in range(h):
        for x in range(w):
            for c in range(ch):
                img[y, x, c] = f(x, y, c)
    return img.astype(np.float32).astype(np.float64)


def direct_ssim_channel(x, y):
    r = 5
    k = np.array([math.exp(-0.5 * (i - r) ** 2 / 1.5 ** 2) for i in range(2 * r + 1)])
    k /= k.sum()
    win = np.outer(k, k)
    c1, c2 = (0.01 * 1.0) ** 2, (0.03 * 1.0) ** 2
    h, w = x.shape
    vals = []
    for j in range(h - 2 * r):
        for i in range(w - 2 * r):
            px = x[j:j + 2 * r + 1, i:i + 2 * r + 1]
            py = y[j:j + 2 * r + 1, i:i + 2 * r + 1]
            mx, my = (win * px).sum(), (win * py).sum()
            vx = (win * (px - mx) ** 2).sum()
            vy = (win * (py - my) ** 2).sum()
            vxy = (win * (px - mx) * (py - my)).sum()
            vals.append((2 * mx * my + c1) * (2 * vxy + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2)))
    return float(np.mean(vals))


def scores(a, b):
    ch = a.shape[2]
    direct = sum(direct_ssim_channel(a[..., c], b[..., c]) for c in range(ch)) / ch
    sk = None
    if structural_similarity is not None:
        sk = sum(
            structural_similarity(a[..., c], b[..., c], gaussian_weights=True, sigma=1.5,
                                  use_sample_covariance=False, data_range=1.0)
            for c in range(ch)) / ch
    mse = float(np.mean((a - b) ** 2))
    return direct, sk, -10.0 * math.log10(mse)


CASES = [
    # name, fa, fb, width, height, channels, crop (left, top, right, bottom)
    ("hash", hash_a, hash_b, 37, 23, 3, (0, 0, 0, 0)),
    ("smooth_noisy", smooth, noisy, 40, 29, 3, (0, 0, 0, 0)),
    ("smooth_shifted", smooth, shifted, 64, 48, 3, (0, 0, 0, 0)),
    ("smooth_noisy_cropped", smooth, noisy, 40, 29, 3, (3, 2, 5, 1)),
    ("hash_grey_min_size", hash_a, hash_b, 12, 11, 1, (0, 0, 0, 0)),
]

if __name__ == "__main__":
    for name, fa, fb, w, h, ch, (l, t, r, bt) in CASES:
        a, b = make(fa, w, h, ch), make(fb, w, h, ch)
        a = a[t:h - bt, l:w - r]
        b = b[t:h - bt, l:w - r]
        direct, sk, p = scores(a, b)
        if sk is not None:
            assert abs(direct - sk) < 1e-9, (name, direct, sk)
        ref = sk if sk is not None else direct
        print(f'("{name}", {ref:.12f}, {p:.12f}),  // direct {direct:.12f} skimage {sk}')
