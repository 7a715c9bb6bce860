//! Connectivity of a [`Mesh`] in flat CSR arrays: vertex→vertex,
//! vertex→face and edge→face, plus boundary and non-manifold flags.
//!
//! Built once per mesh in `O(corners)` time (bucketing edges by their
//! smaller end point, no global sort); connectivity never changes afterwards.

use super::Mesh;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::OnceLock;

/// How a vertex sits in the surface.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum VertexKind {
    /// Every incident edge has exactly two faces and the faces form one fan.
    Interior,
    /// At least one incident edge has a single face (an open surface's rim).
    Boundary,
    /// An incident edge has more than two faces, or the incident faces form
    /// several fans joined only at this vertex (a pinch).
    NonManifold,
    /// No face uses the vertex.
    Isolated,
}

/// Entries of a [`Topology::neighbor_block`].
pub(crate) const NEIGHBOR_BLOCK: usize = 6;

/// Vertex→vertex, vertex→face and edge→face adjacency of a mesh.
#[derive(Debug, Clone)]
pub struct Topology {
    vv_offsets: Vec<u32>,
    /// Neighbour lists, followed by `NEIGHBOR_BLOCK` zeros so a block
    /// read from any list's start stays inside ([`Topology::neighbor_block`]).
    vv: Vec<u32>,
    /// `edges[edge_offsets[v]..edge_offsets[v + 1]]` are the edges whose
    /// smaller end is `v` (sorted by the larger end).
    edge_offsets: Vec<u32>,
    vf_offsets: Vec<u32>,
    vf: Vec<u32>,
    /// Unique undirected edges, `[lo, hi]` with `lo < hi`.
    edges: Vec<[u32; 2]>,
    ef_offsets: Vec<u32>,
    ef: Vec<u32>,
    kinds: Vec<VertexKind>,
    degenerate_faces: usize,
    /// [`Topology::component_ids`], found once on first use: the analysis,
    /// every stage's measures, the volume restoration and the passes all
    /// ask, and each would otherwise walk a union-find over every edge.
    components: OnceLock<(Vec<u32>, usize)>,
}

impl Topology {
    /// Builds the adjacency of `mesh`. Face sides joining a vertex to itself
    /// (a repeated index) are not edges; such faces count as degenerate.
    ///
    /// The edges are sorted and gathered in parallel, a chunk of vertices
    /// at a time and joined in order, beside the vertex -> face lists: the
    /// result does not depend on the thread count.
    pub fn build(mesh: &Mesh) -> Topology {
        // The vertices' face lists need no edges: built beside them.
        let (mut topo, (vf_offsets, vf)) =
            rayon::join(|| Topology::edges_of(mesh), || vertex_face_lists(mesh));
        (topo.vf_offsets, topo.vf) = (vf_offsets, vf);
        topo.kinds = (0..mesh.num_vertices())
            .into_par_iter()
            .with_min_len(CHUNK)
            .map(|v| topo.classify(mesh, v))
            .collect();
        topo
    }

    fn classify(&self, mesh: &Mesh, v: usize) -> VertexKind {
        let faces = self.vertex_faces(v);
        if faces.is_empty() {
            return VertexKind::Isolated;
        }
        let mut boundary = false;
        for e in self.vertex_edges(v) {
            match self.edge_faces(e).len() {
                1 => boundary = true,
                2 => {}
                _ => return VertexKind::NonManifold,
            }
        }
        // Count fans: faces around v joined through shared edges at v.
        // Union-find over the (few) incident faces, on the stack when small.
        let mut parent_small = [0u16; 32];
        let mut parent_big = Vec::new();
        let parent: &mut [u16] = if faces.len() <= 32 {
            &mut parent_small[..faces.len()]
        } else if faces.len() <= u16::MAX as usize {
            parent_big.resize(faces.len(), 0);
            &mut parent_big[..]
        } else {
            return VertexKind::NonManifold;
        };
        for (i, p) in parent.iter_mut().enumerate() {
            *p = i as u16;
        }
        fn find(p: &mut [u16], mut i: usize) -> usize {
            while p[i] as usize != i {
                p[i] = p[p[i] as usize];
                i = p[i] as usize;
            }
            i
        }
        let mut components = faces.len();
        for e in self.vertex_edges(v) {
            let ef = self.edge_faces(e);
            if ef.len() == 2 {
                let a = faces.iter().position(|&f| f == ef[0]);
                let b = faces.iter().position(|&f| f == ef[1]);
                if let (Some(a), Some(b)) = (a, b) {
                    let (ra, rb) = (find(parent, a), find(parent, b));
                    if ra != rb {
                        parent[ra] = rb as u16;
                        components -= 1;
                    }
                }
            }
        }
        let _ = mesh;
        if components > 1 {
            VertexKind::NonManifold
        } else if boundary {
            VertexKind::Boundary
        } else {
            VertexKind::Interior
        }
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.kinds.len()
    }

