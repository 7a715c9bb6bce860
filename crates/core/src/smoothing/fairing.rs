//! Constrained fairing of a voxel staircase (our addition to section 2.2):
//! the surface of least bending that stays close to the staircase and
//! inside every corner's dual voxel.
//!
//! A voxel mask says, for every corner of its boundary, only that the true
//! surface crosses the corner's dual voxel (the cube between the eight
//! voxel centres around it). Fits made to the staircase's corners are
//! biased where the staircase is regular: a terrace (a flat run of faces at
//! a sphere's pole, a gyrus's crown) puts many corners at one height, and
//! a least-squares surface follows them there, however the grid fell. The
//! fairing instead minimises the thin-plate energy of the umbrella operator
//! `L` (Kobbelt 1998; Desbrun et al. 1999 smooth with the same `L^2`),
//! with a weak pull toward the input corners,
//!
//!   E(x) = sum_v |L x_v|^2 + anchor * sum_v |x_v - x0_v|^2,
//!
//! over the positions inside each vertex's box: a terrace bends with the
//! curvature its rims give it, and the boxes keep what the mask says. Deep
//! inside a wide terrace the pull acts only within the terrace's plane
//! ([`TERRACE_RINGS`]): there the corners' common height says no more than
//! the boxes do, and pulled toward it the terrace's middle stays nearly
//! flat however far the grid put its plane from the true pole. The
//! energy is a sum over the lattice's axes, and on thick slices the pull
//! along the coarse axis is weaker, in step with its longer terraces
//! ([`axis_anchors`]).
//! The energy is convex and the boxes are convex, so the minimiser is
//! unique; it is reached by accelerated projected gradient steps (FISTA,
//! Beck & Teboulle 2009), Jacobi-style, so the result does not depend on
//! the thread count.

use super::fidelity::FidelityBound;
use super::laplacian::umbrella_step;
use crate::mesh::Topology;
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Gradient step of the fairing: the energy's gradient `L^2 x + anchor x`
/// has a Lipschitz constant of at most `4 + anchor` (the uniform umbrella
/// operator's eigenvalues lie in `[-2, 0]`), and a step of at most its
/// inverse keeps the accelerated iteration monotone in the limit.
const STEP: f64 = 0.2;

/// How many rings of corners in a terrace's plane a corner must have
/// around it before the fairing stops pulling it along the terrace's
/// normal (its corners' common height tells where the surface is no
/// better than their boxes do; the rims, where the staircase turns, do).
/// A corner three rings in lies on a terrace at least seven corners
/// across, which a surface bends over only where its radius is about five
/// voxels or more (the voxel sphere's poles, a brain's outer convexity). A
/// gyrus's crown two or three voxels across is a narrower terrace and keeps
/// its pull: on the real masks one and two rings flatten such crowns
/// (`docs/tuning.md`, the fairing's terraces).
pub const TERRACE_RINGS: u32 = 3;

/// What a fairing run does.
#[derive(Debug, Clone, Copy)]
pub struct FairingPlan<'a> {
    /// Which vertices move; the others hold the surface where they are.
    pub movable: &'a [bool],
    /// Accelerated gradient steps.
    pub iterations: u32,
    /// Weight of the pull toward the input positions, relative to the
    /// bending energy: with `anchor = s^-4` the fairing damps the
    /// staircase's wiggles shorter than about `2 pi s` edges and keeps
    /// longer ones. Along the finest axis of the lattice; a coarser axis
    /// (thick slices) gets a weaker pull ([`axis_anchors`]).
    pub anchor: f64,
    /// Corners with at least this many rings of a terrace around them get no
    /// pull along its normal ([`TERRACE_RINGS`]); 0 pulls every corner along
    /// every axis.
    pub terrace_rings: u32,
    /// The box each vertex stays in around its anchor position (the
    /// fidelity bound, possibly narrowed), the vertices that do not move
    /// included; applied to every iterate.
    pub bound: &'a FidelityBound,
}

