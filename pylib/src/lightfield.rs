//! `LightField`: a validated `.lfa` asset, its GPU upload (made on first render), and `bake`.

use std::io::Write;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use lumigraph_core::asset::{AssetFile, BlockCodec, Provenance};
use lumigraph_core::auto_bake::{self, AutoEngines, AutoStage, AutoTarget};
use lumigraph_core::bake::{BakeOptions, StateBake};
use lumigraph_core::calibration;
use lumigraph_core::deform::StateMesh;
use lumigraph_core::frame::Frame;
use lumigraph_core::lod::LodError;
use lumigraph_core::page_cache::{
    CacheConfig, PageFrameStats, PageSummary, PagedTwoPlane, Prefetch,
};
use lumigraph_core::quality::{Plan, Quality, QualityError};
use lumigraph_core::render::GpuLightField;
use lumigraph_core::shading::Shading;
use lumigraph_core::two_plane_render::{GpuTwoPlane, TwoPlaneOptions};
use lumigraph_core::view::View;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use crate::frame::{PyFrame, parse_background};
use crate::mesh::{PyMesh, shading};
use crate::{engines, errors, view};

/// Where the asset's bytes live, for `save` / `to_bytes`.
pub(crate) enum Origin {
    /// Baked or loaded from bytes: the encoded file.
    Memory(Arc<Vec<u8>>),
    /// Opened from a file (read lazily; checked against the header on save).
    File(PathBuf),
}

/// The field in `slot`, uploaded by `upload` on first use (the lock held meanwhile, so threads
/// upload once).
fn upload_once<T>(
    slot: &Mutex<Option<Arc<T>>>,
    upload: impl FnOnce() -> PyResult<T>,
) -> PyResult<Arc<T>> {
    let mut slot = slot
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some(field) = slot.as_ref() {
        return Ok(field.clone());
    }
    let field = Arc::new(upload()?);
    *slot = Some(field.clone());
    Ok(field)
}

/// A spherical light field (an ``.lfa`` asset): open one with :meth:`LightField.open` or make one
/// with :func:`lumigraph.bake_mesh`, then :meth:`render` any view.
///
/// The asset's header, index and page checksums are validated on open / first render; the
/// images are uploaded to the GPU once, on the first render. A LightField may be rendered from
/// several threads at once (the GIL is released while rendering).
#[pyclass(name = "LightField", module = "lumigraph", frozen)]
pub struct PyLightField {
    asset: Arc<AssetFile>,
    origin: Origin,
    gpu: Mutex<Option<Arc<GpuLightField>>>,
    two_plane: Mutex<Option<Arc<GpuTwoPlane>>>,
    /// The page cache a two-plane light field renders through (`open(cache_mib=...)`).
    paging: Option<CacheConfig>,
    paged: Mutex<Paged>,
}

/// A light field's page cache (opened on the first render) and what its frames did.
#[derive(Default)]
struct Paged {
    cache: Option<PagedTwoPlane>,
    last: Option<PageFrameStats>,
    summary: PageSummary,
}

impl PyLightField {
    pub(crate) fn new(asset: AssetFile, origin: Origin) -> Self {
        Self {
            asset: Arc::new(asset),
            origin,
            gpu: Mutex::new(None),
            two_plane: Mutex::new(None),
            paging: None,
            paged: Mutex::default(),
        }
    }

    /// A light field held in memory as its encoded bytes, validated (GIL released meanwhile)
    /// as `LightField.from_bytes` validates.
    pub(crate) fn from_encoded(py: Python<'_>, bytes: Vec<u8>) -> PyResult<Self> {
        let asset = py
            .detach(|| AssetFile::from_bytes(bytes.clone()))
            .map_err(|e| errors::asset(&e, None))?;
        Ok(Self::new(asset, Origin::Memory(Arc::new(bytes))))
    }

    /// Uploads a two-plane asset once; call with the GIL released.
    fn uploaded_two_plane(&self) -> PyResult<Arc<GpuTwoPlane>> {
        upload_once(&self.two_plane, || {
            let renderer = engines::two_plane_renderer().map_err(|e| errors::gpu_for_render(&e))?;
            renderer.upload(&self.asset).map_err(|e| errors::render(&e))
        })
    }

    /// Renders every view of a two-plane asset with `options` (GIL released).
    fn render_two_plane(
        &self,
        py: Python<'_>,
        views: &[View],
        (options, draws): &(TwoPlaneOptions, u32),
        background: Option<[u8; 4]>,
    ) -> PyResult<Vec<PyFrame>> {
        if let Some(config) = self.paging {
            let frames = py.detach(|| self.render_paged(config, views, options, *draws))?;
            return Ok(frames
                .into_iter()
                .map(|f| PyFrame::new(f, background))
                .collect());
        }
        let frames: Vec<Frame> = py.detach(|| {
            let field = self.uploaded_two_plane()?;
            let renderer = engines::two_plane_renderer().map_err(|e| errors::gpu_for_render(&e))?;
            views
                .iter()
                .map(|v| {
                    renderer
                        .render_accumulated(&field, v, options, *draws)
                        .map_err(|e| errors::render(&e))
                })
                .collect::<PyResult<Vec<Frame>>>()
        })?;
        Ok(frames
            .into_iter()
            .map(|f| PyFrame::new(f, background))
            .collect())
    }

    /// Renders `views` through the page cache of `config` (opened on first use), recording each
    /// frame's paging; call with the GIL released.
    fn render_paged(
        &self,
        config: CacheConfig,
        views: &[View],
        options: &TwoPlaneOptions,
        draws: u32,
    ) -> PyResult<Vec<Frame>> {
        let renderer = engines::two_plane_renderer().map_err(|e| errors::gpu_for_render(&e))?;
        let mut paged = self
            .paged
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let paged = &mut *paged;
        let cache = match &mut paged.cache {
            Some(cache) => cache,
            slot @ None => slot.insert(
                PagedTwoPlane::open(renderer, Arc::clone(&self.asset), config)
                    .map_err(|e| errors::render(&e))?,
            ),
        };
        let mut frames = Vec::with_capacity(views.len());
        for view in views {
            let (frame, mut stats) = cache
                .render_accumulated(renderer, view, options, draws, true)
                .map_err(|e| errors::render(&e))?;
            stats.degraded_mask = Vec::new();
            paged.summary.add(&stats);
            paged.last = Some(stats);
            frames.push(frame);
        }
        Ok(frames)
    }

