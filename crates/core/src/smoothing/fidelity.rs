//! The fidelity bound: how far a vertex may move from where the input put
//! it, so the smoothed surface stays true to the segmentation it came from.
//!
//! The paper (section 2.2-2.3) moves each vertex onto its fitted quadric
//! with no limit; on thin sheets, tubes and non-manifold contacts the fits
//! then pull vertices across the structure and faces fold. What a vertex's
//! input position says about the true surface decides the bound:
//! - A vertex of a voxel lattice (a voxel-boundary mesh: every edge at the
//!   vertex runs along one of the lattice's three axes) sits at a corner
//!   shared by eight voxels, some inside and some outside. The true surface
//!   separates those voxels' centres, which are the corners of the box of
//!   half a voxel around the vertex along each axis (its dual voxel): the
//!   true surface crosses that box, so the vertex is held inside it, axis by
//!   axis in the lattice's frame. Each axis has its own spacing: a
//!   thick-slice image's voxels are longer across the slices, and so are
//!   their dual voxels.
//! - A vertex of a marching-cubes mesh of a mask sits at the midpoint of a
//!   lattice edge between an inside and an outside voxel centre: the true
//!   surface crosses that edge between the two centres. Moving the surface
//!   by `d` along its unit normal `n` moves its crossing with an edge along
//!   axis `a` by `d / |n.a|`, so the crossing stays on the edge while
//!   `|d| <= (spacing / 2) |n.a|`: the vertex is held in that slab about its
//!   input position, across the surface (along the input's normal averaged
//!   over a few rings, [`SLAB_NORMAL_SMOOTHING`]), and is free along the
//!   surface up to the ball below. Without it the fits' bias (a fit to a
//!   cap lies off the cap where its curvature changes) drifts gyri and
//!   creases by as much as the ball, past the voxel centres that say where
//!   the surface is. The slab stops short of the centres themselves
//!   ([`CROSSING_SHARE`]).
//! - Any vertex off a voxel lattice (marching cubes, molecular surfaces,
//!   neurons) is held within a ball around its input position.
//! - A vertex of a mesh cut from no grid is also held, across the surface,
//!   within a curved slab about its input surface as wide as a multiple of
//!   the input's own noise ([`super::noise`]): such a mesh may already be
//!   smooth, and nothing else says how far its surface may be moved.
//!
//! The sizes are `max_displacement` times the lattice's spacing along each
//! axis (box), times the vertex's mean input edge length (ball) or times the
//! voxel spacing (slab): 0.5 gives the dual voxel on a lattice, so no vertex
//! of a voxel mesh moves more than `sqrt(3) / 2` voxel, and the lattice edge
//! short of its voxel centres ([`CROSSING_SHARE`]) on a marching-cubes
//! mesh, whose ball is also at most `max_displacement`
//! spacings of the vertex's edge and then narrowed by
//! [`MARCHING_CUBES_BALL_SHARE`] (the quality fixes get twice the ball,
//! capped at twice `max_displacement` spacings along each axis where the
//! spacing differs by axis, or on a lattice the ellipsoid of twice the
//! box's half-widths: one voxel).

use super::noise::{self, SurfaceSlab};
use super::project::mean_edge_at;
use crate::fit::normals::vertex_normals_f32_by_faces;
use crate::mesh::lattice::{MarchingCubesGrid, along_axis, lattice_frame, marching_cubes_grid};
use crate::mesh::{Mesh, Topology};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// A run's fidelity bound, if any, with the input positions it holds the
/// vertices to and the vertices it has held back so far.
#[derive(Debug)]
pub struct Fidelity<'a> {
    bound: Option<(&'a FidelityBound, &'a [DVec3])>,
    /// Per vertex (when bounded): whether the bound has held it back;
    /// shared with the [`Fidelity::with_bound`]s made from this one.
    held: Arc<[AtomicBool]>,
}

impl<'a> Fidelity<'a> {
    /// Holds `input.len()` vertices to `bound` around `input`, or lets
    /// them move freely when `bound` is `None`.
    pub fn new(bound: Option<&'a FidelityBound>, input: &'a [DVec3]) -> Self {
        Fidelity {
            bound: bound.map(|b| (b, input)),
            held: if bound.is_some() {
                (0..input.len()).map(|_| AtomicBool::new(false)).collect()
            } else {
                Arc::new([])
            },
        }
    }

    /// The same input positions held to `bound` instead, recording into
    /// the same held-back vertices (the quality fixes' wider bound counts
    /// with the smoothing's); unbounded when either is.
    pub fn with_bound(&self, bound: Option<&'a FidelityBound>) -> Self {
        match (self.bound, bound) {
            (Some((_, input)), Some(b)) => Fidelity {
                bound: Some((b, input)),
                held: Arc::clone(&self.held),
            },
            _ => Fidelity {
                bound: None,
                held: Arc::new([]),
            },
        }
    }

