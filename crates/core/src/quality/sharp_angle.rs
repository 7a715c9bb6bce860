//! Sharp-angle fix (paper section 2.4; algorithm notes section 8):
//! angle-based smoothing (Zhou & Shimada 2000) of the vertices of faces
//! with a split-triangle angle below the threshold, each moved vertex kept
//! on its local surface so the shape is kept.
//!
//! For a vertex `v` with its ordered link `l_0 .. l_{m-1}` (the other
//! corners of its faces, around `v`), the angle-based target is the mean
//! over `j` of `v` rotated about `l_j`, in the tangent plane, onto the
//! bisector of the link's interior angle at `l_j`. The candidates tried, in
//! order: that target and the link centroid at full, half and quarter step,
//! the vertex's own foot point (no tangent step), and, for each split
//! triangle at `v` inverted relative to the input, the tangent step that
//! turns it back. Each is a tangent-plane point lifted, first, onto the
//! quadric fitted to `v`'s 2-ring (section 3) in the frame of its current
//! position and normal, moved along the normal to pass through `v` (so the
//! foot point is `v` itself); then onto the fitted quadric itself, as the
//! paper projects. The fit need not pass through `v`: its offset there is
//! one more smoothing step, which on the real masks took the fixed
//! vertices off the surface the smoothing settled on by about half their
//! tangent move (`docs/tuning.md`). The lift through `v` keeps the fit's
//! slope and bending and leaves the height to the smoothing; the fit's
//! offset is the fallback for faces that no move along the surface opens.
//! Last come the exact steps that turn an inverted triangle back by
//! moving off the surface, allowed up to a twentieth of the mean distance
//! to the link (a face standing almost perpendicular to its input
//! orientation turns only that way). A triangle sharp in the input and
//! now that stands almost across its input orientation without being
//! inverted (an input sliver the smoothing rolled over its long side) gets
//! such steps too: every move along the surface that opens it would turn
//! it past the perpendicular, an inversion, and a vertex that could only
//! try those stayed, leaving the sliver at a degree or two.
//!
//! A candidate counts only when it improves on the current position: no
//! face becomes inverted relative to the input, no quad becomes twisted,
//! no quad corner divided by its split opens beyond 160° (or beyond its
//! angle before, if wider), and either a defect goes away or the smallest
//! split-triangle angle of `v`'s faces grows (or their summed shortfall
//! from the threshold shrinks, no angle falling below the mesh's smallest
//! when the fix began). A move that only improves angles may not close a
//! face the input already had below the sliver floor to less than half
//! its input angle (`local::INPUT_SLIVER_KEEP`): the sliver fix does not
//! guard such faces, and the faces of a marching-cubes mesh across thick
//! slices are needles of a few degrees. The first candidate that
//! leaves no defect and no angle below the threshold is taken; otherwise
//! the best (fewest inverted faces, then fewest twisted quads, then the
//! largest smallest angle); otherwise `v` stays. A vertex stuck in one
//! sweep and visited again in the next also tries a pattern search: sixteen
//! tangent directions at four step sizes (up to half the link radius),
//! each point lifted through `v`, then onto the fit. (Eight directions at
//! three sizes left two torus faces at 14.5 degrees, stuck in a position
//! no smaller search improved.)
//!
//! Order: sweeps of colour classes. Sweep 1 visits the interior corners of
//! every face with a sharp angle or an inverted split triangle; each later
//! sweep visits those of the faces around the vertices moved (or, after a
//! sweep that moved nothing, stuck) in the sweep before. A sweep colours
//! its vertices greedily in ascending index order so that no two vertices
//! of a class are within two edges of each other or share a face; the
//! classes run one after another, the vertices of a class in parallel. A
//! visit reads only positions within two edges or one face of its vertex
//! and writes only its vertex, so the result is that of a Gauss-Seidel
//! sweep in class order and does not depend on the thread count. The fix
//! stops after `max_sweeps` sweeps, or when a sweep moves nothing and the
//! pattern search has had its sweep. Interior vertices whose faces form
//! one closed fan move; boundary and isolated vertices stay, and so do
//! hubs and the corners of large polygons ([`super::local::fixable`]). A
//! hub's neighbour, within two edges of all the hub's other neighbours,
//! takes a class of its own.
//!
//! Non-manifold vertices (where sheets meet at one vertex: voxels touching
//! along an edge or at a corner, a neuron's junctions) have no fan to
//! order and no one surface to fit, and a voxel mesh's pinches were placed
//! at their mask's level ([`crate::smoothing::pinches`]). They move only in
//! a fix run of their own ([`Movers::AlsoNonManifold`]), after the interior
//! vertices have done what they could: the faces around a pinch are sharp
//! when its relaxed neighbours lean toward it, and no move of theirs opens
//! the angle at the pinch. Their candidates: a pattern of sixteen
//! directions at four step sizes (up to 0.3 of the mean distance to the
//! neighbours) across the way the vertex came from its input position,
//! which for a placed pinch is its level's normal, so the pattern keeps it
//! on the level to first order; then the way to its neighbours' mean, in
//! tenths. A vertex still at its input position (a neuron's fin of
//! coincident faces that the fold fix took back there) tries the second
//! first, and only when no step of it improves (the mean lies past a face
//! the step would fold) the same pattern across the way to the mean.

