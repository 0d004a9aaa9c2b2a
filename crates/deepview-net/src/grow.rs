//! Growing a trained model into a larger configuration that computes exactly the same MPI (a
//! function-preserving widening and deepening, as in Net2Net), so a larger model starts its training from
//! a trained smaller one instead of from scratch (`deepview train --init weights/cpu --preset cpu-large`).
//!
//! - **More features:** every conv keeps its trained weights in its first output rows; its weights on the
//!   new input channels are zero. The new output rows (new feature channels) keep a fresh random
//!   initialisation, so they carry non-zero activations and training can use them at once, while nothing
//!   downstream reads them yet (zero weights on them everywhere). A stage's first conv reads
//!   `concat(features, max over views)`: both halves are placed at their new offsets.
//! - **More update nets:** a new net is a copy of the last trained net (grown to its feature count) with
//!   its output conv zeroed: a residual net that adds 0 until trained.

use crate::config::DeepViewConfig;
use crate::network::{CoreNet, DeepViewModel};
use burn::module::Param;
use burn::nn::conv::Conv2d;
use burn::tensor::{Device, Tensor, TensorData};

/// Why a model cannot be grown into a configuration.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("cannot grow the {from} model into {to}: {why}")]
pub struct GrowError {
    pub from: String,
    pub to: String,
    pub why: String,
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("f32 tensor")
}

/// `conv` (`[o, i, 3, 3]`) into `fresh` (`[O, I, 3, 3]`, `O >= o`, `I >= i`): rows `..o` get the trained
/// weights at the input channels `map[..]` and zero elsewhere; rows `o..` keep `fresh`'s random ones.
fn grow_conv(conv: &Conv2d, fresh: &Conv2d, map: &[usize], device: &Device) -> Conv2d {
    let [o, i, kh, kw] = conv.weight.dims();
    let [no, ni, _, _] = fresh.weight.dims();
    debug_assert!(no >= o && ni >= i && map.len() == i && map.iter().all(|&c| c < ni));
    let old = values(conv.weight.val());
    let mut w = values(fresh.weight.val());
    let taps = kh * kw;
    for r in 0..o {
        w[r * ni * taps..(r + 1) * ni * taps].fill(0.0);
        for (a, &c) in map.iter().enumerate() {
            let src = &old[(r * i + a) * taps..][..taps];
            w[(r * ni + c) * taps..][..taps].copy_from_slice(src);
        }
    }
    let weight = Tensor::<4>::from_data(TensorData::new(w, [no, ni, kh, kw]), device);
    // Every conv of the network has a bias (`CoreNet::new`).
    let mut bias = values(fresh.bias.as_ref().expect("a bias").val());
    bias[..o].copy_from_slice(&values(conv.bias.as_ref().expect("a bias").val()));
    let mut out = fresh.clone();
    out.weight = Param::from_tensor(weight);
    out.bias = Some(Param::from_tensor(Tensor::<1>::from_data(
        TensorData::new(bias, [no]),
        device,
    )));
    out
}

/// `net` grown into `fresh` (same inputs, stages and outputs; `fresh` at least as many features).
fn grow_net(net: &CoreNet, fresh: &CoreNet, device: &Device) -> CoreNet {
    let id = |n: usize| (0..n).collect::<Vec<_>>();
    let f_old = net.head.weight.dims()[0];
    let f_new = fresh.head.weight.dims()[0];
    let mut out = fresh.clone();
    out.input[0] = grow_conv(
        &net.input[0],
        &fresh.input[0],
        &id(net.input[0].weight.dims()[1]),
        device,
    );
    out.input[1] = grow_conv(&net.input[1], &fresh.input[1], &id(f_old), device);
    for (s, pair) in net.stages.chunks(2).enumerate() {
        // concat(features [f], max over views [f]): the second half moves to offset f_new.
        let cat: Vec<usize> = (0..f_old).chain(f_new..f_new + f_old).collect();
        out.stages[2 * s] = grow_conv(&pair[0], &fresh.stages[2 * s], &cat, device);
        out.stages[2 * s + 1] = grow_conv(&pair[1], &fresh.stages[2 * s + 1], &id(f_old), device);
    }
    out.head = grow_conv(&net.head, &fresh.head, &id(f_old), device);
    out.out = grow_conv(&net.out, &fresh.out, &id(f_old), device);
    out
}

