//! Pieces shared by the line-based text formats, OBJ and OFF: the encoding
//! check, fields of a line, numbers read and written.

use super::IoError;
use glam::DVec3;
use std::sync::Arc;

/// Calls `each(text, offset, line)` for every line of `bytes` (without its
/// `\n`; `offset` is where it starts, `line` its 1-based number), after a
/// UTF-8 byte-order mark; stops at the first error.
pub(super) fn for_each_line(
    bytes: &[u8],
    mut each: impl FnMut(&[u8], usize, usize) -> Result<(), IoError>,
) -> Result<(), IoError> {
    const UTF8_BOM: &[u8] = b"\xEF\xBB\xBF";
    let mut pos = if bytes.starts_with(UTF8_BOM) {
        UTF8_BOM.len()
    } else {
        0
    };
    let mut line = 0usize;
    while pos < bytes.len() {
        line += 1;
        let rest = bytes.get(pos..).unwrap_or_default();
        let len = memchr::memchr(b'\n', rest).unwrap_or(rest.len());
        each(rest.get(..len).unwrap_or_default(), pos, line)?;
        pos += len + 1;
    }
    Ok(())
}

/// Rejects UTF-16 (by its byte-order mark or NUL bytes) and files whose only
/// line breaks are bare carriage returns, which would otherwise read as one
/// long line. `format` names the format in the messages.
pub(super) fn check_encoding(bytes: &[u8], format: &'static str) -> Result<(), IoError> {
    let error = |line: usize, message: String| IoError::Parse {
        format,
        line: Some(line),
        message,
    };
    if bytes.starts_with(b"\xFE\xFF") || bytes.starts_with(b"\xFF\xFE") {
        return Err(error(
            1,
            "the file is UTF-16 text (byte-order mark); save it as UTF-8 or ASCII".into(),
        ));
    }
    if let Some(at) = memchr::memchr(0, bytes) {
        let line = 1 + bytes
            .get(..at)
            .unwrap_or_default()
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        return Err(error(
            line,
            format!(
                "NUL byte: this is not a text {format} file (UTF-16 or binary?); save it as UTF-8 \
                 or ASCII"
            ),
        ));
    }
    if memchr::memchr(b'\n', bytes).is_none() && memchr::memchr(b'\r', bytes).is_some() {
        return Err(error(
            1,
            "lines end in a bare carriage return (classic Mac OS); convert the line endings to \\n or \\r\\n"
                .into(),
        ));
    }
    Ok(())
}

/// Blanks between fields. `\r` counts as one so `\r\n` endings need no
/// special case.
#[inline]
fn is_blank(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | b'\x0b' | b'\x0c')
}

/// Fields of one line, as byte ranges relative to the line.
pub(super) struct Fields<'a> {
    text: &'a [u8],
    pos: usize,
}

impl<'a> Fields<'a> {
    pub(super) fn new(text: &'a [u8]) -> Self {
        Fields { text, pos: 0 }
    }

    /// Next field as `(start, end, bytes)`; stops at a `#` comment.
    #[inline]
    pub(super) fn next_field(&mut self) -> Option<(usize, usize, &'a [u8])> {
        let t = self.text;
        let start = self.pos + t.get(self.pos..)?.iter().position(|&b| !is_blank(b))?;
        let rest = t.get(start..)?;
        if rest.first() == Some(&b'#') {
            self.pos = t.len();
            return None;
        }
        let len = rest.iter().position(|&b| is_blank(b)).unwrap_or(rest.len());
        self.pos = start + len;
        Some((start, self.pos, rest.get(..len)?))
    }

    /// The `x y z` fields that come next, parsed, and the byte range
    /// `start..end` (relative to the line) they take; `what` names the line's
    /// kind in the message when one is missing (``"`v`"``).
    #[inline]
    pub(super) fn xyz(
        &mut self,
        what: &str,
        line: usize,
        format: &'static str,
    ) -> Result<(DVec3, (usize, usize)), IoError> {
        let mut xyz = [0.0f64; 3];
        let mut span = (0, 0);
        for (axis, value) in ["x", "y", "z"].into_iter().zip(xyz.iter_mut()) {
            let Some((start, end, field)) = self.next_field() else {
                return Err(IoError::Parse {
                    format,
                    line: Some(line),
                    message: format!("{what} needs x, y and z coordinates; {axis} is missing"),
                });
            };
            *value = parse_coordinate(field, axis, line, format)?;
            if axis == "x" {
                span.0 = start;
            }
            span.1 = end;
        }
        Ok((DVec3::from_array(xyz), span))
    }
}

