//! The shared job store: replicas of the real binary on one real
//! `redis-server`. Any replica answers for any job; a job outlives the
//! replica running it, a shutdown and a Redis restart; the queue capacity
//! holds fleet-wide; Redis trouble is a clear answer.

use crate::support::{Client, RedisServer, Req, Resp, Server, job_id, small_sphere};
use hyper::StatusCode;
use serde_json::Value;
use std::time::{Duration, Instant};

const LONG: Duration = Duration::from_secs(30);

/// A replica on `redis` with `workers` workers and the extra `args`.
fn replica(redis: &RedisServer, workers: &str, args: &[&str]) -> Server {
    let url = redis.url();
    let mut all = vec!["--store", &url, "--workers", workers];
    all.extend_from_slice(args);
    Server::start(&all)
}

/// Submits the small sphere with the test hook `hook` (e.g. `sleep=500`).
async fn submit(client: &Client, hook: &str) -> Resp {
    let (obj, _, _) = small_sphere();
    client
        .send(
            Req::raw("/v1/jobs?method=laplacian", "model/obj", obj)
                .header("x-meshsmooth-test-hook", hook),
        )
        .await
}

/// Polls until `pred` holds for the job, up to `timeout`.
async fn wait_for(
    client: &Client,
    id: &str,
    timeout: Duration,
    pred: impl Fn(&Value) -> bool,
) -> Value {
    let start = Instant::now();
    loop {
        let r = client.get(&format!("/v1/jobs/{id}")).await;
        if r.status == StatusCode::OK {
            let job = r.json();
            if pred(&job) {
                return job;
            }
            assert!(
                start.elapsed() < timeout,
                "job {id} after {timeout:?}: {job}"
            );
        } else {
            assert!(start.elapsed() < timeout, "job {id}: {}", r.text());
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_submitted_to_one_replica_is_followed_fetched_and_deleted_through_the_other() {
    let redis = RedisServer::start();
    let a = replica(&redis, "1", &[]);
    let b = replica(&redis, "1", &[]);
    let id = job_id(&submit(&a, "sleep=400").await);

    // B sees the job A accepted, and streams it to its end.
    let r = b.get(&format!("/v1/jobs/{id}")).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text());
    let states = b.events(&id, LONG).await;
    assert!(states.len() >= 2, "{states:?}");
    assert_ne!(
        states[0]["state"], "succeeded",
        "the first event comes at once"
    );
    assert!(states.iter().any(|s| s["state"] == "running"), "{states:?}");
    let last = states.last().unwrap();
    assert_eq!(last["state"], "succeeded", "{last}");
    assert_eq!(last["attempts"], 1, "{last}");

    let job = b.wait_job(&id, LONG).await;
    assert_eq!(job["result"]["available"], true, "{job}");
    let mesh = b.get(&format!("/v1/jobs/{id}/mesh")).await;
    assert_eq!(mesh.status, StatusCode::OK, "{}", mesh.text());
    assert_eq!(
        job["result"]["mesh_bytes"].as_u64(),
        Some(mesh.body.len() as u64)
    );
    assert!(mesh.text().lines().any(|l| l.starts_with("v ")));
    let report = b.get(&format!("/v1/jobs/{id}/report")).await;
    assert_eq!(report.status, StatusCode::OK);
    assert!(report.json()["mesh"].is_object(), "{}", report.text());
    // The same bytes from either replica.
    assert_eq!(a.get(&format!("/v1/jobs/{id}/mesh")).await.body, mesh.body);

    assert_eq!(
        b.delete(&format!("/v1/jobs/{id}")).await.status,
        StatusCode::NO_CONTENT
    );
    a.get(&format!("/v1/jobs/{id}"))
        .await
        .problem(404, "job_not_found");
    b.get(&format!("/v1/jobs/{id}/mesh"))
        .await
        .problem(404, "job_not_found");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_queued_job_is_cancelled_and_a_running_one_stopped_through_another_replica() {
    let redis = RedisServer::start();
    let a = replica(&redis, "1", &[]);
    let b = replica(&redis, "1", &[]);
    // Both workers busy, so the third waits in the queue.
    let running: Vec<String> = [
        job_id(&submit(&a, "sleep=20000").await),
        job_id(&submit(&a, "sleep=20000").await),
    ]
    .into();
    for id in &running {
        wait_for(&a, id, LONG, |j| j["state"] == "running").await;
    }
    let queued = job_id(&submit(&b, "sleep=10").await);
    let next = job_id(&submit(&a, "sleep=10").await);
    let view = a.get(&format!("/v1/jobs/{next}")).await.json();
    assert_eq!(view["state"], "queued", "{view}");
    assert_eq!(view["queue_position"], 1, "one job ahead: {view}");
    let r = a.delete(&format!("/v1/jobs/{queued}")).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text());
    assert_eq!(r.json()["state"], "cancelled");
    for id in &running {
        let r = b.delete(&format!("/v1/jobs/{id}")).await;
        assert_eq!(r.status, StatusCode::ACCEPTED, "{}", r.text());
        let job = wait_for(&a, id, LONG, |j| j["state"] != "running").await;
        assert_eq!(job["state"], "cancelled", "{job}");
        assert_eq!(job["cancel_reason"], "client", "{job}");
    }
    let job = b.wait_job(&next, LONG).await;
    assert_eq!(job["state"], "succeeded", "{job}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kill_9_of_the_replica_running_a_job_lets_the_other_finish_it() {
    let redis = RedisServer::start();
    let mut a = replica(&redis, "1", &["--lease", "1s"]);
    let id = job_id(&submit(&a, "sleep=1500").await);
    wait_for(&a, &id, LONG, |j| j["state"] == "running").await;
    // B comes up only now, so A is the one running the job.
    let b = replica(&redis, "1", &["--lease", "1s"]);
    a.kill9();
    let job = b.wait_job(&id, LONG).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    assert_eq!(job["attempts"], 2, "one extra attempt: {job}");
    assert_eq!(b.metric("meshsmooth_leases_reclaimed_total").await, 1.0);
    assert_eq!(b.metric("meshsmooth_job_attempts_total").await, 1.0);
    let mesh = b.get(&format!("/v1/jobs/{id}/mesh")).await;
    assert_eq!(mesh.status, StatusCode::OK);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_that_kills_every_worker_fails_after_the_set_attempts() {
    let redis = RedisServer::start();
    let args = ["--lease", "500ms", "--max-attempts", "2"];
    let mut first = replica(&redis, "1", &args);
    let id = job_id(&submit(&first, "sleep=60000").await);
    wait_for(&first, &id, LONG, |j| j["state"] == "running").await;
    let mut second = replica(&redis, "1", &args);
    first.kill9();
    wait_for(&second, &id, LONG, |j| {
        j["attempts"] == 2 && j["state"] == "running"
    })
    .await;
    let third = replica(&redis, "1", &args);
    second.kill9();
    let job = third.wait_job(&id, LONG).await;
    assert_eq!(job["state"], "failed", "{job}");
    assert_eq!(job["error"]["code"], "job_attempts_exhausted", "{job}");
    assert_eq!(job["error"]["status"], 500, "{job}");
    assert_eq!(job["attempts"], 2, "{job}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_hands_back_what_it_cannot_finish_and_every_accepted_job_succeeds() {
    let redis = RedisServer::start();
    let mut a = replica(&redis, "1", &["--shutdown-timeout", "500ms"]);
    // A runs the long one; the short ones stay queued.
    let long = job_id(&submit(&a, "sleep=3000").await);
    wait_for(&a, &long, LONG, |j| j["state"] == "running").await;
    let short: Vec<String> = [
        job_id(&submit(&a, "sleep=100").await),
        job_id(&submit(&a, "sleep=100").await),
    ]
    .into();
    a.terminate();
    let status = tokio::task::block_in_place(|| a.wait_exit(LONG)).expect("A exits");
    assert!(status.success(), "{status:?}");
    let logs = a.logs();
    assert!(logs.contains("job handed back to the queue"), "{logs}");
    // Nothing was lost: another replica runs them all.
    let b = replica(&redis, "1", &[]);
    for id in short.iter().chain([&long]) {
        let job = b.wait_job(id, LONG).await;
        assert_eq!(job["state"], "succeeded", "{job}");
        assert_eq!(
            job["attempts"], 1,
            "a handed-back run is not an attempt: {job}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_with_the_memory_store_finishes_the_queued_jobs() {
    let mut server = Server::start(&["--workers", "1", "--shutdown-timeout", "20s"]);
    let (obj, _, _) = small_sphere();
    let answers: Vec<_> = (0..3)
        .map(|_| {
            let client = server.client();
            let obj = obj.clone();
            tokio::spawn(async move {
                client
                    .send(
                        Req::raw("/v1/smooth?method=laplacian", "model/obj", obj)
                            .header("x-meshsmooth-test-hook", "sleep=300"),
                    )
                    .await
            })
        })
        .collect();
    // All three accepted (one running, two queued), then SIGTERM.
    let start = Instant::now();
    while server.metric("meshsmooth_jobs_submitted_total").await < 3.0 {
        assert!(start.elapsed() < LONG, "the uploads were not accepted");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    server.terminate();
    for answer in answers {
        let r = answer.await.unwrap();
        assert_eq!(r.status, StatusCode::OK, "{}", r.text());
    }
    let status = tokio::task::block_in_place(|| server.wait_exit(LONG)).expect("exits");
    assert!(status.success(), "{status:?}");
    let logs = server.logs();
    assert_eq!(logs.matches("job succeeded").count(), 3, "{logs}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn queued_jobs_survive_a_redis_restart() {
    let mut redis = RedisServer::start();
    let a = replica(&redis, "1", &[]);
    let ids: Vec<String> = [
        job_id(&submit(&a, "sleep=600").await),
        job_id(&submit(&a, "sleep=10").await),
        job_id(&submit(&a, "sleep=10").await),
    ]
    .into();
    wait_for(&a, &ids[0], LONG, |j| j["state"] == "running").await;
    redis.stop();
    redis.resume();
    for id in &ids {
        // A poll may find Redis still away (503); the job is never lost.
        let job = wait_for(&a, id, LONG, |j| {
            j["state"] != "queued" && j["state"] != "running"
        })
        .await;
        assert_eq!(job["state"], "succeeded", "{job}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn redis_down_is_a_clear_503_and_work_resumes_when_it_returns() {
    let mut redis = RedisServer::start();
    let a = replica(&redis, "1", &[]);
    assert_eq!(a.get("/readyz").await.status, StatusCode::OK);
    redis.stop();
    let r = submit(&a, "sleep=10").await;
    r.problem(503, "store_unavailable");
    assert!(r.header("retry-after").is_some(), "{:?}", r.headers);
    a.get("/readyz").await.problem(503, "store_unavailable");
    a.get("/v1/jobs/3f1e8a52-1c2b-4d5e-8f90-123456789abc")
        .await
        .problem(503, "store_unavailable");
    assert!(a.metric("meshsmooth_store_errors_total").await >= 1.0);

    redis.resume();
    let start = Instant::now();
    while a.get("/readyz").await.status != StatusCode::OK {
        assert!(start.elapsed() < LONG, "not ready after Redis returned");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let id = job_id(&submit(&a, "sleep=10").await);
    let job = a.wait_job(&id, LONG).await;
    assert_eq!(job["state"], "succeeded", "{job}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_queue_capacity_holds_across_replicas() {
    let redis = RedisServer::start();
    let args = ["--queue-capacity", "2"];
    let a = replica(&redis, "1", &args);
    let b = replica(&redis, "1", &args);
    let (obj, _, _) = small_sphere();
    // Each job holds its worker longer than the flood takes.
    let uploads: Vec<_> = (0..20)
        .map(|i| {
            let client = if i % 2 == 0 { a.client() } else { b.client() };
            let obj = obj.clone();
            tokio::spawn(async move {
                client
                    .send(
                        Req::raw("/v1/jobs?method=laplacian", "model/obj", obj)
                            .header("x-meshsmooth-test-hook", "sleep=1500"),
                    )
                    .await
            })
        })
        .collect();
    let mut accepted = Vec::new();
    for upload in uploads {
        let r = upload.await.unwrap();
        match r.status {
            StatusCode::ACCEPTED => accepted.push(r.json()["id"].as_str().unwrap().to_owned()),
            StatusCode::SERVICE_UNAVAILABLE => {
                r.problem(503, "queue_full");
                let retry: u64 = r
                    .header("retry-after")
                    .expect("Retry-After")
                    .parse()
                    .unwrap();
                assert!(retry >= 1);
            }
            other => panic!("unexpected {other}: {}", r.text()),
        }
    }
    assert!(
        (2..=4).contains(&accepted.len()),
        "a queue of 2 across the fleet plus at most one running per replica: {} accepted",
        accepted.len()
    );
    for id in &accepted {
        let job = a.wait_job(id, LONG).await;
        assert_eq!(job["state"], "succeeded", "{job}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replica_started_while_redis_is_down_is_unready_until_it_comes_up() {
    let mut redis = RedisServer::start();
    redis.stop();
    let a = replica(&redis, "1", &[]);
    a.get("/readyz").await.problem(503, "store_unavailable");
    submit(&a, "sleep=10")
        .await
        .problem(503, "store_unavailable");
    redis.resume();
    let start = Instant::now();
    while a.get("/readyz").await.status != StatusCode::OK {
        assert!(start.elapsed() < LONG, "not ready after Redis came up");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let id = job_id(&submit(&a, "sleep=10").await);
    let job = a.wait_job(&id, LONG).await;
    assert_eq!(job["state"], "succeeded", "{job}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_redis_is_a_503_within_seconds_not_a_hang() {
    let redis = RedisServer::start();
    let a = replica(&redis, "1", &[]);
    let id = job_id(&submit(&a, "sleep=10").await);
    a.wait_job(&id, LONG).await;
    redis.freeze(true);
    let start = Instant::now();
    let r = a.get(&format!("/v1/jobs/{id}")).await;
    let waited = start.elapsed();
    redis.freeze(false);
    r.problem(503, "store_unavailable");
    assert!(
        waited < Duration::from_secs(10),
        "answered after {waited:?}"
    );
    let job = wait_for(&a, &id, LONG, |j| j["state"] == "succeeded").await;
    assert_eq!(job["attempts"], 1, "{job}");
}
