//! What kind of lattice a mesh was cut from, read off its positions: the
//! staircase-specific steps (the relaxation, the fairing, the dual-voxel
//! bound) apply to a mesh that samples a voxel mask, and only to one.
//!
//! - A voxel-boundary mesh: every edge at a vertex runs along one of three
//!   orthogonal axes ([`is_voxel_lattice`], in any orientation).
//! - A marching-cubes mesh of a binary mask: every vertex is the midpoint
//!   of an edge between two voxel centres, so along each axis the
//!   coordinates fall on a grid of half the voxel spacing, and exactly one
//!   coordinate of each vertex is an odd multiple of it
//!   ([`is_marching_cubes_lattice`], axis-aligned grids).

use super::Topology;
use glam::DVec3;
use rayon::prelude::*;

/// Two unit vectors are parallel for the lattice test when the cosine of
/// their angle is at least this: lattice edges are parallel up to the
/// rounding of the file's coordinates (a few units in the seventh digit for
/// single-precision formats), anything else is off by far more.
const PARALLEL_COS: f64 = 0.9999;

/// How many candidate edges the lattice frame is looked for from: a mesh
/// that is a lattice almost everywhere gives the frame from its first
/// edges; one that is not fails every candidate and gets balls only.
const FRAME_CANDIDATES: usize = 8;

/// Whether `positions` is a voxel lattice (a voxel-boundary mesh, in any
/// orientation): see [`lattice_frame`].
pub fn is_voxel_lattice(topo: &Topology, positions: &[DVec3]) -> bool {
    lattice_frame(topo, positions).is_some()
}

/// The lattice's three axes, when `positions` has a vertex whose edges run
/// along three orthogonal directions and at least half the mesh's vertices
/// have all their edges along them; `None` otherwise.
pub(crate) fn lattice_frame(topo: &Topology, positions: &[DVec3]) -> Option<[DVec3; 3]> {
    let n = topo.num_vertices();
    if n == 0 {
        return None;
    }
    let step = (n / FRAME_CANDIDATES).max(1);
    (0..n).step_by(step).take(FRAME_CANDIDATES).find_map(|v| {
        let frame = frame_at(topo, positions, v)?;
        let on = (0..n)
            .into_par_iter()
            .with_min_len(4096)
            .filter(|&u| {
                let nb = topo.neighbors(u);
                !nb.is_empty()
                    && nb.iter().all(|&j| {
                        along_axis(&frame, positions[j as usize] - positions[u]).is_some()
                    })
            })
            .count();
        (2 * on >= n).then_some(frame)
    })
}

/// The orthogonal frame of vertex `v`'s edges, when it has two orthogonal
/// edges and every other edge runs along one of the frame's axes.
fn frame_at(topo: &Topology, positions: &[DVec3], v: usize) -> Option<[DVec3; 3]> {
    let p = positions[v];
    let dirs = topo
        .neighbors(v)
        .iter()
        .map(|&j| (positions[j as usize] - p).normalize_or_zero());
    let mut first = None;
    let mut second = None;
    for d in dirs {
        match first {
            None if d != DVec3::ZERO => first = Some(d),
            Some(a) if second.is_none() && a.dot(d).abs() < 1.0 - PARALLEL_COS => second = Some(d),
            _ => {}
        }
    }
    let (a, b) = (first?, second?);
    let frame = [a, b, a.cross(b).normalize()];
    topo.neighbors(v)
        .iter()
        .all(|&j| along_axis(&frame, positions[j as usize] - p).is_some())
        .then_some(frame)
}

/// The axis of `frame` that `d` runs along, if any.
pub(crate) fn along_axis(frame: &[DVec3; 3], d: DVec3) -> Option<usize> {
    let len = d.length();
    if len == 0.0 {
        return None;
    }
    frame
        .iter()
        .position(|a| a.dot(d).abs() >= PARALLEL_COS * len)
}

/// The share of the vertices that must sit at lattice-edge midpoints for
/// a mesh to count as a marching-cubes mesh of a mask: a crop's cut faces
/// and a file's rounding may put a few elsewhere, a smoothed or decimated
/// mesh has almost none there.
const MIDPOINT_SHARE: f64 = 0.99;

/// How far from the half-spacing grid a coordinate may lie, in half
/// spacings, and still count as on it: the rounding of a file's
/// coordinates (single precision, a few decimals) moves them far less,
/// anything off the grid by far more.
const GRID_TOLERANCE: f64 = 1e-3;

/// Whether `positions` is a marching-cubes mesh of a binary mask on an
/// axis-aligned grid (of any spacing per axis and origin): see the module
/// docs. `O(n log n)`: one sort per axis.
pub fn is_marching_cubes_lattice(positions: &[DVec3]) -> bool {
    marching_cubes_edges(positions).is_some()
}

/// The lattice edge a marching-cubes vertex sits on: the axis it runs
/// along and the voxel spacing on that axis (the distance between the two
/// voxel centres it joins).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatticeEdge {
    /// The axis (0, 1, 2: x, y, z) the edge runs along.
    pub axis: u8,
    /// The voxel spacing along that axis.
    pub spacing: f64,
}

