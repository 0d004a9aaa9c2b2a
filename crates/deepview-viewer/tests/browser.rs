//! The web viewer in headless Chromium (SwiftShader WebGL2), driven over the DevTools protocol.
//!
//! Runs in CI (not ignored): it fails with a clear message when `/usr/bin/chromium` (Debian package
//! `chromium`) is missing. Set `DEEPVIEW_CHROMIUM` to use another browser binary.
//!
//! - a fixed camera (`?camera=`) screenshot matches `deepview_mpi::render` for the same camera (PSNR >= 35 dB),
//!   for the folder format and for the compact export;
//! - the page's measured frame rate for a 32-plane 504x378 MPI is printed (`window.deepviewStats.fps`, from
//!   requestAnimationFrame, and with `bench=sync` the mean draw + GPU-wait time `syncMs`).

use deepview_geometry::{Camera, DMat3, DVec3, Intrinsics, PlaneSpacing, Pose, plane_depths};
use deepview_image::ImageF32;
use deepview_mpi::{Mpi, read_mpi, render, write_mpi};
use deepview_viewer::Server;
use serde_json::{Value, json};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

// ---------------------------------------------------------------- test scene

/// 32 planes of 504x378: soft discs of colour at different depths over an opaque far plane, with partly
/// transparent texels and fully transparent regions.
fn scene() -> Mpi {
    let (w, h, d) = (504u32, 378u32, 32usize);
    let cam = Camera::new(
        w,
        h,
        Intrinsics::new(400.0, 405.0, 250.3, 190.1),
        Pose::IDENTITY,
    );
    let depths = plane_depths(1.5, 40.0, d, PlaneSpacing::InverseDepth).unwrap();
    let mut mpi = Mpi::transparent(cam, depths);
    for p in 0..d {
        let plane = mpi.plane_mut(p);
        for y in 0..h as usize {
            for x in 0..w as usize {
                let (fx, fy) = (x as f32 / w as f32, y as f32 / h as f32);
                let (a, rgb) = if p == 0 {
                    // Far plane: an opaque high-frequency checker and gradient (tests sampling).
                    let check = ((x / 7 + y / 5) % 2) as f32;
                    (1.0, [0.2 + 0.6 * fx, 0.3 + 0.4 * check, 0.8 - 0.6 * fy])
                } else {
                    let cx = 0.15 + 0.7 * ((p * 37) % 29) as f32 / 28.0;
                    let cy = 0.15 + 0.7 * ((p * 11) % 17) as f32 / 16.0;
                    let r = ((fx - cx).powi(2) + (fy - cy).powi(2)).sqrt();
                    let a = (1.0 - r / 0.12).clamp(0.0, 1.0).powf(0.5)
                        * if (x + y) % 3 == 0 { 0.6 } else { 0.9 };
                    (
                        a,
                        [
                            (p as f32 * 0.13).fract(),
                            (p as f32 * 0.29 + fx).fract(),
                            (p as f32 * 0.071 + fy).fract(),
                        ],
                    )
                };
                let q = &mut plane[(y * w as usize + x) * 4..(y * w as usize + x) * 4 + 4];
                q[3] = a;
                for k in 0..3 {
                    q[k] = rgb[k] * a;
                }
            }
        }
    }
    mpi
}

fn target_camera(reference: &Camera) -> Camera {
    // A small move right/up/forward and a small rotation, as a user would look around; a different size and
    // focal length than the reference so the test covers intrinsics as well.
    let rot = DMat3::from_rotation_y(0.03) * DMat3::from_rotation_x(-0.02);
    let pose = Pose::from_center(rot, DVec3::new(0.06, -0.04, 0.05));
    Camera::new(
        480,
        360,
        Intrinsics::new(380.0, 382.0, 241.0, 178.5),
        pose.compose(&reference.pose),
    )
}

fn psnr_rgb(a: &ImageF32, b: &ImageF32) -> f64 {
    deepview_metrics::psnr(&a.to_rgb(), &b.to_rgb()).unwrap()
}

// ---------------------------------------------------------------- chromium + a minimal CDP client

