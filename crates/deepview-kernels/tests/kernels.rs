//! The kernels against direct f64 evaluations of the convolution's definition (zero padding).

use deepview_kernels::{
    Act, Isa, PackedConv, Plane, conv3x3, conv3x3_from, conv3x3_input_grad, conv3x3_weight_grad,
    elu_backward,
};

/// Deterministic values in [-1, 1).
fn noise(n: usize, seed: u64) -> Vec<f32> {
    let mut s = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (0..n)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        })
        .collect()
}

/// `[c][h][w]` images -> padded planes.
fn padded(plane: Plane, img: &[f32], c: usize) -> Vec<Vec<f32>> {
    (0..c)
        .map(|k| {
            let mut p = plane.zeroed();
            plane.pad_into(&img[k * plane.h * plane.w..][..plane.h * plane.w], &mut p);
            p
        })
        .collect()
}

fn unpadded(plane: Plane, planes: &[Vec<f32>]) -> Vec<f32> {
    let mut out = vec![0f32; planes.len() * plane.h * plane.w];
    for (k, p) in planes.iter().enumerate() {
        plane.unpad_into(p, &mut out[k * plane.h * plane.w..][..plane.h * plane.w]);
        // The border stays zero.
        for (i, &v) in p.iter().enumerate() {
            let inside = (0..plane.h).any(|y| {
                let r = plane.index(y, 0);
                (r..r + plane.w).contains(&i)
            });
            assert!(inside || v == 0.0, "non-zero border value {v} at {i}");
        }
    }
    out
}

fn reference(
    x: &[f32],
    w: &[f32],
    b: &[f32],
    cin: usize,
    cout: usize,
    h: usize,
    wd: usize,
    act: Act,
) -> Vec<f64> {
    let mut out = vec![0f64; cout * h * wd];
    for co in 0..cout {
        for y in 0..h {
            for xx in 0..wd {
                let mut s = b[co] as f64;
                for ci in 0..cin {
                    for ky in 0..3 {
                        for kx in 0..3 {
                            let (sy, sx) =
                                (y as isize + ky as isize - 1, xx as isize + kx as isize - 1);
                            if sy < 0 || sx < 0 || sy >= h as isize || sx >= wd as isize {
                                continue;
                            }
                            s += w[((co * cin + ci) * 3 + ky) * 3 + kx] as f64
                                * x[(ci * h + sy as usize) * wd + sx as usize] as f64;
                        }
                    }
                }
                out[(co * h + y) * wd + xx] = match act {
                    Act::Linear => s,
                    Act::Elu if s > 0.0 => s,
                    Act::Elu => s.exp_m1(),
                    Act::Relu => s.max(0.0),
                };
            }
        }
    }
    out
}

fn max_rel(got: &[f32], want: &[f64]) -> f64 {
    let scale = want.iter().fold(1e-6f64, |m, v| m.max(v.abs()));
    got.iter()
        .zip(want)
        .map(|(&g, &w)| (g as f64 - w).abs() / scale)
        .fold(0.0, f64::max)
}

const SHAPES: [(usize, usize, usize, usize); 7] = [
    (4, 8, 17, 23),
    (16, 8, 40, 40),
    (19, 8, 5, 3),
    (8, 64, 9, 31),
    (64, 16, 12, 7),
    (3, 5, 1, 1),
    (7, 13, 33, 2),
];

/// Run `check` on every kernel path this machine has: AVX-512, AVX2 and portable.
fn every_isa(check: fn()) {
    for cap in [Isa::Avx512, Isa::Avx2, Isa::Portable] {
        if deepview_kernels::detected() >= cap {
            deepview_kernels::with_isa_cap(cap, check);
        }
    }
}

#[test]
fn forward_matches_the_definition() {
    every_isa(forward_check);
}

#[test]
fn gradients_match_the_definition() {
    every_isa(gradient_check);
}

