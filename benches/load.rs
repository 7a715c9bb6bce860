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

#[path = "../tests/service/support.rs"]
mod support;

use hyper::body::Bytes;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};
use support::{Client, Req, Server};

fn env_list(name: &str, default: &str) -> Vec<usize> {
    std::env::var(name)
        .unwrap_or_else(|_| default.to_owned())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect()
}

/// Voxel-sphere boundary quads as OBJ text, and its vertex count.
fn voxel_sphere(radius: f64) -> (String, usize) {
    let (text, vertices, _) = support::voxel_sphere_obj(radius);
    (text, vertices)
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

async fn smooth_once(client: Client, path: &str, body: Bytes) -> Outcome {
    let start = Instant::now();
    loop {
        let r = client
            .send(Req::raw(path, "model/obj", body.to_vec()))
            .await;
        let (status, headers) = (r.status.as_u16(), r.headers);
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
        let job = client.get(&format!("/v1/jobs/{id}")).await;
        let job: serde_json::Value = serde_json::from_slice(&job.body).unwrap_or_default();
        let run_seconds = job["run_seconds"].as_f64().unwrap_or(f64::NAN);
        return Outcome {
            latency,
            run_seconds,
        };
    }
}

/// `requests` one-call requests from `clients` concurrent clients.
async fn load(
    client: Client,
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
                    mine.push(smooth_once(client, &path, body.clone()).await);
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
/// mesh and the report, delete. Returns the whole time.
async fn job_api_once(client: Client, path: &str, body: Bytes) -> Duration {
    let start = Instant::now();
    let r = client
        .send(Req::raw(path, "model/obj", body.to_vec()))
        .await;
    assert_eq!(r.status.as_u16(), 202, "submit failed");
    let job: serde_json::Value = serde_json::from_slice(&r.body).unwrap_or_default();
    let id = job["id"].as_str().unwrap_or_default().to_owned();
    loop {
        let r = client.get(&format!("/v1/jobs/{id}")).await;
        assert_eq!(r.status.as_u16(), 200, "poll failed");
        let job: serde_json::Value = serde_json::from_slice(&r.body).unwrap_or_default();
        match job["state"].as_str() {
            Some("succeeded") => break,
            Some("queued" | "running") => tokio::time::sleep(Duration::from_millis(20)).await,
            other => panic!("job ended {other:?}"),
        }
    }
    for part in ["mesh", "report"] {
        let r = client.get(&format!("/v1/jobs/{id}/{part}")).await;
        assert_eq!(r.status.as_u16(), 200, "fetching the {part} failed");
    }
    let _ = client.delete(&format!("/v1/jobs/{id}")).await;
    start.elapsed()
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

/// The meshes to upload: a voxel sphere near each vertex count of `sizes`,
/// and `MESHSMOOTH_BENCH_MESH` when set: (name, vertices, OBJ bytes).
fn bench_meshes(sizes: &[usize]) -> Vec<(String, usize, Bytes)> {
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
    meshes
}

/// Prints the server's overhead per request against the CLI's time on
/// each of `meshes` (name, vertices, OBJ bytes, its file).
fn overhead_table(
    runtime: &tokio::runtime::Runtime,
    client: Client,
    bin: &str,
    path: &str,
    query: &str,
    meshes: Vec<(String, usize, Bytes, std::path::PathBuf)>,
) {
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
    for (name, vertices, body, file) in meshes {
        let mut cli = Vec::new();
        let mut e2e = Vec::new();
        let mut run = Vec::new();
        for _ in 0..OVERHEAD_ROUNDS {
            cli.push(cli_seconds(bin, &file, query));
            let o = runtime.block_on(smooth_once(client, path, body.clone()));
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
}

/// Prints one client's time through the job API on each of `servers`
/// (store name, client) for each of `meshes`, the stores taking turns job
/// by job; the first server is the memory store the others compare with.
fn job_api_table(
    runtime: &tokio::runtime::Runtime,
    servers: &[(String, Client)],
    jobs_path: &str,
    meshes: &[(String, usize, Bytes)],
) {
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
    for (name, _, body) in meshes {
        let mut times: Vec<Vec<f64>> = vec![Vec::new(); servers.len()];
        for _ in 0..JOB_API_ROUNDS {
            for (i, (_, client)) in servers.iter().enumerate() {
                let t = runtime.block_on(job_api_once(*client, jobs_path, body.clone()));
                times[i].push(t.as_secs_f64());
            }
        }
        let memory = median(times[0].clone());
        for ((store, _), t) in servers.iter().zip(&times) {
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
}

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

    let meshes = bench_meshes(&sizes);

    let stores: Vec<String> = std::iter::once("memory".to_owned())
        .chain(store_argument())
        .collect();
    // One server per store, all up for the whole run.
    let servers: Vec<(String, Server)> = stores
        .iter()
        .map(|store| {
            let args = ["--queue-capacity", "64", "--log", "warn", "--store", store];
            (store.clone(), Server::start(&args))
        })
        .collect();
    let clients_of: Vec<(String, Client)> = servers
        .iter()
        .map(|(store, server)| (store.clone(), server.client()))
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
    for (store, client) in &clients_of {
        for (name, vertices, body) in &meshes {
            for &c in &clients {
                let requests = fixed_requests.unwrap_or(c.max(8));
                let start = Instant::now();
                let outcomes = runtime.block_on(load(*client, &path, body, c, requests));
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
    let jobs_path = path.replacen("/v1/smooth", "/v1/jobs", 1);
    job_api_table(&runtime, &clients_of, &jobs_path, &meshes);
    let single_client = meshes
        .into_iter()
        .map(|(name, vertices, body)| {
            let file = dir.join(format!("{vertices}.obj"));
            std::fs::write(&file, &body).expect("write mesh");
            (name, vertices, body, file)
        })
        .collect();
    overhead_table(&runtime, clients_of[0].1, bin, &path, &query, single_client);
    drop(servers);
    let _ = std::fs::remove_dir_all(&dir);
}
