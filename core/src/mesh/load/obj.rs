//! Wavefront OBJ with `.mtl` materials, via `tobj` (triangulate + single index).
//!
//! Rules:
//! - Positions (`v x y z [w]`, divided by w), normals (`vn`), texture coordinates (`vt`, v
//!   flipped to glTF's convention, `v' = 1 - v`) and vertex colours (`v x y z r g b`, floats in
//!   `[0, 1]`, opaque). Polygons are triangulated by `tobj`; points and lines are ignored.
//! - Face indices are checked before `tobj` sees them (`tobj` 4.0 overflows on hostile
//!   relative indices): 0, a relative index reaching before the first element, or an index
//!   above 2^32 is a [`MeshError::Parse`].
//! - Colours are used only when every `v` line has them; a file that mixes lines with and
//!   without colours is loaded without colours (with a warning), because `tobj` would pair
//!   colours with the wrong vertices.
//! - Materials (from a file): `mtllib` is resolved relative to the OBJ's folder; each
//!   material's factor is `Kd` (default 0.8 grey when absent) with alpha `d` (or `1 - Tr`,
//!   default 1); `map_Kd` is loaded with `image`, relative to the OBJ's folder or else the
//!   `.mtl`'s folder (option flags such as `-s 1 1 1` before the name are skipped); every
//!   texture file is decoded once. A missing `.mtl` or texture file is a warning (default
//!   material / no texture); a malformed `.mtl` or an undecodable texture is an error. Faces
//!   without `usemtl` (or naming an unknown material) use the default material.
//! - From bytes (uploads) there is no file system: `mtllib` is ignored with a warning.
//! - Vertices of objects that lack normals, UVs or colours while others have them get zero
//!   normals (computed later), UV (0,0) and white.

use std::cell::RefCell;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::{index_base, parse_error, texture};
use crate::mesh::{DEFAULT_BASE_COLOR, Material, Mesh, MeshError, Texture};

const FORMAT: &str = "OBJ";

/// Loads OBJ bytes into an unvalidated mesh; `base_dir` is the OBJ's folder (`None` for
/// uploads: no materials).
pub(super) fn load(bytes: &[u8], base_dir: Option<&Path>) -> Result<Mesh, MeshError> {
    let scan = prescan(bytes)?;
    // The update covers fields that exist only with some `tobj` features.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let libraries = RefCell::new(Vec::<PathBuf>::new());
    let mtl_error = RefCell::new(None::<MeshError>);
    let material_loader = |mtl: &Path| -> tobj::MTLLoadResult {
        // An empty library (the result's map type is private to `tobj`).
        let empty = tobj::load_mtl_buf(&mut &b""[..]);
        let Some(base_dir) = base_dir else {
            tracing::warn!(mtllib = %mtl.display(), "OBJ upload: material library ignored (no file system)");
            return empty;
        };
        let path = base_dir.join(mtl);
        let text = match std::fs::read(&path) {
            Ok(text) => text,
            Err(e) => {
                tracing::warn!(mtllib = %path.display(), error = %e, "OBJ material library not found: default material");
                return empty;
            }
        };
        match tobj::load_mtl_buf(&mut text.as_slice()) {
            Ok(result) => {
                if let Some(dir) = path.parent() {
                    libraries.borrow_mut().push(dir.to_path_buf());
                }
                Ok(result)
            }
            Err(e) => {
                mtl_error.borrow_mut().get_or_insert_with(|| {
                    parse_error(FORMAT, format!("material library {}: {e}", path.display()))
                });
                empty
            }
        }
    };
    let (models, materials) = tobj::load_obj_buf(&mut &*bytes, &options, material_loader)
        .map_err(|e| parse_error(FORMAT, format!("{e} (tobj)")))?;
    if let Some(error) = mtl_error.into_inner() {
        return Err(error);
    }
    let materials = materials.unwrap_or_default();
    let texture_dirs: Vec<PathBuf> = base_dir
        .map(Path::to_path_buf)
        .into_iter()
        .chain(libraries.into_inner())
        .collect();

    let any_normals = models.iter().any(|m| !m.mesh.normals.is_empty());
    let any_uvs = models.iter().any(|m| !m.mesh.texcoords.is_empty());
    let any_colors = scan.colors_usable && models.iter().any(|m| !m.mesh.vertex_color.is_empty());
    let mut mesh = Mesh::default();
    let mut uvs = Vec::new();
    let mut colors = Vec::new();
    let mut builder = MaterialBuilder::new(&materials, &texture_dirs);
    for model in &models {
        let m = &model.mesh;
        let base = index_base(FORMAT, mesh.positions.len())?;
        let count = m.positions.len() / 3;
        index_base(FORMAT, mesh.positions.len() + count)?;
        mesh.positions
            .extend(m.positions.chunks_exact(3).map(|p| [p[0], p[1], p[2]]));
        if any_normals {
            if m.normals.len() == m.positions.len() {
                mesh.normals
                    .extend(m.normals.chunks_exact(3).map(|n| [n[0], n[1], n[2]]));
            } else {
                if !m.normals.is_empty() {
                    tracing::warn!(object = %model.name, "OBJ object has normals on some vertices only: computing them");
                }
                mesh.normals.resize(mesh.positions.len(), [0.0; 3]);
            }
        }
        if any_uvs {
            if m.texcoords.len() == count * 2 {
                uvs.extend(m.texcoords.chunks_exact(2).map(|t| [t[0], 1.0 - t[1]]));
            } else {
                if !m.texcoords.is_empty() {
                    tracing::warn!(object = %model.name, "OBJ object has texture coordinates on some vertices only: dropped");
                }
                uvs.resize(mesh.positions.len(), [0.0; 2]);
            }
        }
        if any_colors {
            if m.vertex_color.len() == m.positions.len() {
                colors.extend(
                    m.vertex_color
                        .chunks_exact(3)
                        .map(|c| [c[0], c[1], c[2], 1.0]),
                );
            } else {
                colors.resize(mesh.positions.len(), [1.0; 4]);
            }
        }
        let material = builder.material(model.mesh.material_id)?;
        // `tobj` indexes the object's own vertices; anything else becomes an index `finish`
        // rejects rather than one into another object.
        let corner = |i: u32| {
            if (i as usize) < count {
                base + i
            } else {
                u32::MAX
            }
        };
        for tri in m.indices.chunks_exact(3) {
            mesh.triangles
                .push([corner(tri[0]), corner(tri[1]), corner(tri[2])]);
            mesh.triangle_materials.push(material);
        }
    }
    mesh.uvs = any_uvs.then_some(uvs);
    mesh.colors = any_colors.then_some(colors);
    (mesh.materials, mesh.textures) = builder.finish();
    Ok(mesh)
}

