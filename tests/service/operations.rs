//! Operations: health, readiness, metrics, request ids, CORS, logs,
//! the parameter schema and graceful shutdown.

use crate::support::{Req, Server, job_id, small_sphere};
use hyper::{Method, StatusCode};
use serde_json::Value;
use std::time::Duration;

#[tokio::test]
async fn health_and_readiness() {
    let server = Server::start(&["--workers", "1", "--queue-capacity", "1"]);
    let r = server.get("/healthz").await;
    assert_eq!(r.status, StatusCode::OK);
    assert_eq!(r.json()["status"], "ok");
    assert_eq!(server.get("/readyz").await.json()["status"], "ready");

    // One job running and one waiting fill the queue: not ready.
    let (obj, _, _) = small_sphere();
    let slow = || {
        Req::raw("/v1/jobs", "model/obj", obj.clone())
            .header("x-meshsmooth-test-hook", "sleep=20000")
    };
    let running = job_id(&server.send(slow()).await);
    server
        .wait_job_until(&running, |j| j["state"] == "running")
        .await;
    let waiting = job_id(&server.send(slow()).await);
    server.get("/readyz").await.problem(503, "queue_full");
    assert_eq!(server.get("/healthz").await.status, StatusCode::OK);
    server.delete(&format!("/v1/jobs/{waiting}")).await;
    assert_eq!(server.get("/readyz").await.status, StatusCode::OK);
}

#[tokio::test]
async fn metrics_move_with_the_work() {
    let server = Server::start(&[]);
    let text = server.get("/metrics").await;
    assert!(
        text.header("content-type")
            .unwrap()
            .starts_with("text/plain; version=0.0.4")
    );
    assert_eq!(server.metric("meshsmooth_workers_busy").await, 0.0);
    assert_eq!(server.metric("meshsmooth_queue_capacity").await, 16.0);
    assert_eq!(
        server.metric("meshsmooth_jobs{state=\"succeeded\"}").await,
        0.0
    );

    let (obj, vertices, faces) = small_sphere();
    for _ in 0..2 {
        let r = server
            .send(Req::raw("/v1/smooth", "model/obj", obj.clone()))
            .await;
        assert_eq!(r.status, StatusCode::OK);
    }
    let m = |s: &'static str| server.metric(s);
    assert_eq!(m("meshsmooth_jobs_submitted_total").await, 2.0);
    assert_eq!(
        m("meshsmooth_jobs_finished_total{outcome=\"succeeded\"}").await,
        2.0
    );
    assert_eq!(m("meshsmooth_jobs{state=\"succeeded\"}").await, 2.0);
    assert_eq!(
        m("meshsmooth_vertices_processed_total").await,
        2.0 * vertices as f64
    );
    assert_eq!(
        m("meshsmooth_faces_processed_total").await,
        2.0 * faces as f64
    );
    assert_eq!(
        m("meshsmooth_upload_bytes_total").await,
        2.0 * obj.len() as f64
    );
    assert_eq!(m("meshsmooth_results").await, 2.0);
    assert!(m("meshsmooth_results_bytes").await > 0.0);
    assert_eq!(m("meshsmooth_job_duration_seconds_count").await, 2.0);
    assert_eq!(
        m("meshsmooth_http_requests_total{method=\"POST\",route=\"/v1/smooth\",status=\"200\"}")
            .await,
        2.0
    );
    let text = server.get("/metrics").await.text();
    assert!(
        text.contains("meshsmooth_stage_duration_seconds_bucket{stage="),
        "stage histograms with buckets:\n{text}"
    );
    assert!(text.contains("# HELP meshsmooth_queue_depth"));
}

#[tokio::test]
async fn the_parameter_schema_has_every_default() {
    let server = Server::start(&[]);
    let r = server.get("/v1/params/schema").await;
    assert_eq!(r.status, StatusCode::OK);
    assert_eq!(r.header("content-type"), Some("application/schema+json"));
    let schema = r.json();
    assert_eq!(
        schema["$schema"],
        "https://json-schema.org/draft/2020-12/schema"
    );
    // Build the parameter object a form would from the schema's defaults,
    // following `$ref`s into `$defs`.
    fn defaults(schema: &Value, root: &Value) -> Value {
        if let Some(d) = schema.get("default") {
            return d.clone();
        }
        if let Some(r) = schema.get("$ref").and_then(Value::as_str) {
            let name = r.strip_prefix("#/$defs/").expect("local ref");
            return defaults(&root["$defs"][name], root);
        }
        let props = schema["properties"].as_object().expect("properties");
        Value::Object(
            props
                .iter()
                .map(|(k, v)| (k.clone(), defaults(v, root)))
                .collect(),
        )
    }
    let form = defaults(&schema, &schema);
    // Those defaults are what a job gets when it sends no parameters.
    let (obj, _, _) = small_sphere();
    let r = server
        .send(
            Req::raw("/v1/jobs", "model/obj", obj.clone())
                .header("x-meshsmooth-test-hook", "sleep=0"),
        )
        .await;
    assert_eq!(r.json()["params"], form);
    // ... and sending them explicitly is accepted.
    let query = format!("/v1/jobs?params={}", percent_encode(&form.to_string()));
    let r = server.send(Req::raw(&query, "model/obj", obj)).await;
    assert_eq!(r.status, StatusCode::ACCEPTED, "{}", r.text());
    assert_eq!(r.json()["params"], form);
}

