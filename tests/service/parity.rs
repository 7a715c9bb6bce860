//! The CLI and the HTTP service run the same job layer: the same file and
//! parameters give byte-identical meshes and equal reports (timings aside),
//! both with the hashes of what was read and written.

use crate::support::{Req, Server, job_id};
use hyper::StatusCode;
use meshsmooth_core::io::{self, Format, ReadLimits};
use meshsmooth_core::report::sha256_hex;
use meshsmooth_core::shapes;
use serde_json::Value;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// A small marching-cubes ball (triangles) in `format`, with the vertex
/// results asked for where the format holds them.
fn input(format: Format) -> Vec<u8> {
    let (_, mesh) = shapes::mc_sphere(5.0);
    let mut obj = Vec::new();
    io::obj::write_obj_plain(&mesh, mesh.positions(), &mut obj).expect("write the OBJ");
    let doc = io::read(&obj, Format::Obj, &ReadLimits::default()).expect("read the OBJ");
    io::write(&doc, doc.mesh.positions(), format).expect("convert")
}

/// Timings differ from run to run; everything else of a report must not.
fn without_timings(mut report: Value) -> Value {
    let object = report.as_object_mut().expect("a report object");
    assert!(object.remove("timings").is_some(), "no timings: {report}");
    assert!(object.remove("total_ms").is_some());
    report
}

/// `meshsmooth smooth` on `bytes`: (mesh, report).
fn cli(dir: &Path, format: Format, bytes: &[u8], params: &str) -> (Vec<u8>, Value) {
    let ext = format.extension();
    let (input, output, report) = (
        dir.join(format!("in.{ext}")),
        dir.join(format!("out.{ext}")),
        dir.join(format!("report-{ext}.json")),
    );
    let params_file = dir.join(format!("params-{ext}.json"));
    std::fs::write(&input, bytes).unwrap();
    std::fs::write(&params_file, params).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_meshsmooth"))
        .arg("smooth")
        .arg(&input)
        .arg("-o")
        .arg(&output)
        .arg("--report")
        .arg(&report)
        .arg("--params")
        .arg(&params_file)
        .arg("--quiet")
        .output()
        .expect("run meshsmooth smooth");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    (std::fs::read(&output).unwrap(), report)
}

/// `POST /v1/jobs` with `bytes` as the raw body: (mesh, report).
async fn service(server: &Server, format: Format, bytes: &[u8], params: &str) -> (Vec<u8>, Value) {
    let query: String = url_encode(params);
    let r = server
        .send(Req::raw(
            &format!("/v1/jobs?params={query}"),
            format.content_type(),
            bytes.to_vec(),
        ))
        .await;
    let id = job_id(&r);
    let job = server.wait_job(&id, Duration::from_secs(60)).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    let mesh = server.get(&format!("/v1/jobs/{id}/mesh")).await;
    assert_eq!(mesh.status, StatusCode::OK, "{}", mesh.text());
    let report = server.get(&format!("/v1/jobs/{id}/report")).await;
    assert_eq!(report.status, StatusCode::OK, "{}", report.text());
    (mesh.body.to_vec(), report.json())
}

/// Percent-encodes everything but unreserved characters.
fn url_encode(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => {
                (b as char).to_string()
            }
            b => format!("%{b:02X}"),
        })
        .collect()
}

#[tokio::test]
async fn cli_and_service_give_the_same_mesh_and_report() {
    let server = Server::start(&[]);
    let dir = std::env::temp_dir().join(format!("meshsmooth-parity-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (format, params) in [
        (Format::Obj, r#"{"k_max": 4}"#),
        (Format::Glb, r#"{"vertex_results": true}"#),
        (
            Format::Ply,
            r#"{"vertex_results": true, "adaptive_passes": 3}"#,
        ),
        (Format::Stl, r#"{"weld": true}"#),
        (Format::Off, r#"{"initial_passes": 2}"#),
    ] {
        let bytes = input(format);
        let (cli_mesh, cli_report) = cli(&dir, format, &bytes, params);
        let (http_mesh, http_report) = service(&server, format, &bytes, params).await;
        assert!(cli_mesh == http_mesh, "{format}: the meshes differ");
        let repro = &cli_report["reproducibility"];
        assert_eq!(repro["input_sha256"], sha256_hex(&bytes), "{format}");
        assert_eq!(repro["output_sha256"], sha256_hex(&cli_mesh), "{format}");
        assert_eq!(
            without_timings(cli_report),
            without_timings(http_report),
            "{format}: the reports differ"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test]
async fn a_label_complex_smooths_alike_through_the_cli_and_the_service() {
    // Three labels of a block, their walls written once (VTK's surface
    // nets): smoothed region by region either way.
    let server = Server::start(&[]);
    let dir = std::env::temp_dir().join(format!("meshsmooth-complex-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let masks: Vec<_> = (0..3)
        .map(|label| {
            shapes::VoxelMask::from_fn(glam::IVec3::ZERO, [9, 6, 6], |i, _, _| i / 3 == label)
        })
        .collect();
    let complex = shapes::label_complex(&masks);
    let mut bytes = Vec::new();
    io::obj::write_obj_plain(&complex, complex.positions(), &mut bytes).unwrap();
    let (cli_mesh, cli_report) = cli(&dir, Format::Obj, &bytes, "{}");
    let (http_mesh, http_report) = service(&server, Format::Obj, &bytes, "{}").await;
    assert!(cli_mesh == http_mesh, "the meshes differ");
    assert_eq!(http_report["mesh"]["regions"], 3);
    assert_eq!(http_report["mesh"]["region_walls"], 72);
    assert_eq!(without_timings(cli_report), without_timings(http_report));
    let _ = std::fs::remove_dir_all(&dir);
}
