//! Stanford PLY (ASCII, binary little- and big-endian) via `ply-rs-bw`.
//!
//! Rules:
//! - Element `vertex`: `x y z` (any numeric type, required); optional normal `nx ny nz`;
//!   optional colour `red green blue [alpha]` — `uchar` (and other integer types) divided by
//!   255, `ushort` by 65535, `float`/`double` taken as they are; missing alpha is opaque;
//!   optional texture coordinates `u v`, `s t`, `texture_u texture_v` or `texture_s texture_t`
//!   (v flipped to glTF's convention, `v' = 1 - v`). Other properties are ignored.
//! - Element `face`: list `vertex_indices` (or `vertex_index`) of any integer type; polygons
//!   are fan-triangulated `(i0, ik, ik+1)`, faces with fewer than 3 indices skipped, negative
//!   indices rejected. Other elements (edges, materials...) are read and ignored.
//! - Counts in the header are not trusted: `ply-rs-bw` caps preallocation (64 Ki elements) and
//!   fails at the end of the data.

use std::io::Cursor;

use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{ElementDef, PropertyAccess, PropertyAccessResult};

use super::{index_base, parse_error};
use crate::mesh::{Material, Mesh, MeshError};

const FORMAT: &str = "PLY";

/// Loads PLY bytes into an unvalidated mesh.
pub(super) fn load(bytes: &[u8]) -> Result<Mesh, MeshError> {
    let mut reader = Reader::new(Cursor::new(bytes));
    let header = Parser::<IgnoredElement>::new()
        .read_header(&mut reader)
        .map_err(|e| parse_error(FORMAT, format!("header: {e}")))?;
    let vertex_def = header
        .elements
        .get("vertex")
        .ok_or_else(|| parse_error(FORMAT, "the header declares no `vertex` element"))?;
    let layout = VertexLayout::of(vertex_def)?;
    // Every entry of an element takes at least one byte (ASCII: its line's newline; binary:
    // its properties); a larger declared count is a lie that the payload parser would try to
    // allocate up front (found by fuzzing: a count near 2^63 aborted on allocation).
    for (name, def) in &header.elements {
        if def.count > bytes.len() {
            return Err(parse_error(
                FORMAT,
                format!(
                    "element `{name}` declares {} entries, more than the file's {} bytes can hold",
                    def.count,
                    bytes.len()
                ),
            ));
        }
    }

    let mut vertices: Vec<PlyVertex> = Vec::new();
    let mut faces: Vec<PlyFace> = Vec::new();
    for (name, def) in &header.elements {
        let element_error = |e: ply_rs_bw::parser::ParseError| {
            parse_error(FORMAT, format!("element `{name}`: {e}"))
        };
        match name.as_str() {
            "vertex" => {
                vertices = Parser::<PlyVertex>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(element_error)?;
            }
            "face" => {
                faces = Parser::<PlyFace>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(element_error)?;
            }
            _ => {
                // Read to stay in step with the payload, then drop.
                Parser::<IgnoredElement>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(element_error)?;
            }
        }
    }

    index_base(FORMAT, vertices.len())?;
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(faces.len());
    let mut skipped = 0usize;
    for (face_index, face) in faces.iter().enumerate() {
        if let Some(message) = &face.error {
            return Err(parse_error(FORMAT, format!("face {face_index}: {message}")));
        }
        let corner = |i: &i64| -> Result<u32, MeshError> {
            u32::try_from(*i).map_err(|_| {
                parse_error(
                    FORMAT,
                    format!("face {face_index} has the negative or too large vertex index {i}"),
                )
            })
        };
        match face.indices.as_slice() {
            [first, rest @ ..] if rest.len() >= 2 => {
                let first = corner(first)?;
                for pair in rest.windows(2) {
                    if let [b, c] = pair {
                        triangles.push([first, corner(b)?, corner(c)?]);
                    }
                }
            }
            _ => skipped += 1,
        }
    }
    if skipped > 0 {
        tracing::warn!(skipped, "PLY faces with fewer than 3 vertices skipped");
    }
    if faces.is_empty() && !vertices.is_empty() {
        tracing::warn!("PLY file has vertices but no `face` element (a point cloud?)");
    }

    let positions = vertices
        .iter()
        .map(|v| v.position.map(|c| c as f32))
        .collect();
    let normals = if layout.normals {
        vertices.iter().map(|v| v.normal).collect()
    } else {
        Vec::new()
    };
    let colors = layout.colors.then(|| {
        vertices
            .iter()
            .map(|v| {
                let [r, g, b, a] = v.color;
                [r, g, b, if layout.alpha { a } else { 1.0 }]
            })
            .collect()
    });
    let uvs = layout
        .uvs
        .then(|| vertices.iter().map(|v| [v.uv[0], 1.0 - v.uv[1]]).collect());
    let triangle_materials = vec![0; triangles.len()];
    Ok(Mesh {
        positions,
        normals,
        uvs,
        colors,
        triangles,
        triangle_materials,
        materials: vec![Material::default()],
        textures: Vec::new(),
    })
}

