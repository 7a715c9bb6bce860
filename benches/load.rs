//! Load benchmark of `meshsmooth serve` (not a timed test).
//!
//! Starts the real binary, uploads generated voxel spheres of about 10k,
//! 100k and 228k vertices to `POST /v1/smooth` from 1, 4 and 16 concurrent
//! clients, and reports throughput and latency percentiles; then times
//! `meshsmooth smooth` (the CLI) on the same meshes and reports the
//! server's overhead per request (end-to-end time minus the CLI's time).
//!
//! With `-- --store redis://HOST:PORT`, every table is also measured with
//! the server on that Redis store, beside the default memory store, and a
//! table compares one client going through the job API (`POST /v1/jobs`,
//! polls, mesh and report) on each store.
//!
//! Run: `cargo bench --bench load [-- --store redis://…]`. Settings
//! (environment):
//! - `MESHSMOOTH_BENCH_SIZES`: vertex targets, comma separated
//!   (default `10000,100000,228000`);
//! - `MESHSMOOTH_BENCH_CLIENTS`: concurrency levels (default `1,4,16`);
//! - `MESHSMOOTH_BENCH_REQUESTS`: requests per level (default: the larger
//!   of 8 and the concurrency);
//! - `MESHSMOOTH_BENCH_QUERY`: query string of parameters (default: none,
//!   the default Wang-Yu parameters);
//! - `MESHSMOOTH_BENCH_MESH`: an extra OBJ file to include.

use http_body_util::{BodyExt, Full};
use hyper::Request;
use hyper::body::Bytes;
use hyper_util::rt::TokioIo;
use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::net::TcpStream;

fn env_list(name: &str, default: &str) -> Vec<usize> {
    std::env::var(name)
        .unwrap_or_else(|_| default.to_owned())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect()
}

/// Voxel-sphere boundary quads as OBJ text, and its vertex count.
fn voxel_sphere(radius: f64) -> (String, usize) {
    let n = radius.ceil() as i64 + 1;
    let inside = |i: i64, j: i64, k: i64| {
        let c = [i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5];
        c[0] * c[0] + c[1] * c[1] + c[2] * c[2] <= radius * radius
    };
    let mut ids: HashMap<[i64; 3], usize> = HashMap::new();
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for i in -n..n {
        for j in -n..n {
            for k in -n..n {
                if !inside(i, j, k) {
                    continue;
                }
                for axis in 0..3 {
                    for sign in [1i64, -1] {
                        let mut q = [i, j, k];
                        q[axis] += sign;
                        if inside(q[0], q[1], q[2]) {
                            continue;
                        }
                        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
                        let mut base = [i, j, k];
                        if sign > 0 {
                            base[axis] += 1;
                        }
                        let mut p1 = base;
                        p1[b] += 1;
                        let mut p2 = p1;
                        p2[c] += 1;
                        let mut p3 = base;
                        p3[c] += 1;
                        let mut quad = [base, p1, p2, p3].map(|p| {
                            *ids.entry(p).or_insert_with(|| {
                                vertices.push(p);
                                vertices.len()
                            })
                        });
                        if sign < 0 {
                            quad.reverse();
                        }
                        faces.push(quad);
                    }
                }
            }
        }
    }
    let mut text = String::with_capacity(vertices.len() * 40 + faces.len() * 40);
    for v in &vertices {
        text.push_str(&format!("v {} {} {}\n", v[0], v[1], v[2]));
    }
    for f in &faces {
        text.push_str(&format!("f {} {} {} {}\n", f[0], f[1], f[2], f[3]));
    }
    (text, vertices.len())
}

/// The voxel sphere whose vertex count is closest to `target` (the count
/// grows like the radius squared: about 19 r^2).
fn sphere_near(target: usize) -> (String, usize) {
    let guess = (target as f64 / 19.0).sqrt();
    let mut best = voxel_sphere(guess);
    for step in [0.5, 0.25, 0.1] {
        for radius in [guess - step, guess + step] {
            let candidate = voxel_sphere(radius);
            if candidate.1.abs_diff(target) < best.1.abs_diff(target) {
                best = candidate;
            }
        }
    }
    best
}

struct Outcome {
    latency: Duration,
    run_seconds: f64,
}

