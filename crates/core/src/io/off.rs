//! OFF (Geomview's Object File Format) reading and writing: the format of
//! GAMer's molecular surfaces, CGAL and many shape collections.
//!
//! The reader is one pass over the lines. A file starts with the keyword
//! `OFF`, optionally with the prefixes `ST`, `C` and `N` (texture
//! coordinates, a colour and a normal after each vertex's `x y z`), or
//! leaves the keyword out. Then the counts `vertices faces [edges]` (the
//! edge count is not used), which may follow the keyword on its line or be
//! glued to it (`OFF8 6 0`, as some shape collections write them). Then one
//! vertex per line, `x y z` and whatever the prefixes add (kept as text),
//! and one face per line, `n i1 .. in` with 0-based indices and an optional
//! colour. `#` comments and blank lines may stand anywhere.
//!
//! Writing a file back rewrites only the `x y z` fields of the vertex
//! lines: normals (`NOFF`) are written back as they were read, as OBJ's
//! `vn` lines are.
//!
//! Refused with an error naming the 1-based line: bad numbers and counts,
//! faces of fewer than 3 corners or with fewer indices than they announce
//! (code `parse_error`), a file that ends before its counts are reached or
//! goes on after them, NaN or infinite coordinates (`non_finite_coordinate`),
//! indices beyond the vertices (`face_index_out_of_range`); `4OFF`, `nOFF`
//! (not three-dimensional) and `OFF BINARY` (`unsupported_content`); counts
//! beyond the limits (`limit_exceeded`, before anything is read) and files
//! without faces (`no_faces`).

use super::text::{
    Fields, TextSource, check_encoding, for_each_line, parse_index, shorten, write_xyz,
};
use super::{IoError, ReadLimits};
use crate::mesh::Mesh;
use glam::DVec3;

const FORMAT: &str = "OFF";

/// What an OFF file needs besides the mesh to be written back.
pub type OffSource = TextSource;

/// Whether `text` (the first field of a file) is an OFF keyword:
/// `[ST][C][N][4][n]OFF`, possibly with the vertex count glued on. Returns
/// the prefix and what follows `OFF`.
fn keyword(text: &[u8]) -> Option<(&[u8], &[u8])> {
    let at = text.windows(3).position(|w| w == b"OFF")?;
    let (prefix, rest) = (text.get(..at)?, text.get(at + 3..)?);
    let mut expected = [&b"ST"[..], b"C", b"N", b"4", b"n"].into_iter();
    let mut left = prefix;
    while !left.is_empty() {
        let part = expected.find(|p| left.starts_with(p))?;
        left = left.get(part.len()..)?;
    }
    rest.iter()
        .all(u8::is_ascii_digit)
        .then_some((prefix, rest))
}

/// The fields of the first line of `bytes` that has any (comments and
/// blank lines skipped).
fn header_fields(bytes: &[u8]) -> impl Iterator<Item = &[u8]> {
    let mut lines = bytes.split(|&b| b == b'\n');
    let mut fields = Fields::new(b"");
    let mut started = false;
    std::iter::from_fn(move || {
        loop {
            if let Some((_, _, field)) = fields.next_field() {
                started = true;
                return Some(field);
            }
            if started {
                return None;
            }
            fields = Fields::new(lines.next()?);
        }
    })
}

/// Whether the first field of `head` (comments and blank lines skipped) is
/// an OFF keyword; used to tell the format from the content.
pub(super) fn starts_with_keyword(head: &[u8]) -> bool {
    header_fields(head)
        .next()
        .is_some_and(|first| keyword(first).is_some())
}

fn parse_error(line: usize, message: String) -> IoError {
    IoError::Parse {
        format: FORMAT,
        line: Some(line),
        message,
    }
}

/// Where the reader is in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Part {
    /// Before the keyword or the counts.
    Start,
    /// After the keyword, before the counts.
    Counts,
    /// Reading vertex and face lines.
    Body,
}

