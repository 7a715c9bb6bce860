//! The quality report (algorithm notes, section 9): plain data, per stage,
//! serialisable to JSON and back. The schema is documented field by field in
//! `docs/report.md` and versioned by [`SCHEMA_VERSION`].
//!
//! The measures are computed by [`measures`]; the quality
//! fixes return the statistics in [`QualityFixStats`]; the pipeline fills
//! the rest.

pub mod measures;

pub use measures::{mean_curvature_variation, measure_stage, mesh_statistics, wall_parting};

use crate::params::{Method, Params};
pub use crate::quality::{
    InvertedStats, QualityFixStats, SharpAngleStats, ShortEdgeStats, SliverStats, TwistedStats,
};
use crate::smoothing::label::Label;
use crate::smoothing::project::FitStats;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// Version of the report's JSON schema: the major number changes when a
/// field is removed or changes meaning, the minor number when fields are
/// added.
pub const SCHEMA_VERSION: &str = "2.9";

/// Width of one angle-histogram bin, in degrees.
pub const ANGLE_BIN_DEG: f64 = 5.0;

/// Number of angle-histogram bins: `[0, 5), [5, 10), ..., [175, 180]`.
pub const ANGLE_BINS: usize = 36;

/// The quality report of a run.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct QualityReport {
    /// [`SCHEMA_VERSION`] of the producer.
    pub schema_version: String,
    /// Size and topology of the input mesh.
    pub mesh: MeshStatistics,
    /// Measures per stage; a stage a method does not have is absent.
    pub stages: Stages,
    /// Wang-Yu specifics (labels, ring sizes, fit fallbacks); absent for the
    /// baseline methods.
    pub wang_yu: Option<WangYuSummary>,
    /// What the quality fixes did; absent when they did not run.
    pub quality_fixes: Option<QualityFixStats>,
    /// Wall time per pipeline stage, in run order.
    pub timings: Vec<StageTiming>,
    /// Wall time of the whole run, in milliseconds.
    pub total_ms: f64,
    /// Tool, parameters and content hashes that reproduce the run.
    pub reproducibility: Reproducibility,
    /// Plain-language notes on results a user should look at (a volume
    /// that could not be restored, faces left inverted); empty when there
    /// is nothing to say.
    pub warnings: Vec<String>,
    /// Where bodies touch face to face (`mesh.touching_bodies`): how far
    /// apart the output puts the two copies of each vertex of their shared
    /// walls, in model units; absent otherwise. Since schema 2.7.
    #[serde(default)]
    pub walls_parted: Option<Displacement>,
    /// Where the mesh is a complex of regions (`mesh.regions`): how far
    /// each wall vertex's copies, one per region around it, lay from their
    /// mean, which the output takes, over the copies, in model units;
    /// absent otherwise. Since schema 2.8.
    #[serde(default)]
    pub walls_joined: Option<Displacement>,
    /// Where the mesh is a complex of regions: what the quality fixes did
    /// on the complex once its walls were joined (`quality_fixes` are the
    /// regions' runs'); absent otherwise. Since schema 2.8.
    #[serde(default)]
    pub joined_fixes: Option<QualityFixStats>,
}

impl QualityReport {
    /// A report with the mesh statistics and reproducibility block filled,
    /// no stage measured and no timings.
    pub fn new(mesh: MeshStatistics, reproducibility: Reproducibility) -> Self {
        QualityReport {
            schema_version: SCHEMA_VERSION.to_string(),
            mesh,
            stages: Stages::default(),
            wang_yu: None,
            quality_fixes: None,
            timings: Vec::new(),
            total_ms: 0.0,
            reproducibility,
            warnings: Vec::new(),
            walls_parted: None,
            walls_joined: None,
            joined_fixes: None,
        }
    }

