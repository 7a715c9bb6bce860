//! What kind of lattice a mesh was cut from, read off its positions: the
//! staircase-specific steps (the relaxation, the fairing, the dual-voxel
//! bound) apply to a mesh that samples a voxel mask, and only to one.
//!
//! - A voxel-boundary mesh: every edge at a vertex runs along one of three
//!   orthogonal axes ([`is_voxel_lattice`], in any orientation).
//! - A marching-cubes mesh of a binary mask: every vertex is the midpoint
//!   of an edge between two voxel centres, so along each of the grid's axes
//!   the coordinates fall on a grid of half the voxel spacing, and exactly
//!   one coordinate of each vertex is an odd multiple of it
//!   ([`is_marching_cubes_lattice`], in any orientation: an image with an
//!   oblique affine puts its grid's axes anywhere in world coordinates).
//!   Lewiner's variant adds a vertex at the centre of some cubes, all three
//!   coordinates odd; it sits on no lattice edge.

use super::Topology;
use glam::{DMat3, DVec3};
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

/// The share of the vertices that must sit at lattice-edge midpoints (or,
/// fewer of them than at midpoints, at cube centres) for a mesh to count
/// as a marching-cubes mesh of a mask: a crop's cut faces and a file's
/// rounding may put a few elsewhere, a smoothed or decimated mesh has
/// almost none there. Lewiner's marching cubes (scikit-image's) resolves a
/// cube whose faces are ambiguous with a vertex at the cube's centre: on a
/// thin sheet's mask, where voxels touch along edges everywhere, a few
/// percent of its vertices.
const MIDPOINT_SHARE: f64 = 0.99;

/// How far from the half-spacing grid a coordinate may lie, in half
/// spacings, and still count as on it: the rounding of a file's
/// coordinates (single precision, a few decimals) moves them far less, and
/// so does a level a little off the mask's midpoint (128 or 127 on a 0/255
/// mask puts a vertex 0.4% of its edge from the midpoint, 0.008 half
/// spacings); a mesh off the grid has a coordinate within it by chance one
/// time in fifty, all three one time in 125,000, far short of
/// [`MIDPOINT_SHARE`].
const GRID_TOLERANCE: f64 = 1e-2;

/// The same, for a frame estimated from one vertex's edges before it is
/// refined over the whole mesh: the rounding of those few coordinates tilts
/// the frame by up to about 1e-5 radian, which across a mesh a few hundred
/// voxels wide moves a coordinate by a few hundredths of a half spacing.
/// A mesh off the grid has a vertex within it on all three axes about one
/// time in a thousand, far short of [`MIDPOINT_SHARE`].
const ROUGH_GRID_TOLERANCE: f64 = 0.1;

/// How far from a whole multiple of its axis's smallest component an edge's
/// component may be, in those multiples, for a candidate frame to be tried
/// on the whole mesh (see [`edges_fit_frame`]).
const EDGE_TOLERANCE: f64 = 0.02;

/// How many candidate frames, of those that fit a vertex's edges, are
/// tried on the whole mesh (each is a sort of the coordinates per axis): a
/// marching-cubes mesh is found at its first vertex with two equal face
/// diagonals, and a mesh that is not one rarely gets this far.
const FRAME_TRIALS: usize = 8;

/// The most edges a vertex may have and still be looked at as a
/// marching-cubes vertex when the grid's axes are searched for: such a
/// vertex sits on a lattice edge shared by four cubes, each of which joins
/// it to a few other edge midpoints, far fewer than this. The cap keeps the
/// search (pairs of edges at a vertex, edges around it) linear in the mesh
/// whatever its valences.
const MAX_GRID_VALENCE: usize = 24;

/// Whether `positions` is a marching-cubes mesh of a binary mask (on a grid
/// of any orientation, spacing per axis and origin): see the module docs
/// and [`marching_cubes_grid`].
pub fn is_marching_cubes_lattice(topo: &Topology, positions: &[DVec3]) -> bool {
    marching_cubes_grid(topo, positions).is_some()
}

/// The lattice edge a marching-cubes vertex sits on: the axis it runs
/// along and the voxel spacing on that axis (the distance between the two
/// voxel centres it joins).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatticeEdge {
    /// The axis (0, 1, 2: the grid frame's first, second, third) the edge
    /// runs along.
    pub axis: u8,
    /// The voxel spacing along that axis.
    pub spacing: f64,
}

