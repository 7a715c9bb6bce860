//! Binary voxel masks of shapes and their welded quad boundary meshes.

use super::Shape;
use crate::mesh::Mesh;
use glam::{DVec3, IVec3};
use rayon::prelude::*;

/// Empty voxels [`voxel_mask`] leaves around a shape's bounding box on every
/// side.
pub const VOXEL_MARGIN: i32 = 2;

/// A binary voxel grid: voxel `(i, j, k)`, `0 <= i < dims.x` etc., covers
/// the unit cube `[o.x + i, o.x + i + 1] x ...` with `o = origin`. Voxels
/// outside the grid count as outside.
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelMask {
    origin: IVec3,
    dims: [usize; 3],
    /// One entry per voxel (1 inside, 0 outside), x fastest, then y, then z.
    inside: Vec<u8>,
}

impl VoxelMask {
    /// Grid of `dims` voxels whose voxel `(i, j, k)` is inside iff
    /// `f(i, j, k)`; evaluated in parallel, one z layer per task.
    pub fn from_fn(
        origin: IVec3,
        dims: [usize; 3],
        f: impl Fn(usize, usize, usize) -> bool + Sync,
    ) -> VoxelMask {
        let [nx, ny, nz] = dims;
        let mut inside = vec![0u8; nx * ny * nz];
        if nx * ny > 0 {
            inside
                .par_chunks_mut(nx * ny)
                .enumerate()
                .for_each(|(k, layer)| {
                    for j in 0..ny {
                        for i in 0..nx {
                            layer[j * nx + i] = u8::from(f(i, j, k));
                        }
                    }
                });
        }
        VoxelMask {
            origin,
            dims,
            inside,
        }
    }

    /// Position of the lowest corner of voxel `(0, 0, 0)`.
    pub fn origin(&self) -> IVec3 {
        self.origin
    }

    /// Number of voxels along x, y and z.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Whether voxel `(i, j, k)` is inside; `false` outside the grid.
    #[inline]
    pub fn get(&self, i: i64, j: i64, k: i64) -> bool {
        let [nx, ny, nz] = self.dims;
        if i < 0 || j < 0 || k < 0 || i as usize >= nx || j as usize >= ny || k as usize >= nz {
            return false;
        }
        self.inside[(k as usize * ny + j as usize) * nx + i as usize] != 0
    }

    /// Voxel row `(j, k)` (one byte per voxel along x, 1 inside); `None`
    /// outside the grid.
    fn row(&self, j: i64, k: i64) -> Option<&[u8]> {
        let [nx, ny, nz] = self.dims;
        if j < 0 || k < 0 || j as usize >= ny || k as usize >= nz {
            return None;
        }
        let start = (k as usize * ny + j as usize) * nx;
        Some(&self.inside[start..start + nx])
    }

    /// Number of inside voxels (the enclosed volume in voxels).
    pub fn count_inside(&self) -> usize {
        self.inside.par_iter().filter(|&&b| b != 0).count()
    }

    /// Centre of voxel `(i, j, k)`.
    pub fn voxel_center(&self, i: i64, j: i64, k: i64) -> DVec3 {
        self.origin.as_dvec3() + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5)
    }
}

/// Edge length of the voxel blocks [`voxel_mask`] classifies with one test
/// when they lie far from the surface.
const BLOCK: usize = 8;

