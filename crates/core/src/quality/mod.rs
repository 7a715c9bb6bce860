//! Mesh-quality fixes of section 2.4 (algorithm notes section 8) and one of
//! our own for folds (inverted faces), one file per fix. The measures of
//! the quality report (section 9) are the report's
//! ([`crate::report::measures`]).
//!
//! The fixes only move vertices (connectivity never changes), move only
//! interior vertices (those that move vertices back toward the input, also
//! the non-manifold vertices the voxel relaxation moved; the sharp-angle
//! fix, once its interior moves are spent, the non-manifold vertices too),
//! and keep a move only when it makes nothing worse: no face becomes
//! inverted relative to the input, no quad becomes twisted (but that a
//! move back toward the input may twist again a quad the input had
//! twisted, whose orientation is its vector area's alone), no quad corner
//! divided by the triangle split opens beyond 160° (or beyond its angle
//! before; the twisted-quad fix's last resort allows 170°), no defect
//! count grows, and the smallest split-triangle angle of the affected
//! faces does not shrink (a move that removes a twisted quad or an
//! inverted face may shrink it: defects outrank angles). [`improve`] runs
//! them in the order twisted quads, short edges, sharp angles (interior
//! vertices, then with the non-manifold ones), inverted faces (then sharp
//! angles once more, both runs, when that moved anything), slivers. All are
//! deterministic and independent of the number of threads. None moves a
//! hub (a vertex of more than [`local::MAX_FAN`] edges, the tip of a fan)
//! or a corner of a face of more than [`local::MAX_FIX_CORNERS`] corners,
//! and no fit walks through a hub, so a visit's work is bounded whatever
//! the mesh's valences and polygons.

#[cfg(test)]
pub(crate) mod fixtures;
pub mod inverted;
pub(crate) mod local;
pub mod sharp_angle;
pub mod short_edge;
pub mod sliver;
pub mod twisted;

pub use inverted::{InvertedStats, fix_inverted_faces};
pub use sharp_angle::{Movers, SharpAngleStats, fix_sharp_angles};
pub use short_edge::{ShortEdgeStats, fix_short_edges};
pub use sliver::{SliverStats, fix_slivers};
pub use twisted::{TwistedStats, fix_twisted_quads};

use crate::mesh::{Mesh, Topology, VertexKind};
use crate::smoothing::fidelity::FidelityBound;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Parameters of the quality-improvement stage (section 2.4).
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema), schema(default))]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QualityParams {
    /// Run the quality fixes. Default true.
    pub enabled: bool,
    /// An edge shorter than this fraction of the mean edge length is short.
    /// Default 0.2; range 0..=1.
    pub short_edge_fraction: f64,
    /// A triangle-split angle below this (degrees) is sharp and triggers
    /// angle-based smoothing. Default 20: a margin above the 15° floor the
    /// fixes must keep; on the voxel and marching-cubes test shapes it
    /// leaves no angle below 20° at less than half the cost of 25°.
    /// Range 0..=60.
    pub sharp_angle_deg: f64,
    /// Most sweeps of each fix (a fix stops earlier when a sweep moves
    /// nothing). Default 20: on the real masks the sharp-angle fix still
    /// opens faces after ten sweeps, and a shape that needs few sweeps
    /// makes no more (`docs/tuning.md`). Range 0..=100.
    pub max_sweeps: u32,
}

impl Default for QualityParams {
    fn default() -> Self {
        QualityParams {
            enabled: true,
            short_edge_fraction: 0.2,
            sharp_angle_deg: 20.0,
            max_sweeps: 20,
        }
    }
}

/// What the fixes did.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct QualityFixStats {
    /// Twisted-quad fix.
    pub twisted: TwistedStats,
    /// Short-edge fix.
    pub short_edges: ShortEdgeStats,
    /// Sharp-angle fix.
    pub sharp_angles: SharpAngleStats,
    /// Inverted-face (fold) fix.
    pub inverted: InvertedStats,
    /// Sliver fix.
    pub slivers: SliverStats,
}

/// The sliver fix's floor as a fraction of [`QualityParams::sharp_angle_deg`]:
/// a face the sharp-angle fix leaves between the floor and the threshold is
/// sharp but sound, one below half of it is a sliver worth giving up the
/// smoothing around it (10 degrees at the default threshold, the smallest
/// angle the real masks' results are held to).
pub const SLIVER_FRACTION: f64 = 0.5;

