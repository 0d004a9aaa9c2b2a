//! The real binary, run as a user would: outputs, and clear errors with exit code 2 on bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn deepview(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_deepview"))
        .args(args)
        .output()
        .expect("binary runs")
}

fn data() -> PathBuf {
    let d = deepview_data::data_dir();
    assert!(
        d.join("llff/fern").is_dir(),
        "shared data missing at {} (set DEEPVIEW_DATA)",
        d.display()
    );
    d
}

/// Asserts a clean failure: exit code 2, no panic, and every `needle` in stderr.
fn fails_with(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not in: {err}");
    }
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn synth_grid(dir: &Path) -> PathBuf {
    let out = dir.join("grid");
    let o = deepview(&[
        "synth",
        "--out",
        s(&out),
        "--grid",
        "3",
        "--width",
        "96",
        "--height",
        "64",
        "--planes",
        "8",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

#[test]
fn synth_then_render_ground_truth_into_a_view() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = synth_grid(tmp.path());
    let view = tmp.path().join("v4.png");
    let gt = scene.join("ground_truth_mpi");
    let o = deepview(&[
        "render",
        "--mpi",
        s(&gt),
        "--scene",
        s(&scene),
        "--view",
        "4",
        "--out",
        s(&view),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a = deepview_image::read_image(&view, 3).unwrap();
    let b = deepview_image::read_image(&scene.join("input_Cam004.png"), 3).unwrap();
    let mse: f64 = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / a.data.len() as f64;
    let psnr = -10.0 * mse.log10();
    assert!(psnr > 38.0, "PSNR {psnr:.2}");
    // Depth maps and a camera JSON render work on the same MPI.
    let depth = tmp.path().join("depth");
    assert!(
        deepview(&["depth", "--mpi", s(&gt), "--out", s(&depth)])
            .status
            .success()
    );
    assert!(
        depth.join("depth_color.png").is_file() && depth.join("depth_disparity16.png").is_file()
    );
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(gt.join("mpi.json")).unwrap()).unwrap();
    let cam = serde_json::json!({"width": 40, "height": 30, "fx": 50.0, "fy": 50.0, "cx": 20.0, "cy": 15.0,
        "camera_from_world": meta["camera_from_world"]});
    let cam_path = tmp.path().join("cam.json");
    std::fs::write(&cam_path, cam.to_string()).unwrap();
    let out = tmp.path().join("c.png");
    assert!(
        deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--camera",
            s(&cam_path),
            "--out",
            s(&out)
        ])
        .status
        .success()
    );
    assert_eq!(deepview_image::image_size(&out).unwrap(), (40, 30));
    let o = deepview(&["bench", "render", "--mpi", s(&gt), "--repeats", "2"]);
    let line: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(line["fps"].as_f64().unwrap() > 0.0 && line["planes"] == 8);
    // `info --camera N` writes view N's camera JSON: rendering into it equals `--scene S --view N`. (The
    // old spellings, a bare dataset folder and `render --scene`, still work for one release.)
    let o = deepview(&["info", s(&scene), "--camera", "4"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cam4 = tmp.path().join("cam4.json");
    std::fs::write(&cam4, &o.stdout).unwrap();
    let via_json = tmp.path().join("v4_json.png");
    let o = deepview(&[
        "render",
        "--mpi",
        s(&gt),
        "--camera",
        s(&cam4),
        "--out",
        s(&via_json),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read(&via_json).unwrap(),
        std::fs::read(&view).unwrap()
    );
    fails_with(
        &deepview(&["info", "--data", s(&scene), "--camera", "99"]),
        &["view 99 is out of range", "9 views"],
    );
}

#[test]
fn psv_of_a_fern_view_onto_its_own_camera_is_the_image() {
    let tmp = tempfile::tempdir().unwrap();
    let fern = data().join("llff/fern");
    let out = tmp.path().join("psv");
    let o = deepview(&[
        "psv",
        "--data",
        s(&fern),
        "--images",
        "images_8",
        "--view",
        "5",
        "--planes",
        "4",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = deepview_image::read_image(&fern.join("images_8/image005.png"), 3).unwrap();
    for d in 0..4 {
        let plane = deepview_image::read_image(&out.join(format!("psv_{d:03}.png")), 4).unwrap();
        assert_eq!(plane.to_rgb(), img, "plane {d}");
        assert!(plane.data.chunks_exact(4).all(|p| p[3] == 1.0));
    }
}

#[test]
fn bad_input_gives_clear_errors_and_exit_code_2() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = synth_grid(tmp.path());
    let gt = scene.join("ground_truth_mpi");
    let out = tmp.path().join("o.png");

    // A missing layer of an MPI.
    let broken = tmp.path().join("broken_mpi");
    std::fs::create_dir_all(&broken).unwrap();
    for f in std::fs::read_dir(&gt).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, broken.join(f.file_name().unwrap())).unwrap();
    }
    std::fs::remove_file(broken.join("layer_003.png")).unwrap();
    fails_with(
        &deepview(&["render", "--mpi", s(&broken), "--out", s(&out)]),
        &["layer_003.png"],
    );

    // Zero planes.
    let json = std::fs::read_to_string(gt.join("mpi.json")).unwrap();
    let mut meta: serde_json::Value = serde_json::from_str(&json).unwrap();
    meta["depths"] = serde_json::json!([]);
    meta["layers"] = serde_json::json!([]);
    std::fs::write(broken.join("mpi.json"), meta.to_string()).unwrap();
    fails_with(
        &deepview(&["render", "--mpi", s(&broken), "--out", s(&out)]),
        &["mpi.json", "zero planes"],
    );
    fails_with(
        &deepview(&[
            "psv",
            "--data",
            s(&scene),
            "--planes",
            "0",
            "--out",
            s(&tmp.path().join("p")),
        ]),
        &["plane"],
    );

    // Malformed camera JSON, and a non-finite pose value.
    let cam = tmp.path().join("cam.json");
    std::fs::write(&cam, "{\"width\": 10,").unwrap();
    fails_with(
        &deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--camera",
            s(&cam),
            "--out",
            s(&out),
        ]),
        &["cam.json"],
    );
    std::fs::write(
        &cam,
        r#"{"width":10,"height":10,"fx":10,"fy":10,"cx":5,"cy":5,"camera_from_world":[1,0,0,1e999,0,1,0,0,0,0,1,0,0,0,0,1]}"#,
    )
    .unwrap();
    fails_with(
        &deepview(&[
            "render",
            "--mpi",
            s(&gt),
            "--camera",
            s(&cam),
            "--out",
            s(&out),
        ]),
        &["cam.json", "out of range"],
    );

    // A missing image, and an image of the wrong size.
    std::fs::remove_file(scene.join("input_Cam002.png")).unwrap();
    fails_with(
        &deepview(&[
            "psv",
            "--data",
            s(&scene),
            "--view",
            "2",
            "--out",
            s(&tmp.path().join("p")),
        ]),
        &["input_Cam002.png"],
    );
    deepview_image::write_png(
        &scene.join("input_Cam002.png"),
        &deepview_image::ImageF32::new(50, 20, 3),
    )
    .unwrap();
    fails_with(
        &deepview(&[
            "psv",
            "--data",
            s(&scene),
            "--view",
            "2",
            "--out",
            s(&tmp.path().join("p")),
        ]),
        &["input_Cam002.png"],
    );

    // A malformed npy (LLFF) and a malformed COLMAP model.
    let llff = tmp.path().join("llff");
    std::fs::create_dir_all(llff.join("images")).unwrap();
    std::fs::write(llff.join("poses_bounds.npy"), b"\x93NUMPY\x01\x00garbage").unwrap();
    fails_with(
        &deepview(&["info", "--data", s(&llff)]),
        &["poses_bounds.npy"],
    );
    let colmap = tmp.path().join("colmap");
    std::fs::create_dir_all(colmap.join("sparse/0")).unwrap();
    std::fs::write(
        colmap.join("sparse/0/cameras.txt"),
        "1 PINHOLE 10 10 not-a-number 5 5 5\n",
    )
    .unwrap();
    std::fs::write(colmap.join("sparse/0/images.txt"), "").unwrap();
    fails_with(&deepview(&["info", "--data", s(&colmap)]), &["cameras.txt"]);

    // Out-of-range view.
    deepview_image::write_png(
        &scene.join("input_Cam002.png"),
        &deepview_image::ImageF32::new(96, 64, 3),
    )
    .unwrap();
    fails_with(
        &deepview(&[
            "psv",
            "--data",
            s(&scene),
            "--view",
            "99",
            "--out",
            s(&tmp.path().join("p")),
        ]),
        &["out of range"],
    );
}

/// Renders `mpi` into view `view` of `scene` and returns the PSNR (dB) against that view's image.
fn psnr_of_render(tmp: &Path, mpi: &Path, scene: &Path, view: usize, truth: &Path) -> f64 {
    let out = tmp.join(format!("render_v{view}.png"));
    let o = deepview(&[
        "render",
        "--mpi",
        s(mpi),
        "--data",
        s(scene),
        "--view",
        &view.to_string(),
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a = deepview_image::read_image(&out, 3).unwrap();
    let b = deepview_image::read_image(truth, 3).unwrap();
    deepview_metrics::psnr(&a, &b).unwrap()
}

#[test]
fn baseline_mpis_render_held_out_and_input_views() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = synth_grid(tmp.path());

    // psv-mean from the four corners of the 3 x 3 grid, scored on the held-out centre view.
    let psv = tmp.path().join("psv_mpi");
    let o = deepview(&[
        "baseline",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--inputs",
        "0,2,6,8",
        "--planes",
        "12",
        "--out",
        s(&psv),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("psv_mpi") && stdout.contains("12 planes"),
        "{stdout}"
    );
    let mpi = deepview_mpi::read_mpi::<f32>(&psv).unwrap();
    assert_eq!(mpi.planes(), 12);
    let truth = scene.join("input_Cam004.png");
    let psnr = psnr_of_render(tmp.path(), &psv, &scene, 4, &truth);
    // For scale: one corner input reprojected through a single plane (`nearest` of view 0), and the exact
    // ground-truth MPI. Measured: psv-mean 19.5 dB, corner 13.0 dB, ground truth 58.5 dB.
    let corner = tmp.path().join("corner_mpi");
    let o = deepview(&[
        "baseline",
        "--data",
        s(&scene),
        "--method",
        "nearest",
        "--inputs",
        "0",
        "--out",
        s(&corner),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let psnr_corner = psnr_of_render(tmp.path(), &corner, &scene, 4, &truth);
    assert!(
        psnr > 17.0 && psnr > psnr_corner + 4.0,
        "psv-mean PSNR {psnr:.2} dB, corner view {psnr_corner:.2} dB"
    );

    // nearest with the default inputs (the 4 views nearest the grid's centre): the centre view itself, one
    // opaque plane in its camera, so rendering into that camera is an identity warp.
    let near = tmp.path().join("nearest_mpi");
    let o = deepview(&[
        "baseline",
        "--data",
        s(&scene),
        "--method",
        "nearest",
        "--out",
        s(&near),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("view 4"), "{stdout}");
    let mpi = deepview_mpi::read_mpi::<f32>(&near).unwrap();
    assert_eq!(mpi.planes(), 1);
    assert!(mpi.layers.chunks_exact(4).all(|t| t[3] == 1.0));
    // Measured: identical (infinite PSNR); 50 dB allows for the 8-bit round trip of the layer.
    let psnr = psnr_of_render(tmp.path(), &near, &scene, 4, &truth);
    assert!(psnr > 50.0, "nearest PSNR {psnr:.2} dB");

    // Bad flags fail cleanly.
    let bad = tmp.path().join("bad_mpi");
    fails_with(
        &deepview(&[
            "baseline",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--planes",
            "0",
            "--out",
            s(&bad),
        ]),
        &["plane", "got 0"],
    );
    fails_with(
        &deepview(&[
            "baseline",
            "--data",
            s(&scene),
            "--method",
            "nearest",
            "--inputs",
            "4,9",
            "--out",
            s(&bad),
        ]),
        &["view index 9 out of range", "9 views"],
    );
    assert!(!bad.exists());
}

/// Asserts success and returns stdout.
fn succeeds(out: &Output) -> String {
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Copies the files of `src` (recursively) into a new folder `dst`.
fn copy_dir(src: &Path, dst: &Path) -> PathBuf {
    std::fs::create_dir_all(dst).unwrap();
    for f in std::fs::read_dir(src).unwrap() {
        let f = f.unwrap().path();
        let to = dst.join(f.file_name().unwrap());
        if f.is_dir() {
            copy_dir(&f, &to);
        } else {
            std::fs::copy(&f, &to).unwrap();
        }
    }
    dst.to_path_buf()
}

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
fn bad_mpi_files_and_flags_give_clear_errors_and_exit_code_2() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    let grid = synth_grid(t);
    let gt = grid.join("ground_truth_mpi");
    let out = t.join("o.png");
    let render = |mpi: &Path| deepview(&["render", "--mpi", s(mpi), "--out", s(&out)]);
    succeeds(&render(&gt));

    // Truncated mpi.json.
    let bad = copy_dir(&gt, &t.join("mpi_truncated"));
    let text = std::fs::read_to_string(gt.join("mpi.json")).unwrap();
    std::fs::write(bad.join("mpi.json"), &text[..text.len() / 2]).unwrap();
    fails_with(&render(&bad), &["mpi.json", "not valid mpi.json", "EOF"]);

    // A layer PNG of the wrong size.
    let bad = copy_dir(&gt, &t.join("mpi_layer_size"));
    deepview_image::write_png(
        &bad.join("layer_002.png"),
        &deepview_image::ImageF32::new(50, 20, 4),
    )
    .unwrap();
    fails_with(&render(&bad), &["layer_002.png", "50x20", "mpi.json says"]);

    // Too few planes for a synthetic scene.
    for planes in ["0", "1"] {
        let o = deepview(&[
            "synth",
            "--out",
            s(&t.join(format!("synth_{planes}"))),
            "--grid",
            "2",
            "--width",
            "16",
            "--height",
            "16",
            "--planes",
            planes,
        ]);
        fails_with(&o, &["--planes", "at least 2", &format!("got {planes}")]);
    }
}

/// The README's first command: the whole pipeline on the built-in scene (the slow `optimize` baseline
/// skipped). Everything it announces is there, every method is scored, and the learned model beats the
/// nearest-view baseline. (On this noise-free synthetic scene `psv-mean`, the model's own starting point,
/// is hard to beat: colours agree exactly across views; BENCHMARKS.md has the figures.)
#[test]
fn demo_makes_everything_it_announces() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("demo");
    let stdout = succeeds(&deepview(&["demo", "--out", s(&out), "--no-optimize"]));
    for f in [
        "mpi/mpi.json",
        "mpi/layer_007.png",
        "scene/ground_truth_mpi/mpi.json",
        "novel_views/view_05.png",
        "novel_views/view_10_ground_truth.png",
        "depth/depth_color.png",
        "depth/depth_disparity16.png",
        "spiral.gif",
        "eval.json",
        "eval.md",
    ] {
        assert!(out.join(f).is_file(), "{f} missing; stdout: {stdout}");
    }
    // `--planes auto`: the count follows the grid's disparity and is recorded in mpi.json.
    let mpi = deepview_mpi::read_mpi::<f32>(&out.join("mpi")).unwrap();
    let (meta, _) = deepview_mpi::MpiMeta::read(&out.join("mpi")).unwrap();
    let rule = meta.planes_rule.expect("planes_rule in mpi.json");
    assert_eq!(rule.rule, "auto");
    let disparity = rule.max_disparity_px.unwrap();
    assert_eq!(
        mpi.planes(),
        ((disparity - 1e-9).ceil() as usize + 1).clamp(8, 256),
        "{disparity} px"
    );
    let reports: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).unwrap()).unwrap();
    let ssim = |method: &str| {
        reports
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["method"] == method)
            .unwrap_or_else(|| panic!("no {method} in eval.json"))["results"]["ssim"]
            .as_f64()
            .unwrap()
    };
    let (nearest, psv, learned) = (ssim("nearest"), ssim("psv-mean"), ssim("deepview"));
    assert!(
        learned > nearest && psv > nearest,
        "deepview {learned} vs nearest {nearest}, psv-mean {psv}"
    );
    // It says how to look at the MPI in the browser.
    let view_hint = format!("-- view --mpi {}", out.join("mpi").display());
    assert!(stdout.contains(&view_hint), "{view_hint:?} not in {stdout}");
}

/// Every command's `--help` ends with examples in the one scheme (`--data DIR` for a dataset, `--mpi DIR`,
/// `--out`); the old spellings are accepted but not shown.
#[test]
fn every_command_help_shows_examples_in_the_one_scheme() {
    let reads_data = [
        "synth", "psv", "render", "depth", "info", "eval", "optimize", "train", "infer", "baseline",
    ];
    let commands = [
        "demo",
        "synth",
        "psv",
        "render",
        "depth",
        "info",
        "view",
        "export-web",
        "export",
        "import",
        "eval",
        "optimize",
        "train",
        "infer",
        "export-weights",
        "baseline",
    ];
    for cmd in commands {
        let help = succeeds(&deepview(&[cmd, "--help"]));
        let at = help
            .find("Example")
            .unwrap_or_else(|| panic!("{cmd} --help has no example: {help}"));
        let examples = &help[at..];
        assert!(
            examples.contains(&format!("deepview {cmd} ")),
            "{cmd}: {examples}"
        );
        if reads_data.contains(&cmd) {
            assert!(
                examples.contains("--data ") && help.contains("--data"),
                "{cmd}: {help}"
            );
            assert!(
                help.contains("--downscale") && help.contains("--images"),
                "{cmd}"
            );
        }
        assert!(!help.contains("--scene"), "{cmd}: {help}");
    }
    for cmd in ["infer", "eval", "baseline", "optimize", "demo"] {
        let help = succeeds(&deepview(&[cmd, "--help"]));
        assert!(
            help.contains("[default: auto]") && help.contains("--max-memory"),
            "{cmd}: {help}"
        );
    }
}

/// `--planes auto` (the default): the count from the cameras' disparity, printed and stored in mpi.json;
/// clamped by the memory budget; an explicit count wins. Old spellings (bare folders) still work.
#[test]
fn planes_auto_follows_the_scene_and_old_spellings_still_work() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = synth_grid(tmp.path());
    let mpi = tmp.path().join("psv_auto");
    let o = deepview(&[
        "baseline",
        "--data",
        s(&scene),
        "--method",
        "psv-mean",
        "--inputs",
        "0,2,6,8",
        "--out",
        s(&mpi),
    ]);
    succeeds(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("planes: auto -> ") && err.contains("memory budget: "),
        "{err}"
    );
    let (meta, _) = deepview_mpi::MpiMeta::read(&mpi).unwrap();
    let rule = meta.planes_rule.unwrap();
    let disparity = rule.max_disparity_px.unwrap();
    assert!(disparity > 1.0, "{disparity}");
    assert!([0, 2, 6, 8].contains(&rule.view.unwrap()));
    let planes = ((disparity - 1e-9).ceil() as usize + 1).clamp(8, 256);
    assert_eq!(meta.depths.len(), planes);
    assert!(err.contains(&format!("auto -> {planes} ")), "{err}");

    // A budget too small even for the smallest count is refused, naming the budget that fits; with that
    // budget, fewer planes than the rule's, and mpi.json says why.
    let small = tmp.path().join("psv_small");
    let run = |budget: &str| {
        deepview(&[
            "baseline",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--inputs",
            "0,2,6,8",
            "--max-memory",
            budget,
            "--out",
            s(&small),
        ])
    };
    let o = run("1MiB");
    fails_with(&o, &["8 planes", "--max-memory"]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    let least = err
        .rsplit("--max-memory ")
        .next()
        .unwrap()
        .trim()
        .to_string();
    succeeds(&run(&least));
    let (meta, _) = deepview_mpi::MpiMeta::read(&small).unwrap();
    assert!(meta.depths.len() >= 8 && meta.depths.len() < planes);
    assert_eq!(
        meta.planes_rule.unwrap().limited_by.as_deref(),
        Some("memory budget")
    );
    fails_with(
        &deepview(&[
            "baseline",
            "--data",
            s(&scene),
            "--method",
            "psv-mean",
            "--planes",
            "weights",
            "--out",
            s(&small),
        ]),
        &["--planes weights needs a learned model"],
    );

    // The old spellings: a bare dataset folder, a bare MPI folder and output.
    let old = tmp.path().join("psv_old");
    succeeds(&deepview(&[
        "baseline",
        s(&scene),
        "--method",
        "psv-mean",
        "--planes",
        "6",
        "--out",
        s(&old),
    ]));
    assert_eq!(deepview_mpi::read_mpi::<f32>(&old).unwrap().planes(), 6);
    let (meta, _) = deepview_mpi::MpiMeta::read(&old).unwrap();
    assert_eq!(meta.planes_rule.unwrap().rule, "explicit");
    let llff_old = tmp.path().join("llff_old");
    let llff_new = tmp.path().join("llff_new");
    succeeds(&deepview(&[
        "export",
        s(&old),
        s(&llff_old),
        "--format",
        "llff",
    ]));
    succeeds(&deepview(&[
        "export",
        "--mpi",
        s(&old),
        "--out",
        s(&llff_new),
        "--format",
        "llff",
    ]));
    assert_eq!(
        std::fs::read(llff_old.join("mpi.b")).unwrap(),
        std::fs::read(llff_new.join("mpi.b")).unwrap()
    );
    let back = tmp.path().join("back");
    succeeds(&deepview(&[
        "import",
        "--mpi",
        s(&llff_new),
        "--out",
        s(&back),
    ]));
    assert_eq!(deepview_mpi::read_mpi::<f32>(&back).unwrap().planes(), 6);
    // Both spellings at once is an error.
    fails_with(
        &deepview(&["info", s(&scene), "--data", s(&scene)]),
        &["cannot be used with"],
    );
}