/// Which optional vertex attributes the header declares (all components of each).
struct VertexLayout {
    normals: bool,
    colors: bool,
    alpha: bool,
    uvs: bool,
}

impl VertexLayout {
    fn of(def: &ElementDef) -> Result<VertexLayout, MeshError> {
        let mut seen = [[false; 4]; 4];
        for name in def.properties.keys() {
            if let Some((slot, component)) = Slot::of(name)
                && let Some(flag) = seen
                    .get_mut(slot as usize)
                    .and_then(|s| s.get_mut(component))
            {
                *flag = true;
            }
        }
        let [position, normal, color, uv] = seen;
        if !position[..3].iter().all(|&b| b) {
            return Err(parse_error(
                FORMAT,
                "the `vertex` element needs properties `x`, `y` and `z`",
            ));
        }
        Ok(VertexLayout {
            normals: normal[..3].iter().all(|&b| b),
            colors: color[..3].iter().all(|&b| b),
            alpha: color[3],
            uvs: uv[0] && uv[1],
        })
    }
}

#[derive(Clone, Copy)]
enum Slot {
    Position = 0,
    Normal = 1,
    Color = 2,
    Uv = 3,
}

impl Slot {
    /// The attribute and component a vertex property name feeds, if any.
    fn of(name: &str) -> Option<(Slot, usize)> {
        Some(match name {
            "x" => (Slot::Position, 0),
            "y" => (Slot::Position, 1),
            "z" => (Slot::Position, 2),
            "nx" => (Slot::Normal, 0),
            "ny" => (Slot::Normal, 1),
            "nz" => (Slot::Normal, 2),
            "red" => (Slot::Color, 0),
            "green" => (Slot::Color, 1),
            "blue" => (Slot::Color, 2),
            "alpha" => (Slot::Color, 3),
            "u" | "s" | "texture_u" | "texture_s" => (Slot::Uv, 0),
            "v" | "t" | "texture_v" | "texture_t" => (Slot::Uv, 1),
            _ => return None,
        })
    }
}

/// One PLY vertex as read; only the attributes in [`VertexLayout`] are used.
#[derive(Clone, Copy, Debug, Default)]
struct PlyVertex {
    position: [f64; 3],
    normal: [f32; 3],
    color: [f32; 4],
    uv: [f32; 2],
}

impl PlyVertex {
    /// Stores `value` (of an integer type with maximum `integer_max` when that is `Some`).
    fn set(&mut self, name: &str, value: f64, integer_max: Option<f64>) -> PropertyAccessResult {
        let Some((slot, component)) = Slot::of(name) else {
            return PropertyAccessResult::Ignored;
        };
        let target = match slot {
            Slot::Position => {
                if let Some(c) = self.position.get_mut(component) {
                    *c = value;
                }
                return PropertyAccessResult::Set;
            }
            Slot::Normal => self.normal.get_mut(component),
            Slot::Color => {
                let scaled = integer_max.map_or(value, |max| value / max);
                if let Some(c) = self.color.get_mut(component) {
                    *c = scaled as f32;
                }
                return PropertyAccessResult::Set;
            }
            Slot::Uv => self.uv.get_mut(component),
        };
        if let Some(c) = target {
            *c = value as f32;
        }
        PropertyAccessResult::Set
    }
}

