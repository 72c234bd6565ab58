//! `strata serve` end to end: the built binary on a folder or a file, spoken to over raw TCP so that
//! request targets arrive exactly as written (no client normalises `..` away).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

/// A running `strata serve`, killed when dropped.
struct Server {
    child: Child,
    /// `host:port`.
    addr: String,
    first_line: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Server {
    fn start(args: &[&str]) -> Server {
        Server::start_with(args, Stdio::null())
    }

    fn start_with(args: &[&str], stderr: Stdio) -> Server {
        let mut child = Command::new(env!("CARGO_BIN_EXE_strata"))
            .arg("serve")
            .args(args)
            .args(["--port", "0"])
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .unwrap();
        let mut first_line = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut first_line).unwrap();
        let first_line = first_line.trim_end().to_string();
        let after = first_line.split("http://").nth(1).unwrap_or_else(|| panic!("no URL in {first_line:?}"));
        let addr = after.split('/').next().unwrap().to_string();
        Server { child, addr, first_line }
    }

    /// Send `GET path` with extra header lines.
    fn get(&self, path: &str, headers: &[&str]) -> Resp {
        self.request("GET", path, headers)
    }

    fn request(&self, method: &str, path: &str, headers: &[&str]) -> Resp {
        let mut raw = format!("{method} {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n", self.addr);
        for h in headers {
            raw.push_str(h);
            raw.push_str("\r\n");
        }
        raw.push_str("\r\n");
        send(&self.addr, &raw)
    }

    fn alive(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
    }
}

/// A parsed response: status, headers (names lower-case) and body.
#[derive(Debug)]
struct Resp {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Resp {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }
}

/// Send a raw request and read the response to the end of the connection.
fn send(addr: &str, raw: &str) -> Resp {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    s.write_all(raw.as_bytes()).unwrap();
    let mut bytes = Vec::new();
    s.read_to_end(&mut bytes).unwrap();
    parse(&bytes)
}

fn parse(bytes: &[u8]) -> Resp {
    let end =
        bytes.windows(4).position(|w| w == b"\r\n\r\n").unwrap_or_else(|| panic!("no header end in {:?}", String::from_utf8_lossy(bytes)));
    let head = std::str::from_utf8(&bytes[..end]).unwrap();
    let mut lines = head.split("\r\n");
    let status_line = lines.next().unwrap();
    let status = status_line.split(' ').nth(1).unwrap().parse().unwrap();
    let headers = lines
        .map(|l| {
            let (k, v) = l.split_once(':').unwrap();
            (k.trim().to_ascii_lowercase(), v.trim().to_string())
        })
        .collect();
    let resp = Resp { status, headers, body: bytes[end + 4..].to_vec() };
    assert!(resp.header("transfer-encoding").is_none(), "chunked response: {:?}", resp.headers);
    resp
}

/// The icosphere fixture converted once per test process.
fn converted() -> &'static Path {
    static FILE: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &FILE
        .get_or_init(|| {
            let dir = tempfile::tempdir().unwrap();
            let input = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/icosphere.obj");
            let out = dir.path().join("ico.strata");
            let o = Command::new(env!("CARGO_BIN_EXE_strata")).args(["convert", input, out.to_str().unwrap(), "-q"]).output().unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            (dir, out)
        })
        .1
}

/// A scratch folder: `served/` holds `ico.strata`, `sub/nested model.strata`, `notes.txt`;
/// `outside.strata` and `secret.txt` sit beside it, outside what is served.
struct Tree {
    dir: tempfile::TempDir,
}

impl Tree {
    fn new() -> Tree {
        let dir = tempfile::tempdir().unwrap();
        let served = dir.path().join("served");
        std::fs::create_dir_all(served.join("sub")).unwrap();
        std::fs::copy(converted(), served.join("ico.strata")).unwrap();
        std::fs::copy(converted(), served.join("sub/nested model.strata")).unwrap();
        std::fs::write(served.join("notes.txt"), "not a model").unwrap();
        std::fs::copy(converted(), dir.path().join("outside.strata")).unwrap();
        std::fs::write(dir.path().join("secret.txt"), "secret").unwrap();
        Tree { dir }
    }

