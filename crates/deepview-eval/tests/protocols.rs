//! Protocol index sets, the Spaces crop rule, and errors for scenes or rules that do not fit.

#[path = "../../deepview-methods/tests/common/mod.rs"]
mod common;

use common::camera_at;
use deepview_data::{Scene, SceneFormat, View};
use deepview_eval::{EvalError, Protocol, SpacesConfig, TargetRule};
use deepview_geometry::{Camera, DVec3};
use deepview_methods::{InputRule, MethodError};
use deepview_metrics::BorderCrop;
use std::path::PathBuf;

fn scene(format: SceneFormat, cams: Vec<Camera>, grid: Option<(usize, usize)>) -> Scene {
    Scene {
        root: PathBuf::from("/synthetic"),
        format,
        views: cams
            .into_iter()
            .enumerate()
            .map(|(i, camera)| View {
                name: format!("v{i:02}"),
                image_path: PathBuf::from(format!("/synthetic/{i}.png")),
                camera,
            })
            .collect(),
        depth_bounds: Some((1.0, 100.0)),
        grid,
        rig_count: 1,
        downscale: 1,
    }
}

/// Camera centres of Spaces scene 000, rig 0 (metres, from its models.json, rounded to 0.1 mm).
const SPACES_CENTRES: [[f64; 3]; 16] = [
    [-0.0174, 0.0185, 0.0132],
    [-0.1132, 0.0184, 0.0127],
    [-0.2080, 0.0185, 0.0111],
    [-0.3030, 0.0183, 0.0084],
    [-0.3498, 0.0989, 0.0027],
    [-0.2550, 0.1001, 0.0086],
    [-0.1604, 0.1006, 0.0121],
    [-0.0644, 0.1006, 0.0121],
    [0.0316, 0.0998, 0.0112],
    [-0.0157, 0.1824, 0.0097],
    [-0.1118, 0.1825, 0.0100],
    [-0.2077, 0.1822, 0.0082],
    [-0.3028, 0.1821, 0.0066],
    [-0.2524, 0.2650, 0.0078],
    [-0.1564, 0.2653, 0.0098],
    [-0.0597, 0.2654, 0.0091],
];

fn spaces_rig() -> Scene {
    let cams = SPACES_CENTRES
        .iter()
        .map(|c| camera_at(DVec3::from_array(*c), 800, 480, 225.0))
        .collect();
    scene(SceneFormat::Spaces, cams, None)
}

/// The crop table of `compute_metrics.py` (Spaces release): (config, view) -> crop; views not listed: 16 px.
fn official_crop(cfg: SpacesConfig, view: usize) -> BorderCrop {
    let (s, b) = (16, 40);
    let left = BorderCrop {
        left: b,
        top: s,
        right: s,
        bottom: s,
    };
    let top = BorderCrop {
        left: s,
        top: b,
        right: s,
        bottom: s,
    };
    let right = BorderCrop {
        left: s,
        top: s,
        right: b,
        bottom: s,
    };
    let bottom = BorderCrop {
        left: s,
        top: s,
        right: s,
        bottom: b,
    };
    match (cfg, view) {
        (SpacesConfig::SmallQuad, 5) => left,
        (SpacesConfig::SmallQuad, 7) => right,
        (SpacesConfig::MediumQuad, 2) => top,
        (SpacesConfig::MediumQuad, 4) => left,
        (SpacesConfig::MediumQuad, 7) => right,
        (SpacesConfig::MediumQuad, 11) => bottom,
        (SpacesConfig::LargeQuad, 1 | 2) => top,
        (SpacesConfig::LargeQuad, 4) => left,
        (SpacesConfig::LargeQuad, 8) => right,
        (SpacesConfig::LargeQuad, 10 | 11) => bottom,
        _ => BorderCrop::uniform(s),
    }
}

fn check_spaces(scene: &Scene) {
    let expected: [(&str, &[usize], &[usize]); 4] = [
        ("small_quad", &[5, 6, 7], &[2, 1, 11, 10]),
        ("medium_quad", &[2, 4, 5, 6, 7, 11], &[3, 1, 12, 10]),
        ("large_quad", &[1, 2, 4, 5, 6, 7, 8, 10, 11], &[3, 0, 12, 9]),
        (
            "dense",
            &[5, 7, 10, 11],
            &[0, 1, 2, 3, 4, 6, 8, 9, 12, 13, 14, 15],
        ),
    ];
    for (cfg, (name, targets, inputs)) in SpacesConfig::ALL.into_iter().zip(expected) {
        let p = Protocol::from_name(name, None, None).unwrap();
        assert_eq!(p, Protocol::Spaces(cfg));
        let splits = p.splits(scene).unwrap();
        assert_eq!(
            splits.iter().map(|s| s.target).collect::<Vec<_>>(),
            targets,
            "{name}"
        );
        for s in &splits {
            assert_eq!(s.inputs, inputs, "{name}");
            assert_eq!(
                s.crop,
                official_crop(cfg, s.target),
                "{name} view {}",
                s.target
            );
        }
    }
}

