//! glTF 2.0 (`.gltf` JSON and `.glb` binary) via the `gltf` crate's validated document model.
//!
//! Rules:
//! - Which geometry: every mesh instance of the default scene, else of the first scene, else
//!   (no scenes) every mesh once with the identity transform. Node world transforms are applied
//!   to positions, and their inverse transpose to normals; a node whose transform mirrors
//!   (negative determinant) gets its triangles' winding reversed so that they stay
//!   counter-clockwise seen from outside (glTF §3.7.4). A node reached twice (invalid glTF: a
//!   cycle or a shared child) is instantiated once.
//! - Primitives of mode `TRIANGLES`, `TRIANGLE_STRIP` and `TRIANGLE_FAN`; points and lines
//!   are skipped. Morph targets and skins are ignored (the bind pose is loaded), except when an
//!   animation is sampled ([`load_animation`]): then animated node transforms, morph weights
//!   and skins (linear blend skinning) pose the mesh.
//! - Attributes: `POSITION` (required), `NORMAL`, `COLOR_0` (VEC3 or VEC4; float, or unsigned
//!   byte/short always read as normalized, as the `gltf` crate's readers do) and the UV set that
//!   the material's base-colour texture names (`TEXCOORD_0` unless its `texCoord` says
//!   otherwise). Integer positions and normals (KHR_mesh_quantization) follow the accessor's
//!   `normalized` flag. Sparse accessors are applied.
//! - Materials: `baseColorFactor` and `baseColorTexture` of `pbrMetallicRoughness`, or
//!   `diffuseFactor`/`diffuseTexture` when the material uses
//!   `KHR_materials_pbrSpecularGlossiness`. A primitive without a material gets
//!   [`DEFAULT_BASE_COLOR`](crate::mesh::DEFAULT_BASE_COLOR). Materials are deduplicated by
//!   index; each image is decoded once (to RGBA8, bytes as stored, no sRGB decoding). Samplers
//!   and `KHR_texture_transform` are ignored.
//! - Buffers and images: the GLB binary chunk, `data:` URIs (base64), or — only when loading
//!   from a file — paths relative to the file's folder (percent-decoded). Other URI schemes and
//!   absolute paths are rejected.
//!
//! - Limits: a scene may instantiate at most 2^25 vertices and triangle corners (checked from
//!   the accessor counts before any geometry is read; instancing multiplies geometry).
//!
//! Why not `gltf::import`/`import_slice`: in `gltf` 1.4.1 the importer panics on a relative URI
//! whose percent-decoding is not UTF-8, rejects `data:` URI images in slice imports, and decodes
//! every image of the file with no size limit; `Image::source` panics on an image without a
//! source or a buffer-view image without MIME type; the validation hook indexes accessors with
//! an unchecked `POSITION` index; and the accessor `Reader` trusts counts and strides (overflow,
//! assertions). So we parse with `Gltf::from_slice_without_validation`, check what validation
//! assumes, validate with `Document::from_json`, and resolve buffers, images and accessors
//! ourselves with every offset, stride and count checked against the bytes (overflow-checked
//! arithmetic). Data URIs are still decoded by the crate (`buffer::Data::from_source`).

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

use glam::{DMat3, DMat4, DVec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;

use super::{index_base, parse_error, texture};
use crate::mesh::{Material, Mesh, MeshError, Texture};

const FORMAT: &str = "glTF";

/// Most elements an accessor without a buffer view (all zeros plus sparse values) may claim,
/// beyond the total buffer size: such an accessor is backed by no data, so its count alone
/// must not decide an allocation.
const MIN_VIEWLESS_LIMIT: usize = 1 << 16;

/// Most vertices (and triangle corners) a scene may instantiate, checked before any geometry is
/// read: node instancing multiplies geometry, so a small file could otherwise ask for unbounded
/// memory (a few GiB at this limit).
const MAX_SCENE_ELEMENTS: usize = 1 << 25;

/// Refuses a GLB whose header declares a total length shorter than the 12-byte header itself:
/// the `gltf` crate subtracts the header's size from that length unchecked (an overflow panic
/// where overflow is checked; found by fuzzing).
fn check_glb_header(bytes: &[u8]) -> Result<(), MeshError> {
    if let [b'g', b'l', b'T', b'F', _, _, _, _, a, b, c, d, ..] = bytes {
        let length = u32::from_le_bytes([*a, *b, *c, *d]);
        if length < 12 {
            return Err(parse_error(
                FORMAT,
                format!("the GLB header declares {length} bytes, fewer than its own 12"),
            ));
        }
    }
    Ok(())
}

/// Loads glTF or GLB bytes into an unvalidated mesh; `base_dir` resolves external files
/// (`None` for uploads).
pub(super) fn load(bytes: &[u8], base_dir: Option<&Path>) -> Result<Mesh, MeshError> {
    let (document, buffers) = parse(bytes, base_dir)?;
    build(&document, &buffers, base_dir, None)
}

/// Parses, checks and validates the document and resolves its buffers.
fn parse(
    bytes: &[u8],
    base_dir: Option<&Path>,
) -> Result<(gltf::Document, Vec<Vec<u8>>), MeshError> {
    check_glb_header(bytes)?;
    let gltf::Gltf { document, blob } = gltf::Gltf::from_slice_without_validation(bytes)
        .map_err(|e| parse_error(FORMAT, e.to_string()))?;
    let root = document.into_json();
    check_before_validation(&root)?;
    let document =
        gltf::Document::from_json(root).map_err(|e| parse_error(FORMAT, e.to_string()))?;
    let buffers = load_buffers(&document, blob, base_dir)?;
    Ok((document, buffers))
}

/// The scene's mesh, at rest (`pose` `None`: node transforms as written, morph targets and
/// skins ignored) or posed (animated node transforms, morph weights and skins applied).
fn build(
    document: &gltf::Document,
    buffers: &[Vec<u8>],
    base_dir: Option<&Path>,
    pose: Option<&Pose>,
) -> Result<Mesh, MeshError> {
    let mut builder = Builder {
        document,
        buffers,
        base_dir,
        mesh: Mesh::default(),
        any_normals: false,
        any_uvs: false,
        any_colors: false,
        normals: Vec::new(),
        uvs: Vec::new(),
        colors: Vec::new(),
        material_by_index: HashMap::new(),
        texture_by_image: HashMap::new(),
    };

    let (instances, worlds) = instances(document, pose)?;
    let (mut vertices, mut corners) = (0usize, 0usize);
    for (mesh, _, _) in &instances {
        for primitive in mesh.primitives().filter(is_triangles) {
            let count = primitive
                .get(&gltf::Semantic::Positions)
                .map_or(0, |a| a.count());
            vertices = vertices.saturating_add(count);
            corners = corners.saturating_add(primitive.indices().map_or(count, |a| a.count()));
        }
    }
    if vertices.max(corners) > MAX_SCENE_ELEMENTS {
        return Err(parse_error(
            FORMAT,
            format!(
                "the scene instantiates {vertices} vertices and {corners} triangle corners, more than the limit {MAX_SCENE_ELEMENTS}"
            ),
        ));
    }
    for (mesh, world, node) in &instances {
        let deform = match (pose, node) {
            (Some(pose), Some(node)) => Some(builder.deformation(pose, node, mesh, &worlds)?),
            _ => None,
        };
        builder.add_mesh(mesh, *world, deform.as_ref())?;
    }
    Ok(builder.finish())
}

/// The mesh instances to load with their world transforms and nodes: the default scene's (else
/// the first scene's) node tree, each node once; with no scene, every mesh once untransformed.
/// Also every reached node's world transform (joints of skins), by node index. `pose`
/// overrides nodes' local transforms.
#[allow(clippy::type_complexity)]
fn instances<'a>(
    document: &'a gltf::Document,
    pose: Option<&Pose>,
) -> Result<
    (
        Vec<(gltf::Mesh<'a>, DMat4, Option<gltf::Node<'a>>)>,
        Vec<Option<DMat4>>,
    ),
    MeshError,