async fn smooth_once(addr: SocketAddr, path: &str, body: Bytes) -> Outcome {
    let start = Instant::now();
    loop {
        let (status, headers, _) = send(addr, "POST", path, Some(body.clone())).await;
        if status == 503 {
            let wait = headers
                .get("retry-after")
                .and_then(|v| v.parse().ok())
                .unwrap_or(1);
            tokio::time::sleep(Duration::from_secs(wait)).await;
            continue;
        }
        assert_eq!(status, 200, "smoothing failed");
        let latency = start.elapsed();
        let id = headers.get("x-job-id").cloned().unwrap_or_default();
        let (_, _, job) = send(addr, "GET", &format!("/v1/jobs/{id}"), None).await;
        let job: serde_json::Value = serde_json::from_slice(&job).unwrap_or_default();
        let run_seconds = job["run_seconds"].as_f64().unwrap_or(f64::NAN);
        return Outcome {
            latency,
            run_seconds,
        };
    }
}

/// `requests` one-call requests from `clients` concurrent clients.
async fn load(
    addr: SocketAddr,
    path: &str,
    body: &Bytes,
    clients: usize,
    requests: usize,
) -> Vec<Outcome> {
    let next = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let tasks: Vec<_> = (0..clients)
        .map(|_| {
            let next = next.clone();
            let body = body.clone();
            let path = path.to_owned();
            tokio::spawn(async move {
                let mut mine = Vec::new();
                while next.fetch_add(1, std::sync::atomic::Ordering::Relaxed) < requests {
                    mine.push(smooth_once(addr, &path, body.clone()).await);
                }
                mine
            })
        })
        .collect();
    let mut all = Vec::new();
    for t in tasks {
        all.extend(t.await.expect("client task"));
    }
    all
}

/// One job through the job API: submit, poll until finished, fetch the
/// mesh and the report. Returns the whole time.
async fn job_api_once(addr: SocketAddr, path: &str, body: Bytes) -> Duration {
    let start = Instant::now();
    let (status, _, job) = send(addr, "POST", path, Some(body)).await;
    assert_eq!(status, 202, "submit failed");
    let job: serde_json::Value = serde_json::from_slice(&job).unwrap_or_default();
    let id = job["id"].as_str().unwrap_or_default().to_owned();
    loop {
        let (status, _, job) = send(addr, "GET", &format!("/v1/jobs/{id}"), None).await;
        assert_eq!(status, 200, "poll failed");
        let job: serde_json::Value = serde_json::from_slice(&job).unwrap_or_default();
        match job["state"].as_str() {
            Some("succeeded") => break,
            Some("queued" | "running") => tokio::time::sleep(Duration::from_millis(20)).await,
            other => panic!("job ended {other:?}"),
        }
    }
    for part in ["mesh", "report"] {
        let (status, _, _) = send(addr, "GET", &format!("/v1/jobs/{id}/{part}"), None).await;
        assert_eq!(status, 200, "fetching the {part} failed");
    }
    let _ = send(addr, "DELETE", &format!("/v1/jobs/{id}"), None).await;
    start.elapsed()
}

/// Starts `meshsmooth serve` on `store`; the process and its address.
fn start_server(bin: &str, store: &str) -> (std::process::Child, SocketAddr) {
    let mut server = Command::new(bin)
        .args(["serve", "--listen", "127.0.0.1:0", "--queue-capacity", "64"])
        .args(["--log", "warn", "--store", store])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start the server");
    let mut line = String::new();
    BufReader::new(server.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("listening line");
    let addr: SocketAddr = line
        .trim()
        .strip_prefix("meshsmooth listening on http://")
        .and_then(|a| a.parse().ok())
        .expect("bound address");
    (server, addr)
}

/// The `--store` argument after `--`, if any.
fn store_argument() -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == "--store")
        .and_then(|i| args.get(i + 1).cloned())
        .or_else(|| {
            args.iter()
                .find_map(|a| a.strip_prefix("--store=").map(str::to_owned))
        })
}

