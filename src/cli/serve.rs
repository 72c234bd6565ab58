//! `strata serve`: an HTTP/1.1 server for chunk files and the web viewer, so that a browser on this
//! machine (or another, with `--bind`) streams a model by byte ranges as it would from any static
//! file host.
//!
//! A folder serves every `.strata` file under it at its relative path, with an index page at `/`; a
//! single file is served under its own name. The viewer's files are embedded in the binary at build
//! time and served under `/viewer/`. Data files answer byte ranges, conditional requests and CORS
//! (a viewer served from elsewhere may read them); nothing outside the folder is ever served.
//!
//! The transport is hyper's HTTP/1.1 on a tokio runtime: one task per connection, so a connection
//! kept alive and idle (as browsers keep several) holds no thread, and every accepted connection is
//! read. Routing and the file system run on tokio's blocking threads; data files are streamed in
//! chunks of [`READ_BUFFER`] bytes as the client takes them, never read whole.

use anyhow::{bail, Context, Result};
use hyper::body::{Body as HttpBody, Bytes, Frame, Incoming, SizeHint};
use hyper::header::{HeaderName, HeaderValue};
use hyper::http::request::Parts;
use hyper::{Method, Request, Response, StatusCode};
use include_dir::{include_dir, Dir};
use std::borrow::Cow;
use std::convert::Infallible;
use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::net::{IpAddr, SocketAddr};
use std::path::{Component, Path, PathBuf};
use std::pin::Pin;
use std::sync::Arc;
use std::task::{ready, Context as TaskContext, Poll};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::io::{AsyncRead, ReadBuf};

/// The viewer (`viewer/` of the source tree), embedded so that installing the binary is enough.
static VIEWER: Dir<'static> = include_dir!("$CARGO_MANIFEST_DIR/viewer");

/// Bytes read from a data file per chunk handed to the socket: a response holds at most a few such
/// chunks in memory, however large the file.
const READ_BUFFER: usize = 64 * 1024;

const ALLOW: &str = "GET, HEAD, OPTIONS";
const EXPOSED: &str = "Content-Range, Content-Length, Accept-Ranges, ETag, Last-Modified";

#[derive(clap::Args)]
pub struct Args {
    /// A .strata file, or a folder whose .strata files (in any subfolder) are all served.
    path: PathBuf,
    /// TCP port; 0 picks a free one (the URL printed names it).
    #[arg(long, default_value_t = 8080)]
    port: u16,
    /// Address to listen on: the default keeps the server to this machine; 0.0.0.0 opens it to the
    /// network.
    #[arg(long, default_value = "127.0.0.1")]
    bind: IpAddr,
    /// One line per request on stderr: method, path, Range header, status, body bytes sent.
    #[arg(long)]
    log: bool,
}

pub fn run(a: Args) -> Result<()> {
    let site = Site::open(&a.path)?;
    // A client that goes away mid-response must cost only that response: writes into its closed
    // socket then fail with an error (which ends that connection) instead of killing the process
    // with SIGPIPE.
    #[cfg(unix)]
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_IGN);
    }
    let at = SocketAddr::new(a.bind, a.port);
    let listener = std::net::TcpListener::bind(at).map_err(|e| anyhow::anyhow!("cannot listen on {at}: {e}"))?;
    let addr = listener.local_addr().context("the server has no address")?;
    listener.set_nonblocking(true).context("cannot listen")?;
    let runtime = tokio::runtime::Builder::new_multi_thread().enable_all().thread_name("strata-serve").build().context("cannot start")?;
    let listener = {
        let _entered = runtime.enter();
        tokio::net::TcpListener::from_std(listener).context("cannot listen")?
    };
    let first = match &site {
        Site::Folder { .. } => format!("serving {} at http://{addr}/", a.path.display()),
        Site::File { name, .. } => format!("open http://{addr}/viewer/?file=/{}", encode_segment(name)),
    };
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{first}").and_then(|_| out.flush());
    drop(out);
    runtime.block_on(accept(listener, Arc::new(site), a.log));
    Ok(())
}

