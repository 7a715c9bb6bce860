//! Initial smoothing (paper section 2.2): a few Jacobi passes of quadric
//! fits over the fixed 2-ring of every vertex.

use super::curvature::{Curvatures, vertex_curvatures};
use super::neighbourhood::{HoodSource, Neighbourhoods};
use super::project::{
    FitStats, Momentum, Refit, UNFITTED_DRIFT, fit_pass, step_limits, weighted_pass,
};
use crate::control::{Cancelled, check};
use crate::fit::normals::vertex_normals_f32_by_faces;
use crate::fit::quadric_fit::FitModel;
use crate::mesh::{Mesh, Topology};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::atomic::AtomicBool;

/// Runs `passes` passes over `hoods` starting from `positions` (updated in
/// place). Pass `p` fits anew when `refit(p)` holds, and always at the
/// first and the last pass; the others are [`weighted_pass`]es with the
/// weights of the latest fit. The last pass refits so the result lies on
/// fits made for it: on real meshes whose fits are poor (thin tubes,
/// non-manifold parts), passes on reused weights drift (the neuron of the
/// real-mesh sweep gains 15% in volume instead of 10% without it).
/// With `refit_tolerance`, refits after the first are selective: only the
/// [`stale_vertices`] fit anew, the others move by their kept weights.
/// With `early`, its vertices move with momentum and stop after its
/// passes ([`EarlyStop`]).
/// Returns the summed fit statistics. `model` and `min_cos` are
/// [`fit_pass`]'s.
#[allow(clippy::too_many_arguments)]
pub fn smooth_passes(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    hoods: &Neighbourhoods,
    movable: &[bool],
    model: FitModel,
    min_cos: f64,
    passes: u32,
    refit: impl Fn(u32) -> bool,
    refit_tolerance: Option<f32>,
    early: Option<EarlyStop>,
    cancel: &AtomicBool,
    mut on_pass: impl FnMut(u32),
) -> Result<FitStats, Cancelled> {
    let mut moves = vec![Vec3::ZERO; positions.len()];
    let last = passes.saturating_sub(1);
    let refits = |p: u32| p == 0 || p == last || refit(p);
    // Fits are kept only when some pass reuses them.
    let mut kept = (0..passes).any(|p| !refits(p)).then(|| {
        (
            hoods.zero_weights(),
            vec![UNFITTED_DRIFT; positions.len()],
            step_limits(mesh, topo),
        )
    });
    let mut stats = FitStats::default();
    // From the pass the early vertices stop at, the vertices still moving.
    let mut still: Option<Vec<bool>> = None;
    for pass in 0..passes {
        check(cancel)?;
        if let Some(e) = early.filter(|e| e.passes == pass) {
            still = Some(
                movable
                    .iter()
                    .zip(e.vertices)
                    .map(|(&m, &stops)| m && !stops)
                    .collect(),
            );
        }
        let movable = still.as_deref().unwrap_or(movable);
        let momentum = early.filter(|e| pass < e.passes).map(|e| Momentum {
            vertices: e.vertices,
            beta: e.momentum,
        });
        let s =
            match kept.as_mut() {
                Some((weights, drift, limits)) if !refits(pass) => weighted_pass(
                    mesh, topo, positions, hoods, weights, limits, drift, movable, &mut moves,
                    momentum,
                ),
                kept => {
                    // Before the first fit every vertex is stale.
                    let stale =
                        match (&kept, refit_tolerance) {
                            (Some((_, drift, limits)), Some(t)) if pass > 0 => Some(
                                stale_vertices(topo, drift, limits, t, early.map(|e| e.vertices)),
                            ),
                            _ => None,
                        };
                    let refit = kept.map(|(weights, drift, limits)| Refit {
                        weights,
                        drift,
                        limits,
                        stale: stale.as_deref(),
                    });
                    fit_pass(
                        mesh,
                        topo,
                        positions,
                        HoodSource::Stored(hoods),
                        movable,
                        model,
                        min_cos,
                        &mut moves,
                        refit,
                        momentum,
                        None,
                    )
                }
            };
        stats.accumulate(s);
        apply(positions, &moves);
        on_pass(pass + 1);
    }
    Ok(stats)
}

