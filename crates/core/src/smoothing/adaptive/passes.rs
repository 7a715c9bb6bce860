//! The adaptive passes: Jacobi passes of fits over the grown
//! neighbourhoods, refitting on a schedule and only where the surface
//! moved, flat vertices with momentum and an early stop.

use crate::control::{Cancelled, check};
use crate::fit::normals::vertex_normals_f32_by_faces;
use crate::fit::quadric_fit::FitModel;
use crate::mesh::{Mesh, Topology};
use crate::smoothing::fidelity::Fidelity;
use crate::smoothing::neighbourhood::{HoodSource, Neighbourhoods};
use crate::smoothing::project::{
    FitPass, FitStats, Momentum, Refit, Reuse, UNFITTED_DRIFT, apply, fit_pass, step_limits,
    weighted_pass,
};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::atomic::AtomicBool;

/// The gap between the first two refits of the adaptive passes; each later
/// gap is twice the one before ([`is_refit_pass`]).
pub const FIRST_REFIT_GAP: u32 = 4;

/// True when adaptive pass `pass` (from 0) fits anew: passes 0, 4, 12, 28,
/// ... ([`smooth_passes`] adds the last pass). The others reuse the latest
/// fit's linear weights, which change little once the surface has settled:
/// refits grow sparser as the passes go on, and a refit costs several
/// weighted passes. How close this schedule stays to refitting every pass
/// is in `docs/tuning.md`.
pub fn is_refit_pass(pass: u32) -> bool {
    pass.is_multiple_of(FIRST_REFIT_GAP) && (pass / FIRST_REFIT_GAP + 1).is_power_of_two()
}

/// Refits after the first are selective ([`smooth_passes`]):
/// a vertex fits anew only when it or a neighbour has moved more than this
/// fraction of its mean input edge length since its latest fit (or that
/// fit or a later move failed); the others keep moving by their weights.
/// Where the surface has settled, a new fit would give the same weights.
/// The value is the largest that keeps the analytic shapes' accuracy and
/// the real meshes' folds where refitting every vertex leaves them; a
/// larger one lets real meshes fold and swell (`docs/tuning.md`).
pub const REFIT_TOLERANCE: f32 = 0.02;

/// A vertex whose neighbourhood grew to at least this many rings is flat
/// enough to converge with momentum and stop early ([`EarlyStop`],
/// [`FLAT_MOMENTUM`], [`flat_passes`]). There the passes damp long
/// staircase waves slowly but steadily (the voxel sphere r=40 still
/// improves at 30 passes), while where the curvature changes each pass
/// adds bias: flat vertices reach with momentum in fewer passes what plain
/// passes reach in all of them, and stop there. Only vertices of large
/// smooth regions grow this far; curved or noisy parts (most of a real
/// mesh) stay below it and keep all the passes, where momentum or fewer
/// passes would bias or fold them. Flat vertices also keep their first fit
/// ([`EarlyStop`]): their neighbourhoods change too little for a refit to
/// matter. With `k_max` below this no vertex is flat and every vertex
/// makes every pass. The measurements behind the value are in
/// `docs/tuning.md`.
pub const FLAT_RING: u8 = 15;

// A ring size is stored in a byte and neighbourhoods grow to at most
// `MAX_RINGS`: the flat ring must be reachable.
const _: () =
    assert!(FLAT_RING as usize <= crate::smoothing::neighbourhood::MAX_RINGS && FLAT_RING >= 3);

/// The momentum of flat vertices ([`FLAT_RING`], [`Momentum`]): enough to
/// reach in [`flat_passes`] what plain passes reach in all of them; much
/// more overshoots (`docs/tuning.md`).
pub const FLAT_MOMENTUM: f32 = 0.8;

/// How many of the adaptive `passes` flat vertices make ([`FLAT_RING`]):
/// 8 in 11 (16 of the default 22), where momentum [`FLAT_MOMENTUM`] has
/// damped the staircase waves as far as all the passes would.
pub fn flat_passes(passes: u32) -> u32 {
    passes - passes * 3 / 11
}

