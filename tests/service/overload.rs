//! Overload: a flood of uploads against one worker and a queue of two.

use crate::support::{Req, Server, small_sphere};
use hyper::StatusCode;
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_is_refused_politely_and_every_accepted_job_finishes() {
    let server = Server::start(&["--workers", "1", "--queue-capacity", "2"]);
    let (obj, _, _) = small_sphere();
    let baseline_rss = server.peak_rss();
    // Each job holds its worker longer than the whole flood takes, so at
    // most one runs and two wait while the uploads arrive.
    let uploads = (0..20).map(|_| {
        let client = server.client();
        let obj = obj.clone();
        tokio::spawn(async move {
            client
                .send(
                    Req::raw("/v1/jobs?method=laplacian", "model/obj", obj)
                        .header("x-meshsmooth-test-hook", "sleep=1500"),
                )
                .await
        })
    });
    let mut accepted = Vec::new();
    let mut refused = 0;
    for upload in uploads.collect::<Vec<_>>() {
        let r = upload.await.unwrap();
        match r.status {
            StatusCode::ACCEPTED => accepted.push(r.json()["id"].as_str().unwrap().to_owned()),
            StatusCode::SERVICE_UNAVAILABLE => {
                let p = r.problem(503, "queue_full");
                let retry: u64 = r
                    .header("retry-after")
                    .expect("Retry-After")
                    .parse()
                    .unwrap();
                assert!(retry >= 1, "{p}");
                refused += 1;
            }
            other => panic!("unexpected {other}: {}", r.text()),
        }
    }
    assert_eq!(accepted.len() + refused, 20);
    assert!(
        (2..=3).contains(&accepted.len()),
        "queue of 2 plus at most 1 running: {} accepted",
        accepted.len()
    );
    // Refused at the queue, or before: too many uploads in flight.
    let rejected = server
        .metric("meshsmooth_jobs_rejected_total{reason=\"queue_full\"}")
        .await
        + server
            .metric("meshsmooth_jobs_rejected_total{reason=\"uploads_full\"}")
            .await;
    assert_eq!(rejected, refused as f64);
    // Nothing half-accepted: exactly the accepted jobs exist, and all finish.
    assert_eq!(
        server.metric("meshsmooth_jobs_submitted_total").await,
        accepted.len() as f64
    );
    for id in &accepted {
        let job = server.wait_job(id, Duration::from_secs(30)).await;
        assert_eq!(job["state"], "succeeded", "{job}");
    }
    // Refused uploads were not buffered: memory grew by far less than the
    // flood's size times any plausible per-upload overhead.
    let growth = server.peak_rss().saturating_sub(baseline_rss);
    assert!(
        growth < 64 << 20,
        "peak memory grew by {growth} bytes during the flood"
    );
    assert_eq!(server.get("/readyz").await.status, StatusCode::OK);
}
