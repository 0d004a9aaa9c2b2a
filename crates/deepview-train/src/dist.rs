//! Data parallelism across processes: one training replica per rank of a communicator (MPI in the
//! binary's `mpi` feature, or [`ThreadGroup`] in tests).
//!
//! Every rank draws the whole global batch with the same RNG (one global seed), so the tuples of a step
//! do not depend on the number of ranks; rank `r` of `N` computes the tuples
//! `r * batch / N .. (r + 1) * batch / N` (split further across its own `--devices`), each tuple's loss
//! divided by the global batch size. The ranks' gradient sums are then all-reduced (summed: the sum of
//! the `loss / batch` gradients is the gradient of the batch-mean loss) together with the tuples'
//! losses and a stop flag, in one flat buffer; every rank then clips the same global norm and takes the
//! same Adam step, so the replicas stay identical (checked by a hash of the weights at every
//! checkpoint). Only rank 0 writes the run folder (config, metrics, checkpoints) and prints; on
//! `--resume` rank 0 chooses the checkpoint and every rank loads that one.
//!
//! Within one process, the replicas on several devices (`--devices`) are summed first, by
//! [`crate::reduce`] onto the first device, and that sum is what enters the reduction across ranks
//! above: burn 0.22's collective ops (`burn::tensor::distributed`: a `DistributedContext` over the
//! devices, `all_reduce(gradient, Sum, devices)` per parameter and device) where every device is a
//! cubecl device whose runtime has a transport between its devices (in cubecl 0.11.3: CUDA with
//! NCCL), otherwise [`crate::clip::sum_on_device`] (copies to the first device, added in device
//! order): for any `cpu` device (burn-flex has no collective ops) and for wgpu (cubecl's wgpu runtime
//! has no transport and panics on `all_reduce`; file and line evidence in [`crate::reduce`]). The
//! ranks themselves always reduce through [`Collective`] (MPI), on the host.

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor, TensorData};
use std::sync::{Arc, Barrier, Mutex};

/// What training needs from a communicator spanning processes. Collective calls are made by every rank
/// in the same order, from one thread.
pub trait Collective {
    /// This process's rank, `0..size`.
    fn rank(&self) -> usize;
    /// Number of ranks.
    fn size(&self) -> usize;
    /// Element-wise sum over the ranks, in place; every rank receives the same values.
    fn all_reduce_sum(&self, buf: &mut [f32]);
    /// Rank 0's `buf` on every rank.
    fn broadcast_f32(&self, buf: &mut [f32]);
    /// Rank 0's `buf` on every rank.
    fn broadcast_u64(&self, buf: &mut [u64]);
}

/// The ranks' share of a batch of `n` tuples: rank `r` computes `range(n, r, size)`.
pub fn share(n: usize, rank: usize, size: usize) -> std::ops::Range<usize> {
    rank * n / size..(rank + 1) * n / size
}

struct Flatten<'a> {
    grads: Option<&'a GradientsParams>,
    values: Vec<f32>,
    has_grad: Vec<f32>,
}

impl ModuleVisitor for Flatten<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        match self.grads.and_then(|g| g.get::<D>(param.id)) {
            Some(g) => {
                self.values
                    .extend(g.into_data().convert::<f32>().iter::<f32>());
                self.has_grad.push(1.0);
            }
            None => {
                let n = param.val().shape().num_elements();
                self.values.extend(std::iter::repeat_n(0.0, n));
                self.has_grad.push(0.0);
            }
        }
    }
}

/// The gradients of `module`'s parameters as one flat vector in visiting order (zeros for parameters
/// without a gradient, or for all of them when `grads` is `None`) followed by one value per parameter:
/// 1 if it has a gradient, else 0.
pub fn flatten_grads<M: Module>(module: &M, grads: Option<&GradientsParams>) -> Vec<f32> {
    let mut v = Flatten {
        grads,
        values: Vec::new(),
        has_grad: Vec::new(),
    };
    module.visit(&mut v);
    v.values.extend(v.has_grad);
    v.values
}

/// Number of values [`flatten_grads`] produces for `module`.
pub fn flat_len<M: Module>(module: &M) -> usize {
    struct Count(usize, usize);
    impl ModuleVisitor for Count {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0 += param.val().shape().num_elements();
            self.1 += 1;
        }
    }
    let mut c = Count(0, 0);
    module.visit(&mut c);
    c.0 + c.1
}

struct Unflatten<'a> {
    flat: &'a [f32],
    has_grad: &'a [f32],
    at: usize,
    param: usize,
    device: &'a Device,
    grads: GradientsParams,
}

