//! meshsmooth-core: the mesh library behind the `meshsmooth` service and
//! CLI. Synchronous and free of HTTP: a [`Mesh`] with flat CSR
//! [`Topology`], readers and writers in [`io`], the Wang & Yu (IMR 2009)
//! quadric-fitting smoother in [`smoothing`] with the mesh-quality fixes in
//! [`quality`], the [`report`] that proves the result, and [`pipeline::run`]
//! that ties them together.

pub mod control;
pub mod error;
pub mod fit;
pub mod io;
pub mod job;
pub mod mesh;
pub mod params;
pub mod pipeline;
pub mod quality;
pub mod report;
pub mod shapes;
pub mod smoothing;
mod sort;

pub use control::{Cancelled, NoProgress, Progress, Stage};
pub use error::{ErrorCode, MeshError};
pub use mesh::{Mesh, Topology, VertexKind};
pub use params::{Method, ParamError, Params};
pub use pipeline::{SmoothError, SmoothOutput, run};
