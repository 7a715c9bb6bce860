//! PLY (Stanford polygon file) reading and writing: ASCII, binary little
//! and big endian.
//!
//! The reader takes the `vertex` element's `x`, `y`, `z` (float or double)
//! and the `face` element's index list (`vertex_indices`, `vertex_index`,
//! or else its first list property; lists of any arity of at least 3, any
//! integer types). Every other element and property is skipped on reading
//! and kept on writing: writing a file back copies the input's bytes and
//! replaces only the coordinates of each vertex record, plus the per-vertex
//! result properties when they are asked for (appended to the `vertex`
//! element, or overwritten where the file already has them).
//!
//! Counts are checked against the limits and against the bytes actually
//! present before anything is allocated for them. Header errors name the
//! 1-based header line; ASCII body errors the line of the offending value.

use super::text::shorten;
use super::{IoError, ReadLimits, VertexResults};
use crate::mesh::Mesh;
use glam::DVec3;
use std::sync::Arc;

const FORMAT: &str = "PLY";

/// A PLY scalar type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn name(self) -> &'static str {
        match self {
            Scalar::I8 => "char",
            Scalar::U8 => "uchar",
            Scalar::I16 => "short",
            Scalar::U16 => "ushort",
            Scalar::I32 => "int",
            Scalar::U32 => "uint",
            Scalar::F32 => "float",
            Scalar::F64 => "double",
        }
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// Decodes one value from the start of `b`.
    fn decode(self, b: &[u8], big_endian: bool) -> Option<f64> {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let raw: [u8; $n] = b.get(..$n)?.try_into().ok()?;
                if big_endian {
                    <$t>::from_be_bytes(raw) as f64
                } else {
                    <$t>::from_le_bytes(raw) as f64
                }
            }};
        }
        Some(match self {
            Scalar::I8 => num!(i8, 1),
            Scalar::U8 => num!(u8, 1),
            Scalar::I16 => num!(i16, 2),
            Scalar::U16 => num!(u16, 2),
            Scalar::I32 => num!(i32, 4),
            Scalar::U32 => num!(u32, 4),
            Scalar::F32 => num!(f32, 4),
            Scalar::F64 => num!(f64, 8),
        })
    }

    /// Encodes `v` (rounded and clamped for integer types) into `dst`.
    fn encode(self, v: f64, big_endian: bool, dst: &mut [u8]) {
        macro_rules! put {
            ($x:expr) => {{
                let x = $x;
                let raw = if big_endian {
                    x.to_be_bytes()
                } else {
                    x.to_le_bytes()
                };
                if let Some(d) = dst.get_mut(..raw.len()) {
                    d.copy_from_slice(&raw);
                }
            }};
        }
        match self {
            Scalar::I8 => put!(v.round() as i8),
            Scalar::U8 => put!(v.round() as u8),
            Scalar::I16 => put!(v.round() as i16),
            Scalar::U16 => put!(v.round() as u16),
            Scalar::I32 => put!(v.round() as i32),
            Scalar::U32 => put!(v.round() as u32),
            Scalar::F32 => put!(v as f32),
            Scalar::F64 => put!(v),
        }
    }

    /// Appends `v` as text of this type (shortest round-trip for floats).
    fn format(self, v: f64, out: &mut Vec<u8>) {
        match self {
            Scalar::F32 => {
                let mut b = zmij::Buffer::new();
                out.extend_from_slice(trim_zero(b.format_finite(v as f32)).as_bytes());
            }
            Scalar::F64 => {
                let mut b = zmij::Buffer::new();
                out.extend_from_slice(trim_zero(b.format_finite(v)).as_bytes());
            }
            _ => {
                let mut b = itoa::Buffer::new();
                let clamped = match self {
                    Scalar::I8 => v.round().clamp(-128.0, 127.0),
                    Scalar::U8 => v.round().clamp(0.0, 255.0),
                    Scalar::I16 => v.round().clamp(-32768.0, 32767.0),
                    Scalar::U16 => v.round().clamp(0.0, 65535.0),
                    Scalar::I32 => v.round().clamp(i32::MIN as f64, i32::MAX as f64),
                    _ => v.round().clamp(0.0, u32::MAX as f64),
                };
                out.extend_from_slice(b.format(clamped as i64).as_bytes());
            }
        }
    }
}

fn trim_zero(text: &str) -> &str {
    text.strip_suffix(".0").unwrap_or(text)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: u64,
    properties: Vec<Property>,
    /// Byte offset just after this element's last header line.
    header_end: usize,
}

impl Element {
    /// Record size when every property is a scalar.
    fn fixed_size(&self) -> Option<usize> {
        self.properties
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => Some(s.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }

    /// Fewest bytes (binary) or values (ASCII) one record can take.
    fn min_values(&self, binary: bool) -> usize {
        self.properties
            .iter()
            .map(|p| match (p.kind, binary) {
                (Kind::Scalar(s) | Kind::List { count: s, .. }, true) => s.size(),
                (_, false) => 1,
            })
            .sum()
    }
}

/// How the body is encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// `format ascii 1.0`.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLittleEndian,
    /// `format binary_big_endian 1.0`.
    BinaryBigEndian,
}

impl Encoding {
    fn keyword(self) -> &'static str {
        match self {
            Encoding::Ascii => "ascii",
            Encoding::BinaryLittleEndian => "binary_little_endian",
            Encoding::BinaryBigEndian => "binary_big_endian",
        }
    }
}