/// The grid a marching-cubes mesh of a mask was cut from.
#[derive(Debug, Clone, PartialEq)]
pub struct MarchingCubesGrid {
    /// The grid's axes (unit, orthogonal): the standard axes for an image
    /// written in voxel or axis-aligned coordinates, others for one with an
    /// oblique affine.
    pub frame: [DVec3; 3],
    /// The voxel spacing along each axis of `frame`.
    pub spacing: DVec3,
    /// Per vertex, the lattice edge it is the midpoint of (`None` for the
    /// few a crop's cut faces put elsewhere).
    pub edges: Vec<Option<LatticeEdge>>,
}

impl MarchingCubesGrid {
    /// The direction of `edge`'s axis.
    pub fn direction(&self, edge: LatticeEdge) -> DVec3 {
        self.frame[usize::from(edge.axis)]
    }
}

/// The grid `positions` samples, when it is a marching-cubes mesh of a
/// binary mask ([`is_marching_cubes_lattice`]).
///
/// The standard axes are tried first. Otherwise the grid's axes are read off
/// a few vertices' edges: a marching-cubes edge joins the midpoints of two
/// edges of one cube, so its components along the grid's axes are 0, one
/// or two half spacings, and two equally long edges from a vertex to the
/// midpoints of one face's two other edges sum and differ along that face's
/// axes. A frame that fits a vertex's neighbourhood is refined over the
/// whole mesh (a rigid fit of the vertices to their nearest grid points)
/// and must then pass the same test as the standard axes. `O(n log n)`.
pub fn marching_cubes_grid(topo: &Topology, positions: &[DVec3]) -> Option<MarchingCubesGrid> {
    let standard = [DVec3::X, DVec3::Y, DVec3::Z];
    if let Some(grid) = grid_in_frame(positions, &standard, GRID_TOLERANCE) {
        return Some(grid);
    }
    let n = topo.num_vertices().min(positions.len());
    if n < 8 {
        return None;
    }
    let mut tried: Vec<[DVec3; 3]> = vec![standard];
    let step = (n / FRAME_CANDIDATES).max(1);
    for v in (0..n).step_by(step).take(FRAME_CANDIDATES) {
        let Some(local) = local_edges(topo, positions, v) else {
            continue;
        };
        for frame in candidate_frames(topo, positions, v) {
            if tried.len() > FRAME_TRIALS {
                return None;
            }
            if tried.iter().any(|t| same_axes(t, &frame)) || !edges_fit_frame(&local, &frame) {
                continue;
            }
            tried.push(frame);
            let Some(frame) = refined_frame(positions, &frame) else {
                continue;
            };
            if let Some(grid) = grid_in_frame(positions, &frame, GRID_TOLERANCE) {
                return Some(grid);
            }
        }
    }
    None
}

/// The fractions of the coordinates' span under which two of them count as
/// one grid value when the half spacing is read off their gaps
/// ([`axis_grids`]), tried in turn: a thousandth absorbs files written with
/// a few decimals on an oblique grid, but is more than a half spacing on a
/// mesh wider than 500 of them (a whole-body scan, two organs far apart),
/// which a ten-thousandth reads up to 5000 (still ten times the spread a
/// frame tilted by 1e-5 radian gives).
const SPAN_ROUNDINGS: [f64; 2] = [1e-3, 1e-4];

/// The fewest half spacings a marching-cubes mesh spans along each axis of
/// its grid: a voxel is two, and a mask of a few voxels across is no
/// segmentation worth smoothing; a grid read from a wrong gap spans one.
const MIN_GRID_STEPS: f64 = 4.0;

