//! Tests of the forward model against scalar references, finite differences and the CPU crate.

use super::*;
use burn::tensor::{Device, Distribution, Tensor, TensorData};

fn dev() -> Device {
    Device::flex()
}

fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap()
}

/// Independent scalar warp (f64 arithmetic) for one plane, `[C][H][W]` layout.
fn scalar_warp(
    src: &[f32],
    c: usize,
    sh: usize,
    sw: usize,
    h: &Hom,
    oh: usize,
    ow: usize,
) -> Vec<f32> {
    let mut out = vec![0f32; c * oh * ow];
    for y in 0..oh {
        for x in 0..ow {
            let (u, v) = (x as f64 + 0.5, y as f64 + 0.5);
            let z = h[6] * u + h[7] * v + h[8];
            if z <= 0.0 {
                continue;
            }
            let sx = (h[0] * u + h[1] * v + h[2]) / z;
            let sy = (h[3] * u + h[4] * v + h[5]) / z;
            if !(0.0..=sw as f64).contains(&sx) || !(0.0..=sh as f64).contains(&sy) {
                continue;
            }
            let get = |ch: usize, xi: i64, yi: i64| {
                let xi = xi.clamp(0, sw as i64 - 1) as usize;
                let yi = yi.clamp(0, sh as i64 - 1) as usize;
                src[(ch * sh + yi) * sw + xi] as f64
            };
            let (fx, fy) = (sx - 0.5, sy - 0.5);
            let (x0, y0) = (fx.floor(), fy.floor());
            let (tx, ty) = (fx - x0, fy - y0);
            let (x0, y0) = (x0 as i64, y0 as i64);
            for ch in 0..c {
                let val = (1.0 - tx) * (1.0 - ty) * get(ch, x0, y0)
                    + tx * (1.0 - ty) * get(ch, x0 + 1, y0)
                    + (1.0 - tx) * ty * get(ch, x0, y0 + 1)
                    + tx * ty * get(ch, x0 + 1, y0 + 1);
                out[(ch * oh + y) * ow + x] = val as f32;
            }
        }
    }
    out
}

fn some_homs(d: usize) -> Vec<Hom> {
    (0..d)
        .map(|i| {
            let s = i as f64;
            [
                1.05 + 0.02 * s,
                0.03,
                -1.7 + s,
                -0.02,
                0.97,
                0.8 - 0.5 * s,
                0.0005,
                -0.0003,
                1.0,
            ]
        })
        .collect()
}

#[test]
fn identity_warp_is_exact() {
    let x = crate::rng::random::<4, _>([3, 4, 9, 13], Distribution::Uniform(0.0, 1.0), &dev());
    let id = [[1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]; 3];
    let y = warp_planes(x.clone(), &id, 9, 13);
    assert_eq!(to_vec(x), to_vec(y));
}

#[test]
fn warp_matches_scalar_reference() {
    let (d, c, sh, sw, oh, ow) = (3, 2, 17, 23, 15, 26);
    let x = crate::rng::random::<4, _>([d, c, sh, sw], Distribution::Uniform(0.0, 1.0), &dev());
    let homs = some_homs(d);
    let homs32: Vec<[f32; 9]> = homs.iter().map(|h| h.map(|v| v as f32)).collect();
    let y = to_vec(warp_planes(x.clone(), &homs32, oh, ow));
    let xs = to_vec(x.clone());
    let mut n_valid = 0;
    for p in 0..d {
        let h64 = homs32[p].map(|v| v as f64);
        let src = &xs[p * c * sh * sw..(p + 1) * c * sh * sw];
        let expect = scalar_warp(src, c, sh, sw, &h64, oh, ow);
        let got = &y[p * c * oh * ow..(p + 1) * c * oh * ow];
        for (e, g) in expect.iter().zip(got) {
            assert!((e - g).abs() < 2e-5, "plane {p}: {e} vs {g}");
            n_valid += (*e != 0.0) as usize;
        }
    }
    assert!(
        n_valid > d * c * oh * ow / 2,
        "test should sample mostly inside"
    );
    // grid_sample variant agrees.
    let g = to_vec(warp_planes_grid_sample(x, &homs32, oh, ow));
    for (a, b) in y.iter().zip(&g) {
        assert!((a - b).abs() < 1e-4, "{a} vs {b}");
    }
}