> {
    let mut worlds = vec![None; document.nodes().len()];
    let Some(scene) = document
        .default_scene()
        .or_else(|| document.scenes().next())
    else {
        return Ok((
            document
                .meshes()
                .map(|mesh| (mesh, DMat4::IDENTITY, None))
                .collect(),
            worlds,
        ));
    };
    let mut instances = Vec::new();
    let mut visited = vec![false; document.nodes().len()];
    let mut stack: Vec<(gltf::Node<'_>, DMat4)> =
        scene.nodes().map(|node| (node, DMat4::IDENTITY)).collect();
    stack.reverse();
    while let Some((node, parent)) = stack.pop() {
        let Some(seen) = visited.get_mut(node.index()) else {
            continue;
        };
        if *seen {
            tracing::warn!(
                node = node.index(),
                "glTF node reached twice (invalid hierarchy): instantiated once"
            );
            continue;
        }
        *seen = true;
        let local = pose
            .and_then(|p| p.locals.get(node.index()).copied().flatten())
            .unwrap_or_else(|| {
                DMat4::from_cols_array_2d(
                    &node
                        .transform()
                        .matrix()
                        .map(|column| column.map(f64::from)),
                )
            });
        let world = parent * local;
        if !world.is_finite() {
            return Err(parse_error(
                FORMAT,
                format!("node {} has a non-finite transform", node.index()),
            ));
        }
        worlds[node.index()] = Some(world);
        if let Some(mesh) = node.mesh() {
            instances.push((mesh, world, Some(node.clone())));
        }
        let children: Vec<_> = node.children().collect();
        stack.extend(children.into_iter().rev().map(|child| (child, world)));
    }
    Ok((instances, worlds))
}

/// Whether a primitive is made of triangles (list, strip or fan); others are skipped.
fn is_triangles(primitive: &gltf::Primitive<'_>) -> bool {
    matches!(
        primitive.mode(),
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
    )
}

/// What the `gltf-json` validation itself assumes: its primitive hook indexes the accessor
/// list with the `POSITION` index unchecked (a panic on a hostile file).
fn check_before_validation(root: &gltf::json::Root) -> Result<(), MeshError> {
    let accessor_count = root.accessors.len();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            let position = primitive
                .attributes
                .get(&gltf::json::validation::Checked::Valid(
                    gltf::Semantic::Positions,
                ));
            if let Some(index) = position
                && index.value() >= accessor_count
            {
                return Err(parse_error(
                    FORMAT,
                    format!(
                        "mesh {m} primitive {p}: POSITION names accessor {}, but there are {accessor_count}",
                        index.value()
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Loads every buffer: the GLB chunk, a data URI, or a file next to the glTF.
fn load_buffers(
    document: &gltf::Document,
    mut blob: Option<Vec<u8>>,
    base_dir: Option<&Path>,
) -> Result<Vec<Vec<u8>>, MeshError> {
    let mut buffers = Vec::new();
    for buffer in document.buffers() {
        let what = format!("buffer {}", buffer.index());
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => blob.take().ok_or_else(|| {
                parse_error(
                    FORMAT,
                    format!("{what} refers to the GLB binary chunk, which is missing"),
                )
            })?,
            gltf::buffer::Source::Uri(uri) => resolve_uri(uri, base_dir, &what)?,
        };
        if data.len() < buffer.length() {
            return Err(parse_error(
                FORMAT,
                format!(
                    "{what} has {} bytes, the file says {}: it is truncated",
                    data.len(),
                    buffer.length()
                ),
            ));
        }
        buffers.push(data);
    }
    Ok(buffers)
}

/// The bytes a buffer or image URI names.
fn resolve_uri(uri: &str, base_dir: Option<&Path>, what: &str) -> Result<Vec<u8>, MeshError> {
    if uri.starts_with("data:") {
        // The crate's own base64 decoding of data URIs (no file system access).
        return gltf::buffer::Data::from_source(gltf::buffer::Source::Uri(uri), None)
            .map(|data| data.0)
            .map_err(|e| parse_error(FORMAT, format!("{what}: invalid data URI: {e}")));
    }
    if let Some((scheme, _)) = uri.split_once(':')
        && !scheme.contains('/')
    {
        return Err(parse_error(
            FORMAT,
            format!(
                "{what}: URI scheme `{scheme}:` is not supported; use a relative path or a data: URI"
            ),
        ));
    }
    let Some(base_dir) = base_dir else {
        return Err(parse_error(
            FORMAT,
            format!(
                "{what} refers to the external file `{uri}`, which an upload cannot provide: embed it (GLB or data: URI)"
            ),
        ));
    };
    let relative = percent_decode(uri).ok_or_else(|| {
        parse_error(
            FORMAT,
            format!("{what}: `{uri}` is not a valid percent-encoded UTF-8 path"),
        )
    })?;
    let relative = PathBuf::from(relative);
    if relative
        .components()
        .any(|c| matches!(c, Component::RootDir | Component::Prefix(_)))
    {
        return Err(parse_error(
            FORMAT,
            format!("{what}: absolute path `{uri}` is not supported; use a relative path"),
        ));
    }
    let path = base_dir.join(relative);
    std::fs::read(&path).map_err(|source| MeshError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// Decodes `%XX` escapes; `None` for a malformed escape or non-UTF-8 result.
fn percent_decode(text: &str) -> Option<String> {
    let bytes = text.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while let Some(&b) = bytes.get(i) {
        if b == b'%' {
            let hex = std::str::from_utf8(bytes.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// Accumulates primitives into one mesh.
struct Builder<'a> {
    document: &'a gltf::Document,
    buffers: &'a [Vec<u8>],
    base_dir: Option<&'a Path>,
    mesh: Mesh,
    any_normals: bool,
    any_uvs: bool,
    any_colors: bool,
    /// Per vertex; zeros where a primitive has none (then computed by `finish`).
    normals: Vec<[f32; 3]>,
    /// Per vertex; (0,0) where a primitive has none.
    uvs: Vec<[f32; 2]>,
    /// Per vertex; white where a primitive has none.
    colors: Vec<[f32; 4]>,
    material_by_index: HashMap<Option<usize>, u32>,
    texture_by_image: HashMap<usize, u32>,
}

impl Builder<'_> {
    fn add_mesh(
        &mut self,
        mesh: &gltf::Mesh<'_>,
        world: DMat4,
        deform: Option<&Deformation>,
    ) -> Result<(), MeshError> {
        // A skinned mesh is placed by its joints alone (glTF §3.7.3.3), not its node.
        let world = if deform.is_some_and(|d| d.palette.is_some()) {
            DMat4::IDENTITY
        } else {
            world
        };
        let linear = DMat3::from_mat4(world);
        let determinant = linear.determinant();
        // Inverse transpose keeps normals perpendicular under non-uniform scale; a singular
        // transform flattens the mesh, whose normals are then computed from the faces.
        let normal_matrix = (determinant.is_finite() && determinant.abs() > f64::MIN_POSITIVE)
            .then(|| linear.inverse().transpose());
        let mirrored = determinant < 0.0;
        for primitive in mesh.primitives() {
            let what = format!("mesh {} primitive {}", mesh.index(), primitive.index());
            if !is_triangles(&primitive) {
                tracing::debug!(primitive = %what, mode = ?primitive.mode(), "glTF primitive skipped: not triangles");
                continue;
            }
            self.add_primitive(&primitive, &what, (world, normal_matrix, mirrored), deform)?;
        }
        Ok(())
    }

    fn add_primitive(
        &mut self,
        primitive: &gltf::Primitive<'_>,
        what: &str,
        (world, normal_matrix, mirrored): (DMat4, Option<DMat3>, bool),
        deform: Option<&Deformation>,
    ) -> Result<(), MeshError> {
        let positions_accessor = primitive
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| parse_error(FORMAT, format!("{what} has no POSITION attribute")))?;
        let mut positions = read_floats::<3>(
            &positions_accessor,
            self.buffers,
            what,
            "POSITION",
            Normalize::AsFlagged,
        )?;
        let count = positions.len();
        let base = index_base(FORMAT, self.mesh.positions.len())?;
        index_base(FORMAT, self.mesh.positions.len() + count)?;
        let same_count = |attribute: &'static str, got: usize| {
            if got == count {
                Ok(())
            } else {
                Err(parse_error(
                    FORMAT,
                    format!("{what}: {attribute} has {got} elements, POSITION has {count}"),
                ))
            }
        };

        let (material, uv_set) = self.material(&primitive.material())?;
        let mut normals = match primitive.get(&gltf::Semantic::Normals) {
            Some(accessor) => Some(read_floats::<3>(
                &accessor,
                self.buffers,
                what,
                "NORMAL",
                Normalize::AsFlagged,
            )?),
            None => None,
        };
        if let Some(deform) = deform {
            self.apply_deformation(primitive, what, deform, &mut positions, &mut normals)?;
        }
        let uvs = match primitive.get(&gltf::Semantic::TexCoords(uv_set)) {
            Some(accessor) => Some(read_floats::<2>(
                &accessor,
                self.buffers,
                what,
                "TEXCOORD",
                Normalize::Integers,
            )?),
            None => None,
        };
        let colors = match primitive.get(&gltf::Semantic::Colors(0)) {
            Some(accessor) => Some(match accessor.dimensions() {
                Dimensions::Vec3 => read_floats::<3>(
                    &accessor,
                    self.buffers,
                    what,
                    "COLOR_0",
                    Normalize::Integers,
                )?
                .into_iter()
                .map(|[r, g, b]| [r, g, b, 1.0])
                .collect(),
                _ => read_floats::<4>(
                    &accessor,
                    self.buffers,
                    what,
                    "COLOR_0",
                    Normalize::Integers,
                )?,
            }),
            None => None,
        };
        let indices: Vec<u32> = match primitive.indices() {
            Some(accessor) => read_indices(&accessor, self.buffers, what)?,
            None => (0..index_base(FORMAT, count)?).collect(),
        };

        // Triangles, in local indices (glTF §3.7.2.1 for strips and fans).
        let local: Vec<[u32; 3]> = match primitive.mode() {
            Mode::TriangleStrip => indices
                .windows(3)
                .enumerate()
                .map(|(i, w)| {
                    if i % 2 == 0 {
                        [w[0], w[1], w[2]]
                    } else {
                        [w[0], w[2], w[1]]
                    }
                })
                .collect(),
            Mode::TriangleFan => match indices.split_first() {
                Some((&hub, rest)) => rest.windows(2).map(|w| [w[0], w[1], hub]).collect(),
                None => Vec::new(),
            },
            _ => {
                if !indices.len().is_multiple_of(3) {
                    tracing::warn!(
                        primitive = what,
                        "glTF triangle list length is not a multiple of 3: tail ignored"
                    );
                }
                indices
                    .chunks_exact(3)
                    .map(|t| [t[0], t[1], t[2]])
                    .collect()
            }
        };
        for tri in &local {
            if let Some(&vertex) = tri.iter().find(|&&v| v as usize >= count) {
                return Err(MeshError::IndexOutOfRange {
                    triangle: self.mesh.triangles.len(),
                    vertex: u64::from(vertex),
                    vertex_count: count,
                });
            }
        }

        self.mesh.positions.extend(positions.iter().map(|&p| {
            let p = world.transform_point3(DVec3::from(p.map(f64::from)));
            [p.x as f32, p.y as f32, p.z as f32]
        }));
        if let Some(normals) = &normals {
            same_count("NORMAL", normals.len())?;
            self.any_normals = true;
            self.normals
                .resize(self.mesh.positions.len() - count, [0.0; 3]);
            self.normals
                .extend(normals.iter().map(|&n| match normal_matrix {
                    Some(m) => {
                        let n = (m * DVec3::from(n.map(f64::from))).normalize_or_zero();
                        [n.x as f32, n.y as f32, n.z as f32]
                    }
                    None => [0.0; 3],
                }));
        }
        if let Some(uvs) = uvs {
            same_count("TEXCOORD", uvs.len())?;
            self.any_uvs = true;
            self.uvs.resize(self.mesh.positions.len() - count, [0.0; 2]);
            self.uvs.extend(uvs);
        }
        if let Some(colors) = colors {
            same_count("COLOR_0", colors.len())?;
            self.any_colors = true;
            self.colors
                .resize(self.mesh.positions.len() - count, [1.0; 4]);
            self.colors.extend(colors);
        }
        for [a, b, c] in local {
            let tri = if mirrored { [a, c, b] } else { [a, b, c] };
            // In range (checked above), and base + count fits u32.
            self.mesh.triangles.push(tri.map(|v| base + v));
            self.mesh.triangle_materials.push(material);
        }
        Ok(())
    }

    /// The mesh material for a glTF material (deduplicated by index) and the UV set its
    /// base-colour texture reads.
    fn material(&mut self, material: &gltf::Material<'_>) -> Result<(u32, u32), MeshError> {
        let (factor, info) = if let Some(sg) = material.pbr_specular_glossiness() {
            (sg.diffuse_factor(), sg.diffuse_texture())
        } else {
            let pbr = material.pbr_metallic_roughness();
            (pbr.base_color_factor(), pbr.base_color_texture())
        };
        let uv_set = info.as_ref().map_or(0, gltf::texture::Info::tex_coord);
        if let Some(&index) = self.material_by_index.get(&material.index()) {
            return Ok((index, uv_set));
        }
        let resolved = if material.index().is_none() {
            Material::default()
        } else {
            let texture = match &info {
                Some(info) => Some(self.texture(&info.texture())?),
                None => None,
            };
            Material {
                base_color_factor: factor,
                base_color_texture: texture,
            }
        };
        let index = u32::try_from(self.mesh.materials.len())
            .map_err(|_| parse_error(FORMAT, "too many materials"))?;
        self.mesh.materials.push(resolved);
        self.material_by_index.insert(material.index(), index);
        Ok((index, uv_set))
    }

    /// The mesh texture for a glTF texture's image, decoding each image once.
    fn texture(&mut self, texture: &gltf::Texture<'_>) -> Result<u32, MeshError> {
        let image = texture.source();
        if let Some(&index) = self.texture_by_image.get(&image.index()) {
            return Ok(index);
        }
        let what = format!("glTF image {}", image.index());
        // From the JSON: `Image::source` panics on an image with a buffer view but no MIME type
        // or with neither a URI nor a buffer view, which validation lets through.
        let json = self
            .document
            .as_json()
            .images
            .get(image.index())
            .ok_or_else(|| parse_error(FORMAT, format!("{what} does not exist")))?;
        let bytes = if let Some(view_index) = &json.buffer_view {
            let view = self
                .document
                .views()
                .nth(view_index.value())
                .ok_or_else(|| {
                    parse_error(FORMAT, format!("{what} names a missing buffer view"))
                })?;
            view_bytes(&view, self.buffers, &what)?.to_vec()
        } else if let Some(uri) = &json.uri {
            resolve_uri(uri, self.base_dir, &what)?
        } else {
            return Err(parse_error(
                FORMAT,
                format!("{what} has neither a `uri` nor a `bufferView`"),
            ));
        };
        let index = self.mesh.textures.len();
        let decoded: Texture = texture::decode(index, &what, &bytes)?;
        let index = u32::try_from(index).map_err(|_| parse_error(FORMAT, "too many textures"))?;
        self.mesh.textures.push(decoded);
        self.texture_by_image.insert(image.index(), index);
        Ok(index)
    }

    fn finish(mut self) -> Mesh {
        let vertex_count = self.mesh.positions.len();
        if self.any_normals {
            self.normals.resize(vertex_count, [0.0; 3]);
            self.mesh.normals = self.normals;
        }
        if self.any_uvs {
            self.uvs.resize(vertex_count, [0.0; 2]);
            self.mesh.uvs = Some(self.uvs);
        }
        if self.any_colors {
            self.colors.resize(vertex_count, [1.0; 4]);
            self.mesh.colors = Some(self.colors);
        }
        self.mesh
    }
}

/// How integer components become floats.
#[derive(Clone, Copy)]
enum Normalize {
    /// As the accessor's `normalized` flag says (positions, normals).
    AsFlagged,
    /// Always normalized (colours and UVs, as the glTF spec and the `gltf` crate's readers).
    Integers,
}

/// The bytes of a buffer view, checked against its buffer.
/// Animated node transforms and morph weights of one instant (by node index).
#[derive(Clone, Debug, Default)]
pub(super) struct Pose {
    locals: Vec<Option<DMat4>>,
    weights: Vec<Option<Vec<f32>>>,
}

/// What deforms one mesh instance: its morph weights and, for a skinned node, the joint
/// matrices (`world(joint) · inverse bind matrix`).
struct Deformation {
    weights: Vec<f32>,
    palette: Option<Vec<DMat4>>,
}

impl Builder<'_> {
    /// The morph weights (animated, else the node's, else the mesh's) and the skin of `node`.
    fn deformation(
        &self,
        pose: &Pose,
        node: &gltf::Node<'_>,
        mesh: &gltf::Mesh<'_>,
        worlds: &[Option<DMat4>],
    ) -> Result<Deformation, MeshError> {
        let weights = pose
            .weights
            .get(node.index())
            .cloned()
            .flatten()
            .or_else(|| node.weights().map(<[f32]>::to_vec))
            .or_else(|| mesh.weights().map(<[f32]>::to_vec))
            .unwrap_or_default();
        let palette = match node.skin() {
            None => None,
            Some(skin) => {
                let what = format!("skin {}", skin.index());
                let joints: Vec<gltf::Node<'_>> = skin.joints().collect();
                let inverse = match skin.inverse_bind_matrices() {
                    Some(accessor) => {
                        let m = read_floats::<16>(
                            &accessor,
                            self.buffers,
                            &what,
                            "inverseBindMatrices",
                            Normalize::AsFlagged,
                        )?;
                        if m.len() < joints.len() {
                            return Err(parse_error(
                                FORMAT,
                                format!(
                                    "{what}: {} inverse bind matrices for {} joints",
                                    m.len(),
                                    joints.len()
                                ),
                            ));
                        }
                        m.iter()
                            .map(|c| DMat4::from_cols_array(&c.map(f64::from)))
                            .collect()
                    }
                    None => vec![DMat4::IDENTITY; joints.len()],
                };
                let palette: Vec<DMat4> = joints
                    .iter()
                    .zip(inverse)
                    .map(|(joint, inverse)| {
                        let world =
                            worlds
                                .get(joint.index())
                                .copied()
                                .flatten()
                                .unwrap_or_else(|| {
                                    DMat4::from_cols_array_2d(
                                        &joint.transform().matrix().map(|c| c.map(f64::from)),
                                    )
                                });
                        world * inverse
                    })
                    .collect();
                if palette.iter().any(|m| !m.is_finite()) {
                    return Err(parse_error(
                        FORMAT,
                        format!("{what}: a non-finite joint matrix"),
                    ));
                }
                Some(palette)
            }
        };
        Ok(Deformation { weights, palette })
    }

    /// Morph targets (weighted position and normal offsets), then skinning (linear blend of
    /// the joint matrices by `JOINTS_0`/`WEIGHTS_0`), applied in place (glTF §3.7.2.2, §3.7.3).
    fn apply_deformation(
        &self,
        primitive: &gltf::Primitive<'_>,
        what: &str,
        deform: &Deformation,
        positions: &mut [[f32; 3]],
        normals: &mut Option<Vec<[f32; 3]>>,
    ) -> Result<(), MeshError> {
        let count = positions.len();
        for (k, target) in primitive.morph_targets().enumerate() {
            let w = deform.weights.get(k).copied().unwrap_or(0.0);
            if w == 0.0 || !w.is_finite() {
                continue;
            }
            if let Some(accessor) = target.positions() {
                let delta = read_floats::<3>(
                    &accessor,
                    self.buffers,
                    what,
                    "target POSITION",
                    Normalize::AsFlagged,
                )?;
                if delta.len() != count {
                    return Err(parse_error(
                        FORMAT,
                        format!(
                            "{what}: morph target {k} has {} positions for {count}",
                            delta.len()
                        ),
                    ));
                }
                for (p, d) in positions.iter_mut().zip(&delta) {
                    for c in 0..3 {
                        p[c] += w * d[c];
                    }
                }
            }
            if let (Some(accessor), Some(normals)) = (target.normals(), normals.as_mut()) {
                let delta = read_floats::<3>(
                    &accessor,
                    self.buffers,
                    what,
                    "target NORMAL",
                    Normalize::AsFlagged,
                )?;
                if delta.len() == normals.len() {
                    for (n, d) in normals.iter_mut().zip(&delta) {
                        for c in 0..3 {
                            n[c] += w * d[c];
                        }
                    }
                }
            }
        }
        let Some(palette) = &deform.palette else {
            return Ok(());
        };
        let (Some(joints), Some(weights)) = (
            primitive.get(&gltf::Semantic::Joints(0)),
            primitive.get(&gltf::Semantic::Weights(0)),
        ) else {
            return Ok(());
        };
        let joints = read_floats::<4>(
            &joints,
            self.buffers,
            what,
            "JOINTS_0",
            Normalize::AsFlagged,
        )?;
        let weights = read_floats::<4>(
            &weights,
            self.buffers,
            what,
            "WEIGHTS_0",
            Normalize::Integers,
        )?;
        if joints.len() != count || weights.len() != count {
            return Err(parse_error(
                FORMAT,
                format!("{what}: JOINTS_0/WEIGHTS_0 do not match POSITION"),
            ));
        }
        for i in 0..count {
            let mut m = DMat4::ZERO;
            let mut total = 0.0;
            for k in 0..4 {
                let w = f64::from(weights[i][k]);
                if w == 0.0 {
                    continue;
                }
                let j = joints[i][k];
                let joint = palette
                    .get(j as usize)
                    .filter(|_| j >= 0.0 && j.fract() == 0.0)
                    .ok_or_else(|| {
                        parse_error(
                            FORMAT,
                            format!("{what}: vertex {i} names joint {j} of {}", palette.len()),
                        )
                    })?;
                m += *joint * w;
                total += w;
            }
            if total <= 0.0 {
                continue;
            }
            let m = m * (1.0 / total);
            let p = m.transform_point3(DVec3::from(positions[i].map(f64::from)));
            positions[i] = [p.x as f32, p.y as f32, p.z as f32];
            if let Some(normals) = normals.as_mut()
                && let Some(n) = normals.get_mut(i)
            {
                let v = m
                    .transform_vector3(DVec3::from(n.map(f64::from)))
                    .normalize_or_zero();
                *n = [v.x as f32, v.y as f32, v.z as f32];
            }
        }
        Ok(())
    }
}

/// A node's translation, rotation (quaternion x, y, z, w) and scale.
type Trs = ([f32; 3], [f32; 4], [f32; 3]);

/// How a channel interpolates between keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Interp {
    Step,
    Linear,
    CubicSpline,
}

/// What a channel animates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Path3 {
    Translation,
    Rotation,
    Scale,
    Weights,
}

/// One animation channel, its keys read and checked.
struct Channel {
    node: usize,
    path: Path3,
    interp: Interp,
    times: Vec<f32>,
    /// Per key, `width` values (cubic splines: in-tangent, value, out-tangent per key).
    values: Vec<f32>,
    width: usize,
}

impl Channel {
    /// The value at time `t` (clamped to the keys' range).
    fn sample(&self, t: f32) -> Vec<f32> {
        let n = self.times.len();
        let w = self.width;
        let stride = if self.interp == Interp::CubicSpline {
            3 * w
        } else {
            w
        };
        let value = |k: usize| -> &[f32] {
            let at = k * stride
                + if self.interp == Interp::CubicSpline {
                    w
                } else {
                    0
                };
            &self.values[at..at + w]
        };
        if n == 1 || t <= self.times[0] {
            return value(0).to_vec();
        }
        if t >= self.times[n - 1] {
            return value(n - 1).to_vec();
        }
        let k = self
            .times
            .partition_point(|&x| x <= t)
            .saturating_sub(1)
            .min(n - 2);
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        let dt = t1 - t0;
        let u = if dt > 0.0 { (t - t0) / dt } else { 0.0 };
        match self.interp {
            Interp::Step => value(k).to_vec(),
            Interp::Linear => {
                let (a, b) = (value(k), value(k + 1));
                if self.path == Path3::Rotation {
                    let qa = glam::Quat::from_slice(a).normalize();
                    let qb = glam::Quat::from_slice(b).normalize();
                    qa.slerp(qb, u).to_array().to_vec()
                } else {
                    a.iter().zip(b).map(|(x, y)| x + (y - x) * u).collect()
                }
            }
            Interp::CubicSpline => {
                let (u2, u3) = (u * u, u * u * u);
                let p0 = value(k);
                let m0 = &self.values[k * stride + 2 * w..k * stride + 3 * w];
                let p1 = value(k + 1);
                let m1 = &self.values[(k + 1) * stride..(k + 1) * stride + w];
                let out: Vec<f32> = (0..w)
                    .map(|c| {
                        (2.0 * u3 - 3.0 * u2 + 1.0) * p0[c]
                            + (u3 - 2.0 * u2 + u) * dt * m0[c]
                            + (-2.0 * u3 + 3.0 * u2) * p1[c]
                            + (u3 - u2) * dt * m1[c]
                    })
                    .collect();
                if self.path == Path3::Rotation {
                    glam::Quat::from_slice(&out).normalize().to_array().to_vec()
                } else {
                    out
                }
            }
        }
    }
}

/// A glTF animation baked into frames: the mesh posed at `t = i / fps` for `i = 0..frames`,
/// up to the animation's last key.
#[derive(Clone, Debug)]
pub struct Animation {
    /// The animation's name (or `animation_<index>` when it has none).
    pub name: String,
    /// Time of its last key, seconds.
    pub duration: f64,
    /// Frames per second sampled.
    pub fps: f64,
    /// The posed meshes, unvalidated (the caller finishes them).
    pub frames: Vec<Mesh>,
}

/// Samples animation `name` (or the first) of a glTF scene at `fps` into at most `max_frames`
/// posed meshes: node translation, rotation and scale (step, linear with slerp, cubic spline),
/// morph-target weights and skins.
///
/// # Errors
/// [`MeshError::Parse`] for a file without animations, an unknown name (the message lists
/// them), bad keys (times not increasing, non-finite values, wrong counts), a bad fps, or more
/// frames than `max_frames`.
pub(super) fn load_animation(
    bytes: &[u8],
    base_dir: Option<&Path>,
    name: Option<&str>,
    fps: f64,
    max_frames: usize,
) -> Result<Animation, MeshError> {
    if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
        return Err(parse_error(
            FORMAT,
            format!("fps {fps}: give a rate in (0, 1000]"),
        ));
    }
    let (document, buffers) = parse(bytes, base_dir)?;
    let names: Vec<String> = document
        .animations()
        .map(|a| {
            a.name()
                .map_or_else(|| format!("animation_{}", a.index()), str::to_owned)
        })
        .collect();
    if names.is_empty() {
        return Err(parse_error(FORMAT, "the file has no animation".to_owned()));
    }
    let index = match name {
        None => 0,
        Some(name) => names.iter().position(|n| n == name).ok_or_else(|| {
            parse_error(
                FORMAT,
                format!("no animation {name:?}; the file has {}", names.join(", ")),
            )
        })?,
    };
    let animation = document
        .animations()
        .nth(index)
        .ok_or_else(|| parse_error(FORMAT, "animation index out of range".to_owned()))?;
    let what = format!("animation {:?}", names[index]);
    let mut channels = Vec::new();
    for channel in animation.channels() {
        let sampler = channel.sampler();
        let times = read_floats::<1>(
            &sampler.input(),
            &buffers,
            &what,
            "input",
            Normalize::AsFlagged,
        )?
        .into_iter()
        .map(|[t]| t)
        .collect::<Vec<f32>>();
        if times.is_empty()
            || times.iter().any(|t| !t.is_finite())
            || times.windows(2).any(|w| w[1] < w[0])
        {
            return Err(parse_error(
                FORMAT,
                format!("{what}: key times must be finite and increasing"),
            ));
        }
        let path = match channel.target().property() {
            gltf::animation::Property::Translation => Path3::Translation,
            gltf::animation::Property::Rotation => Path3::Rotation,
            gltf::animation::Property::Scale => Path3::Scale,
            gltf::animation::Property::MorphTargetWeights => Path3::Weights,
        };
        let interp = match sampler.interpolation() {
            gltf::animation::Interpolation::Step => Interp::Step,
            gltf::animation::Interpolation::Linear => Interp::Linear,
            gltf::animation::Interpolation::CubicSpline => Interp::CubicSpline,
        };
        let output = sampler.output();
        let values: Vec<f32> = match output.dimensions().multiplicity() {
            1 => read_floats::<1>(&output, &buffers, &what, "output", Normalize::AsFlagged)?
                .into_iter()
                .flatten()
                .collect(),
            3 => read_floats::<3>(&output, &buffers, &what, "output", Normalize::AsFlagged)?
                .into_iter()
                .flatten()
                .collect(),
            4 => read_floats::<4>(&output, &buffers, &what, "output", Normalize::AsFlagged)?
                .into_iter()
                .flatten()
                .collect(),
            n => {
                return Err(parse_error(
                    FORMAT,
                    format!("{what}: output with {n} components"),
                ));
            }
        };
        let per_key = if interp == Interp::CubicSpline { 3 } else { 1 };
        let keys = times.len() * per_key;
        let width = match path {
            Path3::Translation | Path3::Scale => 3,
            Path3::Rotation => 4,
            Path3::Weights => values.len() / keys.max(1),
        };
        if width == 0 || values.len() != keys * width || values.iter().any(|v| !v.is_finite()) {
            return Err(parse_error(
                FORMAT,
                format!(
                    "{what}: {} output values for {} keys of {width}",
                    values.len(),
                    times.len()
                ),
            ));
        }
        channels.push(Channel {
            node: channel.target().node().index(),
            path,
            interp,
            times,
            values,
            width,
        });
    }
    let duration = f64::from(
        channels
            .iter()
            .filter_map(|c| c.times.last().copied())
            .fold(0.0_f32, f32::max),
    );
    let frames = (duration * fps + 1e-6).floor() as usize + 1;
    if frames > max_frames {
        return Err(parse_error(
            FORMAT,
            format!(
                "{what} lasts {duration:.3} s: {frames} frames at {fps} fps, more than the {max_frames} an asset holds; lower the frame rate"
            ),
        ));
    }
    let nodes: Vec<gltf::Node<'_>> = document.nodes().collect();
    let mut meshes = Vec::with_capacity(frames);
    for i in 0..frames {
        let t = (i as f64 / fps) as f32;
        let mut pose = Pose {
            locals: vec![None; nodes.len()],
            weights: vec![None; nodes.len()],
        };
        let mut trs: HashMap<usize, Trs> = HashMap::new();
        for channel in &channels {
            let Some(node) = nodes.get(channel.node) else {
                continue;
            };
            let value = channel.sample(t);
            if channel.path == Path3::Weights {
                pose.weights[channel.node] = Some(value);
                continue;
            }
            let entry = trs
                .entry(channel.node)
                .or_insert_with(|| node.transform().decomposed());
            match channel.path {
                Path3::Translation => entry.0 = [value[0], value[1], value[2]],
                Path3::Rotation => entry.1 = [value[0], value[1], value[2], value[3]],
                Path3::Scale => entry.2 = [value[0], value[1], value[2]],
                Path3::Weights => {}
            }
        }
        for (node, (t, r, s)) in trs {
            let q = glam::DQuat::from_array(r.map(f64::from)).normalize();
            pose.locals[node] = Some(DMat4::from_scale_rotation_translation(
                DVec3::from(s.map(f64::from)),
                q,
                DVec3::from(t.map(f64::from)),
            ));
        }
        meshes.push(build(&document, &buffers, base_dir, Some(&pose))?);
    }
    Ok(Animation {
        name: names[index].clone(),
        duration,
        fps,
        frames: meshes,
    })
}

fn view_bytes<'b>(
    view: &gltf::buffer::View<'_>,
    buffers: &'b [Vec<u8>],
    what: &str,
) -> Result<&'b [u8], MeshError> {
    let buffer = buffers.get(view.buffer().index()).ok_or_else(|| {
        parse_error(
            FORMAT,
            format!(
                "{what}: buffer view {} names a missing buffer",
                view.index()
            ),
        )
    })?;
    view.offset()
        .checked_add(view.length())
        .and_then(|end| buffer.get(view.offset()..end))
        .ok_or_else(|| {
            parse_error(
                FORMAT,
                format!(
                    "{what}: buffer view {} (offset {}, length {}) lies outside its buffer of {} bytes",
                    view.index(),
                    view.offset(),
                    view.length(),
                    buffer.len()
                ),
            )
        })
}

/// The elements of an accessor as raw little-endian bytes: `count` elements of `element_size`
/// bytes, `stride` apart in `bytes` starting at 0 (dense part), plus sparse overrides.
struct Elements<'b> {
    count: usize,
    element_size: usize,
    dense: Option<(&'b [u8], usize)>,
    sparse: Vec<(usize, &'b [u8])>,
}

impl Elements<'_> {
    /// The bytes of element `i` (zeros where there is no buffer view).
    fn dense(&self, i: usize) -> Option<&[u8]> {
        let (bytes, stride) = self.dense?;
        let start = i.checked_mul(stride)?;
        bytes.get(start..start.checked_add(self.element_size)?)
    }
}

/// Locates and bounds-checks all of an accessor's bytes (dense view and sparse substitution).
fn elements<'b>(
    accessor: &gltf::Accessor<'_>,
    buffers: &'b [Vec<u8>],
    what: &str,
) -> Result<Elements<'b>, MeshError> {
    let err = |message: String| {
        parse_error(
            FORMAT,
            format!("{what}: accessor {}: {message}", accessor.index()),
        )
    };
    let element_size = accessor.size();
    let count = accessor.count();
    let dense = if let Some(view) = accessor.view() {
        let bytes = view_bytes(&view, buffers, what)?;
        let stride = view.stride().unwrap_or(element_size);
        if stride < element_size {
            return Err(err(format!(
                "byte stride {stride} is smaller than its element size {element_size}"
            )));
        }
        let needed = count
            .checked_sub(1)
            .map_or(Some(0), |last| {
                last.checked_mul(stride)
                    .and_then(|b| b.checked_add(element_size))
            })
            .and_then(|b| b.checked_add(accessor.offset()));
        let bytes = needed
            .and_then(|end| bytes.get(accessor.offset()..end))
            .ok_or_else(|| {
                err(format!(
                    "{count} elements at offset {} overrun buffer view {} ({} bytes)",
                    accessor.offset(),
                    view.index(),
                    bytes.len()
                ))
            })?;
        Some((bytes, stride))
    } else {
        let limit = buffers
            .iter()
            .map(Vec::len)
            .sum::<usize>()
            .max(MIN_VIEWLESS_LIMIT);
        if count > limit {
            return Err(err(format!(
                "{count} elements without a buffer view exceed the limit {limit} (the size of all buffers)"
            )));
        }
        None
    };
    let mut sparse_values = Vec::new();
    if let Some(sparse) = accessor.sparse() {
        let n = sparse.count();
        let indices = sparse.indices();
        let index_size = match indices.index_type() {
            gltf::accessor::sparse::IndexType::U8 => 1,
            gltf::accessor::sparse::IndexType::U16 => 2,
            gltf::accessor::sparse::IndexType::U32 => 4,
        };
        let index_bytes = slice_at(
            view_bytes(&indices.view(), buffers, what)?,
            indices.offset(),
            n,
            index_size,
        )
        .ok_or_else(|| err(format!("{n} sparse indices overrun their buffer view")))?;
        let values = sparse.values();
        let value_bytes = slice_at(
            view_bytes(&values.view(), buffers, what)?,
            values.offset(),
            n,
            element_size,
        )
        .ok_or_else(|| err(format!("{n} sparse values overrun their buffer view")))?;
        for (index, value) in index_bytes
            .chunks_exact(index_size)
            .zip(value_bytes.chunks_exact(element_size))
        {
            let index = match *index {
                [a] => usize::from(a),
                [a, b] => usize::from(u16::from_le_bytes([a, b])),
                [a, b, c, d] => u32::from_le_bytes([a, b, c, d]) as usize,
                _ => usize::MAX,
            };
            if index >= count {
                return Err(err(format!(
                    "sparse index {index} is past its {count} elements"
                )));
            }
            sparse_values.push((index, value));
        }
    }
    Ok(Elements {
        count,
        element_size,
        dense,
        sparse: sparse_values,
    })
}

