//! Typed errors of the mesh core. The service maps each variant to an HTTP
//! status and a stable machine-readable code in one place (`code()`).

use thiserror::Error;

/// Why a mesh could not be built from positions and faces.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum MeshError {
    /// A face refers to a vertex index that does not exist.
    #[error("face {face} refers to vertex {index}, but the mesh has {num_vertices} vertices")]
    IndexOutOfRange {
        face: usize,
        index: u64,
        num_vertices: usize,
    },
    /// A face has fewer than three corners.
    #[error("face {face} has {arity} corners; a face needs at least 3")]
    FaceTooSmall { face: usize, arity: usize },
    /// A vertex coordinate is NaN or infinite.
    #[error("vertex {vertex} has a non-finite coordinate")]
    NonFinitePosition { vertex: usize },
    /// Face offsets are not a valid CSR offset array.
    #[error("invalid face offsets: {0}")]
    InvalidOffsets(&'static str),
    /// The mesh exceeds what 32-bit indices can address.
    #[error("mesh too large: {what} count {count} exceeds the limit of {limit}")]
    TooLarge {
        what: &'static str,
        count: usize,
        limit: usize,
    },
}

impl MeshError {
    /// Stable snake_case code for machine consumers.
    pub fn code(&self) -> &'static str {
        match self {
            MeshError::IndexOutOfRange { .. } => "face_index_out_of_range",
            MeshError::FaceTooSmall { .. } => "face_too_small",
            MeshError::NonFinitePosition { .. } => "non_finite_coordinate",
            MeshError::InvalidOffsets(_) => "invalid_mesh",
            MeshError::TooLarge { .. } => "mesh_too_large",
        }
    }
}