/// The voxel mask of `shape`: a voxel is inside iff its centre is inside
/// the shape. The grid covers the shape's bounds, rounded out to whole
/// voxels, plus [`VOXEL_MARGIN`] empty voxels on each side; voxel
/// coordinates are the shape's own coordinates.
///
/// Blocks of 8^3 voxels whose centre is farther from the surface than
/// their farthest voxel centre take the centre's side with one
/// [`Shape::inside`] test, so [`Shape::distance`] must not overestimate.
///
/// # Panics
/// If the bounds are not finite or the grid would not fit in `i32`
/// coordinates.
pub fn voxel_mask<S: Shape + ?Sized>(shape: &S) -> VoxelMask {
    let (lo, hi) = shape.bounds();
    assert!(
        lo.is_finite() && hi.is_finite(),
        "shape bounds must be finite"
    );
    let lo = lo.floor().as_ivec3() - VOXEL_MARGIN;
    let hi = hi.ceil().as_ivec3() + VOXEL_MARGIN;
    let d = (hi - lo).max(IVec3::ZERO);
    let [nx, ny, nz] = [d.x as usize, d.y as usize, d.z as usize];
    let mut inside = vec![0u8; nx * ny * nz];
    let centre = |i: usize, j: usize, k: usize| {
        lo.as_dvec3() + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5)
    };
    if nx * ny > 0 {
        inside
            .par_chunks_mut(nx * ny * BLOCK)
            .enumerate()
            .for_each(|(kb, slab)| {
                let k0 = kb * BLOCK;
                let k1 = k0 + slab.len() / (nx * ny);
                for j0 in (0..ny).step_by(BLOCK) {
                    let j1 = (j0 + BLOCK).min(ny);
                    for i0 in (0..nx).step_by(BLOCK) {
                        let i1 = (i0 + BLOCK).min(nx);
                        // Block centre and its distance to the farthest
                        // voxel centre of the block.
                        let c = 0.5 * (centre(i0, j0, k0) + centre(i1 - 1, j1 - 1, k1 - 1));
                        let reach = 0.5
                            * DVec3::new(
                                (i1 - i0 - 1) as f64,
                                (j1 - j0 - 1) as f64,
                                (k1 - k0 - 1) as f64,
                            )
                            .length();
                        let uniform = shape.distance(c) > reach * (1.0 + 1e-9) + 1e-9;
                        let block_value = uniform && shape.inside(c);
                        for k in k0..k1 {
                            for j in j0..j1 {
                                let row = ((k - k0) * ny + j) * nx;
                                let cells = &mut slab[row + i0..row + i1];
                                if uniform {
                                    cells.fill(u8::from(block_value));
                                } else {
                                    for (i, v) in (i0..i1).zip(cells) {
                                        *v = u8::from(shape.inside(centre(i, j, k)));
                                    }
                                }
                            }
                        }
                    }
                }
            });
    }
    VoxelMask {
        origin: lo,
        dims: [nx, ny, nz],
        inside,
    }
}

/// Where each voxel row changes: for row `(j, k)` the sorted positions
/// `0 <= p <= nx` with voxel `p - 1` and voxel `p` on different sides
/// (voxels beyond the row count as outside), so inside runs are
/// `[p0, p1)`, `[p2, p3)`, ...
pub(super) struct RowBreaks {
    ny: usize,
    nz: usize,
    offsets: Vec<usize>,
    points: Vec<u32>,
}

impl RowBreaks {
    pub(super) fn new(mask: &VoxelMask) -> RowBreaks {
        let [nx, ny, nz] = mask.dims;
        let layers: Vec<(Vec<usize>, Vec<u32>)> = (0..nz)
            .into_par_iter()
            .map(|k| {
                let mut counts = Vec::with_capacity(ny);
                let mut points = Vec::new();
                for j in 0..ny {
                    let row = mask.row(j as i64, k as i64).unwrap_or(&[]);
                    let before = points.len();
                    let mut p = 0;
                    let mut want = 1u8;
                    while let Some(o) = memchr::memchr(want, &row[p..]) {
                        p += o;
                        points.push(p as u32);
                        want ^= 1;
                    }
                    if want == 0 {
                        points.push(nx as u32);
                    }
                    counts.push(points.len() - before);
                }
                (counts, points)
            })
            .collect();
        let mut offsets = Vec::with_capacity(ny * nz + 1);
        offsets.push(0);
        let mut points = Vec::new();
        for (counts, p) in layers {
            for c in counts {
                offsets.push(offsets[offsets.len() - 1] + c);
            }
            points.extend(p);
        }
        RowBreaks {
            ny,
            nz,
            offsets,
            points,
        }
    }

