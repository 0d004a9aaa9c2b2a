//! A tiny analytic scene for tests, smoke runs and benchmarks (until `deepview-synth` provides richer
//! ones): two fronto-parallel textured planes, a square occluder at depth 2 in front of a background at
//! depth 4, seen by a grid of cameras on the plane z = 0 looking down +z (OpenCV axes), rendered by ray
//! casting with 2x2 supersampling.

use crate::scene::{Holdout, TrainScene};
use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, Pose};
use deepview_image::ImageF32;

const FRONT_Z: f64 = 2.0;
const BACK_Z: f64 = 4.0;
const HALF: f64 = 0.45;

fn background(x: f64, y: f64) -> [f32; 3] {
    let a = (x * 5.0).sin() * (y * 4.0).cos();
    let b = ((x + y) * 7.0).sin();
    [
        (0.5 + 0.35 * a) as f32,
        (0.5 + 0.3 * b) as f32,
        (0.45 + 0.25 * (x * 3.0 - y * 2.0).sin()) as f32,
    ]
}

fn occluder(x: f64, y: f64) -> [f32; 3] {
    let checker = ((x * 6.0).floor() + (y * 6.0).floor()).rem_euclid(2.0);
    [0.9 - 0.6 * checker as f32, 0.2 + 0.5 * checker as f32, 0.3]
}

/// Colour seen along the ray from `origin` with direction `dir` (dir.z > 0).
fn shade(origin: DVec3, dir: DVec3) -> [f32; 3] {
    let t = (FRONT_Z - origin.z) / dir.z;
    let p = origin + dir * t;
    if p.x.abs() < HALF && p.y.abs() < HALF {
        return occluder(p.x, p.y);
    }
    let t = (BACK_Z - origin.z) / dir.z;
    let p = origin + dir * t;
    background(p.x, p.y)
}

/// `nx x ny` cameras spaced `baseline` apart, `size x size` images, focal `size` px; near 1.5, far 5.
pub fn two_plane_scene(nx: usize, ny: usize, size: u32, baseline: f64) -> TrainScene {
    let mut cameras = Vec::new();
    let mut images = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            let c = DVec3::new(
                (i as f64 - (nx - 1) as f64 / 2.0) * baseline,
                (j as f64 - (ny - 1) as f64 / 2.0) * baseline,
                0.0,
            );
            let cam = Camera::new(
                size,
                size,
                Intrinsics::centred(size as f64, size, size),
                Pose::from_center(DMat3::IDENTITY, c),
            );
            let mut img = ImageF32::new(size, size, 3);
            let k = cam.intrinsics;
            for y in 0..size {
                for x in 0..size {
                    let mut acc = [0f32; 3];
                    for (sx, sy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                        let d = DVec3::new(
                            (x as f64 + sx - k.cx) / k.fx,
                            (y as f64 + sy - k.cy) / k.fy,
                            1.0,
                        );
                        let v = shade(c, d);
                        for ch in 0..3 {
                            acc[ch] += v[ch] / 4.0;
                        }
                    }
                    img.pixel_mut(x, y).copy_from_slice(&acc);
                }
            }
            cameras.push(cam);
            images.push(img);
        }
    }
    TrainScene::new(
        "synthetic:two-planes",
        cameras,
        images,
        1.5,
        5.0,
        Holdout::Nothing,
    )
    .expect("valid synthetic scene")
}
