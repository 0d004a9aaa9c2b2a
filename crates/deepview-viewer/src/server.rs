//! The viewer's HTTP server: GET and HEAD of the page and the MPI's files, nothing else, with every size it
//! reads from a client bounded, so that no request can stop it.
//!
//! - The request line and headers: at most [`MAX_HEAD`] bytes (431 beyond), read within [`TIMEOUT`] of the
//!   connection's start, however slowly the bytes come; the answer written within [`answer_timeout`].
//! - A body: GET and HEAD have none; one announced up to [`MAX_BODY`] is read and dropped, a larger one
//!   answered 413, `Transfer-Encoding` 411, and the connection closed without reading it.
//! - Connections: one thread each, at most [`MAX_CONNECTIONS`] at once (503 beyond); every answer closes
//!   its connection.

use crate::ViewerError;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;

/// Longest request line plus headers.
pub const MAX_HEAD: usize = 16 * 1024;
/// Largest request body read (and dropped).
pub const MAX_BODY: u64 = 64 * 1024;
/// Connections served at once.
pub const MAX_CONNECTIONS: usize = 64;
/// How long a client may take to send its request.
pub const TIMEOUT: Duration = Duration::from_secs(10);
/// The slowest a client may receive an answer: [`TIMEOUT`] plus its bytes at this rate (a layer of a
/// large MPI through a slow tunnel still arrives; a client that reads nothing is cut off).
pub const MIN_RATE: u64 = 64 * 1024;

/// How long a client may take to receive an answer of `bytes`.
pub fn answer_timeout(bytes: usize) -> Duration {
    TIMEOUT + Duration::from_secs(bytes as u64 / MIN_RATE)
}

/// A running viewer server (a thread accepts connections until [`Server::stop`] or drop).
pub struct Server {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    acceptor: Option<std::thread::JoinHandle<()>>,
    url: String,
}

impl Server {
    /// Serve the MPI folder `dir` on `host:port` (port 0: any free port).
    pub fn start(dir: &Path, host: &str, port: u16) -> Result<Server, ViewerError> {
        let files = Arc::new(crate::mpi_files(dir)?);
        let addr = if host.contains(':') && !host.starts_with('[') {
            format!("[{host}]:{port}")
        } else {
            format!("{host}:{port}")
        };
        let bind = |msg: String| ViewerError::Bind {
            addr: addr.clone(),
            msg,
        };
        let listener = TcpListener::bind(&addr).map_err(|e| bind(e.to_string()))?;
        let local = listener.local_addr().map_err(|e| bind(e.to_string()))?;
        let url_host = if local.ip().is_unspecified() {
            "127.0.0.1".to_string()
        } else {
            local.ip().to_string()
        };
        let url_host = if url_host.contains(':') {
            format!("[{url_host}]")
        } else {
            url_host
        };
        let url = format!("http://{url_host}:{}/", local.port());
        let stop = Arc::new(AtomicBool::new(false));
        let dir = Arc::new(dir.to_path_buf());
        let flag = stop.clone();
        let acceptor = std::thread::spawn(move || accept(listener, &flag, &dir, &files));
        Ok(Server {
            addr: local,
            stop,
            acceptor: Some(acceptor),
            url,
        })
    }

    /// `http://host:port/`.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Block until the server stops (it does not stop by itself: for the CLI).
    pub fn wait(mut self) {
        if let Some(a) = self.acceptor.take() {
            let _ = a.join();
        }
    }

    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // Wake the blocking accept with a connection of our own.
        let mut wake = self.addr;
        if wake.ip().is_unspecified() {
            wake.set_ip(match wake {
                SocketAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
                SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
            });
        }
        let _ = TcpStream::connect_timeout(&wake, Duration::from_secs(1));
        if let Some(a) = self.acceptor.take() {
            let _ = a.join();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if self.acceptor.is_some() {
            self.shutdown();
        }
    }
}

