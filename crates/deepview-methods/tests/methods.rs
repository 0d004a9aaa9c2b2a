//! Each classical method, as `infer --method M` runs it, on a textured fronto-parallel plane whose images
//! are known exactly.

mod common;

use common::*;
use deepview_geometry::{Camera, DVec3};
use deepview_image::ImageF32;
use deepview_methods::{
    Classical, MethodError, MethodKind, MethodOptions, MpiRequest, OptimizeOptions, Planes,
    PsvMeanOptions, agreement_mpi, classical_planes, make_method, optimize_mpi_with_history,
};
use deepview_mpi::render;

const W: u32 = 48;
const H: u32 = 32;
const F: f64 = 40.0;
const DEPTH: f64 = 2.0;

/// The target's image as `eval --method kind --planes planes` predicts it: the method's MPI rendered into it.
fn predict(
    kind: MethodKind,
    planes: usize,
    inputs: &[(ImageF32, Camera)],
    target: &Camera,
    near_far: (f64, f64),
) -> Result<ImageF32, MethodError> {
    let options = MethodOptions {
        planes: Planes::Count(planes),
        ..Default::default()
    };
    let mut method = make_method(kind, &options, 1 << 30)?;
    let request = MpiRequest {
        inputs,
        ids: &[],
        near_far,
        toward: Some(target),
    };
    let made = method.make_mpi(&request, &mut |_| {})?;
    Ok(render(&made.mpi, target).to_rgb())
}

