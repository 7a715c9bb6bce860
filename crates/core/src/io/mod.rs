//! Mesh formats: readers and writers over bytes, never paths.
//!
//! [`read`] turns uploaded bytes into a [`Document`]: the [`Mesh`] to smooth
//! plus whatever the format needs to write the same file back with only the
//! positions changed. [`write`] does that, in the input's format or another.
//! Nothing a file points to (external buffers, material libraries) is ever
//! fetched.

pub mod obj;

use crate::mesh::Mesh;
use glam::DVec3;
use thiserror::Error;

/// A mesh file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Format {
    /// Wavefront OBJ (text).
    Obj,
}

impl Format {
    /// Canonical file extension, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Obj => "obj",
        }
    }

    /// MIME type used in HTTP.
    pub fn content_type(self) -> &'static str {
        match self {
            Format::Obj => "model/obj",
        }
    }

    /// Format from a file name's extension (case-insensitive).
    pub fn from_file_name(name: &str) -> Option<Format> {
        let ext = name.rsplit_once('.')?.1.to_ascii_lowercase();
        match ext.as_str() {
            "obj" => Some(Format::Obj),
            _ => None,
        }
    }

    /// Format from an HTTP `Content-Type` (parameters ignored).
    pub fn from_content_type(ct: &str) -> Option<Format> {
        let essence = ct.split(';').next()?.trim().to_ascii_lowercase();
        match essence.as_str() {
            "model/obj" | "text/x-obj" | "application/x-tgif" => Some(Format::Obj),
            _ => None,
        }
    }

    /// Format guessed from the first bytes of a file.
    pub fn sniff(bytes: &[u8]) -> Option<Format> {
        let head = &bytes[..bytes.len().min(4096)];
        let text = std::str::from_utf8(head).ok()?;
        let looks_obj = text.lines().any(|l| {
            let l = l.trim_start();
            l.starts_with("v ") || l.starts_with("f ") || l.starts_with("v\t")
        });
        looks_obj.then_some(Format::Obj)
    }
}

/// Limits applied while reading untrusted input.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadLimits {
    /// Most vertices accepted. Default 20,000,000.
    pub max_vertices: usize,
    /// Most faces accepted. Default 40,000,000.
    pub max_faces: usize,
}

impl Default for ReadLimits {
    fn default() -> Self {
        ReadLimits {
            max_vertices: 20_000_000,
            max_faces: 40_000_000,
        }
    }
}

/// A parsed file: the mesh to smooth plus what is needed to write it back.
#[derive(Debug, Clone)]
pub struct Document {
    /// The mesh the smoother works on.
    pub mesh: Mesh,
    /// Format the document was read from.
    pub format: Format,
    source: Source,
}

#[derive(Debug, Clone)]
enum Source {
    Obj(obj::ObjSource),
}

/// Why a file could not be read or written.
#[derive(Debug, Error)]
pub enum IoError {
    /// Malformed input; `line` is 1-based where the format has lines.
    #[error("{format} parse error{}: {message}", line.map(|l| format!(" on line {l}")).unwrap_or_default())]
    Parse {
        format: &'static str,
        line: Option<usize>,
        message: String,
    },
    /// The input exceeds a configured limit.
    #[error("{what} count {count} exceeds the limit of {limit}")]
    Limit {
        what: &'static str,
        count: usize,
        limit: usize,
    },
    /// The file is valid but uses something this reader does not support.
    #[error("unsupported {format} content: {message}")]
    Unsupported {
        format: &'static str,
        message: String,
    },
    /// The data does not make a valid mesh.
    #[error(transparent)]
    Mesh(#[from] crate::error::MeshError),
    /// Writing failed.
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
}

impl IoError {
    /// Stable snake_case code.
    pub fn code(&self) -> &'static str {
        match self {
            IoError::Parse { .. } => "parse_error",
            IoError::Limit { .. } => "limit_exceeded",
            IoError::Unsupported { .. } => "unsupported_content",
            IoError::Mesh(e) => e.code(),
            IoError::Io(_) => "io_error",
        }
    }
}

/// Reads `bytes` as `format`.
pub fn read(bytes: &[u8], format: Format, limits: &ReadLimits) -> Result<Document, IoError> {
    match format {
        Format::Obj => {
            let (mesh, src) = obj::read_obj(bytes, limits)?;
            Ok(Document {
                mesh,
                format,
                source: Source::Obj(src),
            })
        }
    }
}

/// Writes `doc` with `positions` (one per vertex of `doc.mesh`) as `format`.
/// Writing in the input's format keeps everything else of the file.
pub fn write(doc: &Document, positions: &[DVec3], format: Format) -> Result<Vec<u8>, IoError> {
    let mut out = Vec::new();
    match (format, &doc.source) {
        (Format::Obj, Source::Obj(src)) => obj::write_obj(src, positions, &mut out)?,
    }
    Ok(out)
}
