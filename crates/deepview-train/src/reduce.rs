//! Summing the gradients of the replicas of one process (`--devices`) onto the first device, before the
//! reduction across ranks ([`crate::dist`]) and the global-norm clipping.
//!
//! Two ways, chosen once per trainer by [`choose`] from the devices:
//! - **burn's collective ops** ([`LocalReduction::Collective`]): a [`DistributedContext`] over the
//!   devices, and for every parameter one `all_reduce(gradient, Sum, devices)` per device
//!   (`burn::tensor::distributed`); the sum arrives on every device and the first device's copy is
//!   kept. Taken when there are 2 or more distinct devices, all of them cubecl devices whose runtime
//!   has a transport between its devices: the very check cubecl's `ComputeClient::all_reduce` makes
//!   before it panics (`has_device_transport`, cubecl-runtime 0.11.3 `src/client.rs:943-958`).
//! - **copies** ([`LocalReduction::Copy`]): [`crate::clip::sum_on_device`], every replica's gradients
//!   copied to the first device and added there in device order. Taken for one device, for any set
//!   with a `cpu` device (burn-flex has no collective ops: burn-backend-extension 0.22.1
//!   `src/catalog.rs:30-35` lists it with `distributed: false`, so burn-dispatch's `all_reduce` panics
//!   with "Distributed operations are not supported for tensor kind Flex(..)", burn-dispatch 0.22.1
//!   `src/ops/distributed.rs:163`, reached from `:221`), for a device named twice, and for a runtime
//!   without a transport.
//!
//! In burn 0.22.1 / cubecl 0.11.3 only CUDA has that transport (NCCL: cubecl-cuda
//! `src/runtime.rs:410` sets `server_comm_enabled` when the NCCL library is present). cubecl-wgpu's
//! server takes every default of `ServerCommunication` (`impl ServerCommunication for WgpuServer<C> {}`,
//! cubecl-wgpu 0.11.3 `src/compute/server.rs:109`; the defaults return `NoDeviceTransport`,
//! cubecl-runtime `src/server/base.rs:917-969`) and never turns `server_comm_enabled` on (default
//! `false`, `src/server/base.rs:217`), so `all_reduce` on any wgpu device panics on the caller with
//! "Can't use `all_reduce` on wgpu<wgsl>, which has no transport between its devices"
//! (cubecl-runtime `src/client.rs:956`, measured on lavapipe); burn's catalog says as much
//! (burn-backend-extension 0.22.1 `src/catalog.rs:21-27`: "only CUDA implements them today: a
//! collective on a wgpu or CPU device reaches cubecl's `ComputeServer::all_reduce` and panics
//! there"). wgpu device sets therefore take the copies, and will take the collective ops by
//! themselves once cubecl's wgpu runtime reports a transport.
//!
//! Both sum (each tuple's loss is already divided by the global batch), so both give the gradient of
//! the batch-mean loss; with two devices they agree bit for bit (`a + b == b + a`), with more the
//! collective may add in another order (rounding).

use burn::module::Module;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
use burn::module::{ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::Device;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
use burn::tensor::Tensor;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
use burn::tensor::distributed::{
    DistributedConfig, DistributedContext, ReduceOperation, all_reduce,
};
#[cfg(any(feature = "wgpu", feature = "cuda"))]
use std::cell::Cell;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
use std::sync::{Arc, Mutex, Weak};

use deepview_net::device::{DeviceFamily, device_family};

/// How the replicas of one process are summed (see the module documentation).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LocalReduction {
    /// One device: nothing to sum across devices.
    Single,
    /// [`crate::clip::sum_on_device`]; `why` says why not the collective ops.
    Copy { why: String },
    /// burn's `all_reduce` (sum) across the devices.
    Collective,
}

/// What a trainer holds to sum its replicas.
pub(crate) enum Reducer {
    Copy,
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    Collective {
        /// The devices, without autodiff (the gradients live there).
        devices: Vec<Device>,
        /// burn `all_reduce` calls made so far (one per parameter and device of each step).
        calls: Cell<u64>,
        _context: Arc<DistributedContext>,
    },
}

impl std::fmt::Debug for Reducer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Reducer::Copy => write!(f, "Copy"),
            #[cfg(any(feature = "wgpu", feature = "cuda"))]
            Reducer::Collective { devices, .. } => write!(f, "Collective({devices:?})"),
        }
    }
}

/// Whether `device` is a cubecl device whose runtime moves data between its devices itself (what
/// cubecl's collectives require).
#[cfg(any(feature = "wgpu", feature = "cuda"))]
fn has_device_transport(device: &Device) -> bool {
    match device.clone().inner().as_dispatch() {
        burn::backend::DispatchDevice::Cube(d) => d.client().has_device_transport(),
        #[allow(unreachable_patterns)]
        _ => false,
    }
}

