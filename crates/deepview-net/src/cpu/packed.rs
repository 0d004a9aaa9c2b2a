//! A core net's convolutions packed for the kernels (`PackedNet`) and run on plain arrays, one plane's
//! `K` slices per thread (`NetScratch`): the network's CPU inference of a core net
//! ([`core_net_inference`]) and the nets of the whole-image engine ([`crate::cpu::engine`]).

use crate::cpu::planes::{Planes, for_each_chunk_with, max_into};
use burn::nn::conv::Conv2d;
use burn::tensor::{Tensor, TensorData};
use deepview_kernels::{Act, PackedConv, Plane, conv3x3, conv3x3_from};

/// A convolution split by input channels into a per-view part and a part whose inputs are the same for
/// every view (computed once per plane; the per-view sums start from it: [`conv3x3_from`]).
struct SplitConv {
    /// Input channels `..own.cin`, no bias.
    own: PackedConv,
    /// The remaining input channels, with the bias.
    shared: PackedConv,
}

/// A core net's convolutions packed for the kernels.
pub(crate) struct PackedNet {
    input: Vec<PackedConv>,
    stages: Vec<PackedConv>,
    head: PackedConv,
    out: PackedConv,
    /// The first input conv split, when the last input channels are shared by the views.
    input_split: Option<SplitConv>,
    /// The first conv of every stage (inputs `concat(B_k, max over views)`) split: the max is shared
    /// (empty: not split).
    stage_splits: Vec<SplitConv>,
}

/// `[cout, cin, 3, 3]` weights and bias of a conv.
fn weights(conv: &Conv2d) -> (Vec<f32>, Option<Vec<f32>>, usize, usize) {
    let [cout, cin, kh, kw] = conv.weight.dims();
    assert_eq!((kh, kw), (3, 3), "3x3 convolutions expected");
    let w: Vec<f32> = conv
        .weight
        .val()
        .into_data()
        .try_to_vec()
        .expect("f32 weights");
    let b: Option<Vec<f32>> = conv
        .bias
        .as_ref()
        .map(|b| b.val().into_data().try_to_vec().expect("f32 bias"));
    (w, b, cout, cin)
}

fn pack(conv: &Conv2d) -> PackedConv {
    let (w, b, cout, cin) = weights(conv);
    PackedConv::new(&w, b.as_deref(), cout, cin)
}

/// `conv` split at input channel `at`: `..at` per view, `at..` shared.
fn split(conv: &Conv2d, at: usize) -> SplitConv {
    let (w, b, cout, cin) = weights(conv);
    SplitConv {
        own: PackedConv::input_range(&w, None, cout, cin, 0..at),
        shared: PackedConv::input_range(&w, b.as_deref(), cout, cin, at..cin),
    }
}

impl PackedNet {
    /// The net's convs; `shared_inputs`: how many of the last input channels are the same for every
    /// view (the state of an update net; 0: none), which [`NetScratch::run`] then reads from view 0's
    /// input planes only; `split_stages`: compute each stage's max-over-views part once per plane
    /// (fewer FLOPs, other rounding). Without either, the arithmetic is the per-layer
    /// [`crate::cpu::ops::KernelOps::conv3x3_act`] path's, bit for bit.
    pub(crate) fn new(
        input: &[Conv2d],
        stages: &[Conv2d],
        head: &Conv2d,
        out: &Conv2d,
        shared_inputs: usize,
        split_stages: bool,
    ) -> Self {
        let f = head.weight.dims()[1];
        let cin = input[0].weight.dims()[1];
        assert!(
            shared_inputs < cin,
            "{shared_inputs} shared of {cin} inputs"
        );
        Self {
            input: input.iter().map(pack).collect(),
            stages: stages.iter().map(pack).collect(),
            head: pack(head),
            out: pack(out),
            input_split: (shared_inputs > 0).then(|| split(&input[0], cin - shared_inputs)),
            stage_splits: if split_stages {
                stages.iter().step_by(2).map(|c| split(c, f)).collect()
            } else {
                Vec::new()
            },
        }
    }
    pub(crate) fn in_channels(&self) -> usize {
        self.input[0].cin
    }
    /// The input channels the views share (see [`Self::new`]).
    pub(crate) fn shared_inputs(&self) -> usize {
        self.input_split.as_ref().map_or(0, |s| s.shared.cin)
    }
    pub(crate) fn features(&self) -> usize {
        self.head.cin
    }
    pub(crate) fn out_channels(&self) -> usize {
        self.out.cout
    }
}