    /// Uploads once; call with the GIL released.
    fn uploaded(&self) -> PyResult<Arc<GpuLightField>> {
        upload_once(&self.gpu, || {
            let renderer = engines::renderer().map_err(|e| errors::gpu_for_render(&e))?;
            renderer.upload(&self.asset).map_err(|e| errors::render(&e))
        })
    }

    fn encoded(&self) -> PyResult<Arc<Vec<u8>>> {
        match &self.origin {
            Origin::Memory(bytes) => Ok(bytes.clone()),
            Origin::File(path) => {
                let shown = path.display().to_string();
                let bytes = std::fs::read(path).map_err(|e| {
                    errors::asset(&lumigraph_core::asset::AssetError::Io(e), Some(&shown))
                })?;
                let reread = AssetFile::from_bytes(bytes.clone())
                    .map_err(|e| errors::asset(&e, Some(&shown)))?;
                if reread.header() != self.asset.header()
                    || reread.file_len() != self.asset.file_len()
                {
                    return Err(errors::AssetError::new_err(format!(
                        "{shown} changed on disk since it was opened; open it again"
                    )));
                }
                Ok(Arc::new(bytes))
            }
        }
    }

    /// Renders every view with `plan` (GIL released).
    fn render_all(
        &self,
        py: Python<'_>,
        views: &[View],
        plan: &Plan,
        background: Option<[u8; 4]>,
    ) -> PyResult<Vec<PyFrame>> {
        let frames: Vec<Frame> = py.detach(|| {
            let field = self.uploaded()?;
            let renderer = engines::renderer().map_err(|e| errors::gpu_for_render(&e))?;
            views
                .iter()
                .map(|v| {
                    plan.render(renderer, &field, v)
                        .map(|r| r.frame)
                        .map_err(|e| quality_err(&e))
                })
                .collect::<PyResult<Vec<Frame>>>()
        })?;
        Ok(frames
            .into_iter()
            .map(|f| PyFrame::new(f, background))
            .collect())
    }

    /// The plan of a quality request for this light field.
    fn plan(&self, quality: &Quality) -> PyResult<Plan> {
        quality
            .plan(self.asset.header())
            .map_err(|e| quality_err(&e))
    }
}