use super::local::{
    LocalSurface, MoveTester, Verdict, angle_based_target, face_state, fixable,
    has_repeated_corner, is_hub, link_centroid, link_radius, max_split_cos, ordered_link,
    uninvert_steps,
};
use crate::mesh::{Mesh, Topology, VertexKind};
use crate::smoothing::fidelity::FidelityBound;
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// What the sharp-angle fix did.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SharpAngleStats {
    /// Faces with a split-triangle angle below the threshold before the fix.
    pub faces_found: u64,
    /// Accepted vertex moves, over all sweeps. The fix also visits the
    /// corners of faces inverted relative to the input, so it can move
    /// vertices with no sharp angle found (e.g. at a threshold of 0).
    pub moves: u64,
    /// Vertex visits where no candidate position was an improvement (the
    /// vertex stayed), over all sweeps.
    pub rejected: u64,
    /// Sweeps run.
    pub sweeps: u64,
    /// Faces with a split-triangle angle below the threshold after the fix.
    pub faces_remaining: u64,
}

impl SharpAngleStats {
    /// Adds a later run's counts to these; the faces remaining are the
    /// later run's.
    pub fn add(&mut self, later: &SharpAngleStats) {
        self.moves += later.moves;
        self.rejected += later.rejected;
        self.sweeps += later.sweeps;
        self.faces_remaining = later.faces_remaining;
    }
}

/// Which vertices a fix run may move.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Movers {
    /// Interior vertices (one closed fan) only.
    #[default]
    Interior,
    /// Interior and non-manifold vertices (see the module docs).
    AlsoNonManifold,
}

/// The step sizes of a non-manifold vertex's pattern across the way it
/// came, in mean distances to its neighbours: the interior vertices'
/// pattern search goes to half the link radius, a pinch's level holds only
/// near it.
const ACROSS_STEPS: [f64; 4] = [0.05, 0.1, 0.2, 0.3];

/// Directions of a non-manifold vertex's pattern across the way it came.
const ACROSS_DIRECTIONS: usize = 16;

/// Steps along the way from a non-manifold vertex to its neighbours' mean,
/// as fractions of it: the shortest that opens its faces is taken.
const TOWARD_MEAN_STEPS: usize = 10;

/// Scratch buffers for relocating vertices.
#[derive(Debug, Default)]
pub(crate) struct Relocator {
    /// [`LocalSurface::at`]'s facing rule.
    pub min_normal_cos: f64,
    /// Which vertices it moves.
    movers: Movers,
    ring: Vec<u32>,
    link: Vec<u32>,
    targets: Vec<(f64, f64)>,
    off_surface: Vec<DVec3>,
    candidates: Vec<DVec3>,
    tester: MoveTester,
}

/// Longest off-surface move that turns an inverted triangle, in units of the
/// vertex's mean tangent distance to its link.
const MAX_OFF_SURFACE: f64 = 0.05;

/// Ranks a tried position: fewer inverted faces, then fewer twisted quads,
/// then a smaller angle deficit, then a larger smallest angle, is better
/// (smaller key).
fn rank(v: &Verdict) -> (u32, u32, f64, f64) {
    (v.inverted.1, v.twisted.1, v.deficit.1, v.max_cos.1)
}

/// What a visit of a vertex found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Visit {
    /// None of its faces needed work (or it may not move).
    Skipped,
    /// It should move here.
    Moved(DVec3),
    /// No candidate was an improvement; it stays.
    Stuck,
}

impl Relocator {
    /// A relocator whose surface fits leave out neighbours facing away by
    /// a cosine below `min_normal_cos`.
    pub fn new(min_normal_cos: f64, bound: Option<&FidelityBound>) -> Relocator {
        Relocator {
            min_normal_cos,
            tester: MoveTester::bounded(bound),
            ..Relocator::default()
        }
    }