/// What a PLY file needs besides the mesh to be written back: its bytes,
/// its header and where each vertex record lies.
#[derive(Debug, Clone)]
pub struct PlySource {
    bytes: Arc<[u8]>,
    /// Body encoding of the input.
    pub encoding: Encoding,
    /// Length of the header, `end_header` line included.
    header_len: usize,
    /// Properties of the `vertex` element.
    vertex_properties: Vec<Property>,
    /// Header offset where new `vertex` property lines go.
    vertex_header_end: usize,
    /// Indices of `x`, `y`, `z` in `vertex_properties`.
    xyz: [usize; 3],
    /// Byte range of each vertex record.
    records: Records,
}

#[derive(Debug, Clone)]
enum Records {
    /// Binary records of one size, back to back from `first`.
    Fixed {
        first: usize,
        size: usize,
        count: usize,
    },
    /// Start and end of each record (ASCII, or binary with lists).
    Ranges(Vec<(usize, usize)>),
}

impl Records {
    fn len(&self) -> usize {
        match self {
            Records::Fixed { count, .. } => *count,
            Records::Ranges(r) => r.len(),
        }
    }

    fn range(&self, v: usize) -> (usize, usize) {
        match self {
            Records::Fixed { first, size, .. } => (first + v * size, first + (v + 1) * size),
            Records::Ranges(r) => r.get(v).copied().unwrap_or_default(),
        }
    }

    fn span(&self) -> (usize, usize) {
        let n = self.len();
        if n == 0 {
            return (0, 0);
        }
        (self.range(0).0, self.range(n - 1).1)
    }
}

fn header_error(line: usize, message: String) -> IoError {
    IoError::Parse {
        format: FORMAT,
        line: Some(line),
        message,
    }
}

fn body_error(message: String) -> IoError {
    IoError::Parse {
        format: FORMAT,
        line: None,
        message,
    }
}

struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    len: usize,
}

fn parse_header(bytes: &[u8]) -> Result<Header, IoError> {
    let mut pos = 0;
    let mut line_no = 0;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        line_no += 1;
        let rest = bytes.get(pos..).unwrap_or_default();
        let Some(len) = memchr::memchr(b'\n', rest) else {
            return Err(header_error(
                line_no,
                "the header has no `end_header` line".into(),
            ));
        };
        let raw = rest.get(..len).unwrap_or_default();
        pos += len + 1;
        let text = std::str::from_utf8(raw)
            .map_err(|_| header_error(line_no, "header line is not ASCII text".into()))?;
        let text = text.trim_end_matches('\r');
        let mut words = text.split_ascii_whitespace();
        let keyword = words.next().unwrap_or_default();
        if line_no == 1 {
            if text.trim() != "ply" {
                return Err(header_error(
                    1,
                    "the file does not start with the `ply` magic line".into(),
                ));
            }
            continue;
        }
        match keyword {
            "format" => encoding = Some(parse_format(words, line_no)?),
            "comment" | "obj_info" | "" => {}
            "element" => {
                let (Some(name), Some(count)) = (words.next(), words.next()) else {
                    return Err(header_error(
                        line_no,
                        "`element` needs a name and a count".into(),
                    ));
                };
                let count = count.parse::<u64>().map_err(|_| {
                    header_error(
                        line_no,
                        format!("element count `{}` is not a number", shorten(count)),
                    )
                })?;
                if elements.iter().any(|e| e.name == name) {
                    return Err(header_error(
                        line_no,
                        format!("element `{}` is declared twice", shorten(name)),
                    ));
                }
                elements.push(Element {
                    name: name.to_owned(),
                    count,
                    properties: Vec::new(),
                    header_end: pos,
                });
            }
            "property" => {
                let Some(element) = elements.last_mut() else {
                    return Err(header_error(
                        line_no,
                        "`property` before any `element`".into(),
                    ));
                };
                element.properties.push(parse_property(words, line_no)?);
                element.header_end = pos;
            }
            "end_header" => break,
            other => {
                return Err(header_error(
                    line_no,
                    format!("unknown header keyword `{}`", shorten(other)),
                ));
            }
        }
    }
    let encoding =
        encoding.ok_or_else(|| header_error(line_no, "the header has no `format` line".into()))?;
    Ok(Header {
        encoding,
        elements,
        len: pos,
    })
}

/// The encoding of a `format` line (its words after the keyword): ASCII
/// or binary, version 1.0.
fn parse_format<'a>(
    mut words: impl Iterator<Item = &'a str>,
    line_no: usize,
) -> Result<Encoding, IoError> {
    let kind = words.next().unwrap_or_default();
    let encoding = match kind {
        "ascii" => Encoding::Ascii,
        "binary_little_endian" => Encoding::BinaryLittleEndian,
        "binary_big_endian" => Encoding::BinaryBigEndian,
        _ => {
            return Err(header_error(
                line_no,
                format!("unknown format `{}`", shorten(kind)),
            ));
        }
    };
    let version = words.next().unwrap_or_default();
    if version != "1.0" {
        return Err(header_error(
            line_no,
            format!(
                "unsupported PLY version `{}`; expected 1.0",
                shorten(version)
            ),
        ));
    }
    Ok(encoding)
}

