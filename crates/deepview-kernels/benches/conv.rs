//! `cargo bench -p deepview-kernels`: GFLOP/s of the 3x3 kernels on one thread (AVX-512 and AVX2 where the
//! machine has them), for the layer shapes of
//! the `cpu` preset, on a plane that fits the L2 cache and on a fern-sized one (streams from memory).

use deepview_kernels::{Act, Isa, PackedConv, Plane, conv3x3, conv3x3_weight_grad, with_isa_cap};
use std::time::Instant;

fn main() {
    for isa in [Isa::Avx512, Isa::Avx2] {
        if deepview_kernels::detected() >= isa {
            with_isa_cap(isa, || shapes(isa));
        }
    }
}

fn shapes(isa: Isa) {
    for (h, w) in [(40, 40), (96, 96), (412, 575)] {
        let plane = Plane::new(h, w);
        for (cin, cout) in [(4, 8), (8, 8), (16, 8), (19, 8), (64, 64)] {
            let ins: Vec<Vec<f32>> = (0..cin).map(|_| plane.zeroed()).collect();
            let mut outs: Vec<Vec<f32>> = (0..cout).map(|_| plane.zeroed()).collect();
            let wts = vec![0.01f32; cout * cin * 9];
            let conv = PackedConv::new(&wts, None, cout, cin);
            let flops = 2.0 * (cin * cout * 9 * h * w) as f64;
            let reps = ((2e9 / flops) as usize).clamp(1, 10_000);
            let mut best = f64::INFINITY;
            for _ in 0..3 {
                let t = Instant::now();
                for _ in 0..reps {
                    let i: Vec<&[f32]> = ins.iter().map(|v| v.as_slice()).collect();
                    let mut o: Vec<&mut [f32]> =
                        outs.iter_mut().map(|v| v.as_mut_slice()).collect();
                    conv3x3(plane, &i, &conv, Act::Elu, &mut o);
                }
                best = best.min(t.elapsed().as_secs_f64() / reps as f64);
            }
            let mut gw = vec![0f32; cout * cin * 9];
            let mut gb = vec![0f32; cout];
            let t = Instant::now();
            for _ in 0..reps {
                let i: Vec<&[f32]> = ins.iter().map(|v| v.as_slice()).collect();
                let g: Vec<&[f32]> = outs.iter().map(|v| v.as_slice()).collect();
                conv3x3_weight_grad(plane, &i, &g, &mut gw, &mut gb);
            }
            let wg = t.elapsed().as_secs_f64() / reps as f64;
            println!(
                "{{\"kernel\":\"conv3x3\",\"isa\":\"{isa:?}\",\"h\":{h},\"w\":{w},\"cin\":{cin},\"cout\":{cout},\"forward_gflops\":{:.1},\"weight_grad_gflops\":{:.1}}}",
                flops / best / 1e9,
                flops / wg / 1e9
            );
        }
    }
}