    /// The report of the same run on the mesh scaled by `s`: every length
    /// times `s`, curvatures divided by it, volumes times its cube; counts,
    /// angles and relative measures unchanged. Exact when `s` is a power of
    /// two ([`crate::mesh::UnitScale`]).
    pub fn rescale(&mut self, s: f64) {
        let stages = &mut self.stages;
        for stage in [
            &mut stages.input,
            &mut stages.initial,
            &mut stages.adaptive,
            &mut stages.final_stage,
        ]
        .into_iter()
        .flatten()
        {
            stage.rescale(s);
        }
        if let Some(w) = self.wang_yu.as_mut() {
            w.initial_fits.max_step *= s;
            w.adaptive_fits.max_step *= s;
            w.volume_offset *= s;
        }
        for fixes in [&mut self.quality_fixes, &mut self.joined_fixes]
            .into_iter()
            .flatten()
        {
            fixes.short_edges.threshold *= s;
        }
        for d in [&mut self.walls_parted, &mut self.walls_joined]
            .into_iter()
            .flatten()
        {
            d.rescale(s);
        }
    }
}

impl Default for QualityReport {
    /// An empty report for the default parameters (nothing measured).
    fn default() -> Self {
        QualityReport::new(
            MeshStatistics::default(),
            Reproducibility::new(&Params::default()),
        )
    }
}

/// Measures per stage of the pipeline.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Stages {
    /// The input mesh.
    pub input: Option<StageMeasures>,
    /// After initial smoothing (Wang-Yu), or after the baseline smoother.
    pub initial: Option<StageMeasures>,
    /// After adaptive smoothing and volume restoration (Wang-Yu only).
    pub adaptive: Option<StageMeasures>,
    /// The output: after the quality fixes when they ran.
    #[serde(rename = "final")]
    pub final_stage: Option<StageMeasures>,
}

/// Measures of one set of positions on the mesh, against the input.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageMeasures {
    /// Mean length of the face sides (each side counted once per face), in
    /// mesh units.
    pub mean_edge_length: f64,
    /// Mean curvature variation (section 9); absent when no curvature was
    /// supplied for the stage.
    pub curvature_variation: Option<CurvatureVariation>,
    /// Angles of the triangle split (quads `(v1 v2 v3), (v3 v4 v1)`,
    /// polygons fanned from corner 0).
    pub triangle_angles: AngleStats,
    /// The polygons' own corner angles.
    pub polygon_angles: AngleStats,
    /// Unique edges shorter than `short_edge_fraction` times this stage's
    /// mean edge length.
    pub short_edges: u64,
    /// The threshold used for `short_edges`, in mesh units.
    pub short_edge_threshold: f64,
    /// Quads whose split triangles' normals are more than 90° apart.
    pub twisted_quads: u64,
    /// Faces whose vector area or any split triangle's normal points against
    /// the same in the input.
    pub inverted_faces: u64,
    /// Enclosed volume; absent unless the mesh is closed (no boundary edge).
    /// Of a multi-label complex (`mesh.regions`), the sum of its regions'
    /// volumes, each wall counted for both of its regions.
    pub volume: Option<VolumeMeasure>,
    /// How far vertices moved from the input.
    pub displacement: Displacement,
}

impl StageMeasures {
    /// These measures on the positions scaled by `s`
    /// ([`QualityReport::rescale`]).
    fn rescale(&mut self, s: f64) {
        self.mean_edge_length *= s;
        self.short_edge_threshold *= s;
        if let Some(c) = self.curvature_variation.as_mut() {
            c.mean /= s;
        }
        if let Some(v) = self.volume.as_mut() {
            v.volume *= s * s * s;
        }
        self.displacement.rescale(s);
    }
}

/// Mean curvature variation: per vertex `max_{j in N_1(i)} |H_i - H_j|`,
/// averaged over the vertices that have a neighbour.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CurvatureVariation {
    /// In 1/mesh units.
    pub mean: f64,
    /// `mean` times the stage's mean edge length (scale-free).
    pub mean_scaled: f64,
}

impl CurvatureVariation {
    /// The variation `mean` of a stage whose mean edge length is
    /// `mean_edge_length`
    /// ([`mean_curvature_variation`]).
    pub fn new(mean: f64, mean_edge_length: f64) -> CurvatureVariation {
        CurvatureVariation {
            mean,
            mean_scaled: mean * mean_edge_length,
        }
    }
}

