//! The measures of the quality report (algorithm notes section 9), for one
//! set of positions on a mesh, against the input positions.
//!
//! Runs in parallel over fixed-size chunks of faces, edges and vertices;
//! each chunk's partial sums are combined in chunk order, so the figures do
//! not depend on the number of threads. Angles are binned through their
//! cosines (no `acos` per corner); an angle within `1e-12` (in cosine) of a
//! bin edge counts as equal to it, so the right angles and 45° angles of
//! voxel meshes land in the bins that start at 90° and 45°. The counts
//! below and above thresholds are sums of whole bins (every threshold is a
//! bin edge): "below 15" is `[0, 15)`, "above 120" is `[120, 180]`.

use crate::mesh::{Mesh, Topology, VertexKind, VolumeApexes, vector_area};
use crate::quality::local::{
    corners, cos_between, for_each_split_triangle, has_repeated_corner, is_inverted, is_twisted,
    triangle_cosines,
};
use crate::report::{
    ANGLE_BIN_DEG, ANGLE_BINS, AngleStats, CurvatureVariation, Displacement, MeshStatistics,
    StageMeasures, VolumeMeasure,
};
use glam::DVec3;
use rayon::prelude::*;

/// Items per parallel work chunk; fixed, so the summation order is too.
const CHUNK: usize = 8192;

/// Tolerance, in cosine, under which an angle counts as equal to a bin edge.
const COS_EPS: f64 = 1e-12;

/// Cells of the uniform grid over the cosine range `[-1, 1]` that maps a
/// cosine to its bin with one multiplication and one table look-up.
const GRID: usize = 4096;
/// Marks a grid cell that holds a bin edge: one comparison with that edge
/// decides (cells are far narrower than the bins, so a cell holds at most
/// one edge). The other bits hold the bin of the cell's cosines above the
/// edge; those at or below it fall in the next bin.
const STRADDLE: u8 = 0x80;

/// Cosines of the bin edges, and the grid, computed once per measure.
struct AngleTable {
    /// `cos(5 k deg) + COS_EPS` for `k = 1..ANGLE_BINS` (the inner bin
    /// edges), decreasing.
    edges: [f64; ANGLE_BINS - 1],
    /// Bin of every cosine in grid cell `k`, which covers `[-1 + 2k/GRID,
    /// -1 + 2(k+1)/GRID)`, or `STRADDLE` with the bin of the cell's cosines
    /// above its edge.
    cells: Vec<u8>,
}

impl AngleTable {
    fn new() -> Self {
        let edges: [f64; ANGLE_BINS - 1] =
            std::array::from_fn(|k| ((k + 1) as f64 * ANGLE_BIN_DEG).to_radians().cos() + COS_EPS);
        // A margin well above rounding in the cell index keeps a cosine
        // next to a cell border from taking the neighbour cell's bin.
        let margin = 1e-9;
        let width = 2.0 / GRID as f64;
        let cells = (0..=GRID)
            .map(|k| {
                let lo = -1.0 + k as f64 * width - margin;
                let hi = lo + width + 2.0 * margin;
                let above = edges.iter().filter(|&&e| e >= hi).count() as u8;
                if edges.iter().any(|&e| e >= lo && e < hi) {
                    STRADDLE | above
                } else {
                    above
                }
            })
            .collect();
        AngleTable { edges, cells }
    }

    /// The bin of an angle with cosine `c`: the number of inner edges it
    /// reaches.
    #[inline]
    fn bin(&self, c: f64) -> usize {
        let k = (((c + 1.0) * (GRID as f64 * 0.5)) as usize).min(GRID);
        let cell = self.cells[k];
        let above = usize::from(cell & !STRADDLE);
        if cell & STRADDLE == 0 {
            return above;
        }
        // The edges before `above` lie beyond the cell, those after it
        // below: only edge `above` itself needs comparing.
        above + usize::from(self.edges.get(above).is_some_and(|&e| c <= e))
    }
}

/// Angle counts of one chunk, kept as cosines until the end.
#[derive(Clone)]
struct AngleAcc {
    count: u64,
    max_cos: f64,
    min_cos: f64,
    histogram: [u64; ANGLE_BINS],
}

impl AngleAcc {
    fn new() -> Self {
        AngleAcc {
            count: 0,
            max_cos: f64::NEG_INFINITY,
            min_cos: f64::INFINITY,
            histogram: [0; ANGLE_BINS],
        }
    }