#[test]
fn broadcast_source_equals_repeated_source() {
    let img = crate::rng::random::<4, _>([1, 3, 10, 12], Distribution::Uniform(0.0, 1.0), &dev());
    let homs = some_homs(4);
    let t = WarpTable::new(&homs, 12, 10, 11, 9);
    let a = to_vec(t.apply(img.clone()));
    let b = to_vec(t.apply(img.repeat_dim(0, 4)));
    assert_eq!(a, b);
}

fn random_rgba(d: usize, h: usize, w: usize, device: &Device) -> Tensor<4> {
    let alpha = crate::rng::random::<4, _>([d, 1, h, w], Distribution::Uniform(0.05, 0.95), device);
    let col = crate::rng::random::<4, _>([d, 3, h, w], Distribution::Uniform(0.0, 1.0), device);
    Tensor::cat(vec![col * alpha.clone(), alpha], 1)
}

/// The CPU crate's MPI of `rgba` `[D, 4, H, W]`: layers `[D][H][W][4]`.
fn mpi_from_tensor(
    rgba: Tensor<4>,
    camera: deepview_geometry::Camera,
    depths: &[f64],
) -> deepview_mpi::Mpi {
    let [d, c, h, w] = rgba.dims();
    assert_eq!((c, d), (4, depths.len()));
    let vals = to_vec(rgba);
    let mut layers = vec![0f32; vals.len()];
    for p in 0..d {
        for c in 0..4 {
            for i in 0..h * w {
                layers[(p * h * w + i) * 4 + c] = vals[(p * 4 + c) * h * w + i];
            }
        }
    }
    deepview_mpi::Mpi {
        camera,
        depths: depths.to_vec(),
        layers,
    }
}

/// Planar `[C, H, W]` -> interleaved image.
fn image_from_tensor(t: Tensor<3>) -> deepview_image::ImageF32 {
    let [c, h, w] = t.dims();
    image_from_planar(&to_vec(t), c, h, w)
}

/// Planar `[C][H][W]` values -> interleaved image.
fn image_from_planar(v: &[f32], c: usize, h: usize, w: usize) -> deepview_image::ImageF32 {
    let px = h * w;
    let mut data = vec![0f32; c * px];
    for ch in 0..c {
        for i in 0..px {
            data[i * c + ch] = v[ch * px + i];
        }
    }
    deepview_image::ImageF32 {
        width: w as u32,
        height: h as u32,
        channels: c,
        data,
    }
}

#[test]
fn composite_matches_scalar_over_and_autodiff_identities() {
    let device = dev().autodiff();
    let (d, h, w) = (5, 3, 4);
    let rgba = random_rgba(d, h, w, &dev());
    let rgba = Tensor::<4>::from_data(rgba.into_data(), &device).require_grad();
    let comp = composite(rgba.clone());
    let vals = to_vec(rgba.clone());
    let px = h * w;
    // Scalar over, back to front.
    let render = to_vec(comp.render.clone());
    for c in 0..3 {
        for p in 0..px {
            let mut acc = 0.0f32;
            for pl in 0..d {
                let a = vals[(pl * 4 + 3) * px + p];
                acc = acc * (1.0 - a) + vals[(pl * 4 + c) * px + p];
            }
            assert!((acc - render[c * px + p]).abs() < 1e-5);
        }
    }
    // Gradient of sum(render * weights) w.r.t. c_d and a_d.
    let wts = crate::rng::random::<3, _>([3, h, w], Distribution::Uniform(0.5, 1.5), &device);
    let loss = (comp.render.clone() * wts.clone()).sum();
    let grads = loss.backward();
    let g = to_vec(rgba.grad(&grads).unwrap());
    let t = to_vec(comp.transmittance.clone());
    let acc = to_vec(comp.accumulated.clone());
    let wv = to_vec(wts);
    for pl in 0..d {
        for p in 0..px {
            let tt = t[pl * px + p];
            let mut da = 0.0;
            for c in 0..3 {
                let dc = g[(pl * 4 + c) * px + p];
                assert!((dc - wv[c * px + p] * tt).abs() < 1e-5, "dR/dc = T");
                da += -acc[(pl * 3 + c) * px + p] * tt * wv[c * px + p];
            }
            assert!((g[(pl * 4 + 3) * px + p] - da).abs() < 1e-5, "dR/da = -A T");
        }
    }
    // Front plane has T = 1, back plane has A = 0.
    assert!(t[(d - 1) * px..].iter().all(|&v| v == 1.0));
    assert!(acc[..3 * px].iter().all(|&v| v == 0.0));
}

