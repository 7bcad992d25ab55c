//! STL, ASCII and binary, via `stl_io`.
//!
//! Rules:
//! - Vertices are deduplicated by exact position (bit pattern; `stl_io`'s indexed mesh), so
//!   shared corners become shared vertices and normals are smooth across them.
//! - The facet normals of the file are ignored (too often zero or wrong in real files); vertex
//!   normals are computed (area-weighted) by [`Mesh::finish`]. No colours, no UVs, one default
//!   material.
//! - Binary or ASCII is decided from the bytes: a file whose size is exactly `84 + 50 × count`
//!   (count from bytes 80..84) is binary even when its 80-byte header starts with `solid` (as
//!   some exporters write it); a file that starts with `solid` otherwise is ASCII. A binary
//!   file's triangle count is checked against its size before reading.

use std::io::Cursor;

use super::parse_error;
use crate::mesh::{Material, Mesh, MeshError};

const FORMAT: &str = "STL";
const BINARY_HEADER_BYTES: usize = 84;
const BINARY_TRIANGLE_BYTES: u64 = 50;

/// Loads STL bytes into an unvalidated mesh.
pub(super) fn load(bytes: &[u8]) -> Result<Mesh, MeshError> {
    let binary_count = binary_triangle_count(bytes);
    let starts_solid = bytes.starts_with(b"solid");
    let patched: Vec<u8>;
    let input: &[u8] = match binary_count {
        Some(count)
            if u64::from(count) * BINARY_TRIANGLE_BYTES + BINARY_HEADER_BYTES as u64
                == bytes.len() as u64 =>
        {
            if starts_solid {
                // `stl_io` would take it for ASCII: hide the word from its probe.
                patched = [b"binary".as_slice(), bytes.get(6..).unwrap_or_default()].concat();
                &patched
            } else {
                bytes
            }
        }
        Some(count) if starts_solid && !looks_like_text(bytes) => {
            return Err(parse_error(
                FORMAT,
                format!(
                    "binary STL (header starting with `solid`) of {} bytes cannot hold the {count} triangles it claims (84 + 50 per triangle): the file is truncated or corrupt",
                    bytes.len()
                ),
            ));
        }
        _ if starts_solid => {
            if bytes.get(5).is_some_and(|&b| b == b' ') {
                bytes
            } else {
                // `stl_io` wants `solid ` with a space; `solid\n` (no name) is common too.
                patched = [b"solid ".as_slice(), bytes.get(5..).unwrap_or_default()].concat();
                &patched
            }
        }
        Some(count) => {
            let available = (bytes.len() - BINARY_HEADER_BYTES) as u64 / BINARY_TRIANGLE_BYTES;
            if u64::from(count) > available {
                return Err(parse_error(
                    FORMAT,
                    format!(
                        "binary STL header claims {count} triangles, but its {} bytes hold only {available}: the file is truncated",
                        bytes.len()
                    ),
                ));
            }
            bytes
        }
        None => {
            return Err(parse_error(
                FORMAT,
                format!(
                    "{} bytes are neither ASCII STL (starting with `solid`) nor binary STL (84-byte header)",
                    bytes.len()
                ),
            ));
        }
    };

    let mut cursor = Cursor::new(input);
    let indexed = stl_io::create_stl_reader(&mut cursor)
        .and_then(|mut reader| reader.as_indexed_triangles())
        .map_err(|e| parse_error(FORMAT, e.to_string()))?;

    super::index_base(FORMAT, indexed.vertices.len())?;
    let positions = indexed.vertices.iter().map(|v| v.0).collect();
    let triangles: Vec<[u32; 3]> = indexed
        .faces
        .iter()
        // In range by construction (indices into `vertices`, whose length fits u32).
        .map(|face| face.vertices.map(|v| v as u32))
        .collect();
    let triangle_materials = vec![0; triangles.len()];
    Ok(Mesh {
        positions,
        normals: Vec::new(),
        uvs: None,
        colors: None,
        triangles,
        triangle_materials,
        materials: vec![Material::default()],
        textures: Vec::new(),
    })
}

/// Whether the first KiB is plain text (ASCII STL), not binary floats.
fn looks_like_text(bytes: &[u8]) -> bool {
    bytes
        .iter()
        .take(1024)
        .all(|&b| b.is_ascii_graphic() || b.is_ascii_whitespace())
}

/// The triangle count of a binary STL header, if the bytes are long enough to hold one.
fn binary_triangle_count(bytes: &[u8]) -> Option<u32> {
    let count: [u8; 4] = bytes.get(80..84)?.try_into().ok()?;
    Some(u32::from_le_bytes(count))
}
