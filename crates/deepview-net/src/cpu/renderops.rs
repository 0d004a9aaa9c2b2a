//! The forward model's two hot operations on plain arrays, for the CPU operations of
//! [`crate::cpu::ops::KernelOps`]: the bilinear homography warp of a [`WarpTable`] (forward: four taps
//! per output texel; backward: the same taps scattered back) and over-compositing with its net
//! transmittance `T` and accumulated over `A` (one pass over the planes per pixel, and one back).
//! burn's tensor ops ([`WarpTable::apply_burn`], [`crate::forward::composite_burn`]) are the
//! reference: `tests` compare outputs and gradients.

use crate::forward::WarpTable;
use rayon::prelude::*;

/// A table's planes, texels per output plane, texels per source plane, and taps per corner.
fn warp_sizes(table: &WarpTable) -> (usize, usize, usize, usize) {
    let (d, hw) = (table.planes, table.out_h * table.out_w);
    (d, hw, table.src_h * table.src_w, d * hw)
}

/// `src` `[S, C, sh, sw]` (`S` = the table's planes, or 1: broadcast) -> `[D, C, oh, ow]`.
pub fn warp_forward(table: &WarpTable, src: &[f32], s: usize, c: usize) -> Vec<f32> {
    let (d, hw, shw, n) = warp_sizes(table);
    let mut out = vec![0f32; d * c * hw];
    if hw == 0 || shw == 0 {
        return out;
    }
    let (idx, w) = table.taps();
    out.par_chunks_mut(hw).enumerate().for_each(|(i, o)| {
        let (p, ch) = (i / c, i % c);
        let sp = if s == 1 { 0 } else { p };
        let plane = &src[(sp * c + ch) * shw..][..shw];
        let base = p * hw;
        for (j, v) in o.iter_mut().enumerate() {
            let k = base + j;
            *v = w[k] * plane[idx[k] as usize]
                + w[n + k] * plane[idx[n + k] as usize]
                + w[2 * n + k] * plane[idx[2 * n + k] as usize]
                + w[3 * n + k] * plane[idx[3 * n + k] as usize];
        }
    });
    out
}

/// The gradient of [`warp_forward`] at its source, `[S, C, sh, sw]`, given `grad` `[D, C, oh, ow]`.
pub fn warp_backward(table: &WarpTable, grad: &[f32], s: usize, c: usize) -> Vec<f32> {
    let (d, hw, shw, n) = warp_sizes(table);
    let mut out = vec![0f32; s * c * shw];
    if hw == 0 || shw == 0 {
        return out;
    }
    let (idx, w) = table.taps();
    // One source plane and channel per task: the output planes that read it (all of them for a
    // broadcast source) scatter into it in order.
    out.par_chunks_mut(shw).enumerate().for_each(|(i, g)| {
        let (sp, ch) = (i / c, i % c);
        let planes = if s == 1 { 0..d } else { sp..sp + 1 };
        for p in planes {
            let go = &grad[(p * c + ch) * hw..][..hw];
            let base = p * hw;
            for (j, &v) in go.iter().enumerate() {
                if v == 0.0 {
                    continue;
                }
                let k = base + j;
                for t in 0..4 {
                    g[idx[t * n + k] as usize] += w[t * n + k] * v;
                }
            }
        }
    });
    out
}

/// `rows` planes of `hw` texels computed in runs of pixels: `f(x0, m)` returns the `[rows][m]` values
/// of pixels `x0..x0 + m` (one task per run, in parallel), gathered into `[rows][hw]`.
fn by_pixel_runs(rows: usize, hw: usize, f: impl Fn(usize, usize) -> Vec<f32> + Sync) -> Vec<f32> {
    const RUN: usize = 256;
    let mut out = vec![0f32; rows * hw];
    if hw == 0 || rows == 0 {
        return out;
    }
    let parts: Vec<Vec<f32>> = (0..hw.div_ceil(RUN))
        .into_par_iter()
        .map(|r| f(r * RUN, RUN.min(hw - r * RUN)))
        .collect();
    for (r, part) in parts.iter().enumerate() {
        let (x0, m) = (r * RUN, RUN.min(hw - r * RUN));
        for (k, row) in part.chunks_exact(m).enumerate() {
            out[k * hw + x0..][..m].copy_from_slice(row);
        }
    }
    out
}

