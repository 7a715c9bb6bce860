//! The mesh: f64 positions and polygon faces of any arity in flat CSR arrays.
//!
//! A [`Mesh`] is validated once, at construction ([`Mesh::new`]); algorithms
//! trust it afterwards. Connectivity never changes: smoothing only moves
//! vertices, so vertex and face order are those of the input.

mod bodies;
pub(crate) mod lattice;
mod orientation;
mod paired;
mod regions;
mod ring;
mod scale;
mod topology;
mod volume;
#[cfg(test)]
pub(crate) use topology::tests::{grid as test_grid, unit_cube as test_unit_cube};
#[cfg(test)]
pub(crate) use volume::tests::walled_sphere as test_walled_sphere;

pub use bodies::{TouchingBodies, body_ids, touching_bodies};
pub use orientation::{Orientation, orientation};
pub use paired::{PairedFaces, paired_voxel_faces};
pub use regions::{OUTSIDE, Regions, regions};
pub use ring::RingWalker;
pub use scale::{UNIT_BAND, UnitScale};
pub(crate) use topology::has_repeated_corner;
pub use topology::{Topology, VertexKind};
pub use volume::VolumeApexes;

use crate::error::MeshError;
use glam::DVec3;

/// Positions plus polygon faces, faces stored as CSR (`face_offsets`,
/// `face_vertices`).
#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    positions: Vec<DVec3>,
    face_offsets: Vec<u32>,
    face_vertices: Vec<u32>,
}

impl Mesh {
    /// Builds a mesh from positions and CSR faces: face `f` has corners
    /// `face_vertices[face_offsets[f]..face_offsets[f+1]]`.
    ///
    /// Errors when an offset array is malformed, a face has fewer than 3
    /// corners, an index is out of range or a coordinate is not finite.
    /// Faces with a repeated index or zero area are accepted (they are
    /// counted as degenerate by [`Topology`]).
    pub fn new(
        positions: Vec<DVec3>,
        face_offsets: Vec<u32>,
        face_vertices: Vec<u32>,
    ) -> Result<Self, MeshError> {
        if positions.len() >= u32::MAX as usize {
            return Err(MeshError::TooLarge {
                what: "vertex",
                count: positions.len(),
                limit: u32::MAX as usize - 1,
            });
        }
        if face_vertices.len() >= u32::MAX as usize {
            return Err(MeshError::TooLarge {
                what: "face corner",
                count: face_vertices.len(),
                limit: u32::MAX as usize - 1,
            });
        }
        if face_offsets.first() != Some(&0) {
            return Err(MeshError::InvalidOffsets("the first offset must be 0"));
        }
        if face_offsets.last().map(|&o| o as usize) != Some(face_vertices.len()) {
            return Err(MeshError::InvalidOffsets(
                "the last offset must equal the number of face corners",
            ));
        }
        for (f, w) in face_offsets.windows(2).enumerate() {
            if w[1] < w[0] {
                return Err(MeshError::InvalidOffsets("offsets must not decrease"));
            }
            let arity = (w[1] - w[0]) as usize;
            if arity < 3 {
                return Err(MeshError::FaceTooSmall { face: f, arity });
            }
        }
        let n = positions.len();
        for (f, w) in face_offsets.windows(2).enumerate() {
            for &i in &face_vertices[w[0] as usize..w[1] as usize] {
                if i as usize >= n {
                    return Err(MeshError::IndexOutOfRange {
                        face: f,
                        index: i as u64,
                        num_vertices: n,
                    });
                }
            }
        }
        if let Some(v) = positions.iter().position(|p| !p.is_finite()) {
            return Err(MeshError::NonFinitePosition { vertex: v });
        }
        Ok(Mesh {
            positions,
            face_offsets,
            face_vertices,
        })
    }

    /// Builds a mesh from a list of polygons (convenience for tests and
    /// generators).
    pub fn from_polygons<F: AsRef<[u32]>>(
        positions: Vec<DVec3>,
        faces: &[F],
    ) -> Result<Self, MeshError> {
        let mut offsets = Vec::with_capacity(faces.len() + 1);
        let mut corners = Vec::new();
        offsets.push(0u32);
        for f in faces {
            corners.extend_from_slice(f.as_ref());
            let len = u32::try_from(corners.len()).map_err(|_| MeshError::TooLarge {
                what: "face corner",
                count: corners.len(),
                limit: u32::MAX as usize - 1,
            })?;
            offsets.push(len);
        }
        Mesh::new(positions, offsets, corners)
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.positions.len()
    }