fn accept(listener: TcpListener, stop: &AtomicBool, dir: &Arc<PathBuf>, files: &Arc<Vec<String>>) {
    let live = Arc::new(AtomicUsize::new(0));
    for stream in listener.incoming() {
        if stop.load(Ordering::SeqCst) {
            break;
        }
        let Ok(mut stream) = stream else {
            // A failed accept (the client gave up, or no file descriptors left): wait a moment, go on.
            std::thread::sleep(Duration::from_millis(10));
            continue;
        };
        let _ = stream.set_read_timeout(Some(TIMEOUT));
        let _ = stream.set_write_timeout(Some(TIMEOUT));
        if live.fetch_add(1, Ordering::SeqCst) >= MAX_CONNECTIONS {
            live.fetch_sub(1, Ordering::SeqCst);
            let _ = respond(&mut stream, 503, "text/plain", b"busy", false, &[]);
            close(stream);
            continue;
        }
        let (live, dir, files) = (live.clone(), dir.clone(), files.clone());
        let spawned = std::thread::Builder::new()
            .name("deepview-view".into())
            .spawn(move || {
                serve(stream, &dir, &files);
                live.fetch_sub(1, Ordering::SeqCst);
            });
        if spawned.is_err() {
            // No thread to be had: the connection (moved into the failed closure) is closed.
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

/// A parsed request head: method, path (without query) and the announced body length.
#[derive(Debug, PartialEq)]
pub struct Head {
    pub method: String,
    pub path: String,
    pub content_length: u64,
    pub chunked: bool,
}

/// Why a request head was refused: the status to answer.
#[derive(Debug, PartialEq)]
pub struct Refused(pub u16);

/// Read and parse a request head from `r`, at most [`MAX_HEAD`] bytes.
pub fn read_head(r: &mut impl BufRead) -> Result<Option<Head>, Refused> {
    let mut head = Vec::new();
    let mut limited = r.take(MAX_HEAD as u64 + 1);
    loop {
        let before = head.len();
        match limited.read_until(b'\n', &mut head) {
            Ok(0) if head.is_empty() => return Ok(None),
            Ok(0) => return Err(Refused(400)),
            Ok(_) => {}
            Err(_) => return Err(Refused(408)),
        }
        if head.len() > MAX_HEAD {
            return Err(Refused(431));
        }
        let line = &head[before..];
        if line == b"\r\n" || line == b"\n" {
            // Blank lines before the request line are allowed (RFC 9112 2.2).
            if head[..before].iter().all(|b| b.is_ascii_whitespace()) {
                head.clear();
                continue;
            }
            break;
        }
        if !line.ends_with(b"\n") {
            return Err(Refused(400));
        }
    }
    let text = std::str::from_utf8(&head).map_err(|_| Refused(400))?;
    let mut lines = text.lines();
    let request = lines.next().ok_or(Refused(400))?;
    let mut parts = request.split(' ');
    let (Some(method), Some(target), Some(version), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(Refused(400));
    };
    if !version.starts_with("HTTP/1.") || method.is_empty() || !target.starts_with('/') {
        return Err(Refused(400));
    }
    let mut content_length = None;
    let mut chunked = false;
    for line in lines {
        if line.is_empty() {
            continue;
        }
        let (name, value) = line.split_once(':').ok_or(Refused(400))?;
        let value = value.trim();
        if name.eq_ignore_ascii_case("content-length") {
            let n: u64 = value.parse().map_err(|_| Refused(400))?;
            if content_length.is_some_and(|c| c != n) {
                return Err(Refused(400));
            }
            content_length = Some(n);
        } else if name.eq_ignore_ascii_case("transfer-encoding") {
            chunked = true;
        }
    }
    let path = target.split(['?', '#']).next().unwrap_or("").to_string();
    Ok(Some(Head {
        method: method.to_string(),
        path,
        content_length: content_length.unwrap_or(0),
        chunked,
    }))
}

/// A connection read against one deadline for the whole request (its head and body), not per read: a
/// client sending a byte now and then ("slowloris") is cut off at the deadline like a silent one.
struct Deadline {
    stream: TcpStream,
    until: std::time::Instant,
}

impl Read for Deadline {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let left = self
            .until
            .saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            return Err(std::io::ErrorKind::TimedOut.into());
        }
        self.stream.set_read_timeout(Some(left))?;
        self.stream.read(buf)
    }
}

fn serve(stream: TcpStream, dir: &Path, files: &[String]) {
    let Ok(write) = stream.try_clone() else {
        return;
    };
    let mut write = write;
    let mut reader = BufReader::new(Deadline {
        stream,
        until: std::time::Instant::now() + TIMEOUT,
    });
    let head = match read_head(&mut reader) {
        Ok(Some(h)) => h,
        Ok(None) => return close(write),
        Err(Refused(code)) => {
            let _ = respond(
                &mut write,
                code,
                "text/plain",
                status_text(code).as_bytes(),
                false,
                &[],
            );
            return close(write);
        }
    };
    if head.chunked {
        let _ = respond(
            &mut write,
            411,
            "text/plain",
            b"length required",
            false,
            &[],
        );
        return close(write);
    }
    if head.content_length > MAX_BODY {
        let _ = respond(
            &mut write,
            413,
            "text/plain",
            b"content too large",
            false,
            &[],
        );
        return close(write);
    }
    // Read and drop a small body, so that the client sees an answer rather than a reset.
    let _ = std::io::copy(
        &mut (&mut reader).take(head.content_length),
        &mut std::io::sink(),
    );
    let is_head = head.method == "HEAD";
    if head.method != "GET" && !is_head {
        let _ = respond(
            &mut write,
            405,
            "text/plain",
            b"method not allowed",
            false,
            &[("Allow", "GET, HEAD")],
        );
        return close(write);
    }
    match crate::route(&head.path, dir, files) {
        Some((ct, body)) => {
            let _ = respond(&mut write, 200, ct, &body, is_head, &[]);
        }
        None => {
            let _ = respond(
                &mut write,
                404,
                "text/plain",
                b"404 not found",
                is_head,
                &[],
            );
        }
    }
    close(write);
}

fn status_text(code: u16) -> &'static str {
    match code {
        200 => "OK",
        400 => "Bad Request",
        404 => "Not Found",
        405 => "Method Not Allowed",
        408 => "Request Timeout",
        411 => "Length Required",
        413 => "Content Too Large",
        431 => "Request Header Fields Too Large",
        503 => "Service Unavailable",
        _ => "Error",
    }
}

