//! Welding: joining vertices that share a position.
//!
//! Many files are not welded: glTF exporters split vertices along UV and
//! normal seams, and STL stores three fresh vertices per triangle. The
//! smoother needs the shared topology, so [`weld`] maps every vertex to one
//! representative per position and rewrites the faces. The map lets a
//! writer give every original vertex its representative's new position, so
//! seams stay closed and the output keeps the input's vertex count and
//! order.
//!
//! Exact welding joins vertices whose coordinates are equal (`-0.0` equals
//! `0.0`). With a tolerance, a vertex joins the earliest representative
//! within `tolerance x bounding-box diagonal` of it, searched in a hashed
//! grid of that cell size; the result depends only on the vertex order.
//! Both are linear in the vertex count (expected). Vertices of different
//! groups (for glTF: different meshes, which live in their own spaces)
//! are never joined.

use super::IoError;
use crate::mesh::{Mesh, bounding_box};
use glam::DVec3;
use std::collections::HashMap;
use std::hash::{BuildHasher, Hasher, RandomState};

/// Smallest relative tolerance treated as a tolerance; anything below it
/// welds exactly (it keeps grid cell coordinates well inside `i64`).
const MIN_RELATIVE_TOLERANCE: f64 = 1e-12;

/// Hash maps keyed by coordinates: a folded-multiply hash (as in
/// `ahash`'s fallback), several times faster than SipHash on these keys,
/// seeded per map from [`RandomState`] so crafted inputs cannot aim at
/// collisions.
pub(crate) type FastMap<K, V> = HashMap<K, V, FastState>;

/// Builds [`FastHash`] hashers with one random seed.
#[derive(Clone)]
pub(crate) struct FastState {
    seed: u64,
}

impl FastState {
    /// A state with a fresh random seed.
    pub(crate) fn new() -> Self {
        FastState {
            seed: RandomState::new().hash_one(0x5eed_u64),
        }
    }
}

impl BuildHasher for FastState {
    type Hasher = FastHash;
    fn build_hasher(&self) -> FastHash {
        FastHash { state: self.seed }
    }
}

/// See [`FastMap`].
pub(crate) struct FastHash {
    state: u64,
}

const MULTIPLE: u64 = 0x5851_f42d_4c95_7f2d;

fn folded_multiply(a: u64, b: u64) -> u64 {
    let r = u128::from(a) * u128::from(b);
    (r as u64) ^ ((r >> 64) as u64)
}

impl Hasher for FastHash {
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            self.write_u64(u64::from_le_bytes(word));
        }
    }

    fn write_u64(&mut self, word: u64) {
        self.state = folded_multiply(self.state ^ word, MULTIPLE);
    }

    fn write_u32(&mut self, word: u32) {
        self.write_u64(u64::from(word));
    }

    fn write_usize(&mut self, word: usize) {
        self.write_u64(word as u64);
    }

    fn write_i64(&mut self, word: i64) {
        self.write_u64(word as u64);
    }

    fn finish(&self) -> u64 {
        folded_multiply(self.state, self.state.rotate_left(23) | 1)
    }
}

/// A welded mesh and how the original vertices map onto it.
#[derive(Debug, Clone, PartialEq)]
pub struct Welded {
    /// The welded mesh: one vertex per representative, in the order of
    /// their first occurrence, each at its first occurrence's position;
    /// faces as in the input with their corners remapped.
    pub mesh: Mesh,
    /// One entry per original vertex: its vertex in [`Welded::mesh`].
    pub vertex_map: Vec<u32>,
}

/// Welds `mesh`: vertices closer than `relative_tolerance` times the
/// bounding-box diagonal (equal positions when it is 0) become one vertex,
/// provided they are in the same group (`groups`: one entry per vertex;
/// `None` puts every vertex in one group).
///
/// Returns `None` when no two vertices are joined (the mesh is already
/// welded). Faces keep their order and arity; a face whose corners were
/// joined keeps the repeated index (counted as degenerate by the topology).
/// A negative or NaN tolerance counts as 0.
pub fn weld(
    mesh: &Mesh,
    relative_tolerance: f64,
    groups: Option<&[u32]>,
) -> Result<Option<Welded>, IoError> {
    let positions = mesh.positions();
    let (vertex_map, representatives) = weld_map(positions, relative_tolerance, groups);
    if representatives.len() == positions.len() {
        return Ok(None);
    }
    let welded_positions = representatives
        .iter()
        .map(|&r| positions.get(r as usize).copied().unwrap_or_default())
        .collect();
    let corners = mesh
        .face_vertices()
        .iter()
        .map(|&c| vertex_map.get(c as usize).copied().unwrap_or(c))
        .collect();
    let mesh = Mesh::new(welded_positions, mesh.face_offsets().to_vec(), corners)?;
    Ok(Some(Welded { mesh, vertex_map }))
}