    /// Number of faces.
    pub fn num_faces(&self) -> usize {
        self.face_offsets.len() - 1
    }

    /// All vertex positions, one entry per vertex.
    pub fn positions(&self) -> &[DVec3] {
        &self.positions
    }

    /// Replaces all positions; the new positions must be finite and one per
    /// vertex (checked: a wrong length or a non-finite value is an error).
    pub fn set_positions(&mut self, positions: Vec<DVec3>) -> Result<(), MeshError> {
        if positions.len() != self.positions.len() {
            return Err(MeshError::InvalidOffsets(
                "replacement positions must have one entry per vertex",
            ));
        }
        if let Some(v) = positions.iter().position(|p| !p.is_finite()) {
            return Err(MeshError::NonFinitePosition { vertex: v });
        }
        self.positions = positions;
        Ok(())
    }

    /// Mutable access to positions for algorithms that move vertices in
    /// place. Callers keep every coordinate finite.
    pub fn positions_mut(&mut self) -> &mut [DVec3] {
        &mut self.positions
    }

    /// Corners of face `f`, in order. Panics if `f >= num_faces()`.
    #[inline]
    pub fn face(&self, f: usize) -> &[u32] {
        let a = self.face_offsets[f] as usize;
        let b = self.face_offsets[f + 1] as usize;
        &self.face_vertices[a..b]
    }

    /// Iterator over all faces' corner lists, in face order.
    pub fn faces(&self) -> impl ExactSizeIterator<Item = &[u32]> + '_ {
        self.face_offsets
            .windows(2)
            .map(|w| &self.face_vertices[w[0] as usize..w[1] as usize])
    }

    /// Face CSR offsets (`num_faces() + 1` entries, starting at 0).
    pub fn face_offsets(&self) -> &[u32] {
        &self.face_offsets
    }

    /// Face CSR corner indices.
    pub fn face_vertices(&self) -> &[u32] {
        &self.face_vertices
    }

    /// Vector area of face `f`: `1/2 sum q_j x q_{j+1}` (its length is the
    /// area for planar polygons; well defined for non-planar quads).
    #[inline]
    pub fn face_vector_area(&self, f: usize) -> DVec3 {
        vector_area(self.face(f), &self.positions)
    }

    /// Mean edge length over all face edges (each face side counted once per
    /// face), 0 for a mesh without faces.
    pub fn mean_edge_length(&self) -> f64 {
        mean_edge_length(self, &self.positions)
    }

    /// Enclosed volume by the divergence theorem (meaningful for closed,
    /// consistently oriented meshes; positive when normals point outward).
    pub fn signed_volume(&self) -> f64 {
        signed_volume(self, &self.positions)
    }
}

/// Vector area of the polygon `face` over `positions` (see
/// [`Mesh::face_vector_area`]): half the cross product of the diagonals for
/// a quad, else fanned from the first corner (translation invariant and
/// exact for planar polygons). Triangles and quads are computed inline,
/// other polygons in a call.
#[inline(always)]
pub fn vector_area(face: &[u32], positions: &[DVec3]) -> DVec3 {
    match *face {
        [a, b, c] => {
            let o = positions[a as usize];
            0.5 * (positions[b as usize] - o).cross(positions[c as usize] - o)
        }
        [a, b, c, d] => {
            let d1 = positions[c as usize] - positions[a as usize];
            let d2 = positions[d as usize] - positions[b as usize];
            0.5 * d1.cross(d2)
        }
        _ => polygon_vector_area(face, positions),
    }
}

/// [`vector_area`] of a face that is neither a triangle nor a quad.
#[inline(never)]
fn polygon_vector_area(face: &[u32], positions: &[DVec3]) -> DVec3 {
    let n = face.len();
    let o = positions[face[0] as usize];
    let mut s = DVec3::ZERO;
    for j in 1..n.saturating_sub(1) {
        let a = positions[face[j] as usize] - o;
        let b = positions[face[j + 1] as usize] - o;
        s += a.cross(b);
    }
    0.5 * s
}