fn chromium_path() -> PathBuf {
    let p = PathBuf::from(
        std::env::var("DEEPVIEW_CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into()),
    );
    assert!(
        p.is_file(),
        "{} not found: the browser test needs Chromium (Debian: `apt-get update && apt-get install -y chromium`, \
         or set DEEPVIEW_CHROMIUM)",
        p.display()
    );
    p
}

struct Browser {
    child: Child,
    _profile: tempfile::TempDir,
    ws: WebSocket,
    next_id: u64,
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Browser {
    fn launch(width: u32, height: u32) -> Browser {
        let profile = tempfile::tempdir().unwrap();
        let mut child = Command::new(chromium_path())
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--force-device-scale-factor=1",
                "--remote-debugging-address=127.0.0.1",
                "--remote-debugging-port=0",
            ])
            .arg(format!("--window-size={width},{height}"))
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start chromium");
        // "DevTools listening on ws://127.0.0.1:PORT/devtools/browser/ID" on stderr.
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if let Some(rest) = line.split("DevTools listening on ").nth(1) {
                    let _ = tx.send(rest.trim().to_string());
                }
            }
        });
        let browser_ws = rx
            .recv_timeout(Duration::from_secs(30))
            .expect("chromium printed no DevTools address within 30 s");
        let port: u16 = browser_ws
            .trim_start_matches("ws://")
            .split(['/', ':'])
            .nth(1)
            .unwrap()
            .parse()
            .unwrap();
        // The page target opened for about:blank.
        let deadline = Instant::now() + Duration::from_secs(20);
        let page_ws = loop {
            let list: Value =
                serde_json::from_str(&http_get(port, "/json/list").1).unwrap_or(Value::Null);
            if let Some(t) = list
                .as_array()
                .and_then(|a| a.iter().find(|t| t["type"] == "page"))
            {
                break t["webSocketDebuggerUrl"].as_str().unwrap().to_string();
            }
            assert!(Instant::now() < deadline, "no page target in chromium");
            std::thread::sleep(Duration::from_millis(100));
        };
        let ws = WebSocket::connect(&page_ws);
        Browser {
            child,
            _profile: profile,
            ws,
            next_id: 1,
        }
    }

    fn call(&mut self, method: &str, params: Value) -> Value {
        let id = self.next_id;
        self.next_id += 1;
        self.ws
            .send(&json!({"id": id, "method": method, "params": params}).to_string());
        loop {
            let msg: Value = serde_json::from_str(&self.ws.recv()).unwrap();
            if msg["id"] == id {
                assert!(msg.get("error").is_none(), "{method}: {}", msg["error"]);
                return msg["result"].clone();
            }
        }
    }

    fn eval(&mut self, expr: &str) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": expr, "returnByValue": true}),
        );
        r["result"]["value"].clone()
    }

    /// Load `url` in a `w x h` viewport.
    fn navigate(&mut self, url: &str, w: u32, h: u32) {
        self.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": w, "height": h, "deviceScaleFactor": 1, "mobile": false}),
        );
        self.call("Page.navigate", json!({"url": url}));
    }

    /// The page's `deepviewStats` now (null before the page has them).
    fn stats(&mut self) -> Value {
        let s = self.eval("JSON.stringify(window.deepviewStats || null)");
        serde_json::from_str(s.as_str().unwrap_or("null")).unwrap_or(Value::Null)
    }

    /// Open `url` in a `w x h` viewport and wait until the viewer has drawn `frames` frames.
    fn open(&mut self, url: &str, w: u32, h: u32, frames: u64) -> Value {
        self.navigate(url, w, h);
        let deadline = Instant::now() + Duration::from_secs(90);
        loop {
            let stats = self.stats();
            if let Some(e) = stats["error"].as_str() {
                panic!("viewer error: {e}");
            }
            if stats["ready"] == true && stats["frames"].as_u64().unwrap_or(0) >= frames {
                return stats;
            }
            if Instant::now() > deadline {
                let hud = self.eval("document.getElementById('hud').textContent + ' | loaded: ' + performance.getEntriesByType('resource').map((e) => e.name.split('/').pop() + ':' + e.responseStatus).join(' ')");
                panic!("viewer not ready after 90 s: {stats}; page: {hud}");
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Open `url` and wait for the viewer's error (its `deepviewStats.error`), which it returns.
    fn open_error(&mut self, url: &str, w: u32, h: u32) -> String {
        self.navigate(url, w, h);
        let deadline = Instant::now() + Duration::from_secs(90);
        loop {
            let stats = self.stats();
            if let Some(e) = stats["error"].as_str() {
                return e.to_string();
            }
            assert!(
                stats["ready"] != true,
                "{url}: no error, the viewer is ready"
            );
            assert!(Instant::now() < deadline, "{url}: no error after 90 s");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn screenshot(&mut self) -> ImageF32 {
        let r = self.call("Page.captureScreenshot", json!({"format": "png"}));
        let png = base64_decode(r["data"].as_str().unwrap());
        let img = image::load_from_memory(&png).unwrap().into_rgb8();
        let (w, h) = img.dimensions();
        ImageF32::from_data(
            w,
            h,
            3,
            img.into_raw()
                .into_iter()
                .map(|v| v as f32 / 255.0)
                .collect(),
        )
        .unwrap()
    }
}

fn http_get(port: u16, path: &str) -> (u16, String) {
    // DevTools' HTTP server may keep the connection open: read the headers, then Content-Length bytes.
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut head = Vec::new();
    let mut b = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") {
        if s.read(&mut b).unwrap_or(0) == 0 {
            break;
        }
        head.push(b[0]);
    }
    let head = String::from_utf8_lossy(&head).into_owned();
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let len = head
        .lines()
        .find_map(|l| {
            l.to_ascii_lowercase()
                .strip_prefix("content-length:")
                .map(|v| v.trim().parse::<usize>().unwrap_or(0))
        })
        .unwrap_or(0);
    let mut body = vec![0u8; len];
    let _ = s.read_exact(&mut body);
    (status, String::from_utf8_lossy(&body).into_owned())
}

fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => (c - b'A') as u32,
            b'a'..=b'z' => (c - b'a' + 26) as u32,
            b'0'..=b'9' => (c - b'0' + 52) as u32,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            _ => panic!("bad base64"),
        }
    };
    let clean: Vec<u8> = s
        .bytes()
        .filter(|c| !c.is_ascii_whitespace() && *c != b'=')
        .collect();
    let mut out = Vec::with_capacity(clean.len() * 3 / 4);
    for chunk in clean.chunks(4) {
        let mut n = 0u32;
        for (i, &c) in chunk.iter().enumerate() {
            n |= val(c) << (18 - 6 * i);
        }
        let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
        out.extend_from_slice(&bytes[..chunk.len() - 1]);
    }
    out
}