    /// No bound: every vertex moves freely.
    #[cfg(test)]
    pub fn unbounded() -> Self {
        Fidelity {
            bound: None,
            held: Arc::new([]),
        }
    }

    /// Brings `positions` back within the bound (nothing when unbounded).
    pub fn apply(&self, positions: &mut [DVec3]) {
        if let Some((bound, input)) = self.bound {
            bound.clamp(input, positions, &self.held);
        }
    }

    /// Whether the bound is placed by a lattice's voxel centres (dual-voxel
    /// boxes or marching-cubes slabs), not only balls.
    pub fn on_lattice(&self) -> bool {
        self.bound
            .is_some_and(|(b, _)| b.has_lattice() || b.has_marching_cubes())
    }

    /// Vertices held back at least once, by this bound or by another
    /// made from it with [`Fidelity::with_bound`].
    pub fn held_back(&self) -> u64 {
        self.held
            .iter()
            .filter(|h| h.load(Ordering::Relaxed))
            .count() as u64
    }
}

/// Relative slack of [`FidelityBound::allows`]: a vertex the clamp put on
/// its bound's surface is still allowed after rounding.
const ALLOW_SLACK: f64 = 1e-9;

/// Steps of averaging each vertex's normal with its neighbours' that give
/// a marching-cubes vertex the normal of its slab: the faces of a
/// staircase turn by 45 to 90 degrees from one to the next, and the
/// surface the mask samples has the normal of their average over a few
/// rings, the extent of a staircase's step on an oblique surface. Each
/// step widens the average by about a ring at its edge; from 3 to 12 steps
/// the analytic families and the WM crop's marching cubes change by 2% or
/// less (`docs/tuning.md`).
pub const SLAB_NORMAL_SMOOTHING: u32 = 8;

/// The share of the lattice edge's half length, from its midpoint, that a
/// marching-cubes vertex's slab lets its crossing move (times
/// `max_displacement / 0.5`). A crossing at a voxel centre puts that centre
/// on the surface, and the faces beside the vertex then pass it on the
/// side its mask does not say: where the fits' bias takes a crease or a
/// strand's crossings to the ends of their edges, the output leaves
/// centres of the mask out (or takes them in) that the true surface keeps
/// on their side. Chosen from 0.8, 0.85 and 0.9 (1 is the whole half
/// edge) on the analytic families at eight placements and the real masks
/// at three: every share brings the real masks closer, the more the
/// smaller; 0.8 holds a smooth sphere's or torus's vertices farther from
/// their surface than the whole edge does, and 0.85 is the smallest that
/// brings the smooth, the touching and the folded families closer at
/// their median and their worst placement, the thin tubes within 2%
/// (`docs/tuning.md`). At the defaults the crossing stops 0.075 spacing
/// short of both centres.
pub const CROSSING_SHARE: f64 = 0.85;

/// The share of the ball (`max_displacement` mean edge lengths, at most
/// `max_displacement` voxels) that a marching-cubes vertex of a mask may
/// use; its slab holds it across the surface, the ball along it, and the
/// quality fixes get twice the ball. With less room along the surface the
/// real masks' marching cubes come closer to their truth, where detail two
/// to four voxels across is most of the surface: the WM crop and the GM
/// mask at three placements, the T1 template's levels, and the data
/// folder's neuron, molecular surface and protein density map voxelised.
/// The smooth analytic families, whose fits are true over the whole ball,
/// lose a little at 0.8; at 0.6 the WM crop's marching cubes lose too
/// (`docs/tuning.md`, "The marching cubes' room along the surface").
pub const MARCHING_CUBES_BALL_SHARE: f64 = 0.8;

/// The slab a marching-cubes vertex is held in: `|(p - input) . normal|
/// <= half_width`.
#[derive(Debug, Clone, Copy)]
struct Slab {
    normal: Vec3,
    half_width: f32,
}

impl Slab {
    /// The normal made unit in double precision: a single-precision unit
    /// vector's length is 1 only to about 1e-7, and a move clamped along it
    /// would end that far outside the slab it was clamped to.
    fn unit_normal(&self) -> DVec3 {
        self.normal.as_dvec3().normalize_or_zero()
    }
}

