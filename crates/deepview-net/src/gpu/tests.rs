//! Our GPU kernels against burn's ops on the CPU, on `wgpu:cpu` (Mesa's lavapipe without a GPU):
//! `cargo test --release -p deepview-net --features wgpu gpu::`.

use crate::forward::{Composite, composite, composite_burn};
use burn::tensor::{Device, Tensor, TensorData};

fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap()
}

/// `t` with the same values laid out channels-last in memory, as a GPU convolution writes its output:
/// the output of an identity 1x1 convolution (differentiable, so gradients reach `t`).
fn channels_last_copy(t: Tensor<4>) -> Tensor<4> {
    let c = t.dims()[1];
    let eye: Vec<f32> = (0..c * c)
        .map(|i| if i / c == i % c { 1.0 } else { 0.0 })
        .collect();
    let w = Tensor::<4>::from_data(TensorData::new(eye, [c, c, 1, 1]), &t.device());
    let opts = burn::tensor::ops::ConvOptions::new([1, 1], [0, 0], [1, 1], 1);
    burn::tensor::module::conv2d(t, w, None, opts)
}

thread_local! {
    /// How many [`uniform`] draws this thread (this test: libtest runs each on a thread of its own)
    /// has made.
    static DRAWS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

/// Uniform values in `[lo, hi)` for a tensor of `dims`: a fixed sequence per test, the same every run
/// (burn's generator is one per process, drawn from by the tests running beside this one), so a
/// near-tie or a value at an activation's kink is there every run or never.
fn uniform<const D: usize>(dims: [usize; D], lo: f64, hi: f64) -> Vec<f32> {
    let n: usize = dims.iter().product();
    DRAWS.with(|k| {
        let mut s = (k.get() + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        k.set(k.get() + 1);
        (0..n)
            .map(|_| {
                // xorshift64*
                s ^= s >> 12;
                s ^= s << 25;
                s ^= s >> 27;
                let u = (s.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f64 / (1u64 << 24) as f64;
                (lo + (hi - lo) * u) as f32
            })
            .collect()
    })
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs()))
}

/// The over-composite kernel and its backward on wgpu equal burn's loop on the CPU (outputs and
/// gradients), with opaque and empty texels, for several plane counts and sizes.
#[test]
fn wgpu_composite_kernel_equals_burns_ops() {
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    for (d, h, w) in [(1, 3, 4), (5, 7, 9), (32, 13, 11)] {
        let px = h * w;
        let mut rgba = uniform([d, 4, h, w], 0.0, 1.0);
        for p in 0..d {
            for i in 0..px {
                let a = rgba[(p * 4 + 3) * px + i];
                for c in 0..3 {
                    rgba[(p * 4 + c) * px + i] *= a;
                }
            }
        }
        rgba[3 * px] = 1.0;
        rgba[3 * px + 1] = 0.0;
        let weights: Vec<Vec<f32>> = [3 * px, d * px, d * 3 * px]
            .iter()
            .map(|&n| uniform([n], -1.0, 1.0))
            .collect();
        let run = |dev: &Device, f: fn(Tensor<4>) -> Composite| {
            let ad = dev.clone().autodiff();
            let x = Tensor::<4>::from_data(TensorData::new(rgba.clone(), [d, 4, h, w]), &ad)
                .require_grad();
            let c = f(x.clone());
            let values = [
                to_vec(c.render.clone().inner()),
                to_vec(c.transmittance.clone().inner()),
                to_vec(c.accumulated.clone().inner()),
            ];
            let wt = |i: usize, dims: [usize; 4]| {
                Tensor::<4>::from_data(TensorData::new(weights[i].clone(), dims), &ad)
            };
            let loss = (c.render.reshape([1, 3, h, w]) * wt(0, [1, 3, h, w])).sum()
                + (c.transmittance * wt(1, [d, 1, h, w])).sum()
                + (c.accumulated * wt(2, [d, 3, h, w])).sum();
            let grads = loss.backward();
            (values, to_vec(x.grad(&grads).unwrap()))
        };
        let (want, want_grad) = run(&cpu, composite_burn);
        // On wgpu `composite` is the kernel (the test would pass through burn's ops otherwise: check).
        assert!(crate::gpu::gpu_kernels(&gpu));
        let (got, got_grad) = run(&gpu, composite);
        for (what, (a, b)) in ["render", "T", "A"].iter().zip(want.iter().zip(&got)) {
            let e = max_diff(a, b);
            assert!(e < 1e-6, "{what}, {d} planes {h}x{w}: {e}");
        }
        let e = max_diff(&want_grad, &got_grad);
        assert!(e < 1e-5, "gradient, {d} planes {h}x{w}: {e}");
    }
}

/// The agreement prior kernel on wgpu equals burn's ops on the CPU: views that see a point, one that does
/// (the single-view variance), none that does (transparent), and planes whose depth weights underflow.
#[test]
fn wgpu_prior_kernel_equals_burns_ops() {
    use crate::network::{agreement_prior_logits, agreement_prior_logits_burn};
    use deepview_mpi::agreement::Aggregation;
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let (k, d, h, w) = (4, 9, 6, 7);
    let px = h * w;
    let views: Vec<Vec<f32>> = (0..k)
        .map(|v| {
            // Fixed values (an LCG), so that a failure repeats.
            let mut state = 0x9e37_79b9u32.wrapping_mul(v as u32 + 1);
            let mut x: Vec<f32> = (0..d * 4 * px)
                .map(|_| {
                    state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    (state >> 8) as f32 / (1u32 << 24) as f32
                })
                .collect();
            for p in 0..d {
                for i in 0..px {
                    // Validity: pixel 0 seen by no view, pixel 1 by view 0 only, the rest mostly seen.
                    let m = &mut x[(p * 4 + 3) * px + i];
                    *m = match i {
                        0 => 0.0,
                        1 => f32::from(v == 0),
                        _ => f32::from(*m > 0.2),
                    };
                }
            }
            x
        })
        .collect();
    // Radius 0: the fused kernel; radius > 0: the cost, aggregation and alpha kernels.
    for (temperature, radius, weight) in [
        (0.05, 0, 1.0),
        (1e-4, 0, 1.0),
        (0.05, 2, 0.5),
        (1e-4, 5, 1.0),
        (0.05, 9, 0.3),
    ] {
        let aggregation = Aggregation::window(radius, weight);
        let run = |dev: &Device, gpu: bool| {
            let t: Vec<Tensor<4>> = views
                .iter()
                .map(|x| Tensor::<4>::from_data(TensorData::new(x.clone(), [d, 4, h, w]), dev))
                .collect();
            to_vec(if gpu {
                agreement_prior_logits(&t, temperature, aggregation)
            } else {
                agreement_prior_logits_burn(&t, temperature, aggregation)
            })
        };
        assert!(crate::gpu::gpu_kernels(&gpu));
        let (want, got) = (run(&cpu, false), run(&gpu, true));
        // Logits within [-11.5, 11.5]; at temperature 1e-4 the depth weights' exponents reach ~1e3, where
        // f32 `exp`/`ln` of the GPU and the CPU differ by ~1e-4 (both are f32 computations of the same sums).
        let e = max_diff(&want, &got);
        assert!(
            e < 1e-3,
            "temperature {temperature}, radius {radius}: logits differ by {e}"
        );
    }
}

/// The warp kernel on wgpu (its taps computed on the device) equals burn's warp on the CPU, for a
/// source per plane and a broadcast one (a plane sweep), with samples outside the source, minifying and
/// magnifying planes and one with a horizon: outputs without and with autodiff, and under autodiff the
/// gradient at a tracked source (the device's gather, which finds each texel's samples through the
/// inverse homography, against burn's scatter-add).
#[test]
fn wgpu_warp_kernel_equals_burns_ops() {
    use crate::forward::{Hom, WarpTable};
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let (sw, sh, ow, oh, c) = (23, 17, 19, 13, 3);
    let homs: Vec<Hom> = vec![
        [1.0, 0.0, 2.5, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0],
        [1.13, 0.021, -3.7, -0.013, 1.07, 2.9, 1.3e-3, -2.1e-3, 1.0],
        [0.9, -0.05, 6.1, 0.04, 1.01, -1.9, -3.3e-3, 1.7e-3, 0.99],
        // Minifying (2.5 texels per pixel: texels no sample reads), magnifying, a horizon inside the
        // output (samples behind the camera for u > 12.5), and one inside the source (x = 2: the
        // output's columns crowd towards it, and the backward's box search falls back to the whole
        // window for texels whose footprint crosses it).
        [2.5, 0.1, -4.0, -0.2, 2.3, 1.0, 0.0, 0.0, 1.0],
        [0.3, 0.0, 5.0, 0.02, 0.35, 4.0, 0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, -0.08, 0.0, 1.0],
        [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.5, 0.0, 1.0],
    ];
    let d = homs.len();
    let table = WarpTable::new(&homs, sw, sh, ow, oh);
    let seed = uniform([d, c, oh, ow], -1.0, 1.0);
    for s in [d, 1] {
        let src = uniform([s, c, sh, sw], -1.0, 1.0);
        let on = |dev: &Device| {
            Tensor::<4>::from_data(TensorData::new(src.clone(), [s, c, sh, sw]), dev)
        };
        let want = to_vec(table.apply_burn(on(&cpu)));
        assert!(crate::gpu::gpu_kernels(&gpu) && !gpu.is_autodiff());
        let got = to_vec(table.apply(on(&gpu)));
        // The device computes its own taps (its division and `fma` round within an ulp or so of the
        // CPU's): bilinear weights differ by ~1e-6.
        let e = max_diff(&want, &got);
        assert!(e < 1e-5, "{s} source planes: {e}");
        // Under autodiff, a tracked source: the output and the gradient of a weighted sum.
        let grad = |dev: &Device, burn: bool| {
            let ad = dev.clone().autodiff();
            let x = on(&ad).require_grad();
            let y = if burn {
                table.apply_burn(x.clone())
            } else {
                table.apply(x.clone())
            };
            let out = to_vec(y.clone().inner());
            let wt = Tensor::<4>::from_data(TensorData::new(seed.clone(), [d, c, oh, ow]), &ad);
            let grads = (y * wt).sum().backward();
            (out, to_vec(x.grad(&grads).unwrap()))
        };
        let (_, want_grad) = grad(&cpu, true);
        let (got, got_grad) = grad(&gpu, false);
        let e = max_diff(&want, &got);
        assert!(e < 1e-5, "{s} source planes, autodiff device: {e}");
        let e = max_diff(&want_grad, &got_grad);
        assert!(e < 1e-5, "{s} source planes, source gradient: {e}");
        assert!(want_grad.iter().any(|&g| g != 0.0));
    }
}

/// The activation kernel on wgpu equals burn's `elu` and `relu` on the CPU: outputs and the gradient of
/// a weighted sum, over negative, zero and positive inputs (the nets take it for every ELU layer on a
/// GPU, the VGG loss for its ReLUs), for a
/// contiguous input and for a channels-last one (a convolution's output, which the kernel keeps in its
/// layout), with the incoming gradient in the same layout or another.
#[test]
fn wgpu_activation_kernel_equals_burns_elu_and_relu() {
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let dims = [3, 5, 7, 9];
    let n: usize = dims.iter().product();
    let mut x = uniform([n], -4.0, 3.0);
    x[0] = 0.0;
    x[1] = -30.0;
    let seed = uniform([n], -1.0, 1.0);
    // `channels_last`: the input is a convolution's output (an identity 1x1 convolution: the same
    // values, in a buffer that a GPU convolution writes channels last); `grad_last`: so is the weight
    // of the sum, whose layout the incoming gradient has.
    let run = |dev: &Device, kernel: bool, channels_last: bool, grad_last: bool, relu: bool| {
        let ad = dev.clone().autodiff();
        let t = Tensor::<4>::from_data(TensorData::new(x.clone(), dims), &ad).require_grad();
        let input = if channels_last {
            channels_last_copy(t.clone())
        } else {
            t.clone()
        };
        let y = match (kernel, relu) {
            (true, false) => crate::gpu::elu(input),
            (true, true) => crate::gpu::relu(input),
            (false, false) => burn::tensor::activation::elu(input, 1.0),
            (false, true) => burn::tensor::activation::relu(input),
        };
        let out = to_vec(y.clone().inner());
        let wt = Tensor::<4>::from_data(TensorData::new(seed.clone(), dims), &ad);
        let wt = if grad_last {
            channels_last_copy(wt)
        } else {
            wt
        };
        let grads = (y * wt).sum().backward();
        (out, to_vec(t.grad(&grads).unwrap()))
    };
    for relu in [false, true] {
        for (channels_last, grad_last) in
            [(false, false), (true, true), (true, false), (false, true)]
        {
            let (want, want_grad) = run(&cpu, false, channels_last, grad_last, relu);
            let (got, got_grad) = run(&gpu, true, channels_last, grad_last, relu);
            let what = format!("relu {relu}, layouts ({channels_last}, {grad_last})");
            let e = max_diff(&want, &got);
            assert!(e < 1e-6, "{what}: {e}");
            let e = max_diff(&want_grad, &got_grad);
            assert!(e < 1e-6, "gradient, {what}: {e}");
            assert!(want.iter().any(|&v| v < 0.0) != relu, "{what}");
        }
    }
}

/// The plane sweep and the gradient components on wgpu (taps computed on the device, the validity
/// channel written by the warp) equal the CPU engine's (taps computed on the host, the validity
/// concatenated), with cropped sources and windowed outputs ([`crate::forward::Frames`]) and samples
/// outside the source; the components also under autodiff, with the gradients at the rendered MPI and
/// at the view's image.
#[test]
fn wgpu_sweep_and_components_equal_the_cpu() {
    use crate::forward::{
        Crops, Frames, Hom, gradient_components_framed, plane_sweep_volume_framed,
    };
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let homs: Vec<Hom> = vec![
        [1.0, 0.0, 2.5, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0],
        [1.13, 0.021, -3.7, -0.013, 1.07, 2.9, 1.3e-3, -2.1e-3, 1.0],
        [0.9, -0.05, 6.1, 0.04, 1.01, -1.9, -3.3e-3, 1.7e-3, 0.99],
    ];
    let d = homs.len();
    // A 25 x 19 view cropped at (3, 2) to 20 x 15; the sweep's 17 x 11 output a window at (4, 1).
    let (cw, ch) = (20, 15);
    let image = uniform([3, ch, cw], 0.0, 1.0);
    let frames = Frames {
        src_origin: (3, 2),
        src_full: (25, 19),
        out_origin: (4, 1),
    };
    let sweep = |dev: &Device| {
        let t = Tensor::<3>::from_data(TensorData::new(image.clone(), [3, ch, cw]), dev);
        to_vec(plane_sweep_volume_framed(t, &homs, frames, 11, 17))
    };
    let (want, got) = (sweep(&cpu), sweep(&gpu));
    assert_eq!(want.len(), d * 4 * 11 * 17);
    let invalid = want.chunks(11 * 17).skip(3).step_by(4).flatten();
    assert!(invalid.clone().any(|&v| v == 0.0) && invalid.clone().any(|&v| v == 1.0));
    let e = max_diff(&want, &got);
    assert!(e < 1e-5, "plane sweep: {e}");

    // Components of the 20 x 15 view crop from a 22 x 16 MPI window at (1, 1) of a 24 x 18 MPI, on the
    // MPI region (2, 3, 13, 9).
    let (mw, mh) = (22, 16);
    let mut rgba = uniform([d, 4, mh, mw], 0.0, 1.0);
    let px = mw * mh;
    for p in 0..d {
        for i in 0..px {
            for c in 0..3 {
                rgba[(p * 4 + c) * px + i] *= rgba[(p * 4 + 3) * px + i];
            }
        }
    }
    let crops = Crops {
        window: (1, 1),
        mpi_size: (24, 18),
        crop: (3, 2),
        view_size: (25, 19),
    };
    let region = (2, 3, 13, 9);
    let dims = [d, 11, 9, 13];
    let seed = uniform(dims, -1.0, 1.0);
    let components = |dev: &Device| {
        let ad = dev.clone().autodiff();
        let x = Tensor::<4>::from_data(TensorData::new(rgba.clone(), [d, 4, mh, mw]), &ad)
            .require_grad();
        let img =
            Tensor::<3>::from_data(TensorData::new(image.clone(), [3, ch, cw]), &ad).require_grad();
        let y = gradient_components_framed(x.clone(), img.clone(), &homs, crops, region);
        let out = to_vec(y.clone().inner());
        let wt = Tensor::<4>::from_data(TensorData::new(seed.clone(), dims), &ad);
        let grads = (y * wt).sum().backward();
        let gi = to_vec(img.grad(&grads).unwrap());
        (out, to_vec(x.grad(&grads).unwrap()), gi)
    };
    let (want, want_grad, want_gi) = components(&cpu);
    let (got, got_grad, got_gi) = components(&gpu);
    assert_eq!(want.len(), dims.iter().product::<usize>());
    let e = max_diff(&want, &got);
    assert!(e < 1e-5, "components: {e}");
    let e = max_diff(&want_grad, &got_grad);
    assert!(e < 1e-4, "components, gradient at the MPI: {e}");
    assert!(want_grad.iter().any(|&g| g != 0.0));
    let e = max_diff(&want_gi, &got_gi);
    assert!(e < 1e-4, "components, gradient at the image: {e}");
    assert!(want_gi.iter().any(|&g| g != 0.0));
    // Untracked, as inference runs them.
    let t = Tensor::<4>::from_data(TensorData::new(rgba.clone(), [d, 4, mh, mw]), &gpu);
    let img = Tensor::<3>::from_data(TensorData::new(image.clone(), [3, ch, cw]), &gpu);
    let e = max_diff(
        &want,
        &to_vec(gradient_components_framed(t, img, &homs, crops, region)),
    );
    assert!(e < 1e-5, "components without autodiff: {e}");
}

/// The max over views on wgpu (with the stage's concatenation, and alone) equals burn's reshape, max,
/// repeat and concatenation on the CPU: outputs and the gradient of a weighted sum, input in either
/// layout; where views tie, the max's gradient goes to the first of them (as the CPU engine routes it).
#[test]
fn wgpu_view_max_equals_burns_ops() {
    use crate::network::max_over_views;
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let (k, d, c, h, w) = (3, 4, 5, 6, 7);
    let dims = [k * d, c, h, w];
    let n: usize = dims.iter().product();
    let x = uniform([n], -1.0, 1.0);
    for keep in [true, false] {
        let od = if keep {
            [k * d, 2 * c, h, w]
        } else {
            [d, c, h, w]
        };
        let seed = uniform(od, -1.0, 1.0);
        let run = |dev: &Device, kernel: bool, data: &[f32]| {
            let ad = dev.clone().autodiff();
            let t =
                Tensor::<4>::from_data(TensorData::new(data.to_vec(), dims), &ad).require_grad();
            let y = if kernel {
                crate::gpu::view_max(t.clone(), k, keep)
            } else if keep {
                let m = max_over_views(t.clone(), k)
                    .reshape([1, d, c, h, w])
                    .repeat_dim(0, k);
                Tensor::cat(vec![t.clone(), m.reshape([k * d, c, h, w])], 1)
            } else {
                max_over_views(t.clone(), k)
            };
            let out = to_vec(y.clone().inner());
            let wt = Tensor::<4>::from_data(TensorData::new(seed.clone(), od), &ad);
            let grads = (y * wt).sum().backward();
            (out, to_vec(t.grad(&grads).unwrap()))
        };
        let (want, want_grad) = run(&cpu, false, &x);
        let (got, got_grad) = run(&gpu, true, &x);
        assert_eq!(max_diff(&want, &got), 0.0, "keep {keep}");
        let e = max_diff(&want_grad, &got_grad);
        assert!(e < 1e-5, "keep {keep}: gradient {e}");
        // Every view the same: the max's gradient all at view 0.
        let per = d * c * h * w;
        let same: Vec<f32> = (0..n).map(|i| x[i % per]).collect();
        let (_, g) = run(&gpu, true, &same);
        let od_per = od[1] * h * w;
        for dd in 0..d {
            for ch in 0..c {
                for p in 0..h * w {
                    let max_grad: f32 = if keep {
                        (0..k)
                            .map(|v| seed[(v * d + dd) * od_per + (c + ch) * h * w + p])
                            .sum()
                    } else {
                        seed[dd * od_per + ch * h * w + p]
                    };
                    for v in 0..k {
                        let pass = if keep {
                            seed[(v * d + dd) * od_per + ch * h * w + p]
                        } else {
                            0.0
                        };
                        let want = pass + if v == 0 { max_grad } else { 0.0 };
                        let got = g[((v * d + dd) * c + ch) * h * w + p];
                        assert!((want - got).abs() < 1e-5, "keep {keep}, tie: view {v}");
                    }
                }
            }
        }
    }
}

/// The state's RGBA on wgpu equals burn's sigmoid, premultiplication and concatenation on the CPU:
/// outputs and the gradient at the state (zero at its extra channels), over saturated and mid-range
/// logits.
#[test]
fn wgpu_state_rgba_equals_burns_ops() {
    use crate::network::state_to_rgba_burn;
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let dims = [5, 7, 6, 9];
    let n: usize = dims.iter().product();
    let mut x = uniform([n], -6.0, 6.0);
    x[0] = 40.0;
    x[1] = -40.0;
    let od = [5, 4, 6, 9];
    let seed = uniform(od, -1.0, 1.0);
    let run = |dev: &Device, kernel: bool| {
        let ad = dev.clone().autodiff();
        let t = Tensor::<4>::from_data(TensorData::new(x.clone(), dims), &ad).require_grad();
        let y = if kernel {
            crate::gpu::state_rgba(t.clone())
        } else {
            state_to_rgba_burn(t.clone())
        };
        let out = to_vec(y.clone().inner());
        let wt = Tensor::<4>::from_data(TensorData::new(seed.clone(), od), &ad);
        let grads = (y * wt).sum().backward();
        (out, to_vec(t.grad(&grads).unwrap()))
    };
    let (want, want_grad) = run(&cpu, false);
    let (got, got_grad) = run(&gpu, true);
    let e = max_diff(&want, &got);
    assert!(e < 1e-6, "state rgba: {e}");
    let e = max_diff(&want_grad, &got_grad);
    assert!(e < 1e-6, "state rgba gradient: {e}");
    assert!(want_grad.iter().any(|&g| g != 0.0));
}

/// A net's input on wgpu (the views' inputs with the state beside each, one kernel; the prior as a
/// state with zero extra channels) equals burn's concatenations on the CPU: outputs, and the gradients
/// at every view's input and at the state (summed over the views).
#[test]
fn wgpu_net_input_equals_burns_cats() {
    use crate::network::agreement_prior_logits_burn;
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let (k, d, cv, sc, h, w) = (3, 4, 11, 6, 5, 7);
    let rand = |dims: [usize; 4], lo: f64, hi: f64| uniform(dims, lo, hi);
    let views: Vec<Vec<f32>> = (0..k).map(|_| rand([d, cv, h, w], -1.0, 1.0)).collect();
    let state = rand([d, sc, h, w], -2.0, 2.0);
    let od = [k * d, cv + sc, h, w];
    let seed = rand(od, -1.0, 1.0);
    let run = |dev: &Device, kernel: bool| {
        let ad = dev.clone().autodiff();
        let vs: Vec<Tensor<4>> = views
            .iter()
            .map(|v| {
                Tensor::from_data(TensorData::new(v.clone(), [d, cv, h, w]), &ad).require_grad()
            })
            .collect();
        let s = Tensor::<4>::from_data(TensorData::new(state.clone(), [d, sc, h, w]), &ad)
            .require_grad();
        let y = if kernel {
            crate::gpu::net_input(vs.clone(), Some(s.clone()), None).0
        } else {
            let x: Vec<Tensor<4>> = vs
                .iter()
                .map(|v| Tensor::cat(vec![v.clone(), s.clone()], 1))
                .collect();
            Tensor::cat(x, 0)
        };
        let out = to_vec(y.clone().inner());
        let wt = Tensor::<4>::from_data(TensorData::new(seed.clone(), od), &ad);
        let grads = (y * wt).sum().backward();
        let mut g: Vec<Vec<f32>> = vs.iter().map(|v| to_vec(v.grad(&grads).unwrap())).collect();
        g.push(to_vec(s.grad(&grads).unwrap()));
        (out, g)
    };
    let (want, want_grads) = run(&cpu, false);
    let (got, got_grads) = run(&gpu, true);
    assert_eq!(max_diff(&want, &got), 0.0);
    for (i, (a, b)) in want_grads.iter().zip(&got_grads).enumerate() {
        let e = max_diff(a, b);
        assert!(e < 1e-5, "gradient {i}: {e}");
    }
    // The prior as an 8-channel state: the RGBA logits, then zeros.
    let psv: Vec<Vec<f32>> = (0..k)
        .map(|_| {
            let mut v = rand([d, 4, h, w], 0.0, 1.0);
            for x in &mut v[3 * h * w..] {
                *x = x.round();
            }
            v
        })
        .collect();
    let on = |dev: &Device| -> Vec<Tensor<4>> {
        psv.iter()
            .map(|v| Tensor::from_data(TensorData::new(v.clone(), [d, 4, h, w]), dev))
            .collect()
    };
    let want =
        agreement_prior_logits_burn(&on(&cpu), 0.05, deepview_mpi::agreement::Aggregation::NONE);
    let want = to_vec(Tensor::cat(
        vec![want, Tensor::zeros([d, 4, h, w], &cpu)],
        1,
    ));
    let (_, prior) = crate::gpu::net_input(
        on(&gpu),
        None,
        Some((0.05, 8, deepview_mpi::agreement::Aggregation::NONE)),
    );
    let e = max_diff(&want, &to_vec(prior.unwrap()));
    assert!(e < 1e-4, "prior state: {e}");
}

/// Weights laid out channels-last on wgpu keep their values, their gradient requirement (on an autodiff
/// device) and the convolution's output.
#[test]
fn wgpu_channels_last_weights_keep_values_and_gradients() {
    use burn::module::Module;
    use burn::nn::PaddingConfig2d;
    use burn::nn::conv::{Conv2d, Conv2dConfig};
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let ad = gpu.clone().autodiff();
    let conv: Conv2d = Conv2dConfig::new([5, 7], [3, 3])
        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
        .init(&ad);
    let before = to_vec(conv.weight.val().inner());
    let moved = crate::gpu::channels_last_weights(conv.clone());
    assert_eq!(to_vec(moved.weight.val().inner()), before);
    assert!(moved.weight.val().is_require_grad());
    let x = Tensor::<4>::from_data(
        TensorData::new(uniform([2, 5, 6, 8], -1.0, 1.0), [2, 5, 6, 8]),
        &ad,
    );
    let (a, b) = (conv.forward(x.clone()), moved.forward(x.clone()));
    let e = max_diff(&to_vec(a.inner()), &to_vec(b.clone().inner()));
    assert!(e < 1e-6, "convolution: {e}");
    let grads = b.sum().backward();
    assert!(
        moved.weight.grad(&grads).is_some(),
        "the weight lost its gradient"
    );
    // A frozen module stays frozen.
    let frozen = crate::gpu::channels_last_weights(conv.no_grad());
    assert!(!frozen.weight.val().is_require_grad());
}

/// The feature loss's padded pair on wgpu (one kernel) equals burn's reflection padding and
/// concatenation on the CPU: the values, and the gradients at both inputs (each texel summing the
/// padded positions that read it: a texel next to a corner reaches up to four), for pads of 1 to 4 on
/// sizes from 5 to 32; the second input also given transposed in memory (the kernel reads strides);
/// with VGG's preprocessing folded in (BGR, scaled, the mean removed) against burn's flip and
/// arithmetic after the padding.
#[test]
fn wgpu_reflect_pad_pair_equals_burns_pad() {
    use crate::gpu::ChannelMap;
    use burn::tensor::ops::PadMode;
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let caffe = ChannelMap {
        scale: 255.0,
        offset: [103.939, 116.779, 123.68],
        reverse: true,
    };
    for (n, c, h, w, ph, pw, map) in [
        (1, 3, 16, 16, 2, 2, ChannelMap::IDENTITY),
        (2, 3, 5, 9, 1, 4, ChannelMap::IDENTITY),
        (1, 2, 32, 24, 4, 3, ChannelMap::IDENTITY),
        (2, 3, 16, 24, 2, 3, caffe),
    ] {
        let rand = |dims: [usize; 4]| uniform(dims, -1.0, 1.0);
        let (va, vb) = (rand([n, c, h, w]), rand([n, c, w, h]));
        let od = [2 * n, c, h + 2 * ph, w + 2 * pw];
        let seed = rand(od);
        let run = |dev: &Device, kernel: bool| {
            let ad = dev.clone().autodiff();
            let a = Tensor::<4>::from_data(TensorData::new(va.clone(), [n, c, h, w]), &ad)
                .require_grad();
            let b = Tensor::<4>::from_data(TensorData::new(vb.clone(), [n, c, w, h]), &ad)
                .require_grad();
            let bt = b.clone().swap_dims(2, 3);
            let y = if kernel {
                crate::gpu::reflect_pad_pair(a.clone(), bt, ph, pw, map)
            } else {
                let pad = |t: Tensor<4>| t.pad([(ph, ph), (pw, pw)], PadMode::Reflect);
                let y = Tensor::cat(vec![pad(a.clone()), pad(bt)], 0);
                let y = if map.reverse { y.flip([1]) } else { y };
                let offset = Tensor::<1>::from_floats(&map.offset[..c], &ad).reshape([1, c, 1, 1]);
                y * map.scale - offset
            };
            assert_eq!(y.dims(), od);
            let out = to_vec(y.clone().inner());
            let wt = Tensor::<4>::from_data(TensorData::new(seed.clone(), od), &ad);
            let grads = (y * wt).sum().backward();
            let ga = to_vec(a.grad(&grads).unwrap());
            (out, ga, to_vec(b.grad(&grads).unwrap()))
        };
        let (want, want_a, want_b) = run(&cpu, false);
        let (got, got_a, got_b) = run(&gpu, true);
        let what = format!("{n}x{c}x{h}x{w} padded by {ph}, {pw}");
        assert!(max_diff(&want, &got) <= 1e-5 * map.scale, "values, {what}");
        let e = max_diff(&want_a, &got_a).max(max_diff(&want_b, &got_b));
        assert!(e < 1e-5 * map.scale, "gradients, {what}: {e}");
        // The corner's neighbour gets four reads (itself and its mirrors); the test sees them.
        assert!(want_a.iter().any(|&g| g != 0.0));
    }
}

/// The global norm's squared sums on wgpu (a one-cube reduction per tensor into a shared buffer, up to
/// 32 tensors per dispatch) equal f64 sums of squares on the host, for tensors of several ranks and
/// sizes (one under the cube's 256 units, one of many strides' worth), one given transposed in memory,
/// and more tensors than one dispatch takes.
#[test]
fn wgpu_squared_norms_equal_host_sums() {
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let a = Tensor::<1>::from_data(TensorData::new(uniform([7], -2.0, 2.0), [7]), &cpu);
    let b = Tensor::<4>::from_data(
        TensorData::new(uniform([8, 12, 3, 3], -1.0, 1.0), [8, 12, 3, 3]),
        &cpu,
    );
    let c = Tensor::<2>::from_data(
        TensorData::new(uniform([300, 41], -0.5, 0.5), [300, 41]),
        &cpu,
    );
    // 40 more of a few hundred values each, of growing scale: a slot written twice, or a chunk's
    // sums put in another chunk's slots, changes the total.
    let more: Vec<Tensor<2>> = (0..40)
        .map(|i| {
            let s = 0.1 * (i + 1) as f64;
            let dims = [3 + i % 5, 50 + i];
            Tensor::<2>::from_data(TensorData::new(uniform(dims, -s, s), dims), &cpu)
        })
        .collect();
    let mut values = vec![to_vec(a.clone()), to_vec(b.clone()), to_vec(c.clone())];
    values.extend(more.iter().map(|t| to_vec(t.clone())));
    let host: f64 = values
        .iter()
        .flatten()
        .map(|&v| f64::from(v) * f64::from(v))
        .sum();
    let mut tensors = vec![
        a.to_device(&gpu).into_dispatch(),
        b.to_device(&gpu).into_dispatch(),
        c.to_device(&gpu).transpose().into_dispatch(),
    ];
    tensors.extend(more.into_iter().map(|t| t.to_device(&gpu).into_dispatch()));
    let got = crate::gpu::squared_norms(tensors, &gpu);
    assert!(
        (got - host).abs() <= 1e-6 * host,
        "device {got}, host {host}"
    );
}

/// The feature loss's per-layer term on wgpu (one reduction kernel, one backward) equals burn's
/// subtraction, absolute value and sum on the CPU: values and gradients, with some pairs equal (burn's
/// `abs` has no gradient there), for a contiguous input and a channels-last one (a convolution's
/// output: VGG's features), with more values per example than the cube's 256 units and fewer.
#[test]
fn wgpu_pair_l1_equals_burns_ops() {
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    for (n, c, h, w, last) in [
        (2, 5, 6, 7, false),
        (1, 16, 9, 11, true),
        (3, 2, 3, 4, true),
    ] {
        let dims = [2 * n, c, h, w];
        let len: usize = dims.iter().product();
        let mut v = uniform([len], -1.0, 1.0);
        // Every 7th pair equal: zero difference (values in [N, C, h, w] order).
        for i in (0..len / 2).step_by(7) {
            v[len / 2 + i] = v[i];
        }
        let weights = uniform([n], 0.5, 2.0);
        let run = |dev: &Device, kernel: bool| {
            let ad = dev.clone().autodiff();
            let t = Tensor::<4>::from_data(TensorData::new(v.clone(), dims), &ad).require_grad();
            let f = if last {
                channels_last_copy(t.clone())
            } else {
                t.clone()
            };
            // The loss folds a layer's weight over the crop's area into the kernel.
            let scale = 0.37f32;
            let l = if kernel {
                crate::gpu::pair_l1(f, scale)
            } else {
                (f.clone().narrow(0, 0, n) - f.narrow(0, n, n))
                    .abs()
                    .reshape([n as i32, -1])
                    .sum_dim(1)
                    .reshape([n])
                    * scale
            };
            let out = to_vec(l.clone().inner());
            let wt = Tensor::<1>::from_data(TensorData::new(weights.clone(), [n]), &ad);
            let grads = (l * wt).sum().backward();
            (out, to_vec(t.grad(&grads).unwrap()))
        };
        let (want, want_grad) = run(&cpu, false);
        let (got, got_grad) = run(&gpu, true);
        let what = format!("{dims:?}, channels last {last}");
        for (a, b) in want.iter().zip(&got) {
            assert!((a - b).abs() <= 1e-5 * a.abs(), "{what}: {a} vs {b}");
        }
        assert_eq!(max_diff(&want_grad, &got_grad), 0.0, "gradient, {what}");
        assert!(want_grad.contains(&0.0) && want_grad.iter().any(|&g| g != 0.0));
    }
}

/// The 3x3 convolution on wgpu (burn's forward; its input gradient as a convolution with the weights
/// flipped and transposed) equals burn's `conv2d` on the CPU: values and the gradients at the input, the
/// weights and the bias, with the input contiguous or channels-last, for channel counts of the nets
/// and more.
#[test]
fn wgpu_conv3x3_equals_burns_conv() {
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    for (n, ci, co, h, w, last) in [
        (3, 8, 8, 9, 7, false),
        (2, 19, 8, 6, 11, true),
        (1, 4, 13, 5, 5, true),
        // More output positions than a cube's 256 units (the bias gradient's strided share).
        (4, 8, 8, 12, 10, true),
    ] {
        let rand = |len: usize| uniform([len], -1.0, 1.0);
        let (vx, vw, vb) = (rand(n * ci * h * w), rand(co * ci * 9), rand(co));
        let seed = rand(n * co * h * w);
        let run = |dev: &Device, kernel: bool| {
            let ad = dev.clone().autodiff();
            let x = Tensor::<4>::from_data(TensorData::new(vx.clone(), [n, ci, h, w]), &ad)
                .require_grad();
            let wt = Tensor::<4>::from_data(TensorData::new(vw.clone(), [co, ci, 3, 3]), &ad)
                .require_grad();
            let b = Tensor::<1>::from_data(TensorData::new(vb.clone(), [co]), &ad).require_grad();
            let input = if last {
                channels_last_copy(x.clone())
            } else {
                x.clone()
            };
            let y = if kernel {
                crate::gpu::conv3x3(input, wt.clone(), b.clone())
            } else {
                let opts = burn::tensor::ops::ConvOptions::new([1, 1], [1, 1], [1, 1], 1);
                burn::tensor::module::conv2d(input, wt.clone(), Some(b.clone()), opts)
            };
            let out = to_vec(y.clone().inner());
            let s = Tensor::<4>::from_data(TensorData::new(seed.clone(), [n, co, h, w]), &ad);
            let grads = (y * s).sum().backward();
            (
                out,
                to_vec(x.grad(&grads).unwrap()),
                to_vec(wt.grad(&grads).unwrap()),
                b.grad(&grads)
                    .unwrap()
                    .into_data()
                    .try_to_vec::<f32>()
                    .unwrap(),
            )
        };
        let want = run(&cpu, false);
        let got = run(&gpu, true);
        let what = format!("{n}x{ci}x{h}x{w} -> {co}, channels last {last}");
        assert!(max_diff(&want.0, &got.0) < 1e-5, "values, {what}");
        assert!(max_diff(&want.1, &got.1) < 1e-5, "input gradient, {what}");
        assert!(max_diff(&want.2, &got.2) < 1e-4, "weight gradient, {what}");
        assert!(max_diff(&want.3, &got.3) < 1e-4, "bias gradient, {what}");
    }
}

/// A convolution whose weights take no gradient (VGG's in the feature loss) keeps its weights' flip
/// on wgpu: the input gradient equals burn's `conv2d` on the CPU on the first backward pass (the flip
/// made), on the second (the flip kept: one hit), and for other weights of the same shape (their own
/// flip, not the first one's).
#[test]
fn wgpu_frozen_conv_keeps_its_flip() {
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    let (n, ci, co, h, w) = (2, 8, 8, 7, 6);
    let rand = |len: usize| uniform([len], -1.0, 1.0);
    let (vx, vb, seed) = (rand(n * ci * h * w), rand(co), rand(n * co * h * w));
    // `ad`: an autodiff device; `wt` on it without require_grad (no gradient: frozen).
    let x_grad = |ad: &Device, kernel: bool, wt: &Tensor<4>| {
        let x =
            Tensor::<4>::from_data(TensorData::new(vx.clone(), [n, ci, h, w]), ad).require_grad();
        let wt = wt.clone();
        let b = Tensor::<1>::from_data(TensorData::new(vb.clone(), [co]), ad);
        let y = if kernel {
            crate::gpu::conv3x3(channels_last_copy(x.clone()), wt, b)
        } else {
            let opts = burn::tensor::ops::ConvOptions::new([1, 1], [1, 1], [1, 1], 1);
            burn::tensor::module::conv2d(x.clone(), wt, Some(b), opts)
        };
        let s = Tensor::<4>::from_data(TensorData::new(seed.clone(), [n, co, h, w]), ad);
        to_vec(x.grad(&(y * s).sum().backward()).unwrap())
    };
    let (gpu, cpu) = (gpu.autodiff(), cpu.clone().autodiff());
    let weights = |dev: &Device, v: &[f32]| {
        Tensor::<4>::from_data(TensorData::new(v.to_vec(), [co, ci, 3, 3]), dev)
    };
    let (v1, v2) = (rand(co * ci * 9), rand(co * ci * 9));
    let (w1, w2) = (weights(&gpu, &v1), weights(&gpu, &v2));
    let want1 = x_grad(&cpu, false, &weights(&cpu, &v1));
    let want2 = x_grad(&cpu, false, &weights(&cpu, &v2));
    let hits = crate::gpu::frozen_flip_hits();
    let first = x_grad(&gpu, true, &w1);
    assert_eq!(
        crate::gpu::frozen_flip_hits(),
        hits,
        "the first pass makes the flip"
    );
    let second = x_grad(&gpu, true, &w1);
    assert_eq!(
        crate::gpu::frozen_flip_hits(),
        hits + 1,
        "the second pass keeps it"
    );
    let other = x_grad(&gpu, true, &w2);
    assert_eq!(
        crate::gpu::frozen_flip_hits(),
        hits + 1,
        "other weights, another flip"
    );
    assert!(max_diff(&want1, &first) < 1e-5, "first pass");
    assert!(max_diff(&want1, &second) < 1e-5, "second pass");
    assert!(max_diff(&want2, &other) < 1e-5, "other weights");
    assert!(
        max_diff(&want1, &want2) > 1e-2,
        "the two weights give other gradients"
    );
}

/// The training window's crop on wgpu (one kernel each way) equals burn's two narrows on the CPU:
/// values, and gradients (the output's gradient inside the window, zero outside), for a contiguous
/// input and a channels-last one (the state after a convolution), whose layout the output keeps.
#[test]
fn wgpu_crop_equals_burns_narrow() {
    let gpu = crate::device::parse_device("wgpu:cpu").expect("lavapipe (mesa-vulkan-drivers)");
    let cpu = Device::flex();
    for (dims, (y0, x0, oh, ow), last) in [
        ([3, 5, 11, 13], (2, 3, 6, 7), false),
        ([2, 8, 12, 10], (4, 4, 4, 2), true),
    ] {
        let len: usize = dims.iter().product();
        let v = uniform([len], -1.0, 1.0);
        let seed = uniform([dims[0] * dims[1] * oh * ow], -1.0, 1.0);
        let run = |dev: &Device, kernel: bool| {
            let ad = dev.clone().autodiff();
            let t = Tensor::<4>::from_data(TensorData::new(v.clone(), dims), &ad).require_grad();
            let x = if last {
                channels_last_copy(t.clone())
            } else {
                t.clone()
            };
            let y = if kernel {
                let y = crate::gpu::crop(x, y0, x0, oh, ow);
                if last {
                    // The output keeps the channels-last layout.
                    let s = super::cube_float(y.clone().inner().into_dispatch())
                        .meta
                        .strides()
                        .to_vec();
                    assert_eq!(s[1], 1, "channels fastest: {s:?}");
                }
                y
            } else {
                x.narrow(3, x0, ow).narrow(2, y0, oh)
            };
            let out = to_vec(y.clone().inner());
            let s = Tensor::<4>::from_data(
                TensorData::new(seed.clone(), [dims[0], dims[1], oh, ow]),
                &ad,
            );
            let grads = (y * s).sum().backward();
            (out, to_vec(t.grad(&grads).unwrap()))
        };
        let (want, want_grad) = run(&cpu, false);
        let (got, got_grad) = run(&gpu, true);
        let what = format!("{dims:?}, channels last {last}");
        assert_eq!(want, got, "values, {what}");
        assert_eq!(want_grad, got_grad, "gradient, {what}");
        assert!(want_grad.contains(&0.0) && want_grad.iter().any(|&g| g != 0.0));
    }
}