fn quad_inputs(offset: f64) -> Vec<(ImageF32, Camera)> {
    [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
        .iter()
        .map(|&(x, y)| {
            let cam = camera_at(DVec3::new(x * offset, y * offset, 0.0), W, H, F);
            (render_plane(&cam, DEPTH), cam)
        })
        .collect()
}

/// [`quad_inputs`] of the plane textured `freq` times finer, the target camera the psv-mean tests render
/// into (off the reference, at fractional disparities) and its true image.
fn textured_quad(offset: f64, freq: f64) -> (Vec<(ImageF32, Camera)>, Camera, ImageF32) {
    let inputs = quad_inputs(offset)
        .into_iter()
        .map(|(_, c)| (render_plane_scaled(&c, DEPTH, freq), c))
        .collect();
    let target = camera_at(DVec3::new(0.03, -0.02, 0.0), W, H, F);
    let truth = render_plane_scaled(&target, DEPTH, freq);
    (inputs, target, truth)
}

#[test]
fn nearest_at_the_right_depth_reproduces_the_target() {
    // Target 0.1 right of the nearest input: disparity f t / d = 40 * 0.1 / 2 = 2 px exactly, so the single plane
    // at the plane's depth is an integer shift and bilinear sampling hits texel centres.
    let near_cam = camera_at(DVec3::ZERO, W, H, F);
    let far_cam = camera_at(DVec3::new(0.5, 0.0, 0.0), W, H, F);
    let inputs = vec![
        (render_plane(&far_cam, DEPTH), far_cam),
        (render_plane(&near_cam, DEPTH), near_cam),
    ];
    let target = camera_at(DVec3::new(0.1, 0.0, 0.0), W, H, F);
    let truth = render_plane(&target, DEPTH);
    let pred = predict(
        MethodKind::Nearest,
        1,
        &inputs,
        &target,
        bounds_around(DEPTH),
    )
    .unwrap();
    assert_eq!((pred.width, pred.height, pred.channels), (W, H, 3));
    let mut max_err = 0.0f32;
    for y in 0..H {
        for x in 0..W - 2 {
            for c in 0..3 {
                max_err = max_err.max((pred.pixel(x, y)[c] - truth.pixel(x, y)[c]).abs());
            }
        }
    }
    assert!(max_err < 1e-4, "max error {max_err}");
    // The last 2 columns see beyond the input image: black.
    assert!(pred.pixel(W - 1, 5).iter().all(|&v| v == 0.0));
    // At a wrong depth the same method is clearly worse.
    let wrong = predict(
        MethodKind::Nearest,
        1,
        &inputs,
        &target,
        bounds_around(DEPTH * 3.0),
    )
    .unwrap();
    assert!(psnr_interior(&wrong, &truth, 4) < psnr_interior(&pred, &truth, 4) - 10.0);
}

/// Share of the reference view's visible weight on plane `true_plane` (interior pixels).
fn weight_on_plane(mpi: &deepview_mpi::Mpi, true_plane: usize, border: u32) -> f64 {
    let (rw, rh) = (mpi.camera.width, mpi.camera.height);
    let (mut on, mut total) = (0.0f64, 0.0f64);
    for y in border..rh - border {
        for x in border..rw - border {
            let p = (y * rw + x) as usize;
            let mut front = 1.0f64;
            for d in (0..mpi.planes()).rev() {
                let a = mpi.plane(d)[p * 4 + 3] as f64;
                if d == true_plane {
                    on += a * front;
                }
                total += a * front;
                front *= 1.0 - a;
            }
        }
    }
    on / total
}

/// Cost aggregation (`--aggregate`): with noisy inputs the per-pixel variance often prefers a wrong
/// plane; averaged over a window it finds the textured plane again, and the target renders closer to the
/// truth.
#[test]
fn psv_mean_aggregation_finds_the_plane_through_noise() {
    let freq = 3.0;
    // Fixed noise (an LCG), uniform in +-0.1 per channel.
    let mut state = 12345u32;
    let inputs: Vec<(ImageF32, Camera)> = quad_inputs(0.1)
        .into_iter()
        .map(|(_, c)| {
            let mut img = render_plane_scaled(&c, DEPTH, freq);
            for v in img.data.iter_mut() {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                *v += 0.2 * ((state >> 8) as f32 / (1u32 << 24) as f32 - 0.5);
            }
            (img, c)
        })
        .collect();
    let target = camera_at(DVec3::new(0.03, -0.02, 0.0), W, H, F);
    let truth = render_plane_scaled(&target, DEPTH, freq);
    let nf = (1.0 / 0.9, 1.0 / 0.1);
    let share = |radius: usize| {
        let options = PsvMeanOptions {
            planes: 9,
            aggregation: deepview_mpi::agreement::Aggregation::window(radius, 1.0),
            ..Default::default()
        };
        let mpi = agreement_mpi(&inputs, nf, &options).unwrap();
        let pred = render(&mpi, &target).to_rgb();
        (weight_on_plane(&mpi, 4, 6), psnr_interior(&pred, &truth, 6))
    };
    let (per_pixel, p0) = share(0);
    let (aggregated, p3) = share(3);
    eprintln!(
        "weight on the true plane: {per_pixel:.3} per pixel, {aggregated:.3} over 7x7 ({p0:.2} / {p3:.2} dB)"
    );
    // Measured: 0.712 per pixel, 0.962 over 7x7; 27.09 -> 29.83 dB.
    assert!(
        per_pixel < 0.8,
        "the noise should mislead the per-pixel cost: {per_pixel}"
    );
    assert!(
        aggregated > 0.9 && aggregated > per_pixel + 0.15,
        "aggregated weight on the true plane {aggregated} (per pixel {per_pixel})"
    );
    assert!(
        p3 > p0 + 1.5,
        "aggregation should render closer to the truth: {p0} -> {p3} dB"
    );
}

/// The learned method runs its prior at the radius of the images' size: an untrained prior model (its
/// output convolutions zero, so its MPI is the prior's) saved with `prior_radius` 2 over a
/// `prior_radius_size` of 16 gives, on 48-px images, `psv-mean --aggregate 6`'s MPI (the prior's one
/// definition) and not `--aggregate 2`'s.
#[test]
fn learned_prior_radius_grows_with_the_image_size() {
    use deepview_net::config::DeepViewConfig;
    use deepview_net::network::DeepViewModel;
    use deepview_net::weights::save_model;
    let (inputs, _, _) = textured_quad(0.1, 3.0);
    let nf = (1.0 / 0.9, 1.0 / 0.1);
    let cfg = DeepViewConfig {
        prior_radius: 2,
        prior_weight: 0.5,
        prior_radius_size: Some(16),
        ..DeepViewConfig::preset("cpu").unwrap()
    };
    assert_eq!(cfg.prior_radius_at(W.max(H)), 6);
    let dir = tempfile::tempdir().unwrap();
    let model = DeepViewModel::new(&cfg, &deepview_net::burn::tensor::Device::flex());
    save_model(dir.path(), &model, &cfg).unwrap();
    let make_at = |kind: MethodKind, aggregate: usize, mpi_scale: f64| {
        let options = MethodOptions {
            planes: Planes::Count(9),
            weights: Some(dir.path().to_path_buf()),
            aggregate,
            // (psv-mean's own option: the learned method refuses it.)
            aggregate_weight: if kind == MethodKind::PsvMean {
                0.5
            } else {
                1.0
            },
            mpi_scale: Some(mpi_scale),
            ..Default::default()
        };
        let mut method = make_method(kind, &options, 1 << 30).unwrap();
        let request = MpiRequest {
            inputs: &inputs,
            ids: &[],
            near_far: nf,
            toward: None,
        };
        method.make_mpi(&request, &mut |_| {}).unwrap()
    };
    let make = |kind: MethodKind, aggregate: usize| make_at(kind, aggregate, 1.0);
    let made = make(MethodKind::Deepview, 0);
    assert_eq!(
        made.note.as_deref(),
        Some("prior window radius 6, grown from 2 for 48-px images")
    );
    let learned = made.mpi;
    let diff = |a: &deepview_mpi::Mpi, b: &deepview_mpi::Mpi| {
        assert_eq!(a.layers.len(), b.layers.len());
        a.layers
            .iter()
            .zip(&b.layers)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max)
    };
    let at6 = diff(&learned, &make(MethodKind::PsvMean, 6).mpi);
    let at2 = diff(&learned, &make(MethodKind::PsvMean, 2).mpi);
    eprintln!("learned vs psv-mean: {at6:e} at radius 6, {at2:e} at radius 2");
    assert!(at6 < 3e-4, "the prior at radius 6: {at6}");
    assert!(at2 > 1e-2, "radius 2 should differ clearly: {at2}");
    // On a grid 1.5 times finer (--mpi-scale 1.5) the window grows with it, to radius 9 (72 MPI pixels
    // across): the learned model's prior is psv-mean's at radius 9 on the same grid.
    let fine = make_at(MethodKind::Deepview, 0, 1.5);
    assert_eq!(
        fine.note.as_deref(),
        Some("prior window radius 9, grown from 2 for 48-px images at MPI scale 1.5")
    );
    let base = &learned.camera;
    assert_eq!(
        (fine.mpi.camera.width, fine.mpi.camera.height),
        (
            (base.width as f64 * 1.5).round() as u32,
            (base.height as f64 * 1.5).round() as u32
        )
    );
    let at9 = diff(&fine.mpi, &make_at(MethodKind::PsvMean, 9, 1.5).mpi);
    let at6_fine = diff(&fine.mpi, &make_at(MethodKind::PsvMean, 6, 1.5).mpi);
    eprintln!("at MPI scale 1.5: {at9:e} at radius 9, {at6_fine:e} at radius 6");
    assert!(at9 < 3e-4, "the prior at radius 9: {at9}");
    assert!(
        at6_fine > 1e-2,
        "radius 6 should differ clearly: {at6_fine}"
    );
}