    /// The same relocator, moving `movers`.
    pub fn moving(self, movers: Movers) -> Relocator {
        Relocator { movers, ..self }
    }

    /// The same relocator, refusing the angle-only moves that take a face
    /// the input already had sharper than the angle of cosine `cos_guard`
    /// below it and below where the face was ([`MoveTester::guarding`]).
    pub fn guarding(self, cos_guard: f64) -> Relocator {
        Relocator {
            tester: self.tester.guarding(cos_guard),
            ..self
        }
    }

    /// The best of interior vertex `v`'s candidate positions if that
    /// improves its faces (`positions` is not changed; a non-manifold `v`
    /// has its own candidates when the relocator moves such vertices, and
    /// any other kind is skipped). A face needs work
    /// when it is inverted, twisted, or its smallest split-triangle angle
    /// has a cosine above `cos_goal`; a vertex none of whose faces needs
    /// work is skipped. The first candidate that leaves no defect and every
    /// angle at or above the goal is taken at once. `thorough` adds the
    /// pattern search when no other candidate helps.
    #[allow(clippy::too_many_arguments)]
    pub fn relocate(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        v: usize,
        positions: &[DVec3],
        input: &[DVec3],
        cos_goal: f64,
        cos_floor: f64,
        thorough: bool,
    ) -> Visit {
        if topo.kind(v) == VertexKind::NonManifold && self.movers == Movers::AlsoNonManifold {
            return self
                .relocate_non_manifold(mesh, topo, v, positions, input, cos_goal, cos_floor);
        }
        if topo.kind(v) != VertexKind::Interior {
            return Visit::Skipped;
        }
        self.tester
            .begin(mesh, topo, &[v], positions, input, cos_goal);
        if !self.tester.needs_work() || !ordered_link(mesh, topo, v, &mut self.link) {
            return Visit::Skipped;
        }
        let surface = LocalSurface::at(
            mesh,
            topo,
            v,
            positions,
            &mut self.ring,
            self.min_normal_cos,
        );
        let Some(surface) = surface else {
            return Visit::Skipped;
        };
        let mut targets = std::mem::take(&mut self.targets);
        targets.clear();
        let zs = angle_based_target(&surface, &self.link, positions);
        let centroid = link_centroid(&surface, &self.link, positions);
        for step in [1.0, 0.5, 0.25] {
            for (x, y) in [zs, centroid].into_iter().flatten() {
                targets.push((step * x, step * y));
            }
        }
        targets.push((0.0, 0.0));
        let mut off_surface = std::mem::take(&mut self.off_surface);
        off_surface.clear();
        let radius = link_radius(&surface, &self.link, positions);
        uninvert_steps(
            mesh,
            topo,
            v,
            positions,
            input,
            &surface,
            MAX_OFF_SURFACE * radius,
            cos_goal,
            &mut targets,
            &mut off_surface,
        );
        // Lifted candidates first, then the off-surface ones.
        let mut candidates = std::mem::take(&mut self.candidates);
        candidates.clear();
        // Along the vertex's own surface first; then onto the fit, whose
        // offset at the vertex also takes a smoothing step (module docs).
        candidates.extend(
            targets
                .iter()
                .map(|&(x, y)| surface.point_through_vertex(x, y)),
        );
        candidates.extend(targets.iter().map(|&(x, y)| surface.point(x, y)));
        candidates.extend_from_slice(&off_surface);
        let mut best = self.best_of(mesh, v, &candidates, positions, cos_floor);
        if best.is_none() && thorough {
            candidates.clear();
            for step in [0.5, 0.25, 0.1, 0.04] {
                for k in 0..16 {
                    let (sin, cos) = (k as f64 * std::f64::consts::FRAC_PI_8).sin_cos();
                    let (x, y) = (step * radius * cos, step * radius * sin);
                    candidates.push(surface.point_through_vertex(x, y));
                    candidates.push(surface.point(x, y));
                }
            }
            best = self.best_of(mesh, v, &candidates, positions, cos_floor);
        }
        self.targets = targets;
        self.off_surface = off_surface;
        self.candidates = candidates;
        best.map_or(Visit::Stuck, Visit::Moved)
    }