/// Per-vertex bound on the distance from the input position, built once
/// from the input mesh.
#[derive(Debug, Clone)]
pub struct FidelityBound {
    /// The lattice's axes, when the mesh has one.
    frame: Option<[DVec3; 3]>,
    /// The lattice's spacing along each axis of `frame` (ones without a
    /// lattice).
    spacing: DVec3,
    /// Per vertex: on the lattice, the bound's half-widths in spacings along
    /// each axis (positive); elsewhere a ball radius (negative, stored as
    /// its negation); 0 holds the vertex fixed.
    size: Arc<[f32]>,
    /// Whether this is the quality fixes' room ([`FidelityBound::widened`]):
    /// a lattice vertex is held in the ellipsoid of its half-widths rather
    /// than in their box, and a ball is capped per axis by `caps`.
    widened: bool,
    /// Per vertex, on a marching-cubes mesh of a mask: the slab across the
    /// surface that keeps its crossing on the vertex's lattice edge (`None`
    /// for a vertex off the lattice's edges).
    slabs: Option<Arc<[Option<Slab>]>>,
    /// On a marching-cubes mesh of a grid whose spacing differs by axis:
    /// the grid's axes and the most the quality fixes' ball may reach along
    /// each ([`VoxelCaps`]).
    caps: Option<VoxelCaps>,
    /// Per vertex, on a mesh of no grid: the slab about its input surface
    /// that its input's noise allows ([`FidelityBound::across_input_noise`];
    /// `None` for a vertex the ball alone holds), shared by the scaled and
    /// widened bounds, with the factor this bound widens them by.
    surface: Option<(Arc<[Option<SurfaceSlab>]>, f64)>,
}

/// The reach of the quality fixes' ball along each axis of an anisotropic
/// marching-cubes grid: the room's factor times `max_displacement` times the
/// grid's spacing along that axis, one voxel at the defaults. The ball is
/// as wide as the vertex's own edge allows, and the edge across a thick
/// slice is the slice's length: twice that ball would take a vertex more
/// than a voxel along the thin axes. Capped per axis it is an ellipsoid
/// that, like a voxel corner's room, keeps within one voxel along each
/// axis. The smoothing passes' ball (half as wide, and held in the slab
/// across the surface) stays uncapped: the surface crosses a long edge
/// anywhere along it, and the passes need that freedom along the surface.
#[derive(Debug, Clone, Copy)]
struct VoxelCaps {
    frame: [DVec3; 3],
    reach: DVec3,
}

/// How much the spacing of a marching-cubes grid may differ between its
/// axes and still count as isotropic: more than a file's rounding, less
/// than any real voxel shape's.
const ANISOTROPY: f64 = 1e-3;

impl VoxelCaps {
    /// The caps of `grid` for `max_displacement`, when its spacing
    /// differs by axis.
    fn of(grid: &MarchingCubesGrid, max_displacement: f64) -> Option<Self> {
        let s = grid.spacing;
        (s.max_element() > s.min_element() * (1.0 + ANISOTROPY)).then_some(VoxelCaps {
            frame: grid.frame,
            reach: max_displacement * s,
        })
    }

    /// Offset `d` in units of the ellipsoid whose semi-axes are `radius`
    /// capped by the reach along each axis: at most 1 inside it (a radius
    /// of 0 holds the vertex where it is).
    fn extent(&self, d: DVec3, radius: f64) -> f64 {
        if radius <= 0.0 {
            return if d == DVec3::ZERO { 0.0 } else { f64::INFINITY };
        }
        let semi = self.reach.min(DVec3::splat(radius));
        (in_frame_of(&self.frame, d) / semi).length()
    }

    /// The caps of a bound `factor` times as large.
    fn scaled(self, factor: f64) -> Self {
        VoxelCaps {
            reach: self.reach * factor,
            ..self
        }
    }
}

impl FidelityBound {
    /// The bound for `mesh`'s input positions with sizes of
    /// `max_displacement` lattice spacings along each axis (a box, at the
    /// vertices whose edges all run along the lattice's axes) or mean edge
    /// lengths (a ball, per vertex, of its own edges).
    pub fn new(mesh: &Mesh, topo: &Topology, max_displacement: f64) -> Self {
        let p = mesh.positions();
        let frame = lattice_frame(topo, p);
        let grid = if frame.is_none() {
            marching_cubes_grid(topo, p)
        } else {
            None
        };
        // Whether each vertex has all its edges along the lattice's axes.
        let on_lattice: Vec<bool> = (0..topo.num_vertices())
            .into_par_iter()
            .with_min_len(4096)
            .map(|v| {
                frame.is_some_and(|f| {
                    topo.neighbors(v)
                        .iter()
                        .all(|&j| along_axis(&f, p[j as usize] - p[v]).is_some())
                })
            })
            .collect();
        let spacing = frame.map_or(DVec3::ONE, |f| lattice_spacing(topo, p, &f, &on_lattice));
        let size = (0..topo.num_vertices())
            .into_par_iter()
            .with_min_len(4096)
            .map(|v| {
                if topo.neighbors(v).is_empty() {
                    return 0.0;
                }
                if on_lattice[v] {
                    return max_displacement as f32;
                }
                let mut s = max_displacement * mean_edge_at(topo, p, v);
                // A marching-cubes vertex's ball is at most as large as a
                // voxel corner's box: where the mesh's edges are longer
                // than a voxel, the quality fixes' room (twice the ball)
                // would otherwise take it more than a voxel from its edge.
                // It is also narrower than another vertex's
                // ([`MARCHING_CUBES_BALL_SHARE`]).
                if let Some(Some(edge)) = grid.as_ref().map(|g| g.edges[v]) {
                    s = MARCHING_CUBES_BALL_SHARE * s.min(max_displacement * edge.spacing);
                }
                -s as f32
            })
            .collect::<Vec<f32>>()
            .into();
        let caps = grid
            .as_ref()
            .and_then(|grid| VoxelCaps::of(grid, max_displacement));
        let slabs = grid.map(|grid| marching_cubes_slabs(mesh, topo, max_displacement, &grid));
        FidelityBound {
            frame,
            spacing,
            size,
            widened: false,
            slabs,
            caps,
            surface: None,
        }
    }

