//! Geomview OFF: `OFF`, `COFF`, `NOFF`, `CNOFF` (and `ST` texture coordinates), ASCII.
//!
//! Our own parser rather than `off-rs` 2.0: that crate has no `NOFF` normals or `ST` texture
//! coordinates, must be told up front whether colours are integers or floats (real files use
//! both), and its limits are global counts rather than "what the remaining bytes can hold".
//!
//! Rules:
//! - `#` starts a comment anywhere; blank lines are skipped anywhere.
//! - Header keyword `[ST][C][N]OFF` (optional, as in Geomview), optionally followed on the same
//!   line by the counts; `4OFF`/`nOFF` (other dimensions) and `OFF BINARY` are rejected.
//! - Counts `V F [E]` (E is ignored). They are checked against the bytes that follow before
//!   anything is allocated: every vertex line needs at least 6 bytes and every face line 2.
//! - One vertex per line: `x y z`, then `nx ny nz` if `N`, then 3 or 4 colour values if `C`,
//!   then `s t` if `ST` (v flipped to glTF's convention, `t' = 1 - t`). Extra values on a plain
//!   `OFF` vertex line are ignored.
//! - Colours are bytes (0–255, divided by 255) when every colour value in the file is an integer
//!   literal and at least one exceeds 1; otherwise floats in `[0, 1]`. Missing alpha is opaque.
//! - One face per line: `n i0 i1 ... i(n-1)`, optionally followed by a face colour (ignored).
//!   Polygons are fan-triangulated `(i0, ik, ik+1)`; faces with fewer than 3 vertices are
//!   skipped. Anything after the last face (edges) is ignored.

use super::{index_base, parse_error};
use crate::mesh::{Material, Mesh, MeshError};

const FORMAT: &str = "OFF";

/// Fewest bytes a vertex line can take: `0 0 0` and a line break.
const MIN_VERTEX_LINE_BYTES: u64 = 6;
/// Fewest bytes a face line can take: `0` and a line break.
const MIN_FACE_LINE_BYTES: u64 = 2;
/// Fewest bytes a triangle's face line can take: `3 0 1 2` and a line break.
const MIN_TRIANGLE_LINE_BYTES: u64 = 8;

