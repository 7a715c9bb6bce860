//! Inverted-face fix (an addition to the paper's section 2.4): a fold the
//! smoothing left, where a face points against its input orientation.
//!
//! A fold usually spans several vertices (a thin ridge of a voxel mask
//! pinched by the fits from both sides), so no single-vertex move within
//! its star can open it, and the sharp-angle fix's relocations leave it.
//! This fix moves a whole fold back towards the input, where no face is
//! inverted by definition: the vertices of a cluster of inverted faces
//! (faces sharing a vertex) that can move (interior or non-manifold, away
//! from their input position, see `movable`) are moved together by the
//! fraction `t` of the way to their input positions, trying the
//! [`RETREATS`] from the smallest, and the
//! first move that leaves fewer inverted faces and makes nothing worse is
//! kept (see `MoveTester`; a retreat may move a vertex farther than its
//! longest edge, the reach that guards the fixes against a fit gone wrong:
//! it goes back the way the vertex came, as across thick slices, where
//! vertices move along the deep axis by more than an in-plane edge). When
//! none is, the cluster takes in such
//! vertices one ring further out and tries again, at most [`FOLD_WIDENINGS`]
//! times, then as many times takes in the movable corners of the faces its
//! full retreat would fold (on an input of slivers, where each new ring
//! leaves such faces at its rim). The result gives up a little smoothing where the fold was, and
//! only there. It runs after the sharp-angle fix, which opens most folds by
//! single-vertex moves that keep the smoothing; on the synthetic shapes it
//! leaves none, so this fix moves nothing there.
//!
//! Order: sequential, clusters in ascending order of their smallest face
//! (deterministic); each sweep scans the whole mesh for inverted faces;
//! the fix stops after a sweep that changes nothing, when none is left, or
//! after `max_sweeps`. Only interior and non-manifold vertices move.

use super::local::{MoveTester, Verdict, has_repeated_corner, is_inverted};
use crate::mesh::{Mesh, Topology, VertexKind};
use crate::smoothing::fidelity::FidelityBound;
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Fractions of the way back to the input tried for a cluster, smallest
/// first: the least smoothing given up that opens the fold.
pub const RETREATS: [f64; 5] = [0.125, 0.25, 0.5, 0.75, 1.0];

/// How many times a fold's cluster may take in one more ring of vertices.
/// In a mesh of slivers (the marching cubes of a probability map, where
/// the surface passing near a grid node leaves a sliver in most cubes) a
/// fold spreads over a few rings of faces that each turn with a small
/// move, and going back only part of the way reopens it at the cluster's
/// rim. A fold outranks the smoothing given up to open it; the search stays
/// linear (each widening is one ring of a cluster of at most
/// [`MAX_CLUSTER_FACES`] faces).
pub const FOLD_WIDENINGS: usize = 4;

/// Largest cluster of inverted faces moved as one; a larger one (a mesh
/// turned inside out over a whole region) is left as it is.
pub const MAX_CLUSTER_FACES: usize = 64;

/// Most vertices a cluster's widenings take in: a few rings around
/// vertices of high valence (the pipeline takes a thousand edges) could
/// otherwise take in much of the mesh, and judging a move costs its
/// vertices' faces, so a mesh of many such folds would cost the square of
/// its size. The rings around a fold of a few faces stay far below it.
pub const MAX_CLUSTER_VERTICES: usize = 512;

/// What the inverted-face fix did.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct InvertedStats {
    /// Faces inverted relative to the input before the fix.
    pub found: u64,
    /// Accepted cluster moves towards the input.
    pub retreats: u64,
    /// Vertices those moves moved (a vertex moved twice counts twice).
    pub vertices_moved: u64,
    /// Clusters no tried move could open.
    pub rejected: u64,
    /// Sweeps run.
    pub sweeps: u64,
    /// Inverted faces after the fix.
    pub remaining: u64,
}

/// Moves folds back towards `input` (one position per vertex, like
/// `positions`, which are moved in place); at most `max_sweeps` sweeps.
pub fn fix_inverted_faces(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    input: &[DVec3],
    bound: Option<&FidelityBound>,
    max_sweeps: u32,
) -> InvertedStats {
    let rule = RetreatRule {
        bad: &|face, p| is_inverted(face, p, input),
        cos_goal: 1.0,
        accept: &|v| !v.new_defect && v.inverted.1 < v.inverted.0 && v.twisted.1 <= v.twisted.0,
        fallback: None,
        widenings: FOLD_WIDENINGS,
        refold_growths: FOLD_WIDENINGS,
        corner_subsets: false,
    };
    let s = retreat_sweeps(mesh, topo, positions, input, bound, max_sweeps, &rule);
    InvertedStats {
        found: s.found,
        retreats: s.retreats,
        vertices_moved: s.vertices_moved,
        rejected: s.rejected,
        sweeps: s.sweeps,
        remaining: s.remaining,
    }
}

