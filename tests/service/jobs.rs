//! The job API and the one-call path, end to end.

use crate::support::{Part, Req, Server, job_id, obj_stats, small_sphere};
use http_body_util::BodyExt;
use hyper::{Method, StatusCode};
use serde_json::Value;
use std::time::{Duration, Instant};

const LONG: Duration = Duration::from_secs(60);

/// Asserts `smoothed` is `input` with only vertex positions changed: same
/// vertex and face counts, identical face lines, finite coordinates, and at
/// least one vertex moved.
#[track_caller]
fn assert_smoothed(input: &str, smoothed: &str) {
    let (before, faces_before) = obj_stats(input);
    let (after, faces_after) = obj_stats(smoothed);
    assert_eq!(after.len(), before.len(), "vertex count changed");
    assert_eq!(faces_after, faces_before, "face count changed");
    let face_lines = |t: &str| -> Vec<String> {
        t.lines()
            .filter(|l| l.starts_with("f "))
            .map(str::to_owned)
            .collect()
    };
    assert_eq!(
        face_lines(smoothed),
        face_lines(input),
        "connectivity changed"
    );
    assert!(after.iter().flatten().all(|c| c.is_finite()));
    let moved = before
        .iter()
        .zip(&after)
        .filter(|(a, b)| (0..3).any(|i| (a[i] - b[i]).abs() > 1e-9))
        .count();
    assert!(moved > 0, "no vertex moved");
}

#[track_caller]
fn assert_report(report: &Value) {
    let object = report.as_object().expect("the report is a JSON object");
    assert!(!object.is_empty());
}

#[tokio::test]
async fn multipart_upload_gives_a_smoothed_mesh_and_a_report() {
    let server = Server::start(&[]);
    let (obj, vertices, faces) = small_sphere();
    let r = server
        .send(Req::multipart("/v1/jobs", &[Part::obj(&obj)]))
        .await;
    let id = job_id(&r);
    let job = r.json();
    assert!(
        ["queued", "running"].contains(&job["state"].as_str().unwrap()),
        "{job}"
    );
    assert_eq!(job["input"]["vertices"], vertices);
    assert_eq!(job["input"]["faces"], faces);
    assert_eq!(job["input"]["format"], "obj");
    assert_eq!(job["params"]["method"], "wang-yu", "defaults filled in");
    assert_eq!(job["links"]["mesh"], format!("/v1/jobs/{id}/mesh"));

    let job = server.wait_job(&id, LONG).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    assert!(job["run_seconds"].as_f64().unwrap() >= 0.0);
    assert!(job["finished_at"].as_str().unwrap().ends_with('Z'));
    assert_eq!(job["result"]["available"], true);

    let mesh = server.get(&format!("/v1/jobs/{id}/mesh")).await;
    assert_eq!(mesh.status, StatusCode::OK);
    assert_eq!(mesh.header("content-type"), Some("model/obj"));
    assert_eq!(
        job["result"]["mesh_bytes"].as_u64().unwrap() as usize,
        mesh.body.len()
    );
    assert_smoothed(&obj, &mesh.text());

    let report = server.get(&format!("/v1/jobs/{id}/report")).await;
    assert_eq!(report.status, StatusCode::OK);
    assert_eq!(report.header("content-type"), Some("application/json"));
    assert_report(&report.json());
}

#[tokio::test]
async fn raw_upload_with_query_parameters() {
    let server = Server::start(&[]);
    let (obj, _, _) = small_sphere();
    let r = server
        .send(Req::raw(
            "/v1/jobs?method=taubin&baseline.iterations=7&quality.enabled=false",
            "model/obj",
            obj.clone(),
        ))
        .await;
    let id = job_id(&r);
    let params = &r.json()["params"];
    assert_eq!(params["method"], "taubin");
    assert_eq!(params["baseline"]["iterations"], 7);
    assert_eq!(params["quality"]["enabled"], false);
    let job = server.wait_job(&id, LONG).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    let mesh = server.get(&format!("/v1/jobs/{id}/mesh?format=obj")).await;
    assert_eq!(mesh.status, StatusCode::OK);
    assert_smoothed(&obj, &mesh.text());
    let e = server.get(&format!("/v1/jobs/{id}/mesh?format=dwg")).await;
    e.problem(400, "unknown_output_format");

    // The format is sniffed from the content of an octet stream.
    let r = server
        .send(Req::raw(
            "/v1/jobs?method=laplacian",
            "application/octet-stream",
            obj,
        ))
        .await;
    assert_eq!(r.json()["input"]["format"], "obj");
}

