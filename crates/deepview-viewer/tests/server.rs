//! The viewer's HTTP server and static export: only the page, the MPI JSON and its listed files are served.

use deepview_geometry::{Camera, Intrinsics, Pose};
use deepview_mpi::{Mpi, write_mpi};
use deepview_viewer::{INDEX_HTML, Server, export_web, mpi_files};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;

fn small_mpi(dir: &Path) {
    let cam = Camera::new(40, 30, Intrinsics::centred(40.0, 40, 30), Pose::IDENTITY);
    let mut mpi = Mpi::transparent(cam, vec![10.0, 4.0, 2.0]);
    for (i, p) in mpi.layers.chunks_exact_mut(4).enumerate() {
        let a = (i % 7) as f32 / 6.0;
        p.copy_from_slice(&[0.5 * a, 0.25 * a, 0.1 * a, a]);
    }
    write_mpi(dir, &mpi).unwrap();
}

/// Raw request so paths reach the server unnormalised.
fn get(url: &str, path: &str) -> (u16, Vec<u8>) {
    let host = url.trim_start_matches("http://").trim_end_matches('/');
    let mut s = TcpStream::connect(host).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).unwrap();
    let split = buf.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let head = String::from_utf8_lossy(&buf[..split]).into_owned();
    let status = head.split(' ').nth(1).unwrap().parse().unwrap();
    (status, buf[split + 4..].to_vec())
}

#[test]
fn serves_only_the_page_and_the_mpi_files() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("mpi");
    small_mpi(&dir);
    std::fs::write(dir.join("secret.txt"), "not for the web").unwrap();
    std::fs::write(tmp.path().join("outside.txt"), "not for the web").unwrap();
    let server = Server::start(&dir, "127.0.0.1", 0).unwrap();
    let url = server.url().to_string();
    assert!(url.starts_with("http://127.0.0.1:"), "{url}");

    let (s, body) = get(&url, "/");
    assert_eq!(s, 200);
    assert_eq!(body, INDEX_HTML.as_bytes());
    assert_eq!(get(&url, "/index.html?camera=x").0, 200);
    let (s, body) = get(&url, "/mpi.json");
    assert_eq!(s, 200);
    assert_eq!(body, std::fs::read(dir.join("mpi.json")).unwrap());
    let (s, body) = get(&url, "/layer_002.png?v=1");
    assert_eq!(s, 200);
    assert_eq!(body, std::fs::read(dir.join("layer_002.png")).unwrap());
    for bad in [
        "/secret.txt",
        "/../outside.txt",
        "/%2e%2e/outside.txt",
        "/..%2Foutside.txt",
        "//etc/passwd",
        "/layer_003.png",
        "/./mpi.json",
        "/mpi.json/",
        "/LAYER_000.PNG",
        "/layer_000.png/../secret.txt",
    ] {
        assert_eq!(get(&url, bad).0, 404, "{bad}");
    }
    // The MPI rewritten with more planes while it is served (another `demo`): its new layers are
    // served (they answered 404, the reloaded page loaded for ever); names it does not list still not.
    let cam = Camera::new(40, 30, Intrinsics::centred(40.0, 40, 30), Pose::IDENTITY);
    write_mpi(&dir, &Mpi::transparent(cam, vec![10.0, 6.0, 4.0, 3.0, 2.0])).unwrap();
    let (s, body) = get(&url, "/layer_004.png");
    assert_eq!(s, 200);
    assert_eq!(body, std::fs::read(dir.join("layer_004.png")).unwrap());
    assert_eq!(get(&url, "/layer_005.png").0, 404);
    assert_eq!(get(&url, "/secret.txt").0, 404);
    // A name listed later that is a link out of the folder is not served.
    std::os::unix::fs::symlink(tmp.path().join("outside.txt"), dir.join("leak.png")).unwrap();
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("mpi.json")).unwrap()).unwrap();
    json["layers"][4] = "leak.png".into();
    std::fs::write(dir.join("mpi.json"), json.to_string()).unwrap();
    assert_eq!(get(&url, "/leak.png").0, 404);
    // A method other than GET/HEAD.
    let host = url.trim_start_matches("http://").trim_end_matches('/');
    let mut s = TcpStream::connect(host).unwrap();
    write!(s, "DELETE /mpi.json HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\nContent-Length: 0\r\n\r\n").unwrap();
    let mut buf = String::new();
    s.read_to_string(&mut buf).unwrap();
    assert!(buf.starts_with("HTTP/1.1 405"), "{buf}");
    server.stop();
    assert!(dir.join("mpi.json").is_file());
}