/// One thread's activations of a core net on the `K` slices of one plane: per view `[in (Cin) | A (F) |
/// B (F)]`, then the max over views (F), the head (F), the output (S) planes and the shared partial
/// sums (F) of a split conv.
pub(crate) struct NetScratch {
    planes: Planes,
    views: usize,
    cin: usize,
    f: usize,
    so: usize,
}

impl NetScratch {
    pub(crate) fn new(net: &PackedNet, plane: Plane, views: usize) -> Self {
        let (cin, f, so) = (net.in_channels(), net.features(), net.out_channels());
        Self {
            planes: Planes::new(plane, views * (cin + 2 * f) + 3 * f + so),
            views,
            cin,
            f,
            so,
        }
    }

    /// The padded input plane of channel `c` of view `k` (write the interior; the border stays zero).
    pub(crate) fn input_mut(&mut self, k: usize, c: usize) -> &mut [f32] {
        &mut self.planes.bufs[k * (self.cin + 2 * self.f) + c]
    }

    /// The padded input planes of view `k` (all `Cin` channels).
    pub(crate) fn view_inputs_mut(&mut self, k: usize) -> Vec<&mut [f32]> {
        let base = k * (self.cin + 2 * self.f);
        self.planes.bufs[base..base + self.cin]
            .iter_mut()
            .map(|v| v.as_mut_slice())
            .collect()
    }

    /// The padded input planes of every view, view after view (`K * Cin` planes).
    pub(crate) fn inputs_mut(&mut self) -> Vec<&mut [f32]> {
        let per_view = self.cin + 2 * self.f;
        let cin = self.cin;
        self.planes.bufs[..self.views * per_view]
            .chunks_mut(per_view)
            .flat_map(|v| v[..cin].iter_mut().map(|b| b.as_mut_slice()))
            .collect()
    }

    /// The padded output plane of channel `c` after [`Self::run`].
    pub(crate) fn output(&self, c: usize) -> &[f32] {
        debug_assert!(c < self.so);
        &self.planes.bufs[self.views * (self.cin + 2 * self.f) + 2 * self.f + c]
    }