/// The property of a `property` line (its words after the keyword): a
/// scalar `TYPE NAME` or a `list COUNT_TYPE ITEM_TYPE NAME`.
fn parse_property<'a>(
    words: impl Iterator<Item = &'a str>,
    line_no: usize,
) -> Result<Property, IoError> {
    let words: Vec<&str> = words.collect();
    let scalar = |name: &str| {
        Scalar::parse(name).ok_or_else(|| {
            header_error(
                line_no,
                format!("unknown property type `{}`", shorten(name)),
            )
        })
    };
    let (kind, name) = match words.as_slice() {
        ["list", count, item, name] => {
            let count = scalar(count)?;
            if count.is_float() {
                return Err(header_error(
                    line_no,
                    "a list count must have an integer type".into(),
                ));
            }
            (
                Kind::List {
                    count,
                    item: scalar(item)?,
                },
                name,
            )
        }
        [ty, name] if *ty != "list" => (Kind::Scalar(scalar(ty)?), name),
        _ => {
            return Err(header_error(
                line_no,
                "expected `property TYPE NAME` or `property list COUNT_TYPE ITEM_TYPE NAME`".into(),
            ));
        }
    };
    Ok(Property {
        name: (*name).to_owned(),
        kind,
    })
}

/// Reads values from the body, ASCII or binary.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
    encoding: Encoding,
}

impl Cursor<'_> {
    fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }

    /// Moves to the start of the next record and returns its offset.
    fn record_start(&mut self) -> usize {
        if self.encoding == Encoding::Ascii {
            self.skip_blanks();
        }
        self.pos
    }

    fn skip_blanks(&mut self) {
        let rest = self.bytes.get(self.pos..).unwrap_or_default();
        self.pos += rest
            .iter()
            .position(|b| !b.is_ascii_whitespace())
            .unwrap_or(rest.len());
    }

    /// 1-based line of the current position (ASCII error messages).
    fn line(&self) -> usize {
        let upto = self.bytes.get(..self.pos).unwrap_or_default();
        1 + memchr::memchr_iter(b'\n', upto).count()
    }

    /// Next value of type `t`, or `what` in an error.
    fn value(&mut self, t: Scalar, what: &dyn Fn() -> String) -> Result<f64, IoError> {
        match self.encoding {
            Encoding::Ascii => {
                self.skip_blanks();
                let rest = self.bytes.get(self.pos..).unwrap_or_default();
                let len = rest
                    .iter()
                    .position(|b| b.is_ascii_whitespace())
                    .unwrap_or(rest.len());
                if len == 0 {
                    return Err(body_error(format!("the file ends before {}", what())));
                }
                let token = rest.get(..len).unwrap_or_default();
                let parsed = std::str::from_utf8(token)
                    .ok()
                    .and_then(|s| s.parse::<f64>().ok())
                    .filter(|v| t.is_float() || v.fract() == 0.0);
                let Some(v) = parsed else {
                    return Err(IoError::Parse {
                        format: FORMAT,
                        line: Some(self.line()),
                        message: format!(
                            "`{}` is not a valid {} for {}",
                            shorten(&String::from_utf8_lossy(token)),
                            t.name(),
                            what()
                        ),
                    });
                };
                self.pos += len;
                Ok(v)
            }
            _ => {
                let big = self.encoding == Encoding::BinaryBigEndian;
                let v = self
                    .bytes
                    .get(self.pos..)
                    .and_then(|b| t.decode(b, big))
                    .ok_or_else(|| body_error(format!("the file ends before {}", what())))?;
                self.pos += t.size();
                Ok(v)
            }
        }
    }

    /// A list count: an integer from 0 up to what the remaining bytes can
    /// hold.
    fn list_len(
        &mut self,
        t: Scalar,
        item: Scalar,
        what: &dyn Fn() -> String,
    ) -> Result<usize, IoError> {
        let n = self.value(t, what)?;
        let per_item = match self.encoding {
            Encoding::Ascii => 2,
            _ => item.size(),
        };
        if n < 0.0 || n > (self.remaining() / per_item + 1) as f64 {
            return Err(body_error(format!(
                "list length {n} of {} is negative or longer than the rest of the file",
                what()
            )));
        }
        Ok(n as usize)
    }

    /// Skips one record of `element`.
    fn skip_record(&mut self, element: &Element, r: u64) -> Result<(), IoError> {
        for p in &element.properties {
            let what = || format!("property `{}` of {} {r}", p.name, element.name);
            match p.kind {
                Kind::Scalar(t) => self.skip_value(t, &what)?,
                Kind::List { count, item } => {
                    let n = self.list_len(count, item, &what)?;
                    for _ in 0..n {
                        self.skip_value(item, &what)?;
                    }
                }
            }
        }
        Ok(())
    }

    fn skip_value(&mut self, t: Scalar, what: &dyn Fn() -> String) -> Result<(), IoError> {
        if self.encoding == Encoding::Ascii {
            self.value(t, what).map(|_| ())
        } else if self.remaining() < t.size() {
            Err(body_error(format!("the file ends before {}", what())))
        } else {
            self.pos += t.size();
            Ok(())
        }
    }
}

