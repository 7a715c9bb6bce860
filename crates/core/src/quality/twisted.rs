//! Twisted-quad fix (paper section 2.4; algorithm notes section 8).
//!
//! A quad `(v1 v2 v3 v4)` is twisted when the normals of its split
//! triangles `(v1 v2 v3)` and `(v3 v4 v1)` are more than 90° apart. Twisted
//! quads come in pairs sharing an edge: swapping the positions of that
//! edge's two end points untwists both. A twisted quad with no twisted
//! neighbour, or whose swap is refused, is handled by relocating its
//! corners with the angle-based candidates of
//! [`sharp_angle`](super::sharp_angle). When none of those untwists it (two
//! opposite corners pinned, as where two sheets of a voxel mask touch at a
//! corner), its corners that can move go back toward their input positions,
//! where the quad was not twisted, by the smallest of the fold fix's
//! [`RETREATS`](super::inverted::RETREATS) that untwists it: each corner
//! alone, then all of them together, then with one more ring of the
//! vertices around them at a time, at most
//! [`FOLD_WIDENINGS`](super::inverted::FOLD_WIDENINGS) times (a twisted
//! quad is a defect like a fold; where its corners crossed far along the
//! deep axis of thick slices, going back alone folds the quads around
//! them). When no such move keeps the split corners of the quads around
//! within 160° (`MoveTester`), the same moves are tried once more letting
//! one open up to 170° ([`UNTWIST_CORNER_COS`]): a fold outranks a wide
//! corner.
//!
//! Every move is tried and kept only when it makes nothing worse (see
//! `MoveTester`): no face becomes inverted relative to the input, no quad
//! becomes twisted, the number of twisted quads among the affected faces
//! drops, and the number of inverted faces does not grow. Removing a
//! twisted quad outranks the smallest angle: a swap may shrink it (the
//! sharp-angle fix runs afterwards).
//!
//! Order: Gauss-Seidel, sequential, quads in ascending face order within a
//! sweep (deterministic); a sweep rescans only the quads that were still
//! twisted; the fix stops after a sweep that changes nothing, when none is
//! left, or after `max_sweeps`. Only interior vertices move, and in the
//! retreats also non-manifold ones (`inverted::movable`).

use super::inverted::{Cluster, FOLD_WIDENINGS, movable_corners};
use super::local::{MoveTester, Verdict, is_twisted};
use super::sharp_angle::{Relocator, Visit};
use crate::mesh::{Mesh, Topology, VertexKind};
use crate::smoothing::fidelity::FidelityBound;
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// What the twisted-quad fix did.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TwistedStats {
    /// Twisted quads before the fix.
    pub found: u64,
    /// Accepted swaps of an edge's end points.
    pub swaps: u64,
    /// Accepted single-vertex relocations.
    pub relocations: u64,
    /// Accepted moves of a quad's corners toward their input positions.
    pub retreats: u64,
    /// Tried moves refused because they would have made something worse.
    pub rejected: u64,
    /// Sweeps run.
    pub sweeps: u64,
    /// Twisted quads after the fix.
    pub remaining: u64,
}

fn twisted_quads(mesh: &Mesh, positions: &[DVec3]) -> Vec<u32> {
    (0..mesh.num_faces() as u32)
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&f| is_twisted(mesh.face(f as usize), positions))
        .collect()
}

/// Accepted when it removes a twisted quad and adds no defect.
fn untwists(v: &Verdict) -> bool {
    !v.new_defect && v.twisted.1 < v.twisted.0 && v.inverted.1 <= v.inverted.0
}

/// Cosine of the widest split corner (170°) a retreat may open in a quad
/// around a twisted one when no retreat untwists it within the usual 160°
/// (`local::WIDEST_CORNER_COS`): a twisted quad is a fold, while a quad
/// with a corner this wide is still convex, and the sharp-angle fix that
/// runs next may close the corner again.
const UNTWIST_CORNER_COS: f64 = -0.984_807_753_012_208;