/// What a fix that moves clusters of faces back toward the input repairs
/// and which move it keeps: the fold fix here, the sliver fix in
/// [`super::sliver`].
pub(super) struct RetreatRule<'r> {
    /// Whether a face, at the given positions, needs the repair.
    pub bad: &'r (dyn Fn(&[u32], &[DVec3]) -> bool + Sync),
    /// The angle goal the tried moves are judged against (cosine).
    pub cos_goal: f64,
    /// Whether a tried move repairs the cluster.
    pub accept: &'r dyn Fn(&Verdict) -> bool,
    /// What is kept when no widening of the cluster gives an accepted
    /// move, tried from the narrowest cluster out; `None`: nothing.
    pub fallback: Option<&'r dyn Fn(&Verdict) -> bool>,
    /// How many times a cluster may take in one more ring of vertices.
    pub widenings: usize,
    /// How many times, once its widenings are spent, a cluster may take in
    /// the corners of the faces its full retreat would leave inverted
    /// ([`Cluster::retreat_refolded`]); 0: never.
    pub refold_growths: usize,
    /// Whether, once a sweep's cluster retreats moved nothing, the later
    /// sweeps also try, for a cluster no widening of which gives a kept
    /// move, the movable corners of the face it was gathered from in
    /// subsets, fewest corners first ([`retreat_corner_subsets`]).
    pub corner_subsets: bool,
}

/// What [`retreat_sweeps`] did; each fix reports it under its own name.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Sweeps {
    pub found: u64,
    pub retreats: u64,
    pub vertices_moved: u64,
    pub rejected: u64,
    pub sweeps: u64,
    pub remaining: u64,
}

fn faces_where(mesh: &Mesh, positions: &[DVec3], rule: &RetreatRule) -> Vec<u32> {
    (0..mesh.num_faces() as u32)
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&f| (rule.bad)(mesh.face(f as usize), positions))
        .collect()
}

/// Moves the clusters of `rule.bad` faces back towards `input` (see the
/// module docs), at most `max_sweeps` sweeps.
pub(super) fn retreat_sweeps(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    input: &[DVec3],
    bound: Option<&FidelityBound>,
    max_sweeps: u32,
    rule: &RetreatRule,
) -> Sweeps {
    let mut left = faces_where(mesh, positions, rule);
    let mut stats = Sweeps {
        found: left.len() as u64,
        ..Sweeps::default()
    };
    let mut tester = MoveTester::bounded(bound).allowing_input_twists();
    let mut cluster = Cluster::default();
    let bad = |f: u32, p: &[DVec3]| (rule.bad)(mesh.face(f as usize), p);
    // The corner subsets join only once the clusters' retreats are stuck:
    // taken earlier, a subset's move can block what a later sweep's
    // cluster retreat would open.
    let mut subsets = false;
    while !left.is_empty() && stats.sweeps < max_sweeps as u64 {
        stats.sweeps += 1;
        let mut changed = false;
        for &f in &left {
            if !bad(f, positions) {
                continue; // repaired by an earlier move of this sweep
            }
            cluster.gather(mesh, topo, f, positions, input, |g| bad(g, positions));
            if cluster.vertices.is_empty() || cluster.faces.len() > MAX_CLUSTER_FACES {
                stats.rejected += 1;
                continue;
            }
            // The fallback starts from the narrowest cluster again: a wider
            // one gives up more smoothing, and its outer ring may refuse
            // every fraction that the narrowest takes.
            let mut moved = None;
            for (k, accept) in std::iter::once(rule.accept)
                .chain(rule.fallback)
                .enumerate()
            {
                if k > 0 {
                    cluster.gather(mesh, topo, f, positions, input, |g| bad(g, positions));
                }
                moved = cluster.retreat_widening(
                    mesh,
                    topo,
                    positions,
                    input,
                    &mut tester,
                    rule.cos_goal,
                    accept,
                    rule.widenings,
                );
                if moved.is_some() {
                    break;
                }
            }
            if moved.is_none() && rule.refold_growths > 0 {
                moved = cluster.retreat_refolded(mesh, topo, positions, input, &mut tester, rule);
            }
            if moved.is_none() && subsets {
                moved = retreat_corner_subsets(
                    mesh,
                    topo,
                    f,
                    positions,
                    input,
                    &mut tester,
                    &mut cluster,
                    rule,
                );
            }
            match moved {
                Some(n) => {
                    stats.retreats += 1;
                    stats.vertices_moved += n as u64;
                    changed = true;
                }
                None => stats.rejected += 1,
            }
        }
        if !changed {
            if subsets || !rule.corner_subsets {
                break;
            }
            subsets = true;
            continue;
        }
        // Rescanned, not only the faces left: a fallback move may lift a
        // cluster's smallest angle while closing a face next to it below
        // the floor, which the next sweep then takes up.
        left = faces_where(mesh, positions, rule);
    }
    stats.remaining = faces_where(mesh, positions, rule).len() as u64;
    stats
}

