//! The measures of the quality report (algorithm notes section 9), for one
//! set of positions on a mesh, against the input positions.
//!
//! Runs in parallel over fixed-size chunks of faces, edges and vertices;
//! each chunk's partial sums are combined in chunk order, so the figures do
//! not depend on the number of threads. Angles are binned through their
//! cosines (no `acos` per corner); an angle within `1e-12` (in cosine) of a
//! bin edge or a threshold counts as equal to it, so the right angles and
//! 45° angles of voxel meshes land in the bins that start at 90° and 45°.

use crate::mesh::{Mesh, Topology, VertexKind, vector_area};
use crate::quality::local::{
    cos_between, for_each_split_triangle, has_repeated_corner, is_inverted, is_twisted,
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

/// Tolerance, in cosine, under which an angle counts as equal to a bin edge
/// or threshold.
const COS_EPS: f64 = 1e-12;

/// Angle thresholds (degrees) counted below, in [`AngleStats`] order.
const BELOW_DEG: [f64; 3] = [15.0, 20.0, 30.0];
/// Angle thresholds (degrees) counted above, in [`AngleStats`] order.
const ABOVE_DEG: [f64; 3] = [120.0, 150.0, 160.0];

/// Cosines of the bin edges and thresholds, computed once per measure.
struct AngleTable {
    /// `cos(5 k deg)` for `k = 1..ANGLE_BINS` (the inner bin edges),
    /// decreasing.
    edges: [f64; ANGLE_BINS - 1],
    below: [f64; 3],
    above: [f64; 3],
}

impl AngleTable {
    fn new() -> Self {
        let c = |deg: f64| deg.to_radians().cos();
        AngleTable {
            edges: std::array::from_fn(|k| c((k + 1) as f64 * ANGLE_BIN_DEG)),
            below: BELOW_DEG.map(c),
            above: ABOVE_DEG.map(c),
        }
    }
}

/// Angle counts of one chunk, kept as cosines until the end.
#[derive(Clone)]
struct AngleAcc {
    count: u64,
    max_cos: f64,
    min_cos: f64,
    below: [u64; 3],
    above: [u64; 3],
    histogram: [u64; ANGLE_BINS],
}

impl AngleAcc {
    fn new() -> Self {
        AngleAcc {
            count: 0,
            max_cos: f64::NEG_INFINITY,
            min_cos: f64::INFINITY,
            below: [0; 3],
            above: [0; 3],
            histogram: [0; ANGLE_BINS],
        }
    }

    #[inline]
    fn add(&mut self, t: &AngleTable, c: f64) {
        self.count += 1;
        self.max_cos = self.max_cos.max(c);
        self.min_cos = self.min_cos.min(c);
        // The bin is the number of inner edges the angle reaches.
        let bin = t.edges.partition_point(|&e| c <= e + COS_EPS);
        self.histogram[bin] += 1;
        for (n, &b) in self.below.iter_mut().zip(&t.below) {
            *n += (c > b + COS_EPS) as u64;
        }
        for (n, &a) in self.above.iter_mut().zip(&t.above) {
            *n += (c < a - COS_EPS) as u64;
        }
    }

    fn merge(&mut self, o: &AngleAcc) {
        self.count += o.count;
        self.max_cos = self.max_cos.max(o.max_cos);
        self.min_cos = self.min_cos.min(o.min_cos);
        for (a, b) in self.below.iter_mut().zip(&o.below) {
            *a += b;
        }
        for (a, b) in self.above.iter_mut().zip(&o.above) {
            *a += b;
        }
        for (a, b) in self.histogram.iter_mut().zip(&o.histogram) {
            *a += b;
        }
    }

    fn finish(&self) -> AngleStats {
        let deg = |c: f64| c.clamp(-1.0, 1.0).acos().to_degrees();
        let some = self.count > 0;
        AngleStats {
            count: self.count,
            min_deg: some.then(|| deg(self.max_cos)),
            max_deg: some.then(|| deg(self.min_cos)),
            below_15: self.below[0],
            below_20: self.below[1],
            below_30: self.below[2],
            above_120: self.above[0],
            above_150: self.above[1],
            above_160: self.above[2],
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
    volume: f64,
    input_volume: f64,
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
    let (displacement, variation) = vertex_pass(topo, positions, input, curvature);
    let volume = (boundary_edges == 0 && mesh.num_faces() > 0).then(|| VolumeMeasure {
        volume: faces.volume,
        relative_change: (faces.input_volume != 0.0)
            .then(|| (faces.volume - faces.input_volume) / faces.input_volume.abs()),
    });
    StageMeasures {
        mean_edge_length,
        curvature_variation: variation.map(|mean| CurvatureVariation {
            mean,
            mean_scaled: mean * mean_edge_length,
        }),
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
                volume: 0.0,
                input_volume: 0.0,
            };
            for f in c * CHUNK..((c + 1) * CHUNK).min(nf) {
                let face = mesh.face(f);
                let k = face.len();
                let mut prev = positions[face[k - 1] as usize];
                for j in 0..k {
                    let p = positions[face[j] as usize];
                    acc.side_sum += p.distance(prev);
                    prev = p;
                }
                acc.sides += k as u64;
                acc.volume += fan_volume(face, positions);
                acc.input_volume += fan_volume(face, input);
                acc.twisted += is_twisted(face, positions) as u64;
                acc.inverted += is_inverted(face, positions, input) as u64;
                if has_repeated_corner(face) {
                    continue;
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
        volume: 0.0,
        input_volume: 0.0,
    };
    for c in &chunks {
        total.triangles.merge(&c.triangles);
        total.corners.merge(&c.corners);
        total.twisted += c.twisted;
        total.inverted += c.inverted;
        total.side_sum += c.side_sum;
        total.sides += c.sides;
        total.volume += c.volume;
        total.input_volume += c.input_volume;
    }
    total.volume /= 6.0;
    total.input_volume /= 6.0;
    total
}

/// Six times the signed volume of the cone from the origin over `face`
/// (fan from corner 0).
#[inline]
fn fan_volume(face: &[u32], positions: &[DVec3]) -> f64 {
    let o = positions[face[0] as usize];
    let mut v = 0.0;
    for j in 1..face.len() - 1 {
        v += o.dot(positions[face[j] as usize].cross(positions[face[j + 1] as usize]));
    }
    v
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

/// Displacement statistics and the mean curvature variation.
fn vertex_pass(
    topo: &Topology,
    positions: &[DVec3],
    input: &[DVec3],
    curvature: Option<&[(f64, f64)]>,
) -> (Displacement, Option<f64>) {
    let n = positions.len();
    // (sum d, sum d^2, max d, sum variation, vertices with neighbours)
    let chunks: Vec<(f64, f64, f64, f64, u64)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut s = (0.0, 0.0, 0.0f64, 0.0, 0u64);
            for v in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let d = positions[v].distance(input[v]);
                s.0 += d;
                s.1 += d * d;
                s.2 = s.2.max(d);
                if let Some(hk) = curvature {
                    let nb = topo.neighbors(v);
                    if !nb.is_empty() {
                        let h = hk[v].0;
                        let var = nb
                            .iter()
                            .map(|&j| (h - hk[j as usize].0).abs())
                            .fold(0.0, f64::max);
                        s.3 += var;
                        s.4 += 1;
                    }
                }
            }
            s
        })
        .collect();
    let mut t = (0.0, 0.0, 0.0f64, 0.0, 0u64);
    for c in &chunks {
        t.0 += c.0;
        t.1 += c.1;
        t.2 = t.2.max(c.2);
        t.3 += c.3;
        t.4 += c.4;
    }
    let nv = n.max(1) as f64;
    let displacement = Displacement {
        mean: t.0 / nv,
        rms: (t.1 / nv).sqrt(),
        max: t.2,
    };
    let variation = curvature.map(|_| if t.4 > 0 { t.3 / t.4 as f64 } else { 0.0 });
    (displacement, variation)
}

/// Size and topology figures of `mesh` (whose adjacency is `topo`).
pub fn mesh_statistics(mesh: &Mesh, topo: &Topology) -> MeshStatistics {
    let positions = mesh.positions();
    let mut s = MeshStatistics {
        vertices: mesh.num_vertices() as u64,
        faces: mesh.num_faces() as u64,
        edges: topo.edges().len() as u64,
        ..MeshStatistics::default()
    };
    for face in mesh.faces() {
        match face.len() {
            3 => s.triangles += 1,
            4 => s.quads += 1,
            _ => s.polygons += 1,
        }
        s.max_face_arity = s.max_face_arity.max(face.len() as u64);
        if has_repeated_corner(face) || vector_area(face, positions) == DVec3::ZERO {
            s.degenerate_faces += 1;
        }
    }
    s.boundary_edges = topo.num_boundary_edges() as u64;
    s.non_manifold_edges = topo.num_non_manifold_edges() as u64;
    s.max_faces_per_edge = topo.max_faces_per_edge() as u64;
    s.boundary_vertices = topo.count_kind(VertexKind::Boundary) as u64;
    s.non_manifold_vertices = topo.count_kind(VertexKind::NonManifold) as u64;
    s.isolated_vertices = topo.count_kind(VertexKind::Isolated) as u64;
    s.components = topo.num_components() as u64;
    s.closed = s.boundary_edges == 0;
    s
}
