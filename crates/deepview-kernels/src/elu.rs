//! `exp(x) - 1` for the ELU, accurate near 0 (no cancellation) and shared by both kernel paths.

/// `exp(x) - 1` for `x <= 0` (inputs below -87 give -1): `x = n ln2 + r`, `|r| <= ln2 / 2`,
/// `expm1(r)` by a degree-7 Taylor polynomial (relative error < 1e-7), then
/// `exp(x) - 1 = 2^n expm1(r) + (2^n - 1)`.
#[inline(always)]
pub fn expm1_neg(x: f32) -> f32 {
    let x = x.max(-87.0);
    let n = (x * std::f32::consts::LOG2_E).round();
    let r = x - n * LN2_HI - n * LN2_LO;
    let q = r * (1.0 + r * (C2 + r * (C3 + r * (C4 + r * (C5 + r * (C6 + r * C7))))));
    let s = (n as i32 + 127).max(0) as u32;
    let p = f32::from_bits(s << 23);
    p * q + (p - 1.0)
}

pub const LN2_HI: f32 = 0.693_145_75;
pub const LN2_LO: f32 = 1.428_606_8e-6;
pub const C2: f32 = 1.0 / 2.0;
pub const C3: f32 = 1.0 / 6.0;
pub const C4: f32 = 1.0 / 24.0;
pub const C5: f32 = 1.0 / 120.0;
pub const C6: f32 = 1.0 / 720.0;
pub const C7: f32 = 1.0 / 5040.0;

#[inline(always)]
pub fn elu(x: f32) -> f32 {
    if x > 0.0 { x } else { expm1_neg(x) }
}

#[cfg(test)]
mod tests {
    #[test]
    fn expm1_matches_f64() {
        let mut worst = 0f64;
        for i in 0..200_000 {
            let x = -(i as f32) * 1e-4 * (1.0 + (i % 7) as f32 * 0.013);
            let got = super::expm1_neg(x) as f64;
            let want = (x as f64).exp_m1();
            let err = (got - want).abs() / want.abs().max(1e-30);
            if x != 0.0 {
                worst = worst.max(err);
            }
        }
        assert!(worst < 4e-7, "relative error {worst}");
        assert_eq!(super::expm1_neg(-200.0), -1.0);
        assert_eq!(super::expm1_neg(0.0), 0.0);
    }
}