    /// The best of non-manifold vertex `v`'s candidates (see the module
    /// docs) if that improves its faces, as [`Relocator::relocate`] does for
    /// an interior vertex.
    #[allow(clippy::too_many_arguments)]
    fn relocate_non_manifold(
        &mut self,
        mesh: &Mesh,
        topo: &Topology,
        v: usize,
        positions: &[DVec3],
        input: &[DVec3],
        cos_goal: f64,
        cos_floor: f64,
    ) -> Visit {
        let neighbours = topo.neighbors(v);
        if neighbours.is_empty() {
            return Visit::Skipped;
        }
        self.tester
            .begin(mesh, topo, &[v], positions, input, cos_goal);
        if !self.tester.needs_work() {
            return Visit::Skipped;
        }
        let p = positions[v];
        let count = neighbours.len() as f64;
        let mean = neighbours
            .iter()
            .map(|&w| positions[w as usize])
            .sum::<DVec3>()
            / count;
        let reach = neighbours
            .iter()
            .map(|&w| positions[w as usize].distance(p))
            .sum::<f64>()
            / count;
        let mut candidates = std::mem::take(&mut self.candidates);
        candidates.clear();
        let came = (p - input[v]).normalize_or_zero();
        push_across(&mut candidates, p, came, reach);
        for k in 1..=TOWARD_MEAN_STEPS {
            candidates.push(p.lerp(mean, k as f64 / TOWARD_MEAN_STEPS as f64));
        }
        let mut best = self.best_of(mesh, v, &candidates, positions, cos_floor);
        if best.is_none() && came == DVec3::ZERO {
            candidates.clear();
            push_across(&mut candidates, p, (mean - p).normalize_or_zero(), reach);
            best = self.best_of(mesh, v, &candidates, positions, cos_floor);
        }
        self.candidates = candidates;
        best.map_or(Visit::Stuck, Visit::Moved)
    }

    /// The best improving position among `candidates`, stopping at the
    /// first that reaches the goal.
    fn best_of(
        &self,
        mesh: &Mesh,
        v: usize,
        candidates: &[DVec3],
        positions: &[DVec3],
        cos_floor: f64,
    ) -> Option<DVec3> {
        let cos_goal = self.tester.cos_goal();
        let mut best: Option<((u32, u32, f64, f64), DVec3)> = None;
        for &p in candidates {
            if !p.is_finite() {
                continue;
            }
            let verdict = self.tester.judge(mesh, &[(v, p)], positions);
            if verdict.improves(cos_floor) && best.is_none_or(|(k, _)| rank(&verdict) < k) {
                if verdict.inverted.1 == 0
                    && verdict.twisted.1 == 0
                    && verdict.max_cos.1 <= cos_goal
                {
                    return Some(p);
                }
                best = Some((rank(&verdict), p));
            }
        }
        best.map(|(_, p)| p)
    }
}

/// Pushes a non-manifold vertex's pattern at `p` across `axis` (a unit
/// vector; nothing for zero): [`ACROSS_DIRECTIONS`] directions in the plane
/// normal to it, at each of the [`ACROSS_STEPS`] times `reach`.
fn push_across(candidates: &mut Vec<DVec3>, p: DVec3, axis: DVec3, reach: f64) {
    if axis == DVec3::ZERO {
        return;
    }
    let e1 = axis.any_orthonormal_vector();
    let e2 = axis.cross(e1);
    for step in ACROSS_STEPS {
        for k in 0..ACROSS_DIRECTIONS {
            let turn = k as f64 * std::f64::consts::TAU / ACROSS_DIRECTIONS as f64;
            let (sin, cos) = turn.sin_cos();
            candidates.push(p + (e1 * cos + e2 * sin) * (step * reach));
        }
    }
}

/// True when face `f` has a split-triangle angle whose cosine exceeds
/// `cos_limit`, or is inverted relative to `input`.
fn needs_work(face: &[u32], positions: &[DVec3], input: &[DVec3], cos_limit: f64) -> bool {
    if has_repeated_corner(face) {
        return false;
    }
    let s = face_state(face, positions, input);
    s.max_cos > cos_limit || s.inverted
}

fn count_sharp(mesh: &Mesh, positions: &[DVec3], cos_limit: f64) -> u64 {
    (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&f| {
            let face = mesh.face(f);
            !has_repeated_corner(face) && max_split_cos(face, positions) > cos_limit
        })
        .count() as u64
}