#[test]
fn warp_gradient_matches_finite_differences() {
    let device = dev().autodiff();
    let x = crate::rng::random::<4, _>([2, 1, 6, 7], Distribution::Uniform(0.0, 1.0), &dev());
    let xs = to_vec(x.clone());
    let homs = some_homs(2);
    let t = WarpTable::new(&homs, 7, 6, 6, 5);
    let xa = Tensor::<4>::from_data(x.into_data(), &device).require_grad();
    let y = t.apply(xa.clone());
    let wts = crate::rng::random::<4, _>(y.dims(), Distribution::Uniform(0.0, 1.0), &device);
    let grads = (y * wts.clone()).sum().backward();
    let g = to_vec(xa.grad(&grads).unwrap());
    // The warp is linear: the gradient w.r.t. texel i is the output for a unit impulse at i.
    for i in [0, 5, 13, 40, 60, 83] {
        let mut e = vec![0f32; xs.len()];
        e[i] = 1.0;
        let imp = Tensor::<4>::from_data(TensorData::new(e, [2, 1, 6, 7]), &dev());
        let yi = (t.apply(imp) * Tensor::<4>::from_data(wts.clone().into_data(), &dev())).sum();
        let expect: f32 = yi.into_scalar();
        assert!(
            (expect - g[i]).abs() < 1e-5,
            "texel {i}: {expect} vs {}",
            g[i]
        );
    }
}

#[test]
fn matches_the_cpu_renderer_and_plane_sweep() {
    use deepview_geometry::{
        Camera, DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths, plane_homography,
    };
    let reference = Camera::new(30, 24, Intrinsics::centred(28.0, 30, 24), Pose::IDENTITY);
    let target = Camera::new(
        27,
        22,
        Intrinsics::new(26.0, 27.0, 13.1, 11.4),
        Pose::from_center(DMat3::from_rotation_y(0.03), DVec3::new(0.12, -0.05, 0.02)),
    );
    let depths = plane_depths(1.0, 8.0, 5, PlaneSpacing::InverseDepth).unwrap();
    let (d, h, w) = (5, 24, 30);
    let rgba = random_rgba(d, h, w, &dev());
    let mpi = mpi_from_tensor(rgba.clone(), reference, &depths);
    let cpu = deepview_mpi::render_components(&mpi, &target);
    let homs = deepview_mpi::target_to_plane_homographies(&reference, &target, &depths);
    let comp = render_view(rgba, &homs, 22, 27);
    let px = 22 * 27;
    let (r, t, a) = (
        to_vec(comp.render),
        to_vec(comp.transmittance),
        to_vec(comp.accumulated),
    );
    for i in 0..px {
        for c in 0..3 {
            assert!((r[c * px + i] - cpu.render.data[i * 4 + c]).abs() < 1e-5);
            for p in 0..d {
                assert!(
                    (a[(p * 3 + c) * px + i] - cpu.accumulated_over[(p * px + i) * 3 + c]).abs()
                        < 1e-5
                );
            }
        }
        for p in 0..d {
            assert!((t[p * px + i] - cpu.transmittance[p * px + i]).abs() < 1e-5);
        }
    }
    // Plane sweep of a target image onto the reference planes.
    let img = crate::rng::random::<3, _>([3, 22, 27], Distribution::Uniform(0.0, 1.0), &dev());
    let image = image_from_tensor(img.clone());
    let cpu_psv = deepview_mpi::plane_sweep(&image, &target, &reference, &depths);
    let m2v: Vec<Hom> = depths
        .iter()
        .map(|&z| plane_homography(&reference, &target, z).to_row_major())
        .collect();
    let psv = to_vec(plane_sweep_volume(img, &m2v, h, w));
    for p in 0..d {
        for c in 0..4 {
            for i in 0..h * w {
                assert!(
                    (psv[(p * 4 + c) * h * w + i] - cpu_psv.data[(p * h * w + i) * 4 + c]).abs()
                        < 1e-5
                );
            }
        }
    }
}