/// What [`smooth_passes`] runs: the neighbourhoods, which vertices move,
/// the fit, and the schedule of refits and early stops.
#[derive(Clone, Copy)]
pub struct PassPlan<'a> {
    /// Each vertex's neighbourhood.
    pub hoods: &'a Neighbourhoods,
    /// Which vertices may move.
    pub movable: &'a [bool],
    /// The surface model of the fits.
    pub model: FitModel,
    /// Neighbours facing away by a cosine below this are left out of a fit
    /// ([`fit_pass`]).
    pub min_cos: f64,
    /// Passes to run.
    pub passes: u32,
    /// Whether pass `p` (from 0) fits anew; the first and the last always do.
    pub refit: &'a dyn Fn(u32) -> bool,
    /// Refits after the first fit only the [`stale_vertices`] under this
    /// tolerance; `None`: every vertex.
    pub refit_tolerance: Option<f32>,
    /// Vertices that move with momentum and stop early.
    pub early: Option<EarlyStop<'a>>,
    /// The fidelity bound every pass keeps to; `None`: no bound.
    pub fidelity: Option<&'a Fidelity<'a>>,
    /// Vertices that stop after a few passes because they lie on the
    /// shape, not on the staircase ([`ShapeStop`]).
    pub shape_stop: Option<ShapeStop<'a>>,
}

/// Vertices whose adaptive neighbourhood could not grow beyond the rings
/// of the initial passes: the curvature changes within a few rings of
/// them, so they lie on the shape itself (a gyrus, a thin tube), where the
/// initial passes already removed the staircase. More passes of fits that
/// small only flatten the shape; these vertices stop after `passes` passes
/// while the others go on.
#[derive(Debug, Clone, Copy)]
pub struct ShapeStop<'a> {
    /// Whether each vertex stops.
    pub vertices: &'a [bool],
    /// Passes they make (passes `0..passes`).
    pub passes: u32,
}

/// Runs `plan.passes` passes over `plan.hoods` starting from `positions` (updated in
/// place). Pass `p` fits anew when `refit(p)` holds, and always at the
/// first and the last pass; the others are [`weighted_pass`]es with the
/// weights of the latest fit. The last pass refits so the result lies on
/// fits made for it: on real meshes whose fits are poor (thin tubes,
/// non-manifold parts), passes on reused weights drift.
/// With `refit_tolerance`, refits after the first are selective: only the
/// [`stale_vertices`] fit anew, the others move by their kept weights.
/// With `early`, its vertices move with momentum and stop after its
/// passes ([`EarlyStop`]).
/// Returns the summed fit statistics. `model` and `min_cos` are
/// [`fit_pass`]'s.
pub fn smooth_passes(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    plan: &PassPlan,
    cancel: &AtomicBool,
    mut on_pass: impl FnMut(u32),
) -> Result<FitStats, Cancelled> {
    let PassPlan {
        hoods,
        movable,
        model,
        min_cos,
        passes,
        refit,
        refit_tolerance,
        early,
        fidelity,
        shape_stop,
    } = *plan;
    let mut moves = vec![Vec3::ZERO; positions.len()];
    // The normals of the starting positions serve every pass: a pass moves
    // a vertex by a fraction of a voxel, which turns its normal by little,
    // and the mean move needs only its sign and size along the surface.
    let debias = fidelity.is_some_and(|f| f.on_lattice()).then(|| {
        let (component, count) = topo.component_ids();
        let normals = vertex_normals_f32_by_faces(mesh, topo, positions);
        (component, count, normals)
    });
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
        if let Some(stop) = shape_stop.filter(|s| s.passes == pass) {
            let moving = still.as_deref().unwrap_or(movable);
            still = Some(
                moving
                    .iter()
                    .zip(stop.vertices)
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
                Some((weights, drift, limits)) if !refits(pass) => {
                    let reuse = Reuse {
                        hoods,
                        weights,
                        limits,
                        movable,
                        momentum,
                    };
                    weighted_pass(mesh, topo, positions, reuse, drift, &mut moves)
                }
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
                        FitPass {
                            hoods: HoodSource::Stored(hoods),
                            movable,
                            model,
                            min_cos,
                            refit,
                            momentum,
                            curvature: None,
                        },
                        &mut moves,
                    )
                }
            };
        stats.accumulate(s);
        if let Some((component, count, normals)) = &debias {
            remove_mean_normal_move(normals, (component, *count), &mut moves);
        }
        apply(positions, &moves);
        if let Some(f) = fidelity {
            f.apply(positions);
        }
        on_pass(pass + 1);
    }
    Ok(stats)
}