/// Loads OFF bytes into an unvalidated mesh.
pub(super) fn load(bytes: &[u8]) -> Result<Mesh, MeshError> {
    let mut lines = Lines {
        bytes,
        pos: 0,
        line: 0,
    };
    let (line_no, first) = lines
        .next_content()?
        .ok_or_else(|| parse_error(FORMAT, "the file is empty: expected an `OFF` header"))?;
    let mut tokens = first.split_whitespace();
    let first_token = tokens.next().unwrap_or_default();
    let (flags, count_tokens): (Flags, Vec<&str>) = if first_token.ends_with("OFF") {
        let flags = Flags::parse(first_token, line_no)?;
        let rest: Vec<&str> = tokens.collect();
        if rest
            .first()
            .is_some_and(|t| t.eq_ignore_ascii_case("BINARY"))
        {
            return Err(parse_error(
                FORMAT,
                "binary OFF is not supported: convert it to ASCII OFF",
            ));
        }
        if rest.is_empty() {
            let (_, counts_line) = lines.next_content()?.ok_or_else(|| {
                parse_error(
                    FORMAT,
                    "the file ends after the header: expected the counts `V F E`",
                )
            })?;
            (flags, counts_line.split_whitespace().collect())
        } else {
            (flags, rest)
        }
    } else if first_token.parse::<u64>().is_ok() {
        // Geomview makes the keyword optional: the first line is then the counts.
        (Flags::default(), first.split_whitespace().collect())
    } else {
        return Err(parse_error(
            FORMAT,
            format!(
                "line {line_no}: expected an `OFF`, `COFF`, `NOFF` or `CNOFF` header, found `{}`",
                clip(first_token)
            ),
        ));
    };

    let count = |i: usize, what: &str| -> Result<u64, MeshError> {
        let token = count_tokens.get(i).ok_or_else(|| {
            parse_error(
                FORMAT,
                format!("the counts line needs `V F E`, it has no {what}"),
            )
        })?;
        token.parse::<u64>().map_err(|_| {
            parse_error(
                FORMAT,
                format!("the {what} `{}` is not a non-negative integer", clip(token)),
            )
        })
    };
    let vertex_count = count(0, "vertex count")?;
    let face_count = count(1, "face count")?;
    let remaining = lines.remaining() as u64;
    let needed = vertex_count
        .saturating_mul(MIN_VERTEX_LINE_BYTES)
        .saturating_add(face_count.saturating_mul(MIN_FACE_LINE_BYTES));
    // The last line may lack its line break.
    if needed > remaining.saturating_add(1) {
        return Err(parse_error(
            FORMAT,
            format!(
                "the header claims {vertex_count} vertices and {face_count} faces, but only {remaining} bytes follow: the file is truncated or its counts are wrong"
            ),
        ));
    }
    // Both counts are now bounded by the file size.
    let vertex_count = usize::try_from(vertex_count)
        .map_err(|_| parse_error(FORMAT, "vertex count exceeds this platform's memory"))?;
    let face_count = usize::try_from(face_count)
        .map_err(|_| parse_error(FORMAT, "face count exceeds this platform's memory"))?;
    index_base(FORMAT, vertex_count)?;

    let mut positions = Vec::with_capacity(vertex_count);
    let mut normals = Vec::with_capacity(if flags.normals { vertex_count } else { 0 });
    let mut uvs = Vec::with_capacity(if flags.texcoords { vertex_count } else { 0 });
    let mut colors = Colors::with_capacity(if flags.colors { vertex_count } else { 0 });
    for index in 0..vertex_count {
        let (line_no, line) = lines.next_content()?.ok_or_else(|| {
            parse_error(
                FORMAT,
                format!("the file ends after {index} of {vertex_count} vertices"),
            )
        })?;
        let values: Vec<&str> = line.split_whitespace().collect();
        let at = |what: &str| format!("vertex {index} (line {line_no}): {what}");
        let position: [f32; 3] = floats(&values, 0, "position x y z", &at)?;
        positions.push(position);
        let mut next = 3;
        if flags.normals {
            normals.push(floats::<3>(&values, 3, "normal nx ny nz", &at)?);
            next = 6;
        }
        let mut end = values.len();
        if flags.texcoords {
            let st_start = end.checked_sub(2).filter(|&s| s >= next).ok_or_else(|| {
                parse_error(
                    FORMAT,
                    at("expected texture coordinates `s t` at the end of the line"),
                )
            })?;
            let [s, t] = floats::<2>(&values, st_start, "texture coordinates s t", &at)?;
            uvs.push([s, 1.0 - t]);
            end = st_start;
        }
        if flags.colors {
            let color_tokens = values.get(next..end).unwrap_or_default();
            if !(3..=4).contains(&color_tokens.len()) {
                return Err(parse_error(
                    FORMAT,
                    at(&format!(
                        "expected 3 or 4 colour values, found {}",
                        color_tokens.len()
                    )),
                ));
            }
            let mut rgba = [0.0f32; 4];
            for (value, token) in rgba.iter_mut().zip(color_tokens) {
                *value = number(token, "colour", &at)?;
            }
            colors.push(&rgba[..color_tokens.len()], color_tokens);
        }
    }

    let triangle_capacity =
        face_count.min((lines.remaining() as u64 / MIN_TRIANGLE_LINE_BYTES) as usize + 1);
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(triangle_capacity);
    let mut skipped = 0usize;
    let mut corners: Vec<u32> = Vec::new();
    for face in 0..face_count {
        let (line_no, line) = lines.next_content()?.ok_or_else(|| {
            parse_error(
                FORMAT,
                format!("the file ends after {face} of {face_count} faces"),
            )
        })?;
        let mut values = line.split_whitespace();
        let arity_token = values.next().unwrap_or_default();
        let arity: usize = arity_token.parse().map_err(|_| {
            parse_error(
                FORMAT,
                format!("face {face} (line {line_no}): the vertex count `{}` is not a non-negative integer", clip(arity_token)),
            )
        })?;
        corners.clear();
        for k in 0..arity {
            let token = values.next().ok_or_else(|| {
                parse_error(
                    FORMAT,
                    format!("face {face} (line {line_no}) lists {arity} vertices but the line has only {k}"),
                )
            })?;
            let vertex: u64 = token.parse().map_err(|_| {
                parse_error(
                    FORMAT,
                    format!("face {face} (line {line_no}): vertex index `{}` is not a non-negative integer", clip(token)),
                )
            })?;
            match u32::try_from(vertex) {
                Ok(v) if (v as usize) < vertex_count => corners.push(v),
                _ => {
                    return Err(MeshError::IndexOutOfRange {
                        triangle: triangles.len(),
                        vertex,
                        vertex_count,
                    });
                }
            }
        }
        match corners.as_slice() {
            [first, rest @ ..] if rest.len() >= 2 => {
                triangles.extend(rest.windows(2).map(|pair| [*first, pair[0], pair[1]]));
            }
            _ => skipped += 1,
        }
    }
    if skipped > 0 {
        tracing::warn!(skipped, "OFF faces with fewer than 3 vertices skipped");
    }

    let triangle_materials = vec![0; triangles.len()];
    Ok(Mesh {
        positions,
        normals,
        uvs: flags.texcoords.then_some(uvs),
        colors: flags.colors.then(|| colors.finish()),
        triangles,
        triangle_materials,
        materials: vec![Material::default()],
        textures: Vec::new(),
    })
}

/// `N` numbers from `values[start..]`; `at` prefixes error messages with the location.
fn floats<const N: usize>(
    values: &[&str],
    start: usize,
    what: &str,
    at: &dyn Fn(&str) -> String,
) -> Result<[f32; N], MeshError> {
    let tokens = start
        .checked_add(N)
        .and_then(|end| values.get(start..end))
        .ok_or_else(|| {
            parse_error(
                FORMAT,
                at(&format!("expected {what}, the line has too few values")),
            )
        })?;
    let mut out = [0.0; N];
    for (value, token) in out.iter_mut().zip(tokens) {
        *value = number(token, what, at)?;
    }
    Ok(out)
}