    /// Neighbours of vertex `v` (one entry per edge), ascending.
    #[inline]
    pub fn neighbors(&self, v: usize) -> &[u32] {
        &self.vv[self.vv_offsets[v] as usize..self.vv_offsets[v + 1] as usize]
    }

    /// Vertex `v`'s neighbours as the first `n` entries of a block of 6
    /// (the rest belong to other vertices or are padding), or `None` when
    /// it has more: a loop over a whole block has a fixed trip count, where
    /// a loop over a short list of varying length mispredicts its exit.
    #[inline]
    pub(crate) fn neighbor_block(&self, v: usize) -> Option<(&[u32; NEIGHBOR_BLOCK], usize)> {
        let (a, b) = (self.vv_offsets[v] as usize, self.vv_offsets[v + 1] as usize);
        let block = self.vv.get(a..a + NEIGHBOR_BLOCK)?.try_into().ok()?;
        (b - a <= NEIGHBOR_BLOCK).then_some((block, b - a))
    }

    /// Edge ids of vertex `v`'s edges, in the order of
    /// [`Topology::neighbors`].
    #[inline]
    pub fn vertex_edges(&self, v: usize) -> impl Iterator<Item = usize> + '_ {
        self.neighbors(v)
            .iter()
            .filter_map(move |&u| self.edge(v, u as usize))
    }

    /// The id of the edge joining `a` and `b`, if there is one: a binary
    /// search among the few edges of the smaller end (no per-entry edge
    /// ids stored: 4 bytes an edge end saved).
    #[inline]
    pub fn edge(&self, a: usize, b: usize) -> Option<usize> {
        let (lo, hi) = (a.min(b), a.max(b) as u32);
        let start = *self.edge_offsets.get(lo)? as usize;
        let end = *self.edge_offsets.get(lo + 1)? as usize;
        let i = self.edges[start..end]
            .binary_search_by_key(&hi, |e| e[1])
            .ok()?;
        Some(start + i)
    }

    /// Faces using vertex `v`, each once, ascending.
    #[inline]
    pub fn vertex_faces(&self, v: usize) -> &[u32] {
        &self.vf[self.vf_offsets[v] as usize..self.vf_offsets[v + 1] as usize]
    }

    /// All unique undirected edges, `[lo, hi]` with `lo < hi`.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }

    /// Faces sharing edge `e`, each once, ascending.
    #[inline]
    pub fn edge_faces(&self, e: usize) -> &[u32] {
        &self.ef[self.ef_offsets[e] as usize..self.ef_offsets[e + 1] as usize]
    }

    /// Kind of vertex `v`.
    #[inline]
    pub fn kind(&self, v: usize) -> VertexKind {
        self.kinds[v]
    }

    /// Kinds of all vertices, one entry per vertex.
    pub fn kinds(&self) -> &[VertexKind] {
        &self.kinds
    }

    /// The number of `mesh`'s edges with one face, as
    /// [`Topology::num_boundary_edges`] counts them, without the rest of the
    /// topology (the vertices' face lists and kinds): all a check on a
    /// weld's open edges needs.
    pub fn count_boundary_edges(mesh: &Mesh) -> usize {
        Topology::edges_of(mesh).num_boundary_edges()
    }

    /// Edges with exactly one face.
    pub fn num_boundary_edges(&self) -> usize {
        (0..self.edges.len())
            .filter(|&e| self.edge_faces(e).len() == 1)
            .count()
    }

    /// Edges with more than two faces.
    pub fn num_non_manifold_edges(&self) -> usize {
        (0..self.edges.len())
            .filter(|&e| self.edge_faces(e).len() > 2)
            .count()
    }

    /// Largest number of faces sharing one edge (0 without edges).
    pub fn max_faces_per_edge(&self) -> usize {
        (0..self.edges.len())
            .map(|e| self.edge_faces(e).len())
            .max()
            .unwrap_or(0)
    }

    /// Faces with a repeated corner index.
    pub fn num_degenerate_faces(&self) -> usize {
        self.degenerate_faces
    }

    /// Number of vertices of the given kind.
    pub fn count_kind(&self, kind: VertexKind) -> usize {
        self.kinds.iter().filter(|&&k| k == kind).count()
    }

    /// Connected components of the vertex graph, not counting isolated
    /// vertices.
    pub fn num_components(&self) -> usize {
        self.component_ids().1 - self.count_kind(VertexKind::Isolated)
    }

    /// For each vertex, the number of vertices of its connected component
    /// (1 for an isolated vertex).
    pub fn component_sizes(&self) -> Vec<u32> {
        let (ids, count) = self.component_ids();
        let mut size = vec![0u32; count];
        for &c in ids {
            size[c as usize] += 1;
        }
        ids.iter().map(|&c| size[c as usize]).collect()
    }

    /// Each vertex's connected component, numbered from 0 in the order of
    /// the components' lowest vertex, and the number of components
    /// (isolated vertices count as components of their own).
    pub fn component_ids(&self) -> (&[u32], usize) {
        let (ids, count) = self.components.get_or_init(|| {
            let roots = self.component_roots();
            let mut id = vec![u32::MAX; roots.len()];
            let mut count = 0u32;
            for v in 0..roots.len() {
                let r = roots[v] as usize;
                if id[r] == u32::MAX {
                    id[r] = count;
                    count += 1;
                }
                id[v] = id[r];
            }
            (id, count as usize)
        });
        (ids, *count)
    }

    /// Each vertex's component as one root vertex (union-find over the
    /// edges, paths compressed so every entry is its root).
    fn component_roots(&self) -> Vec<u32> {
        fn find(p: &mut [u32], mut i: usize) -> usize {
            while p[i] as usize != i {
                p[i] = p[p[i] as usize];
                i = p[i] as usize;
            }
            i
        }
        let n = self.num_vertices();
        let mut parent: Vec<u32> = (0..n as u32).collect();
        for e in &self.edges {
            let (a, b) = (
                find(&mut parent, e[0] as usize),
                find(&mut parent, e[1] as usize),
            );
            if a != b {
                parent[a] = b as u32;
            }
        }
        for i in 0..n {
            parent[i] = find(&mut parent, i) as u32;
        }
        parent
    }
}

