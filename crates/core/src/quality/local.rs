//! Per-face predicates shared by the measures and the fixes, and the local
//! acceptance test every quality move goes through.
//!
//! The triangle split is the paper's: a quad `(v1 v2 v3 v4)` splits into
//! `(v1 v2 v3)` and `(v3 v4 v1)`, a general polygon fans from its corner 0
//! (for a quad the fan `(v1 v2 v3), (v1 v3 v4)` is the same pair), and a
//! triangle is itself. Angles are compared through their cosines (cosine
//! falls as the angle grows), so no `acos` runs in the hot loops. A corner
//! with a zero-length side counts as a 0° angle (cosine 1).

use crate::fit::frame::Frame;
use crate::fit::normals::vertex_normal;
use crate::fit::quadric_fit::{FitKind, QuadricFit, fit_quadric};
pub(crate) use crate::mesh::has_repeated_corner;
use crate::mesh::{Mesh, Topology, vector_area};
use crate::smoothing::fidelity::FidelityBound;
use glam::DVec3;

/// Cosine of the angle between `a` and `b`; 1 (a 0° angle) when either is
/// zero or the quotient is not a number.
#[inline]
pub(crate) fn cos_between(a: DVec3, b: DVec3) -> f64 {
    let d = (a.length_squared() * b.length_squared()).sqrt();
    if d > 0.0 {
        let c = a.dot(b) / d;
        if c.is_nan() { 1.0 } else { c.clamp(-1.0, 1.0) }
    } else {
        1.0
    }
}

/// Cosines of the three corner angles of triangle `(a, b, c)`, in corner
/// order.
#[inline]
pub(crate) fn triangle_cosines(a: DVec3, b: DVec3, c: DVec3) -> [f64; 3] {
    let ab = b - a;
    let bc = c - b;
    let ca = a - c;
    [
        cos_between(ab, -ca),
        cos_between(bc, -ab),
        cos_between(ca, -bc),
    ]
}

/// The positions of the first `N` corners of `face`, which has at least
/// `N` (an array `map` here was left out of line: a call per face).
#[inline(always)]
pub(crate) fn corners<const N: usize>(face: &[u32], positions: &[DVec3]) -> [DVec3; N] {
    let mut out = [DVec3::ZERO; N];
    for (o, &v) in out.iter_mut().zip(face) {
        *o = positions[v as usize];
    }
    out
}

/// Calls `f(a, b, c)` for each triangle of the split of `face`, with the
/// corners' positions.
#[inline]
pub(crate) fn for_each_split_triangle(
    face: &[u32],
    positions: &[DVec3],
    mut f: impl FnMut(DVec3, DVec3, DVec3),
) {
    let o = positions[face[0] as usize];
    for j in 1..face.len().saturating_sub(1) {
        f(
            o,
            positions[face[j] as usize],
            positions[face[j + 1] as usize],
        );
    }
}

/// Cosine from a dot product and two squared lengths; 1 (a 0° angle) when
/// a length is zero or the quotient is not a number.
#[inline]
fn cos_from(dot: f64, l1: f64, l2: f64) -> f64 {
    let d = (l1 * l2).sqrt();
    if d > 0.0 {
        let c = dot / d;
        if c.is_nan() { 1.0 } else { c.clamp(-1.0, 1.0) }
    } else {
        1.0
    }
}

/// Cosine of the smallest angle of triangle `(a, b, c)`: the angle opposite
/// its shortest side.
#[inline]
pub(crate) fn min_angle_cos(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let ab = b - a;
    let bc = c - b;
    let ca = a - c;
    let (x, y, z) = (
        ab.length_squared(),
        bc.length_squared(),
        ca.length_squared(),
    );
    if x <= y && x <= z {
        cos_from(-ca.dot(bc), z, y) // at c
    } else if y <= z {
        cos_from(-ab.dot(ca), x, z) // at a
    } else {
        cos_from(-bc.dot(ab), y, x) // at b
    }
}

/// Largest cosine (that is, the smallest angle) over the split triangles'
/// corners of `face`.
#[inline]
pub(crate) fn max_split_cos(face: &[u32], positions: &[DVec3]) -> f64 {
    let mut m = -1.0f64;
    for_each_split_triangle(face, positions, |a, b, c| {
        m = m.max(min_angle_cos(a, b, c));
    });
    m
}

/// Whether `face` has a split-triangle angle whose cosine exceeds
/// `cos_floor` at `positions` (a face with a repeated corner never has).
#[inline]
pub(crate) fn has_angle_below(face: &[u32], positions: &[DVec3], cos_floor: f64) -> bool {
    !has_repeated_corner(face) && max_split_cos(face, positions) > cos_floor
}

/// A quad is twisted when the normals of its split triangles `(v1 v2 v3)`
/// and `(v3 v4 v1)` are more than 90° apart. Other faces are never twisted.
#[inline]
pub(crate) fn is_twisted(face: &[u32], positions: &[DVec3]) -> bool {
    if face.len() != 4 {
        return false;
    }
    let [p1, p2, p3, p4] = corners(face, positions);
    let n1 = (p2 - p1).cross(p3 - p1);
    let n2 = (p4 - p3).cross(p1 - p3);
    n1.dot(n2) < 0.0
}

/// A face is inverted relative to the input when its vector area, or the
/// normal of any of its split triangles, points against the same quantity
/// in `input` (negative dot product). A quad the input has twisted is
/// judged by its vector area alone: its split triangles face opposite ways
/// in the input, so no untwisted position keeps both, and the quad's
/// orientation is its vector area's.
#[inline]
pub(crate) fn is_inverted(face: &[u32], positions: &[DVec3], input: &[DVec3]) -> bool {
    if vector_area(face, positions).dot(vector_area(face, input)) < 0.0 {
        return true;
    }
    if face.len() == 3 || is_twisted(face, input) {
        return false;
    }
    let (o, o0) = (positions[face[0] as usize], input[face[0] as usize]);
    (1..face.len() - 1).any(|j| {
        let (a, b) = (face[j] as usize, face[j + 1] as usize);
        let n = (positions[a] - o).cross(positions[b] - o);
        let n0 = (input[a] - o0).cross(input[b] - o0);
        n.dot(n0) < 0.0
    })
}

/// The state of one face that moves are judged on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct FaceState {
    pub inverted: bool,
    pub twisted: bool,
    /// Cosine of the face's smallest split-triangle angle.
    pub max_cos: f64,
    /// Cosine of the wider of a quad's two corners that its split divides
    /// (corners 1 and 3 of `(v1 v2 v3 v4)`); 1 for other faces. The
    /// split-triangle angles do not bound these corners.
    pub wide_cos: f64,
    /// Sum over the split triangles of `(c - c_goal)^2` where the cosine
    /// `c` of a triangle's smallest angle exceeds the goal's `c_goal`: how
    /// far the face falls short of the angle goal.
    pub deficit: f64,
}