#[test]
fn spaces_index_sets_and_crop_rule_match_the_official_table() {
    check_spaces(&spaces_rig());
}

#[test]
fn spaces_crop_rule_on_the_real_calibration() {
    let dir = deepview_data::data_dir().join("spaces/scene_000");
    if !dir.join("models.json").is_file() {
        eprintln!("skipped: {} not found (set DEEPVIEW_DATA)", dir.display());
        return;
    }
    let scene = deepview_data::load_scene(&dir, &Default::default()).unwrap();
    check_spaces(&scene);
}

#[test]
fn spaces_needs_the_16_camera_rig() {
    let mut s = spaces_rig();
    s.views.truncate(12);
    let e = Protocol::Spaces(SpacesConfig::Dense)
        .splits(&s)
        .unwrap_err();
    assert!(
        matches!(e, EvalError::WrongScene { .. }) && e.to_string().contains("12 views"),
        "{e}"
    );
    let e = Protocol::Auto
        .splits(&spaces_rig())
        .unwrap_err()
        .to_string();
    assert!(e.contains("small_quad"), "{e}");
    assert!(Protocol::from_name("dense", Some(TargetRule::Every(2)), None).is_err());
}

fn line_scene(n: usize) -> Scene {
    scene(
        SceneFormat::Llff,
        (0..n)
            .map(|i| camera_at(DVec3::new(i as f64 * 0.1, 0.0, 0.0), 40, 30, 30.0))
            .collect(),
        None,
    )
}

#[test]
fn posed_every_8_nearest_4() {
    let s = line_scene(20);
    let p = Protocol::from_name(
        "posed",
        Some("every:8".parse().unwrap()),
        Some("nearest:4".parse().unwrap()),
    )
    .unwrap();
    assert_eq!(
        p,
        Protocol::Posed {
            targets: TargetRule::Every(8),
            inputs: InputRule::Nearest(4)
        }
    );
    // `auto` on an LLFF scene is the same protocol.
    assert_eq!(Protocol::Auto.resolve(&s).unwrap(), p);
    let splits = p.splits(&s).unwrap();
    let got: Vec<(usize, Vec<usize>)> = splits
        .iter()
        .map(|s| (s.target, s.inputs.clone()))
        .collect();
    assert_eq!(
        got,
        vec![
            (0, vec![1, 2, 3, 4]),
            (8, vec![7, 9, 6, 10]),
            (16, vec![15, 17, 14, 18])
        ]
    );
    assert!(splits.iter().all(|s| s.crop == BorderCrop::uniform(16)));
    // Other targets are never inputs: targets 0, 2, 4 ... with nearest:2 around 2 -> 1, 3.
    let p = Protocol::Posed {
        targets: TargetRule::Every(2),
        inputs: InputRule::Nearest(2),
    };
    assert_eq!(p.splits(&line_scene(6)).unwrap()[1].inputs, vec![1, 3]);
}

#[test]
fn posed_explicit_lists() {
    let s = line_scene(10);
    let p = Protocol::from_name(
        "posed",
        Some("3,7".parse().unwrap()),
        Some("0,9".parse().unwrap()),
    )
    .unwrap();
    let splits = p.splits(&s).unwrap();
    assert_eq!(splits.len(), 2);
    assert_eq!(splits[1].target, 7);
    assert_eq!(splits[1].inputs, vec![0, 9]);
}

