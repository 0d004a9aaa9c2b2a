//! Branch-free `exp`, `ln`, sigmoid and logit of `f32` that the compiler vectorises (no libm calls), and
//! [`with_simd`] to compile a loop over them for the machine's widest vectors.
//!
//! Accuracy: `exp` and `ln` are within a few units in the last place of the f64 results over the
//! ranges the network uses (tests below); `exp` is 0 below -87.3 (where f32's normal range ends) and
//! `ln` takes positive normal numbers.

/// 2^23 + 2^22: adding it rounds an `f32` of magnitude below 2^22 to the nearest integer (ties to even).
const ROUND: f32 = 12_582_912.0;

/// `e^x`: `x = n ln2 + r`, `|r| <= ln2 / 2`, `e^r` by its degree-7 Taylor polynomial, `2^n` from the
/// exponent field. 0 for `x < -87.3`; `x` above 88.7 gives +inf.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    let xc = x.clamp(-87.3, 88.7);
    let n = (xc * std::f32::consts::LOG2_E + ROUND) - ROUND;
    let r = xc - n * crate::elu::LN2_HI - n * crate::elu::LN2_LO;
    use crate::elu::{C2, C3, C4, C5, C6, C7};
    let q = 1.0 + r * (1.0 + r * (C2 + r * (C3 + r * (C4 + r * (C5 + r * (C6 + r * C7))))));
    let p = f32::from_bits(((n as i32 + 127) as u32) << 23);
    let v = p * q;
    let v = if x > 88.7 { f32::INFINITY } else { v };
    if x < -87.3 { 0.0 } else { v }
}

/// Natural logarithm of a positive normal `x`: `x = 2^e m` with `m` in `[sqrt(1/2), sqrt(2))`, `ln m =
/// 2 atanh(s)`, `s = (m - 1) / (m + 1)`, by its odd series to `s^11` (`|s| <= 0.172`).
#[inline(always)]
pub fn ln(x: f32) -> f32 {
    let bits = x.to_bits() as i32;
    // Shift the mantissa range so that m lands in [sqrt(1/2), sqrt(2)): subtract the bits of sqrt(1/2).
    let k = bits - 0x3f35_04f3;
    let e = k >> 23;
    let m = f32::from_bits((bits - (e << 23)) as u32);
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let poly = 2.0
        + s2 * (2.0 / 3.0
            + s2 * (2.0 / 5.0 + s2 * (2.0 / 7.0 + s2 * (2.0 / 9.0 + s2 * (2.0 / 11.0)))));
    let ln2 = std::f32::consts::LN_2;
    e as f32 * ln2 + s * poly
}

/// `1 / (1 + e^-x)`.
#[inline(always)]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// Run `f` compiled for AVX-512 (or AVX2 + FMA) where the machine has it and the kernels' choice allows
/// it (see [`crate::isa`]), else as is: loops in `f`'s body over the functions of this module become
/// vector loops (`f` is inlined into the feature-enabled function).
#[inline(always)]
pub fn with_simd<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx2,fma")]
        unsafe fn avx512<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        #[target_feature(enable = "avx2,fma")]
        unsafe fn avx2<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        match crate::isa() {
            // SAFETY: the CPU has the features (detected).
            crate::Isa::Avx512 => return unsafe { avx512(f) },
            crate::Isa::Avx2 => return unsafe { avx2(f) },
            crate::Isa::Portable => {}
        }
    }
    f()
}

#[cfg(test)]
mod tests {
    fn ulps(got: f32, want: f64) -> f64 {
        ((got as f64 - want) / (want.abs() * f32::EPSILON as f64).max(1e-300)).abs()
    }

    #[test]
    fn exp_matches_f64() {
        let mut worst = 0f64;
        let mut x = -87.0f32;
        while x < 88.0 {
            worst = worst.max(ulps(super::exp(x), (x as f64).exp()));
            x += 0.001_37;
        }
        assert!(worst < 4.0, "exp: {worst} ulps");
        assert_eq!(super::exp(0.0), 1.0);
        assert_eq!(super::exp(-1e30), 0.0);
        assert_eq!(super::exp(-88.0), 0.0);
        assert_eq!(super::exp(100.0), f32::INFINITY);
    }

    #[test]
    fn ln_matches_f64() {
        let mut worst = 0f64;
        for i in 0..400_000 {
            // Logarithmically spaced over [1e-37, 1e37], and densely around 1 (where ln is near 0:
            // the error is taken relative to max(|ln x|, 2^-20)).
            let x = 10f32.powf(-37.0 + 74.0 * i as f32 / 400_000.0);
            let y = 1.0 + (i as f32 - 200_000.0) * 2e-6;
            for x in [x, y] {
                let want = (x as f64).ln();
                let err = (super::ln(x) as f64 - want).abs() / want.abs().max(2f64.powi(-20));
                worst = worst.max(err / f32::EPSILON as f64);
            }
        }
        assert!(worst < 4.0, "ln: {worst} ulps");
        assert_eq!(super::ln(1.0), 0.0);
    }

    #[test]
    fn sigmoid_matches_f64() {
        for i in -2000..2000 {
            let x = i as f32 * 0.01;
            let want = 1.0 / (1.0 + (-(x as f64)).exp());
            assert!(ulps(super::sigmoid(x), want) < 4.0, "sigmoid({x})");
        }
    }
}
