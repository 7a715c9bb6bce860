//! `run(mesh, &params, &progress, &cancel)`: the whole smoothing pipeline,
//! one entry point shared by the CLI and the service.

use crate::control::{Cancelled, Progress, Stage, check};
use crate::error::ErrorCode;
use crate::fit::normals::vertex_normals_f32_by_faces;
use crate::fit::quadric_fit::FitModel;
use crate::mesh::{Mesh, Topology, VertexKind, mean_edge_length, signed_volume};
use crate::params::{AdaptiveFit, BoundaryRule, Method, ParamError, Params};
use crate::quality::{defect_count, improve};
use crate::report::{CurvatureVariation, QualityReport, StageMeasures};
use crate::report::{
    LabelCounts, Reproducibility, StageTiming, WangYuSummary, ring_size_histogram,
};
use crate::report::{mean_curvature_variation, measure_stage, mesh_statistics};
use crate::smoothing::adaptive::{
    AdaptiveNeighbourhoods, EarlyStop, FLAT_MOMENTUM, FLAT_RING, GrowthRule, REFIT_TOLERANCE,
    adaptive_neighbourhoods, agreement_masks, flat_passes, is_refit_pass, smooth_passes,
};
use crate::smoothing::curvature::{Curvatures, vertex_curvatures};
use crate::smoothing::initial::initial_passes;
use crate::smoothing::label::{Label, label};
use crate::smoothing::neighbourhood::release_walk_scratch;
use crate::smoothing::project::FitStats;
use crate::smoothing::volume::restore_volume;
use crate::smoothing::{laplacian::laplacian_smooth, taubin::taubin_smooth};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use thiserror::Error;

/// Why a run did not produce a result.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SmoothError {
    /// A parameter is out of range.
    #[error(transparent)]
    Params(#[from] ParamError),
    /// The cancellation flag was raised.
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
}

