//! Triangle meshes: the in-memory form every loader produces and the baker and reference renderer
//! consume (DESIGN §3 shading inputs: positions, normals, optional UVs, vertex colours, materials).

mod demo;
mod load;

pub use demo::{DEMO_SOURCE_NAME, demo_mesh, demo_provenance};
pub use load::{
    AnimationFrames, MAX_ANIMATION_FRAMES, MeshFormat, load_animation, load_mesh,
    load_mesh_from_bytes,
};

use glam::DVec3;

/// Material factor used where the file defines no material (DESIGN §3: default 0.8 grey).
pub const DEFAULT_BASE_COLOR: [f32; 4] = [0.8, 0.8, 0.8, 1.0];

/// Largest texture side kept after loading; larger ones are downscaled (bounded GPU memory).
pub const MAX_TEXTURE_PX: u32 = 4096;

/// Errors while loading or validating a mesh.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// The file could not be read.
    #[error("cannot read mesh file {path}: {source}")]
    Io {
        /// The path.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file extension is not a known mesh format.
    #[error("unknown mesh format `{0}`: use .gltf, .glb, .obj, .ply, .stl or .off")]
    UnknownFormat(String),
    /// The file is malformed for its format.
    #[error("malformed {format} mesh: {message}")]
    Parse {
        /// Format name.
        format: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The mesh has no triangles.
    #[error("mesh has no triangles")]
    Empty,
    /// A vertex attribute holds NaN or infinity.
    #[error("mesh vertex {index} has a non-finite {attribute}")]
    NonFinite {
        /// Attribute name.
        attribute: &'static str,
        /// Vertex index.
        index: usize,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error(
        "triangle {triangle} refers to vertex {vertex}, but the mesh has {vertex_count} vertices"
    )]
    IndexOutOfRange {
        /// Triangle index.
        triangle: usize,
        /// Offending vertex index.
        vertex: u64,
        /// Number of vertices.
        vertex_count: usize,
    },
    /// Every triangle has zero area.
    #[error("mesh has only degenerate (zero-area) triangles")]
    AllDegenerate,
    /// Attribute arrays disagree in length.
    #[error("mesh attribute `{attribute}` has {got} entries, expected {expected}")]
    AttributeLength {
        /// Attribute name.
        attribute: &'static str,
        /// Entries found.
        got: usize,
        /// Entries expected (the vertex count).
        expected: usize,
    },
    /// A texture could not be decoded or is unusable.
    #[error("texture {index}: {message}")]
    Texture {
        /// Texture index.
        index: usize,
        /// What is wrong.
        message: String,
    },
}

/// An RGBA8 image used as a base-colour texture; bytes are display values (no sRGB decoding).
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 4` bytes, row-major, top row first.
    pub rgba8: Vec<u8>,
}

/// A material: base-colour factor times an optional texture.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Multiplies texture and vertex colour; RGBA in \[0, 1\].
    pub base_color_factor: [f32; 4],
    /// Index into [`Mesh::textures`].
    pub base_color_texture: Option<u32>,
}

impl Default for Material {
    fn default() -> Self {
        Self {
            base_color_factor: DEFAULT_BASE_COLOR,
            base_color_texture: None,
        }
    }
}

/// An indexed triangle mesh ready for baking.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions, world units.
    pub positions: Vec<[f32; 3]>,
    /// Unit vertex normals (area-weighted face normals where the source has none).
    pub normals: Vec<[f32; 3]>,
    /// Texture coordinates (glTF convention: v down, origin top-left), if any.
    pub uvs: Option<Vec<[f32; 2]>>,
    /// Vertex colours RGBA in \[0, 1\], if any.
    pub colors: Option<Vec<[f32; 4]>>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Material index per triangle (same length as `triangles`).
    pub triangle_materials: Vec<u32>,
    /// Materials; at least one.
    pub materials: Vec<Material>,
    /// Base-colour textures.
    pub textures: Vec<Texture>,
}

impl Mesh {
    /// Hex SHA-256 of the geometry: positions, then triangles, as little-endian bytes (for
    /// sources that are not files, such as the demo or arrays).
    pub fn geometry_sha256(&self) -> String {
        use sha2::Digest;
        let mut bytes = Vec::with_capacity(12 * (self.positions.len() + self.triangles.len()));
        for c in self.positions.iter().flatten() {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
        for i in self.triangles.iter().flatten() {
            bytes.extend_from_slice(&i.to_le_bytes());
        }
        sha2::Sha256::digest(&bytes)
            .iter()
            .fold(String::with_capacity(64), |mut hex, b| {
                use std::fmt::Write;
                let _ = write!(hex, "{b:02x}");
                hex
            })
    }
}

/// The smallest sphere found around a set of points (Ritter's bound refined; within a few
/// per cent of optimal, always containing every point).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoundingSphere {
    /// Centre, world units.
    pub center: DVec3,
    /// Radius, world units; > 0.
    pub radius: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn geometry_hash_covers_positions_then_triangles() {
        // SHA-256 of no bytes.
        assert_eq!(
            Mesh::default().geometry_sha256(),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
        let mesh = Mesh {
            positions: vec![[0.0, 1.0, 2.0]],
            triangles: vec![[0, 0, 0]],
            ..Mesh::default()
        };
        let mut swapped = mesh.clone();
        swapped.triangles = vec![[0, 0, 1]];
        assert_ne!(mesh.geometry_sha256(), swapped.geometry_sha256());
        assert_eq!(mesh.geometry_sha256().len(), 64);
        let provenance = demo_provenance(&mesh);
        assert_eq!(provenance.source_name, DEMO_SOURCE_NAME);
        assert_eq!(provenance.source_sha256, mesh.geometry_sha256());
    }
}