    fn served(&self) -> PathBuf {
        self.dir.path().join("served")
    }

    fn ico(&self) -> Vec<u8> {
        std::fs::read(self.served().join("ico.strata")).unwrap()
    }

    fn serve(&self) -> Server {
        let s = Server::start(&[self.served().to_str().unwrap()]);
        assert_eq!(s.first_line, format!("serving {} at http://{}/", self.served().display(), s.addr));
        s
    }
}

fn range(s: &Server, path: &str, spec: &str) -> Resp {
    s.get(path, &[&format!("Range: {spec}")])
}

#[test]
fn byte_ranges_are_exact_and_past_the_end_is_416() {
    let t = Tree::new();
    let s = t.serve();
    let data = t.ico();
    let len = data.len();
    assert!(len > 1000);

    let whole = s.get("/ico.strata", &[]);
    assert_eq!(whole.status, 200);
    assert_eq!(whole.body, data);
    assert_eq!(whole.header("content-length"), Some(len.to_string().as_str()));
    assert_eq!(whole.header("accept-ranges"), Some("bytes"));
    assert_eq!(whole.header("content-type"), Some("application/octet-stream"));

    let cases = [
        ("bytes=0-0", 0, 0),
        ("bytes=100-499", 100, 499),
        (&*format!("bytes={}-{}", len - 1, len - 1), len - 1, len - 1),
        ("bytes=-100", len - 100, len - 1),
        ("bytes=5-", 5, len - 1),
        (&*format!("bytes={}-{}", len - 10, len + 1000), len - 10, len - 1),
        (&*format!("bytes=-{}", len * 2), 0, len - 1),
    ];
    for (spec, first, last) in cases {
        let r = range(&s, "/ico.strata", spec);
        assert_eq!(r.status, 206, "{spec}");
        assert_eq!(r.header("content-range"), Some(format!("bytes {first}-{last}/{len}").as_str()), "{spec}");
        assert_eq!(r.header("content-length"), Some((last - first + 1).to_string().as_str()), "{spec}");
        assert_eq!(r.header("accept-ranges"), Some("bytes"));
        assert_eq!(r.body, &data[first..=last], "{spec}");
    }

    for spec in [format!("bytes={len}-"), format!("bytes={}-{}", len + 5, len + 10), "bytes=-0".to_string()] {
        let r = range(&s, "/ico.strata", &spec);
        assert_eq!(r.status, 416, "{spec}");
        assert_eq!(r.header("content-range"), Some(format!("bytes */{len}").as_str()), "{spec}");
        assert!(r.body.is_empty());
    }

    // Ranges the server may ignore: the whole file.
    for spec in ["bytes=0-1,5-6", "bytes=9-3", "bytes=abc", "lines=0-1", "bytes=-"] {
        let r = range(&s, "/ico.strata", spec);
        assert_eq!(r.status, 200, "{spec}");
        assert_eq!(r.body, data, "{spec}");
    }

    let nested = range(&s, "/sub/nested%20model.strata", "bytes=0-3");
    assert_eq!(nested.status, 206);
    assert_eq!(nested.body, &data[..4]);
}

#[test]
fn head_has_the_headers_of_get_and_no_body() {
    let t = Tree::new();
    let s = t.serve();
    let len = t.ico().len();
    let h = s.request("HEAD", "/ico.strata", &[]);
    assert_eq!(h.status, 200);
    assert!(h.body.is_empty());
    assert_eq!(h.header("content-length"), Some(len.to_string().as_str()));
    let g = s.get("/ico.strata", &[]);
    for name in ["etag", "last-modified", "accept-ranges", "content-type", "access-control-allow-origin"] {
        assert_eq!(h.header(name), g.header(name), "{name}");
    }
    let hr = s.request("HEAD", "/ico.strata", &["Range: bytes=10-19"]);
    assert_eq!(hr.status, 206);
    assert!(hr.body.is_empty());
    assert_eq!(hr.header("content-range"), Some(format!("bytes 10-19/{len}").as_str()));
    assert_eq!(hr.header("content-length"), Some("10"));
    for path in ["/", "/viewer/"] {
        let r = s.request("HEAD", path, &[]);
        assert_eq!(r.status, 200, "{path}");
        assert!(r.body.is_empty(), "{path}");
    }
}