/// Angle statistics over a set of corners. Angles are unsigned, in
/// `[0, 180]` degrees; a corner with a zero-length side counts as 0°.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AngleStats {
    /// Number of corners measured.
    pub count: u64,
    /// Smallest angle in degrees; absent when `count` is 0.
    pub min_deg: Option<f64>,
    /// Largest angle in degrees; absent when `count` is 0.
    pub max_deg: Option<f64>,
    /// Corners below 15°.
    pub below_15: u64,
    /// Corners below 20°.
    pub below_20: u64,
    /// Corners below 30°.
    pub below_30: u64,
    /// Corners above 120°.
    pub above_120: u64,
    /// Corners above 150°.
    pub above_150: u64,
    /// Corners above 160°.
    pub above_160: u64,
    /// [`ANGLE_BINS`] counts; bin `i` holds angles in `[5 i, 5 i + 5)`
    /// degrees, the last bin includes 180.
    pub histogram: Vec<u64>,
}

impl Default for AngleStats {
    fn default() -> Self {
        AngleStats {
            count: 0,
            min_deg: None,
            max_deg: None,
            below_15: 0,
            below_20: 0,
            below_30: 0,
            above_120: 0,
            above_150: 0,
            above_160: 0,
            histogram: vec![0; ANGLE_BINS],
        }
    }
}

/// Enclosed volume of a closed mesh.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VolumeMeasure {
    /// Signed volume by the divergence theorem, in cubic mesh units
    /// (positive for outward normals), each connected component's cones
    /// taken from its input centroid: a surface with edges of an odd
    /// number of faces (a neuron's junctions) measures alike wherever its
    /// file puts the origin ([`crate::mesh::VolumeApexes`]).
    pub volume: f64,
    /// `(volume - input volume) / |input volume|`; absent when the input
    /// volume is 0.
    pub relative_change: Option<f64>,
}

/// Vertex displacement from the input, over all vertices, in mesh units.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Displacement {
    /// Mean distance.
    pub mean: f64,
    /// Root mean square distance.
    pub rms: f64,
    /// Largest distance.
    pub max: f64,
}

impl Displacement {
    /// These distances scaled by `s`.
    fn rescale(&mut self, s: f64) {
        self.mean *= s;
        self.rms *= s;
        self.max *= s;
    }
}

/// Size and topology of a mesh.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshStatistics {
    /// Vertices.
    pub vertices: u64,
    /// Faces.
    pub faces: u64,
    /// Faces with 3 corners.
    pub triangles: u64,
    /// Faces with 4 corners.
    pub quads: u64,
    /// Faces with more than 4 corners.
    pub polygons: u64,
    /// Most corners of one face (0 without faces).
    pub max_face_arity: u64,
    /// Unique undirected edges.
    pub edges: u64,
    /// Edges with exactly one face.
    pub boundary_edges: u64,
    /// Vertices on a boundary edge (and not non-manifold).
    pub boundary_vertices: u64,
    /// Edges with more than two faces.
    pub non_manifold_edges: u64,
    /// Vertices on a non-manifold edge or joining separate fans (pinches).
    pub non_manifold_vertices: u64,
    /// Most faces sharing one edge.
    pub max_faces_per_edge: u64,
    /// Vertices no face uses.
    pub isolated_vertices: u64,
    /// Faces with a repeated corner or zero vector area.
    pub degenerate_faces: u64,
    /// Connected components (isolated vertices not counted).
    pub components: u64,
    /// True when no edge is a boundary edge (volume is then reported).
    pub closed: bool,
    /// Vertices in the file before welding; absent when the file was not
    /// welded (then `vertices` is the file's count). Since schema 1.1.
    pub file_vertices: Option<u64>,
    /// Faces whose corners the run took in reverse order, so that faces
    /// sharing an edge wind it opposite ways and a closed mesh encloses a
    /// positive volume: faces wound against their neighbours, or every
    /// face of a mesh wound inside out. Every stage and measure reads the
    /// turned faces; the output keeps the file's faces. Since schema 2.6.
    #[serde(default)]
    pub reoriented_faces: u64,
    /// True when the closed mesh, once its faces agreed, was wound inside
    /// out and every face was turned. Since schema 2.6.
    #[serde(default)]
    pub inside_out: bool,
    /// Bodies (connected parts of a closed mesh) wound inside out on their
    /// own and turned whole, beside bodies wound outward: each enclosed a
    /// negative volume and lay inside no other body (a body inside another
    /// keeps its winding, as it may be a cavity). Never with `inside_out`.
    /// Since schema 2.9.
    #[serde(default)]
    pub inside_out_bodies: u64,
    /// Faces of those bodies (included in `reoriented_faces`). Since schema
    /// 2.9.
    #[serde(default)]
    pub inside_out_body_faces: u64,
    /// Edges between two faces that still wind it the same way after the
    /// turns: a surface that cannot be oriented (a Moebius strip). Since
    /// schema 2.6.
    #[serde(default)]
    pub orientation_seams: u64,
    /// Bodies told apart because their surfaces touch face to face: closed
    /// surfaces with their own vertices in one file (the segments of a
    /// segmentation exported together) that share the faces of a common
    /// wall. Each is welded, and gets its volume back, on its own; 0 when
    /// the file has no such bodies. Since schema 2.7.
    #[serde(default)]
    pub touching_bodies: u64,
    /// Faces those bodies share, a wall's face from both sides counted
    /// once. Since schema 2.7.
    #[serde(default)]
    pub shared_faces: u64,
    /// Regions of a multi-label complex: closed spaces the surface bounds
    /// whose walls between two of them are written once (VTK's surface
    /// nets over a label map). Each is smoothed as its own closed surface
    /// and the walls joined again; 0 when the mesh is no such complex.
    /// Since schema 2.8.
    #[serde(default)]
    pub regions: u64,
    /// Faces with a region on both sides: the walls the regions share.
    /// Since schema 2.8.
    #[serde(default)]
    pub region_walls: u64,
}