/// `n` tightly packed items of `size` bytes at `offset`, if they fit.
fn slice_at(bytes: &[u8], offset: usize, n: usize, size: usize) -> Option<&[u8]> {
    let end = n.checked_mul(size)?.checked_add(offset)?;
    bytes.get(offset..end)
}

/// Reads an accessor of N-component vectors into floats.
fn read_floats<const N: usize>(
    accessor: &gltf::Accessor<'_>,
    buffers: &[Vec<u8>],
    what: &str,
    attribute: &str,
    normalize: Normalize,
) -> Result<Vec<[f32; N]>, MeshError> {
    let dims = accessor.dimensions().multiplicity();
    if dims != N {
        return Err(parse_error(
            FORMAT,
            format!(
                "{what}: {attribute} accessor {} has {dims} components per element, expected {N}",
                accessor.index()
            ),
        ));
    }
    let data_type = accessor.data_type();
    let normalized = match normalize {
        Normalize::AsFlagged => accessor.normalized(),
        Normalize::Integers => true,
    };
    let elements = elements(accessor, buffers, what)?;
    let component_size = data_type.size();
    let decode = |bytes: &[u8]| -> [f32; N] {
        std::array::from_fn(|k| {
            bytes
                .get(k * component_size..(k + 1) * component_size)
                .map_or(0.0, |c| component_to_f32(c, data_type, normalized))
        })
    };
    let mut out: Vec<[f32; N]> = (0..elements.count)
        .map(|i| elements.dense(i).map_or([0.0; N], decode))
        .collect();
    for &(index, bytes) in &elements.sparse {
        if let Some(slot) = out.get_mut(index) {
            *slot = decode(bytes);
        }
    }
    Ok(out)
}

