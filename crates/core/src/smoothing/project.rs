//! Step 4: projection, the smoothing step (algorithm notes section 4).
//!
//! Each vertex moves along its normal onto its fitted quadric, `p_i' = p_i +
//! g n_i`. Updates are Jacobi style: all moves are computed from the old
//! positions and written to a second buffer (single precision: a move is at
//! most an edge long, so its rounding is a ten-millionth of an edge), then
//! applied, so the result is deterministic and independent of the thread
//! count.

use super::curvature::curvature_at;
use super::neighbourhood::{CHUNK, ChunkWeights, HoodSource, NeighbourWeights, Neighbourhoods};
use crate::fit::frame::Frame;
use crate::fit::normals::{
    face_vector_areas_f32, normal_from_areas, vertex_normal, vertex_normals_f32,
    vertex_normals_f32_by_faces,
};
use crate::fit::quadric_fit::{
    Facing, FitHeight, FitKind, FitModel, fit_neighbours, fit_neighbours_weighted,
};
use crate::mesh::{Mesh, Topology, VertexKind};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use serde::Serialize;

/// Largest move of one pass, in units of the vertex's mean edge length.
pub const MAX_STEP: f64 = 1.0;

/// What one pass (or a sum of passes) did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct FitStats {
    /// Fits that used the quadric plus cubic terms.
    pub cubic: u64,
    /// Fits that used the full quadric.
    pub quadric: u64,
    /// Fits that fell back to a plane.
    pub plane_fallback: u64,
    /// Vertices left in place because no fit was possible.
    pub fixed_fallback: u64,
    /// Largest distance a vertex moved.
    pub max_displacement: f64,
    /// Moves cut to [`MAX_STEP`] mean edge lengths.
    pub clamped: u64,
}

impl FitStats {
    fn merge(self, o: FitStats) -> FitStats {
        FitStats {
            cubic: self.cubic + o.cubic,
            quadric: self.quadric + o.quadric,
            plane_fallback: self.plane_fallback + o.plane_fallback,
            fixed_fallback: self.fixed_fallback + o.fixed_fallback,
            max_displacement: self.max_displacement.max(o.max_displacement),
            clamped: self.clamped + o.clamped,
        }
    }

    /// Adds another pass's counts (maximum of the displacements).
    pub fn accumulate(&mut self, o: FitStats) {
        *self = self.merge(o);
    }
}

/// What a [`fit_pass`] keeps for later passes to reuse its fits.
#[derive(Debug)]
pub struct Refit<'a> {
    /// Each fitted vertex's linear weights ([`fit_neighbours_weighted`]),
    /// made by the pass's `hoods`.
    pub weights: &'a mut NeighbourWeights,
    /// Per vertex, how far it has moved since its latest fit ([`UNFITTED_DRIFT`]).
    pub drift: &'a mut [f32],
    /// [`step_limits`].
    pub limits: &'a [f32],
    /// The vertices to fit anew; the others move by their stored weights,
    /// as in [`weighted_pass`], and keep them. `None`: all.
    pub stale: Option<&'a [bool]>,
}

/// A vertex's drift is how far it has moved since its latest fit: the sum
/// of the lengths of its moves since (an upper bound on the distance). It
/// is `UNFITTED_DRIFT` before the first fit and when that fit or a move on
/// its weights failed (a fixed fit, a move cut to the step limit), so the
/// vertex is refitted at the next chance.
pub const UNFITTED_DRIFT: f32 = f32::INFINITY;

/// Momentum for some vertices' moves in [`fit_pass`] and [`weighted_pass`]:
/// a vertex of `vertices` whose new move `m` points the same way as its
/// previous one `p` (what `out` holds when the pass starts) moves by
/// `m (1 + beta min(m . p / |m|, |m|) / |m|)`: at most `1 + beta` times
/// `m`, and only where consecutive moves agree, so a vertex converging
/// monotonically gets there in fewer passes and one that oscillates does
/// not oscillate more.
#[derive(Debug, Clone, Copy)]
pub struct Momentum<'a> {
    /// Whether each vertex takes momentum.
    pub vertices: &'a [bool],
    /// How much of the agreeing previous move is added.
    pub beta: f32,
}