/// The welding map of `positions`: `(map, representatives)` where
/// `map[i]` is the welded index of vertex `i` and `representatives[k]` the
/// original vertex that welded vertex `k` stands for (its first
/// occurrence). See [`weld`] for the tolerance and the groups.
pub fn weld_map(
    positions: &[DVec3],
    relative_tolerance: f64,
    groups: Option<&[u32]>,
) -> (Vec<u32>, Vec<u32>) {
    let group = |i: usize| groups.and_then(|g| g.get(i)).copied().unwrap_or(0);
    let diagonal = bounding_box(positions).map_or(0.0, |(lo, hi)| (hi - lo).length());
    let tolerance = relative_tolerance * diagonal;
    if relative_tolerance.is_nan()
        || relative_tolerance < MIN_RELATIVE_TOLERANCE
        || !tolerance.is_finite()
        || tolerance <= 0.0
    {
        weld_exact(positions, group)
    } else {
        let origin = bounding_box(positions).map_or(DVec3::ZERO, |(lo, _)| lo);
        weld_within(positions, origin, tolerance, group)
    }
}

fn weld_exact(positions: &[DVec3], group: impl Fn(usize) -> u32) -> (Vec<u32>, Vec<u32>) {
    // Adding 0.0 turns -0.0 into 0.0, so both weld together. Coordinates
    // that all came from f32 (STL, glTF) are keyed by their f32 bits: half
    // the key size, noticeably faster on millions of vertices.
    let all_f32 = positions
        .iter()
        .all(|p| p.to_array().iter().all(|&c| f64::from(c as f32) == c));
    if all_f32 {
        weld_by_key(positions.len(), |i| {
            let p = positions.get(i).copied().unwrap_or_default();
            [
                (p.x as f32 + 0.0).to_bits(),
                (p.y as f32 + 0.0).to_bits(),
                (p.z as f32 + 0.0).to_bits(),
                group(i),
            ]
        })
    } else {
        weld_by_key(positions.len(), |i| {
            let p = positions.get(i).copied().unwrap_or_default();
            [
                (p.x + 0.0).to_bits(),
                (p.y + 0.0).to_bits(),
                (p.z + 0.0).to_bits(),
                u64::from(group(i)),
            ]
        })
    }
}

/// Joins the vertices `0..n` with equal keys.
fn weld_by_key<K: Eq + std::hash::Hash>(
    n: usize,
    key: impl Fn(usize) -> K,
) -> (Vec<u32>, Vec<u32>) {
    let mut map = Vec::with_capacity(n);
    let mut representatives = Vec::new();
    // Unwelded files (STL) have about six times as many vertices as welded
    // ones: start smaller and let the map grow.
    let mut seen: FastMap<K, u32> = FastMap::with_capacity_and_hasher(n / 4, FastState::new());
    for i in 0..n {
        let next = representatives.len() as u32;
        let k = *seen.entry(key(i)).or_insert(next);
        if k == next {
            representatives.push(i as u32);
        }
        map.push(k);
    }
    (map, representatives)
}

fn weld_within(
    positions: &[DVec3],
    origin: DVec3,
    tolerance: f64,
    group: impl Fn(usize) -> u32,
) -> (Vec<u32>, Vec<u32>) {
    let mut map = Vec::with_capacity(positions.len());
    let mut representatives: Vec<u32> = Vec::new();
    // Cell -> welded vertices whose representative lies in it, in creation
    // order.
    let mut grid: FastMap<[i64; 4], Vec<u32>> = FastMap::with_hasher(FastState::new());
    let cell_of = |p: DVec3, g: u32| {
        let c = ((p - origin) / tolerance).floor();
        [c.x as i64, c.y as i64, c.z as i64, i64::from(g)]
    };
    let squared = tolerance * tolerance;
    for (i, &p) in positions.iter().enumerate() {
        let cell = cell_of(p, group(i));
        let mut best: Option<u32> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let key = [cell[0] + dx, cell[1] + dy, cell[2] + dz, cell[3]];
                    let Some(candidates) = grid.get(&key) else {
                        continue;
                    };
                    for &k in candidates {
                        let q = representatives
                            .get(k as usize)
                            .and_then(|&r| positions.get(r as usize));
                        if q.is_some_and(|q| q.distance_squared(p) <= squared)
                            && best.is_none_or(|b| k < b)
                        {
                            best = Some(k);
                        }
                    }
                }
            }
        }
        let k = match best {
            Some(k) => k,
            None => {
                let k = representatives.len() as u32;
                representatives.push(i as u32);
                grid.entry(cell).or_default().push(k);
                k
            }
        };
        map.push(k);
    }
    (map, representatives)
}

