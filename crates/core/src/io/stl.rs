//! STL reading and writing, ASCII and binary.
//!
//! STL stores every triangle with three vertices of its own, so the reader
//! gives vertex `3t + j` to corner `j` of triangle `t`; welding (on by
//! default for STL, see [`super::weld`]) joins them afterwards. Stored
//! facet normals are ignored on reading and recomputed on writing.
//!
//! A file is binary when its size is exactly `84 + 50 x count` (whatever
//! its first bytes say: many binary files start with `solid`), ASCII when it
//! starts with `solid`, and binary otherwise. Binary files may carry
//! trailing bytes after the last triangle (ignored); a count needing more
//! bytes than the file has is an error. ASCII errors name the 1-based line.

use super::{IoError, ReadLimits};
use crate::error::MeshError;
use crate::mesh::Mesh;
use glam::DVec3;

const FORMAT: &str = "STL";
const HEADER_LEN: usize = 80;
const FACET_LEN: usize = 50;
/// Header of binary files this crate writes; it must not start with
/// `solid`, or readers would take the file for ASCII.
const BINARY_HEADER: &[u8] = b"binary STL written by meshsmooth";

/// What an STL file needs besides the mesh to be written back.
#[derive(Debug, Clone)]
pub struct StlSource {
    /// Whether the input was ASCII.
    pub ascii: bool,
    /// The solid's name (ASCII input; empty otherwise).
    name: String,
    /// Binary input: the 80-byte header, kept unless it starts with
    /// `solid`.
    header: Option<Vec<u8>>,
    /// Binary input: the 2-byte attribute of every facet (some tools keep
    /// colours there); empty for ASCII input.
    attributes: Vec<u16>,
}

impl StlSource {
    /// Number of triangles in the file.
    pub fn num_triangles(&self) -> usize {
        self.attributes.len()
    }
}

/// Parses STL bytes into an unwelded triangle mesh (three vertices per
/// triangle, in file order) and what [`write_stl`] needs.
///
/// Errors on a count beyond `limits` (vertices count three per triangle),
/// a file too short for its count, non-finite coordinates, malformed ASCII
/// (with its line) and files without triangles.
pub fn read_stl(bytes: &[u8], limits: &ReadLimits) -> Result<(Mesh, StlSource), IoError> {
    let declared = binary_count(bytes);
    let exact_binary =
        declared.is_some_and(|n| (n as u128) * FACET_LEN as u128 + 84 == bytes.len() as u128);
    let (positions, source) = if !exact_binary && starts_with_solid(bytes) {
        read_ascii(bytes, limits)?
    } else {
        read_binary(bytes, limits)?
    };
    let num_triangles = positions.len() / 3;
    if num_triangles == 0 {
        return Err(IoError::NoFaces {
            format: FORMAT,
            message: "the file has no triangles".into(),
        });
    }
    let offsets = (0..=num_triangles).map(|t| 3 * t as u32).collect();
    let corners = (0..3 * num_triangles as u32).collect();
    let mesh = Mesh::new(positions, offsets, corners)?;
    let mut source = source;
    if source.attributes.is_empty() {
        source.attributes = vec![0; num_triangles];
    }
    Ok((mesh, source))
}

/// The triangle count a binary header declares, if the file is long enough
/// to have one.
fn binary_count(bytes: &[u8]) -> Option<u32> {
    let raw = bytes.get(HEADER_LEN..HEADER_LEN + 4)?;
    Some(u32::from_le_bytes(raw.try_into().ok()?))
}

fn starts_with_solid(bytes: &[u8]) -> bool {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    bytes
        .get(start..start + 5)
        .is_some_and(|w| w.eq_ignore_ascii_case(b"solid"))
}

fn parse_error(line: Option<usize>, message: String) -> IoError {
    IoError::Parse {
        format: FORMAT,
        line,
        message,
    }
}

fn check_counts(triangles: usize, limits: &ReadLimits) -> Result<(), IoError> {
    if triangles > limits.max_faces {
        return Err(IoError::Limit {
            what: "face",
            count: triangles,
            limit: limits.max_faces,
        });
    }
    if triangles.saturating_mul(3) > limits.max_vertices {
        return Err(IoError::Limit {
            what: "vertex",
            count: triangles.saturating_mul(3),
            limit: limits.max_vertices,
        });
    }
    Ok(())
}

