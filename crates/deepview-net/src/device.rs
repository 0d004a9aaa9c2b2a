//! Devices by name, for inference and training: `cpu`, `wgpu[:N]`, `wgpu:cpu`, `cuda[:N]`, `cuda:local`.

use burn::tensor::Device;

/// A device name that cannot be used in this build or on this machine.
#[derive(Debug, thiserror::Error)]
#[error("device `{name}`: {message}")]
pub struct DeviceError {
    pub name: String,
    pub message: String,
}

/// The process's rank on its machine under an MPI launcher (Open MPI, MPICH, Slurm, PMI), 0 without one:
/// the index of `cuda:local`.
pub fn local_rank() -> usize {
    [
        "OMPI_COMM_WORLD_LOCAL_RANK",
        "MPI_LOCALRANKID",
        "MPI_LOCAL_RANK",
        "SLURM_LOCALID",
        "PMI_LOCAL_RANK",
    ]
    .iter()
    .find_map(|k| std::env::var(k).ok()?.parse().ok())
    .unwrap_or(0)
}

/// A wgpu device, initialised once per name (burn refuses a second initialisation of the same runtime)
/// through the options API, which reports a missing adapter as an error instead of panicking at the
/// first tensor operation. `wgpu` is the default adapter (a GPU, or a CPU Vulkan driver such as Mesa's
/// lavapipe), `wgpu:N` the N-th discrete GPU, `wgpu:cpu` the CPU adapter (lavapipe): on a machine with
/// lavapipe alone, `wgpu` and `wgpu:cpu` are two distinct devices (two wgpu devices, queues and burn
/// servers) on the same adapter, which is how the tests run two wgpu replicas without a GPU.
#[cfg(feature = "wgpu")]
fn wgpu_device(name: &str, index: Option<WgpuIndex>) -> Result<Device, String> {
    use burn::tensor::DeviceKind;
    use std::sync::{Mutex, OnceLock};
    static DEVICES: OnceLock<Mutex<Vec<(String, Device)>>> = OnceLock::new();
    let mut cache = DEVICES
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    if let Some((_, d)) = cache.iter().find(|(n, _)| n == name) {
        return Ok(d.clone());
    }
    let kind = match index {
        Some(WgpuIndex::Discrete(i)) => DeviceKind::DiscreteGpu(i),
        Some(WgpuIndex::Cpu) => DeviceKind::Cpu,
        None => DeviceKind::DefaultDevice,
    };
    let device = Device::wgpu_options()
        .device_kind(kind)
        .init()
        .map_err(|e| format!("cannot initialise the wgpu device: {e}"))?;
    cache.push((name.to_string(), device.clone()));
    Ok(device)
}

#[cfg(not(feature = "wgpu"))]
const NO_WGPU: &str = "this build has no wgpu support (rebuild with `--features wgpu`)";

/// The part of a wgpu device name after `wgpu:`.
#[cfg(feature = "wgpu")]
#[derive(Clone, Copy)]
enum WgpuIndex {
    Discrete(usize),
    Cpu,
}

/// What kind of device a name (as [`parse_device`] accepts it) is, without initialising it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeviceFamily {
    /// `cpu`: burn-flex.
    Cpu,
    /// `wgpu[:N|:cpu]`: cubecl's wgpu runtime.
    Wgpu,
    /// `cuda[:N]`: cubecl's CUDA runtime.
    Cuda,
}

/// The family of a device name, or `None` for a name [`parse_device`] rejects as unknown.
pub fn device_family(name: &str) -> Option<DeviceFamily> {
    match name.split_once(':').map_or(name, |(k, _)| k) {
        "cpu" | "flex" => Some(DeviceFamily::Cpu),
        "wgpu" => Some(DeviceFamily::Wgpu),
        "cuda" => Some(DeviceFamily::Cuda),
        _ => None,
    }
}

