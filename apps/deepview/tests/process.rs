//! `deepview process` on real photos (fern's `images_8` without their poses), run with Debian's COLMAP.
//! COLMAP runs once for fern (shared by the tests through a `OnceLock`), and one run at a time.

mod common;

use common::{deepview, fails_with, s};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

static COLMAP: Mutex<()> = Mutex::new(());

fn have_colmap() -> bool {
    Command::new("colmap").arg("help").output().is_ok()
}

/// Copy the photos only (no poses) of `src` to a new folder.
fn bare_photos(src: &Path, dst: &Path) -> PathBuf {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let p = e.unwrap().path();
        let ext = p.extension().unwrap_or_default().to_ascii_lowercase();
        if ext == "png" || ext == "jpg" || ext == "jpeg" {
            std::fs::copy(&p, dst.join(p.file_name().unwrap())).unwrap();
        }
    }
    dst.into()
}

struct Fern {
    _tmp: tempfile::TempDir,
    scene: PathBuf,
    output: Output,
    took: Duration,
}

fn fern() -> &'static Fern {
    static FERN: OnceLock<Fern> = OnceLock::new();
    FERN.get_or_init(|| {
        let _one = COLMAP.lock().unwrap_or_else(|e| e.into_inner());
        let tmp = tempfile::tempdir().unwrap();
        let fern = deepview_data::data_dir().join("llff/fern/images_8");
        assert!(fern.is_dir(), "shared data missing (set DEEPVIEW_DATA)");
        let photos = bare_photos(&fern, &tmp.path().join("photos"));
        let scene = tmp.path().join("fern_scene");
        let t = Instant::now();
        let output = deepview(&["process", "--data", s(&photos), "--out", s(&scene)]);
        let took = t.elapsed();
        eprintln!(
            "deepview process on fern images_8 took {:.1} s:\n{}{}",
            took.as_secs_f64(),
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
        Fern {
            _tmp: tmp,
            scene,
            output,
            took,
        }
    })
}

