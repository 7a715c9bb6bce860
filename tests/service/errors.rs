//! Bad input: each gets its status and code, and the server stays up.

use crate::support::{Part, Req, Server, obj_stats, small_sphere};
use hyper::{Method, StatusCode};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// Writes `head` (and `body`) on a raw connection and reads the answer's
/// status and body, for requests an HTTP client would not send.
async fn raw_exchange(server: &Server, head: &str, body: &[u8]) -> (u16, String) {
    let addr = server.addr;
    let request = [head.as_bytes(), body].concat();
    tokio::task::spawn_blocking(move || raw_exchange_blocking(addr, &request))
        .await
        .unwrap()
}

fn raw_exchange_blocking(addr: std::net::SocketAddr, request: &[u8]) -> (u16, String) {
    let mut stream = std::net::TcpStream::connect(addr).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    stream.write_all(request).unwrap();
    let mut answer = Vec::new();
    let mut buf = [0u8; 4096];
    // Read until the server closes or the body is complete.
    loop {
        let n = stream.read(&mut buf).expect("an answer in time");
        if n == 0 {
            break;
        }
        answer.extend_from_slice(&buf[..n]);
        let text = String::from_utf8_lossy(&answer);
        if let Some((head, body)) = text.split_once("\r\n\r\n") {
            let length = head
                .lines()
                .find_map(|l| {
                    l.to_ascii_lowercase()
                        .strip_prefix("content-length: ")
                        .map(str::to_owned)
                })
                .and_then(|v| v.trim().parse::<usize>().ok());
            if length.is_some_and(|n| body.len() >= n) {
                break;
            }
        }
    }
    let text = String::from_utf8_lossy(&answer).into_owned();
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no status line in {text:?}"));
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_owned())
        .unwrap_or_default();
    (status, body)
}

#[tokio::test]
async fn every_bad_upload_gets_its_status_and_code() {
    let server = Server::start(&[]);
    let (obj, _, _) = small_sphere();
    let obj_req = |body: &str| Req::raw("/v1/jobs", "model/obj", body.to_owned());

    // Empty body.
    server.send(obj_req("")).await.problem(400, "empty_body");
    // Truncated OBJ: a vertex line cut short.
    let truncated = &obj[..obj.find("\nv ").unwrap() + 5];
    let p = server
        .send(obj_req(truncated))
        .await
        .problem(422, "parse_error");
    assert!(p["detail"].as_str().unwrap().contains("line 2"), "{p}");
    // Face index out of range: the OBJ reader names the line and index.
    let p = server
        .send(obj_req("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"))
        .await
        .problem(422, "face_index_out_of_range");
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains("line 4") && detail.contains('9'), "{p}");
    // NaN coordinates.
    let p = server
        .send(obj_req("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n"))
        .await
        .problem(422, "non_finite_coordinate");
    let detail = p["detail"].as_str().unwrap();
    assert!(
        detail.contains("line 2") && detail.contains("not finite"),
        "{p}"
    );
    // Wrong content type.
    server
        .send(Req::raw("/v1/jobs", "image/png", obj.clone()))
        .await
        .problem(415, "unsupported_media_type");
    server
        .send(Req::new(Method::POST, "/v1/jobs").body(obj.clone()))
        .await
        .problem(415, "unsupported_media_type");
    // Unknown parameter, in the query and in a params part.
    let p = server
        .send(Req::raw("/v1/jobs?k_maks=3", "model/obj", obj.clone()))
        .await
        .problem(422, "unknown_parameter");
    assert_eq!(p["field"], "k_maks");
    let p = server
        .send(Req::multipart(
            "/v1/jobs",
            &[
                Part::obj(&obj),
                Part::params(r#"{"quality": {"sweeps": 3}}"#),
            ],
        ))
        .await
        .problem(422, "unknown_parameter");
    assert_eq!(p["field"], "quality.sweeps");
    // Out-of-range parameter: the detail names the field and the range.
    let p = server
        .send(Req::raw("/v1/jobs?k_max=100000", "model/obj", obj.clone()))
        .await
        .problem(422, "parameter_out_of_range");
    assert_eq!(p["field"], "k_max");
    assert!(p["detail"].as_str().unwrap().contains("allowed"), "{p}");
    // A parameter of the wrong type, and malformed parameter JSON.
    server
        .send(Req::raw("/v1/jobs?k_max=many", "model/obj", obj.clone()))
        .await
        .problem(422, "invalid_parameter");
    server
        .send(Req::multipart(
            "/v1/jobs",
            &[Part::obj(&obj), Part::params("{\"k_max\": ")],
        ))
        .await
        .problem(400, "invalid_params_json");
    // A multipart body without a mesh part, and one with a stray part.
    server
        .send(Req::multipart("/v1/jobs", &[Part::params("{}")]))
        .await
        .problem(400, "missing_mesh_part");
    let stray = Part {
        name: "notes",
        file_name: None,
        content_type: None,
        data: b"hello".to_vec(),
    };
    server
        .send(Req::multipart("/v1/jobs", &[Part::obj(&obj), stray]))
        .await
        .problem(400, "unexpected_part");
    server
        .send(Req::multipart(
            "/v1/jobs",
            &[Part::obj(&obj), Part::obj(&obj)],
        ))
        .await
        .problem(400, "duplicate_part");
    // Garbage bytes: declared as OBJ they fail to parse; undeclared, their
    // format cannot be told.
    let garbage: Vec<u8> = (0..4096u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    server
        .send(Req::raw("/v1/jobs", "model/obj", garbage.clone()))
        .await
        .problem(422, "parse_error");
    server
        .send(Req::raw(
            "/v1/jobs",
            "application/octet-stream",
            garbage.clone(),
        ))
        .await
        .problem(415, "unknown_format");
    let garbage_part = Part {
        name: "mesh",
        file_name: Some("blob.bin"),
        content_type: None,
        data: garbage,
    };
    server
        .send(Req::multipart("/v1/jobs", &[garbage_part]))
        .await
        .problem(415, "unknown_format");
    // A broken multipart body.
    server
        .send(Req::raw(
            "/v1/jobs",
            "multipart/form-data; boundary=x",
            "no parts here",
        ))
        .await
        .problem(400, "malformed_multipart");
    // The one-call path refuses the same way.
    server
        .send(Req::raw("/v1/smooth", "model/obj", ""))
        .await
        .problem(400, "empty_body");
    // Unknown routes and methods.
    server.get("/v2/nothing").await.problem(404, "not_found");
    server
        .send(Req::new(Method::PUT, "/v1/jobs"))
        .await
        .problem(405, "method_not_allowed");

    // Nothing became a job, and the server still works.
    assert_eq!(server.metric("meshsmooth_jobs_submitted_total").await, 0.0);
    assert_eq!(server.get("/healthz").await.status, StatusCode::OK);
    let r = server
        .send(Req::raw(
            "/v1/smooth?method=laplacian",
            "model/obj",
            obj.clone(),
        ))
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text());
    assert_eq!(obj_stats(&r.text()).0.len(), obj_stats(&obj).0.len());
    // A fan whose hub has more edges than smoothing takes is read, then
    // refused by the job with its code, not a worker busy for minutes.
    let mut fan = String::from("v 0 0 0\n");
    let n = 5000;
    for i in 0..n {
        let a = std::f64::consts::TAU * i as f64 / n as f64;
        fan.push_str(&format!("v {} {} 0\n", a.cos(), a.sin()));
    }
    for i in 0..n {
        fan.push_str(&format!("f 1 {} {}\n", i + 2, (i + 1) % n + 2));
    }
    let p = server
        .send(Req::raw("/v1/smooth", "model/obj", fan))
        .await
        .problem(422, "vertex_valence_too_high");
    assert!(p["detail"].as_str().unwrap().contains("5000 edges"), "{p}");
}