/// `gradient_components` (the per-view gradient components `[I_k, R_k, A_k, T_k, validity]` in MPI
/// space) against the CPU crate, for two views with general poses (rotation about all three axes plus
/// translation, other intrinsics and image sizes than the MPI): `R_k` is `deepview_mpi::render` into
/// view k, `A_k`/`T_k` come from `deepview_mpi::render_components` (plane d of each, an image in view
/// k), and every one of them is inverse-warped onto the planes with `deepview_mpi::plane_sweep` (`I_k`
/// and `R_k` onto every plane; `A_k`, `T_k` of plane d onto plane d only). Also a sub-region of the
/// MPI, which must equal the same window of the full result.
///
/// Tolerance 1e-4, though the two agree bit for bit here: both use the same f32 sampling rule and the
/// same operation order, but the burn side inverts the MPI->view homographies itself (`invert`) where
/// the CPU renderer inverts its own `Homography`, so in general f32 taps may differ in the last bits.
#[test]
fn gradient_components_match_the_cpu_crate() {
    use deepview_geometry::{
        Camera, DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths, plane_homography,
    };
    let (d, h, w) = (4, 24, 30);
    let reference = Camera::new(
        w as u32,
        h as u32,
        Intrinsics::centred(28.0, 30, 24),
        Pose::IDENTITY,
    );
    let views = [
        Camera::new(
            27,
            22,
            Intrinsics::new(26.0, 27.0, 13.1, 11.4),
            Pose::from_center(
                DMat3::from_rotation_y(0.04)
                    * DMat3::from_rotation_x(-0.03)
                    * DMat3::from_rotation_z(0.05),
                DVec3::new(0.15, -0.08, 0.05),
            ),
        ),
        Camera::new(
            25,
            20,
            Intrinsics::new(23.0, 22.5, 12.7, 9.6),
            Pose::from_center(
                DMat3::from_rotation_x(0.035)
                    * DMat3::from_rotation_z(-0.04)
                    * DMat3::from_rotation_y(-0.03),
                DVec3::new(-0.12, 0.07, -0.06),
            ),
        ),
    ];
    let depths = plane_depths(1.0, 8.0, d, PlaneSpacing::InverseDepth).unwrap();
    let rgba = random_rgba(d, h, w, &dev());
    let mpi = mpi_from_tensor(rgba.clone(), reference, &depths);
    let (mpx, region) = (h * w, (3usize, 2usize, 20usize, 17usize));
    let names = ["I", "I", "I", "R", "R", "R", "A", "A", "A", "T", "valid"];
    let mut worst = [0f32; GRADIENT_CHANNELS];
    for view in &views {
        let (vw, vh) = (view.width as usize, view.height as usize);
        let vpx = vw * vh;
        let img = crate::rng::random::<3, _>([3, vh, vw], Distribution::Uniform(0.0, 1.0), &dev());
        // CPU: R_k, A_k, T_k in view k, then the inverse warps.
        let image = image_from_tensor(img.clone());
        let render = deepview_mpi::render(&mpi, view);
        let r_img = deepview_image::ImageF32 {
            width: view.width,
            height: view.height,
            channels: 3,
            data: render
                .data
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect(),
        };
        let comps = deepview_mpi::render_components(&mpi, view);
        let psv_i = deepview_mpi::plane_sweep(&image, view, &reference, &depths);
        let psv_r = deepview_mpi::plane_sweep(&r_img, view, &reference, &depths);
        let mut expect = vec![0f32; d * GRADIENT_CHANNELS * mpx];
        for p in 0..d {
            let a_img = deepview_image::ImageF32 {
                width: view.width,
                height: view.height,
                channels: 3,
                data: comps.accumulated_over[p * vpx * 3..(p + 1) * vpx * 3].to_vec(),
            };
            let t_img = image_from_planar(&comps.transmittance[p * vpx..(p + 1) * vpx], 1, vh, vw);
            let one = [depths[p]];
            let psv_a = deepview_mpi::plane_sweep(&a_img, view, &reference, &one);
            let psv_t = deepview_mpi::plane_sweep(&t_img, view, &reference, &one);
            let (i4, r4) = (psv_i.plane(p), psv_r.plane(p));
            let (a4, t2) = (psv_a.plane(0), psv_t.plane(0));
            for i in 0..mpx {
                let valid = i4[i * 4 + 3];
                assert_eq!(
                    [r4[i * 4 + 3], a4[i * 4 + 3], t2[i * 2 + 1]],
                    [valid; 3],
                    "one homography per plane: one validity"
                );
                let mut ch = [0f32; GRADIENT_CHANNELS];
                ch[0..3].copy_from_slice(&i4[i * 4..i * 4 + 3]);
                ch[3..6].copy_from_slice(&r4[i * 4..i * 4 + 3]);
                ch[6..9].copy_from_slice(&a4[i * 4..i * 4 + 3]);
                ch[9] = t2[i * 2];
                ch[10] = valid;
                for (c, v) in ch.into_iter().enumerate() {
                    expect[(p * GRADIENT_CHANNELS + c) * mpx + i] = v;
                }
            }
        }
        // The test is not vacuous: mostly valid, some invalid, A and T far from trivial.
        let valid: Vec<f32> = (0..d)
            .flat_map(|p| expect[(p * GRADIENT_CHANNELS + 10) * mpx..][..mpx].to_vec())
            .collect();
        let n_valid = valid.iter().filter(|&&v| v == 1.0).count();
        assert!(
            n_valid > d * mpx / 2 && n_valid < d * mpx,
            "{n_valid} valid"
        );
        assert!((0..mpx).any(|i| expect[(GRADIENT_CHANNELS + 9) * mpx + i] < 0.5));
        assert!((0..mpx).any(|i| expect[((d - 1) * GRADIENT_CHANNELS + 6) * mpx + i] > 0.1));

        // burn.
        let m2v: Vec<Hom> = depths
            .iter()
            .map(|&z| plane_homography(&reference, view, z).to_row_major())
            .collect();
        let got = to_vec(gradient_components(
            rgba.clone(),
            img.clone(),
            &m2v,
            (0, 0, w, h),
        ));
        assert_eq!(got.len(), expect.len());
        for p in 0..d {
            for c in 0..GRADIENT_CHANNELS {
                for i in 0..mpx {
                    let o = (p * GRADIENT_CHANNELS + c) * mpx + i;
                    let err = (got[o] - expect[o]).abs();
                    worst[c] = worst[c].max(err);
                    assert!(
                        err < 1e-4,
                        "plane {p} channel {c} ({}) pixel {i}: burn {} vs cpu {}",
                        names[c],
                        got[o],
                        expect[o]
                    );
                }
            }
        }
        // A sub-region is the same window of the full result.
        let (x0, y0, rw, rh) = region;
        let sub = to_vec(gradient_components(rgba.clone(), img, &m2v, region));
        for p in 0..d {
            for c in 0..GRADIENT_CHANNELS {
                for y in 0..rh {
                    for x in 0..rw {
                        let g = sub[((p * GRADIENT_CHANNELS + c) * rh + y) * rw + x];
                        let e = expect[(p * GRADIENT_CHANNELS + c) * mpx + (y0 + y) * w + x0 + x];
                        assert!(
                            (g - e).abs() < 1e-4,
                            "region: plane {p} channel {c} ({}) at ({x}, {y}): {g} vs {e}",
                            names[c]
                        );
                    }
                }
            }
        }
    }
    eprintln!("max |burn - cpu| per channel: {worst:?}");
}