fn angle_deg(r: deepview_geometry::DMat3) -> f64 {
    let c = ((r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0);
    c.acos().to_degrees()
}

#[test]
fn process_fern_photos_recovers_llff_relative_rotations() {
    assert!(
        have_colmap(),
        "colmap is not installed (apt-get install colmap)"
    );
    let f = fern();
    assert!(
        f.output.status.success(),
        "{}",
        String::from_utf8_lossy(&f.output.stderr)
    );
    let stdout = String::from_utf8_lossy(&f.output.stdout);
    assert!(stdout.contains("20 of 20 images registered"), "{stdout}");
    // Each stage's progress goes to stderr, beside any warning or error.
    let stderr = String::from_utf8_lossy(&f.output.stderr);
    for stage in ["feature extraction", "matching", "mapping", "undistortion"] {
        assert!(stderr.contains(stage), "{stage} not in {stderr}");
    }
    assert!(f.scene.join("colmap.log").is_file());
    assert!(f.scene.join("sparse/0/cameras.bin").is_file());
    assert!(!f.scene.with_file_name("fern_scene.incomplete").exists());
    assert!(f.took < Duration::from_secs(600), "{:?}", f.took);

    let ours = deepview_data::load_scene(&f.scene, &Default::default()).unwrap();
    assert_eq!(ours.format, deepview_data::SceneFormat::Colmap);
    ours.check_images().unwrap();
    let (near, far) = ours.near_far().unwrap();
    assert!(near > 0.0 && far > near);
    let fern = deepview_data::data_dir().join("llff/fern");
    let llff = deepview_data::load_scene(
        &fern,
        &deepview_data::LoadOptions {
            images: Some("images_8".into()),
            ..Default::default()
        },
    )
    .unwrap();
    // Images map by file name: COLMAP names them image000.png, LLFF views are image000.
    let pairs: Vec<_> = ours
        .views
        .iter()
        .map(|v| {
            let stem = v.name.trim_end_matches(".png");
            let l = llff.views.iter().find(|l| l.name == stem).unwrap();
            (v.camera.pose.rotation, l.camera.pose.rotation)
        })
        .collect();
    assert_eq!(pairs.len(), 20);
    let (mut worst, mut sum, mut n) = (0.0f64, 0.0, 0);
    for i in 0..pairs.len() {
        for j in i + 1..pairs.len() {
            let ours = pairs[i].0 * pairs[j].0.transpose();
            let theirs = pairs[i].1 * pairs[j].1.transpose();
            let e = angle_deg(ours * theirs.transpose());
            worst = worst.max(e);
            sum += e;
            n += 1;
        }
    }
    eprintln!(
        "relative rotation error over {n} pairs: max {worst:.4} deg, mean {:.4} deg",
        sum / n as f64
    );
    assert!(worst < 1.0, "max relative rotation error {worst} deg");
}

#[test]
fn processed_fern_infers_and_renders() {
    assert!(
        have_colmap(),
        "colmap is not installed (apt-get install colmap)"
    );
    let f = fern();
    assert!(
        f.output.status.success(),
        "{}",
        String::from_utf8_lossy(&f.output.stderr)
    );
    let tmp = tempfile::tempdir().unwrap();
    let mpi = tmp.path().join("mpi");
    let o = deepview(&[
        "infer",
        "--data",
        s(&f.scene),
        "--planes",
        "8",
        "--out",
        s(&mpi),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let png = tmp.path().join("view3.png");
    let o = deepview(&[
        "render",
        "--mpi",
        s(&mpi),
        "--data",
        s(&f.scene),
        "--view",
        "3",
        "--out",
        s(&png),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scene = deepview_data::load_scene(&f.scene, &Default::default()).unwrap();
    let img = deepview_image::read_image(&png, 3).unwrap();
    let cam = scene.views[3].camera;
    assert_eq!((img.width, img.height), (cam.width, cam.height));
    // The render of an input-adjacent view resembles the photo (not a blank or misaligned image).
    let truth = scene.load_image(3).unwrap();
    let mse: f64 = img
        .data
        .iter()
        .zip(&truth.data)
        .map(|(a, b)| ((a - b) as f64).powi(2))
        .sum::<f64>()
        / img.data.len() as f64;
    let psnr = -10.0 * mse.log10();
    eprintln!("render of processed fern view 3: PSNR {psnr:.2} dB");
    assert!(psnr > 15.0, "PSNR {psnr}");
}

fn noise_png(path: &Path, seed: u32) {
    let (w, h) = (160u32, 120u32);
    let mut x = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
    let mut data = Vec::with_capacity((w * h * 3) as usize);
    for _ in 0..w * h * 3 {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        data.push((x >> 24) as f32 / 255.0);
    }
    let img = deepview_image::ImageF32::from_data(w, h, 3, data).unwrap();
    deepview_image::write_png(path, &img).unwrap();
}

#[test]
fn unrelated_images_fail_clearly_with_exit_code_2() {
    assert!(
        have_colmap(),
        "colmap is not installed (apt-get install colmap)"
    );
    let _one = COLMAP.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let photos = tmp.path().join("noise");
    std::fs::create_dir(&photos).unwrap();
    for i in 0..4 {
        noise_png(&photos.join(format!("noise{i}.png")), i + 1);
    }
    let out = tmp.path().join("scene");
    let o = deepview(&["process", "--data", s(&photos), "--out", s(&out)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        err.contains("registered 0 of 4 images") && err.contains("noise0.png"),
        "{err}"
    );
    assert!(!out.exists(), "no scene is written");
    // The working folder is removed; the log is kept beside, for inspection, and named.
    assert!(err.contains("scene.colmap.log"), "{err}");
    assert!(tmp.path().join("scene.colmap.log").is_file());
    assert!(!tmp.path().join("scene.incomplete").exists());
    // A file of that name is never replaced (it may be the user's, or an earlier run's log): the next
    // failure keeps its log under the first free name.
    let first = tmp.path().join("scene.colmap.log");
    std::fs::write(&first, b"my own notes").unwrap();
    let o = deepview(&["process", "--data", s(&photos), "--out", s(&out)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(std::fs::read(&first).unwrap(), b"my own notes");
    assert!(err.contains("scene.colmap.2.log"), "{err}");
    let second = std::fs::read_to_string(tmp.path().join("scene.colmap.2.log")).unwrap();
    assert!(second.len() > 100, "COLMAP's log: {second}");
}

#[test]
fn missing_colmap_or_photos_give_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let photos = tmp.path().join("photos");
    std::fs::create_dir(&photos).unwrap();
    noise_png(&photos.join("a.png"), 1);
    noise_png(&photos.join("b.png"), 2);
    let out = tmp.path().join("scene");
    let o = deepview(&[
        "process",
        "--data",
        s(&photos),
        "--out",
        s(&out),
        "--colmap",
        "/nonexistent/colmap",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("/nonexistent/colmap") && err.contains("apt-get install colmap"),
        "{err}"
    );
    // No colmap on PATH.
    let o = Command::new(env!("CARGO_BIN_EXE_deepview"))
        .args(["process", "--data", s(&photos), "--out", s(&out)])
        .env("PATH", tmp.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("apt-get install colmap"), "{err}");
    assert!(!out.exists());
    // Photos that are not images are named before COLMAP runs (it aborted with too few left).
    let bad = tmp.path().join("bad");
    std::fs::create_dir(&bad).unwrap();
    std::fs::write(bad.join("x.jpg"), "not a photo").unwrap();
    std::fs::write(bad.join("y.png"), b"\x89PNG\r\n\x1a\n").unwrap();
    noise_png(&bad.join("z.png"), 3);
    let o = deepview(&["process", "--data", s(&bad), "--out", s(&out)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("only 1 of 3 photos") && err.contains("x.jpg") && err.contains("y.png"),
        "{err}"
    );
    assert!(!err.contains("z.png"), "{err}");
    assert!(!out.exists());
    // A JPEG named .png is a photo (its format is read from its content, as COLMAP reads it): with it
    // two photos are left, and the run goes on to look for COLMAP.
    let img = deepview_image::ImageF32::from_data(16, 12, 3, vec![0.5; 16 * 12 * 3]).unwrap();
    deepview_image::write_jpeg(&bad.join("w.png"), &img, 90).unwrap();
    fails_with(
        &deepview(&[
            "process",
            "--data",
            s(&bad),
            "--out",
            s(&out),
            "--colmap",
            "/nonexistent/colmap",
        ]),
        &["/nonexistent/colmap"],
    );
    // A folder without photos, and an existing output folder.
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    std::fs::write(empty.join("notes.txt"), "not a photo").unwrap();
    let o = deepview(&["process", "--data", s(&empty), "--out", s(&out)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("no images found") && err.contains("empty"),
        "{err}"
    );
    // Only an iPhone's HEIC photos: named, with what to do.
    std::fs::write(empty.join("IMG_0001.HEIC"), b"\0\0\0\x18ftypheic").unwrap();
    fails_with(
        &deepview(&["process", "--data", s(&empty), "--out", s(&out)]),
        &[
            "no images found",
            "skipped 1 photo in formats deepview does not read: IMG_0001.HEIC",
            "convert them to JPEG first",
        ],
    );
    // A folder of photos given to a command that needs a scene: the hint names `process`.
    fails_with(
        &deepview(&["infer", "--data", s(&bad), "--out", s(&out)]),
        &[
            "cannot detect the dataset format",
            "deepview process --data",
        ],
    );
    // --fps with photos: refused, not ignored.
    fails_with(
        &deepview(&[
            "process",
            "--data",
            s(&photos),
            "--fps",
            "3",
            "--out",
            s(&out),
        ]),
        &["--fps applies to frames taken from a --video"],
    );
    let o = deepview(&["process", "--data", s(&photos), "--out", s(&empty)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("already exists"), "{err}");
    assert!(empty.join("notes.txt").is_file());
}

/// SIGTERM to `deepview process` stops the COLMAP it started (issue 28: a rerun used to start a second
/// COLMAP on the same database). A stand-in `colmap` records its pid and waits; the test waits for that
/// file (an event, not a fixed sleep), signals deepview, and then for the stand-in to be gone.
#[test]
fn sigterm_to_process_stops_colmap() {
    use std::os::unix::fs::PermissionsExt;
    let tmp = tempfile::tempdir().unwrap();
    let photos = tmp.path().join("photos");
    std::fs::create_dir(&photos).unwrap();
    noise_png(&photos.join("a.png"), 1);
    noise_png(&photos.join("b.png"), 2);
    let pid_file = tmp.path().join("colmap.pid");
    let fake = tmp.path().join("colmap");
    std::fs::write(
        &fake,
        format!(
            "#!/bin/sh\ncase \"$1\" in help) echo COLMAP; exit 0;; esac\necho $$ > {p}.tmp && mv {p}.tmp {p}\nexec sleep 120\n",
            p = s(&pid_file)
        ),
    )
    .unwrap();
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let out = tmp.path().join("scene");
    let mut child = Command::new(env!("CARGO_BIN_EXE_deepview"))
        .args([
            "process",
            "--data",
            s(&photos),
            "--out",
            s(&out),
            "--colmap",
            s(&fake),
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !pid_file.is_file() {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the stand-in colmap never started"
        );
        if let Some(st) = child.try_wait().unwrap() {
            let mut err = String::new();
            std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
            panic!("deepview process ended first ({st}): {err}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let colmap_pid = std::fs::read_to_string(&pid_file)
        .unwrap()
        .trim()
        .to_string();
    // SAFETY: kill(2) on the pid of a child this test started.
    unsafe {
        libc::kill(child.id() as i32, libc::SIGTERM);
    }
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(143), "{status}");
    let proc_dir = Path::new("/proc").join(&colmap_pid);
    let start = Instant::now();
    // Gone, or a zombie waiting for its new parent to reap it.
    let alive = || {
        std::fs::read_to_string(proc_dir.join("stat")).is_ok_and(|st| {
            st.rsplit(')')
                .next()
                .is_some_and(|r| !r.trim_start().starts_with('Z'))
        })
    };
    while alive() {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "colmap (pid {colmap_pid}) outlived deepview process"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(!out.exists(), "a stopped process left {}", out.display());
    assert!(
        !tmp.path().join("scene.incomplete").exists(),
        "a stopped process left its working folder"
    );
}

/// A video too short for its frame rate stops before COLMAP with the video and `--fps` named, and leaves
/// nothing behind: no scene, no working folder, no `OUT.colmap.log` (the error names no log).
#[test]
fn a_video_with_too_few_frames_leaves_nothing_behind() {
    let tmp = tempfile::tempdir().unwrap();
    let video = tmp.path().join("clip.mp4");
    let made = Command::new("ffmpeg")
        .args(["-hide_banner", "-loglevel", "error", "-f", "lavfi", "-i"])
        .arg("testsrc=duration=1:size=64x48:rate=5")
        .args(["-pix_fmt", "yuv420p"])
        .arg(&video)
        .status()
        .expect("ffmpeg runs (CI installs it)");
    assert!(made.success());
    let out = tmp.path().join("scene");
    let o = deepview(&[
        "process",
        "--video",
        s(&video),
        "--fps",
        "0.5",
        "--out",
        s(&out),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("clip.mp4") && err.contains("extracted at 0.5 frames per second"),
        "{err}"
    );
    let left: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(left, ["clip.mp4"], "{err}");
}