impl Momentum<'_> {
    /// Vertex `v`'s move `m` with momentum from its previous move `prev`.
    #[inline]
    fn apply(&self, v: usize, m: Vec3, prev: Vec3) -> Vec3 {
        let len = m.length();
        let along = m.dot(prev);
        if !self.vertices[v] || len <= 0.0 || along <= 0.0 {
            return m;
        }
        m * (1.0 + self.beta * (along / len).min(len) / len)
    }
}

/// One Jacobi pass: fits `model` to every movable vertex's neighbourhood in
/// `positions` and writes each vertex's move to `out` (zero for immovable
/// vertices; movable boundary vertices fit a plane). Neighbours
/// whose normal makes a cosine below `min_cos` with the vertex's are left
/// out of its fit ([`Facing`]).
/// With `refit`, keeps each fit's linear weights and the vertices' drift
/// for [`weighted_pass`], and fits only `refit.stale` vertices (all when
/// `None`).
/// With `momentum`, the moves of its vertices take momentum from the moves
/// `out` holds when the pass starts ([`Momentum`]).
/// With `curvature`, also writes every vertex's `(H, K)` from its fit, as
/// [`vertex_curvatures`](super::curvature::vertex_curvatures) computes it
/// when `model` is the quadric and `hoods` are the same neighbourhoods
/// (immovable vertices are fitted for it without moving).
/// Returns the fit statistics.
///
/// # Panics
/// When `refit` is given with walked neighbourhoods (kept weights are laid
/// out like stored lists) or with `curvature` (a fit that keeps weights
/// solves for its height only).
/// What one [`fit_pass`] fits: where the neighbours come from, which
/// vertices move, the model, and what the pass keeps or adds.
pub struct FitPass<'a> {
    /// Each vertex's neighbourhood.
    pub hoods: HoodSource<'a>,
    /// Which vertices may move.
    pub movable: &'a [bool],
    /// The surface model.
    pub model: FitModel,
    /// Neighbours whose normal makes a cosine below this with the vertex's
    /// are left out of its fit ([`Facing`]).
    pub min_cos: f64,
    /// Keep the fits' weights for [`weighted_pass`] ([`Refit`]).
    pub refit: Option<Refit<'a>>,
    /// Moves with momentum ([`Momentum`]).
    pub momentum: Option<Momentum<'a>>,
    /// Where to write every vertex's `(H, K)` from its fit.
    pub curvature: Option<&'a mut [(f64, f64)]>,
}

pub fn fit_pass(
    mesh: &Mesh,
    topo: &Topology,
    positions: &[DVec3],
    pass: FitPass,
    out: &mut [Vec3],
) -> FitStats {
    let FitPass {
        hoods,
        movable,
        model,
        min_cos,
        refit,
        momentum,
        curvature,
    } = pass;
    let stored = match hoods {
        HoodSource::Stored(h) if curvature.is_none() => Some(h),
        _ => None,
    };
    // Passes over stored lists are the adaptive ones, where the run's
    // memory peaks: no face areas there.
    let normals = match hoods {
        HoodSource::Stored(_) => vertex_normals_f32(mesh, topo, positions),
        HoodSource::Walked { .. } => vertex_normals_f32_by_faces(mesh, topo, positions),
    };
    let chunks = out.len().div_ceil(CHUNK);
    let curvature: Vec<Option<&mut [(f64, f64)]>> = match curvature {
        Some(c) => c.chunks_mut(CHUNK).map(Some).collect(),
        None => (0..chunks).map(|_| None).collect(),
    };
    let (kept, limits, stale): (Vec<Option<Kept>>, &[f32], Option<&[bool]>) = match refit {
        Some(r) => (
            r.weights
                .chunks_mut(
                    stored.expect("fit weights are kept with stored lists and no curvature"),
                )
                .zip(r.drift.chunks_mut(CHUNK))
                .map(Some)
                .collect(),
            r.limits,
            r.stale,
        ),
        None => ((0..chunks).map(|_| None).collect(), &[], None),
    };
    let chunk_pass = ChunkPass {
        mesh,
        topo,
        positions,
        normals: &normals,
        hoods,
        movable,
        model,
        min_cos,
        momentum,
        limits,
        stale,
    };
    out.par_chunks_mut(CHUNK)
        .zip(kept)
        .zip(curvature)
        .enumerate()
        .map(|(c, ((out, kept), curvature))| chunk_pass.run(c, out, kept, curvature))
        .reduce(FitStats::default, FitStats::merge)
}