/// Fairs `positions` (one per vertex, moved in place) toward the minimiser
/// of the energy of the module docs, pulled toward `anchor_positions`,
/// within `plan.bound` around them. Deterministic and parallel per vertex.
///
/// The iterates are single-precision offsets from the anchor positions in
/// the lattice's frame, where the bound's boxes are a clamp per coordinate:
/// the offsets are a fraction of an edge, which single precision resolves
/// far below the bound, and the umbrella operator commutes with the
/// rotation, so the umbrella of a position is the anchor's (computed once)
/// plus the offsets'.
pub fn fair(
    topo: &Topology,
    positions: &mut [DVec3],
    anchor_positions: &[DVec3],
    plan: &FairingPlan,
) {
    if plan.iterations == 0 {
        return;
    }
    let (frame, spacing, size) = plan.bound.in_frame();
    let spacing = spacing.as_vec3();
    let to_frame = |d: DVec3| {
        Vec3::new(
            d.dot(frame[0]) as f32,
            d.dot(frame[1]) as f32,
            d.dot(frame[2]) as f32,
        )
    };
    let mut means = vec![DVec3::ZERO; positions.len()];
    let every = vec![true; positions.len()];
    umbrella_step(topo, &every, 1.0, anchor_positions, &mut means);
    let anchor_umbrella: Vec<Vec3> = means
        .par_iter()
        .zip(anchor_positions)
        .with_min_len(4096)
        .map(|(m, a)| to_frame(*m - *a))
        .collect();
    // `x`: the iterate, every vertex within the bound from the start (the
    // held ones too); `y`: the extrapolated point the next gradient is taken
    // at; `umbrella`: `L y`.
    let mut x: Vec<Vec3> = positions
        .par_iter()
        .zip(anchor_positions)
        .zip(size)
        .map(|((p, a), &s)| within(to_frame(*p - *a), s, spacing))
        .collect();
    let mut y = x.clone();
    let mut umbrella = vec![Vec3::ZERO; positions.len()];
    let anchor = axis_anchors(plan.anchor, spacing);
    let terraces = terrace_axes(
        topo,
        anchor_positions,
        plan.terrace_rings,
        &to_frame,
        spacing,
    );
    let step = STEP as f32;
    let mut t = 1.0f64;
    for _ in 0..plan.iterations {
        umbrella
            .par_iter_mut()
            .enumerate()
            .with_min_len(4096)
            .for_each(|(v, u)| *u = anchor_umbrella[v] + umbrella_at(topo, &y, v));
        let t_next = 0.5 * (1.0 + (1.0 + 4.0 * t * t).sqrt());
        let momentum = ((t - 1.0) / t_next) as f32;
        // The gradient step at `y` within the bound, then the next
        // extrapolation; each vertex reads and writes only its own `x`
        // and `y`, so both are updated in place.
        x.par_iter_mut()
            .zip(&mut y[..])
            .enumerate()
            .with_min_len(4096)
            .for_each(|(v, (x, y))| {
                if !plan.movable[v] {
                    return;
                }
                let bend = umbrella_at(topo, &umbrella, v);
                let pull = anchor * pulled_axes(terraces[v]);
                let next = within(*y - step * (bend + pull * *y), size[v], spacing);
                *y = next + momentum * (next - *x);
                *x = next;
            });
        t = t_next;
    }
    positions
        .par_iter_mut()
        .zip(&x[..])
        .zip(anchor_positions)
        .with_min_len(4096)
        .for_each(|((p, d), a)| {
            let d = d.as_dvec3();
            *p = *a + d.x * frame[0] + d.y * frame[1] + d.z * frame[2];
        });
}

/// The anchor weight along each axis of a lattice of `spacing`: `anchor`
/// along the finest axis, and `anchor * (finest / spacing)^4` along a
/// coarser one. The fairing keeps the wiggles longer than about
/// `2 pi anchor^(-1/4)` edges (see [`FairingPlan::anchor`]), and a
/// staircase along an axis whose voxels are `k` times as long as the
/// finest has terraces `k` times as many edges wide (a surface of slope `m`
/// climbs one voxel of `k` per `k / m` fine edges): its cut-off is
/// lengthened by `k` along that axis. The same weight on every axis of an
/// isotropic lattice.
fn axis_anchors(anchor: f64, spacing: Vec3) -> Vec3 {
    let finest = spacing.min_element();
    Vec3::from_array(spacing.to_array().map(|s| {
        if s > 0.0 {
            anchor as f32 * (finest / s).powi(4)
        } else {
            anchor as f32
        }
    }))
}