    /// This bound with each vertex of `mesh` also held across its input
    /// surface within `reach` times the input's noise ([`noise::estimate`],
    /// neighbours facing below `min_cos` left out of the fits), and the
    /// estimate. Only a bound of no grid takes slabs: a voxel corner's box
    /// and a marching-cubes vertex's slab already say how far the surface
    /// may move, and there no estimate is made. Unchanged, with no
    /// estimate, when the mesh has too few fits for one.
    pub fn across_input_noise(
        self,
        mesh: &Mesh,
        topo: &Topology,
        reach: f64,
        min_cos: f64,
    ) -> (Self, Option<f64>) {
        if self.has_lattice() || self.has_marching_cubes() {
            return (self, None);
        }
        let _s = tracing::info_span!("input_noise").entered();
        match noise::estimate(mesh, topo, reach, min_cos) {
            Some(noise) => (
                FidelityBound {
                    surface: Some((noise.slabs.into(), 1.0)),
                    ..self
                },
                Some(noise.median),
            ),
            None => (self, None),
        }
    }

    /// `factor` times this bound's size at every vertex, as a ball off the
    /// lattice (capped per axis on an anisotropic marching-cubes grid,
    /// [`VoxelCaps`]) and as the ellipsoid of the box's half-widths on it:
    /// the room the quality fixes get, which must be able to open a
    /// triangle that the box's walls flattened (a box of that size would
    /// reach `sqrt(3)` times as far along its diagonals).
    pub fn widened(&self, factor: f64) -> Self {
        FidelityBound {
            frame: self.frame,
            spacing: self.spacing,
            slabs: None,
            surface: self.scaled_surface(factor),
            caps: self.caps.map(|c| c.scaled(factor)),
            widened: true,
            size: self
                .size
                .iter()
                .map(|&s| s * factor as f32)
                .collect::<Vec<f32>>()
                .into(),
        }
    }

    /// The same bound with every size times `factor`, in the same frame.
    pub fn scaled(&self, factor: f64) -> Self {
        FidelityBound {
            frame: self.frame,
            spacing: self.spacing,
            widened: self.widened,
            surface: self.scaled_surface(factor),
            caps: self.caps.map(|c| c.scaled(factor)),
            slabs: self.slabs.as_ref().map(|slabs| {
                slabs
                    .iter()
                    .map(|s| {
                        s.map(|s| Slab {
                            half_width: s.half_width * factor as f32,
                            ..s
                        })
                    })
                    .collect()
            }),
            size: self
                .size
                .iter()
                .map(|&s| s * factor as f32)
                .collect::<Vec<f32>>()
                .into(),
        }
    }

    /// Whether position `p` of vertex `v` (input position `input`) is
    /// within the bound.
    pub fn allows(&self, v: usize, input: DVec3, p: DVec3) -> bool {
        let Some(&s) = self.size.get(v) else {
            return true;
        };
        let d = p - input;
        match self.frame {
            Some(f) if s > 0.0 => {
                let h = f64::from(s) * (1.0 + ALLOW_SLACK);
                let local = self.in_spacings(&f, d);
                if self.widened {
                    local.length() <= h
                } else {
                    local.abs().max_element() <= h
                }
            }
            _ => {
                let in_slab = self.slab(v).is_none_or(|slab| {
                    d.dot(slab.unit_normal()).abs()
                        <= f64::from(slab.half_width) * (1.0 + ALLOW_SLACK)
                }) && self
                    .surface_slab(v)
                    .is_none_or(|slab| slab.contains(d, ALLOW_SLACK));
                let r = f64::from(s).abs();
                let in_ball = match self.ball_caps() {
                    Some(caps) => caps.extent(d, r) <= 1.0 + ALLOW_SLACK,
                    None => d.length() <= r * (1.0 + ALLOW_SLACK),
                };
                in_slab && in_ball
            }
        }
    }

    /// Vertex `v`'s slab about its input surface, if it has one.
    fn surface_slab(&self, v: usize) -> Option<SurfaceSlab> {
        let (slabs, factor) = self.surface.as_ref()?;
        let slab = slabs.get(v).copied().flatten()?;
        Some(if *factor == 1.0 {
            slab
        } else {
            slab.scaled(*factor)
        })
    }

