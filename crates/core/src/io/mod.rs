//! Mesh formats: readers and writers over bytes, never paths.
//!
//! [`read`] turns uploaded bytes into a [`Document`]: the [`Mesh`] to smooth
//! plus whatever the format needs to write the same file back with only the
//! positions changed. [`write()`] does that, in the input's format or another.
//! Nothing a file points to (external buffers, material libraries) is ever
//! fetched.

mod bodies;
pub mod gltf;
pub mod obj;
pub mod off;
pub mod ply;
pub mod stl;
mod text;
pub mod weld;

pub use bodies::FileBodies;
use bodies::{dense_pairs, weld_bodies};

use crate::error::ErrorCode;
use crate::mesh::{Mesh, Topology};
use glam::DVec3;
use thiserror::Error;

/// A mesh file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Format {
    /// Wavefront OBJ (text).
    Obj,
    /// glTF 2.0 JSON (`.gltf`) with buffers embedded as `data:` URIs.
    Gltf,
    /// Binary glTF 2.0 (`.glb`).
    Glb,
    /// Stanford PLY: ASCII or binary.
    Ply,
    /// STL: ASCII or binary.
    Stl,
    /// Geomview's OFF (text).
    Off,
}

impl Format {
    /// Every format, in the order they are listed to users.
    pub const ALL: &'static [Format] = &[
        Format::Obj,
        Format::Gltf,
        Format::Glb,
        Format::Ply,
        Format::Stl,
        Format::Off,
    ];

    /// Short lowercase name, as accepted by [`str::parse`] (`obj`).
    pub fn name(self) -> &'static str {
        self.extension()
    }

    /// Canonical file extension, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Obj => "obj",
            Format::Gltf => "gltf",
            Format::Glb => "glb",
            Format::Ply => "ply",
            Format::Stl => "stl",
            Format::Off => "off",
        }
    }

    /// MIME type used in HTTP.
    pub fn content_type(self) -> &'static str {
        match self {
            Format::Obj => "model/obj",
            Format::Gltf => "model/gltf+json",
            Format::Glb => "model/gltf-binary",
            Format::Ply => "application/x-ply",
            Format::Stl => "model/stl",
            Format::Off => "model/x-off",
        }
    }

    /// Format from a file name's extension (case-insensitive).
    pub fn from_file_name(name: &str) -> Option<Format> {
        let ext = name.rsplit_once('.')?.1;
        Format::ALL
            .iter()
            .copied()
            .find(|f| f.extension().eq_ignore_ascii_case(ext))
    }

    /// Format from an HTTP `Content-Type` (parameters ignored).
    pub fn from_content_type(ct: &str) -> Option<Format> {
        let essence = ct.split(';').next()?.trim().to_ascii_lowercase();
        match essence.as_str() {
            "model/obj" | "text/x-obj" | "application/x-tgif" => Some(Format::Obj),
            "model/gltf+json" => Some(Format::Gltf),
            "model/gltf-binary" => Some(Format::Glb),
            "application/ply" | "application/x-ply" | "model/ply" | "model/x-ply" => {
                Some(Format::Ply)
            }
            "model/stl"
            | "model/x.stl-ascii"
            | "model/x.stl-binary"
            | "application/sla"
            | "application/vnd.ms-pki.stl" => Some(Format::Stl),
            "model/x-off" | "application/x-off" | "model/off" => Some(Format::Off),
            _ => None,
        }
    }

    /// Format guessed from the bytes of a file, checked in this order: the
    /// GLB magic, the `ply` magic, a binary STL's size (`84 + 50 x` its
    /// triangle count), a JSON object (glTF), `solid` (ASCII STL), the `OFF`
    /// keyword, OBJ keywords; `None` when nothing matches.
    pub fn sniff(bytes: &[u8]) -> Option<Format> {
        let head = bytes.get(..bytes.len().min(8192)).unwrap_or(bytes);
        let head = head.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(head);
        let text = head.trim_ascii_start();
        if gltf::is_glb(bytes) {
            return Some(Format::Glb);
        }
        if head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n") {
            return Some(Format::Ply);
        }
        let stl_count = bytes.get(80..84).and_then(|c| c.try_into().ok());
        if stl_count
            .is_some_and(|c| 84 + 50 * u64::from(u32::from_le_bytes(c)) == bytes.len() as u64)
        {
            return Some(Format::Stl);
        }
        if text.starts_with(b"{") {
            return Some(Format::Gltf);
        }
        if text
            .get(..5)
            .is_some_and(|w| w.eq_ignore_ascii_case(b"solid"))
        {
            return Some(Format::Stl);
        }
        if off::starts_with_keyword(head) {
            return Some(Format::Off);
        }
        const OBJ_KEYWORDS: &[&[u8]] =
            &[b"v", b"vt", b"vn", b"f", b"o", b"g", b"mtllib", b"usemtl"];
        let looks_obj = head.split(|&b| b == b'\n').any(|line| {
            let keyword = line
                .split(|b| b.is_ascii_whitespace())
                .find(|w| !w.is_empty())
                .unwrap_or_default();
            OBJ_KEYWORDS.contains(&keyword)
        });
        looks_obj.then_some(Format::Obj)
    }
}

