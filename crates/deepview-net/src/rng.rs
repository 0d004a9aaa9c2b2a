//! Reproducible draws from burn's random generator.
//!
//! burn's CPU backend has one generator per process, not per device, and a module's parameters are
//! drawn lazily, at their first use. So `device.seed(n)` followed by building a model does not fix
//! its weights where anything else in the process draws at the same time (the trainers of a
//! multi-replica run, or the tests of one test binary, run two at a time): their draws interleave.
//! [`seeded`] seeds and runs its closure with [`BURN_RNG`] held, and [`materialize`] makes the
//! parameters draw inside it.

use burn::module::{Module, ModuleVisitor, Param};
use burn::tensor::{Device, Tensor};

/// Held by every seeding of burn's generator together with the draws that must follow it, and by
/// every other draw of the tests ([`random`], [`module`]), so that none falls between a seeding and
/// its draws.
pub static BURN_RNG: std::sync::Mutex<()> = std::sync::Mutex::new(());

thread_local! {
    /// Whether this thread holds [`BURN_RNG`] (a draw inside [`seeded`] does not lock again).
    static HELD: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// `f()` with [`BURN_RNG`] held (already held by this thread: as it is; a panic in another holder
/// does not poison it for the rest).
fn locked<T>(f: impl FnOnce() -> T) -> T {
    if HELD.get() {
        return f();
    }
    struct Release;
    impl Drop for Release {
        fn drop(&mut self) {
            HELD.set(false);
        }
    }
    let _guard = BURN_RNG.lock().unwrap_or_else(|e| e.into_inner());
    HELD.set(true);
    let _release = Release;
    f()
}

/// `f()` right after seeding burn's generator with `seed`, with [`BURN_RNG`] held throughout.
pub fn seeded<T>(device: &Device, seed: u64, f: impl FnOnce() -> T) -> T {
    locked(|| {
        device.seed(seed);
        f()
    })
}

/// [`Tensor::random`] with [`BURN_RNG`] held: a draw that does not fall inside another's seeded
/// section.
pub fn random<const D: usize, S: Into<burn::tensor::Shape>>(
    shape: S,
    distribution: burn::tensor::Distribution,
    device: &Device,
) -> Tensor<D> {
    locked(|| Tensor::<D>::random(shape, distribution, device))
}

/// A module built and drawn (its lazily initialised parameters) with [`BURN_RNG`] held, unseeded.
pub fn module<M: Module>(build: impl FnOnce() -> M) -> M {
    locked(|| {
        let m = build();
        materialize(&m);
        m
    })
}

/// Draws every lazily initialised parameter of `module` now (call it inside [`seeded`]).
pub fn materialize<M: Module>(module: &M) {
    struct Touch;
    impl ModuleVisitor for Touch {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let _ = param.val();
        }
    }
    module.visit(&mut Touch);
}

/// A module built and drawn inside [`seeded`]: the same weights every run, whatever else runs.
pub fn seeded_module<M: Module>(device: &Device, seed: u64, build: impl FnOnce() -> M) -> M {
    seeded(device, seed, || module(build))
}

/// All parameter values of a module, flattened in visiting order (drawing lazily initialised ones;
/// for tests and comparisons).
pub fn parameter_values<M: Module>(module: &M) -> Vec<f32> {
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0
                .extend(param.val().into_data().convert::<f32>().iter::<f32>());
        }
    }
    let mut c = Collect(Vec::new());
    module.visit(&mut c);
    c.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::DeepViewConfig;
    use crate::network::DeepViewModel;

    /// The same seed gives the same weights even when other draws come between the model's
    /// construction and its first use; another seed gives others.
    #[test]
    fn seeded_modules_keep_their_weights_whatever_draws_after() {
        let dev = Device::flex();
        let cfg = DeepViewConfig::preset("cpu").unwrap();
        let a = seeded_module(&dev, 5, || DeepViewModel::new(&cfg, &dev));
        // Draws (and a reseed) by someone else before `a` is first used.
        seeded(&dev, 99, || {
            let _ = Tensor::<2>::random([64, 64], burn::tensor::Distribution::Default, &dev)
                .into_data();
        });
        let b = seeded_module(&dev, 5, || DeepViewModel::new(&cfg, &dev));
        let c = seeded_module(&dev, 6, || DeepViewModel::new(&cfg, &dev));
        let (va, vb, vc) = (
            parameter_values(&a),
            parameter_values(&b),
            parameter_values(&c),
        );
        assert!(va.len() > 1000, "{}", va.len());
        assert_eq!(va, vb);
        assert_ne!(va, vc);
    }
}