/// The most movable corners a face may have for [`retreat_corner_subsets`]:
/// a quad's four give fifteen subsets; a polygon's `2^n` would make one
/// face's repair cost grow with the power of its size.
pub const MAX_SUBSET_CORNERS: usize = 4;

/// Moves the movable corners of face `f` (see [`movable`]; at most
/// [`MAX_SUBSET_CORNERS`], else nothing) back toward `input` in every
/// non-empty subset, each by the smallest of [`RETREATS`] that
/// `rule.accept`s, the subsets of one corner first, then of two, and so on
/// (the least smoothing given up first); when none does, the same with
/// `rule.fallback`. Returns how many vertices the kept move moved.
///
/// A cluster moves all its vertices by one fraction. Where the smoothing
/// squeezed a face between corners that moved by different amounts (across
/// a thick slice, a corner on a non-manifold edge beside one that is not),
/// every common fraction that opens it closes a face around another of its
/// corners; going back with some of its corners only opens it.
#[allow(clippy::too_many_arguments)]
fn retreat_corner_subsets(
    mesh: &Mesh,
    topo: &Topology,
    f: u32,
    positions: &mut [DVec3],
    input: &[DVec3],
    tester: &mut MoveTester,
    cluster: &mut Cluster,
    rule: &RetreatRule,
) -> Option<usize> {
    let (corners, n) = movable_corners(mesh, topo, f, positions, input)?;
    let mut subset = [0usize; MAX_SUBSET_CORNERS];
    for accept in std::iter::once(rule.accept).chain(rule.fallback) {
        for size in 1..=n as u32 {
            for mask in (1u32..1 << n).filter(|m| m.count_ones() == size) {
                let mut k = 0;
                for (i, &c) in corners[..n].iter().enumerate() {
                    if mask & (1 << i) != 0 {
                        subset[k] = c;
                        k += 1;
                    }
                }
                cluster.set(&subset[..k]);
                let moved =
                    cluster.retreat(mesh, topo, positions, input, tester, rule.cos_goal, accept);
                if moved.is_some() {
                    return moved;
                }
            }
        }
    }
    None
}

/// The distinct corners of face `f` that can move back ([`movable`]), in
/// corner order, with their count; `None` when there are more than
/// [`MAX_SUBSET_CORNERS`].
pub(super) fn movable_corners(
    mesh: &Mesh,
    topo: &Topology,
    f: u32,
    positions: &[DVec3],
    input: &[DVec3],
) -> Option<([usize; MAX_SUBSET_CORNERS], usize)> {
    let mut corners = [0usize; MAX_SUBSET_CORNERS];
    let mut n = 0;
    for &c in mesh.face(f as usize) {
        let c = c as usize;
        if !movable(topo, c, positions, input) || corners[..n].contains(&c) {
            continue;
        }
        if n == MAX_SUBSET_CORNERS {
            return None;
        }
        corners[n] = c;
        n += 1;
    }
    Some((corners, n))
}

/// True when vertex `v` is interior or non-manifold and away from its input
/// position. The staircase relaxation moves a voxel mesh's non-manifold
/// vertices (where voxels touch along an edge or at a corner) and no later
/// step does: each end of a one-voxel contact edge has the other as its
/// only neighbour along the edge, so the relaxation pulls the two together
/// and squeezes the side walls that share the edge. The relocating fixes
/// cannot move them (they have no single fan to relocate over); going back
/// toward the input, along the way they came, is the one repair left.
pub(super) fn movable(topo: &Topology, v: usize, positions: &[DVec3], input: &[DVec3]) -> bool {
    matches!(topo.kind(v), VertexKind::Interior | VertexKind::NonManifold)
        && positions[v] != input[v]
}

