//! The cubecl kernels of [`super::GpuOps`] (one thread per pixel; strided tensors).

use cubecl::prelude::*;

#[cube(launch)]
pub(super) fn composite_kernel(rgba: &Tensor<f32>, out: &mut Tensor<f32>) {
    let (d, h, w) = (rgba.shape(0), rgba.shape(2), rgba.shape(3));
    let pix = ABSOLUTE_POS;
    if pix >= h * w {
        terminate!();
    }
    let (y, x) = (pix / w, pix % w);
    let (s0, s1) = (rgba.stride(0), rgba.stride(1));
    let (o0, o1) = (out.stride(0), out.stride(1));
    let ib = y * rgba.stride(2) + x * rgba.stride(3);
    let ob = y * out.stride(2) + x * out.stride(3);
    // A, back to front; the render after the last plane.
    let mut r = 0.0f32;
    let mut g = 0.0f32;
    let mut b = 0.0f32;
    for p in 0..d {
        let i = ib + p * s0;
        let o = ob + p * o0;
        out[o] = r;
        out[o + o1] = g;
        out[o + 2 * o1] = b;
        let m = 1.0f32 - rgba[i + 3 * s1];
        r = r * m + rgba[i];
        g = g * m + rgba[i + s1];
        b = b * m + rgba[i + 2 * s1];
    }
    let o = ob + d * o0;
    out[o] = r;
    out[o + o1] = g;
    out[o + 2 * o1] = b;
    out[o + 3 * o1] = 0.0f32;
    // T, front to back.
    let mut t = 1.0f32;
    for k in 0..d {
        let p = d - 1 - k;
        out[ob + p * o0 + 3 * o1] = t;
        t *= 1.0f32 - rgba[ib + p * s0 + 3 * s1];
    }
}

#[cube(launch)]
pub(super) fn composite_backward_kernel(
    rgba: &Tensor<f32>,
    out: &Tensor<f32>,
    grad: &Tensor<f32>,
    gin: &mut Tensor<f32>,
) {
    let (d, h, w) = (rgba.shape(0), rgba.shape(2), rgba.shape(3));
    let pix = ABSOLUTE_POS;
    if pix >= h * w {
        terminate!();
    }
    let (y, x) = (pix / w, pix % w);
    let (s0, s1) = (rgba.stride(0), rgba.stride(1));
    let (o0, o1) = (out.stride(0), out.stride(1));
    let (q0, q1) = (grad.stride(0), grad.stride(1));
    let (g0, g1) = (gin.stride(0), gin.stride(1));
    let ib = y * rgba.stride(2) + x * rgba.stride(3);
    let ob = y * out.stride(2) + x * out.stride(3);
    let qb = y * grad.stride(2) + x * grad.stride(3);
    let gb = y * gin.stride(2) + x * gin.stride(3);
    for p in 0..d {
        gin[gb + p * g0 + 3 * g1] = 0.0f32;
    }
    // `A_{p+1} = A_p (1 - a_p) + c_p` (`A_D` the render), back from the render: `ga` is the whole
    // gradient at `A_{p+1}`.
    for ch in 0..3usize {
        let mut ga = grad[qb + d * q0 + ch * q1];
        for k in 0..d {
            let p = d - 1 - k;
            let a = rgba[ib + p * s0 + 3 * s1];
            let acc = out[ob + p * o0 + ch * o1];
            gin[gb + p * g0 + ch * g1] = ga;
            gin[gb + p * g0 + 3 * g1] -= ga * acc;
            ga = ga * (1.0f32 - a) + grad[qb + p * q0 + ch * q1];
        }
    }
    // `T_{p-1} = T_p (1 - a_p)` for `p >= 1` (`T_{D-1} = 1`), forward from `T_0`: `gt` is the whole
    // gradient at `T_{p-1}`.
    let mut gt = grad[qb + 3 * q1];
    for p in 1..d {
        let a = rgba[ib + p * s0 + 3 * s1];
        let t = out[ob + p * o0 + 3 * o1];
        gin[gb + p * g0 + 3 * g1] -= gt * t;
        gt = gt * (1.0f32 - a) + grad[qb + p * q0 + 3 * q1];
    }
}

/// One plane's agreement statistics at one pixel (`ib`: the pixel's offset in `psv`, view-major
/// `[K*D, 4, h, w]`): the mean colour of the valid samples, the masked depth-weight logit (`-variance /
/// temperature`, `-1e30` where no view sees the point) and whether any view sees it (1 or 0).
#[cube]
fn plane_cost(
    psv: &Tensor<f32>,
    ib: usize,
    p: usize,
    d: usize,
    temperature: f32,
    single_view_variance: f32,
) -> (f32, f32, f32, f32, f32) {
    let k = psv.shape(0) / d;
    let (s0, s1) = (psv.stride(0), psv.stride(1));
    let mut count = 0.0f32;
    let mut sr = 0.0f32;
    let mut sg = 0.0f32;
    let mut sb = 0.0f32;
    for v in 0..k {
        let i = ib + (v * d + p) * s0;
        let m = psv[i + 3 * s1];
        count += m;
        sr += psv[i] * m;
        sg += psv[i + s1] * m;
        sb += psv[i + 2 * s1] * m;
    }
    let denom = if count > 1.0f32 { count } else { 1.0f32 };
    let (mr, mg, mb) = (sr / denom, sg / denom, sb / denom);
    let mut vr = 0.0f32;
    let mut vg = 0.0f32;
    let mut vb = 0.0f32;
    for v in 0..k {
        let i = ib + (v * d + p) * s0;
        let m = psv[i + 3 * s1];
        let er = psv[i] * m - mr * m;
        let eg = psv[i + s1] * m - mg * m;
        let eb = psv[i + 2 * s1] * m - mb * m;
        vr += er * er;
        vg += eg * eg;
        vb += eb * eb;
    }
    let mut q = (vr / denom + vg / denom + vb / denom) / 3.0f32;
    if count == 1.0f32 {
        q = single_view_variance;
    }
    let seen = if count > 0.5f32 { 1.0f32 } else { 0.0f32 };
    let l = (-q / temperature) * seen + (1.0f32 - seen) * -1e30f32;
    (mr, mg, mb, l, seen)
}

/// Plane `p`'s mean colour as clamped logits into `out` (channels 0-2, zeros in channels `4..S`).
#[cube]
fn write_colour(out: &mut Tensor<f32>, o: usize, mr: f32, mg: f32, mb: f32, eps: f32) {
    let (o1, s) = (out.stride(1), out.shape(1));
    out[o] = clamped_logit(mr, eps);
    out[o + o1] = clamped_logit(mg, eps);
    out[o + 2 * o1] = clamped_logit(mb, eps);
    // A state's extra channels (the prior fills only RGBA).
    for c in 4..s {
        out[o + c * o1] = 0.0f32;
    }
}