/// Weights that name their own inference grid (`infer_mpi_scale`) get it without `--mpi-scale`, and
/// the option overrides it; the model's MPI on that grid is the one `--mpi-scale` asks for, bit for bit;
/// a scale outside 1..=4 in the weights is refused when they load.
#[test]
fn weights_choose_their_mpi_grid_unless_told() {
    use deepview_net::config::DeepViewConfig;
    use deepview_net::network::DeepViewModel;
    use deepview_net::weights::save_model;
    let (inputs, _, _) = textured_quad(0.1, 3.0);
    let nf = (1.0 / 0.9, 1.0 / 0.1);
    let save = |scale: Option<f64>| {
        let cfg = DeepViewConfig {
            infer_mpi_scale: scale,
            ..DeepViewConfig::preset("cpu").unwrap()
        };
        let dir = tempfile::tempdir().unwrap();
        let model = DeepViewModel::new(&cfg, &deepview_net::burn::tensor::Device::flex());
        save_model(dir.path(), &model, &cfg).unwrap();
        dir
    };
    let make = |dir: &std::path::Path, mpi_scale: Option<f64>| {
        let options = MethodOptions {
            planes: Planes::Count(6),
            weights: Some(dir.to_path_buf()),
            mpi_scale,
            ..Default::default()
        };
        let mut method = make_method(MethodKind::Deepview, &options, 1 << 30)?;
        let request = MpiRequest {
            inputs: &inputs,
            ids: &[],
            near_far: nf,
            toward: None,
        };
        Ok::<_, MethodError>(method.make_mpi(&request, &mut |_| {})?.mpi)
    };
    let plain = save(None);
    let fine = save(Some(1.5));
    let base = make(plain.path(), None).unwrap();
    let own = make(fine.path(), None).unwrap();
    let asked = make(plain.path(), Some(1.5)).unwrap();
    let (bw, bh) = (base.camera.width, base.camera.height);
    assert_eq!(
        (own.camera.width, own.camera.height),
        (
            (bw as f64 * 1.5).ceil() as u32,
            (bh as f64 * 1.5).ceil() as u32
        )
    );
    assert_eq!(own.camera, asked.camera);
    assert!(
        own.layers == asked.layers,
        "the weights' grid is --mpi-scale's"
    );
    // The option overrides the weights' own grid.
    let told = make(fine.path(), Some(1.0)).unwrap();
    assert_eq!((told.camera.width, told.camera.height), (bw, bh));
    assert!(told.layers == base.layers);
    // A damaged scale is refused by name.
    let bad = save(Some(1.5));
    let path = bad.path().join("config.json");
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, text.replace("1.5", "0.5")).unwrap();
    let err = make(bad.path(), None).unwrap_err().to_string();
    assert!(err.contains("inference MPI scale 0.5"), "{err}");
}