/// True when a face repeats a corner index (a degenerate face; its angles
/// are undefined). Triangles and quads are compared directly, small
/// polygons pair by pair, larger ones sorted (a face of `n` corners costs
/// `n log n`, never `n^2`: the topology is built before a face too large
/// to smooth is refused).
#[inline]
pub(crate) fn has_repeated_corner(face: &[u32]) -> bool {
    match *face {
        [a, b, c] => a == b || a == c || b == c,
        [a, b, c, d] => a == b || a == c || a == d || b == c || b == d || c == d,
        _ if face.len() <= SMALL_POLYGON => {
            face.iter().enumerate().any(|(j, v)| face[..j].contains(v))
        }
        _ => {
            let mut sorted = face.to_vec();
            sorted.sort_unstable();
            sorted.windows(2).any(|w| w[0] == w[1])
        }
    }
}

/// Corners up to which a polygon's repeated corners are found pair by
/// pair: cheaper than sorting a copy, and `n^2` stays small.
const SMALL_POLYGON: usize = 16;

impl Topology {
    /// What [`Topology::build`] derives from the face sides: the unique
    /// edges with their faces, the vertex -> vertex lists and the count of
    /// degenerate faces (no vertex -> face lists or kinds yet).
    fn edges_of(mesh: &Mesh) -> Topology {
        let n = mesh.num_vertices();
        // Half-edges bucketed by their smaller end point (a counting sort:
        // serial, as atomic counters cost more than they share).
        let mut bucket = vec![0u32; n + 1];
        let mut degenerate_faces = 0usize;
        for face in mesh.faces() {
            for (a, b) in sides(face) {
                bucket[a.min(b) as usize + 1] += 1;
            }
            degenerate_faces += usize::from(has_repeated_corner(face));
        }
        prefix_sum(&mut bucket);
        let mut fill = bucket.clone();
        // (larger end, face) packed in one word: sorting a bucket sorts by
        // the larger end, then by face.
        let mut half = vec![0u64; bucket[n] as usize];
        for (f, face) in mesh.faces().enumerate() {
            for (a, b) in sides(face) {
                let slot = &mut fill[a.min(b) as usize];
                half[*slot as usize] = u64::from(a.max(b)) << 32 | f as u64;
                *slot += 1;
            }
        }
        drop(fill);

        // Unique edges with their (deduplicated) faces, in parallel over
        // chunks of smaller end points, joined in order.
        let parts: Vec<EdgePart> = chunk_runs(&mut half, &bucket)
            .into_par_iter()
            .map(|(first, half)| EdgePart::new(first, half, &bucket))
            .collect();
        drop(half);
        let num_edges = parts.iter().map(|p| p.edges.len()).sum();
        let mut edges: Vec<[u32; 2]> = Vec::with_capacity(num_edges);
        let mut ef_offsets = Vec::with_capacity(num_edges + 1);
        let mut ef = Vec::with_capacity(parts.iter().map(|p| p.ef.len()).sum());
        let mut edge_offsets = Vec::with_capacity(n + 1);
        ef_offsets.push(0u32);
        for part in parts {
            let mut at = edges.len() as u32;
            for count in part.edges_per_vertex {
                edge_offsets.push(at);
                at += count;
            }
            let base = ef.len() as u32;
            ef_offsets.extend(part.ef_ends.iter().map(|&e| base + e));
            ef.extend_from_slice(&part.ef);
            edges.extend_from_slice(&part.edges);
        }
        edge_offsets.push(edges.len() as u32);

        // Vertex -> vertex, sorted by neighbour within a vertex
        // because edges are produced in (lo, hi) order.
        let mut vv_offsets = vec![0u32; n + 1];
        for e in &edges {
            vv_offsets[e[0] as usize + 1] += 1;
            vv_offsets[e[1] as usize + 1] += 1;
        }
        prefix_sum(&mut vv_offsets);
        let mut fill = vv_offsets.clone();
        let mut vv = vec![0u32; vv_offsets[n] as usize + NEIGHBOR_BLOCK];
        // Entries where the vertex is `hi` come first (their `lo` is smaller).
        for e in &edges {
            let s = &mut fill[e[1] as usize];
            vv[*s as usize] = e[0];
            *s += 1;
        }
        for e in &edges {
            let s = &mut fill[e[0] as usize];
            vv[*s as usize] = e[1];
            *s += 1;
        }
        Topology {
            vv_offsets,
            vv,
            edge_offsets,
            vf_offsets: Vec::new(),
            vf: Vec::new(),
            edges,
            ef_offsets,
            ef,
            kinds: Vec::new(),
            degenerate_faces,
            components: OnceLock::new(),
        }
    }
}

