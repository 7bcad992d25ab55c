//! Mesh loading: glTF/GLB, OBJ, PLY, STL and OFF files into one validated [`Mesh`].
//!
//! Every loader ends in [`Mesh::finish`], so every mesh that leaves this module has passed the
//! same checks (finite attributes, indices in range, no degenerate triangles, unit normals, at
//! least one material, bounded textures).
//!
//! # Shading inputs (DESIGN §3), the rules every independent renderer must reproduce
//!
//! - **Colours** are display values in `[0, 1]`: no sRGB decoding, no gamma. Texture bytes are used
//!   exactly as stored in the image file. Vertex colours and material factors are clamped to
//!   `[0, 1]` by [`Mesh::finish`].
//! - **Material factor**: the file's base-colour factor where the file defines a material
//!   (glTF `baseColorFactor`, or `diffuseFactor` of `KHR_materials_pbrSpecularGlossiness`;
//!   OBJ `Kd` with alpha `d`, or `1 - Tr` when only `Tr` is given), else
//!   [`DEFAULT_BASE_COLOR`](super::DEFAULT_BASE_COLOR) (0.8 grey). Formats without materials
//!   (PLY, STL, OFF, raw arrays) get one default material.
//! - **albedo** = base-colour texture × vertex colour × material factor; the shaders compute it,
//!   this module only loads the three inputs. A missing vertex colour is white (1,1,1,1).
//! - **UVs** follow glTF: origin top-left, v down. OBJ and PLY store v up, so their v is
//!   flipped on load (`v' = 1 - v`). Vertices without UVs in a mesh that has some get (0,0).
//! - **Normals**: the file's normals, normalized; where the file has none (or a zero or
//!   non-finite one), the area-weighted average of the incident face normals, accumulated in
//!   f64. STL normals are always computed (facet normals in STL files are too often wrong).
//!
//! # Formats
//!
//! Each format's exact rules are in its submodule's documentation (`load/gltf_scene.rs`,
//! `obj.rs`, `ply.rs`, `stl.rs`, `off.rs`):
//! - glTF 2.0 (`.gltf`, `.glb`): the default scene's mesh instances with node transforms
//!   applied; base-colour factor and texture.
//! - Wavefront OBJ (`.obj`) with `.mtl` materials (`Kd`, `d`, `map_Kd`).
//! - Stanford PLY (`.ply`), ASCII and binary: positions, normals, colours, UVs, polygons.
//! - STL (`.stl`), ASCII and binary: positions only.
//! - Geomview OFF (`.off`, `COFF`, `NOFF`, `CNOFF`, `STOFF`): our own parser.

mod bounding;
mod gltf_scene;
mod obj;
mod off;
mod ply;
mod stl;
mod texture;
mod validate;

use std::path::Path;

use super::{Material, Mesh, MeshError};

/// A mesh file format, chosen by file extension (or by the caller for uploads).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MeshFormat {
    /// glTF 2.0 JSON (`.gltf`), buffers and images external, embedded or data URIs.
    Gltf,
    /// Binary glTF 2.0 (`.glb`).
    Glb,
    /// Wavefront OBJ (`.obj`), materials from `.mtl` files.
    Obj,
    /// Stanford PLY (`.ply`), ASCII or binary.
    Ply,
    /// STL (`.stl`), ASCII or binary.
    Stl,
    /// Geomview Object File Format (`.off`) and its `COFF`/`NOFF`/`CNOFF` variants.
    Off,
}

impl MeshFormat {
    /// All formats, in the order of [`MeshFormat::extension`]'s documentation.
    pub const ALL: [MeshFormat; 6] = [
        MeshFormat::Gltf,
        MeshFormat::Glb,
        MeshFormat::Obj,
        MeshFormat::Ply,
        MeshFormat::Stl,
        MeshFormat::Off,
    ];

    /// The format of a file extension, case-insensitive, with or without the leading dot.
    pub fn from_extension(ext: &str) -> Option<MeshFormat> {
        let ext = ext.strip_prefix('.').unwrap_or(ext).to_ascii_lowercase();
        match ext.as_str() {
            "gltf" => Some(MeshFormat::Gltf),
            "glb" => Some(MeshFormat::Glb),
            "obj" => Some(MeshFormat::Obj),
            "ply" => Some(MeshFormat::Ply),
            "stl" => Some(MeshFormat::Stl),
            "off" => Some(MeshFormat::Off),
            _ => None,
        }
    }

    /// The format of a path, from its extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<MeshFormat, MeshError> {
        let ext = path
            .extension()
            .and_then(|ext| ext.to_str())
            .ok_or_else(|| {
                MeshError::UnknownFormat(format!("{} (no file extension)", path.display()))
            })?;
        MeshFormat::from_extension(ext).ok_or_else(|| MeshError::UnknownFormat(format!(".{ext}")))
    }

    /// The canonical lower-case file extension, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            MeshFormat::Gltf => "gltf",
            MeshFormat::Glb => "glb",
            MeshFormat::Obj => "obj",
            MeshFormat::Ply => "ply",
            MeshFormat::Stl => "stl",
            MeshFormat::Off => "off",
        }
    }

    /// The name used in error messages.
    pub fn name(self) -> &'static str {
        match self {
            MeshFormat::Gltf => "glTF",
            MeshFormat::Glb => "GLB",
            MeshFormat::Obj => "OBJ",
            MeshFormat::Ply => "PLY",
            MeshFormat::Stl => "STL",
            MeshFormat::Off => "OFF",
        }
    }
}

