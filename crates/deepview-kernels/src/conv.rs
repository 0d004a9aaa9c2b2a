//! 3x3 convolutions on [`Plane`] buffers: packed weights, the forward pass with fused bias and
//! activation, the input gradient (a convolution with transposed, flipped weights) and the weight and
//! bias gradients (correlations of the input with the output gradient).

use crate::act::{Act, CO_BLOCK};
use crate::{Isa, Plane, isa, scalar};

/// Rows of a band (see [`conv3x3`]).
const ROWS_PER_BAND: usize = 8;

/// Weights of one 3x3 convolution in the kernel's order: blocks of 8 output channels, then input
/// channel, tap (row-major `3 * ky + kx`) and the 8 outputs (`w[((block * cin + ci) * 9 + t) * 8 + j]`);
/// output channels beyond `cout` have zero weights.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedConv {
    pub cin: usize,
    pub cout: usize,
    pub w: Vec<f32>,
    /// Bias, zero-padded to whole blocks.
    pub b: Vec<f32>,
}

impl PackedConv {
    /// From burn's / PyTorch's `[cout, cin, 3, 3]` weights and an optional `[cout]` bias.
    pub fn new(w_oihw: &[f32], bias: Option<&[f32]>, cout: usize, cin: usize) -> Self {
        assert_eq!(w_oihw.len(), cout * cin * 9, "3x3 weights of {cout}x{cin}");
        Self::pack(cout, cin, bias, |co, ci, t| w_oihw[(co * cin + ci) * 9 + t])
    }

    /// The part of `[cout, cin, 3, 3]` weights that reads input channels `inputs` (a convolution of
    /// `inputs.len()` inputs), with the bias or without it: a convolution's sum split over groups of
    /// input channels (see [`conv3x3_from`]).
    pub fn input_range(
        w_oihw: &[f32],
        bias: Option<&[f32]>,
        cout: usize,
        cin: usize,
        inputs: std::ops::Range<usize>,
    ) -> Self {
        assert_eq!(w_oihw.len(), cout * cin * 9, "3x3 weights of {cout}x{cin}");
        assert!(inputs.end <= cin, "input channels {inputs:?} of {cin}");
        let c0 = inputs.start;
        Self::pack(cout, inputs.len(), bias, |co, ci, t| {
            w_oihw[(co * cin + c0 + ci) * 9 + t]
        })
    }

    /// The convolution whose output is the input gradient of `[cout, cin, 3, 3]` weights: `cin` outputs
    /// from `cout` inputs, each tap flipped, no bias.
    pub fn transposed(w_oihw: &[f32], cout: usize, cin: usize) -> Self {
        assert_eq!(w_oihw.len(), cout * cin * 9, "3x3 weights of {cout}x{cin}");
        Self::pack(cin, cout, None, |o, i, t| w_oihw[(i * cin + o) * 9 + 8 - t])
    }

    fn pack(
        cout: usize,
        cin: usize,
        bias: Option<&[f32]>,
        w: impl Fn(usize, usize, usize) -> f32,
    ) -> Self {
        let blocks = cout.div_ceil(CO_BLOCK);
        let mut packed = vec![0f32; blocks * cin * 9 * CO_BLOCK];
        for co in 0..cout {
            let (blk, j) = (co / CO_BLOCK, co % CO_BLOCK);
            for ci in 0..cin {
                for t in 0..9 {
                    packed[((blk * cin + ci) * 9 + t) * CO_BLOCK + j] = w(co, ci, t);
                }
            }
        }
        let mut b = vec![0f32; blocks * CO_BLOCK];
        if let Some(bias) = bias {
            assert_eq!(bias.len(), cout, "bias of {cout}");
            b[..cout].copy_from_slice(bias);
        }
        Self {
            cin,
            cout,
            w: packed,
            b,
        }
    }

    pub fn blocks(&self) -> usize {
        self.cout.div_ceil(CO_BLOCK)
    }

    /// Multiply-adds per output texel.
    pub fn macs(&self) -> usize {
        self.cin * self.cout * 9
    }
}