/// What a line scan learns before `tobj` runs.
struct Prescan {
    /// Every `v` line has a colour (and there is at least one).
    colors_usable: bool,
}

/// Checks face indices (see the module rules) and whether vertex colours are consistent.
fn prescan(bytes: &[u8]) -> Result<Prescan, MeshError> {
    let mut counts = [0u64; 3]; // v, vt, vn
    let (mut with_color, mut without_color) = (0u64, 0u64);
    for (line_index, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let line_no = line_index + 1;
        let line = std::str::from_utf8(raw).map_err(|_| {
            parse_error(
                FORMAT,
                format!("line {line_no} is not UTF-8 text: the file is not an OBJ file"),
            )
        })?;
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                counts[0] += 1;
                if words.count() >= 6 {
                    with_color += 1;
                } else {
                    without_color += 1;
                }
            }
            Some("vt") => counts[1] += 1,
            Some("vn") => counts[2] += 1,
            Some("f") => {
                for word in words {
                    for (kind, part) in word.split('/').enumerate() {
                        if part.is_empty() {
                            continue;
                        }
                        let (Some(&available), Ok(index)) = (counts.get(kind), part.parse::<i64>())
                        else {
                            continue; // `tobj` reports malformed faces itself.
                        };
                        let ok = match index {
                            0 => false,
                            i if i < 0 => i.unsigned_abs() <= available,
                            i => i <= i64::from(u32::MAX),
                        };
                        if !ok {
                            let what = ["vertex", "texture coordinate", "normal"]
                                .get(kind)
                                .copied()
                                .unwrap_or("");
                            return Err(parse_error(
                                FORMAT,
                                format!(
                                    "line {line_no}: {what} index {index} is invalid (indices start at 1; negative ones count back from the {available} defined so far)"
                                ),
                            ));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    if with_color > 0 && without_color > 0 {
        tracing::warn!(
            with_color,
            without_color,
            "OBJ vertex colours on some `v` lines only: colours ignored"
        );
    }
    Ok(Prescan {
        colors_usable: with_color > 0 && without_color == 0,
    })
}

/// Maps `tobj` material ids to mesh materials, loading each texture file once.
struct MaterialBuilder<'a> {
    source: &'a [tobj::Material],
    texture_dirs: &'a [PathBuf],
    by_id: HashMap<Option<usize>, u32>,
    materials: Vec<Material>,
    textures: Vec<Texture>,
    texture_by_path: HashMap<PathBuf, u32>,
}

impl<'a> MaterialBuilder<'a> {
    fn new(source: &'a [tobj::Material], texture_dirs: &'a [PathBuf]) -> Self {
        MaterialBuilder {
            source,
            texture_dirs,
            by_id: HashMap::new(),
            materials: Vec::new(),
            textures: Vec::new(),
            texture_by_path: HashMap::new(),
        }
    }

    /// The mesh material index for a `tobj` material id (`None` or unknown: default).
    fn material(&mut self, id: Option<usize>) -> Result<u32, MeshError> {
        let id = id.filter(|&i| i < self.source.len());
        if let Some(&index) = self.by_id.get(&id) {
            return Ok(index);
        }
        let material = match id.and_then(|i| self.source.get(i)) {
            None => Material::default(),
            Some(m) => {
                let [r, g, b] = m.diffuse.unwrap_or([
                    DEFAULT_BASE_COLOR[0],
                    DEFAULT_BASE_COLOR[1],
                    DEFAULT_BASE_COLOR[2],
                ]);
                let transparency = m
                    .unknown_param
                    .get("Tr")
                    .and_then(|t| t.trim().parse::<f32>().ok());
                let alpha = m.dissolve.or(transparency.map(|t| 1.0 - t)).unwrap_or(1.0);
                let texture = match &m.diffuse_texture {
                    Some(name) => self.texture(&m.name, name)?,
                    None => None,
                };
                Material {
                    base_color_factor: [r, g, b, alpha],
                    base_color_texture: texture,
                }
            }
        };
        let index = u32::try_from(self.materials.len())
            .map_err(|_| parse_error(FORMAT, "too many materials"))?;
        self.materials.push(material);
        self.by_id.insert(id, index);
        Ok(index)
    }

    /// Loads (once) the texture `map_Kd` names; `None` with a warning when no file is found.
    fn texture(&mut self, material: &str, map_kd: &str) -> Result<Option<u32>, MeshError> {
        let names = texture_name_candidates(map_kd);
        let found = self
            .texture_dirs
            .iter()
            .flat_map(|dir| names.iter().map(move |name| dir.join(name)))
            .find(|path| path.is_file());
        let Some(path) = found else {
            tracing::warn!(
                material,
                map_Kd = map_kd,
                "OBJ texture file not found: material without texture"
            );
            return Ok(None);
        };
        if let Some(&known) = self.texture_by_path.get(&path) {
            return Ok(Some(known));
        }
        let bytes = std::fs::read(&path).map_err(|source| MeshError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let index = self.textures.len();
        let decoded = texture::decode(index, &format!("map_Kd {}", path.display()), &bytes)?;
        let index = u32::try_from(index).map_err(|_| parse_error(FORMAT, "too many textures"))?;
        self.textures.push(decoded);
        self.texture_by_path.insert(path, index);
        Ok(Some(index))
    }

    fn finish(self) -> (Vec<Material>, Vec<Texture>) {
        (self.materials, self.textures)
    }
}

/// File names a `map_Kd` value may mean, in order: the whole value (names may contain spaces),
/// the value after any leading option flags (`-s 1 1 1 -bm 0.5 name.png`), its last word, and
/// each of these with Windows separators turned into `/`.
fn texture_name_candidates(map_kd: &str) -> Vec<String> {
    let value = map_kd.trim();
    let words: Vec<&str> = value.split_whitespace().collect();
    let mut i = 0;
    while let Some(flag) = words.get(i).filter(|w| w.starts_with('-')) {
        i += 1;
        if matches!(*flag, "-imfchan" | "-type") {
            i += 1; // One word argument.
            continue;
        }
        while words
            .get(i)
            .is_some_and(|w| w.parse::<f32>().is_ok() || matches!(*w, "on" | "off"))
        {
            i += 1;
        }
    }
    let mut names = vec![value.to_owned()];
    if let Some(rest) = words.get(i..).filter(|rest| !rest.is_empty()) {
        names.push(rest.join(" "));
    }
    if let Some(last) = words.last() {
        names.push((*last).to_owned());
    }
    let windows: Vec<String> = names
        .iter()
        .filter(|n| n.contains('\\'))
        .map(|n| n.replace('\\', "/"))
        .collect();
    names.extend(windows);
    let mut unique = Vec::new();
    for name in names {
        if !name.is_empty() && !unique.contains(&name) {
            unique.push(name);
        }
    }
    unique
}