/// A chunk's kept weights and drift ([`Refit`]).
type Kept<'b> = (ChunkWeights<'b>, &'b mut [f32]);

/// What every chunk of a [`fit_pass`] reads.
struct ChunkPass<'a> {
    mesh: &'a Mesh,
    topo: &'a Topology,
    positions: &'a [DVec3],
    normals: &'a [Vec3],
    hoods: HoodSource<'a>,
    movable: &'a [bool],
    model: FitModel,
    min_cos: f64,
    momentum: Option<Momentum<'a>>,
    limits: &'a [f32],
    stale: Option<&'a [bool]>,
}

impl ChunkPass<'_> {
    /// Fits the vertices of chunk `c` (moves in `out`, one per vertex of
    /// the chunk), keeping their weights in `kept` and writing their
    /// curvature to `curvature` when given.
    #[inline]
    fn run(
        &self,
        c: usize,
        out: &mut [Vec3],
        mut kept: Option<Kept>,
        mut curvature: Option<&mut [(f64, f64)]>,
    ) -> FitStats {
        let ChunkPass {
            mesh,
            topo,
            positions,
            normals,
            hoods,
            movable,
            model: _,
            min_cos,
            momentum,
            limits,
            stale,
        } = *self;
        let mut stats = FitStats::default();
        // Scratch for one vertex: its decoded list and fit weights.
        let (mut list, mut slot_weights) = (Vec::new(), Vec::new());
        for (i, o) in out.iter_mut().enumerate() {
            let v = c * CHUNK + i;
            let p = positions[v];
            let prev = std::mem::replace(o, Vec3::ZERO);
            if let (Some((w, drift)), Some(stale)) = (kept.as_mut(), stale)
                && !stale[v]
            {
                if movable[v] {
                    w.get_f32_into(v, &mut slot_weights);
                    let (m, d) = reused_move(
                        positions,
                        vertex_normal(mesh, topo, positions, v),
                        w.hoods(),
                        &slot_weights,
                        limits[v],
                        v,
                        &mut stats,
                    );
                    (*o, drift[i]) = with_momentum(momentum, v, m, prev, drift[i], d);
                }
                continue;
            }
            let n = normals[v].as_dvec3().normalize_or_zero();
            if !movable[v] || n == DVec3::ZERO {
                if let Some(curvature) = curvature.as_mut() {
                    hoods.get_into(topo, v, &mut list);
                    curvature[i] = curvature_at(topo, positions, normals, v, &list, min_cos);
                }
                if let Some((w, drift)) = kept.as_mut() {
                    w.set(v, &[]);
                    drift[i] = if movable[v] { UNFITTED_DRIFT } else { 0.0 };
                }
                continue;
            }
            hoods.get_into(topo, v, &mut list);
            let fit = self.fit_height(
                v,
                Frame::new(p, n),
                &list,
                &mut slot_weights,
                kept.as_mut().map(|(w, _)| w),
                curvature.as_mut().map(|c| &mut c[i]),
            );
            match fit.kind {
                FitKind::Cubic => stats.cubic += 1,
                FitKind::Quadric => stats.quadric += 1,
                FitKind::Plane => stats.plane_fallback += 1,
                FitKind::Fixed => stats.fixed_fallback += 1,
            }
            let g = fit.height;
            let cut = step(topo, positions, v, g, &mut stats);
            let failed = fit.kind == FitKind::Fixed || cut != g;
            let (m, d) = with_momentum(
                momentum.filter(|_| !failed),
                v,
                (cut * n).as_vec3(),
                prev,
                0.0,
                cut.abs() as f32,
            );
            *o = m;
            if let Some((_, drift)) = kept.as_mut() {
                drift[i] = if failed { UNFITTED_DRIFT } else { d };
            }
        }
        stats
    }

    /// Fits vertex `v` in `frame` to its neighbours `list`: the fit's kind
    /// and height. With `weights`, keeps the fit's linear weights there
    /// (`scratch` holds them on the way); with `curvature`, writes the
    /// fit's `(H, K)`.
    #[inline]
    fn fit_height(
        &self,
        v: usize,
        frame: Frame,
        list: &[u32],
        scratch: &mut Vec<f32>,
        weights: Option<&mut ChunkWeights>,
        curvature: Option<&mut (f64, f64)>,
    ) -> FitHeight {
        // A movable boundary vertex (rule `normal_only`) fits a plane.
        let model = if self.topo.kind(v) == VertexKind::Boundary {
            FitModel::Plane
        } else {
            self.model
        };
        let facing = Facing {
            normals: self.normals,
            min_cos: self.min_cos,
        };
        match weights {
            Some(w) => {
                scratch.resize(list.len(), 0.0);
                let fit = fit_neighbours_weighted(
                    &frame,
                    self.positions,
                    list,
                    model,
                    Some(facing),
                    scratch,
                );
                w.set(v, scratch);
                fit
            }
            None => {
                let fit = fit_neighbours(&frame, self.positions, list, model, Some(facing));
                if let Some(curvature) = curvature {
                    *curvature = fit.curvature();
                }
                FitHeight {
                    kind: fit.kind,
                    height: fit.height(),
                }
            }
        }
    }
}