/// One little-endian component as f32 (glTF §3.11 normalization for integer types).
fn component_to_f32(bytes: &[u8], data_type: DataType, normalized: bool) -> f32 {
    match (data_type, bytes) {
        (DataType::F32, &[a, b, c, d]) => f32::from_le_bytes([a, b, c, d]),
        (DataType::U8, &[a]) => {
            if normalized {
                f32::from(a) / 255.0
            } else {
                f32::from(a)
            }
        }
        (DataType::I8, &[a]) => {
            let v = f32::from(i8::from_le_bytes([a]));
            if normalized { (v / 127.0).max(-1.0) } else { v }
        }
        (DataType::U16, &[a, b]) => {
            let v = f32::from(u16::from_le_bytes([a, b]));
            if normalized { v / 65_535.0 } else { v }
        }
        (DataType::I16, &[a, b]) => {
            let v = f32::from(i16::from_le_bytes([a, b]));
            if normalized {
                (v / 32_767.0).max(-1.0)
            } else {
                v
            }
        }
        (DataType::U32, &[a, b, c, d]) => u32::from_le_bytes([a, b, c, d]) as f32,
        _ => 0.0,
    }
}

/// Reads an index accessor (unsigned byte, short or int scalars).
fn read_indices(
    accessor: &gltf::Accessor<'_>,
    buffers: &[Vec<u8>],
    what: &str,
) -> Result<Vec<u32>, MeshError> {
    let data_type = accessor.data_type();
    if accessor.dimensions() != Dimensions::Scalar
        || !matches!(data_type, DataType::U8 | DataType::U16 | DataType::U32)
    {
        return Err(parse_error(
            FORMAT,
            format!(
                "{what}: index accessor {} must be unsigned byte, short or int scalars",
                accessor.index()
            ),
        ));
    }
    let elements = elements(accessor, buffers, what)?;
    let decode = |bytes: &[u8]| -> u32 {
        match *bytes {
            [a] => u32::from(a),
            [a, b] => u32::from(u16::from_le_bytes([a, b])),
            [a, b, c, d] => u32::from_le_bytes([a, b, c, d]),
            _ => 0,
        }
    };
    let mut out: Vec<u32> = (0..elements.count)
        .map(|i| elements.dense(i).map_or(0, decode))
        .collect();
    for &(index, bytes) in &elements.sparse {
        if let Some(slot) = out.get_mut(index) {
            *slot = decode(bytes);
        }
    }
    Ok(out)
}