/// Takes the mean of `moves` along the vertex `normals`, per connected
/// component (`component`: each vertex's, and their number; over the
/// vertices that move), off every move of the component. The fits are
/// biased along the normal where the curvature is not constant over a
/// neighbourhood (a fit to a cap lies off it), and over many passes a
/// surface drifts by a fraction of a voxel, outward on a solid and inward
/// on a cavity's surface (a shell's inner sphere). The volume restoration
/// takes that back at the end, but on a lattice, whose bounds (dual
/// voxels, marching-cubes slabs) are placed by the voxel centres, the
/// drifted surface is clamped against one face of the bounds first,
/// unevenly, and the clamps stay. Summed in order in double precision: the
/// same for any thread count.
fn remove_mean_normal_move(
    normals: &[Vec3],
    (component, count): (&[u32], usize),
    moves: &mut [Vec3],
) {
    let mut sums = vec![(0.0f64, 0u32); count];
    for ((m, n), &c) in moves.iter().zip(normals).zip(component) {
        if *m != Vec3::ZERO {
            let s = &mut sums[c as usize];
            *s = (s.0 + f64::from(m.dot(*n)), s.1 + 1);
        }
    }
    let means: Vec<f32> = sums
        .iter()
        .map(|&(sum, n)| (sum / f64::from(n.max(1))) as f32)
        .collect();
    moves
        .par_iter_mut()
        .zip(normals)
        .zip(component)
        .with_min_len(4096)
        .filter(|((m, _), _)| **m != Vec3::ZERO)
        .for_each(|((m, n), &c)| *m -= means[c as usize] * *n);
}

/// Vertices that move with momentum and stop early in [`smooth_passes`]:
/// where the fits converge slowly but steadily (flat regions with large
/// neighbourhoods), momentum reaches in fewer passes what plain passes
/// reach in all of them, and stopping there keeps the later passes' bias
/// out. They also keep their first fit's weights through the selective
/// refits (unless a move on them failed): their neighbourhoods change
/// shape too little for a refit to matter
/// ([`FLAT_RING`] has the
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
    use crate::smoothing::initial::{InitialPlan, initial_passes};
    use crate::smoothing::neighbourhood::push_thinned;

    /// `mesh`'s positions after the initial passes, as in the pipeline: the
    /// adaptive passes start from a surface without its staircase.
    fn without_staircase(mesh: &Mesh, topo: &Topology) -> Vec<DVec3> {
        let mut start = mesh.positions().to_vec();
        let movable = vec![true; mesh.num_vertices()];
        let never = AtomicBool::new(false);
        let plan = InitialPlan {
            movable: &movable,
            max_points: 56,
            min_cos: 0.0,
            passes: 3,
            fidelity: &Fidelity::unbounded(),
            curvature: true,
        };
        initial_passes(mesh, topo, &mut start, plan, &never, |_| {}).expect("not cancelled");
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
                &PassPlan {
                    hoods: &hoods,
                    movable: &movable,
                    model: FitModel::Cubic,
                    min_cos: 0.0,
                    passes: 14,
                    refit,
                    refit_tolerance: tolerance,
                    early: None,
                    fidelity: None,
                    shape_stop: None,
                },
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
                &PassPlan {
                    hoods: &hoods,
                    movable: &movable,
                    model: FitModel::Quadric,
                    min_cos: 0.0,
                    passes,
                    refit: &|_| true,
                    refit_tolerance: None,
                    early: Some(EarlyStop {
                        vertices: &early,
                        momentum: 0.8,
                        passes: 3,
                    }),
                    fidelity: None,
                    shape_stop: None,
                },
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
                &PassPlan {
                    hoods: &hoods,
                    movable: &movable,
                    model: FitModel::Quadric,
                    min_cos: 0.0,
                    passes: 10,
                    refit: &is_refit_pass,
                    refit_tolerance: Some(REFIT_TOLERANCE),
                    early,
                    fidelity: None,
                    shape_stop: None,
                },
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
    fn refits_double_their_gap() {
        let refits: Vec<u32> = (0..100).filter(|&p| is_refit_pass(p)).collect();
        assert_eq!(refits, [0, 4, 12, 28, 60]);
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