impl MeshStatistics {
    /// Faces the file winds against their neighbours: `reoriented_faces`,
    /// less the whole mesh's turn when it was inside out, or less the
    /// bodies turned whole.
    pub fn faces_wound_against(&self) -> u64 {
        if self.inside_out {
            self.faces.saturating_sub(self.reoriented_faces)
        } else {
            self.reoriented_faces
                .saturating_sub(self.inside_out_body_faces)
        }
    }
}

/// Vertices per label of the paper's Table 2.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LabelCounts {
    /// Flat vertices.
    pub flat: u64,
    /// Minimal (saddle-like) vertices.
    pub minimal: u64,
    /// Convex vertices.
    pub convex: u64,
    /// Concave vertices.
    pub concave: u64,
}

impl LabelCounts {
    /// Counts `labels` (one per vertex).
    pub fn from_labels(labels: &[Label]) -> Self {
        let mut c = LabelCounts::default();
        for l in labels {
            match l {
                Label::Flat => c.flat += 1,
                Label::Minimal => c.minimal += 1,
                Label::Convex => c.convex += 1,
                Label::Concave => c.concave += 1,
            }
        }
        c
    }
}

/// How the fits of a stage ended (section 3 fallbacks). Counts cover the
/// passes that fit (not the adaptive passes that reuse a fit's linear
/// weights); `max_step` and `clamped` cover every pass.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct FitCounts {
    /// Fits that used the quadric plus cubic terms (adaptive passes with
    /// `adaptive_fit: cubic`), summed over passes.
    #[serde(default)]
    pub cubic: u64,
    /// Fits that used the full quadric, summed over passes.
    pub quadric: u64,
    /// Fits that fell back to a plane.
    pub plane: u64,
    /// Fits that left the vertex in place.
    pub fixed: u64,
    /// Largest single move of a vertex in one pass, in mesh units.
    pub max_step: f64,
    /// Moves cut to the vertex's mean edge length (a fit that would
    /// have jumped).
    pub clamped: u64,
}

impl From<FitStats> for FitCounts {
    fn from(s: FitStats) -> Self {
        FitCounts {
            cubic: s.cubic,
            quadric: s.quadric,
            plane: s.plane_fallback,
            fixed: s.fixed_fallback,
            max_step: s.max_displacement,
            clamped: s.clamped,
        }
    }
}

