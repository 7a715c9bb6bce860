//! Welding a file whose bodies touch face to face: each vertex keeps the
//! side of each body it lies on ([`touching_bodies`]), so that segments
//! written into one file are welded, and smoothed, each on its own.

use super::IoError;
use super::weld::{self, FastMap, FastState, Welded};
use crate::mesh::{Mesh, Topology, body_ids, touching_bodies};

/// The bodies of a file: several closed surfaces with their own vertices
/// whose surfaces touch face to face (the segments of a segmentation
/// exported together), which welding by position alone would join along
/// their common walls, and the meshes of a glTF file, each in its own
/// space. Each body is welded on its own and gets its volume back on its
/// own.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileBodies {
    /// One entry per vertex of [`super::Document::mesh`]: its body, from 0.
    pub of_vertex: Vec<u32>,
    /// Number of bodies (at least 2).
    pub count: usize,
    /// The faces the bodies share: pairs of coincident faces (a wall's
    /// face from each side), each pair once; empty when the bodies are
    /// only glTF meshes.
    pub shared: Vec<(u32, u32)>,
}

/// Each vertex's pair of a group (`groups`) and a body (`bodies`),
/// numbered from 0 in the order first met, and the number of pairs.
pub(super) fn dense_pairs(groups: &[u32], bodies: &[u32]) -> (Vec<u32>, usize) {
    let mut id: FastMap<(u32, u32), u32> = FastMap::with_hasher(FastState::new());
    let of_vertex = groups
        .iter()
        .zip(bodies)
        .map(|(&g, &b)| {
            let next = id.len() as u32;
            *id.entry((g, b)).or_insert(next)
        })
        .collect();
    (of_vertex, id.len())
}

/// Welds `mesh` ([`weld::weld`]); where that joins bodies face to face
/// ([`touching_bodies`]), keeps each vertex's sides apart. Returns the
/// weld (`None` when it joins nothing) and, when bodies were told apart,
/// their [`FileBodies`] with one entry per vertex of `mesh` (the file's).
pub(super) fn weld_bodies(
    mesh: &Mesh,
    tolerance: f64,
    groups: Option<&[u32]>,
) -> Result<(Option<Welded>, Option<FileBodies>), IoError> {
    let Some(w) = weld::weld(mesh, tolerance, groups)? else {
        return Ok((None, None));
    };
    if !passes_an_edge_twice(&w.mesh) {
        return Ok((Some(w), None));
    }
    let Some(touching) = touching_bodies(&w.mesh, &Topology::build(&w.mesh), Some(mesh)) else {
        return Ok((Some(w), None));
    };
    let Some(keys) = side_groups(mesh, &touching.corner_side, groups) else {
        return Ok((Some(w), None));
    };
    let apart = weld::weld(mesh, tolerance, Some(&keys))?;
    let split = apart.as_ref().map_or(mesh, |a| &a.mesh);
    let (of_vertex, count) = body_ids(split, &Topology::build(split), &touching.shared);
    let of_vertex = match &apart {
        Some(a) => weld::expand(&of_vertex, &a.vertex_map),
        None => of_vertex,
    };
    Ok((
        apart,
        Some(FileBodies {
            of_vertex,
            count,
            shared: touching.shared,
        }),
    ))
}

/// Weld groups that keep each file vertex on its side
/// ([`crate::mesh::TouchingBodies::corner_side`], one entry per corner of
/// `mesh`; a vertex no face uses on side 0) and in its `groups` entry;
/// `None` when a file vertex lies on two sides (the file itself joins the
/// bodies there, and no weld parts them).
fn side_groups(mesh: &Mesh, corner_side: &[u32], groups: Option<&[u32]>) -> Option<Vec<u32>> {
    let mut side = vec![u32::MAX; mesh.num_vertices()];
    for (&v, &s) in mesh.face_vertices().iter().zip(corner_side) {
        let slot = &mut side[v as usize];
        if *slot != u32::MAX && *slot != s {
            return None;
        }
        *slot = s;
    }
    let sides = corner_side.iter().max().map_or(1, |&m| m + 1);
    side.iter()
        .enumerate()
        .map(|(v, &s)| {
            let group = groups.and_then(|g| g.get(v)).copied().unwrap_or(0);
            let s = if s == u32::MAX { 0 } else { s };
            group.checked_mul(sides)?.checked_add(s)
        })
        .collect()
}

/// Whether two faces of `mesh` pass an edge the same way: the cheap test
/// before [`touching_bodies`] looks for bodies that touch (two bodies'
/// walls pass each of their edges both ways twice; so do a mask's voxels
/// touching along an edge, and faces wound against their neighbours).
fn passes_an_edge_twice(mesh: &Mesh) -> bool {
    let mut seen: FastMap<u64, ()> =
        FastMap::with_capacity_and_hasher(mesh.face_vertices().len(), FastState::new());
    mesh.faces().any(|face| {
        face.iter().enumerate().any(|(i, &a)| {
            let b = face[(i + 1) % face.len()];
            seen.insert(u64::from(a) << 32 | u64::from(b), ()).is_some()
        })
    })
}