/// Vertices that move with momentum and stop early in [`smooth_passes`]:
/// where the fits converge slowly but steadily (flat regions with large
/// neighbourhoods), momentum reaches in fewer passes what plain passes
/// reach in all of them, and stopping there keeps the later passes' bias
/// out. They also keep their first fit's weights through the selective
/// refits (unless a move on them failed): their neighbourhoods change
/// shape too little for a refit to matter
/// ([`adaptive::FLAT_RING`](super::adaptive::growth::FLAT_RING) has the
/// measurements).
#[derive(Debug, Clone, Copy)]
pub struct EarlyStop<'a> {
    /// Whether each vertex stops early.
    pub vertices: &'a [bool],
    /// Their [`Momentum::beta`].
    pub momentum: f32,
    /// Passes they make (passes `0..passes`); the other vertices make all.
    pub passes: u32,
}

/// Initial smoothing: `passes` Jacobi passes of quadric fits over every
/// vertex's 2-ring (at most `max_points` points,
/// [`select_rings`](super::neighbourhood::select_rings)), walked
/// as each vertex is fitted rather than stored. Updates `positions` in
/// place and returns the fit statistics, and the curvature of the starting
/// positions that pass 0's fits give: [`vertex_curvatures`] with 2 rings,
/// the curvature a report gives for the input, at no extra cost. `min_cos`
/// is [`fit_pass`]'s.
#[allow(clippy::too_many_arguments)]
pub fn initial_passes(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    movable: &[bool],
    max_points: usize,
    min_cos: f64,
    passes: u32,
    cancel: &AtomicBool,
    mut on_pass: impl FnMut(u32),
) -> Result<(FitStats, Curvatures), Cancelled> {
    let hoods = HoodSource::Walked {
        rings: 2,
        max_points,
    };
    let mut moves = vec![Vec3::ZERO; positions.len()];
    let mut stats = FitStats::default();
    let mut curvature = Vec::new();
    if passes == 0 {
        let normals = vertex_normals_f32_by_faces(mesh, topo, positions);
        curvature = vertex_curvatures(topo, positions, &normals, 2, max_points, min_cos);
    }
    for pass in 0..passes {
        check(cancel)?;
        let first = (pass == 0).then(|| {
            curvature = vec![(0.0, 0.0); positions.len()];
            &mut curvature[..]
        });
        stats.accumulate(fit_pass(
            mesh,
            topo,
            positions,
            hoods,
            movable,
            FitModel::Quadric,
            min_cos,
            &mut moves,
            None,
            None,
            first,
        ));
        apply(positions, &moves);
        on_pass(pass + 1);
    }
    Ok((stats, curvature))
}

/// Adds each vertex's move to its position.
fn apply(positions: &mut [DVec3], moves: &[Vec3]) {
    positions
        .par_iter_mut()
        .zip(moves)
        .with_min_len(4096)
        .for_each(|(p, m)| *p += m.as_dvec3());
}