impl std::fmt::Display for MeshFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Loads a mesh file; the format comes from the extension (see [`MeshFormat::from_path`]).
///
/// External glTF buffers and images, OBJ `.mtl` files and their textures are resolved relative
/// to the file's folder. A missing `.mtl` file or texture of an OBJ is logged as a warning and
/// the default material is used; a missing glTF buffer or image is an error. The mesh is
/// validated by [`Mesh::finish`].
pub fn load_mesh(path: &Path) -> Result<Mesh, MeshError> {
    let format = MeshFormat::from_path(path)?;
    let base_dir = path.parent().unwrap_or_else(|| Path::new("."));
    let bytes = read_file(path)?;
    let mesh = match format {
        MeshFormat::Gltf | MeshFormat::Glb => gltf_scene::load(&bytes, Some(base_dir))?,
        MeshFormat::Obj => obj::load(&bytes, Some(base_dir))?,
        MeshFormat::Ply => ply::load(&bytes)?,
        MeshFormat::Stl => stl::load(&bytes)?,
        MeshFormat::Off => off::load(&bytes)?,
    };
    mesh.finish()
}

/// Most frames an animation may be baked into: an asset holds at most 256 states, the base
/// state (frame 0) and 255 more.
pub const MAX_ANIMATION_FRAMES: usize = 256;

/// A glTF animation sampled into validated meshes, frame `i` at `i / fps` seconds.
#[derive(Clone, Debug)]
pub struct AnimationFrames {
    /// The animation's name (`animation_<index>` when it has none).
    pub name: String,
    /// Time of its last key, seconds.
    pub duration: f64,
    /// Frames per second.
    pub fps: f64,
    /// The posed meshes, each validated by [`Mesh::finish`].
    pub frames: Vec<Mesh>,
}

/// Samples animation `name` (the first when `None`) of a glTF/GLB file at `fps`: node
/// transforms (step, linear with slerp, cubic spline), morph-target weights and skins pose the
/// scene at every `i / fps` up to the last key, at most [`MAX_ANIMATION_FRAMES`] frames.
///
/// # Errors
/// [`MeshError`]: not glTF, no animation or an unknown name (the message lists the file's),
/// bad keys, too many frames for the rate, or a posed mesh that fails validation.
pub fn load_animation(
    path: &Path,
    name: Option<&str>,
    fps: f64,
) -> Result<AnimationFrames, MeshError> {
    let format = MeshFormat::from_path(path)?;
    if !matches!(format, MeshFormat::Gltf | MeshFormat::Glb) {
        return Err(MeshError::Parse {
            format: format.name(),
            message: "animations come from glTF or GLB files".to_owned(),
        });
    }
    let base_dir = path.parent().unwrap_or_else(|| Path::new("."));
    let bytes = read_file(path)?;
    let animation =
        gltf_scene::load_animation(&bytes, Some(base_dir), name, fps, MAX_ANIMATION_FRAMES)?;
    Ok(AnimationFrames {
        name: animation.name,
        duration: animation.duration,
        fps: animation.fps,
        frames: animation
            .frames
            .into_iter()
            .map(Mesh::finish)
            .collect::<Result<_, _>>()?,
    })
}

/// Loads a mesh from bytes, for uploads: nothing is read from the file system.
///
/// glTF must then embed its buffers and images (data URIs or the GLB binary chunk); `.gltf` and
/// `.glb` bytes are both accepted for either glTF format. OBJ is loaded without materials (a
/// `mtllib` line is ignored with a warning). The mesh is validated by [`Mesh::finish`].
pub fn load_mesh_from_bytes(bytes: &[u8], format: MeshFormat) -> Result<Mesh, MeshError> {
    let mesh = match format {
        MeshFormat::Gltf | MeshFormat::Glb => gltf_scene::load(bytes, None)?,
        MeshFormat::Obj => obj::load(bytes, None)?,
        MeshFormat::Ply => ply::load(bytes)?,
        MeshFormat::Stl => stl::load(bytes)?,
        MeshFormat::Off => off::load(bytes)?,
    };
    mesh.finish()
}

impl Mesh {
    /// Builds a mesh from plain arrays (the Python bindings' `(vertices, faces[, colors])`):
    /// one default material, normals computed, validated by [`Mesh::finish`].
    pub fn from_arrays(
        positions: Vec<[f32; 3]>,
        triangles: Vec<[u32; 3]>,
        colors: Option<Vec<[f32; 4]>>,
    ) -> Result<Mesh, MeshError> {
        let triangle_materials = vec![0; triangles.len()];
        Mesh {
            positions,
            normals: Vec::new(),
            uvs: None,
            colors,
            triangles,
            triangle_materials,
            materials: vec![Material::default()],
            textures: Vec::new(),
        }
        .finish()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Number of vertices (including any that no triangle uses).
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }
}

/// Reads a whole file, naming it in the error.
fn read_file(path: &Path) -> Result<Vec<u8>, MeshError> {
    std::fs::read(path).map_err(|source| MeshError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// A [`MeshError::Parse`] for `format`.
fn parse_error(format: &'static str, message: impl Into<String>) -> MeshError {
    MeshError::Parse {
        format,
        message: message.into(),
    }
}

/// Converts a vertex count to the `u32` index space of [`Mesh::triangles`].
fn index_base(format: &'static str, vertex_count: usize) -> Result<u32, MeshError> {
    u32::try_from(vertex_count).map_err(|_| {
        parse_error(
            format,
            format!("{vertex_count} vertices exceed the 2^32 vertex limit"),
        )
    })
}