/// The share of its input angle that a sliver of the input keeps through
/// the angle-only moves of the sharp-angle fix ([`MoveTester::guarding`]).
/// The sliver fix holds the faces the input had sound to the sliver floor,
/// a fraction of the sharp-angle threshold
/// ([`SLIVER_FRACTION`](super::SLIVER_FRACTION)), but cannot help a face
/// that was a sliver already (going back to the input does not open it):
/// without a floor of its own, the sharp-angle fix's moves that lower the
/// summed angle deficit of a star may close such a face down to the
/// mesh's smallest angle, and a marching-cubes mesh of voxels six times
/// as deep as wide, whose faces along the deep axis are needles of 6-7
/// degrees, then ends with hundreds of angles under 1 degree. The same
/// fraction as the sliver floor's: each face is held to at least half of
/// what it started from, and closer to it just under the guard
/// ([`input_sliver_floor`]).
pub(crate) const INPUT_SLIVER_KEEP: f64 = super::SLIVER_FRACTION;

/// The cosine of the smallest angle the angle-only moves may leave a face
/// whose smallest input angle has the cosine `input_cos`: for a sliver of
/// the input (sharper than the guard, the angle of cosine `cos_guard`),
/// the larger of [`INPUT_SLIVER_KEEP`] of that angle and the angle less
/// its shortfall to the guard (`2 angle - guard`); 1 (no floor) for the
/// others. The second term makes the floor continuous at the guard, where
/// the sliver fix holds the faces the input had sound: a face of 9.9
/// degrees under a guard of 10 keeps 9.8, not 4.95. It binds within a
/// third of the guard below it, where the side walls of voxels four times
/// as deep as wide lie (9.9 degrees on their marching cubes); a needle
/// sharper than two thirds of the guard keeps half its angle.
fn input_sliver_floor(input_cos: f64, cos_guard: f64) -> f64 {
    if input_cos > cos_guard {
        let angle = input_cos.clamp(-1.0, 1.0).acos();
        let guard = cos_guard.clamp(-1.0, 1.0).acos();
        (INPUT_SLIVER_KEEP * angle).max(2.0 * angle - guard).cos()
    } else {
        1.0
    }
}

/// The cosine of the smallest angle a move that only trades the angles
/// for something else (the volume restoration's last offset) may leave
/// `face`, now at `positions`, with `cos_keep` the cosine of an angle a
/// face at or above it keeps (at most the guard's angle) and the sliver
/// floor of cosine `cos_guard`: `cos_keep` for a face at or above it; the
/// floor for a face above the floor; for a face already sharper, the floor
/// the sharp-angle fix holds it to when the input had it sharper too
/// ([`input_sliver_floor`]), and its own angle where it is sharper still
/// or the input had it sound. A face with a repeated corner has no angle
/// (-1).
pub(crate) fn closing_floor_cos(
    face: &[u32],
    positions: &[DVec3],
    input: &[DVec3],
    cos_keep: f64,
    cos_guard: f64,
) -> f64 {
    if has_repeated_corner(face) {
        return -1.0;
    }
    let now = max_split_cos(face, positions);
    if now <= cos_keep {
        return cos_keep;
    }
    if now <= cos_guard {
        return cos_guard;
    }
    let held = input_sliver_floor(max_split_cos(face, input), cos_guard);
    // 1 (no floor): the input had the face sound, and it closes no further.
    if held < 1.0 { now.max(held) } else { now }
}

/// A move may not open a quad's split corner beyond this angle (cosine of
/// 160°), unless the corner was already wider.
pub(crate) const WIDEST_CORNER_COS: f64 = -0.939_692_620_785_908_4;

/// Twice the area-weighted normals of the split triangles of `face` (fan
/// from corner 0), appended to `out`, followed by their sum (twice the
/// vector area).
#[inline]
fn push_split_normals(face: &[u32], positions: &[DVec3], out: &mut Vec<DVec3>) {
    let o = positions[face[0] as usize];
    let mut sum = DVec3::ZERO;
    for j in 1..face.len() - 1 {
        let n = (positions[face[j] as usize] - o).cross(positions[face[j + 1] as usize] - o);
        sum += n;
        out.push(n);
    }
    out.push(sum);
}

/// Whether a face of `k` corners whose split normals are `normals` (as
/// written by `push_split_normals`) is a twisted quad ([`is_twisted`]).
#[inline]
fn split_normals_twisted(k: usize, normals: &[DVec3]) -> bool {
    k == 4 && normals[0].dot(normals[1]) < 0.0
}

/// State of `face` given the split normals of the input (as written by
/// `push_split_normals`).
#[inline]
fn face_state_with(
    face: &[u32],
    positions: &[DVec3],
    input_normals: &[DVec3],
    cos_goal: f64,
) -> FaceState {
    face_state_at(face, |w| positions[w as usize], input_normals, cos_goal)
}

/// [`face_state_with`] reading corner positions through `pos`.
#[inline]
fn face_state_at(
    face: &[u32],
    pos: impl Fn(u32) -> DVec3,
    input_normals: &[DVec3],
    cos_goal: f64,
) -> FaceState {
    let o = pos(face[0]);
    let k = face.len();
    // A quad the input has twisted: its vector area alone says whether it
    // is inverted (see `is_inverted`).
    let split_oriented = k > 3 && !split_normals_twisted(k, input_normals);
    let mut sum = DVec3::ZERO;
    let mut first = DVec3::ZERO;
    let mut inverted = false;
    let mut twisted = false;
    let mut max_cos = -1.0f64;
    let mut deficit = 0.0;
    for j in 1..k - 1 {
        let a = pos(face[j]);
        let b = pos(face[j + 1]);
        let n = (a - o).cross(b - o);
        if split_oriented {
            inverted |= n.dot(input_normals[j - 1]) < 0.0;
        }
        if j == 1 {
            first = n;
        } else if k == 4 {
            twisted = first.dot(n) < 0.0;
        }
        sum += n;
        let c = min_angle_cos(o, a, b);
        max_cos = max_cos.max(c);
        let short = (c - cos_goal).max(0.0);
        deficit += short * short;
    }
    inverted |= sum.dot(input_normals[k - 2]) < 0.0;
    let wide_cos = if k == 4 {
        let (p1, p2, p3) = (pos(face[1]), pos(face[2]), pos(face[3]));
        cos_between(p1 - o, p3 - o).min(cos_between(p1 - p2, p3 - p2))
    } else {
        1.0
    };
    FaceState {
        inverted,
        twisted,
        max_cos,
        wide_cos,
        deficit,
    }
}

/// State of `face` at `positions` against `input`.
#[inline]
pub(crate) fn face_state(face: &[u32], positions: &[DVec3], input: &[DVec3]) -> FaceState {
    let mut buf = [DVec3::ZERO; 8];
    if face.len() <= 7 {
        let o = input[face[0] as usize];
        let mut sum = DVec3::ZERO;
        for j in 1..face.len() - 1 {
            let n = (input[face[j] as usize] - o).cross(input[face[j + 1] as usize] - o);
            buf[j - 1] = n;
            sum += n;
        }
        buf[face.len() - 2] = sum;
        face_state_with(face, positions, &buf, 1.0)
    } else {
        let mut v = Vec::with_capacity(face.len());
        push_split_normals(face, input, &mut v);
        face_state_with(face, positions, &v, 1.0)
    }
}

