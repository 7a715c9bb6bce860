//! Step 4: projection, the smoothing step (algorithm notes section 4).
//!
//! Each vertex moves along its normal onto its fitted quadric, `p_i' = p_i +
//! g n_i`. Updates are Jacobi style: all new positions are computed from the
//! old ones and written to a second buffer, so the result is deterministic
//! and independent of the thread count.

use super::frame::Frame;
use super::neighbourhood::Neighbourhoods;
use super::normals::vertex_normals_f32;
use super::quadric_fit::{Facing, FitKind, FitModel, fit_neighbours};
use crate::mesh::{Mesh, Topology, VertexKind};
use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

/// Largest move of one pass, in units of the vertex's mean edge length.
pub const MAX_STEP: f64 = 1.0;

/// What one pass (or a sum of passes) did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct FitStats {
    /// Fits that used the quadric plus cubic terms.
    pub cubic: u64,
    /// Fits that used the full quadric.
    pub quadric: u64,
    /// Fits that fell back to a plane.
    pub plane_fallback: u64,
    /// Vertices left in place because no fit was possible.
    pub fixed_fallback: u64,
    /// Largest distance a vertex moved.
    pub max_displacement: f64,
    /// Moves cut to [`MAX_STEP`] mean edge lengths.
    pub clamped: u64,
}

impl FitStats {
    fn merge(self, o: FitStats) -> FitStats {
        FitStats {
            cubic: self.cubic + o.cubic,
            quadric: self.quadric + o.quadric,
            plane_fallback: self.plane_fallback + o.plane_fallback,
            fixed_fallback: self.fixed_fallback + o.fixed_fallback,
            max_displacement: self.max_displacement.max(o.max_displacement),
            clamped: self.clamped + o.clamped,
        }
    }

    /// Adds another pass's counts (maximum of the displacements).
    pub fn accumulate(&mut self, o: FitStats) {
        *self = self.merge(o);
    }
}

/// Per-vertex curvature `(H, K)` from the fits of a pass.
pub type Curvatures = Vec<(f64, f64)>;

/// One Jacobi pass: fits `model` to every movable vertex's neighbourhood in
/// `positions` and writes the projected positions to `out` (immovable
/// vertices are copied; movable boundary vertices fit a plane). Neighbours
/// whose normal makes a cosine below `min_cos` with the vertex's are left
/// out of its fit ([`Facing`]).
/// Returns the fit statistics and, per vertex, the curvature of its fit (0
/// where it was not fitted).
#[allow(clippy::too_many_arguments)]
pub fn fit_pass(
    mesh: &Mesh,
    topo: &Topology,
    positions: &[DVec3],
    hoods: &Neighbourhoods,
    movable: &[bool],
    model: FitModel,
    min_cos: f64,
    out: &mut [DVec3],
    curvature: &mut [(f64, f64)],
) -> FitStats {
    let normals = vertex_normals_f32(mesh, topo, positions);
    out.par_iter_mut()
        .zip(curvature.par_iter_mut())
        .enumerate()
        .with_min_len(1024)
        .map(|(v, (o, hk))| {
            let p = positions[v];
            let n = normals[v].as_dvec3().normalize_or_zero();
            *o = p;
            *hk = (0.0, 0.0);
            let mut s = FitStats::default();
            if !movable[v] || n == DVec3::ZERO {
                return s;
            }
            // A movable boundary vertex (rule `normal_only`) fits a plane.
            let model = if topo.kind(v) == VertexKind::Boundary {
                FitModel::Plane
            } else {
                model
            };
            let facing = Facing {
                normals: &normals,
                min_cos,
            };
            let frame = Frame::new(p, n);
            let fit = fit_neighbours(&frame, positions, hoods.get(v), model, Some(facing));
            match fit.kind {
                FitKind::Cubic => s.cubic = 1,
                FitKind::Quadric => s.quadric = 1,
                FitKind::Plane => s.plane_fallback = 1,
                FitKind::Fixed => s.fixed_fallback = 1,
            }
            *hk = fit.curvature();
            // No jumps: one pass moves a vertex by at most its mean
            // edge length (staircase noise needs at most half of that;
            // a larger step means a fit that does not describe the surface).
            let nb = topo.neighbors(v);
            let local = nb
                .iter()
                .map(|&j| positions[j as usize].distance(p))
                .sum::<f64>()
                / nb.len().max(1) as f64;
            let g = fit.height().clamp(-MAX_STEP * local, MAX_STEP * local);
            if g != fit.height() {
                s.clamped = 1;
            }
            *o = p + g * n;
            s.max_displacement = g.abs();
            s
        })
        .reduce(FitStats::default, FitStats::merge)
}