#[test]
fn etag_validates_and_if_range_guards_ranges() {
    let t = Tree::new();
    let s = t.serve();
    let data = t.ico();
    let g = s.get("/ico.strata", &[]);
    let etag = g.header("etag").unwrap().to_string();
    let modified = g.header("last-modified").unwrap().to_string();
    assert!(etag.starts_with('"') && etag.ends_with('"') && !etag.starts_with("W/"), "{etag}");

    let r = s.get("/ico.strata", &[&format!("If-None-Match: {etag}")]);
    assert_eq!(r.status, 304);
    assert!(r.body.is_empty());
    assert_eq!(r.header("etag"), Some(etag.as_str()));
    let r = s.get("/ico.strata", &[&format!("If-None-Match: \"other\", W/{etag}")]);
    assert_eq!(r.status, 304);
    let r = s.get("/ico.strata", &["If-None-Match: \"other\""]);
    assert_eq!(r.status, 200);
    assert_eq!(r.body, data);
    let r = s.get("/ico.strata", &[&format!("If-Modified-Since: {modified}")]);
    assert_eq!(r.status, 304);

    let r = s.get("/ico.strata", &["Range: bytes=0-9", &format!("If-Range: {etag}")]);
    assert_eq!(r.status, 206);
    assert_eq!(r.body, &data[..10]);
    let r = s.get("/ico.strata", &["Range: bytes=0-9", "If-Range: \"stale\""]);
    assert_eq!(r.status, 200);
    assert_eq!(r.body, data);
    let r = s.get("/ico.strata", &["Range: bytes=0-9", "If-Range: Thu, 01 Jan 1998 00:00:00 GMT"]);
    assert_eq!(r.status, 200);
    assert_eq!(r.body, data);
    let r = s.get("/ico.strata", &["Range: bytes=0-9", &format!("If-Range: {modified}")]);
    assert_eq!(r.status, 206);

    // A changed file has a new ETag.
    std::fs::write(t.served().join("ico.strata"), &data[..data.len() - 1]).unwrap();
    let r = s.get("/ico.strata", &[&format!("If-None-Match: {etag}"), "Range: bytes=0-9", &format!("If-Range: {etag}")]);
    assert_eq!(r.status, 200);
    assert_eq!(r.body, &data[..data.len() - 1]);
}

#[test]
fn cors_headers_and_preflight() {
    let t = Tree::new();
    let s = t.serve();
    let r = range(&s, "/ico.strata", "bytes=0-0");
    assert_eq!(r.header("access-control-allow-origin"), Some("*"));
    let exposed = r.header("access-control-expose-headers").unwrap();
    for h in ["Content-Range", "Content-Length", "Accept-Ranges", "ETag", "Last-Modified"] {
        assert!(exposed.contains(h), "{h} not in {exposed}");
    }
    let p = s.request(
        "OPTIONS",
        "/ico.strata",
        &["Origin: http://elsewhere.example", "Access-Control-Request-Method: GET", "Access-Control-Request-Headers: range"],
    );
    assert_eq!(p.status, 204);
    assert!(p.body.is_empty());
    assert_eq!(p.header("access-control-allow-origin"), Some("*"));
    assert_eq!(p.header("access-control-allow-methods"), Some("GET, HEAD, OPTIONS"));
    assert_eq!(p.header("access-control-allow-headers"), Some("Range, If-Range, If-None-Match"));
    assert_eq!(p.header("access-control-max-age"), Some("86400"));
}