/// What a tried move would do to the faces around it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Verdict {
    /// A face that was not inverted becomes inverted, a quad that was not
    /// twisted becomes twisted, or a quad's split corner opens beyond 160°
    /// (or beyond its angle before, if wider): the move is never allowed.
    pub new_defect: bool,
    /// The part of `new_defect` that is not a wide corner: a jump beyond
    /// the vertex's reach or the fidelity bound, a face newly inverted or
    /// a quad newly twisted.
    pub new_fold_or_jump: bool,
    /// Cosine of the widest split corner the move opens beyond 160° (or
    /// beyond its angle before, if wider); 1 when it opens none.
    pub opened_corner_cos: f64,
    /// Inverted faces before and after, among the affected faces.
    pub inverted: (u32, u32),
    /// Twisted quads before and after, among the affected faces.
    pub twisted: (u32, u32),
    /// Cosine of the smallest split-triangle angle over the affected faces,
    /// before and after.
    pub max_cos: (f64, f64),
    /// Summed angle deficit of the affected faces (see `FaceState`), before
    /// and after.
    pub deficit: (f64, f64),
    /// A face the input already had sharper than the tester's guard ends
    /// below [`INPUT_SLIVER_KEEP`] of its input angle and sharper than it
    /// was ([`MoveTester::guarding`]).
    pub input_sliver_shrunk: bool,
    /// A face whose angles all met the goal no longer does.
    pub newly_sharp: bool,
}

impl Verdict {
    /// No new defect and the smallest angle did not shrink.
    pub fn keeps_quality(&self) -> bool {
        !self.new_defect
            && self.inverted.1 <= self.inverted.0
            && self.twisted.1 <= self.twisted.0
            && self.max_cos.1 <= self.max_cos.0
    }

    /// No new defect, no more defects, and one of: fewer defects; a
    /// strictly larger smallest angle; or a smaller angle deficit with no
    /// face newly short of the goal and no angle below `cos_floor`'s (the
    /// mesh's smallest angle when the fix began). The last lets a straight
    /// row of slivers shift as a whole, which no single move can do while
    /// every move must grow the local smallest angle. Only the first may
    /// close a sliver of the input below its floor
    /// ([`Verdict::input_sliver_shrunk`]).
    pub fn improves(&self, cos_floor: f64) -> bool {
        if self.new_defect || self.inverted.1 > self.inverted.0 || self.twisted.1 > self.twisted.0 {
            return false;
        }
        if self.inverted.1 < self.inverted.0 || self.twisted.1 < self.twisted.0 {
            return true;
        }
        if self.input_sliver_shrunk {
            return false;
        }
        if self.max_cos.1 < self.max_cos.0 {
            return true;
        }
        !self.newly_sharp
            && self.deficit.1 < self.deficit.0 * (1.0 - 1e-9)
            && self.max_cos.1 <= cos_floor.max(self.max_cos.0)
    }
}

/// Judges tried moves of a few vertices against the faces around them,
/// without changing the positions. Holds scratch buffers so that a try
/// allocates nothing once warmed up.
#[derive(Debug, Default)]
pub(crate) struct MoveTester {
    faces: Vec<u32>,
    /// Start of each face's input split normals in `input_normals`.
    starts: Vec<u32>,
    input_normals: Vec<DVec3>,
    before: Vec<FaceState>,
    /// Per face of `faces`, the cosine of the smallest angle an
    /// angle-only move may leave it ([`input_sliver_floor`]; 1 for none).
    input_floor: Vec<f64>,
    /// Per face of `faces`, whether it is a quad the input already had
    /// twisted and the tester lets it twist again
    /// ([`MoveTester::allowing_input_twists`]).
    input_twist: Vec<bool>,
    /// Whether a quad the input had twisted may be twisted again.
    input_twists_allowed: bool,
    /// Cosine of the angle below which an input face is a sliver
    /// ([`MoveTester::guarding`]).
    guard: Option<f64>,
    cos_goal: f64,
    /// Each vertex given to `begin` with its longest edge: no move may take
    /// it farther than that.
    reach: Vec<(usize, f64)>,
    /// The fidelity bound no move may take a vertex out of, with the input
    /// position of each vertex of `reach`.
    bound: Option<FidelityBound>,
    reach_input: Vec<DVec3>,
    /// A vertex given to `begin` may not move ([`fixable`]): nothing needs
    /// work and no move is allowed.
    frozen: bool,
}

impl MoveTester {
    /// A tester that also rejects any move out of `bound` (none: no
    /// bound).
    pub fn bounded(bound: Option<&FidelityBound>) -> Self {
        MoveTester {
            bound: bound.cloned(),
            ..MoveTester::default()
        }
    }

    /// The same tester, also flagging a move that takes a face the input
    /// already had with an angle below the one of cosine `cos_guard` (a
    /// sliver of the input) below [`INPUT_SLIVER_KEEP`] of its input angle
    /// and below where the face was ([`Verdict::input_sliver_shrunk`]).
    pub fn guarding(self, cos_guard: f64) -> Self {
        MoveTester {
            guard: Some(cos_guard),
            ..self
        }
    }

    /// The same tester, for moves back toward the input: a quad the input
    /// already had twisted may end twisted again, and neither counts among
    /// the twisted quads nor makes a move a new defect. Going back toward
    /// the input restores the input's own state there; without this, a
    /// fold next to a twisted quad of the input (a subdivision cage's
    /// degenerate strip, which the twisted-quad fix untwisted) cannot go
    /// back, since every retreat twists that quad again.
    pub fn allowing_input_twists(self) -> Self {
        MoveTester {
            input_twists_allowed: true,
            ..self
        }
    }

    /// Collects the faces around `vertices` (each once, skipping faces with
    /// a repeated corner) and records their state; `cos_goal` is the cosine
    /// of the angle goal the deficits are measured against (1 for none).
    pub fn begin(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        vertices: &[usize],
        positions: &[DVec3],
        input: &[DVec3],
        cos_goal: f64,
    ) {
        self.cos_goal = cos_goal;
        self.reach.clear();
        self.reach_input.clear();
        self.faces.clear();
        self.starts.clear();
        self.input_normals.clear();
        self.before.clear();
        self.input_floor.clear();
        self.input_twist.clear();
        self.frozen = !vertices.iter().all(|&v| fixable(mesh, topo, v));
        if self.frozen {
            return;
        }
        self.reach_input.extend(vertices.iter().map(|&v| input[v]));
        for &v in vertices {
            let p = positions[v];
            let longest = topo
                .neighbors(v)
                .iter()
                .map(|&w| positions[w as usize].distance_squared(p))
                .fold(0.0f64, f64::max)
                .sqrt();
            self.reach.push((v, longest));
        }
        for &v in vertices {
            for &f in topo.vertex_faces(v) {
                if !self.faces.contains(&f) && !has_repeated_corner(mesh.face(f as usize)) {
                    self.faces.push(f);
                }
            }
        }
        for &f in &self.faces {
            let face = mesh.face(f as usize);
            self.input_floor.push(match self.guard {
                Some(c) => input_sliver_floor(max_split_cos(face, input), c),
                None => 1.0,
            });
            let start = self.input_normals.len();
            self.starts.push(start as u32);
            push_split_normals(face, input, &mut self.input_normals);
            let normals = &self.input_normals[start..];
            self.input_twist
                .push(self.input_twists_allowed && split_normals_twisted(face.len(), normals));
            self.before
                .push(face_state_with(face, positions, normals, cos_goal));
        }
    }