fn check(plane: Plane, bufs: &[&[f32]], n: usize, what: &str) {
    assert_eq!(bufs.len(), n, "{what}: {n} planes expected");
    for b in bufs {
        assert!(b.len() >= plane.len(), "{what}: plane buffer too short");
    }
}

/// `outputs[co] = act(b[co] + sum_ci sum_t w[co][ci][t] * inputs[ci][. + tap_t])` on one slice; every
/// buffer is a [`Plane`] of `plane` with a zero border (the outputs' borders are zeroed afterwards).
pub fn conv3x3(
    plane: Plane,
    inputs: &[&[f32]],
    conv: &PackedConv,
    act: Act,
    outputs: &mut [&mut [f32]],
) {
    conv3x3_init(plane, inputs, conv, act, None, outputs)
}

/// `outputs[co] = act(init[co][.] + sum_ci sum_t w[co][ci][t] * inputs[ci][. + tap_t])`: [`conv3x3`]
/// with the sums starting from the planes `init` instead of the bias (which is not added). With `init`
/// the [`Act::Linear`] output of another part of the same convolution (see
/// [`PackedConv::input_range`]), this is the convolution of the concatenated inputs: a part shared by
/// several calls (channels equal for every view) is then computed once.
pub fn conv3x3_from(
    plane: Plane,
    inputs: &[&[f32]],
    conv: &PackedConv,
    act: Act,
    init: &[&[f32]],
    outputs: &mut [&mut [f32]],
) {
    check(plane, init, conv.cout, "conv3x3 initial sums");
    conv3x3_init(plane, inputs, conv, act, Some(init), outputs)
}

fn conv3x3_init(
    plane: Plane,
    inputs: &[&[f32]],
    conv: &PackedConv,
    act: Act,
    init: Option<&[&[f32]]>,
    outputs: &mut [&mut [f32]],
) {
    check(plane, inputs, conv.cin, "conv3x3 inputs");
    assert_eq!(outputs.len(), conv.cout, "conv3x3: {} outputs", conv.cout);
    for o in outputs.iter() {
        assert!(
            o.len() >= plane.len(),
            "conv3x3 outputs: plane buffer too short"
        );
    }
    if plane.is_empty() {
        return;
    }
    let taps = plane.taps();
    let ins: Vec<*const f32> = inputs.iter().map(|b| b.as_ptr()).collect();
    let init: Option<Vec<*const f32>> = init.map(|i| i.iter().map(|b| b.as_ptr()).collect());
    // Row bands of the plane, every output block within a band: the band's input rows stay in the
    // L2 cache while the output blocks (passes of the kernel) reread them.
    let band = ROWS_PER_BAND * plane.pitch();
    let (start, end) = (plane.start(), plane.end());
    // Bands are whole kernel steps, so that no output is computed twice.
    let step = match isa() {
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => crate::x86_512::STEP,
        _ => 16,
    };
    let mut b0 = start;
    while b0 < end {
        let b1 = (b0 + band.next_multiple_of(step)).min(end);
        for blk in 0..conv.blocks() {
            let co0 = blk * CO_BLOCK;
            let n = (conv.cout - co0).min(CO_BLOCK);
            let w = &conv.w[blk * conv.cin * 9 * CO_BLOCK..][..conv.cin * 9 * CO_BLOCK];
            let b = &conv.b[co0..co0 + CO_BLOCK];
            let mut outs: [*mut f32; CO_BLOCK] = [std::ptr::null_mut(); CO_BLOCK];
            for j in 0..n {
                outs[j] = outputs[co0 + j].as_mut_ptr();
            }
            let init = init.as_ref().map(|i| &i[co0..co0 + n]);
            // SAFETY (both SIMD paths): every input and output holds `plane.len()` floats (checked
            // above), which covers the kernel's reads (taps of one step past `end`) and writes (one
            // step past `end`); outputs are distinct buffers from the inputs (they are `&mut`).
            #[cfg(target_arch = "x86_64")]
            match isa() {
                Isa::Avx512 => {
                    unsafe {
                        crate::x86_512::conv_block(&ins, w, b, init, &outs[..n], b0, b1, &taps, act)
                    };
                    continue;
                }
                Isa::Avx2 => {
                    unsafe {
                        crate::x86::conv_block(&ins, w, b, init, &outs[..n], b0, b1, &taps, act)
                    };
                    continue;
                }
                Isa::Portable => {}
            }
            // SAFETY: as above.
            unsafe { scalar::conv_block(&ins, w, b, init, &outs[..n], b0, b1, &taps, act) };
        }
        b0 = b1;
    }
    for o in outputs.iter_mut() {
        plane.clear_border(o);
    }
}