/// Gives every original vertex the value of its welded vertex:
/// `out[i] = values[map[i]]`. Entries of `map` beyond `values` get the
/// default value (never the case for a map made by [`weld`]).
pub fn expand<T: Copy + Default>(values: &[T], map: &[u32]) -> Vec<T> {
    map.iter()
        .map(|&k| values.get(k as usize).copied().unwrap_or_default())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn split_square() -> Mesh {
        // Two triangles of a unit square that share no vertex index.
        let p = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(-0.0, 0.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ];
        Mesh::from_polygons(p.to_vec(), &[[0u32, 1, 2], [3, 4, 5]]).unwrap()
    }

    #[test]
    fn exact_weld_joins_equal_positions_including_signed_zero() {
        let w = weld(&split_square(), 0.0, None).unwrap().unwrap();
        assert_eq!(w.vertex_map, vec![0, 1, 2, 0, 2, 3]);
        assert_eq!(w.mesh.num_vertices(), 4);
        assert_eq!(w.mesh.face(1), &[0, 2, 3]);
        assert_eq!(w.mesh.positions()[3], DVec3::new(0.0, 1.0, 0.0));
        let expanded = expand(w.mesh.positions(), &w.vertex_map);
        for (a, b) in expanded.iter().zip(split_square().positions()) {
            assert_eq!(a, b);
        }
    }

    #[test]
    fn an_already_welded_mesh_gives_none() {
        let w = weld(&split_square(), 0.0, None).unwrap().unwrap();
        assert!(weld(&w.mesh, 0.0, None).unwrap().is_none());
        assert!(weld(&w.mesh, 1e-3, None).unwrap().is_none());
    }

    #[test]
    fn tolerance_is_relative_to_the_diagonal() {
        let mut p = split_square().positions().to_vec();
        p[3] = DVec3::new(1e-4, 0.0, 0.0); // diagonal is sqrt(2)
        p[4] = DVec3::new(1.0, 1.0 + 3e-4, 0.0);
        let m = Mesh::from_polygons(p, &[[0u32, 1, 2], [3, 4, 5]]).unwrap();
        assert!(weld(&m, 0.0, None).unwrap().is_none());
        let (map, _) = weld_map(m.positions(), 1e-4, None);
        assert_eq!(map, vec![0, 1, 2, 0, 3, 4], "only the 1e-4 offset welds");
        let (map, reps) = weld_map(m.positions(), 1e-3, None);
        assert_eq!(map, vec![0, 1, 2, 0, 2, 3]);
        assert_eq!(reps, vec![0, 1, 2, 5]);
    }

    #[test]
    fn tolerance_weld_picks_the_earliest_representative() {
        // 0 and 1 are 0.6 tol apart, 2 is within tol of both: it joins 0.
        let p = vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.5, 0.0, 0.0),
            DVec3::new(0.8, 0.0, 0.0),
            DVec3::new(100.0, 0.0, 0.0),
        ];
        let (map, reps) = weld_map(&p, 0.01, None); // tol = 1.0
        assert_eq!(map, vec![0, 1, 0, 2]);
        assert_eq!(reps, vec![0, 1, 3]);
    }

    #[test]
    fn nan_or_negative_tolerance_is_exact() {
        let m = split_square();
        for t in [f64::NAN, -1.0, 1e-15] {
            let (map, _) = weld_map(m.positions(), t, None);
            assert_eq!(map, vec![0, 1, 2, 0, 2, 3]);
        }
    }

    #[test]
    fn groups_are_never_joined() {
        let m = split_square();
        let groups = [0, 0, 0, 1, 1, 1];
        for t in [0.0, 1e-3] {
            let (map, _) = weld_map(m.positions(), t, Some(&groups));
            assert_eq!(map, vec![0, 1, 2, 3, 4, 5], "tolerance {t}");
        }
        let groups = [0, 0, 1, 0, 1, 1];
        let (map, _) = weld_map(m.positions(), 0.0, Some(&groups));
        assert_eq!(map, vec![0, 1, 2, 0, 2, 3]);
    }
}