/// What a [`weighted_pass`] reuses: the neighbourhoods the fits were made
/// over, their linear weights, the step limits ([`step_limits`]), which
/// vertices move, and their momentum.
#[derive(Clone, Copy)]
pub struct Reuse<'a> {
    /// The neighbourhoods of the kept fits.
    pub hoods: &'a Neighbourhoods,
    /// Each vertex's kept linear weights.
    pub weights: &'a NeighbourWeights,
    /// Each vertex's step limit.
    pub limits: &'a [f32],
    /// Which vertices may move.
    pub movable: &'a [bool],
    /// Moves with momentum ([`Momentum`]).
    pub momentum: Option<Momentum<'a>>,
}

/// One Jacobi pass that moves each vertex along its current normal by the
/// height its last fit's linear `weights` give for the current heights of
/// its neighbours ([`fit_neighbours_weighted`]), with `momentum` from the
/// moves `out` holds when the pass starts ([`Momentum`]): the fit repeated with its
/// frame coordinates and point weights kept, at the cost of one weighted
/// sum, written as each vertex's move to `out`, its length added to the
/// vertex's `drift` ([`UNFITTED_DRIFT`]). The move is along the current
/// normal, not the fit's: on poorly fitted real meshes the fit's normal
/// lets the passes fold and swell the surface (`docs/tuning.md`).
/// Vertices whose weights are all zero (fixed, immovable) stay; so does a
/// vertex whose move would exceed its `limits` entry ([`step_limits`]),
/// counted as clamped: reused weights no longer describe a surface that
/// has moved that far, and a bound taken from the current edges could grow
/// with them, pass after pass. Counts no fits; returns the displacement
/// statistics.
pub fn weighted_pass(
    mesh: &Mesh,
    topo: &Topology,
    positions: &[DVec3],
    reuse: Reuse,
    drift: &mut [f32],
    out: &mut [Vec3],
) -> FitStats {
    let Reuse {
        hoods,
        weights,
        limits,
        movable,
        momentum,
    } = reuse;
    let areas = face_vector_areas_f32(mesh, positions);
    out.par_chunks_mut(CHUNK)
        .zip(drift.par_chunks_mut(CHUNK))
        .enumerate()
        .map(|(c, (out, drift))| {
            let mut stats = FitStats::default();
            let mut w = Vec::new();
            for (i, (o, drift)) in out.iter_mut().zip(drift).enumerate() {
                let v = c * CHUNK + i;
                let prev = std::mem::replace(o, Vec3::ZERO);
                if !movable[v] {
                    continue;
                }
                weights.get_f32_into(hoods, v, &mut w);
                let n = normal_from_areas(topo, &areas, v);
                let (m, d) = reused_move(positions, n, hoods, &w, limits[v], v, &mut stats);
                (*o, *drift) = with_momentum(momentum, v, m, prev, *drift, d);
            }
            stats
        })
        .reduce(FitStats::default, FitStats::merge)
}

