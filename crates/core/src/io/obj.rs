//! Wavefront OBJ reading and writing.
//!
//! The reader is one streaming pass over the bytes. It understands `v`
//! (x y z, any extra fields such as `w` or vertex colours are kept as text)
//! and `f` (corners `v`, `v/vt`, `v//vn`, `v/vt/vn`, negative indices
//! relative to the vertices defined so far, any arity of at least 3). Every
//! other line (`vt`, `vn`, `o`, `g`, `s`, `usemtl`, `mtllib`, `l`, `p`,
//! comments, unknown statements) is kept as bytes and written back
//! unchanged; `mtllib` paths are never opened. Writing a file back rewrites
//! only the `x y z` fields of the `v` lines.
//!
//! Accepted: `\n` and `\r\n` line endings, a UTF-8 byte-order mark,
//! trailing `#` comments, and bytes that are not UTF-8 inside lines that are
//! copied verbatim (comments, group names). Rejected with an error naming
//! the 1-based line: UTF-16 text (NUL bytes), bad numbers, faces with fewer
//! than 3 corners (code `parse_error`), NaN or infinite coordinates
//! (`non_finite_coordinate`), index 0 and indices out of range
//! (`face_index_out_of_range`); and files without any face (`no_faces`:
//! smoothing needs a surface).

use super::text::{
    Fields, TextSource, check_encoding, for_each_line, parse_index, shorten, write_xyz,
};
use super::{IoError, ReadLimits};
use crate::mesh::Mesh;
use glam::DVec3;

const FORMAT: &str = "OBJ";

/// What an OBJ file needs besides the mesh to be written back.
pub type ObjSource = TextSource;

/// Parses OBJ bytes into a mesh (one vertex per `v` line, one face per `f`
/// line, both in file order) and what [`write_obj`] needs to write the file
/// back.
///
/// Errors name the 1-based line and the problem; counts beyond `limits` are
/// refused while parsing. A file without faces is an error.
pub fn read_obj(bytes: &[u8], limits: &ReadLimits) -> Result<(Mesh, ObjSource), IoError> {
    check_encoding(bytes, FORMAT)?;
    let mut reader = Reader::new(limits);
    for_each_line(bytes, |text, offset, line| reader.line(text, offset, line))?;
    reader.finish(bytes)
}

/// Writes the file `src` was read from with `positions` (one per vertex) in
/// place of the `x y z` fields of its `v` lines; every other byte is copied
/// unchanged. Coordinates are printed with shortest round-trip precision.
pub fn write_obj(src: &ObjSource, positions: &[DVec3], out: &mut Vec<u8>) -> Result<(), IoError> {
    src.write(positions, out)
}

/// Writes `mesh` with `positions` (one per vertex) as a plain OBJ: one
/// `v x y z` line per vertex, then one `f` line per face (1-based indices).
/// Used when the input was in another format.
pub fn write_obj_plain(mesh: &Mesh, positions: &[DVec3], out: &mut Vec<u8>) -> Result<(), IoError> {
    IoError::check_position_count(mesh.num_vertices(), positions.len())?;
    out.reserve(40 * positions.len() + 8 * mesh.face_vertices().len());
    for (v, p) in positions.iter().enumerate() {
        out.extend_from_slice(b"v ");
        write_xyz(out, v, *p)?;
        out.push(b'\n');
    }
    for face in mesh.faces() {
        out.push(b'f');
        for &i in face {
            out.push(b' ');
            out.extend_from_slice(itoa::Buffer::new().format(u64::from(i) + 1).as_bytes());
        }
        out.push(b'\n');
    }
    Ok(())
}

fn parse_error(line: usize, message: String) -> IoError {
    IoError::Parse {
        format: FORMAT,
        line: Some(line),
        message,
    }
}

fn index_error(line: usize, message: String) -> IoError {
    IoError::IndexOutOfRange {
        format: FORMAT,
        line: Some(line),
        message,
    }
}

/// Parser state: the mesh so far plus what is needed to check positive
/// indices against the final vertex count.
struct Reader<'l> {
    limits: &'l ReadLimits,
    positions: Vec<DVec3>,
    coords: Vec<(usize, usize)>,
    face_offsets: Vec<u32>,
    face_vertices: Vec<u32>,
    /// `(line, index)` of forward references (1-based index beyond the
    /// vertices defined so far), each larger than the one before, so the
    /// first entry beyond the final count is the first offending line.
    forward_refs: Vec<(usize, u64)>,
    /// Lines with `l` or `p` elements, for the no-faces message.
    line_elements: usize,
}