    /// Lets each vertex recorded by [`MoveTester::begin`] jump as far as
    /// its input position: a retreat goes back along the way the vertex
    /// came, to where its faces were sound, not to a fit's guess (what the
    /// reach guards against).
    pub fn reaching_input(&mut self, positions: &[DVec3], input: &[DVec3]) {
        for r in &mut self.reach {
            r.1 = r.1.max(positions[r.0].distance(input[r.0]));
        }
    }

    /// The goal given to [`MoveTester::begin`].
    pub fn cos_goal(&self) -> f64 {
        self.cos_goal
    }

    /// True when a recorded face is inverted, twisted, or has a smallest
    /// split-triangle angle below the goal.
    pub fn needs_work(&self) -> bool {
        !self.frozen
            && self
                .before
                .iter()
                .any(|s| s.inverted || s.twisted || s.max_cos > self.cos_goal)
    }

    /// Judges the faces recorded by [`MoveTester::begin`] as they would be
    /// with `moves` (vertex, new position) applied to `positions`.
    pub fn judge(&self, mesh: &Mesh, moves: &[(usize, DVec3)], positions: &[DVec3]) -> Verdict {
        let pos = |w: u32| {
            moves
                .iter()
                .find(|m| m.0 == w as usize)
                .map_or(positions[w as usize], |m| m.1)
        };
        let mut verdict = Verdict {
            new_defect: false,
            new_fold_or_jump: false,
            opened_corner_cos: 1.0,
            inverted: (0, 0),
            twisted: (0, 0),
            max_cos: (-1.0, -1.0),
            deficit: (0.0, 0.0),
            input_sliver_shrunk: false,
            newly_sharp: false,
        };
        // A fix moves a vertex within its star; a longer jump (a fit or
        // centroid gone wrong on a tangled patch) is never a repair. A
        // frozen vertex does not move at all.
        verdict.new_fold_or_jump = self.frozen
            || moves.iter().any(|&(w, p)| {
                let reach = self.reach.iter().find(|r| r.0 == w).map_or(0.0, |r| r.1);
                let jump = p.distance(positions[w]);
                jump > reach || jump.is_nan()
            });
        if let Some(bound) = &self.bound {
            verdict.new_fold_or_jump |= moves.iter().any(|&(w, p)| {
                self.reach
                    .iter()
                    .zip(&self.reach_input)
                    .find(|(r, _)| r.0 == w)
                    .is_some_and(|(_, &o)| !bound.allows(w, o, p))
            });
        }
        for ((((&f, b), &start), &input_floor), &input_twist) in self
            .faces
            .iter()
            .zip(&self.before)
            .zip(&self.starts)
            .zip(&self.input_floor)
            .zip(&self.input_twist)
        {
            let normals = &self.input_normals[start as usize..];
            let mut a = face_state_at(mesh.face(f as usize), pos, normals, self.cos_goal);
            let mut b = *b;
            if input_twist {
                a.twisted = false;
                b.twisted = false;
            }
            verdict.new_fold_or_jump |= (a.inverted && !b.inverted) || (a.twisted && !b.twisted);
            if a.wide_cos < b.wide_cos.min(WIDEST_CORNER_COS) {
                verdict.opened_corner_cos = verdict.opened_corner_cos.min(a.wide_cos);
            }
            verdict.inverted.0 += b.inverted as u32;
            verdict.inverted.1 += a.inverted as u32;
            verdict.twisted.0 += b.twisted as u32;
            verdict.twisted.1 += a.twisted as u32;
            verdict.max_cos.0 = verdict.max_cos.0.max(b.max_cos);
            verdict.max_cos.1 = verdict.max_cos.1.max(a.max_cos);
            verdict.deficit.0 += b.deficit;
            verdict.deficit.1 += a.deficit;
            verdict.newly_sharp |= b.max_cos <= self.cos_goal && a.max_cos > self.cos_goal;
            verdict.input_sliver_shrunk |= a.max_cos > input_floor.max(b.max_cos);
        }
        verdict.new_defect = verdict.new_fold_or_jump || verdict.opened_corner_cos < 1.0;
        verdict
    }
}

/// Most neighbours of a vertex the fixes treat as a sample of a surface. A
/// vertex with more is a hub (the apex of a fan, many sheets pinched at one
/// point): the fixes do not move it, the 2-rings of its neighbours do not
/// walk through it and their fits leave it out (its normal sums every face
/// around it). Each visit then costs a bounded amount of work whatever the
/// valence, and a mesh of many hubs costs in proportion to its size; a
/// closed fan of up to this many faces still fits the bit mask
/// [`ordered_link`] chains it with.
pub(crate) const MAX_FAN: usize = 64;

/// Most corners of a face whose corners the fixes move. Judging a tried
/// position re-splits every face around the vertex, so each corner of a
/// face of `k` corners costs `k` per try and the face `k^2` a sweep:
/// polygons of a few dozen corners would cost as much as thousands of
/// quads. Real meshes' faces beyond quads are pentagons and hexagons (a
/// subdivision cage's extraordinary faces, a mesh of hexagons). The split
/// of a regular polygon of `k` corners has angles of `180 / k` degrees at
/// its first corner, 20 (the sharp-angle threshold) at nine: past eight
/// corners a polygon's split is sharp by construction, which no move of
/// one corner opens.
pub(crate) const MAX_FIX_CORNERS: usize = 8;

/// Whether the fixes may move `v`: it is no hub ([`MAX_FAN`]) and no face
/// around it has more than [`MAX_FIX_CORNERS`] corners. Costs a look at
/// each of its faces' sizes.
pub(crate) fn fixable(mesh: &Mesh, topo: &Topology, v: usize) -> bool {
    !is_hub(topo, v)
        && topo
            .vertex_faces(v)
            .iter()
            .all(|&f| mesh.face(f as usize).len() <= MAX_FIX_CORNERS)
}

/// Whether `v` is a hub ([`MAX_FAN`]).
#[inline]
pub(crate) fn is_hub(topo: &Topology, v: usize) -> bool {
    topo.neighbors(v).len() > MAX_FAN
}

/// Appends the 2-ring of `v` (every vertex within two edges, not `v`) to
/// `out`, sorted and without duplicates; a hub among `v`'s neighbours is in
/// it but not its own neighbours ([`MAX_FAN`]).
pub(crate) fn two_ring(topo: &Topology, v: usize, out: &mut Vec<u32>) {
    out.clear();
    for &a in topo.neighbors(v) {
        out.push(a);
        if !is_hub(topo, a as usize) {
            out.extend(topo.neighbors(a as usize).iter().copied());
        }
    }
    out.sort_unstable();
    out.dedup();
    out.retain(|&w| w as usize != v);
}