fn read_binary(bytes: &[u8], limits: &ReadLimits) -> Result<(Vec<DVec3>, StlSource), IoError> {
    let Some(declared) = binary_count(bytes) else {
        return Err(parse_error(
            None,
            format!(
                "the file has {} bytes: too short for a binary STL (84-byte header) and it does not start with `solid`",
                bytes.len()
            ),
        ));
    };
    let n = declared as usize;
    let needed = (n as u128) * FACET_LEN as u128 + 84;
    if needed > bytes.len() as u128 {
        return Err(parse_error(
            None,
            format!(
                "binary STL declares {n} triangles ({needed} bytes) but the file has only {} bytes",
                bytes.len()
            ),
        ));
    }
    check_counts(n, limits)?;
    let mut positions = Vec::with_capacity(3 * n);
    let mut attributes = Vec::with_capacity(n);
    let body = bytes.get(84..84 + n * FACET_LEN).unwrap_or_default();
    for (t, facet) in body.chunks_exact(FACET_LEN).enumerate() {
        // 12 bytes of normal, then three vertices of 12 bytes each.
        for j in 0..3 {
            let at = 12 + 12 * j;
            let p = DVec3::new(
                f32_le(facet, at).into(),
                f32_le(facet, at + 4).into(),
                f32_le(facet, at + 8).into(),
            );
            if !p.is_finite() {
                return Err(parse_error(
                    None,
                    format!("triangle {t} has a non-finite coordinate (NaN or infinity)"),
                ));
            }
            positions.push(p);
        }
        attributes.push(u16::from_le_bytes([
            facet.get(48).copied().unwrap_or(0),
            facet.get(49).copied().unwrap_or(0),
        ]));
    }
    let header = bytes.get(..HEADER_LEN).map(<[u8]>::to_vec);
    let header = header.filter(|h| !starts_with_solid(h));
    let source = StlSource {
        ascii: false,
        name: String::new(),
        header,
        attributes,
    };
    Ok((positions, source))
}

fn f32_le(bytes: &[u8], at: usize) -> f32 {
    let raw = bytes.get(at..at + 4).and_then(|b| b.try_into().ok());
    f32::from_le_bytes(raw.unwrap_or([0; 4]))
}

fn read_ascii(bytes: &[u8], limits: &ReadLimits) -> Result<(Vec<DVec3>, StlSource), IoError> {
    let mut positions: Vec<DVec3> = Vec::new();
    let mut name = None;
    // Vertices seen in the current facet, or None outside a facet.
    let mut in_facet: Option<(usize, usize)> = None;
    let mut in_solid = false;
    for (index, raw_line) in bytes.split(|&b| b == b'\n').enumerate() {
        let line = index + 1;
        let mut words = raw_line
            .split(|b| b.is_ascii_whitespace())
            .filter(|w| !w.is_empty());
        let Some(keyword) = words.next() else {
            continue;
        };
        let mut lower = [0u8; 16];
        match lowercase(keyword, &mut lower) {
            b"solid" => {
                if in_solid {
                    return Err(parse_error(Some(line), "`solid` inside a solid".into()));
                }
                in_solid = true;
                if name.is_none() {
                    let text = raw_line.get(raw_line.len().min(first_word_end(raw_line))..);
                    let text = String::from_utf8_lossy(text.unwrap_or_default());
                    name = Some(text.trim().to_owned());
                }
            }
            b"endsolid" => {
                if in_facet.is_some() {
                    return Err(parse_error(
                        Some(line),
                        "`endsolid` inside an unfinished facet".into(),
                    ));
                }
                in_solid = false;
            }
            b"facet" => {
                if !in_solid {
                    return Err(parse_error(
                        Some(line),
                        "`facet` outside `solid` ... `endsolid`".into(),
                    ));
                }
                if in_facet.is_some() {
                    return Err(parse_error(
                        Some(line),
                        "`facet` before the previous facet's `endfacet`".into(),
                    ));
                }
                let triangles = positions.len() / 3 + 1;
                check_counts(triangles, limits)?;
                in_facet = Some((line, 0));
            }
            b"outer" | b"endloop" => {
                if in_facet.is_none() {
                    return Err(parse_error(
                        Some(line),
                        format!("`{}` outside a facet", String::from_utf8_lossy(keyword)),
                    ));
                }
            }
            b"vertex" => positions.push(facet_vertex(in_facet.as_mut(), words, line)?),
            b"endfacet" => end_facet(in_facet.take(), line)?,
            other => {
                return Err(parse_error(
                    Some(line),
                    format!(
                        "unknown keyword `{}` in ASCII STL",
                        String::from_utf8_lossy(other.get(..other.len().min(40)).unwrap_or(other))
                    ),
                ));
            }
        }
    }
    if let Some((start, _)) = in_facet {
        return Err(parse_error(
            Some(start),
            "the file ends inside the facet that starts here".into(),
        ));
    }
    let source = StlSource {
        ascii: true,
        name: name.unwrap_or_default(),
        header: None,
        attributes: Vec::new(),
    };
    Ok((positions, source))
}