async fn send(
    addr: SocketAddr,
    method: &str,
    path: &str,
    body: Option<Bytes>,
) -> (u16, HashMap<String, String>, Bytes) {
    let stream = TcpStream::connect(addr).await.expect("connect");
    let _ = stream.set_nodelay(true);
    let (mut sender, conn) = hyper::client::conn::http1::handshake(TokioIo::new(stream))
        .await
        .expect("handshake");
    tokio::spawn(conn);
    let req = Request::builder()
        .method(method)
        .uri(path)
        .header("host", addr.to_string())
        .header("content-type", "model/obj")
        .body(Full::new(body.unwrap_or_default()))
        .expect("request");
    let response = sender.send_request(req).await.expect("send");
    let status = response.status().as_u16();
    let headers = response
        .headers()
        .iter()
        .map(|(k, v)| {
            (
                k.as_str().to_owned(),
                v.to_str().unwrap_or_default().to_owned(),
            )
        })
        .collect();
    let body = response
        .into_body()
        .collect()
        .await
        .expect("body")
        .to_bytes();
    (status, headers, body)
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (p / 100.0 * (sorted.len() - 1) as f64).round() as usize;
    sorted[rank.min(sorted.len() - 1)]
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    percentile(&v, 50.0)
}

/// Times one run of `meshsmooth smooth` on `input`.
fn cli_seconds(bin: &str, input: &std::path::Path, query: &str) -> f64 {
    let output = input.with_extension("out.obj");
    let mut args: Vec<String> = vec![
        "smooth".into(),
        input.display().to_string(),
        "-o".into(),
        output.display().to_string(),
        "-q".into(),
    ];
    if !query.is_empty() {
        let params: serde_json::Map<String, serde_json::Value> = query
            .split('&')
            .filter_map(|kv| kv.split_once('='))
            .map(|(k, v)| {
                let value = serde_json::from_str(v).unwrap_or_else(|_| v.into());
                (k.to_owned(), value)
            })
            .collect();
        let file = input.with_extension("params.json");
        std::fs::write(&file, serde_json::Value::Object(params).to_string()).expect("params");
        args.push("--params".into());
        args.push(file.display().to_string());
    }
    let start = Instant::now();
    let status = Command::new(bin)
        .args(&args)
        .stdout(Stdio::null())
        .status()
        .expect("run the CLI");
    assert!(status.success(), "meshsmooth smooth failed");
    start.elapsed().as_secs_f64()
}

/// Alternating CLI/server rounds in the overhead table.
const OVERHEAD_ROUNDS: usize = 3;
/// Jobs per store in the job API table.
const JOB_API_ROUNDS: usize = 10;