/// One number (`nan` and `inf` parse; [`Mesh::finish`] rejects them).
fn number(token: &str, what: &str, at: &dyn Fn(&str) -> String) -> Result<f32, MeshError> {
    token.parse::<f32>().map_err(|_| {
        parse_error(
            FORMAT,
            at(&format!("`{}` in the {what} is not a number", clip(token))),
        )
    })
}

/// The optional parts of each vertex line, from the header keyword.
#[derive(Clone, Copy, Debug, Default)]
struct Flags {
    texcoords: bool,
    colors: bool,
    normals: bool,
}

impl Flags {
    /// Parses `[ST][C][N]OFF` (the prefixes in any order).
    fn parse(keyword: &str, line_no: usize) -> Result<Flags, MeshError> {
        let mut flags = Flags::default();
        let mut prefix = keyword.strip_suffix("OFF").unwrap_or(keyword);
        loop {
            if let Some(rest) = prefix.strip_prefix("ST") {
                flags.texcoords = true;
                prefix = rest;
            } else if let Some(rest) = prefix.strip_prefix('C') {
                flags.colors = true;
                prefix = rest;
            } else if let Some(rest) = prefix.strip_prefix('N') {
                flags.normals = true;
                prefix = rest;
            } else {
                break;
            }
        }
        match prefix {
            "" => Ok(flags),
            p if p.contains('4') || p.contains('n') => Err(parse_error(
                FORMAT,
                format!(
                    "line {line_no}: `{}` is a 4-D or n-D OFF; only 3-D OFF is supported",
                    clip(keyword)
                ),
            )),
            _ => Err(parse_error(
                FORMAT,
                format!(
                    "line {line_no}: unknown header `{}`: use OFF, COFF, NOFF, CNOFF or STOFF",
                    clip(keyword)
                ),
            )),
        }
    }
}

/// Vertex colours as read, scaled once the whole file has been seen.
struct Colors {
    /// RGBA as read; alpha is `None` where the line had only RGB.
    rgba: Vec<([f32; 3], Option<f32>)>,
    all_integer_literals: bool,
    any_above_one: bool,
}

impl Colors {
    fn with_capacity(capacity: usize) -> Colors {
        Colors {
            rgba: Vec::with_capacity(capacity),
            all_integer_literals: true,
            any_above_one: false,
        }
    }

    /// `values` are the 3 or 4 parsed `tokens`.
    fn push(&mut self, values: &[f32], tokens: &[&str]) {
        self.all_integer_literals &= tokens.iter().all(|t| is_integer_literal(t));
        self.any_above_one |= values.iter().any(|&v| v > 1.0);
        let channel = |i: usize| values.get(i).copied().unwrap_or(0.0);
        self.rgba
            .push(([channel(0), channel(1), channel(2)], values.get(3).copied()));
    }

    fn finish(self) -> Vec<[f32; 4]> {
        let scale = if self.all_integer_literals && self.any_above_one {
            1.0 / 255.0
        } else {
            1.0
        };
        self.rgba
            .into_iter()
            .map(|([r, g, b], a)| {
                [
                    r * scale,
                    g * scale,
                    b * scale,
                    a.map_or(1.0, |a| a * scale),
                ]
            })
            .collect()
    }
}

fn is_integer_literal(token: &str) -> bool {
    let digits = token.strip_prefix(['+', '-']).unwrap_or(token);
    !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit())
}

/// The content lines of an OFF file: comments stripped, blank lines skipped, numbered from 1.
struct Lines<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: usize,
}

impl<'a> Lines<'a> {
    /// Bytes not yet consumed.
    fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }

    /// The next line with content, as (line number, trimmed text without comment).
    fn next_content(&mut self) -> Result<Option<(usize, &'a str)>, MeshError> {
        while self.pos < self.bytes.len() {
            let rest = self.bytes.get(self.pos..).unwrap_or_default();
            let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
            let raw = rest.get(..len).unwrap_or_default();
            self.pos += len + 1;
            self.line += 1;
            let raw = raw.split(|&b| b == b'#').next().unwrap_or_default();
            let text = std::str::from_utf8(raw).map_err(|_| {
                parse_error(
                    FORMAT,
                    format!(
                        "line {} is not text: the file is not an ASCII OFF file",
                        self.line
                    ),
                )
            })?;
            let text = text.trim_start_matches('\u{feff}').trim();
            if !text.is_empty() {
                return Ok(Some((self.line, text)));
            }
        }
        Ok(None)
    }
}

/// A token shortened for error messages (hostile files can have megabyte-long tokens).
fn clip(token: &str) -> String {
    const MAX_CHARS: usize = 40;
    if token.chars().count() <= MAX_CHARS {
        token.to_owned()
    } else {
        format!("{}…", token.chars().take(MAX_CHARS).collect::<String>())
    }
}