/// Integer colour channels are bytes, except 16-bit ones (PLY writers use `ushort` for 16-bit
/// colour).
const BYTE_MAX: Option<f64> = Some(255.0);
const SHORT_MAX: Option<f64> = Some(65_535.0);

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        PlyVertex::default()
    }
    fn set_char(&mut self, name: &str, value: i8) -> PropertyAccessResult {
        self.set(name, f64::from(value), BYTE_MAX)
    }
    fn set_uchar(&mut self, name: &str, value: u8) -> PropertyAccessResult {
        self.set(name, f64::from(value), BYTE_MAX)
    }
    fn set_short(&mut self, name: &str, value: i16) -> PropertyAccessResult {
        self.set(name, f64::from(value), SHORT_MAX)
    }
    fn set_ushort(&mut self, name: &str, value: u16) -> PropertyAccessResult {
        self.set(name, f64::from(value), SHORT_MAX)
    }
    fn set_int(&mut self, name: &str, value: i32) -> PropertyAccessResult {
        self.set(name, f64::from(value), BYTE_MAX)
    }
    fn set_uint(&mut self, name: &str, value: u32) -> PropertyAccessResult {
        self.set(name, f64::from(value), BYTE_MAX)
    }
    fn set_float(&mut self, name: &str, value: f32) -> PropertyAccessResult {
        self.set(name, f64::from(value), None)
    }
    fn set_double(&mut self, name: &str, value: f64) -> PropertyAccessResult {
        self.set(name, value, None)
    }
}

/// One PLY face: its vertex indices (widened), or why they are unusable.
#[derive(Debug, Default)]
struct PlyFace {
    indices: Vec<i64>,
    error: Option<String>,
}

impl PlyFace {
    fn set_indices(
        &mut self,
        name: &str,
        values: impl Iterator<Item = i64>,
    ) -> PropertyAccessResult {
        if is_index_list(name) {
            self.indices.clear();
            self.indices.extend(values);
            PropertyAccessResult::Set
        } else {
            PropertyAccessResult::Ignored
        }
    }
}

fn is_index_list(name: &str) -> bool {
    name == "vertex_indices" || name == "vertex_index"
}

impl PropertyAccess for PlyFace {
    fn new() -> Self {
        PlyFace::default()
    }
    fn set_list_char(&mut self, name: &str, value: Vec<i8>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn set_list_uchar(&mut self, name: &str, value: Vec<u8>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn set_list_short(&mut self, name: &str, value: Vec<i16>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn set_list_ushort(&mut self, name: &str, value: Vec<u16>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn set_list_int(&mut self, name: &str, value: Vec<i32>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn set_list_uint(&mut self, name: &str, value: Vec<u32>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn set_list_float(&mut self, name: &str, _value: Vec<f32>) -> PropertyAccessResult {
        self.float_indices(name)
    }
    fn set_list_double(&mut self, name: &str, _value: Vec<f64>) -> PropertyAccessResult {
        self.float_indices(name)
    }
}

impl PlyFace {
    fn float_indices(&mut self, name: &str) -> PropertyAccessResult {
        if is_index_list(name) {
            self.error = Some(format!(
                "`{name}` is a list of floats; it must be an integer list"
            ));
        }
        PropertyAccessResult::Ignored
    }
}

/// Elements we do not use (edges, materials, ...): read and dropped.
#[derive(Debug)]
struct IgnoredElement;

impl PropertyAccess for IgnoredElement {
    fn new() -> Self {
        IgnoredElement
    }
}