fn respond(
    w: &mut TcpStream,
    code: u16,
    content_type: &str,
    body: &[u8],
    head_only: bool,
    extra: &[(&str, &str)],
) -> std::io::Result<()> {
    respond_by(
        w,
        code,
        content_type,
        body,
        head_only,
        extra,
        std::time::Instant::now() + answer_timeout(body.len()),
    )
}

/// [`respond`], the whole answer written by `until` (a client that reads too slowly or not at all is
/// cut off then, not after [`TIMEOUT`] per write, however long).
fn respond_by(
    w: &mut TcpStream,
    code: u16,
    content_type: &str,
    body: &[u8],
    head_only: bool,
    extra: &[(&str, &str)],
    until: std::time::Instant,
) -> std::io::Result<()> {
    let mut out = format!(
        "HTTP/1.1 {code} {}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\n\
         Cache-Control: no-cache\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n",
        status_text(code),
        body.len()
    );
    for (k, v) in extra {
        out.push_str(&format!("{k}: {v}\r\n"));
    }
    out.push_str("\r\n");
    let body = if head_only { &[][..] } else { body };
    for chunk in std::iter::once(out.as_bytes()).chain(body.chunks(64 << 10)) {
        let left = until.saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            return Err(std::io::ErrorKind::TimedOut.into());
        }
        w.set_write_timeout(Some(left))?;
        w.write_all(chunk)?;
    }
    w.flush()
}