/// Largest difference of `a` and `b` relative to the largest magnitude of `b`.
fn max_rel<const D: usize>(a: Tensor<D>, b: Tensor<D>) -> f32 {
    let (a, b) = (to_vec(a), to_vec(b));
    assert_eq!(a.len(), b.len());
    let s = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-6);
    a.iter()
        .zip(&b)
        .fold(0f32, |m, (x, y)| m.max((x - y).abs()))
        / s
}

/// The CPU warp operation (forward, and its scatter backward) equals burn's `select` + weighted sum
/// under autodiff: per-plane sources and a broadcast source, odd sizes, samples leaving the source.
#[test]
fn cpu_warp_matches_burn_ops() {
    let ad = dev().autodiff();
    for (s, c, sh, sw, d, oh, ow) in [
        (3, 4, 9, 11, 3, 7, 10),
        (1, 3, 13, 8, 5, 6, 9),
        (2, 11, 5, 7, 2, 5, 6),
        (1, 1, 1, 1, 2, 3, 2),
    ] {
        let homs = some_homs(d);
        let table = WarpTable::new(&homs, sw, sh, ow, oh);
        let x = crate::rng::random::<4, _>([s, c, sh, sw], Distribution::Uniform(-1.0, 1.0), &ad);
        let seed =
            crate::rng::random::<4, _>([d, c, oh, ow], Distribution::Uniform(-1.0, 1.0), &ad);
        let (xa, xb) = (x.clone().require_grad(), x.require_grad());
        let (ya, yb) = (table.apply(xa.clone()), table.apply_burn(xb.clone()));
        let case = format!("{s}x{c} {sh}x{sw} -> {d} {oh}x{ow}");
        assert!(
            max_rel(ya.clone().inner(), yb.clone().inner()) < 1e-6,
            "output {case}"
        );
        let ga = (ya * seed.clone()).sum().backward();
        let gb = (yb * seed).sum().backward();
        let e = max_rel(xa.grad(&ga).unwrap(), xb.grad(&gb).unwrap());
        assert!(e < 1e-5, "source gradient {case}: {e}");
    }
}