/// Wang-Yu specifics.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WangYuSummary {
    /// Vertices per label (from the curvature after initial smoothing).
    pub labels: LabelCounts,
    /// Entry `k` is the number of vertices whose adaptive neighbourhood
    /// ended at ring `k` (entries 0 and 1 are vertices that were not grown,
    /// e.g. fixed ones).
    pub ring_size_histogram: Vec<u64>,
    /// Fits of the initial passes.
    pub initial_fits: FitCounts,
    /// Fits of the adaptive passes.
    pub adaptive_fits: FitCounts,
    /// Offset along the vertex normals that restored the input volume after
    /// adaptive smoothing, plus the small one (at most a tenth of an edge)
    /// that restores it again after the quality fixes, in mesh units (0 when
    /// not applied). The solids and the cavities get an offset each; this is
    /// their mean weighted by area.
    pub volume_offset: f64,
    /// The relative change of the enclosed volume the restoration aimed at:
    /// 0 (the input's volume), but on a voxel lattice, where the smooth
    /// surface through the output's vertices gets the mask's volume and
    /// its flat faces enclose a little less where it is convex (at most
    /// 1.5% less, on tubes a few voxels across), and where parts collapsed:
    /// a fragment or a hole whose loss no offset of half an edge gives back
    /// is left as smoothed, and its change counts here. Since schema 2.3.
    #[serde(default)]
    pub volume_target_change: f64,
    /// Vertices the fidelity bound (`max_displacement`) held back at least
    /// once: a smoothing pass, the volume restoration or a quality fix
    /// would have moved them farther from their input position; `null`
    /// when the run had no bound.
    pub fidelity_held_back: Option<u64>,
    /// On a mesh cut from no grid: the input's noise estimate, the median
    /// height of a vertex above the quadric with cubic terms fitted to its
    /// 2-ring, in its mean edge lengths; each vertex was held within
    /// `noise_bound` times it (times its mean edge) across its input
    /// surface. `null` on a voxel
    /// or marching-cubes mesh, without `noise_bound` or `max_displacement`,
    /// or when fewer than 32 vertices have a fit. Since schema 2.5.
    #[serde(default)]
    pub input_noise: Option<f64>,
    /// Pairs of triangles joined back into the square voxel faces they
    /// split (a voxel-boundary mesh written as triangles, as STL and glTF
    /// hold it): such a mesh is smoothed as its voxel faces, and every
    /// stage is measured on its triangles. 0 otherwise. Since schema 2.4.
    #[serde(default)]
    pub paired_triangles: u64,
    /// The grid the input was recognised as cut from, which decides the
    /// staircase steps and the fidelity bound's shape.
    #[serde(default)]
    pub input_grid: InputGrid,
}

/// The grid a mesh was recognised as cut from (`mesh::lattice`).
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InputGrid {
    /// A voxel-boundary mesh (every edge along one of three orthogonal
    /// axes, in any orientation): relaxed, faired and low-passed, each
    /// corner held in its dual voxel.
    Voxel,
    /// A marching-cubes mesh of a binary mask (every vertex at the midpoint
    /// of a lattice edge, on a grid of any orientation): relaxed between
    /// the initial passes, each vertex held in its edge's slab.
    MarchingCubes,
    /// Neither: the paper's passes alone, each vertex held in a ball and,
    /// across its input surface, by the input's noise (`input_noise`).
    #[default]
    None,
}

/// Histogram of ring sizes: entry `k` counts the vertices with `ring[v] ==
/// k`; its length is the largest `k` plus one (empty for no vertices).
pub fn ring_size_histogram(ring: &[u8]) -> Vec<u64> {
    let mut h = vec![0u64; ring.iter().max().map_or(0, |&m| m as usize + 1)];
    for &k in ring {
        h[k as usize] += 1;
    }
    h
}

/// Wall time of one pipeline stage.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageTiming {
    /// Stable stage name (`analyse`, `initial`, `label`, `adaptive`,
    /// `quality`, `report`).
    pub stage: String,
    /// Milliseconds.
    pub ms: f64,
}

/// What reproduces the run.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reproducibility {
    /// Always `meshsmooth`.
    pub tool: String,
    /// Version of the tool (the core crate's version).
    pub tool_version: String,
    /// The smoother used (also in `params.method`).
    pub method: Method,
    /// The parameters as used, defaults filled in.
    pub params: Params,
    /// SHA-256 of the input file's bytes, lower-case hex; filled by the
    /// caller that read the file.
    pub input_sha256: Option<String>,
    /// SHA-256 of the output file's bytes, lower-case hex; filled by the
    /// caller that wrote the file.
    pub output_sha256: Option<String>,
}

