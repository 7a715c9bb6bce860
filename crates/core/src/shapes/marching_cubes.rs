//! Marching cubes (Lorensen & Cline 1987) on a binary voxel mask.
//!
//! The 256-case table is generated rather than typed in: in each cube face
//! the surface's trace joins every edge crossing where the value enters the
//! inside (walking the face anticlockwise seen from outside the cube) to the
//! next crossing where it leaves. On the ambiguous faces (two diagonal inside
//! corners) this always separates the inside corners, and because a face's
//! trace depends on that face alone, neighbouring cubes agree and the
//! surface is closed and manifold. The traces chain into loops inside each
//! cube, and each loop is fanned into triangles from its first crossing.
//! This is the classic case table with the "separate inside corners"
//! resolution of ambiguous faces (no holes).

use super::voxel::{RankedSet, RowBreaks, VoxelMask};
use crate::mesh::Mesh;
use glam::DVec3;
use rayon::prelude::*;
use std::sync::OnceLock;

/// Cube corner `c` sits at offset `(c & 1, c >> 1 & 1, c >> 2 & 1)`. Edge
/// `4 a + m` runs along axis `a` from the corner [`edge_start`] returns.
const NUM_EDGES: usize = 12;

/// Lower corner and axis of cube edge `e`.
fn edge_start(e: usize) -> (usize, usize) {
    let a = e / 4;
    let m = e % 4;
    let (u, w) = ((a + 1) % 3, (a + 2) % 3);
    let c = ((m & 1) << u) | ((m >> 1) << w);
    (c, a)
}

/// Cube edge joining corners `c` and `d` (adjacent).
fn edge_between(c: usize, d: usize) -> usize {
    let lo = c.min(d);
    let a = (c ^ d).trailing_zeros() as usize;
    let (u, w) = ((a + 1) % 3, (a + 2) % 3);
    4 * a + ((lo >> u) & 1) + (((lo >> w) & 1) << 1)
}

/// Triangles (as cube-edge triples, outward orientation) of each of the 256
/// cases; bit `c` of the case is set when corner `c` is inside.
fn case_table() -> &'static [Vec<[u8; 3]>; 256] {
    static TABLE: OnceLock<[Vec<[u8; 3]>; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(triangulate_case))
}

fn triangulate_case(case: usize) -> Vec<[u8; 3]> {
    let inside = |c: usize| case >> c & 1 == 1;
    // next[e]: the crossing that follows crossing e along the surface trace.
    let mut next = [usize::MAX; NUM_EDGES];
    for a in 0..3 {
        for positive in [false, true] {
            let (u, w) = ((a + 1) % 3, (a + 2) % 3);
            let base = if positive { 1 << a } else { 0 };
            // Anticlockwise seen from outside: e_u x e_w = e_a faces +a.
            let mut quad = [base, base | 1 << u, base | 1 << u | 1 << w, base | 1 << w];
            if !positive {
                quad.reverse();
            }
            // Crossings in walking order: (edge, entering the inside?).
            let crossings: Vec<(usize, bool)> = (0..4)
                .filter(|&j| inside(quad[j]) != inside(quad[(j + 1) % 4]))
                .map(|j| {
                    let (c, d) = (quad[j], quad[(j + 1) % 4]);
                    (edge_between(c, d), inside(d))
                })
                .collect();
            let n = crossings.len();
            for (s, &(e, entering)) in crossings.iter().enumerate() {
                if entering {
                    // The next crossing in walking order leaves the inside.
                    next[e] = crossings[(s + 1) % n].0;
                }
            }
        }
    }
    let mut triangles = Vec::new();
    let mut seen = [false; NUM_EDGES];
    for start in 0..NUM_EDGES {
        if next[start] == usize::MAX || seen[start] {
            continue;
        }
        let mut ring = Vec::new();
        let mut e = start;
        while !seen[e] {
            seen[e] = true;
            ring.push(e as u8);
            e = next[e];
        }
        for t in 1..ring.len() - 1 {
            triangles.push([ring[0], ring[t], ring[t + 1]]);
        }
    }
    triangles
}

