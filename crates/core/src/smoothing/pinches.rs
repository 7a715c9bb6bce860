//! Pinches of a voxel mask: where voxels touch only along an edge or at a
//! corner, the voxel-boundary mesh joins two sheets at one vertex (our
//! addition to section 2.2; the paper's meshes are manifold).
//!
//! Such a vertex has no surface of its own to fit: its rings run into both
//! sheets, so the fits and the fairing leave it where the staircase
//! relaxation puts it, and the relaxation only averages its fans'
//! neighbours, which lie around it on every side. What says where the
//! surface passes there is the mask itself: the eight voxels around the
//! corner, inside or outside, read off the faces at the vertex. Their
//! trilinear interpolation (1 inside, 0 outside) between the voxel centres
//! is the smoothest surface those eight voxels give, and its one-half level
//! is where a corner with two, three, five or six of eight voxels inside
//! retreats into the mask or advances out of it: the end of a line where
//! two voxels touch along an edge lies inside the end of that line, not at
//! the lattice corner. [`place_pinches`] moves each non-manifold lattice
//! vertex to that level, within its dual voxel (the fidelity bound's box).

use super::fidelity::FidelityBound;
use crate::mesh::{Mesh, Topology, VertexKind, vector_area};
use glam::DVec3;
use rayon::prelude::*;

/// A lattice corner has at most 12 faces around it (24 when each voxel
/// face is split into two triangles); a vertex with more is not one, and
/// skipping it keeps the work per vertex bounded whatever the valence.
const MAX_CORNER_FACES: usize = 24;

/// How far off its lattice axis a face's normal may turn, as the largest
/// other component of the unit normal, and still count as a voxel face:
/// the rounding of a file's coordinates tilts a face by far less, a face
/// that is not a voxel face by far more.
const AXIS_TOLERANCE: f64 = 1e-3;

/// Newton steps toward the one-half level; each moves at most a quarter of
/// a spacing per axis, so the level is found well within the dual voxel.
const LEVEL_STEPS: usize = 12;

/// The share of an edge between two pinches that the pinches keep when
/// both retreat along it (the two ends of a line of touching voxels one
/// voxel long): each end takes at most half of the rest. On cubic voxels
/// the walls along the line are then trapezoids whose triangles keep
/// angles of 20 degrees (`atan(0.72) - atan(0.28)`), the sharp-angle fix's
/// threshold; the one-half level alone would shrink such a line to a point
/// and the walls to needles.
pub const LINE_KEEP: f64 = 0.44;

/// Moves every non-manifold vertex of a voxel-lattice mesh among `movable`
/// to the one-half level of its eight voxels' trilinear interpolation (see
/// the module docs), within its box of `bound` (its dual voxel at the
/// default `max_displacement`); where the pinch at the edge's other end
/// comes toward it too, the two keep [`LINE_KEEP`] of the edge. A vertex whose faces do not give all eight
/// voxels consistently (not a lattice corner, an open rim) stays. Returns
/// which vertices moved (empty off a lattice). Deterministic and parallel
/// per vertex.
pub fn place_pinches(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    movable: &[bool],
    bound: &FidelityBound,
) -> Vec<bool> {
    if !bound.has_lattice() {
        return Vec::new();
    }
    let (frame, spacing, room) = bound.in_frame();
    let input = mesh.positions();
    let local = |d: DVec3| DVec3::new(frame[0].dot(d), frame[1].dot(d), frame[2].dot(d)) / spacing;
    // Each pinch's level, in spacings along the lattice's axes.
    let levels: Vec<DVec3> = (0..topo.num_vertices())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| {
            let box_size = room.get(v).map_or(0.0, |&r| f64::from(r));
            if !movable[v] || topo.kind(v) != VertexKind::NonManifold || box_size <= 0.0 {
                return DVec3::ZERO;
            }
            // The eight voxels' interpolation holds between their centres.
            let room = box_size.min(0.5);
            corner_voxels(mesh, topo, v, &frame)
                .map_or(DVec3::ZERO, |inside| half_level(&inside, room))
        })
        .collect();
    positions
        .par_iter_mut()
        .zip(&levels)
        .enumerate()
        .with_min_len(4096)
        .map(|(v, (p, &level))| {
            if level == DVec3::ZERO {
                return false;
            }
            let mut q = level;
            for &j in topo.neighbors(v) {
                let e = local(input[j as usize] - input[v]);
                let a = e.abs().max_position();
                let (toward, length) = (e[a].signum(), e[a].abs());
                let both_come = levels[j as usize][a] * toward < 0.0;
                let most = 0.5 * (1.0 - LINE_KEEP) * length;
                if both_come && q[a] * toward > most {
                    q[a] = most * toward;
                }
            }
            let d = q * spacing;
            *p = input[v] + frame[0] * d.x + frame[1] * d.y + frame[2] * d.z;
            true
        })
        .collect()
}

/// Index of the voxel on sides `s` (per axis, `true` for the positive
/// side) of a corner.
fn voxel_index(s: [bool; 3]) -> usize {
    usize::from(s[0]) | usize::from(s[1]) << 1 | usize::from(s[2]) << 2
}