/// Parses a finite coordinate on `line`.
#[inline]
fn parse_coordinate(
    field: &[u8],
    axis: &str,
    line: usize,
    format: &'static str,
) -> Result<f64, IoError> {
    let error = |message: String| IoError::Parse {
        format,
        line: Some(line),
        message,
    };
    let text = std::str::from_utf8(field).map_err(|_| {
        error(format!(
            "{axis} coordinate is not a number (it has non-ASCII bytes)"
        ))
    })?;
    let value: f64 = text.parse().map_err(|_| {
        error(format!(
            "{axis} coordinate `{}` is not a number",
            shorten(text)
        ))
    })?;
    if !value.is_finite() {
        return Err(IoError::NonFiniteCoordinate {
            format,
            line: Some(line),
            message: format!(
                "{axis} coordinate `{}` is not finite (NaN or infinity)",
                shorten(text)
            ),
        });
    }
    Ok(value)
}

/// Parses an optionally signed decimal integer; `None` when malformed or
/// beyond 18 digits (no mesh has that many vertices).
#[inline]
pub(super) fn parse_index(text: &[u8]) -> Option<i64> {
    let (negative, digits) = match text.split_first() {
        Some((b'-', rest)) => (true, rest),
        Some((b'+', rest)) => (false, rest),
        _ => (false, text),
    };
    if digits.is_empty() || digits.len() > 18 {
        return None;
    }
    let mut value: i64 = 0;
    for &d in digits {
        if !d.is_ascii_digit() {
            return None;
        }
        value = value * 10 + i64::from(d - b'0');
    }
    Some(if negative { -value } else { value })
}

/// What a text format (OBJ, OFF) needs besides the mesh to be written
/// back: the original bytes and, per vertex, where its `x y z` fields lie in
/// them.
#[derive(Debug, Clone)]
pub struct TextSource {
    bytes: Arc<[u8]>,
    /// One entry per vertex: byte range `start..end` of the `x y z` fields.
    coords: Vec<(usize, usize)>,
}

impl TextSource {
    pub(super) fn new(bytes: &[u8], coords: Vec<(usize, usize)>) -> Self {
        TextSource {
            bytes: Arc::from(bytes),
            coords,
        }
    }

    /// Writes the file with `positions` (one per vertex) in place of the
    /// `x y z` fields; every other byte is copied unchanged.
    pub(super) fn write(&self, positions: &[DVec3], out: &mut Vec<u8>) -> Result<(), IoError> {
        let (bytes, coords) = (&self.bytes[..], &self.coords[..]);
        IoError::check_position_count(coords.len(), positions.len())?;
        out.reserve(bytes.len() + bytes.len() / 8);
        let mut copied = 0;
        for (v, (p, &(start, end))) in positions.iter().zip(coords).enumerate() {
            out.extend_from_slice(bytes.get(copied..start).unwrap_or_default());
            write_xyz(out, v, *p)?;
            copied = end;
        }
        out.extend_from_slice(bytes.get(copied..).unwrap_or_default());
        Ok(())
    }
}

/// `x y z` of vertex `vertex` with [`write_coordinate`]; a position that is
/// not finite is an error.
pub(super) fn write_xyz(out: &mut Vec<u8>, vertex: usize, p: DVec3) -> Result<(), IoError> {
    if !p.is_finite() {
        return Err(crate::error::MeshError::NonFinitePosition { vertex }.into());
    }
    write_coordinate(out, p.x);
    out.push(b' ');
    write_coordinate(out, p.y);
    out.push(b' ');
    write_coordinate(out, p.z);
    Ok(())
}

/// Shortest text that parses back to exactly `x` (`x` finite), without a
/// trailing `.0`; scientific notation only for very small or large
/// magnitudes.
pub(super) fn write_coordinate(out: &mut Vec<u8>, x: f64) {
    let mut buffer = zmij::Buffer::new();
    let text = buffer.format_finite(x);
    out.extend_from_slice(text.strip_suffix(".0").unwrap_or(text).as_bytes());
}

/// At most 40 characters of `text`, for messages.
pub(super) fn shorten(text: &str) -> &str {
    match text.char_indices().nth(40) {
        Some((at, _)) => text.get(..at).unwrap_or(text),
        None => text,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coordinates_are_written_short_and_exact() {
        for (x, text) in [
            (0.0, "0"),
            (-0.0, "-0"),
            (1.0, "1"),
            (0.1, "0.1"),
            (-4.33681e-19, "-4.33681e-19"),
            (1e300, "1e+300"),
            (16384.0, "16384"),
            (123456.75, "123456.75"),
        ] {
            let mut out = Vec::new();
            write_coordinate(&mut out, x);
            assert_eq!(std::str::from_utf8(&out).unwrap(), text);
        }
        for x in [
            f64::MIN_POSITIVE,
            f64::MAX,
            -f64::MAX,
            5e-324,
            1.0 / 3.0,
            2e-5,
            9.999e15,
        ] {
            let mut out = Vec::new();
            write_coordinate(&mut out, x);
            let back: f64 = std::str::from_utf8(&out).unwrap().parse().unwrap();
            assert_eq!(back.to_bits(), x.to_bits());
        }
    }
}
