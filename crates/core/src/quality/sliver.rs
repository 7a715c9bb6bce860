//! Sliver fix (an addition to the paper's section 2.4): a face whose
//! smallest split-triangle angle the sharp-angle fix left far below its
//! threshold.
//!
//! The sharp-angle fix moves one vertex at a time onto its local fitted
//! surface. Where the smoothing squeezed a triangle between neighbours that
//! moved across a thin sheet or a crease, every such move is refused and a
//! sliver of a degree or two can remain. The input has no such sliver (a
//! marching-cubes mesh's smallest angle is 30 degrees, a voxel mesh's 45),
//! so, like the fold fix ([`super::inverted`]), this fix moves the sliver's
//! movable vertices back toward the input: a cluster of slivers (faces
//! sharing a vertex) goes back together by the smallest of the
//! [`RETREATS`](super::inverted::RETREATS) that lifts every angle around it
//! to the floor and makes nothing worse (see `MoveTester`), taking in one
//! ring more at most [`SLIVER_WIDENINGS`] times; when none does, by the
//! smallest that widens the cluster's smallest angle (tried from the
//! narrowest cluster out, so a ring whose faces refuse every fraction does
//! not block the fraction the sliver's own corners take). Once a sweep
//! moves nothing so, the later sweeps also try, where no retreat of the
//! cluster is kept, some of the sliver's own corners only, fewest first,
//! with the same two rules (`retreat_corner_subsets`: a face squeezed
//! between corners that moved by different amounts opens only so; tried
//! earlier, such a move can block a cluster's retreat that a later sweep
//! would have kept). Smoothing is given up only where a sliver was
//! ([`retreat_sweeps`], the fold fix's mechanism).
//!
//! Order: sequential, slivers in ascending face order (deterministic); each
//! sweep scans the whole mesh again (a fallback move may close a face next
//! to its cluster below the floor); the fix stops after a sweep with the
//! corner subsets that changes nothing, when none is left, or after
//! `max_sweeps`. Only interior and non-manifold vertices move (a voxel
//! mesh's side wall squeezed across a non-manifold edge opens only when
//! that edge's ends go back, `inverted::movable`).

use super::inverted::{RetreatRule, retreat_sweeps};
use super::local::{Verdict, has_angle_below};
use crate::mesh::{Mesh, Topology};
use crate::smoothing::fidelity::FidelityBound;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// How many times a sliver's cluster may take in one more ring of
/// vertices: each ring gives up more smoothing for an angle, where a fold
/// (`FOLD_WIDENINGS`) is a defect worth more rings.
pub const SLIVER_WIDENINGS: usize = 2;

/// What the sliver fix did.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SliverStats {
    /// Faces with a split-triangle angle below the floor before the fix
    /// (and not in the input).
    pub found: u64,
    /// Accepted moves towards the input: of a cluster's vertices
    /// together, or, once those are stuck, of some of one sliver's
    /// corners.
    pub retreats: u64,
    /// Vertices those moves moved (a vertex moved twice counts twice).
    pub vertices_moved: u64,
    /// Clusters no tried move improved.
    pub rejected: u64,
    /// Sweeps run.
    pub sweeps: u64,
    /// Such faces after the fix.
    pub remaining: u64,
}

/// Whether `face` has a split-triangle angle whose cosine exceeds
/// `cos_floor` at `positions` but not at `input`: going back cannot open a
/// sliver the input already had (a decimated neuron's). A face with a
/// repeated corner never counts.
fn is_sliver(face: &[u32], positions: &[DVec3], input: &[DVec3], cos_floor: f64) -> bool {
    has_angle_below(face, positions, cos_floor) && !has_angle_below(face, input, cos_floor)
}