/// Per axis of `frame`: the grid's origin and half spacing, from the
/// smallest gap between the coordinates' distinct values (values closer
/// than `span_rounding` times their span count as one), refined by a
/// least-squares fit of the coordinates within a quarter of a half spacing
/// of it.
fn axis_grids(
    positions: &[DVec3],
    frame: &[DVec3; 3],
    span_rounding: f64,
) -> Option<[(f64, f64); 3]> {
    let mut grid = [(0.0, 0.0); 3];
    for (axis, g) in frame.iter().zip(grid.iter_mut()) {
        let mut xs: Vec<f64> = positions.iter().map(|p| p.dot(*axis)).collect();
        xs.sort_unstable_by(f64::total_cmp);
        let (lo, hi) = (*xs.first()?, *xs.last()?);
        let tiny = span_rounding * (hi - lo);
        let half = xs
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|&d| d > tiny)
            .min_by(f64::total_cmp)?;
        // A grid read off the gap between two parts of a mesh, all of whose
        // half spacings fell under `tiny`, spans a few of its steps at most.
        if half * MIN_GRID_STEPS > hi - lo {
            return None;
        }
        // x = lo + k half, fitted over the k of every coordinate near one.
        let (mut s, mut sk, mut skk, mut sx, mut skx) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &x in &xs {
            let k = ((x - lo) / half).round();
            if ((x - lo) / half - k).abs() <= 0.25 {
                s += 1.0;
                sk += k;
                skk += k * k;
                sx += x - lo;
                skx += k * (x - lo);
            }
        }
        let det = s * skk - sk * sk;
        *g = if det > 0.0 {
            let slope = (s * skx - sk * sx) / det;
            (lo + (sx - slope * sk) / s, slope)
        } else {
            (lo, half)
        };
    }
    Some(grid)
}

/// The grid with axes `frame` whose edges' midpoints at least
/// [`MIDPOINT_SHARE`] of `positions` sit at, within `tolerance` half
/// spacings, with the lattice edge of each vertex.
fn grid_in_frame(
    positions: &[DVec3],
    frame: &[DVec3; 3],
    tolerance: f64,
) -> Option<MarchingCubesGrid> {
    let n = positions.len();
    if n < 8 {
        return None;
    }
    let (grid, bits, flip) = SPAN_ROUNDINGS.into_iter().find_map(|rounding| {
        let grid = axis_grids(positions, frame, rounding)?;
        let bits = grid_parities(positions, frame, &grid, tolerance);
        // Which parity is the voxel centres' on each axis is not known: of
        // the eight choices, the one that puts the most vertices at
        // midpoints (exactly one coordinate off the centres; a cube's
        // centre has all three). Flipping two axes also leaves the
        // midpoints along them, and makes the third axis's look like cube
        // centres, so the count of midpoints, not of both, decides; it
        // decides right while the centres are fewer than the midpoints
        // along any one axis (a few percent against a third).
        let mut parities = [0usize; 8];
        for &b in bits.iter().flatten() {
            parities[usize::from(b)] += 1;
        }
        let counts = |flip: u8| {
            let off = |k: u32| -> usize {
                (0u8..8)
                    .filter(|b| (b ^ flip).count_ones() == k)
                    .map(|b| parities[usize::from(b)])
                    .sum()
            };
            (off(1), off(3))
        };
        let flip = (0u8..8).max_by_key(|&flip| (counts(flip).0, std::cmp::Reverse(flip)))?;
        let (midpoints, centres) = counts(flip);
        if centres > midpoints || ((midpoints + centres) as f64) < MIDPOINT_SHARE * n as f64 {
            return None;
        }
        Some((grid, bits, flip))
    })?;
    let spacing = DVec3::new(2.0 * grid[0].1, 2.0 * grid[1].1, 2.0 * grid[2].1);
    let edges = bits
        .iter()
        .map(|b| {
            let off = b.map(|b| b ^ flip).filter(|b| b.count_ones() == 1)?;
            let axis = off.trailing_zeros() as u8;
            Some(LatticeEdge {
                axis,
                spacing: spacing[usize::from(axis)],
            })
        })
        .collect();
    Some(MarchingCubesGrid {
        frame: *frame,
        spacing,
        edges,
    })
}

/// Each vertex's parity on each axis's half grid (bit `a` for axis `a`),
/// `None` for a vertex off the grid by more than `tolerance` half spacings.
fn grid_parities(
    positions: &[DVec3],
    frame: &[DVec3; 3],
    grid: &[(f64, f64); 3],
    tolerance: f64,
) -> Vec<Option<u8>> {
    positions
        .par_iter()
        .with_min_len(4096)
        .map(|p| {
            let mut bits = 0u8;
            for (axis, &(lo, half)) in grid.iter().enumerate() {
                let k = (p.dot(frame[axis]) - lo) / half;
                let r = k.round();
                if (k - r).abs() > tolerance {
                    return None;
                }
                bits |= ((r as i64).rem_euclid(2) as u8) << axis;
            }
            Some(bits)
        })
        .collect()
}