#[tokio::test]
async fn one_call_answers_with_the_mesh_and_links_the_report() {
    let server = Server::start(&[]);
    let (obj, _, _) = small_sphere();
    let r = server
        .send(Req::raw("/v1/smooth", "model/obj", obj.clone()))
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text());
    assert_eq!(r.header("content-type"), Some("model/obj"));
    assert_smoothed(&obj, &r.text());
    let id = r.header("x-job-id").expect("x-job-id").to_owned();
    let link = r.header("link").expect("link");
    assert!(
        link.contains(&format!("</v1/jobs/{id}/report>; rel=\"describedby\"")),
        "{link}"
    );
    let report = server.get(&format!("/v1/jobs/{id}/report")).await;
    assert_report(&report.json());
    assert_eq!(
        server.get(&format!("/v1/jobs/{id}")).await.json()["state"],
        "succeeded"
    );

    // Mesh and report together.
    let r = server
        .send(
            Req::multipart(
                "/v1/smooth",
                &[Part::obj(&obj), Part::params(r#"{"method": "laplacian"}"#)],
            )
            .header("accept", "multipart/mixed"),
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text());
    let ct = r.header("content-type").unwrap();
    let boundary = ct
        .strip_prefix("multipart/mixed; boundary=")
        .expect("multipart/mixed");
    let text = r.text();
    let parts: Vec<&str> = text
        .split(&format!("--{boundary}"))
        .filter(|p| !p.trim().is_empty() && p.trim() != "--")
        .collect();
    assert_eq!(parts.len(), 2, "{text}");
    let (head, mesh) = parts[0].split_once("\r\n\r\n").unwrap();
    assert!(head.contains("Content-Type: model/obj") && head.contains("name=\"mesh\""));
    assert_smoothed(&obj, mesh.trim_end_matches("\r\n"));
    let (head, report) = parts[1].split_once("\r\n\r\n").unwrap();
    assert!(head.contains("application/json") && head.contains("name=\"report\""));
    assert_report(&serde_json::from_str(report.trim_end_matches("\r\n")).unwrap());
}

#[tokio::test]
async fn cancel_running_and_queued_jobs_and_forget_finished_ones() {
    let server = Server::start(&["--workers", "1"]);
    let (obj, _, _) = small_sphere();
    let slow = |ms: u64| {
        Req::raw("/v1/jobs?method=laplacian", "model/obj", obj.clone())
            .header("x-meshsmooth-test-hook", &format!("sleep={ms}"))
    };
    let running = job_id(&server.send(slow(30_000)).await);
    let queued = job_id(&server.send(slow(0)).await);
    server
        .wait_job_until(&running, |j| j["state"] == "running")
        .await;
    let q = server.get(&format!("/v1/jobs/{queued}")).await.json();
    assert_eq!(q["state"], "queued");
    assert_eq!(q["queue_position"], 0);

    // A queued job is cancelled at once.
    let r = server.delete(&format!("/v1/jobs/{queued}")).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text());
    assert_eq!(r.json()["state"], "cancelled");
    assert_eq!(r.json()["cancel_reason"], "client");

    // A running job stops soon after its flag is raised.
    let start = Instant::now();
    let r = server.delete(&format!("/v1/jobs/{running}")).await;
    assert_eq!(r.status, StatusCode::ACCEPTED, "{}", r.text());
    let job = server.wait_job(&running, Duration::from_secs(10)).await;
    assert_eq!(job["state"], "cancelled", "{job}");
    assert!(start.elapsed() < Duration::from_secs(5));
    server
        .get(&format!("/v1/jobs/{running}/mesh"))
        .await
        .problem(409, "job_cancelled");

    // A finished job is forgotten.
    let done = job_id(&server.send(slow(0)).await);
    server.wait_job(&done, LONG).await;
    let r = server.delete(&format!("/v1/jobs/{done}")).await;
    assert_eq!(r.status, StatusCode::NO_CONTENT);
    server
        .get(&format!("/v1/jobs/{done}"))
        .await
        .problem(404, "job_not_found");
    server
        .delete(&format!("/v1/jobs/{done}"))
        .await
        .problem(404, "job_not_found");
}