    /// Run `net` on the inputs (see [`CoreNet::forward`](crate::network::CoreNet::forward)).
    pub(crate) fn run(&mut self, net: &PackedNet) {
        let plane = self.planes.plane;
        let (views, cin, f) = (self.views, self.cin, self.f);
        let per_view = cin + 2 * f;
        let m0 = views * per_view;
        let bufs = &mut self.planes.bufs;
        // Convolve planes `from` (all before `to`) into `c.cout` planes from `to` on.
        let layer =
            |bufs: &mut Vec<Vec<f32>>, from: &[usize], to: usize, c: &PackedConv, act: Act| {
                let (lo, hi) = bufs.split_at_mut(to);
                let ins: Vec<&[f32]> = from.iter().map(|&i| lo[i].as_slice()).collect();
                let mut outs: Vec<&mut [f32]> =
                    hi[..c.cout].iter_mut().map(|v| v.as_mut_slice()).collect();
                conv3x3(plane, &ins, c, act, &mut outs);
            };
        let a = |k: usize| k * per_view + cin;
        let b = |k: usize| k * per_view + cin + f;
        // The shared partial sums of a split conv.
        let sh = m0 + 2 * f + self.so;
        // `split` of the planes `own(k)` and `shared` into A_k for every view: the shared part once, into
        // the planes from `sh` on, then each view's part from those sums.
        let split_layer = |bufs: &mut Vec<Vec<f32>>,
                           own: &dyn Fn(usize) -> Vec<usize>,
                           shared: &[usize],
                           split: &SplitConv| {
            layer(bufs, shared, sh, &split.shared, Act::Linear);
            for k in 0..views {
                // A_k lies before the inputs and the sums: move its planes out meanwhile.
                let mut a_planes: Vec<Vec<f32>> = (0..f)
                    .map(|c| std::mem::take(&mut bufs[a(k) + c]))
                    .collect();
                {
                    let ins: Vec<&[f32]> = own(k).iter().map(|&i| bufs[i].as_slice()).collect();
                    let init: Vec<&[f32]> = (sh..sh + f).map(|i| bufs[i].as_slice()).collect();
                    let mut outs: Vec<&mut [f32]> =
                        a_planes.iter_mut().map(|v| v.as_mut_slice()).collect();
                    conv3x3_from(plane, &ins, &split.own, Act::Elu, &init, &mut outs);
                }
                for (c, v) in a_planes.into_iter().enumerate() {
                    bufs[a(k) + c] = v;
                }
            }
        };
        match &net.input_split {
            Some(split) => {
                let own_cin = split.own.cin;
                let shared: Vec<usize> = (own_cin..cin).collect();
                split_layer(
                    bufs,
                    &|k| (k * per_view..k * per_view + own_cin).collect(),
                    &shared,
                    split,
                );
            }
            None => {
                for k in 0..views {
                    let from: Vec<usize> = (k * per_view..k * per_view + cin).collect();
                    layer(bufs, &from, a(k), &net.input[0], Act::Elu);
                }
            }
        }
        for k in 0..views {
            let from: Vec<usize> = (a(k)..a(k) + f).collect();
            layer(bufs, &from, b(k), &net.input[1], Act::Elu);
        }
        let max_views = |bufs: &mut Vec<Vec<f32>>| {
            let (lo, hi) = bufs.split_at_mut(m0);
            for c in 0..f {
                let srcs: Vec<&[f32]> = (0..views).map(|k| lo[b(k) + c].as_slice()).collect();
                max_into(&mut hi[c], &srcs);
            }
        };
        for (i, pair) in net.stages.chunks(2).enumerate() {
            max_views(bufs);
            match net.stage_splits.get(i) {
                // concat(B_k, m) -> A_k, the max's part once.
                Some(split) => {
                    let shared: Vec<usize> = (m0..m0 + f).collect();
                    split_layer(bufs, &|k| (b(k)..b(k) + f).collect(), &shared, split);
                }
                // concat(B_k, m) -> A_k as one conv per view.
                None => {
                    for k in 0..views {
                        // A lies before B and m: move A's planes out meanwhile.
                        let mut a_planes: Vec<Vec<f32>> = (0..f)
                            .map(|c| std::mem::take(&mut bufs[a(k) + c]))
                            .collect();
                        {
                            let ins: Vec<&[f32]> = (b(k)..b(k) + f)
                                .chain(m0..m0 + f)
                                .map(|i| bufs[i].as_slice())
                                .collect();
                            let mut outs: Vec<&mut [f32]> =
                                a_planes.iter_mut().map(|v| v.as_mut_slice()).collect();
                            conv3x3(plane, &ins, &pair[0], Act::Elu, &mut outs);
                        }
                        for (c, v) in a_planes.into_iter().enumerate() {
                            bufs[a(k) + c] = v;
                        }
                    }
                }
            }
            for k in 0..views {
                let from: Vec<usize> = (a(k)..a(k) + f).collect();
                layer(bufs, &from, b(k), &pair[1], Act::Elu);
            }
        }
        max_views(bufs);
        let from: Vec<usize> = (m0..m0 + f).collect();
        layer(bufs, &from, m0 + f, &net.head, Act::Elu);
        let from: Vec<usize> = (m0 + f..m0 + 2 * f).collect();
        layer(bufs, &from, m0 + 2 * f, &net.out, Act::Linear);
    }
}

/// The whole core net (without the U-Net's resampling) on one plane's `K` slices at a time, every
/// activation in per-thread plane buffers ([`NetScratch`]): no tensor per layer, the concatenation with
/// the max over views by plane lists. `x` `[K*D, Cin, h, w]` (view-major) -> `[D, out, h, w]`; the same
/// arithmetic as the per-layer [`crate::cpu::ops::KernelOps::conv3x3_act`] path (bit-identical outputs).
pub fn core_net_inference(
    input: &[Conv2d],
    stages: &[Conv2d],
    head: &Conv2d,
    out: &Conv2d,
    x: Tensor<4>,
    views: usize,
) -> Tensor<4> {
    let device = x.device();
    let [kd, cin, h, w] = x.dims();
    let d = kd / views;
    // Not split: the same arithmetic as the per-layer path under autodiff (training's recompute relies on
    // it: `recompute_gradients_match_full_backward`).
    let net = PackedNet::new(input, stages, head, out, 0, false);
    let so = net.out_channels();
    let x: Vec<f32> = x.into_data().try_to_vec().expect("f32 tensor");
    let plane = Plane::new(h, w);
    let hw = h * w;
    let mut result = vec![0f32; d * so * hw];
    if hw > 0 {
        for_each_chunk_with(
            &mut result,
            so * hw,
            || NetScratch::new(&net, plane, views),
            |s, (p, res)| {
                for k in 0..views {
                    for c in 0..cin {
                        let src = &x[((k * d + p) * cin + c) * hw..][..hw];
                        plane.pad_into(src, s.input_mut(k, c));
                    }
                }
                s.run(&net);
                for (c, dst) in res.chunks_exact_mut(hw).enumerate() {
                    plane.unpad_into(s.output(c), dst);
                }
            },
        );
    }
    Tensor::from_data(TensorData::new(result, [d, so, h, w]), &device)
}