impl std::fmt::Display for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A format name that is not one of [`Format::ALL`].
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("unknown mesh format `{0}`; expected one of: {list}", list = format_names())]
pub struct UnknownFormat(pub String);

fn format_names() -> String {
    let names: Vec<&str> = Format::ALL.iter().map(|f| f.name()).collect();
    names.join(", ")
}

impl std::str::FromStr for Format {
    type Err = UnknownFormat;

    /// Parses a [`Format::name`] or extension, case-insensitively.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Format::ALL
            .iter()
            .copied()
            .find(|f| f.name().eq_ignore_ascii_case(s) || f.extension().eq_ignore_ascii_case(s))
            .ok_or_else(|| UnknownFormat(s.to_owned()))
    }
}

/// Limits applied while reading untrusted input.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadLimits {
    /// Most vertices accepted. Default 20,000,000.
    pub max_vertices: usize,
    /// Most faces accepted. Default 40,000,000.
    pub max_faces: usize,
}

impl Default for ReadLimits {
    fn default() -> Self {
        ReadLimits {
            max_vertices: 20_000_000,
            max_faces: 40_000_000,
        }
    }
}

/// Options of [`read_with`]: limits and welding.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadOptions {
    /// Limits on untrusted input.
    pub limits: ReadLimits,
    /// Join vertices that share a position (see [`weld`]); `None` takes the
    /// format's default: on for glTF and STL; for OBJ, PLY and OFF, on
    /// when the file repeats most of its positions or its repeated positions
    /// join open edges.
    pub weld: Option<bool>,
    /// Welding tolerance as a fraction of the bounding-box diagonal; 0
    /// joins only equal positions. Default 0.
    pub weld_tolerance: f64,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions {
            limits: ReadLimits::default(),
            weld: None,
            weld_tolerance: 0.0,
        }
    }
}

/// A parsed file: the mesh to smooth plus what is needed to write it back.
#[derive(Debug, Clone)]
pub struct Document {
    /// The mesh the smoother works on (welded when welding was on).
    pub mesh: Mesh,
    /// Format the document was read from.
    pub format: Format,
    /// Whether welding ran (asked for, or the format's default), whether or
    /// not it joined anything.
    pub welded: bool,
    /// When the file was welded: one entry per vertex of the file, its
    /// vertex in `mesh`.
    pub vertex_map: Option<Vec<u32>>,
    /// When the file holds bodies that touch face to face (segments written
    /// into one file), welded each on its own
    /// ([`crate::mesh::touching_bodies`]), or
    /// several glTF meshes, each in its own space: the bodies, each
    /// smoothed on its own.
    pub bodies: Option<FileBodies>,
    source: Source,
}

#[derive(Debug, Clone)]
enum Source {
    Obj(obj::ObjSource),
    Gltf(gltf::GltfSource),
    Ply(ply::PlySource),
    Stl(stl::StlSource),
    Off(off::OffSource),
}