/// Moves the slivers' vertices (faces with a split-triangle angle below
/// `floor_deg` that the input did not have) back towards `input` (one
/// position per vertex, like `positions`, which are moved in place); at
/// most `max_sweeps` sweeps.
pub fn fix_slivers(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    input: &[DVec3],
    bound: Option<&FidelityBound>,
    floor_deg: f64,
    max_sweeps: u32,
) -> SliverStats {
    let cos_floor = floor_deg.to_radians().cos();
    let clean =
        |v: &Verdict| !v.new_defect && v.inverted.1 <= v.inverted.0 && v.twisted.1 <= v.twisted.0;
    let rule = RetreatRule {
        bad: &|face, p| is_sliver(face, p, input, cos_floor),
        cos_goal: cos_floor,
        accept: &|v| clean(v) && v.max_cos.1 <= cos_floor,
        fallback: Some(&|v| clean(v) && v.max_cos.1 < v.max_cos.0),
        widenings: SLIVER_WIDENINGS,
        refold_growths: 0,
        corner_subsets: true,
    };
    let s = retreat_sweeps(mesh, topo, positions, input, bound, max_sweeps, &rule);
    SliverStats {
        found: s.found,
        retreats: s.retreats,
        vertices_moved: s.vertices_moved,
        rejected: s.rejected,
        sweeps: s.sweeps,
        remaining: s.remaining,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::VertexKind;
    use crate::quality::fixtures::{at, grid, min_split_angle, patch};
    use crate::shapes::{VoxelMask, voxel_boundary_mesh};
    use glam::IVec3;

    #[test]
    fn a_sliver_goes_back_by_the_smallest_fraction_that_lifts_it() {
        // Vertex (3, 3) pushed down to y = 2.1: the split triangle
        // (2,2) (3,2) (3,3) of the quad below it closes to 5.7 degrees.
        let m = grid(6);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let a = at(6, 3, 3);
        let mut p = input.clone();
        p[a] = DVec3::new(3.0, 2.1, 0.0);
        assert!(min_split_angle(&m, &p, None) < 6.0);
        let squeezed = p.clone();
        let stats = fix_slivers(&m, &t, &mut p, &input, None, 10.0, 10);
        assert_eq!((stats.retreats, stats.remaining), (1, 0), "{stats:?}");
        // An eighth of the way back (y = 2.2125) lifts that triangle to 12
        // degrees but closes (3,2) (4,3) (3,3) of the quad to its right to
        // 7; a quarter (y = 2.325) leaves both above 10.
        assert!(
            (p[a] - DVec3::new(3.0, 2.325, 0.0)).length() < 1e-12,
            "{}",
            p[a]
        );
        assert!(min_split_angle(&m, &p, None) >= 10.0);
        for v in (0..p.len()).filter(|&v| v != a) {
            assert_eq!(p[v], squeezed[v], "vertex {v} is not the sliver's");
        }
    }

    #[test]
    fn a_side_wall_squeezed_across_a_non_manifold_edge_opens() {
        // Two voxels of a thick-slice mask (1 x 1 x 2.5) touching along the
        // edge x in [1, 2], y = 2, z = 5: its two ends are non-manifold.
        let mask = VoxelMask::from_fn(IVec3::ZERO, [4, 4, 4], |i, j, k| {
            (i, j, k) == (1, 1, 1) || (i, j, k) == (1, 2, 2)
        });
        let mut m = voxel_boundary_mesh(&mask);
        for q in m.positions_mut() {
            q.z *= 2.5;
        }
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let ends: Vec<usize> = (0..m.num_vertices())
            .filter(|&v| t.kind(v) == VertexKind::NonManifold)
            .collect();
        assert_eq!(ends.len(), 2);
        // The relaxation pulls each end toward the other (its only
        // neighbour along the edge): the edge closes to 0.4 and the side
        // walls on it, 1 x 2.5, to slivers.
        let mid = 0.5 * (input[ends[0]] + input[ends[1]]);
        let mut p = input.clone();
        for &v in &ends {
            p[v] = mid + 0.4 * (input[v] - mid);
        }
        assert!(min_split_angle(&m, &p, None) < 10.0);
        let squeezed = p.clone();
        let stats = fix_slivers(&m, &t, &mut p, &input, None, 10.0, 10);
        assert_eq!(stats.remaining, 0, "{stats:?}");
        assert!(min_split_angle(&m, &p, None) >= 10.0);
        for v in 0..p.len() {
            if ends.contains(&v) {
                let back = input[v].distance(p[v]);
                assert!(back < input[v].distance(squeezed[v]), "end {v} went back");
            } else {
                assert_eq!(p[v], squeezed[v], "vertex {v} is not the edge's");
            }
        }
    }

    /// Runs the fix on a real patch (`fixtures::patch`) whose smallest
    /// angle starts below `below` degrees: no sliver is left and every
    /// angle ends at the 10-degree floor or above.
    fn opens_to_the_floor(text: &str, below: f64) {
        let (m, input, squeezed) = patch(text);
        let t = Topology::build(&m);
        assert!(min_split_angle(&m, &squeezed, None) < below);
        let mut p = squeezed;
        let stats = fix_slivers(&m, &t, &mut p, &input, None, 10.0, 10);
        assert_eq!(stats.remaining, 0, "{stats:?}");
        assert!(min_split_angle(&m, &p, None) >= 10.0);
    }

    #[test]
    fn a_sliver_whose_widened_cluster_refuses_every_fraction_still_opens() {
        // Three corners of the sliver's quad are non-manifold (two sheets
        // of a 1 x 1 x 2.5 mm mask touching along an edge). Within their
        // reach no fraction lifts it to the floor and every fraction of the
        // widened cluster makes a defect, while a small step of its own
        // corners widens it; the step closes a face next to it below the
        // floor, which the next sweep finds and opens. A retreat reaching
        // back to the input opens it too: the patch fails only without
        // both (on the whole mesh, under its fidelity bound, each is
        // needed; `docs/tuning.md`).
        opens_to_the_floor(include_str!("testdata/thick_slice_sliver.txt"), 5.0);
    }

    #[test]
    fn a_sliver_goes_back_farther_than_its_edges_are_long() {
        // A 1 x 1 x 4 mm mask: the sliver's corners moved along the deep
        // axis by more than their longest edge is now long, and only going
        // half way back opens it. A retreat may jump that far.
        opens_to_the_floor(include_str!("testdata/deep_slice_sliver.txt"), 6.0);
    }

    #[test]
    fn a_sliver_opens_when_some_of_its_corners_go_back() {
        // A 1 x 1 x 4 mm mask at a thin threshold: two of the sliver's
        // corners sit on non-manifold edges and moved less than the other
        // two. No fraction of the cluster or its widenings, taken by all
        // of its vertices, widens the sliver without closing a face beside
        // it; some of its corners going back without the others open it.
        opens_to_the_floor(include_str!("testdata/deep_slice_sliver_corners.txt"), 5.0);
    }

    #[test]
    fn corner_subsets_wait_until_the_clusters_are_stuck() {
        // The same voxels at a thick threshold. The clusters' retreats
        // alone open every sliver, over a few sweeps. With the subsets
        // tried from the first sweep, a subset's move that only widens a
        // sliver a little leaves it at 9.4 degrees, where no later
        // retreat opens it.
        opens_to_the_floor(include_str!("testdata/deep_slice_sliver_order.txt"), 7.0);
    }

    #[test]
    fn a_sliver_the_input_had_is_left_alone() {
        let m = grid(6);
        let t = Topology::build(&m);
        let mut input = m.positions().to_vec();
        input[at(6, 3, 3)] = DVec3::new(3.0, 2.1, 0.0);
        let mut p = input.clone();
        let stats = fix_slivers(&m, &t, &mut p, &input, None, 10.0, 10);
        assert_eq!((stats.found, stats.retreats), (0, 0), "{stats:?}");
        assert_eq!(p, input);
    }
}