/// Vertex -> face lists of `mesh` (offsets, faces): each face once per
/// vertex, in face order.
fn vertex_face_lists(mesh: &Mesh) -> (Vec<u32>, Vec<u32>) {
    let n = mesh.num_vertices();
    // A corner repeated in a small face is found by scanning the corners
    // before it; in a larger one by the last face its vertex was seen in
    // (faces are visited in order), so no face costs the square of its
    // size.
    let mut last_face = Vec::new();
    let mut vf_offsets = vec![0u32; n + 1];
    for (f, face) in mesh.faces().enumerate() {
        if face.len() <= SMALL_POLYGON {
            for (j, &v) in face.iter().enumerate() {
                if !face[..j].contains(&v) {
                    vf_offsets[v as usize + 1] += 1;
                }
            }
        } else {
            if last_face.is_empty() {
                last_face = vec![u32::MAX; n];
            }
            for &v in face {
                if last_face[v as usize] != f as u32 {
                    last_face[v as usize] = f as u32;
                    vf_offsets[v as usize + 1] += 1;
                }
            }
        }
    }
    prefix_sum(&mut vf_offsets);
    let mut fill = vf_offsets.clone();
    let mut vf = vec![0u32; vf_offsets[n] as usize];
    for (f, face) in mesh.faces().enumerate() {
        for &v in face {
            let s = &mut fill[v as usize];
            // Faces are filled in order: the vertex's list already ends
            // with this face when the corner repeats.
            let repeated = *s > vf_offsets[v as usize] && vf[*s as usize - 1] == f as u32;
            if !repeated {
                vf[*s as usize] = f as u32;
                *s += 1;
            }
        }
    }
    (vf_offsets, vf)
}