/// Per vertex, the lattice edge it is the midpoint of (`None` for the few
/// a crop's cut faces put elsewhere), when `positions` is a marching-cubes
/// mesh of a binary mask ([`is_marching_cubes_lattice`]).
pub fn marching_cubes_edges(positions: &[DVec3]) -> Option<Vec<Option<LatticeEdge>>> {
    let n = positions.len();
    if n < 8 {
        return None;
    }
    // Per axis: the grid's origin and half spacing, from the smallest gap
    // between the coordinates' distinct values.
    let mut grid = [(0.0, 0.0); 3];
    for (axis, g) in grid.iter_mut().enumerate() {
        let mut xs: Vec<f64> = positions.iter().map(|p| p[axis]).collect();
        xs.sort_unstable_by(f64::total_cmp);
        let (lo, hi) = (xs[0], xs[n - 1]);
        let tiny = GRID_TOLERANCE * (hi - lo);
        let half = xs
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|&d| d > tiny)
            .min_by(f64::total_cmp)?;
        *g = (lo, half);
    }
    // Each coordinate's parity on its axis's half grid; a coordinate off
    // the grid disqualifies its vertex.
    let parities = |p: &DVec3| -> Option<u8> {
        let mut bits = 0u8;
        for (axis, &(lo, half)) in grid.iter().enumerate() {
            let k = (p[axis] - lo) / half;
            let r = k.round();
            if (k - r).abs() > GRID_TOLERANCE {
                return None;
            }
            bits |= ((r as i64).rem_euclid(2) as u8) << axis;
        }
        Some(bits)
    };
    let bits: Vec<Option<u8>> = positions
        .par_iter()
        .with_min_len(4096)
        .map(parities)
        .collect();
    // Which parity is the voxel centres' on each axis is not known: try
    // the eight choices; a midpoint has exactly one coordinate off them.
    let flip = (0u8..8).find(|&flip| {
        let midpoints = bits
            .iter()
            .filter(|b| b.is_some_and(|b| (b ^ flip).count_ones() == 1))
            .count();
        midpoints as f64 >= MIDPOINT_SHARE * n as f64
    })?;
    Some(
        bits.iter()
            .map(|b| {
                let off = b.map(|b| b ^ flip).filter(|b| b.count_ones() == 1)?;
                let axis = off.trailing_zeros() as u8;
                Some(LatticeEdge {
                    axis,
                    spacing: 2.0 * grid[usize::from(axis)].1,
                })
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    #[test]
    fn voxel_and_marching_cubes_meshes_are_told_apart() {
        let (_, voxel) = shapes::voxel_sphere(6.0);
        let (_, mc) = shapes::mc_sphere(6.0);
        let voxel_topo = Topology::build(&voxel);
        let mc_topo = Topology::build(&mc);
        assert!(is_voxel_lattice(&voxel_topo, voxel.positions()));
        assert!(!is_voxel_lattice(&mc_topo, mc.positions()));
        assert!(is_marching_cubes_lattice(mc.positions()));
        assert!(!is_marching_cubes_lattice(voxel.positions()));
    }

    #[test]
    fn marching_cubes_grids_of_any_spacing_and_origin_are_found() {
        let (_, mc) = shapes::mc_sphere(5.0);
        // Anisotropic voxels (0.8 x 0.8 x 1.5 mm) at an odd origin, as an
        // imaging affine would put them, rounded to single precision.
        let scaled: Vec<DVec3> = mc
            .positions()
            .iter()
            .map(|p| {
                let q = *p * DVec3::new(0.8, 0.8, 1.5) + DVec3::new(-91.3, 12.7, 40.1);
                q.as_vec3().as_dvec3()
            })
            .collect();
        assert!(is_marching_cubes_lattice(&scaled));
    }

    #[test]
    fn each_marching_cubes_vertex_gets_the_edge_between_an_inside_and_an_outside_centre() {
        use crate::shapes::Shape;
        let (sphere, mc) = shapes::mc_sphere(5.0);
        // Anisotropic voxels: the spacing follows the axis.
        let spacing = DVec3::new(0.8, 0.8, 1.5);
        let scaled: Vec<DVec3> = mc.positions().iter().map(|p| *p * spacing).collect();
        let edges = marching_cubes_edges(&scaled).expect("a marching-cubes mesh");
        assert_eq!(edges.len(), scaled.len());
        for (p, edge) in mc.positions().iter().zip(&edges) {
            let edge = edge.expect("every vertex is a midpoint");
            let axis = usize::from(edge.axis);
            assert!((edge.spacing - spacing[axis]).abs() < 1e-9);
            let mut half = DVec3::ZERO;
            half[axis] = 0.5;
            assert_ne!(sphere.inside(*p - half), sphere.inside(*p + half));
        }
    }

    #[test]
    fn meshes_off_the_grid_are_no_lattice() {
        let (_, mc) = shapes::mc_sphere(5.0);
        // A smoothed or interpolated mesh: vertices moved off the midpoints.
        let moved: Vec<DVec3> = mc
            .positions()
            .iter()
            .enumerate()
            .map(|(i, p)| *p + DVec3::splat(0.013 * (i % 7) as f64))
            .collect();
        assert!(!is_marching_cubes_lattice(&moved));
        assert!(!is_marching_cubes_lattice(&mc.positions()[..4]));
        // A rotated grid is not found (axis-aligned grids only).
        let rot = glam::DQuat::from_rotation_z(0.3);
        let rotated: Vec<DVec3> = mc.positions().iter().map(|p| rot * *p).collect();
        assert!(!is_marching_cubes_lattice(&rotated));
    }
}