/// Accept connections for ever, each served by a task of its own.
async fn accept(listener: tokio::net::TcpListener, site: Arc<Site>, log: bool) {
    loop {
        let stream = match listener.accept().await {
            Ok((stream, _)) => stream,
            Err(e) => {
                // Out of file descriptors, or a connection reset before it was taken: wait a little
                // (connections still open may close) rather than spin.
                if log {
                    let _ = writeln!(std::io::stderr(), "accept: {e}");
                }
                tokio::time::sleep(Duration::from_millis(10)).await;
                continue;
            }
        };
        // Small responses go out at once instead of waiting for the previous segment's ACK.
        let _ = stream.set_nodelay(true);
        let site = site.clone();
        tokio::spawn(async move {
            let service = hyper::service::service_fn(move |rq| respond(site.clone(), rq, log));
            // A connection's error (a client gone, a malformed request) ends that connection only.
            let _ = hyper::server::conn::http1::Builder::new()
                .keep_alive(true)
                // A client may shut its side once its request is sent (`nc -N`, some scripts): it
                // still gets its answer.
                .half_close(true)
                .title_case_headers(true)
                .serve_connection(hyper_util::rt::TokioIo::new(stream), service)
                .await;
        });
    }
}

/// Answer one request. Routing touches the file system, so it runs on a blocking thread; a panic
/// there answers 500 and touches nothing else.
async fn respond(site: Arc<Site>, rq: Request<Incoming>, log: bool) -> std::result::Result<Response<Out>, Infallible> {
    let (parts, _body) = rq.into_parts();
    let line = log.then(|| {
        let range = header(&parts, "Range").map(|r| format!(" range {r:?}")).unwrap_or_default();
        format!("{} {}{range}", parts.method, parts.uri)
    });
    let head = parts.method == Method::HEAD;
    let reply = tokio::task::spawn_blocking(move || {
        let reply = route(&site, &parts);
        // Seek here, off the runtime's threads.
        match reply.body {
            Body::File { mut file, start, len } => match file.seek(SeekFrom::Start(start)) {
                Ok(_) => Reply { body: Body::File { file, start, len }, ..reply },
                Err(_) => Reply::text(500, "cannot read the file"),
            },
            _ => reply,
        }
    })
    .await
    .unwrap_or_else(|_| Reply::text(500, "internal error"));
    Ok(reply.into_response(head, line))
}

/// What is served besides the viewer.
enum Site {
    /// Every `.strata` file under `root` (canonical).
    Folder { root: PathBuf },
    /// One file, at `/<name>`.
    File { name: String, path: PathBuf },
}

impl Site {
    /// Check the path given on the command line, so that a typo fails at once and not per request.
    fn open(path: &Path) -> Result<Site> {
        let meta = std::fs::metadata(path).with_context(|| format!("cannot serve {}", path.display()))?;
        if meta.is_dir() {
            let root = std::fs::canonicalize(path).with_context(|| format!("cannot serve {}", path.display()))?;
            return Ok(Site::Folder { root });
        }
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        if !meta.is_file() || !name.ends_with(".strata") {
            bail!("{}: neither a .strata file nor a folder", path.display());
        }
        File::open(path).with_context(|| format!("cannot serve {}", path.display()))?;
        let canonical = std::fs::canonicalize(path).with_context(|| format!("cannot serve {}", path.display()))?;
        Ok(Site::File { name: name.to_string(), path: canonical })
    }

    /// The data file a request path names. A path with `..`, `.`, empty segments, backslashes or
    /// NUL is refused before the file system is asked (403), and so is a file that resolves outside
    /// the folder through a link; a path that names no served file is 404.
    fn resolve(&self, path: &str) -> std::result::Result<PathBuf, u16> {
        let segments = decode_path(path)?;
        match self {
            Site::File { name, path } => match segments.as_slice() {
                [only] if only == name => Ok(path.clone()),
                _ => Err(404),
            },
            Site::Folder { root } => {
                if !segments.last().is_some_and(|s| s.ends_with(".strata")) {
                    return Err(404);
                }
                let rel: PathBuf = segments.iter().collect();
                if rel.components().count() != segments.len() || !rel.components().all(|c| matches!(c, Component::Normal(_))) {
                    return Err(403);
                }
                let real = std::fs::canonicalize(root.join(rel)).map_err(|_| 404u16)?;
                if !real.starts_with(root) {
                    return Err(403);
                }
                if !std::fs::metadata(&real).is_ok_and(|m| m.is_file()) {
                    return Err(404);
                }
                Ok(real)
            }
        }
    }
}

