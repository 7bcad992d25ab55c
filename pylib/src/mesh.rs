//! `Mesh`: a validated triangle mesh with its provenance, and the reference renderer on it.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use lumigraph_core::bake::sha256_hex;
use lumigraph_core::gpu::mesh::GpuMesh;
use lumigraph_core::mesh::{
    DEFAULT_BASE_COLOR, Material, Mesh, Texture, demo_mesh, demo_provenance, load_mesh,
};
use lumigraph_core::shading::Shading;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::frame::{PyFrame, parse_background};
use crate::{arrays, engines, errors, view};

/// Mesh(vertices, faces, colors=None, *, normals=None, uvs=None, texture=None, base_color=None, name="arrays")
///
/// A validated triangle mesh ready for baking and reference rendering. Any array-like is
/// accepted and converted (dtype and contiguity); wrong kinds or shapes are rejected.
///
/// Args:
///     vertices: (N, 3) real positions, world units (converted to float32).
///     faces: (M, 3) integer vertex indices, counter-clockwise seen from outside.
///     colors: optional per-vertex colours, (N, 3) or (N, 4); uint8 in 0..255 or float in [0, 1].
///     normals: optional (N, 3) vertex normals (normalized); default: area-weighted face normals.
///     uvs: optional (N, 2) texture coordinates in glTF convention (v down, origin top-left);
///         ``lumigraph.as_mesh`` converts trimesh's (v up) for you.
///     texture: optional base-colour image (H, W, 3|4), uint8 or float in [0, 1]; needs ``uvs``.
///     base_color: RGBA material factor in [0, 1]; default (0.8, 0.8, 0.8, 1) without colours or
///         texture, (1, 1, 1, 1) with them (so they show as given).
///     name: source name recorded in the baked asset's provenance.
///
/// Shading (DESIGN §3): albedo = texture × vertex colour × base_color.
///
/// Raises:
///     MeshError (a ValueError): no triangles, non-finite values, indices out of range, only
///         degenerate triangles, a texture without uvs.
///     TypeError / ValueError: an array of the wrong dtype kind or shape.
#[pyclass(name = "Mesh", module = "lumigraph", frozen)]
pub struct PyMesh {
    pub mesh: Arc<Mesh>,
    pub source_name: String,
    pub source_sha256: String,
    gpu: Mutex<Option<Arc<GpuMesh>>>,
}

impl PyMesh {
    pub fn from_core(mesh: Mesh, source_name: String, source_sha256: String) -> Self {
        Self {
            mesh: Arc::new(mesh),
            source_name,
            source_sha256,
            gpu: Mutex::new(None),
        }
    }

    /// The reference renderer's upload, made once; call with the GIL released.
    fn gpu_mesh(&self) -> PyResult<Arc<GpuMesh>> {
        let mut slot = self
            .gpu
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(uploaded) = slot.as_ref() {
            return Ok(uploaded.clone());
        }
        let reference = engines::reference().map_err(|e| errors::gpu_for_render(&e))?;
        let uploaded = Arc::new(
            reference
                .upload(&self.mesh)
                .map_err(|e| errors::gpu_for_render(&e))?,
        );
        *slot = Some(uploaded.clone());
        Ok(uploaded)
    }
}

#[pymethods]
impl PyMesh {
    #[new]
    #[pyo3(signature = (vertices, faces, colors = None, *, normals = None, uvs = None, texture = None, base_color = None, name = "arrays".to_owned()))]
    fn new(
        py: Python<'_>,
        vertices: &Bound<'_, PyAny>,
        faces: &Bound<'_, PyAny>,
        colors: Option<&Bound<'_, PyAny>>,
        normals: Option<&Bound<'_, PyAny>>,
        uvs: Option<&Bound<'_, PyAny>>,
        texture: Option<&Bound<'_, PyAny>>,
        base_color: Option<[f32; 4]>,
        name: String,
    ) -> PyResult<Self> {
        let positions = arrays::float_rows::<3>(vertices, "vertices")?;
        let triangles = arrays::triangles(faces, "faces")?;
        let colors = colors.map(|c| arrays::colors(c, "colors")).transpose()?;
        let normals = normals
            .map(|n| arrays::float_rows::<3>(n, "normals"))
            .transpose()?;
        let uvs = uvs.map(|u| arrays::float_rows::<2>(u, "uvs")).transpose()?;
        let texture = texture
            .map(|t| arrays::rgba8(t, "texture", true))
            .transpose()?;
        if texture.is_some() && uvs.is_none() {
            return Err(PyValueError::new_err(
                "a texture needs uvs: pass uvs=(N, 2) texture coordinates",
            ));
        }
        let plain = colors.is_none() && texture.is_none();
        let base_color = base_color.unwrap_or(if plain { DEFAULT_BASE_COLOR } else { [1.0; 4] });
        if !base_color.iter().all(|c| (0.0..=1.0).contains(c)) {
            return Err(PyValueError::new_err(format!(
                "base_color {base_color:?} must be RGBA in [0, 1]"
            )));
        }
        let textures: Vec<Texture> = texture
            .into_iter()
            .map(|(width, height, rgba8)| Texture {
                width,
                height,
                rgba8,
            })
            .collect();
        let mesh = Mesh {
            normals: normals.unwrap_or_default(),
            uvs,
            colors,
            triangle_materials: vec![0; triangles.len()],
            materials: vec![Material {
                base_color_factor: base_color,
                base_color_texture: if textures.is_empty() { None } else { Some(0) },
            }],
            textures,
            positions,
            triangles,
        };
        let mesh = py
            .detach(move || mesh.finish())
            .map_err(|e| errors::mesh(&e))?;
        let sha = mesh.geometry_sha256();
        Ok(Self::from_core(mesh, name, sha))
    }