/// The process-wide [`DistributedContext`]. burn keeps one gradient-sync server per backend type
/// (burn-backend 0.22.1 `src/backend/distributed/api.rs:44-59`: a second `init` is a no-op, and the
/// first context dropped closes it for everyone), so trainers living at the same time share one
/// context instead of closing each other's. The explicit `all_reduce` used here does not go through
/// that server (it goes to cubecl's client), so its device list only needs to be the first one's.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
fn shared_context(devices: &[Device]) -> Arc<DistributedContext> {
    static CONTEXT: Mutex<Weak<DistributedContext>> = Mutex::new(Weak::new());
    let mut slot = CONTEXT.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(c) = slot.upgrade() {
        return c;
    }
    let c = Arc::new(DistributedContext::init(
        devices.to_vec(),
        DistributedConfig {
            all_reduce_op: ReduceOperation::Sum,
        },
    ));
    *slot = Arc::downgrade(&c);
    c
}

/// Choose how to sum the replicas on `devices` (named `names`, as [`deepview_net::device::parse_device`] read them).
pub(crate) fn choose(names: &[String], devices: &[Device]) -> (Reducer, LocalReduction) {
    let copy = |why: &str| {
        (
            Reducer::Copy,
            LocalReduction::Copy {
                why: why.to_string(),
            },
        )
    };
    if devices.len() < 2 {
        return (Reducer::Copy, LocalReduction::Single);
    }
    if names
        .iter()
        .any(|n| device_family(n) == Some(DeviceFamily::Cpu))
    {
        return copy("a `cpu` device (burn-flex has no collective ops)");
    }
    let inner: Vec<Device> = devices.iter().map(|d| d.clone().inner()).collect();
    if (1..inner.len()).any(|i| inner[..i].contains(&inner[i])) {
        return copy("a device is named twice");
    }
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    {
        if let Some(i) = inner.iter().position(|d| !has_device_transport(d)) {
            return copy(&format!(
                "the runtime of `{}` has no transport between its devices (cubecl 0.11.3: CUDA with \
                 NCCL only; wgpu has none)",
                names.get(i).map_or("?", |s| s.as_str())
            ));
        }
        let context = shared_context(&inner);
        (
            Reducer::Collective {
                devices: inner,
                calls: Cell::new(0),
                _context: context,
            },
            LocalReduction::Collective,
        )
    }
    #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
    copy("this build has no GPU backend")
}

impl Reducer {
    /// The sum of the replicas' gradient sets (`sets[i]` from device `i`; `None`: that replica stopped
    /// early on a non-finite loss, or had no tuples) on `main`, the first device without autodiff.
    pub(crate) fn reduce<M: Module>(
        &self,
        module: &M,
        sets: Vec<Option<GradientsParams>>,
        main: &Device,
    ) -> GradientsParams {
        match self {
            #[cfg(any(feature = "wgpu", feature = "cuda"))]
            Reducer::Collective { devices, calls, .. } if sets.len() >= 2 => {
                let n = sets.len();
                let (sum, made) = collective_sum(module, sets, &devices[..n]);
                calls.set(calls.get() + made);
                sum
            }
            _ => crate::clip::sum_on_device(module, sets.into_iter().flatten().collect(), main),
        }
    }

    /// How many burn `all_reduce` calls this reducer has made (0 for copies).
    pub(crate) fn all_reduce_calls(&self) -> u64 {
        match self {
            Reducer::Copy => 0,
            #[cfg(any(feature = "wgpu", feature = "cuda"))]
            Reducer::Collective { calls, .. } => calls.get(),
        }
    }
}

/// `all_reduce` (sum) of every parameter's gradient across `devices` (`sets[i]` on `devices[i]`); a
/// parameter that has a gradient on some device gets zeros on the others (every device must take part
/// in each collective), one without a gradient anywhere stays without. The result is on `devices[0]`,
/// with the number of `all_reduce` calls made.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub fn collective_sum<M: Module>(
    module: &M,
    sets: Vec<Option<GradientsParams>>,
    devices: &[Device],
) -> (GradientsParams, u64) {
    struct AllReduce<'a> {
        sets: Vec<GradientsParams>,
        devices: &'a [Device],
        out: GradientsParams,
        calls: u64,
    }
    impl ModuleVisitor for AllReduce<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let grads: Vec<Option<Tensor<D>>> = self
                .sets
                .iter_mut()
                .map(|s| s.remove::<D>(param.id))
                .collect();
            if grads.iter().all(Option::is_none) {
                return;
            }
            let shape = param.val().shape();
            // Submit on every device before resolving any (each waits for the others).
            let pending: Vec<_> = grads
                .into_iter()
                .zip(self.devices)
                .map(|(g, d)| {
                    let g = g.unwrap_or_else(|| Tensor::<D>::zeros(shape.clone(), d));
                    self.calls += 1;
                    all_reduce(g, ReduceOperation::Sum, self.devices.to_vec())
                })
                .collect();
            let mut sums = pending.into_iter().map(|c| c.resolve());
            let first = sums.next().expect("two or more devices");
            sums.for_each(drop);
            self.out.register::<D>(param.id, first);
        }
    }
    assert_eq!(sets.len(), devices.len(), "one gradient set per device");
    let mut v = AllReduce {
        sets: sets
            .into_iter()
            .map(|s| s.unwrap_or_else(GradientsParams::new))
            .collect(),
        devices,
        out: GradientsParams::new(),
        calls: 0,
    };
    module.visit(&mut v);
    (v.out, v.calls)
}