/// Per-vertex results to store with the written mesh, each slice empty
/// (left out) or one entry per vertex of [`Document::mesh`]. glTF stores
/// them as float attributes `_LABEL`, `_MEAN_CURVATURE`,
/// `_GAUSSIAN_CURVATURE`, `_DISPLACEMENT`; PLY as vertex properties
/// `label` (uchar), `mean_curvature`, `gaussian_curvature`, `displacement`
/// (float); OBJ, STL and OFF cannot hold them.
#[derive(Debug, Clone, Copy, Default)]
pub struct VertexResults<'a> {
    /// Label of each vertex (Table 2 of Wang & Yu).
    pub label: &'a [u8],
    /// Mean curvature `H`.
    pub mean_curvature: &'a [f64],
    /// Gaussian curvature `K`.
    pub gaussian_curvature: &'a [f64],
    /// Distance moved.
    pub displacement: &'a [f64],
}

/// Options of [`write_with`].
#[derive(Debug, Clone, Copy, Default)]
pub struct WriteOptions<'a> {
    /// Per-vertex results to add (glTF and PLY only). Default none.
    pub results: Option<VertexResults<'a>>,
    /// Write STL as ASCII instead of binary. Default false.
    pub stl_ascii: bool,
}

/// Why a file could not be read or written.
#[derive(Debug, Error)]
pub enum IoError {
    /// Malformed input; `line` is 1-based where the format has lines.
    #[error("{format} parse error{}: {message}", line.map(|l| format!(" on line {l}")).unwrap_or_default())]
    Parse {
        format: &'static str,
        line: Option<usize>,
        message: String,
    },
    /// A face refers to a vertex the file does not define (OBJ: index 0,
    /// beyond the vertices, or a relative index before the first vertex);
    /// `line` is 1-based where the format has lines.
    #[error("{format} parse error{}: {message}", line.map(|l| format!(" on line {l}")).unwrap_or_default())]
    IndexOutOfRange {
        format: &'static str,
        line: Option<usize>,
        message: String,
    },
    /// A coordinate is NaN or infinite; `line` is 1-based where the format
    /// has lines.
    #[error("{format} parse error{}: {message}", line.map(|l| format!(" on line {l}")).unwrap_or_default())]
    NonFiniteCoordinate {
        format: &'static str,
        line: Option<usize>,
        message: String,
    },
    /// The input exceeds a configured limit. When found while streaming,
    /// `count` is how many were seen when the limit was passed.
    #[error("{what} count exceeds the limit of {limit} (found at least {count})")]
    Limit {
        what: &'static str,
        count: usize,
        limit: usize,
    },
    /// The file is valid but has no faces: there is no surface to smooth.
    #[error("{format} file has no faces: {message}")]
    NoFaces {
        format: &'static str,
        message: String,
    },
    /// The file is valid but uses something this reader does not support.
    #[error("unsupported {format} content: {message}")]
    Unsupported {
        format: &'static str,
        message: String,
    },
    /// The data does not make a valid mesh.
    #[error(transparent)]
    Mesh(#[from] crate::error::MeshError),
    /// Positions handed to a writer are not one per vertex.
    #[error("{got} positions given for a mesh of {expected} vertices")]
    PositionCount { expected: usize, got: usize },
    /// Writing failed.
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
    /// The file refers to an external resource, which is never fetched.
    #[error(
        "glTF {what} {index} refers to the external URI `{uri}`; external files and URLs are never fetched: embed the data (a data: URI) or send a .glb"
    )]
    ExternalUri {
        what: &'static str,
        index: usize,
        uri: String,
    },
    /// A required extension this reader cannot handle.
    #[error("unsupported required {format} extension `{name}`")]
    UnsupportedExtension { format: &'static str, name: String },
    /// The only primitives are points or lines.
    #[error(
        "glTF mesh {mesh} primitive {primitive} has mode {mode} ({}) and the document has no triangles; only triangles, strips and fans can be smoothed",
        primitive_mode_name(*mode)
    )]
    UnsupportedPrimitiveMode {
        mesh: usize,
        primitive: usize,
        mode: u64,
    },
    /// The glTF document breaks the specification; `accessor` names the
    /// accessor at fault, if one is.
    #[error("invalid glTF: {message}")]
    GltfInvalid {
        accessor: Option<usize>,
        message: String,
    },
    /// The GLB container (header and chunks) is malformed.
    #[error("invalid GLB container: {0}")]
    GlbInvalid(String),
}