    /// The slabs about the input surface, `factor` times as wide (the same
    /// slabs, not a copy).
    fn scaled_surface(&self, factor: f64) -> Option<(Arc<[Option<SurfaceSlab>]>, f64)> {
        self.surface
            .as_ref()
            .map(|(slabs, f)| (Arc::clone(slabs), f * factor))
    }

    /// Vertex `v`'s slab, if it has one.
    fn slab(&self, v: usize) -> Option<Slab> {
        self.slabs
            .as_ref()
            .and_then(|s| s.get(v).copied().flatten())
    }

    /// Offset `d` in the lattice's frame `f`, in its spacings.
    fn in_spacings(&self, f: &[DVec3; 3], d: DVec3) -> DVec3 {
        in_frame_of(f, d) / self.spacing
    }

    /// The per-axis caps of a ball, which only the quality fixes' room
    /// ([`FidelityBound::widened`]) has.
    fn ball_caps(&self) -> Option<VoxelCaps> {
        self.caps.filter(|_| self.widened)
    }

    /// The lattice's axes (the standard axes when the mesh has none), its
    /// spacing along them (ones when none) and the per-vertex sizes: a box
    /// of that many spacings along each axis (positive), a ball radius
    /// (negative, stored as its negation), or 0 for a vertex held fixed.
    /// For solvers that iterate in the lattice's frame, where a box is a
    /// clamp per coordinate; not for the quality fixes' widened bound,
    /// whose lattice vertices have ellipsoids.
    pub fn in_frame(&self) -> ([DVec3; 3], DVec3, &[f32]) {
        (
            self.frame.unwrap_or([DVec3::X, DVec3::Y, DVec3::Z]),
            self.spacing,
            &self.size,
        )
    }

    /// Whether the mesh was recognised as a voxel lattice.
    pub fn has_lattice(&self) -> bool {
        self.frame.is_some()
    }

    /// Whether vertices have slabs about their input surface (a mesh of no
    /// grid whose noise was estimated).
    pub fn has_surface(&self) -> bool {
        self.surface.is_some()
    }

    /// Vertex `v`'s input normal where it has a slab about its input
    /// surface ([`FidelityBound::across_input_noise`]): on a mesh of no
    /// grid whose noise was estimated, at an interior vertex with a fit.
    pub fn surface_normal(&self, v: usize) -> Option<DVec3> {
        self.surface_slab(v).map(|slab| slab.normal())
    }

    /// Whether the mesh was recognised as a marching-cubes mesh of a mask
    /// (its vertices have slabs).
    pub fn has_marching_cubes(&self) -> bool {
        self.slabs.is_some()
    }

    /// Brings every vertex of `positions` back within its bound around
    /// `input` (the same vertex's input position) and marks in `held` the
    /// vertices it moved. Deterministic and parallel per vertex.
    fn clamp(&self, input: &[DVec3], positions: &mut [DVec3], held: &[AtomicBool]) {
        let frame = self.frame.unwrap_or([DVec3::X, DVec3::Y, DVec3::Z]);
        positions
            .par_iter_mut()
            .zip(input)
            .zip(&self.size[..])
            .zip(held)
            .enumerate()
            .with_min_len(4096)
            .for_each(|(v, (((p, &o), &s), held))| {
                let d = *p - o;
                let bounded = if s > 0.0 {
                    let h = f64::from(s);
                    let local = self.in_spacings(&frame, d);
                    let c = if self.widened {
                        local.clamp_length_max(h)
                    } else {
                        local.clamp(DVec3::splat(-h), DVec3::splat(h))
                    };
                    if c == local {
                        return;
                    }
                    let c = c * self.spacing;
                    c.x * frame[0] + c.y * frame[1] + c.z * frame[2]
                } else {
                    // The slab first, then the ball: the ball only shortens
                    // a move, which keeps it in a flat slab. A curved slab
                    // (a mesh of no grid, which has no flat slab and no
                    // caps) clamps both at once.
                    let mut b = d;
                    let r = -f64::from(s);
                    if let Some(slab) = self.surface_slab(v) {
                        b = slab.clamp_within(b, r);
                    }
                    if let Some(slab) = self.slab(v) {
                        let n = slab.unit_normal();
                        let w = f64::from(slab.half_width);
                        let across = b.dot(n);
                        b -= (across - across.clamp(-w, w)) * n;
                    }
                    match self.ball_caps() {
                        Some(caps) => {
                            let e = caps.extent(b, r);
                            if e > 1.0 {
                                b /= e;
                            }
                        }
                        None => {
                            let len = b.length();
                            if len > r {
                                b *= r / len;
                            }
                        }
                    }
                    if b == d {
                        return;
                    }
                    b
                };
                *p = o + bounded;
                held.store(true, Ordering::Relaxed);
            });
    }
}

