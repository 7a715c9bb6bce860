//! Test support: start the real `meshsmooth serve` binary on a loopback
//! port, a minimal HTTP/1.1 client, and meshes generated in code.

#![allow(dead_code)] // Each test module uses a different part.

use http_body_util::{BodyExt, Full};
use hyper::body::Bytes;
use hyper::body::Incoming;
use hyper::{Method, Request, StatusCode};
use hyper_util::rt::TokioIo;
use meshsmooth_core::{io, shapes};
use serde_json::Value;
use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read};
use std::net::SocketAddr;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::net::TcpStream;

/// A running `meshsmooth serve` process, killed on drop. Derefs to a
/// [`Client`] of it.
pub struct Server {
    child: Child,
    client: Client,
    stderr: Arc<Mutex<String>>,
}

/// An HTTP/1.1 client of a server (one connection per request).
#[derive(Debug, Clone, Copy)]
pub struct Client {
    /// The server's address.
    pub addr: SocketAddr,
}

impl std::ops::Deref for Server {
    type Target = Client;

    fn deref(&self) -> &Client {
        &self.client
    }
}

impl Server {
    /// Starts the binary on 127.0.0.1, port 0, with test hooks and the
    /// extra `args`.
    pub fn start(args: &[&str]) -> Server {
        let mut child = Command::new(env!("CARGO_BIN_EXE_meshsmooth"))
            .args(["serve", "--listen", "127.0.0.1:0", "--enable-test-hooks"])
            .args(args)
            .env_remove("RUST_LOG")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start meshsmooth serve");
        let stderr = Arc::new(Mutex::new(String::new()));
        let mut err_pipe = child.stderr.take().expect("stderr");
        let sink = stderr.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 8192];
            while let Ok(n) = err_pipe.read(&mut buf) {
                if n == 0 {
                    break;
                }
                sink.lock()
                    .unwrap()
                    .push_str(&String::from_utf8_lossy(&buf[..n]));
            }
        });
        let mut stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let mut line = String::new();
        stdout
            .read_line(&mut line)
            .expect("read the listening line");
        let addr = line
            .trim()
            .strip_prefix("meshsmooth listening on http://")
            .and_then(|a| a.parse().ok())
            .unwrap_or_else(|| {
                let _ = child.kill();
                panic!(
                    "unexpected first stdout line {line:?}; stderr:\n{}",
                    stderr.lock().unwrap()
                )
            });
        // Keep draining stdout so the server never blocks on it.
        std::thread::spawn(move || {
            let mut rest = String::new();
            let _ = stdout.read_to_string(&mut rest);
        });
        Server {
            child,
            client: Client { addr },
            stderr,
        }
    }

    /// A client that can outlive this borrow (for spawned tasks).
    pub fn client(&self) -> Client {
        self.client
    }

    /// The process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Everything the server logged so far.
    pub fn logs(&self) -> String {
        self.stderr.lock().unwrap().clone()
    }

    /// Sends SIGTERM.
    pub fn terminate(&self) {
        let status = Command::new("kill")
            .args(["-TERM", &self.pid().to_string()])
            .status()
            .expect("run kill");
        assert!(status.success());
    }

    /// Waits for the process to exit, up to `timeout`.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let start = Instant::now();
        while start.elapsed() < timeout {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }

    /// Memory high-water mark of the process (VmHWM), in bytes.
    pub fn peak_rss(&self) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.pid()))
            .expect("read /proc status");
        let kib: u64 = status
            .lines()
            .find_map(|l| l.strip_prefix("VmHWM:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            .expect("VmHWM line");
        kib * 1024
    }
}

impl Client {
    /// Sends a request and reads the whole answer.
    pub async fn send(&self, req: Req) -> Resp {
        let response = self.send_streaming(req).await;
        let status = response.status();
        let headers = header_map(response.headers());
        let body = response
            .into_body()
            .collect()
            .await
            .expect("read the body")
            .to_bytes();
        Resp {
            status,
            headers,
            body,
        }
    }