#[test]
fn broken_mpi_folders_are_refused_with_the_file_named() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("mpi");
    small_mpi(&dir);
    std::fs::remove_file(dir.join("layer_001.png")).unwrap();
    let e = Server::start(&dir, "127.0.0.1", 0)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("layer_001.png"), "{e}");
    small_mpi(&dir);
    deepview_image::write_png_u8(&dir.join("layer_001.png"), 8, 8, 4, &[0; 256]).unwrap();
    let e = mpi_files(&dir).unwrap_err().to_string();
    assert!(e.contains("layer_001.png") && e.contains("8x8"), "{e}");
    std::fs::write(dir.join("mpi.json"), "{ not json").unwrap();
    let e = export_web(&dir, &tmp.path().join("web"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("mpi.json"), "{e}");
    let e = Server::start(tmp.path(), "127.0.0.1", 0)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("no known MPI format"), "{e}");
    // A port that cannot be bound is an error, not a panic.
    let busy = Server::start(
        &{
            let d = tmp.path().join("ok");
            small_mpi(&d);
            d
        },
        "127.0.0.1",
        0,
    )
    .unwrap();
    let port = busy
        .url()
        .rsplit(':')
        .next()
        .unwrap()
        .trim_end_matches('/')
        .parse::<u16>()
        .unwrap();
    let e = Server::start(&tmp.path().join("ok"), "127.0.0.1", port)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("cannot serve"), "{e}");
}

#[test]
fn export_web_writes_a_static_site() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("mpi");
    small_mpi(&dir);
    let out = tmp.path().join("site");
    let files = export_web(&dir, &out).unwrap();
    assert_eq!(files.len(), 5);
    assert_eq!(
        std::fs::read_to_string(out.join("index.html")).unwrap(),
        INDEX_HTML
    );
    for name in [
        "mpi.json",
        "layer_000.png",
        "layer_001.png",
        "layer_002.png",
    ] {
        assert_eq!(
            std::fs::read(out.join(name)).unwrap(),
            std::fs::read(dir.join(name)).unwrap(),
            "{name}"
        );
    }
    // The exported site is itself a servable MPI folder, and so is a compact export.
    assert_eq!(mpi_files(&out).unwrap().len(), 4);
    let compact = tmp.path().join("compact");
    deepview_mpi::export(&dir, &compact, deepview_mpi::ExportFormat::Compact).unwrap();
    let site2 = tmp.path().join("site2");
    export_web(&compact, &site2).unwrap();
    assert!(site2.join("mpi_compact.json").is_file() && site2.join("tiles_000.png").is_file());
}

/// Send `raw` and read the answer's status line (the server closes every connection after one answer).
fn raw(url: &str, raw: &[u8]) -> String {
    let host = url.trim_start_matches("http://").trim_end_matches('/');
    let mut s = TcpStream::connect(host).unwrap();
    s.set_read_timeout(Some(std::time::Duration::from_secs(30)))
        .unwrap();
    let _ = s.write_all(raw);
    let mut buf = Vec::new();
    let _ = s.read_to_end(&mut buf);
    String::from_utf8_lossy(&buf)
        .lines()
        .next()
        .unwrap_or("")
        .to_string()
}

#[test]
fn no_request_stops_the_server() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("mpi");
    small_mpi(&dir);
    let server = Server::start(&dir, "127.0.0.1", 0).unwrap();
    let url = server.url().to_string();
    let cases: Vec<(Vec<u8>, &str)> = vec![
        // A huge announced body (the abort of issue 28): refused unread.
        (
            b"GET /mpi.json HTTP/1.1\r\nContent-Length: 18446744073709551615\r\n\r\n".to_vec(),
            "413",
        ),
        (
            b"POST / HTTP/1.1\r\nContent-Length: 9000000000\r\n\r\nxx".to_vec(),
            "413",
        ),
        (
            b"GET / HTTP/1.1\r\nContent-Length: 99999999999999999999999999\r\n\r\n".to_vec(),
            "400",
        ),
        (
            b"GET / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\nffffffffffff\r\n".to_vec(),
            "411",
        ),
        // Endless headers: bounded.
        (
            [b"GET / HTTP/1.1\r\nX: ".to_vec(), vec![b'a'; 200_000]].concat(),
            "431",
        ),
        (b"\x00\x01\x02\xff\r\n\r\n".to_vec(), "400"),
        (b"GET / HTTP/1.1\r\nbroken header\r\n\r\n".to_vec(), "400"),
        // A small body on GET is read and ignored.
        (
            b"GET /mpi.json HTTP/1.1\r\nContent-Length: 5\r\n\r\nhello".to_vec(),
            "200",
        ),
    ];
    for (req, status) in &cases {
        let line = raw(&url, req);
        assert!(
            line.starts_with(&format!("HTTP/1.1 {status}")),
            "{:?}: {line}",
            String::from_utf8_lossy(&req[..req.len().min(60)])
        );
        // The server still answers.
        assert_eq!(get(&url, "/mpi.json").0, 200);
    }
    // A client that connects and says nothing, and one that half-sends a head: others are still served.
    let host = url.trim_start_matches("http://").trim_end_matches('/');
    let idle = TcpStream::connect(host).unwrap();
    let mut half = TcpStream::connect(host).unwrap();
    half.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n").unwrap();
    assert_eq!(get(&url, "/").0, 200);
    drop((idle, half));
    server.stop();
}