/// Vertices per parallel work item of the build.
const CHUNK: usize = 4096;

/// The sides `(a, b)` of `face` that join two different vertices.
#[inline]
fn sides(face: &[u32]) -> impl Iterator<Item = (u32, u32)> + '_ {
    let k = face.len();
    (0..k)
        .map(move |j| (face[j], face[(j + 1) % k]))
        .filter(|(a, b)| a != b)
}

fn prefix_sum(a: &mut [u32]) {
    for i in 1..a.len() {
        a[i] += a[i - 1];
    }
}

/// `values` split into the runs of [`CHUNK`] consecutive vertices (run
/// `v` is `offsets[v]..offsets[v + 1]`), each with its first vertex.
fn chunk_runs<'a, T>(mut values: &'a mut [T], offsets: &[u32]) -> Vec<(usize, &'a mut [T])> {
    let n = offsets.len() - 1;
    let mut chunks = Vec::with_capacity(n.div_ceil(CHUNK));
    for first in (0..n).step_by(CHUNK) {
        let end = (first + CHUNK).min(n);
        let len = (offsets[end] - offsets[first]) as usize;
        let (chunk, rest) = std::mem::take(&mut values).split_at_mut(len);
        chunks.push((first, chunk));
        values = rest;
    }
    chunks
}

/// The edges whose smaller end lies in one chunk of vertices, with their
/// faces ([`Topology::build`]).
struct EdgePart {
    edges: Vec<[u32; 2]>,
    /// End of each edge's faces in `ef`.
    ef_ends: Vec<u32>,
    ef: Vec<u32>,
    /// Edges of each vertex of the chunk (as the smaller end).
    edges_per_vertex: Vec<u32>,
}