#[test]
fn paths_outside_the_folder_are_refused() {
    let t = Tree::new();
    let s = t.serve();
    let outside = t.dir.path().join("outside.strata");
    let absolute = outside.to_str().unwrap();
    let attempts = [
        "/../Cargo.toml".to_string(),
        "/%2e%2e/Cargo.toml".to_string(),
        "/..%2fCargo.toml".to_string(),
        "/sub/../../x".to_string(),
        "/%5c..%5cx".to_string(),
        "/etc/passwd".to_string(),
        "/../outside.strata".to_string(),
        "/%2e%2e/outside.strata".to_string(),
        "/%2E%2E%2Foutside.strata".to_string(),
        "/..%2foutside.strata".to_string(),
        "/sub/../../outside.strata".to_string(),
        "/sub/%2e%2e/%2e%2e/outside.strata".to_string(),
        "/..\\outside.strata".to_string(),
        "/%5c..%5coutside.strata".to_string(),
        "/sub/..%5c..%5coutside.strata".to_string(),
        "//outside.strata".to_string(),
        "/./../outside.strata".to_string(),
        "/%00/../outside.strata".to_string(),
        "/ico.strata%00".to_string(),
        "/%zz.strata".to_string(),
        format!("/{absolute}"),
        absolute.to_string(),
        format!("/{}", absolute.trim_start_matches('/')),
        format!("http://{}/../outside.strata", s.addr),
        "/notes.txt".to_string(),
        "/../secret.txt".to_string(),
    ];
    let secret = std::fs::read(&outside).unwrap();
    for path in &attempts {
        let r = s.get(path, &[]);
        assert!((400..500).contains(&r.status), "{path}: {}", r.status);
        assert!(!r.body.windows(6).any(|w| w == b"secret") && r.body != secret && !r.body.starts_with(b"[package]"), "{path}");
    }
    assert_eq!(s.get("/ico.strata", &[]).status, 200);
}

#[cfg(unix)]
#[test]
fn a_link_pointing_outside_is_refused_and_not_listed() {
    let t = Tree::new();
    std::os::unix::fs::symlink(t.dir.path().join("outside.strata"), t.served().join("escape.strata")).unwrap();
    std::os::unix::fs::symlink(t.dir.path(), t.served().join("up")).unwrap();
    std::os::unix::fs::symlink(t.served().join("ico.strata"), t.served().join("alias.strata")).unwrap();
    let s = t.serve();
    for path in ["/escape.strata", "/up/outside.strata", "/up/served/../outside.strata"] {
        let r = s.get(path, &[]);
        assert!((400..500).contains(&r.status), "{path}: {}", r.status);
    }
    let index = String::from_utf8(s.get("/", &[]).body).unwrap();
    assert!(!index.contains("escape.strata") && !index.contains("outside.strata"), "{index}");
    let alias = s.get("/alias.strata", &[]);
    assert_eq!(alias.status, 200);
    assert_eq!(alias.body, t.ico());
}

#[test]
fn the_index_lists_the_models_with_viewer_links() {
    let t = Tree::new();
    let s = t.serve();
    let r = s.get("/", &[]);
    assert_eq!(r.status, 200);
    assert_eq!(r.header("content-type"), Some("text/html; charset=utf-8"));
    let html = String::from_utf8(r.body).unwrap();
    assert!(html.contains("href=\"/viewer/?file=/ico.strata\""), "{html}");
    assert!(html.contains("href=\"/viewer/?file=/sub/nested%20model.strata\""), "{html}");
    assert!(html.contains(">sub/nested model.strata<"), "{html}");
    assert!(!html.contains("notes.txt"), "{html}");
    assert!(html.contains("KiB"), "{html}");
}