/// Python exception of a quality error: device failures as render errors, the rest (conflicts,
/// bad values, no calibration) as ValueError.
fn quality_err(err: &QualityError) -> PyErr {
    match err {
        QualityError::Render(r) | QualityError::Lod(LodError::Render(r)) => errors::render(r),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// A Python keyword value as JSON (JSON has no infinity: ±inf becomes the largest float, which
/// every quality bound treats alike).
fn json_of(value: &Bound<'_, PyAny>) -> PyResult<serde_json::Value> {
    use pyo3::types::{PyBool, PyFloat, PyInt, PyString};
    if value.is_none() {
        return Ok(serde_json::Value::Null);
    }
    if let Ok(b) = value.cast::<PyBool>() {
        return Ok(serde_json::Value::Bool(b.is_true()));
    }
    if value.cast::<PyInt>().is_ok() {
        if let Ok(i) = value.extract::<i64>() {
            return Ok(i.into());
        }
        return Ok(value.extract::<u64>()?.into());
    }
    if value.cast::<PyFloat>().is_ok() {
        let x: f64 = value.extract()?;
        let x = if x.is_infinite() {
            f64::MAX.copysign(x)
        } else {
            x
        };
        return Ok(serde_json::Number::from_f64(x)
            .map_or_else(|| serde_json::Value::String("nan".to_owned()), Into::into));
    }
    if let Ok(text) = value.cast::<PyString>() {
        return Ok(serde_json::Value::String(text.to_str()?.to_owned()));
    }
    // A sequence: the `light` direction ((x, y, z), a list or a numpy array).
    if let Ok(list) = value.cast::<pyo3::types::PyList>() {
        return list.iter().map(|item| json_of(&item)).collect();
    }
    if let Ok(tuple) = value.cast::<pyo3::types::PyTuple>() {
        return tuple.iter().map(|item| json_of(&item)).collect();
    }
    if value.hasattr("tolist")? && value.hasattr("shape")? {
        return json_of(&value.call_method0("tolist")?);
    }
    // A dict: the `layers` opacities ({"skin": 0.3}).
    if let Ok(dict) = value.cast::<pyo3::types::PyDict>() {
        let mut map = serde_json::Map::new();
        for (key, item) in dict.iter() {
            map.insert(key.extract::<String>()?, json_of(&item)?);
        }
        return Ok(serde_json::Value::Object(map));
    }
    Err(PyTypeError::new_err(format!(
        "a quality option must be a number, a string, a sequence (light), a dict (layers) or \
         None, got {}",
        value.get_type().name()?
    )))
}

/// The quality request of keyword arguments (core `Quality`: the same keys as the HTTP body).
/// The keyword options of a two-plane render (`uv_filter`, `focus`, `aperture`, `steps`,
/// `tolerance`, `dither_amplitude`, `sample_budget`, `frame_index`).
fn two_plane_options_of(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<(TwoPlaneOptions, u32)> {
    let mut map = serde_json::Map::new();
    if let Some(kwargs) = kwargs {
        for (key, value) in kwargs.iter() {
            map.insert(key.extract::<String>()?, json_of(&value)?);
        }
    }
    // `refine`: aperture draws averaged, as the service's quality key.
    let draws = match map.remove("refine") {
        None | Some(serde_json::Value::Null) => 1,
        Some(value) => value
            .as_u64()
            .and_then(|n| u32::try_from(n).ok())
            .filter(|n| (1..=lumigraph_core::two_plane_render::MAX_DRAWS).contains(n))
            .ok_or_else(|| {
                PyValueError::new_err(format!(
                    "refine {value}: give 1..={} aperture draws",
                    lumigraph_core::two_plane_render::MAX_DRAWS
                ))
            })?,
    };
    let options: TwoPlaneOptions =
        serde_json::from_value(serde_json::Value::Object(map)).map_err(|e| {
            PyValueError::new_err(format!(
                "two-plane render options (uv_filter, focus, aperture, refine, steps, tolerance, \
                 dither_amplitude, sample_budget, frame_index): {e}"
            ))
        })?;
    options
        .validate()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok((options, draws))
}

fn quality_of(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<Quality> {
    let mut map = serde_json::Map::new();
    if let Some(kwargs) = kwargs {
        for (key, value) in kwargs.iter() {
            map.insert(key.extract::<String>()?, json_of(&value)?);
        }
    }
    Quality::from_json_map(map).map_err(|e| quality_err(&e))
}

fn json_to_py<'py>(py: Python<'py>, value: &AssetHeader) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value).map_err(|e| PyValueError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

use lumigraph_core::asset::AssetHeader;

fn shading_of(header: &AssetHeader) -> Shading {
    BakeOptions::of(header).shading
}

#[pymethods]
impl PyLightField {
    /// LightField.open(path, *, cache_mib=None, prefetch="lru", pages_per_frame=64) -> LightField
    ///
    /// Opens an ``.lfa`` file, validating its preamble, header and index (pages are verified
    /// when first read). The file stays open and is read on the first render.
    ///
    /// ``cache_mib`` renders a two-plane light field through a paged cache of that many MiB of
    /// device memory instead of uploading it whole (light fields larger than memory;
    /// docs/two_plane.md "Paged rendering"): pages are read from the file as views need them,
    /// ``prefetch`` (``"none"``, ``"lru"`` or ``"predict"``) says which are loaded ahead and
    /// evicted, at most ``pages_per_frame`` are loaded per frame, and a page not resident yet
    /// reads a coarse copy (the frame is degraded there: see :attr:`page_stats`).
    ///
    /// Raises:
    ///     FileNotFoundError: no such file.
    ///     AssetError: not an asset, unsupported version, truncated or corrupt.
    ///     ValueError: a cache for a spherical light field, a cache_mib that is not a positive
    ///         number, an unknown prefetch policy, pages_per_frame 0, or prefetch /
    ///         pages_per_frame without cache_mib.
    #[staticmethod]
    #[pyo3(signature = (path, *, cache_mib = None, prefetch = None, pages_per_frame = None))]
    fn open(
        py: Python<'_>,
        path: PathBuf,
        cache_mib: Option<f64>,
        prefetch: Option<&str>,
        pages_per_frame: Option<u32>,
    ) -> PyResult<Self> {
        let shown = path.display().to_string();
        let paging = match cache_mib {
            None => {
                if prefetch.is_some() || pages_per_frame.is_some() {
                    return Err(PyValueError::new_err(
                        "prefetch and pages_per_frame apply to a page cache: give cache_mib",
                    ));
                }
                None
            }
            Some(mib) => {
                if !(mib.is_finite() && mib > 0.0) {
                    return Err(PyValueError::new_err(format!(
                        "cache_mib {mib}: give a positive number of MiB"
                    )));
                }
                let prefetch: Prefetch = prefetch
                    .unwrap_or("lru")
                    .parse()
                    .map_err(|e: String| PyValueError::new_err(e))?;
                let pages =
                    pages_per_frame.unwrap_or(lumigraph_core::page_cache::DEFAULT_PAGES_PER_FRAME);
                if pages == 0 {
                    return Err(PyValueError::new_err("pages_per_frame 0: give at least 1"));
                }
                Some(CacheConfig::with_mib(mib, prefetch, pages))
            }
        };
        let asset = py
            .detach(|| AssetFile::open(&path))
            .map_err(|e| errors::asset(&e, Some(&shown)))?;
        if paging.is_some() && asset.header().two_plane().is_none() {
            return Err(PyValueError::new_err(format!(
                "{shown}: a page cache (cache_mib) is for two-plane light fields; this one is {}",
                asset.header().kind.name()
            )));
        }
        let mut field = Self::new(asset, Origin::File(path));
        field.paging = paging;
        Ok(field)
    }

    /// The paging of a light field opened with ``cache_mib``, else None: ``{"cache": {...},
    /// "last": {...}, "summary": {...}}``. ``cache``: ``prefetch``, ``pages_per_frame``,
    /// ``budget_bytes``, and once the first frame opened it ``slots``, ``pages``, ``page_size``,
    /// ``coarse_factor``, ``page_levels`` (levels between the full resolution and the coarse
    /// level), ``level_pages``, ``level_file_bytes``, ``device_bytes``, ``resident_bytes``.
    /// ``last`` (the last frame; None before any): ``faults`` (pages it touched that were not
    /// resident when it started), ``degraded_px``, ``overview_px`` (pixels spanning 2 or more
    /// st texels, read from a downsampled level by choice), ``pages_loaded``, ``bytes_uploaded``, ``ms``, ``pages_touched``,
    /// ``pages_projected``, ``projection_missed``, ``resident``, ``load_ms``, ``plan_ms`` and
    /// ``read_errors`` when pages failed to read. ``summary``: ``frames``, ``faults``,
    /// ``degraded_px``, ``pages_loaded``, ``bytes_uploaded``, ``mean_ms``, ``max_ms``,
    /// ``overview_px``, ``projection_missed`` over every frame so far.
    #[getter]
    fn page_stats<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let Some(config) = self.paging else {
            return Ok(None);
        };
        let paged = self
            .paged
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut cache = serde_json::json!({
            "prefetch": config.prefetch.to_string(),
            "pages_per_frame": config.pages_per_frame,
            "budget_bytes": config.budget_bytes,
        });
        if let Some(c) = &paged.cache {
            cache["slots"] = c.slots.into();
            cache["pages"] = c.grid.total().into();
            cache["page_size"] = c.grid.page_size.into();
            cache["coarse_factor"] = c.coarse_factor.into();
            cache["page_levels"] = (c.grid.levels - 1).into();
            cache["level_pages"] = (c.grid.all_pages() - c.grid.total()).into();
            cache["level_file_bytes"] = c.level_file_bytes().into();
            cache["device_bytes"] = c.bytes.into();
            cache["resident_bytes"] = c.full_bytes.into();
        }
        let value = serde_json::json!({
            "cache": cache,
            "last": paged.last,
            "summary": paged.summary,
        });
        let text =
            serde_json::to_string(&value).map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(Some(py.import("json")?.call_method1("loads", (text,))?))
    }

    /// LightField.from_bytes(data) -> LightField
    ///
    /// Validates an asset held in memory (e.g. downloaded), exactly as :meth:`open` does.
    ///
    /// Raises:
    ///     AssetError: not an asset, unsupported version, truncated or corrupt.
    #[staticmethod]
    fn from_bytes(py: Python<'_>, data: &Bound<'_, PyBytes>) -> PyResult<Self> {
        Self::from_encoded(py, data.as_bytes().to_vec())
    }

    /// to_bytes() -> bytes
    ///
    /// The encoded ``.lfa`` file.
    fn to_bytes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let bytes = py.detach(|| self.encoded())?;
        Ok(PyBytes::new(py, &bytes))
    }

    /// save(path) -> None
    ///
    /// Writes the asset to ``path`` atomically (a temporary file beside it, then a rename):
    /// on error nothing is left at ``path``.
    ///
    /// Raises:
    ///     AssetError: the file cannot be written (the message includes the OS error).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let shown = path.display().to_string();
        py.detach(|| {
            let bytes = self.encoded()?;
            lumigraph_core::atomic_write(&path, |w| w.write_all(&bytes))
                .map_err(|e| errors::AssetError::new_err(format!("cannot write {shown}: {e}")))
        })
    }

    /// verify() -> None
    ///
    /// Reads every page and checks its CRC-32 (what ``lumigraph info`` does).
    ///
    /// Raises:
    ///     AssetError: the first corrupt or missing page.
    fn verify(&self, py: Python<'_>) -> PyResult<()> {
        py.detach(|| self.asset.verify_all())
            .map_err(|e| errors::asset(&e, None))
    }

    /// The asset's JSON header as a dict (docs/format.md): kind, geometry (camera_level,
    /// camera_count, resolution_px), frame (bounding sphere centre and radius, world units),
    /// page_size, channels, layers, states, provenance (source, bake options, bake_ms), quality.
    #[getter]
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_to_py(py, self.asset.header())
    }

    /// The deformation states (``bake_mesh(states=...)``), each ``{"name", "fraction",
    /// "stored_pages", "total_pages", "cameras"}``: the share of the pages (colour and depth,
    /// every camera) it stores, the rest reading from the base state.
    #[getter]
    fn deformations<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let storage =
            lumigraph_core::deform::storage(&self.asset).map_err(|e| errors::asset(&e, None))?;
        let text =
            serde_json::to_string(&storage).map_err(|e| PyValueError::new_err(e.to_string()))?;
        py.import("json")?.call_method1("loads", (text,))
    }

    /// Number of cameras baked (12, 42, 162 or 642; a two-plane light field: nu·nv).
    #[getter]
    fn cameras(&self) -> u32 {
        self.asset.header().camera_count()
    }

    /// The kind of light field: ``"spherical"`` or ``"two_plane"``.
    #[getter]
    fn kind(&self) -> &'static str {
        if self.asset.header().two_plane().is_some() {
            "two_plane"
        } else {
            "spherical"
        }
    }

    /// The planes of a two-plane light field (DESIGN §9's JSON as a dict), None for a spherical
    /// one.
    #[getter]
    fn planes<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let Some(planes) = self.asset.header().two_plane() else {
            return Ok(None);
        };
        let text =
            serde_json::to_string(planes).map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(Some(py.import("json")?.call_method1("loads", (text,))?))
    }

    /// Side of each camera's parabolic map, pixels (a two-plane light field: its st width).
    #[getter]
    fn resolution(&self) -> u32 {
        self.asset.header().image_size()[0]
    }

    /// The object's bounding sphere ``((cx, cy, cz), radius)``, world units.
    #[getter]
    fn bounding_sphere(&self) -> ((f64, f64, f64), f64) {
        let f = &self.asset.header().frame;
        ((f.center[0], f.center[1], f.center[2]), f.radius)
    }

    /// The shading the asset was baked with, as keyword arguments for
    /// :func:`lumigraph.reference_render`: ``{"light", "ambient", "specular", "unlit",
    /// "shadows"}``.
    #[getter]
    fn shading<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = shading_of(self.asset.header());
        let d = PyDict::new(py);
        d.set_item("light", (s.light[0], s.light[1], s.light[2]))?;
        d.set_item("ambient", s.ambient)?;
        d.set_item("specular", s.specular)?;
        d.set_item("unlit", s.unlit)?;
        d.set_item("shadows", s.shadows)?;
        Ok(d)
    }

    /// render(view, *, background=None, **quality) -> Frame
    ///
    /// Renders one view with depth-corrected ray casting on the GPU (GIL released).
    ///
    /// Args:
    ///     view: a :class:`View` or a dict with keys eye, target, up, yfov_deg, width, height
    ///         (world coordinates of the source mesh).
    ///     background: RGB or RGBA integers 0..255 for pixels outside coverage. Default
    ///         transparent black.
    ///     **quality: the quality request, the same keys as the HTTP render body and the CLI
    ///         flags (docs/protocol.md): explicit knobs ``lod`` (cameras 12/42/162/642 or a level
    ///         0-3), ``step`` and ``tolerance`` (bounding-sphere diameters), ``method``
    ///         (``"default"`` or ``"fixed"``), ``guide`` (coarse-to-fine factor 2-16, 0 = off);
    ///         or a goal ``target_psnr`` (dB) / ``budget_ms`` served by the calibration (see
    ///         :meth:`choose`); or automatic LOD ``auto_lod`` (bound on the predicted
    ///         silhouette error, pixels) with ``lod_min_psnr``, ``lod_max_psnr_drop`` and
    ///         ``lod_blend`` (see :meth:`choose_lod`). ``light=(x, y, z)`` relights an asset
    ///         baked with ``lights=`` at that world-space direction (DESIGN §9).
    ///         ``state="NAME"`` renders a deformation state (baked with ``states=``);
    ///         ``time=SECONDS`` or ``frame=N`` a frame of an asset baked with
    ///         ``lumigraph bake --animation``.
    ///
    /// Raises:
    ///     ValueError: a bad view, an unknown or bad quality option, or a conflict between
    ///         them; a zero or NaN light, or a light for an asset without light states; an
    ///         unknown state.
    ///         TypeError: an argument of the wrong type. AssetError: a corrupt page.
    ///     RenderError: the device failed.
    #[pyo3(signature = (view, *, background = None, **quality))]
    fn render(
        &self,
        py: Python<'_>,
        view: &Bound<'_, PyAny>,
        background: Option<&Bound<'_, PyAny>>,
        quality: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<PyFrame> {
        let view = view::parse_view(view)?;
        let background = background.map(parse_background).transpose()?;
        if self.asset.header().two_plane().is_some() {
            let options = two_plane_options_of(quality)?;
            return self
                .render_two_plane(py, &[view], &options, background)?
                .pop()
                .ok_or_else(|| errors::RenderError::new_err("no frame rendered"));
        }
        let plan = self.plan(&quality_of(quality)?)?;
        self.render_all(py, &[view], &plan, background)?
            .pop()
            .ok_or_else(|| errors::RenderError::new_err("no frame rendered"))
    }

    /// render_many(views, *, background=None, **quality) -> list[Frame]
    ///
    /// Renders a batch of views (a list of :class:`View` or dicts) with one release of the GIL;
    /// options as in :meth:`render`. Every view and option is validated before any is rendered.
    #[pyo3(signature = (views, *, background = None, **quality))]
    fn render_many(
        &self,
        py: Python<'_>,
        views: &Bound<'_, PyAny>,
        background: Option<&Bound<'_, PyAny>>,
        quality: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Vec<PyFrame>> {
        let views = view::parse_views(views)?;
        if self.asset.header().two_plane().is_some() {
            let options = two_plane_options_of(quality)?;
            for v in &views {
                v.basis(lumigraph_core::view::DEFAULT_MAX_VIEW_PX)
                    .map_err(|e| PyValueError::new_err(e.to_string()))?;
            }
            let background = background.map(parse_background).transpose()?;
            return self.render_two_plane(py, &views, &options, background);
        }
        let plan = self.plan(&quality_of(quality)?)?;
        for v in &views {
            v.basis(lumigraph_core::view::DEFAULT_MAX_VIEW_PX)
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            plan.decide(v).map_err(|e| quality_err(&e))?;
        }
        let background = background.map(parse_background).transpose()?;
        self.render_all(py, &views, &plan, background)
    }

    /// choose(view, *, target_psnr=None, budget_ms=None) -> dict
    ///
    /// The setting :meth:`render` would use for a goal at the view's size, from the light
    /// field's calibration (baked with ``calibrate=True``): ``{"cameras", "step",
    /// "predicted_psnr", "predicted_ms", "met"}``. ``target_psnr``: the cheapest setting
    /// predicted to reach that masked PSNR (dB); ``budget_ms``: the most accurate setting
    /// predicted to render within that time. ``met`` is False when no calibrated setting
    /// meets the goal (the closest one is returned).
    ///
    /// Raises:
    ///     ValueError: no goal, both goals, a non-finite or non-positive goal, a bad view, or
    ///         no calibration in this light field.
    #[pyo3(signature = (view, *, target_psnr = None, budget_ms = None))]
    fn choose<'py>(
        &self,
        py: Python<'py>,
        view: &Bound<'_, PyAny>,
        target_psnr: Option<f64>,
        budget_ms: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let view = view::parse_view(view)?;
        if target_psnr.is_none() && budget_ms.is_none() {
            return Err(PyValueError::new_err("give target_psnr or budget_ms"));
        }
        let quality = Quality {
            target_psnr,
            budget_ms,
            ..Quality::default()
        };
        let decision = self
            .plan(&quality)?
            .decide(&view)
            .map_err(|e| quality_err(&e))?;
        let c = decision
            .choice
            .ok_or_else(|| PyValueError::new_err("give target_psnr or budget_ms"))?;
        let out = PyDict::new(py);
        out.set_item("cameras", c.cameras)?;
        out.set_item("step", c.step)?;
        out.set_item("predicted_psnr", c.predicted_psnr)?;
        out.set_item("predicted_ms", c.predicted_ms)?;
        out.set_item("met", c.met)?;
        Ok(out)
    }

    /// choose_lod(view, *, auto_lod=1.0, lod_min_psnr=None, lod_max_psnr_drop=None, lod_blend=None, lod=None, step=None, tolerance=None, guide=None) -> dict
    ///
    /// What :meth:`render` with ``auto_lod`` would use for this view: ``{"projected_px",
    /// "cameras", "step", "error_px", "met", "predicted_psnr", "predicted_ms", "blend"}``.
    /// ``blend`` is None, or ``{"cameras", "step", "weight"}`` of the level being cross-faded
    /// in near a switch. ``auto_lod`` bounds the predicted silhouette error in pixels;
    /// explicit ``lod``/``step`` are kept (``tolerance`` too).
    ///
    /// Raises:
    ///     ValueError: a bad view or policy, no calibration, or no level left.
    #[pyo3(signature = (view, *, auto_lod = 1.0, lod_min_psnr = None, lod_max_psnr_drop = None, lod_blend = None, lod = None, step = None, tolerance = None, guide = None))]
    fn choose_lod<'py>(
        &self,
        py: Python<'py>,
        view: &Bound<'_, PyAny>,
        auto_lod: f64,
        lod_min_psnr: Option<f64>,
        lod_max_psnr_drop: Option<f64>,
        lod_blend: Option<f64>,
        lod: Option<u32>,
        step: Option<f32>,
        tolerance: Option<f32>,
        guide: Option<u32>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let view = view::parse_view(view)?;
        let quality = Quality {
            lod,
            step,
            tolerance,
            guide,
            auto_lod: Some(auto_lod),
            lod_min_psnr,
            lod_max_psnr_drop,
            lod_blend,
            ..Quality::default()
        };
        let decision = self
            .plan(&quality)?
            .decide(&view)
            .map_err(|e| quality_err(&e))?;
        let d = decision
            .lod
            .ok_or_else(|| PyValueError::new_err("auto_lod is required"))?;
        let out = PyDict::new(py);
        out.set_item("projected_px", d.projected_px)?;
        out.set_item("cameras", d.level.cameras)?;
        out.set_item("step", d.level.step)?;
        out.set_item("error_px", d.error_px)?;
        out.set_item("met", d.met)?;
        out.set_item("predicted_psnr", d.level.masked_psnr)?;
        out.set_item(
            "predicted_ms",
            d.predicted_ms(u64::from(view.width) * u64::from(view.height)),
        )?;
        match d.blend {
            Some((next, w)) => {
                let b = PyDict::new(py);
                b.set_item("cameras", next.cameras)?;
                b.set_item("step", next.step)?;
                b.set_item("weight", w)?;
                out.set_item("blend", b)?;
            }
            None => out.set_item("blend", py.None())?,
        }
        Ok(out)
    }

    fn __repr__(&self) -> String {
        let h = self.asset.header();
        format!(
            "LightField(source={:?}, cameras={}, resolution={}, bytes={})",
            h.provenance.source_name,
            h.camera_count(),
            h.image_size()[0],
            self.asset.file_len()
        )
    }
}

