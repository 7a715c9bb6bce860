//! meshsmooth-core: the mesh library behind the `meshsmooth` service and
//! CLI. It smooths surface meshes from biomedical imaging with the
//! quadric-fitting, curvature-adaptive method of Wang & Yu (IMR 2009) and
//! proves the result with a quality report. Synchronous and free of HTTP.
//!
//! # A guide, from the top
//!
//! - [`job`]: one call from the bytes of a mesh file to the bytes of the
//!   smoothed file and its full report ([`job::run`]), or in two steps
//!   ([`job::Input::read`], [`job::Input::smooth`]). Start here.
//! - [`io`]: the formats (OBJ, glTF 2.0 and GLB, PLY, STL), read into a
//!   [`Mesh`] and written back with everything else of the file kept.
//! - [`params`]: every parameter of a run, with its default and range
//!   ([`Params`]).
//! - [`pipeline`]: the stages on a mesh ([`pipeline::run`]): analyse,
//!   initial smoothing, labelling, adaptive smoothing, quality fixes,
//!   measures.
//! - [`report`]: the quality report and its measures.
//! - [`control`]: progress ([`Progress`]) and cancellation.
//! - [`mesh`]: the mesh with flat CSR [`Topology`].
//! - `shapes` (feature `shapes`): analytic test shapes with exact
//!   distances, for tests and benchmarks.
//!
//! The paper's steps themselves (fitting primitives, the smoothing steps,
//! the quality fixes) are internal: their parameters are in [`Params`],
//! their results in the report. Each module uses only those below it
//! (`tests/layers.rs` holds that).
//!
//! # Example
//!
//! Smooth a small closed OBJ surface (an octahedron) and read the report:
//!
//! ```
//! use meshsmooth_core::io::{Format, ReadLimits};
//! use meshsmooth_core::job::{self, Request};
//! use meshsmooth_core::{NoProgress, Params};
//! use std::sync::atomic::AtomicBool;
//!
//! let obj = b"v 1 0 0\nv -1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1\n\
//!     f 1 3 5\nf 3 2 5\nf 2 4 5\nf 4 1 5\nf 3 1 6\nf 2 3 6\nf 4 2 6\nf 1 4 6\n";
//! let params = Params::default();
//! let request = Request {
//!     bytes: obj,
//!     format: Format::Obj,
//!     params: &params,
//!     limits: ReadLimits::default(),
//!     output_format: None,
//! };
//! let cancel = AtomicBool::new(false);
//! let output = job::run(&request, &NoProgress, &cancel)?;
//! assert_eq!(output.format, Format::Obj);
//! assert!(output.bytes.starts_with(b"v "));
//! assert_eq!(output.report.mesh.vertices, 6);
//! let hashes = &output.report.reproducibility;
//! assert!(hashes.input_sha256.is_some() && hashes.output_sha256.is_some());
//! # Ok::<(), meshsmooth_core::job::JobError>(())
//! ```

pub mod control;
pub mod error;
pub(crate) mod fit;
pub mod io;
pub mod job;
pub mod mesh;
pub mod params;
pub mod pipeline;
pub(crate) mod quality;
pub mod report;
#[cfg(any(test, feature = "shapes"))]
pub mod shapes;
pub(crate) mod smoothing;
mod sort;

pub use control::{Cancelled, NoProgress, Progress, Stage};
pub use error::{ErrorCode, MeshError};
pub use mesh::{Mesh, Topology, VertexKind};
pub use params::{Method, ParamError, Params};
pub use pipeline::{SmoothError, SmoothOutput, run};