impl<'l> Reader<'l> {
    fn new(limits: &'l ReadLimits) -> Self {
        Reader {
            limits,
            positions: Vec::new(),
            coords: Vec::new(),
            face_offsets: vec![0],
            face_vertices: Vec::new(),
            forward_refs: Vec::new(),
            line_elements: 0,
        }
    }

    /// Handles one line (without its `\n`) that starts at byte `offset`.
    fn line(&mut self, text: &[u8], offset: usize, line: usize) -> Result<(), IoError> {
        let mut fields = Fields::new(text);
        match fields.next_field() {
            Some((_, _, b"v")) => self.vertex(fields, offset, line),
            Some((_, _, b"f")) => self.face(fields, line),
            Some((_, _, b"l" | b"p")) => {
                self.line_elements += 1;
                Ok(())
            }
            _ => Ok(()),
        }
    }

    fn vertex(&mut self, mut fields: Fields, offset: usize, line: usize) -> Result<(), IoError> {
        if self.positions.len() >= self.limits.max_vertices {
            return Err(IoError::Limit {
                what: "vertex",
                count: self.positions.len() + 1,
                limit: self.limits.max_vertices,
            });
        }
        let (position, (start, end)) = fields.xyz("`v`", line, FORMAT)?;
        self.positions.push(position);
        self.coords.push((offset + start, offset + end));
        Ok(())
    }

    fn face(&mut self, mut fields: Fields, line: usize) -> Result<(), IoError> {
        let num_faces = self.face_offsets.len() - 1;
        if num_faces >= self.limits.max_faces {
            return Err(IoError::Limit {
                what: "face",
                count: num_faces + 1,
                limit: self.limits.max_faces,
            });
        }
        let first = self.face_vertices.len();
        while let Some((_, _, field)) = fields.next_field() {
            let index = parse_corner(field).map_err(|m| parse_error(line, m))?;
            if index == 0 {
                return Err(index_error(
                    line,
                    format!(
                        "face corner `{}` uses index 0; OBJ indices start at 1",
                        shorten(&String::from_utf8_lossy(field))
                    ),
                ));
            }
            let defined = self.positions.len() as u64;
            let resolved = if index < 0 {
                let back = index.unsigned_abs();
                if back > defined {
                    return Err(index_error(
                        line,
                        format!(
                            "relative vertex index {index} points before the first vertex: \
                             only {defined} vertices are defined above this line"
                        ),
                    ));
                }
                defined - back
            } else {
                let one_based = index.unsigned_abs();
                if one_based > defined
                    && self.forward_refs.last().is_none_or(|&(_, i)| one_based > i)
                {
                    self.forward_refs.push((line, one_based));
                }
                one_based - 1
            };
            let resolved = u32::try_from(resolved)
                .map_err(|_| index_error(line, format!("vertex index {index} is too large")))?;
            self.face_vertices.push(resolved);
        }
        let arity = self.face_vertices.len() - first;
        if arity < 3 {
            return Err(parse_error(
                line,
                format!("a face needs at least 3 corners, this one has {arity}"),
            ));
        }
        let end = u32::try_from(self.face_vertices.len()).map_err(|_| IoError::Limit {
            what: "face corner",
            count: self.face_vertices.len(),
            limit: u32::MAX as usize - 1,
        })?;
        self.face_offsets.push(end);
        Ok(())
    }

    fn finish(self, bytes: &[u8]) -> Result<(Mesh, ObjSource), IoError> {
        let n = self.positions.len() as u64;
        if let Some(&(line, index)) = self.forward_refs.iter().find(|&&(_, i)| i > n) {
            return Err(index_error(
                line,
                format!("face refers to vertex {index}, but the file defines only {n} vertices"),
            ));
        }
        if self.face_offsets.len() == 1 {
            let elements = if self.line_elements > 0 {
                format!(
                    " ({} `l`/`p` line or point elements are not faces)",
                    self.line_elements
                )
            } else {
                String::new()
            };
            return Err(IoError::NoFaces {
                format: FORMAT,
                message: format!(
                    "the file has {n} vertices and no `f` faces{elements}; smoothing needs a surface"
                ),
            });
        }
        let mesh = Mesh::new(self.positions, self.face_offsets, self.face_vertices)?;
        let src = TextSource::new(bytes, self.coords);
        Ok((mesh, src))
    }
}