/// The frames vertex `v`'s edges suggest: from each two equally long edges
/// their sum and difference (two face diagonals of one cube face), and from
/// each two orthogonal edges the edges themselves (two cube edges).
fn candidate_frames(topo: &Topology, positions: &[DVec3], v: usize) -> Vec<[DVec3; 3]> {
    if topo.neighbors(v).len() > MAX_GRID_VALENCE {
        return Vec::new();
    }
    let p = positions[v];
    let edges: Vec<DVec3> = topo
        .neighbors(v)
        .iter()
        .map(|&j| positions[j as usize] - p)
        .filter(|d| d.length() > 0.0)
        .collect();
    let mut frames = Vec::new();
    for (i, &a) in edges.iter().enumerate() {
        for &b in &edges[i + 1..] {
            let (la, lb) = (a.length(), b.length());
            let cos = a.dot(b) / (la * lb);
            if cos.abs() >= PARALLEL_COS {
                continue;
            }
            if (la - lb).abs() <= (1.0 - PARALLEL_COS) * la.max(lb) {
                frames.extend(frame_of(a + b, a - b));
            }
            if cos.abs() <= 1.0 - PARALLEL_COS {
                frames.extend(frame_of(a, b));
            }
        }
    }
    frames
}

/// The orthonormal frame of two orthogonal directions.
fn frame_of(a: DVec3, b: DVec3) -> Option<[DVec3; 3]> {
    let a = a.try_normalize()?;
    let b = b.try_normalize()?;
    let c = a.cross(b).try_normalize()?;
    Some([a, b, c])
}

/// Whether two frames have the same axes, in any order and sense.
fn same_axes(f: &[DVec3; 3], g: &[DVec3; 3]) -> bool {
    f.iter()
        .all(|a| g.iter().any(|b| a.dot(*b).abs() >= PARALLEL_COS))
}

/// How many vertices around a candidate vertex give the edges a frame is
/// checked on before it is tried on the whole mesh: enough to meet every
/// kind of marching-cubes edge, few enough to be free.
const LOCAL_VERTICES: usize = 32;

/// The edges of the first [`LOCAL_VERTICES`] vertices found breadth first
/// from `v`; `None` when one of them has more than [`MAX_GRID_VALENCE`]
/// edges (no marching-cubes vertex has).
fn local_edges(topo: &Topology, positions: &[DVec3], v: usize) -> Option<Vec<DVec3>> {
    let mut seen = vec![v];
    let mut next = 0;
    let mut edges = Vec::new();
    while next < seen.len() && next < LOCAL_VERTICES {
        let u = seen[next];
        next += 1;
        if topo.neighbors(u).len() > MAX_GRID_VALENCE {
            return None;
        }
        for &j in topo.neighbors(u) {
            let j = j as usize;
            edges.push(positions[j] - positions[u]);
            if !seen.contains(&j) && seen.len() < LOCAL_VERTICES {
                seen.push(j);
            }
        }
    }
    Some(edges)
}

/// Whether every edge's components along `frame`'s axes are 0, or one or
/// two times the smallest nonzero component along that axis (half a
/// spacing and a spacing), as a marching-cubes mesh's edges are in the
/// frame of its grid.
fn edges_fit_frame(edges: &[DVec3], frame: &[DVec3; 3]) -> bool {
    let scale = edges.iter().map(|d| d.length()).fold(0.0, f64::max);
    if scale == 0.0 {
        return false;
    }
    frame.iter().all(|axis| {
        let zero = EDGE_TOLERANCE * scale;
        let parts = || {
            edges
                .iter()
                .map(|d| d.dot(*axis).abs())
                .filter(move |&c| c > zero)
        };
        let Some(unit) = parts().min_by(f64::total_cmp) else {
            return true;
        };
        parts().all(|c| {
            let k = c / unit;
            (k - k.round()).abs() <= EDGE_TOLERANCE && k.round() <= 2.0
        })
    })
}

/// `frame` refined over the whole mesh: the rotation that best carries
/// each vertex's nearest grid point (within [`ROUGH_GRID_TOLERANCE`]) onto
/// it, when at least [`MIDPOINT_SHARE`] of the vertices have one.
fn refined_frame(positions: &[DVec3], frame: &[DVec3; 3]) -> Option<[DVec3; 3]> {
    SPAN_ROUNDINGS
        .into_iter()
        .find_map(|rounding| refined_frame_with(positions, frame, rounding))
}

