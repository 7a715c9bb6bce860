//! Pinches of a voxel mask: where voxels touch only along an edge or at a
//! corner, the voxel-boundary mesh joins two sheets at one vertex (our
//! addition to section 2.2; the paper's meshes are manifold).
//!
//! Such a vertex has no surface of its own to fit: its rings run into both
//! sheets, so the fits and the fairing leave it where the staircase
//! relaxation puts it, and the relaxation only averages its fans'
//! neighbours, which lie around it on every side. What says where the
//! surface passes there is the mask itself, which the mesh's voxel faces
//! give: each face separates an inside voxel from an outside one, and two
//! voxels with no face between them are alike. [`place_pinches`] reads the
//! 4 x 4 x 4 voxels around each pinch (its eight voxels and the next layer),
//! blurs them by a Gaussian of [`BLUR_SIGMA`] voxel, interpolates the eight
//! blurred values trilinearly between their voxel centres, and moves the
//! pinch to where that is one half: the end of a line where two voxels
//! touch along an edge lies inside the end of that line, a corner with
//! three of its eight voxels inside lies inside the corner, and the next
//! layer of voxels tells a bridge between two voxels touching along an
//! edge from a gap, which their eight voxels alone cannot (a saddle). The
//! pipeline does this before the staircase relaxation, within the lattice
//! fairing's room of the pinch's dual voxel, and holds the placed pinches
//! there; only the sharp-angle fix moves them later, when the interior
//! vertices cannot open the angles at them, and across their level first
//! ([`crate::quality::sharp_angle`]).

use super::fidelity::{FidelityBound, in_frame_of};
use crate::mesh::{Mesh, Topology, VertexKind, vector_area};
use glam::DVec3;
use rayon::prelude::*;

/// How far off its lattice axis a face's normal may turn, as the largest
/// other component of the unit normal, and still count as a voxel face:
/// the rounding of a file's coordinates tilts a face by far less, a face
/// that is not a voxel face by far more.
const AXIS_TOLERANCE: f64 = 1e-3;