/// Per vertex, bit `a` set where it lies `rings` rings deep in a terrace
/// across axis `a` of the lattice's frame: all its edges and those of the
/// `rings - 1` rings around it run across that axis (at the input
/// corners). No vertex is that deep when `rings` is 0.
fn terrace_axes(
    topo: &Topology,
    anchor_positions: &[DVec3],
    rings: u32,
    to_frame: &(impl Fn(DVec3) -> Vec3 + Sync),
    spacing: Vec3,
) -> Vec<u8> {
    let n = anchor_positions.len();
    if rings == 0 {
        return vec![0; n];
    }
    let mut flat: Vec<u8> = (0..n)
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| {
            let nb = topo.neighbors(v);
            if nb.is_empty() {
                return 0;
            }
            let mut bits = 0b111;
            for &j in nb {
                let d = to_frame(anchor_positions[j as usize] - anchor_positions[v]);
                for a in 0..3 {
                    if d[a].abs() >= FLAT_TOLERANCE * spacing[a] {
                        bits &= !(1 << a);
                    }
                }
            }
            bits
        })
        .collect();
    for _ in 1..rings {
        flat = (0..n)
            .into_par_iter()
            .with_min_len(4096)
            .map(|v| {
                topo.neighbors(v)
                    .iter()
                    .fold(flat[v], |bits, &j| bits & flat[j as usize])
            })
            .collect();
    }
    flat
}

/// 1 along each axis a vertex of [`terrace_axes`] bits `terraces` is pulled
/// along, 0 along a deep terrace's normal.
#[inline]
fn pulled_axes(terraces: u8) -> Vec3 {
    Vec3::from_array([0, 1, 2].map(|a| f32::from(u8::from(terraces & (1 << a) == 0))))
}

/// How far off a terrace's plane, in spacings along its normal, an input
/// corner may lie and still count as in it: the input corners of a voxel
/// mesh lie on the lattice up to the file's rounding.
const FLAT_TOLERANCE: f32 = 1e-3;

/// Offset `d` (in the lattice's frame) brought within a bound of `size`:
/// a box of that many `spacing`s along each axis when positive, a ball of
/// its negation's radius when negative.
#[inline]
fn within(d: Vec3, size: f32, spacing: Vec3) -> Vec3 {
    if size > 0.0 {
        let half = size * spacing;
        d.clamp(-half, half)
    } else {
        d.clamp_length_max(-size)
    }
}