/// The input gradient of a convolution: `gx = conv3x3(g_pre, transposed)`, where `g_pre` is the
/// gradient at the convolution's output before its activation and `transposed` is
/// [`PackedConv::transposed`] of its weights.
pub fn conv3x3_input_grad(
    plane: Plane,
    g_pre: &[&[f32]],
    transposed: &PackedConv,
    gx: &mut [&mut [f32]],
) {
    conv3x3(plane, g_pre, transposed, Act::Linear, gx);
}

/// Accumulate the weight gradient `gw[co][ci][t] += sum_p g[co][p] * x[ci][p + tap_t]` (`[cout, cin, 3,
/// 3]` order) and the bias gradient `gb[co] += sum_p g[co][p]` of one slice. `x` and `g` are planes of
/// `plane` with zero borders.
pub fn conv3x3_weight_grad(
    plane: Plane,
    x: &[&[f32]],
    g: &[&[f32]],
    gw: &mut [f32],
    gb: &mut [f32],
) {
    let (cin, cout) = (x.len(), g.len());
    check(plane, x, cin, "weight grad inputs");
    check(plane, g, cout, "weight grad output gradients");
    assert_eq!(gw.len(), cout * cin * 9);
    assert_eq!(gb.len(), cout);
    if plane.is_empty() {
        return;
    }
    let taps = plane.taps();
    let xs: Vec<*const f32> = x.iter().map(|b| b.as_ptr()).collect();
    let gs: Vec<*const f32> = g.iter().map(|b| b.as_ptr()).collect();
    let (start, end) = (plane.start(), plane.end());
    // SAFETY (both SIMD paths): buffers hold `plane.len()` floats, covering reads of 16 past `end`
    // plus the taps.
    #[cfg(target_arch = "x86_64")]
    match isa() {
        Isa::Avx512 => {
            unsafe { crate::x86_512::weight_grad(&xs, &gs, start, end, &taps, gw, gb) };
            return;
        }
        Isa::Avx2 => {
            unsafe { crate::x86::weight_grad(&xs, &gs, start, end, &taps, gw, gb) };
            return;
        }
        Isa::Portable => {}
    }
    // SAFETY: as above.
    unsafe { scalar::weight_grad(&xs, &gs, plane.start(), plane.end(), &taps, gw, gb) };
}

/// `grad *= elu'(x)` given the ELU's output `out = elu(x)`: 1 where `out > 0`, `out + 1 = exp(x)`
/// elsewhere. Works on any matching buffers (padded or not).
pub fn elu_backward(out: &[f32], grad: &mut [f32]) {
    assert_eq!(out.len(), grad.len());
    // Branch-free (a vector loop): the factor is 1 where `out > 0`.
    crate::fastmath::with_simd(
        #[inline(always)]
        || {
            for (g, &o) in grad.iter_mut().zip(out) {
                *g *= if o <= 0.0 { o + 1.0 } else { 1.0 };
            }
        },
    )
}

/// `grad *= relu'(x)` given the ReLU's output: 1 where `out > 0`, 0 elsewhere.
pub fn relu_backward(out: &[f32], grad: &mut [f32]) {
    assert_eq!(out.len(), grad.len());
    crate::fastmath::with_simd(
        #[inline(always)]
        || {
            for (g, &o) in grad.iter_mut().zip(out) {
                *g = if o <= 0.0 { 0.0 } else { *g };
            }
        },
    )
}
