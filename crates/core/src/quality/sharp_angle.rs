//! Sharp-angle fix (paper section 2.4; algorithm notes section 8):
//! angle-based smoothing (Zhou & Shimada 2000) of the vertices of faces
//! with a split-triangle angle below the threshold, each moved vertex then
//! brought back onto its local fitted quadric so the shape is kept.
//!
//! For a vertex `v` with its ordered link `l_0 .. l_{m-1}` (the other
//! corners of its faces, around `v`), the angle-based target is the mean
//! over `j` of `v` rotated about `l_j`, in the tangent plane, onto the
//! bisector of the link's interior angle at `l_j`. The candidates tried are
//! that target and the link centroid, each at full, half and quarter step;
//! each candidate's tangent-plane point is lifted onto the quadric fitted
//! to `v`'s 2-ring (section 3) in the frame of its current position and
//! normal. The candidate kept is the one that leaves the fewest inverted
//! faces, then the fewest twisted quads, then the largest smallest angle
//! among `v`'s faces; it is kept only when it improves on the current
//! position (see [`MoveTester`]): no face becomes inverted relative to the
//! input, no quad becomes twisted, and either a defect goes away or the
//! smallest split-triangle angle of `v`'s faces grows. Otherwise `v` stays.
//!
//! Order: Gauss-Seidel, sequential, vertices in ascending index order
//! within a sweep, so the result is deterministic. Sweep 1 visits the
//! corners of every face with a sharp angle or an inverted split triangle;
//! each later sweep visits only such corners among the faces around the
//! vertices moved in the sweep before, and the fix stops after a sweep that
//! moves nothing or after `max_sweeps`. Only interior vertices whose faces
//! form one closed fan move; boundary, non-manifold and isolated vertices
//! stay.

use super::local::{
    LocalSurface, MoveTester, Verdict, angle_based_target, face_state, has_repeated_corner,
    link_centroid, ordered_link, uninvert_steps,
};
use crate::mesh::{Mesh, Topology, VertexKind};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// What the sharp-angle fix did.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SharpAngleStats {
    /// Faces with a split-triangle angle below the threshold before the fix.
    pub faces_found: u64,
    /// Accepted vertex moves, over all sweeps.
    pub moves: u64,
    /// Vertex visits where no candidate position was an improvement (the
    /// vertex stayed), over all sweeps.
    pub rejected: u64,
    /// Sweeps run.
    pub sweeps: u64,
    /// Faces with a split-triangle angle below the threshold after the fix.
    pub faces_remaining: u64,
}

/// Scratch buffers for relocating vertices.
#[derive(Debug, Default)]
pub(crate) struct Relocator {
    ring: Vec<u32>,
    link: Vec<u32>,
    targets: Vec<(f64, f64)>,
    tester: MoveTester,
}

/// Ranks a tried position: fewer inverted faces, then fewer twisted quads,
/// then a larger smallest angle, is better (smaller key).
fn rank(v: &Verdict) -> (u32, u32, f64) {
    (v.inverted.1, v.twisted.1, v.max_cos.1)
}

impl Relocator {
    /// Moves interior vertex `v` to the best of its angle-based candidates
    /// if that improves its faces; returns whether it moved.
    pub fn relocate(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        v: usize,
        positions: &mut [DVec3],
        input: &[DVec3],
    ) -> bool {
        if topo.kind(v) != VertexKind::Interior || !ordered_link(mesh, topo, v, &mut self.link) {
            return false;
        }
        let Some(surface) = LocalSurface::at(mesh, topo, v, positions, &mut self.ring) else {
            return false;
        };
        let mut targets = std::mem::take(&mut self.targets);
        targets.clear();
        for (x, y) in [
            angle_based_target(&surface, &self.link, positions),
            link_centroid(&surface, &self.link, positions),
        ]
        .into_iter()
        .flatten()
        {
            targets.extend([1.0, 0.5, 0.25].map(|s| (s * x, s * y)));
        }
        targets.push((0.0, 0.0));
        uninvert_steps(mesh, topo, v, positions, input, &surface, &mut targets);
        self.tester.begin(mesh, topo, &[v], positions, input);
        let mut best: Option<((u32, u32, f64), DVec3)> = None;
        for &(x, y) in &targets {
            let p = surface.point(x, y);
            if !p.is_finite() {
                continue;
            }
            let verdict = self.tester.apply(mesh, &[(v, p)], positions);
            self.tester.undo(positions);
            if verdict.improves() && best.is_none_or(|(k, _)| rank(&verdict) < k) {
                best = Some((rank(&verdict), p));
            }
        }
        self.targets = targets;
        match best {
            Some((_, p)) => {
                positions[v] = p;
                true
            }
            None => false,
        }
    }
}

/// True when face `f` has a split-triangle angle whose cosine exceeds
/// `cos_limit`, or is inverted relative to `input`.
fn needs_work(face: &[u32], positions: &[DVec3], input: &[DVec3], cos_limit: f64) -> bool {
    if has_repeated_corner(face) {
        return false;
    }
    let s = face_state(face, positions, input);
    s.max_cos > cos_limit || s.inverted
}

fn count_sharp(mesh: &Mesh, positions: &[DVec3], cos_limit: f64) -> u64 {
    (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&f| {
            let face = mesh.face(f);
            !has_repeated_corner(face) && super::local::max_split_cos(face, positions) > cos_limit
        })
        .count() as u64
}

/// Angle-based smoothing of the vertices around faces with a split-triangle
/// angle below `sharp_angle_deg` degrees (or inverted relative to `input`),
/// at most `max_sweeps` sweeps; moves vertices in `positions` in place
/// (one entry per vertex; `input` likewise). See the module documentation
/// for the order and the acceptance rule.
pub fn fix_sharp_angles(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    input: &[DVec3],
    sharp_angle_deg: f64,
    max_sweeps: u32,
) -> SharpAngleStats {
    let cos_limit = sharp_angle_deg.to_radians().cos();
    let mut stats = SharpAngleStats {
        faces_found: count_sharp(mesh, positions, cos_limit),
        ..SharpAngleStats::default()
    };
    let p: &[DVec3] = positions;
    let bad_faces: Vec<u32> = (0..mesh.num_faces() as u32)
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&f| needs_work(mesh.face(f as usize), p, input, cos_limit))
        .collect();
    let mut visit = corners_of(mesh, topo, &bad_faces);
    let mut relocator = Relocator::default();
    let mut moved = Vec::new();
    let mut faces = Vec::new();
    while stats.sweeps < max_sweeps as u64 && !visit.is_empty() {
        stats.sweeps += 1;
        moved.clear();
        for &v in &visit {
            if relocator.relocate(mesh, topo, v as usize, positions, input) {
                moved.push(v);
                stats.moves += 1;
            } else {
                stats.rejected += 1;
            }
        }
        faces.clear();
        for &v in &moved {
            faces.extend_from_slice(topo.vertex_faces(v as usize));
        }
        faces.sort_unstable();
        faces.dedup();
        faces.retain(|&f| needs_work(mesh.face(f as usize), positions, input, cos_limit));
        visit = corners_of(mesh, topo, &faces);
    }
    stats.faces_remaining = count_sharp(mesh, positions, cos_limit);
    stats
}

/// Interior corners of `faces`, ascending, each once.
fn corners_of(mesh: &Mesh, topo: &Topology, faces: &[u32]) -> Vec<u32> {
    let mut out: Vec<u32> = faces
        .iter()
        .flat_map(|&f| mesh.face(f as usize).iter().copied())
        .filter(|&v| topo.kind(v as usize) == VertexKind::Interior)
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}
