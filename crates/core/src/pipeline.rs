//! `run(mesh, &params, &progress, &cancel)`: the whole smoothing pipeline
//! on a mesh, under the job layer ([`crate::job`]) that reads and writes
//! the files: analyse, smooth (Wang-Yu's initial, label and adaptive
//! stages, or a baseline), fix the quality, measure, and the report.

use crate::control::{Cancelled, Progress, Stage, check};
use crate::error::{ErrorCode, ShapeError};
use crate::fit::normals::vertex_normals_f32_by_faces;
use crate::fit::quadric_fit::FitModel;
use crate::mesh::lattice::{is_marching_cubes_lattice, is_voxel_lattice};
use crate::mesh::{
    Mesh, Orientation, PairedFaces, Topology, UnitScale, VertexKind, mean_edge_length, orientation,
    paired_voxel_faces, regions,
};
use crate::params::{AdaptiveFit, BoundaryRule, Method, ParamError, Params};
use crate::quality::{SLIVER_FRACTION, closing_floor_cos, has_sliver_angle, improve, is_defective};
use crate::report::{CurvatureVariation, QualityReport, StageMeasures};
use crate::report::{
    InputGrid, LabelCounts, Reproducibility, StageTiming, WangYuSummary, ring_size_histogram,
};
use crate::report::{mean_curvature_variation, measure_stage, mesh_statistics};
use crate::smoothing::adaptive::{GrowthRule, PassSettings, adaptive_passes, grow_neighbourhoods};
use crate::smoothing::curvature::{Curvatures, vertex_curvatures};
use crate::smoothing::fairing::{FairingPlan, TERRACE_RINGS, fair};
use crate::smoothing::fidelity::{Fidelity, FidelityBound};
use crate::smoothing::initial::{InitialPlan, initial_passes};
use crate::smoothing::label::{Label, label};
use crate::smoothing::local_height::take_back_drift;
use crate::smoothing::pinches::place_pinches;
use crate::smoothing::project::FitStats;
use crate::smoothing::staircase::{compensate_shrinkage, relax_staircase};
use crate::smoothing::taubin::{LOWPASS_LAMBDA, LOWPASS_MU, taubin_in_place};
use crate::smoothing::volume::{MAX_VOLUME_OFFSET, Restored, VolumeParts, restore_volume};
use crate::smoothing::{laplacian::laplacian_smooth, taubin::taubin_smooth};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use thiserror::Error;

mod regions;

/// Why a run did not produce a result.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SmoothError {
    /// A parameter is out of range.
    #[error(transparent)]
    Params(#[from] ParamError),
    /// The cancellation flag was raised.
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
    /// The mesh's shape would make the run's cost grow faster than its
    /// size ([`check_shape`]).
    #[error(transparent)]
    Shape(#[from] ShapeError),
}

impl SmoothError {
    /// Stable code.
    pub fn code(&self) -> ErrorCode {
        match self {
            SmoothError::Params(e) => e.code(),
            SmoothError::Cancelled(_) => ErrorCode::Cancelled,
            SmoothError::Shape(e) => e.code(),
        }
    }
}

/// The most edges a vertex may have for smoothing: every ring walk through
/// a vertex scans all its neighbours, so a vertex of valence `d` costs
/// about `d^2` over its neighbours' walks. Poles of latitude-longitude
/// spheres and cone tips reach a few hundred; a thousand keeps a hub's cost
/// near that of a thousand ordinary vertices' walks.
pub const MAX_VALENCE: usize = 1000;

/// The most corners a face may have for smoothing: normals, fits and the
/// quality fixes visit a face once from each corner, so a face of `n`
/// corners costs `n^2`. Real polygons have a handful of corners; the
/// largest in the test data is a 66-gon.
pub const MAX_FACE_CORNERS: usize = 1000;

/// Refuses a mesh with a vertex of more than [`MAX_VALENCE`] edges or a
/// face of more than [`MAX_FACE_CORNERS`] corners, in time linear in the
/// mesh, before any stage whose cost would grow with their square.
pub fn check_shape(mesh: &Mesh, topo: &Topology) -> Result<(), ShapeError> {
    if let Some((face, arity)) = (0..mesh.num_faces())
        .map(|f| (f, mesh.face(f).len()))
        .find(|&(_, n)| n > MAX_FACE_CORNERS)
    {
        return Err(ShapeError::FaceTooLarge {
            face,
            arity,
            limit: MAX_FACE_CORNERS,
        });
    }
    if let Some((vertex, valence)) = (0..topo.num_vertices())
        .map(|v| (v, topo.neighbors(v).len()))
        .find(|&(_, d)| d > MAX_VALENCE)
    {
        return Err(ShapeError::ValenceTooHigh {
            vertex,
            valence,
            limit: MAX_VALENCE,
        });
    }
    Ok(())
}

/// Per-vertex results of a run, one entry per vertex each.
#[derive(Debug, Clone, Default)]
pub struct PerVertex {
    /// Label of Table 2 (0 flat, 1 minimal, 2 convex, 3 concave); empty for
    /// baseline methods.
    pub label: Vec<u8>,
    /// Mean curvature `H` of the output, from 2-ring quadric fits (outward
    /// normals: convex < 0).
    pub mean_curvature: Vec<f64>,
    /// Gaussian curvature `K` of the output, from the same fits.
    pub gaussian_curvature: Vec<f64>,
    /// Distance each vertex moved.
    pub displacement: Vec<f64>,
}

/// What a run returns: new positions (one per input vertex), the report and
/// per-vertex results.
#[derive(Debug, Clone)]
pub struct SmoothOutput {
    /// Smoothed positions, one per vertex, in input order.
    pub positions: Vec<DVec3>,
    /// The quality report.
    pub report: QualityReport,
    /// Per-vertex results.
    pub per_vertex: PerVertex,
}

impl SmoothOutput {
    /// The output of the same run on the mesh scaled by `s`: positions and
    /// displacements times `s`, mean curvatures divided by it, Gaussian
    /// curvatures by its square, and the report likewise
    /// ([`QualityReport::rescale`]). Exact when `s` is a power of two.
    fn rescale(&mut self, s: f64) {
        for p in &mut self.positions {
            *p *= s;
        }
        let v = &mut self.per_vertex;
        v.mean_curvature.iter_mut().for_each(|h| *h /= s);
        v.gaussian_curvature.iter_mut().for_each(|k| *k /= s * s);
        v.displacement.iter_mut().for_each(|d| *d *= s);
        self.report.rescale(s);
    }
}

/// Components of at most this many vertices stay where they are: the
/// quadric of section 2.1 has six coefficients, and on so small a piece no
/// vertex has the six other points a fit needs. A fit there falls back to
/// a plane through the vertex's neighbours, and a plane through a
/// tetrahedron's other three corners folds it flat and through itself (the
/// specks that segmentation meshes of neurons carry).
pub const MAX_FIXED_COMPONENT: u32 = 6;

/// Which vertices may move: not isolated, not non-manifold, not on a
/// component too small to fit ([`MAX_FIXED_COMPONENT`]), and not on the
/// boundary unless the boundary rule lets them move along their normal.
pub fn movable_mask(topo: &Topology, boundary: BoundaryRule) -> Vec<bool> {
    vertex_masks(topo, boundary).movable
}

/// The vertices each step may move.
struct VertexMasks {
    /// [`movable_mask`].
    movable: Vec<bool>,
    /// `movable` and the non-manifold vertices of components large enough
    /// to fit: the voxel lattice's relaxation moves those too.
    relaxable: Vec<bool>,
}

/// Both [`VertexMasks`] from one pass over the vertices (and one
/// union-find for the component sizes).
fn vertex_masks(topo: &Topology, boundary: BoundaryRule) -> VertexMasks {
    let (movable, relaxable) = topo
        .kinds()
        .iter()
        .zip(topo.component_sizes())
        .map(|(k, size)| match k {
            _ if size <= MAX_FIXED_COMPONENT => (false, false),
            VertexKind::Interior => (true, true),
            VertexKind::Boundary => {
                let normal_only = boundary == BoundaryRule::NormalOnly;
                (normal_only, normal_only)
            }
            VertexKind::NonManifold => (false, true),
            VertexKind::Isolated => (false, false),
        })
        .unzip();
    VertexMasks { movable, relaxable }
}

/// `movable` without the vertices next to a non-manifold one: on a voxel
/// lattice their fitting rings run through the pinch into the other sheet,
/// and the adaptive passes leave them where the relaxation put them.
fn away_from_pinches(topo: &Topology, movable: &[bool]) -> Vec<bool> {
    (0..topo.num_vertices())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| {
            movable[v]
                && !topo
                    .neighbors(v)
                    .iter()
                    .any(|&j| topo.kind(j as usize) == VertexKind::NonManifold)
        })
        .collect()
}

/// How much farther than the fidelity bound the quality fixes may take a
/// vertex, as a ball of this many times the bound's size (on a voxel
/// lattice, the ellipsoid of this many times its box's half-widths,
/// [`FidelityBound::widened`]): the smoothing
/// passes leave vertices against the walls of their dual voxels (a thin
/// sheet's two sides against the same wall), and opening the triangles
/// flattened there needs room beyond the wall. Twice the default half voxel
/// is one voxel, the most the fidelity bound promises.
const QUALITY_ROOM: f64 = 2.0;