/// The segments of a request path (`/a/b%20c` → `a`, `b c`), percent-decoded: 400 for a bad escape
/// or non-UTF-8, 403 for a segment that could climb or hide a separator.
fn decode_path(path: &str) -> std::result::Result<Vec<String>, u16> {
    let rest = path.strip_prefix('/').ok_or(400u16)?;
    rest.split('/')
        .map(|raw| {
            let seg = String::from_utf8(percent_decode(raw).ok_or(400u16)?).map_err(|_| 400u16)?;
            if seg.is_empty() || seg == "." || seg == ".." || seg.contains(['/', '\\', '\0']) {
                return Err(403);
            }
            Ok(seg)
        })
        .collect()
}

/// `%XX` escapes decoded; `None` for a `%` not followed by two hex digits.
fn percent_decode(s: &str) -> Option<Vec<u8>> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = std::str::from_utf8(b.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    Some(out)
}

/// One path segment percent-encoded: everything but RFC 3986's unreserved characters.
fn encode_segment(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for &b in s.as_bytes() {
        if b.is_ascii_alphanumeric() || matches!(b, b'-' | b'.' | b'_' | b'~') {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// A relative path (`/`-separated) percent-encoded segment by segment.
fn encode_path(rel: &str) -> String {
    rel.split('/').map(encode_segment).collect::<Vec<_>>().join("/")
}

fn html_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// A response before it is sent.
struct Reply {
    status: u16,
    headers: Vec<(&'static str, String)>,
    body: Body,
}

enum Body {
    Bytes(Cow<'static, [u8]>),
    /// No body, with Content-Length saying this many bytes: a 304's, the length a 200 would have.
    Headless(u64),
    /// `len` bytes of a file from `start`, streamed.
    File {
        file: File,
        start: u64,
        len: u64,
    },
}

impl Reply {
    fn bytes(status: u16, content_type: &str, body: impl Into<Cow<'static, [u8]>>) -> Reply {
        Reply { status, headers: vec![("Content-Type", content_type.to_string())], body: Body::Bytes(body.into()) }
    }

    /// A short plain-text answer, for errors.
    fn text(status: u16, text: &str) -> Reply {
        Reply::bytes(status, "text/plain; charset=utf-8", format!("{text}\n").into_bytes())
    }

    fn empty(status: u16) -> Reply {
        Reply { status, headers: Vec::new(), body: Body::Bytes(Cow::Borrowed(&[])) }
    }

    fn redirect(to: String) -> Reply {
        Reply::text(302, &format!("see {to}")).with("Location", to)
    }

    fn with(mut self, name: &'static str, value: impl Into<String>) -> Reply {
        self.headers.push((name, value.into()));
        self
    }

    fn body_len(&self) -> u64 {
        match &self.body {
            Body::Bytes(b) => b.len() as u64,
            Body::Headless(len) | Body::File { len, .. } => *len,
        }
    }
}

impl Reply {
    /// The response hyper sends: the exact length always (never chunked), so that a range's
    /// Content-Length is exact; for HEAD the length a GET would have, and no body.
    fn into_response(self, head: bool, log: Option<String>) -> Response<Out> {
        let status = StatusCode::from_u16(self.status).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
        let body = if head { Body::Headless(self.body_len()) } else { self.body };
        let mut headers: Vec<(&str, Cow<str>)> = vec![
            ("Server", Cow::Borrowed(concat!("strata/", env!("CARGO_PKG_VERSION")))),
            ("Access-Control-Allow-Origin", Cow::Borrowed("*")),
            ("Access-Control-Expose-Headers", Cow::Borrowed(EXPOSED)),
        ];
        headers.extend(self.headers.iter().map(|(k, v)| (*k, Cow::Borrowed(v.as_str()))));
        let kind = match body {
            Body::Bytes(Cow::Borrowed(b)) => Kind::Bytes(Some(Bytes::from_static(b))),
            Body::Bytes(Cow::Owned(b)) => Kind::Bytes(Some(Bytes::from(b))),
            Body::Headless(len) => {
                // hyper sends this Content-Length on a HEAD answer and drops it from a 304's.
                headers.push(("Content-Length", Cow::Owned(len.to_string())));
                Kind::Empty
            }
            Body::File { file, len, .. } => Kind::File { file: tokio::fs::File::from_std(file), left: len, buf: Vec::new() },
        };
        let mut response = Response::new(Out { kind, sent: 0, status: status.as_u16(), log });
        *response.status_mut() = status;
        let map = response.headers_mut();
        for (k, v) in headers {
            if let (Ok(k), Ok(v)) = (HeaderName::from_bytes(k.as_bytes()), HeaderValue::from_str(&v)) {
                map.append(k, v);
            }
        }
        response
    }
}

/// A response body as hyper pulls it. With `--log`, its line is written when it is dropped: once
/// its last byte is handed to the connection, or when the client has gone.
struct Out {
    kind: Kind,
    /// Body bytes handed to the connection.
    sent: u64,
    status: u16,
    log: Option<String>,
}

enum Kind {
    Empty,
    Bytes(Option<Bytes>),
    /// `left` more bytes of `file` from its position, read a chunk at a time into `buf`.
    File {
        file: tokio::fs::File,
        left: u64,
        buf: Vec<u8>,
    },
}

impl HttpBody for Out {
    type Data = Bytes;
    type Error = std::io::Error;

    fn poll_frame(self: Pin<&mut Self>, cx: &mut TaskContext<'_>) -> Poll<Option<std::result::Result<Frame<Bytes>, std::io::Error>>> {
        let this = self.get_mut();
        let chunk = match &mut this.kind {
            Kind::Empty => None,
            Kind::Bytes(b) => b.take(),
            Kind::File { left: 0, .. } => None,
            Kind::File { file, left, buf } => {
                if buf.is_empty() {
                    *buf = vec![0; (*left).min(READ_BUFFER as u64) as usize];
                }
                let mut read = ReadBuf::new(buf);
                ready!(Pin::new(file).poll_read(cx, &mut read))?;
                let n = read.filled().len();
                if n == 0 {
                    // The file shrank since its length was announced: end the connection.
                    return Poll::Ready(Some(Err(std::io::ErrorKind::UnexpectedEof.into())));
                }
                *left -= n as u64;
                let mut chunk = std::mem::take(buf);
                chunk.truncate(n);
                Some(Bytes::from(chunk))
            }
        };
        Poll::Ready(chunk.map(|c| {
            this.sent += c.len() as u64;
            Ok(Frame::data(c))
        }))
    }

    fn is_end_stream(&self) -> bool {
        self.size_hint().exact() == Some(0)
    }

    fn size_hint(&self) -> SizeHint {
        SizeHint::with_exact(match &self.kind {
            Kind::Empty => 0,
            Kind::Bytes(b) => b.as_ref().map_or(0, |b| b.len() as u64),
            Kind::File { left, .. } => *left,
        })
    }
}

impl Drop for Out {
    fn drop(&mut self) {
        if let Some(line) = self.log.take() {
            let _ = writeln!(std::io::stderr(), "{line} -> {}, {} bytes", self.status, self.sent);
        }
    }
}

/// A request header's value, if present and plain text.
fn header<'a>(rq: &'a Parts, name: &'static str) -> Option<&'a str> {
    rq.headers.get(name).and_then(|v| v.to_str().ok())
}

fn route(site: &Site, rq: &Parts) -> Reply {
    match rq.method {
        Method::GET | Method::HEAD => {}
        Method::OPTIONS => {
            return Reply::empty(204)
                .with("Access-Control-Allow-Methods", ALLOW)
                .with("Access-Control-Allow-Headers", "Range, If-Range, If-None-Match")
                .with("Access-Control-Max-Age", "86400")
                .with("Allow", ALLOW)
        }
        _ => return Reply::text(405, "method not allowed").with("Allow", ALLOW),
    }
    // The target as sent, less the scheme and host of an absolute-form one (`GET http://h/p`).
    let url = rq.uri.path_and_query().map_or("", |p| p.as_str());
    let (path, query) = url.split_once('?').unwrap_or((url, ""));
    if !path.starts_with('/') {
        return Reply::text(400, "bad request target");
    }
    if path == "/" {
        return match site {
            Site::Folder { root } => index_page(root),
            Site::File { name, .. } => Reply::redirect(format!("/viewer/?file=/{}", encode_segment(name))),
        };
    }
    if path == "/viewer" {
        let query = if query.is_empty() { String::new() } else { format!("?{query}") };
        return Reply::redirect(format!("/viewer/{query}"));
    }
    if let Some(rest) = path.strip_prefix("/viewer/") {
        return asset(rest, rq);
    }
    match site.resolve(path) {
        Ok(file) => data_file(&file, rq),
        Err(403) => Reply::text(403, "refused: outside the served folder"),
        Err(status) => Reply::text(status, if status == 404 { "not found" } else { "bad path" }),
    }
}

/// An embedded viewer file; a path ending in `/` names that folder's index.html.
fn asset(rest: &str, rq: &Parts) -> Reply {
    let mut rel = rest.to_string();
    if rel.is_empty() || rel.ends_with('/') {
        rel.push_str("index.html");
    }
    let segments = match decode_path(&format!("/{rel}")) {
        Ok(s) => s,
        Err(status) => return Reply::text(status, "bad path"),
    };
    let Some(file) = VIEWER.get_file(segments.join("/")) else { return Reply::text(404, "not found") };
    let contents = file.contents();
    let etag = format!("\"{:08x}\"", crc32fast::hash(contents));
    let reply = if header(rq, "If-None-Match").is_some_and(|v| none_match(v, &etag)) {
        Reply { status: 304, headers: Vec::new(), body: Body::Headless(contents.len() as u64) }
    } else {
        Reply::bytes(200, content_type(&segments.join("/")), contents)
    };
    reply.with("ETag", etag).with("Cache-Control", "no-cache")
}

/// The Content-Type of a file by its extension; ES modules need a JavaScript type.
fn content_type(name: &str) -> &'static str {
    let ext = name.rsplit_once('.').map(|(_, e)| e.to_ascii_lowercase()).unwrap_or_default();
    match ext.as_str() {
        "html" | "htm" => "text/html; charset=utf-8",
        "js" | "mjs" => "text/javascript",
        "css" => "text/css",
        "json" => "application/json",
        "png" => "image/png",
        "svg" => "image/svg+xml",
        _ => "application/octet-stream",
    }
}

/// Whether an If-None-Match value lists `etag` (weak comparison, RFC 9110 §13.1.2).
fn none_match(value: &str, etag: &str) -> bool {
    let weakless = |t: &str| t.trim().trim_start_matches("W/").to_string();
    value.trim() == "*" || value.split(',').any(|t| weakless(t) == weakless(etag))
}

/// A data file, whole or one byte range, honouring If-None-Match, If-Modified-Since and If-Range.
fn data_file(path: &Path, rq: &Parts) -> Reply {
    let opened = File::open(path).and_then(|f| f.metadata().map(|m| (f, m)));
    let Ok((file, meta)) = opened else { return Reply::text(404, "not found") };
    if !meta.is_file() {
        return Reply::text(404, "not found");
    }
    let len = meta.len();
    let modified = meta.modified().unwrap_or(UNIX_EPOCH);
    let nanos = modified.duration_since(UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
    let etag = format!("\"{len:x}-{nanos:x}\"");
    let last_modified = httpdate::fmt_http_date(modified);
    let validators = |r: Reply| r.with("ETag", etag.clone()).with("Last-Modified", last_modified.clone()).with("Accept-Ranges", "bytes");

    let not_modified = match (header(rq, "If-None-Match"), header(rq, "If-Modified-Since")) {
        (Some(v), _) => none_match(v, &etag),
        (None, Some(date)) => httpdate::parse_http_date(date).is_ok_and(|since| whole_seconds(modified) <= since),
        (None, None) => false,
    };
    if not_modified {
        return validators(Reply { status: 304, headers: Vec::new(), body: Body::Headless(len) });
    }
    let range_applies = match header(rq, "If-Range") {
        None => true,
        Some(v) if v.trim().starts_with('"') => v.trim() == etag,
        Some(v) => httpdate::parse_http_date(v.trim()).is_ok_and(|d| d == whole_seconds(modified)),
    };
    let ask = match header(rq, "Range") {
        Some(r) if range_applies => parse_range(r, len),
        _ => RangeAsk::Whole,
    };
    let reply = match ask {
        RangeAsk::Whole => Reply { status: 200, headers: Vec::new(), body: Body::File { file, start: 0, len } },
        RangeAsk::Part(first, last) => {
            Reply { status: 206, headers: Vec::new(), body: Body::File { file, start: first, len: last - first + 1 } }
                .with("Content-Range", format!("bytes {first}-{last}/{len}"))
        }
        RangeAsk::Unsatisfiable => Reply::empty(416).with("Content-Range", format!("bytes */{len}")),
    };
    validators(reply.with("Content-Type", content_type(".strata")))
}

/// A time as HTTP dates carry it, to the second.
fn whole_seconds(t: SystemTime) -> SystemTime {
    let secs = t.duration_since(UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    UNIX_EPOCH + Duration::from_secs(secs)
}

/// What a Range header asks of a file of some length (RFC 9110 §14.1.2).
#[derive(Debug, PartialEq)]
enum RangeAsk {
    /// The whole file: no usable range. A server may ignore a Range header (RFC 9110 §14.2), so a
    /// malformed one, another unit, or several ranges (which would need a multipart body) get 200.
    Whole,
    /// Bytes `first..=last`, clamped to the file.
    Part(u64, u64),
    /// 416: the range starts at or past the end, or is an empty suffix.
    Unsatisfiable,
}

fn parse_range(value: &str, len: u64) -> RangeAsk {
    let value = value.trim();
    let Some(spec) = value.get(..6).filter(|u| u.eq_ignore_ascii_case("bytes=")).map(|_| value[6..].trim()) else {
        return RangeAsk::Whole;
    };
    if spec.contains(',') {
        return RangeAsk::Whole;
    }
    let Some((a, b)) = spec.split_once('-') else { return RangeAsk::Whole };
    match (number(a), number(b)) {
        (None, Some(n)) if a.is_empty() => {
            if n == 0 || len == 0 {
                RangeAsk::Unsatisfiable
            } else {
                RangeAsk::Part(len - n.min(len), len - 1)
            }
        }
        (Some(first), None) if b.is_empty() => {
            if first >= len {
                RangeAsk::Unsatisfiable
            } else {
                RangeAsk::Part(first, len - 1)
            }
        }
        (Some(first), Some(last)) if first <= last => {
            if first >= len {
                RangeAsk::Unsatisfiable
            } else {
                RangeAsk::Part(first, last.min(len - 1))
            }
        }
        _ => RangeAsk::Whole,
    }
}

/// A non-empty run of decimal digits; a value past u64 saturates (it is past any file's end).
fn number(s: &str) -> Option<u64> {
    if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    Some(s.bytes().fold(0u64, |n, d| n.saturating_mul(10).saturating_add(u64::from(d - b'0'))))
}

/// The folder's `.strata` files (relative path, size), sorted; links to files are followed when
/// they stay inside the folder, links to folders are not (no cycles).
fn models(root: &Path) -> Vec<(String, u64)> {
    fn walk(root: &Path, dir: &Path, prefix: &str, out: &mut Vec<(String, u64)>) {
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        for entry in entries.flatten() {
            let Ok(name) = entry.file_name().into_string() else { continue };
            let Ok(kind) = entry.file_type() else { continue };
            let rel = format!("{prefix}{name}");
            if kind.is_dir() {
                walk(root, &entry.path(), &format!("{rel}/"), out);
            } else if name.ends_with(".strata") {
                let inside = kind.is_file() || std::fs::canonicalize(entry.path()).is_ok_and(|p| p.starts_with(root));
                match std::fs::metadata(entry.path()) {
                    Ok(m) if inside && m.is_file() => out.push((rel, m.len())),
                    _ => {}
                }
            }
        }
    }
    let mut out = Vec::new();
    walk(root, root, "", &mut out);
    out.sort();
    out
}

/// `/` in folder mode: the models, each linked to the viewer.
fn index_page(root: &Path) -> Reply {
    // The folder's name only: the page may be seen from other machines (`--bind`).
    let title = html_escape(&root.file_name().map(|n| n.to_string_lossy()).unwrap_or_default());
    let mut html = format!(
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>strata: {title}</title>\n\
         <style>body{{font-family:sans-serif;margin:2em}}td{{padding:.2em 1.5em .2em 0}}td.size{{text-align:right}}</style></head>\n\
         <body><h1>{title}</h1>\n"
    );
    let list = models(root);
    if list.is_empty() {
        html.push_str("<p>No .strata files here.</p>\n");
    } else {
        html.push_str("<table>\n<tr><th>model</th><th>size</th></tr>\n");
        for (rel, size) in &list {
            let href = html_escape(&format!("/viewer/?file=/{}", encode_path(rel)));
            html.push_str(&format!(
                "<tr><td><a href=\"{href}\">{}</a></td><td class=\"size\">{}</td></tr>\n",
                html_escape(rel),
                human(*size)
            ));
        }
        html.push_str("</table>\n");
    }
    html.push_str("</body></html>\n");
    Reply::bytes(200, "text/html; charset=utf-8", html.into_bytes()).with("Cache-Control", "no-cache")
}

/// A byte count for people: `812 B`, `4.2 MiB`.
fn human(bytes: u64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = bytes as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < units.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{bytes} B")
    } else {
        format!("{v:.1} {}", units[u])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges() {
        assert_eq!(parse_range("bytes=0-0", 10), RangeAsk::Part(0, 0));
        assert_eq!(parse_range("bytes=2-", 10), RangeAsk::Part(2, 9));
        assert_eq!(parse_range("bytes=-3", 10), RangeAsk::Part(7, 9));
        assert_eq!(parse_range("bytes=-30", 10), RangeAsk::Part(0, 9));
        assert_eq!(parse_range("bytes=5-99", 10), RangeAsk::Part(5, 9));
        assert_eq!(parse_range("BYTES=1-2", 10), RangeAsk::Part(1, 2));
        assert_eq!(parse_range("bytes=10-", 10), RangeAsk::Unsatisfiable);
        assert_eq!(parse_range("bytes=-0", 10), RangeAsk::Unsatisfiable);
        assert_eq!(parse_range("bytes=99999999999999999999999-", 10), RangeAsk::Unsatisfiable);
        for bad in ["bytes=3-2", "bytes=0-1,4-5", "items=0-1", "bytes=a-b", "bytes=-", "bytes=1", "0-1", "bytes= 1-2x"] {
            assert_eq!(parse_range(bad, 10), RangeAsk::Whole, "{bad}");
        }
    }

    #[test]
    fn paths() {
        assert_eq!(decode_path("/a/b%20c.strata"), Ok(vec!["a".to_string(), "b c.strata".to_string()]));
        for refused in ["/../x", "/%2e%2e/x", "/..%2fx", "/a//b", "/%5c..%5cx", "/a/./b", "/x%00.strata", "/a/"] {
            assert_eq!(decode_path(refused), Err(403), "{refused}");
        }
        assert_eq!(decode_path("/%zz"), Err(400));
        assert_eq!(decode_path("/%ff"), Err(400));
        assert_eq!(encode_path("a b/c&d.strata"), "a%20b/c%26d.strata");
    }
}