/// [`refined_frame`] with the half spacing read at `span_rounding`.
fn refined_frame_with(
    positions: &[DVec3],
    frame: &[DVec3; 3],
    span_rounding: f64,
) -> Option<[DVec3; 3]> {
    let grid = axis_grids(positions, frame, span_rounding)?;
    let snapped = |p: &DVec3| -> Option<DVec3> {
        let mut g = DVec3::ZERO;
        for (axis, &(lo, half)) in grid.iter().enumerate() {
            let k = (p.dot(frame[axis]) - lo) / half;
            if (k - k.round()).abs() > ROUGH_GRID_TOLERANCE {
                return None;
            }
            g[axis] = lo + k.round() * half;
        }
        Some(g)
    };
    let pairs: Vec<(DVec3, DVec3)> = positions
        .iter()
        .filter_map(|p| Some((*p, snapped(p)?)))
        .collect();
    if (pairs.len() as f64) < MIDPOINT_SHARE * positions.len() as f64 {
        return None;
    }
    let count = pairs.len() as f64;
    let (sp, sg) = pairs
        .iter()
        .fold((DVec3::ZERO, DVec3::ZERO), |(sp, sg), (p, g)| {
            (sp + *p, sg + *g)
        });
    let (mp, mg) = (sp / count, sg / count);
    // Cross-covariance H = sum (p - mp)(g - mg)^T; the rotation R that
    // maximises trace(R^T H) is the orthogonal factor of H's polar
    // decomposition, and R's columns are the refined axes.
    let cov = pairs.iter().fold(DMat3::ZERO, |h, (p, g)| {
        let (dp, dg) = (*p - mp, *g - mg);
        h + DMat3::from_cols(dp * dg.x, dp * dg.y, dp * dg.z)
    });
    let r = orthogonal_factor(cov)?;
    frame_of(r.x_axis, r.y_axis)
}

/// The orthogonal factor of `m`'s polar decomposition, by Newton's
/// iteration `X <- (X + X^-T) / 2` (quadratic near the factor).
fn orthogonal_factor(m: DMat3) -> Option<DMat3> {
    let mut x = m;
    for _ in 0..POLAR_ITERATIONS {
        // Scaled to unit determinant first, so that the step converges
        // whatever the cross-covariance's magnitude.
        let det = x.determinant().abs();
        if !det.is_normal() {
            return None;
        }
        x *= det.cbrt().recip();
        let next = (x + x.inverse().transpose()) * 0.5;
        let settled = next.abs_diff_eq(x, 1e-13);
        x = next;
        if settled {
            break;
        }
    }
    let ortho = (x.transpose() * x).abs_diff_eq(DMat3::IDENTITY, 1e-9);
    ortho.then_some(x)
}