/// The link of interior vertex `v`: the corners of its faces other than
/// `v`, in order around `v` (counter-clockwise seen from the side its faces'
/// normals point to), each once. Returns false (and leaves `out` in an
/// unspecified state) when the faces do not chain into one closed fan, or
/// the fixes may not move `v` ([`fixable`]).
pub(crate) fn ordered_link(mesh: &Mesh, topo: &Topology, v: usize, out: &mut Vec<u32>) -> bool {
    out.clear();
    let faces = topo.vertex_faces(v);
    // The chaining below marks the faces used in a 64-bit mask.
    if faces.len() > MAX_FAN || !fixable(mesh, topo, v) {
        return false;
    }
    if faces
        .iter()
        .any(|&f| has_repeated_corner(mesh.face(f as usize)))
    {
        return false;
    }
    let Some((&first, rest)) = faces.split_first() else {
        return false;
    };
    // Corners after `v` up to the one before `v`, cyclically.
    let segment = |f: u32| -> Option<(usize, &[u32])> {
        let face = mesh.face(f as usize);
        let at = face.iter().position(|&w| w as usize == v)?;
        Some((at, face))
    };
    let Some((at, face)) = segment(first) else {
        return false;
    };
    let k = face.len();
    for j in 1..k {
        out.push(face[(at + j) % k]);
    }
    let mut used = 1usize;
    let mut pending_mask: u64 = 0; // bit i set = rest[i] used
    while used < faces.len() {
        let last = *out.last().unwrap_or(&u32::MAX);
        let mut found = false;
        for (i, &f) in rest.iter().enumerate() {
            if pending_mask & (1 << i) != 0 {
                continue;
            }
            let Some((at, face)) = segment(f) else {
                return false;
            };
            let k = face.len();
            if face[(at + 1) % k] == last {
                for j in 2..k {
                    out.push(face[(at + j) % k]);
                }
                pending_mask |= 1 << i;
                used += 1;
                found = true;
                break;
            }
        }
        if !found {
            return false;
        }
    }
    // A closed fan ends where it started.
    if out.len() < 3 || out.last() != out.first() {
        return false;
    }
    out.pop();
    true
}

/// The fitted surface around a vertex: its quadric (section 3) in the frame
/// at its current position and normal, fitted to its 2-ring less the
/// neighbours facing away (cosine of their normal with the vertex's below
/// `min_normal_cos`, as in the smoothing passes) and the hubs
/// ([`MAX_FAN`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct LocalSurface {
    pub frame: Frame,
    pub fit: QuadricFit,
}

impl LocalSurface {
    /// Fits the surface at `v`; `None` when `v` has no usable normal.
    pub fn at(
        mesh: &Mesh,
        topo: &Topology,
        v: usize,
        positions: &[DVec3],
        ring: &mut Vec<u32>,
        min_normal_cos: f64,
    ) -> Option<LocalSurface> {
        let n = vertex_normal(mesh, topo, positions, v);
        if n == DVec3::ZERO {
            return None;
        }
        let frame = Frame::new(positions[v], n);
        two_ring(topo, v, ring);
        ring.retain(|&w| {
            !is_hub(topo, w as usize)
                && (min_normal_cos <= -1.0
                    || vertex_normal(mesh, topo, positions, w as usize).dot(n) >= min_normal_cos)
        });
        let fit = fit_quadric(&frame, positions, ring);
        Some(LocalSurface { frame, fit })
    }

    /// The point of the fitted surface above the tangent-plane point `(x,
    /// y)` (local coordinates). Without a usable fit the point stays in the
    /// tangent plane.
    pub fn point(&self, x: f64, y: f64) -> DVec3 {
        let z = match self.fit.kind {
            FitKind::Fixed => 0.0,
            FitKind::Cubic | FitKind::Quadric | FitKind::Plane => {
                let [a, b, c, e, f, g] = self.fit.coeffs;
                a * x * x + b * x * y + c * y * y + e * x + f * y + g
            }
        };
        self.frame.to_world(DVec3::new(x, y, z))
    }

    /// The point above the tangent-plane point `(x, y)` of the fitted
    /// surface moved along the normal to pass through the vertex itself:
    /// the fit's shape without its offset at the vertex, so that a
    /// tangent step keeps the vertex on the surface it is on rather than
    /// also taking a smoothing step toward the fit.
    pub fn point_through_vertex(&self, x: f64, y: f64) -> DVec3 {
        let g = match self.fit.kind {
            FitKind::Fixed => 0.0,
            FitKind::Cubic | FitKind::Quadric | FitKind::Plane => self.fit.coeffs[5],
        };
        self.point(x, y) - g * self.frame.w
    }

    /// Tangent-plane coordinates `(x, y)` of a world point.
    pub fn tangent(&self, q: DVec3) -> (f64, f64) {
        let l = self.frame.to_local(q);
        (l.x, l.y)
    }
}

/// Angle-based smoothing target of Zhou & Shimada (2000) in the tangent
/// plane of `surface`, for a vertex whose ordered link is `link`: the mean
/// over link vertices `l_j` of the vertex rotated about `l_j` onto the
/// bisector of the link's interior angle at `l_j`. Returns the tangent
/// coordinates, or `None` when no link corner is usable.
pub(crate) fn angle_based_target(
    surface: &LocalSurface,
    link: &[u32],
    positions: &[DVec3],
) -> Option<(f64, f64)> {
    let m = link.len();
    if m < 3 {
        return None;
    }
    let pt = |j: usize| -> (f64, f64) { surface.tangent(positions[link[j % m] as usize]) };
    let (mut sx, mut sy, mut count) = (0.0, 0.0, 0u32);
    for j in 0..m {
        let cur = pt(j);
        let next = pt(j + 1);
        let prev = pt(j + m - 1);
        let a = (next.0 - cur.0, next.1 - cur.1);
        let b = (prev.0 - cur.0, prev.1 - cur.1);
        let la = (a.0 * a.0 + a.1 * a.1).sqrt();
        let r = (cur.0 * cur.0 + cur.1 * cur.1).sqrt();
        if la == 0.0 || b == (0.0, 0.0) || r == 0.0 {
            continue;
        }
        // Bisector of the interior angle, counter-clockwise from `a` to `b`
        // (the link runs counter-clockwise, its interior on the left).
        let lb = (b.0 * b.0 + b.1 * b.1).sqrt();
        let (ua, ub) = ((a.0 / la, a.1 / la), (b.0 / lb, b.1 / lb));
        let (hx, hy) = (ua.0 + ub.0, ua.1 + ub.1);
        let lh = (hx * hx + hy * hy).sqrt();
        let cross = ua.0 * ub.1 - ua.1 * ub.0;
        let dir = if lh < 1e-9 {
            (-ua.1, ua.0) // a straight angle: the left normal of `a`
        } else if cross >= 0.0 {
            (hx / lh, hy / lh)
        } else {
            (-hx / lh, -hy / lh) // a reflex angle
        };
        sx += cur.0 + r * dir.0;
        sy += cur.1 + r * dir.1;
        count += 1;
    }
    (count > 0).then(|| (sx / count as f64, sy / count as f64))
}