/// A smoothing run's inputs, shared by its stages.
#[derive(Clone, Copy)]
struct Run<'a> {
    /// The mesh smoothed: the input, or its split voxel faces paired back
    /// into quads ([`paired_voxel_faces`]).
    mesh: &'a Mesh,
    topo: &'a Topology,
    /// The input's own faces and topology, which every stage is measured
    /// on: the same as `mesh` unless its triangles were paired.
    measured: (&'a Mesh, &'a Topology),
    /// Triangle pairs joined back into voxel faces.
    paired_triangles: usize,
    /// [`movable_mask`].
    movable: &'a [bool],
    /// [`VertexMasks::relaxable`].
    relaxable: &'a [bool],
    /// The vertices the lattice fairing and the adaptive passes move:
    /// `movable`, less on a voxel lattice the vertices next to a
    /// non-manifold one ([`away_from_pinches`]).
    fitted: &'a [bool],
    params: &'a Params,
    /// Whether the input is a voxel lattice ([`is_voxel_lattice`]): its
    /// staircase is relaxed instead of fitted by the initial passes.
    lattice: bool,
    /// Whether the input is a marching-cubes mesh of a binary mask
    /// ([`is_marching_cubes_lattice`]): its staircase is relaxed between
    /// the initial passes. A mesh that samples no lattice has no staircase
    /// to relax, and umbrella steps would only shrink its thin parts (a
    /// neuron's neurites) and roughen them.
    marching_cubes: bool,
    /// The fidelity bound of the smoothing passes and the volume
    /// restoration ([`Params::max_displacement`]).
    fidelity: &'a Fidelity<'a>,
    /// The fidelity bound itself.
    bound: Option<&'a FidelityBound>,
    /// The wider bound of the quality fixes ([`QUALITY_ROOM`]), and the
    /// record of what it held back.
    quality_bound: Option<&'a FidelityBound>,
    quality_fidelity: &'a Fidelity<'a>,
    /// The parts whose volumes are restored, when the volume is to be
    /// preserved and the mesh is closed ([`VolumeParts`]).
    volume_parts: Option<&'a VolumeParts>,
    /// Each vertex's body, when the mesh holds bodies that touch face to
    /// face ([`run_bodies`]).
    bodies: Option<&'a [u32]>,
    progress: &'a dyn Progress,
    cancel: &'a AtomicBool,
}

/// Milliseconds per stage, summed over the places a stage is timed.
#[derive(Default)]
struct Timings(Vec<(Stage, f64)>);

impl Timings {
    /// Runs `f`, adding its time to `stage`.
    fn time<T>(&mut self, stage: Stage, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let value = f();
        self.add(stage, ms(t));
        value
    }

    /// Adds another run's timings (a report's entries), stage by stage.
    fn absorb(&mut self, other: &[StageTiming]) {
        for t in other {
            if let Some(stage) = Stage::named(&t.stage) {
                self.add(stage, t.ms);
            }
        }
    }

    fn add(&mut self, stage: Stage, ms: f64) {
        match self.0.iter_mut().find(|t| t.0 == stage) {
            Some(t) => t.1 += ms,
            None => self.0.push((stage, ms)),
        }
    }

    /// One entry per stage, in pipeline order.
    fn into_report(mut self) -> Vec<StageTiming> {
        self.0.sort_by_key(|t| t.0);
        self.0
            .into_iter()
            .map(|(stage, ms)| StageTiming {
                stage: stage.name().to_string(),
                ms,
            })
            .collect()
    }
}

/// After the quality fixes, which slide vertices over their fits, the
/// volume is restored again by an offset of at most this fraction of the
/// mean edge length: a small correction that must fold or twist no face.
const MAX_VOLUME_REOFFSET: f64 = 0.1;

/// A relative volume change left below this counts as restored.
const VOLUME_RESTORED: f64 = 1e-6;

/// A final relative volume change beyond this (half a percent) is worth a
/// warning when the volume was to be preserved.
const VOLUME_WARNING: f64 = 0.005;

/// Intermediate results of the Wang-Yu stages.
struct WangYuRun {
    /// The input's mean curvature variation
    /// ([`mean_curvature_variation`]), from the 2-ring quadric fits of the
    /// first initial pass (the estimator of [`WangYuRun::curvature`]).
    input_curvature_variation: f64,
    /// Measures after initial smoothing.
    initial: StageMeasures,
    /// Positions after adaptive smoothing (and volume restoration).
    adaptive: Vec<DVec3>,
    /// `(H, K)` per vertex of `adaptive`, from 2-ring quadric fits.
    curvature: Curvatures,
    /// Label per vertex (from the curvature after initial smoothing).
    labels: Vec<Label>,
    /// Final ring size per vertex.
    ring: Vec<u8>,
    /// Fit statistics of the initial passes.
    initial_fits: FitStats,
    /// Fit statistics of the adaptive passes.
    adaptive_fits: FitStats,
    /// What the volume restoration did ([`Restored`]; all 0 when it did
    /// not run).
    volume: Restored,
    /// Relative volume change left when restoring the volume was asked for
    /// but refused (the offset needed was too large or did not converge).
    volume_not_restored: Option<f64>,
}

/// Initial smoothing, labelling and adaptive smoothing with volume
/// restoration (paper sections 2.2-2.3), without the quality fixes.
fn wang_yu(run: &Run, timings: &mut Timings) -> Result<WangYuRun, Cancelled> {
    let Run {
        mesh,
        topo,
        params,
        progress,
        cancel,
        ..
    } = *run;
    let mut positions = mesh.positions().to_vec();
    let (initial_fits, input_curvature_variation) =
        timings.time(Stage::Initial, || initial_stage(run, &mut positions))?;
    let initial = timings.time(Stage::Report, || {
        measure_stage(
            run.measured.0,
            run.measured.1,
            &positions,
            mesh.positions(),
            None,
            params.quality.short_edge_fraction,
        )
    });
    check(cancel)?;
    let (labels, curvature, normals, edge_length) =
        timings.time(Stage::Label, || label_stage(run, &positions));
    progress.update(Stage::Label, 1.0);

    let (adaptive_fits, ring) = timings.time(Stage::Adaptive, || {
        let grown = grow_neighbourhoods(
            topo,
            &positions,
            &labels,
            curvature,
            normals,
            growth_rule(params, edge_length),
        );
        release_free_memory();
        let passes = if run.lattice {
            params.lattice_adaptive_passes
        } else {
            params.adaptive_passes
        };
        let settings = PassSettings {
            movable: run.fitted,
            passes,
            model: match params.adaptive_fit {
                AdaptiveFit::Cubic => FitModel::Cubic,
                AdaptiveFit::Quadric => FitModel::Quadric,
            },
            min_cos: params.min_normal_cos(),
            fidelity: Some(run.fidelity),
            shape_ring: params.shape_ring.min(u32::from(u8::MAX)) as u8,
            shape_passes: if run.lattice {
                params.lattice_shape_passes
            } else {
                params.shape_passes
            },
        };
        adaptive_passes(mesh, topo, &mut positions, grown, settings, cancel, |p| {
            progress.update(Stage::Adaptive, p as f64 / passes.max(1) as f64)
        })
    })?;
    timings.time(Stage::Adaptive, || local_height_stage(run, &mut positions));
    timings.time(Stage::Adaptive, || lowpass_stage(run, &mut positions));
    let (volume, volume_not_restored) = timings.time(Stage::Adaptive, || {
        restore_after_passes(run, &mut positions)
    });
    let curvature = timings.time(Stage::Report, || {
        stage_curvature(mesh, topo, &positions, params)
    });
    Ok(WangYuRun {
        input_curvature_variation,
        initial,
        adaptive: positions,
        curvature,
        labels,
        ring,
        initial_fits,
        adaptive_fits,
        volume,
        volume_not_restored,
    })
}