/// Newton steps of [`orthogonal_factor`] at most: from a cross-covariance
/// whose columns' lengths differ by the vertices' spread along each axis,
/// a handful reach machine precision.
const POLAR_ITERATIONS: usize = 30;

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
        assert!(is_marching_cubes_lattice(&mc_topo, mc.positions()));
        assert!(!is_marching_cubes_lattice(&voxel_topo, voxel.positions()));
    }

    /// `mesh` with every position mapped by `f`, and its topology.
    fn mapped(mesh: &crate::mesh::Mesh, f: impl Fn(DVec3) -> DVec3) -> (Topology, Vec<DVec3>) {
        let positions = mesh.positions().iter().map(|&p| f(p)).collect();
        (Topology::build(mesh), positions)
    }

    #[test]
    fn marching_cubes_grids_of_any_spacing_and_origin_are_found() {
        let (_, mc) = shapes::mc_sphere(5.0);
        // Anisotropic voxels (0.8 x 0.8 x 1.5 mm) at an odd origin, as an
        // imaging affine would put them, rounded to single precision.
        let (topo, scaled) = mapped(&mc, |p| {
            let q = p * DVec3::new(0.8, 0.8, 1.5) + DVec3::new(-91.3, 12.7, 40.1);
            q.as_vec3().as_dvec3()
        });
        let grid = marching_cubes_grid(&topo, &scaled).expect("a marching-cubes mesh");
        assert_eq!(grid.frame, [DVec3::X, DVec3::Y, DVec3::Z]);
        assert!(grid.spacing.abs_diff_eq(DVec3::new(0.8, 0.8, 1.5), 1e-5));
    }

    #[test]
    fn marching_cubes_at_a_level_a_little_off_the_midpoint_is_found() {
        use crate::shapes::Shape;
        // Level 128 on a 0/255 mask: each vertex 128/255 of its edge from
        // the outside centre, 0.002 voxel past the midpoint.
        let (sphere, mc) = shapes::mc_sphere(6.0);
        let (topo, shifted) = mapped(&mc, |p| {
            let axis = (0..3)
                .find(|&a| (p[a] - p[a].floor() - 0.5).abs() < 1e-9)
                .unwrap();
            let along = DVec3::AXES[axis];
            let inward = if sphere.inside(p + 0.5 * along) {
                1.0
            } else {
                -1.0
            };
            p + inward * (128.0 / 255.0 - 0.5) * along
        });
        let grid = marching_cubes_grid(&topo, &shifted).expect("a marching-cubes mesh");
        assert!(grid.edges.iter().all(Option::is_some));
    }

    #[test]
    fn a_marching_cubes_mesh_wider_than_a_thousand_half_spacings_is_found() {
        // Two small balls 1500 voxels apart (two organs of a whole-body
        // scan), on the axes and on an oblique grid.
        let (_, ball) = shapes::mc_sphere(4.0);
        let n = ball.num_vertices() as u32;
        let far = DVec3::new(1500.0, 0.0, 0.0);
        let positions: Vec<DVec3> = ball
            .positions()
            .iter()
            .copied()
            .chain(ball.positions().iter().map(|&p| p + far))
            .collect();
        let faces: Vec<Vec<u32>> = ball
            .faces()
            .map(<[u32]>::to_vec)
            .chain(ball.faces().map(|f| f.iter().map(|&v| v + n).collect()))
            .collect();
        let pair = crate::mesh::Mesh::from_polygons(positions, &faces).unwrap();
        let rot = glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1);
        for turn in [glam::DQuat::IDENTITY, rot] {
            let (topo, placed) = mapped(&pair, |p| turn * p);
            let grid = marching_cubes_grid(&topo, &placed).expect("a marching-cubes mesh");
            assert!(
                grid.spacing.abs_diff_eq(DVec3::ONE, 1e-6),
                "{:?}",
                grid.spacing
            );
        }
    }

    #[test]
    fn each_marching_cubes_vertex_gets_the_edge_between_an_inside_and_an_outside_centre() {
        use crate::shapes::Shape;
        let (sphere, mc) = shapes::mc_sphere(5.0);
        // Anisotropic voxels on an oblique grid far from the origin, as an
        // image with an oblique affine gives them in world coordinates,
        // rounded to single precision: the spacing and the direction follow
        // the axis.
        let spacing = DVec3::new(0.8, 0.8, 1.5);
        let rot = glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1);
        let origin = DVec3::new(-91.3, 112.7, 40.1);
        let (topo, placed) = mapped(&mc, |p| (rot * (p * spacing) + origin).as_vec3().as_dvec3());
        let grid = marching_cubes_grid(&topo, &placed).expect("a marching-cubes mesh");
        assert_eq!(grid.edges.len(), placed.len());
        for (p, edge) in mc.positions().iter().zip(&grid.edges) {
            let edge = edge.expect("every vertex is a midpoint");
            // The frame's axes come in any order and sense.
            let axis = (0..3)
                .find(|&a| grid.direction(edge).dot(rot * DVec3::AXES[a]).abs() > 1.0 - 1e-9)
                .expect("the edge runs along an axis of the grid");
            assert!((edge.spacing - spacing[axis]).abs() < 1e-5);
            let along = DVec3::AXES[axis];
            assert_ne!(
                sphere.inside(*p - 0.5 * along),
                sphere.inside(*p + 0.5 * along)
            );
        }
    }

    /// `mc` with every `nth` triangle fanned from the centre of the cube
    /// it lies in, as Lewiner's marching cubes resolves an ambiguous cube,
    /// and the count of vertices so added.
    fn with_cube_centres(mc: &crate::mesh::Mesh, nth: usize) -> (crate::mesh::Mesh, usize) {
        let mut positions = mc.positions().to_vec();
        let mut faces: Vec<Vec<u32>> = Vec::new();
        for (i, f) in mc.faces().enumerate() {
            if i % nth != 0 {
                faces.push(f.to_vec());
                continue;
            }
            let centroid = f.iter().map(|&v| positions[v as usize]).sum::<DVec3>() / 3.0;
            let centre = positions.len() as u32;
            // The shapes' voxel centres sit at half-integers, their cubes'
            // centres at integers.
            positions.push(centroid.round());
            faces.extend((0..3).map(|k| vec![f[k], f[(k + 1) % 3], centre]));
        }
        let added = positions.len() - mc.num_vertices();
        let mesh = crate::mesh::Mesh::from_polygons(positions, &faces).unwrap();
        (mesh, added)
    }

    #[test]
    fn a_lewiner_marching_cubes_mesh_with_cube_centres_is_found() {
        // A thin sheet's mask puts a few percent of Lewiner's vertices at
        // cube centres; the midpoints keep their edges, the centres get none.
        let (_, mc) = shapes::mc_sphere(6.0);
        let (lewiner, added) = with_cube_centres(&mc, 8);
        let share = added as f64 / lewiner.num_vertices() as f64;
        assert!(
            share > 1.0 - MIDPOINT_SHARE,
            "the fixture has {share} at centres"
        );
        let plain = {
            let topo = Topology::build(&mc);
            marching_cubes_grid(&topo, mc.positions()).expect("a marching-cubes mesh")
        };
        let rot = glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1);
        for turn in [glam::DQuat::IDENTITY, rot] {
            let (topo, placed) = mapped(&lewiner, |p| turn * p);
            let grid = marching_cubes_grid(&topo, &placed).expect("a marching-cubes mesh");
            let (midpoints, centres) = grid.edges.split_at(mc.num_vertices());
            assert!(centres.iter().all(Option::is_none));
            for (edge, expected) in midpoints.iter().zip(&plain.edges) {
                let (edge, expected) = (edge.unwrap(), expected.unwrap());
                let along = turn * plain.direction(expected);
                assert!(grid.direction(edge).dot(along).abs() > 1.0 - 1e-9);
            }
        }
    }

    #[test]
    fn meshes_off_the_grid_are_no_lattice() {
        let (sphere, mc) = shapes::mc_sphere(5.0);
        // A smoothed or interpolated mesh: vertices moved off the midpoints,
        // on the standard axes and on a rotated grid.
        let nudge =
            |p: DVec3| DVec3::splat(0.013 * (p.x * 7.0 + p.y * 3.0).rem_euclid(7.0).floor());
        let (topo, moved) = mapped(&mc, |p| p + nudge(p));
        assert!(!is_marching_cubes_lattice(&topo, &moved));
        let rot = glam::DQuat::from_rotation_z(0.3);
        let (_, rotated) = mapped(&mc, |p| rot * (p + nudge(p)));
        assert!(!is_marching_cubes_lattice(&topo, &rotated));
        // Too few vertices to tell.
        assert!(!is_marching_cubes_lattice(&topo, &mc.positions()[..4]));
        // Meshes of no grid: the same triangles with their vertices on the
        // sphere, a tilted voxel mesh.
        let (_, on_sphere) = mapped(&mc, |p| {
            sphere.center + sphere.radius * (p - sphere.center).normalize()
        });
        assert!(!is_marching_cubes_lattice(&topo, &on_sphere));
        let (_, voxel) = shapes::voxel_sphere(5.0);
        let (voxel_topo, tilted) = mapped(&voxel, |p| rot * p);
        assert!(!is_marching_cubes_lattice(&voxel_topo, &tilted));
        // A fan of 900 triangles about one vertex, its rim on half-grid
        // points: the hub's pairs of edges are not searched.
        let rim: Vec<DVec3> = (0..900)
            .map(|i| DVec3::new((i % 30) as f64, (i / 30) as f64, 0.5 * (i % 2) as f64))
            .collect();
        let mut fan_positions = vec![DVec3::new(14.5, 14.5, 3.0)];
        fan_positions.extend(rim);
        let faces: Vec<[u32; 3]> = (1..900u32).map(|i| [0, i, i + 1]).collect();
        let fan = crate::mesh::Mesh::from_polygons(fan_positions, &faces).expect("a fan");
        let fan_topo = Topology::build(&fan);
        assert!(!is_marching_cubes_lattice(&fan_topo, fan.positions()));
    }
}