/// Parses PLY bytes into a mesh (vertices and faces in file order) and
/// what [`write_ply`] needs to write the file back.
pub fn read_ply(bytes: &[u8], limits: &ReadLimits) -> Result<(Mesh, PlySource), IoError> {
    let header = parse_header(bytes)?;
    let vertex = header
        .elements
        .iter()
        .find(|e| e.name == "vertex")
        .ok_or_else(|| body_error("the file has no `vertex` element".into()))?;
    let xyz = coordinate_properties(vertex)?;
    let face = header.elements.iter().find(|e| e.name == "face");
    let face_list = match face {
        Some(f) => Some(index_list(f)?),
        None => None,
    };
    if face.is_none_or(|f| f.count == 0) {
        let strips = header.elements.iter().any(|e| e.name == "tristrips");
        return Err(if strips {
            IoError::Unsupported {
                format: FORMAT,
                message: "triangle strips (`tristrips` element) are not supported; store faces"
                    .into(),
            }
        } else {
            IoError::NoFaces {
                format: FORMAT,
                message: format!(
                    "the file has {} vertices and no `face` element records; smoothing needs a surface",
                    vertex.count
                ),
            }
        });
    }
    check_limit("vertex", vertex.count, limits.max_vertices)?;
    check_limit("face", face.map_or(0, |f| f.count), limits.max_faces)?;

    let binary = header.encoding != Encoding::Ascii;
    let mut cursor = Cursor {
        bytes,
        pos: header.len,
        encoding: header.encoding,
    };
    let mut positions = Vec::new();
    let mut records = Records::Ranges(Vec::new());
    let mut offsets = vec![0u32];
    let mut corners = Vec::new();
    for element in &header.elements {
        // No record is smaller than this, so a count beyond what the rest of
        // the file can hold is refused before anything is allocated.
        let min = element.min_values(binary);
        let capacity = (cursor.remaining() / min.max(1)) as u64;
        if min > 0 && element.count > capacity {
            return Err(body_error(format!(
                "element `{}` declares {} records but the rest of the file can hold at most {capacity}",
                shorten(&element.name),
                element.count
            )));
        }
        let count = element.count as usize;
        if element.name == "vertex" {
            positions.reserve(count);
            records = read_vertices(&mut cursor, element, xyz, &mut positions)?;
        } else if Some(element.name.as_str()) == face.map(|f| f.name.as_str()) {
            let list = face_list.unwrap_or(0);
            offsets.reserve(count);
            read_faces(&mut cursor, element, list, &mut offsets, &mut corners)?;
        } else if let (true, Some(size)) = (binary, element.fixed_size()) {
            let len = count.saturating_mul(size);
            if len > cursor.remaining() {
                return Err(body_error(format!(
                    "the file ends inside element `{}`",
                    shorten(&element.name)
                )));
            }
            cursor.pos += len;
        } else if min > 0 {
            for r in 0..element.count {
                cursor.skip_record(element, r)?;
            }
        }
    }
    let mesh = Mesh::new(positions, offsets, corners)?;
    let source = PlySource {
        bytes: Arc::from(bytes),
        encoding: header.encoding,
        header_len: header.len,
        vertex_properties: vertex.properties.clone(),
        vertex_header_end: vertex.header_end,
        xyz,
        records,
    };
    Ok((mesh, source))
}

fn check_limit(what: &'static str, count: u64, limit: usize) -> Result<(), IoError> {
    if count > limit as u64 {
        return Err(IoError::Limit {
            what,
            count: usize::try_from(count).unwrap_or(usize::MAX),
            limit,
        });
    }
    Ok(())
}

fn coordinate_properties(vertex: &Element) -> Result<[usize; 3], IoError> {
    let mut xyz = [0; 3];
    for (slot, axis) in xyz.iter_mut().zip(["x", "y", "z"]) {
        let (i, p) = vertex
            .properties
            .iter()
            .enumerate()
            .find(|(_, p)| p.name == axis)
            .ok_or_else(|| body_error(format!("the `vertex` element has no `{axis}` property")))?;
        match p.kind {
            Kind::Scalar(t) if t.is_float() => *slot = i,
            Kind::Scalar(t) => {
                return Err(IoError::Unsupported {
                    format: FORMAT,
                    message: format!(
                        "vertex property `{axis}` has integer type `{}`; only float and double coordinates can hold smoothed positions",
                        t.name()
                    ),
                });
            }
            Kind::List { .. } => {
                return Err(body_error(format!("vertex property `{axis}` is a list")));
            }
        }
    }
    Ok(xyz)
}

/// Index of the face element's corner list property.
fn index_list(face: &Element) -> Result<usize, IoError> {
    let lists = || {
        face.properties
            .iter()
            .enumerate()
            .filter(|(_, p)| matches!(p.kind, Kind::List { .. }))
    };
    let found = lists()
        .find(|(_, p)| p.name == "vertex_indices" || p.name == "vertex_index")
        .or_else(|| lists().next());
    let Some((i, p)) = found else {
        return Err(body_error(
            "the `face` element has no list property of vertex indices".into(),
        ));
    };
    if let Kind::List { item, .. } = p.kind
        && item.is_float()
    {
        return Err(body_error(format!(
            "face property `{}` lists `{}` values; vertex indices must be integers",
            p.name,
            item.name()
        )));
    }
    Ok(i)
}