/// Angle-based smoothing of the vertices around faces with a split-triangle
/// angle below `sharp_angle_deg` degrees (or inverted relative to `input`),
/// at most `max_sweeps` sweeps; moves vertices in `positions` in place
/// (one entry per vertex; `input` likewise). See the module documentation
/// for the order and the acceptance rule.
#[allow(clippy::too_many_arguments)]
pub fn fix_sharp_angles(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    input: &[DVec3],
    bound: Option<&FidelityBound>,
    sharp_angle_deg: f64,
    max_sweeps: u32,
    min_normal_cos: f64,
    movers: Movers,
) -> SharpAngleStats {
    let cos_limit = sharp_angle_deg.to_radians().cos();
    let cos_guard = (super::SLIVER_FRACTION * sharp_angle_deg)
        .to_radians()
        .cos();
    let p: &[DVec3] = positions;
    // Faces that need work, with the cosine of their smallest angle.
    let bad_faces: Vec<(u32, f64)> = (0..mesh.num_faces() as u32)
        .into_par_iter()
        .with_min_len(4096)
        .filter_map(|f| {
            let face = mesh.face(f as usize);
            if has_repeated_corner(face) {
                return None;
            }
            let s = face_state(face, p, input);
            (s.max_cos > cos_limit || s.inverted).then_some((f, s.max_cos))
        })
        .collect();
    let mut stats = SharpAngleStats {
        faces_found: bad_faces.iter().filter(|b| b.1 > cos_limit).count() as u64,
        ..SharpAngleStats::default()
    };
    // The mesh's smallest angle now: no move may go below it.
    let cos_floor = bad_faces.iter().map(|b| b.1).fold(cos_limit, f64::max);
    // A run that may move non-manifold vertices starts at their faces: the
    // others had the interior run.
    let bad_faces: Vec<u32> = bad_faces
        .into_iter()
        .map(|b| b.0)
        .filter(|&f| {
            movers == Movers::Interior
                || mesh
                    .face(f as usize)
                    .iter()
                    .any(|&v| topo.kind(v as usize) == VertexKind::NonManifold)
        })
        .collect();
    let mut visit = corners_of(mesh, topo, &bad_faces, movers);
    let mut colouring = Colouring::new(mesh.num_vertices());
    let mut stuck: Vec<u32> = Vec::new();
    let mut moved: Vec<u32> = Vec::new();
    let mut searched = false;
    while !visit.is_empty() && stats.sweeps < max_sweeps as u64 {
        stats.sweeps += 1;
        colouring.colour(mesh, topo, &visit);
        let previously_stuck = std::mem::take(&mut stuck);
        moved.clear();
        for class in colouring.classes() {
            let p: &[DVec3] = positions;
            let results: Vec<Visit> = class
                .par_iter()
                .with_min_len(64)
                .map_init(
                    || {
                        Relocator::new(min_normal_cos, bound)
                            .guarding(cos_guard)
                            .moving(movers)
                    },
                    |r, &v| {
                        let thorough = previously_stuck.binary_search(&v).is_ok();
                        r.relocate(
                            mesh, topo, v as usize, p, input, cos_limit, cos_floor, thorough,
                        )
                    },
                )
                .collect();
            for (&v, visit) in class.iter().zip(results) {
                match visit {
                    Visit::Moved(q) => {
                        positions[v as usize] = q;
                        moved.push(v);
                        stats.moves += 1;
                    }
                    Visit::Stuck => {
                        stuck.push(v);
                        stats.rejected += 1;
                    }
                    Visit::Skipped => {}
                }
            }
        }
        stuck.sort_unstable();
        if moved.is_empty() {
            // Give the stuck vertices one sweep with the pattern search.
            if searched {
                break;
            }
            searched = true;
        }
        let around = if moved.is_empty() { &stuck } else { &moved };
        // Tens of thousands of faces after a first sweep: in parallel.
        let mut faces: Vec<u32> = around
            .par_iter()
            .flat_map_iter(|&v| topo.vertex_faces(v as usize).iter().copied())
            .collect();
        faces.par_sort_unstable();
        faces.dedup();
        let p: &[DVec3] = positions;
        let faces: Vec<u32> = faces
            .into_par_iter()
            .filter(|&f| needs_work(mesh.face(f as usize), p, input, cos_limit))
            .collect();
        visit = corners_of(mesh, topo, &faces, movers);
    }
    stats.faces_remaining = count_sharp(mesh, positions, cos_limit);
    stats
}