fn forward_check() {
    for (n, &(cin, cout, h, w)) in SHAPES.iter().enumerate() {
        let plane = Plane::new(h, w);
        let x = noise(cin * h * w, n as u64);
        let wt = noise(cout * cin * 9, 100 + n as u64);
        let b = noise(cout, 200 + n as u64);
        let conv = PackedConv::new(&wt, Some(&b), cout, cin);
        let xin = padded(plane, &x, cin);
        for act in [Act::Linear, Act::Elu, Act::Relu] {
            let mut outs: Vec<Vec<f32>> = (0..cout).map(|_| plane.zeroed()).collect();
            // Garbage in the outputs must not matter.
            for o in outs.iter_mut() {
                o.iter_mut().for_each(|v| *v = 7.0);
            }
            {
                let ins: Vec<&[f32]> = xin.iter().map(|v| v.as_slice()).collect();
                let mut os: Vec<&mut [f32]> = outs.iter_mut().map(|v| v.as_mut_slice()).collect();
                conv3x3(plane, &ins, &conv, act, &mut os);
            }
            // Front slack and top border row were not written by the kernel: zero them like a fresh
            // buffer would be.
            for o in outs.iter_mut() {
                o[..plane.start()].fill(0.0);
            }
            let got = unpadded(plane, &outs);
            let want = reference(&x, &wt, &b, cin, cout, h, w, act);
            let e = max_rel(&got, &want);
            assert!(
                e < 1e-5,
                "{cin}->{cout} {h}x{w} {act:?}: relative error {e}"
            );
        }
    }
}

#[test]
fn split_sums_match_the_definition() {
    every_isa(split_check);
}

/// A convolution computed in two parts, the input channels `split..` first (with the bias, linear) and
/// then `..split` from those sums ([`conv3x3_from`]), against the definition of the whole convolution.
fn split_check() {
    for (n, &(cin, cout, h, w)) in SHAPES.iter().enumerate() {
        if cin < 2 {
            continue;
        }
        let split = cin / 2 + 1;
        let plane = Plane::new(h, w);
        let x = noise(cin * h * w, 300 + n as u64);
        let wt = noise(cout * cin * 9, 400 + n as u64);
        let b = noise(cout, 500 + n as u64);
        let shared = PackedConv::input_range(&wt, Some(&b), cout, cin, split..cin);
        let own = PackedConv::input_range(&wt, None, cout, cin, 0..split);
        assert_eq!((own.cin, shared.cin), (split, cin - split));
        let xin = padded(plane, &x, cin);
        let ins: Vec<&[f32]> = xin.iter().map(|v| v.as_slice()).collect();
        let mut part: Vec<Vec<f32>> = (0..cout).map(|_| plane.zeroed()).collect();
        {
            let mut os: Vec<&mut [f32]> = part.iter_mut().map(|v| v.as_mut_slice()).collect();
            conv3x3(plane, &ins[split..], &shared, Act::Linear, &mut os);
        }
        let init: Vec<&[f32]> = part.iter().map(|v| v.as_slice()).collect();
        for act in [Act::Linear, Act::Elu, Act::Relu] {
            let mut outs: Vec<Vec<f32>> = (0..cout).map(|_| plane.zeroed()).collect();
            {
                let mut os: Vec<&mut [f32]> = outs.iter_mut().map(|v| v.as_mut_slice()).collect();
                conv3x3_from(plane, &ins[..split], &own, act, &init, &mut os);
            }
            let got = unpadded(plane, &outs);
            let want = reference(&x, &wt, &b, cin, cout, h, w, act);
            let e = max_rel(&got, &want);
            assert!(
                e < 1e-5,
                "split {cin}->{cout} {h}x{w} {act:?}: relative error {e}"
            );
        }
    }
}