fn read_vertices(
    cursor: &mut Cursor,
    element: &Element,
    xyz: [usize; 3],
    positions: &mut Vec<DVec3>,
) -> Result<Records, IoError> {
    let binary = cursor.encoding != Encoding::Ascii;
    let fixed = element.fixed_size().filter(|_| binary);
    let first = cursor.pos;
    let mut ranges = Vec::new();
    if fixed.is_none() {
        ranges.reserve(element.count as usize);
    }
    for v in 0..element.count {
        let start = cursor.record_start();
        let mut p = [0.0; 3];
        for (i, prop) in element.properties.iter().enumerate() {
            let what = || format!("property `{}` of vertex {v}", prop.name);
            match prop.kind {
                Kind::Scalar(t) => {
                    let value = cursor.value(t, &what)?;
                    if let Some(axis) = xyz.iter().position(|&a| a == i) {
                        if !value.is_finite() {
                            return Err(body_error(format!(
                                "vertex {v} has a non-finite coordinate (NaN or infinity)"
                            )));
                        }
                        if let Some(slot) = p.get_mut(axis) {
                            *slot = value;
                        }
                    }
                }
                Kind::List { count, item } => {
                    let n = cursor.list_len(count, item, &what)?;
                    for _ in 0..n {
                        cursor.skip_value(item, &what)?;
                    }
                }
            }
        }
        positions.push(DVec3::from_array(p));
        if fixed.is_none() {
            ranges.push((start, cursor.pos));
        }
    }
    Ok(match fixed {
        Some(size) => Records::Fixed {
            first,
            size,
            count: element.count as usize,
        },
        None => Records::Ranges(ranges),
    })
}

fn read_faces(
    cursor: &mut Cursor,
    element: &Element,
    list: usize,
    offsets: &mut Vec<u32>,
    corners: &mut Vec<u32>,
) -> Result<(), IoError> {
    for f in 0..element.count {
        for (i, prop) in element.properties.iter().enumerate() {
            let what = || format!("property `{}` of face {f}", prop.name);
            match prop.kind {
                Kind::Scalar(t) => cursor.skip_value(t, &what)?,
                Kind::List { count, item } if i == list => {
                    let n = cursor.list_len(count, item, &what)?;
                    if n < 3 {
                        return Err(body_error(format!(
                            "face {f} has {n} corners; a face needs at least 3"
                        )));
                    }
                    for _ in 0..n {
                        let index = cursor.value(item, &what)?;
                        if !(0.0..u32::MAX as f64).contains(&index) {
                            return Err(body_error(format!(
                                "face {f} has vertex index {index}, which is out of range"
                            )));
                        }
                        corners.push(index as u32);
                    }
                    let end = u32::try_from(corners.len()).map_err(|_| IoError::Limit {
                        what: "face corner",
                        count: corners.len(),
                        limit: u32::MAX as usize - 1,
                    })?;
                    offsets.push(end);
                }
                Kind::List { count, item } => {
                    let n = cursor.list_len(count, item, &what)?;
                    for _ in 0..n {
                        cursor.skip_value(item, &what)?;
                    }
                }
            }
        }
    }
    Ok(())
}

/// Names and PLY types of the per-vertex result properties.
const RESULT_PROPERTIES: [(&str, Scalar); 4] = [
    ("label", Scalar::U8),
    ("mean_curvature", Scalar::F32),
    ("gaussian_curvature", Scalar::F32),
    ("displacement", Scalar::F32),
];

/// One value column to write into each vertex record.
struct Column<'a> {
    values: ColumnValues<'a>,
}

enum ColumnValues<'a> {
    Axis(&'a [DVec3], usize),
    Labels(&'a [u8]),
    Reals(&'a [f64]),
}

impl Column<'_> {
    fn get(&self, v: usize) -> f64 {
        match self.values {
            ColumnValues::Axis(p, a) => p.get(v).map_or(0.0, |p| p[a]),
            ColumnValues::Labels(l) => l.get(v).map_or(0.0, |&x| f64::from(x)),
            ColumnValues::Reals(r) => r.get(v).copied().unwrap_or(0.0),
        }
    }
}

/// The per-vertex result columns present in `results`, in
/// [`RESULT_PROPERTIES`] order.
fn result_columns<'a>(
    results: Option<&VertexResults<'a>>,
) -> Vec<(&'static str, Scalar, Column<'a>)> {
    let Some(r) = results else {
        return Vec::new();
    };
    let [label, mean, gauss, disp] = RESULT_PROPERTIES;
    let mut columns = Vec::new();
    if !r.label.is_empty() {
        columns.push((
            label.0,
            label.1,
            Column {
                values: ColumnValues::Labels(r.label),
            },
        ));
    }
    for ((name, ty), values) in [
        (mean, r.mean_curvature),
        (gauss, r.gaussian_curvature),
        (disp, r.displacement),
    ] {
        if !values.is_empty() {
            columns.push((
                name,
                ty,
                Column {
                    values: ColumnValues::Reals(values),
                },
            ));
        }
    }
    columns
}

fn check_results(results: Option<&VertexResults>, n: usize) -> Result<(), IoError> {
    if let Some(r) = results {
        for len in [
            r.label.len(),
            r.mean_curvature.len(),
            r.gaussian_curvature.len(),
            r.displacement.len(),
        ] {
            if len != 0 && len != n {
                return Err(IoError::PositionCount {
                    expected: n,
                    got: len,
                });
            }
        }
    }
    Ok(())
}