/// The marching-cubes surface of `mask` at level 0.5, with value 1 at the
/// centres of inside voxels and 0 elsewhere (also beyond the grid): one
/// vertex at the midpoint of each pair of face-adjacent voxel centres with
/// one inside and one outside (welded: one vertex per grid edge), triangles
/// oriented outward. Closed and manifold for every mask; inside voxels that
/// touch only along an edge or at a corner are kept apart.
///
/// Vertices are ordered by the lower voxel of their grid edge (z, y, x
/// order) and then its axis (x, y, z); triangles come cube by cube in z, y,
/// x order.
///
/// # Panics
/// If the mesh would have `u32::MAX` vertices or corners or more.
pub fn marching_cubes_mesh(mask: &VoxelMask) -> Mesh {
    let table = case_table();
    let [nx, ny, nz] = mask.dims();
    // Grid edge from voxel v along axis a, with -1 <= v_i <= n_i - 1, has
    // key 3 (((v_z + 1) ey + v_y + 1) ex + v_x + 1) + a.
    let (ex, ey, ez) = (nx as u64 + 1, ny as u64 + 1, nz as u64 + 1);
    let edge_key = |v: [i64; 3], a: usize| {
        3 * ((((v[2] + 1) as u64) * ey + (v[1] + 1) as u64) * ex + (v[0] + 1) as u64) + a as u64
    };
    let edges: [(usize, usize); NUM_EDGES] = std::array::from_fn(edge_start);
    let breaks = RowBreaks::new(mask);
    let layers: Vec<Vec<[u64; 3]>> = (-1..nz as i64)
        .into_par_iter()
        .map(|k| {
            let mut tris = Vec::new();
            let mut merged = Vec::new();
            let mut emit = |i: i64, j: i64| {
                let mut case = 0usize;
                for c in 0..8 {
                    let inside = mask.get(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1));
                    case |= usize::from(inside) << c;
                }
                for t in &table[case] {
                    tris.push(t.map(|e| {
                        let (c, a) = edges[e as usize];
                        let v = [
                            i + (c & 1) as i64,
                            j + (c >> 1 & 1) as i64,
                            k + (c >> 2 & 1) as i64,
                        ];
                        edge_key(v, a)
                    }));
                }
            };
            for j in -1..ny as i64 {
                // Between merged breaks the four voxel rows of this cell row
                // are constant: there a cell is cut only when the rows
                // differ, and the cells astride a break are always visited.
                breaks.merged(
                    &[(j, k), (j + 1, k), (j, k + 1), (j + 1, k + 1)],
                    &mut merged,
                );
                let Some(&first) = merged.first() else {
                    continue;
                };
                emit(i64::from(first) - 1, j);
                for w in merged.windows(2) {
                    let (a, b) = (i64::from(w[0]), i64::from(w[1]));
                    let inside = [(j, k), (j + 1, k), (j, k + 1), (j + 1, k + 1)]
                        .map(|(y, z)| mask.get(a, y, z));
                    if inside.iter().any(|&v| v != inside[0]) {
                        (a..b - 1).for_each(|i| emit(i, j));
                    }
                    emit(b - 1, j);
                }
            }
            tris
        })
        .collect();
    let vertices = RankedSet::new(3 * ex * ey * ez, layers.iter().flatten().flatten().copied());
    let origin = mask.origin().as_dvec3();
    let positions: Vec<DVec3> = vertices
        .keys()
        .map(|key| {
            let a = (key % 3) as usize;
            let v = key / 3;
            let x = (v % ex) as f64 - 1.0;
            let y = ((v / ex) % ey) as f64 - 1.0;
            let z = (v / (ex * ey)) as f64 - 1.0;
            let mut p = DVec3::new(x, y, z) + 0.5;
            p[a] += 0.5;
            origin + p
        })
        .collect();
    let num_tris: usize = layers.iter().map(Vec::len).sum();
    let mut face_vertices = Vec::with_capacity(num_tris * 3);
    for t in layers.iter().flatten() {
        face_vertices.extend(t.iter().map(|&key| vertices.rank(key)));
    }
    let face_offsets = (0..=num_tris)
        .map(|f| u32::try_from(3 * f).expect("too many triangle corners"))
        .collect();
    Mesh::new(positions, face_offsets, face_vertices)
        .expect("a marching-cubes surface is a valid mesh")
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::IVec3;
    use std::collections::BTreeMap;

    /// Every cell of the padded grid, welded through an ordered map.
    fn brute_force(mask: &VoxelMask) -> Mesh {
        let [nx, ny, nz] = mask.dims().map(|n| n as i64);
        let table = case_table();
        let mut tris = Vec::new();
        for k in -1..nz {
            for j in -1..ny {
                for i in -1..nx {
                    let mut case = 0;
                    for c in 0..8 {
                        let v = [i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1)];
                        case |= usize::from(mask.get(v[0], v[1], v[2])) << c;
                    }
                    for t in &table[case] {
                        tris.push(t.map(|e| {
                            let (c, a) = edge_start(e as usize);
                            let v = [
                                i + (c & 1) as i64,
                                j + (c >> 1 & 1) as i64,
                                k + (c >> 2 & 1) as i64,
                            ];
                            (v[2], v[1], v[0], a)
                        }));
                    }
                }
            }
        }
        let mut ids = BTreeMap::new();
        for t in &tris {
            for &e in t {
                ids.insert(e, 0u32);
            }
        }
        for (n, id) in ids.values_mut().enumerate() {
            *id = n as u32;
        }
        let positions = ids
            .keys()
            .map(|&(z, y, x, a)| {
                let mut p = mask.voxel_center(x, y, z);
                p[a] += 0.5;
                p
            })
            .collect();
        let faces: Vec<[u32; 3]> = tris.iter().map(|t| t.map(|e| ids[&e])).collect();
        Mesh::from_polygons(positions, &faces).unwrap()
    }

    #[test]
    fn fast_scan_matches_brute_force() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut rand = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for dims in [[9, 7, 6], [1, 5, 3], [13, 2, 11], [17, 15, 12]] {
            for density in [0.15, 0.5, 0.85, 1.0] {
                let bits: Vec<bool> = (0..dims[0] * dims[1] * dims[2])
                    .map(|_| rand() < density)
                    .collect();
                let mask = VoxelMask::from_fn(IVec3::new(2, -5, 1), dims, |i, j, k| {
                    bits[(k * dims[1] + j) * dims[0] + i]
                });
                assert_eq!(marching_cubes_mesh(&mask), brute_force(&mask));
            }
        }
    }

    #[test]
    fn table_has_classic_case_sizes() {
        let t = case_table();
        assert!(t[0].is_empty() && t[255].is_empty());
        // One corner: a triangle; two adjacent corners: a quad.
        assert_eq!(t[1].len(), 1);
        assert_eq!(t[0b11].len(), 2);
        // Two corners diagonal on a face (ambiguous): kept apart.
        assert_eq!(t[0b1001].len(), 2);
        // Four corners of a face: a quad.
        assert_eq!(t[0b1111].len(), 2);
        // The triangles use exactly the edges whose ends differ.
        for (case, tris) in t.iter().enumerate() {
            let used: u32 = tris.iter().flatten().fold(0, |m, &e| m | 1 << e);
            let cut = (0..NUM_EDGES).fold(0u32, |m, e| {
                let (c, a) = edge_start(e);
                let differs = (case >> c & 1) != (case >> (c | 1 << a) & 1);
                m | u32::from(differs) << e
            });
            assert_eq!(used, cut, "case {case}");
        }
    }
}
