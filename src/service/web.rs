//! The web page at `GET /`: upload a mesh, watch the job, compare before
//! and after in 3D and read the report. Everything it needs is embedded in
//! the binary (no CDN, works offline): the page, its script and style
//! sheet, a minimal build of three.js (`web/vendor/`, with its licence) and
//! the sample meshes of `samples/`.
//!
//! The page calls only the public API (`/v1/...`), so it is also the worked
//! example for front-end developers (docs/browser.md).

use axum::Router;
use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use serde_json::json;

/// One embedded file served at a fixed path.
struct Asset {
    path: &'static str,
    content_type: &'static str,
    bytes: &'static [u8],
}

/// The page and what it loads.
const ASSETS: &[Asset] = &[
    Asset {
        path: "/",
        content_type: "text/html; charset=utf-8",
        bytes: include_bytes!("web/index.html"),
    },
    Asset {
        path: "/web/app.js",
        content_type: "text/javascript; charset=utf-8",
        bytes: include_bytes!("web/app.js"),
    },
    Asset {
        path: "/web/glb.js",
        content_type: "text/javascript; charset=utf-8",
        bytes: include_bytes!("web/glb.js"),
    },
    Asset {
        path: "/web/style.css",
        content_type: "text/css; charset=utf-8",
        bytes: include_bytes!("web/style.css"),
    },
    Asset {
        path: "/web/vendor/three.min.js",
        content_type: "text/javascript; charset=utf-8",
        bytes: include_bytes!("web/vendor/three.min.js"),
    },
    Asset {
        path: "/web/vendor/LICENSE-three.txt",
        content_type: "text/plain; charset=utf-8",
        bytes: include_bytes!("web/vendor/LICENSE-three.txt"),
    },
];

/// A sample mesh offered on the page ("try a sample") and served at
/// `/samples/{file}`; the same files are in the repository's `samples/`.
pub struct Sample {
    /// File name in `samples/`.
    pub file: &'static str,
    /// What the mesh is, for the page.
    pub description: &'static str,
    /// Content.
    pub bytes: &'static [u8],
}

/// The samples, generated from the core's analytic shapes (see
/// samples/README.md).
pub const SAMPLES: &[Sample] = &[
    Sample {
        file: "voxel-torus.obj",
        description: "voxel-mask boundary of a torus (quads, OBJ)",
        bytes: include_bytes!("../../samples/voxel-torus.obj"),
    },
    Sample {
        file: "mc-ellipsoid.obj",
        description: "marching-cubes ellipsoid (triangles, OBJ)",
        bytes: include_bytes!("../../samples/mc-ellipsoid.obj"),
    },
    Sample {
        file: "voxel-sphere.glb",
        description: "voxel-mask boundary of a sphere (binary glTF)",
        bytes: include_bytes!("../../samples/voxel-sphere.glb"),
    },
];

/// Content-Security-Policy of the page: its own origin only (the page
/// loads nothing from elsewhere; downloads are same-origin links).
const CSP: &str = "default-src 'self'; img-src 'self' data: blob:; \
                   style-src 'self'; script-src 'self'; connect-src 'self'; \
                   object-src 'none'; base-uri 'none'; frame-ancestors 'none'";

/// The routes of the page, its assets and the samples.
pub fn router() -> Router {
    let mut router = Router::new();
    for asset in ASSETS {
        router = router.route(
            asset.path,
            get(move || async move { asset_response(asset.content_type, asset.bytes) }),
        );
    }
    for sample in SAMPLES {
        let content_type = meshsmooth_core::io::Format::from_file_name(sample.file)
            .map_or("application/octet-stream", |f| f.content_type());
        router = router.route(
            &format!("/samples/{}", sample.file),
            get(move || async move { asset_response(content_type, sample.bytes) }),
        );
    }
    router.route("/web/samples.json", get(samples_list))
}

fn asset_response(content_type: &'static str, bytes: &'static [u8]) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(content_type)),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
            (
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static(CSP),
            ),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
        ],
        bytes,
    )
        .into_response()
}

/// `GET /web/samples.json`: the samples the page offers.
async fn samples_list() -> Response {
    let list: Vec<_> = SAMPLES
        .iter()
        .map(|s| {
            json!({
                "file": s.file,
                "url": format!("/samples/{}", s.file),
                "description": s.description,
                "bytes": s.bytes.len(),
            })
        })
        .collect();
    axum::Json(list).into_response()
}