#[test]
fn a_finer_mpi_grid_renders_the_target_sharper() {
    // A texture 3x finer than the other tests' and inputs 1.45 px of disparity from the reference at the
    // plane's depth: at the inputs' own pitch, bilinear sampling (inputs into the planes, planes into the
    // target) blurs it at every fractional offset; on a grid twice as fine much less.
    let (inputs, target, truth) = textured_quad(0.0725, 3.0);
    let nf = (1.0 / 0.9, 1.0 / 0.1);
    let psnr_at = |mpi_scale: f64| {
        let options = MethodOptions {
            planes: Planes::Count(9),
            mpi_scale: Some(mpi_scale),
            ..Default::default()
        };
        let mut method = make_method(MethodKind::PsvMean, &options, 1 << 30).unwrap();
        let request = MpiRequest {
            inputs: &inputs,
            ids: &[],
            near_far: nf,
            toward: Some(&target),
        };
        let mpi = method.make_mpi(&request, &mut |_| {}).unwrap().mpi;
        let pred = render(&mpi, &target).to_rgb();
        (psnr_interior(&pred, &truth, 6), mpi.camera)
    };
    let (p1, c1) = psnr_at(1.0);
    let (p2, c2) = psnr_at(2.0);
    eprintln!("psv-mean PSNR {p1:.2} dB at MPI scale 1, {p2:.2} dB at 2");
    assert_eq!((c2.width, c2.height), (2 * c1.width, 2 * c1.height));
    assert!(p2 > p1 + 1.0, "scale 2: {p2} dB, scale 1: {p1} dB");
    // The methods that make their MPI in another camera refuse it.
    for kind in [MethodKind::Nearest, MethodKind::Optimize] {
        let options = MethodOptions {
            mpi_scale: Some(1.5),
            ..Default::default()
        };
        let err = make_method(kind, &options, 1 << 30).err().expect("refused");
        assert!(err.to_string().contains("--mpi-scale"), "{err}");
    }
}