/// The Gaussian that blurs the mask around a pinch, in spacings of the
/// lattice's finest axis (the same physical width along every axis: across
/// thick slices the next voxel lies farther away and weighs less). It
/// gives each voxel's next neighbour along a finest axis 4% of its own
/// weight, enough for the next layer to tip a saddle of four voxels and to
/// turn the level toward where the structure goes on, little enough that
/// the eight voxels around the corner decide where they agree. The GM and
/// WM masks' pinches come closest to the truth at 0.4-0.5, farther at 0.3
/// and below; a width per axis in that axis's own spacing took masks of
/// voxels four times as deep as wide farther from the truth
/// (`docs/tuning.md`).
pub const BLUR_SIGMA: f64 = 0.4;

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
/// to the one-half level of its blurred mask (see the module docs), within
/// its box of `bound` (its dual voxel at the default `max_displacement`);
/// where the pinch at an edge's other end comes toward it too, the two
/// keep [`LINE_KEEP`] of the edge. A vertex whose voxels the faces do not
/// give consistently (not a lattice corner, an open rim) stays. Returns
/// which vertices moved (empty when the mesh has no lattice or no pinch).
/// Deterministic and parallel per vertex; the faces are sorted once, and
/// each pinch looks up the 144 squares between its 64 voxels. With
/// `bodies` (one entry per vertex: bodies that touch face to face,
/// [`crate::io::FileBodies`]), a pinch reads its own body's faces only.
pub fn place_pinches(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    movable: &[bool],
    bound: &FidelityBound,
    bodies: Option<&[u32]>,
) -> Vec<bool> {
    let body_of = |v: usize| bodies.and_then(|b| b.get(v)).copied().unwrap_or(0);
    let any =
        (0..topo.num_vertices()).any(|v| movable[v] && topo.kind(v) == VertexKind::NonManifold);
    if !bound.has_lattice() || !any {
        return Vec::new();
    }
    let (frame, spacing, room) = bound.in_frame();
    let input = mesh.positions();
    // Grid coordinates count from a lattice node: a vertex with a box.
    let Some(node) = room.iter().position(|&r| r > 0.0) else {
        return Vec::new();
    };
    let faces = VoxelFaces::build(mesh, frame, spacing, input[node], &body_of);
    let weights = blur_weights(spacing);
    // Each pinch's level, in spacings along the lattice's axes.
    let levels: Vec<DVec3> = (0..topo.num_vertices())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| {
            let box_size = room.get(v).map_or(0.0, |&r| f64::from(r));
            if !movable[v] || topo.kind(v) != VertexKind::NonManifold || box_size <= 0.0 {
                return DVec3::ZERO;
            }
            // The blurred mask is interpolated between the eight voxel
            // centres, which bound the dual voxel.
            let room = box_size.min(0.5);
            faces
                .voxels_around(faces.grid(input[v]).round(), body_of(v))
                .map_or(DVec3::ZERO, |block| {
                    half_level(&blurred_corner(&block, &weights), room)
                })
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
            let here = faces.grid(input[v]);
            for &j in topo.neighbors(v) {
                let e = faces.grid(input[j as usize]) - here;
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

/// The voxel faces of a lattice mesh, by the lattice square each covers.
struct VoxelFaces {
    /// The lattice's axes, its spacing along them, and the input position
    /// of the lattice node the grid coordinates count from.
    frame: [DVec3; 3],
    spacing: DVec3,
    origin: DVec3,
    /// Per face on the lattice: its square's key ([`square_key`]), its
    /// body (that of its first corner) and whether its normal points along
    /// the square's axis; sorted.
    squares: Vec<(u64, u32, bool)>,
}

/// Bits per coordinate of a square's key: grid coordinates within half a
/// million spacings of the origin node, far more than any image has.
const KEY_BITS: u32 = 20;

/// The key of the lattice square whose lowest corner is at grid
/// coordinates `c` and whose normal runs along `axis`; `None` out of
/// range.
fn square_key(c: [i64; 3], axis: usize) -> Option<u64> {
    let half = 1i64 << (KEY_BITS - 1);
    c.iter().try_fold(axis as u64, |key, &x| {
        let u = u64::try_from(x + half)
            .ok()
            .filter(|&u| u < 1 << KEY_BITS)?;
        Some(key << KEY_BITS | u)
    })
}

/// Index of a voxel in a 4 x 4 x 4 block.
fn block_index(x: usize, y: usize, z: usize) -> usize {
    x + 4 * y + 16 * z
}

impl VoxelFaces {
    /// The squares of `mesh`'s faces that lie on the lattice of `frame`
    /// and `spacing` through the node at `origin`, with their bodies
    /// (`body_of` a vertex); a face off the lattice (not axis-aligned) is
    /// left out.
    fn build(
        mesh: &Mesh,
        frame: [DVec3; 3],
        spacing: DVec3,
        origin: DVec3,
        body_of: &(impl Fn(usize) -> u32 + Sync),
    ) -> Self {
        let p = mesh.positions();
        let mut faces = VoxelFaces {
            frame,
            spacing,
            origin,
            squares: Vec::new(),
        };
        let mut squares: Vec<(u64, u32, bool)> = (0..mesh.num_faces())
            .into_par_iter()
            .with_min_len(4096)
            .filter_map(|f| {
                let face = mesh.face(f);
                let n = in_frame_of(&frame, vector_area(face, p));
                let len = n.length();
                let a = n.abs().max_position();
                if len == 0.0 || (0..3).any(|k| k != a && n[k].abs() > AXIS_TOLERANCE * len) {
                    return None;
                }
                let low = face
                    .iter()
                    .fold(DVec3::INFINITY, |m, &j| m.min(faces.grid(p[j as usize])))
                    .round();
                let key = square_key([low.x as i64, low.y as i64, low.z as i64], a)?;
                let body = face.first().map_or(0, |&v| body_of(v as usize));
                Some((key, body, n[a] > 0.0))
            })
            .collect();
        // A square split into two triangles counts once.
        squares.par_sort_unstable();
        squares.dedup_by_key(|s| (s.0, s.1));
        faces.squares = squares;
        faces
    }

    /// Grid coordinates of `p`: spacings along each axis from the origin
    /// node.
    fn grid(&self, p: DVec3) -> DVec3 {
        in_frame_of(&self.frame, p - self.origin) / self.spacing
    }

    /// Whether a face of `body` covers the square at `c` along `axis`,
    /// and if so whether its normal points along the axis.
    fn face_at(&self, c: [i64; 3], axis: usize, body: u32) -> Option<bool> {
        let key = square_key(c, axis)?;
        let i = self
            .squares
            .binary_search_by_key(&(key, body), |s| (s.0, s.1))
            .ok()?;
        Some(self.squares[i].2)
    }

    /// The 4 x 4 x 4 voxels around the lattice node at grid coordinates
    /// `node` ([`block_index`]; voxel `(1, 1, 1)` is the one below the node
    /// on every axis), inside or not, read off the faces between them: a
    /// face's normal points from its inside voxel to its outside one, and
    /// voxels with no face between them are alike. `None` when the faces
    /// contradict each other or leave a voxel undecided. Which side counts
    /// as inside does not matter to the one-half level. Only the faces of
    /// `body` count.
    fn voxels_around(&self, node: DVec3, body: u32) -> Option<[bool; 64]> {
        let base = [node.x as i64 - 2, node.y as i64 - 2, node.z as i64 - 2];
        let mut state: [Option<bool>; 64] = [None; 64];
        // Per voxel and axis: whether a face separates it from the next
        // voxel along that axis.
        let mut walled = [[false; 3]; 64];
        // Voxels decided and not yet spread; each enters once.
        let (mut stack, mut pending) = ([0usize; 64], 0);
        for z in 0..4 {
            for y in 0..4 {
                for x in 0..4 {
                    let here = [x, y, z];
                    let low = block_index(x, y, z);
                    for axis in 0..3 {
                        let mut next = here;
                        next[axis] += 1;
                        if next[axis] > 3 {
                            continue;
                        }
                        // The square between them: its lowest corner is
                        // the upper voxel's along the axis.
                        let mut square = [0i64; 3];
                        for (k, c) in square.iter_mut().enumerate() {
                            *c = base[k] + if k == axis { next[k] } else { here[k] } as i64;
                        }
                        let Some(along) = self.face_at(square, axis, body) else {
                            continue;
                        };
                        walled[low][axis] = true;
                        let high = block_index(next[0], next[1], next[2]);
                        for (i, inside) in [(low, along), (high, !along)] {
                            if state[i].is_some_and(|s| s != inside) {
                                return None;
                            }
                            if state[i].is_none() {
                                state[i] = Some(inside);
                                stack[pending] = i;
                                pending += 1;
                            }
                        }
                    }
                }
            }
        }
        // Spread the decided voxels to their unwalled neighbours.
        while pending > 0 {
            pending -= 1;
            let i = stack[pending];
            let here = [i % 4, (i / 4) % 4, i / 16];
            for axis in 0..3 {
                for up in [false, true] {
                    let mut next = here;
                    match (up, here[axis]) {
                        (true, 3) | (false, 0) => continue,
                        (true, _) => next[axis] += 1,
                        (false, _) => next[axis] -= 1,
                    }
                    let j = block_index(next[0], next[1], next[2]);
                    if walled[if up { i } else { j }][axis] {
                        continue;
                    }
                    match state[j] {
                        None => {
                            state[j] = state[i];
                            stack[pending] = j;
                            pending += 1;
                        }
                        Some(x) if Some(x) != state[i] => return None,
                        Some(_) => {}
                    }
                }
            }
        }
        let mut inside = [false; 64];
        for (out, s) in inside.iter_mut().zip(state) {
            *out = s?;
        }
        Some(inside)
    }
}

/// The blur's weights per axis for the lattice's `spacing`: a voxel's own
/// and its two next neighbours' along that axis ([`BLUR_SIGMA`], truncated
/// there: the next ones would weigh less than 1e-5), summing to one.
fn blur_weights(spacing: DVec3) -> [[f64; 3]; 3] {
    let finest = spacing.min_element();
    std::array::from_fn(|k| {
        let sigma = BLUR_SIGMA * finest / spacing[k];
        let next = (-0.5 / (sigma * sigma)).exp();
        [next, 1.0, next].map(|x| x / (1.0 + 2.0 * next))
    })
}

/// The eight voxels around a block's centre node ([`VoxelFaces::voxels_around`])
/// blurred by the separable `weights` ([`blur_weights`]); voxel `i` lies
/// on the positive side of the node along axis `k` when bit `k` of `i` is
/// set.
fn blurred_corner(block: &[bool; 64], weights: &[[f64; 3]; 3]) -> [f64; 8] {
    std::array::from_fn(|i| {
        let centre = [1 + (i & 1), 1 + ((i >> 1) & 1), 1 + ((i >> 2) & 1)];
        let mut sum = 0.0;
        for (dz, wz) in weights[2].iter().enumerate() {
            for (dy, wy) in weights[1].iter().enumerate() {
                for (dx, wx) in weights[0].iter().enumerate() {
                    let (x, y, z) = (centre[0] + dx - 1, centre[1] + dy - 1, centre[2] + dz - 1);
                    if block[block_index(x, y, z)] {
                        sum += wx * wy * wz;
                    }
                }
            }
        }
        sum
    })
}

/// The trilinear interpolation of the eight voxels' `values` at `q` (in
/// spacings from the corner, the voxel centres at `±1/2`), and its
/// gradient.
fn trilinear(values: &[f64; 8], q: DVec3) -> (f64, DVec3) {
    let mut value = 0.0;
    let mut grad = DVec3::ZERO;
    for (i, &x) in values.iter().enumerate() {
        let s = DVec3::new(
            if i & 1 != 0 { 1.0 } else { -1.0 },
            if i & 2 != 0 { 1.0 } else { -1.0 },
            if i & 4 != 0 { 1.0 } else { -1.0 },
        );
        let w = DVec3::splat(0.5) + q * s;
        value += x * w.x * w.y * w.z;
        grad += x * s * DVec3::new(w.y * w.z, w.x * w.z, w.x * w.y);
    }
    (value, grad)
}

/// The point nearest the corner, found by Newton steps along the gradient,
/// where the trilinear interpolation of `values` is one half, within
/// `room` spacings of the corner per axis (zero when the corner is on the
/// level or the gradient vanishes there).
fn half_level(values: &[f64; 8], room: f64) -> DVec3 {
    let mut q = DVec3::ZERO;
    for _ in 0..LEVEL_STEPS {
        let (f, g) = trilinear(values, q);
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
    use crate::shapes::{Shape, VoxelMask, placed, sphere_pair, voxel_boundary_mesh, voxel_mask};
    use glam::IVec3;

    fn bound_of(mesh: &Mesh, topo: &Topology) -> FidelityBound {
        FidelityBound::new(mesh, topo, 0.5)
    }

    /// Every vertex of `mesh` movable, one body: the placed pinches'
    /// positions and which moved.
    fn place_all(mesh: &Mesh, topo: &Topology) -> (Vec<DVec3>, Vec<bool>) {
        let mut p = mesh.positions().to_vec();
        let movable = vec![true; p.len()];
        let placed = place_pinches(mesh, topo, &mut p, &movable, &bound_of(mesh, topo), None);
        (p, placed)
    }

    /// The mask's 4 x 4 x 4 voxels around the lattice node at `c`, in the
    /// order of [`VoxelFaces::voxels_around`].
    fn mask_block(mask: &VoxelMask, c: DVec3) -> [bool; 64] {
        let c = c.round().as_ivec3() - mask.origin();
        std::array::from_fn(|i| {
            let v = c + IVec3::new(i as i32 % 4, (i as i32 / 4) % 4, i as i32 / 16) - 2;
            mask.get(i64::from(v.x), i64::from(v.y), i64::from(v.z))
        })
    }

    #[test]
    fn the_voxel_faces_give_the_mask_around_every_corner() {
        let shape = placed(sphere_pair(5.0, 0.0), 3);
        let mask = voxel_mask(&shape);
        let mesh = voxel_boundary_mesh(&mask);
        let topo = Topology::build(&mesh);
        let faces = VoxelFaces::build(
            &mesh,
            [DVec3::X, DVec3::Y, DVec3::Z],
            DVec3::ONE,
            mesh.positions()[0],
            &|_| 0,
        );
        let pinches = (0..mesh.num_vertices())
            .filter(|&v| topo.kind(v) == VertexKind::NonManifold)
            .count();
        assert!(pinches >= 4, "{pinches} pinches");
        for (v, &p) in mesh.positions().iter().enumerate() {
            let read = faces.voxels_around(faces.grid(p).round(), 0);
            assert_eq!(read, Some(mask_block(&mask, p)), "vertex {v}");
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
        let (p, placed) = place_all(&mesh, &topo);
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
    fn a_saddle_of_four_voxels_stays_and_a_line_end_retreats() {
        let saddle = [1.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0];
        assert_eq!(half_level(&saddle, 0.5), DVec3::ZERO);
        // Two voxels touching along an edge (along z) end at the corner,
        // both above it: the level lies along the edge, at the voxel
        // centres' plane.
        let mut end = [0.0; 8];
        end[0b111] = 1.0;
        end[0b100] = 1.0;
        let q = half_level(&end, 0.5);
        assert!(q.abs_diff_eq(DVec3::new(0.0, 0.0, 0.5), 1e-9), "{q}");
        assert!((trilinear(&end, q).0 - 0.5).abs() < 1e-9);
        // Blurred, the next layer matters: the same two voxels alone end
        // short of one half (the level is clamped at the room), and a saddle
        // whose two inside voxels go on below is tipped toward them.
        let mut block = [false; 64];
        block[block_index(2, 2, 2)] = true;
        block[block_index(1, 1, 2)] = true;
        let cubic = blur_weights(DVec3::ONE);
        let values = blurred_corner(&block, &cubic);
        assert!(trilinear(&values, DVec3::new(0.0, 0.0, 0.5)).0 < 0.5);
        let mut saddle_block = [false; 64];
        for (x, y, z) in [
            (2, 2, 2),
            (1, 1, 2),
            (2, 1, 1),
            (1, 2, 1),
            (2, 1, 0),
            (1, 2, 0),
        ] {
            saddle_block[block_index(x, y, z)] = true;
        }
        let q = half_level(&blurred_corner(&saddle_block, &cubic), 0.5);
        assert!(
            q.z.abs() > 0.05 && q.x.abs() < 0.01 && q.y.abs() < 0.01,
            "{q}"
        );
        // Across slices four times as deep, the layer that tipped it lies
        // four times as far away: the saddle stays.
        let deep = blur_weights(DVec3::new(1.0, 1.0, 4.0));
        assert_eq!(deep[0], cubic[0]);
        let q = half_level(&blurred_corner(&saddle_block, &deep), 0.5);
        assert!(q.length() < 1e-3, "{q}");
    }

    #[test]
    fn placed_pinches_lie_closer_to_the_true_surface() {
        // Squared distances of the placed pinches, summed over placements.
        let (mut before, mut after, mut count) = (0.0, 0.0, 0);
        for seed in 0..6 {
            let shape = placed(sphere_pair(6.0, 0.0), seed);
            let mesh = voxel_boundary_mesh(&voxel_mask(&shape));
            let topo = Topology::build(&mesh);
            let (p, placed) = place_all(&mesh, &topo);
            for v in (0..p.len()).filter(|&v| placed[v]) {
                before += shape.distance(mesh.positions()[v]).powi(2);
                after += shape.distance(p[v]).powi(2);
                count += 1;
            }
        }
        assert!(count >= 40, "{count} pinches placed");
        let (before, after) = (
            (before / count as f64).sqrt(),
            (after / count as f64).sqrt(),
        );
        assert!(after < 0.8 * before, "{before} -> {after}");
    }
}
