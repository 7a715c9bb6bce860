//! Initial smoothing (paper section 2.2): a few Jacobi passes of quadric
//! fits over the fixed 2-ring of every vertex.

use super::curvature::{Curvatures, vertex_curvatures};
use super::fidelity::Fidelity;
use super::neighbourhood::HoodSource;
use super::project::{FitPass, FitStats, apply, fit_pass};
use crate::control::{Cancelled, check};
use crate::fit::normals::vertex_normals_f32_by_faces;
use crate::fit::quadric_fit::FitModel;
use crate::mesh::{Mesh, Topology};
use glam::{DVec3, Vec3};
use std::sync::atomic::AtomicBool;

/// What [`initial_passes`] runs.
#[derive(Debug, Clone, Copy)]
pub struct InitialPlan<'a> {
    /// Which vertices may move.
    pub movable: &'a [bool],
    /// Most points of a fit.
    pub max_points: usize,
    /// Neighbours facing away by a cosine below this are left out of a fit
    /// ([`fit_pass`]).
    pub min_cos: f64,
    /// Passes to run.
    pub passes: u32,
    /// The fidelity bound each pass's moves are held to.
    pub fidelity: &'a Fidelity<'a>,
    /// Whether to return the curvature of the starting positions (empty
    /// when not asked for).
    pub curvature: bool,
}

/// Initial smoothing: `plan.passes` Jacobi passes of quadric fits over every
/// vertex's 2-ring (at most `plan.max_points` points,
/// [`select_rings`](super::neighbourhood::select_rings)), walked
/// as each vertex is fitted rather than stored. Updates `positions` in
/// place, each pass held to `plan.fidelity`, and returns the fit
/// statistics and the curvature of the starting positions that pass 0's
/// fits give: [`vertex_curvatures`] with 2 rings, the curvature a report
/// gives for the input, at no extra cost.
pub fn initial_passes(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    plan: InitialPlan,
    cancel: &AtomicBool,
    mut on_pass: impl FnMut(u32),
) -> Result<(FitStats, Curvatures), Cancelled> {
    let InitialPlan {
        movable,
        max_points,
        min_cos,
        passes,
        fidelity,
        curvature: measure,
    } = plan;
    let hoods = HoodSource::Walked {
        rings: 2,
        max_points,
    };
    let mut moves = vec![Vec3::ZERO; positions.len()];
    let mut stats = FitStats::default();
    let mut curvature = Vec::new();
    if passes == 0 && measure {
        let normals = vertex_normals_f32_by_faces(mesh, topo, positions);
        curvature = vertex_curvatures(topo, positions, &normals, 2, max_points, min_cos);
    }
    for pass in 0..passes {
        check(cancel)?;
        let first = (pass == 0 && measure).then(|| {
            curvature = vec![(0.0, 0.0); positions.len()];
            &mut curvature[..]
        });
        stats.accumulate(fit_pass(
            mesh,
            topo,
            positions,
            FitPass {
                hoods,
                movable,
                model: FitModel::Quadric,
                min_cos,
                refit: None,
                momentum: None,
                curvature: first,
            },
            &mut moves,
        ));
        apply(positions, &moves);
        fidelity.apply(positions);
        on_pass(pass + 1);
    }
    Ok((stats, curvature))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_initial_pass_gives_the_curvature_of_the_start() {
        // A bumpy open grid: its boundary vertices do not move (fitted for
        // the curvature only), one interior vertex is held too.
        let mut mesh = crate::mesh::test_grid(12);
        let bumped: Vec<DVec3> = mesh
            .positions()
            .iter()
            .map(|p| p + DVec3::Z * (0.3 * (p.x * 1.7).sin() * (p.y * 0.9).cos()))
            .collect();
        mesh = crate::mesh::Mesh::from_polygons(bumped, &mesh.faces().collect::<Vec<_>>())
            .expect("valid mesh");
        let topo = Topology::build(&mesh);
        let mut movable: Vec<bool> = (0..mesh.num_vertices())
            .map(|v| topo.kind(v) == crate::mesh::VertexKind::Interior)
            .collect();
        movable[40] = false;
        let normals = vertex_normals_f32_by_faces(&mesh, &topo, mesh.positions());
        let expected = vertex_curvatures(&topo, mesh.positions(), &normals, 2, 56, 0.5);
        let never = AtomicBool::new(false);
        for passes in [0, 2] {
            let mut p = mesh.positions().to_vec();
            let plan = InitialPlan {
                movable: &movable,
                max_points: 56,
                min_cos: 0.5,
                passes,
                fidelity: &Fidelity::unbounded(),
                curvature: true,
            };
            let (stats, curvature) =
                initial_passes(&mesh, &topo, &mut p, plan, &never, |_| {}).expect("not cancelled");
            assert_eq!(curvature, expected, "{passes} passes");
            assert!(expected.iter().any(|c| c.0 != 0.0));
            assert_eq!(
                stats.quadric,
                u64::from(passes) * movable.iter().filter(|&&m| m).count() as u64
            );
            assert_eq!(p == mesh.positions(), passes == 0);
        }
    }
}