#[tokio::test]
async fn size_and_count_limits_are_enforced() {
    let server = Server::start(&["--max-upload-bytes", "64KiB", "--max-vertices", "50"]);
    let (obj, vertices, _) = small_sphere();
    assert!(vertices > 50);

    // A 2 GiB claimed size is refused from the headers alone.
    let head = format!(
        "POST /v1/jobs HTTP/1.1\r\nHost: {}\r\nContent-Type: model/obj\r\n\
         Content-Length: 2147483648\r\n\r\n",
        server.addr
    );
    let started = Instant::now();
    let (status, body) = raw_exchange(&server, &head, b"v 0 0 0\n").await;
    assert_eq!(status, 413, "{body}");
    assert!(body.contains("\"code\":\"upload_too_large\""), "{body}");
    assert!(started.elapsed() < Duration::from_secs(5));

    // A chunked body (no Content-Length) over the limit.
    let big = "v 0 0 0\n".repeat(10_000);
    server
        .send(Req::raw("/v1/jobs", "model/obj", big.clone()))
        .await
        .problem(413, "upload_too_large");
    let part = Part {
        name: "mesh",
        file_name: Some("big.obj"),
        content_type: None,
        data: big.into_bytes(),
    };
    server
        .send(Req::multipart("/v1/jobs", &[part]))
        .await
        .problem(413, "upload_too_large");

    // Too many vertices.
    let p = server
        .send(Req::raw("/v1/jobs", "model/obj", obj))
        .await
        .problem(413, "limit_exceeded");
    assert!(p["detail"].as_str().unwrap().contains("50"), "{p}");
    assert_eq!(server.get("/healthz").await.status, StatusCode::OK);
}

#[tokio::test]
async fn slow_uploads_time_out() {
    let server = Server::start(&["--upload-timeout", "500ms", "--header-timeout", "500ms"]);
    // Headers that never end: the connection is closed.
    let addr = server.addr;
    let started = Instant::now();
    let closed = tokio::task::spawn_blocking(move || {
        let mut stream = std::net::TcpStream::connect(addr).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        stream
            .write_all(b"POST /v1/jobs HTTP/1.1\r\nHost: x\r\n")
            .unwrap();
        let mut buf = [0u8; 1024];
        loop {
            match stream.read(&mut buf) {
                Ok(0) | Err(_) => return,
                Ok(_) => {}
            }
        }
    });
    closed.await.unwrap();
    assert!(started.elapsed() < Duration::from_secs(5));

    let head = format!(
        "POST /v1/jobs HTTP/1.1\r\nHost: {}\r\nContent-Type: model/obj\r\n\
         Content-Length: 100000\r\n\r\n",
        server.addr
    );
    // Send a little, then stall: the server answers 408 on its own.
    let started = Instant::now();
    let (status, body) = raw_exchange(&server, &head, b"v 0 0 0\n").await;
    assert_eq!(status, 408, "{body}");
    assert!(body.contains("upload_timeout"), "{body}");
    assert!(started.elapsed() < Duration::from_secs(5));
    assert_eq!(server.get("/healthz").await.status, StatusCode::OK);
}