/// Writes the file `src` was read from with `positions` (one per vertex)
/// in place of each vertex's `x y z`, and the per-vertex `results` (each
/// empty or one entry per vertex) as vertex properties `label` (uchar),
/// `mean_curvature`, `gaussian_curvature` and `displacement` (float):
/// overwritten where the file has a scalar property of that name, appended
/// otherwise. Everything else is copied unchanged.
pub fn write_ply(
    src: &PlySource,
    positions: &[DVec3],
    results: Option<&VertexResults>,
    out: &mut Vec<u8>,
) -> Result<(), IoError> {
    let n = src.records.len();
    IoError::check_position_count(n, positions.len())?;
    if let Some(v) = positions.iter().position(|p| !p.is_finite()) {
        return Err(crate::error::MeshError::NonFinitePosition { vertex: v }.into());
    }
    check_results(results, n)?;
    // (property index, column) to overwrite, and columns to append.
    let mut patches: Vec<(usize, Column)> = (0..3)
        .map(|a| {
            (
                src.xyz[a],
                Column {
                    values: ColumnValues::Axis(positions, a),
                },
            )
        })
        .collect();
    let mut appended = Vec::new();
    for (name, ty, column) in result_columns(results) {
        let existing = src
            .vertex_properties
            .iter()
            .position(|p| p.name == name && matches!(p.kind, Kind::Scalar(_)));
        match existing {
            Some(i) => patches.push((i, column)),
            None => appended.push((name, ty, column)),
        }
    }
    patches.sort_by_key(|(i, _)| *i);
    let bytes = &src.bytes[..];
    let header = bytes.get(..src.header_len).unwrap_or_default();
    out.reserve(bytes.len() + appended.len() * 8 * n);
    out.extend_from_slice(header.get(..src.vertex_header_end).unwrap_or_default());
    for (name, ty, _) in &appended {
        out.extend_from_slice(format!("property {} {name}\n", ty.name()).as_bytes());
    }
    out.extend_from_slice(header.get(src.vertex_header_end..).unwrap_or_default());
    let (span_start, span_end) = src.records.span();
    let span_start = if n == 0 { src.header_len } else { span_start };
    let span_end = if n == 0 { src.header_len } else { span_end };
    out.extend_from_slice(bytes.get(src.header_len..span_start).unwrap_or_default());
    let mut copied = span_start;
    for v in 0..n {
        let (start, end) = src.records.range(v);
        out.extend_from_slice(bytes.get(copied..start).unwrap_or_default());
        let record = bytes.get(start..end).unwrap_or_default();
        match src.encoding {
            Encoding::Ascii => write_ascii_record(src, record, v, &patches, &appended, out),
            encoding => {
                let big = encoding == Encoding::BinaryBigEndian;
                write_binary_record(src, record, v, &patches, &appended, big, out);
            }
        }
        copied = end;
    }
    out.extend_from_slice(bytes.get(copied.max(span_end)..).unwrap_or_default());
    Ok(())
}

fn write_ascii_record(
    src: &PlySource,
    record: &[u8],
    v: usize,
    patches: &[(usize, Column)],
    appended: &[(&str, Scalar, Column)],
    out: &mut Vec<u8>,
) {
    // Walks the record's tokens, copying the blanks between them; a list
    // property takes its count token plus that many item tokens.
    let mut pos = 0;
    let mut property = 0;
    let mut list_left: Option<usize> = None;
    let mut patch = patches.iter().peekable();
    while pos < record.len() {
        let rest = record.get(pos..).unwrap_or_default();
        let blank = rest
            .iter()
            .position(|b| !b.is_ascii_whitespace())
            .unwrap_or(rest.len());
        out.extend_from_slice(rest.get(..blank).unwrap_or_default());
        pos += blank;
        let rest = record.get(pos..).unwrap_or_default();
        let len = rest
            .iter()
            .position(|b| b.is_ascii_whitespace())
            .unwrap_or(rest.len());
        if len == 0 {
            break;
        }
        let token = rest.get(..len).unwrap_or_default();
        pos += len;
        if let Some(left) = list_left {
            out.extend_from_slice(token);
            list_left = left.checked_sub(1).filter(|&l| l > 0);
            if list_left.is_none() {
                property += 1;
            }
            continue;
        }
        match src.vertex_properties.get(property).map(|p| p.kind) {
            Some(Kind::List { .. }) => {
                out.extend_from_slice(token);
                let n = std::str::from_utf8(token)
                    .ok()
                    .and_then(|s| s.parse::<f64>().ok())
                    .unwrap_or(0.0) as usize;
                if n == 0 {
                    property += 1;
                } else {
                    list_left = Some(n);
                }
            }
            Some(Kind::Scalar(t)) => {
                if patch.peek().is_some_and(|(i, _)| *i == property) {
                    if let Some((_, column)) = patch.next() {
                        t.format(column.get(v), out);
                    }
                } else {
                    out.extend_from_slice(token);
                }
                property += 1;
            }
            None => out.extend_from_slice(token),
        }
    }
    for (_, ty, column) in appended {
        out.push(b' ');
        ty.format(column.get(v), out);
    }
}

fn write_binary_record(
    src: &PlySource,
    record: &[u8],
    v: usize,
    patches: &[(usize, Column)],
    appended: &[(&str, Scalar, Column)],
    big_endian: bool,
    out: &mut Vec<u8>,
) {
    let base = out.len();
    out.extend_from_slice(record);
    let mut at = 0;
    let mut patch = patches.iter().peekable();
    for (i, prop) in src.vertex_properties.iter().enumerate() {
        match prop.kind {
            Kind::Scalar(t) => {
                if patch.peek().is_some_and(|(p, _)| *p == i)
                    && let Some((_, column)) = patch.next()
                    && let Some(dst) = out.get_mut(base + at..)
                {
                    t.encode(column.get(v), big_endian, dst);
                }
                at += t.size();
            }
            Kind::List { count, item } => {
                let n = record
                    .get(at..)
                    .and_then(|b| count.decode(b, big_endian))
                    .unwrap_or(0.0);
                at += count.size() + (n.max(0.0) as usize) * item.size();
            }
        }
        if patch.peek().is_none() {
            break;
        }
    }
    for (_, ty, column) in appended {
        let start = out.len();
        out.resize(start + ty.size(), 0);
        if let Some(dst) = out.get_mut(start..) {
            ty.encode(column.get(v), big_endian, dst);
        }
    }
}