/// Offset `d` in the coordinates of the orthonormal `frame`.
pub(crate) fn in_frame_of(frame: &[DVec3; 3], d: DVec3) -> DVec3 {
    DVec3::new(frame[0].dot(d), frame[1].dot(d), frame[2].dot(d))
}

/// The lattice's spacing along each axis of `frame`: the median length of
/// the edges along it between the vertices `on_lattice`. An axis without
/// such edges (no closed voxel surface lacks any) takes the others'
/// median. Sequential, so the same for any thread count.
fn lattice_spacing(topo: &Topology, p: &[DVec3], frame: &[DVec3; 3], on_lattice: &[bool]) -> DVec3 {
    let mut lengths: [Vec<f64>; 3] = Default::default();
    for v in (0..topo.num_vertices()).filter(|&v| on_lattice[v]) {
        for &j in topo.neighbors(v) {
            let d = p[j as usize] - p[v];
            if (j as usize) > v
                && let Some(a) = along_axis(frame, d)
            {
                lengths[a].push(d.length());
            }
        }
    }
    let median = |l: &mut Vec<f64>| {
        let mid = l.len() / 2;
        (!l.is_empty()).then(|| *l.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1)
    };
    let per_axis: Vec<Option<f64>> = lengths.iter_mut().map(median).collect();
    let mut all: Vec<f64> = per_axis.iter().flatten().copied().collect();
    let fallback = median(&mut all).unwrap_or(1.0);
    DVec3::new(
        per_axis[0].unwrap_or(fallback),
        per_axis[1].unwrap_or(fallback),
        per_axis[2].unwrap_or(fallback),
    )
}