/// Runs the fixes on `positions` (one per vertex, moved in place) with
/// `input` the input positions (one per vertex, the reference for inverted
/// faces): twisted quads, then short edges, then sharp angles (moving the
/// interior vertices, then, for the faces they could not open, the
/// non-manifold vertices as well: [`Movers`]), then the folds the
/// sharp-angle fix's single-vertex moves could not open, then the slivers
/// neither could open ([`SLIVER_FRACTION`]), each at most
/// `params.max_sweeps` sweeps. The fold and the sliver fixes move clusters
/// back toward the input only until their faces are sound, which can leave
/// angles just above the sliver floor: when either moved a vertex, sharp
/// angles run again after it, their counts added to the first run's.
/// Surface fits leave out neighbours facing away by a cosine below
/// `min_normal_cos` ([`crate::Params::min_normal_cos`]). No move takes a
/// vertex out of `bound` around its input position. Does nothing when
/// `params.enabled` is false.
pub fn improve(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    input: &[DVec3],
    bound: Option<&FidelityBound>,
    params: &QualityParams,
    min_normal_cos: f64,
) -> QualityFixStats {
    if !params.enabled {
        return QualityFixStats::default();
    }
    let sweeps = params.max_sweeps;
    let twisted = fix_twisted_quads(mesh, topo, positions, input, bound, sweeps, min_normal_cos);
    let short_edges = fix_short_edges(
        mesh,
        topo,
        positions,
        input,
        bound,
        params.short_edge_fraction,
        sweeps,
        min_normal_cos,
    );
    let sharp = |positions: &mut [DVec3], movers: Movers| {
        fix_sharp_angles(
            mesh,
            topo,
            positions,
            input,
            bound,
            params.sharp_angle_deg,
            sweeps,
            min_normal_cos,
            movers,
        )
    };
    // Where sheets meet at a vertex, the interior vertices alone may not
    // open the angles at it (a placed pinch with its relaxed neighbours
    // leaning toward it): that vertex moves last, and only as needed (a
    // mesh without one has nothing for that run to start from).
    let has_non_manifold = topo.kinds().contains(&VertexKind::NonManifold);
    let sharp_then_non_manifold = |positions: &mut [DVec3]| {
        let mut stats = sharp(positions, Movers::Interior);
        if stats.faces_remaining > 0 && has_non_manifold {
            stats.add(&sharp(positions, Movers::AlsoNonManifold));
        }
        stats
    };
    let mut sharp_angles = sharp_then_non_manifold(positions);
    let inverted = fix_inverted_faces(mesh, topo, positions, input, bound, sweeps);
    if inverted.vertices_moved > 0 {
        // The folds moved back towards the input: clean up their angles,
        // by the same two runs (a fold's cluster may hold sheets' meeting
        // vertices, and a retreat to the input may bring back an input
        // sliver that only such a vertex can open).
        sharp_angles.add(&sharp_then_non_manifold(positions));
    }
    let slivers = fix_slivers(
        mesh,
        topo,
        positions,
        input,
        bound,
        SLIVER_FRACTION * params.sharp_angle_deg,
        sweeps,
    );
    if slivers.vertices_moved > 0 {
        // The sliver fix moved clusters back toward the input only until
        // their angles reached the floor: the angle-based moves may open
        // them further (a face the passes squeezed that was sound in the
        // input).
        sharp_angles.add(&sharp_then_non_manifold(positions));
    }
    QualityFixStats {
        twisted,
        short_edges,
        sharp_angles,
        inverted,
        slivers,
    }
}

/// Whether face `f` has a split-triangle angle whose cosine exceeds
/// `cos_floor` at `positions` (a face with a repeated corner never has).
pub fn has_sliver_angle(mesh: &Mesh, f: usize, positions: &[DVec3], cos_floor: f64) -> bool {
    local::has_angle_below(mesh.face(f), positions, cos_floor)
}

/// The cosine of the smallest angle a move made for something other than
/// the angles (the volume restoration's last offset) may leave face `f`,
/// now at `positions`, with `input` the input positions, `cos_keep` the
/// cosine of an angle a face at or above it keeps (at most the floor's
/// angle: the floor itself, or the sharp-angle threshold so that the move
/// undoes none of what the fix opened) and `cos_floor` the sliver floor's
/// cosine: `cos_keep` for a face at or above it; the floor for a face
/// above the floor; a face already sharper closes no further, but for a
/// sliver of the input, which may close as far as the sharp-angle fix lets
/// it (half its input angle, [`SLIVER_FRACTION`]). -1 (no floor) for a
/// face with a repeated corner.
pub fn closing_floor_cos(
    mesh: &Mesh,
    f: usize,
    positions: &[DVec3],
    input: &[DVec3],
    cos_keep: f64,
    cos_floor: f64,
) -> f64 {
    local::closing_floor_cos(mesh.face(f), positions, input, cos_keep, cos_floor)
}

/// Whether face `f` is inverted relative to `input` or a twisted quad at
/// `positions` (a face with a repeated corner never is).
pub fn is_defective(mesh: &Mesh, f: usize, positions: &[DVec3], input: &[DVec3]) -> bool {
    let face = mesh.face(f);
    !local::has_repeated_corner(face)
        && (local::is_inverted(face, positions, input) || local::is_twisted(face, positions))
}