#[tokio::test]
async fn the_pipeline_stops_when_cancelled_mid_run() {
    // A real run (no test hook) that takes seconds: the most baseline
    // iterations on a 17k-vertex sphere. The core must notice the flag.
    let server = Server::start(&["--workers", "1"]);
    let (obj, _, _) = crate::support::voxel_sphere_obj(30.0);
    let r = server
        .send(Req::raw(
            "/v1/jobs?method=laplacian&baseline.iterations=10000",
            "model/obj",
            obj,
        ))
        .await;
    let id = job_id(&r);
    server
        .wait_job_until(&id, |j| j["state"] == "running" && j["stage"].is_string())
        .await;
    let r = server.delete(&format!("/v1/jobs/{id}")).await;
    assert_eq!(r.status, StatusCode::ACCEPTED, "{}", r.text());
    assert_eq!(r.json()["cancel_requested"], true);
    let job = server.wait_job(&id, Duration::from_secs(30)).await;
    assert_eq!(job["state"], "cancelled", "{job}");
    assert_eq!(job["cancel_reason"], "client");
}

#[tokio::test]
async fn queued_jobs_report_their_position_and_events_follow_progress() {
    let server = Server::start(&["--workers", "1"]);
    let (obj, _, _) = small_sphere();
    let id = job_id(
        &server
            .send(
                Req::raw("/v1/jobs", "model/obj", obj.clone())
                    .header("x-meshsmooth-test-hook", "sleep=300"),
            )
            .await,
    );
    let response = server
        .send_streaming(Req::new(Method::GET, &format!("/v1/jobs/{id}/events")))
        .await;
    assert_eq!(response.status(), StatusCode::OK);
    assert_eq!(response.headers()["content-type"], "text/event-stream");
    let mut body = response.into_body();
    let mut text = String::new();
    while let Some(frame) = tokio::time::timeout(LONG, body.frame())
        .await
        .expect("events keep coming")
    {
        if let Ok(data) = frame.expect("frame").into_data() {
            text.push_str(&String::from_utf8_lossy(&data));
        }
    }
    let states: Vec<Value> = text
        .split("\n\n")
        .filter_map(|event| {
            let mut lines = event.lines();
            assert!(
                event.trim().is_empty()
                    || event.starts_with(':')
                    || lines.any(|l| l == "event: state"),
                "{event}"
            );
            event
                .lines()
                .find_map(|l| l.strip_prefix("data: "))
                .map(|d| serde_json::from_str(d).unwrap())
        })
        .collect();
    assert!(states.len() >= 2, "{text}");
    assert_ne!(states[0]["state"], "succeeded", "first event comes at once");
    assert_eq!(states.last().unwrap()["state"], "succeeded", "{text}");
    assert!(states.iter().any(|s| s["state"] == "running"), "{text}");
}

