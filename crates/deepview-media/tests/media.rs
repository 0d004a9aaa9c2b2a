//! Camera paths, camera_path.json and videos on small MPIs built here.

use deepview_geometry::{
    Camera, DMat3, DVec2, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths,
};
use deepview_media::camera_path::{
    camera_path_file, parse_camera_path, read_camera_path, write_camera_path,
};
use deepview_media::path::{PathKind, PathSpec, Radius, camera_path, spiral};
use deepview_media::render_video;
use deepview_media::video::{FrameSink, Mp4Sink};
use deepview_mpi::Mpi;
use std::path::Path;

fn reference() -> Camera {
    let r = DMat3::from_rotation_x(0.1) * DMat3::from_rotation_y(-0.2);
    Camera::new(
        70,
        45,
        Intrinsics::new(60.0, 61.0, 35.5, 22.0),
        Pose::from_center(r, DVec3::new(0.5, -1.0, 2.0)),
    )
}

/// A test MPI: 5 planes with pseudo-random texels, the upper-left block of every plane fully transparent
/// and the near plane transparent except for one square.
fn test_mpi() -> Mpi {
    let cam = reference();
    let depths = plane_depths(2.0, 20.0, 5, PlaneSpacing::InverseDepth).unwrap();
    let mut mpi = Mpi::transparent(cam, depths);
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut s = 12345u32;
    for d in 0..5 {
        let plane = mpi.plane_mut(d);
        for y in 0..h {
            for x in 0..w {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                let transparent = (x < 33 && y < 33) || (d == 4 && !(40..50).contains(&x));
                let a = if transparent {
                    0.0
                } else {
                    ((s % 251) as f32 / 250.0).max(0.05)
                };
                let p = &mut plane[(y * w + x) * 4..(y * w + x) * 4 + 4];
                p[3] = a;
                for k in 0..3 {
                    p[k] = (((s >> (8 * k)) % 256) as f32 / 255.0) * a;
                }
            }
        }
    }
    mpi
}