#[test]
fn posed_errors() {
    // Target out of range.
    let p = Protocol::Posed {
        targets: TargetRule::List(vec![3, 99]),
        inputs: InputRule::Nearest(2),
    };
    let e = p.splits(&line_scene(10)).unwrap_err();
    assert!(
        matches!(
            e,
            EvalError::ViewOutOfRange {
                index: 99,
                views: 10,
                ..
            }
        ),
        "{e}"
    );
    // Input out of range.
    let p = Protocol::Posed {
        targets: TargetRule::List(vec![3]),
        inputs: InputRule::List(vec![1, 12]),
    };
    assert!(matches!(
        p.splits(&line_scene(10)).unwrap_err(),
        EvalError::ViewOutOfRange { index: 12, .. }
    ));
    // A target that is its own input.
    let p = Protocol::Posed {
        targets: TargetRule::List(vec![3]),
        inputs: InputRule::List(vec![1, 3]),
    };
    assert!(
        p.splits(&line_scene(10))
            .unwrap_err()
            .to_string()
            .contains("target view 3 is also an input")
    );
    // Too few candidates: 5 views, targets 0, 2, 4, candidates 1, 3.
    let p = Protocol::Posed {
        targets: TargetRule::Every(2),
        inputs: InputRule::Nearest(4),
    };
    let e = p.splits(&line_scene(5)).unwrap_err();
    assert!(
        matches!(
            e,
            EvalError::NotEnoughInputs {
                target: 0,
                wanted: 4,
                available: 2,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("only 2 candidate"), "{e}");
    // No targets selected.
    let p = Protocol::Posed {
        targets: TargetRule::List(vec![]),
        inputs: InputRule::Nearest(1),
    };
    assert!(matches!(
        p.splits(&line_scene(5)).unwrap_err(),
        EvalError::NoTargets { .. }
    ));
    assert!("".parse::<TargetRule>().is_err());
}

#[test]
fn rule_parsing_errors() {
    assert!(matches!(
        "every:0".parse::<TargetRule>(),
        Err(EvalError::Method(MethodError::BadRule { .. }))
    ));
    assert!("every:x".parse::<TargetRule>().is_err());
    assert!("nearest:-1".parse::<InputRule>().is_err());
    assert!(
        "1,1"
            .parse::<InputRule>()
            .unwrap_err()
            .to_string()
            .contains("twice")
    );
    assert_eq!(
        "1, 4,2".parse::<InputRule>().unwrap(),
        InputRule::List(vec![1, 4, 2])
    );
    let e = Protocol::from_name("tiny_quad", None, None).unwrap_err();
    assert!(
        matches!(e, EvalError::UnknownProtocol(_)) && e.to_string().contains("small_quad"),
        "{e}"
    );
    assert_eq!(
        Protocol::from_name("Small-Quad", None, None).unwrap(),
        Protocol::Spaces(SpacesConfig::SmallQuad)
    );
}

fn grid_scene(rows: usize, cols: usize) -> Scene {
    let cams = (0..rows * cols)
        .map(|i| {
            camera_at(
                DVec3::new((i % cols) as f64, (i / cols) as f64, 0.0),
                32,
                32,
                32.0,
            )
        })
        .collect();
    scene(SceneFormat::LightField, cams, Some((rows, cols)))
}

#[test]
fn light_field_corners_in_inner_views_out() {
    let s = grid_scene(5, 5);
    let splits = Protocol::Auto.splits(&s).unwrap();
    assert_eq!(splits.len(), 21);
    assert!(splits.iter().all(|sp| sp.inputs == vec![0, 4, 20, 24]));
    assert!(splits.iter().all(|sp| ![0, 4, 20, 24].contains(&sp.target)));
    // Kalantari's 8x8: 60 targets.
    assert_eq!(
        Protocol::from_name("light-field", None, None)
            .unwrap()
            .splits(&grid_scene(8, 8))
            .unwrap()
            .len(),
        60
    );
    let p = Protocol::from_name("light-field", Some("12".parse().unwrap()), None).unwrap();
    assert_eq!(p.splits(&s).unwrap().len(), 1);
    let p = Protocol::LightField {
        targets: Some(TargetRule::List(vec![4])),
    };
    assert!(p.splits(&s).unwrap_err().to_string().contains("corner"));
    assert!(Protocol::from_name("light-field", None, Some(InputRule::Nearest(4))).is_err());
    // `auto` with --targets on a light field is still the light-field protocol with those targets (it
    // was the posed protocol: corners as targets, nearest inputs); an input rule is the posed protocol's.
    let auto = Protocol::from_name("auto", Some("every:12".parse().unwrap()), None).unwrap();
    assert_eq!(
        auto.resolve(&s).unwrap(),
        Protocol::LightField {
            targets: Some(TargetRule::Every(12))
        }
    );
    let splits = auto.resolve(&s).unwrap().splits(&s).unwrap();
    assert!(
        splits.iter().all(|sp| sp.inputs == vec![0, 4, 20, 24]),
        "{splits:?}"
    );
    assert_eq!(
        Protocol::from_name("auto", None, Some(InputRule::Nearest(4)))
            .unwrap()
            .resolve(&s)
            .unwrap(),
        Protocol::Posed {
            targets: TargetRule::Every(8),
            inputs: InputRule::Nearest(4)
        }
    );
    // Not a grid.
    let e = Protocol::LightField { targets: None }
        .splits(&line_scene(9))
        .unwrap_err();
    assert!(matches!(e, EvalError::WrongScene { .. }), "{e}");
}