#[tokio::test]
async fn finished_jobs_expire_after_the_ttl() {
    let server = Server::start(&["--result-ttl", "1s"]);
    let (obj, _, _) = small_sphere();
    let r = server
        .send(Req::raw("/v1/smooth?method=laplacian", "model/obj", obj))
        .await;
    let id = r.header("x-job-id").unwrap().to_owned();
    let job = server.get(&format!("/v1/jobs/{id}")).await.json();
    assert!(job["expires_at"].as_str().is_some());
    assert_eq!(
        server.get(&format!("/v1/jobs/{id}/report")).await.status,
        StatusCode::OK
    );
    let start = Instant::now();
    loop {
        let r = server.get(&format!("/v1/jobs/{id}")).await;
        if r.status == StatusCode::NOT_FOUND {
            r.problem(404, "job_not_found");
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(5), "never expired");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(start.elapsed() >= Duration::from_millis(500));
    server
        .get(&format!("/v1/jobs/{id}/mesh"))
        .await
        .problem(404, "job_not_found");
    assert!(
        server
            .metric("meshsmooth_results_evicted_total{reason=\"ttl\"}")
            .await
            >= 1.0
    );
    assert_eq!(server.metric("meshsmooth_results_bytes").await, 0.0);
}

#[tokio::test]
async fn results_over_the_memory_budget_are_evicted_oldest_first() {
    let server = Server::start(&["--result-memory", "1B"]);
    let (obj, _, _) = small_sphere();
    let mut ids = Vec::new();
    for _ in 0..2 {
        let r = server
            .send(Req::raw(
                "/v1/smooth?method=laplacian",
                "model/obj",
                obj.clone(),
            ))
            .await;
        assert_eq!(r.status, StatusCode::OK);
        ids.push(r.header("x-job-id").unwrap().to_owned());
    }
    let old = server.get(&format!("/v1/jobs/{}", ids[0])).await.json();
    assert_eq!(old["state"], "succeeded");
    assert_eq!(old["result"]["available"], false);
    server
        .get(&format!("/v1/jobs/{}/mesh", ids[0]))
        .await
        .problem(410, "result_evicted");
    server
        .get(&format!("/v1/jobs/{}/report", ids[0]))
        .await
        .problem(410, "result_evicted");
    let new = server.get(&format!("/v1/jobs/{}/mesh", ids[1])).await;
    assert_eq!(new.status, StatusCode::OK);
    assert_eq!(
        server
            .metric("meshsmooth_results_evicted_total{reason=\"memory\"}")
            .await,
        1.0
    );
}

#[tokio::test]
async fn a_panicking_job_fails_alone_and_the_next_one_succeeds() {
    let server = Server::start(&["--workers", "1"]);
    let (obj, _, _) = small_sphere();
    let r = server
        .send(
            Req::raw("/v1/jobs", "model/obj", obj.clone())
                .header("x-meshsmooth-test-hook", "panic"),
        )
        .await;
    let id = job_id(&r);
    let job = server.wait_job(&id, LONG).await;
    assert_eq!(job["state"], "failed", "{job}");
    assert_eq!(job["error"]["code"], "job_panicked");
    assert_eq!(job["error"]["status"], 500);
    assert!(
        !job["error"]["detail"]
            .as_str()
            .unwrap()
            .contains("test hook"),
        "the panic message stays internal"
    );
    server
        .get(&format!("/v1/jobs/{id}/mesh"))
        .await
        .problem(409, "job_failed");
    // The one-call path answers the job's problem.
    server
        .send(
            Req::raw("/v1/smooth", "model/obj", obj.clone())
                .header("x-meshsmooth-test-hook", "panic"),
        )
        .await
        .problem(500, "job_panicked");
    // The single worker survived.
    let r = server
        .send(Req::raw(
            "/v1/smooth?method=laplacian",
            "model/obj",
            obj.clone(),
        ))
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text());
    assert_smoothed(&obj, &r.text());
    assert_eq!(server.metric("meshsmooth_job_panics_total").await, 2.0);
    assert!(server.logs().contains("job panicked"));
}