    #[inline]
    fn add(&mut self, t: &AngleTable, c: f64) {
        self.count += 1;
        self.max_cos = self.max_cos.max(c);
        self.min_cos = self.min_cos.min(c);
        self.histogram[t.bin(c)] += 1;
    }

    fn merge(&mut self, o: &AngleAcc) {
        self.count += o.count;
        self.max_cos = self.max_cos.max(o.max_cos);
        self.min_cos = self.min_cos.min(o.min_cos);
        for (a, b) in self.histogram.iter_mut().zip(&o.histogram) {
            *a += b;
        }
    }

    fn finish(&self) -> AngleStats {
        let deg = |c: f64| c.clamp(-1.0, 1.0).acos().to_degrees();
        let some = self.count > 0;
        // Every threshold is a bin edge: count whole bins.
        let below = |d: f64| -> u64 { self.histogram[..(d / ANGLE_BIN_DEG) as usize].iter().sum() };
        let from = |d: f64| -> u64 { self.histogram[(d / ANGLE_BIN_DEG) as usize..].iter().sum() };
        AngleStats {
            count: self.count,
            min_deg: some.then(|| deg(self.max_cos)),
            max_deg: some.then(|| deg(self.min_cos)),
            below_15: below(15.0),
            below_20: below(20.0),
            below_30: below(30.0),
            above_120: from(120.0),
            above_150: from(150.0),
            above_160: from(160.0),
            histogram: self.histogram.to_vec(),
        }
    }
}

/// Per-chunk results of the face pass.
#[derive(Clone)]
struct FaceAcc {
    triangles: AngleAcc,
    corners: AngleAcc,
    twisted: u64,
    inverted: u64,
    side_sum: f64,
    sides: u64,
}

/// Measures `positions` on `mesh` against `input` (the input positions,
/// one per vertex). `curvature` is `(H, K)` per vertex for this stage, if
/// known (it gives the curvature variation). Edges shorter than
/// `short_edge_fraction` times this stage's mean edge length count as
/// short. Faces with a repeated corner are left out of the angle counts.
///
/// Panics if `positions`, `input` or `curvature` do not have one entry per
/// vertex (a caller bug, not a user input).
pub fn measure_stage(
    mesh: &Mesh,
    topo: &Topology,
    positions: &[DVec3],
    input: &[DVec3],
    curvature: Option<&[(f64, f64)]>,
    short_edge_fraction: f64,
) -> StageMeasures {
    let n = mesh.num_vertices();
    assert_eq!(positions.len(), n, "one position per vertex");
    assert_eq!(input.len(), n, "one input position per vertex");
    if let Some(c) = curvature {
        assert_eq!(c.len(), n, "one curvature per vertex");
    }
    let table = AngleTable::new();
    let faces = face_pass(mesh, positions, input, &table);
    let mean_edge_length = if faces.sides > 0 {
        faces.side_sum / faces.sides as f64
    } else {
        0.0
    };
    let threshold = short_edge_fraction * mean_edge_length;
    let (short_edges, boundary_edges) = edge_pass(topo, positions, threshold);
    let displacement = vertex_pass(positions, input);
    let volume = (boundary_edges == 0 && mesh.num_faces() > 0).then(|| {
        // The restoration's measure of the volume (`VolumeApexes`), so
        // that the report and the restoration agree on any surface.
        let apexes = VolumeApexes::new(topo, input);
        let (volume, input_volume) = (apexes.volume(mesh, positions), apexes.volume(mesh, input));
        VolumeMeasure {
            volume,
            relative_change: (input_volume != 0.0)
                .then(|| (volume - input_volume) / input_volume.abs()),
        }
    });
    StageMeasures {
        mean_edge_length,
        curvature_variation: curvature
            .map(|c| CurvatureVariation::new(mean_curvature_variation(topo, c), mean_edge_length)),
        triangle_angles: faces.triangles.finish(),
        polygon_angles: faces.corners.finish(),
        short_edges,
        short_edge_threshold: threshold,
        twisted_quads: faces.twisted,
        inverted_faces: faces.inverted,
        volume,
        displacement,
    }
}