/// Parse a device name: `cpu` (burn's flex backend), `wgpu`/`wgpu:N`/`wgpu:cpu` (feature `wgpu`),
/// `cuda`/`cuda:N` (feature `cuda`). The index `local` is the process's rank on its machine under an MPI launcher
/// (`cuda:local`: one GPU per rank), see [`local_rank`].
pub fn parse_device(name: &str) -> Result<Device, DeviceError> {
    let err = |m: &str| DeviceError {
        name: name.to_string(),
        message: m.to_string(),
    };
    if name == "wgpu:cpu" {
        #[cfg(feature = "wgpu")]
        return wgpu_device(name, Some(WgpuIndex::Cpu)).map_err(|m| err(&m));
        #[cfg(not(feature = "wgpu"))]
        return Err(err(NO_WGPU));
    }
    let (kind, index) = match name.split_once(':') {
        Some((k, "local")) => (k, Some(local_rank())),
        Some((k, i)) => (
            k,
            Some(
                i.parse::<usize>()
                    .map_err(|_| err("the index after ':' must be a number or `local`"))?,
            ),
        ),
        None => (name, None),
    };
    match kind {
        // One CPU device: `cpu:0` and `cpu:local` (every rank its own process) name it too, another
        // index none.
        "cpu" | "flex" if index.is_some_and(|i| i > 0) && !name.ends_with(":local") => Err(err(
            "there is one CPU device: `cpu` (`train --devices cpu,cpu` trains two replicas on it)",
        )),
        "cpu" | "flex" => Ok(Device::flex()),
        #[cfg(feature = "wgpu")]
        "wgpu" => wgpu_device(name, index.map(WgpuIndex::Discrete)).map_err(|m| err(&m)),
        #[cfg(not(feature = "wgpu"))]
        "wgpu" => {
            let _ = index;
            Err(err(NO_WGPU))
        }
        #[cfg(feature = "cuda")]
        "cuda" => Ok(Device::cuda(index.unwrap_or(0))),
        #[cfg(not(feature = "cuda"))]
        "cuda" => Err(err(
            "this build has no CUDA support (rebuild with `--features cuda`)",
        )),
        _ => Err(err(
            "unknown device (expected cpu, wgpu[:N], wgpu:cpu or cuda[:N])",
        )),
    }
}

/// What a device's memory allows, as its runtime reports it: `None` where there is no figure (the CPU,
/// whose budget is the host's, or a runtime that states none).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DeviceMemory {
    /// Bytes the device can hold at once (cubecl's `max_memory`: the largest device-local heap on Vulkan,
    /// the total memory on CUDA).
    pub capacity: Option<u64>,
    /// Bytes of the largest single allocation (cubecl's `max_page_size`: on wgpu the smaller of the
    /// storage-buffer binding and buffer size limits, on CUDA a quarter of the memory). A tensor over it
    /// cannot be allocated at all.
    pub max_allocation: Option<u64>,
}

/// The memory figures of `device` (opens the device's runtime where it is not open yet).
pub fn device_memory(device: &Device) -> DeviceMemory {
    dispatch_memory(device.as_dispatch())
}

fn dispatch_memory(device: &burn::backend::DispatchDevice) -> DeviceMemory {
    use burn::backend::DispatchDevice;
    match device {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        DispatchDevice::Cube(d) => {
            let client = d.client();
            let memory = &client.properties().memory;
            DeviceMemory {
                capacity: memory.max_memory(),
                max_allocation: Some(memory.max_page_size).filter(|&b| b > 0),
            }
        }
        DispatchDevice::Autodiff(inner) => dispatch_memory(inner),
        #[allow(unreachable_patterns)]
        _ => DeviceMemory::default(),
    }
}

/// `module`'s weights in the layout the device's convolutions read them in: channels-last on a GPU
/// ([`crate::gpu::channels_last_weights`]: no copy of each weight at every convolution), unchanged
/// elsewhere.
pub fn weights_layout<M: burn::module::Module>(module: M) -> M {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    return crate::gpu::channels_last_weights(module);
    #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
    module
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One CPU device: `cpu`, `flex`, `cpu:0` and `cpu:local` name it; another index is refused (it was
    /// accepted as the same device, as if a second CPU existed).
    #[test]
    fn cpu_names_and_indices() {
        for ok in ["cpu", "flex", "cpu:0", "cpu:local"] {
            assert!(parse_device(ok).is_ok(), "{ok}");
        }
        for bad in ["cpu:3", "flex:1", "cpu:x", "gpu", "cpu:"] {
            assert!(parse_device(bad).is_err(), "{bad}");
        }
    }
}