/// The vertices of a cluster of faces in need of repair (inverted faces
/// here, slivers in [`super::sliver`]) that can move back ([`movable`]),
/// with scratch.
#[derive(Debug, Default)]
pub(super) struct Cluster {
    vertices: Vec<usize>,
    faces: Vec<u32>,
    moves: Vec<(usize, DVec3)>,
}

impl Cluster {
    /// The faces for which `bad` holds reachable from face `f` through
    /// shared vertices (at most [`MAX_CLUSTER_FACES`] and one more), and
    /// their vertices that can move back.
    fn gather(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        f: u32,
        positions: &[DVec3],
        input: &[DVec3],
        bad: impl Fn(u32) -> bool,
    ) {
        self.faces.clear();
        self.vertices.clear();
        self.faces.push(f);
        let mut next = 0;
        while next < self.faces.len() {
            let face = mesh.face(self.faces[next] as usize);
            next += 1;
            for &v in face {
                let v = v as usize;
                if self.vertices.contains(&v) {
                    continue;
                }
                if movable(topo, v, positions, input) {
                    self.vertices.push(v);
                }
                for &g in topo.vertex_faces(v) {
                    if self.faces.len() <= MAX_CLUSTER_FACES && !self.faces.contains(&g) && bad(g) {
                        self.faces.push(g);
                    }
                }
            }
        }
    }

    /// The cluster of just `vertices` (no faces gathered).
    pub(super) fn set(&mut self, vertices: &[usize]) {
        self.faces.clear();
        self.vertices.clear();
        self.vertices.extend_from_slice(vertices);
    }

    /// Adds the neighbours of the cluster's vertices that can move back,
    /// up to [`MAX_CLUSTER_VERTICES`] in all; false when there is none to
    /// add.
    fn widen(&mut self, topo: &Topology, positions: &[DVec3], input: &[DVec3]) -> bool {
        let before = self.vertices.len();
        for i in 0..before {
            for &w in topo.neighbors(self.vertices[i]) {
                let w = w as usize;
                if self.vertices.len() >= MAX_CLUSTER_VERTICES {
                    return self.vertices.len() > before;
                }
                if movable(topo, w, positions, input) && !self.vertices.contains(&w) {
                    self.vertices.push(w);
                }
            }
        }
        self.vertices.len() > before
    }