/// Over-composite `rgba` `[D, 4, h, w]` (premultiplied, back to front) -> `[D + 1, 4, h, w]`: planes
/// `0..D` hold `A_d` (3) and `T_d` (1), plane `D` the render (3) and 0.
pub fn composite_forward(rgba: &[f32], d: usize, hw: usize) -> Vec<f32> {
    by_pixel_runs((d + 1) * 4, hw, |x0, m| {
        let mut o = vec![0f32; (d + 1) * 4 * m];
        let at = |p: usize, ch: usize| (p * 4 + ch) * hw + x0;
        // A, back to front.
        let mut acc = [vec![0f32; m], vec![0f32; m], vec![0f32; m]];
        for p in 0..d {
            let a = &rgba[at(p, 3)..][..m];
            for ch in 0..3 {
                o[(p * 4 + ch) * m..][..m].copy_from_slice(&acc[ch]);
                let c = &rgba[at(p, ch)..][..m];
                for j in 0..m {
                    acc[ch][j] = acc[ch][j] * (1.0 - a[j]) + c[j];
                }
            }
        }
        for ch in 0..3 {
            o[(d * 4 + ch) * m..][..m].copy_from_slice(&acc[ch]);
        }
        // T, front to back.
        let mut t = vec![1f32; m];
        for p in (0..d).rev() {
            o[(p * 4 + 3) * m..][..m].copy_from_slice(&t);
            if p > 0 {
                let a = &rgba[at(p, 3)..][..m];
                for j in 0..m {
                    t[j] *= 1.0 - a[j];
                }
            }
        }
        o
    })
}

/// The gradient of [`composite_forward`] at `rgba`, given its output `out` and the gradient `grad` at
/// it (both `[D + 1, 4, h, w]`; the last plane's channel 3 is ignored).
pub fn composite_backward(
    rgba: &[f32],
    out: &[f32],
    grad: &[f32],
    d: usize,
    hw: usize,
) -> Vec<f32> {
    by_pixel_runs(d * 4, hw, |x0, m| {
        let at = |p: usize, ch: usize| (p * 4 + ch) * hw + x0;
        let mut g = vec![0f32; d * 4 * m];
        // `A_{p+1} = A_p (1 - a_p) + c_p` (`A_D` the render), back from the render: `ga` holds the
        // whole gradient at `A_{p+1}`.
        for ch in 0..3 {
            let mut ga = grad[at(d, ch)..][..m].to_vec();
            for p in (0..d).rev() {
                let a = &rgba[at(p, 3)..][..m];
                let acc = &out[at(p, ch)..][..m];
                let direct = &grad[at(p, ch)..][..m];
                for j in 0..m {
                    g[(p * 4 + ch) * m + j] += ga[j];
                    g[(p * 4 + 3) * m + j] -= ga[j] * acc[j];
                    ga[j] = ga[j] * (1.0 - a[j]) + direct[j];
                }
            }
        }
        // `T_{p-1} = T_p (1 - a_p)` for `p >= 1` (`T_{D-1} = 1`), forward from `T_0`: `gt` holds the
        // whole gradient at `T_{p-1}`.
        let mut gt = grad[at(0, 3)..][..m].to_vec();
        for p in 1..d {
            let a = &rgba[at(p, 3)..][..m];
            let t = &out[at(p, 3)..][..m];
            let direct = &grad[at(p, 3)..][..m];
            for j in 0..m {
                g[(p * 4 + 3) * m + j] -= gt[j] * t[j];
                gt[j] = gt[j] * (1.0 - a[j]) + direct[j];
            }
        }
        g
    })
}
