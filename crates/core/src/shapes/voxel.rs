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
    /// One entry per voxel, x fastest, then y, then z.
    inside: Vec<bool>,
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
        let mut inside = vec![false; nx * ny * nz];
        if nx * ny > 0 {
            inside
                .par_chunks_mut(nx * ny)
                .enumerate()
                .for_each(|(k, layer)| {
                    for j in 0..ny {
                        for i in 0..nx {
                            layer[j * nx + i] = f(i, j, k);
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
        self.inside[(k as usize * ny + j as usize) * nx + i as usize]
    }

    /// Number of inside voxels (the enclosed volume in voxels).
    pub fn count_inside(&self) -> usize {
        self.inside.par_iter().filter(|&&b| b).count()
    }

    /// Centre of voxel `(i, j, k)`.
    pub fn voxel_center(&self, i: i64, j: i64, k: i64) -> DVec3 {
        self.origin.as_dvec3() + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5)
    }
}

/// The voxel mask of `shape`: a voxel is inside iff its centre is inside
/// the shape. The grid covers the shape's bounds, rounded out to whole
/// voxels, plus [`VOXEL_MARGIN`] empty voxels on each side; voxel
/// coordinates are the shape's own coordinates.
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
    let dims = [d.x as usize, d.y as usize, d.z as usize];
    let o = lo.as_dvec3() + 0.5;
    VoxelMask::from_fn(lo, dims, |i, j, k| {
        shape.inside(o + DVec3::new(i as f64, j as f64, k as f64))
    })
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
    let layers: Vec<Vec<[u64; 4]>> = (0..nz)
        .into_par_iter()
        .map(|k| {
            let mut quads = Vec::new();
            let k = k as i64;
            for j in 0..ny as i64 {
                for i in 0..nx as i64 {
                    if !mask.get(i, j, k) {
                        continue;
                    }
                    let v = [i, j, k];
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