/// Writes `mesh` with `positions` (one per vertex) as a binary
/// little-endian PLY: `double` coordinates, faces as `list uchar int
/// vertex_indices` (`uint` counts and indices where needed), plus the
/// per-vertex `results` as in [`write_ply`].
pub fn write_ply_plain(
    mesh: &Mesh,
    positions: &[DVec3],
    results: Option<&VertexResults>,
    out: &mut Vec<u8>,
) -> Result<(), IoError> {
    let n = mesh.num_vertices();
    IoError::check_position_count(n, positions.len())?;
    if let Some(v) = positions.iter().position(|p| !p.is_finite()) {
        return Err(crate::error::MeshError::NonFinitePosition { vertex: v }.into());
    }
    check_results(results, n)?;
    let columns = result_columns(results);
    let max_arity = mesh.faces().map(<[u32]>::len).max().unwrap_or(3);
    let count_type = if max_arity > 255 {
        Scalar::U32
    } else {
        Scalar::U8
    };
    let index_type = if n > i32::MAX as usize {
        Scalar::U32
    } else {
        Scalar::I32
    };
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by meshsmooth\nelement vertex {n}\n\
         property double x\nproperty double y\nproperty double z\n"
    );
    for (name, ty, _) in &columns {
        header.push_str(&format!("property {} {name}\n", ty.name()));
    }
    header.push_str(&format!(
        "element face {}\nproperty list {} {} vertex_indices\nend_header\n",
        mesh.num_faces(),
        count_type.name(),
        index_type.name()
    ));
    let record = 24 + columns.iter().map(|(_, t, _)| t.size()).sum::<usize>();
    out.reserve(header.len() + n * record + mesh.num_faces() + 4 * mesh.face_vertices().len());
    out.extend_from_slice(header.as_bytes());
    let mut scratch = [0u8; 8];
    for (v, p) in positions.iter().enumerate() {
        for c in p.to_array() {
            out.extend_from_slice(&c.to_le_bytes());
        }
        for (_, ty, column) in &columns {
            ty.encode(column.get(v), false, &mut scratch);
            out.extend_from_slice(scratch.get(..ty.size()).unwrap_or_default());
        }
    }
    for face in mesh.faces() {
        count_type.encode(face.len() as f64, false, &mut scratch);
        out.extend_from_slice(scratch.get(..count_type.size()).unwrap_or_default());
        for &i in face {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    Ok(())
}

impl PlySource {
    /// The header keyword of the input's encoding (`ascii`,
    /// `binary_little_endian`, `binary_big_endian`).
    pub fn encoding_name(&self) -> &'static str {
        self.encoding.keyword()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SQUARE_ASCII: &str = "ply\r\nformat ascii 1.0\r\ncomment a square\r\n\
        element vertex 4\r\nproperty float x\r\nproperty float y\r\nproperty uchar red\r\nproperty float z\r\n\
        element face 2\r\nproperty uchar flags\r\nproperty list uchar int vertex_indices\r\n\
        element edge 1\r\nproperty int vertex1\r\nproperty int vertex2\r\n\
        end_header\r\n\
        0 0 255 0\r\n1 0 128 0\r\n1 1 0 0.5\r\n0 1 7 0\r\n\
        1 3 0 1 2\r\n2 3 0 2 3\r\n\
        0 1\r\n";

    fn limits() -> ReadLimits {
        ReadLimits::default()
    }

    #[test]
    fn ascii_reads_coordinates_in_any_property_order() {
        let (mesh, src) = read_ply(SQUARE_ASCII.as_bytes(), &limits()).unwrap();
        assert_eq!(src.encoding, Encoding::Ascii);
        assert_eq!(mesh.num_vertices(), 4);
        assert_eq!(mesh.positions()[2], DVec3::new(1.0, 1.0, 0.5));
        assert_eq!(mesh.face(1), &[0, 2, 3]);
    }

    #[test]
    fn ascii_identity_write_is_byte_identical_and_moves_only_coordinates() {
        let (mesh, src) = read_ply(SQUARE_ASCII.as_bytes(), &limits()).unwrap();
        let mut out = Vec::new();
        write_ply(&src, mesh.positions(), None, &mut out).unwrap();
        assert_eq!(String::from_utf8(out).unwrap(), SQUARE_ASCII);
        let mut moved = mesh.positions().to_vec();
        moved[1].z = 0.25;
        let mut out = Vec::new();
        write_ply(&src, &moved, None, &mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert!(text.contains("\r\n1 0 128 0.25\r\n"), "{text}");
        assert_eq!(
            read_ply(text.as_bytes(), &limits()).unwrap().0.positions(),
            &moved[..]
        );
    }

    #[test]
    fn binary_both_endians_round_trip_with_lists_in_vertices() {
        for (keyword, big) in [("binary_little_endian", false), ("binary_big_endian", true)] {
            let mut b = format!(
                "ply\nformat {keyword} 1.0\nelement vertex 3\nproperty list uchar short tags\n\
                 property double x\nproperty double y\nproperty double z\nproperty ushort id\n\
                 element face 1\nproperty list uchar uint vertex_index\nend_header\n"
            )
            .into_bytes();
            let put = |s: Scalar, v: f64, b: &mut Vec<u8>| {
                let mut raw = [0u8; 8];
                s.encode(v, big, &mut raw);
                b.extend_from_slice(&raw[..s.size()]);
            };
            for v in 0..3 {
                put(Scalar::U8, v as f64, &mut b);
                for t in 0..v {
                    put(Scalar::I16, -(t as f64), &mut b);
                }
                for c in [v as f64, 0.5 * v as f64, 1.0 / 3.0] {
                    put(Scalar::F64, c, &mut b);
                }
                put(Scalar::U16, 1000.0 + v as f64, &mut b);
            }
            put(Scalar::U8, 3.0, &mut b);
            for i in [2.0, 1.0, 0.0] {
                put(Scalar::U32, i, &mut b);
            }
            let (mesh, src) = read_ply(&b, &limits()).unwrap();
            assert_eq!(mesh.positions()[2], DVec3::new(2.0, 1.0, 1.0 / 3.0));
            assert_eq!(mesh.face(0), &[2, 1, 0]);
            let mut out = Vec::new();
            write_ply(&src, mesh.positions(), None, &mut out).unwrap();
            assert_eq!(out, b, "{keyword}");
            let moved: Vec<DVec3> = mesh.positions().iter().map(|p| *p * 2.0).collect();
            let mut out = Vec::new();
            write_ply(&src, &moved, None, &mut out).unwrap();
            assert_eq!(read_ply(&out, &limits()).unwrap().0.positions(), &moved[..]);
            assert_eq!(out.len(), b.len());
        }
    }

    #[test]
    fn results_are_appended_or_overwritten() {
        let (mesh, src) = read_ply(SQUARE_ASCII.as_bytes(), &limits()).unwrap();
        let label = [0u8, 1, 2, 3];
        let mean = [0.5, -0.25, 0.0, 1.0];
        let results = VertexResults {
            label: &label,
            mean_curvature: &mean,
            gaussian_curvature: &[],
            displacement: &[],
        };
        let mut out = Vec::new();
        write_ply(&src, mesh.positions(), Some(&results), &mut out).unwrap();
        let text = String::from_utf8(out.clone()).unwrap();
        assert!(text.contains("property float z\r\nproperty uchar label\nproperty float mean_curvature\nelement face"), "{text}");
        assert!(text.contains("\r\n1 0 128 0 1 -0.25\r\n"), "{text}");
        let (again, src2) = read_ply(&out, &limits()).unwrap();
        assert_eq!(again, mesh);
        // Writing results again overwrites the properties in place.
        let label2 = [9u8, 9, 9, 9];
        let results2 = VertexResults {
            label: &label2,
            ..results
        };
        let mut out2 = Vec::new();
        write_ply(&src2, again.positions(), Some(&results2), &mut out2).unwrap();
        let text2 = String::from_utf8(out2).unwrap();
        assert_eq!(text2.matches("property uchar label").count(), 1);
        assert!(text2.contains("\r\n1 0 128 0 9 -0.25\r\n"), "{text2}");
    }

    #[test]
    fn plain_writer_round_trips_polygons_and_results() {
        let mesh = Mesh::from_polygons(
            vec![
                DVec3::ZERO,
                DVec3::X,
                DVec3::new(1.0, 1.0, 0.1),
                DVec3::Y,
                DVec3::Z,
            ],
            &[vec![0u32, 1, 2, 3], vec![0, 1, 4]],
        )
        .unwrap();
        let disp = [0.0, 0.1, 0.2, 0.3, 0.4];
        let results = VertexResults {
            label: &[],
            mean_curvature: &[],
            gaussian_curvature: &[],
            displacement: &disp,
        };
        let mut out = Vec::new();
        write_ply_plain(&mesh, mesh.positions(), Some(&results), &mut out).unwrap();
        let (again, src) = read_ply(&out, &limits()).unwrap();
        assert_eq!(again, mesh);
        assert_eq!(src.encoding, Encoding::BinaryLittleEndian);
        assert!(
            src.vertex_properties
                .iter()
                .any(|p| p.name == "displacement")
        );
    }

    #[test]
    fn errors_are_specific() {
        let e = |b: &[u8]| read_ply(b, &limits()).unwrap_err();
        let err = e(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty int x\nend_header\n");
        assert!(err.to_string().contains("`x` has integer type"), "{err}");
        let err = e(b"ply\nformat ascii 2.0\nend_header\n");
        assert!(err.to_string().contains("line 2"), "{err}");
        let err = e(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n");
        assert_eq!(err.code(), "face_index_out_of_range", "{err}");
        let err = e(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 zz\n");
        assert!(
            err.to_string().contains("line 10") && err.to_string().contains("`zz`"),
            "{err}"
        );
        let err = e(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n");
        assert_eq!(err.code(), "no_faces");
        let err = e(b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n");
        assert_eq!(err.code(), "limit_exceeded");
        let err = e(b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\0\0\0\0");
        assert!(err.to_string().contains("can hold at most"), "{err}");
        let err = e(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n");
        assert!(err.to_string().contains("face 0 has 2 corners"), "{err}");
        assert_eq!(e(b"").code(), "parse_error");
    }
}