/// The transposed taps (the GPU warp's gather-only backward) applied on the host equal the CPU warp's
/// scatter backward, for per-plane and broadcast sources, with samples outside the source (weight 0,
/// left out) and the entries of each texel in sample order.
#[test]
fn transposed_taps_are_the_warps_adjoint() {
    for (s, c, sh, sw, d, oh, ow) in [(3, 2, 9, 11, 3, 7, 10), (1, 3, 13, 8, 5, 6, 9)] {
        let table = WarpTable::new(&some_homs(d), sw, sh, ow, oh);
        let t = table.transposed(s);
        let (per, shw) = (oh * ow, sh * sw);
        assert_eq!(t.offsets.len(), s * shw + 1);
        let (_, w) = table.taps();
        let nonzero = w.iter().filter(|&&v| v != 0.0).count();
        assert_eq!(t.pos.len(), nonzero, "every tap of nonzero weight, once");
        assert!(nonzero < w.len(), "the case has samples outside the source");
        let grad = to_vec(crate::rng::random::<4, _>(
            [d, c, oh, ow],
            Distribution::Uniform(-1.0, 1.0),
            &dev(),
        ));
        let mut got = vec![0f32; s * c * shw];
        for e in 0..s * shw {
            let (sp, texel) = (e / shw, e % shw);
            let range = t.offsets[e] as usize..t.offsets[e + 1] as usize;
            assert!(t.pos[range.clone()].windows(2).all(|p| p[0] <= p[1]));
            for ch in 0..c {
                got[(sp * c + ch) * shw + texel] = range
                    .clone()
                    .map(|j| {
                        let q = t.pos[j] as usize;
                        t.w[j] * grad[((q / per) * c + ch) * per + q % per]
                    })
                    .sum();
            }
        }
        let want = crate::cpu::renderops::warp_backward(&table, &grad, s, c);
        let e = got
            .iter()
            .zip(&want)
            .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(e < 1e-5, "{s} source planes: {e}");
    }
}

