//! The agreement prior of the first net's input on plain arrays, in two passes: [`prior_stats`] per
//! plane (while the plane's sweeps are in the net's scratch; the mean colour's logits go straight onto
//! the plane's state, [`add_colour_logits`]), then [`prior_logits`] of the depth weights over all
//! planes; the same arithmetic as [`crate::network::agreement_prior_logits`].

use deepview_kernels::Plane;
use deepview_kernels::fastmath;
use deepview_mpi::agreement::{
    LOGIT_EPS as PRIOR_EPS, SINGLE_VIEW_VARIANCE, grey_level, leave_one_out_variance,
};
use rayon::prelude::*;

#[inline(always)]
fn logit(p: f32) -> f32 {
    let p = p.clamp(PRIOR_EPS as f32, 1.0 - PRIOR_EPS as f32);
    fastmath::ln(p / (1.0 - p))
}

/// Pass 1 of the agreement prior (see [`crate::network::agreement_prior_logits`], same arithmetic) on
/// one plane: from the views' plane sweeps `psv` (per view: R, G, B, validity planes of `plane`), the mean
/// colour into `mean` (`[3][H*W]`) and the masked logit of the depth weight into `lg` (`[H*W]`). With
/// `census = (cost, weight)` (`cost`: `[H*W]` from [`census_cost`]) `weight * cost` is added to the
/// variance where two or more views see a pixel. With `leave_one_out = Some(b)` the variance of a pixel
/// three or more views see is first blended with its least leave-one-out variance
/// ([`leave_one_out_variance`]), weight `b`; with `sample_variance` the variance of a pixel `n >= 2`
/// views see is then scaled by `n / (n - 1)`.
pub(crate) fn prior_stats(
    psv: &[&mut [f32]],
    plane: Plane,
    temperature: f64,
    census: Option<(&[f32], f32)>,
    leave_one_out: Option<f32>,
    sample_variance: bool,
    mean: &mut [f32],
    lg: &mut [f32],
) {
    let hw = plane.h * plane.w;
    let w = plane.w;
    let k = psv.len() / 4;
    // Row by row with the columns innermost (vectorised by the compiler); the same operations per
    // pixel, in the same order, as the per-pixel definition.
    let mut count = vec![0f32; w];
    let mut sum = vec![0f32; 3 * w];
    let mut var = vec![0f32; 3 * w];
    // Per column, one view's squared deviation (summed over RGB) and the largest of the views' (the
    // leave-one-out term's).
    let (mut dev, mut max_dev) = (vec![0f32; w], vec![0f32; w]);
    for y in 0..plane.h {
        let i0 = plane.index(y, 0);
        let o0 = y * w;
        count.fill(0.0);
        sum.fill(0.0);
        var.fill(0.0);
        for v in 0..k {
            let m = &psv[4 * v + 3][i0..i0 + w];
            for (c, m) in count.iter_mut().zip(m) {
                *c += m;
            }
            for c in 0..3 {
                let x = &psv[4 * v + c][i0..i0 + w];
                for ((s, &x), &m) in sum[c * w..(c + 1) * w].iter_mut().zip(x).zip(m) {
                    *s += x * m;
                }
            }
        }
        for c in 0..3 {
            let mu = &mut mean[c * hw + o0..c * hw + o0 + w];
            for ((mu, &s), &n) in mu.iter_mut().zip(&sum[c * w..(c + 1) * w]).zip(&count) {
                *mu = s / n.max(1.0);
            }
        }
        max_dev.fill(0.0);
        for v in 0..k {
            let m = &psv[4 * v + 3][i0..i0 + w];
            dev.fill(0.0);
            for c in 0..3 {
                let x = &psv[4 * v + c][i0..i0 + w];
                let mu = &mean[c * hw + o0..c * hw + o0 + w];
                let q = var[c * w..(c + 1) * w].iter_mut().zip(dev.iter_mut());
                for ((((q, d), &x), &m), &mu) in q.zip(x).zip(m).zip(mu) {
                    let e = x * m - mu * m;
                    *q += e * e;
                    *d += e * e;
                }
            }
            for (a, &d) in max_dev.iter_mut().zip(&dev) {
                *a = a.max(d);
            }
        }
        let t = temperature as f32;
        for (x, l) in lg[o0..o0 + w].iter_mut().enumerate() {
            let n = count[x];
            let denom = n.max(1.0);
            let mut q = (var[x] / denom + var[w + x] / denom + var[2 * w + x] / denom) / 3.0;
            if let Some(b) = leave_one_out.filter(|_| n >= 2.5) {
                let ss = var[x] + var[w + x] + var[2 * w + x];
                let loo = leave_one_out_variance(ss as f64, max_dev[x] as f64, n as f64) as f32;
                q = (1.0 - b) * q + b * loo;
            }
            if sample_variance && n >= 1.5 {
                q *= n / (n - 1.0);
            }
            if let Some((cost, weight)) = census {
                q += weight * cost[o0 + x];
            }
            if n == 1.0 {
                q = SINGLE_VIEW_VARIANCE as f32;
            }
            let seen = if n > 0.5 { 1.0 } else { 0.0 };
            *l = (-q / t) * seen + (1.0 - seen) * -1e30;
        }
    }
}