fn face_pass(mesh: &Mesh, positions: &[DVec3], input: &[DVec3], table: &AngleTable) -> FaceAcc {
    let nf = mesh.num_faces();
    let chunks: Vec<FaceAcc> = (0..nf.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut acc = FaceAcc {
                triangles: AngleAcc::new(),
                corners: AngleAcc::new(),
                twisted: 0,
                inverted: 0,
                side_sum: 0.0,
                sides: 0,
            };
            for f in c * CHUNK..((c + 1) * CHUNK).min(nf) {
                let face = mesh.face(f);
                match face.len() {
                    3 if !has_repeated_corner(face) => {
                        measure_triangle(face, positions, input, table, &mut acc)
                    }
                    4 if !has_repeated_corner(face) => {
                        measure_quad(face, positions, input, table, &mut acc)
                    }
                    _ => measure_polygon(face, positions, input, table, &mut acc),
                }
            }
            acc
        })
        .collect();
    let mut total = FaceAcc {
        triangles: AngleAcc::new(),
        corners: AngleAcc::new(),
        twisted: 0,
        inverted: 0,
        side_sum: 0.0,
        sides: 0,
    };
    for c in &chunks {
        total.triangles.merge(&c.triangles);
        total.corners.merge(&c.corners);
        total.twisted += c.twisted;
        total.inverted += c.inverted;
        total.side_sum += c.side_sum;
        total.sides += c.sides;
    }
    total
}

/// Cosine from a dot product and the product of two lengths; 1 (a 0°
/// angle) when the product is zero or the quotient is not a number.
#[inline]
fn cos_ll(dot: f64, ll: f64) -> f64 {
    if ll > 0.0 {
        let c = dot / ll;
        if c.is_nan() { 1.0 } else { c.clamp(-1.0, 1.0) }
    } else {
        1.0
    }
}

/// A triangle with three distinct corners.
#[inline]
fn measure_triangle(
    face: &[u32],
    positions: &[DVec3],
    input: &[DVec3],
    table: &AngleTable,
    acc: &mut FaceAcc,
) {
    let [p0, p1, p2] = corners(face, positions);
    let [q0, q1, q2] = corners(face, input);
    let (e01, e12, e20) = (p1 - p0, p2 - p1, p0 - p2);
    let (l01, l12, l20) = (e01.length(), e12.length(), e20.length());
    acc.side_sum += l01 + l12 + l20;
    acc.sides += 3;
    let n = e01.cross(-e20);
    let m = (q1 - q0).cross(q2 - q0);
    acc.inverted += (n.dot(m) < 0.0) as u64;
    for c in [
        cos_ll(-e01.dot(e20), l01 * l20),
        cos_ll(-e12.dot(e01), l12 * l01),
        cos_ll(-e20.dot(e12), l20 * l12),
    ] {
        acc.triangles.add(table, c);
        acc.corners.add(table, c);
    }
}

/// A quad with four distinct corners: split triangles `(p0 p1 p2)` and
/// `(p0 p2 p3)`, sharing all their side lengths with the corners.
#[inline]
fn measure_quad(
    face: &[u32],
    positions: &[DVec3],
    input: &[DVec3],
    table: &AngleTable,
    acc: &mut FaceAcc,
) {
    let [p0, p1, p2, p3] = corners(face, positions);
    let [q0, q1, q2, q3] = corners(face, input);
    let (e01, e12, e23, e30, d02) = (p1 - p0, p2 - p1, p3 - p2, p0 - p3, p2 - p0);
    let (l01, l12, l23, l30, l02) = (
        e01.length(),
        e12.length(),
        e23.length(),
        e30.length(),
        d02.length(),
    );
    acc.side_sum += l01 + l12 + l23 + l30;
    acc.sides += 4;
    let n1 = e01.cross(d02);
    let n2 = d02.cross(-e30);
    let g02 = q2 - q0;
    let m1 = (q1 - q0).cross(g02);
    let m2 = g02.cross(q3 - q0);
    acc.twisted += (n1.dot(n2) < 0.0) as u64;
    acc.inverted += (n1.dot(m1) < 0.0 || n2.dot(m2) < 0.0 || (n1 + n2).dot(m1 + m2) < 0.0) as u64;
    let at1 = cos_ll(-e01.dot(e12), l01 * l12);
    let at3 = cos_ll(-e23.dot(e30), l23 * l30);
    for c in [
        cos_ll(e01.dot(d02), l01 * l02),
        at1,
        cos_ll(e12.dot(d02), l12 * l02),
        cos_ll(-d02.dot(e30), l02 * l30),
        cos_ll(-d02.dot(e23), l02 * l23),
        at3,
    ] {
        acc.triangles.add(table, c);
    }
    for c in [
        cos_ll(-e01.dot(e30), l01 * l30),
        at1,
        cos_ll(-e12.dot(e23), l12 * l23),
        at3,
    ] {
        acc.corners.add(table, c);
    }
}