impl EdgePart {
    /// From the half-edges `half` (packed larger end and face) of the
    /// chunk starting at vertex `first`, bucketed by `bucket`.
    fn new(first: usize, half: &mut [u64], bucket: &[u32]) -> EdgePart {
        let end = (first + CHUNK).min(bucket.len() - 1);
        let base = bucket[first];
        let mut part = EdgePart {
            edges: Vec::with_capacity(half.len() / 2 + 1),
            ef_ends: Vec::with_capacity(half.len() / 2 + 1),
            ef: Vec::with_capacity(half.len()),
            edges_per_vertex: Vec::with_capacity(end - first),
        };
        for lo in first..end {
            let b = &mut half[(bucket[lo] - base) as usize..(bucket[lo + 1] - base) as usize];
            b.sort_unstable();
            let before = part.edges.len();
            let mut i = 0;
            while i < b.len() {
                let hi = (b[i] >> 32) as u32;
                let mut last_face = u32::MAX;
                while i < b.len() && (b[i] >> 32) as u32 == hi {
                    let face = b[i] as u32;
                    if face != last_face {
                        part.ef.push(face);
                        last_face = face;
                    }
                    i += 1;
                }
                part.edges.push([lo as u32, hi]);
                part.ef_ends.push(part.ef.len() as u32);
            }
            part.edges_per_vertex
                .push((part.edges.len() - before) as u32);
        }
        part
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use glam::DVec3;

    /// A closed unit cube of six quads, wound outward.
    pub(crate) fn unit_cube() -> Mesh {
        let p = (0..8)
            .map(|i| DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64))
            .collect();
        let faces = [
            [0u32, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        Mesh::from_polygons(p, &faces).unwrap()
    }

    /// An `n` x `n` grid of unit quads in the plane z = 0, an open surface.
    pub(crate) fn grid(n: u32) -> Mesh {
        let mut p = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                p.push(DVec3::new(i as f64, j as f64, 0.0));
            }
        }
        let mut f = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let a = j * (n + 1) + i;
                f.push([a, a + 1, a + n + 2, a + n + 1]);
            }
        }
        Mesh::from_polygons(p, &f).unwrap()
    }

    #[test]
    fn neighbor_blocks_start_with_the_neighbours() {
        // A fan of 9 triangles: the hub has 9 neighbours (no block), the
        // rim vertices 3; the last rim vertex's block runs into the padding.
        let mut p = vec![DVec3::ZERO];
        let mut f = Vec::new();
        for i in 0..9u32 {
            let a = i as f64 * std::f64::consts::TAU / 9.0;
            p.push(DVec3::new(a.cos(), a.sin(), 0.0));
            f.push([0, i + 1, (i + 1) % 9 + 1]);
        }
        let m = Mesh::from_polygons(p, &f).unwrap();
        let t = Topology::build(&m);
        assert!(t.neighbor_block(0).is_none());
        for v in 1..10 {
            let (block, n) = t.neighbor_block(v).unwrap();
            assert_eq!(&block[..n], t.neighbors(v), "vertex {v}");
        }
    }

    #[test]
    fn a_large_polygon_repeating_a_corner_lists_each_face_once() {
        // A 40-gon round a circle whose corner 0 comes back halfway, and a
        // triangle on two of its corners: past `SMALL_POLYGON` corners the
        // repeats are found without scanning the face.
        let n = 40u32;
        let p: Vec<DVec3> = (0..n)
            .map(|i| {
                let a = i as f64 * std::f64::consts::TAU / n as f64;
                DVec3::new(a.cos(), a.sin(), 0.0)
            })
            .chain([DVec3::Z])
            .collect();
        let mut big: Vec<u32> = (0..n).collect();
        big[20] = 0;
        let m = Mesh::from_polygons(p, &[big.clone(), vec![1, 0, n]]).unwrap();
        let t = Topology::build(&m);
        assert_eq!(t.num_degenerate_faces(), 1);
        assert!(has_repeated_corner(&big));
        big[20] = 20;
        assert!(!has_repeated_corner(&big));
        assert_eq!(t.vertex_faces(0), &[0, 1]);
        assert_eq!(t.vertex_faces(1), &[0, 1]);
        assert_eq!(t.vertex_faces(20), &[] as &[u32]);
        assert_eq!(t.vertex_faces(2), &[0]);
    }

    #[test]
    fn grid_adjacency() {
        let m = grid(3);
        let t = Topology::build(&m);
        assert_eq!(t.edges().len(), 24);
        assert_eq!(t.neighbors(5), &[1, 4, 6, 9]);
        assert_eq!(t.vertex_faces(5), &[0, 1, 3, 4]);
        assert_eq!(t.kind(5), VertexKind::Interior);
        assert_eq!(t.kind(0), VertexKind::Boundary);
        assert_eq!(t.num_boundary_edges(), 12);
        assert_eq!(t.num_components(), 1);
    }

    #[test]
    fn edge_ids_are_found_from_either_end() {
        let m = grid(4);
        let t = Topology::build(&m);
        for (e, &[lo, hi]) in t.edges().iter().enumerate() {
            assert_eq!(t.edge(lo as usize, hi as usize), Some(e));
            assert_eq!(t.edge(hi as usize, lo as usize), Some(e));
        }
        for v in 0..m.num_vertices() {
            let ids: Vec<usize> = t.vertex_edges(v).collect();
            assert_eq!(ids.len(), t.neighbors(v).len());
            for (&u, e) in t.neighbors(v).iter().zip(ids) {
                let [a, b] = t.edges()[e];
                assert!((a, b) == (v as u32, u) || (a, b) == (u, v as u32));
            }
        }
        // Diagonal corners of a quad share no edge; a vertex none with itself.
        assert_eq!(t.edge(0, 6), None);
        assert_eq!(t.edge(3, 3), None);
    }

    #[test]
    fn non_manifold_edge_and_pinch_and_isolated() {
        // Three triangles on edge 0-1 (a fin), plus an isolated vertex 5.
        let p = vec![DVec3::ZERO; 6];
        let m = Mesh::from_polygons(p, &[[0u32, 1, 2], [1, 0, 3], [0, 1, 4]]).unwrap();
        let t = Topology::build(&m);
        assert_eq!(t.num_non_manifold_edges(), 1);
        assert_eq!(t.max_faces_per_edge(), 3);
        assert_eq!(t.kind(0), VertexKind::NonManifold);
        assert_eq!(t.kind(2), VertexKind::Boundary);
        assert_eq!(t.kind(5), VertexKind::Isolated);
        // Two triangles sharing only vertex 0: a pinch.
        let p = vec![DVec3::ZERO; 5];
        let m = Mesh::from_polygons(p, &[[0u32, 1, 2], [0, 3, 4]]).unwrap();
        let t = Topology::build(&m);
        assert_eq!(t.kind(0), VertexKind::NonManifold);
        assert_eq!(t.num_components(), 1);
    }

    #[test]
    fn parallel_build_matches_a_plain_reference_on_a_scrambled_mesh() {
        use std::collections::{BTreeMap, BTreeSet};
        // Random faces of 3 to 5 corners over more vertices and faces than
        // one chunk: non-manifold edges, repeated corners, isolated
        // vertices and all.
        let n = 3 * CHUNK as u32 + 17;
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = |m: u32| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state % u64::from(m)) as u32
        };
        let faces: Vec<Vec<u32>> = (0..5 * CHUNK)
            .map(|_| {
                let k = 3 + next(3);
                let base = next(n - 40);
                (0..k).map(|_| base + next(40)).collect()
            })
            .collect();
        let m = Mesh::from_polygons(vec![DVec3::ZERO; n as usize], &faces).unwrap();
        let t = Topology::build(&m);

        let mut edge_faces: BTreeMap<(u32, u32), BTreeSet<u32>> = BTreeMap::new();
        let mut vertex_faces = vec![BTreeSet::new(); n as usize];
        let mut degenerate = 0;
        for (f, face) in faces.iter().enumerate() {
            degenerate += usize::from(has_repeated_corner(face));
            for j in 0..face.len() {
                let (a, b) = (face[j], face[(j + 1) % face.len()]);
                vertex_faces[a as usize].insert(f as u32);
                if a != b {
                    edge_faces
                        .entry((a.min(b), a.max(b)))
                        .or_default()
                        .insert(f as u32);
                }
            }
        }
        assert_eq!(t.num_degenerate_faces(), degenerate);
        let edges: Vec<[u32; 2]> = edge_faces.keys().map(|&(a, b)| [a, b]).collect();
        assert_eq!(t.edges(), &edges[..]);
        for (e, faces) in edge_faces.values().enumerate() {
            assert_eq!(
                t.edge_faces(e),
                &faces.iter().copied().collect::<Vec<_>>()[..]
            );
        }
        let mut neighbours = vec![BTreeSet::new(); n as usize];
        for (e, &[a, b]) in edges.iter().enumerate() {
            neighbours[a as usize].insert(b);
            neighbours[b as usize].insert(a);
            assert_eq!(t.edge(b as usize, a as usize), Some(e));
        }
        for v in 0..n as usize {
            let nb: Vec<u32> = neighbours[v].iter().copied().collect();
            assert_eq!(t.neighbors(v), &nb[..], "vertex {v}");
            let vf: Vec<u32> = vertex_faces[v].iter().copied().collect();
            assert_eq!(t.vertex_faces(v), &vf[..], "vertex {v}");
        }
        assert!(t.kinds().contains(&VertexKind::Isolated));
        assert!(t.num_non_manifold_edges() > 0);
    }

    #[test]
    fn repeated_index_is_degenerate_not_an_edge() {
        let p = vec![DVec3::ZERO; 3];
        let m = Mesh::from_polygons(p, &[[0u32, 1, 1, 2]]).unwrap();
        let t = Topology::build(&m);
        assert_eq!(t.num_degenerate_faces(), 1);
        assert_eq!(t.edges().len(), 3);
        assert_eq!(t.vertex_faces(1), &[0]);
    }
}