/// The block codecs of `color_codec=` and `depth_codec=` (`None` or `"raw"`: no codec); whether
/// they fit the bake is checked with the bake's options.
pub(crate) fn codecs(
    color: Option<&str>,
    depth: Option<&str>,
) -> PyResult<(Option<BlockCodec>, Option<BlockCodec>)> {
    let parse = |name: Option<&str>, what: &str| match name {
        None | Some("raw") => Ok(None),
        Some(name) => name
            .parse::<BlockCodec>()
            .map(Some)
            .map_err(|e| PyValueError::new_err(format!("{what}: {e}"))),
    };
    Ok((parse(color, "color_codec")?, parse(depth, "depth_codec")?))
}

/// Native bake on a `Mesh` (the Python `bake_mesh` converts other inputs and the progress flag).
#[pyfunction]
#[pyo3(signature = (mesh, *, cameras, resolution, light, ambient, specular, unlit, depth_bits, progress, calibrate = false, auto = false, target_psnr = None, max_bytes = None, shadows = false, lights = None, states = None, animation = None, color_codec = None, depth_codec = None))]
// Python's keyword-only flags, one parameter each (the Python signature is the interface).
#[allow(clippy::fn_params_excessive_bools)]
pub fn bake(
    py: Python<'_>,
    mesh: Option<Bound<'_, PyMesh>>,
    cameras: u32,
    resolution: u32,
    light: [f32; 3],
    ambient: f32,
    specular: Option<(f32, f32)>,
    unlit: bool,
    depth_bits: u8,
    progress: Option<Py<PyAny>>,
    calibrate: bool,
    auto: bool,
    target_psnr: Option<f64>,
    max_bytes: Option<u64>,
    shadows: bool,
    lights: Option<u32>,
    states: Option<Vec<(String, Bound<'_, PyMesh>)>>,
    animation: Option<(PathBuf, Option<String>, f64)>,
    color_codec: Option<String>,
    depth_codec: Option<String>,
) -> PyResult<PyLightField> {
    if let Some(callback) = &progress
        && !callback.bind(py).is_callable()
    {
        return Err(PyTypeError::new_err(
            "progress must be a bool or a callable(done, total)",
        ));
    }
    let auto_target = if auto {
        Some(AutoTarget::from_flags(target_psnr, max_bytes).map_err(|e| errors::auto_bake(&e))?)
    } else if target_psnr.is_some() || max_bytes.is_some() {
        return Err(PyValueError::new_err(
            "target_psnr and max_bytes choose the setting of an automatic bake: pass auto=True",
        ));
    } else {
        None
    };
    if auto && lights.is_some() {
        return Err(PyValueError::new_err(
            "lights: an automatic bake chooses settings for the base state only; bake light \
             states without auto",
        ));
    }
    let (color_codec, depth_codec) = codecs(color_codec.as_deref(), depth_codec.as_deref())?;
    if auto && (color_codec.is_some() || depth_codec.is_some()) {
        return Err(PyValueError::new_err(
            "color_codec, depth_codec: an automatic bake chooses settings for raw pages; bake \
             block-compressed pages without auto",
        ));
    }
    let states: Vec<(String, Arc<lumigraph_core::mesh::Mesh>, String, String)> = states
        .unwrap_or_default()
        .iter()
        .map(|(name, m)| {
            let m = m.get();
            (
                name.clone(),
                m.mesh.clone(),
                m.source_name.clone(),
                m.source_sha256.clone(),
            )
        })
        .collect();
    if animation.is_some() && (auto || !states.is_empty() || lights.is_some()) {
        return Err(PyValueError::new_err(
            "animation: an animated bake takes no auto, states or lights",
        ));
    }
    if auto && !states.is_empty() {
        return Err(PyValueError::new_err(
            "states: an automatic bake chooses settings for the base state only; bake \
             deformation states without auto",
        ));
    }
    let options = BakeOptions {
        cameras,
        resolution,
        shading: shading(light, ambient, specular, unlit, shadows)?,
        depth_bits,
        lights,
        one_sided: false,
        color_codec,
        depth_codec,
    };
    options.validate().map_err(|e| errors::bake(&e))?;
    // An animation: its frames, frame 0 the base mesh.
    let frames = match &animation {
        Some((path, name, fps)) => Some(
            py.detach(|| lumigraph_core::mesh::load_animation(path, name.as_deref(), *fps))
                .map_err(|e| errors::mesh(&e))?,
        ),
        None => None,
    };
    let (core_mesh, provenance) = match (&frames, &mesh, &animation) {
        (Some(frames), _, Some((path, _, _))) => {
            let bytes = std::fs::read(path).map_err(|e| {
                pyo3::exceptions::PyOSError::new_err(format!("{}: {e}", path.display()))
            })?;
            (
                Arc::new(frames.frames[0].clone()),
                Provenance {
                    source_name: path.file_name().map_or_else(
                        || path.display().to_string(),
                        |n| n.to_string_lossy().into_owned(),
                    ),
                    source_sha256: lumigraph_core::bake::sha256_hex(&bytes),
                    ..Provenance::default()
                },
            )
        }
        (_, Some(mesh), _) => {
            let mesh = mesh.get();
            (
                mesh.mesh.clone(),
                Provenance {
                    source_name: mesh.source_name.clone(),
                    source_sha256: mesh.source_sha256.clone(),
                    ..Provenance::default()
                },
            )
        }
        _ => return Err(PyValueError::new_err("give a mesh or an animation")),
    };
    let (bytes, callback_error) = py.detach(|| {
        let state_meshes: Vec<StateMesh<'_>> = states
            .iter()
            .map(|(name, mesh, source_name, source_sha256)| StateMesh {
                name,
                mesh,
                source_name,
                source_sha256,
                params: None,
            })
            .collect();
        let layout = frames
            .as_ref()
            .map(lumigraph_core::deform::AnimationLayout::new);
        let frame_meshes = match (&layout, &frames) {
            (Some(layout), Some(frames)) => layout.state_meshes(
                &frames.frames,
                &provenance.source_name,
                &provenance.source_sha256,
            ),
            _ => Vec::new(),
        };
        let state_bake = match &layout {
            Some(layout) => layout.state_bake(&frame_meshes),
            None => StateBake {
                meshes: &state_meshes,
                ..StateBake::default()
            },
        };
        let baker = engines::baker().map_err(|e| errors::BakeError::new_err(e.to_string()))?;
        // The callback runs with the GIL re-acquired; its first exception is raised after the
        // bake (the bake itself cannot be interrupted half-way).
        let mut callback_error: Option<PyErr> = None;
        let mut report = |done: u32, total: u32| {
            if let (Some(callback), None) = (&progress, &callback_error) {
                Python::attach(|py| {
                    if let Err(e) = callback.call1(py, (done, total)) {
                        callback_error = Some(e);
                    }
                });
            }
        };
        let bytes = if let Some(target) = auto_target {
            let renderer = engines::renderer().map_err(|e| errors::gpu_for_render(&e))?;
            let reference = engines::reference().map_err(|e| errors::gpu_for_render(&e))?;
            let engines = AutoEngines {
                baker,
                renderer,
                reference,
            };
            auto_bake::auto_bake(
                &engines,
                &core_mesh,
                &options.shading,
                target,
                &provenance,
                calibrate,
                &mut |stage| {
                    if let AutoStage::Bake { done, cameras } = stage {
                        report(done, cameras);
                    }
                },
            )
            .map_err(|e| errors::auto_bake(&e))?
            .bytes
        } else if calibrate {
            let renderer = engines::renderer().map_err(|e| errors::gpu_for_render(&e))?;
            let reference = engines::reference().map_err(|e| errors::gpu_for_render(&e))?;
            calibration::bake_states_calibrated(
                baker,
                renderer,
                reference,
                (&core_mesh, &state_bake),
                &options,
                &provenance,
                &mut report,
            )
            .map_err(|e| match e {
                calibration::CalibrationError::Bake(e) => errors::bake(&e),
                other => errors::BakeError::new_err(format!("calibration failed: {other}")),
            })?
            .bytes
        } else {
            baker
                .bake_states_to_bytes(&core_mesh, &state_bake, &options, &provenance, &mut report)
                .map_err(|e| errors::bake(&e))?
        };
        PyResult::Ok((bytes, callback_error))
    })?;
    if let Some(error) = callback_error {
        return Err(error);
    }
    PyLightField::from_encoded(py, bytes)
}

/// Native two-plane bake on a `Mesh` (the Python `bake_two_plane` converts other inputs, the
/// planes and the progress flag). `planes`: DESIGN §9's JSON, or None to fit them to the mesh's
/// bounding sphere along `axis` with `grid` and `st_res`.
#[pyfunction]
#[pyo3(signature = (mesh, *, planes, axis, grid, st_res, light, ambient, specular, unlit, shadows, progress))]
#[allow(clippy::too_many_arguments, clippy::fn_params_excessive_bools)]
pub fn bake_two_plane(
    py: Python<'_>,
    mesh: Bound<'_, PyMesh>,
    planes: Option<String>,
    axis: [f64; 3],
    grid: [u32; 2],
    st_res: [u32; 2],
    light: [f32; 3],
    ambient: f32,
    specular: Option<(f32, f32)>,
    unlit: bool,
    shadows: bool,
    progress: Option<Py<PyAny>>,
) -> PyResult<PyLightField> {
    if let Some(callback) = &progress
        && !callback.bind(py).is_callable()
    {
        return Err(PyTypeError::new_err(
            "progress must be a bool or a callable(done, total)",
        ));
    }
    let shading = shading(light, ambient, specular, unlit, shadows)?;
    let explicit = planes
        .as_deref()
        .map(lumigraph_core::two_plane::TwoPlanes::from_json)
        .transpose()
        .map_err(|e| PyValueError::new_err(format!("planes: {e}")))?;
    let m = mesh.get();
    let core_mesh = m.mesh.clone();
    let mut provenance = Provenance {
        source_name: m.source_name.clone(),
        source_sha256: m.source_sha256.clone(),
        lumigraph_version: env!("CARGO_PKG_VERSION").to_owned(),
        triangles: core_mesh.triangles.len() as u64,
        vertices: core_mesh.positions.len() as u64,
        created_unix: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
        ..Provenance::default()
    };
    let (bytes, callback_error) = py.detach(|| {
        let reference = engines::reference().map_err(|e| errors::gpu_for_render(&e))?;
        let gpu_mesh = reference
            .upload(&core_mesh)
            .map_err(|e| errors::BakeError::new_err(e.to_string()))?;
        let planes = match explicit {
            Some(p) => p,
            None => lumigraph_core::two_plane::fit_planes(
                lumigraph_core::glam::DVec3::from(gpu_mesh.frame.center),
                gpu_mesh.frame.radius,
                lumigraph_core::glam::DVec3::from(axis),
                grid,
                st_res,
            )
            .map_err(|e| PyValueError::new_err(format!("cannot fit planes: {e}")))?,
        };
        provenance.bake_options = serde_json::json!({"two_plane": planes, "shading": shading});
        let mut callback_error: Option<PyErr> = None;
        let mut report = |done: u32, total: u32| {
            if let (Some(callback), None) = (&progress, &callback_error) {
                Python::attach(|py| {
                    if let Err(e) = callback.call1(py, (done, total)) {
                        callback_error = Some(e);
                    }
                });
            }
        };
        let (bytes, _) = lumigraph_core::two_plane::bake_to_bytes(
            reference,
            &gpu_mesh,
            &planes,
            &shading,
            provenance,
            &mut report,
        )
        .map_err(|e| errors::BakeError::new_err(e.to_string()))?;
        PyResult::Ok((bytes, callback_error))
    })?;
    if let Some(error) = callback_error {
        return Err(error);
    }
    PyLightField::from_encoded(py, bytes)
}

/// Native import (the Python `import_lightfield` checks the arguments' types): a folder of
/// images on a camera grid (`grid`, `stanford`) or a raw lenslet image with its calibration
/// (`lenslet`) into a two-plane light field, written to `output` (then opened from there) or
/// held in memory.
#[pyfunction]
#[pyo3(signature = (path, *, layout, planes, output))]
pub fn import_lightfield(
    py: Python<'_>,
    path: PathBuf,
    layout: &str,
    planes: Option<String>,
    output: Option<PathBuf>,
) -> PyResult<PyLightField> {
    if !path.exists() {
        return Err(pyo3::exceptions::PyFileNotFoundError::new_err(format!(
            "{} does not exist",
            path.display()
        )));
    }
    if layout == "lenslet" && planes.is_some() {
        return Err(PyValueError::new_err(
            "planes do not apply to layout='lenslet': they follow from the calibration",
        ));
    }
    let planes = planes
        .as_deref()
        .map(lumigraph_core::two_plane::TwoPlanes::from_json)
        .transpose()
        .map_err(|e| PyValueError::new_err(format!("planes: {e}")))?;
    let grid = if layout == "lenslet" {
        None
    } else {
        Some(
            layout
                .parse::<lumigraph_core::two_plane_io::GridLayout>()
                .map_err(PyValueError::new_err)?,
        )
    };
    let target = import_target(output.as_deref(), "import");
    let imported = py.detach(|| match grid {
        None => lumigraph_core::lenslet::import_lenslet(&path, &target, &mut |_, _| {})
            .map(|_| ())
            .map_err(|e| e.to_string()),
        Some(layout) => lumigraph_core::two_plane_io::import_grid(
            &path,
            layout,
            planes,
            &target,
            &mut |_, _| {},
        )
        .map(|_| ())
        .map_err(|e| e.to_string()),
    });
    if let Err(message) = imported {
        return Err(PyValueError::new_err(format!(
            "cannot import {}: {message}",
            path.display()
        )));
    }
    open_import(py, target, output.is_some())
}

/// Where an import writes: `output`, or a temporary file (named after `what`) for a light
/// field held in memory.
pub(crate) fn import_target(output: Option<&std::path::Path>, what: &str) -> PathBuf {
    output.map_or_else(
        || {
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos());
            std::env::temp_dir().join(format!(
                "lumigraph-{what}-{}-{nanos}.lfa",
                std::process::id()
            ))
        },
        std::path::Path::to_path_buf,
    )
}

/// The light field an import wrote to `target`: opened from there when it is the caller's
/// `output` (`kept`), else read into memory and the temporary file removed.
pub(crate) fn open_import(py: Python<'_>, target: PathBuf, kept: bool) -> PyResult<PyLightField> {
    if kept {
        let shown = target.display().to_string();
        let asset = py
            .detach(|| AssetFile::open(&target))
            .map_err(|e| errors::asset(&e, Some(&shown)))?;
        return Ok(PyLightField::new(asset, Origin::File(target)));
    }
    let bytes = std::fs::read(&target);
    let _ = std::fs::remove_file(&target);
    let bytes = bytes.map_err(|e| PyValueError::new_err(format!("cannot read the import: {e}")))?;
    PyLightField::from_encoded(py, bytes)
}