/// The corners of `faces` that `movers` may move, ascending, each once
/// (never a hub or a corner of a large polygon: [`fixable`]).
fn corners_of(mesh: &Mesh, topo: &Topology, faces: &[u32], movers: Movers) -> Vec<u32> {
    let mut out: Vec<u32> = faces
        .iter()
        .flat_map(|&f| mesh.face(f as usize).iter().copied())
        .filter(|&v| match topo.kind(v as usize) {
            VertexKind::Interior => true,
            VertexKind::NonManifold => movers == Movers::AlsoNonManifold,
            _ => false,
        })
        .collect();
    out.sort_unstable();
    out.dedup();
    out.retain(|&v| fixable(mesh, topo, v as usize));
    out
}

/// Greedy colouring of a vertex list such that no two vertices of a class
/// are within two edges of each other or share a face.
struct Colouring {
    /// Colour per mesh vertex; `NONE` when not in the current list.
    colour: Vec<u8>,
    /// Vertices grouped by class, class by class (CSR).
    order: Vec<u32>,
    starts: Vec<usize>,
    coloured: Vec<u32>,
}

const NONE: u8 = u8::MAX;
/// Classes beyond this many hold one vertex each (very high valence).
const MAX_CLASSES: usize = 64;

impl Colouring {
    fn new(num_vertices: usize) -> Self {
        Colouring {
            colour: vec![NONE; num_vertices],
            order: Vec::new(),
            starts: Vec::new(),
            coloured: Vec::new(),
        }
    }

    /// Colours `vertices` (ascending) greedily in that order.
    fn colour(&mut self, mesh: &Mesh, topo: &Topology, vertices: &[u32]) {
        for &v in &self.coloured {
            self.colour[v as usize] = NONE;
        }
        self.coloured.clear();
        let mut overflow = Vec::new();
        let mut counts = [0usize; MAX_CLASSES];
        for &v in vertices {
            let used = self.classes_near(mesh, topo, v as usize);
            let c = (!used).trailing_zeros() as usize;
            if c < MAX_CLASSES {
                self.colour[v as usize] = c as u8;
                counts[c] += 1;
            } else {
                self.colour[v as usize] = MAX_CLASSES as u8;
                overflow.push(v);
            }
            self.coloured.push(v);
        }
        // Group by class, ascending within a class; overflow vertices form
        // classes of one.
        self.starts.clear();
        self.starts.push(0);
        let mut acc = 0;
        for &n in counts.iter().take_while(|&&n| n > 0) {
            acc += n;
            self.starts.push(acc);
        }
        self.order.clear();
        self.order.resize(acc, 0);
        let mut fill: Vec<usize> = self.starts[..self.starts.len() - 1].to_vec();
        for &v in vertices {
            let c = self.colour[v as usize] as usize;
            if c < fill.len() {
                self.order[fill[c]] = v;
                fill[c] += 1;
            }
        }
        for v in overflow {
            self.order.push(v);
            self.starts.push(self.order.len());
        }
    }

    /// The classes already taken within two edges of `v` or on its faces,
    /// one bit each; all of them for a neighbour of a hub, which is within
    /// two edges of all the hub's neighbours and takes a class of its own
    /// without that walk.
    fn classes_near(&self, mesh: &Mesh, topo: &Topology, v: usize) -> u64 {
        if topo.neighbors(v).iter().any(|&a| is_hub(topo, a as usize)) {
            return u64::MAX;
        }
        let mut used = 0u64;
        let mut mark = |w: u32| {
            let c = self.colour[w as usize];
            if (c as usize) < MAX_CLASSES {
                used |= 1 << c;
            }
        };
        for &a in topo.neighbors(v) {
            mark(a);
            for &b in topo.neighbors(a as usize) {
                mark(b);
            }
        }
        for &f in topo.vertex_faces(v) {
            for &w in mesh.face(f as usize) {
                mark(w);
            }
        }
        used
    }

    fn classes(&self) -> impl Iterator<Item = &[u32]> + '_ {
        self.starts.windows(2).map(|w| &self.order[w[0]..w[1]])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quality::fix_twisted_quads;
    use crate::quality::fixtures::{
        at, flattened_staircase, grid, min_split_angle, radially_projected_sphere, two_fans,
    };
    use crate::report::measure_stage;
    use crate::shapes::CENTER_OFFSET;

    /// The fix at a 20 degree threshold, 10 sweeps, no bound.
    fn fix_at_20(
        m: &Mesh,
        t: &Topology,
        p: &mut [DVec3],
        input: &[DVec3],
        movers: Movers,
    ) -> SharpAngleStats {
        fix_sharp_angles(m, t, p, input, None, 20.0, 10, 0.5, movers)
    }

