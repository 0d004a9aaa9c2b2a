//! The runner end to end on a light-field grid written to disk and loaded by deepview-data.

#[path = "../../deepview-methods/tests/common/mod.rs"]
mod common;

use common::render_plane;
use deepview_data::{LoadOptions, light_field_cameras, load_scene, write_light_field};
use deepview_eval::{EvalOptions, MpiPredictor, Protocol, evaluate};
use deepview_geometry::Camera;
use deepview_image::ImageF32;
use deepview_methods::{
    MadeMpi, MethodError, MethodEvent, MethodKind, MethodOptions, MpiMethod, MpiRequest, Planes,
    make_method,
};
use deepview_mpi::Mpi;

/// Depth of the textured plane: light-field cameras of a 64 px wide grid have focal 64, baseline 1 and focus
/// depth 4, so depth 3.2 has disparity (1/3.2 - 1/4) 64 = 4 px between neighbouring views (an integer shift).
const DEPTH: f64 = 3.2;

/// A 3x3 light field of the textured plane at `depth` (light-field cameras of deepview-data), 64x56.
fn write_grid(dir: &std::path::Path, depth: f64) -> Vec<ImageF32> {
    let lf = light_field_cameras(3, 3, 64, 56);
    let images: Vec<ImageF32> = lf
        .cameras()
        .iter()
        .map(|c| render_plane(c, depth))
        .collect();
    write_light_field(dir, 3, 3, &images, None).unwrap();
    images
}

/// `eval --method nearest`, as the program scores it.
fn nearest() -> MpiPredictor<'static> {
    let options = MethodOptions {
        planes: Planes::Count(1),
        ..Default::default()
    };
    MpiPredictor::new(
        make_method(MethodKind::Nearest, &options, 1 << 30).unwrap(),
        |_| {},
    )
}

/// One opaque plane in `camera` holding `image` (rendered into `camera`, exactly the image).
fn picture(camera: Camera, image: &ImageF32) -> Mpi {
    Mpi {
        camera,
        depths: vec![2.0],
        layers: image
            .data
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 1.0])
            .collect(),
    }
}

/// Makes the ground truth it is given (looked up by the target's camera) as a picture in the target's
/// camera: SSIM 1, infinite PSNR.
struct Oracle(Vec<(Camera, ImageF32)>);

impl MpiMethod for Oracle {
    fn name(&self) -> &str {
        "oracle"
    }
    fn uses_target(&self) -> bool {
        true
    }
    fn make_mpi(
        &mut self,
        request: &MpiRequest<'_>,
        _: &mut dyn FnMut(MethodEvent<'_>),
    ) -> Result<MadeMpi, MethodError> {
        let target = request.toward.expect("eval names the target");
        let (_, image) = self
            .0
            .iter()
            .find(|(c, _)| c == target)
            .expect("known camera");
        Ok(MadeMpi {
            mpi: picture(*target, image),
            planes: None,
            note: None,
        })
    }
}

#[test]
fn evaluate_writes_report_and_renders() {
    let dir = tempfile::tempdir().unwrap();
    let depth = DEPTH;
    write_grid(dir.path(), depth);
    let scene = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.grid, Some((3, 3)));
    let renders = dir.path().join("renders");
    let options = EvalOptions {
        near_far: Some((depth / 1.25, depth / 0.75)),
        crop: Some(4),
        save_renders: Some(renders.clone()),
        ..Default::default()
    };
    let report = evaluate(&scene, &Protocol::Auto, &mut nearest(), &options).unwrap();
    assert_eq!(report.method, "nearest");
    assert_eq!(report.results.num_views, 5);
    assert_eq!(
        report.views.iter().map(|v| v.target).collect::<Vec<_>>(),
        vec![1, 3, 4, 5, 7]
    );
    assert!(
        report
            .views
            .iter()
            .all(|v| v.inputs == vec![0, 2, 6, 8] && v.crop == [4, 4, 4, 4])
    );
    // The single plane sits at the true depth: near-perfect reprojection.
    assert!(report.results.ssim > 0.999, "{}", report.table());
    assert!(report.table().contains("mean"));
    for v in &report.views {
        let path = renders.join(format!(
            "{:03}_{}.png",
            v.target,
            v.target_name
                .replace(|c: char| !c.is_ascii_alphanumeric(), "_")
        ));
        let (w, h) = deepview_image::image_size(&path).unwrap();
        assert_eq!((w, h), (3 * 64, 56));
    }
    // JSON in nerfstudio's shape.
    let json_path = dir.path().join("out/results.json");
    report.write_json(&json_path).unwrap();
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    for key in ["ssim", "ssim_std", "seconds_per_view"] {
        assert!(j["results"][key].is_number(), "results.{key}");
    }
    // The reprojection is exact after 8-bit rounding here (integer disparity): PSNR is infinite, written as null.
    assert!(j["results"]["psnr"].is_null() && j["results"].get("psnr_std").is_some());
    assert_eq!(j["method"], "nearest");
    assert!(j["checkpoint"].is_null());
    assert_eq!(j["views"][0]["inputs"], serde_json::json!([0, 2, 6, 8]));
}