/// Mean face-side length of `mesh` with alternative `positions` (each
/// side counted once per face), 0 for a mesh without faces. In parallel,
/// summed in fixed chunks: the same bits whatever the thread count.
pub fn mean_edge_length(mesh: &Mesh, positions: &[DVec3]) -> f64 {
    use rayon::prelude::*;
    const CHUNK: usize = 8192;
    let nf = mesh.num_faces();
    let chunks: Vec<(f64, u64)> = (0..nf.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let (mut sum, mut count) = (0.0, 0u64);
            for f in c * CHUNK..((c + 1) * CHUNK).min(nf) {
                let face = mesh.face(f);
                let mut prev = positions[face[face.len() - 1] as usize];
                for &v in face {
                    let p = positions[v as usize];
                    sum += p.distance(prev);
                    prev = p;
                }
                count += face.len() as u64;
            }
            (sum, count)
        })
        .collect();
    let (sum, count) = chunks
        .iter()
        .fold((0.0, 0u64), |a, b| (a.0 + b.0, a.1 + b.1));
    if count == 0 { 0.0 } else { sum / count as f64 }
}

/// Signed enclosed volume of `mesh` with alternative `positions` (fan
/// triangulation of each face, divergence theorem), the cones taken from
/// the origin: for a closed surface. Where edges may have an odd number of
/// faces, [`VolumeApexes::volume`] measures alike wherever the origin lies.
pub fn signed_volume(mesh: &Mesh, positions: &[DVec3]) -> f64 {
    sum_over_face_chunks(mesh.num_faces(), |faces| {
        let mut v = 0.0;
        for f in faces {
            v += cone_volume6(mesh.face(f), positions);
        }
        v
    }) / 6.0
}

/// Six times the signed volume of the cone from the origin over `face`,
/// fanned from its first corner: [`signed_volume`]'s term per face.
#[inline]
pub(crate) fn cone_volume6(face: &[u32], positions: &[DVec3]) -> f64 {
    cone_volume6_about(face, positions, DVec3::ZERO)
}

/// Six times the signed volume of the cone from `apex` over `face`, fanned
/// from its first corner: an apex near the face keeps the digits that far
/// coordinates would cancel.
#[inline]
pub(crate) fn cone_volume6_about(face: &[u32], positions: &[DVec3], apex: DVec3) -> f64 {
    let Some(&first) = face.first() else {
        return 0.0;
    };
    let o = positions[first as usize] - apex;
    let mut v = 0.0;
    for j in 1..face.len().saturating_sub(1) {
        let a = positions[face[j] as usize] - apex;
        let b = positions[face[j + 1] as usize] - apex;
        v += o.dot(a.cross(b));
    }
    v
}

/// Axis-aligned bounding box `(min, max)` of `positions`; `None` when
/// empty.
pub(crate) fn bounding_box(positions: &[DVec3]) -> Option<(DVec3, DVec3)> {
    let first = *positions.first()?;
    Some(
        positions
            .iter()
            .fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))),
    )
}

/// `chunk_sum` over faces `0..num_faces` in fixed chunks of 4096, in
/// parallel, the chunks' sums added in order: the same bits whatever the
/// thread count.
pub(crate) fn sum_over_face_chunks(
    num_faces: usize,
    chunk_sum: impl Fn(std::ops::Range<usize>) -> f64 + Sync,
) -> f64 {
    use rayon::prelude::*;
    const CHUNK: usize = 4096;
    let chunks: Vec<f64> = (0..num_faces.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| chunk_sum(c * CHUNK..((c + 1) * CHUNK).min(num_faces)))
        .collect();
    chunks.iter().sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_square() -> Mesh {
        Mesh::from_polygons(
            vec![
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(1.0, 0.0, 0.0),
                DVec3::new(1.0, 1.0, 0.0),
                DVec3::new(0.0, 1.0, 0.0),
            ],
            &[[0u32, 1, 2, 3]],
        )
        .unwrap()
    }

    #[test]
    fn quad_vector_area_is_area_times_normal() {
        let m = unit_square();
        assert_eq!(m.face_vector_area(0), DVec3::new(0.0, 0.0, 1.0));
        assert_eq!(m.mean_edge_length(), 1.0);
    }

    #[test]
    fn construction_rejects_bad_input() {
        let p = vec![DVec3::ZERO; 3];
        assert!(matches!(
            Mesh::from_polygons(p.clone(), &[[0u32, 1, 3]]),
            Err(MeshError::IndexOutOfRange {
                face: 0,
                index: 3,
                ..
            })
        ));
        assert!(matches!(
            Mesh::from_polygons(p.clone(), &[vec![0u32, 1]]),
            Err(MeshError::FaceTooSmall { face: 0, arity: 2 })
        ));
        let mut q = p.clone();
        q[1].y = f64::NAN;
        assert!(matches!(
            Mesh::from_polygons(q, &[[0u32, 1, 2]]),
            Err(MeshError::NonFinitePosition { vertex: 1 })
        ));
        assert!(Mesh::new(p, vec![1, 3], vec![0, 1, 2]).is_err());
    }
}