/// `keyword` in lower case, in `buf` when it fits (keywords are matched
/// case-insensitively without allocating).
fn lowercase<'a>(keyword: &'a [u8], buf: &'a mut [u8; 16]) -> &'a [u8] {
    match buf.get_mut(..keyword.len()) {
        Some(buf) => {
            buf.copy_from_slice(keyword);
            buf.make_ascii_lowercase();
            buf
        }
        None => keyword,
    }
}

/// The vertex of a `vertex` line (its coordinates in `words`) inside the
/// facet `in_facet` (its first line and vertices so far), counted there.
fn facet_vertex<'w>(
    in_facet: Option<&mut (usize, usize)>,
    mut words: impl Iterator<Item = &'w [u8]>,
    line: usize,
) -> Result<DVec3, IoError> {
    let Some((start, count)) = in_facet else {
        return Err(parse_error(Some(line), "`vertex` outside a facet".into()));
    };
    if *count == 3 {
        return Err(parse_error(
            Some(line),
            format!(
                "the facet that starts on line {start} has more than 3 vertices; STL facets are triangles"
            ),
        ));
    }
    *count += 1;
    let mut xyz = [0.0; 3];
    for (axis, value) in ["x", "y", "z"].into_iter().zip(xyz.iter_mut()) {
        let word = words.next().ok_or_else(|| {
            parse_error(
                Some(line),
                format!("`vertex` needs x, y and z; {axis} is missing"),
            )
        })?;
        *value = parse_number(word).ok_or_else(|| {
            parse_error(
                Some(line),
                format!(
                    "{axis} coordinate `{}` is not a number within the float32 range",
                    String::from_utf8_lossy(word.get(..word.len().min(40)).unwrap_or(word))
                ),
            )
        })?;
    }
    Ok(DVec3::from_array(xyz))
}

/// Checks the facet an `endfacet` line closes (its first line and vertex
/// count).
fn end_facet(facet: Option<(usize, usize)>, line: usize) -> Result<(), IoError> {
    let Some((start, count)) = facet else {
        return Err(parse_error(Some(line), "`endfacet` without `facet`".into()));
    };
    if count != 3 {
        return Err(parse_error(
            Some(line),
            format!(
                "the facet that starts on line {start} has {count} vertices; STL facets are triangles"
            ),
        ));
    }
    Ok(())
}

fn first_word_end(line: &[u8]) -> usize {
    let start = line
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(line.len());
    start
        + line
            .get(start..)
            .unwrap_or_default()
            .iter()
            .position(|b| b.is_ascii_whitespace())
            .unwrap_or(line.len() - start)
}

/// A coordinate within the f32 range (binary STL, which the writer
/// produces by default, stores f32).
fn parse_number(word: &[u8]) -> Option<f64> {
    let value: f64 = std::str::from_utf8(word).ok()?.parse().ok()?;
    (value.abs() <= f64::from(f32::MAX)).then_some(value)
}

/// Writes the triangles of an STL file read by [`read_stl`] with
/// `positions` (one per original vertex: three per triangle, in file
/// order). Binary unless `ascii`; a binary file keeps the input's header and
/// facet attributes. Normals are recomputed.
pub fn write_stl(
    src: &StlSource,
    positions: &[DVec3],
    ascii: bool,
    out: &mut Vec<u8>,
) -> Result<(), IoError> {
    let n = src.num_triangles();
    IoError::check_position_count(3 * n, positions.len())?;
    let triangles = positions.chunks_exact(3).map(|t| [t[0], t[1], t[2]]);
    if ascii {
        write_ascii(&src.name, triangles, out)
    } else {
        let header = src.header.as_deref().unwrap_or(BINARY_HEADER);
        write_binary(
            header,
            n,
            triangles.zip(src.attributes.iter().copied()),
            out,
        )
    }
}

