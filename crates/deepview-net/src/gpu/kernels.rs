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