    /// Sends a request; the body is left to the caller.
    pub async fn send_streaming(&self, req: Req) -> hyper::Response<Incoming> {
        let stream = TcpStream::connect(self.addr).await.expect("connect");
        // Small requests and answers: no Nagle delay on top of the server's.
        let _ = stream.set_nodelay(true);
        let (mut sender, connection) = hyper::client::conn::http1::handshake(TokioIo::new(stream))
            .await
            .expect("handshake");
        tokio::spawn(connection);
        let mut builder = Request::builder()
            .method(req.method)
            .uri(req.path)
            .header("host", self.addr.to_string());
        for (name, value) in req.headers {
            builder = builder.header(name, value);
        }
        let request = builder
            .body(Full::new(Bytes::from(req.body)))
            .expect("request");
        sender.send_request(request).await.expect("send request")
    }

    /// `GET path`.
    pub async fn get(&self, path: &str) -> Resp {
        self.send(Req::new(Method::GET, path)).await
    }

    /// `DELETE path`.
    pub async fn delete(&self, path: &str) -> Resp {
        self.send(Req::new(Method::DELETE, path)).await
    }

    /// Polls `GET /v1/jobs/{id}` until the job is finished.
    pub async fn wait_job(&self, id: &str, timeout: Duration) -> Value {
        let start = Instant::now();
        loop {
            let r = self.get(&format!("/v1/jobs/{id}")).await;
            assert_eq!(r.status, StatusCode::OK, "{}", r.text());
            let job = r.json();
            if ["succeeded", "failed", "cancelled"].contains(&job["state"].as_str().unwrap()) {
                return job;
            }
            assert!(
                start.elapsed() < timeout,
                "job {id} not finished after {timeout:?}: {job}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// Polls until `pred` holds for the job.
    pub async fn wait_job_until(&self, id: &str, pred: impl Fn(&Value) -> bool) -> Value {
        let start = Instant::now();
        loop {
            let job = self.get(&format!("/v1/jobs/{id}")).await.json();
            if pred(&job) {
                return job;
            }
            assert!(start.elapsed() < Duration::from_secs(20), "{job}");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    /// The value of a metric sample (`name{labels}` exactly as rendered),
    /// 0 when absent.
    pub async fn metric(&self, sample: &str) -> f64 {
        let text = self.get("/metrics").await.text();
        text.lines()
            .find_map(|l| {
                let (name, value) = l.rsplit_once(' ')?;
                (name == sample).then(|| value.parse().ok())?
            })
            .unwrap_or(0.0)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A request to send.
pub struct Req {
    method: Method,
    path: String,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Req {
    /// A request without a body.
    pub fn new(method: Method, path: &str) -> Req {
        Req {
            method,
            path: path.to_owned(),
            headers: Vec::new(),
            body: Vec::new(),
        }
    }

    /// `POST path` with a raw body of `content_type`.
    pub fn raw(path: &str, content_type: &str, body: impl Into<Vec<u8>>) -> Req {
        Req::new(Method::POST, path)
            .header("content-type", content_type)
            .body(body)
    }

    /// `POST path` with a multipart form of `parts`.
    pub fn multipart(path: &str, parts: &[Part]) -> Req {
        let boundary = "test-boundary-7d1c2a";
        Req::new(Method::POST, path)
            .header(
                "content-type",
                &format!("multipart/form-data; boundary={boundary}"),
            )
            .body(multipart_body(boundary, parts))
    }

    /// Adds a header.
    pub fn header(mut self, name: &str, value: &str) -> Req {
        self.headers.push((name.to_owned(), value.to_owned()));
        self
    }

    /// Sets the body.
    pub fn body(mut self, body: impl Into<Vec<u8>>) -> Req {
        self.body = body.into();
        self
    }
}

/// One part of a multipart form.
pub struct Part {
    /// Part name.
    pub name: &'static str,
    /// File name, if a file.
    pub file_name: Option<&'static str>,
    /// Part Content-Type.
    pub content_type: Option<&'static str>,
    /// Content.
    pub data: Vec<u8>,
}

impl Part {
    /// A `mesh` file part named `mesh.obj`.
    pub fn obj(data: &str) -> Part {
        Part {
            name: "mesh",
            file_name: Some("mesh.obj"),
            content_type: Some("application/octet-stream"),
            data: data.as_bytes().to_vec(),
        }
    }

    /// A `params` JSON part.
    pub fn params(json: &str) -> Part {
        Part {
            name: "params",
            file_name: None,
            content_type: Some("application/json"),
            data: json.as_bytes().to_vec(),
        }
    }
}

fn multipart_body(boundary: &str, parts: &[Part]) -> Vec<u8> {
    let mut body = Vec::new();
    for part in parts {
        body.extend_from_slice(format!("--{boundary}\r\n").as_bytes());
        let mut disposition = format!("Content-Disposition: form-data; name=\"{}\"", part.name);
        if let Some(f) = part.file_name {
            disposition.push_str(&format!("; filename=\"{f}\""));
        }
        body.extend_from_slice(disposition.as_bytes());
        body.extend_from_slice(b"\r\n");
        if let Some(ct) = part.content_type {
            body.extend_from_slice(format!("Content-Type: {ct}\r\n").as_bytes());
        }
        body.extend_from_slice(b"\r\n");
        body.extend_from_slice(&part.data);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    body
}

/// A whole answer.
#[derive(Debug)]
pub struct Resp {
    /// Status.
    pub status: StatusCode,
    /// Headers (lowercase names; repeated headers joined with `, `).
    pub headers: HashMap<String, String>,
    /// Body.
    pub body: Bytes,
}

fn header_map(headers: &hyper::HeaderMap) -> HashMap<String, String> {
    let mut map: HashMap<String, String> = HashMap::new();
    for (name, value) in headers {
        let value = value.to_str().unwrap_or_default().to_owned();
        map.entry(name.as_str().to_owned())
            .and_modify(|v| {
                v.push_str(", ");
                v.push_str(&value);
            })
            .or_insert(value);
    }
    map
}

impl Resp {
    /// The body as text.
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    /// The body as JSON.
    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.text()))
    }

    /// A header's value.
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.get(name).map(String::as_str)
    }

    /// Asserts an RFC 9457 problem with `status` and `code`; returns it.
    #[track_caller]
    pub fn problem(&self, status: u16, code: &str) -> Value {
        assert_eq!(self.status.as_u16(), status, "{}", self.text());
        assert_eq!(
            self.header("content-type"),
            Some("application/problem+json"),
            "{}",
            self.text()
        );
        let p = self.json();
        assert_eq!(p["code"], code, "{p}");
        assert_eq!(p["status"], status, "{p}");
        assert_eq!(p["type"], format!("urn:meshsmooth:problem:{code}"), "{p}");
        assert!(p["title"].as_str().is_some_and(|t| !t.is_empty()), "{p}");
        assert!(p["detail"].as_str().is_some_and(|d| !d.is_empty()), "{p}");
        p
    }
}

/// A voxel sphere ([`shapes::voxel_sphere`]: the boundary quads of the
/// voxels inside the sphere, corners welded, outward-facing) as OBJ text.
/// Returns the text and (vertices, faces).
pub fn voxel_sphere_obj(radius: f64) -> (String, usize, usize) {
    let (_, mesh) = shapes::voxel_sphere(radius);
    let mut obj = Vec::new();
    io::obj::write_obj_plain(&mesh, mesh.positions(), &mut obj).expect("write the OBJ");
    let text = String::from_utf8(obj).expect("OBJ is text");
    (text, mesh.num_vertices(), mesh.num_faces())
}

/// Counts the `v` and `f` lines of an OBJ file, and returns the vertices.
pub fn obj_stats(text: &str) -> (Vec<[f64; 3]>, usize) {
    let mut vertices = Vec::new();
    let mut faces = 0;
    for line in text.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let c: Vec<f64> = words.take(3).map(|w| w.parse().unwrap()).collect();
                vertices.push([c[0], c[1], c[2]]);
            }
            Some("f") => faces += 1,
            _ => {}
        }
    }
    (vertices, faces)
}

/// A small sphere for quick tests: text, vertex count, face count.
pub fn small_sphere() -> (String, usize, usize) {
    voxel_sphere_obj(4.0)
}

/// Job id from a 202 answer.
#[track_caller]
pub fn job_id(r: &Resp) -> String {
    assert_eq!(r.status, StatusCode::ACCEPTED, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_owned();
    assert_eq!(
        r.header("location"),
        Some(format!("/v1/jobs/{id}").as_str())
    );
    id
}

/// A `redis-server` (Debian's package) on a free loopback port, with its
/// data (AOF on) in a temporary directory; killed and removed on drop.
pub struct RedisServer {
    child: Option<Child>,
    /// The port it listens on.
    pub port: u16,
    dir: std::path::PathBuf,
}

impl RedisServer {
    /// Starts a fresh one.
    pub fn start() -> RedisServer {
        static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("meshsmooth-redis-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("create the Redis directory");
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("a free port")
            .port();
        let mut redis = RedisServer {
            child: None,
            port,
            dir,
        };
        redis.resume();
        redis
    }

    /// `--store` value of this server.
    pub fn url(&self) -> String {
        format!("redis://127.0.0.1:{}", self.port)
    }

    /// Starts the server again (same port, same data).
    pub fn resume(&mut self) {
        assert!(self.child.is_none(), "already running");
        let child = Command::new("redis-server")
            .args(["--port", &self.port.to_string(), "--bind", "127.0.0.1"])
            .args(["--save", "", "--appendonly", "yes", "--appendfsync", "always"])
            .arg("--dir")
            .arg(&self.dir)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect(
                "start redis-server (Debian: `apt-get install -y redis-server`; .ci/run installs it)",
            );
        self.child = Some(child);
        let start = Instant::now();
        while !self.answers() {
            assert!(
                start.elapsed() < Duration::from_secs(10),
                "redis-server did not answer on port {}",
                self.port
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Stops the server the polite way (SIGTERM: the AOF is flushed).
    pub fn stop(&mut self) {
        let Some(mut child) = self.child.take() else {
            return;
        };
        let _ = Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status();
        let _ = child.wait();
    }

    /// Freezes (SIGSTOP, `true`) or thaws (SIGCONT, `false`) the server:
    /// it keeps its connections but answers nothing while frozen.
    pub fn freeze(&self, frozen: bool) {
        let child = self.child.as_ref().expect("running");
        let signal = if frozen { "-STOP" } else { "-CONT" };
        let status = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .expect("run kill");
        assert!(status.success());
    }

    /// True when `PING` gets `+PONG`.
    fn answers(&self) -> bool {
        use std::io::Write;
        let Ok(mut s) = std::net::TcpStream::connect(("127.0.0.1", self.port)) else {
            return false;
        };
        let _ = s.set_read_timeout(Some(Duration::from_secs(1)));
        let mut buf = [0u8; 7];
        s.write_all(b"PING\r\n").is_ok() && s.read_exact(&mut buf).is_ok() && &buf == b"+PONG\r\n"
    }
}

impl Drop for RedisServer {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

impl Server {
    /// Kills the process with SIGKILL (no shutdown of any kind).
    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Client {
    /// Follows `GET /v1/jobs/{id}/events` to its end; the jobs of the
    /// `state` events.
    pub async fn events(&self, id: &str, timeout: Duration) -> Vec<Value> {
        let response = self
            .send_streaming(Req::new(Method::GET, &format!("/v1/jobs/{id}/events")))
            .await;
        assert_eq!(response.status(), StatusCode::OK);
        let mut body = response.into_body();
        let mut text = String::new();
        while let Some(frame) = tokio::time::timeout(timeout, body.frame())
            .await
            .expect("events keep coming")
        {
            if let Ok(data) = frame.expect("frame").into_data() {
                text.push_str(&String::from_utf8_lossy(&data));
            }
        }
        text.split("\n\n")
            .filter(|event| event.lines().any(|l| l == "event: state"))
            .filter_map(|event| event.lines().find_map(|l| l.strip_prefix("data: ")))
            .map(|d| serde_json::from_str(d).expect("event data is JSON"))
            .collect()
    }
}