fn percent_encode(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' => (b as char).to_string(),
            _ => format!("%{b:02X}"),
        })
        .collect()
}

#[tokio::test]
async fn request_ids_are_set_propagated_and_tied_to_jobs() {
    let server = Server::start(&["--log-format", "json"]);
    let r = server.get("/healthz").await;
    let generated = r.header("x-request-id").expect("x-request-id");
    assert_eq!(generated.len(), 36, "a UUID: {generated}");

    let (obj, _, _) = small_sphere();
    let r = server
        .send(
            Req::raw("/v1/smooth?method=laplacian", "model/obj", obj)
                .header("x-request-id", "pipeline-run-42"),
        )
        .await;
    assert_eq!(r.status, StatusCode::OK);
    assert_eq!(r.header("x-request-id"), Some("pipeline-run-42"));
    // JSON logs: every line is an object; the job's lines carry the id. The
    // worker logs success just after the response is sent: wait for it.
    let mut logs = server.logs();
    for _ in 0..50 {
        if logs.contains("job succeeded") {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        logs = server.logs();
    }
    let lines: Vec<Value> = logs
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert!(
        lines.iter().any(|l| {
            l["fields"]["message"] == "job succeeded"
                && l["span"]["request_id"] == "pipeline-run-42"
        }),
        "{logs}"
    );
}

#[tokio::test]
async fn cors_allows_the_configured_origin() {
    let server = Server::start(&["--cors-origins", "https://viewer.example"]);
    let preflight = server
        .send(
            Req::new(Method::OPTIONS, "/v1/jobs")
                .header("origin", "https://viewer.example")
                .header("access-control-request-method", "POST")
                .header("access-control-request-headers", "content-type"),
        )
        .await;
    assert!(preflight.status.is_success(), "{:?}", preflight);
    assert_eq!(
        preflight.header("access-control-allow-origin"),
        Some("https://viewer.example")
    );
    let r = server
        .send(Req::new(Method::GET, "/healthz").header("origin", "https://viewer.example"))
        .await;
    assert_eq!(
        r.header("access-control-allow-origin"),
        Some("https://viewer.example")
    );
    assert!(
        r.header("access-control-expose-headers")
            .unwrap()
            .contains("location")
    );
    let other = server
        .send(Req::new(Method::GET, "/healthz").header("origin", "https://evil.example"))
        .await;
    assert_eq!(other.header("access-control-allow-origin"), None);
}

#[tokio::test]
async fn the_docs_page_is_served_without_internet() {
    let server = Server::start(&[]);
    let page = server.get("/docs/").await;
    assert_eq!(page.status, StatusCode::OK);
    let html = page.text();
    assert!(html.contains("swagger-ui"), "{html}");
    assert!(!html.contains("https://"), "no external assets: {html}");
    for asset in [
        "/docs/swagger-ui.css",
        "/docs/swagger-ui-bundle.js",
        "/docs/swagger-initializer.js",
    ] {
        let r = server.get(asset).await;
        assert_eq!(r.status, StatusCode::OK, "{asset}");
        assert!(!r.body.is_empty());
    }
    let init = server.get("/docs/swagger-initializer.js").await.text();
    assert!(init.contains("/openapi.json"), "{init}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_finishes_running_jobs_then_exits() {
    let mut server = Server::start(&["--workers", "1", "--shutdown-timeout", "10s"]);
    let (obj, _, _) = small_sphere();
    let answer = {
        let client = server.client();
        let obj = obj.clone();
        tokio::spawn(async move {
            client
                .send(
                    Req::raw("/v1/smooth?method=laplacian", "model/obj", obj)
                        .header("x-meshsmooth-test-hook", "sleep=800"),
                )
                .await
        })
    };
    // Let the job start, then SIGTERM.
    tokio::time::sleep(Duration::from_millis(300)).await;
    server.terminate();
    let answer = answer.await.unwrap();
    assert_eq!(
        answer.status,
        StatusCode::OK,
        "the running job finished: {}",
        answer.text()
    );
    let status = tokio::task::block_in_place(|| server.wait_exit(Duration::from_secs(10)))
        .expect("the server exits");
    assert!(status.success(), "{status:?}");
    let logs = server.logs();
    assert!(logs.contains("SIGTERM received"), "{logs}");
    assert!(logs.contains("meshsmooth serve stopped"), "{logs}");
}
