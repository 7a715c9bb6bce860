//! The API contract: the committed `api/openapi.json` must equal the
//! document the server generates from its code.
//!
//! To regenerate it after an intended API change:
//! `MESHSMOOTH_UPDATE_OPENAPI=1 cargo test --test service contract`.

use crate::support::Server;
use hyper::StatusCode;
use serde_json::Value;
use std::path::Path;

#[tokio::test]
async fn the_committed_openapi_document_matches_the_code() {
    let server = Server::start(&[]);
    let r = server.get("/openapi.json").await;
    assert_eq!(r.status, StatusCode::OK);
    let generated = r.json();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("api/openapi.json");
    let pretty = serde_json::to_string_pretty(&generated).unwrap() + "\n";
    if std::env::var_os("MESHSMOOTH_UPDATE_OPENAPI").is_some() {
        std::fs::write(&path, &pretty).expect("write api/openapi.json");
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    let committed: Value = serde_json::from_str(&committed).unwrap_or(Value::Null);
    let mut differences = Vec::new();
    diff("", &committed, &generated, &mut differences);
    assert!(
        differences.is_empty(),
        "api/openapi.json differs from the API the code serves at:\n  {}\nreview the change \
         and regenerate it with `MESHSMOOTH_UPDATE_OPENAPI=1 cargo test --test service contract`",
        differences.join("\n  ")
    );
}

/// JSON pointers where `a` and `b` differ (at most 20).
fn diff(at: &str, a: &Value, b: &Value, out: &mut Vec<String>) {
    if out.len() >= 20 || a == b {
        return;
    }
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let key = k.replace('~', "~0").replace('/', "~1");
                let next = format!("{at}/{key}");
                match (x.get(k), y.get(k)) {
                    (Some(u), Some(v)) => diff(&next, u, v, out),
                    (Some(_), None) => out.push(format!("{next} (only in the committed file)")),
                    (None, _) => out.push(format!("{next} (only in the code)")),
                }
            }
        }
        _ => out.push(if at.is_empty() { "/".into() } else { at.into() }),
    }
}

#[tokio::test]
async fn the_contract_describes_every_route_and_error() {
    let server = Server::start(&[]);
    let api = server.get("/openapi.json").await.json();
    assert!(api["openapi"].as_str().unwrap().starts_with("3."));
    let paths = api["paths"].as_object().unwrap();
    for (path, method) in [
        ("/v1/jobs", "post"),
        ("/v1/jobs/{id}", "get"),
        ("/v1/jobs/{id}", "delete"),
        ("/v1/jobs/{id}/mesh", "get"),
        ("/v1/jobs/{id}/report", "get"),
        ("/v1/jobs/{id}/events", "get"),
        ("/v1/smooth", "post"),
        ("/v1/params/schema", "get"),
        ("/healthz", "get"),
        ("/readyz", "get"),
        ("/metrics", "get"),
    ] {
        let op = &paths[path][method];
        assert!(op.is_object(), "{method} {path} is documented");
        assert!(op["responses"].as_object().is_some_and(|r| !r.is_empty()));
    }
    let upload = &paths["/v1/jobs"]["post"];
    let types = upload["requestBody"]["content"].as_object().unwrap();
    assert!(types.contains_key("multipart/form-data"));
    assert!(types.contains_key("model/obj"));
    for status in ["400", "413", "415", "422", "503"] {
        assert_eq!(
            upload["responses"][status]["content"]["application/problem+json"]["schema"]["$ref"],
            "#/components/schemas/ProblemDetails",
            "{status}"
        );
    }
    assert!(api["components"]["schemas"]["Params"].is_object());
}