/// The agreement prior's logits (see [`crate::network::agreement_prior_logits`], the same arithmetic):
/// `psv` `[K*D, 4, h, w]` (view-major: view `v`'s plane `p` at `v*D + p`; RGB and validity) -> `out`
/// `[D, S, h, w]` (the mean colour's and the depth weight's clamped logits; zeros in channels `4..S`).
#[cube(launch)]
pub(super) fn prior_kernel(
    psv: &Tensor<f32>,
    out: &mut Tensor<f32>,
    temperature: f32,
    single_view_variance: f32,
    eps: f32,
) {
    let (d, h, w) = (out.shape(0), out.shape(2), out.shape(3));
    let pix = ABSOLUTE_POS;
    if pix >= h * w {
        terminate!();
    }
    let (y, x) = (pix / w, pix % w);
    let (o0, o1) = (out.stride(0), out.stride(1));
    let ib = y * psv.stride(2) + x * psv.stride(3);
    let ob = y * out.stride(2) + x * out.stride(3);
    let mut run_m = 0.0f32;
    let mut run_s = 1.0f32;
    for p in 0..d {
        let (mr, mg, mb, l, seen) = plane_cost(psv, ib, p, d, temperature, single_view_variance);
        let (alpha, m, s) = alpha_step(l, p, run_m, run_s);
        (run_m, run_s) = (m, s);
        let o = ob + p * o0;
        write_colour(out, o, mr, mg, mb, eps);
        out[o + 3 * o1] = clamped_logit(alpha * seen, eps);
    }
}

/// The aggregated prior's first pass: [`prior_kernel`]'s colour logits into `out`, and each plane's
/// masked depth-weight logit into `lg` `[D, 1, h, w]` (for [`aggregate_rows_kernel`] and [`aggregate_cols_kernel`]).
#[cube(launch)]
pub(super) fn prior_cost_kernel(
    psv: &Tensor<f32>,
    out: &mut Tensor<f32>,
    lg: &mut Tensor<f32>,
    temperature: f32,
    single_view_variance: f32,
    eps: f32,
) {
    let (d, h, w) = (out.shape(0), out.shape(2), out.shape(3));
    let pix = ABSOLUTE_POS;
    if pix >= h * w {
        terminate!();
    }
    let (y, x) = (pix / w, pix % w);
    let ib = y * psv.stride(2) + x * psv.stride(3);
    let ob = y * out.stride(2) + x * out.stride(3);
    let lb = y * lg.stride(2) + x * lg.stride(3);
    let (o0, l0) = (out.stride(0), lg.stride(0));
    for p in 0..d {
        let (mr, mg, mb, l, _seen) = plane_cost(psv, ib, p, d, temperature, single_view_variance);
        write_colour(out, ob + p * o0, mr, mg, mb, eps);
        lg[lb + p * l0] = l;
    }
}