/// The slabs of a marching-cubes mesh of a mask whose vertices sit on
/// `grid`'s edges (see the module docs): half-width `max_displacement`
/// voxel spacings times the share of the normal along the vertex's edge.
fn marching_cubes_slabs(
    mesh: &Mesh,
    topo: &Topology,
    max_displacement: f64,
    grid: &MarchingCubesGrid,
) -> Arc<[Option<Slab>]> {
    let p = mesh.positions();
    let mut normals = vertex_normals_f32_by_faces(mesh, topo, p);
    for _ in 0..SLAB_NORMAL_SMOOTHING {
        normals = (0..normals.len())
            .into_par_iter()
            .with_min_len(4096)
            .map(|v| {
                let sum = topo
                    .neighbors(v)
                    .iter()
                    .fold(normals[v], |n, &j| n + normals[j as usize]);
                sum.normalize_or_zero()
            })
            .collect();
    }
    // A vertex without a normal (one without faces, a sheet folded onto
    // itself) gets no slab: the ball alone decides.
    grid.edges
        .iter()
        .zip(&normals)
        .map(|(edge, &normal)| {
            let edge = (*edge)?;
            if normal == Vec3::ZERO {
                return None;
            }
            let share = normal.as_dvec3().dot(grid.direction(edge)).abs();
            Some(Slab {
                normal,
                half_width: (CROSSING_SHARE * max_displacement * edge.spacing * share) as f32,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    /// `mesh` with every position multiplied by `spacing`, axis by axis: a
    /// mask's mesh on voxels of that shape.
    fn stretched(mesh: &Mesh, spacing: DVec3) -> Mesh {
        let mut mesh = mesh.clone();
        for p in mesh.positions_mut() {
            *p *= spacing;
        }
        mesh
    }

    #[test]
    fn voxel_meshes_get_the_dual_voxel_and_others_a_ball() {
        let (_, voxel) = shapes::voxel_sphere(6.0);
        let topo = Topology::build(&voxel);
        let bound = FidelityBound::new(&voxel, &topo, 0.5);
        assert!(bound.has_lattice());
        assert!(bound.size.iter().all(|&s| (s - 0.5).abs() < 1e-6));

        let (_, mc) = shapes::mc_sphere(6.0);
        let topo = Topology::build(&mc);
        let bound = FidelityBound::new(&mc, &topo, 0.5);
        assert!(!bound.has_lattice());
        assert!(bound.size.iter().all(|&s| s < 0.0));
    }

    #[test]
    fn marching_cubes_vertices_move_freely_along_the_surface_and_within_their_edge_across_it() {
        let (sphere, mc) = shapes::mc_sphere(8.0);
        let topo = Topology::build(&mc);
        let bound = FidelityBound::new(&mc, &topo, 0.5);
        assert!(bound.has_marching_cubes() && !bound.has_lattice());
        let input = mc.positions();
        let v = 0;
        let slab = bound.slab(v).expect("a midpoint has a slab");
        let n = slab.normal.as_dvec3();
        let w = f64::from(slab.half_width);
        // On a sphere the averaged normal is close to the radial one, and
        // the slab is at most half the edge between two voxel centres.
        assert!(n.dot((input[v] - sphere.center).normalize()).abs() > 0.95);
        assert!(w > 0.0 && w <= 0.5 + 1e-6);
        let tangent = n.any_orthonormal_vector();
        let mut p = input.to_vec();
        // Along the surface, inside the ball: allowed as it is.
        p[v] += 0.2 * tangent;
        let fidelity = Fidelity::new(Some(&bound), input);
        fidelity.apply(&mut p);
        assert_eq!(fidelity.held_back(), 0);
        assert!((p[v] - input[v] - 0.2 * tangent).length() < 1e-12);
        // Across it, twice the slab: back within the slab (and the ball).
        p[v] = input[v] + 2.0 * w * n;
        fidelity.apply(&mut p);
        assert_eq!(fidelity.held_back(), 1);
        let across = (p[v] - input[v]).dot(n);
        assert!(across > 0.0 && across <= w * (1.0 + 1e-6));
        assert!(bound.allows(v, input[v], p[v]));
        assert!(!bound.allows(v, input[v], input[v] + 1.5 * w * n));
    }

    #[test]
    fn a_marching_cubes_crossing_stops_short_of_its_edges_voxel_centres() {
        let (_, mc) = shapes::mc_sphere(8.0);
        let topo = Topology::build(&mc);
        let bound = FidelityBound::new(&mc, &topo, 0.5);
        let input = mc.positions();
        let grid = marching_cubes_grid(&topo, input).expect("a marching-cubes mesh");
        let mut checked = 0;
        for (v, edge) in grid.edges.iter().enumerate() {
            let (Some(edge), Some(slab)) = (edge, bound.slab(v)) else {
                continue;
            };
            // The surface moved across by the whole slab crosses the
            // vertex's edge this far from its midpoint, in spacings.
            let cos = slab.normal.as_dvec3().dot(grid.direction(*edge)).abs();
            if cos < 0.1 {
                continue;
            }
            let reach = f64::from(slab.half_width) / cos / edge.spacing;
            let short = CROSSING_SHARE * 0.5;
            assert!((reach - short).abs() < 1e-6, "vertex {v}: {reach}");
            assert!(reach < 0.5 - 0.04, "vertex {v} reaches a voxel centre");
            checked += 1;
        }
        assert!(checked > 1000);
    }

    #[test]
    fn no_marching_cubes_vertex_may_leave_its_voxel_even_with_the_fixes_room() {
        // Voxels three times as deep as wide: the edges at a vertex on an x
        // or y edge are longer than that edge's spacing, and twice the
        // ball of half their mean would reach past one voxel along it.
        let (_, mc) = shapes::mc_sphere(6.0);
        let mesh = stretched(&mc, DVec3::new(1.0, 1.0, 3.0));
        let topo = Topology::build(&mesh);
        let bound = FidelityBound::new(&mesh, &topo, 0.5);
        let room = bound.widened(2.0);
        let input = mesh.positions();
        let grid = marching_cubes_grid(&topo, input).expect("a marching-cubes mesh");
        let mut long = 0;
        for (v, edge) in grid.edges.iter().enumerate() {
            let edge = edge.expect("every vertex is a midpoint");
            let along = grid.direction(edge);
            let mean = mean_edge_at(&topo, input, v);
            long += usize::from(mean > edge.spacing);
            let past = input[v] + 1.01 * edge.spacing * along;
            assert!(!room.allows(v, input[v], past), "vertex {v}");
            // Within the room: twice the ball of its share of half the
            // mean edge, or of one voxel where that is less.
            let within = 0.99 * MARCHING_CUBES_BALL_SHARE * mean.min(edge.spacing);
            assert!(room.allows(v, input[v], input[v] + within * along));
        }
        assert!(long > 0, "the fixture has edges longer than a voxel");
    }

    #[test]
    fn the_fixes_room_keeps_a_thick_slice_marching_cubes_vertex_within_a_voxel_along_each_axis() {
        // Voxels 2.5 times as deep as wide, on a grid turned off the world's
        // axes: a vertex on an edge across the slices has edges longer than
        // a thin voxel, and twice the ball of half their mean would reach
        // past one thin voxel across its edge.
        let spacing = DVec3::new(1.0, 1.0, 2.5);
        let rot = glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.4, -0.3, 0.9);
        let (_, mc) = shapes::mc_sphere(6.0);
        let mut mesh = stretched(&mc, spacing);
        for p in mesh.positions_mut() {
            *p = rot * *p;
        }
        let topo = Topology::build(&mesh);
        let bound = FidelityBound::new(&mesh, &topo, 0.5);
        let room = bound.widened(2.0);
        let input = mesh.positions();
        let grid = marching_cubes_grid(&topo, input).expect("a marching-cubes mesh");
        let mut capped = 0;
        for (v, edge) in grid.edges.iter().enumerate() {
            let edge = edge.expect("every vertex is a midpoint");
            let reach = MARCHING_CUBES_BALL_SHARE * mean_edge_at(&topo, input, v).min(edge.spacing);
            for (axis, &dir) in grid.frame.iter().enumerate() {
                let voxel = grid.spacing[axis];
                assert!(!room.allows(v, input[v], input[v] + 1.01 * voxel * dir));
                capped += usize::from(reach > 1.01 * voxel);
            }
            // Along its own edge the room is the ball's, as before.
            let along = grid.direction(edge);
            assert!(room.allows(v, input[v], input[v] + 0.99 * reach * along));
        }
        assert!(capped > 0, "the fixture has balls wider than a thin voxel");
        // The smoothing's own bound keeps the ball.
        let v = (0..input.len())
            .find(|&v| {
                grid.edges[v].is_some_and(|e| {
                    MARCHING_CUBES_BALL_SHARE * mean_edge_at(&topo, input, v) > 1.04
                        && e.spacing > 2.0
                })
            })
            .expect("a vertex on a long edge with long edges");
        let slab = bound.slab(v).expect("a midpoint has a slab");
        let across = slab.normal.as_dvec3();
        let thin = grid.frame[0] - grid.frame[0].dot(across) * across;
        let step = 0.51 * thin.normalize();
        assert!(bound.allows(v, input[v], input[v] + step));
    }

    #[test]
    fn a_thick_slice_lattice_gets_the_dual_voxel_of_each_axis() {
        // Voxels 2.5 times as deep as wide: the dual voxel is half a voxel
        // along each axis, 1.25 across the slices.
        let (_, voxel) = shapes::voxel_sphere(6.0);
        let mesh = stretched(&voxel, DVec3::new(1.0, 1.0, 2.5));
        let topo = Topology::build(&mesh);
        let bound = FidelityBound::new(&mesh, &topo, 0.5);
        assert!(bound.has_lattice());
        let (frame, found, _) = bound.in_frame();
        let along = |axis: DVec3| frame.iter().position(|a| a.dot(axis).abs() > 0.99).unwrap();
        assert!((found[along(DVec3::Z)] - 2.5).abs() < 1e-9, "{found}");
        assert!((found[along(DVec3::X)] - 1.0).abs() < 1e-9, "{found}");
        let input = mesh.positions();
        // Every lattice vertex, terraces included (whose own edges are all
        // one voxel long): 1.2 across the slices is inside, 0.55 along them
        // is not.
        for (v, &o) in input.iter().enumerate() {
            assert!(bound.allows(v, o, o + 1.2 * DVec3::Z));
            assert!(!bound.allows(v, o, o + 0.55 * DVec3::X));
        }
        // The fixes' room is the ellipsoid of one voxel along each axis.
        let room = bound.widened(2.0);
        let (v, o) = (0, input[0]);
        assert!(room.allows(v, o, o + 2.4 * DVec3::Z));
        assert!(room.allows(v, o, o + 0.99 * DVec3::Y));
        assert!(!room.allows(v, o, o + 1.01 * DVec3::X));
        assert!(!room.allows(v, o, o + DVec3::new(0.75, 0.0, 0.75 * 2.5)));
        let mut p = input.to_vec();
        p[v] = o + DVec3::new(2.0, 0.0, 0.0);
        Fidelity::new(Some(&room), input).apply(&mut p);
        assert!((p[v] - o - DVec3::X).length() < 1e-9, "{}", p[v] - o);
        p[v] = o + DVec3::new(0.0, 0.0, 4.0);
        Fidelity::new(Some(&bound), input).apply(&mut p);
        assert!((p[v] - o - 1.25 * DVec3::Z).length() < 1e-9, "{}", p[v] - o);
    }

    #[test]
    fn a_rotated_lattice_is_found_and_clamped_in_its_own_frame() {
        let (_, voxel) = shapes::voxel_sphere(5.0);
        let rot = glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1);
        let mut mesh = voxel.clone();
        for p in mesh.positions_mut() {
            *p = rot * *p;
        }
        let topo = Topology::build(&mesh);
        let bound = FidelityBound::new(&mesh, &topo, 0.5);
        assert!(bound.has_lattice());
        // A move of 0.4 voxel along two lattice axes is inside the dual
        // voxel (0.57 from the corner); 0.7 along one is not.
        let input = mesh.positions();
        let mut p = input.to_vec();
        p[0] += rot * DVec3::new(0.4, -0.4, 0.0);
        p[1] += rot * DVec3::new(0.0, 0.0, 0.7);
        let fidelity = Fidelity::new(Some(&bound), input);
        fidelity.apply(&mut p);
        assert_eq!(fidelity.held_back(), 1);
        assert!(!fidelity.held[0].load(Ordering::Relaxed));
        assert!((p[0].distance(input[0]) - 0.4 * 2f64.sqrt()).abs() < 1e-9);
        assert!((p[1].distance(input[1]) - 0.5).abs() < 1e-6);
    }
}