fn angle_between(a: &DMat3, b: &DMat3) -> f64 {
    let r = *a * b.transpose();
    ((r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
}

#[test]
fn spiral_is_continuous_closed_and_within_the_valid_range() {
    let cam = reference();
    let depths = [20.0, 8.0, 2.0];
    let frames = 120;
    let r = 0.05;
    let cams = spiral(&cam, &depths, r, frames).unwrap();
    assert_eq!(cams.len(), frames);
    let radius = r * 2.0;
    // Path length of two turns plus the forward motion, over frames: a bound on consecutive steps.
    let max_step = 2.0 * std::f64::consts::TAU * radius * 1.2 / frames as f64;
    for i in 0..frames {
        let (a, b) = (&cams[i], &cams[(i + 1) % frames]);
        let step = (a.center() - b.center()).length();
        assert!(
            step < max_step && step > 0.0,
            "frame {i}: step {step} (max {max_step})"
        );
        assert!(
            angle_between(&a.pose.rotation, &b.pose.rotation) < 0.01,
            "frame {i}"
        );
        assert!((a.center() - cam.center()).length() <= radius * 1.2);
        assert!(a.pose.validate().is_ok());
        assert_eq!(a.intrinsics, cam.intrinsics);
    }
    // Every camera looks at the focus point (default: middle of the disparity range) through its principal point.
    let focus = 2.0 / (1.0 / 20.0 + 1.0 / 2.0);
    let p = cam.unproject(DVec2::new(cam.intrinsics.cx, cam.intrinsics.cy), focus);
    for c in &cams {
        let q = c.project(p).unwrap();
        assert!(
            (q - DVec2::new(c.intrinsics.cx, c.intrinsics.cy)).length() < 1e-9,
            "{q}"
        );
    }
    // Swing stays on the reference x axis; circle stays in the reference image plane.
    for (kind, axis) in [(PathKind::Swing, 0), (PathKind::Circle, 1)] {
        let spec = PathSpec {
            kind,
            frames: 16,
            radius: Radius::Scene(0.1),
            focus_depth: Some(5.0),
        };
        for c in camera_path(&cam, &depths, &spec).unwrap() {
            let off = cam.pose.transform_point(c.center());
            assert!(off.z.abs() < 1e-12, "{off}");
            if axis == 0 {
                assert!(off.y.abs() < 1e-12, "{off}");
            }
            assert!(off.length() <= 0.1 + 1e-12);
        }
    }
    // Too far from the reference: refused with the reason.
    let e = spiral(&cam, &depths, 0.5, 10).unwrap_err().to_string();
    assert!(e.contains("valid"), "{e}");
    assert!(spiral(&cam, &depths, 0.05, 0).is_err());
    assert!("zigzag".parse::<PathKind>().is_err());
}

#[test]
fn camera_path_json_round_trip_and_axes() {
    let dir = tempfile::tempdir().unwrap();
    // Square pixels, centred principal point: representable exactly.
    let base = Camera::new(64, 48, Intrinsics::centred(50.0, 64, 48), reference().pose);
    let cams = spiral(&base, &[20.0, 2.0], 0.05, 12).unwrap();
    let p = dir.path().join("camera_path.json");
    write_camera_path(&p, &cams, 2.0).unwrap();
    let back = read_camera_path(&p).unwrap();
    assert_eq!(back.cameras.len(), 12);
    assert!((back.seconds - 2.0).abs() < 1e-12 && (back.fps() - 6.0).abs() < 1e-12);
    for (a, b) in cams.iter().zip(&back.cameras) {
        assert!(a.pose.rotation.abs_diff_eq(b.pose.rotation, 1e-12));
        assert!(a.pose.translation.abs_diff_eq(b.pose.translation, 1e-12));
        let (ka, kb) = (a.intrinsics, b.intrinsics);
        assert!(
            (ka.fx - kb.fx).abs() < 1e-9
                && (ka.fy - kb.fy).abs() < 1e-9
                && ka.cx == kb.cx
                && ka.cy == kb.cy
        );
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    assert_eq!(json["render_width"], 64);
    assert_eq!(
        json["camera_path"][0]["camera_to_world"]
            .as_array()
            .unwrap()
            .len(),
        16
    );

    // Known case written by hand: an OpenGL camera at (2, 0, 0) rotated +90 deg about y (right = -z,
    // up = +y, back = +x), so it looks along -x at the origin; vertical fov 2 atan(5/10) on a 10x10 image
    // gives f = 10.
    let fov = (2.0 * (0.5f64).atan()).to_degrees();
    let text = format!(
        r#"{{"render_width": 10, "render_height": 10, "seconds": 1,
            "camera_path": [{{"camera_to_world": [0,0,1,2, 0,1,0,0, -1,0,0,0, 0,0,0,1], "fov": {fov}}}]}}"#
    );
    let cp = parse_camera_path(&text, Path::new("known.json")).unwrap();
    let c = cp.cameras[0];
    assert!((c.intrinsics.fy - 10.0).abs() < 1e-9 && (c.intrinsics.fx - 10.0).abs() < 1e-9);
    let near = |p: DVec3, expect: DVec2| {
        let q = c.project(p).unwrap();
        assert!(
            (q - expect).length() < 1e-9,
            "{p} -> {q}, expected {expect}"
        );
    };
    near(DVec3::ZERO, DVec2::new(5.0, 5.0));
    near(DVec3::new(0.0, 1.0, 0.0), DVec2::new(5.0, 0.0)); // world up is image up
    near(DVec3::new(0.0, 0.0, -1.0), DVec2::new(10.0, 5.0)); // camera right is world -z
    assert!(c.project(DVec3::new(4.0, 0.0, 0.0)).is_none()); // behind the camera
    // Writing it back gives the same numbers.
    let f = camera_path_file(&cp.cameras, 1.0).unwrap();
    let expect = [
        0.0, 0.0, 1.0, 2.0, 0.0, 1.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ];
    for (a, b) in f.camera_path[0].camera_to_world.iter().zip(expect) {
        assert!((a - b).abs() < 1e-12);
    }
    assert!((f.camera_path[0].fov - fov).abs() < 1e-9);
}

#[test]
fn malformed_camera_path_files_give_clear_errors() {
    let good_c2w = "[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]";
    let cases = [
        ("{not json".to_string(), "not valid JSON"),
        (r#"{"render_width": 10, "seconds": 1, "camera_path": []}"#.to_string(), "render_height"),
        (r#"{"render_width":10,"render_height":10,"seconds":1,"camera_path":[]}"#.to_string(), "empty"),
        (r#"{"render_width":10,"render_height":10,"seconds":1,"camera_path":[{"camera_to_world":[1,0,0],"fov":50}]}"#.to_string(), "has 3 numbers"),
        (format!(r#"{{"render_width":10,"render_height":10,"seconds":1,"camera_path":[{{"camera_to_world":{good_c2w},"fov":0}}]}}"#), "fov"),
        (format!(r#"{{"render_width":10,"render_height":10,"seconds":0,"camera_path":[{{"camera_to_world":{good_c2w},"fov":50}}]}}"#), "seconds"),
        (r#"{"render_width":10,"render_height":10,"seconds":1,"camera_path":[{"camera_to_world":[2,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1],"fov":50}]}"#.to_string(), "camera_path[0].camera_to_world"),
        (r#"{"render_width":10,"render_height":10,"seconds":1,"camera_path":[{"camera_to_world":[1,0,0,0, 0,1,0,0, 0,0,1,0, 1,0,0,1],"fov":50}]}"#.to_string(), "last row"),
        (format!(r#"{{"camera_type":"fisheye","render_width":10,"render_height":10,"seconds":1,"camera_path":[{{"camera_to_world":{good_c2w},"fov":50}}]}}"#), "fisheye"),
    ];
    for (text, needle) in cases {
        let e = parse_camera_path(&text, Path::new("bad_path.json"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("bad_path.json") && e.contains(needle),
            "{needle}: {e}"
        );
    }
    let e = read_camera_path(Path::new("/nonexistent/camera_path.json"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/camera_path.json"), "{e}");
}

#[test]
fn gif_and_png_frames_are_written_and_decodable() {
    let dir = tempfile::tempdir().unwrap();
    let mpi = test_mpi();
    let cams = spiral(&mpi.camera, &mpi.depths, 0.05, 7).unwrap();
    let u8mpi = mpi.to_u8();
    let gif = dir.path().join("path.gif");
    let rep = render_video(&u8mpi, &cams, &gif, 10.0, &mut |_, _| {}).unwrap();
    assert_eq!(rep.frames, 7);
    use image::AnimationDecoder;
    let dec = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
        std::fs::File::open(&gif).unwrap(),
    ))
    .unwrap();
    let frames = dec.into_frames().collect_frames().unwrap();
    assert_eq!(frames.len(), 7);
    assert_eq!(frames[0].buffer().dimensions(), (70, 45));
    assert_eq!(frames[0].delay().numer_denom_ms(), (100, 1));
    // The first GIF frame resembles the native render of the first camera (GIF palette: loose bound).
    let native = deepview_mpi::render(&u8mpi, &cams[0]);
    let mut err = 0.0f64;
    for (g, n) in frames[0].buffer().pixels().zip(native.data.chunks_exact(4)) {
        for k in 0..3 {
            err += (g[k] as f64 / 255.0 - n[k] as f64).abs();
        }
    }
    assert!(
        err / (70.0 * 45.0 * 3.0) < 0.05,
        "mean abs error {}",
        err / (70.0 * 45.0 * 3.0)
    );

    // At 30 and 15 frames/s (3.33 and 6.67 cs a frame) the animation lasts frames / fps to the
    // centisecond (a fixed rounded delay played 30 at 33 frames/s, 15 at 16.7); over 50 frames/s,
    // which browsers slow to 10, is refused.
    for (fps, total_cs) in [(30.0, 23), (15.0, 47)] {
        let g = dir.path().join(format!("at{fps}.gif"));
        render_video(&u8mpi, &cams, &g, fps, &mut |_, _| {}).unwrap();
        let dec = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
            std::fs::File::open(&g).unwrap(),
        ))
        .unwrap();
        let ms: u32 = dec
            .into_frames()
            .collect_frames()
            .unwrap()
            .iter()
            .map(|f| {
                let (n, d) = f.delay().numer_denom_ms();
                n / d
            })
            .sum();
        assert_eq!(ms, total_cs * 10, "{fps} frames/s");
    }
    let e = render_video(
        &u8mpi,
        &cams,
        &dir.path().join("fast.gif"),
        60.0,
        &mut |_, _| {},
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("0.0016 to 50 frames per second"), "{e}");
    assert!(!dir.path().join("fast.gif").exists());

    let frames_dir = dir.path().join("frames");
    render_video(&u8mpi, &cams[..3], &frames_dir, 10.0, &mut |_, _| {}).unwrap();
    let names: Vec<_> = (0..3)
        .map(|i| frames_dir.join(format!("frame_{i:05}.png")))
        .collect();
    for n in &names {
        assert_eq!(image::image_dimensions(n).unwrap(), (70, 45));
    }
    assert_eq!(
        std::fs::read_dir(&frames_dir).unwrap().count(),
        3,
        "no temporary files left"
    );
}

#[test]
fn missing_ffmpeg_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let e = Mp4Sink::new(
        &dir.path().join("v.mp4"),
        64,
        48,
        30.0,
        "/nonexistent/ffmpeg-for-test",
    )
    .err()
    .unwrap();
    let msg = e.to_string();
    assert!(
        msg.contains("not found") && msg.contains("v.mp4") && msg.contains(".gif"),
        "{msg}"
    );
    let e = Mp4Sink::new(&dir.path().join("v.mp4"), 1, 48, 30.0, "ffmpeg")
        .err()
        .unwrap();
    assert!(e.to_string().contains("2x2"), "{e}");
    // No temporary left by the failed starts.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    // A program that takes every frame and exits 0 without writing (a stand-in for ffmpeg) is an
    // error, not an empty "video" (it was renamed into place as one).
    let tools = tempfile::tempdir().unwrap();
    let fake = tools.path().join("fake-ffmpeg");
    std::fs::write(&fake, "#!/bin/sh\ncat > /dev/null\n").unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let out = dir.path().join("v.mp4");
    let mut sink: Box<dyn FrameSink> =
        Box::new(Mp4Sink::new(&out, 4, 4, 10.0, fake.to_str().unwrap()).unwrap());
    sink.push(&[0; 4 * 4 * 3]).unwrap();
    let e = sink.finish().err().unwrap().to_string();
    assert!(e.contains("wrote nothing") && e.contains("v.mp4"), "{e}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn mp4_through_ffmpeg_when_available() {
    if std::process::Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_err()
    {
        eprintln!(
            "ffmpeg not on PATH: MP4 writing not exercised (missing_ffmpeg_is_a_clear_error covers the message)"
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.mp4");
    let mut sink: Box<dyn FrameSink> =
        Box::new(Mp4Sink::new(&out, 64, 48, 10.0, "ffmpeg").unwrap());
    for i in 0..5u8 {
        sink.push(&vec![i * 40; 64 * 48 * 3]).unwrap();
    }
    sink.finish().unwrap();
    assert!(std::fs::metadata(&out).unwrap().len() > 100);
    // An odd size (an MPI of 707x505 on the 1.25x grid) is written too, its last column and row cropped.
    let odd = dir.path().join("odd.mp4");
    let mut sink: Box<dyn FrameSink> =
        Box::new(Mp4Sink::new(&odd, 65, 49, 10.0, "ffmpeg").unwrap());
    for i in 0..3u8 {
        sink.push(&vec![i * 40; 65 * 49 * 3]).unwrap();
    }
    sink.finish().unwrap();
    let probe = std::process::Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-show_entries",
            "stream=width,height",
            "-of",
            "csv=p=0",
        ])
        .arg(&odd)
        .output();
    if let Some(p) = probe.ok().filter(|p| p.status.success()) {
        assert_eq!(String::from_utf8_lossy(&p.stdout).trim(), "64,48");
    }
}