    /// Breaks of row `(j, k)`; empty outside the grid.
    pub(super) fn row(&self, j: i64, k: i64) -> &[u32] {
        if j < 0 || k < 0 || j as usize >= self.ny || k as usize >= self.nz {
            return &[];
        }
        let r = k as usize * self.ny + j as usize;
        &self.points[self.offsets[r]..self.offsets[r + 1]]
    }

    /// The union of the breaks of `rows`, sorted, into `out`.
    pub(super) fn merged(&self, rows: &[(i64, i64)], out: &mut Vec<u32>) {
        out.clear();
        for &(j, k) in rows {
            out.extend_from_slice(self.row(j, k));
        }
        out.sort_unstable();
        out.dedup();
    }
}

/// A set of `u64` keys stored as a bit set with a rank index: the `n`-th
/// smallest key gets index `n`.
pub(super) struct RankedSet {
    words: Vec<u64>,
    before: Vec<u32>,
}

impl RankedSet {
    /// Builds the set of `keys`, all `< universe`.
    ///
    /// # Panics
    /// If the set holds `u32::MAX` keys or more.
    pub(super) fn new(universe: u64, keys: impl Iterator<Item = u64>) -> RankedSet {
        let mut words = vec![0u64; universe.div_ceil(64) as usize];
        for k in keys {
            words[(k / 64) as usize] |= 1 << (k % 64);
        }
        let mut before = Vec::with_capacity(words.len());
        let mut total = 0u64;
        for w in &words {
            before.push(total as u32);
            total += u64::from(w.count_ones());
        }
        assert!(total < u64::from(u32::MAX), "too many mesh vertices");
        RankedSet { words, before }
    }

    /// Index of `key`, which must be in the set.
    #[inline]
    pub(super) fn rank(&self, key: u64) -> u32 {
        let w = (key / 64) as usize;
        let below = self.words[w] & ((1u64 << (key % 64)) - 1);
        self.before[w] + below.count_ones()
    }

    /// The keys in increasing order.
    pub(super) fn keys(&self) -> impl Iterator<Item = u64> + '_ {
        self.words.iter().enumerate().flat_map(|(w, &bits)| {
            let mut b = bits;
            std::iter::from_fn(move || {
                if b == 0 {
                    return None;
                }
                let t = b.trailing_zeros();
                b &= b - 1;
                Some(w as u64 * 64 + u64::from(t))
            })
        })
    }
}

/// The boundary of `mask` as a quad mesh: one quad per face between an
/// inside and an outside voxel, oriented outward (vector area from inside
/// to outside), corners welded so each grid corner is one vertex.
///
/// Vertices are the used grid corners in z, y, x order; quads come voxel by
/// voxel in z, y, x order and per voxel in the order -x, +x, -y, +y, -z, +z.
/// Voxels that share only an edge give that edge four faces (a non-manifold
/// edge); only a corner, a non-manifold vertex. The result is closed.
///
/// # Panics
/// If the mesh would have `u32::MAX` vertices or corners or more.
pub fn voxel_boundary_mesh(mask: &VoxelMask) -> Mesh {
    let [nx, ny, nz] = mask.dims;
    // Corner (x, y, z), 0 <= x <= nx etc., has key (z (ny+1) + y)(nx+1) + x.
    let (cx, cy) = (nx as u64 + 1, ny as u64 + 1);
    let key = |c: [i64; 3]| (c[2] as u64 * cy + c[1] as u64) * cx + c[0] as u64;
    let breaks = RowBreaks::new(mask);
    let layers: Vec<Vec<[u64; 4]>> = (0..nz)
        .into_par_iter()
        .map(|k| {
            let mut quads = Vec::new();
            let mut merged = Vec::new();
            let k = k as i64;
            for j in 0..ny as i64 {
                if breaks.row(j, k).is_empty() {
                    continue;
                }
                // Between merged breaks this row and its four neighbours
                // are constant: an inside stretch whose neighbours are all
                // inside has faces only at its two ends.
                breaks.merged(
                    &[(j, k), (j - 1, k), (j + 1, k), (j, k - 1), (j, k + 1)],
                    &mut merged,
                );
                for w in merged.windows(2) {
                    let (a, b) = (i64::from(w[0]), i64::from(w[1]));
                    if !mask.get(a, j, k) {
                        continue;
                    }
                    let covered = mask.get(a, j - 1, k)
                        && mask.get(a, j + 1, k)
                        && mask.get(a, j, k - 1)
                        && mask.get(a, j, k + 1);
                    let mut visit = |i: i64| push_faces(mask, [i, j, k], &key, &mut quads);
                    if covered {
                        visit(a);
                        if b - 1 > a {
                            visit(b - 1);
                        }
                    } else {
                        (a..b).for_each(visit);
                    }
                }
            }
            quads
        })
        .collect();
    let corners = RankedSet::new(
        cx * cy * (nz as u64 + 1),
        layers.iter().flatten().flatten().copied(),
    );
    let origin = mask.origin.as_dvec3();
    let positions: Vec<DVec3> = corners
        .keys()
        .map(|c| {
            let x = c % cx;
            let y = (c / cx) % cy;
            let z = c / (cx * cy);
            origin + DVec3::new(x as f64, y as f64, z as f64)
        })
        .collect();
    let num_quads: usize = layers.iter().map(Vec::len).sum();
    let mut face_vertices = Vec::with_capacity(num_quads * 4);
    for q in layers.iter().flatten() {
        face_vertices.extend(q.iter().map(|&c| corners.rank(c)));
    }
    let face_offsets = (0..=num_quads)
        .map(|f| u32::try_from(4 * f).expect("too many quad corners"))
        .collect();
    Mesh::new(positions, face_offsets, face_vertices).expect("a voxel boundary is a valid mesh")
}