fn primitive_mode_name(mode: u64) -> &'static str {
    match mode {
        0 => "POINTS",
        1 => "LINES",
        2 => "LINE_LOOP",
        3 => "LINE_STRIP",
        4 => "TRIANGLES",
        5 => "TRIANGLE_STRIP",
        6 => "TRIANGLE_FAN",
        _ => "unknown",
    }
}

impl IoError {
    /// Stable code.
    pub fn code(&self) -> ErrorCode {
        match self {
            IoError::Parse { .. } => ErrorCode::ParseError,
            // The same codes as the mesh's own checks (`MeshError`).
            IoError::IndexOutOfRange { .. } => ErrorCode::FaceIndexOutOfRange,
            IoError::NonFiniteCoordinate { .. } => ErrorCode::NonFiniteCoordinate,
            IoError::Limit { .. } => ErrorCode::LimitExceeded,
            IoError::NoFaces { .. } => ErrorCode::NoFaces,
            IoError::Unsupported { .. } => ErrorCode::UnsupportedContent,
            IoError::Mesh(e) => e.code(),
            IoError::PositionCount { .. } => ErrorCode::PositionCountMismatch,
            IoError::Io(_) => ErrorCode::IoError,
            IoError::ExternalUri { .. } => ErrorCode::ExternalUriNotAllowed,
            IoError::UnsupportedExtension { .. } => ErrorCode::UnsupportedExtension,
            IoError::UnsupportedPrimitiveMode { .. } => ErrorCode::UnsupportedPrimitiveMode,
            IoError::GltfInvalid { .. } => ErrorCode::GltfInvalid,
            IoError::GlbInvalid(_) => ErrorCode::GlbInvalid,
        }
    }

    /// `Ok` when a writer got `got` positions for the `expected` it writes,
    /// [`IoError::PositionCount`] otherwise.
    pub(crate) fn check_position_count(expected: usize, got: usize) -> Result<(), IoError> {
        if got == expected {
            Ok(())
        } else {
            Err(IoError::PositionCount { expected, got })
        }
    }
}

/// Reads `bytes` as `format` with the format's default welding.
pub fn read(bytes: &[u8], format: Format, limits: &ReadLimits) -> Result<Document, IoError> {
    let options = ReadOptions {
        limits: limits.clone(),
        ..ReadOptions::default()
    };
    read_with(bytes, format, &options)
}

