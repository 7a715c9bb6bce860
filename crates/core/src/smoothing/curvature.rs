//! Step 5: mean and Gaussian curvature from the quadric fits (algorithm
//! notes section 5). The formulas live on
//! [`QuadricFit::curvature`](crate::fit::quadric_fit::QuadricFit::curvature);
//! this file estimates them for a whole mesh without moving it.

use super::neighbourhood::{Neighbourhoods, select_rings};
use crate::fit::frame::Frame;
use crate::fit::quadric_fit::{Facing, FitModel, fit_neighbours};
use crate::mesh::{Topology, VertexKind};
use glam::{DVec3, Vec3};

/// Per-vertex curvature `(H, K)`.
pub type Curvatures = Vec<(f64, f64)>;

/// `(H, K)` at every vertex of `positions` from a quadric fit to its
/// `rings`-ring as [`select_rings`] chooses it (at most `max_points`
/// points). 0 where the vertex has no usable normal; boundary vertices fit
/// a plane ([`curvature_at`]). `normals` are the unit vertex normals of
/// `positions` ([`vertex_normals_f32`](crate::fit::normals::vertex_normals_f32));
/// neighbours facing away by a cosine below `min_cos` are left out. The
/// rings are walked and fitted vertex by vertex, never stored.
pub fn vertex_curvatures(
    topo: &Topology,
    positions: &[DVec3],
    normals: &[Vec3],
    rings: u32,
    max_points: usize,
    min_cos: f64,
) -> Curvatures {
    Neighbourhoods::map(
        topo,
        |v, w, out| select_rings(w, topo, v, rings, max_points, out),
        |v, hood| curvature_at(topo, positions, normals, v, hood, min_cos),
    )
}

/// `(H, K)` at vertex `v` from a quadric fit to `hood` in `positions`,
/// as [`vertex_curvatures`] computes it: 0 where the vertex has no
/// normal, and 0 at boundary vertices (they fit a plane). `normals` are the
/// unit vertex normals of `positions`
/// ([`vertex_normals_f32`](crate::fit::normals::vertex_normals_f32)).
pub fn curvature_at(
    topo: &Topology,
    positions: &[DVec3],
    normals: &[Vec3],
    v: usize,
    hood: &[u32],
    min_cos: f64,
) -> (f64, f64) {
    let n = normals[v].as_dvec3().normalize_or_zero();
    if n == DVec3::ZERO {
        return (0.0, 0.0);
    }
    let model = if topo.kind(v) == VertexKind::Boundary {
        FitModel::Plane
    } else {
        FitModel::Quadric
    };
    let facing = Facing { normals, min_cos };
    let frame = Frame::new(positions[v], n);
    fit_neighbours(&frame, positions, hood, model, Some(facing)).curvature()
}