#[tokio::test]
async fn jobs_past_the_time_limit_fail() {
    let server = Server::start(&["--job-time-limit", "300ms"]);
    let (obj, _, _) = small_sphere();
    let start = Instant::now();
    let r = server
        .send(
            Req::raw("/v1/smooth", "model/obj", obj)
                .header("x-meshsmooth-test-hook", "sleep=20000"),
        )
        .await;
    let p = r.problem(503, "job_time_limit_exceeded");
    assert!(p["detail"].as_str().unwrap().contains("0.3 s"), "{p}");
    assert!(start.elapsed() < Duration::from_secs(5));
    let id = r.header("x-job-id").unwrap();
    let job = server.get(&format!("/v1/jobs/{id}")).await.json();
    assert_eq!(job["state"], "failed");
    assert_eq!(job["error"]["code"], "job_time_limit_exceeded");
}

#[tokio::test]
async fn unknown_jobs_are_not_found() {
    let server = Server::start(&[]);
    for path in [
        "/v1/jobs/3f1e8a52-1c2b-4d5e-8f90-123456789abc",
        "/v1/jobs/not-a-uuid",
        "/v1/jobs/3f1e8a52-1c2b-4d5e-8f90-123456789abc/mesh",
        "/v1/jobs/3f1e8a52-1c2b-4d5e-8f90-123456789abc/report",
        "/v1/jobs/3f1e8a52-1c2b-4d5e-8f90-123456789abc/events",
    ] {
        server.get(path).await.problem(404, "job_not_found");
    }
    // Results of unfinished jobs are a conflict.
    let (obj, _, _) = small_sphere();
    let id = job_id(
        &server
            .send(
                Req::raw("/v1/jobs", "model/obj", obj)
                    .header("x-meshsmooth-test-hook", "sleep=20000"),
            )
            .await,
    );
    server
        .get(&format!("/v1/jobs/{id}/mesh"))
        .await
        .problem(409, "job_not_finished");
    server
        .get(&format!("/v1/jobs/{id}/report"))
        .await
        .problem(409, "job_not_finished");
}

#[tokio::test]
async fn glb_uploads_come_back_as_glb_with_the_same_counts() {
    let server = Server::start(&[]);
    let (obj, vertices, _) = small_sphere();
    // A GLB made by the service itself from the OBJ.
    let r = server
        .send(Req::raw(
            "/v1/smooth?method=laplacian&format=glb",
            "model/obj",
            obj,
        ))
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text());
    assert_eq!(r.header("content-type"), Some("model/gltf-binary"));
    assert!(r.body.starts_with(b"glTF"));
    let glb = r.body.to_vec();

    // Counts as the server reads them back.
    let counts = |job: &Value| {
        (
            job["input"]["vertices"].clone(),
            job["input"]["faces"].clone(),
        )
    };
    let r = server
        .send(Req::raw("/v1/jobs", "model/gltf-binary", glb.clone()))
        .await;
    let id = job_id(&r);
    let input = r.json();
    assert_eq!(input["input"]["format"], "glb");
    assert_eq!(input["output_format"], "glb");
    assert_eq!(input["input"]["vertices"], vertices);
    let job = server.wait_job(&id, LONG).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    let smoothed = server.get(&format!("/v1/jobs/{id}/mesh")).await;
    assert_eq!(smoothed.header("content-type"), Some("model/gltf-binary"));
    assert!(smoothed.body.starts_with(b"glTF"));
    assert_ne!(smoothed.body.to_vec(), glb, "the positions changed");

    // The smoothed GLB, uploaded as a named multipart file, has the input's
    // vertex and face counts.
    let part = Part {
        name: "mesh",
        file_name: Some("smoothed.glb"),
        content_type: None,
        data: smoothed.body.to_vec(),
    };
    let again = server.send(Req::multipart("/v1/jobs", &[part])).await;
    job_id(&again);
    assert_eq!(counts(&again.json()), counts(&input));

    // Download in another format.
    let as_obj = server.get(&format!("/v1/jobs/{id}/mesh?format=obj")).await;
    assert_eq!(as_obj.status, StatusCode::OK, "{}", as_obj.text());
    assert_eq!(as_obj.header("content-type"), Some("model/obj"));
    let (v, f) = obj_stats(&as_obj.text());
    assert_eq!(v.len(), vertices);
    assert_eq!(serde_json::json!(f), input["input"]["faces"]);
}
