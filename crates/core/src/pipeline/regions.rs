//! A multi-label complex smoothed region by region
//! ([`crate::mesh::regions`]).
//!
//! Each bounded region's closed surface, on its own copies of the wall
//! vertices, is smoothed as a body of its own ([`run_bodies`]): so each
//! label's fits, volume restoration (paper section 2.3) and pinches read
//! its own surface, as they would in a file of that label alone. The
//! complex stays one: each vertex then takes the mean of its regions'
//! results (a wall is as much one label's as the other's), and the quality
//! fixes (section 2.4) run once more on the complex, whose joined walls
//! may close or turn faces that each region's run left sound.

use super::{Call, QUALITY_ROOM, SmoothError, SmoothOutput, Timings, ms, run_inner};
use crate::control::{Progress, Stage};
use crate::mesh::{Mesh, OUTSIDE, Regions, Topology, body_ids, paired_voxel_faces};
use crate::params::Params;
use crate::quality::improve;
use crate::report::{
    CurvatureVariation, Displacement, QualityReport, VolumeMeasure, mean_curvature_variation,
    measure_stage,
};
use crate::smoothing::fidelity::{Fidelity, FidelityBound};
use glam::DVec3;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

/// A complex's regions, each on its own copies of its vertices.
pub(super) struct Split {
    mesh: Mesh,
    /// Per vertex of the complex, the range of its copies in `mesh`
    /// (copies are numbered by complex vertex, then region).
    copies: Vec<u32>,
    /// Pairs of faces of `mesh` that copy one wall, a copy for each region
    /// on its sides.
    shared: Vec<(u32, u32)>,
}

/// The copies of a face with region `sides`: for each side with a region,
/// that region and whether the face is turned over for it; a face with no
/// region on either side (of a closed part that encloses no volume, such
/// as a sheet written twice) is copied once, as it is, for such faces' own
/// part `open`.
fn face_copies(sides: [u32; 2], open: u32) -> [Option<(u32, bool)>; 2] {
    match sides {
        [OUTSIDE, OUTSIDE] => [Some((open, false)), None],
        [behind, front] => [
            (behind != OUTSIDE).then_some((behind, false)),
            (front != OUTSIDE).then_some((front, true)),
        ],
    }
}

