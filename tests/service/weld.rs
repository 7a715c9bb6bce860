//! Welding and per-vertex results through the API: the upload is read with
//! the job's parameters.

use crate::support::{Part, Req, Server, job_id};
use hyper::StatusCode;
use meshsmooth_core::io::stl::write_stl_plain;
use meshsmooth_core::io::{self, Format, ReadOptions};
use meshsmooth_core::shapes;
use serde_json::Value;
use std::time::Duration;

const LONG: Duration = Duration::from_secs(60);

/// A binary STL of a marching-cubes ball: a triangle soup (three vertices
/// per triangle). Returns the bytes, the welded vertex count and the
/// file's vertex count.
fn stl_soup() -> (Vec<u8>, usize, usize) {
    let (_, mesh) = shapes::mc_sphere(4.0);
    let mut bytes = Vec::new();
    write_stl_plain(&mesh, mesh.positions(), false, &mut bytes).unwrap();
    (bytes, mesh.num_vertices(), 3 * mesh.num_faces())
}

/// Submits `req`, waits for the job and returns (job, report).
async fn run(server: &Server, req: Req) -> (Value, Value) {
    let r = server.send(req).await;
    let id = job_id(&r);
    let job = server.wait_job(&id, LONG).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    let report = server.get(&format!("/v1/jobs/{id}/report")).await;
    assert_eq!(report.status, StatusCode::OK, "{}", report.text());
    (job, report.json())
}

/// The JSON chunk of a GLB.
fn glb_json(bytes: &[u8]) -> Value {
    assert_eq!(bytes.get(..4), Some(&b"glTF"[..]), "not a GLB");
    let len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    serde_json::from_slice(&bytes[20..20 + len]).unwrap()
}

#[tokio::test]
async fn stl_soups_are_welded_unless_asked_not_to() {
    let server = Server::start(&[]);
    let (stl, welded, file_vertices) = stl_soup();

    // Default (`weld` null): STL is welded; the result keeps the file's
    // vertices, each copy at its welded vertex's position.
    let (job, report) = run(&server, Req::raw("/v1/jobs", "model/stl", stl.clone())).await;
    // Asked as `null` (the format's default): the job shows the request,
    // the report what was done.
    assert_eq!(job["params"]["weld"], Value::Null);
    assert_eq!(report["reproducibility"]["params"]["weld"], true);
    assert_eq!(job["input"]["vertices"], welded);
    assert_eq!(
        report["schema_version"],
        meshsmooth_core::report::SCHEMA_VERSION
    );
    assert_eq!(report["mesh"]["vertices"], welded);
    assert_eq!(report["mesh"]["file_vertices"], file_vertices);
    assert_eq!(report["mesh"]["closed"], true);
    let id = job["id"].as_str().unwrap();
    let mesh = server.get(&format!("/v1/jobs/{id}/mesh")).await;
    assert_eq!(mesh.status, StatusCode::OK);
    let unwelded = ReadOptions {
        weld: Some(false),
        ..ReadOptions::default()
    };
    let back = io::read_with(&mesh.body, Format::Stl, &unwelded).unwrap();
    assert_eq!(back.mesh.num_vertices(), file_vertices);
    let rewelded = io::read_with(&mesh.body, Format::Stl, &ReadOptions::default()).unwrap();
    assert_eq!(rewelded.mesh.num_vertices(), welded, "seams opened");

    // `?weld=false`: the soup is smoothed as it is.
    let (job, report) = run(
        &server,
        Req::raw("/v1/jobs?weld=false", "model/stl", stl.clone()),
    )
    .await;
    assert_eq!(job["params"]["weld"], false);
    assert_eq!(job["input"]["vertices"], file_vertices);
    assert_eq!(report["mesh"]["vertices"], file_vertices);
    assert_eq!(report["mesh"]["file_vertices"], Value::Null);
    assert_eq!(report["mesh"]["closed"], false);

    // The `params` part chooses the welding too; the tolerance is checked
    // before the job is queued.
    let part = |json: &str| {
        Req::multipart(
            "/v1/jobs",
            &[
                Part {
                    name: "mesh",
                    file_name: Some("ball.stl"),
                    content_type: Some("application/octet-stream"),
                    data: stl.clone(),
                },
                Part::params(json),
            ],
        )
    };
    let (_, report) = run(&server, part(r#"{"weld": false}"#)).await;
    assert_eq!(report["mesh"]["vertices"], file_vertices);
    let p = server
        .send(part(r#"{"weld_tolerance": 0.5}"#))
        .await
        .problem(422, "parameter_out_of_range");
    assert_eq!(p["field"], "weld_tolerance");
}

#[tokio::test]
async fn vertex_results_become_glb_attributes() {
    let server = Server::start(&[]);
    let (stl, welded, _) = stl_soup();
    let (job, _) = run(
        &server,
        Req::raw(
            "/v1/jobs?vertex_results=true&format=glb",
            "model/stl",
            stl.clone(),
        ),
    )
    .await;
    assert_eq!(job["params"]["vertex_results"], true);
    let id = job["id"].as_str().unwrap();
    let mesh = server.get(&format!("/v1/jobs/{id}/mesh")).await;
    assert_eq!(mesh.status, StatusCode::OK);
    assert_eq!(mesh.header("content-type"), Some("model/gltf-binary"));
    let json = glb_json(&mesh.body);
    let attributes = &json["meshes"][0]["primitives"][0]["attributes"];
    for name in [
        "_LABEL",
        "_MEAN_CURVATURE",
        "_GAUSSIAN_CURVATURE",
        "_DISPLACEMENT",
    ] {
        let accessor = &json["accessors"][attributes[name].as_u64().unwrap() as usize];
        assert_eq!(accessor["count"], welded, "{name}");
    }

    // Without the parameter the GLB has no result attributes.
    let (job, _) = run(&server, Req::raw("/v1/jobs?format=glb", "model/stl", stl)).await;
    let id = job["id"].as_str().unwrap();
    let mesh = server.get(&format!("/v1/jobs/{id}/mesh")).await;
    let json = glb_json(&mesh.body);
    assert!(json["meshes"][0]["primitives"][0]["attributes"]["_LABEL"].is_null());
}