#[test]
fn oracle_scores_one_and_downscale_halves_everything() {
    let dir = tempfile::tempdir().unwrap();
    write_grid(dir.path(), DEPTH);
    let scene = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    let mut truth = Vec::new();
    for i in 0..scene.views.len() {
        let img = scene.load_image(i).unwrap().downscale(2);
        let k = scene.views[i].camera.intrinsics.scaled(0.5, 0.5);
        truth.push((
            Camera::new(img.width, img.height, k, scene.views[i].camera.pose),
            img,
        ));
    }
    let options = EvalOptions {
        near_far: Some((1.0, 100.0)),
        downscale: 2,
        ..Default::default()
    };
    let mut oracle = MpiPredictor::new(Box::new(Oracle(truth)), |_| {});
    let report = evaluate(&scene, &Protocol::Auto, &mut oracle, &options).unwrap();
    assert!((report.results.ssim - 1.0).abs() < 1e-12);
    assert_eq!(report.results.psnr, f64::INFINITY);
    // Default light-field crop 16 px at full resolution -> 8 px at half resolution.
    assert_eq!(report.views[0].crop, [8, 8, 8, 8]);
    let j = serde_json::to_value(&report).unwrap();
    assert!(
        j["results"]["psnr"].is_null(),
        "infinite PSNR serialises as null"
    );
}

#[test]
fn runner_errors() {
    let dir = tempfile::tempdir().unwrap();
    write_grid(dir.path(), DEPTH);
    let scene = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    // Crop larger than the image.
    let options = EvalOptions {
        near_far: Some((1.0, 100.0)),
        crop: Some(30),
        ..Default::default()
    };
    let e = evaluate(&scene, &Protocol::Auto, &mut nearest(), &options).unwrap_err();
    assert!(e.to_string().contains("border crop"), "{e}");
    // A crop leaving less than SSIM's window (16x8 of 64x56) is refused before any method runs.
    struct Never;
    impl MpiMethod for Never {
        fn name(&self) -> &str {
            "never"
        }
        fn make_mpi(
            &mut self,
            _: &MpiRequest<'_>,
            _: &mut dyn FnMut(MethodEvent<'_>),
        ) -> Result<MadeMpi, MethodError> {
            panic!("the crop is checked before any MPI is made");
        }
    }
    let options = EvalOptions {
        near_far: Some((1.0, 100.0)),
        crop: Some(24),
        ..Default::default()
    };
    let mut never = MpiPredictor::new(Box::new(Never), |_| {});
    let e = evaluate(&scene, &Protocol::Auto, &mut never, &options)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("64x56 image leaves 16x8 pixels") && e.contains("11x11 window"),
        "{e}"
    );
    // A method whose MPI holds NaNs.
    struct Bad;
    impl MpiMethod for Bad {
        fn name(&self) -> &str {
            "bad"
        }
        fn make_mpi(
            &mut self,
            request: &MpiRequest<'_>,
            _: &mut dyn FnMut(MethodEvent<'_>),
        ) -> Result<MadeMpi, MethodError> {
            let camera = request.inputs[0].1;
            let mut nan = ImageF32::new(camera.width, camera.height, 3);
            nan.data.fill(f32::NAN);
            Ok(MadeMpi {
                mpi: picture(camera, &nan),
                planes: None,
                note: None,
            })
        }
    }
    let options = EvalOptions {
        near_far: Some((1.0, 100.0)),
        ..Default::default()
    };
    let mut bad = MpiPredictor::new(Box::new(Bad), |_| {});
    let e = evaluate(&scene, &Protocol::Auto, &mut bad, &options)
        .unwrap_err()
        .to_string();
    assert!(e.contains("method bad") && e.contains("NaN"), "{e}");
    // A missing image names the file.
    std::fs::remove_file(dir.path().join("input_Cam004.png")).unwrap();
    let e = evaluate(&scene, &Protocol::Auto, &mut nearest(), &options)
        .unwrap_err()
        .to_string();
    assert!(e.contains("input_Cam004.png"), "{e}");
}