/// Reads `bytes` as `format`, then welds when `options` (or the format's
/// default) ask for it. `.gltf` and `.glb` are read alike (by the magic).
pub fn read_with(bytes: &[u8], format: Format, options: &ReadOptions) -> Result<Document, IoError> {
    let limits = &options.limits;
    let (mesh, source) = match format {
        Format::Obj => {
            let (mesh, src) = obj::read_obj(bytes, limits)?;
            (mesh, Source::Obj(src))
        }
        Format::Glb if !gltf::is_glb(bytes) && !bytes.trim_ascii_start().starts_with(b"{") => {
            return Err(IoError::GlbInvalid(
                "the file does not start with the GLB magic `glTF` (and is not glTF JSON \
                 either)"
                    .to_owned(),
            ));
        }
        Format::Gltf | Format::Glb => {
            let (mesh, src) = gltf::read_gltf(bytes, limits)?;
            (mesh, Source::Gltf(src))
        }
        Format::Ply => {
            let (mesh, src) = ply::read_ply(bytes, limits)?;
            (mesh, Source::Ply(src))
        }
        Format::Stl => {
            let (mesh, src) = stl::read_stl(bytes, limits)?;
            (mesh, Source::Stl(src))
        }
        Format::Off => {
            let (mesh, src) = off::read_off(bytes, limits)?;
            (mesh, Source::Off(src))
        }
    };
    let weld_default = matches!(format, Format::Gltf | Format::Glb | Format::Stl);
    let groups = match &source {
        Source::Gltf(src) => Some(src.vertex_groups()),
        _ => None,
    };
    let weld = |mesh: &Mesh| weld_bodies(mesh, options.weld_tolerance, groups.as_deref());
    let (welded, bodies, mesh, vertex_map) = match options.weld.or(weld_default.then_some(true)) {
        Some(false) => (false, None, mesh, None),
        Some(true) => match weld(&mesh)? {
            (Some(w), bodies) => (true, bodies, w.mesh, Some(w.vertex_map)),
            (None, bodies) => (true, bodies, mesh, None),
        },
        // OBJ, PLY and OFF share vertices by index: a file that still repeats
        // most of its positions was written face by face (a soup, a
        // flat-shaded export), and one whose repeated positions join open
        // edges has cracks (rims at the same place: a mesher that splits
        // voxels touching along an edge into separate sheets, a PLY cut
        // along its texture seams). Either smooths as one surface only
        // once welded; unwelded, the rims' vertices stay where they were
        // (the boundary rule) or pull apart and open holes.
        None => match weld(&mesh)? {
            (Some(w), bodies)
                if 2 * w.mesh.num_vertices() <= mesh.num_vertices()
                    || closes_open_edges(&mesh, &w.mesh) =>
            {
                (true, bodies, w.mesh, Some(w.vertex_map))
            }
            (_, bodies) => (false, bodies, mesh, None),
        },
    };
    // Each glTF mesh lives in its own space: a body of its own, never
    // welded to another, whose volume is restored on its own.
    let bodies = match groups.as_deref() {
        Some(g) if g.iter().any(|&x| Some(&x) != g.first()) => {
            let (of_vertex, shared) = match bodies {
                Some(b) => (b.of_vertex, b.shared),
                None => (vec![0; g.len()], Vec::new()),
            };
            let (of_vertex, count) = dense_pairs(g, &of_vertex);
            Some(FileBodies {
                of_vertex,
                count,
                shared,
            })
        }
        _ => bodies,
    };
    let bodies = bodies.map(|b| FileBodies {
        of_vertex: match &vertex_map {
            Some(map) => {
                let mut of = vec![0; mesh.num_vertices()];
                for (&k, &body) in map.iter().zip(&b.of_vertex) {
                    of[k as usize] = body;
                }
                of
            }
            None => b.of_vertex,
        },
        ..b
    });
    Ok(Document {
        welded,
        mesh,
        format,
        vertex_map,
        bodies,
        source,
    })
}

/// True when `welded` (the weld of `mesh`) has fewer open edges (edges of
/// one face) than `mesh`: welding joins rims that lie at the same place.
fn closes_open_edges(mesh: &Mesh, welded: &Mesh) -> bool {
    let (before, after) = rayon::join(
        || Topology::count_boundary_edges(mesh),
        || Topology::count_boundary_edges(welded),
    );
    after < before
}

/// Writes `doc` with `positions` (one per vertex of `doc.mesh`) as `format`.
/// Writing in the input's format keeps everything else of the file; another
/// format gets the mesh alone.
pub fn write(doc: &Document, positions: &[DVec3], format: Format) -> Result<Vec<u8>, IoError> {
    write_with(doc, positions, format, &WriteOptions::default())
}

