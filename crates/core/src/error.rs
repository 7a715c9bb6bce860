//! Typed errors of the mesh core and the one list of their stable,
//! machine-readable codes ([`ErrorCode`]). Each error's `code()` names its
//! code; the service maps every code to an HTTP status in one `match`.

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
    /// Stable code for machine consumers.
    pub fn code(&self) -> ErrorCode {
        match self {
            MeshError::IndexOutOfRange { .. } => ErrorCode::FaceIndexOutOfRange,
            MeshError::FaceTooSmall { .. } => ErrorCode::FaceTooSmall,
            MeshError::NonFinitePosition { .. } => ErrorCode::NonFiniteCoordinate,
            MeshError::InvalidOffsets(_) => ErrorCode::InvalidMesh,
            MeshError::TooLarge { .. } => ErrorCode::MeshTooLarge,
        }
    }
}

/// A mesh whose shape would make smoothing cost grow faster than its size:
/// the ring walks and fits visit every neighbour of every vertex in a
/// ring, so one vertex of valence `d` costs `d^2` across its neighbours'
/// walks, and one face of `n` corners costs `n^2` across its corners.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ShapeError {
    /// A vertex has more edges than smoothing takes.
    #[error(
        "vertex {vertex} has {valence} edges; smoothing takes vertices of at most {limit} \
         (a fan this wide makes every ring walk around it cost its square)"
    )]
    ValenceTooHigh {
        vertex: usize,
        valence: usize,
        limit: usize,
    },
    /// A face has more corners than smoothing takes.
    #[error(
        "face {face} has {arity} corners; smoothing takes faces of at most {limit} corners \
         (split it into smaller polygons)"
    )]
    FaceTooLarge {
        face: usize,
        arity: usize,
        limit: usize,
    },
}

impl ShapeError {
    /// Stable code for machine consumers.
    pub fn code(&self) -> ErrorCode {
        match self {
            ShapeError::ValenceTooHigh { .. } => ErrorCode::VertexValenceTooHigh,
            ShapeError::FaceTooLarge { .. } => ErrorCode::FaceTooLarge,
        }
    }
}

/// Declares an enum of stable error codes, each variant with its
/// snake_case text: `as_str`, `OWN` (the variants declared here, in
/// order), `Display` and comparison with text. An optional first variant
/// wraps another such enum (the service's codes wrap the core's).
#[macro_export]
macro_rules! error_code_enum {
    (
        $(#[$meta:meta])*
        $name:ident $({ $(#[$wrap_doc:meta])* $wrap:ident($inner:ty) })?;
        $($(#[$doc:meta])* $variant:ident = $text:literal,)*
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum $name {
            $($(#[$wrap_doc])* $wrap($inner),)?
            $($(#[$doc])* $variant,)*
        }

        impl $name {
            /// The codes declared here (not those wrapped), in order.
            #[allow(dead_code)]
            pub const OWN: &[$name] = &[$($name::$variant,)*];

            /// The snake_case text, e.g. `parse_error`.
            pub fn as_str(self) -> &'static str {
                match self {
                    $($name::$wrap(code) => code.as_str(),)?
                    $($name::$variant => $text,)*
                }
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.as_str())
            }
        }

        impl PartialEq<&str> for $name {
            fn eq(&self, other: &&str) -> bool {
                self.as_str() == *other
            }
        }
    };
}

error_code_enum! {
    /// The stable code of every error the core reports: what a machine
    /// consumer matches on (the service's `code` field). Adding one makes
    /// every exhaustive `match` on it (the service's status table) name it.
    ErrorCode;
    /// A file is malformed.
    ParseError = "parse_error",
    /// A face refers to a vertex that does not exist.
    FaceIndexOutOfRange = "face_index_out_of_range",
    /// A face has fewer than three corners.
    FaceTooSmall = "face_too_small",
    /// A coordinate is NaN or infinite.
    NonFiniteCoordinate = "non_finite_coordinate",
    /// The face offsets are not valid.
    InvalidMesh = "invalid_mesh",
    /// The mesh exceeds what 32-bit indices address.
    MeshTooLarge = "mesh_too_large",
    /// A vertex or face count exceeds the reading limits.
    LimitExceeded = "limit_exceeded",
    /// The file has no faces.
    NoFaces = "no_faces",
    /// The file uses something the reader does not support.
    UnsupportedContent = "unsupported_content",
    /// Positions handed to a writer are not one per vertex.
    PositionCountMismatch = "position_count_mismatch",
    /// Reading or writing failed below the format.
    IoError = "io_error",
    /// A glTF file refers to an external resource (never fetched).
    ExternalUriNotAllowed = "external_uri_not_allowed",
    /// A glTF file requires an extension the reader does not handle.
    UnsupportedExtension = "unsupported_extension",
    /// A glTF file has only points or lines.
    UnsupportedPrimitiveMode = "unsupported_primitive_mode",
    /// A glTF document breaks the specification.
    GltfInvalid = "gltf_invalid",
    /// A GLB container is malformed.
    GlbInvalid = "glb_invalid",
    /// A parameter is out of its range.
    ParameterOutOfRange = "parameter_out_of_range",
    /// A vertex has more edges than smoothing takes ([`ShapeError`]).
    VertexValenceTooHigh = "vertex_valence_too_high",
    /// A face has more corners than smoothing takes ([`ShapeError`]).
    FaceTooLarge = "face_too_large",
    /// The run was cancelled.
    Cancelled = "cancelled",
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_are_distinct_snake_case() {
        let mut seen = std::collections::HashSet::new();
        for code in ErrorCode::OWN {
            let s = code.as_str();
            assert!(seen.insert(s), "{s} twice");
            assert!(
                s.bytes().all(|b| b.is_ascii_lowercase() || b == b'_'),
                "{s}"
            );
        }
    }
}