/// The CPU composite operation equals burn's plane loop: the render, `T` and `A`, and the gradient of
/// a weighted sum of all three at the RGBA planes (colour and alpha), including alpha 0 and 1.
#[test]
fn cpu_composite_matches_burn_ops() {
    let ad = dev().autodiff();
    for (d, h, w) in [(6, 5, 7), (1, 3, 4), (33, 17, 19)] {
        let mut rgba = to_vec(crate::rng::random::<4, _>(
            [d, 4, h, w],
            Distribution::Uniform(0.0, 1.0),
            &dev(),
        ));
        let px = h * w;
        // Opaque and empty texels.
        rgba[3 * px] = 1.0;
        rgba[3 * px + 1] = 0.0;
        let x = Tensor::<4>::from_data(TensorData::new(rgba, [d, 4, h, w]), &ad);
        let (xa, xb) = (x.clone().require_grad(), x.require_grad());
        let (ca, cb) = (composite(xa.clone()), composite_burn(xb.clone()));
        let case = format!("{d} planes {h}x{w}");
        for (a, b, what) in [
            (ca.transmittance.clone(), cb.transmittance.clone(), "T"),
            (ca.accumulated.clone(), cb.accumulated.clone(), "A"),
        ] {
            assert!(max_rel(a.inner(), b.inner()) < 1e-5, "{what} {case}");
        }
        assert!(
            max_rel(ca.render.clone().inner(), cb.render.clone().inner()) < 1e-5,
            "render {case}"
        );
        let wr = crate::rng::random::<3, _>([3, h, w], Distribution::Uniform(-1.0, 1.0), &ad);
        let wt = crate::rng::random::<4, _>([d, 1, h, w], Distribution::Uniform(-1.0, 1.0), &ad);
        let wa = crate::rng::random::<4, _>([d, 3, h, w], Distribution::Uniform(-1.0, 1.0), &ad);
        let loss = |c: Composite| {
            (c.render * wr.clone()).sum()
                + (c.transmittance * wt.clone()).sum()
                + (c.accumulated * wa.clone()).sum()
        };
        let ga = loss(ca).backward();
        let gb = loss(cb).backward();
        let e = max_rel(xa.grad(&ga).unwrap(), xb.grad(&gb).unwrap());
        assert!(e < 1e-4, "RGBA gradient {case}: {e}");
    }
}

/// A warp of a crop of the source into a window of the output ([`Frames`]) is bit for bit the matching
/// part of the whole warp: the same validity and weights, and texel indices moved by the crop's origin.
/// Among the homographies, one puts samples exactly on the source's right edge (valid there) and a
/// perspective one rounds differently once shifted: shifting the homographies instead of framing them
/// flips such samples (found on fern, where tiled and whole-image inference differed by up to 17/255).
#[test]
fn framed_taps_are_the_whole_tables_crop() {
    let (sw, sh, ow, oh) = (50usize, 36usize, 40usize, 30usize);
    let homs: Vec<Hom> = vec![
        [1.0, 0.0, 10.5, 0.0, 1.0, 6.0, 0.0, 0.0, 1.0],
        [1.13, 0.021, 3.7, -0.013, 1.07, 2.9, 1.3e-4, -2.1e-4, 1.0],
        [
            0.97,
            -0.05,
            12.123456789,
            0.04,
            1.01,
            -1.987654321,
            -3.3e-4,
            1.7e-4,
            0.99,
        ],
    ];
    let whole = WarpTable::new(&homs, sw, sh, ow, oh);
    let mut edge = 0;
    for (ox, oy, ww, wh) in [
        (0, 0, ow, oh),
        (7, 3, 20, 11),
        (25, 19, 15, 11),
        (39, 0, 1, 30),
    ] {
        // The source crop: every texel that a valid sample of the window reads in the whole table.
        let (mut x0, mut y0, mut x1, mut y1) = (sw, sh, 0, 0);
        for d in 0..homs.len() {
            for y in oy..oy + wh {
                for x in ox..ox + ww {
                    let o = (d * oh + y) * ow + x;
                    if whole.valid_data()[o] == 0.0 {
                        continue;
                    }
                    for t in 0..4 {
                        let i = whole.taps().0[t * whole.valid_data().len() + o] as usize;
                        let (tx, ty) = (i % sw, i / sw);
                        (x0, y0, x1, y1) = (x0.min(tx), y0.min(ty), x1.max(tx + 1), y1.max(ty + 1));
                    }
                }
            }
        }
        let (cw, ch) = (x1 - x0, y1 - y0);
        let frames = Frames {
            src_origin: (x0, y0),
            src_full: (sw, sh),
            out_origin: (ox, oy),
        };
        let framed = WarpTable::new_framed(&homs, frames, cw, ch, ww, wh);
        let (n, nw) = (framed.valid_data().len(), whole.valid_data().len());
        for d in 0..homs.len() {
            for y in 0..wh {
                for x in 0..ww {
                    let o = (d * wh + y) * ww + x;
                    let ow_ = (d * oh + oy + y) * ow + ox + x;
                    assert_eq!(
                        framed.valid_data()[o],
                        whole.valid_data()[ow_],
                        "plane {d} ({x}, {y})"
                    );
                    for t in 0..4 {
                        assert_eq!(
                            framed.taps().1[t * n + o].to_bits(),
                            whole.taps().1[t * nw + ow_].to_bits()
                        );
                        if framed.valid_data()[o] != 0.0 {
                            let i = framed.taps().0[t * n + o] as usize;
                            let moved = (i / cw + y0) * sw + i % cw + x0;
                            assert_eq!(moved as i64, whole.taps().0[t * nw + ow_]);
                        }
                    }
                    // Samples at exactly x = sw: plane 0, output column sw - 11 - 0.5 + 0.5.
                    if d == 0 && ox + x == sw - 11 && framed.valid_data()[o] != 0.0 {
                        edge += 1;
                    }
                }
            }
        }
    }
    assert!(edge > 0, "no sample on the source's edge was checked");
}