/// Which of the eight voxels around lattice vertex `v` are inside, read
/// off its faces: each voxel face at `v` separates an inside voxel (behind
/// it) from an outside one (in front), and two voxels that share a square
/// at `v` without a face between them are alike. `None` when the faces
/// are not voxel faces at a corner, contradict each other, or leave a
/// voxel undecided. Which side counts as inside does not matter to the
/// one-half level.
fn corner_voxels(mesh: &Mesh, topo: &Topology, v: usize, frame: &[DVec3; 3]) -> Option<[bool; 8]> {
    let faces = topo.vertex_faces(v);
    if faces.len() > MAX_CORNER_FACES {
        return None;
    }
    let positions = mesh.positions();
    let local = |d: DVec3| DVec3::new(frame[0].dot(d), frame[1].dot(d), frame[2].dot(d));
    let mut state: [Option<bool>; 8] = [None; 8];
    // Whether a face lies on the square between two voxels (by the lower
    // index of the pair and the axis they differ along).
    let mut walled = [[false; 3]; 8];
    for &f in faces {
        let face = mesh.face(f as usize);
        let n = local(vector_area(face, positions));
        let len = n.length();
        if len == 0.0 {
            return None;
        }
        let a = n.abs().max_position();
        if (0..3).any(|k| k != a && n[k].abs() > AXIS_TOLERANCE * len) {
            return None;
        }
        // The quadrant of the face's square around `v`: the side of each
        // in-plane axis its other corners lie on (a square's, or a
        // triangle's of a split square, reach along both).
        let (extent, reach) = face.iter().fold((DVec3::ZERO, DVec3::ZERO), |(s, m), &j| {
            let d = local(positions[j as usize] - positions[v]);
            (s + d, m.max(d.abs()))
        });
        let mut side = [false; 3];
        for k in (0..3).filter(|&k| k != a) {
            if reach[k] == 0.0 || extent[k].abs() < 0.5 * reach[k] {
                return None;
            }
            side[k] = extent[k] > 0.0;
        }
        let mut front = side;
        front[a] = n[a] > 0.0;
        let mut back = side;
        back[a] = n[a] <= 0.0;
        for (s, inside) in [(front, false), (back, true)] {
            let i = voxel_index(s);
            if state[i].is_some_and(|x| x != inside) {
                return None;
            }
            state[i] = Some(inside);
        }
        let low = voxel_index(side);
        walled[low][a] = true;
    }
    // Spread the decided voxels to their unwalled neighbours.
    for _ in 0..8 {
        let mut changed = false;
        for (i, walls) in walled.iter().enumerate() {
            for (a, &wall) in walls.iter().enumerate() {
                if i & (1 << a) != 0 || wall {
                    continue;
                }
                let j = i | (1 << a);
                match (state[i], state[j]) {
                    (Some(x), None) => state[j] = Some(x),
                    (None, Some(x)) => state[i] = Some(x),
                    (Some(x), Some(y)) if x != y => return None,
                    _ => continue,
                }
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let mut inside = [false; 8];
    for (out, s) in inside.iter_mut().zip(state) {
        *out = s?;
    }
    Some(inside)
}

/// The trilinear interpolation of the eight voxels' `inside` (1 or 0) at
/// `q` (in spacings from the corner, the voxel centres at `±1/2`), and its
/// gradient.
fn trilinear(inside: &[bool; 8], q: DVec3) -> (f64, DVec3) {
    let mut value = 0.0;
    let mut grad = DVec3::ZERO;
    for (i, _) in inside.iter().enumerate().filter(|(_, x)| **x) {
        let s = DVec3::new(
            if i & 1 != 0 { 1.0 } else { -1.0 },
            if i & 2 != 0 { 1.0 } else { -1.0 },
            if i & 4 != 0 { 1.0 } else { -1.0 },
        );
        let w = DVec3::splat(0.5) + q * s;
        value += w.x * w.y * w.z;
        grad += s * DVec3::new(w.y * w.z, w.x * w.z, w.x * w.y);
    }
    (value, grad)
}

/// The point nearest the corner, found by Newton steps along the gradient,
/// where the trilinear interpolation of `inside` is one half, within
/// `room` spacings of the corner per axis (zero when the corner is on the
/// level or the gradient vanishes there).
fn half_level(inside: &[bool; 8], room: f64) -> DVec3 {
    let mut q = DVec3::ZERO;
    for _ in 0..LEVEL_STEPS {
        let (f, g) = trilinear(inside, q);
        let g2 = g.length_squared();
        if g2 < 1e-12 || (f - 0.5).abs() < 1e-9 {
            break;
        }
        let step = g * (-(f - 0.5) / g2);
        let step = step * (0.25 / step.abs().max_element()).min(1.0);
        q = (q + step).clamp(DVec3::splat(-room), DVec3::splat(room));
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::{
        VoxelMask, placed, rms_distance, sphere_pair, voxel_boundary_mesh, voxel_mask,
    };
    use glam::IVec3;

    fn bound_of(mesh: &Mesh, topo: &Topology) -> FidelityBound {
        FidelityBound::new(mesh, topo, 0.5)
    }

    /// The mask's eight voxels around the lattice corner at `c`.
    fn mask_corner(mask: &VoxelMask, c: DVec3) -> [bool; 8] {
        let c = c.round().as_ivec3() - mask.origin();
        std::array::from_fn(|i| {
            let s = IVec3::new(i as i32 & 1, (i as i32 >> 1) & 1, (i as i32 >> 2) & 1);
            let v = c + s - IVec3::ONE;
            mask.get(i64::from(v.x), i64::from(v.y), i64::from(v.z))
        })
    }

    #[test]
    fn the_faces_at_a_pinch_give_its_eight_voxels() {
        let shape = placed(sphere_pair(5.0, 0.0), 3);
        let mask = voxel_mask(&shape);
        let mesh = voxel_boundary_mesh(&mask);
        let topo = Topology::build(&mesh);
        let frame = [DVec3::X, DVec3::Y, DVec3::Z];
        let pinches: Vec<usize> = (0..mesh.num_vertices())
            .filter(|&v| topo.kind(v) == VertexKind::NonManifold)
            .collect();
        assert!(pinches.len() >= 4, "{} pinches", pinches.len());
        for v in (0..mesh.num_vertices()).filter(|&v| !topo.vertex_faces(v).is_empty()) {
            let read = corner_voxels(&mesh, &topo, v, &frame);
            assert_eq!(
                read,
                Some(mask_corner(&mask, mesh.positions()[v])),
                "vertex {v}"
            );
        }
    }

    #[test]
    fn the_ends_of_a_one_voxel_line_retreat_into_it_and_keep_part_of_it() {
        // Two voxels touching along one edge, along z, one voxel long.
        let mask = VoxelMask::from_fn(IVec3::ZERO, [4, 4, 3], |i, j, k| {
            k == 1 && matches!((i, j), (1, 1) | (2, 2))
        });
        let mesh = voxel_boundary_mesh(&mask);
        let topo = Topology::build(&mesh);
        let mut p = mesh.positions().to_vec();
        let movable = vec![true; p.len()];
        let placed = place_pinches(&mesh, &topo, &mut p, &movable, &bound_of(&mesh, &topo));
        let ends: Vec<usize> = (0..p.len())
            .filter(|&v| topo.kind(v) == VertexKind::NonManifold)
            .collect();
        assert_eq!(ends.len(), 2);
        for &v in &ends {
            assert!(placed[v]);
            let d = p[v] - mesh.positions()[v];
            let inward = if mesh.positions()[v].z < 1.5 {
                1.0
            } else {
                -1.0
            };
            assert!(
                d.x.abs() < 1e-12 && d.y.abs() < 1e-12,
                "moved off the line: {d}"
            );
            assert!(
                (d.z * inward - 0.5 * (1.0 - LINE_KEEP)).abs() < 1e-9,
                "moved {d}"
            );
        }
        assert_eq!(placed.iter().filter(|&&x| x).count(), 2);
        let kept = p[ends[0]].distance(p[ends[1]]);
        assert!((kept - LINE_KEEP).abs() < 1e-9, "the line keeps {kept}");
    }

    #[test]
    fn a_saddle_of_four_voxels_stays() {
        let inside = [true, false, false, true, false, true, true, false];
        assert_eq!(half_level(&inside, 0.5), DVec3::ZERO);
        // Two voxels touching along an edge end at the corner: the level
        // lies along the edge, at the voxel centres' plane.
        let mut end = [false; 8];
        end[voxel_index([true, true, true])] = true;
        end[voxel_index([false, false, true])] = true;
        let q = half_level(&end, 0.5);
        assert!(q.abs_diff_eq(DVec3::new(0.0, 0.0, 0.5), 1e-9), "{q}");
        assert!((trilinear(&end, q).0 - 0.5).abs() < 1e-9);
    }

    #[test]
    fn placed_pinches_lie_closer_to_the_true_surface() {
        for seed in 0..4 {
            let shape = placed(sphere_pair(6.0, 0.0), seed);
            let mesh = voxel_boundary_mesh(&voxel_mask(&shape));
            let topo = Topology::build(&mesh);
            let mut p = mesh.positions().to_vec();
            let movable = vec![true; p.len()];
            let placed = place_pinches(&mesh, &topo, &mut p, &movable, &bound_of(&mesh, &topo));
            let moved: Vec<usize> = (0..p.len()).filter(|&v| placed[v]).collect();
            assert!(!moved.is_empty(), "seed {seed}: no pinch placed");
            let at = |q: &[DVec3]| moved.iter().map(|&v| q[v]).collect::<Vec<_>>();
            let before = rms_distance(&shape, &at(mesh.positions()));
            let after = rms_distance(&shape, &at(&p));
            assert!(after < 0.8 * before, "seed {seed}: {before} -> {after}");
        }
    }
}
