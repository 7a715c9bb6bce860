//! Wavefront OBJ reading and writing. (Being written.)

use super::{IoError, ReadLimits};
use crate::mesh::Mesh;
use glam::DVec3;

/// What an OBJ file needs besides the mesh to be written back unchanged.
#[derive(Debug, Clone, Default)]
pub struct ObjSource {}

/// Parses OBJ bytes.
pub fn read_obj(bytes: &[u8], limits: &ReadLimits) -> Result<(Mesh, ObjSource), IoError> {
    let _ = (bytes, limits);
    Err(IoError::Unsupported {
        format: "OBJ",
        message: "reader not written yet".into(),
    })
}

/// Writes an OBJ with new positions.
pub fn write_obj(src: &ObjSource, positions: &[DVec3], out: &mut Vec<u8>) -> Result<(), IoError> {
    let _ = (src, positions, out);
    Ok(())
}