/// [`write()`] with options: per-vertex results and STL encoding. Writing in
/// the input's format (`.gltf` and `.glb` count as one) keeps the file's
/// vertex count and order: welded vertices get their welded vertex's
/// position.
pub fn write_with(
    doc: &Document,
    positions: &[DVec3],
    format: Format,
    options: &WriteOptions,
) -> Result<Vec<u8>, IoError> {
    IoError::check_position_count(doc.mesh.num_vertices(), positions.len())?;
    let results = options.results.as_ref();
    if let Some(r) = results {
        let lengths = [
            r.label.len(),
            r.mean_curvature.len(),
            r.gaussian_curvature.len(),
            r.displacement.len(),
        ];
        if let Some(&got) = lengths
            .iter()
            .find(|&&n| n != 0 && n != doc.mesh.num_vertices())
        {
            return Err(IoError::PositionCount {
                expected: doc.mesh.num_vertices(),
                got,
            });
        }
    }
    let mut out = Vec::new();
    let same_format = matches!(
        (&doc.source, format),
        (Source::Obj(_), Format::Obj)
            | (Source::Gltf(_), Format::Gltf | Format::Glb)
            | (Source::Ply(_), Format::Ply)
            | (Source::Stl(_), Format::Stl)
            | (Source::Off(_), Format::Off)
    );
    if same_format {
        let expanded = doc.expand_positions(positions);
        let expanded_results = results.map(|r| ExpandedResults::new(r, doc.vertex_map.as_deref()));
        let results = expanded_results.as_ref().map(ExpandedResults::view);
        let results = results.as_ref();
        match (&doc.source, format) {
            (Source::Obj(src), _) => obj::write_obj(src, &expanded, &mut out)?,
            (Source::Gltf(src), _) => {
                gltf::write_gltf(src, &expanded, results, format == Format::Glb, &mut out)?
            }
            (Source::Ply(src), _) => ply::write_ply(src, &expanded, results, &mut out)?,
            (Source::Stl(src), _) => stl::write_stl(src, &expanded, options.stl_ascii, &mut out)?,
            (Source::Off(src), _) => off::write_off(src, &expanded, &mut out)?,
        }
        return Ok(out);
    }
    let mesh = &doc.mesh;
    match format {
        Format::Obj => obj::write_obj_plain(mesh, positions, &mut out)?,
        Format::Gltf | Format::Glb => {
            gltf::write_gltf_plain(mesh, positions, results, format == Format::Glb, &mut out)?
        }
        Format::Ply => ply::write_ply_plain(mesh, positions, results, &mut out)?,
        Format::Stl => stl::write_stl_plain(mesh, positions, options.stl_ascii, &mut out)?,
        Format::Off => off::write_off_plain(mesh, positions, &mut out)?,
    }
    Ok(out)
}

/// Per-vertex results expanded to the file's vertices.
struct ExpandedResults {
    label: Vec<u8>,
    mean_curvature: Vec<f64>,
    gaussian_curvature: Vec<f64>,
    displacement: Vec<f64>,
}

impl ExpandedResults {
    fn new(r: &VertexResults, map: Option<&[u32]>) -> Self {
        fn one<T: Copy + Default>(values: &[T], map: Option<&[u32]>) -> Vec<T> {
            match map {
                Some(map) if !values.is_empty() => weld::expand(values, map),
                _ => values.to_vec(),
            }
        }
        ExpandedResults {
            label: one(r.label, map),
            mean_curvature: one(r.mean_curvature, map),
            gaussian_curvature: one(r.gaussian_curvature, map),
            displacement: one(r.displacement, map),
        }
    }

    fn view(&self) -> VertexResults<'_> {
        VertexResults {
            label: &self.label,
            mean_curvature: &self.mean_curvature,
            gaussian_curvature: &self.gaussian_curvature,
            displacement: &self.displacement,
        }
    }
}

impl Document {
    /// Positions for every vertex of the file from `positions` (one per
    /// vertex of [`Document::mesh`]): each welded vertex's position goes to
    /// all the file vertices joined into it. Without welding, a copy.
    pub fn expand_positions(&self, positions: &[DVec3]) -> Vec<DVec3> {
        match &self.vertex_map {
            Some(map) => weld::expand(positions, map),
            None => positions.to_vec(),
        }
    }

    /// Number of vertices in the file (before welding).
    pub fn num_file_vertices(&self) -> usize {
        self.vertex_map
            .as_ref()
            .map_or(self.mesh.num_vertices(), Vec::len)
    }