impl Reproducibility {
    /// The block for a run with `params`, hashes not yet known.
    pub fn new(params: &Params) -> Self {
        Reproducibility {
            tool: "meshsmooth".to_string(),
            tool_version: env!("CARGO_PKG_VERSION").to_string(),
            method: params.method,
            params: params.clone(),
            input_sha256: None,
            output_sha256: None,
        }
    }
}

/// SHA-256 of `bytes` as 64 lower-case hex digits.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    let mut s = String::with_capacity(64);
    for b in digest {
        const HEX: &[u8; 16] = b"0123456789abcdef";
        s.push(HEX[(b >> 4) as usize] as char);
        s.push(HEX[(b & 15) as usize] as char);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sha256_of_known_strings() {
        // FIPS 180-2 test vectors.
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(
            sha256_hex(b""),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
    }

    #[test]
    fn ring_histogram_counts_each_k() {
        assert_eq!(ring_size_histogram(&[2, 2, 5, 3]), vec![0, 0, 2, 1, 0, 1]);
        assert!(ring_size_histogram(&[]).is_empty());
    }

    /// Numbers equal within a relative 1e-15 (JSON float parsing may be one
    /// unit in the last place off), everything else exactly.
    fn same(a: &serde_json::Value, b: &serde_json::Value) -> bool {
        use serde_json::Value;
        match (a, b) {
            (Value::Number(x), Value::Number(y)) => {
                let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
                (x - y).abs() <= 1e-15 * x.abs().max(y.abs())
            }
            (Value::Array(x), Value::Array(y)) => {
                x.len() == y.len() && x.iter().zip(y).all(|(x, y)| same(x, y))
            }
            (Value::Object(x), Value::Object(y)) => {
                x.len() == y.len() && x.iter().all(|(k, v)| y.get(k).is_some_and(|w| same(v, w)))
            }
            _ => a == b,
        }
    }

    #[test]
    fn a_measured_report_round_trips_through_json() {
        use crate::mesh::Topology;
        use crate::quality::improve;
        use crate::shapes::voxel_sphere;
        let (_, mesh) = voxel_sphere(4.0);
        let topo = Topology::build(&mesh);
        let params = Params::default();
        let input = mesh.positions();
        let mut report =
            QualityReport::new(mesh_statistics(&mesh, &topo), Reproducibility::new(&params));
        report.stages.input = Some(measure_stage(&mesh, &topo, input, input, None, 0.2));
        let mut p: Vec<_> = input.iter().map(|&q| q * 1.01).collect();
        report.quality_fixes = Some(improve(
            &mesh,
            &topo,
            &mut p,
            input,
            None,
            &params.quality,
            params.min_normal_cos(),
        ));
        report.stages.final_stage = Some(measure_stage(&mesh, &topo, &p, input, None, 0.2));
        report.timings.push(StageTiming {
            stage: "quality".into(),
            ms: 1.5,
        });
        report.reproducibility.input_sha256 = Some(sha256_hex(b"mesh"));
        let json = serde_json::to_string_pretty(&report).unwrap();
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(v["schema_version"], SCHEMA_VERSION);
        assert!(v["stages"]["final"].is_object() && v["stages"]["initial"].is_null());
        assert_eq!(
            v["stages"]["input"]["triangle_angles"]["histogram"]
                .as_array()
                .unwrap()
                .len(),
            ANGLE_BINS
        );
        assert_eq!(v["reproducibility"]["params"]["method"], "wang-yu");
        assert!(v["mesh"]["closed"].as_bool().unwrap());
        let back: QualityReport = serde_json::from_str(&json).unwrap();
        assert!(same(&serde_json::to_value(&back).unwrap(), &v));
        assert_eq!(back.mesh, report.mesh);
        let (fixes, fixes_back) = (report.quality_fixes.unwrap(), back.quality_fixes.unwrap());
        assert_eq!(fixes_back.twisted, fixes.twisted);
        assert_eq!(fixes_back.sharp_angles, fixes.sharp_angles);
    }

    #[test]
    fn labels_are_counted() {
        let c = LabelCounts::from_labels(&[Label::Flat, Label::Convex, Label::Convex]);
        assert_eq!((c.flat, c.minimal, c.convex, c.concave), (1, 0, 2, 0));
    }
}
