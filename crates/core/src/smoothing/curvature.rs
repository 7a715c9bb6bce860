//! Step 5: mean and Gaussian curvature from the quadric fits (algorithm
//! notes section 5). The formulas live on
//! [`QuadricFit::curvature`](super::quadric_fit::QuadricFit::curvature);
//! this file estimates them for a whole mesh without moving it.

use super::neighbourhood::Neighbourhoods;
use super::project::{Curvatures, FitStats, fit_pass};
use crate::mesh::{Mesh, Topology};
use glam::DVec3;

/// `(H, K)` at every vertex from a fit to its neighbourhood in `positions`
/// (0 where the vertex has no usable normal or is not fitted); neighbours
/// facing away by a cosine below `min_cos` are left out.
pub fn vertex_curvatures(
    mesh: &Mesh,
    topo: &Topology,
    positions: &[DVec3],
    hoods: &Neighbourhoods,
    min_cos: f64,
) -> (Curvatures, FitStats) {
    let n = positions.len();
    let mut scratch = vec![DVec3::ZERO; n];
    let mut hk = vec![(0.0, 0.0); n];
    let all = vec![true; n];
    let stats = fit_pass(
        mesh,
        topo,
        positions,
        hoods,
        &all,
        min_cos,
        &mut scratch,
        &mut hk,
    );
    (hk, stats)
}

/// Face curvature: the mean of its vertices' `H` (one entry per face).
pub fn face_mean_curvature(mesh: &Mesh, hk: &[(f64, f64)]) -> Vec<f64> {
    mesh.faces()
        .map(|f| f.iter().map(|&v| hk[v as usize].0).sum::<f64>() / f.len() as f64)
        .collect()
}