#[test]
fn a_single_file_is_served_under_its_name_and_root_redirects_to_the_viewer() {
    let t = Tree::new();
    let file = t.served().join("sub/nested model.strata");
    let s = Server::start(&[file.to_str().unwrap()]);
    assert_eq!(s.first_line, format!("open http://{}/viewer/?file=/nested%20model.strata", s.addr));
    let r = s.get("/", &[]);
    assert_eq!(r.status, 302);
    assert_eq!(r.header("location"), Some("/viewer/?file=/nested%20model.strata"));
    let r = range(&s, "/nested%20model.strata", "bytes=-4");
    assert_eq!(r.status, 206);
    assert_eq!(r.body, &t.ico()[t.ico().len() - 4..]);
    for other in ["/ico.strata", "/sub/nested%20model.strata", "/../ico.strata"] {
        assert!((400..500).contains(&s.get(other, &[]).status), "{other}");
    }
    let v = s.get("/viewer/?file=/nested%20model.strata", &[]);
    assert_eq!(v.status, 200);
    assert_eq!(v.body, std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/viewer/index.html")).unwrap());
}

#[test]
fn startup_errors_name_the_path() {
    let t = Tree::new();
    for (path, says) in
        [(t.served().join("missing.strata"), "missing.strata"), (t.served().join("notes.txt"), "neither a .strata file nor a folder")]
    {
        let o = Command::new(env!("CARGO_BIN_EXE_strata")).args(["serve", path.to_str().unwrap(), "--port", "0"]).output().unwrap();
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(says) && err.contains(path.to_str().unwrap()), "{err}");
        assert!(o.stdout.is_empty());
    }
}

/// The Content-Type the server must give a viewer file.
fn expected_type(path: &Path) -> &'static str {
    match path.extension().and_then(|e| e.to_str()).unwrap_or("") {
        "html" => "text/html; charset=utf-8",
        "js" | "mjs" => "text/javascript",
        "css" => "text/css",
        "json" => "application/json",
        "png" => "image/png",
        "svg" => "image/svg+xml",
        _ => "application/octet-stream",
    }
}

fn files_under(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            files_under(&p, out);
        } else {
            out.push(p);
        }
    }
}

#[test]
fn every_viewer_file_is_served_as_on_disk() {
    let t = Tree::new();
    let s = t.serve();
    let viewer = Path::new(env!("CARGO_MANIFEST_DIR")).join("viewer");
    let mut files = Vec::new();
    files_under(&viewer, &mut files);
    assert!(!files.is_empty());
    for f in &files {
        let rel = f.strip_prefix(&viewer).unwrap().to_str().unwrap().replace('\\', "/");
        let url: String = rel.split('/').map(|seg| seg.replace('%', "%25").replace(' ', "%20")).collect::<Vec<_>>().join("/");
        let r = s.get(&format!("/viewer/{url}"), &[]);
        assert_eq!(r.status, 200, "{rel}");
        assert_eq!(r.body, std::fs::read(f).unwrap(), "{rel}: embedded copy differs from the file (rebuild?)");
        assert_eq!(r.header("content-type"), Some(expected_type(f)), "{rel}");
        assert_eq!(r.header("cache-control"), Some("no-cache"), "{rel}");
        let etag = r.header("etag").unwrap_or_else(|| panic!("{rel}: no ETag"));
        assert_eq!(s.get(&format!("/viewer/{url}"), &[&format!("If-None-Match: {etag}")]).status, 304, "{rel}");
    }
    let index = s.get("/viewer/", &[]);
    assert_eq!(index.status, 200);
    assert_eq!(index.body, std::fs::read(viewer.join("index.html")).unwrap());
    let bare = s.get("/viewer?file=/ico.strata", &[]);
    assert_eq!(bare.status, 302);
    assert_eq!(bare.header("location"), Some("/viewer/?file=/ico.strata"));
    for missing in ["/viewer/no-such-file.js", "/viewer/../Cargo.toml", "/viewer/%2e%2e/Cargo.toml"] {
        assert!((400..500).contains(&s.get(missing, &[]).status), "{missing}");
    }
}