/// The census cost ([`deepview_mpi::agreement::census_disagreement`]) of one plane's sweeps `psv`
/// (per view: R, G, B, validity planes of `plane`) into `out` (`[H*W]`); `greys` and `bits` are
/// scratch.
pub(crate) fn census_cost(
    psv: &[&mut [f32]],
    plane: Plane,
    radius: usize,
    greys: &mut Vec<f32>,
    bits: &mut deepview_mpi::agreement::CensusScratch,
    out: &mut Vec<f32>,
) {
    let (h, w) = (plane.h, plane.w);
    let hw = h * w;
    let k = psv.len() / 4;
    greys.resize(k * hw, 0.0);
    out.resize(hw, 0.0);
    for (v, g) in greys.chunks_exact_mut(hw.max(1)).enumerate() {
        for y in 0..h {
            let i0 = plane.index(y, 0);
            let row = &mut g[y * w..(y + 1) * w];
            for (x, g) in row.iter_mut().enumerate() {
                let i = i0 + x;
                *g = grey_level(
                    psv[4 * v][i],
                    psv[4 * v + 1][i],
                    psv[4 * v + 2][i],
                    psv[4 * v + 3][i],
                );
            }
        }
    }
    let views: Vec<&[f32]> = greys.chunks_exact(hw.max(1)).take(k).collect();
    deepview_mpi::agreement::census_disagreement(&views, w, h, radius, bits, out);
}

/// The clamped logits of a plane's mean colour (`[3][H*W]` from [`prior_stats`]) added onto its state's
/// first three channels (`st`, `[S][H*W]`).
pub(crate) fn add_colour_logits(mean: &[f32], st: &mut [f32]) {
    fastmath::with_simd(
        #[inline(always)]
        || {
            for (o, &m) in st[..mean.len()].iter_mut().zip(mean) {
                *o += logit(m);
            }
        },
    )
}

/// Pass 2 of the agreement prior over all `d` planes' depth-weight logits `out` (`[D][H*W]` from
/// [`prior_stats`]): per pixel, back to front, `alpha_d = w_d / sum_{i<=d} w_i` in the log domain,
/// turned into its clamped logit.
pub(crate) fn prior_logits(out: &mut [f32], d: usize, hw: usize) {
    // Pass 2, per pixel over planes back to front: alpha_d = w_d / sum_{i<=d} w_i (log domain), on
    // runs of pixels with the pixels innermost (vector loops, [`fastmath::with_simd`]).
    const RUN: usize = 512;
    let base = out.as_mut_ptr() as usize;
    (0..hw.div_ceil(RUN)).into_par_iter().for_each(|k| {
        let (o0, n) = (k * RUN, RUN.min(hw - k * RUN));
        let ptr = base as *mut f32;
        // SAFETY: each task touches only pixels `o0..o0 + n` of every plane (disjoint across tasks).
        let row = |p: usize| unsafe { std::slice::from_raw_parts_mut(ptr.add(p * hw + o0), n) };
        fastmath::with_simd(
            #[inline(always)]
            || {
                let (mut m, mut s) = ([0f32; RUN], [0f32; RUN]);
                for p in 0..d {
                    let lg = row(p);
                    if p == 0 {
                        m[..n].copy_from_slice(lg);
                        s[..n].fill(1.0);
                    } else {
                        for ((m, s), &l) in m[..n].iter_mut().zip(&mut s[..n]).zip(&*lg) {
                            let m1 = m.max(l);
                            *s = *s * fastmath::exp(*m - m1) + fastmath::exp(l - m1);
                            *m = m1;
                        }
                    }
                    for ((l, &m), &s) in lg.iter_mut().zip(&m[..n]).zip(&s[..n]) {
                        let alpha = fastmath::exp(*l - (m + fastmath::ln(s))).min(1.0);
                        // `seen` is encoded in the masked logit (unseen: -1e30, alpha 0 there too).
                        *l = logit(if *l > -1e29 { alpha } else { 0.0 });
                    }
                }
            },
        )
    });
}