/// The scan composite (GPU devices) equals the loop (burn's ops) in outputs and gradients, with opaque
/// and empty texels, for plane counts around the powers of two.
#[test]
fn scan_composite_matches_the_loop() {
    let ad = dev().autodiff();
    for (d, h, w) in [
        (1, 3, 4),
        (2, 2, 3),
        (3, 5, 7),
        (5, 4, 4),
        (8, 3, 3),
        (13, 6, 5),
        (33, 4, 6),
    ] {
        let mut rgba = to_vec(crate::rng::random::<4, _>(
            [d, 4, h, w],
            Distribution::Uniform(0.0, 1.0),
            &dev(),
        ));
        let px = h * w;
        // Premultiplied: colour at most alpha; opaque and empty texels.
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
        if d > 2 {
            rgba[(2 * 4 + 3) * px + 2] = 1.0;
        }
        let x = Tensor::<4>::from_data(TensorData::new(rgba, [d, 4, h, w]), &ad);
        let (xa, xb) = (x.clone().require_grad(), x.require_grad());
        let (ca, cb) = (composite_scan(xa.clone()), composite_burn(xb.clone()));
        let case = format!("{d} planes {h}x{w}");
        assert_eq!(ca.transmittance.dims(), [d, 1, h, w]);
        assert_eq!(ca.accumulated.dims(), [d, 3, h, w]);
        for (a, b, what) in [
            (ca.transmittance.clone(), cb.transmittance.clone(), "T"),
            (ca.accumulated.clone(), cb.accumulated.clone(), "A"),
        ] {
            let e: f32 = (a.inner() - b.inner()).abs().max().into_scalar();
            assert!(e < 1e-6, "{what} {case}: {e}");
        }
        let e: f32 = (ca.render.clone().inner() - cb.render.clone().inner())
            .abs()
            .max()
            .into_scalar();
        assert!(e < 1e-6, "render {case}: {e}");
        let wr = crate::rng::random::<3, _>([3, h, w], Distribution::Uniform(-1.0, 1.0), &ad);
        let wt = crate::rng::random::<4, _>([d, 1, h, w], Distribution::Uniform(-1.0, 1.0), &ad);
        let wa = crate::rng::random::<4, _>([d, 3, h, w], Distribution::Uniform(-1.0, 1.0), &ad);
        let loss = |c: Composite| {
            (c.render * wr.clone()).sum()
                + (c.transmittance * wt.clone()).sum()
                + (c.accumulated * wa.clone()).sum()
        };
        let ga = loss(ca).backward();
        let gb = loss(cb).backward();
        let e: f32 = (xa.grad(&ga).unwrap() - xb.grad(&gb).unwrap())
            .abs()
            .max()
            .into_scalar();
        assert!(e < 1e-5, "RGBA gradient {case}: {e}");
    }
}