    /// [`Cluster::retreat`], taking in one more ring of vertices after each
    /// refusal, at most `widenings` times.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn retreat_widening(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        positions: &mut [DVec3],
        input: &[DVec3],
        tester: &mut MoveTester,
        cos_goal: f64,
        accept: &dyn Fn(&Verdict) -> bool,
        widenings: usize,
    ) -> Option<usize> {
        for widening in 0..=widenings {
            if widening > 0 && !self.widen(topo, positions, input) {
                break;
            }
            let moved = self.retreat(mesh, topo, positions, input, tester, cos_goal, accept);
            if moved.is_some() {
                return moved;
            }
        }
        None
    }

    /// [`Cluster::retreat`] after taking in the movable corners of the
    /// faces around the cluster that its full retreat would leave inverted,
    /// at most `rule.refold_growths` times (and [`MAX_CLUSTER_VERTICES`]
    /// vertices); judged by `rule.accept` alone.
    ///
    /// On an input full of slivers (an isosurface of a noisy image, whose
    /// angles go down to a tenth of a degree) a fold's rings hold faces
    /// whose orientation turns with a hundredth of an edge: each ring the
    /// widenings take in leaves faces with some corners back at the input
    /// and some not, which the retreat folds. The faces it folds say which
    /// corners must come back with the cluster.
    pub(super) fn retreat_refolded(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        positions: &mut [DVec3],
        input: &[DVec3],
        tester: &mut MoveTester,
        rule: &RetreatRule,
    ) -> Option<usize> {
        for _ in 0..rule.refold_growths {
            if !self.take_in_refolded(mesh, topo, positions, input) {
                break;
            }
            let moved = self.retreat(
                mesh,
                topo,
                positions,
                input,
                tester,
                rule.cos_goal,
                rule.accept,
            );
            if moved.is_some() {
                return moved;
            }
        }
        None
    }

    /// Adds the movable corners of the faces around the cluster that are
    /// inverted with every cluster vertex back at its input position (up to
    /// [`MAX_CLUSTER_VERTICES`] in all); false when there is none to add.
    /// `positions` are as they were on return.
    fn take_in_refolded(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        positions: &mut [DVec3],
        input: &[DVec3],
    ) -> bool {
        self.moves.clear();
        self.moves
            .extend(self.vertices.iter().map(|&v| (v, positions[v])));
        for &v in &self.vertices {
            positions[v] = input[v];
        }
        // The corners taken in keep their positions, so they are pushed as
        // found; only the vertices there before are back at the input.
        let before = self.vertices.len();
        for i in 0..before {
            for &f in topo.vertex_faces(self.vertices[i]) {
                let face = mesh.face(f as usize);
                if has_repeated_corner(face) || !is_inverted(face, positions, input) {
                    continue;
                }
                for &c in face {
                    let c = c as usize;
                    if self.vertices.len() < MAX_CLUSTER_VERTICES
                        && movable(topo, c, positions, input)
                        && !self.vertices.contains(&c)
                    {
                        self.vertices.push(c);
                    }
                }
            }
        }
        for &(v, p) in &self.moves {
            positions[v] = p;
        }
        self.vertices.len() > before
    }

    /// Tries the [`RETREATS`] of the cluster's vertices, smallest first,
    /// judged against the angle goal `cos_goal`; applies the first that
    /// `accept`s and returns how many vertices it moved.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn retreat(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        positions: &mut [DVec3],
        input: &[DVec3],
        tester: &mut MoveTester,
        cos_goal: f64,
        accept: &dyn Fn(&Verdict) -> bool,
    ) -> Option<usize> {
        tester.begin(mesh, topo, &self.vertices, positions, input, cos_goal);
        tester.reaching_input(positions, input);
        for t in RETREATS {
            self.moves.clear();
            self.moves.extend(
                self.vertices
                    .iter()
                    .map(|&v| (v, positions[v] + t * (input[v] - positions[v]))),
            );
            if accept(&tester.judge(mesh, &self.moves, positions)) {
                for &(w, p) in &self.moves {
                    positions[w] = p;
                }
                return Some(self.moves.len());
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quality::fixtures::{at, grid, patch};
    use crate::quality::is_defective;
    use crate::report::measure_stage;

    /// A flat 6 x 6 grid, its topology, its positions, and two neighbours
    /// along x in its middle row, (2, 3) and (3, 3).
    fn grid_with_two_neighbours() -> (Mesh, Topology, Vec<DVec3>, usize, usize) {
        let m = grid(6);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        (m, t, input, at(6, 2, 3), at(6, 3, 3))
    }

    #[test]
    fn a_fold_of_two_vertices_goes_back_as_one() {
        // Two neighbours of a flat grid pushed past each other: the faces
        // around them fold, and both move back together.
        let (m, t, input, a, b) = grid_with_two_neighbours();
        let mut p = input.clone();
        p[a] = DVec3::new(3.6, 3.0, 0.0);
        p[b] = DVec3::new(2.4, 3.0, 0.0);
        let before = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert!(before.inverted_faces >= 2, "the fixture folds");
        let folded = p.clone();
        let stats = fix_inverted_faces(&m, &t, &mut p, &input, None, 10);
        assert_eq!(stats.found, before.inverted_faces);
        assert_eq!((stats.retreats, stats.remaining), (1, 0), "{stats:?}");
        assert!((0..m.num_faces()).all(|f| !is_defective(&m, f, &p, &input)));
        for v in 0..p.len() {
            if v != a && v != b {
                assert_eq!(p[v], folded[v], "vertex {v} is not in the fold");
            }
        }
        // Half way back they still cross (2.8 > 2.7); three quarters of the
        // way (2.4 < 2.85) they do not.
        let blend = |v: usize| folded[v] + 0.75 * (input[v] - folded[v]);
        assert_eq!((p[a], p[b]), (blend(a), blend(b)));
    }

    #[test]
    fn a_fold_goes_back_by_the_smallest_fraction_that_opens_it() {
        let m = grid(6);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let a = at(6, 2, 3);
        let mut p = input.clone();
        // Past its neighbour (3, 3): a quarter of the way back (x = 3.05)
        // is still past it, half of the way (x = 2.7) is not.
        p[a] = DVec3::new(3.4, 3.0, 0.0);
        let stats = fix_inverted_faces(&m, &t, &mut p, &input, None, 10);
        assert_eq!((stats.retreats, stats.remaining), (1, 0), "{stats:?}");
        assert!(
            (p[a] - DVec3::new(2.7, 3.0, 0.0)).length() < 1e-12,
            "{}",
            p[a]
        );
        assert_eq!(stats.vertices_moved, 1);
    }

    #[test]
    fn boundary_vertices_never_move() {
        let m = grid(2);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        // A boundary corner pushed across the grid: only the boundary vertex
        // could open the fold.
        let corner = at(2, 0, 0);
        p[corner] = DVec3::new(1.5, 1.5, 0.0);
        let moved = p.clone();
        let stats = fix_inverted_faces(&m, &t, &mut p, &input, None, 10);
        assert!(stats.found >= 1);
        assert_eq!(stats.remaining, stats.found);
        assert!(stats.rejected >= 1);
        assert_eq!(p, moved);
    }

    #[test]
    fn an_unfolded_mesh_is_left_alone() {
        let m = grid(4);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        p[at(4, 2, 2)].z = 0.3;
        let bumped = p.clone();
        let stats = fix_inverted_faces(&m, &t, &mut p, &input, None, 10);
        assert_eq!(stats, InvertedStats::default());
        assert_eq!(p, bumped);
    }

    #[test]
    fn a_cluster_takes_in_the_corners_its_retreat_would_fold() {
        // Vertex a moved left to x = 1.5, its right neighbour b to x = 1.8,
        // beyond a's input (x = 2): nothing is folded, but a going back
        // alone would land past b and fold the faces between them.
        let (m, t, input, a, b) = grid_with_two_neighbours();
        let mut p = input.clone();
        p[a].x = 1.5;
        p[b].x = 1.8;
        let before = p.clone();
        let mut cluster = Cluster::default();
        cluster.set(&[a]);
        assert!(cluster.take_in_refolded(&m, &t, &mut p, &input));
        assert_eq!(cluster.vertices, vec![a, b]);
        assert_eq!(p, before, "the trial is undone");
        assert!(!cluster.take_in_refolded(&m, &t, &mut p, &input));
        // The two go back together.
        let rule = RetreatRule {
            bad: &|face, q| is_inverted(face, q, &input),
            cos_goal: 1.0,
            accept: &|v| !v.new_defect,
            fallback: None,
            widenings: 0,
            refold_growths: 1,
            corner_subsets: false,
        };
        let mut tester = MoveTester::default();
        cluster.set(&[a]);
        assert_eq!(
            cluster.retreat_refolded(&m, &t, &mut p, &input, &mut tester, &rule),
            Some(2)
        );
        assert!((0..m.num_faces()).all(|f| !is_defective(&m, f, &p, &input)));
    }

    #[test]
    fn a_fold_among_the_slivers_of_a_noisy_isosurface_opens() {
        // A real patch (`testdata/README.md`): every ring the widenings
        // take in leaves a sliver at the cluster's rim that the retreat
        // folds; the corners of those faces, taken in, let it go back.
        let (m, input, mut p) = patch(include_str!("testdata/noisy_isosurface_fold.txt"));
        let t = Topology::build(&m);
        let stats = fix_inverted_faces(&m, &t, &mut p, &input, None, 20);
        assert_eq!((stats.found, stats.remaining), (1, 0), "{stats:?}");
        assert!((0..m.num_faces()).all(|f| !is_defective(&m, f, &p, &input)));
    }

    #[test]
    fn widening_around_a_hub_stops_at_the_cluster_cap() {
        // A double cone: two hubs of valence 800 joined by a ring. From the
        // top hub, one widening would take in the whole ring.
        let n = 800u32;
        let mut p = vec![DVec3::Z, -DVec3::Z];
        for k in 0..n {
            let a = std::f64::consts::TAU * f64::from(k) / f64::from(n);
            p.push(DVec3::new(a.cos(), a.sin(), 0.0));
        }
        let mut f = Vec::new();
        for k in 0..n {
            let (a, b) = (2 + k, 2 + (k + 1) % n);
            f.push([0, a, b]);
            f.push([1, b, a]);
        }
        let m = Mesh::from_polygons(p, &f).expect("valid double cone");
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let moved: Vec<DVec3> = input.iter().map(|&q| q * 0.99).collect();
        let mut cluster = Cluster::default();
        cluster.set(&[0]);
        assert!(cluster.widen(&t, &moved, &input));
        assert_eq!(cluster.vertices.len(), MAX_CLUSTER_VERTICES);
        assert!(!cluster.widen(&t, &moved, &input));
    }
}