    #[test]
    fn a_sliver_in_a_grid_opens_up() {
        let m = grid(5);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        // Vertex (2,2) dragged next to (3,2): slivers all around it.
        p[at(5, 2, 2)] = DVec3::new(2.9, 2.05, 0.0);
        assert!(min_split_angle(&m, &p, None) < 5.0);
        let stats = fix_at_20(&m, &t, &mut p, &input, Movers::Interior);
        assert!(stats.faces_found > 0 && stats.moves > 0);
        assert_eq!(stats.faces_remaining, 0);
        assert!(min_split_angle(&m, &p, None) >= 20.0 - 1e-9);
        assert!(p.iter().all(|q| q.z.abs() < 1e-9), "stays on the plane");
        let s = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert_eq!((s.inverted_faces, s.twisted_quads), (0, 0));
    }

    #[test]
    fn a_raised_vertex_opens_its_angles_at_its_own_height() {
        // The smoothing left vertex (3,3) 0.08 above its flat neighbours
        // and next to (4,3). Its neighbours' fit is the plane z = 0: the
        // fix opens the slivers without flattening the bump.
        let m = grid(6);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        let v = at(6, 3, 3);
        p[v] = DVec3::new(3.97, 3.02, 0.08);
        assert!(min_split_angle(&m, &p, None) < 10.0);
        let stats = fix_at_20(&m, &t, &mut p, &input, Movers::Interior);
        assert_eq!(stats.faces_remaining, 0, "{stats:?}");
        assert!(min_split_angle(&m, &p, None) >= 20.0 - 1e-9);
        assert!((p[v].z - 0.08).abs() < 1e-3, "moved to height {}", p[v].z);
    }

    #[test]
    fn flattened_risers_spread_tangentially() {
        let (m, flat, plane) = flattened_staircase(4, 6, 6);
        let t = Topology::build(&m);
        let input = m.positions();
        // Faces with no boundary corner can all be repaired; the slivers on
        // the rim keep their fixed boundary edge.
        let inner: Vec<usize> = (0..m.num_faces())
            .filter(|&f| {
                m.face(f)
                    .iter()
                    .all(|&v| t.kind(v as usize) == VertexKind::Interior)
            })
            .collect();
        let worst_before = min_split_angle(&m, &flat, Some(&inner));
        assert!(worst_before < 10.0, "risers are slivers: {worst_before}");
        let all_before = min_split_angle(&m, &flat, None);
        let mut p = flat.clone();
        fix_sharp_angles(&m, &t, &mut p, input, None, 20.0, 20, 0.5, Movers::Interior);
        let worst_after = min_split_angle(&m, &p, Some(&inner));
        assert!(worst_after > 15.0, "inner faces now {worst_after}");
        assert!(min_split_angle(&m, &p, None) >= all_before);
        let s = measure_stage(&m, &t, &p, input, None, 0.2);
        assert_eq!((s.inverted_faces, s.twisted_quads), (0, 0));
        for q in &p {
            assert!(plane.signed_distance(*q).abs() < 1e-9, "left the plane");
        }
    }

    #[test]
    fn a_projected_voxel_sphere_meets_the_quality_targets() {
        let radius = 8.0;
        let (m, projected) = radially_projected_sphere(radius);
        let t = Topology::build(&m);
        let input = m.positions();
        let before = measure_stage(&m, &t, &projected, input, None, 0.2);
        assert!(before.triangle_angles.below_15 > 0 && before.inverted_faces > 0);
        let mut p = projected.clone();
        fix_twisted_quads(&m, &t, &mut p, input, None, 10, 0.5);
        let stats = fix_at_20(&m, &t, &mut p, input, Movers::Interior);
        assert_eq!(stats.faces_remaining, 0, "{stats:?}");
        let after = measure_stage(&m, &t, &p, input, None, 0.2);
        assert_eq!(after.triangle_angles.below_15, 0);
        assert_eq!((after.inverted_faces, after.twisted_quads), (0, 0));
        // The shape is kept: the vertices stay close to the sphere (they
        // start on it; a voxel is 1).
        let d: Vec<f64> = p
            .iter()
            .map(|q| (q.distance(CENTER_OFFSET) - radius).abs())
            .collect();
        let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
        let worst = d.iter().fold(0.0f64, |a, &b| a.max(b));
        assert!(
            rms < 0.01 && worst < 0.1,
            "distance to the sphere: rms {rms}, max {worst}"
        );
    }