/// The initial passes (paper section 2.2) on `positions`: their fit
/// statistics and the input's mean curvature variation, from the first
/// pass's fits. On a marching-cubes mesh of a mask
/// ([`Params::marching_cubes_initial_passes`] passes) the staircase
/// relaxation ([`relax_staircase`]) runs between the first pass, whose
/// fits also give the input's curvature, and the second, and gives back the
/// local shrinkage of its umbrella steps ([`compensate_shrinkage`]); a mesh
/// that samples no lattice gets the paper's passes alone. On a voxel
/// lattice the relaxation, over all neighbours, and the fairing
/// ([`fair_staircase`]) replace the passes ([`Params::staircase_steps`]),
/// and the input's curvature comes from the same 2-ring fits made without
/// moving a vertex; before the relaxation, the lattice's pinches go to
/// their mask's level ([`place_pinches`]).
fn initial_stage(run: &Run, positions: &mut [DVec3]) -> Result<(FitStats, f64), Cancelled> {
    let params = run.params;
    if run.lattice && params.staircase_steps > 0 {
        let normals = vertex_normals_f32_by_faces(run.mesh, run.topo, positions);
        let input_curvature = vertex_curvatures(
            run.topo,
            positions,
            &normals,
            2,
            params.max_fit_points as usize,
            params.min_normal_cos(),
        );
        // Where voxels touch only along an edge or at a corner, the shared
        // corner goes to its mask's one-half level first and stays there
        // through the relaxation, whose mean of both sheets' neighbours
        // would pull it back toward the corner (only the sharp-angle fix's
        // last resort moves it later). A pinch already at its level relaxes
        // with the rest: held where it was it would pin both sheets to the
        // lattice. Like the faired corners, a pinch keeps off the walls of
        // its dual voxel (`FAIRING_ROOM`).
        let placed = run.bound.map_or_else(Vec::new, |bound| {
            let room = bound.scaled(FAIRING_ROOM);
            place_pinches(
                run.mesh,
                run.topo,
                positions,
                run.relaxable,
                &room,
                run.bodies,
            )
        });
        tracing::debug!(
            placed = placed.iter().filter(|&&p| p).count(),
            "pinches placed at their mask's level"
        );
        let held: Vec<bool>;
        let relaxable = if placed.is_empty() {
            run.relaxable
        } else {
            held = run
                .relaxable
                .iter()
                .zip(&placed)
                .map(|(&r, &p)| r && !p)
                .collect();
            &held
        };
        relax_staircase(
            run.mesh,
            run.topo,
            positions,
            relaxable,
            params.staircase_steps,
            params.lattice_staircase_lambda,
            f64::NEG_INFINITY,
            run.fidelity,
        );
        compensate_shrinkage(
            run.mesh,
            run.topo,
            positions,
            relaxable,
            params.lattice_shrinkage_compensation,
            f64::NEG_INFINITY,
            run.fidelity,
        );
        fair_staircase(run, positions);
        run.progress.update(Stage::Initial, 1.0);
        let variation = mean_curvature_variation(run.topo, &input_curvature);
        return Ok((FitStats::default(), variation));
    }
    let passes = if run.marching_cubes {
        params.marching_cubes_initial_passes
    } else {
        params.initial_passes
    };
    let some_passes = |positions: &mut [DVec3], n: u32, done: u32, curvature: bool| {
        let plan = InitialPlan {
            movable: run.movable,
            max_points: params.max_fit_points as usize,
            min_cos: params.min_normal_cos(),
            passes: n,
            fidelity: run.fidelity,
            curvature,
        };
        initial_passes(run.mesh, run.topo, positions, plan, run.cancel, |p| {
            run.progress.update(
                Stage::Initial,
                f64::from(done + p) / f64::from(passes.max(1)),
            )
        })
    };
    let (mut fits, input_curvature) = some_passes(positions, passes.min(1), 0, true)?;
    if passes > 1 {
        if run.marching_cubes {
            relax_staircase(
                run.mesh,
                run.topo,
                positions,
                run.movable,
                params.staircase_steps,
                params.staircase_lambda,
                params.min_normal_cos(),
                run.fidelity,
            );
            if params.staircase_steps > 0 {
                compensate_shrinkage(
                    run.mesh,
                    run.topo,
                    positions,
                    run.movable,
                    params.shrinkage_compensation,
                    params.min_normal_cos(),
                    run.fidelity,
                );
            }
        }
        fits.accumulate(some_passes(positions, passes - 1, 1, false)?.0);
    }
    Ok((fits, mean_curvature_variation(run.topo, &input_curvature)))
}

/// How much of the fidelity bound's box the lattice fairing may use: the
/// faired corners stay off the walls of their dual voxels, where the
/// surface would pass through the four voxel centres of a wall, which the
/// mask puts on both sides of it, and where the quality fixes need room to
/// open the triangles the walls flatten. Chosen from 0.8, 0.9 and 1 on the
/// real voxel masks and the analytic families (`docs/tuning.md`).
const FAIRING_ROOM: f64 = 0.8;

/// The lattice fairing ([`fair`]) of the relaxed `positions`, anchored to
/// the input and held to [`FAIRING_ROOM`] of each corner's box. The
/// vertices next to a non-manifold one stay where the relaxation put them:
/// the bending energy couples them, through the pinch, to the other sheet.
fn fair_staircase(run: &Run, positions: &mut [DVec3]) {
    let params = run.params;
    let Some(bound) = run.bound.filter(|_| params.lattice_fairing_iterations > 0) else {
        return;
    };
    let room = bound.scaled(FAIRING_ROOM);
    let plan = FairingPlan {
        movable: run.fitted,
        iterations: params.lattice_fairing_iterations,
        anchor: params.lattice_fairing_anchor,
        terrace_rings: TERRACE_RINGS,
        bound: &room,
    };
    fair(run.topo, positions, run.mesh.positions(), &plan);
}

/// Curvature and labels after the initial passes (paper section 2.3,
/// Table 2): the labels, the curvature `(H, K)` and facing normals growth
/// needs, and the mean edge length that scales them. The curvature rings
/// are walked and fitted vertex by vertex, never stored (as lists they
/// would be the run's peak memory).
fn label_stage(run: &Run, positions: &[DVec3]) -> (Vec<Label>, Curvatures, Vec<Vec3>, f64) {
    let params = run.params;
    let normals = vertex_normals_f32_by_faces(run.mesh, run.topo, positions);
    let curvature = vertex_curvatures(
        run.topo,
        positions,
        &normals,
        params.curvature_ring,
        params.max_fit_points as usize,
        params.min_normal_cos(),
    );
    let l = mean_edge_length(run.mesh, positions);
    let labels = curvature
        .par_iter()
        .map(|&(h, k)| label(h, k, l, params.tolerance_h, params.tolerance_k))
        .collect();
    (labels, curvature, normals, l)
}

/// The growth rule of `params` on a surface of mean edge length `l`.
fn growth_rule(params: &Params, edge_length: f64) -> GrowthRule {
    GrowthRule {
        k_max: params.k_max,
        max_points: params.max_fit_points as usize,
        std_bound: params.curvature_std_bound,
        std_tolerance: params.std_tolerance,
        bias_bound: params.bias_bound,
        edge_length,
        tolerance_h: params.tolerance_h,
        tolerance_k: params.tolerance_k,
        label_margin: params.label_margin,
        label_disagreement: params.label_disagreement,
    }
}

/// On a mesh of no grid whose noise bounds the move across
/// ([`Params::noise_bound`]): the passes' drift across the input surface
/// taken back ([`take_back_drift`]), within the fidelity bound.
fn local_height_stage(run: &Run, positions: &mut [DVec3]) {
    let Some(bound) = run.bound.filter(|b| b.has_surface()) else {
        return;
    };
    let _s = tracing::info_span!("local_height").entered();
    let min_cos = run.params.min_normal_cos();
    let taken = take_back_drift(
        run.topo,
        run.mesh.positions(),
        positions,
        run.movable,
        min_cos,
        |v| bound.surface_normal(v),
    );
    tracing::debug!(taken_back_rms = taken, "drift across the input surface");
    run.fidelity.apply(positions);
}

/// The closing low-pass on a voxel lattice
/// ([`Params::lattice_lowpass_steps`] Taubin pairs), each pair brought back
/// within the fidelity bound; the volume restoration that follows takes
/// back what little the filter shrinks. Part of the staircase treatment
/// that replaces the initial passes there: with `staircase_steps` 0 the
/// lattice gets the paper's passes alone.
fn lowpass_stage(run: &Run, positions: &mut [DVec3]) {
    if !run.lattice || run.params.staircase_steps == 0 {
        return;
    }
    taubin_in_place(
        run.topo,
        run.movable,
        positions,
        run.params.lattice_lowpass_steps,
        (LOWPASS_LAMBDA, LOWPASS_MU),
        |p| run.fidelity.apply(p),
    );
}

/// Restores each part's enclosed volume after the adaptive passes when
/// asked and the mesh is closed ([`restore_volume`]): what it did, and the
/// relative change left when some part's restoration was refused.
fn restore_after_passes(run: &Run, positions: &mut [DVec3]) -> (Restored, Option<f64>) {
    let Some(parts) = run.volume_parts else {
        return (Restored::default(), None);
    };
    let max_offset = MAX_VOLUME_OFFSET * mean_edge_length(run.mesh, positions);
    let restored = restore_volume(
        run.mesh,
        run.topo,
        parts,
        positions,
        run.movable,
        max_offset,
        |_| true,
    );
    run.fidelity.apply(positions);
    // A part left as it was is worth a warning when nothing moved or when
    // what it leaves is a visible share of the whole volume.
    let refused = restored.left.abs() > VOLUME_RESTORED
        && (restored.mean_offset == 0.0 || restored.left.abs() > VOLUME_WARNING);
    let change = || {
        let apexes = parts.apexes();
        let target = apexes.volume(run.mesh, run.mesh.positions());
        (apexes.volume(run.mesh, positions) - target) / target.abs()
    };
    (restored, refused.then(change))
}

/// The curvature a stage reports (and the run's per-vertex result): from
/// quadric fits to every vertex's 2-ring, the same estimator for the input
/// and the output, so their curvature variations compare.
fn stage_curvature(
    mesh: &Mesh,
    topo: &Topology,
    positions: &[DVec3],
    params: &Params,
) -> Curvatures {
    let normals = vertex_normals_f32_by_faces(mesh, topo, positions);
    vertex_curvatures(
        topo,
        positions,
        &normals,
        2,
        params.max_fit_points as usize,
        params.min_normal_cos(),
    )
}