/// Parser state.
struct Reader<'l> {
    limits: &'l ReadLimits,
    part: Part,
    num_vertices: usize,
    num_faces: usize,
    positions: Vec<DVec3>,
    coords: Vec<(usize, usize)>,
    face_offsets: Vec<u32>,
    face_vertices: Vec<u32>,
    /// Line of the counts, for messages about them.
    counts_line: usize,
    /// Bytes in the file: the counts' reservations are capped by what the
    /// file can hold, so a lying header allocates nothing.
    file_len: usize,
}

/// Parses OFF bytes into a mesh (vertices and faces in file order) and what
/// [`write_off`] needs to write the file back.
///
/// Errors name the 1-based line and the problem.
pub fn read_off(bytes: &[u8], limits: &ReadLimits) -> Result<(Mesh, OffSource), IoError> {
    // A binary file would fail the text checks first; say what it is.
    let mut header = header_fields(bytes);
    if header.next().is_some_and(|k| keyword(k).is_some()) && header.next() == Some(&b"BINARY"[..])
    {
        return Err(IoError::Unsupported {
            format: FORMAT,
            message: "binary OFF files are not read; write the mesh as text OFF, or as PLY, glTF \
                      or STL"
                .to_owned(),
        });
    }
    check_encoding(bytes, FORMAT)?;
    let mut reader = Reader {
        limits,
        part: Part::Start,
        num_vertices: 0,
        num_faces: 0,
        positions: Vec::new(),
        coords: Vec::new(),
        face_offsets: vec![0],
        face_vertices: Vec::new(),
        counts_line: 0,
        file_len: bytes.len(),
    };
    for_each_line(bytes, |text, offset, line| reader.line(text, offset, line))?;
    reader.finish(bytes)
}