/// Vertex `v`'s move `m` (drift `d`, [`UNFITTED_DRIFT`]) with `momentum`
/// from its previous move `prev`, and its drift `drift` plus the length of
/// that move (or plus `d` when `d` is not finite: a failed move, which
/// takes no momentum).
#[inline]
fn with_momentum(
    momentum: Option<Momentum>,
    v: usize,
    m: Vec3,
    prev: Vec3,
    drift: f32,
    d: f32,
) -> (Vec3, f32) {
    match momentum {
        Some(momentum) if d.is_finite() => {
            let moved = momentum.apply(v, m, prev);
            (moved, drift + moved.length())
        }
        _ => (m, drift + d),
    }
}

/// Vertex `v`'s move by its stored fit weights `w` (laid out by unit,
/// [`NeighbourWeights::get_f32_into`]) along its current unit normal `n`,
/// and the drift it adds ([`UNFITTED_DRIFT`]): its length, or infinity when
/// it is cut to zero beyond `limit` (counted as clamped, [`weighted_pass`]).
#[allow(clippy::too_many_arguments)]
#[inline]
fn reused_move(
    positions: &[DVec3],
    n: DVec3,
    hoods: &Neighbourhoods,
    w: &[f32],
    limit: f32,
    v: usize,
    stats: &mut FitStats,
) -> (Vec3, f32) {
    let p = positions[v];
    let mut d = DVec3::ZERO;
    for (unit, j) in hoods.entries(v) {
        let a = w.get(unit).copied().unwrap_or(0.0);
        d += f64::from(a) * (positions[j as usize] - p);
    }
    let g = d.dot(n);
    if g.abs() > f64::from(limit) || !g.is_finite() {
        stats.clamped += 1;
        return (Vec3::ZERO, UNFITTED_DRIFT);
    }
    stats.max_displacement = stats.max_displacement.max(g.abs());
    ((g * n).as_vec3(), g.abs() as f32)
}

/// The largest move [`weighted_pass`] accepts at each vertex: [`MAX_STEP`]
/// times the vertex's mean edge length in the input `mesh` (fixed, so
/// computed once for all passes).
pub fn step_limits(mesh: &Mesh, topo: &Topology) -> Vec<f32> {
    (0..topo.num_vertices())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| (MAX_STEP * mean_edge_at(topo, mesh.positions(), v)) as f32)
        .collect()
}

/// Mean length of the edges at vertex `v` in `positions`.
#[inline]
pub(crate) fn mean_edge_at(topo: &Topology, positions: &[DVec3], v: usize) -> f64 {
    let p = positions[v];
    let nb = topo.neighbors(v);
    nb.iter()
        .map(|&j| positions[j as usize].distance(p))
        .sum::<f64>()
        / nb.len().max(1) as f64
}