#[test]
fn many_concurrent_clients_get_their_bytes() {
    let t = Tree::new();
    let s = t.serve();
    let data = std::sync::Arc::new(t.ico());
    let addr = s.addr.clone();
    let threads: Vec<_> = (0..32u64)
        .map(|k| {
            let (data, addr) = (data.clone(), addr.clone());
            std::thread::spawn(move || {
                let mut x = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
                let len = data.len() as u64;
                for _ in 0..20 {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    let first = x % len;
                    let last = (first + (x >> 32) % 4096).min(len - 1);
                    let raw =
                        format!("GET /ico.strata HTTP/1.1\r\nHost: {addr}\r\nRange: bytes={first}-{last}\r\nConnection: close\r\n\r\n");
                    let r = send(&addr, &raw);
                    assert_eq!(r.status, 206);
                    assert_eq!(r.body, &data[first as usize..=last as usize]);
                }
            })
        })
        .collect();
    for th in threads {
        th.join().unwrap();
    }
}

#[test]
fn a_client_leaving_mid_response_does_not_stop_the_server_and_big_files_stream() {
    let t = Tree::new();
    // 48 MiB of varied bytes: far more than a socket buffers, so the server is mid-write when the
    // client goes.
    let big: Vec<u8> = (0..48u32 << 20).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
    std::fs::write(t.served().join("big.strata"), &big).unwrap();
    let mut s = t.serve();
    for _ in 0..20 {
        let mut c = TcpStream::connect(&s.addr).unwrap();
        c.write_all(format!("GET /big.strata HTTP/1.1\r\nHost: {}\r\n\r\n", s.addr).as_bytes()).unwrap();
        let mut few = [0u8; 64];
        c.read_exact(&mut few).unwrap();
        drop(c);
    }
    std::thread::sleep(Duration::from_millis(200));
    assert!(s.alive());
    let r = range(&s, "/big.strata", "bytes=40000000-40000099");
    assert_eq!(r.status, 206);
    assert_eq!(r.body, &big[40_000_000..40_000_100]);
    let whole = s.get("/big.strata", &[]);
    assert_eq!(whole.status, 200);
    assert!(whole.body == big, "whole big file differs");
    // Streamed, not read whole: the server's peak memory stays well under the file's size.
    #[cfg(target_os = "linux")]
    {
        let status = std::fs::read_to_string(format!("/proc/{}/status", s.child.id())).unwrap();
        let peak_kib: u64 = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap().split_whitespace().nth(1).unwrap().parse().unwrap();
        assert!(peak_kib < 24 << 10, "peak resident {peak_kib} KiB serving a 48 MiB file");
    }
    assert!(s.alive());
}

#[test]
fn other_methods_get_405_with_allow() {
    let t = Tree::new();
    let s = t.serve();
    for method in ["POST", "PUT", "DELETE"] {
        let r = s.request(method, "/ico.strata", &["Content-Length: 0"]);
        assert_eq!(r.status, 405, "{method}");
        assert_eq!(r.header("allow"), Some("GET, HEAD, OPTIONS"));
    }
}

#[test]
fn log_prints_one_line_per_request() {
    let t = Tree::new();
    let mut s = Server::start_with(&[t.served().to_str().unwrap(), "--log"], Stdio::piped());
    assert!(s.alive());
    let (tx, rx) = std::sync::mpsc::channel();
    let stderr = BufReader::new(s.child.stderr.take().unwrap());
    std::thread::spawn(move || stderr.lines().map_while(Result::ok).for_each(|l| tx.send(l).unwrap_or(())));
    range(&s, "/ico.strata", "bytes=0-9");
    s.get("/missing.strata", &[]);
    // A line is written once its response is sent, so it may come just after the client has it,
    // and after the next request's line.
    let mut lines: Vec<String> = (0..2).map_while(|_| rx.recv_timeout(Duration::from_secs(10)).ok()).collect();
    std::thread::sleep(Duration::from_millis(200));
    lines.extend(rx.try_iter());
    lines.sort();
    let err = lines.join("\n");
    assert_eq!(lines.len(), 2, "{err}");
    assert!(
        lines[0].starts_with("GET /ico.strata")
            && lines[0].contains("bytes=0-9")
            && lines[0].contains("206")
            && lines[0].contains("10 bytes"),
        "{err}"
    );
    assert!(lines[1].starts_with("GET /missing.strata") && lines[1].contains("404"), "{err}");
}

