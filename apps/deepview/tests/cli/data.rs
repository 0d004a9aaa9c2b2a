//! Dataset formats (`deepview info`): the synthetic grid rewritten as LLFF, COLMAP (text and binary) and
//! Spaces, and broken dataset files.

use crate::common::{copy_dir, deepview, fails_with, s, succeeds, synth_grid};
use std::path::{Path, PathBuf};

/// The synthetic grid scene (made by `deepview synth`) rewritten by the library's writers as an `llff`,
/// `colmap` (text) or `spaces` dataset in `out`; `deepview info` must accept the result.
fn grid_as(grid: &Path, format: &str, out: &Path) -> PathBuf {
    let scene = deepview_data::load_scene(grid, &Default::default()).unwrap();
    let cams = scene.cameras();
    let images: Vec<_> = (0..cams.len())
        .map(|i| scene.load_image(i).unwrap())
        .collect();
    match format {
        "llff" => {
            // LLFF stores a centred principal point; the grid's are off-centre (sheared frusta). Centring
            // them changes what the images mean, not what these error tests look at.
            let cams: Vec<_> = cams
                .iter()
                .map(|c| {
                    let mut c = *c;
                    c.intrinsics.cx = c.width as f64 / 2.0;
                    c.intrinsics.cy = c.height as f64 / 2.0;
                    c
                })
                .collect();
            let bounds = vec![scene.near_far().unwrap(); cams.len()];
            deepview_data::write_llff(out, &cams, &bounds, &images, 1).unwrap();
        }
        "colmap" => {
            let names: Vec<String> = (0..cams.len())
                .map(|i| format!("image{i:03}.png"))
                .collect();
            deepview_data::write_colmap_text(&out.join("sparse/0"), &names, &cams, &[]).unwrap();
            for (n, img) in names.iter().zip(&images) {
                std::fs::create_dir_all(out.join("images")).unwrap();
                deepview_image::write_png(&out.join("images").join(n), img).unwrap();
            }
        }
        "spaces" => {
            let paths: Vec<String> = (0..cams.len())
                .map(|i| format!("cam_{i:02}/image_000.png"))
                .collect();
            deepview_data::write_spaces_models(
                &out.join("models.json"),
                std::slice::from_ref(&cams),
                std::slice::from_ref(&paths),
            )
            .unwrap();
            for (p, img) in paths.iter().zip(&images) {
                std::fs::create_dir_all(out.join(p).parent().unwrap()).unwrap();
                deepview_image::write_png(&out.join(p), img).unwrap();
            }
        }
        f => panic!("unknown format {f}"),
    }
    let info = succeeds(&deepview(&["info", "--data", s(out)]));
    assert!(info.contains(format) && info.contains('9'), "{info}");
    out.to_path_buf()
}

/// COLMAP's binary model (`cameras.bin`, `images.bin`; no points) from the text model in `dir`, written by
/// hand per COLMAP's layout (little-endian; PINHOLE is model id 1; no 2D points per image). The text files
/// are removed so the binary ones are what is read.
fn colmap_text_to_bin(dir: &Path) {
    let data_lines = |name: &str| -> Vec<String> {
        std::fs::read_to_string(dir.join(name))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(str::to_string)
            .collect()
    };
    let cams: Vec<String> = data_lines("cameras.txt")
        .into_iter()
        .filter(|l| !l.trim().is_empty())
        .collect();
    let mut c = (cams.len() as u64).to_le_bytes().to_vec();
    for l in &cams {
        let t: Vec<&str> = l.split_whitespace().collect();
        assert_eq!(t[1], "PINHOLE");
        c.extend(t[0].parse::<i32>().unwrap().to_le_bytes());
        c.extend(1i32.to_le_bytes());
        c.extend(t[2].parse::<u64>().unwrap().to_le_bytes());
        c.extend(t[3].parse::<u64>().unwrap().to_le_bytes());
        for v in &t[4..8] {
            c.extend(v.parse::<f64>().unwrap().to_le_bytes());
        }
    }
    // Two lines per image: the pose line, then the (here ignored) 2D points line.
    let imgs: Vec<String> = data_lines("images.txt").into_iter().step_by(2).collect();
    let mut im = (imgs.len() as u64).to_le_bytes().to_vec();
    for l in &imgs {
        let t: Vec<&str> = l.split_whitespace().collect();
        im.extend(t[0].parse::<i32>().unwrap().to_le_bytes());
        for v in &t[1..8] {
            im.extend(v.parse::<f64>().unwrap().to_le_bytes());
        }
        im.extend(t[8].parse::<i32>().unwrap().to_le_bytes());
        im.extend(t[9].as_bytes());
        im.push(0);
        im.extend(0u64.to_le_bytes());
    }
    std::fs::write(dir.join("cameras.bin"), c).unwrap();
    std::fs::write(dir.join("images.bin"), im).unwrap();
    for f in ["cameras.txt", "images.txt", "points3D.txt"] {
        std::fs::remove_file(dir.join(f)).unwrap();
    }
}