    /// Mesh.load(path) -> Mesh
    ///
    /// Loads glTF/GLB, OBJ (+MTL, textures), PLY, STL or OFF with lumigraph's own loaders (the
    /// CLI's), with vertex colours and base-colour textures.
    ///
    /// Raises:
    ///     FileNotFoundError: no such file.
    ///     MeshError: unknown extension or malformed file.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let (mesh, sha) = py.detach(|| {
            let mesh = load_mesh(&path).map_err(|e| errors::mesh(&e));
            let bytes = std::fs::read(&path).map_err(|e| {
                errors::mesh(&lumigraph_core::mesh::MeshError::Io {
                    path: path.display().to_string(),
                    source: e,
                })
            });
            mesh.and_then(|m| Ok((m, sha256_hex(&bytes?))))
        })?;
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        Ok(Self::from_core(mesh, name, sha))
    }

    /// Mesh.demo() -> Mesh
    ///
    /// The built-in demo scene (a vertex-coloured trefoil knot) the service bakes by default.
    #[staticmethod]
    fn demo() -> PyResult<Self> {
        let mesh = demo_mesh().map_err(|e| errors::mesh(&e))?;
        let provenance = demo_provenance(&mesh);
        Ok(Self::from_core(
            mesh,
            provenance.source_name,
            provenance.source_sha256,
        ))
    }

    /// Vertex positions (N, 3) float32, world units (a copy).
    #[getter]
    fn vertices<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray2<f32>>> {
        use numpy::{IntoPyArray, PyArrayMethods};
        let flat: Vec<f32> = self.mesh.positions.iter().flatten().copied().collect();
        flat.into_pyarray(py)
            .reshape([self.mesh.positions.len(), 3])
    }

    /// Triangles (M, 3) uint32 vertex indices (a copy; degenerate triangles were dropped).
    #[getter]
    fn faces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray2<u32>>> {
        use numpy::{IntoPyArray, PyArrayMethods};
        let flat: Vec<u32> = self.mesh.triangles.iter().flatten().copied().collect();
        flat.into_pyarray(py)
            .reshape([self.mesh.triangles.len(), 3])
    }

    /// Number of vertices.
    #[getter]
    fn vertex_count(&self) -> usize {
        self.mesh.vertex_count()
    }

    /// Number of triangles.
    #[getter]
    fn triangle_count(&self) -> usize {
        self.mesh.triangle_count()
    }

    /// The bounding sphere ``((cx, cy, cz), radius)`` in world units that baking normalizes by.
    #[getter]
    fn bounding_sphere(&self) -> ((f64, f64, f64), f64) {
        let s = self.mesh.bounding_sphere();
        ((s.center.x, s.center.y, s.center.z), s.radius)
    }

    /// Source name recorded in baked assets.
    #[getter]
    fn name(&self) -> &str {
        &self.source_name
    }

    fn __repr__(&self) -> String {
        format!(
            "Mesh(name={:?}, vertices={}, triangles={}, colors={}, textures={})",
            self.source_name,
            self.mesh.vertex_count(),
            self.mesh.triangle_count(),
            self.mesh.colors.is_some(),
            self.mesh.textures.len()
        )
    }
}

/// Shading options as the Python API spells them (keyword-only everywhere).
pub fn shading(
    light: [f32; 3],
    ambient: f32,
    specular: Option<(f32, f32)>,
    unlit: bool,
    shadows: bool,
) -> PyResult<Shading> {
    let shading = Shading {
        light,
        ambient,
        specular,
        unlit,
        shadows,
    };
    shading.validate().map_err(|e| errors::shading(&e))?;
    Ok(shading)
}

/// Native reference render on a `Mesh` (the Python wrapper converts other mesh inputs).
#[pyfunction]
#[pyo3(signature = (mesh, view, *, light, ambient, specular, unlit, background, shadows = false))]
#[allow(clippy::too_many_arguments)]
pub fn reference_render(
    py: Python<'_>,
    mesh: &Bound<'_, PyMesh>,
    view: &Bound<'_, PyAny>,
    light: [f32; 3],
    ambient: f32,
    specular: Option<(f32, f32)>,
    unlit: bool,
    background: Option<&Bound<'_, PyAny>>,
    shadows: bool,
) -> PyResult<PyFrame> {
    let view = view::parse_view(view)?;
    let shading = shading(light, ambient, specular, unlit, shadows)?;
    let background = background.map(parse_background).transpose()?;
    let mesh = mesh.get();
    let frame = py.detach(|| {
        let gpu_mesh = mesh.gpu_mesh()?;
        let reference = engines::reference().map_err(|e| errors::gpu_for_render(&e))?;
        reference
            .render(&gpu_mesh, &view, &shading)
            .map_err(|e| errors::reference(&e))
    })?;
    Ok(PyFrame::new(frame, background))
}