#[test]
fn psv_mean_finds_the_plane_and_renders_the_target() {
    // A texture 3x finer than the other tests', so colours disagree clearly one plane off.
    let (inputs, target, truth) = textured_quad(0.1, 3.0);
    // 9 planes, the middle one on the textured plane; inverse depths 0.1 .. 0.9 in steps of 0.1, i.e. 0.8 px of
    // disparity per plane step across the 0.2 baseline.
    let options = PsvMeanOptions {
        planes: 9,
        ..Default::default()
    };
    let nf = (1.0 / 0.9, 1.0 / 0.1);
    let mpi = agreement_mpi(&inputs, nf, &options).unwrap();
    assert!((mpi.depths[4] - DEPTH).abs() < 1e-9);
    // In the reference view, the visible contribution of each plane; the true plane should dominate.
    let (rw, rh) = (mpi.camera.width, mpi.camera.height);
    let (mut on_plane, mut total, mut argmax_right, mut pixels) = (0.0f64, 0.0f64, 0, 0);
    for y in 6..rh - 6 {
        for x in 6..rw - 6 {
            let p = (y * rw + x) as usize;
            let mut front = 1.0f64;
            let mut best = (0, 0.0);
            for d in (0..9).rev() {
                let a = mpi.plane(d)[p * 4 + 3] as f64;
                let w = a * front;
                if d == 4 {
                    on_plane += w;
                }
                if w > best.1 {
                    best = (d, w);
                }
                total += w;
                front *= 1.0 - a;
            }
            argmax_right += (best.0 == 4) as usize;
            pixels += 1;
        }
    }
    assert!(
        on_plane / total > 0.5,
        "weight on the true plane {}",
        on_plane / total
    );
    assert!(
        argmax_right as f64 > 0.9 * pixels as f64,
        "true plane strongest at {argmax_right} of {pixels} pixels"
    );
    let pred = predict(MethodKind::PsvMean, options.planes, &inputs, &target, nf).unwrap();
    let p = psnr_interior(&pred, &truth, 6);
    assert!(p > 25.0, "psv-mean PSNR {p}");
    // `psv-mean` renders agreement_mpi.
    assert_eq!(render(&mpi, &target).to_rgb(), pred);
    eprintln!(
        "psv-mean: weight on the true plane {:.3}, PSNR {p:.2}",
        on_plane / total
    );
}

#[test]
fn optimize_reduces_the_input_view_loss_and_generalises() {
    let inputs = quad_inputs(0.1);
    let target = camera_at(DVec3::new(0.03, -0.02, 0.0), W, H, F);
    let truth = render_plane(&target, DEPTH);
    let options = OptimizeOptions {
        planes: 9,
        steps: 150,
        learning_rate: 0.1,
        max_width: 160,
    };
    let (mpi, history) =
        optimize_mpi_with_history(&inputs, bounds_around(DEPTH), &options).unwrap();
    assert_eq!(history.len(), 151);
    let (first, last) = (history[0], *history.last().unwrap());
    assert!(last < 0.25 * first, "loss {first} -> {last}");
    let p = psnr_interior(&render(&mpi, &target).to_rgb(), &truth, 6);
    assert!(p > 25.0, "optimize PSNR on a held-out view {p}");
}

#[test]
fn optimize_works_at_reduced_resolution() {
    let inputs = quad_inputs(0.1);
    let options = OptimizeOptions {
        planes: 5,
        steps: 20,
        learning_rate: 0.1,
        max_width: 24,
    };
    let (mpi, history) =
        optimize_mpi_with_history(&inputs, bounds_around(DEPTH), &options).unwrap();
    assert!(
        mpi.camera.width <= 32,
        "MPI at the working resolution, got {}",
        mpi.camera.width
    );
    assert!(history.last().unwrap() < &history[0]);
}

#[test]
fn bad_inputs_are_clear_errors() {
    let target = camera_at(DVec3::ZERO, W, H, F);
    let e = predict(MethodKind::Nearest, 1, &[], &target, (1.0, 2.0)).unwrap_err();
    assert!(
        matches!(e, MethodError::Method { .. }) && e.to_string().contains("no input views"),
        "{e}"
    );
    let inputs = quad_inputs(0.1);
    let e = predict(MethodKind::PsvMean, 32, &inputs, &target, (2.0, 1.0))
        .unwrap_err()
        .to_string();
    assert!(e.contains("near 2") && e.contains("far 1"), "{e}");
    let mut wrong_size = inputs.clone();
    wrong_size[0].0 = ImageF32::new(5, 5, 3);
    let e = predict(MethodKind::Nearest, 1, &wrong_size, &target, (1.0, 2.0))
        .unwrap_err()
        .to_string();
    assert!(e.contains("input 0") && e.contains("5x5"), "{e}");
}