/// Close after the answer: no more writes, then a short drain so that the answer is not reset away by
/// unread request bytes.
fn close(stream: TcpStream) {
    let _ = stream.shutdown(Shutdown::Write);
    let _ = stream.set_read_timeout(Some(Duration::from_millis(200)));
    let _ = (&stream).take(MAX_BODY).read_to_end(&mut Vec::new());
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<Option<Head>, Refused> {
        read_head(&mut std::io::Cursor::new(s.as_bytes().to_vec()))
    }

    #[test]
    fn a_client_trickling_its_head_is_cut_off_at_the_deadline() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        // The client sends a header line every 50 ms, for ever (until the server closes).
        let client = std::thread::spawn(move || {
            let mut c = TcpStream::connect(addr).unwrap();
            let _ = c.write_all(b"GET /mpi.json HTTP/1.1\r\n");
            for _ in 0..2000 {
                std::thread::sleep(Duration::from_millis(50));
                if c.write_all(b"X-A: b\r\n").is_err() {
                    return;
                }
            }
        });
        let (stream, _) = listener.accept().unwrap();
        let start = std::time::Instant::now();
        let mut reader = BufReader::new(Deadline {
            stream,
            until: start + Duration::from_millis(400),
        });
        // Each read gets bytes well within any per-read timeout; the whole head does not come in time.
        assert_eq!(read_head(&mut reader), Err(Refused(408)));
        let took = start.elapsed();
        assert!(took < Duration::from_secs(5), "{took:?}");
        drop(reader);
        client.join().unwrap();
    }

    #[test]
    fn a_client_that_does_not_read_is_cut_off_at_the_deadline() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        // Connected, and never reading: the socket buffers fill, then every write waits.
        let client = TcpStream::connect(addr).unwrap();
        let (mut stream, _) = listener.accept().unwrap();
        let body = vec![7u8; 256 << 20];
        let start = std::time::Instant::now();
        let r = respond_by(
            &mut stream,
            200,
            "image/png",
            &body,
            false,
            &[],
            start + Duration::from_millis(500),
        );
        assert!(r.is_err(), "256 MiB went to a client that reads nothing");
        let took = start.elapsed();
        assert!(took < Duration::from_secs(10), "{took:?}");
        drop(client);
    }

    #[test]
    fn heads_are_parsed_and_bounded() {
        let h = parse("GET /mpi.json?x=1 HTTP/1.1\r\nHost: a\r\n\r\n")
            .unwrap()
            .unwrap();
        assert_eq!(
            (h.method.as_str(), h.path.as_str(), h.content_length),
            ("GET", "/mpi.json", 0)
        );
        let h = parse("GET / HTTP/1.1\r\nContent-Length: 99999999999999999\r\n\r\n")
            .unwrap()
            .unwrap();
        assert_eq!(h.content_length, 99_999_999_999_999_999);
        assert_eq!(parse(""), Ok(None));
        for (bad, code) in [
            ("GET / HTTP/1.1\r\nContent-Length: -1\r\n\r\n", 400),
            (
                "GET / HTTP/1.1\r\nContent-Length: 99999999999999999999999\r\n\r\n",
                400,
            ),
            (
                "GET / HTTP/1.1\r\nContent-Length: 1\r\nContent-Length: 2\r\n\r\n",
                400,
            ),
            ("GET /\r\n\r\n", 400),
            ("GET x HTTP/1.1\r\n\r\n", 400),
            ("GET / HTTP/1.1\r\nno colon\r\n\r\n", 400),
            ("GET / HTTP/1.1\r\nHost: a", 400),
        ] {
            assert_eq!(parse(bad), Err(Refused(code)), "{bad:?}");
        }
        let long = format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(MAX_HEAD));
        assert_eq!(parse(&long), Err(Refused(431)));
    }
}