/// The umbrella vector of `x` at `v`: the mean of its neighbours less
/// itself (zero for a vertex without neighbours).
#[inline]
fn umbrella_at(topo: &Topology, x: &[Vec3], v: usize) -> Vec3 {
    if let Some((block, n)) = topo.neighbor_block(v) {
        // A whole block, the entries past the list weighted 0: a loop of
        // fixed length, where the list's own length mispredicts its exit.
        if n == 0 {
            return Vec3::ZERO;
        }
        let sum = block.iter().enumerate().fold(Vec3::ZERO, |s, (k, &j)| {
            s + f32::from(u8::from(k < n)) * x[j as usize]
        });
        return sum / n as f32 - x[v];
    }
    let nb = topo.neighbors(v);
    if nb.is_empty() {
        return Vec3::ZERO;
    }
    let sum = nb.iter().fold(Vec3::ZERO, |s, &j| s + x[j as usize]);
    sum / nb.len() as f32 - x[v]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    #[test]
    fn thick_slices_fair_their_long_terraces() {
        // The voxel sphere's mesh stretched six times along z is the mask
        // of an ellipsoid sampled on voxels six times as deep as wide (a
        // clinical axial series): its terraces are six times as many edges
        // wide as those of the same slope on cubic voxels. One anchor for
        // every axis keeps them; the coarse axis's weaker pull fairs them.
        let spacing = DVec3::new(1.0, 1.0, 6.0);
        let (sphere, voxel) = shapes::voxel_sphere(12.0);
        let mut mesh = voxel.clone();
        for p in mesh.positions_mut() {
            *p *= spacing;
        }
        let truth = shapes::Ellipsoid {
            center: sphere.center * spacing,
            semi_axes: sphere.radius * spacing,
        };
        let (before, after) = (
            shapes::rms_distance(&truth, mesh.positions()),
            shapes::rms_distance(&truth, &faired(&mesh)),
        );
        assert!(after < 0.17 * before, "{before} -> {after}");
    }

    #[test]
    fn a_wide_terrace_bends_toward_the_pole_the_grid_put_above_it() {
        // Placement 12 of the voxel sphere r=12 has its poles along z about
        // half a voxel beyond its terraces, each some nine corners across.
        // Pulled along z toward their height, the terraces' middles stay
        // nearly flat; pulled only within their plane, they bend out with
        // their rims.
        let sphere = shapes::placed(
            shapes::Sphere {
                center: DVec3::ZERO,
                radius: 12.0,
            },
            12,
        );
        let mesh = shapes::voxel_boundary_mesh(&shapes::voxel_mask(&sphere));
        let center = sphere.offset;
        let polar: Vec<usize> = (0..mesh.num_vertices())
            .filter(|&v| (mesh.positions()[v] - center).normalize().z.abs() > 0.97)
            .collect();
        let rms = |rings| {
            let p = faired_with(&mesh, rings);
            let at: Vec<DVec3> = polar.iter().map(|&v| p[v]).collect();
            shapes::rms_distance(&sphere, &at)
        };
        let (pulled, free) = (rms(0), rms(TERRACE_RINGS));
        assert!(polar.len() > 40, "{} polar corners", polar.len());
        assert!(free < 0.85 * pulled, "{pulled} -> {free}");
    }

    /// `mesh`'s vertices after 40 fairing steps of anchor 0.03 within its
    /// fidelity bound, every vertex movable.
    fn faired(mesh: &crate::mesh::Mesh) -> Vec<DVec3> {
        faired_with(mesh, TERRACE_RINGS)
    }

    /// [`faired`] with terraces `terrace_rings` deep left free along their
    /// normals.
    fn faired_with(mesh: &crate::mesh::Mesh, terrace_rings: u32) -> Vec<DVec3> {
        let topo = Topology::build(mesh);
        let input = mesh.positions();
        let bound = FidelityBound::new(mesh, &topo, 0.5);
        let movable = vec![true; mesh.num_vertices()];
        let plan = FairingPlan {
            movable: &movable,
            iterations: 40,
            anchor: 0.03,
            terrace_rings,
            bound: &bound,
        };
        let mut p = input.to_vec();
        fair(&topo, &mut p, input, &plan);
        p
    }

    #[test]
    fn fairing_a_voxel_sphere_brings_it_close_within_the_dual_voxels() {
        let (sphere, mesh) = shapes::voxel_sphere(8.0);
        let input = mesh.positions();
        let p = faired(&mesh);
        let (before, after) = (
            shapes::rms_distance(&sphere, input),
            shapes::rms_distance(&sphere, &p),
        );
        assert!(after < 0.3 * before, "{before} -> {after}");
        assert!(
            p.iter()
                .zip(input)
                .all(|(a, b)| (*a - *b).abs().max_element() <= 0.5 + 1e-6)
        );

        // Held vertices stay; no iterations, no change.
        let topo = Topology::build(&mesh);
        let bound = FidelityBound::new(&mesh, &topo, 0.5);
        let held = vec![false; mesh.num_vertices()];
        let movable = vec![true; mesh.num_vertices()];
        let plan = FairingPlan {
            movable: &held,
            iterations: 40,
            anchor: 0.03,
            terrace_rings: TERRACE_RINGS,
            bound: &bound,
        };
        let mut q = input.to_vec();
        fair(&topo, &mut q, input, &plan);
        assert_eq!(q, input);
        fair(
            &topo,
            &mut q,
            input,
            &FairingPlan {
                movable: &movable,
                iterations: 0,
                ..plan
            },
        );
        assert_eq!(q, input);
    }
}