/// Each region's faces, wound so that the region lies behind them (the
/// side in front of a face turns it over about its first corner), on a
/// copy per region of each vertex, and the faces of no region as they are
/// on copies of their own; `None` when the copies would pass the mesh's
/// size limits.
pub(super) fn split(mesh: &Mesh, regions: &Regions) -> Option<Split> {
    let n = mesh.num_vertices();
    let open = regions.count as u32;
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(mesh.face_vertices().len());
    for (f, face) in mesh.faces().enumerate() {
        for (r, _) in face_copies(regions.sides[f], open).into_iter().flatten() {
            pairs.extend(face.iter().map(|&v| (v, r)));
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    let mut copies = vec![0u32; n + 1];
    for &(v, _) in &pairs {
        copies[v as usize + 1] += 1;
    }
    for v in 0..n {
        copies[v + 1] += copies[v];
    }
    let copy = |v: u32, r: u32| -> u32 {
        let (lo, hi) = (copies[v as usize] as usize, copies[v as usize + 1] as usize);
        let at = pairs[lo..hi].partition_point(|p| p.1 < r);
        (lo + at) as u32
    };
    let positions: Vec<DVec3> = pairs
        .iter()
        .map(|&(v, _)| mesh.positions()[v as usize])
        .collect();
    let mut offsets: Vec<u32> = vec![0];
    let mut corners: Vec<u32> = Vec::with_capacity(pairs.len());
    let mut shared = Vec::new();
    for (f, face) in mesh.faces().enumerate() {
        let mut made = [u32::MAX; 2];
        for (k, side) in face_copies(regions.sides[f], open).into_iter().enumerate() {
            let Some((r, turned)) = side else {
                continue;
            };
            let start = corners.len();
            corners.extend(face.iter().map(|&v| copy(v, r)));
            if turned {
                // Turned over about its first corner, so that a quad keeps
                // the diagonal it is split along.
                corners[start + 1..].reverse();
            }
            made[k] = (offsets.len() - 1) as u32;
            offsets.push(u32::try_from(corners.len()).ok()?);
        }
        if made[0] != u32::MAX && made[1] != u32::MAX {
            shared.push((made[0], made[1]));
        }
    }
    let mesh = Mesh::new(positions, offsets, corners).ok()?;
    Some(Split {
        mesh,
        copies,
        shared,
    })
}

/// What a run passes on to [`run`]: its timings so far, its start, and
/// its arguments.
pub(super) struct Context<'a> {
    pub timings: Timings,
    pub start: Instant,
    pub params: &'a Params,
    pub progress: &'a dyn Progress,
    pub cancel: &'a AtomicBool,
}

/// Smooths the complex `mesh` (topology `topo`) region by region (module
/// docs): `regions` and `split` of it ([`split`]), `report` its analysis.
pub(super) fn run(
    mesh: &Mesh,
    topo: &Topology,
    regions: &Regions,
    split: Split,
    mut report: QualityReport,
    context: Context,
) -> Result<SmoothOutput, SmoothError> {
    let Context {
        mut timings,
        start,
        params,
        progress,
        cancel,
    } = context;
    let _s =
        tracing::info_span!("regions", regions = regions.count, walls = regions.walls).entered();
    let bodies = timings.time(Stage::Analyse, || {
        body_ids(&split.mesh, &Topology::build(&split.mesh), &split.shared).0
    });
    let smoothed = run_inner(
        &split.mesh,
        Some(&bodies),
        params,
        progress,
        cancel,
        Call::Regions,
    )?;
    let input = mesh.positions();
    let offsets = &split.copies;
    let (positions, joined, fixes) = timings.time(Stage::Quality, || {
        let mut positions: Vec<DVec3> = (0..mesh.num_vertices())
            .map(|v| {
                let own = &smoothed.positions[offsets[v] as usize..offsets[v + 1] as usize];
                if own.is_empty() {
                    return input[v];
                }
                own.iter().sum::<DVec3>() / own.len() as f64
            })
            .collect();
        let joined = wall_spread(&positions, &smoothed.positions, offsets);
        // The bound of the regions' runs, widened for the fixes: a voxel
        // complex written as triangles is bounded on its voxel faces.
        let bound = params.max_displacement.map(|d| {
            let bound = match paired_voxel_faces(mesh, topo) {
                Some(p) => FidelityBound::new(&p.mesh, &p.topo, d),
                None => FidelityBound::new(mesh, topo, d),
            };
            bound.widened(QUALITY_ROOM)
        });
        let fixes = improve(
            mesh,
            topo,
            &mut positions,
            input,
            bound.as_ref(),
            &params.quality,
            params.min_normal_cos(),
        );
        Fidelity::new(bound.as_ref(), input).apply(&mut positions);
        (positions, joined, fixes)
    });

    // The complex's report: its own statistics, input and final measures;
    // the regions' runs' summary, intermediate stages and fixes.
    let inner = smoothed.report;
    let curvature = timings.time(Stage::Report, || {
        // The analysis measured the input but for its curvature, which a
        // run takes from its first fits: here those were the regions'.
        if let Some(stage) = report.stages.input.as_mut() {
            let c = super::stage_curvature(mesh, topo, input, params);
            stage.curvature_variation = Some(CurvatureVariation::new(
                mean_curvature_variation(topo, &c),
                stage.mean_edge_length,
            ));
        }
        let curvature = super::stage_curvature(mesh, topo, &positions, params);
        report.stages.final_stage = Some(measure_stage(
            mesh,
            topo,
            &positions,
            input,
            Some(&curvature),
            params.quality.short_edge_fraction,
        ));
        curvature
    });
    report.stages.initial = inner.stages.initial;
    report.stages.adaptive = inner.stages.adaptive;
    report.wang_yu = inner.wang_yu;
    report.quality_fixes = inner.quality_fixes;
    report.warnings = inner.warnings;
    // A complex's volume is its regions': one wall face bounds two.
    let input_volume = regions.volume(mesh, input);
    let volume = |positions: &[DVec3]| {
        let v = regions.volume(mesh, positions);
        VolumeMeasure {
            volume: v,
            relative_change: (input_volume != 0.0).then(|| (v - input_volume) / input_volume.abs()),
        }
    };
    for (stage, at) in [
        (report.stages.input.as_mut(), input),
        (report.stages.final_stage.as_mut(), &positions[..]),
    ] {
        if let Some(stage) = stage {
            stage.volume = Some(volume(at));
        }
    }
    report.mesh.regions = regions.count as u64;
    report.mesh.region_walls = regions.walls as u64;
    report.walls_joined = Some(joined);
    report.joined_fixes = Some(fixes);
    // In edge lengths, which mean the same in every unit the mesh may have
    // been smoothed in (`UnitScale`); `walls_joined` has them in its own.
    let edge = report
        .stages
        .input
        .as_ref()
        .map_or(0.0, |s| s.mean_edge_length);
    let in_edges = |d: f64| if edge > 0.0 { d / edge } else { 0.0 };
    report.warnings.push(format!(
        "the mesh is a complex of {} regions sharing {} wall faces (a multi-label surface, \
         each wall written once): each region was smoothed as its own closed surface, and each \
         wall vertex put at the mean of its regions' results, which lay {:.3} mean edge \
         lengths from it on average and {:.3} at most",
        regions.count,
        regions.walls,
        in_edges(joined.mean),
        in_edges(joined.max)
    ));
    super::final_warnings(params, &mut report, true);
    timings.absorb(&inner.timings);
    report.timings = timings.into_report();
    report.total_ms = ms(start);
    let label: Vec<u8> = (0..mesh.num_vertices())
        .map(|v| {
            smoothed
                .per_vertex
                .label
                .get(offsets[v] as usize)
                .copied()
                .unwrap_or_default()
        })
        .collect();
    Ok(SmoothOutput {
        per_vertex: super::PerVertex::new(input, &positions, label, &curvature),
        positions,
        report,
    })
}

/// How far the copies of the vertices with more than one (the walls')
/// lay from their mean `joined`, over the copies: vertex `v`'s copies are
/// `copies[offsets[v]..offsets[v + 1]]`.
fn wall_spread(joined: &[DVec3], copies: &[DVec3], offsets: &[u32]) -> Displacement {
    let (mut sum, mut sum2, mut max, mut count) = (0.0, 0.0, 0.0f64, 0usize);
    for (v, &p) in joined.iter().enumerate() {
        let own = &copies[offsets[v] as usize..offsets[v + 1] as usize];
        if own.len() < 2 {
            continue;
        }
        for c in own {
            let d = c.distance(p);
            sum += d;
            sum2 += d * d;
            max = max.max(d);
            count += 1;
        }
    }
    let k = count.max(1) as f64;
    Displacement {
        mean: sum / k,
        rms: (sum2 / k).sqrt(),
        max,
    }
}