impl SmoothError {
    /// Stable code.
    pub fn code(&self) -> ErrorCode {
        match self {
            SmoothError::Params(e) => e.code(),
            SmoothError::Cancelled(_) => ErrorCode::Cancelled,
        }
    }
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

/// Which vertices may move: not isolated, not non-manifold, and not on the
/// boundary unless the boundary rule lets them move along their normal.
pub fn movable_mask(topo: &Topology, boundary: BoundaryRule) -> Vec<bool> {
    topo.kinds()
        .iter()
        .map(|k| match k {
            VertexKind::Interior => true,
            VertexKind::Boundary => boundary == BoundaryRule::NormalOnly,
            VertexKind::NonManifold | VertexKind::Isolated => false,
        })
        .collect()
}

/// Intermediate results of the Wang-Yu stages.
#[derive(Debug, Clone)]
pub struct WangYuRun {
    /// The input's mean curvature variation
    /// ([`mean_curvature_variation`]), from the 2-ring quadric fits of the
    /// first initial pass (the estimator of [`WangYuRun::curvature`]).
    pub input_curvature_variation: f64,
    /// Measures after initial smoothing.
    pub initial: StageMeasures,
    /// Positions after adaptive smoothing (and volume restoration).
    pub adaptive: Vec<DVec3>,
    /// `(H, K)` per vertex of `adaptive`, from 2-ring quadric fits.
    pub curvature: Curvatures,
    /// Label per vertex (from the curvature after initial smoothing).
    pub labels: Vec<Label>,
    /// Final ring size per vertex.
    pub ring: Vec<u8>,
    /// Fit statistics of the initial passes.
    pub initial_fits: FitStats,
    /// Fit statistics of the adaptive passes.
    pub adaptive_fits: FitStats,
    /// Offset along the normals applied to restore the volume (0 if none).
    pub volume_offset: f64,
    /// Relative volume change left when restoring the volume was asked for
    /// but refused (the offset needed was too large or did not converge).
    pub volume_not_restored: Option<f64>,
    /// Milliseconds per stage.
    pub timings_ms: Vec<(Stage, f64)>,
}

/// Initial smoothing, labelling and adaptive smoothing with volume
/// restoration (paper sections 2.2-2.3), without the quality fixes.
pub fn wang_yu(
    mesh: &Mesh,
    topo: &Topology,
    movable: &[bool],
    params: &Params,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<WangYuRun, Cancelled> {
    let mut timings_ms = Vec::new();
    let max_points = params.max_fit_points as usize;
    let min_cos = params.min_normal_cos();
    let t = Instant::now();
    let mut positions = mesh.positions().to_vec();
    let passes = params.initial_passes;
    let (initial_fits, input_curvature) = initial_passes(
        mesh,
        topo,
        &mut positions,
        movable,
        max_points,
        min_cos,
        passes,
        cancel,
        |p| progress.update(Stage::Initial, p as f64 / passes.max(1) as f64),
    )?;
    let input_curvature_variation = mean_curvature_variation(topo, &input_curvature);
    drop(input_curvature);
    timings_ms.push((Stage::Initial, ms(t)));
    let t = Instant::now();
    let initial = measure_stage(
        mesh,
        topo,
        &positions,
        mesh.positions(),
        None,
        params.quality.short_edge_fraction,
    );
    timings_ms.push((Stage::Report, ms(t)));

    let t = Instant::now();
    check(cancel)?;
    // The curvature rings are used once: walked and fitted vertex by
    // vertex, never stored (as lists they would be the run's peak memory).
    let facing_normals = vertex_normals_f32_by_faces(mesh, topo, &positions);
    let hk = vertex_curvatures(
        topo,
        &positions,
        &facing_normals,
        params.curvature_ring,
        max_points,
        min_cos,
    );

    let l = mean_edge_length(mesh, &positions);
    let labels: Vec<Label> = hk
        .par_iter()
        .map(|&(h, k)| label(h, k, l, params.tolerance_h, params.tolerance_k))
        .collect();
    // Single precision: growth compares spreads of about 0.005.
    let h_scaled: Vec<f32> = hk.par_iter().map(|&(h, _)| (h * l) as f32).collect();
    let rule = GrowthRule {
        k_max: params.k_max,
        max_points,
        std_bound: params.curvature_std_bound,
        std_tolerance: params.std_tolerance,
        bias_bound: params.bias_bound,
        edge_length: l,
        tolerance_h: params.tolerance_h,
        tolerance_k: params.tolerance_k,
        label_margin: params.label_margin,
        label_disagreement: params.label_disagreement,
    };
    let agreement = agreement_masks(&hk, &rule);
    drop(hk);
    let AdaptiveNeighbourhoods { hoods, ring } = adaptive_neighbourhoods(
        topo,
        &positions,
        &labels,
        &agreement,
        &h_scaled,
        &facing_normals,
        rule,
    );
    // Free what growth needed before the passes allocate theirs.
    drop((h_scaled, facing_normals, agreement));
    release_walk_scratch();
    release_free_memory();
    timings_ms.push((Stage::Label, ms(t)));
    progress.update(Stage::Label, 1.0);

    let t = Instant::now();
    let passes = params.adaptive_passes;
    let flat: Vec<bool> = ring.par_iter().map(|&k| k >= FLAT_RING).collect();
    let adaptive_fits = smooth_passes(
        mesh,
        topo,
        &mut positions,
        &hoods,
        movable,
        match params.adaptive_fit {
            AdaptiveFit::Cubic => FitModel::Cubic,
            AdaptiveFit::Quadric => FitModel::Quadric,
        },
        min_cos,
        passes,
        is_refit_pass,
        Some(REFIT_TOLERANCE),
        Some(EarlyStop {
            vertices: &flat,
            momentum: FLAT_MOMENTUM,
            passes: flat_passes(passes),
        }),
        cancel,
        |p| progress.update(Stage::Adaptive, p as f64 / passes.max(1) as f64),
    )?;
    drop((hoods, flat));
    let mut volume_offset = 0.0;
    let mut volume_not_restored = None;
    if params.preserve_volume && topo.num_boundary_edges() == 0 {
        let target = mesh.signed_volume();
        // More than half an edge length is no smoothing bias to undo.
        let max_offset = 0.5 * mean_edge_length(mesh, &positions);
        volume_offset = restore_volume(
            mesh,
            topo,
            &mut positions,
            movable,
            target,
            max_offset,
            |_| true,
        );
        let change = (signed_volume(mesh, &positions) - target) / target.abs();
        if volume_offset == 0.0 && change.abs() > 1e-6 {
            volume_not_restored = Some(change);
        }
    }
    timings_ms.push((Stage::Adaptive, ms(t)));
    let t = Instant::now();
    let curvature = stage_curvature(mesh, topo, &positions, params);
    timings_ms.push((Stage::Report, ms(t)));
    Ok(WangYuRun {
        input_curvature_variation,
        initial,
        adaptive: positions,
        curvature,
        labels,
        ring,
        initial_fits,
        adaptive_fits,
        volume_offset,
        volume_not_restored,
        timings_ms,
    })
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
/// scratch would otherwise count in the peak. 13-17 bytes a vertex on the
/// benchmark spheres.
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

/// Smooths `mesh` with `params` and measures the result. Never changes
/// connectivity: the output has one position per input vertex, in order.
///
/// Stages: analyse (topology, input measures), then for `wang-yu` initial
/// smoothing, labelling, adaptive smoothing with volume restoration and the
/// quality fixes; for the baselines the baseline smoother (and the quality
/// fixes). The report's hashes are left for the caller, who has the bytes.
pub fn run(
    mesh: &Mesh,
    params: &Params,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<SmoothOutput, SmoothError> {
    params.validate()?;
    let start = Instant::now();
    let span = tracing::info_span!("smooth", vertices = mesh.num_vertices(), faces = mesh.num_faces(), method = ?params.method);
    let _enter = span.enter();
    let mut timings = Vec::new();
    let input = mesh.positions();
    let fraction = params.quality.short_edge_fraction;

    let t = Instant::now();
    progress.update(Stage::Analyse, 0.0);
    let topo = Topology::build(mesh);
    let movable = movable_mask(&topo, params.boundary);
    // Wang-Yu's first initial pass fits the input's 2-rings anyway: the
    // input's curvature variation comes from those fits.
    let input_curvature =
        (params.method != Method::WangYu).then(|| stage_curvature(mesh, &topo, input, params));
    // The statistics' union-find is serial: it runs beside the measures.
    let (statistics, input_measures) = rayon::join(
        || mesh_statistics(mesh, &topo),
        || {
            measure_stage(
                mesh,
                &topo,
                input,
                input,
                input_curvature.as_deref(),
                fraction,
            )
        },
    );
    let mut report = QualityReport::new(statistics, Reproducibility::new(params));
    report.stages.input = Some(input_measures);
    drop(input_curvature);
    timings.push((Stage::Analyse, ms(t)));
    progress.update(Stage::Analyse, 1.0);
    check(cancel)?;

    // Set when the adaptive stage already reported an unrestored volume.
    let mut volume_warned = false;
    let (mut positions, labels, adaptive_curvature) = match params.method {
        Method::WangYu => {
            let r = {
                let _s = tracing::info_span!("wang_yu").entered();
                wang_yu(mesh, &topo, &movable, params, progress, cancel)?
            };
            let t = Instant::now();
            if let Some(stage) = report.stages.input.as_mut() {
                stage.curvature_variation = Some(CurvatureVariation::new(
                    r.input_curvature_variation,
                    stage.mean_edge_length,
                ));
            }
            report.stages.initial = Some(r.initial);
            report.stages.adaptive = Some(measure_stage(
                mesh,
                &topo,
                &r.adaptive,
                input,
                Some(&r.curvature),
                fraction,
            ));
            report.wang_yu = Some(WangYuSummary {
                labels: LabelCounts::from_labels(&r.labels),
                ring_size_histogram: ring_size_histogram(&r.ring),
                initial_fits: r.initial_fits.into(),
                adaptive_fits: r.adaptive_fits.into(),
                volume_offset: r.volume_offset,
            });
            if let Some(change) = r.volume_not_restored {
                volume_warned = true;
                report.warnings.push(format!(
                    "the enclosed volume changed by {:+.2}% and could not be restored: a \
                     uniform offset of at most half an edge length does not bring it back (the mesh may be \
                     too coarse or too thin for quadric fitting, or the volume restoration \
                     cannot undo a collapse)",
                    100.0 * change
                ));
            }
            timings.extend(r.timings_ms.iter().copied());
            timings.push((Stage::Report, ms(t)));
            let labels = r.labels.iter().map(|&l| l as u8).collect();
            (r.adaptive, labels, Some(r.curvature))
        }
        Method::Laplacian | Method::Taubin => {
            let t = Instant::now();
            let positions = {
                let _s = tracing::info_span!("baseline").entered();
                baseline(mesh, &topo, &movable, params, cancel)?
            };
            timings.push((Stage::Initial, ms(t)));
            report.stages.initial = Some(measure_stage(
                mesh, &topo, &positions, input, None, fraction,
            ));
            (positions, Vec::new(), None)
        }
    };
    // The adaptive stage's curvature is the final stage's when no quality
    // fix moves a vertex in between.
    let unmoved_curvature = adaptive_curvature.filter(|_| !params.quality.enabled);
    check(cancel)?;

    if params.quality.enabled {
        let t = Instant::now();
        let _s = tracing::info_span!("quality").entered();
        progress.update(Stage::Quality, 0.0);
        report.quality_fixes = Some(improve(
            mesh,
            &topo,
            &mut positions,
            input,
            &params.quality,
            params.min_normal_cos(),
        ));
        // The fixes slide vertices over their fitted quadrics, which shifts
        // the volume a little; restore it again with an offset of at most a
        // tenth of an edge, kept only if it folds or twists no face.
        if let Some(summary) = report.wang_yu.as_mut()
            && params.preserve_volume
            && topo.num_boundary_edges() == 0
            && summary.volume_offset != 0.0
        {
            let defects = defect_count(mesh, &positions, input);
            let max_offset = 0.1 * mean_edge_length(mesh, &positions);
            let target = mesh.signed_volume();
            summary.volume_offset += restore_volume(
                mesh,
                &topo,
                &mut positions,
                &movable,
                target,
                max_offset,
                |moved| defect_count(mesh, moved, input) <= defects,
            );
        }
        timings.push((Stage::Quality, ms(t)));
        progress.update(Stage::Quality, 1.0);
    }
    check(cancel)?;

    let t = Instant::now();
    let curvature =
        unmoved_curvature.unwrap_or_else(|| stage_curvature(mesh, &topo, &positions, params));
    report.stages.final_stage = Some(measure_stage(
        mesh,
        &topo,
        &positions,
        input,
        Some(&curvature),
        fraction,
    ));
    timings.push((Stage::Report, ms(t)));
    progress.update(Stage::Report, 1.0);
    let final_change = report
        .stages
        .final_stage
        .as_ref()
        .and_then(|s| s.volume)
        .and_then(|v| v.relative_change);
    if let Some(change) = final_change
        && params.method == Method::WangYu
        && params.preserve_volume
        && change.abs() > 0.005
        && !volume_warned
    {
        report.warnings.push(format!(
            "the enclosed volume ends {:+.2}% from the input's: restoring it after the quality \
             fixes would have folded faces or needed an offset of more than a tenth of an edge",
            100.0 * change
        ));
    }
    if let Some(inverted) = report
        .stages
        .final_stage
        .as_ref()
        .map(|s| s.inverted_faces)
        .filter(|&n| n > 0)
    {
        report.warnings.push(format!(
            "{inverted} faces are inverted relative to the input: the surface folded there \
             (typically at thin, pinched or non-manifold parts); look at those regions, or \
             smooth less (fewer passes, a smaller k_max)"
        ));
    }

    let displacement = positions
        .iter()
        .zip(input)
        .map(|(a, b)| a.distance(*b))
        .collect();
    // One entry per stage, in pipeline order (measuring happens in several
    // places).
    let mut per_stage: Vec<(Stage, f64)> = Vec::new();
    for (stage, ms) in timings {
        match per_stage.iter_mut().find(|t| t.0 == stage) {
            Some(t) => t.1 += ms,
            None => per_stage.push((stage, ms)),
        }
    }
    per_stage.sort_by_key(|t| t.0);
    report.timings = per_stage
        .into_iter()
        .map(|(stage, ms)| StageTiming {
            stage: stage.name().to_string(),
            ms,
        })
        .collect();
    report.total_ms = ms(start);
    Ok(SmoothOutput {
        per_vertex: PerVertex {
            label: labels,
            mean_curvature: curvature.iter().map(|c| c.0).collect(),
            gaussian_curvature: curvature.iter().map(|c| c.1).collect(),
            displacement,
        },
        positions,
        report,
    })
}

/// Measures a mesh without smoothing it: the report's `input` stage (with
/// curvature from 2-ring fits) and the mesh statistics.
pub fn measure(mesh: &Mesh, params: &Params) -> QualityReport {
    let topo = Topology::build(mesh);
    let curvature = stage_curvature(mesh, &topo, mesh.positions(), params);
    let mut report = QualityReport::new(mesh_statistics(mesh, &topo), Reproducibility::new(params));
    report.stages.input = Some(measure_stage(
        mesh,
        &topo,
        mesh.positions(),
        mesh.positions(),
        Some(&curvature),
        params.quality.short_edge_fraction,
    ));
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