/// Just enough of RFC 6455 for the DevTools protocol: masked text frames out, (fragmented) text frames in.
struct WebSocket {
    stream: TcpStream,
}

impl WebSocket {
    fn connect(url: &str) -> WebSocket {
        let rest = url.strip_prefix("ws://").expect("ws:// URL");
        let (host, path) = rest.split_at(rest.find('/').unwrap());
        let mut stream = TcpStream::connect(host).unwrap();
        write!(
            stream,
            "GET {path} HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
        )
        .unwrap();
        let mut head = Vec::new();
        let mut b = [0u8; 1];
        while !head.ends_with(b"\r\n\r\n") {
            stream.read_exact(&mut b).unwrap();
            head.push(b[0]);
        }
        let head = String::from_utf8_lossy(&head);
        assert!(
            head.starts_with("HTTP/1.1 101"),
            "websocket handshake failed: {head}"
        );
        stream
            .set_read_timeout(Some(Duration::from_secs(120)))
            .unwrap();
        WebSocket { stream }
    }

    fn send(&mut self, text: &str) {
        let payload = text.as_bytes();
        let mut frame = vec![0x81u8];
        let n = payload.len();
        if n < 126 {
            frame.push(0x80 | n as u8);
        } else if n < 65536 {
            frame.push(0x80 | 126);
            frame.extend_from_slice(&(n as u16).to_be_bytes());
        } else {
            frame.push(0x80 | 127);
            frame.extend_from_slice(&(n as u64).to_be_bytes());
        }
        let mask = [0x12u8, 0x34, 0x56, 0x78];
        frame.extend_from_slice(&mask);
        frame.extend(payload.iter().enumerate().map(|(i, b)| b ^ mask[i % 4]));
        self.stream.write_all(&frame).unwrap();
    }

    fn recv(&mut self) -> String {
        let mut message = Vec::new();
        loop {
            let mut h = [0u8; 2];
            self.stream.read_exact(&mut h).unwrap();
            let (fin, opcode) = (h[0] & 0x80 != 0, h[0] & 0x0f);
            let mut len = (h[1] & 0x7f) as u64;
            if len == 126 {
                let mut e = [0u8; 2];
                self.stream.read_exact(&mut e).unwrap();
                len = u16::from_be_bytes(e) as u64;
            } else if len == 127 {
                let mut e = [0u8; 8];
                self.stream.read_exact(&mut e).unwrap();
                len = u64::from_be_bytes(e);
            }
            let mut payload = vec![0u8; len as usize];
            self.stream.read_exact(&mut payload).unwrap();
            match opcode {
                0x0 | 0x1 => message.extend_from_slice(&payload),
                0x8 => panic!("DevTools closed the connection"),
                _ => continue, // ping / pong / binary: not used by DevTools
            }
            if fin {
                return String::from_utf8(message).unwrap();
            }
        }
    }
}