/// Mean of the link vertices in the tangent plane of `surface`.
pub(crate) fn link_centroid(
    surface: &LocalSurface,
    link: &[u32],
    positions: &[DVec3],
) -> Option<(f64, f64)> {
    if link.is_empty() {
        return None;
    }
    let (mut sx, mut sy) = (0.0, 0.0);
    for &w in link {
        let (x, y) = surface.tangent(positions[w as usize]);
        sx += x;
        sy += y;
    }
    let k = link.len() as f64;
    Some((sx / k, sy / k))
}

/// A split triangle whose normal makes a cosine below this with its input
/// normal is turned: standing almost across its input orientation, as a
/// sliver of the input that the smoothing rolled over its long side may
/// stand. Every move along the surface that opens such a sliver turns it
/// past the perpendicular, which the fixes refuse as an inversion, so
/// [`uninvert_steps`] also tries turning it back toward its input
/// orientation, by steps off the surface. The value leaves alone the
/// triangles a curved surface tilts by up to about 70 degrees. Only a
/// triangle sharp in the input and now counts: a voxel mesh's risers
/// turn by 45 to 90 degrees as the smoothing intends, and no step may
/// raise them back.
const TURNED_COS: f64 = 0.3;

/// Steps that turn each split triangle at `v` that is inverted relative to
/// `input` (or turned, below) the right way round: a triangle `(v, a, b)`'s
/// normal dotted with its input normal `m` is affine in `v`,
/// `(a x b).m + v.((a - b) x m)`, so a step along `g = (a - b) x m` that
/// makes it positive is exact. Written
/// to `tangent` as tangent-plane steps (local coordinates of `surface`,
/// along the tangent part of `g`, to be lifted onto the surface) and to
/// `direct` as positions moved along `g` itself, off the surface, when that
/// move is shorter than `max_direct` (a face standing almost perpendicular
/// to its input orientation can only be turned by such a move). Two steps
/// each per triangle (1.5 and 3 times the step that reaches zero), at most
/// four triangles. A triangle that is not inverted but turned
/// ([`TURNED_COS`]), and whose smallest angle has a cosine above
/// `cos_sharp` both in the input and now, gets the steps that take `n.m`
/// to `TURNED_COS |n| |m|` and to twice that, `n` its normal before the
/// step.
#[allow(clippy::too_many_arguments)]
pub(crate) fn uninvert_steps(
    mesh: &Mesh,
    topo: &Topology,
    v: usize,
    positions: &[DVec3],
    input: &[DVec3],
    surface: &LocalSurface,
    max_direct: f64,
    cos_sharp: f64,
    tangent: &mut Vec<(f64, f64)>,
    direct: &mut Vec<DVec3>,
) {
    let mut found = 0;
    for &f in topo.vertex_faces(v) {
        let face = mesh.face(f as usize);
        for j in 1..face.len() - 1 {
            let tri = [face[0], face[j], face[j + 1]];
            let Some(at) = tri.iter().position(|&w| w as usize == v) else {
                continue;
            };
            let (a, b) = (tri[(at + 1) % 3] as usize, tri[(at + 2) % 3] as usize);
            let m = (input[a] - input[v]).cross(input[b] - input[v]);
            let n = (positions[a] - positions[v]).cross(positions[b] - positions[v]);
            let s = n.dot(m);
            let nm = n.length() * m.length();
            let turned = || {
                s < TURNED_COS * nm
                    && min_angle_cos(input[v], input[a], input[b]) > cos_sharp
                    && min_angle_cos(positions[v], positions[a], positions[b]) > cos_sharp
            };
            if s >= 0.0 && !turned() {
                continue;
            }
            let g = (positions[a] - positions[b]).cross(m);
            let (gx, gy) = (g.dot(surface.frame.u), g.dot(surface.frame.v));
            let gg = gx * gx + gy * gy;
            // An inverted triangle: 1.5 and 3 times the step to zero. A
            // turned one: the steps to TURNED_COS and twice that.
            let goals = if s < 0.0 {
                [1.5 * -s, 3.0 * -s]
            } else {
                [TURNED_COS * nm - s, 2.0 * TURNED_COS * nm - s]
            };
            if gg > 0.0 {
                tangent.extend(goals.map(|d| (d / gg * gx, d / gg * gy)));
            }
            let g3 = g.length_squared();
            if g3 > 0.0 {
                for d in goals {
                    let step = (d / g3) * g;
                    if step.length() <= max_direct {
                        direct.push(positions[v] + step);
                    }
                }
            }
            found += 1;
            if found == 4 {
                return;
            }
        }
    }
}