    #[test]
    fn the_result_does_not_depend_on_the_thread_count() {
        let (m, projected) = radially_projected_sphere(7.0);
        let t = Topology::build(&m);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let mut p = projected.clone();
                    let s = fix_sharp_angles(
                        &m,
                        &t,
                        &mut p,
                        m.positions(),
                        None,
                        25.0,
                        10,
                        0.5,
                        Movers::Interior,
                    );
                    (p, s)
                })
        };
        let (p1, s1) = run(1);
        let (p3, s3) = run(3);
        assert_eq!(s1, s3);
        assert!(p1 == p3, "positions differ between 1 and 3 threads");
        assert!(s1.moves > 0);
    }

    #[test]
    fn a_vertex_where_two_sheets_meet_moves_only_when_allowed_and_opens_its_angles() {
        // Two hexagonal discs, one in the plane z = 0 and one in x = 0,
        // share their centre (a non-manifold vertex); their rims are
        // boundaries, so only the centre can open the angles it closed by
        // coming most of the way to the rims.
        let mut input = vec![DVec3::ZERO];
        let mut faces = Vec::new();
        for disc in 0..2u32 {
            let first = input.len() as u32;
            for k in 0..6 {
                let turn = (60.0 * k as f64 + 30.0 * disc as f64).to_radians();
                let (sin, cos) = turn.sin_cos();
                input.push(if disc == 0 {
                    DVec3::new(cos, sin, 0.0)
                } else {
                    DVec3::new(0.0, cos, sin)
                });
            }
            for k in 0..6 {
                faces.push(vec![0, first + k, first + (k + 1) % 6]);
            }
        }
        let m = Mesh::from_polygons(input.clone(), &faces).expect("two discs");
        let t = Topology::build(&m);
        assert_eq!(t.kind(0), VertexKind::NonManifold);
        let mut start = input.clone();
        start[0] = DVec3::new(0.0, 0.82, 0.0);
        let before = min_split_angle(&m, &start, None);
        assert!(before < 10.0, "{before}");

        let mut p = start.clone();
        let stats = fix_at_20(&m, &t, &mut p, &input, Movers::Interior);
        assert_eq!(p, start);
        assert_eq!(stats.moves, 0);

        let mut p = start.clone();
        let stats = fix_at_20(&m, &t, &mut p, &input, Movers::AlsoNonManifold);
        let after = min_split_angle(&m, &p, None);
        assert!(stats.moves > 0 && after >= 20.0, "{after}");
        // The shortest step that opens them, not all the way back.
        assert!(p[0].y > 0.1, "{}", p[0]);
        assert!(p[1..] == start[1..]);
    }

    #[test]
    fn a_meeting_vertex_at_its_input_steps_across_the_way_to_its_neighbours() {
        // The centre of `two_fans` sits at its input position near the
        // first fan's rim, where that fan's face between its rim vertices
        // at 60 and 120 degrees is a sliver. Its neighbours' mean lies
        // beyond that rim: every step toward it folds the sliver, so only a
        // step across that way (out of the plane z = 0, within the second
        // fan's plane) opens it.
        let m = two_fans(DVec3::new(0.0, 0.82, 0.0));
        let input = m.positions().to_vec();
        let t = Topology::build(&m);
        assert_eq!(t.kind(0), VertexKind::NonManifold);
        let before = min_split_angle(&m, &input, None);
        assert!(before < 10.0, "{before}");

        let mut p = input.clone();
        let stats = fix_at_20(&m, &t, &mut p, &input, Movers::AlsoNonManifold);
        let after = min_split_angle(&m, &p, None);
        assert!(
            stats.moves > 0 && after > before + 10.0,
            "{before} -> {after}"
        );
        assert!(p[0].z.abs() > 0.05, "across the way to the mean: {}", p[0]);
        assert!(p[1..] == input[1..]);
        let s = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert_eq!(s.inverted_faces, 0);
    }

    #[test]
    fn colour_classes_are_independent_and_cover_the_list() {
        let m = grid(8);
        let t = Topology::build(&m);
        let list: Vec<u32> = (0..m.num_vertices() as u32)
            .filter(|&v| t.kind(v as usize) == VertexKind::Interior)
            .collect();
        let mut c = Colouring::new(m.num_vertices());
        c.colour(&m, &t, &list);
        let mut seen: Vec<u32> = c.classes().flatten().copied().collect();
        seen.sort_unstable();
        assert_eq!(seen, list);
        let mut ring = Vec::new();
        for class in c.classes() {
            for &v in class {
                crate::quality::local::two_ring(&t, v as usize, &mut ring);
                for &w in class {
                    assert!(w == v || !ring.contains(&w), "{v} and {w} in one class");
                }
            }
        }
    }
}