/// Hands the allocator's free memory back to the operating system (glibc
/// keeps what the worker threads freed in their arenas): before the
/// adaptive passes, where a run's memory peaks, the label stage's freed
/// scratch would otherwise count in the peak.
fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        unsafe extern "C" {
            fn malloc_trim(pad: usize) -> std::ffi::c_int;
        }
        // SAFETY: glibc's `malloc_trim` only returns free memory to the
        // system; it takes the arenas' locks and may be called from any
        // thread at any time.
        unsafe {
            malloc_trim(0);
        }
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// What the smoothing stage gives the rest of the run.
struct Smoothed {
    positions: Vec<DVec3>,
    /// Labels as numbers (empty for the baselines).
    labels: Vec<u8>,
    /// The curvature at `positions`, when the stage measured it.
    curvature: Option<Curvatures>,
    /// Whether a warning already said the volume could not be restored.
    volume_warned: bool,
}

impl Smoothed {
    /// The result of a baseline smoother: positions alone.
    fn plain(positions: Vec<DVec3>) -> Self {
        Smoothed {
            positions,
            labels: Vec::new(),
            curvature: None,
            volume_warned: false,
        }
    }
}

/// Smooths `mesh` with `params` and measures the result. Never changes
/// connectivity: the output has one position per input vertex, in order.
///
/// Stages: analyse (topology, input measures), then for `wang-yu` initial
/// smoothing, labelling, adaptive smoothing with volume restoration and the
/// quality fixes; for the baselines the baseline smoother (and the quality
/// fixes). A voxel mesh written as triangles is smoothed as its voxel faces
/// ([`paired_voxel_faces`]) and measured on its triangles. A mesh whose
/// edges are far from unit length in its units is smoothed at unit edges
/// and scaled back exactly ([`UnitScale`]). The report's hashes are left
/// for the caller, who has the bytes.
pub fn run(
    mesh: &Mesh,
    params: &Params,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<SmoothOutput, SmoothError> {
    run_bodies(mesh, None, params, progress, cancel)
}

/// [`run`] on a mesh that holds bodies touching face to face, each welded
/// on its own ([`crate::io::FileBodies`]; `bodies`: one entry per vertex,
/// its body, or `None`): each body's solids and cavities get their volume
/// back on their own (`VolumeParts::new`) and its pinches read its
/// own faces only, so a body smooths as it would alone. Entries beyond a
/// mismatched length are ignored (then as `None`).
pub fn run_bodies(
    mesh: &Mesh,
    bodies: Option<&[u32]>,
    params: &Params,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<SmoothOutput, SmoothError> {
    // A mesh in units far from its edges' is smoothed at unit edges and
    // scaled back ([`UnitScale`]): the same bits as in any ordinary unit.
    let unit = UnitScale::of(mesh);
    let scaled = unit.map(|u| u.apply(mesh));
    let mesh = scaled.as_ref().unwrap_or(mesh);
    let mut out = run_inner(mesh, bodies, params, progress, cancel, Call::Whole)?;
    if let Some(u) = unit {
        out.rescale(u.inverse());
    }
    Ok(out)
}

/// What [`run_inner`] is called on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Call {
    /// A whole mesh: a multi-label complex ([`crate::mesh::regions`]) is
    /// smoothed region by region ([`regions::run`]).
    Whole,
    /// The regions of a complex, each on its own copies of its walls: the
    /// complex measures its own final curvature, so the run leaves out the
    /// fits that would measure the copies' (the per-vertex curvature it
    /// returns is then the smoothing stage's, or empty).
    Regions,
}

/// [`run_bodies`], on a whole mesh or on a complex's regions (`call`).
fn run_inner(
    mesh: &Mesh,
    bodies: Option<&[u32]>,
    params: &Params,
    progress: &dyn Progress,
    cancel: &AtomicBool,
    call: Call,
) -> Result<SmoothOutput, SmoothError> {
    params.validate()?;
    let bodies = bodies.filter(|b| b.len() == mesh.num_vertices());
    let start = Instant::now();
    let span = tracing::info_span!("smooth", vertices = mesh.num_vertices(), faces = mesh.num_faces(), method = ?params.method);
    let _enter = span.enter();
    let mut timings = Timings::default();
    progress.update(Stage::Analyse, 0.0);
    let (oriented, input_topo, input_masks, mut report) =
        timings.time(Stage::Analyse, || analyse(mesh, params))?;
    let mesh = oriented.as_ref().unwrap_or(mesh);
    if call == Call::Whole && bodies.is_none() && params.method == Method::WangYu {
        let split = timings.time(Stage::Analyse, || {
            regions(mesh, &input_topo).and_then(|r| regions::split(mesh, &r).map(|s| (r, s)))
        });
        if let Some((r, split)) = split {
            let context = regions::Context {
                timings,
                start,
                params,
                progress,
                cancel,
            };
            return regions::run(mesh, &input_topo, &r, split, report, context);
        }
    }
    // A voxel mesh written as triangles is smoothed as its voxel faces; the
    // measures stay on the file's triangles.
    let input_mesh = mesh;
    let paired = timings.time(Stage::Analyse, || {
        (params.method == Method::WangYu)
            .then(|| paired_voxel_faces(input_mesh, &input_topo))
            .flatten()
            .map(|PairedFaces { mesh, topo, pairs }| {
                let masks = vertex_masks(&topo, params.boundary);
                (mesh, topo, masks, pairs)
            })
    });
    let (mesh, topo, masks, paired_triangles) = match &paired {
        Some((mesh, topo, masks, pairs)) => (mesh, topo, masks, *pairs),
        None => (input_mesh, &input_topo, &input_masks, 0),
    };
    progress.update(Stage::Analyse, 1.0);
    check(cancel)?;
    // The bound, and off any grid the input's noise that narrows it.
    let (bound, input_noise) = timings.time(Stage::Analyse, || {
        let Some(d) = params
            .max_displacement
            .filter(|_| params.method == Method::WangYu)
        else {
            return (None, None);
        };
        let bound = FidelityBound::new(mesh, topo, d);
        let (bound, noise) = match params.noise_bound {
            Some(k) => bound.across_input_noise(mesh, topo, k, params.min_normal_cos()),
            None => (bound, None),
        };
        (Some(bound), noise)
    });
    let quality_bound = bound.as_ref().map(|b| b.widened(QUALITY_ROOM));
    let fidelity = Fidelity::new(bound.as_ref(), mesh.positions());
    let quality_fidelity = fidelity.with_bound(quality_bound.as_ref());
    // The bound found the lattice or the marching-cubes grid already;
    // without one, only the Wang-Yu stages ask.
    let lattice = match &bound {
        Some(b) => b.has_lattice(),
        None => params.method == Method::WangYu && is_voxel_lattice(topo, mesh.positions()),
    };
    let marching_cubes = match &bound {
        Some(b) => b.has_marching_cubes(),
        None => {
            params.method == Method::WangYu
                && !lattice
                && is_marching_cubes_lattice(topo, mesh.positions())
        }
    };
    let volume_parts = (params.method == Method::WangYu
        && params.preserve_volume
        && topo.num_boundary_edges() == 0)
        .then(|| {
            // The staircase treatment (relaxation, fairing, low-pass) leaves
            // the vertices on a smooth surface; the paper's passes alone
            // (`staircase_steps` 0) may leave a voxel's corners where they
            // were.
            if lattice && params.staircase_steps > 0 {
                VolumeParts::for_voxel_lattice(mesh, topo, bodies)
            } else {
                VolumeParts::new(mesh, topo, bodies)
            }
        });
    let away = lattice.then(|| away_from_pinches(topo, &masks.movable));
    let run = Run {
        mesh,
        topo,
        measured: (input_mesh, &input_topo),
        paired_triangles,
        movable: &masks.movable,
        relaxable: &masks.relaxable,
        fitted: away.as_deref().unwrap_or(&masks.movable),
        params,
        lattice,
        marching_cubes,
        fidelity: &fidelity,
        bound: bound.as_ref(),
        quality_bound: quality_bound.as_ref(),
        quality_fidelity: &quality_fidelity,
        volume_parts: volume_parts.as_ref(),
        bodies,
        progress,
        cancel,
    };
    let smoothed = match params.method {
        Method::WangYu => {
            let r = {
                let _s = tracing::info_span!("wang_yu").entered();
                wang_yu(&run, &mut timings)?
            };
            timings.time(Stage::Report, || report_wang_yu(&run, &mut report, r))
        }
        Method::Laplacian | Method::Taubin => {
            let positions = timings.time(Stage::Initial, || {
                let _s = tracing::info_span!("baseline").entered();
                baseline(mesh, topo, &masks.movable, params, cancel)
            })?;
            report.stages.initial = Some(measure_stage(
                input_mesh,
                &input_topo,
                &positions,
                mesh.positions(),
                None,
                params.quality.short_edge_fraction,
            ));
            Smoothed::plain(positions)
        }
    };
    let Smoothed {
        mut positions,
        labels,
        curvature,
        volume_warned,
    } = smoothed;
    // The smoothing stage's curvature is the final stage's when no quality
    // fix moves a vertex in between (a smooth surface often needs none).
    let mut unmoved_curvature = curvature;
    check(cancel)?;
    if params.quality.enabled {
        let moved = timings.time(Stage::Quality, || {
            quality_stage(&run, &mut positions, &mut report)
        });
        if moved {
            unmoved_curvature = None;
        }
    }
    check(cancel)?;
    if let Some(summary) = report.wang_yu.as_mut() {
        summary.fidelity_held_back = bound.as_ref().map(|_| fidelity.held_back());
        summary.input_noise = input_noise;
    }

    let curvature = timings.time(Stage::Report, || {
        let curvature = match (unmoved_curvature, call) {
            (Some(c), _) => Some(c),
            (None, Call::Whole) => Some(stage_curvature(mesh, topo, &positions, params)),
            (None, Call::Regions) => None,
        };
        report.stages.final_stage = Some(measure_stage(
            input_mesh,
            &input_topo,
            &positions,
            mesh.positions(),
            curvature.as_deref(),
            params.quality.short_edge_fraction,
        ));
        curvature.unwrap_or_default()
    });
    progress.update(Stage::Report, 1.0);
    final_warnings(params, &mut report, volume_warned);

    report.timings = timings.into_report();
    report.total_ms = ms(start);
    Ok(SmoothOutput {
        per_vertex: PerVertex::new(mesh.positions(), &positions, labels, &curvature),
        positions,
        report,
    })
}

impl PerVertex {
    /// The results at `positions` (from `input`).
    fn new(input: &[DVec3], positions: &[DVec3], label: Vec<u8>, curvature: &Curvatures) -> Self {
        PerVertex {
            label,
            mean_curvature: curvature.iter().map(|c| c.0).collect(),
            gaussian_curvature: curvature.iter().map(|c| c.1).collect(),
            displacement: positions
                .iter()
                .zip(input)
                .map(|(a, b)| a.distance(*b))
                .collect(),
        }
    }
}

/// The analyse stage: topology, the faces' winding made consistent
/// ([`oriented`]: the mesh with turned faces, when any turn), the vertices
/// each step may move, and a report with the mesh statistics and the
/// input's measures (of the turned faces).
fn analyse(
    mesh: &Mesh,
    params: &Params,
) -> Result<(Option<Mesh>, Topology, VertexMasks, QualityReport), ShapeError> {
    let topo = Topology::build(mesh);
    check_shape(mesh, &topo)?;
    let (oriented, orientation) = oriented(mesh, &topo);
    let mesh = oriented.as_ref().unwrap_or(mesh);
    let input = mesh.positions();
    // Wang-Yu's first initial pass fits the input's 2-rings anyway: the
    // input's curvature variation comes from those fits.
    let input_curvature =
        (params.method != Method::WangYu).then(|| stage_curvature(mesh, &topo, input, params));
    // The statistics' and the masks' union-finds are serial: they run
    // beside the measures.
    let ((statistics, masks), input_measures) = rayon::join(
        || {
            (
                mesh_statistics(mesh, &topo),
                vertex_masks(&topo, params.boundary),
            )
        },
        || {
            measure_stage(
                mesh,
                &topo,
                input,
                input,
                input_curvature.as_deref(),
                params.quality.short_edge_fraction,
            )
        },
    );
    let mut report = QualityReport::new(statistics, Reproducibility::new(params));
    report.stages.input = Some(input_measures);
    report_orientation(&orientation, &mut report);
    Ok((oriented, topo, masks, report))
}

/// `mesh` with its faces wound consistently and outward ([`orientation`]),
/// or `None` when it already is, and the turns. The topology does not
/// depend on the winding: `topo` is the turned mesh's too.
fn oriented(mesh: &Mesh, topo: &Topology) -> (Option<Mesh>, Orientation) {
    let _s = tracing::info_span!("orientation").entered();
    let orientation = orientation(mesh, topo);
    (orientation.apply(mesh), orientation)
}

/// The turns in the report's mesh statistics, and a warning for each kind.
fn report_orientation(orientation: &Orientation, report: &mut QualityReport) {
    report.mesh.reoriented_faces = orientation.turned_faces as u64;
    report.mesh.inside_out = orientation.inside_out;
    report.mesh.inside_out_bodies = orientation.inside_out_bodies as u64;
    report.mesh.inside_out_body_faces = orientation.inside_out_body_faces as u64;
    report.mesh.orientation_seams = orientation.seams as u64;
    if orientation.inside_out {
        report.warnings.push(
            "the mesh is wound inside out (its faces enclose a negative volume): it was smoothed \
             and measured with every face turned; the output keeps the file's winding"
                .to_string(),
        );
    }
    if orientation.inside_out_bodies > 0 {
        let (bodies, faces) = (
            orientation.inside_out_bodies,
            orientation.inside_out_body_faces,
        );
        let verb = if bodies == 1 { "is" } else { "are" };
        report.warnings.push(format!(
            "{bodies} of the mesh's closed parts ({faces} faces) {verb} wound inside out beside \
             parts wound outward: they were smoothed and measured turned; the output keeps the \
             file's winding"
        ));
    }
    let against = report.mesh.faces_wound_against();
    if against > 0 {
        report.warnings.push(format!(
            "the file winds {against} of its {} faces against their neighbours (an edge shared \
             by two faces should be passed in opposite directions): they were smoothed and \
             measured turned; the output keeps the file's winding",
            report.mesh.faces
        ));
    }
    if orientation.seams > 0 {
        report.warnings.push(format!(
            "faces that no turn can make agree meet at {} edges (the surface cannot be \
             oriented, like a Moebius strip): the fits' normals and the inverted-face counts \
             there are unreliable",
            orientation.seams
        ));
    }
}

/// Puts the Wang-Yu stages' results in `report` (the input's curvature
/// variation, the initial and adaptive stages, the summary, a warning
/// when the volume could not be restored).
fn report_wang_yu(run: &Run, report: &mut QualityReport, r: WangYuRun) -> Smoothed {
    if let Some(stage) = report.stages.input.as_mut() {
        stage.curvature_variation = Some(CurvatureVariation::new(
            r.input_curvature_variation,
            stage.mean_edge_length,
        ));
    }
    report.stages.initial = Some(r.initial);
    report.stages.adaptive = Some(measure_stage(
        run.measured.0,
        run.measured.1,
        &r.adaptive,
        run.mesh.positions(),
        Some(&r.curvature),
        run.params.quality.short_edge_fraction,
    ));
    report.wang_yu = Some(WangYuSummary {
        labels: LabelCounts::from_labels(&r.labels),
        ring_size_histogram: ring_size_histogram(&r.ring),
        initial_fits: r.initial_fits.into(),
        adaptive_fits: r.adaptive_fits.into(),
        volume_offset: r.volume.mean_offset,
        volume_target_change: r.volume.aimed,
        fidelity_held_back: None,
        input_noise: None,
        paired_triangles: run.paired_triangles as u64,
        input_grid: if run.lattice {
            InputGrid::Voxel
        } else if run.marching_cubes {
            InputGrid::MarchingCubes
        } else {
            InputGrid::None
        },
    });
    if let Some(change) = r.volume_not_restored {
        report.warnings.push(format!(
            "the enclosed volume changed by {:+.2}% and could not be restored: a \
             uniform offset of at most half an edge length (one for the solids, one for the cavities) does not bring it back (the mesh may be \
             too coarse or too thin for quadric fitting, or the volume restoration \
             cannot undo a collapse)",
            100.0 * change
        ));
    }
    let collapsed = r.volume.collapsed;
    let collapse_warned = collapsed.abs() > VOLUME_WARNING;
    if collapse_warned {
        report.warnings.push(format!(
            "{:+.2}% of the enclosed volume could not be restored: it went with parts \
             that collapsed (fragments or holes a voxel or two across, thinner than the \
             smoothing's reach, whose loss no offset of half an edge gives back), which \
             are left as smoothed",
            100.0 * collapsed
        ));
    }
    Smoothed {
        positions: r.adaptive,
        labels: r.labels.iter().map(|&l| l as u8).collect(),
        curvature: Some(r.curvature),
        volume_warned: r.volume_not_restored.is_some() || collapse_warned,
    }
}

/// The quality fixes (paper section 2.4) on `positions`, then, after a
/// Wang-Yu run that restored the volume and when a fix moved a vertex, a
/// second small restoration kept only if it folds or twists no face and
/// closes no face the fixes left sound below the sharp-angle threshold;
/// where no such restoration is found, one that closes no face below the
/// sliver floor instead (the volume is a promise, an angle between the
/// floor and the threshold is not a defect). Whether any vertex moved.
fn quality_stage(run: &Run, positions: &mut [DVec3], report: &mut QualityReport) -> bool {
    let Run {
        mesh, topo, params, ..
    } = *run;
    let input = mesh.positions();
    let _s = tracing::info_span!("quality").entered();
    run.progress.update(Stage::Quality, 0.0);
    let before = positions.to_vec();
    report.quality_fixes = Some(improve(
        mesh,
        topo,
        positions,
        input,
        run.quality_bound,
        &params.quality,
        params.min_normal_cos(),
    ));
    // The fixes slide vertices over their fitted quadrics, which shifts
    // the volume a little; when they moved none there is nothing to give
    // back.
    let fixed = positions != &before[..];
    if fixed
        && let Some(summary) = report.wang_yu.as_mut()
        && let Some(parts) = run.volume_parts
        && summary.volume_offset != 0.0
    {
        let threshold = params.quality.sharp_angle_deg;
        summary.volume_offset += restore_after_fixes(
            mesh,
            topo,
            parts,
            positions,
            run.movable,
            run.quality_bound,
            Floors {
                keep_deg: threshold,
                sliver_deg: SLIVER_FRACTION * threshold,
            },
        );
    }
    run.quality_fidelity.apply(positions);
    run.progress.update(Stage::Quality, 1.0);
    fixed || positions != &before[..]
}

/// The volume restoration after the quality fixes ([`restore_where_safe`]):
/// holding the faces at or above `floors.keep_deg` there, or, where no
/// such offset is found, at the sliver floor alone (`floors.sliver_deg`
/// kept too). The mean offset applied, 0 when neither was found.
fn restore_after_fixes(
    mesh: &Mesh,
    topo: &Topology,
    parts: &VolumeParts,
    positions: &mut [DVec3],
    movable: &[bool],
    quality_bound: Option<&FidelityBound>,
    floors: Floors,
) -> f64 {
    let restore = |positions: &mut [DVec3], floors| {
        restore_where_safe(mesh, topo, parts, positions, movable, quality_bound, floors)
    };
    let offset = restore(positions, floors);
    if offset != 0.0 {
        return offset;
    }
    let sliver = Floors {
        keep_deg: floors.sliver_deg,
        ..floors
    };
    restore(positions, sliver)
}

/// Rounds of the volume restoration after the quality fixes
/// ([`restore_where_safe`]): each round leaves out the vertices the
/// previous round's offset could not move; a few rounds reach the faces
/// around the first ones left out. Held at the sharp-angle threshold, the
/// offset meets a face the fixes opened just to the threshold wherever the
/// surface turns, and the rounds must reach further: with eight, the real
/// meshes measured find such an offset where four fell back to the sliver
/// floor (`docs/tuning.md`, "The last restoration keeps what the
/// sharp-angle fix opened").
const REOFFSET_ROUNDS: usize = 8;

/// The angles the last volume restoration keeps ([`restore_where_safe`]),
/// in degrees: a face at or above `keep_deg` stays at or above it, a face
/// sharper than that no sharper than `sliver_deg` (the sliver floor, at
/// most `keep_deg`) or than [`closing_floor_cos`] holds it.
#[derive(Debug, Clone, Copy)]
struct Floors {
    keep_deg: f64,
    sliver_deg: f64,
}

/// Restores each part's input volume after the quality fixes by an offset
/// of at most [`MAX_VOLUME_REOFFSET`] of the mean edge length, over the
/// movable vertices whose move folds or twists no face that was sound,
/// closes no face at or above `floors.keep_deg` below it, nor a face
/// already sharper below the sliver floor or, sharper still, below where
/// the sharp-angle fix would hold it ([`closing_floor_cos`]:
/// what the sliver fix opened stays open, and a needle of the input that
/// the fixes held at half its angle closes no more), and keeps them
/// within the quality bound: a round that would fold or close a face
/// or leave the bound leaves that face's corners (or that vertex) where
/// they are and solves again, up to [`REOFFSET_ROUNDS`] rounds. The mean
/// offset applied, 0 when no round succeeded (the positions are then
/// unchanged). A thin neurite's few near-degenerate faces would otherwise
/// keep the whole surface from its volume.
fn restore_where_safe(
    mesh: &Mesh,
    topo: &Topology,
    parts: &VolumeParts,
    positions: &mut [DVec3],
    movable: &[bool],
    quality_bound: Option<&FidelityBound>,
    floors: Floors,
) -> f64 {
    let input = mesh.positions();
    let cos_keep = floors.keep_deg.to_radians().cos();
    let cos_sliver = floors.sliver_deg.to_radians().cos();
    let sound: Vec<bool> = (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .map(|f| !is_defective(mesh, f, positions, input))
        .collect();
    // Per face, the cosine of the smallest angle the offset may leave it.
    let floor: Vec<f64> = (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .map(|f| closing_floor_cos(mesh, f, positions, input, cos_keep, cos_sliver))
        .collect();
    let max_offset = MAX_VOLUME_REOFFSET * mean_edge_length(mesh, positions);
    let mut movable = movable.to_vec();
    let mut trial = positions.to_vec();
    for _ in 0..REOFFSET_ROUNDS {
        trial.copy_from_slice(positions);
        let offset = restore_volume(mesh, topo, parts, &mut trial, &movable, max_offset, |_| {
            true
        })
        .mean_offset;
        if offset == 0.0 {
            return 0.0;
        }
        let folded: Vec<usize> = (0..mesh.num_faces())
            .into_par_iter()
            .with_min_len(4096)
            .filter(|&f| {
                (sound[f] && is_defective(mesh, f, &trial, input))
                    || has_sliver_angle(mesh, f, &trial, floor[f])
            })
            .collect();
        let outside: Vec<usize> = match quality_bound {
            Some(b) => (0..trial.len())
                .into_par_iter()
                .with_min_len(4096)
                .filter(|&v| !b.allows(v, input[v], trial[v]))
                .collect(),
            None => Vec::new(),
        };
        if folded.is_empty() && outside.is_empty() {
            positions.copy_from_slice(&trial);
            return offset;
        }
        for f in folded {
            for &c in mesh.face(f) {
                movable[c as usize] = false;
            }
        }
        for v in outside {
            movable[v] = false;
        }
    }
    0.0
}

/// Warnings on the final stage: a volume that ends far from the input's
/// (unless a warning already said so), and inverted faces.
fn final_warnings(params: &Params, report: &mut QualityReport, volume_warned: bool) {
    let Some(last) = report.stages.final_stage.as_ref() else {
        return;
    };
    let change = last.volume.and_then(|v| v.relative_change);
    let inverted = last.inverted_faces;
    let aimed = report
        .wang_yu
        .as_ref()
        .map_or(0.0, |w| w.volume_target_change);
    if let Some(change) = change
        && params.method == Method::WangYu
        && params.preserve_volume
        && (change - aimed).abs() > VOLUME_WARNING
        && !volume_warned
    {
        report.warnings.push(format!(
            "the enclosed volume ends {:+.2}% from the input's (the restoration aimed at \
             {:+.2}%): restoring it after the quality fixes would have folded faces or needed \
             an offset of more than a tenth of an edge",
            100.0 * change,
            100.0 * aimed
        ));
    }
    if inverted > 0 {
        report.warnings.push(format!(
            "{inverted} faces are inverted relative to the input: the surface folded there \
             (typically at thin, pinched or non-manifold parts); look at those regions, or \
             smooth less (fewer passes, a smaller k_max)"
        ));
    }
}

/// Measures a mesh without smoothing it: the report's `input` stage (with
/// curvature from 2-ring fits) and the mesh statistics.
/// A mesh [`check_shape`] refuses is measured without the curvature (whose
/// fits would cost the square of its largest valence or face), and the
/// report's warnings say why.
pub fn measure(mesh: &Mesh, params: &Params) -> QualityReport {
    // Measured at unit edges when the units are extreme, as [`run_bodies`]
    // smooths.
    let unit = UnitScale::of(mesh);
    let scaled = unit.map(|u| u.apply(mesh));
    let mut report = measure_in_units(scaled.as_ref().unwrap_or(mesh), params);
    if let Some(u) = unit {
        report.rescale(u.inverse());
    }
    report
}

/// [`measure`] in the mesh's own units.
fn measure_in_units(mesh: &Mesh, params: &Params) -> QualityReport {
    let topo = Topology::build(mesh);
    let shape = check_shape(mesh, &topo);
    let (oriented, orientation) = oriented(mesh, &topo);
    let mesh = oriented.as_ref().unwrap_or(mesh);
    let curvature = shape
        .is_ok()
        .then(|| stage_curvature(mesh, &topo, mesh.positions(), params));
    let mut report = QualityReport::new(mesh_statistics(mesh, &topo), Reproducibility::new(params));
    report.stages.input = Some(measure_stage(
        mesh,
        &topo,
        mesh.positions(),
        mesh.positions(),
        curvature.as_deref(),
        params.quality.short_edge_fraction,
    ));
    report_orientation(&orientation, &mut report);
    if let Some(r) = regions(mesh, &topo) {
        report.mesh.regions = r.count as u64;
        report.mesh.region_walls = r.walls as u64;
        if let Some(v) = report.stages.input.as_mut().and_then(|s| s.volume.as_mut()) {
            v.volume = r.volume(mesh, mesh.positions());
        }
    }
    if let Err(e) = shape {
        report.warnings.push(format!(
            "no curvature measured and no smoothing possible: {e}"
        ));
    }
    report
}

/// Runs the baseline smoother `params.method` (Laplacian or Taubin).
fn baseline(
    mesh: &Mesh,
    topo: &Topology,
    movable: &[bool],
    params: &Params,
    cancel: &AtomicBool,
) -> Result<Vec<DVec3>, Cancelled> {
    let b = &params.baseline;
    match params.method {
        Method::Taubin => taubin_smooth(
            topo,
            movable,
            mesh.positions(),
            b.iterations,
            b.lambda,
            b.mu,
            cancel,
        ),
        _ => laplacian_smooth(
            topo,
            movable,
            mesh.positions(),
            b.iterations,
            b.lambda,
            cancel,
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::signed_volume;
    use crate::shapes::{self, VoxelMask, voxel_boundary_mesh};

    /// The pipeline at its default parameters.
    fn run_defaults(mesh: &Mesh) -> SmoothOutput {
        run(
            mesh,
            &Params::default(),
            &crate::NoProgress,
            &AtomicBool::new(false),
        )
        .expect("run")
    }

    /// `mesh` with the corners of the faces `turn` picks in reverse order.
    fn turned(mesh: &Mesh, turn: impl Fn(usize) -> bool) -> Mesh {
        let faces: Vec<Vec<u32>> = mesh
            .faces()
            .enumerate()
            .map(|(f, c)| {
                let mut c = c.to_vec();
                if turn(f) {
                    c.reverse();
                }
                c
            })
            .collect();
        Mesh::from_polygons(mesh.positions().to_vec(), &faces).unwrap()
    }

    #[test]
    fn a_mesh_wound_inside_out_or_against_itself_smooths_as_wound_outward() {
        for (_, mesh) in [shapes::voxel_sphere(5.0), shapes::mc_sphere(5.0)] {
            let outward = run_defaults(&mesh);
            assert_eq!(outward.report.mesh.reoriented_faces, 0);
            assert!(outward.report.warnings.is_empty());
            // Every face, a seventh of them, all but that seventh.
            for (turn, inside_out) in [
                (&(|_| true) as &dyn Fn(usize) -> bool, true),
                (&|f| f % 7 == 3, false),
                (&|f| f % 7 != 3, true),
            ] {
                let out = run_defaults(&turned(&mesh, turn));
                assert_eq!(out.positions, outward.positions);
                let count = (0..mesh.num_faces()).filter(|&f| turn(f)).count() as u64;
                assert_eq!(
                    (out.report.mesh.reoriented_faces, out.report.mesh.inside_out),
                    (count, inside_out)
                );
                assert_eq!(out.report.stages, outward.report.stages);
                assert!(!out.report.warnings.is_empty());
            }
        }
    }

    #[test]
    fn a_body_wound_inside_out_beside_an_outward_one_smooths_as_wound_outward() {
        // Two marching-cubes spheres apart in one file, the second wound
        // inside out: the whole encloses no volume to speak of, and only
        // that body turns.
        let (_, sphere) = shapes::mc_sphere(5.0);
        let n = sphere.num_vertices() as u32;
        let two = |inward: bool| {
            let mut p = sphere.positions().to_vec();
            p.extend(
                sphere
                    .positions()
                    .iter()
                    .map(|&q| q + DVec3::new(20.0, 0.0, 0.0)),
            );
            let mut polygons: Vec<Vec<u32>> = sphere.faces().map(<[u32]>::to_vec).collect();
            polygons.extend(sphere.faces().map(|f| {
                let mut c: Vec<u32> = f.iter().map(|&v| v + n).collect();
                if inward {
                    c.reverse();
                }
                c
            }));
            Mesh::from_polygons(p, &polygons).unwrap()
        };
        let outward = run_defaults(&two(false));
        let out = run_defaults(&two(true));
        assert_eq!(out.positions, outward.positions);
        assert_eq!(out.report.stages, outward.report.stages);
        let m = &out.report.mesh;
        let body = sphere.num_faces() as u64;
        assert_eq!(
            (m.inside_out, m.inside_out_bodies, m.inside_out_body_faces),
            (false, 1, body)
        );
        assert_eq!((m.reoriented_faces, m.faces_wound_against()), (body, 0));
        assert_eq!(out.report.warnings.len(), 1, "{:?}", out.report.warnings);
    }

    #[test]
    fn the_adaptive_passes_leave_the_vertices_beside_a_pinch() {
        let mesh = shapes::edge_touching_blocks();
        let topo = Topology::build(&mesh);
        let movable = movable_mask(&topo, BoundaryRule::Fixed);
        let kept = away_from_pinches(&topo, &movable);
        let mut beside = 0;
        for v in 0..topo.num_vertices() {
            let near = topo
                .neighbors(v)
                .iter()
                .any(|&j| topo.kind(j as usize) == VertexKind::NonManifold);
            beside += usize::from(near && movable[v]);
            assert_eq!(kept[v], movable[v] && !near, "vertex {v}");
        }
        assert!(beside > 0);
    }

    #[test]
    fn the_ends_of_a_line_of_touching_voxels_retreat_into_it() {
        // Two blocks of different widths touching along an edge five
        // voxels long: the line's two ends retreat into it, toward the
        // one-half level of their blurred voxels (two of eight inside), as
        // far as the fairing's room, and end there; the relaxation alone
        // leaves them short of it.
        let mask = VoxelMask::from_fn(glam::IVec3::ZERO, [11, 12, 7], |i, j, k| {
            (1..6).contains(&k)
                && ((1..6).contains(&i) && (1..6).contains(&j)
                    || (6..9).contains(&i) && (6..10).contains(&j))
        });
        let mesh = voxel_boundary_mesh(&mask);
        let topo = Topology::build(&mesh);
        let out = run_defaults(&mesh);
        let line: Vec<usize> = (0..topo.num_vertices())
            .filter(|&v| topo.kind(v) == VertexKind::NonManifold)
            .collect();
        assert_eq!(line.len(), 6);
        let (low, high) = (1.0, 6.0);
        let retreat = 0.5 * FAIRING_ROOM;
        for &v in &line {
            let (p, q) = (mesh.positions()[v], out.positions[v]);
            if p.z == low || p.z == high {
                let inward = if p.z == low { retreat } else { -retreat };
                assert!(
                    q.abs_diff_eq(p + DVec3::Z * inward, 1e-6),
                    "end {v}: {p} -> {q}"
                );
            } else {
                assert!(q.z != p.z || q.x != p.x, "corner {v} did not relax: {q}");
            }
        }
    }

    #[test]
    fn a_marching_cubes_mesh_of_deep_voxels_keeps_half_its_needles_angles() {
        // A folded sheet three voxels thick on a seeded placement, meshed
        // by marching cubes on voxels six times as deep as wide (a clinical
        // axial series): the faces across the slices are needles of 6.7
        // degrees, under the sliver floor already in the input. Without a
        // floor of their own the sharp-angle fix closed them to 0.9 degrees
        // while it opened the faces around them.
        let mask = shapes::voxel_mask(&shapes::placed(shapes::folded_sheet(3.0), 1));
        let mut mesh = shapes::marching_cubes_mesh(&mask);
        for p in mesh.positions_mut() {
            p.z *= 6.0;
        }
        let out = run_defaults(&mesh);
        let min_angle = |p: &[DVec3]| crate::quality::fixtures::min_split_angle(&mesh, p, None);
        let (before, after) = (min_angle(mesh.positions()), min_angle(&out.positions));
        assert!(before < 10.0, "the input has needles: {before}");
        assert!(
            after >= 0.45 * before,
            "smallest angle {after} degrees from {before}"
        );
        let last = out
            .report
            .stages
            .final_stage
            .as_ref()
            .expect("final measures");
        assert_eq!(last.inverted_faces, 0);
    }

    #[test]
    fn the_output_curvature_is_that_of_the_output_positions() {
        // The smoothing stage's curvature is reused when the quality fixes
        // move nothing (then nor does the volume's re-restoration); either
        // way the per-vertex curvature is the output's own.
        let (_, sphere) = shapes::voxel_sphere(10.0);
        let (_, ellipsoid) = shapes::mc_ellipsoid(12.0, 8.0, 5.0);
        let params = Params::default();
        let mut reused = 0;
        for mesh in [sphere, ellipsoid, shapes::edge_touching_blocks()] {
            let out =
                run(&mesh, &params, &crate::NoProgress, &AtomicBool::new(false)).expect("run");
            let topo = Topology::build(&mesh);
            let fresh = stage_curvature(&mesh, &topo, &out.positions, &params);
            let h: Vec<f64> = fresh.iter().map(|c| c.0).collect();
            let k: Vec<f64> = fresh.iter().map(|c| c.1).collect();
            assert_eq!(out.per_vertex.mean_curvature, h);
            assert_eq!(out.per_vertex.gaussian_curvature, k);
            let fixes = out.report.quality_fixes.expect("the fixes ran");
            reused += usize::from(
                fixes.sharp_angles.moves == 0
                    && fixes.short_edges.lengthened == 0
                    && fixes.twisted.found == 0
                    && fixes.inverted.found == 0
                    && fixes.slivers.found == 0,
            );
        }
        assert!(
            reused > 0 && reused < 3,
            "both cases: {reused} of 3 unmoved"
        );
    }

    /// A cube of 4 x 4 x 4 voxels, its topology, movable vertices and
    /// volume parts, and its positions shrunk by 3% about its centre: the
    /// restorations' fixture.
    struct ShrunkCube {
        mesh: Mesh,
        topo: Topology,
        movable: Vec<bool>,
        parts: VolumeParts,
        shrunk: Vec<DVec3>,
    }

    impl ShrunkCube {
        fn new() -> Self {
            let mask = VoxelMask::from_fn(glam::IVec3::ZERO, [6, 6, 6], |i, j, k| {
                (1..5).contains(&i) && (1..5).contains(&j) && (1..5).contains(&k)
            });
            let mesh = voxel_boundary_mesh(&mask);
            let topo = Topology::build(&mesh);
            let movable = movable_mask(&topo, BoundaryRule::Fixed);
            let parts = VolumeParts::new(&mesh, &topo, None);
            let centre = DVec3::splat(3.0);
            let shrunk = mesh
                .positions()
                .iter()
                .map(|&p| centre + 0.97 * (p - centre))
                .collect();
            ShrunkCube {
                mesh,
                topo,
                movable,
                parts,
                shrunk,
            }
        }

        /// [`restore_where_safe`] from `start`: the positions and the offset.
        fn restored_from(
            &self,
            start: &[DVec3],
            bound: Option<&FidelityBound>,
            floors: Floors,
        ) -> (Vec<DVec3>, f64) {
            let mut p = start.to_vec();
            let offset = restore_where_safe(
                &self.mesh,
                &self.topo,
                &self.parts,
                &mut p,
                &self.movable,
                bound,
                floors,
            );
            (p, offset)
        }

        /// The same from the shrunk positions, with no bound.
        fn restored(&self, floors: Floors) -> (Vec<DVec3>, f64) {
            self.restored_from(&self.shrunk, None, floors)
        }

        /// Faces with a split-triangle angle whose cosine is above `cos`.
        fn sharper_than(&self, p: &[DVec3], cos: f64) -> usize {
            (0..self.mesh.num_faces())
                .filter(|&f| has_sliver_angle(&self.mesh, f, p, cos))
                .count()
        }

        fn volume_restored(&self, p: &[DVec3]) -> bool {
            let target = self.mesh.signed_volume();
            (signed_volume(&self.mesh, p) - target).abs() < 1e-6 * target
        }
    }

    /// The same angle kept and as the sliver floor.
    fn at(deg: f64) -> Floors {
        Floors {
            keep_deg: deg,
            sliver_deg: deg,
        }
    }

    #[test]
    fn the_last_restoration_keeps_faces_at_the_threshold_above_a_lower_sliver_floor() {
        // As below, with the sliver floor at 0: a face at or above the
        // angle kept stays there all the same.
        let cube = ShrunkCube::new();
        let keep = 44.9f64.to_radians().cos();
        let (unguarded, _) = cube.restored(at(0.0));
        assert!(
            cube.sharper_than(&unguarded, keep) > 0,
            "the fixture closes faces"
        );
        let (p, _) = cube.restored(Floors {
            keep_deg: 44.9,
            sliver_deg: 0.0,
        });
        assert_eq!(cube.sharper_than(&p, keep), 0);
    }

    #[test]
    fn the_restoration_after_the_fixes_falls_back_to_the_sliver_floor() {
        // Held just under the cube's 45 degree corners no offset restores
        // the volume (the fixture above closes some wherever it turns);
        // held at a sliver floor of 10 one does.
        let cube = ShrunkCube::new();
        assert_eq!(cube.restored(at(44.9)).1, 0.0);
        let mut p = cube.shrunk.clone();
        let floors = Floors {
            keep_deg: 44.9,
            sliver_deg: 10.0,
        };
        let offset = restore_after_fixes(
            &cube.mesh,
            &cube.topo,
            &cube.parts,
            &mut p,
            &cube.movable,
            None,
            floors,
        );
        assert!(offset > 0.0);
        assert!(cube.volume_restored(&p));
        assert_eq!(cube.sharper_than(&p, 10f64.to_radians().cos()), 0);
    }

    #[test]
    fn the_last_restoration_closes_no_face_below_the_sliver_floor() {
        // The square faces' split triangles have 45 degree corners, and
        // offsetting the vertices along their normals (diagonal at the
        // cube's edges and corners) skews the faces there, closing some of
        // those corners below a floor just under 45.
        let cube = ShrunkCube::new();
        let floor: f64 = 44.9;
        let cos = floor.to_radians().cos();
        assert_eq!(cube.sharper_than(&cube.shrunk, cos), 0);
        let (unguarded, _) = cube.restored(at(0.0));
        assert!(
            cube.sharper_than(&unguarded, cos) > 0,
            "the fixture closes faces"
        );
        let (p, _) = cube.restored(at(floor));
        assert_eq!(cube.sharper_than(&p, cos), 0);
    }

    #[test]
    fn the_last_restoration_closes_a_sliver_of_the_input_no_further_than_the_fixes() {
        // Under a floor of 46 degrees every face of the cube is a sliver of
        // the input (45 degree corners), as a marching-cubes needle is
        // under the sliver floor: the offset may close them only as far as
        // the sharp-angle fix would, to twice their angle less the floor
        // (44 degrees).
        let cube = ShrunkCube::new();
        let held = 44.0f64.to_radians().cos() + 1e-12;
        let (unguarded, _) = cube.restored(at(0.0));
        assert!(
            cube.sharper_than(&unguarded, held) > 0,
            "the fixture closes faces"
        );
        let (p, _) = cube.restored(at(46.0));
        assert_eq!(cube.sharper_than(&p, held), 0);
    }

    #[test]
    fn the_last_restoration_holds_back_what_it_cannot_move() {
        let cube = ShrunkCube::new();
        let (mesh, topo) = (&cube.mesh, &cube.topo);
        let input = mesh.positions();

        // Free to move: the volume comes back.
        let (p, offset) = cube.restored(at(10.0));
        assert!(offset > 0.0);
        assert!(cube.volume_restored(&p));

        // A corner already at the outer edge of its bound (a tenth of an
        // edge) stays; the others make up for it.
        let bound = FidelityBound::new(mesh, topo, 0.1);
        let corner = (0..input.len())
            .find(|&v| input[v] == DVec3::splat(1.0))
            .unwrap();
        let mut start = cube.shrunk.clone();
        start[corner] = input[corner] - DVec3::splat(0.0999);
        let (p, offset) = cube.restored_from(&start, Some(&bound), at(10.0));
        assert!(offset > 0.0);
        assert_eq!(p[corner], start[corner]);
        assert!(cube.volume_restored(&p));
        assert!((0..p.len()).all(|v| bound.allows(v, input[v], p[v])));

        // Every vertex beyond its bound: nothing moves.
        let bound = FidelityBound::new(mesh, topo, 0.01);
        let (p, offset) = cube.restored_from(&cube.shrunk, Some(&bound), at(10.0));
        assert_eq!(offset, 0.0);
        assert_eq!(p, cube.shrunk);
    }

    /// Asserts that every number of the report `b` is the same entry of
    /// `a` times `2^(k e)` for a whole `k` in `-3..=3` (a count, a length,
    /// an area, a volume or a curvature), bit for bit, and that every other
    /// entry is equal; wall times are left out.
    fn assert_rescaled(a: &serde_json::Value, b: &serde_json::Value, e: i32, at: &str) {
        use serde_json::Value;
        match (a, b) {
            (Value::Object(a), Value::Object(b)) => {
                assert_eq!(a.len(), b.len(), "{at}");
                for (key, x) in a {
                    if key == "timings" || key == "total_ms" {
                        continue;
                    }
                    let y = b.get(key).unwrap_or(&Value::Null);
                    assert_rescaled(x, y, e, &format!("{at}.{key}"));
                }
            }
            (Value::Array(a), Value::Array(b)) => {
                assert_eq!(a.len(), b.len(), "{at}");
                for (i, (x, y)) in a.iter().zip(b).enumerate() {
                    assert_rescaled(x, y, e, &format!("{at}[{i}]"));
                }
            }
            (Value::Number(x), Value::Number(y)) => {
                let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
                let step = 2f64.powi(e);
                let scaled = |k: i32| {
                    let mut v = x;
                    for _ in 0..k.abs() {
                        v = if k > 0 { v * step } else { v / step };
                    }
                    v
                };
                assert!(
                    (-3..=3).any(|k| scaled(k) == y),
                    "{at}: {y:e} is not {x:e} times a power of 2^{e}"
                );
            }
            _ => assert_eq!(a, b, "{at}"),
        }
    }

    #[test]
    fn a_mesh_in_extreme_units_smooths_as_in_ordinary_ones() {
        // At 2^3 the meshes are smoothed in their own units; at 2^303 and
        // 2^-297 (volumes stay finite) at unit edges, 2^3 from the reference, so a
        // length the rescaling left out would differ from the reference by
        // a power of 2^3, not of 2^300.
        let scaled = |mesh: &Mesh, e: i32| {
            let mut m = mesh.clone();
            for p in m.positions_mut() {
                *p *= 2f64.powi(e);
            }
            m
        };
        let (_, sphere) = shapes::voxel_sphere(5.0);
        let walled = crate::mesh::test_walled_sphere(4.0, DVec3::ZERO);
        for (name, mesh) in [("sphere", sphere), ("walled", walled)] {
            let reference = scaled(&mesh, 3);
            assert_eq!(UnitScale::of(&reference), None);
            let a = run_defaults(&reference);
            let a_measured = measure(&reference, &Params::default());
            for e in [300, -300] {
                let extreme = scaled(&mesh, 3 + e);
                assert!(UnitScale::of(&extreme).is_some());
                let b = run_defaults(&extreme);
                let s = 2f64.powi(e);
                for (p, q) in a.positions.iter().zip(&b.positions) {
                    assert_eq!(*p * s, *q, "{name} at 2^{e}");
                }
                let (va, vb) = (&a.per_vertex, &b.per_vertex);
                assert_eq!(va.label, vb.label);
                for (x, y) in va.mean_curvature.iter().zip(&vb.mean_curvature) {
                    assert_eq!(x / s, *y, "{name} at 2^{e}");
                }
                for (x, y) in va.gaussian_curvature.iter().zip(&vb.gaussian_curvature) {
                    assert_eq!(x / s / s, *y, "{name} at 2^{e}");
                }
                for (x, y) in va.displacement.iter().zip(&vb.displacement) {
                    assert_eq!(x * s, *y, "{name} at 2^{e}");
                }
                let json = |r: &QualityReport| serde_json::to_value(r).unwrap();
                let at = format!("{name} at 2^{e}");
                assert_rescaled(&json(&a.report), &json(&b.report), e, &at);
                let b_measured = measure(&extreme, &Params::default());
                assert_rescaled(&json(&a_measured), &json(&b_measured), e, &at);
            }
        }
    }
}