/// Mean tangent-plane distance from the vertex to its link vertices.
pub(crate) fn link_radius(surface: &LocalSurface, link: &[u32], positions: &[DVec3]) -> f64 {
    if link.is_empty() {
        return 0.0;
    }
    let sum: f64 = link
        .iter()
        .map(|&w| {
            let (x, y) = surface.tangent(positions[w as usize]);
            (x * x + y * y).sqrt()
        })
        .sum();
    sum / link.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quality::fixtures::{at, grid};

    #[test]
    fn a_turned_triangle_gets_steps_that_turn_it_back() {
        // Vertex (1,1) of a flat grid raised four edges: its split
        // triangles stand almost across their input orientation, none
        // inverted. Each direct step reaches its goal for `n.m` exactly.
        let m = grid(3);
        let t = Topology::build(&m);
        let v = at(3, 1, 1);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        p[v].z = 4.0;
        let mut ring = Vec::new();
        let surface = LocalSurface::at(&m, &t, v, &p, &mut ring, -1.0).unwrap();
        let (mut tangent, mut direct) = (Vec::new(), Vec::new());
        uninvert_steps(
            &m,
            &t,
            v,
            &p,
            &input,
            &surface,
            f64::INFINITY,
            0.0, // every triangle with angles under 90 degrees is sharp
            &mut tangent,
            &mut direct,
        );
        assert!(
            !direct.is_empty() && direct.len() == tangent.len(),
            "{direct:?}"
        );
        // The first triangle at v in face order, and its steps.
        let face = m.face(t.vertex_faces(v)[0] as usize);
        let tri = [face[0], face[1], face[2]];
        let at_v = tri.iter().position(|&w| w as usize == v).unwrap();
        let (a, b) = (tri[(at_v + 1) % 3] as usize, tri[(at_v + 2) % 3] as usize);
        let normal = |q: DVec3, pos: &[DVec3]| (pos[a] - q).cross(pos[b] - q);
        let mi = normal(input[v], &input);
        let n = normal(p[v], &p);
        let cos = n.dot(mi) / (n.length() * mi.length());
        assert!(cos > 0.0 && cos < TURNED_COS, "{cos}");
        for (k, goal) in [1.0, 2.0].into_iter().enumerate() {
            let turned = normal(direct[k], &p).dot(mi);
            let want = goal * TURNED_COS * n.length() * mi.length();
            assert!((turned - want).abs() < 1e-9 * want, "{turned} vs {want}");
        }
    }

    #[test]
    fn min_angle_cos_is_the_smallest_angle() {
        let tris = [
            [DVec3::ZERO, DVec3::X, DVec3::Y],
            [
                DVec3::ZERO,
                DVec3::new(5.0, 0.1, 0.0),
                DVec3::new(2.0, 0.3, 1.0),
            ],
            [
                DVec3::ZERO,
                DVec3::new(1.0, 0.0, 0.0),
                DVec3::new(0.5, 3.0, -0.2),
            ],
        ];
        for [a, b, c] in tris {
            let smallest = [(a, b, c), (b, c, a), (c, a, b)]
                .map(|(x, y, z)| (y - x).angle_between(z - x))
                .into_iter()
                .fold(f64::INFINITY, f64::min);
            assert!((min_angle_cos(a, b, c) - smallest.cos()).abs() < 1e-12);
            let all = triangle_cosines(a, b, c);
            assert!((all.iter().fold(-1.0f64, |m, &x| m.max(x)) - smallest.cos()).abs() < 1e-12);
        }
        // A zero-length side is a 0° angle.
        assert_eq!(min_angle_cos(DVec3::ZERO, DVec3::ZERO, DVec3::X), 1.0);
    }

    #[test]
    fn twisted_and_inverted_quads() {
        let input = [DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y];
        let face = [0u32, 1, 2, 3];
        assert!(!is_twisted(&face, &input));
        assert!(!is_inverted(&face, &input, &input));
        // A bow-tie: corners 1 and 2 swapped.
        let bow = [input[0], input[2], input[1], input[3]];
        assert!(is_twisted(&face, &bow));
        // Mirrored: every normal flips.
        let mirrored = input.map(|p| DVec3::new(p.x, -p.y, p.z));
        assert!(is_inverted(&face, &mirrored, &input));
        assert!(!is_twisted(&face, &mirrored));
        let s = face_state(&face, &mirrored, &input);
        assert!(s.inverted && !s.twisted);
        assert!((s.max_cos - 45f64.to_radians().cos()).abs() < 1e-12);
        assert!(s.wide_cos.abs() < 1e-12, "square corners are 90°");
    }

    /// A quad folded along its diagonal 0-2 past a right angle (its two
    /// split triangles face opposite ways: twisted), and the same quad
    /// unfolded by its corner 3 moving across the diagonal.
    fn twisted_and_unfolded() -> (Vec<DVec3>, Vec<DVec3>) {
        let input = vec![
            DVec3::ZERO,
            DVec3::new(1.0, -1.0, 0.0),
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(1.0, -0.5, -1.0),
        ];
        let mut open = input.clone();
        open[3] = DVec3::new(1.0, 0.5, -0.2);
        (input, open)
    }

    #[test]
    fn a_quad_the_input_twisted_is_inverted_by_its_vector_area_alone() {
        let (input, open) = twisted_and_unfolded();
        let face = [0u32, 1, 2, 3];
        assert!(is_twisted(&face, &input));
        // Unfolded, the second split triangle turns against the input's,
        // the quad's vector area does not.
        assert!(!is_twisted(&face, &open));
        assert!(!is_inverted(&face, &open, &input));
        assert!(!face_state(&face, &open, &input).inverted);
        // Mirrored across the plane y = 0, its vector area turns too.
        let mirrored: Vec<DVec3> = open.iter().map(|p| DVec3::new(p.x, -p.y, p.z)).collect();
        assert!(is_inverted(&face, &mirrored, &input));
        assert!(face_state(&face, &mirrored, &input).inverted);
        // A quad the input had sound still counts each split triangle.
        let flat = [DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y];
        let mut folded = flat;
        folded[3] = DVec3::new(0.9, 0.2, 0.0);
        assert!(is_inverted(&face, &folded, &flat));
    }

    #[test]
    fn a_retreat_may_twist_again_a_quad_the_input_had_twisted() {
        let (input, open) = twisted_and_unfolded();
        let m = Mesh::from_polygons(input.clone(), &[[0u32, 1, 2, 3]]).expect("one quad");
        let t = Topology::build(&m);
        let back = [(3, input[3])];
        let mut plain = MoveTester::default();
        plain.begin(&m, &t, &[3], &open, &input, 1.0);
        plain.reaching_input(&open, &input);
        let verdict = plain.judge(&m, &back, &open);
        assert!(verdict.new_fold_or_jump && verdict.twisted == (0, 1));
        let mut retreating = MoveTester::default().allowing_input_twists();
        retreating.begin(&m, &t, &[3], &open, &input, 1.0);
        retreating.reaching_input(&open, &input);
        let verdict = retreating.judge(&m, &back, &open);
        assert!(
            !verdict.new_defect && verdict.twisted == (0, 0),
            "{verdict:?}"
        );
    }

    #[test]
    fn link_runs_counter_clockwise_around_the_normal() {
        let m = grid(4);
        let t = Topology::build(&m);
        let v = at(4, 2, 2);
        let mut link = Vec::new();
        assert!(ordered_link(&m, &t, v, &mut link));
        assert_eq!(link.len(), 8);
        let c = m.positions()[v];
        let angles: Vec<f64> = link
            .iter()
            .map(|&w| {
                let d = m.positions()[w as usize] - c;
                d.y.atan2(d.x)
            })
            .collect();
        for k in 0..8 {
            let mut step = angles[(k + 1) % 8] - angles[k];
            if step < 0.0 {
                step += std::f64::consts::TAU;
            }
            assert!(
                (step - std::f64::consts::FRAC_PI_4).abs() < 1e-12,
                "{angles:?}"
            );
        }
        // A boundary vertex has no closed fan.
        assert!(!ordered_link(&m, &t, at(4, 0, 2), &mut link));
    }

    #[test]
    fn angle_based_target_recentres_a_displaced_vertex() {
        let mut m = grid(4);
        let t = Topology::build(&m);
        let v = at(4, 2, 2);
        let mut link = Vec::new();
        let mut ring = Vec::new();
        assert!(ordered_link(&m, &t, v, &mut link));
        let s = LocalSurface::at(&m, &t, v, m.positions(), &mut ring, 0.5).unwrap();
        let (x, y) = angle_based_target(&s, &link, m.positions()).unwrap();
        assert!(x.abs() < 1e-12 && y.abs() < 1e-12, "a regular vertex stays");
        m.positions_mut()[v] += DVec3::new(0.3, -0.2, 0.0);
        let s = LocalSurface::at(&m, &t, v, m.positions(), &mut ring, 0.5).unwrap();
        let (x, y) = angle_based_target(&s, &link, m.positions()).unwrap();
        let target = s.point(x, y);
        let centre = DVec3::new(2.0, 2.0, 0.0);
        assert!(target.distance(centre) < 0.5 * m.positions()[v].distance(centre));
        assert!(target.z.abs() < 1e-12, "stays on the plane");
    }

    #[test]
    fn tester_judges_without_moving() {
        let m = grid(3);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let v = at(3, 1, 1);
        let mut tester = MoveTester::default();
        tester.begin(&m, &t, &[v], &input, &input, 20f64.to_radians().cos());
        assert!(!tester.needs_work());
        // Pushing the vertex across its neighbour inverts faces.
        let bad = tester.judge(&m, &[(v, DVec3::new(2.5, 1.0, 0.0))], &input);
        assert!(bad.new_defect && bad.inverted.1 > 0 && !bad.improves(1.0));
        // A small move shrinks the smallest angle: kept quality fails.
        let worse = tester.judge(&m, &[(v, DVec3::new(1.2, 1.1, 0.0))], &input);
        assert!(!worse.new_defect && !worse.keeps_quality() && !worse.improves(1.0));
        assert_eq!(m.positions(), &input[..]);
    }

    #[test]
    fn a_sliver_of_the_input_keeps_half_its_angle() {
        // A fan around vertex 0 whose first face is a sliver in the input
        // (6.3 degrees at the centre, under two thirds of the 10 degree
        // guard: its floor is half its angle). The centre has since moved
        // where its last face is at 0.88 degrees and the sliver at 3.7;
        // the tried move opens the last face a little (the star's smallest
        // angle grows) but closes the sliver to 3.08, under half its input
        // angle.
        let ring = [
            (10.0, 0.0),
            (10.0, 1.1),
            (0.0, 10.0),
            (-10.0, 0.0),
            (0.0, -10.0),
        ];
        let mut input = vec![DVec3::ZERO];
        input.extend(ring.iter().map(|&(x, y)| DVec3::new(x, y, 0.0)));
        let faces: Vec<[u32; 3]> = (1..=5).map(|i| [0, i, i % 5 + 1]).collect();
        let m = Mesh::from_polygons(input.clone(), &faces).expect("fan");
        let t = Topology::build(&m);
        let mut current = input.clone();
        current[0] = DVec3::new(1.75, -8.0, 0.0);
        let tried = [(0, DVec3::new(0.0, -9.675, 0.0))];
        let cos_goal = 20f64.to_radians().cos();
        let cos_guard = 10f64.to_radians().cos();
        let mut plain = MoveTester::default();
        plain.begin(&m, &t, &[0], &current, &input, cos_goal);
        let verdict = plain.judge(&m, &tried, &current);
        assert!(verdict.max_cos.1 < verdict.max_cos.0 && verdict.improves(1.0));
        let mut guarded = MoveTester::default().guarding(cos_guard);
        guarded.begin(&m, &t, &[0], &current, &input, cos_goal);
        let verdict = guarded.judge(&m, &tried, &current);
        assert!(verdict.input_sliver_shrunk && !verdict.improves(1.0));
        // Closing it only to 3.48 degrees is allowed: a smaller step the
        // same way stays above half its input angle.
        let half_way = [(0, DVec3::new(1.2, -8.5, 0.0))];
        let verdict = guarded.judge(&m, &half_way, &current);
        let sliver = min_angle_cos(half_way[0].1, input[1], input[2])
            .acos()
            .to_degrees();
        assert!(sliver > 3.2 && !verdict.input_sliver_shrunk, "{sliver}");
    }

    #[test]
    fn a_sliver_just_under_the_guard_keeps_nearly_all_of_its_angle() {
        // The floor is continuous at the guard: a face of the input just
        // sharper than it is held nearly where it was, not to half of it,
        // and a needle far under it to half its angle.
        let guard = 10f64;
        let floor = |input_deg: f64| {
            input_sliver_floor(input_deg.to_radians().cos(), guard.to_radians().cos())
                .acos()
                .to_degrees()
        };
        assert!((floor(9.9) - 9.8).abs() < 1e-9, "{}", floor(9.9));
        assert!((floor(8.0) - 6.0).abs() < 1e-9, "{}", floor(8.0));
        assert!((floor(6.0) - 3.0).abs() < 1e-9, "{}", floor(6.0));
        assert_eq!(
            input_sliver_floor(guard.to_radians().cos(), guard.to_radians().cos()),
            1.0
        );
        // Never above the input's own angle, and rising with it.
        let mut last = 0.0;
        for tenth in 1..100 {
            let a = f64::from(tenth) / 10.0;
            assert!(floor(a) <= a + 1e-9 && floor(a) >= last, "{a}");
            last = floor(a);
        }
    }

    #[test]
    fn a_move_beyond_the_longest_edge_is_a_defect() {
        let m = grid(3);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let v = at(3, 1, 1);
        let mut tester = MoveTester::default();
        tester.begin(&m, &t, &[v], &input, &input, 20f64.to_radians().cos());
        // Straight up by 0.9 and by 1.1 edge lengths: no face inverts
        // either way, but only the first stays within the vertex's star.
        let near = tester.judge(&m, &[(v, DVec3::new(1.0, 1.0, 0.9))], &input);
        assert!(!near.new_defect);
        let far = tester.judge(&m, &[(v, DVec3::new(1.0, 1.0, 1.1))], &input);
        assert!(far.new_defect && far.inverted.1 == 0);
    }

    #[test]
    fn a_hubs_neighbours_do_not_walk_through_it() {
        let m = crate::shapes::double_cones(1, 4 * MAX_FAN);
        let t = Topology::build(&m);
        let mut ring = Vec::new();
        // Rim vertex 10: its four neighbours (the two tips, rim vertices 9
        // and 11) and theirs along the rim (8 and 12), not the whole rim.
        two_ring(&t, 10, &mut ring);
        assert_eq!(ring, vec![0, 1, 8, 9, 11, 12]);
        assert!(is_hub(&t, 0) && !fixable(&m, &t, 0));
        assert!(fixable(&m, &t, 10));
        // A fan the chaining cannot hold is no link.
        let mut link = Vec::new();
        assert!(!ordered_link(&m, &t, 0, &mut link));
        assert!(ordered_link(&m, &t, 10, &mut link));
        // The tips are left out of the fit, with no facing rule.
        assert!(LocalSurface::at(&m, &t, 10, m.positions(), &mut ring, -2.0).is_some());
        assert_eq!(ring, vec![8, 9, 11, 12]);
    }

    #[test]
    fn the_corners_of_a_large_polygon_stay() {
        for (corners, movable) in [(MAX_FIX_CORNERS, true), (MAX_FIX_CORNERS + 1, false)] {
            let m = crate::shapes::prisms(1, corners);
            let t = Topology::build(&m);
            let input = m.positions().to_vec();
            assert_eq!(fixable(&m, &t, 0), movable);
            let mut link = Vec::new();
            assert_eq!(ordered_link(&m, &t, 0, &mut link), movable);
            // Every split triangle of a cap is sharper than 90 degrees
            // allows: work to do, unless the corner may not move.
            let mut tester = MoveTester::default();
            tester.begin(&m, &t, &[0], &input, &input, 0.0);
            assert_eq!(tester.needs_work(), movable);
            let nudge = input[0] + DVec3::new(-0.01, 0.0, 0.0);
            assert_eq!(tester.judge(&m, &[(0, nudge)], &input).new_defect, !movable);
        }
    }
}