#[test]
fn a_finer_grid_keeps_the_plane_rule_within_the_budget() {
    // `auto` follows the inputs' disparities, not the grid: the same count at scale 1 and 1.5 with ample
    // memory. The memory estimate grows with the grid: the least budget that holds scale 1's count holds
    // fewer planes at scale 1.5 (2.25 times the pixels).
    let cams: Vec<Camera> = quad_inputs(0.1).into_iter().map(|(_, c)| c).collect();
    let nf = (0.2, 100.0);
    let count = |scale: f64, budget: u64| {
        let method = Classical {
            kind: MethodKind::PsvMean,
            psv: PsvMeanOptions {
                scale,
                ..Default::default()
            },
            optimize: OptimizeOptions::default(),
            planes: Planes::Auto,
            budget,
        };
        classical_planes(&method, &cams, &[], nf).map_or(0, |c| c.count)
    };
    let full = count(1.0, 1 << 40);
    assert!(full > 20, "auto planes {full}");
    assert_eq!(count(1.5, 1 << 40), full);
    let (mut lo, mut hi) = (0u64, 1u64 << 40);
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if count(1.0, mid) == full {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let fine = count(1.5, hi);
    eprintln!("auto: {full} planes at scale 1 within {hi} bytes, {fine} at scale 1.5");
    assert!(
        (8..full).contains(&fine),
        "scale 1.5 within scale 1's budget: {fine} of {full} planes"
    );
}

/// An option of one method given to another is refused, naming it and the method it belongs to (the
/// learned method made a byte-identical MPI whatever `--smoothing` said, psv-mean ignored `--steps`,
/// nearest gave its one plane for `--planes 20`); the defaults pass for every method.
#[test]
fn options_of_another_method_are_refused() {
    let refused = |kind: MethodKind, options: MethodOptions| -> String {
        match make_method(kind, &options, 1 << 30) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("{kind} accepted {options:?}"),
        }
    };
    let smoothing = MethodOptions {
        smoothing: Some(deepview_mpi::agreement::Smoothing {
            p1: 50.0,
            p2: 500.0,
        }),
        temperature: 0.5,
        ..Default::default()
    };
    for kind in [MethodKind::Nearest, MethodKind::Optimize] {
        let e = refused(kind, smoothing.clone());
        assert!(
            e.contains("--temperature, --smoothing shape psv-mean's agreement only"),
            "{e}"
        );
    }
    let steps = MethodOptions {
        steps: 20,
        ..Default::default()
    };
    for kind in [
        MethodKind::PsvMean,
        MethodKind::Nearest,
        MethodKind::Deepview,
    ] {
        let e = refused(kind, steps.clone());
        assert!(
            e.contains("--steps shapes optimize's gradient descent only"),
            "{e}"
        );
    }
    let planes = MethodOptions {
        planes: Planes::Count(20),
        ..Default::default()
    };
    assert!(refused(MethodKind::Nearest, planes).contains("--planes does not apply"));
    // Where the caller says which options the command line gave, one given at its default value is
    // refused too (`--aggregate 0` to deepview had passed, as if left out); unnamed ones still pass.
    let named = MethodOptions {
        given: Some(vec!["aggregate_weight".into(), "lr".into()]),
        ..Default::default()
    };
    let e = refused(MethodKind::Deepview, named.clone());
    assert!(
        e.contains("--aggregate-weight shapes psv-mean's agreement only"),
        "{e}"
    );
    assert!(refused(MethodKind::PsvMean, named).contains("--lr shapes optimize's"));
    let scale = MethodOptions {
        mpi_scale: Some(1.0),
        given: Some(vec!["mpi_scale".into()]),
        ..Default::default()
    };
    assert!(refused(MethodKind::Nearest, scale.clone()).contains("--mpi-scale 1 applies to"));
    assert!(make_method(MethodKind::PsvMean, &scale, 1 << 30).is_ok());
    let named = MethodOptions {
        given: Some(vec!["planes".into(), "device".into()]),
        ..Default::default()
    };
    assert!(make_method(MethodKind::PsvMean, &named, 1 << 30).is_ok());
    for kind in [
        MethodKind::Nearest,
        MethodKind::PsvMean,
        MethodKind::Optimize,
    ] {
        assert!(
            make_method(kind, &MethodOptions::default(), 1 << 30).is_ok(),
            "{kind}"
        );
    }
    assert!(make_method(MethodKind::PsvMean, &smoothing, 1 << 30).is_ok());
    // Every spelling of the CPU device passes.
    for device in ["cpu:0", "cpu:local", "flex"] {
        let o = MethodOptions {
            device: device.into(),
            ..Default::default()
        };
        assert!(
            make_method(MethodKind::PsvMean, &o, 1 << 30).is_ok(),
            "{device}"
        );
    }
    assert!(make_method(MethodKind::Optimize, &steps, 1 << 30).is_ok());
}