/// [`untwists`], letting a split corner around the quad open up to
/// [`UNTWIST_CORNER_COS`].
fn untwists_opening(v: &Verdict) -> bool {
    !v.new_fold_or_jump
        && v.opened_corner_cos >= UNTWIST_CORNER_COS
        && v.twisted.1 < v.twisted.0
        && v.inverted.1 <= v.inverted.0
}

/// Untwists twisted quads by swapping the end points of an edge shared
/// with another twisted quad, else by relocating a corner; at most
/// `max_sweeps` sweeps. Moves vertices in `positions` in place (one entry
/// per vertex; `input`, the input positions, likewise).
pub fn fix_twisted_quads(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    input: &[DVec3],
    bound: Option<&FidelityBound>,
    max_sweeps: u32,
    min_normal_cos: f64,
) -> TwistedStats {
    let mut twisted = twisted_quads(mesh, positions);
    let mut stats = TwistedStats {
        found: twisted.len() as u64,
        ..TwistedStats::default()
    };
    let mut tester = MoveTester::bounded(bound);
    let mut relocator = Relocator::new(min_normal_cos, bound);
    let mut cluster = Cluster::default();
    while !twisted.is_empty() && stats.sweeps < max_sweeps as u64 {
        stats.sweeps += 1;
        let mut changed = false;
        for &f in &twisted {
            let face = mesh.face(f as usize);
            if !is_twisted(face, positions) {
                continue; // untwisted by an earlier move of this sweep
            }
            if swap_with_twisted_neighbour(mesh, topo, f, positions, input, &mut tester, &mut stats)
            {
                changed = true;
                continue;
            }
            // Relocate a corner: keep the first that untwists.
            let mut relocated = false;
            for &corner in &face[..4] {
                let v = corner as usize;
                if topo.kind(v) != VertexKind::Interior {
                    continue;
                }
                let before: u32 = count_twisted_around(mesh, topo, v, positions);
                let saved = positions[v];
                if let Visit::Moved(q) =
                    relocator.relocate(mesh, topo, v, positions, input, 1.0, 1.0, true)
                {
                    positions[v] = q;
                    if count_twisted_around(mesh, topo, v, positions) < before {
                        stats.relocations += 1;
                        changed = true;
                        relocated = true;
                        break;
                    }
                    positions[v] = saved;
                }
                stats.rejected += 1;
            }
            if !relocated
                && [untwists, untwists_opening].iter().any(|accept| {
                    retreat_corners(
                        mesh,
                        topo,
                        f,
                        positions,
                        input,
                        &mut tester,
                        &mut cluster,
                        accept,
                    )
                })
            {
                stats.retreats += 1;
                changed = true;
            }
        }
        let p: &[DVec3] = positions;
        twisted.retain(|&f| is_twisted(mesh.face(f as usize), p));
        if !changed {
            break;
        }
    }
    stats.remaining = twisted_quads(mesh, positions).len() as u64;
    stats
}

/// Moves the corners of quad `f` that can move back (interior or
/// non-manifold, away from the input) toward their input positions, one
/// corner alone (in corner order), then all of them together, then with
/// up to [`FOLD_WIDENINGS`] more rings of such vertices, each by the
/// smallest of [`RETREATS`](super::inverted::RETREATS) that untwists the
/// quad and adds no defect; keeps the first such move.
#[allow(clippy::too_many_arguments)]
fn retreat_corners(
    mesh: &Mesh,
    topo: &Topology,
    f: u32,
    positions: &mut [DVec3],
    input: &[DVec3],
    tester: &mut MoveTester,
    cluster: &mut Cluster,
    accept: &dyn Fn(&Verdict) -> bool,
) -> bool {
    let Some((corners, n)) = movable_corners(mesh, topo, f, positions, input) else {
        return false;
    };
    let corners = &corners[..n];
    for single in corners.iter().map(std::slice::from_ref) {
        cluster.set(single);
        if cluster
            .retreat(mesh, topo, positions, input, tester, 1.0, accept)
            .is_some()
        {
            return true;
        }
    }
    if n == 0 {
        return false;
    }
    cluster.set(corners);
    cluster
        .retreat_widening(
            mesh,
            topo,
            positions,
            input,
            tester,
            1.0,
            accept,
            FOLD_WIDENINGS,
        )
        .is_some()
}