/// Cost aggregation ([`deepview_mpi::agreement::aggregate_seen`]), its first, horizontal pass: per texel
/// of `lg` `[D, 1, h, w]`, the sum and the count of the seen logits (above `-1e29`) in the `2r+1` columns
/// around it (clipped at the border), into channels 0 and 1 of `rows` `[D, 2, h, w]`. One thread per
/// texel, `2r+1` reads.
#[cube(launch)]
#[allow(clippy::implicit_saturating_sub)] // cubecl expands `if`, not `saturating_sub`
pub(super) fn aggregate_rows_kernel(lg: &Tensor<f32>, rows: &mut Tensor<f32>, radius: u32) {
    let (d, h, w) = (lg.shape(0), lg.shape(2), lg.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= d * h * w {
        terminate!();
    }
    let (p, y, x) = (pos / (h * w), (pos / w) % h, pos % w);
    let base = p * lg.stride(0) + y * lg.stride(2);
    let l3 = lg.stride(3);
    let rad = usize::cast_from(radius);
    let x0 = if x > rad { x - rad } else { 0usize };
    let x1 = if x + rad + 1 < w { x + rad + 1 } else { w };
    let mut sum = 0.0f32;
    let mut count = 0.0f32;
    for xx in x0..x1 {
        let u = lg[base + xx * l3];
        if u > -1e29f32 {
            sum += u;
            count += 1.0f32;
        }
    }
    let o = p * rows.stride(0) + y * rows.stride(2) + x * rows.stride(3);
    let r1 = rows.stride(1);
    rows[o] = sum;
    rows[o + r1] = count;
}

/// Cost aggregation's second, vertical pass: every seen logit of `lg` becomes `weight` times the mean of
/// the seen logits in its `(2r+1)^2` window (the column sums of [`aggregate_rows_kernel`]'s `rows` over
/// `2r+1` rows, clipped) plus `1 - weight` times its own, into `out` `[D, 1, h, w]`; unseen ones are
/// copied. One thread per texel, `2r+1` reads.
#[cube(launch)]
#[allow(clippy::implicit_saturating_sub)] // cubecl expands `if`, not `saturating_sub`
pub(super) fn aggregate_cols_kernel(
    lg: &Tensor<f32>,
    rows: &Tensor<f32>,
    out: &mut Tensor<f32>,
    radius: u32,
    weight: f32,
) {
    let (d, h, w) = (lg.shape(0), lg.shape(2), lg.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= d * h * w {
        terminate!();
    }
    let (p, y, x) = (pos / (h * w), (pos / w) % h, pos % w);
    let v = lg[p * lg.stride(0) + y * lg.stride(2) + x * lg.stride(3)];
    let mut r = v;
    if v > -1e29f32 {
        let rad = usize::cast_from(radius);
        let y0 = if y > rad { y - rad } else { 0usize };
        let y1 = if y + rad + 1 < h { y + rad + 1 } else { h };
        let base = p * rows.stride(0) + x * rows.stride(3);
        let (r1, r2) = (rows.stride(1), rows.stride(2));
        let mut sum = 0.0f32;
        let mut count = 0.0f32;
        for yy in y0..y1 {
            sum += rows[base + yy * r2];
            count += rows[base + r1 + yy * r2];
        }
        r = weight * (sum / count) + (1.0f32 - weight) * v;
    }
    let o = p * out.stride(0) + y * out.stride(2) + x * out.stride(3);
    out[o] = r;
}

/// The aggregated prior's last pass: per pixel, the depth weights' alphas from the (aggregated) logits
/// `lg` `[D, 1, h, w]` as in [`prior_kernel`], into channel 3 of `out`.
#[cube(launch)]
pub(super) fn prior_alpha_kernel(lg: &Tensor<f32>, out: &mut Tensor<f32>, eps: f32) {
    let (d, h, w) = (out.shape(0), out.shape(2), out.shape(3));
    let pix = ABSOLUTE_POS;
    if pix >= h * w {
        terminate!();
    }
    let (y, x) = (pix / w, pix % w);
    let lb = y * lg.stride(2) + x * lg.stride(3);
    let ob = y * out.stride(2) + x * out.stride(3) + 3 * out.stride(1);
    let mut run_m = 0.0f32;
    let mut run_s = 1.0f32;
    let o0 = out.stride(0);
    for p in 0..d {
        let l = lg[lb + p * lg.stride(0)];
        let seen = if l > -1e29f32 { 1.0f32 } else { 0.0f32 };
        let (alpha, m, s) = alpha_step(l, p, run_m, run_s);
        (run_m, run_s) = (m, s);
        out[ob + p * o0] = clamped_logit(alpha * seen, eps);
    }
}

/// One plane of the depth weights' alphas, back to front: with `(run_m, run_s)` the running
/// log-sum-exp of the planes before `p` (max and sum of exponentials), `alpha_p = min(exp(l_p -
/// logsumexp_{i<=p} l_i), 1)` and the running pair including `p`.
#[cube]
fn alpha_step(l: f32, p: usize, run_m: f32, run_s: f32) -> (f32, f32, f32) {
    let mut m = l;
    let mut s = 1.0f32;
    if p != 0 {
        m = if l > run_m { l } else { run_m };
        s = run_s * (run_m - m).exp() + (l - m).exp();
    }
    let mut alpha = (l - (m + s.ln())).exp();
    if alpha > 1.0f32 {
        alpha = 1.0f32;
    }
    (alpha, m, s)
}

#[cube]
fn clamped_logit(p: f32, eps: f32) -> f32 {
    let mut q = p;
    if q < eps {
        q = eps;
    }
    if q > 1.0f32 - eps {
        q = 1.0f32 - eps;
    }
    (q / (1.0f32 - q)).ln()
}

/// `v` clamped to `lo..=hi`.
#[cube]
fn clamp_i32(v: i32, lo: i32, hi: i32) -> i32 {
    let mut r = v;
    if r < lo {
        r = lo;
    }
    if r > hi {
        r = hi;
    }
    r
}

/// Where an output sample of a homography warp reads its source: the texels of its four bilinear taps
/// (`(xa, ya)`, `(xb, ya)`, `(xa, yb)`, `(xb, yb)`, clamped to the whole `full_w x full_h` source and then
/// moved into its crop at `(ox, oy)` of `cwmax + 1 x chmax + 1` texels) and the fractions `ax`, `ay`
/// between them; `valid` where the sample lies inside the source in front of the camera.
#[derive(CubeType, Clone, Copy)]
struct Footprint {
    valid: bool,
    xa: i32,
    xb: i32,
    ya: i32,
    yb: i32,
    ax: f32,
    ay: f32,
}

/// The [`Footprint`] of output column `u` (a pixel centre, in the output frame) of the row whose
/// coefficients start at `rb` in the plane's at `cb` (`coef`:
/// [`crate::forward::WarpTable::coefficients`]), as [`crate::forward::WarpTable`] computes its taps on
/// the CPU. The forward warp and its backward both take their taps from here, so they agree exactly.
#[cube]
#[allow(clippy::too_many_arguments)]
fn footprint(
    coef: &Tensor<f32>,
    cb: usize,
    rb: usize,
    u: f32,
    full_w: i32,
    full_h: i32,
    ox: i32,
    oy: i32,
    cwmax: i32,
    chmax: i32,
) -> Footprint {
    let wn = fma(coef[cb + 2], u, coef[rb + 2]);
    let inv = 1.0f32 / wn;
    let sx = fma(coef[cb], u, coef[rb]) * inv;
    let sy = fma(coef[cb + 1], u, coef[rb + 1]) * inv;
    let (wf, hf) = (f32::cast_from(full_w), f32::cast_from(full_h));
    // Comparisons with NaN are false: a NaN position is invalid, as on the CPU.
    let inside = sx >= 0.0f32 && sx <= wf && sy >= 0.0f32 && sy <= hf;
    let mut fp = Footprint {
        valid: false,
        xa: 0i32,
        xb: 0i32,
        ya: 0i32,
        yb: 0i32,
        ax: 0.0f32,
        ay: 0.0f32,
    };
    if wn > 0.0f32 && full_w > 0 && full_h > 0 && cwmax >= 0 && chmax >= 0 && inside {
        let fx = sx - 0.5f32;
        let fy = sy - 0.5f32;
        let x0f = fx.floor();
        let y0f = fy.floor();
        let x0 = i32::cast_from(x0f);
        let y0 = i32::cast_from(y0f);
        let (wmax, hmax) = (full_w - 1, full_h - 1);
        fp.valid = true;
        fp.ax = fx - x0f;
        fp.ay = fy - y0f;
        // Clamped to the whole source, then moved into the crop.
        fp.xa = clamp_i32(clamp_i32(x0, 0, wmax) - ox, 0, cwmax);
        fp.xb = clamp_i32(clamp_i32(x0 + 1, 0, wmax) - ox, 0, cwmax);
        fp.ya = clamp_i32(clamp_i32(y0, 0, hmax) - oy, 0, chmax);
        fp.yb = clamp_i32(clamp_i32(y0 + 1, 0, hmax) - oy, 0, chmax);
    }
    fp
}

/// A homography warp that computes its own bilinear taps, as [`crate::forward::WarpTable`] does on the
/// CPU, from the table's coefficients (`coef` `[D][3 + 3 * oh]`: per plane `a`, then per output row `b`;
/// [`crate::forward::WarpTable::coefficients`]): channels `src_c0..src_c0 + c` of `src` `[S, C, sh, sw]`
/// (plane `d` warped into plane `d`, or where `src_plane < S` that one plane into every plane, as also
/// for `S = 1`; a crop at `(ox, oy)` of a `full_w x full_h` source) -> channels `c0..c0 + c` of `out`
/// `[D, C', oh, ow]` (a window at column `ux` of the output frame), and where `valid_ch < C'` the
/// validity (1 inside the source) into channel `valid_ch`. One thread per output sample; nothing but
/// the coefficients is uploaded.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(super) fn warp_hom_kernel(
    src: &Tensor<f32>,
    coef: &Tensor<f32>,
    out: &mut Tensor<f32>,
    src_plane: u32,
    src_c0: u32,
    c: u32,
    c0: u32,
    valid_ch: u32,
    ux: u32,
    full_w: u32,
    full_h: u32,
    ox: i32,
    oy: i32,
) {
    let (d, oh, ow) = (out.shape(0), out.shape(2), out.shape(3));
    let (sh, sw) = (src.shape(2), src.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= d * oh * ow {
        terminate!();
    }
    let per = oh * ow;
    let p = pos / per;
    let pix = pos % per;
    let (y, x) = (pix / ow, pix % ow);
    let cb = p * (3 + 3 * oh);
    let rb = cb + 3 + 3 * y;
    let u = f32::cast_from(ux + u32::cast_from(x)) + 0.5f32;
    let (cwmax, chmax) = (i32::cast_from(sw) - 1, i32::cast_from(sh) - 1);
    let fp = footprint(
        coef,
        cb,
        rb,
        u,
        i32::cast_from(full_w),
        i32::cast_from(full_h),
        ox,
        oy,
        cwmax,
        chmax,
    );
    let valid = fp.valid;
    let mut ws = Array::<f32>::new(4usize);
    let mut taps = Array::<usize>::new(4usize);
    for t in 0..4usize {
        ws[t] = 0.0f32;
        taps[t] = 0usize;
    }
    if valid {
        let (xa, xb) = (usize::cast_from(fp.xa), usize::cast_from(fp.xb));
        let (ya, yb) = (usize::cast_from(fp.ya), usize::cast_from(fp.yb));
        let (s2, s3) = (src.stride(2), src.stride(3));
        taps[0] = ya * s2 + xa * s3;
        taps[1] = ya * s2 + xb * s3;
        taps[2] = yb * s2 + xa * s3;
        taps[3] = yb * s2 + xb * s3;
        ws[0] = (1.0f32 - fp.ax) * (1.0f32 - fp.ay);
        ws[1] = fp.ax * (1.0f32 - fp.ay);
        ws[2] = (1.0f32 - fp.ax) * fp.ay;
        ws[3] = fp.ax * fp.ay;
    }
    let mut plane = p;
    let fixed = usize::cast_from(src_plane);
    if fixed < src.shape(0) {
        plane = fixed;
    } else if src.shape(0) == 1 {
        plane = 0;
    }
    let sb = plane * src.stride(0) + usize::cast_from(src_c0) * src.stride(1);
    let ob = p * out.stride(0) + y * out.stride(2) + x * out.stride(3);
    let oc = out.stride(1);
    let first = usize::cast_from(c0);
    for ch in 0..usize::cast_from(c) {
        let mut acc = 0.0f32;
        if valid {
            let b = sb + ch * src.stride(1);
            acc = ws[0] * src[b + taps[0]]
                + ws[1] * src[b + taps[1]]
                + ws[2] * src[b + taps[2]]
                + ws[3] * src[b + taps[3]];
        }
        out[ob + (first + ch) * oc] = acc;
    }
    let vc = usize::cast_from(valid_ch);
    if vc < out.shape(1) {
        let mut v = 0.0f32;
        if valid {
            v = 1.0f32;
        }
        out[ob + vc * oc] = v;
    }
}

/// The texel a tap of an output sample reads, computed as [`warp_hom_kernel`] does: for output
/// column `x` of row coefficients `rb` in plane coefficients `cb`, tap `t` (0..4: `(x0, y0)`,
/// `(x0 + 1, y0)`, `(x0, y0 + 1)`, `(x0 + 1, y0 + 1)`), its weight where it reads texel `(tx, ty)` of the
/// crop, else 0 (and 0 for an invalid sample).
#[cube]
#[allow(clippy::too_many_arguments)]
fn tap_weight_at(
    coef: &Tensor<f32>,
    cb: usize,
    rb: usize,
    x: usize,
    geometry: &Array<i32>,
    tx: i32,
    ty: i32,
) -> Array<f32> {
    let (gux, full_w, full_h) = (geometry[0], geometry[2], geometry[3]);
    let (ox, oy, cwmax, chmax) = (geometry[4], geometry[5], geometry[6], geometry[7]);
    let mut ws = Array::<f32>::new(4usize);
    for t in 0..4usize {
        ws[t] = 0.0f32;
    }
    let u = f32::cast_from(gux + i32::cast_from(x)) + 0.5f32;
    let fp = footprint(coef, cb, rb, u, full_w, full_h, ox, oy, cwmax, chmax);
    if fp.valid {
        if fp.ya == ty && fp.xa == tx {
            ws[0] = (1.0f32 - fp.ax) * (1.0f32 - fp.ay);
        }
        if fp.ya == ty && fp.xb == tx {
            ws[1] = fp.ax * (1.0f32 - fp.ay);
        }
        if fp.yb == ty && fp.xa == tx {
            ws[2] = (1.0f32 - fp.ax) * fp.ay;
        }
        if fp.yb == ty && fp.xb == tx {
            ws[3] = fp.ax * fp.ay;
        }
    }
    ws
}

/// The gradient of [`warp_hom_kernel`] at its source, on the device: channels `grad_c0..grad_c0 + c` of
/// `grad` `[D, C, oh, ow]` -> planes `p0..p0 + s`, channels `c0..c0 + c` of `gsrc` `[S', C', sh, sw]`
/// (`s` the source's planes: `D`, or 1 for a source broadcast to every plane). One thread per source
/// texel: the output samples that can read it lie where the inverse homography (`inv` `[D][9]`,
/// row-major, source -> output frame) maps the texel's bilinear footprint (a 2 x 2 texel square), so
/// the thread visits that box (the whole window where the map is not finite in front of the camera),
/// recomputes each sample's taps exactly as the forward does, and sums `weight * grad` over the taps
/// that read it: in sample order, no atomics, nothing computed on the host.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(super) fn warp_backward_kernel(
    grad: &Tensor<f32>,
    coef: &Tensor<f32>,
    inv: &Tensor<f32>,
    gsrc: &mut Tensor<f32>,
    ux: i32,
    uy: i32,
    full_w: i32,
    full_h: i32,
    ox: i32,
    oy: i32,
    s: u32,
    c: u32,
    grad_c0: u32,
    p0: u32,
    c0: u32,
    zeros: u32,
) {
    let (sh, sw) = (gsrc.shape(2), gsrc.shape(3));
    let (d, oh, ow) = (grad.shape(0), grad.shape(2), grad.shape(3));
    let shw = sh * sw;
    let e = ABSOLUTE_POS;
    if e >= usize::cast_from(s) * shw {
        terminate!();
    }
    let (sp, texel) = (e / shw, e % shw);
    let (tyu, txu) = (texel / sw, texel % sw);
    let (tx, ty) = (i32::cast_from(txu), i32::cast_from(tyu));
    // The frames, as `tap_weight_at` takes them.
    let mut geometry = Array::<i32>::new(8usize);
    geometry[0] = ux;
    geometry[1] = uy;
    geometry[2] = full_w;
    geometry[3] = full_h;
    geometry[4] = ox;
    geometry[5] = oy;
    geometry[6] = i32::cast_from(sw) - 1;
    geometry[7] = i32::cast_from(sh) - 1;
    let gb = (usize::cast_from(p0) + sp) * gsrc.stride(0)
        + usize::cast_from(c0) * gsrc.stride(1)
        + tyu * gsrc.stride(2)
        + txu * gsrc.stride(3);
    let (mut first, mut last) = (sp, sp + 1);
    if s == 1 {
        first = 0;
        last = d;
    }
    // The texel's footprint in the whole source: centres within 1 of the texel's centre.
    let cx = f32::cast_from(tx + ox) + 0.5f32;
    let cy = f32::cast_from(ty + oy) + 0.5f32;
    let (fw, fh) = (f32::cast_from(ow), f32::cast_from(oh));
    let (uxf, uyf) = (f32::cast_from(ux), f32::cast_from(uy));
    let g0 = usize::cast_from(grad_c0);
    let gcs = gsrc.stride(1);
    for ch in 0..usize::cast_from(c) {
        let gc = (g0 + ch) * grad.stride(1);
        let mut acc = 0.0f32;
        for p in first..last {
            let ib = p * 9;
            // The box of output pixels: the footprint's corners mapped into the output window, one
            // pixel of margin; everything where a corner does not map in front.
            // (Initial bounds beyond the window: a box never narrower than the corners'.)
            let mut x_lo = fw;
            let mut x_hi = -fw;
            let mut y_lo = fh;
            let mut y_hi = -fh;
            let mut whole = false;
            for k in 0..4u32 {
                let mut px = cx - 1.0f32;
                if k % 2 == 1 {
                    px = cx + 1.0f32;
                }
                let mut py = cy - 1.0f32;
                if k / 2 == 1 {
                    py = cy + 1.0f32;
                }
                let wq = inv[ib + 6] * px + inv[ib + 7] * py + inv[ib + 8];
                let qx = (inv[ib] * px + inv[ib + 1] * py + inv[ib + 2]) / wq - uxf - 0.5f32;
                let qy = (inv[ib + 3] * px + inv[ib + 4] * py + inv[ib + 5]) / wq - uyf - 0.5f32;
                // NaN and infinities fail these comparisons too.
                if wq > 0.0f32 && qx > -1.0e7f32 && qx < 1.0e7f32 && qy > -1.0e7f32 && qy < 1.0e7f32
                {
                    if qx < x_lo {
                        x_lo = qx;
                    }
                    if qx > x_hi {
                        x_hi = qx;
                    }
                    if qy < y_lo {
                        y_lo = qy;
                    }
                    if qy > y_hi {
                        y_hi = qy;
                    }
                } else {
                    whole = true;
                }
            }
            let mut xa = 0i32;
            let mut xb = i32::cast_from(ow) - 1;
            let mut ya = 0i32;
            let mut yb = i32::cast_from(oh) - 1;
            if !whole {
                xa = clamp_i32(i32::cast_from(x_lo.floor()) - 1, 0, xb + 1);
                xb = clamp_i32(i32::cast_from(-(-x_hi).floor()) + 1, -1, xb);
                ya = clamp_i32(i32::cast_from(y_lo.floor()) - 1, 0, yb + 1);
                yb = clamp_i32(i32::cast_from(-(-y_hi).floor()) + 1, -1, yb);
            }
            let cb = p * (3 + 3 * oh);
            let pb = p * grad.stride(0) + gc;
            let mut y = ya;
            while y <= yb {
                let yu = usize::cast_from(y);
                let rb = cb + 3 + 3 * yu;
                let mut x = xa;
                while x <= xb {
                    let xu = usize::cast_from(x);
                    let ws = tap_weight_at(coef, cb, rb, xu, &geometry, tx, ty);
                    let gv = grad[pb + yu * grad.stride(2) + xu * grad.stride(3)];
                    for t in 0..4usize {
                        if ws[t] != 0.0f32 {
                            acc += ws[t] * gv;
                        }
                    }
                    x += 1;
                }
                y += 1;
            }
        }
        gsrc[gb + ch * gcs] = acc;
    }
    // The `zeros` channels after the written ones get 0 (a packed gradient's unused channel, written
    // here rather than by a fill of the whole tensor first).
    for ch in 0..usize::cast_from(zeros) {
        gsrc[gb + (usize::cast_from(c) + ch) * gcs] = 0.0f32;
    }
}

/// A texel index of a `[D, C, h, w]` iteration with channels fastest (the layout a convolution reads)
/// split into `(d, y, x, ch)`.
#[cube]
fn channels_fastest(pos: usize, c: usize, h: usize, w: usize) -> (usize, usize, usize, usize) {
    let ch = pos % c;
    let pix = pos / c;
    (pix / (w * h), (pix / w) % h, pix % w, ch)
}

/// The max over the `k_n` views of plane `d` of `f` (view `k`'s plane at `k * d_n + d`; `fb` the
/// texel's offset within a plane) and the first view that holds it.
#[cube]
fn view_argmax(f: &Tensor<f32>, fb: usize, d: usize, d_n: usize, k_n: usize) -> (f32, usize) {
    let mut m = f[fb + d * f.stride(0)];
    let mut first = 0usize;
    for k in 1..k_n {
        let v = f[fb + (k * d_n + d) * f.stride(0)];
        if v > m {
            m = v;
            first = k;
        }
    }
    (m, first)
}

/// The max over views of `f` `[K*D, C, h, w]` (view-major: plane `d` of view `k` at `k*D + d`): where
/// `keep`, `out` `[K*D, 2C, h, w]` holds `f` in channels `..C` and the max (broadcast to every view) in
/// channels `C..` (a stage's input: the concatenation of the views' features with their max), else
/// `out` `[D, C, h, w]` holds the max. One thread per `(d, y, x, c)`, channels fastest (the layout a
/// convolution reads).
#[cube(launch)]
pub(super) fn view_max_kernel(f: &Tensor<f32>, out: &mut Tensor<f32>, views: u32, keep: u32) {
    let (kd, c, h, w) = (f.shape(0), f.shape(1), f.shape(2), f.shape(3));
    let k_n = usize::cast_from(views);
    let d_n = kd / k_n;
    let pos = ABSOLUTE_POS;
    if pos >= d_n * h * w * c {
        terminate!();
    }
    let (d, y, x, ch) = channels_fastest(pos, c, h, w);
    let fb = ch * f.stride(1) + y * f.stride(2) + x * f.stride(3);
    let ob = y * out.stride(2) + x * out.stride(3);
    let (o0, o1) = (out.stride(0), out.stride(1));
    let (m, _) = view_argmax(f, fb, d, d_n, k_n);
    if keep == 1 {
        for k in 0..k_n {
            let p = k * d_n + d;
            out[ob + p * o0 + ch * o1] = f[fb + p * f.stride(0)];
            out[ob + p * o0 + (c + ch) * o1] = m;
        }
    } else {
        out[ob + d * o0 + ch * o1] = m;
    }
}

/// The gradient of [`view_max_kernel`] at `f`, given the output's `grad`: where `keep`, `grad`'s first
/// `C` channels pass through and its last `C` (the max's copies) are summed over the views; the max's
/// gradient goes to the first view that holds the maximum (as the CPU engine routes it).
#[cube(launch)]
pub(super) fn view_max_backward_kernel(
    f: &Tensor<f32>,
    grad: &Tensor<f32>,
    gin: &mut Tensor<f32>,
    views: u32,
    keep: u32,
) {
    let (kd, c, h, w) = (f.shape(0), f.shape(1), f.shape(2), f.shape(3));
    let k_n = usize::cast_from(views);
    let d_n = kd / k_n;
    let pos = ABSOLUTE_POS;
    if pos >= d_n * h * w * c {
        terminate!();
    }
    let (d, y, x, ch) = channels_fastest(pos, c, h, w);
    let fb = ch * f.stride(1) + y * f.stride(2) + x * f.stride(3);
    let gb = y * grad.stride(2) + x * grad.stride(3);
    let ib = ch * gin.stride(1) + y * gin.stride(2) + x * gin.stride(3);
    let i0 = gin.stride(0);
    let (_, first) = view_argmax(f, fb, d, d_n, k_n);
    let mut gm = 0.0f32;
    if keep == 1 {
        for k in 0..k_n {
            gm += grad[gb + (k * d_n + d) * grad.stride(0) + (c + ch) * grad.stride(1)];
        }
    } else {
        gm = grad[gb + d * grad.stride(0) + ch * grad.stride(1)];
    }
    for k in 0..k_n {
        let p = k * d_n + d;
        let mut g = 0.0f32;
        if keep == 1 {
            g = grad[gb + p * grad.stride(0) + ch * grad.stride(1)];
        }
        if k == first {
            g += gm;
        }
        gin[ib + p * i0] = g;
    }
}

/// The logistic function as burn computes it (`1 / (1 + exp(-x))`).
#[cube]
fn logistic(x: f32) -> f32 {
    1.0f32 / (1.0f32 + (-x).exp())
}

/// The state's RGBA ([`crate::network::state_to_rgba`]): `state` `[D, S, h, w]` -> `out` `[D, 4, h, w]`,
/// the sigmoid of channels `..4` with the colour premultiplied by the alpha. One thread per texel.
#[cube(launch)]
pub(super) fn state_rgba_kernel(state: &Tensor<f32>, out: &mut Tensor<f32>) {
    let (d, h, w) = (out.shape(0), out.shape(2), out.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= d * h * w {
        terminate!();
    }
    let x = pos % w;
    let y = (pos / w) % h;
    let p = pos / (w * h);
    let sb = p * state.stride(0) + y * state.stride(2) + x * state.stride(3);
    let ob = p * out.stride(0) + y * out.stride(2) + x * out.stride(3);
    let (s1, o1) = (state.stride(1), out.stride(1));
    let a = logistic(state[sb + 3 * s1]);
    for c in 0..3usize {
        out[ob + c * o1] = logistic(state[sb + c * s1]) * a;
    }
    out[ob + 3 * o1] = a;
}

/// The gradient of [`state_rgba_kernel`] at the state `[D, S, h, w]` (zero beyond channel 3), given the
/// output's `grad`.
#[cube(launch)]
pub(super) fn state_rgba_backward_kernel(
    state: &Tensor<f32>,
    grad: &Tensor<f32>,
    gin: &mut Tensor<f32>,
) {
    let (d, sc, h, w) = (gin.shape(0), gin.shape(1), gin.shape(2), gin.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= d * h * w {
        terminate!();
    }
    let x = pos % w;
    let y = (pos / w) % h;
    let p = pos / (w * h);
    let sb = p * state.stride(0) + y * state.stride(2) + x * state.stride(3);
    let gb = p * grad.stride(0) + y * grad.stride(2) + x * grad.stride(3);
    let ib = p * gin.stride(0) + y * gin.stride(2) + x * gin.stride(3);
    let (s1, g1, i1) = (state.stride(1), grad.stride(1), gin.stride(1));
    let a = logistic(state[sb + 3 * s1]);
    let mut ga = grad[gb + 3 * g1];
    for c in 0..3usize {
        let v = logistic(state[sb + c * s1]);
        let g = grad[gb + c * g1];
        ga += g * v;
        gin[ib + c * i1] = g * a * (v * (1.0f32 - v));
    }
    gin[ib + 3 * i1] = ga * (a * (1.0f32 - a));
    for c in 4..sc {
        gin[ib + c * i1] = 0.0f32;
    }
}

/// An update net's input: `x` `[K*D, Cv, h, w]` (the views' components, view-major) with the state `[D,
/// S, h, w]` beside each view's planes -> `out` `[K*D, Cv + S, h, w]`. One thread per output texel and
/// channel, channels fastest (the layout a convolution reads).
#[cube(launch)]
pub(super) fn append_state_kernel(x: &Tensor<f32>, state: &Tensor<f32>, out: &mut Tensor<f32>) {
    let (kd, cv, h, w) = (x.shape(0), x.shape(1), x.shape(2), x.shape(3));
    let (d, sc) = (state.shape(0), state.shape(1));
    let ct = cv + sc;
    let pos = ABSOLUTE_POS;
    if pos >= kd * h * w * ct {
        terminate!();
    }
    let (p, y, xx, ch) = channels_fastest(pos, ct, h, w);
    let q = p % d;
    let v = if ch < cv {
        x[p * x.stride(0) + ch * x.stride(1) + y * x.stride(2) + xx * x.stride(3)]
    } else {
        state[q * state.stride(0)
            + (ch - cv) * state.stride(1)
            + y * state.stride(2)
            + xx * state.stride(3)]
    };
    let o = p * out.stride(0) + ch * out.stride(1) + y * out.stride(2) + xx * out.stride(3);
    out[o] = v;
}

/// The gradients of [`append_state_kernel`] from the output's `grad` `[K*D, Cv + S, h, w]`: `gx` its first
/// `Cv` channels, `gs` `[D, S, h, w]` the sum over the views of the rest (in view order).
#[cube(launch)]
pub(super) fn append_state_backward_kernel(
    grad: &Tensor<f32>,
    gx: &mut Tensor<f32>,
    gs: &mut Tensor<f32>,
) {
    let (kd, ct, h, w) = (grad.shape(0), grad.shape(1), grad.shape(2), grad.shape(3));
    let (d, sc) = (gs.shape(0), gs.shape(1));
    let cv = ct - sc;
    let k_n = kd / d;
    let pos = ABSOLUTE_POS;
    if pos >= d * h * w * ct {
        terminate!();
    }
    let (q, y, xx, ch) = channels_fastest(pos, ct, h, w);
    let gb = ch * grad.stride(1) + y * grad.stride(2) + xx * grad.stride(3);
    let g0 = grad.stride(0);
    if ch < cv {
        let xb = ch * gx.stride(1) + y * gx.stride(2) + xx * gx.stride(3);
        let x0 = gx.stride(0);
        for k in 0..k_n {
            let p = k * d + q;
            gx[xb + p * x0] = grad[gb + p * g0];
        }
    } else {
        let mut acc = 0.0f32;
        for k in 0..k_n {
            acc += grad[gb + (k * d + q) * g0];
        }
        let sb = q * gs.stride(0) + (ch - cv) * gs.stride(1) + y * gs.stride(2) + xx * gs.stride(3);
        gs[sb] = acc;
    }
}

/// A copy of the rank-4 `src` into `out` of the same shape and another layout: one thread per element,
/// each tensor indexed through its strides.
#[cube(launch)]
pub(super) fn relayout_kernel(src: &Tensor<f32>, out: &mut Tensor<f32>) {
    let (a, b, c, d) = (src.shape(0), src.shape(1), src.shape(2), src.shape(3));
    let i = ABSOLUTE_POS;
    if i >= a * b * c * d {
        terminate!();
    }
    let (i3, r3) = (i % d, i / d);
    let (i2, r2) = (r3 % c, r3 / c);
    let (i1, i0) = (r2 % b, r2 / b);
    let si = i0 * src.stride(0) + i1 * src.stride(1) + i2 * src.stride(2) + i3 * src.stride(3);
    let oi = i0 * out.stride(0) + i1 * out.stride(1) + i2 * out.stride(2) + i3 * out.stride(3);
    out[oi] = src[si];
}

/// The nets' activation, element-wise over the buffers of two tensors of one dense layout: `x` where
/// `x > 0`, elsewhere `exp(x) - 1` (ELU with alpha 1, burn's `elu`) or, where `relu` is 1, 0 (burn's
/// `relu`: VGG's).
#[cube(launch)]
pub(super) fn act_kernel(x: &Tensor<f32>, out: &mut Tensor<f32>, relu: u32) {
    let i = ABSOLUTE_POS;
    if i >= out.len() {
        terminate!();
    }
    let v = x[i];
    let mut y = v;
    if v <= 0.0f32 {
        y = 0.0f32;
        if relu == 0 {
            y = v.exp() - 1.0f32;
        }
    }
    out[i] = y;
}

/// The gradient of [`act_kernel`] from its output `y`: `grad` where `y > 0`, elsewhere `grad * (y + 1)`
/// (ELU's `grad * exp(x)`) or 0 (ReLU's).
#[cube(launch)]
pub(super) fn act_backward_kernel(
    y: &Tensor<f32>,
    grad: &Tensor<f32>,
    gin: &mut Tensor<f32>,
    relu: u32,
) {
    let i = ABSOLUTE_POS;
    if i >= gin.len() {
        terminate!();
    }
    let v = y[i];
    let mut d = 1.0f32;
    if v <= 0.0f32 {
        d = 0.0f32;
        if relu == 0 {
            d = v + 1.0f32;
        }
    }
    gin[i] = grad[i] * d;
}

/// One Adam step of each of several parameters in one dispatch: cube row `k` (`CUBE_POS_Y`) steps
/// parameter `ps[k]` (dense, its moments in its layout, the gradient read through its own strides)
/// into `p_outs[k]`, `m_outs[k]` and `v_outs[k]`, one unit per element, every parameter with the same
/// step scalars, burn's `Adam` arithmetic in its order: `m' = m b1 + g (1 - b1)`,
/// `v' = v b2 + g^2 (1 - b2)`, `p' = p - (m' c) / (sqrt(v') + e) lr` (`c` and `e` the step's bias
/// corrections, computed on the host; `g` the clipped gradient, rounded as burn's scaling of it would
/// be).
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(super) fn adam_many_kernel(
    ps: &Sequence<OwnedTensor<f32>>,
    gs: &Sequence<OwnedTensor<f32>>,
    ms: &Sequence<OwnedTensor<f32>>,
    vs: &Sequence<OwnedTensor<f32>>,
    p_outs: &mut Sequence<OwnedTensor<f32>>,
    m_outs: &mut Sequence<OwnedTensor<f32>>,
    v_outs: &mut Sequence<OwnedTensor<f32>>,
    beta_1: f32,
    factor_1: f32,
    beta_2: f32,
    factor_2: f32,
    combined: f32,
    epsilon: f32,
    lr: f32,
    grad_scale: f32,
) {
    let which = CUBE_POS_Y as usize;
    let i = (CUBE_POS_X * CUBE_DIM_X + UNIT_POS_X) as usize;
    #[unroll]
    for k in 0..ps.len() {
        if which == k {
            let p = ps.index(k);
            let mut n = 1usize;
            for d in 0..p.rank() {
                n *= p.shape(d);
            }
            if i < n {
                let g = gs.index(k);
                let mut gi_at = 0usize;
                for d in 0..p.rank() {
                    gi_at += ((i / p.stride(d)) % p.shape(d)) * g.stride(d);
                }
                let gi = g[gi_at] * grad_scale;
                let m1 = ms.index(k)[i] * beta_1 + gi * factor_1;
                let v1 = vs.index(k)[i] * beta_2 + (gi * gi) * factor_2;
                let p1 = p[i] - ((m1 * combined) / (v1.sqrt() + epsilon)) * lr;
                let mo = m_outs.index_mut(k);
                mo[i] = m1;
                let vo = v_outs.index_mut(k);
                vo[i] = v1;
                let po = p_outs.index_mut(k);
                po[i] = p1;
            }
        }
    }
}

/// `i` reflected into `0..n` as reflection padding reads it (the edge not repeated: `-1 -> 1`,
/// `n -> n - 2`; for `|i|` under `n` outside `0..n`).
#[cube]
fn reflect_index(i: i32, n: i32) -> i32 {
    let mut j = i;
    if j < 0 {
        j = -j;
    }
    if j >= n {
        j = 2 * (n - 1) - j;
    }
    j
}

/// The feature loss's input: `a` and `b` `[n, C, h, w]`, each reflect-padded by `ph` rows and `pw`
/// columns per side, concatenated into `out` `[2n, C, h + 2ph, w + 2pw]` (`a`'s examples first), each
/// value mapped as `v * scale - offset[c]`, read from channel `C - 1 - c` where `reverse` (VGG's
/// preprocessing: RGB to BGR, the 0..255 scale, the mean removed). One thread per output texel and
/// channel, channels fastest (the layout a convolution reads).
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(super) fn reflect_pad_pair_kernel(
    a: &Tensor<f32>,
    b: &Tensor<f32>,
    out: &mut Tensor<f32>,
    ph: u32,
    pw: u32,
    scale: f32,
    offset: &Tensor<f32>,
    reverse: u32,
) {
    let (n2, c, oh, ow) = (out.shape(0), out.shape(1), out.shape(2), out.shape(3));
    let (h, w) = (a.shape(2), a.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= n2 * c * oh * ow {
        terminate!();
    }
    let (e, y, x, ch) = channels_fastest(pos, c, oh, ow);
    let n = n2 / 2;
    let sy = usize::cast_from(reflect_index(
        i32::cast_from(y) - i32::cast_from(ph),
        i32::cast_from(h),
    ));
    let sx = usize::cast_from(reflect_index(
        i32::cast_from(x) - i32::cast_from(pw),
        i32::cast_from(w),
    ));
    let mut sc = ch;
    if reverse == 1 {
        sc = c - 1 - ch;
    }
    let v = if e < n {
        a[e * a.stride(0) + sc * a.stride(1) + sy * a.stride(2) + sx * a.stride(3)]
    } else {
        b[(e - n) * b.stride(0) + sc * b.stride(1) + sy * b.stride(2) + sx * b.stride(3)]
    };
    let o = e * out.stride(0) + ch * out.stride(1) + y * out.stride(2) + x * out.stride(3);
    out[o] = v * scale - offset[ch];
}

/// The padded rows (or columns) of a padding by `p` of `n` that read source row `s` (as
/// [`reflect_index`] maps them): `s + p`, its mirror above the top (`p - s`, for `1 <= s <= p`) and
/// below the bottom (`2(n - 1) - s + p`, for `n - 1 - p <= s <= n - 2`); -1 where there is none.
#[cube]
fn reflect_sources(s: i32, n: i32, p: i32) -> Array<i32> {
    let mut r = Array::<i32>::new(3usize);
    r[0] = s + p;
    r[1] = -1i32;
    r[2] = -1i32;
    if s >= 1 && s <= p {
        r[1] = p - s;
    }
    if s >= n - 1 - p && s <= n - 2 {
        r[2] = 2 * (n - 1) - s + p;
    }
    r
}

/// The gradient of [`reflect_pad_pair_kernel`] at one of its inputs (`e0`: 0 for `a`, `n` for `b`):
/// each texel of `gin` `[n, C, h, w]` sums the output gradient `grad` `[2n, C, h + 2ph, w + 2pw]` at
/// the (up to 3 x 3) padded positions that read it (in the channel it was moved to), times `scale`.
/// One thread per texel, no atomics.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(super) fn reflect_pad_backward_kernel(
    grad: &Tensor<f32>,
    gin: &mut Tensor<f32>,
    e0: u32,
    ph: u32,
    pw: u32,
    scale: f32,
    reverse: u32,
) {
    let (n, c, h, w) = (gin.shape(0), gin.shape(1), gin.shape(2), gin.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= n * c * h * w {
        terminate!();
    }
    let x = pos % w;
    let y = (pos / w) % h;
    let ch = (pos / (w * h)) % c;
    let e = pos / (w * h * c);
    let rows = reflect_sources(i32::cast_from(y), i32::cast_from(h), i32::cast_from(ph));
    let cols = reflect_sources(i32::cast_from(x), i32::cast_from(w), i32::cast_from(pw));
    let mut gc = ch;
    if reverse == 1 {
        gc = c - 1 - ch;
    }
    let gb = (usize::cast_from(e0) + e) * grad.stride(0) + gc * grad.stride(1);
    let (g2, g3) = (grad.stride(2), grad.stride(3));
    let mut acc = 0.0f32;
    for i in 0..3usize {
        if rows[i] >= 0 {
            let rb = gb + usize::cast_from(rows[i]) * g2;
            for j in 0..3usize {
                if cols[j] >= 0 {
                    acc += grad[rb + usize::cast_from(cols[j]) * g3];
                }
            }
        }
    }
    let o = e * gin.stride(0) + ch * gin.stride(1) + y * gin.stride(2) + x * gin.stride(3);
    gin[o] = acc * scale;
}

/// The sum of `s` over the 256 units of a cube (`u` this unit's position), valid at unit 0: a tree in
/// shared memory. Every unit must call it (it synchronises the cube).
#[cube]
fn cube_sum(s: f32, u: usize) -> f32 {
    let mut shared = Shared::<[f32]>::new_slice(256usize);
    shared[u] = s;
    sync_cube();
    for k in 0..8u32 {
        let half = usize::cast_from(128u32 >> k);
        if u < half {
            shared[u] += shared[u + half];
        }
        sync_cube();
    }
    shared[0]
}

/// The sums of the squares of several dense buffers in one dispatch: cube `k` of 256 units sums the
/// squares of `ts[k]` (each unit a strided share, then a tree in shared memory) into element
/// `first + k` of `acc` (the gradients' shares of the global norm, as many per
/// launch as the device binds buffers).
#[cube(launch)]
pub(super) fn sum_squares_many_kernel(
    ts: &Sequence<OwnedTensor<f32>>,
    acc: &mut Tensor<f32>,
    first: u32,
) {
    let u = UNIT_POS_X as usize;
    let threads = CUBE_DIM_X as usize;
    let which = CUBE_POS_X as usize;
    let mut s = 0.0f32;
    #[unroll]
    for k in 0..ts.len() {
        if which == k {
            let t = ts.index(k);
            let mut len = 1usize;
            for d in 0..t.rank() {
                len *= t.shape(d);
            }
            let mut i = u;
            while i < len {
                let v = t[i];
                s += v * v;
                i += threads;
            }
        }
    }
    let total = cube_sum(s, u);
    if u == 0 {
        acc[usize::cast_from(first) + which] = total;
    }
}

/// A window of `x` `[N, C, h, w]`: `out` `[N, C, oh, ow]` holds rows `y0..` and columns `x0..` of `x`
/// (any strides both). One thread per output value, channels fastest.
#[cube(launch)]
pub(super) fn crop_kernel(x: &Tensor<f32>, out: &mut Tensor<f32>, y0: u32, x0: u32) {
    let (n, c, oh, ow) = (out.shape(0), out.shape(1), out.shape(2), out.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= n * c * oh * ow {
        terminate!();
    }
    let (e, y, xx, ch) = channels_fastest(pos, c, oh, ow);
    let (y0, x0) = (usize::cast_from(y0), usize::cast_from(x0));
    let i = e * x.stride(0) + ch * x.stride(1) + (y + y0) * x.stride(2) + (xx + x0) * x.stride(3);
    let o = e * out.stride(0) + ch * out.stride(1) + y * out.stride(2) + xx * out.stride(3);
    out[o] = x[i];
}

/// The gradient of [`crop_kernel`] at its input: `gin` `[N, C, h, w]` is `grad` `[N, C, oh, ow]` at
/// rows `y0..` and columns `x0..`, zero elsewhere. One thread per input value, channels fastest.
#[cube(launch)]
pub(super) fn crop_backward_kernel(grad: &Tensor<f32>, gin: &mut Tensor<f32>, y0: u32, x0: u32) {
    let (n, c, h, w) = (gin.shape(0), gin.shape(1), gin.shape(2), gin.shape(3));
    let (oh, ow) = (grad.shape(2), grad.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= n * c * h * w {
        terminate!();
    }
    let (e, y, x, ch) = channels_fastest(pos, c, h, w);
    let (y0, x0) = (usize::cast_from(y0), usize::cast_from(x0));
    let mut g = 0.0f32;
    if y >= y0 && y < y0 + oh && x >= x0 && x < x0 + ow {
        g = grad[e * grad.stride(0)
            + ch * grad.stride(1)
            + (y - y0) * grad.stride(2)
            + (x - x0) * grad.stride(3)];
    }
    let o = e * gin.stride(0) + ch * gin.stride(1) + y * gin.stride(2) + x * gin.stride(3);
    gin[o] = g;
}

/// A convolution's bias gradient: `out[c]` = the sum of `g` `[N, C, h, w]` (any strides: a
/// convolution's output gradient comes channels-last) over everything but its channel. One cube of 256
/// units per channel, each summing a strided share, then a tree in shared memory (burn: a contiguous
/// copy, then its reduction).
#[cube(launch)]
pub(super) fn bias_grad_kernel(g: &Tensor<f32>, out: &mut Tensor<f32>) {
    let c = CUBE_POS_X as usize;
    let u = UNIT_POS_X as usize;
    let threads = CUBE_DIM_X as usize;
    let (h, w) = (g.shape(2), g.shape(3));
    let m = g.shape(0) * h * w;
    let (s0, s1, s2, s3) = (g.stride(0), g.stride(1), g.stride(2), g.stride(3));
    let base = c * s1;
    let mut s = 0.0f32;
    let mut j = u;
    while j < m {
        let e = j / (h * w);
        let r = j % (h * w);
        s += g[base + e * s0 + (r / w) * s2 + (r % w) * s3];
        j += threads;
    }
    let total = cube_sum(s, u);
    if u == 0 {
        out[c] = total;
    }
}

/// The L1 distance between the two halves of `f` `[2n, C, h, w]` per example, scaled: `out[e]` =
/// `scale * sum |f[e] - f[n + e]|` over its `C x h x w` values (the feature loss's weighted per-layer
/// term). One cube of
/// 256 units per example, each summing a strided share (channels fastest), then a tree in shared
/// memory.
#[cube(launch)]
pub(super) fn pair_l1_kernel(f: &Tensor<f32>, out: &mut Tensor<f32>, scale: f32) {
    let (c, h, w) = (f.shape(1), f.shape(2), f.shape(3));
    let n = f.shape(0) / 2;
    let e = CUBE_POS_X as usize;
    let u = UNIT_POS_X as usize;
    let threads = CUBE_DIM_X as usize;
    let m = c * h * w;
    let (s0, s1, s2, s3) = (f.stride(0), f.stride(1), f.stride(2), f.stride(3));
    let mut s = 0.0f32;
    let mut j = u;
    while j < m {
        let (_, y, x, ch) = channels_fastest(j, c, h, w);
        let o = ch * s1 + y * s2 + x * s3;
        s += (f[e * s0 + o] - f[(n + e) * s0 + o]).abs();
        j += threads;
    }
    let total = cube_sum(s, u);
    if u == 0 {
        out[e] = total * scale;
    }
}

/// The gradient of [`pair_l1_kernel`] at `f`, given the output's `grad` `[n]`: `sign(d) * grad[e] * scale` for
/// the first half and its negation for the second, `d = f[e] - f[n + e]` (0 where `d` is: burn's `abs`).
/// One thread per pair of values.
#[cube(launch)]
pub(super) fn pair_l1_backward_kernel(
    f: &Tensor<f32>,
    grad: &Tensor<f32>,
    gin: &mut Tensor<f32>,
    scale: f32,
) {
    let (c, h, w) = (f.shape(1), f.shape(2), f.shape(3));
    let n = f.shape(0) / 2;
    let m = c * h * w;
    let pos = ABSOLUTE_POS;
    if pos >= n * m {
        terminate!();
    }
    let (e, y, x, ch) = channels_fastest(pos, c, h, w);
    let s0 = f.stride(0);
    let o = ch * f.stride(1) + y * f.stride(2) + x * f.stride(3);
    let d = f[e * s0 + o] - f[(n + e) * s0 + o];
    let mut g = 0.0f32;
    if d > 0.0f32 {
        g = grad[e] * scale;
    }
    if d < 0.0f32 {
        g = -(grad[e] * scale);
    }
    let i0 = gin.stride(0);
    let oi = ch * gin.stride(1) + y * gin.stride(2) + x * gin.stride(3);
    gin[e * i0 + oi] = g;
    gin[(n + e) * i0 + oi] = -g;
}

/// A convolution's weights `w` `[O, I, kh, kw]` as the weights of its gradient at the input (a
/// convolution of the output's gradient, for stride 1): `out` `[I, O, kh, kw]`, out[i, o, y, x] =
/// w[o, i, kh - 1 - y, kw - 1 - x]. One thread per weight, channels fastest (`out` is channels-last).
#[cube(launch)]
pub(super) fn flip_transpose_kernel(w: &Tensor<f32>, out: &mut Tensor<f32>) {
    let (ni, no, kh, kw) = (out.shape(0), out.shape(1), out.shape(2), out.shape(3));
    let pos = ABSOLUTE_POS;
    if pos >= ni * no * kh * kw {
        terminate!();
    }
    let (i, y, x, o) = channels_fastest(pos, no, kh, kw);
    let src =
        o * w.stride(0) + i * w.stride(1) + (kh - 1 - y) * w.stride(2) + (kw - 1 - x) * w.stride(3);
    let dst = i * out.stride(0) + o * out.stride(1) + y * out.stride(2) + x * out.stride(3);
    out[dst] = w[src];
}