/// Parses one face corner `v`, `v/vt`, `v//vn` or `v/vt/vn` and returns its
/// vertex index as written (1-based, negative for relative, or 0, which the
/// caller refuses as out of range). Texture and normal indices must be
/// integers when present; their range is not checked because `vt`/`vn`
/// lines are carried through untouched.
fn parse_corner(field: &[u8]) -> Result<i64, String> {
    let shown = || shorten(&String::from_utf8_lossy(field)).to_owned();
    let mut parts = field.split(|&b| b == b'/');
    let vertex = parts.next().unwrap_or_default();
    let index = parse_index(vertex).ok_or_else(|| {
        if field == b"\\" {
            "line continuations (`\\`) are not supported; put the face on one line".to_owned()
        } else {
            format!(
                "face corner `{}` does not start with a vertex index",
                shown()
            )
        }
    })?;
    let mut extra = 0;
    for part in parts {
        extra += 1;
        if extra > 2 || (!part.is_empty() && parse_index(part).is_none()) {
            return Err(format!(
                "face corner `{}` is not of the form v, v/vt, v//vn or v/vt/vn",
                shown()
            ));
        }
    }
    Ok(index)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<(Mesh, ObjSource), IoError> {
        read_obj(text.as_bytes(), &ReadLimits::default())
    }

    fn faces(mesh: &Mesh) -> Vec<Vec<u32>> {
        mesh.faces().map(<[u32]>::to_vec).collect()
    }

    fn err_line(text: &str) -> (Option<usize>, String) {
        match read(text) {
            Err(
                IoError::Parse { line, message, .. }
                | IoError::IndexOutOfRange { line, message, .. }
                | IoError::NonFiniteCoordinate { line, message, .. },
            ) => (line, message),
            other => panic!("expected a parse error, got {other:?}"),
        }
    }

    const SQUARE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

    #[test]
    fn every_corner_form_gives_the_same_face() {
        for f in [
            "f 1 2 3 4",
            "f 1/1 2/2 3/3 4/4",
            "f 1//1 2//1 3//1 4//1",
            "f 1/1/1 2/2/1 3/3/1 4/4/1",
            "f -4 -3 -2 -1",
            "f -4/-1/-1 2 -2//2 +4",
            "f\t1 2   3\t4  # trailing comment",
        ] {
            let (mesh, _) = read(&format!("{SQUARE}{f}\n")).unwrap();
            assert_eq!(faces(&mesh), vec![vec![0, 1, 2, 3]], "{f}");
        }
    }

    #[test]
    fn negative_indices_are_relative_to_the_vertices_defined_so_far() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 1 1 0\nf -3 -1 -2\n";
        let (mesh, _) = read(text).unwrap();
        assert_eq!(faces(&mesh), vec![vec![0, 1, 2], vec![1, 3, 2]]);
    }

    #[test]
    fn positive_indices_may_refer_forward() {
        let (mesh, _) = read("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
        assert_eq!(faces(&mesh), vec![vec![0, 1, 2]]);
    }

    #[test]
    fn coordinates_and_arity_are_read() {
        let text =
            "v 1.5 -2e-3 +4.\nv .25 0 1E2\nv 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3 4 5\nf 1 2 3\n";
        let (mesh, _) = read(text).unwrap();
        assert_eq!(mesh.positions()[0], DVec3::new(1.5, -0.002, 4.0));
        assert_eq!(mesh.positions()[1], DVec3::new(0.25, 0.0, 100.0));
        assert_eq!(mesh.face(0).len(), 5);
        assert_eq!(mesh.face(1).len(), 3);
    }

    #[test]
    fn other_lines_survive_byte_for_byte() {
        let text = "\u{feff}# header\r\nmtllib a.mtl\r\no thing\r\n\r\nv  1 2 3 0.5 0.25 0.125 # colour\r\n\
                    v\t4 5 6\r\nv 7 8 9\r\nvt 0 1\r\nvn 0 0 1\r\ng grp\r\ns off\r\nusemtl m\r\n\
                    l 1 2\r\np 3\r\nf 1/1/1 2/1/1 3/1/1\r\nweird statement here\r\nv 1e0 2 3";
        let (mesh, src) = read(text).unwrap();
        let mut out = Vec::new();
        write_obj(&src, mesh.positions(), &mut out).unwrap();
        let expected = text.replace("v 1e0 2 3", "v 1 2 3");
        assert_eq!(String::from_utf8(out).unwrap(), expected);

        let moved: Vec<DVec3> = mesh.positions().iter().map(|p| *p * 0.1).collect();
        let mut out = Vec::new();
        write_obj(&src, &moved, &mut out).unwrap();
        let out = String::from_utf8(out).unwrap();
        assert!(
            out.starts_with("\u{feff}# header\r\nmtllib a.mtl\r\n"),
            "{out}"
        );
        assert!(out.contains("\r\nv  0.1 0.2 0.30000000000000004 0.5 0.25 0.125 # colour\r\n"));
        assert!(out.contains("\r\nv\t0.4 0.5 0.6000000000000001\r\n"));
        assert!(out.ends_with("weird statement here\r\nv 0.1 0.2 0.30000000000000004"));
        let (again, _) = read(&out).unwrap();
        assert_eq!(again.positions(), &moved[..]);
        assert_eq!(faces(&again), faces(&mesh));
    }

    #[test]
    fn plain_writer_round_trips() {
        let (mesh, _) = read(&format!("{SQUARE}f 1 2 3 4\nf 4 3 1\n")).unwrap();
        let moved: Vec<DVec3> = mesh.positions().iter().map(|p| *p + 1.0 / 3.0).collect();
        let mut out = Vec::new();
        write_obj_plain(&mesh, &moved, &mut out).unwrap();
        let (again, _) = read(std::str::from_utf8(&out).unwrap()).unwrap();
        assert_eq!(again.positions(), &moved[..]);
        assert_eq!(faces(&again), faces(&mesh));
    }

    #[test]
    fn writers_reject_wrong_counts_and_non_finite_positions() {
        let (mesh, src) = read(&format!("{SQUARE}f 1 2 3 4\n")).unwrap();
        let mut out = Vec::new();
        let short = &mesh.positions()[..3];
        assert!(matches!(
            write_obj(&src, short, &mut out),
            Err(IoError::PositionCount {
                expected: 4,
                got: 3
            })
        ));
        assert!(matches!(
            write_obj_plain(&mesh, short, &mut out),
            Err(IoError::PositionCount {
                expected: 4,
                got: 3
            })
        ));
        let mut bad = mesh.positions().to_vec();
        bad[2].z = f64::INFINITY;
        let e = write_obj(&src, &bad, &mut out).unwrap_err();
        assert_eq!(e.code(), "non_finite_coordinate");
    }

    #[test]
    fn errors_name_the_line_and_the_problem() {
        let (line, msg) = err_line("v 0 0 0\nv 1 0 0\n\nv 3.1+e2 0 0\nf 1 2 3\n");
        assert_eq!(line, Some(4));
        assert!(
            msg.contains("`3.1+e2`") && msg.contains("x coordinate"),
            "{msg}"
        );

        let (line, msg) = err_line("v 0 0 0\nv 1 nan 0\n");
        assert_eq!(line, Some(2));
        assert!(msg.contains("not finite"), "{msg}");

        let (line, msg) = err_line("v 0 0 0\nv 1 0 1e999\n");
        assert_eq!(line, Some(2));
        assert!(msg.contains("not finite"), "{msg}");

        let (line, msg) = err_line("v 0 0\n");
        assert_eq!(line, Some(1));
        assert!(msg.contains("z is missing"), "{msg}");

        let (line, msg) = err_line(&format!("{SQUARE}f 1 2 0\n"));
        assert_eq!(line, Some(5));
        assert!(msg.contains("index 0"), "{msg}");

        let (line, msg) = err_line(&format!("{SQUARE}f 1 2 3\nf 1 2 7\nf 1 2 9\n"));
        assert_eq!(line, Some(6));
        assert!(
            msg.contains("vertex 7") && msg.contains("only 4 vertices"),
            "{msg}"
        );

        let (line, msg) = err_line("v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n");
        assert_eq!(line, Some(3));
        assert!(
            msg.contains("-3") && msg.contains("only 2 vertices"),
            "{msg}"
        );

        let (line, msg) = err_line(&format!("{SQUARE}f 1// 2//\n"));
        assert_eq!(line, Some(5));
        assert!(
            msg.contains("at least 3 corners") && msg.contains("has 2"),
            "{msg}"
        );

        let (line, msg) = err_line(&format!("{SQUARE}f 1/2/3/4 2 3\n"));
        assert_eq!(line, Some(5));
        assert!(msg.contains("`1/2/3/4`"), "{msg}");

        let (line, msg) = err_line(&format!("{SQUARE}f 1 x 3\n"));
        assert_eq!(line, Some(5));
        assert!(msg.contains("`x`"), "{msg}");

        let (line, msg) = err_line(&format!("{SQUARE}f 1 2 99999999999999999999\n"));
        assert_eq!(line, Some(5));
        assert!(msg.contains("99999999999999999999"), "{msg}");

        let (line, _) = err_line("v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3 4\r\n");
        assert_eq!(line, Some(4));
    }

    #[test]
    fn bad_indices_and_coordinates_have_their_own_codes() {
        let code = |text: &str| {
            let e = read(text).unwrap_err();
            assert!(e.to_string().contains("OBJ parse error on line"), "{e}");
            (e.code(), e.to_string())
        };
        for (text, line) in [
            (format!("{SQUARE}f 1 2 9\n"), 5),
            (format!("{SQUARE}f 1 2 3\nf 1 2 0\n"), 6),
            ("v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n".to_owned(), 3),
            (format!("{SQUARE}f 1 2 4294967297\n"), 5),
            (format!("{SQUARE}f 1 2 7/1/1\n"), 5),
        ] {
            let (code, message) = code(&text);
            assert_eq!(code, "face_index_out_of_range", "{message}");
            assert!(message.contains(&format!("line {line}")), "{message}");
        }
        for text in [
            "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n",
            "v 0 0 0\nv 0 -inf 0\nv 0 1 0\nf 1 2 3\n",
            "v 0 0 0\nv 0 0 1e400\nv 0 1 0\nf 1 2 3\n",
        ] {
            let (code, message) = code(text);
            assert_eq!(code, "non_finite_coordinate", "{message}");
            assert!(message.contains("line 2"), "{message}");
        }
        // Malformed numbers and corners stay parse errors.
        assert_eq!(code("v 0 0 0\nv x 0 0\n").0, "parse_error");
        assert_eq!(code(&format!("{SQUARE}f 1 x 3\n")).0, "parse_error");
        assert_eq!(code(&format!("{SQUARE}f 1 2\n")).0, "parse_error");
    }

    #[test]
    fn encodings_that_are_not_utf8_text_are_refused() {
        let utf16: Vec<u8> = "v 0 0 0\n"
            .encode_utf16()
            .flat_map(u16::to_be_bytes)
            .collect();
        for bytes in [[&b"\xFE\xFF"[..], &utf16].concat(), utf16.clone()] {
            let e = read_obj(&bytes, &ReadLimits::default()).unwrap_err();
            assert_eq!(e.code(), "parse_error");
            assert!(e.to_string().contains("UTF-16"), "{e}");
        }
        let e = read("v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3\r").unwrap_err();
        assert!(e.to_string().contains("carriage return"), "{e}");
    }

    #[test]
    fn non_utf8_bytes_in_copied_lines_are_kept() {
        let mut bytes = b"# caf\xE9\nv 0 0 0\nv 1 0 0\nv 0 1 0\ng gr\xFCn\nf 1 2 3\n".to_vec();
        let (mesh, src) = read_obj(&bytes, &ReadLimits::default()).unwrap();
        let mut out = Vec::new();
        write_obj(&src, mesh.positions(), &mut out).unwrap();
        assert_eq!(out, bytes);
        bytes.extend_from_slice(b"v 1 \xE9 0\n");
        let e = read_obj(&bytes, &ReadLimits::default()).unwrap_err();
        assert!(e.to_string().contains("line 7"), "{e}");
    }

    #[test]
    fn files_without_faces_are_refused() {
        let e = read("v 0 0 0\nv 1 0 0\nl 1 2\n").unwrap_err();
        assert_eq!(e.code(), "no_faces");
        assert!(e.to_string().contains("2 vertices"), "{e}");
        assert!(e.to_string().contains("`l`/`p`"), "{e}");
        assert_eq!(read("").unwrap_err().code(), "no_faces");
    }

    #[test]
    fn limits_are_enforced_while_parsing() {
        let limits = ReadLimits {
            max_vertices: 3,
            max_faces: 1,
        };
        let e = read_obj(format!("{SQUARE}f 1 2 3\n").as_bytes(), &limits).unwrap_err();
        assert!(
            matches!(
                e,
                IoError::Limit {
                    what: "vertex",
                    limit: 3,
                    ..
                }
            ),
            "{e:?}"
        );
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 3 2 1\n";
        let e = read_obj(text.as_bytes(), &limits).unwrap_err();
        assert!(
            matches!(
                e,
                IoError::Limit {
                    what: "face",
                    limit: 1,
                    ..
                }
            ),
            "{e:?}"
        );
        assert_eq!(e.code(), "limit_exceeded");
    }
}