/// Read one response from a kept-alive connection: the head, then exactly Content-Length body bytes.
fn read_one(s: &mut TcpStream) -> std::io::Result<Resp> {
    let mut bytes = Vec::new();
    let mut byte = [0u8; 1];
    while !bytes.ends_with(b"\r\n\r\n") {
        if s.read(&mut byte)? == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        bytes.push(byte[0]);
    }
    let mut resp = parse(&bytes);
    let len: usize = resp.header("content-length").expect("no Content-Length").parse().unwrap();
    resp.body = vec![0; len];
    s.read_exact(&mut resp.body)?;
    Ok(resp)
}

/// A browser opens a page's modules on several kept-alive connections at once and leaves them open.
/// Every request on every accepted connection must be answered, however many connections sit idle:
/// tiny_http (before hyper) lost a wake-up in its per-connection thread pool when connections came
/// faster than its idle threads woke, and the request on the connection left over then sat unread
/// for as long as the others stayed open.
#[test]
fn bursts_of_keep_alive_connections_beside_idle_ones_are_all_answered() {
    let t = Tree::new();
    let s = t.serve();
    let data = t.ico();
    // Eight new connections at once, each sending one request; the answered connections are returned
    // open, with nothing more to say.
    let burst = |round: usize| -> Vec<TcpStream> {
        let barrier = std::sync::Arc::new(std::sync::Barrier::new(8));
        let threads: Vec<_> = (0..8usize)
            .map(|k| {
                let (barrier, addr) = (barrier.clone(), s.addr.clone());
                let raw = format!("GET /ico.strata HTTP/1.1\r\nHost: {addr}\r\nRange: bytes={k}-{}\r\n\r\n", k + 99);
                std::thread::spawn(move || {
                    barrier.wait();
                    let mut c = TcpStream::connect(&addr).unwrap();
                    c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
                    c.write_all(raw.as_bytes()).unwrap();
                    (read_one(&mut c), c)
                })
            })
            .collect();
        let answers: Vec<_> = threads.into_iter().map(|h| h.join().unwrap()).collect();
        answers
            .into_iter()
            .enumerate()
            .map(|(k, (r, c))| {
                let r = r.unwrap_or_else(|e| panic!("round {round}, connection {k}: no answer within 5 s ({e})"));
                assert_eq!(r.status, 206);
                assert_eq!(r.body, &data[k..k + 100]);
                c
            })
            .collect()
    };
    let mut idle = burst(0);
    for round in 1..=20 {
        // Two connections close, so that a few server threads (if it has them) wait for work; the
        // other six stay open and idle, as a browser keeps them.
        let mut open = burst(round);
        open.truncate(6);
        idle.extend(open);
        std::thread::sleep(Duration::from_millis(10));
    }
    // Every idle connection still answers.
    for c in &mut idle {
        c.write_all(format!("GET /viewer/ HTTP/1.1\r\nHost: {}\r\n\r\n", s.addr).as_bytes()).unwrap();
        assert_eq!(read_one(c).unwrap().status, 200);
    }
}

/// A client that shuts its sending side once the request is written still gets the answer.
#[test]
fn a_half_closed_request_is_answered() {
    let t = Tree::new();
    let s = t.serve();
    let mut c = TcpStream::connect(&s.addr).unwrap();
    c.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    c.write_all(format!("GET /ico.strata HTTP/1.1\r\nHost: {}\r\nRange: bytes=0-9\r\n\r\n", s.addr).as_bytes()).unwrap();
    c.shutdown(std::net::Shutdown::Write).unwrap();
    let r = read_one(&mut c).unwrap();
    assert_eq!(r.status, 206);
    assert_eq!(r.body, &t.ico()[..10]);
}