/// Any face: polygons, and faces with a repeated corner (left out of the
/// angle counts).
fn measure_polygon(
    face: &[u32],
    positions: &[DVec3],
    input: &[DVec3],
    table: &AngleTable,
    acc: &mut FaceAcc,
) {
    let k = face.len();
    let mut prev = positions[face[k - 1] as usize];
    for j in 0..k {
        let p = positions[face[j] as usize];
        acc.side_sum += p.distance(prev);
        prev = p;
    }
    acc.sides += k as u64;
    acc.twisted += is_twisted(face, positions) as u64;
    acc.inverted += is_inverted(face, positions, input) as u64;
    if has_repeated_corner(face) {
        return;
    }
    for_each_split_triangle(face, positions, |a, b, c| {
        for x in triangle_cosines(a, b, c) {
            acc.triangles.add(table, x);
        }
    });
    for j in 0..k {
        let p = positions[face[j] as usize];
        let a = positions[face[(j + k - 1) % k] as usize];
        let b = positions[face[(j + 1) % k] as usize];
        acc.corners.add(table, cos_between(a - p, b - p));
    }
}

/// Short edges and boundary edges.
fn edge_pass(topo: &Topology, positions: &[DVec3], threshold: f64) -> (u64, u64) {
    let edges = topo.edges();
    let t2 = threshold * threshold;
    (0..edges.len().div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let range = c * CHUNK..((c + 1) * CHUNK).min(edges.len());
            let mut short = 0u64;
            let mut boundary = 0u64;
            for e in range {
                let [a, b] = edges[e];
                short +=
                    (positions[a as usize].distance_squared(positions[b as usize]) < t2) as u64;
                boundary += (topo.edge_faces(e).len() == 1) as u64;
            }
            (short, boundary)
        })
        .reduce(|| (0, 0), |x, y| (x.0 + y.0, x.1 + y.1))
}

/// Displacement statistics.
fn vertex_pass(positions: &[DVec3], input: &[DVec3]) -> Displacement {
    let n = positions.len();
    // (sum d, sum d^2, max d)
    let chunks: Vec<(f64, f64, f64)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut s = (0.0, 0.0, 0.0f64);
            for v in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let d = positions[v].distance(input[v]);
                s.0 += d;
                s.1 += d * d;
                s.2 = s.2.max(d);
            }
            s
        })
        .collect();
    let mut t = (0.0, 0.0, 0.0f64);
    for c in &chunks {
        t.0 += c.0;
        t.1 += c.1;
        t.2 = t.2.max(c.2);
    }
    let nv = n.max(1) as f64;
    Displacement {
        mean: t.0 / nv,
        rms: (t.1 / nv).sqrt(),
        max: t.2,
    }
}

/// How far apart `positions` put the two copies of each vertex of the
/// walls that touching bodies share ([`crate::io::FileBodies`]): `shared`
/// pairs coincident faces of `mesh`, one from each body, and each corner
/// of one at the input position of a corner of the other is a pair of
/// copies; each pair counts once.
pub fn wall_parting(mesh: &Mesh, shared: &[(u32, u32)], positions: &[DVec3]) -> Displacement {
    let input = mesh.positions();
    let mut copies: Vec<(u32, u32)> = shared
        .iter()
        .flat_map(|&(f, g)| {
            let (f, g) = (mesh.face(f as usize), mesh.face(g as usize));
            f.iter().filter_map(move |&a| {
                let b = *g
                    .iter()
                    .find(|&&b| input[b as usize] == input[a as usize])?;
                (a != b).then_some((a.min(b), a.max(b)))
            })
        })
        .collect();
    copies.sort_unstable();
    copies.dedup();
    let (a, b): (Vec<DVec3>, Vec<DVec3>) = copies
        .iter()
        .map(|&(a, b)| (positions[a as usize], positions[b as usize]))
        .unzip();
    vertex_pass(&a, &b)
}