impl ModuleVisitor for Unflatten<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let shape = param.val().shape();
        let n = shape.num_elements();
        let values = &self.flat[self.at..self.at + n];
        self.at += n;
        let used = self.has_grad[self.param] > 0.0;
        self.param += 1;
        if used {
            let t = Tensor::<D>::from_data(TensorData::new(values.to_vec(), shape), self.device);
            self.grads.register::<D>(param.id, t);
        }
    }
}

/// The inverse of [`flatten_grads`] (after a reduction: a parameter has a gradient if any rank had
/// one), on `device` (a plain, non-autodiff device).
pub fn unflatten_grads<M: Module>(module: &M, flat: &[f32], device: &Device) -> GradientsParams {
    let values = flat_len(module);
    assert_eq!(flat.len(), values, "flat gradient length");
    let mut count = 0;
    struct Params<'a>(&'a mut usize);
    impl ModuleVisitor for Params<'_> {
        fn visit_float<const D: usize>(&mut self, _: &Param<Tensor<D>>) {
            *self.0 += 1;
        }
    }
    module.visit(&mut Params(&mut count));
    let (flat, has_grad) = flat.split_at(values - count);
    let mut v = Unflatten {
        flat,
        has_grad,
        at: 0,
        param: 0,
        device,
        grads: GradientsParams::new(),
    };
    module.visit(&mut v);
    v.grads
}

/// A module with its float parameters replaced by `values` (in visiting order, as
/// [`crate::example::parameter_values`] lists them), keeping ids and gradient requirements.
pub fn with_parameter_values<M: Module>(module: M, values: &[f32]) -> M {
    struct Set<'a> {
        values: &'a [f32],
        at: usize,
    }
    impl ModuleMapper for Set<'_> {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let n = param.val().shape().num_elements();
            let values = &self.values[self.at..self.at + n];
            self.at += n;
            param.map(|t| {
                let grad = t.is_require_grad();
                Tensor::<D>::from_data(TensorData::new(values.to_vec(), t.shape()), &t.device())
                    .set_require_grad(grad)
            })
        }
    }
    let mut s = Set { values, at: 0 };
    let m = module.map(&mut s);
    assert_eq!(s.at, values.len(), "parameter count");
    m
}

/// A 64-bit FNV-1a hash of the bits of parameter values (replicas must agree exactly).
pub fn hash_values(values: &[f32]) -> u64 {
    values.iter().fold(0xcbf2_9ce4_8422_2325, |h, v| {
        (h ^ v.to_bits() as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Ranks as threads of one process (for tests): `ThreadGroup::new(n)` gives one [`Collective`] per
/// rank, each to be moved into its own thread. Reductions sum in rank order, like a single process
/// summing its replicas in turn.
pub struct ThreadGroup {
    rank: usize,
    size: usize,
    shared: Arc<(Mutex<Vec<Vec<f32>>>, Barrier)>,
}

impl ThreadGroup {
    pub fn new(size: usize) -> Vec<ThreadGroup> {
        let shared = Arc::new((Mutex::new(vec![Vec::new(); size]), Barrier::new(size)));
        (0..size)
            .map(|rank| ThreadGroup {
                rank,
                size,
                shared: shared.clone(),
            })
            .collect()
    }

    /// Post `buf`, wait for everyone, read every rank's posting, wait again (so postings are not
    /// overwritten before everyone has read them).
    fn exchange<T>(&self, buf: Vec<f32>, read: impl FnOnce(&[Vec<f32>]) -> T) -> T {
        let (slots, barrier) = &*self.shared;
        slots.lock().unwrap()[self.rank] = buf;
        barrier.wait();
        let out = read(&slots.lock().unwrap());
        barrier.wait();
        out
    }
}

impl Collective for ThreadGroup {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    fn all_reduce_sum(&self, buf: &mut [f32]) {
        let sum = self.exchange(buf.to_vec(), |all| {
            let mut sum = all[0].clone();
            for other in &all[1..] {
                for (s, v) in sum.iter_mut().zip(other) {
                    *s += v;
                }
            }
            sum
        });
        buf.copy_from_slice(&sum);
    }

    fn broadcast_f32(&self, buf: &mut [f32]) {
        let root = self.exchange(buf.to_vec(), |all| all[0].clone());
        buf.copy_from_slice(&root);
    }

    fn broadcast_u64(&self, buf: &mut [u64]) {
        // Each u64 travels as four 16-bit pieces (exact in f32).
        let enc: Vec<f32> = buf
            .iter()
            .flat_map(|v| (0..4).map(move |i| ((v >> (16 * i)) & 0xffff) as f32))
            .collect();
        let root = self.exchange(enc, |all| all[0].clone());
        for (v, c) in buf.iter_mut().zip(root.chunks(4)) {
            *v = c
                .iter()
                .enumerate()
                .fold(0, |a, (i, x)| a | ((*x as u64) << (16 * i)));
        }
    }
}