impl Reader<'_> {
    /// Handles one line (without its `\n`) that starts at byte `offset`.
    fn line(&mut self, text: &[u8], offset: usize, line: usize) -> Result<(), IoError> {
        let mut fields = Fields::new(text);
        let Some((_, _, first)) = fields.next_field() else {
            return Ok(());
        };
        match self.part {
            Part::Start => match keyword(first) {
                Some((prefix, _)) if prefix.contains(&b'4') || prefix.contains(&b'n') => {
                    Err(IoError::Unsupported {
                        format: FORMAT,
                        message: format!(
                            "`{}` on line {line} is not a three-dimensional OFF file; only \
                             x y z vertices can be smoothed",
                            shorten(&String::from_utf8_lossy(first))
                        ),
                    })
                }
                Some((_, glued)) => self.counts(fields, (!glued.is_empty()).then_some(glued), line),
                None => self.counts(Fields::new(text), None, line),
            },
            Part::Counts => self.counts(Fields::new(text), None, line),
            Part::Body if self.positions.len() < self.num_vertices => {
                let (position, (x, z)) = Fields::new(text).xyz("a vertex line", line, FORMAT)?;
                self.positions.push(position);
                self.coords.push((offset + x, offset + z));
                Ok(())
            }
            Part::Body if self.face_offsets.len() - 1 < self.num_faces => {
                self.face(Fields::new(text), line)
            }
            Part::Body => Err(parse_error(
                line,
                format!(
                    "the file goes on after the {} vertices and {} faces that line {} counts",
                    self.num_vertices, self.num_faces, self.counts_line
                ),
            )),
        }
    }

    /// Reads the counts line `vertices faces [edges]`: `glued` is a vertex
    /// count written against the keyword, `fields` the rest of the line.
    /// A keyword alone on its line leaves the counts to the next line.
    fn counts(
        &mut self,
        mut fields: Fields,
        glued: Option<&[u8]>,
        line: usize,
    ) -> Result<(), IoError> {
        let mut values = glued.into_iter().chain(std::iter::from_fn(|| {
            fields.next_field().map(|(_, _, field)| field)
        }));
        let Some(first) = values.next() else {
            self.part = Part::Counts;
            return Ok(());
        };
        let count = |field: &[u8]| {
            parse_index(field)
                .and_then(|n| usize::try_from(n).ok())
                .ok_or_else(|| {
                    parse_error(
                        line,
                        format!(
                            "expected the vertex, face and edge counts (after an optional `OFF` \
                             keyword), found `{}`",
                            shorten(&String::from_utf8_lossy(field))
                        ),
                    )
                })
        };
        let num_vertices = count(first)?;
        let Some(faces) = values.next() else {
            return Err(parse_error(
                line,
                "the counts line needs the vertex and face counts; the face count is missing"
                    .to_owned(),
            ));
        };
        let num_faces = count(faces)?;
        if let Some(edges) = values.next() {
            count(edges)?;
        }
        if values.next().is_some() {
            return Err(parse_error(
                line,
                "the counts line has more than three numbers (vertices, faces, edges)".to_owned(),
            ));
        }
        for (what, count, limit) in [
            ("vertex", num_vertices, self.limits.max_vertices),
            ("face", num_faces, self.limits.max_faces),
        ] {
            if count > limit {
                return Err(IoError::Limit { what, count, limit });
            }
        }
        // A vertex line takes at least 6 bytes (`0 0 0\n`), a face line 8.
        let vertices = num_vertices.min(self.file_len / 6);
        let faces = num_faces.min(self.file_len / 8);
        self.positions.reserve(vertices);
        self.coords.reserve(vertices);
        self.face_offsets.reserve(faces);
        self.face_vertices.reserve(3 * faces);
        (self.num_vertices, self.num_faces) = (num_vertices, num_faces);
        self.counts_line = line;
        self.part = Part::Body;
        Ok(())
    }

    /// Reads a face line: `n i1 .. in`, then anything (a colour).
    fn face(&mut self, mut fields: Fields, line: usize) -> Result<(), IoError> {
        let field_text = |field: &[u8]| shorten(&String::from_utf8_lossy(field)).to_owned();
        let (_, _, first) = fields.next_field().unwrap_or_default();
        let corners = parse_index(first)
            .and_then(|n| u64::try_from(n).ok())
            .ok_or_else(|| {
                parse_error(
                    line,
                    format!(
                        "a face line starts with its corner count; `{}` is not one",
                        field_text(first)
                    ),
                )
            })?;
        if corners < 3 {
            return Err(parse_error(
                line,
                format!("a face needs at least 3 corners, this one has {corners}"),
            ));
        }
        for listed in 0..corners {
            let Some((_, _, field)) = fields.next_field() else {
                return Err(parse_error(
                    line,
                    format!("the face announces {corners} corners but lists {listed}"),
                ));
            };
            let index = parse_index(field)
                .and_then(|i| u64::try_from(i).ok())
                .ok_or_else(|| {
                    parse_error(
                        line,
                        format!("`{}` is not a vertex index", field_text(field)),
                    )
                })?;
            let vertex = u32::try_from(index)
                .ok()
                .filter(|&v| (v as usize) < self.num_vertices)
                .ok_or_else(|| IoError::IndexOutOfRange {
                    format: FORMAT,
                    line: Some(line),
                    message: format!(
                        "face refers to vertex {index}, but the file has {} vertices (OFF \
                         indices start at 0)",
                        self.num_vertices
                    ),
                })?;
            self.face_vertices.push(vertex);
        }
        let end = u32::try_from(self.face_vertices.len()).map_err(|_| IoError::Limit {
            what: "face corner",
            count: self.face_vertices.len(),
            limit: u32::MAX as usize - 1,
        })?;
        self.face_offsets.push(end);
        Ok(())
    }

    fn finish(self, bytes: &[u8]) -> Result<(Mesh, OffSource), IoError> {
        let ends_early = |message: String| IoError::Parse {
            format: FORMAT,
            line: None,
            message,
        };
        match self.part {
            Part::Start => {
                return Err(IoError::NoFaces {
                    format: FORMAT,
                    message: "the file holds no counts, vertices or faces".to_owned(),
                });
            }
            Part::Counts => {
                return Err(ends_early(
                    "the file ends before the vertex and face counts".to_owned(),
                ));
            }
            Part::Body => {}
        }
        let faces = self.face_offsets.len() - 1;
        if self.positions.len() < self.num_vertices || faces < self.num_faces {
            return Err(ends_early(format!(
                "the file ends after {} of the {} vertices and {faces} of the {} faces that \
                 line {} counts",
                self.positions.len(),
                self.num_vertices,
                self.num_faces,
                self.counts_line
            )));
        }
        if faces == 0 {
            return Err(IoError::NoFaces {
                format: FORMAT,
                message: format!(
                    "the file has {} vertices and no faces; smoothing needs a surface",
                    self.num_vertices
                ),
            });
        }
        let mesh = Mesh::new(self.positions, self.face_offsets, self.face_vertices)?;
        let src = TextSource::new(bytes, self.coords);
        Ok((mesh, src))
    }
}