/// The mean curvature variation of a stage whose per-vertex `(H, K)` is
/// `curvature`: over the vertices with neighbours, the mean of the largest
/// `|H_i - H_j|` to a neighbour `j` (what [`measure_stage`] reports, times
/// the stage's mean edge length as well, when given the curvature).
pub fn mean_curvature_variation(topo: &Topology, curvature: &[(f64, f64)]) -> f64 {
    let n = curvature.len();
    // (sum variation, vertices with neighbours), summed in fixed chunks.
    let chunks: Vec<(f64, u64)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut s = (0.0, 0u64);
            for v in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let nb = topo.neighbors(v);
                if !nb.is_empty() {
                    let h = curvature[v].0;
                    s.0 += nb
                        .iter()
                        .map(|&j| (h - curvature[j as usize].0).abs())
                        .fold(0.0, f64::max);
                    s.1 += 1;
                }
            }
            s
        })
        .collect();
    let (sum, count) = chunks
        .iter()
        .fold((0.0, 0u64), |t, c| (t.0 + c.0, t.1 + c.1));
    if count > 0 { sum / count as f64 } else { 0.0 }
}

/// Size and topology figures of `mesh` (whose adjacency is `topo`).
pub fn mesh_statistics(mesh: &Mesh, topo: &Topology) -> MeshStatistics {
    // The components' union-find is serial: it runs beside the rest.
    let (components, (faces, edges)) = rayon::join(
        || topo.num_components() as u64,
        || rayon::join(|| face_counts(mesh), || edge_counts(topo)),
    );
    MeshStatistics {
        vertices: mesh.num_vertices() as u64,
        faces: mesh.num_faces() as u64,
        edges: topo.edges().len() as u64,
        triangles: faces.triangles,
        quads: faces.quads,
        polygons: faces.polygons,
        max_face_arity: faces.max_arity,
        degenerate_faces: faces.degenerate,
        boundary_edges: edges.boundary,
        non_manifold_edges: edges.non_manifold,
        max_faces_per_edge: edges.max_faces,
        boundary_vertices: topo.count_kind(VertexKind::Boundary) as u64,
        non_manifold_vertices: topo.count_kind(VertexKind::NonManifold) as u64,
        isolated_vertices: topo.count_kind(VertexKind::Isolated) as u64,
        components,
        closed: edges.boundary == 0,
        ..MeshStatistics::default()
    }
}

/// Face counts of [`mesh_statistics`].
#[derive(Clone, Copy, Default)]
struct FaceCounts {
    triangles: u64,
    quads: u64,
    polygons: u64,
    max_arity: u64,
    degenerate: u64,
}