fn camera_query(c: &Camera) -> String {
    // The JSON of the camera, percent-encoded for the query string.
    let text = serde_json::to_string(&c.to_json()).unwrap();
    text.bytes()
        .map(|b| {
            if b.is_ascii_alphanumeric() || b"-_.".contains(&b) {
                (b as char).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect()
}

fn check_fixed_camera(
    browser: &mut Browser,
    dir: &Path,
    native: &ImageF32,
    cam: &Camera,
    what: &str,
) {
    let server = Server::start(dir, "127.0.0.1", 0).unwrap();
    let url = format!("{}?camera={}", server.url(), camera_query(cam));
    browser.open(&url, cam.width, cam.height, 2);
    let shot = browser.screenshot();
    assert_eq!(
        (shot.width, shot.height),
        (cam.width, cam.height),
        "{what}: screenshot size"
    );
    let psnr = psnr_rgb(&shot, native);
    println!("{what}: browser vs native renderer PSNR {psnr:.2} dB");
    if psnr < 35.0 {
        let out = std::env::temp_dir().join(format!("deepview_viewer_{what}.png"));
        deepview_image::write_png(&out, &shot).unwrap();
        panic!(
            "{what}: PSNR {psnr:.2} dB < 35 (screenshot in {})",
            out.display()
        );
    }
    server.stop();
}

#[test]
fn browser_matches_native_renderer_and_reports_fps() {
    let _ = chromium_path();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("mpi");
    write_mpi(&dir, &scene()).unwrap();
    let mpi = read_mpi::<f32>(&dir).unwrap(); // what the files hold (8-bit straight alpha)
    let cam = target_camera(&mpi.camera);
    let native = render(&mpi, &cam);

    let mut browser = Browser::launch(cam.width, cam.height);
    check_fixed_camera(&mut browser, &dir, &native, &cam, "folder");

    // The compact export renders the same.
    let compact = tmp.path().join("compact");
    let rep = deepview_mpi::export(&dir, &compact, deepview_mpi::ExportFormat::Compact).unwrap();
    println!(
        "compact export: tiles {:?}, {} bytes vs {} bytes of layers",
        rep.tiles, rep.bytes, rep.source_bytes
    );
    check_fixed_camera(&mut browser, &compact, &native, &cam, "compact");

    // The same camera given as base64 JSON is accepted too.
    let server = Server::start(&dir, "127.0.0.1", 0).unwrap();
    let b64 = base64_encode(serde_json::to_string(&cam.to_json()).unwrap().as_bytes());
    browser.open(
        &format!("{}?camera={b64}", server.url()),
        cam.width,
        cam.height,
        2,
    );
    let psnr = psnr_rgb(&browser.screenshot(), &native);
    assert!(psnr >= 35.0, "base64 camera: PSNR {psnr}");

    // Errors are named and stay on screen: a missing layer is still what the page shows once every
    // other layer has loaded (their progress wrote over it: "loading 31/32" for ever), and a camera
    // with a width of no pixels is refused.
    let (w, h) = (mpi.camera.width, mpi.camera.height);
    let broken = tmp.path().join("broken");
    std::fs::create_dir(&broken).unwrap();
    for f in std::fs::read_dir(&dir).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, broken.join(f.file_name().unwrap())).unwrap();
    }
    // (Removed once the server has started: it checks every layer at its start.)
    let broken_server = Server::start(&broken, "127.0.0.1", 0).unwrap();
    std::fs::remove_file(broken.join("layer_005.png")).unwrap();
    let e = browser.open_error(broken_server.url(), w, h);
    assert!(e.contains("layer_005.png") && e.contains("404"), "{e}");
    let deadline = Instant::now() + Duration::from_secs(60);
    while browser
        .eval("performance.getEntriesByType('resource').length")
        .as_u64()
        .unwrap_or(0)
        < 33
    {
        assert!(Instant::now() < deadline, "the other layers did not load");
        std::thread::sleep(Duration::from_millis(100));
    }
    let hud = browser.eval("document.getElementById('hud').textContent");
    assert!(
        hud.as_str().unwrap_or("").contains("layer_005.png"),
        "{hud}"
    );
    let mut bad = cam;
    bad.width = 0;
    let e = browser.open_error(
        &format!("{}?camera={}", broken_server.url(), camera_query(&bad)),
        w,
        h,
    );
    assert!(e.contains("width must be a whole number of pixels"), "{e}");
    broken_server.stop();

    // Frame rate of the interactive page at the MPI's own size (504x378, 32 planes).
    let raf = measure_fps(&mut browser, &server, "bench=1", w, h, 3000);
    let sync = measure_fps(&mut browser, &server, "bench=sync", w, h, 3000);
    println!(
        "viewer fps (headless chromium, SwiftShader, {w}x{h}, 32 planes): {:.1} (requestAnimationFrame, \
         {:.1} ms CPU per frame); {:.1} GPU-synchronised ({:.1} ms draw + readPixels wait)",
        raf.fps, raf.cpu_ms, sync.fps, sync.sync_ms
    );
    server.stop();
}

/// What the interactive page measured: the requestAnimationFrame rate over the whole window (frames / wall
/// time), the page's GPU-synchronised mean frame time (`bench=sync` only, else 0) and the CPU time all Chromium
/// processes spent per frame (renderer + GPU process with SwiftShader + browser; Linux only, else 0).
struct Measured {
    fps: f64,
    sync_ms: f64,
    cpu_ms: f64,
}

/// CPU seconds (user + system) of `root` and all its descendants, from /proc (0 where unavailable).
fn tree_cpu_seconds(root: u32) -> f64 {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return 0.0;
    };
    let mut procs = Vec::new(); // (pid, ppid, ticks)
    for e in dir.flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else {
            continue;
        };
        // "pid (comm) state ppid ... utime stime": fields after the last ')' start at field 3.
        let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else {
            continue;
        };
        let f: Vec<&str> = rest.split_whitespace().collect();
        let num = |k: usize| f.get(k).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0);
        procs.push((pid, num(1) as u32, num(11) + num(12)));
    }
    let mut tree = vec![root];
    let mut grew = true;
    while grew {
        grew = false;
        for &(pid, ppid, _) in &procs {
            if tree.contains(&ppid) && !tree.contains(&pid) {
                tree.push(pid);
                grew = true;
            }
        }
    }
    let ticks: u64 = procs
        .iter()
        .filter(|p| tree.contains(&p.0))
        .map(|p| p.2)
        .sum();
    ticks as f64 / 100.0 // USER_HZ
}