fn count_twisted_around(mesh: &Mesh, topo: &Topology, v: usize, positions: &[DVec3]) -> u32 {
    topo.vertex_faces(v)
        .iter()
        .filter(|&&f| is_twisted(mesh.face(f as usize), positions))
        .count() as u32
}

/// Tries the swaps of quad `f`'s edges shared with another twisted quad, in
/// corner order; keeps the first accepted one.
fn swap_with_twisted_neighbour(
    mesh: &Mesh,
    topo: &Topology,
    f: u32,
    positions: &mut [DVec3],
    input: &[DVec3],
    tester: &mut MoveTester,
    stats: &mut TwistedStats,
) -> bool {
    let face = mesh.face(f as usize);
    for j in 0..4 {
        let (a, b) = (face[j] as usize, face[(j + 1) % 4] as usize);
        if topo.kind(a) != VertexKind::Interior || topo.kind(b) != VertexKind::Interior {
            continue;
        }
        let Some(e) = topo.edge(a, b) else {
            continue;
        };
        let shares_twisted = topo
            .edge_faces(e)
            .iter()
            .any(|&g| g != f && is_twisted(mesh.face(g as usize), positions));
        if !shares_twisted {
            continue;
        }
        tester.begin(mesh, topo, &[a, b], positions, input, 1.0);
        let (pa, pb) = (positions[a], positions[b]);
        let verdict = tester.judge(mesh, &[(a, pb), (b, pa)], positions);
        if untwists(&verdict) {
            positions[a] = pb;
            positions[b] = pa;
            stats.swaps += 1;
            return true;
        }
        stats.rejected += 1;
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quality::fixtures::{at, grid, patch};
    use crate::quality::local::face_state;
    use crate::report::measure_stage;

    #[test]
    fn a_swapped_pair_is_swapped_back() {
        let m = grid(4);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let (a, b) = (at(4, 1, 2), at(4, 2, 2));
        let mut p = input.clone();
        p.swap(a, b);
        let before = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert!(before.twisted_quads >= 2, "the fixture has a twisted pair");
        let stats = fix_twisted_quads(&m, &t, &mut p, &input, None, 10, 0.5);
        assert_eq!(stats.found, before.twisted_quads);
        assert!(stats.swaps >= 1);
        assert_eq!(stats.remaining, 0);
        let after = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert_eq!((after.twisted_quads, after.inverted_faces), (0, 0));
        assert_eq!(p, input, "the swap restores the grid exactly");
    }

    #[test]
    fn a_lone_twisted_quad_is_untwisted_by_relocation() {
        let m = grid(4);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        // Vertex (2,2), corner v3 of the quad below-left, pulled across that
        // quad's split diagonal v1-v3: the quad folds over it.
        let v = at(4, 2, 2);
        p[v] = DVec3::new(0.8, 1.5, 0.1);
        let before = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert!(before.twisted_quads >= 1);
        let stats = fix_twisted_quads(&m, &t, &mut p, &input, None, 10, 0.5);
        assert_eq!(stats.remaining, 0, "{stats:?}");
        let after = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert_eq!(after.twisted_quads, 0);
        assert!(after.inverted_faces <= before.inverted_faces);
        assert!(p.iter().all(|q| q.z.abs() <= 0.2), "stays near the plane");
    }

    #[test]
    fn a_twisted_quad_goes_back_toward_the_input() {
        // The fixture of the relocation test, without the relocation: its
        // corners move back toward the input by the smallest fraction that
        // untwists it.
        let m = grid(4);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        let v = at(4, 2, 2);
        p[v] = DVec3::new(0.8, 1.5, 0.1);
        let f = (0..m.num_faces() as u32)
            .find(|&f| is_twisted(m.face(f as usize), &p))
            .expect("the fixture twists a quad");
        let twisted = p.clone();
        let mut tester = MoveTester::default();
        let mut cluster = Cluster::default();
        assert!(retreat_corners(
            &m,
            &t,
            f,
            &mut p,
            &input,
            &mut tester,
            &mut cluster,
            &untwists
        ));
        assert!(!is_twisted(m.face(f as usize), &p));
        let moved: Vec<usize> = (0..p.len()).filter(|&w| p[w] != twisted[w]).collect();
        assert_eq!(moved, [v]);
        let back = (p[v] - twisted[v]).length() / (input[v] - twisted[v]).length();
        assert!(
            crate::quality::inverted::RETREATS
                .iter()
                .any(|&r| (r - back).abs() < 1e-12),
            "{back}"
        );
        let after = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert_eq!((after.twisted_quads, after.inverted_faces), (0, 0));
    }

    /// Runs the fix on a real patch (`fixtures::patch`) with a twisted
    /// quad: none is left. Returns the mesh, its topology, the input
    /// positions and the fixed ones.
    fn untwisted(text: &str) -> (Mesh, Topology, Vec<DVec3>, Vec<DVec3>) {
        let (m, input, mut p) = patch(text);
        let t = Topology::build(&m);
        let stats = fix_twisted_quads(&m, &t, &mut p, &input, None, 10, 0.5);
        assert!(stats.found >= 1, "{stats:?}");
        assert_eq!(stats.remaining, 0, "{stats:?}");
        (m, t, input, p)
    }

    #[test]
    fn a_twisted_quad_pinned_by_its_neighbours_goes_back_with_them() {
        // Two corners of the quad are the ends of a non-manifold edge of a
        // 0.5 x 0.5 x 3 mm mask; the other two crossed along the deep
        // axis. No relocation untwists it, and its corners alone cannot go
        // back without folding the quads around them. Either last resort
        // untwists it (the corners going back with the ring around them,
        // or a neighbour's split corner opening past 160 degrees); without
        // both it stays.
        let (m, t, input, p) = untwisted(include_str!("testdata/thick_slice_twisted.txt"));
        let after = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert_eq!((after.twisted_quads, after.inverted_faces), (0, 0));
    }

    #[test]
    fn a_twisted_quad_may_open_a_neighbour_up_to_170_degrees() {
        // The same configuration elsewhere (a mask thresholded lower): only
        // a retreat of the corners with the rings around them untwists the
        // quad, and only by opening a split corner of a quad next to it
        // past 160 degrees. It stays twisted without either.
        let (m, _, input, p) = untwisted(include_str!("testdata/thick_slice_twisted_wide.txt"));
        let widest = (0..m.num_faces())
            .map(|f| face_state(m.face(f), &p, &input).wide_cos)
            .fold(1.0f64, f64::min);
        assert!(
            widest >= UNTWIST_CORNER_COS,
            "{}",
            widest.acos().to_degrees()
        );
    }

    #[test]
    fn boundary_vertices_never_move() {
        let m = grid(2);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        p.swap(at(2, 0, 0), at(2, 1, 0)); // both on the boundary
        let moved = p.clone();
        let stats = fix_twisted_quads(&m, &t, &mut p, &input, None, 10, 0.5);
        assert!(stats.found >= 1);
        for v in 0..p.len() {
            if t.kind(v) != VertexKind::Interior {
                assert_eq!(p[v], moved[v], "boundary vertex {v} moved");
            }
        }
    }
}