fn face_counts(mesh: &Mesh) -> FaceCounts {
    let positions = mesh.positions();
    (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(CHUNK)
        .fold(FaceCounts::default, |mut c, f| {
            let face = mesh.face(f);
            match face.len() {
                3 => c.triangles += 1,
                4 => c.quads += 1,
                _ => c.polygons += 1,
            }
            c.max_arity = c.max_arity.max(face.len() as u64);
            if has_repeated_corner(face) || vector_area(face, positions) == DVec3::ZERO {
                c.degenerate += 1;
            }
            c
        })
        .reduce(FaceCounts::default, |a, b| FaceCounts {
            triangles: a.triangles + b.triangles,
            quads: a.quads + b.quads,
            polygons: a.polygons + b.polygons,
            max_arity: a.max_arity.max(b.max_arity),
            degenerate: a.degenerate + b.degenerate,
        })
}

/// Edge counts of [`mesh_statistics`].
#[derive(Clone, Copy, Default)]
struct EdgeCounts {
    boundary: u64,
    non_manifold: u64,
    max_faces: u64,
}

fn edge_counts(topo: &Topology) -> EdgeCounts {
    (0..topo.edges().len())
        .into_par_iter()
        .with_min_len(CHUNK)
        .fold(EdgeCounts::default, |mut c, e| {
            let faces = topo.edge_faces(e).len() as u64;
            c.boundary += u64::from(faces == 1);
            c.non_manifold += u64::from(faces > 2);
            c.max_faces = c.max_faces.max(faces);
            c
        })
        .reduce(EdgeCounts::default, |a, b| EdgeCounts {
            boundary: a.boundary + b.boundary,
            non_manifold: a.non_manifold + b.non_manifold,
            max_faces: a.max_faces.max(b.max_faces),
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_unit_cube as unit_cube;
    use crate::quality::fixtures::{at, grid, radially_projected_sphere};

    #[test]
    fn cube_angles_volume_and_counts() {
        let m = unit_cube();
        let t = Topology::build(&m);
        let p = m.positions();
        let s = measure_stage(&m, &t, p, p, None, 0.2);
        assert_eq!(s.mean_edge_length, 1.0);
        assert_eq!(s.triangle_angles.count, 36);
        // Each quad splits into two right isosceles triangles.
        assert_eq!(s.triangle_angles.histogram[9], 24, "45° angles in [45, 50)");
        assert_eq!(
            s.triangle_angles.histogram[18], 12,
            "90° angles in [90, 95)"
        );
        assert_eq!(s.triangle_angles.histogram.iter().sum::<u64>(), 36);
        assert!((s.triangle_angles.min_deg.unwrap() - 45.0).abs() < 1e-9);
        assert!((s.triangle_angles.max_deg.unwrap() - 90.0).abs() < 1e-9);
        assert_eq!(s.polygon_angles.count, 24);
        assert_eq!(s.polygon_angles.histogram[18], 24);
        assert_eq!(s.triangle_angles.below_15 + s.triangle_angles.above_120, 0);
        assert_eq!(
            (s.twisted_quads, s.inverted_faces, s.short_edges),
            (0, 0, 0)
        );
        let vol = s.volume.unwrap();
        assert!((vol.volume - 1.0).abs() < 1e-12);
        assert_eq!(vol.relative_change, Some(0.0));
        assert_eq!(s.displacement, Displacement::default());
        assert!(s.curvature_variation.is_none());
    }

    #[test]
    fn mirror_inverts_every_face_and_the_volume() {
        let m = unit_cube();
        let t = Topology::build(&m);
        let mirrored: Vec<DVec3> = m
            .positions()
            .iter()
            .map(|p| DVec3::new(-p.x, p.y, p.z))
            .collect();
        let s = measure_stage(&m, &t, &mirrored, m.positions(), None, 0.2);
        // A mirror in x keeps the normals of the two x faces (reflected and
        // reversed) and turns the other four over.
        assert_eq!(s.inverted_faces, 4);
        let vol = s.volume.unwrap();
        assert!((vol.volume + 1.0).abs() < 1e-12);
        assert!((vol.relative_change.unwrap() + 2.0).abs() < 1e-12);
        // Every vertex with x = 1 moved by 2, the others not at all.
        assert!((s.displacement.max - 2.0).abs() < 1e-12);
        assert!((s.displacement.mean - 1.0).abs() < 1e-12);
        assert!((s.displacement.rms - 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn the_volume_change_of_a_walled_surface_does_not_depend_on_the_origin() {
        // Faces sharing an edge three times enclose no volume independent
        // of the cones' apex: the report must measure it as the
        // restoration does, wherever the file puts the origin.
        let change = |shift: DVec3| {
            let m = crate::mesh::test_walled_sphere(4.0, shift);
            let t = Topology::build(&m);
            let c = m.positions().iter().sum::<DVec3>() / m.num_vertices() as f64;
            let shrunk: Vec<DVec3> = m.positions().iter().map(|&p| c + 0.99 * (p - c)).collect();
            let s = measure_stage(&m, &t, &shrunk, m.positions(), None, 0.2);
            s.volume.unwrap().relative_change.unwrap()
        };
        let (here, there) = (
            change(DVec3::ZERO),
            change(DVec3::new(400.0, -250.0, 120.0)),
        );
        assert!((here - (0.99f64.powi(3) - 1.0)).abs() < 1e-3, "{here}");
        assert!((here - there).abs() < 1e-9, "{here} vs {there}");
    }

    #[test]
    fn twisted_short_and_sharp_counts_on_a_grid() {
        let m = grid(3);
        let t = Topology::build(&m);
        let input = m.positions().to_vec();
        let mut p = input.clone();
        // Vertex (1,1) pulled to within 0.1 of (2,1): one short edge and
        // slivers; vertex (1,2) pushed across (2,2): twisted quads.
        p[at(3, 1, 1)] = DVec3::new(1.9, 1.0, 0.0);
        p[at(3, 1, 2)] = DVec3::new(2.4, 2.0, 0.3);
        let s = measure_stage(&m, &t, &p, &input, None, 0.2);
        assert_eq!(s.short_edges, 1);
        assert!(s.twisted_quads >= 1);
        assert!(s.inverted_faces >= 1);
        assert!(s.triangle_angles.below_15 > 0);
        assert!(s.volume.is_none(), "an open grid has no volume");
    }

    #[test]
    fn curvature_variation_is_the_mean_of_the_largest_neighbour_jump() {
        let m = grid(1); // one quad (0 1 3 2): each vertex has two neighbours
        let t = Topology::build(&m);
        let p = m.positions();
        let hk = [(0.0, 0.0), (1.0, 0.0), (3.0, 0.0), (0.5, 0.0)];
        // Face (0 1 3 2): neighbours 0-1, 1-3, 3-2, 2-0. Largest jumps:
        // 3, 1, 3, 2.5; mean 2.375.
        let s = measure_stage(&m, &t, p, p, Some(&hk), 0.2);
        let cv = s.curvature_variation.unwrap();
        assert!((cv.mean - 2.375).abs() < 1e-12);
        assert!((cv.mean_scaled - 2.375 * s.mean_edge_length).abs() < 1e-12);
    }

    #[test]
    fn bins_match_acos_except_at_the_edges() {
        let t = AngleTable::new();
        let mut c = -1.0f64;
        while c <= 1.0 {
            let deg = c.acos().to_degrees();
            let expected = ((deg / ANGLE_BIN_DEG) as usize).min(ANGLE_BINS - 1);
            let edge_dist = (deg / ANGLE_BIN_DEG - (deg / ANGLE_BIN_DEG).round()).abs();
            if edge_dist > 1e-6 {
                assert_eq!(t.bin(c), expected, "cos {c} = {deg}°");
            }
            c += 1.0 / 4093.0;
        }
        assert_eq!(t.bin(0.0), 18);
        assert_eq!(t.bin(1.0), 0);
        assert_eq!(t.bin(-1.0), ANGLE_BINS - 1);
        assert_eq!(t.bin(45f64.to_radians().cos()), 9);
        // At and next to every edge, the grid gives what a search over all
        // edges gives.
        for &e in &t.edges {
            for d in [0.0, 1e-16, 1e-14, 1e-12, 1e-10, 1e-6] {
                for c in [e - d, e + d, e - COS_EPS - d, e - COS_EPS + d] {
                    let c = c.clamp(-1.0, 1.0);
                    assert_eq!(t.bin(c), t.edges.partition_point(|&e| c <= e), "cos {c}");
                }
            }
        }
    }

    #[test]
    fn measures_do_not_depend_on_the_thread_count() {
        let (m, p) = radially_projected_sphere(10.0);
        let t = Topology::build(&m);
        let hk: Vec<(f64, f64)> = p.iter().map(|q| (q.x.sin(), 0.0)).collect();
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| measure_stage(&m, &t, &p, m.positions(), Some(&hk), 0.2))
        };
        let one = run(1);
        assert_eq!(one, run(3));
        assert!(one.triangle_angles.below_15 > 0, "the fixture has slivers");
    }

    #[test]
    fn statistics_of_a_mesh_with_every_kind_of_vertex() {
        // A fin (three triangles on edge 0-1), a degenerate quad, an
        // isolated vertex 9.
        let mut p = vec![DVec3::ZERO; 10];
        p[1] = DVec3::X;
        p[2] = DVec3::Y;
        p[3] = DVec3::Z;
        p[4] = DVec3::new(1.0, 1.0, 1.0);
        p[5] = DVec3::new(5.0, 0.0, 0.0);
        p[6] = DVec3::new(6.0, 0.0, 0.0);
        p[7] = DVec3::new(6.0, 1.0, 0.0);
        let faces: Vec<Vec<u32>> = vec![
            vec![0, 1, 2],
            vec![1, 0, 3],
            vec![0, 1, 4],
            vec![5, 6, 7, 7],
            vec![5, 6, 7, 8, 8],
        ];
        let m = Mesh::from_polygons(p, &faces).unwrap();
        let t = Topology::build(&m);
        let s = mesh_statistics(&m, &t);
        assert_eq!((s.vertices, s.faces), (10, 5));
        assert_eq!(
            (s.triangles, s.quads, s.polygons, s.max_face_arity),
            (3, 1, 1, 5)
        );
        assert_eq!(s.non_manifold_edges, 1);
        assert_eq!(s.max_faces_per_edge, 3);
        assert_eq!(s.isolated_vertices, 1);
        assert_eq!(s.degenerate_faces, 2);
        assert_eq!(s.components, 2);
        assert!(!s.closed);
        assert!(s.boundary_edges > 0 && s.boundary_vertices > 0 && s.non_manifold_vertices >= 2);
    }
}