/// Open the interactive page with `query` at `w x h`, let it warm up for 1 s, then measure for `ms`.
fn measure_fps(
    browser: &mut Browser,
    server: &Server,
    query: &str,
    w: u32,
    h: u32,
    ms: u64,
) -> Measured {
    browser.open(&format!("{}?{query}", server.url()), w, h, 1);
    std::thread::sleep(Duration::from_millis(1000));
    let sample = |b: &mut Browser| {
        let stats: Value = serde_json::from_str(
            b.eval("JSON.stringify(window.deepviewStats)")
                .as_str()
                .unwrap(),
        )
        .unwrap();
        (stats, Instant::now(), tree_cpu_seconds(b.child.id()))
    };
    let (s0, t0, c0) = sample(browser);
    std::thread::sleep(Duration::from_millis(ms));
    let (stats, t1, c1) = sample(browser);
    assert!(stats["fps"].as_f64().unwrap() > 0.0, "{query}: {stats}");
    assert_eq!(stats["width"], w, "{query}: {stats}");
    assert_eq!(stats["planes"], 32, "{query}: {stats}");
    let frames = stats["frames"].as_f64().unwrap() - s0["frames"].as_f64().unwrap();
    assert!(frames > 0.0, "{query}: no frames drawn: {stats}");
    println!("  {query}: {stats}");
    Measured {
        fps: frames / (t1 - t0).as_secs_f64(),
        sync_ms: stats["syncMs"].as_f64().unwrap_or(0.0),
        cpu_ms: 1000.0 * (c1 - c0) / frames,
    }
}

/// Longer frame-rate measurement with and without tile culling:
/// `cargo test --release -p deepview-viewer --test browser -- --ignored --nocapture bench_viewer_fps`.
#[test]
#[ignore]
fn bench_viewer_fps() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("mpi");
    write_mpi(&dir, &scene()).unwrap();
    let (w, h) = (504, 378);
    let mut browser = Browser::launch(w, h);
    let server = Server::start(&dir, "127.0.0.1", 0).unwrap();
    for query in [
        "bench=1",
        "bench=sync",
        "bench=1&cull=0",
        "bench=sync&cull=0",
    ] {
        let m = measure_fps(&mut browser, &server, query, w, h, 6000);
        println!(
            "{query}: {:.1} fps, {:.1} ms draw + GPU wait, {:.1} ms CPU per frame (all chromium processes)",
            m.fps, m.sync_ms, m.cpu_ms
        );
    }
    server.stop();
}

fn base64_encode(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for i in 0..4 {
            if i <= c.len() {
                s.push(A[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}