/// The height `g` a pass moves vertex `v` by, cut to [`MAX_STEP`] times the
/// vertex's mean edge length (counted in `stats`): staircase noise needs at
/// most half of that, and a larger step means a fit that does not describe
/// the surface.
#[inline]
fn step(topo: &Topology, positions: &[DVec3], v: usize, g: f64, stats: &mut FitStats) -> f64 {
    let limit = MAX_STEP * mean_edge_at(topo, positions, v);
    let cut = g.clamp(-limit, limit);
    if cut != g {
        stats.clamped += 1;
    }
    stats.max_displacement = stats.max_displacement.max(cut.abs());
    cut
}

/// Adds each vertex's move to its position.
pub fn apply(positions: &mut [DVec3], moves: &[Vec3]) {
    positions
        .par_iter_mut()
        .zip(moves)
        .with_min_len(4096)
        .for_each(|(p, m)| *p += m.as_dvec3());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn momentum_adds_only_where_consecutive_moves_agree() {
        let vertices = [true, false];
        let momentum = Momentum {
            vertices: &vertices,
            beta: 0.5,
        };
        let m = Vec3::new(0.0, 0.0, 0.2);
        // A larger previous move the same way: half the new move is added.
        assert_eq!(momentum.apply(0, m, Vec3::new(0.1, 0.0, 1.0)), m * 1.5);
        // A smaller one: half of its part along the new move.
        let with = momentum.apply(0, m, Vec3::new(0.3, 0.0, 0.1));
        assert!((with - m * 1.25).length() < 1e-6, "{with}");
        // Opposite, across, none, or a vertex without momentum: unchanged.
        for prev in [-m, Vec3::X, Vec3::ZERO] {
            assert_eq!(momentum.apply(0, m, prev), m);
        }
        assert_eq!(momentum.apply(1, m, m), m);
        assert_eq!(momentum.apply(0, Vec3::ZERO, m), Vec3::ZERO);
    }
    use crate::mesh::test_grid as grid;

    #[test]
    fn a_reused_fit_never_jumps_beyond_an_input_edge_and_asks_for_a_refit() {
        // A flat unit grid whose centre vertex puts all its weight on one
        // neighbour: the vertex follows that neighbour's height while it
        // stays within one input edge length, and stays put beyond.
        let mesh = grid(4);
        let topo = Topology::build(&mesh);
        let hoods = Neighbourhoods::two_ring(&topo, 64);
        let centre = 12;
        let mut list = Vec::new();
        hoods.get_into(centre, &mut list);
        let target = list[0] as usize;
        let mut weights = hoods.zero_weights();
        for mut chunk in weights.chunks_mut(&hoods) {
            chunk.set(centre, &[1.0]);
        }
        let movable = vec![true; mesh.num_vertices()];
        let mut out = vec![Vec3::ZERO; mesh.num_vertices()];
        let edge = mean_edge_at(&topo, mesh.positions(), centre);
        let limits = step_limits(&mesh, &topo);
        let normal = vertex_normal(&mesh, &topo, mesh.positions(), centre);
        for (lift, moves) in [(0.5, true), (3.0, false)] {
            let mut p = mesh.positions().to_vec();
            p[target] += lift * edge * normal;
            let mut drift = vec![0.25f32; mesh.num_vertices()];
            let reuse = Reuse {
                hoods: &hoods,
                weights: &weights,
                limits: &limits,
                movable: &movable,
                momentum: None,
            };
            let stats = weighted_pass(&mesh, &topo, &p, reuse, &mut drift, &mut out);
            let moved = f64::from(out[centre].length());
            if moves {
                assert!(moved > 0.3 * edge, "followed by {moved}");
                assert_eq!(stats.clamped, 0);
                assert!((f64::from(drift[centre]) - 0.25 - moved).abs() < 1e-6);
            } else {
                assert_eq!(moved, 0.0);
                assert_eq!(stats.clamped, 1);
                // A failed move asks for a refit.
                assert_eq!(drift[centre], UNFITTED_DRIFT);
            }
        }
    }
}
