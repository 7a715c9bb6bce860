//! The sample meshes in `samples/`: generated from the core's analytic
//! shapes (so they carry no third-party licence), committed, and served by
//! the binary at `/samples/{file}` for the page's "try a sample".
//!
//! To regenerate them after an intended change of the shapes or writers:
//! `MESHSMOOTH_UPDATE_SAMPLES=1 cargo test --test web samples`.

use crate::support::Server;
use hyper::StatusCode;
use meshsmooth_core::io::gltf::write_gltf_plain;
use meshsmooth_core::io::obj::write_obj_plain;
use meshsmooth_core::shapes;
use std::path::Path;

/// Each sample: its file name and its content, generated now.
fn generated() -> Vec<(&'static str, Vec<u8>)> {
    let (_, torus) = shapes::voxel_torus(10.0, 4.0);
    let mut voxel_torus = Vec::new();
    write_obj_plain(&torus, torus.positions(), &mut voxel_torus).unwrap();
    let (_, ellipsoid) = shapes::mc_ellipsoid(14.0, 10.0, 7.0);
    let mut mc_ellipsoid = Vec::new();
    write_obj_plain(&ellipsoid, ellipsoid.positions(), &mut mc_ellipsoid).unwrap();
    let (_, sphere) = shapes::voxel_sphere(10.0);
    let mut voxel_sphere = Vec::new();
    write_gltf_plain(&sphere, sphere.positions(), None, true, &mut voxel_sphere).unwrap();
    vec![
        ("voxel-torus.obj", voxel_torus),
        ("mc-ellipsoid.obj", mc_ellipsoid),
        ("voxel-sphere.glb", voxel_sphere),
    ]
}

#[test]
fn the_committed_samples_are_the_generated_ones() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples");
    for (file, bytes) in generated() {
        let path = dir.join(file);
        if std::env::var_os("MESHSMOOTH_UPDATE_SAMPLES").is_some() {
            std::fs::write(&path, &bytes).expect("write the sample");
            continue;
        }
        let committed = std::fs::read(&path).unwrap_or_default();
        assert!(
            committed == bytes,
            "samples/{file} differs from what the shapes generate; review the change and \
             regenerate with `MESHSMOOTH_UPDATE_SAMPLES=1 cargo test --test web samples`"
        );
    }
}

#[tokio::test]
async fn the_server_offers_every_sample() {
    let server = Server::start(&[]);
    let list = server.get("/web/samples.json").await;
    assert_eq!(list.status, StatusCode::OK, "{}", list.text());
    let list = list.json();
    let files: Vec<&str> = list
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["file"].as_str().unwrap())
        .collect();
    let expected: Vec<&str> = generated().iter().map(|(f, _)| *f).collect();
    assert_eq!(files, expected);
    for entry in list.as_array().unwrap() {
        let file = entry["file"].as_str().unwrap();
        let r = server.get(entry["url"].as_str().unwrap()).await;
        assert_eq!(r.status, StatusCode::OK, "{file}");
        let committed = std::fs::read(
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("samples")
                .join(file),
        )
        .unwrap();
        assert!(
            r.body == committed,
            "{file} served differs from samples/{file}"
        );
        assert_eq!(entry["bytes"], committed.len(), "{file}");
    }
}

#[tokio::test]
async fn the_page_and_its_assets_are_served() {
    let server = Server::start(&[]);
    let page = server.get("/").await;
    assert_eq!(page.status, StatusCode::OK);
    assert_eq!(
        page.header("content-type"),
        Some("text/html; charset=utf-8")
    );
    assert!(
        page.header("content-security-policy")
            .is_some_and(|c| c.contains("default-src 'self'"))
    );
    let html = page.text();
    for asset in ["/web/style.css", "/web/app.js"] {
        assert!(html.contains(asset), "{asset}");
        let r = server.get(asset).await;
        assert_eq!(r.status, StatusCode::OK, "{asset}");
    }
    for asset in [
        "/web/glb.js",
        "/web/vendor/three.min.js",
        "/web/vendor/LICENSE-three.txt",
    ] {
        let r = server.get(asset).await;
        assert_eq!(r.status, StatusCode::OK, "{asset}");
        assert!(!r.body.is_empty(), "{asset}");
    }
    let r = server.get("/web/nothing.js").await;
    r.problem(404, "not_found");
}

/// Every `THREE.X` the page's script uses is exported by the vendored
/// minimal build's entry (`src/service/web/vendor/three-entry.js`).
#[test]
fn the_minimal_three_build_exports_what_the_page_uses() {
    let web = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/service/web");
    let app = std::fs::read_to_string(web.join("app.js")).unwrap();
    let entry = std::fs::read_to_string(web.join("vendor/three-entry.js")).unwrap();
    let exported: Vec<&str> = entry
        .split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|w| !w.is_empty())
        .collect();
    let mut used: Vec<&str> = app
        .split("THREE.")
        .skip(1)
        .map(|rest| {
            let end = rest
                .find(|c: char| !c.is_ascii_alphanumeric())
                .unwrap_or(rest.len());
            &rest[..end]
        })
        .collect();
    used.sort_unstable();
    used.dedup();
    assert!(used.len() > 5, "{used:?}");
    let missing: Vec<&&str> = used.iter().filter(|u| !exported.contains(u)).collect();
    assert!(
        missing.is_empty(),
        "three-entry.js lacks {missing:?}: add them and rebuild three.min.js (vendor/README.md)"
    );
}