#[test]
fn bad_dataset_files_give_clear_errors_and_exit_code_2() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let grid = synth_grid(t);

    // LLFF: a NaN in the pose data of poses_bounds.npy (row 1, column 3: the camera centre's x).
    let llff = grid_as(&grid, "llff", &t.join("llff"));
    let bad = copy_dir(&llff, &t.join("llff_nan"));
    let npy = bad.join("poses_bounds.npy");
    let mut bytes = std::fs::read(&npy).unwrap();
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
    let data_start = 10 + u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    assert_eq!(bytes.len(), data_start + 9 * 17 * 8);
    let at = data_start + (17 + 3) * 8;
    bytes[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
    std::fs::write(&npy, bytes).unwrap();
    fails_with(
        &deepview(&["info", "--data", s(&bad)]),
        &["poses_bounds.npy", "non-finite", "NaN", "row 1"],
    );

    // COLMAP text: `nan` for a translation in images.txt.
    let colmap = grid_as(&grid, "colmap", &t.join("colmap"));
    let bad = copy_dir(&colmap, &t.join("colmap_nan"));
    let images_txt = bad.join("sparse/0/images.txt");
    let text = std::fs::read_to_string(&images_txt).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let first = lines.iter().position(|l| !l.starts_with('#')).unwrap();
    let mut tok: Vec<&str> = lines[first].split_whitespace().collect();
    tok[6] = "nan";
    lines[first] = tok.join(" ");
    std::fs::write(&images_txt, lines.join("\n") + "\n").unwrap();
    fails_with(
        &deepview(&["info", "--data", s(&bad)]),
        &[
            &format!("images.txt:{}", first + 1),
            "non-finite pose value",
        ],
    );

    // COLMAP binary: a valid model (checked), then images.bin cut short inside its last record.
    let bad = copy_dir(&colmap, &t.join("colmap_bin"));
    colmap_text_to_bin(&bad.join("sparse/0"));
    let info = succeeds(&deepview(&["info", "--data", s(&bad), "--json"]));
    let info: serde_json::Value = serde_json::from_str(&info).unwrap();
    assert_eq!(info["views"], 9);
    let images_bin = bad.join("sparse/0/images.bin");
    let bytes = std::fs::read(&images_bin).unwrap();
    std::fs::write(&images_bin, &bytes[..bytes.len() - 5]).unwrap();
    fails_with(
        &deepview(&["info", "--data", s(&bad)]),
        &["images.bin", "truncated"],
    );
    // ... and cut short right after its image count.
    std::fs::write(&images_bin, &bytes[..12]).unwrap();
    fails_with(
        &deepview(&["info", "--data", s(&bad)]),
        &["images.bin", "truncated"],
    );

    // Spaces: truncated models.json, a camera without focal_length, and camera / rig counts that do not fit.
    let spaces = grid_as(&grid, "spaces", &t.join("spaces"));
    let text = std::fs::read_to_string(spaces.join("models.json")).unwrap();
    let bad = copy_dir(&spaces, &t.join("spaces_bad"));
    let models = bad.join("models.json");
    std::fs::write(&models, &text[..text.len() / 2]).unwrap();
    fails_with(
        &deepview(&["info", "--data", s(&bad)]),
        &["models.json", "malformed JSON"],
    );
    let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
    json[0][3].as_object_mut().unwrap().remove("focal_length");
    std::fs::write(&models, json.to_string()).unwrap();
    fails_with(
        &deepview(&["info", "--data", s(&bad)]),
        &["models.json", "missing field", "focal_length"],
    );
    std::fs::write(&models, "[[]]").unwrap();
    fails_with(
        &deepview(&["info", "--data", s(&bad)]),
        &["models.json", "no cameras"],
    );
    fails_with(
        &deepview(&["info", "--data", s(&spaces), "--rig", "1"]),
        &[
            "models.json",
            "rig position 1 is out of range",
            "1 rig position",
        ],
    );
}

#[test]
fn a_light_field_takes_no_images_folder_and_says_so() {
    let tmp = tempfile::tempdir().unwrap();
    let grid = synth_grid(tmp.path());
    let out = deepview(&["info", "--data", s(&grid), "--images", "images_4"]);
    let text = succeeds(&out);
    assert!(text.contains("light"), "{text}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--images images_4 is ignored") && err.contains("light field"),
        "{err}"
    );
    // The same for every command that reads one scene.
    let out = deepview(&[
        "eval",
        "--data",
        s(&grid),
        "--images",
        "images_4",
        "--method",
        "nearest",
    ]);
    succeeds(&out);
    assert!(String::from_utf8_lossy(&out.stderr).contains("--images images_4 is ignored"));
    // Without --images there is nothing to say.
    let out = deepview(&["info", "--data", s(&grid)]);
    succeeds(&out);
    assert!(!String::from_utf8_lossy(&out.stderr).contains("ignored"));
}