/// Pushes the boundary quads of inside voxel `v` (keys of their corners),
/// in the order -x, +x, -y, +y, -z, +z.
fn push_faces(
    mask: &VoxelMask,
    v: [i64; 3],
    key: &impl Fn([i64; 3]) -> u64,
    quads: &mut Vec<[u64; 4]>,
) {
    for a in 0..3 {
        for positive in [false, true] {
            let mut n = v;
            n[a] += if positive { 1 } else { -1 };
            if mask.get(n[0], n[1], n[2]) {
                continue;
            }
            let (u, w) = ((a + 1) % 3, (a + 2) % 3);
            let mut base = v;
            if positive {
                base[a] += 1;
            }
            let mut bu = base;
            bu[u] += 1;
            let mut buw = bu;
            buw[w] += 1;
            let mut bw = base;
            bw[w] += 1;
            // e_u x e_w = e_a: this order faces +a.
            let q = [key(base), key(bu), key(buw), key(bw)];
            quads.push(if positive {
                q
            } else {
                [q[0], q[3], q[2], q[1]]
            });
        }
    }
}

/// The labels `masks` of one label map as VTK's surface nets write it
/// with its internal walls: each label's voxel boundary
/// ([`voxel_boundary_mesh`]) on one vertex per position, each face two
/// labels share written once (wound outward from the first of them). A
/// multi-label complex: where a wall meets the outer surface an edge has
/// three faces.
///
/// # Panics
/// If the mesh would have `u32::MAX` vertices or corners or more.
pub fn label_complex(masks: &[VoxelMask]) -> Mesh {
    let mut index: std::collections::HashMap<[u64; 3], u32> = Default::default();
    let mut positions: Vec<DVec3> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut faces: Vec<Vec<u32>> = Vec::new();
    for mask in masks {
        let mesh = voxel_boundary_mesh(mask);
        for face in mesh.faces() {
            let face: Vec<u32> = face
                .iter()
                .map(|&v| {
                    let p = mesh.positions()[v as usize];
                    *index
                        .entry(p.to_array().map(f64::to_bits))
                        .or_insert_with(|| {
                            positions.push(p);
                            (positions.len() - 1) as u32
                        })
                })
                .collect();
            let mut key = face.clone();
            key.sort_unstable();
            if seen.insert(key) {
                faces.push(face);
            }
        }
    }
    Mesh::from_polygons(positions, &faces).expect("a label map's faces are valid polygons")
}