/// Whether a model of configuration `from` can grow into `to`: the same inputs, state channels, max-pool
/// stages, prior and U-Net layout, and at least as many features per net and nets.
pub fn check_growth(from: &DeepViewConfig, to: &DeepViewConfig) -> Result<(), GrowError> {
    let refuse = |why: String| GrowError {
        from: from.name.clone(),
        to: to.name.clone(),
        why,
    };
    to.validate().map_err(|e| refuse(e.to_string()))?;
    if to.state_channels() != from.state_channels() {
        return Err(refuse(format!(
            "{} state channels, not {}",
            to.state_channels(),
            from.state_channels()
        )));
    }
    if to.max_pool_stages != from.max_pool_stages {
        return Err(refuse("a different number of max-pool stages".into()));
    }
    if to.init_prior != from.init_prior {
        return Err(refuse("a different agreement prior".into()));
    }
    if to.views.is_some() && to.views != from.views {
        return Err(refuse("a different fixed view count".into()));
    }
    if to.nets() < from.nets() {
        return Err(refuse(format!(
            "{} nets, fewer than {}",
            to.nets(),
            from.nets()
        )));
    }
    for n in 0..to.nets() {
        let src = n.min(from.nets() - 1);
        if to.features(n) < from.features(src) || to.unet(n) != from.unet(src) {
            return Err(refuse(format!(
                "net {n} would have {} features{} where net {src} has {}{}",
                to.features(n),
                if to.unet(n) { " (U-Net)" } else { "" },
                from.features(src),
                if from.unet(src) { " (U-Net)" } else { "" },
            )));
        }
    }
    Ok(())
}

/// `model` (configuration `from`) grown into configuration `to` ([module docs](self)); the new random
/// weights come from `device`'s seeded generator. Refused as [`check_growth`] refuses.
pub fn grow_model(
    model: &DeepViewModel,
    from: &DeepViewConfig,
    to: &DeepViewConfig,
    device: &Device,
) -> Result<DeepViewModel, GrowError> {
    check_growth(from, to)?;
    let fresh = DeepViewModel::new(to, device);
    let mut nets = Vec::with_capacity(to.nets());
    for n in 0..to.nets() {
        let src = n.min(from.nets() - 1);
        let grown = grow_net(&model.nets[src], &fresh.nets[n], device);
        nets.push(if n >= from.nets() {
            grown.zero_output()
        } else {
            grown
        });
    }
    Ok(DeepViewModel { nets, ..fresh })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::synthetic_inputs;

    fn trained_like(cfg: &DeepViewConfig, device: &Device) -> DeepViewModel {
        // A model whose output convs are not zero (as after training), so every net contributes.
        let random = DeepViewModel::new(
            &DeepViewConfig {
                init_prior: None,
                ..cfg.clone()
            },
            device,
        );
        DeepViewModel {
            nets: random.nets,
            ..DeepViewModel::new(cfg, device)
        }
    }

    #[test]
    fn grown_model_computes_the_same_mpi() {
        let dev = Device::flex();
        let from = DeepViewConfig::preset("cpu").unwrap();
        let to = DeepViewConfig::preset("cpu-large").unwrap();
        // Both models drawn under one seed with the generator held (other tests draw too).
        let (small, big) = crate::rng::seeded(&dev, 7, || {
            let small = trained_like(&from, &dev);
            crate::rng::materialize(&small);
            let big = grow_model(&small, &from, &to, &dev).unwrap();
            crate::rng::materialize(&big);
            (small, big)
        });
        assert_eq!(big.nets.len(), to.nets());
        assert_eq!(big.nets[2].head.weight.dims(), [12, 12, 3, 3]);
        for (k, d, h, w) in [(4, 5, 17, 21), (2, 3, 12, 9)] {
            let inputs = synthetic_inputs(k, d, h, w, &dev);
            let a = small.forward(&inputs).state;
            let b = big.forward(&inputs).state;
            let scale: f32 = a.clone().abs().max().into_scalar();
            let diff: f32 = (a - b).abs().max().into_scalar();
            assert!(scale > 0.1, "the test model's output is trivial");
            assert!(
                diff <= 1e-5 * scale,
                "{k} views: max difference {diff} (scale {scale})"
            );
        }
        // The new feature channels are live (random incoming weights), the copied net adds nothing yet.
        let w0 = values(big.nets[0].input[1].weight.val());
        let new_rows = &w0[8 * 12 * 9..];
        assert!(new_rows.iter().filter(|v| **v != 0.0).count() > new_rows.len() / 2);
        let out2: f32 = big.nets[2].out.weight.val().abs().sum().into_scalar();
        assert_eq!(out2, 0.0);
        let head1 = values(big.nets[1].head.weight.val());
        let head2 = values(big.nets[2].head.weight.val());
        let trained = 8 * 12 * 9;
        assert!(
            head1[..trained] == head2[..trained],
            "the new update net starts as a copy of the last one (its new feature rows are random)"
        );
    }

    #[test]
    fn growing_is_refused_where_it_cannot_preserve_the_model() {
        let dev = Device::flex();
        let from = DeepViewConfig::preset("cpu-large").unwrap();
        let small = crate::rng::module(|| DeepViewModel::new(&from, &dev));
        let to = DeepViewConfig::preset("cpu").unwrap();
        let e = grow_model(&small, &from, &to, &dev).unwrap_err();
        assert!(e.why.contains("fewer than"), "{e}");
        let to = DeepViewConfig {
            max_pool_stages: 2,
            ..from.clone()
        };
        assert!(grow_model(&small, &from, &to, &dev).is_err());
        let to = DeepViewConfig {
            features_large: 8,
            features_small: 8,
            ..from.clone()
        };
        let e = grow_model(&small, &from, &to, &dev).unwrap_err();
        assert!(e.why.contains("features"), "{e}");
    }
}