    /// [`write()`] as a method: `doc.write_as(positions, format)`.
    pub fn write_as(&self, positions: &[DVec3], format: Format) -> Result<Vec<u8>, IoError> {
        write(self, positions, format)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_names_parse_and_display() {
        for &f in Format::ALL {
            assert_eq!(f.name().parse::<Format>(), Ok(f));
            assert_eq!(f.to_string(), f.name());
            assert_eq!(f.name().to_uppercase().parse::<Format>(), Ok(f));
        }
        let e = "stp".parse::<Format>().unwrap_err();
        assert!(
            e.to_string().contains("`stp`") && e.to_string().contains("obj"),
            "{e}"
        );
        assert_eq!(Format::from_file_name("a/b.OBJ"), Some(Format::Obj));
        assert_eq!(Format::from_file_name("noext"), None);
        assert_eq!(
            Format::from_content_type("model/obj; charset=utf-8"),
            Some(Format::Obj)
        );
    }

    #[test]
    fn sniffing_finds_obj_keywords() {
        assert_eq!(Format::sniff(b"# c\n\nv 1 2 3\n"), Some(Format::Obj));
        assert_eq!(
            Format::sniff(b"\xEF\xBB\xBFmtllib x.mtl\r\n"),
            Some(Format::Obj)
        );
        assert_eq!(Format::sniff(b"hello world\n"), None);
        assert_eq!(Format::sniff(b""), None);
    }

    #[test]
    fn write_checks_the_position_count() {
        let text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
        let doc = read(text, Format::Obj, &ReadLimits::default()).unwrap();
        let out = doc.write_as(doc.mesh.positions(), Format::Obj).unwrap();
        assert_eq!(out, text);
        let e = write(&doc, &[DVec3::ZERO], Format::Obj).unwrap_err();
        assert_eq!(e.code(), "position_count_mismatch");
    }

    #[test]
    fn a_glb_without_the_magic_says_so() {
        for bytes in [&b""[..], b"\0\0\0\0", b"gltf\x02\0\0\0"] {
            let e = read(bytes, Format::Glb, &ReadLimits::default()).unwrap_err();
            assert_eq!(e.code(), "glb_invalid");
            assert!(e.to_string().contains("magic"), "{e}");
        }
        // glTF JSON under a .glb name is still read as glTF.
        let e = read(b"{}", Format::Glb, &ReadLimits::default()).unwrap_err();
        assert_eq!(e.code(), "gltf_invalid");
    }

    #[test]
    fn welding_is_recorded_as_done() {
        let text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
        assert!(
            !read(text, Format::Obj, &ReadLimits::default())
                .unwrap()
                .welded
        );
        let options = ReadOptions {
            weld: Some(true),
            ..ReadOptions::default()
        };
        assert!(read_with(text, Format::Obj, &options).unwrap().welded);
    }

    #[test]
    fn a_file_written_face_by_face_is_welded_by_default() {
        // A tetrahedron, each face with its own three corners.
        let corners = ["0 0 0", "1 0 0", "0 1 0", "0 0 1"];
        let mut text = String::new();
        for face in [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]] {
            for c in face {
                text += &format!("v {}\n", corners[c]);
            }
        }
        for f in 0..4 {
            text += &format!("f {} {} {}\n", 3 * f + 1, 3 * f + 2, 3 * f + 3);
        }
        let soup = text.as_bytes();
        let doc = read(soup, Format::Obj, &ReadLimits::default()).unwrap();
        assert!(doc.welded);
        assert_eq!(doc.mesh.num_vertices(), 4);
        // A few repeated positions that join no open edge (a vertex split
        // on purpose, here where two triangles touch at a corner): left as
        // the file has them.
        let shared = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 0 0\nv -1 0 0\nv 0 -1 0\nf 1 2 3\nf 4 5 6\n";
        let doc = read(shared, Format::Obj, &ReadLimits::default()).unwrap();
        assert!(!doc.welded);
        assert_eq!(doc.mesh.num_vertices(), 6);
        // A few that do (a crack: the square's diagonal split in two rims).
        let cracked = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 0\nf 1 2 3\nf 5 3 4\n";
        let doc = read(cracked, Format::Obj, &ReadLimits::default()).unwrap();
        assert!(doc.welded);
        assert_eq!(doc.mesh.num_vertices(), 4);
        // Asked not to weld, a soup stays one.
        let options = ReadOptions {
            weld: Some(false),
            ..ReadOptions::default()
        };
        let doc = read_with(soup, Format::Obj, &options).unwrap();
        assert!(!doc.welded);
        assert_eq!(doc.mesh.num_vertices(), 12);
    }
}