/// Writes `mesh` with `positions` (one per vertex) as STL, binary unless
/// `ascii`; faces with more than three corners are split into a fan from
/// their first corner.
pub fn write_stl_plain(
    mesh: &Mesh,
    positions: &[DVec3],
    ascii: bool,
    out: &mut Vec<u8>,
) -> Result<(), IoError> {
    IoError::check_position_count(mesh.num_vertices(), positions.len())?;
    let at = |i: u32| positions.get(i as usize).copied().unwrap_or_default();
    let triangles = mesh.faces().flat_map(|face| {
        let first = face.first().copied().unwrap_or(0);
        face.windows(2)
            .skip(1)
            .map(move |w| [at(first), at(w[0]), at(w[1])])
    });
    if ascii {
        write_ascii("meshsmooth", triangles, out)
    } else {
        let n = mesh.faces().map(|f| f.len() - 2).sum();
        write_binary(BINARY_HEADER, n, triangles.map(|t| (t, 0)), out)
    }
}

fn facet_normal(t: &[DVec3; 3]) -> DVec3 {
    (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero()
}

/// `p` as f32, refusing values that are not finite in f32.
fn to_f32(p: DVec3, triangle: usize) -> Result<[f32; 3], IoError> {
    let q = [p.x as f32, p.y as f32, p.z as f32];
    if q.iter().all(|c| c.is_finite()) {
        Ok(q)
    } else {
        Err(MeshError::NonFinitePosition {
            vertex: 3 * triangle,
        }
        .into())
    }
}

fn write_binary(
    header: &[u8],
    n: usize,
    triangles: impl Iterator<Item = ([DVec3; 3], u16)>,
    out: &mut Vec<u8>,
) -> Result<(), IoError> {
    let count = u32::try_from(n).map_err(|_| IoError::Limit {
        what: "STL triangle",
        count: n,
        limit: u32::MAX as usize,
    })?;
    out.reserve(84 + FACET_LEN * n);
    let mut head = [0u8; HEADER_LEN];
    let len = header.len().min(HEADER_LEN);
    head[..len].copy_from_slice(&header[..len]);
    out.extend_from_slice(&head);
    out.extend_from_slice(&count.to_le_bytes());
    for (t, (tri, attribute)) in triangles.enumerate() {
        let normal = facet_normal(&tri);
        for c in [normal.x as f32, normal.y as f32, normal.z as f32] {
            out.extend_from_slice(&c.to_le_bytes());
        }
        for p in tri {
            for c in to_f32(p, t)? {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        out.extend_from_slice(&attribute.to_le_bytes());
    }
    Ok(())
}

fn write_ascii(
    name: &str,
    triangles: impl Iterator<Item = [DVec3; 3]>,
    out: &mut Vec<u8>,
) -> Result<(), IoError> {
    // A name must stay on the `solid` line.
    let name: String = name.chars().filter(|c| !c.is_control()).collect();
    out.extend_from_slice(b"solid ");
    out.extend_from_slice(name.as_bytes());
    out.push(b'\n');
    let mut buffer = zmij::Buffer::new();
    let mut number = |out: &mut Vec<u8>, x: f64| {
        out.push(b' ');
        out.extend_from_slice(buffer.format_finite(x).as_bytes());
    };
    for (t, tri) in triangles.enumerate() {
        let normal = facet_normal(&tri);
        out.extend_from_slice(b"facet normal");
        for c in normal.to_array() {
            number(out, c);
        }
        out.extend_from_slice(b"\n outer loop\n");
        for (j, p) in tri.iter().enumerate() {
            if !p.is_finite() {
                return Err(MeshError::NonFinitePosition { vertex: 3 * t + j }.into());
            }
            out.extend_from_slice(b"  vertex");
            for c in p.to_array() {
                number(out, c);
            }
            out.push(b'\n');
        }
        out.extend_from_slice(b" endloop\nendfacet\n");
    }
    out.extend_from_slice(b"endsolid ");
    out.extend_from_slice(name.as_bytes());
    out.push(b'\n');
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const TETRA_ASCII: &str = "solid tetra\n\
        facet normal 0 0 -1\n outer loop\n  vertex 0 0 0\n  vertex 0 1 0\n  vertex 1 0 0\n endloop\nendfacet\n\
        facet normal 0 -1 0\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  vertex 0 0 1\n endloop\nendfacet\n\
        facet normal -1 0 0\n outer loop\n  vertex 0 0 0\n  vertex 0 0 1\n  vertex 0 1 0\n endloop\nendfacet\n\
        facet normal 1 1 1\n outer loop\n  vertex 1 0 0\n  vertex 0 1 0\n  vertex 0 0 1\n endloop\nendfacet\n\
        endsolid tetra\n";

    #[test]
    fn ascii_reads_three_vertices_per_triangle() {
        let (mesh, src) = read_stl(TETRA_ASCII.as_bytes(), &ReadLimits::default()).unwrap();
        assert!(src.ascii);
        assert_eq!(src.name, "tetra");
        assert_eq!(mesh.num_faces(), 4);
        assert_eq!(mesh.num_vertices(), 12);
        assert_eq!(mesh.face(3), &[9, 10, 11]);
        assert_eq!(mesh.positions()[11], DVec3::Z);
    }

    #[test]
    fn binary_round_trip_keeps_positions_header_and_attributes() {
        let (mesh, ascii_src) = read_stl(TETRA_ASCII.as_bytes(), &ReadLimits::default()).unwrap();
        let mut bin = Vec::new();
        write_stl(&ascii_src, mesh.positions(), false, &mut bin).unwrap();
        assert_eq!(bin.len(), 84 + 4 * 50);
        // Give triangle 2 an attribute and a custom header, then round-trip.
        bin[84 + 2 * 50 + 48] = 7;
        bin[..6].copy_from_slice(b"custom");
        let (again, src) = read_stl(&bin, &ReadLimits::default()).unwrap();
        assert!(!src.ascii);
        assert_eq!(again.positions(), mesh.positions());
        let mut out = Vec::new();
        write_stl(&src, again.positions(), false, &mut out).unwrap();
        assert_eq!(out, bin);
        // The stored normal of the slanted face is the recomputed one.
        let n = f32_le(&out, 84 + 3 * 50);
        assert!((n - 1.0 / 3f32.sqrt()).abs() < 1e-6, "{n}");
    }

    #[test]
    fn binary_starting_with_solid_is_binary_when_the_size_matches() {
        let (mesh, src) = read_stl(TETRA_ASCII.as_bytes(), &ReadLimits::default()).unwrap();
        let mut bin = Vec::new();
        write_stl(&src, mesh.positions(), false, &mut bin).unwrap();
        bin[..12].copy_from_slice(b"solid binary");
        let (again, src) = read_stl(&bin, &ReadLimits::default()).unwrap();
        assert!(!src.ascii);
        assert_eq!(again.positions(), mesh.positions());
        assert!(src.header.is_none(), "a `solid` header is not written back");
    }

    #[test]
    fn ascii_writer_round_trips() {
        let (mesh, src) = read_stl(TETRA_ASCII.as_bytes(), &ReadLimits::default()).unwrap();
        let mut text = Vec::new();
        write_stl(&src, mesh.positions(), true, &mut text).unwrap();
        let (again, src2) = read_stl(&text, &ReadLimits::default()).unwrap();
        assert!(src2.ascii);
        assert_eq!(again, mesh);
    }

    #[test]
    fn plain_writer_fans_polygons() {
        let quad = Mesh::from_polygons(
            vec![DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y],
            &[[0u32, 1, 2, 3]],
        )
        .unwrap();
        let mut bin = Vec::new();
        write_stl_plain(&quad, quad.positions(), false, &mut bin).unwrap();
        let (mesh, _) = read_stl(&bin, &ReadLimits::default()).unwrap();
        assert_eq!(mesh.num_faces(), 2);
        assert_eq!(
            mesh.positions()[3..6],
            [DVec3::ZERO, DVec3::new(1.0, 1.0, 0.0), DVec3::Y]
        );
    }

    #[test]
    fn errors_are_specific() {
        let limits = ReadLimits::default();
        let code = |b: &[u8]| read_stl(b, &limits).unwrap_err();
        let e = code(b"solid x\nfacet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0\n");
        assert!(
            e.to_string().contains("line 5") && e.to_string().contains("z is missing"),
            "{e}"
        );
        let e = code(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\nendfacet\nendsolid\n");
        assert!(e.to_string().contains("has 2 vertices"), "{e}");
        let e = code(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex nan 0 0\n");
        assert!(e.to_string().contains("not a number within"), "{e}");
        let e = code(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 1e39 0 0\n");
        assert!(e.to_string().contains("`1e39`"), "{e}");
        let e = code(b"solid x\nendsolid x\n");
        assert_eq!(e.code(), "no_faces");
        let mut short = vec![0u8; 84];
        short[80] = 5;
        let e = code(&short);
        assert!(e.to_string().contains("declares 5 triangles"), "{e}");
        assert_eq!(code(b"abc").code(), "parse_error");
        let mut huge = vec![0u8; 84 + 50];
        huge[80..84].copy_from_slice(&1u32.to_le_bytes());
        let tight = ReadLimits {
            max_vertices: 2,
            ..ReadLimits::default()
        };
        assert_eq!(
            read_stl(&huge, &tight).unwrap_err().code(),
            "limit_exceeded"
        );
    }
}