/// The vertices a selective refit fits anew: those where the vertex or one
/// of its neighbours drifted ([`UNFITTED_DRIFT`]) more than `tolerance`
/// times the vertex's step limit (its mean input edge length) since its
/// latest fit. Vertices of `keeping` ([`EarlyStop`]) are fitted anew only
/// when their own move failed (infinite drift).
pub fn stale_vertices(
    topo: &Topology,
    drift: &[f32],
    limits: &[f32],
    tolerance: f32,
    keeping: Option<&[bool]>,
) -> Vec<bool> {
    (0..drift.len())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| {
            if keeping.is_some_and(|k| k[v]) {
                return drift[v] == UNFITTED_DRIFT;
            }
            let most = topo
                .neighbors(v)
                .iter()
                .fold(drift[v], |m, &j| m.max(drift[j as usize]));
            most > tolerance * limits[v]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;
    use crate::smoothing::adaptive::growth::{REFIT_TOLERANCE, is_refit_pass};
    use crate::smoothing::neighbourhood::push_thinned;

    /// `mesh`'s positions after the initial passes, as in the pipeline: the
    /// adaptive passes start from a surface without its staircase.
    fn without_staircase(mesh: &Mesh, topo: &Topology) -> Vec<DVec3> {
        let mut start = mesh.positions().to_vec();
        let movable = vec![true; mesh.num_vertices()];
        let never = AtomicBool::new(false);
        initial_passes(mesh, topo, &mut start, &movable, 56, 0.0, 3, &never, |_| {})
            .expect("not cancelled");
        start
    }

    #[test]
    fn reused_fits_track_fits_made_every_pass() {
        let (sphere, mesh) = shapes::voxel_sphere(8.0);
        let topo = Topology::build(&mesh);
        let hoods = Neighbourhoods::build(&topo, |v, w, out| {
            w.start(&topo, v);
            for _ in 0..5 {
                w.grow(&topo);
            }
            push_thinned(w, 56, 14, out);
        });
        let movable = vec![true; mesh.num_vertices()];
        let start = without_staircase(&mesh, &topo);
        let never = AtomicBool::new(false);
        let run = |start: &[DVec3], refit: &dyn Fn(u32) -> bool, tolerance: Option<f32>| {
            let mut p = start.to_vec();
            let stats = smooth_passes(
                &mesh,
                &topo,
                &mut p,
                &hoods,
                &movable,
                FitModel::Cubic,
                0.0,
                14,
                refit,
                tolerance,
                None,
                &never,
                |_| {},
            )
            .expect("not cancelled");
            (p, stats)
        };
        let (every, every_stats) = run(&start, &|_| true, None);
        let (reused, reused_stats) = run(&start, &is_refit_pass, None);
        // Passes 0, 4, 12 and 13 fit; the other ten reuse weights.
        let fits = |s: &FitStats| s.cubic + s.quadric + s.plane_fallback + s.fixed_fallback;
        assert_eq!(fits(&every_stats), 14 * mesh.num_vertices() as u64);
        assert_eq!(fits(&reused_stats), 4 * mesh.num_vertices() as u64);
        assert_ne!(every, reused, "the reused weights were not used");
        let max_diff = every
            .iter()
            .zip(&reused)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0, f64::max);
        assert!(max_diff < 0.01, "moved {max_diff} apart");
        let (rms_every, rms_reused) = (
            shapes::rms_distance(&sphere, &every),
            shapes::rms_distance(&sphere, &reused),
        );
        assert!(rms_reused < 0.25 * shapes::rms_distance(&sphere, mesh.positions()));
        assert!(
            (rms_every - rms_reused).abs() < 0.002,
            "{rms_every} vs {rms_reused}"
        );

        // Passes continued from there move less: selective refits skip
        // many vertices and end where refitting every vertex ends.
        let n = mesh.num_vertices() as u64;
        let (all, all_stats) = run(&reused, &is_refit_pass, None);
        let (some, some_stats) = run(&reused, &is_refit_pass, Some(REFIT_TOLERANCE));
        assert_eq!(fits(&all_stats), 4 * n);
        assert!(
            fits(&some_stats) < 3 * n,
            "{} fits for {n} vertices",
            fits(&some_stats)
        );
        let max_diff = all
            .iter()
            .zip(&some)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0, f64::max);
        assert!(max_diff < 0.002, "moved {max_diff} apart");
    }

    #[test]
    fn early_vertices_stop_after_their_passes_and_the_others_go_on() {
        let (_, mesh) = shapes::voxel_sphere(6.0);
        let topo = Topology::build(&mesh);
        let hoods = Neighbourhoods::two_ring(&topo, 56);
        let movable = vec![true; mesh.num_vertices()];
        // Every other vertex stops early.
        let early: Vec<bool> = (0..mesh.num_vertices()).map(|v| v % 2 == 0).collect();
        let never = AtomicBool::new(false);
        let run = |passes: u32| {
            let mut p = mesh.positions().to_vec();
            smooth_passes(
                &mesh,
                &topo,
                &mut p,
                &hoods,
                &movable,
                FitModel::Quadric,
                0.0,
                passes,
                |_| true,
                None,
                Some(EarlyStop {
                    vertices: &early,
                    momentum: 0.8,
                    passes: 3,
                }),
                &never,
                |_| {},
            )
            .expect("not cancelled");
            p
        };
        let (three, six) = (run(3), run(6));
        for (v, (a, b)) in three.iter().zip(&six).enumerate() {
            if early[v] {
                assert_eq!(a, b, "vertex {v} moved after its passes");
            }
        }
        assert!(
            (0..mesh.num_vertices()).any(|v| !early[v] && three[v] != six[v]),
            "the other vertices went on"
        );
    }

    #[test]
    fn early_vertices_keep_their_first_fit() {
        let (_, mesh) = shapes::voxel_sphere(6.0);
        let topo = Topology::build(&mesh);
        let hoods = Neighbourhoods::two_ring(&topo, 56);
        let movable = vec![true; mesh.num_vertices()];
        let all = vec![true; mesh.num_vertices()];
        let never = AtomicBool::new(false);
        let start = without_staircase(&mesh, &topo);
        let fits = |early: Option<EarlyStop>| {
            let mut p = start.clone();
            let s = smooth_passes(
                &mesh,
                &topo,
                &mut p,
                &hoods,
                &movable,
                FitModel::Quadric,
                0.0,
                10,
                is_refit_pass,
                Some(REFIT_TOLERANCE),
                early,
                &never,
                |_| {},
            )
            .expect("not cancelled");
            assert_eq!(s.fixed_fallback + s.clamped, 0, "no failed move");
            s.quadric + s.plane_fallback
        };
        let n = mesh.num_vertices() as u64;
        // Refits at passes 4 and 9 (the last) fit again without early
        // vertices; early ones that stop after pass 7 fit only at pass 0.
        assert!(fits(None) > n);
        let early = EarlyStop {
            vertices: &all,
            momentum: 0.8,
            passes: 8,
        };
        assert_eq!(fits(Some(early)), n);
    }

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
            let (stats, curvature) = initial_passes(
                &mesh,
                &topo,
                &mut p,
                &movable,
                56,
                0.5,
                passes,
                &never,
                |_| {},
            )
            .expect("not cancelled");
            assert_eq!(curvature, expected, "{passes} passes");
            assert!(expected.iter().any(|c| c.0 != 0.0));
            assert_eq!(
                stats.quadric,
                u64::from(passes) * movable.iter().filter(|&&m| m).count() as u64
            );
            assert_eq!(p == mesh.positions(), passes == 0);
        }
    }

    #[test]
    fn stale_vertices_are_those_near_a_drift_beyond_the_tolerance() {
        let mesh = crate::mesh::test_grid(4);
        let topo = Topology::build(&mesh);
        let limits = vec![1.0f32; mesh.num_vertices()];
        let mut drift = vec![0.0f32; mesh.num_vertices()];
        let (moved, failed, settled) = (6usize, 18usize, 12usize);
        drift[moved] = 0.03;
        drift[failed] = UNFITTED_DRIFT;
        drift[settled] = 0.01;
        let stale = stale_vertices(&topo, &drift, &limits, 0.02, None);
        for (v, &is_stale) in stale.iter().enumerate() {
            let near = |c: usize| v == c || topo.neighbors(c).contains(&(v as u32));
            assert_eq!(is_stale, near(moved) || near(failed), "vertex {v}");
        }
        assert!(!stale[settled]);
        // Vertices that keep their fit are stale only by their own failure.
        let keeping = vec![true; mesh.num_vertices()];
        let stale = stale_vertices(&topo, &drift, &limits, 0.02, Some(&keeping));
        for (v, &is_stale) in stale.iter().enumerate() {
            assert_eq!(is_stale, v == failed, "vertex {v}");
        }
    }
}