fn main() {
    let bin = env!("CARGO_BIN_EXE_meshsmooth");
    let sizes = env_list("MESHSMOOTH_BENCH_SIZES", "10000,100000,228000");
    let clients = env_list("MESHSMOOTH_BENCH_CLIENTS", "1,4,16");
    let fixed_requests = env_list("MESHSMOOTH_BENCH_REQUESTS", "").first().copied();
    let query = std::env::var("MESHSMOOTH_BENCH_QUERY").unwrap_or_default();
    let path = if query.is_empty() {
        "/v1/smooth".to_owned()
    } else {
        format!("/v1/smooth?{query}")
    };
    let dir = std::env::temp_dir().join(format!("meshsmooth-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");

    let mut meshes: Vec<(String, usize, Bytes)> = sizes
        .iter()
        .map(|&target| {
            let (text, vertices) = sphere_near(target);
            (
                format!("voxel sphere {vertices}"),
                vertices,
                Bytes::from(text),
            )
        })
        .collect();
    if let Ok(extra) = std::env::var("MESHSMOOTH_BENCH_MESH") {
        let text = std::fs::read(&extra).expect("read MESHSMOOTH_BENCH_MESH");
        let vertices = text
            .split(|&b| b == b'\n')
            .filter(|l| l.starts_with(b"v "))
            .count();
        meshes.push((extra, vertices, Bytes::from(text)));
    }

    let stores: Vec<String> = std::iter::once("memory".to_owned())
        .chain(store_argument())
        .collect();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");

    println!("# meshsmooth load benchmark");
    println!(
        "workers = {cores} (cores), stores: {}, parameters: {}",
        stores.join(", "),
        if query.is_empty() { "defaults" } else { &query }
    );
    println!();
    println!(
        "| store | mesh | vertices | MB | clients | requests | req/s | Mvertices/s | min s | p50 s | p90 s | p99 s | max s | mean run s |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut single_client = Vec::new();
    // One server per store, all up for the whole run.
    let servers: Vec<(String, std::process::Child, SocketAddr)> = stores
        .iter()
        .map(|store| {
            let (child, addr) = start_server(bin, store);
            (store.clone(), child, addr)
        })
        .collect();
    for (store, _, addr) in &servers {
        for (name, vertices, body) in &meshes {
            for &c in &clients {
                let requests = fixed_requests.unwrap_or(c.max(8));
                let start = Instant::now();
                let outcomes = runtime.block_on(load(*addr, &path, body, c, requests));
                let wall = start.elapsed().as_secs_f64();
                let mut lat: Vec<f64> = outcomes.iter().map(|o| o.latency.as_secs_f64()).collect();
                lat.sort_by(f64::total_cmp);
                let run_mean =
                    outcomes.iter().map(|o| o.run_seconds).sum::<f64>() / outcomes.len() as f64;
                println!(
                    "| {store} | {name} | {vertices} | {:.1} | {c} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
                    body.len() as f64 / 1e6,
                    outcomes.len(),
                    outcomes.len() as f64 / wall,
                    (outcomes.len() * vertices) as f64 / wall / 1e6,
                    lat.first().copied().unwrap_or(f64::NAN),
                    percentile(&lat, 50.0),
                    percentile(&lat, 90.0),
                    percentile(&lat, 99.0),
                    lat.last().copied().unwrap_or(f64::NAN),
                    run_mean,
                );
            }
        }
    }
    for (_, vertices, body) in &meshes {
        let file = dir.join(format!("{vertices}.obj"));
        std::fs::write(&file, body).expect("write mesh");
        single_client.push(file);
    }

    println!();
    println!("## One client through the job API, per store");
    println!();
    println!(
        "Submit, poll every 20 ms, fetch mesh and report, delete; {JOB_API_ROUNDS} jobs per \
         store, the stores taking turns job by job (so that load from elsewhere on the machine \
         hits them alike); median and spread."
    );
    println!();
    println!(
        "| store | mesh | median s | min s | max s | vs memory % | median of paired differences s |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|");
    let jobs_path = path.replacen("/v1/smooth", "/v1/jobs", 1);
    for (name, _, body) in &meshes {
        let mut times: Vec<Vec<f64>> = vec![Vec::new(); servers.len()];
        for _ in 0..JOB_API_ROUNDS {
            for (i, (_, _, addr)) in servers.iter().enumerate() {
                let t = runtime.block_on(job_api_once(*addr, &jobs_path, body.clone()));
                times[i].push(t.as_secs_f64());
            }
        }
        let memory = median(times[0].clone());
        for ((store, _, _), t) in servers.iter().zip(&times) {
            // Each job against the memory job of the same round.
            let paired: Vec<f64> = t.iter().zip(&times[0]).map(|(x, m)| x - m).collect();
            let mut sorted = t.clone();
            sorted.sort_by(f64::total_cmp);
            let m = median(t.clone());
            println!(
                "| {store} | {name} | {m:.3} | {:.3} | {:.3} | {:+.1} | {:+.3} |",
                sorted.first().copied().unwrap_or(f64::NAN),
                sorted.last().copied().unwrap_or(f64::NAN),
                100.0 * (m - memory) / memory,
                median(paired)
            );
        }
    }
    let addr = servers[0].2;
    println!();
    println!("## Server overhead per request vs `meshsmooth smooth` (1 client)");
    println!();
    println!(
        "CLI and server runs alternate ({OVERHEAD_ROUNDS} rounds each) so that load from \
         elsewhere on the machine hits both alike; medians."
    );
    println!();
    println!(
        "| mesh | vertices | CLI s | server end-to-end s | overhead s | overhead % | server pipeline s |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for ((name, vertices, body), file) in meshes.iter().zip(single_client) {
        let mut cli = Vec::new();
        let mut e2e = Vec::new();
        let mut run = Vec::new();
        for _ in 0..OVERHEAD_ROUNDS {
            cli.push(cli_seconds(bin, &file, &query));
            let o = runtime.block_on(smooth_once(addr, &path, body.clone()));
            e2e.push(o.latency.as_secs_f64());
            run.push(o.run_seconds);
        }
        let (cli, e2e, run) = (median(cli), median(e2e), median(run));
        println!(
            "| {name} | {vertices} | {cli:.3} | {e2e:.3} | {:.3} | {:.1} | {run:.3} |",
            e2e - cli,
            100.0 * (e2e - cli) / cli
        );
    }
    for (_, mut server, _) in servers {
        let _ = server.kill();
        let _ = server.wait();
    }
    let _ = std::fs::remove_dir_all(&dir);
}