/// Writes the file `src` was read from with `positions` (one per vertex) in
/// place of the `x y z` fields of its vertex lines; every other byte is
/// copied unchanged. Coordinates are printed with shortest round-trip
/// precision.
pub fn write_off(src: &OffSource, positions: &[DVec3], out: &mut Vec<u8>) -> Result<(), IoError> {
    src.write(positions, out)
}

/// Writes `mesh` with `positions` (one per vertex) as a plain OFF: the
/// keyword, the counts (an edge count of 0, which readers ignore), one
/// `x y z` line per vertex and one `n i1 .. in` line per face. Used when the
/// input was in another format.
pub fn write_off_plain(mesh: &Mesh, positions: &[DVec3], out: &mut Vec<u8>) -> Result<(), IoError> {
    IoError::check_position_count(mesh.num_vertices(), positions.len())?;
    out.reserve(40 * positions.len() + 8 * mesh.face_vertices().len());
    let mut number = itoa::Buffer::new();
    out.extend_from_slice(b"OFF\n");
    out.extend_from_slice(number.format(positions.len()).as_bytes());
    out.push(b' ');
    out.extend_from_slice(number.format(mesh.num_faces()).as_bytes());
    out.extend_from_slice(b" 0\n");
    for (v, p) in positions.iter().enumerate() {
        write_xyz(out, v, *p)?;
        out.push(b'\n');
    }
    for face in mesh.faces() {
        out.extend_from_slice(number.format(face.len()).as_bytes());
        for &i in face {
            out.push(b' ');
            out.extend_from_slice(number.format(i).as_bytes());
        }
        out.push(b'\n');
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit square as two triangles and a quad of the same corners.
    const SQUARE: &str = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n";

    fn read(text: &str) -> Result<(Mesh, OffSource), IoError> {
        read_off(text.as_bytes(), &ReadLimits::default())
    }

    fn faces(mesh: &Mesh) -> Vec<Vec<u32>> {
        mesh.faces().map(<[u32]>::to_vec).collect()
    }

    /// The code and message of reading `text`.
    fn error(text: &str) -> (&'static str, String) {
        let e = read(text).unwrap_err();
        (e.code().as_str(), e.to_string())
    }

    #[test]
    fn every_header_form_gives_the_same_mesh() {
        let body = format!("{SQUARE}3 0 1 2\n4 0 1 2 3\n");
        let (expected, _) = read(&format!("OFF\n4 2 0\n{body}")).unwrap();
        assert_eq!(faces(&expected), [vec![0, 1, 2], vec![0, 1, 2, 3]]);
        assert_eq!(expected.positions()[2], DVec3::new(1.0, 1.0, 0.0));
        for text in [
            format!("4 2 5\n{body}"),
            format!("OFF 4 2 0\n{body}"),
            format!("OFF4 2 0\n{body}"),
            format!("OFF\n4 2\n{body}"),
            format!("\u{feff}# made by hand\n\nOFF # keyword\n# counts next\n4 2 0\r\n{body}"),
            format!(
                "NOFF\n4 2 0\n{}3 0 1 2\n4 0 1 2 3\n",
                SQUARE.replace('\n', " 0 0 1\n")
            ),
            format!(
                "COFF\n4 2 0\n{}3 0 1 2 255 0 0\n4 0 1 2 3\n",
                SQUARE.replace('\n', " 1 0.5 0 1\n")
            ),
            format!("STCNOFF\n4 2 0\n{body}"),
        ] {
            let (mesh, _) = read(&text).unwrap_or_else(|e| panic!("{text:?}: {e}"));
            assert_eq!(mesh, expected, "{text:?}");
        }
    }

    #[test]
    fn write_back_moves_only_the_coordinates() {
        let text = "# GAMer\r\nCOFF\r\n4 2 0\r\n0 0 0 1 0 0 1\r\n1e0 0 0  0 1 0 1\r\n\
                    1 1 0 0 0 1 1 # a comment\r\n0 1 0 1 1 1 1\r\n3 0 1 2 9 9 9\r\n3 0 2 3\r\n";
        let (mesh, src) = read(text).unwrap();
        let mut out = Vec::new();
        write_off(&src, mesh.positions(), &mut out).unwrap();
        assert_eq!(
            String::from_utf8(out).unwrap(),
            text.replace("1e0 0 0", "1 0 0")
        );

        let moved: Vec<DVec3> = mesh.positions().iter().map(|p| *p * 0.1 + 1.0).collect();
        let mut out = Vec::new();
        write_off(&src, &moved, &mut out).unwrap();
        let out = String::from_utf8(out).unwrap();
        assert!(out.contains("\r\n1.1 1 1  0 1 0 1\r\n"), "{out}");
        assert!(
            out.contains("\r\n1.1 1.1 1 0 0 1 1 # a comment\r\n"),
            "{out}"
        );
        assert!(out.ends_with("\r\n3 0 1 2 9 9 9\r\n3 0 2 3\r\n"), "{out}");
        let (again, _) = read(&out).unwrap();
        assert_eq!(again.positions(), &moved[..]);
        assert_eq!(faces(&again), faces(&mesh));
    }

    #[test]
    fn plain_writer_round_trips() {
        let (mesh, _) = read(&format!("OFF\n4 2 0\n{SQUARE}4 0 1 2 3\n3 3 2 0\n")).unwrap();
        let moved: Vec<DVec3> = mesh.positions().iter().map(|p| *p + 1.0 / 3.0).collect();
        let mut out = Vec::new();
        write_off_plain(&mesh, &moved, &mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert!(text.starts_with("OFF\n4 2 0\n"), "{text}");
        assert!(text.ends_with("\n4 0 1 2 3\n3 3 2 0\n"), "{text}");
        let (back, _) = read(&text).unwrap();
        assert_eq!(back.positions(), &moved[..]);
        assert_eq!(faces(&back), faces(&mesh));
        assert!(starts_with_keyword(text.as_bytes()));
        let e = write_off_plain(&mesh, &moved[..3], &mut Vec::new()).unwrap_err();
        assert_eq!(e.code(), "position_count_mismatch");
        let mut bad = moved.clone();
        bad[1].y = f64::NAN;
        assert_eq!(
            write_off_plain(&mesh, &bad, &mut Vec::new())
                .unwrap_err()
                .code(),
            "non_finite_coordinate"
        );
    }

    #[test]
    fn errors_name_the_line_and_the_problem() {
        let faces = "3 0 1 2\n";
        for (text, code, says) in [
            (
                format!("4OFF\n4 1 0\n{SQUARE}{faces}"),
                "unsupported_content",
                "three-dimensional",
            ),
            (
                format!("nOFF\n3\n4 1 0\n{SQUARE}{faces}"),
                "unsupported_content",
                "line 1",
            ),
            (
                "OFF BINARY\n\0\0".to_owned(),
                "unsupported_content",
                "binary",
            ),
            ("OFF\n4 1 0\0\n".to_owned(), "parse_error", "NUL byte"),
            ("OFF BINARY\n".to_owned(), "unsupported_content", "binary"),
            (
                format!("OFF\nfour 1 0\n{SQUARE}{faces}"),
                "parse_error",
                "line 2",
            ),
            (
                format!("OFF\n4\n{SQUARE}{faces}"),
                "parse_error",
                "face count is missing",
            ),
            (
                format!("OFF\n4 1 0 7\n{SQUARE}{faces}"),
                "parse_error",
                "more than three",
            ),
            (
                format!("OFF\n4 -1 0\n{SQUARE}{faces}"),
                "parse_error",
                "`-1`",
            ),
            (
                format!("OFF\n4 1 0\n0 0 0\n1 0\n1 1 0\n0 1 0\n{faces}"),
                "parse_error",
                "line 4",
            ),
            (
                format!("OFF\n4 1 0\n0 0 0\n1 x 0\n1 1 0\n0 1 0\n{faces}"),
                "parse_error",
                "`x`",
            ),
            (
                format!("OFF\n4 1 0\n0 0 nan\n1 0 0\n1 1 0\n0 1 0\n{faces}"),
                "non_finite_coordinate",
                "line 3",
            ),
            (
                format!("OFF\n4 1 0\n{SQUARE}3 0 1 4\n"),
                "face_index_out_of_range",
                "vertex 4",
            ),
            (
                format!("OFF\n4 1 0\n{SQUARE}3 0 1 -1\n"),
                "parse_error",
                "`-1`",
            ),
            (
                format!("OFF\n4 1 0\n{SQUARE}2 0 1\n"),
                "parse_error",
                "at least 3",
            ),
            (
                format!("OFF\n4 1 0\n{SQUARE}4 0 1 2\n"),
                "parse_error",
                "lists 3",
            ),
            (
                format!("OFF\n4 1 0\n{SQUARE}x 0 1 2\n"),
                "parse_error",
                "corner count",
            ),
            (
                format!("OFF\n4 2 0\n{SQUARE}{faces}"),
                "parse_error",
                "1 of the 2 faces",
            ),
            (
                format!("OFF\n5 1 0\n{SQUARE}"),
                "parse_error",
                "4 of the 5 vertices",
            ),
            (
                format!("OFF\n4 1 0\n{SQUARE}{faces}{faces}"),
                "parse_error",
                "line 8",
            ),
            (
                "OFF\n".to_owned(),
                "parse_error",
                "before the vertex and face counts",
            ),
            (format!("OFF\n4 0 0\n{SQUARE}"), "no_faces", "4 vertices"),
            ("# nothing\n".to_owned(), "no_faces", "no counts"),
            (String::new(), "no_faces", "no counts"),
            (format!("{SQUARE}{faces}"), "parse_error", "line 2"),
        ] {
            let (got, message) = error(&text);
            assert_eq!(got, code, "{text:?}: {message}");
            assert!(message.contains(says), "{text:?}: {message}");
        }
    }

    #[test]
    fn counts_beyond_the_limits_are_refused_before_reading() {
        let limits = ReadLimits {
            max_vertices: 3,
            max_faces: 1,
        };
        let e = read_off(format!("OFF\n4 1 0\n{SQUARE}3 0 1 2\n").as_bytes(), &limits).unwrap_err();
        assert!(
            matches!(
                e,
                IoError::Limit {
                    what: "vertex",
                    count: 4,
                    limit: 3
                }
            ),
            "{e:?}"
        );
        let e = read_off(
            b"OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 2 1 0\n",
            &limits,
        )
        .unwrap_err();
        assert!(matches!(e, IoError::Limit { what: "face", .. }), "{e:?}");
        assert_eq!(e.code(), "limit_exceeded");
        // Counts within the limits but far beyond the file reserve nothing
        // they cannot fill: the file simply ends early.
        let e = read("OFF\n19999999 39999999 0\n0 0 0\n").unwrap_err();
        assert!(e.to_string().contains("1 of the 19999999 vertices"), "{e}");
    }

    #[test]
    fn the_keyword_tells_the_format() {
        for head in ["OFF\n", "# c\n\n  COFF 4 2 0\n", "OFF12 3 0", "STNOFF\n"] {
            assert!(starts_with_keyword(head.as_bytes()), "{head:?}");
        }
        for head in ["v 0 0 0\n", "4 2 0\nOFF\n", "OFFICE\n", "XOFF\n", ""] {
            assert!(!starts_with_keyword(head.as_bytes()), "{head:?}");
        }
    }
}