fn gradient_check() {
    for (n, &(cin, cout, h, w)) in SHAPES.iter().enumerate() {
        let plane = Plane::new(h, w);
        let x = noise(cin * h * w, 300 + n as u64);
        let wt = noise(cout * cin * 9, 400 + n as u64);
        let g = noise(cout * h * w, 500 + n as u64);
        let xin = padded(plane, &x, cin);
        let gin = padded(plane, &g, cout);
        // Input gradient: gx[ci](p) = sum_co sum_t w[co][ci][t] g[co](p - tap_t).
        let t = PackedConv::transposed(&wt, cout, cin);
        let mut gx: Vec<Vec<f32>> = (0..cin).map(|_| plane.zeroed()).collect();
        {
            let gs: Vec<&[f32]> = gin.iter().map(|v| v.as_slice()).collect();
            let mut os: Vec<&mut [f32]> = gx.iter_mut().map(|v| v.as_mut_slice()).collect();
            conv3x3_input_grad(plane, &gs, &t, &mut os);
        }
        let got = unpadded(plane, &gx);
        let mut want = vec![0f64; cin * h * w];
        for ci in 0..cin {
            for y in 0..h {
                for xx in 0..w {
                    let mut s = 0f64;
                    for co in 0..cout {
                        for ky in 0..3 {
                            for kx in 0..3 {
                                let (oy, ox) =
                                    (y as isize - ky as isize + 1, xx as isize - kx as isize + 1);
                                if oy < 0 || ox < 0 || oy >= h as isize || ox >= w as isize {
                                    continue;
                                }
                                s += wt[((co * cin + ci) * 3 + ky) * 3 + kx] as f64
                                    * g[(co * h + oy as usize) * w + ox as usize] as f64;
                            }
                        }
                    }
                    want[(ci * h + y) * w + xx] = s;
                }
            }
        }
        let e = max_rel(&got, &want);
        assert!(
            e < 1e-5,
            "input grad {cin}->{cout} {h}x{w}: relative error {e}"
        );

        // Weight and bias gradients.
        let mut gw = vec![0f32; cout * cin * 9];
        let mut gb = vec![0f32; cout];
        let xs: Vec<&[f32]> = xin.iter().map(|v| v.as_slice()).collect();
        let gs: Vec<&[f32]> = gin.iter().map(|v| v.as_slice()).collect();
        conv3x3_weight_grad(plane, &xs, &gs, &mut gw, &mut gb);
        let mut want_w = vec![0f64; cout * cin * 9];
        let mut want_b = vec![0f64; cout];
        for co in 0..cout {
            for y in 0..h {
                for xx in 0..w {
                    let gv = g[(co * h + y) * w + xx] as f64;
                    want_b[co] += gv;
                    for ci in 0..cin {
                        for ky in 0..3 {
                            for kx in 0..3 {
                                let (sy, sx) =
                                    (y as isize + ky as isize - 1, xx as isize + kx as isize - 1);
                                if sy < 0 || sx < 0 || sy >= h as isize || sx >= w as isize {
                                    continue;
                                }
                                want_w[((co * cin + ci) * 3 + ky) * 3 + kx] +=
                                    gv * x[(ci * h + sy as usize) * w + sx as usize] as f64;
                            }
                        }
                    }
                }
            }
        }
        let e = max_rel(&gw, &want_w);
        assert!(
            e < 1e-5,
            "weight grad {cin}->{cout} {h}x{w}: relative error {e}"
        );
        let e = max_rel(&gb, &want_b);
        assert!(
            e < 1e-5,
            "bias grad {cin}->{cout} {h}x{w}: relative error {e}"
        );
    }
}

#[test]
fn elu_backward_is_the_derivative() {
    let xs = [-3.0f32, -0.5, -1e-3, 0.0, 1e-3, 2.0];
    let mut g = [1.0f32; 6];
    let out: Vec<f32> = xs
        .iter()
        .map(|&x| if x > 0.0 { x } else { x.exp_m1() })
        .collect();
    elu_backward(&out, &mut g);
    for (x, d) in xs.iter().zip(g) {
        let want = if *x > 0.0 { 1.0 } else { x.exp() };
        assert!((d - want).abs() < 1e-6, "elu'({x}) = {d}, want {want}");
    }
}
