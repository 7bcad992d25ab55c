//! The asset store: `.lfa` files in one folder, each uploaded to the GPU once and shared by every
//! request and session through an `Arc`.
//!
//! An asset's id is its file stem. Ids are restricted to `[A-Za-z0-9][A-Za-z0-9_-]{0,63}`, so
//! no id can name a path outside the folder, a hidden file or a temporary file.

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError, RwLock};

use lumigraph_core::asset::{AssetFile, AssetHeader};
use lumigraph_core::gpu::Gpu;
use lumigraph_core::page_cache::{CacheConfig, CacheLayout, PagedTwoPlane};
use lumigraph_core::render::{GpuLightField, field_bytes};
use lumigraph_core::two_plane::TwoPlanes;
use lumigraph_core::two_plane_render::GpuTwoPlane;
use serde::Serialize;

use super::budget::{Charge, MemoryBudget};
use super::error::AppError;
use super::render_pool::Engine;

/// Longest accepted asset id.
pub const MAX_ID_LEN: usize = 64;

/// Checks an asset or job id: 1..=64 characters of `[A-Za-z0-9_-]`, starting alphanumeric.
pub fn validate_id(id: &str) -> Result<(), AppError> {
    let ok = !id.is_empty()
        && id.len() <= MAX_ID_LEN
        && id.as_bytes()[0].is_ascii_alphanumeric()
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
    if ok {
        Ok(())
    } else {
        Err(AppError::Invalid(format!(
            "invalid id {:?}: ids are 1..={MAX_ID_LEN} characters of [A-Za-z0-9_-] starting with a \
             letter or digit",
            truncate(id, 80)
        )))
    }
}

fn truncate(s: &str, max: usize) -> &str {
    match s.char_indices().nth(max) {
        Some((i, _)) => &s[..i],
        None => s,
    }
}

/// An asset ready to render: its header and its images on the GPU.
pub struct LoadedAsset {
    /// The id (file stem).
    pub id: String,
    /// The `.lfa` file.
    pub path: PathBuf,
    /// The validated header.
    pub header: AssetHeader,
    /// File size in bytes.
    pub file_bytes: u64,
    /// Fingerprint of the file's content ([`content_id`]): what a render's `ETag` depends on,
    /// so an id given to new content gets new tags.
    pub content_id: String,
    /// Colour and depth texture arrays.
    pub field: AssetField,
    /// The asset's share of the memory budget, given back when the last holder drops it (the
    /// moment its textures are freed).
    _charge: MemoryCharge,
}

/// An asset's textures on the device, by kind.
pub enum AssetField {
    /// A spherical light field.
    Spherical(GpuLightField),
    /// A two-plane light field.
    TwoPlane(GpuTwoPlane),
    /// A two-plane light field larger than the page cache's budget (`serve --cache-mib`),
    /// rendered through a paged cache of that budget.
    Paged(Box<PagedField>),
}

/// A two-plane light field's paged cache, shared by every request and stream of the asset (one
/// frame renders through it at a time).
pub struct PagedField {
    /// The cache.
    pub cache: Mutex<PagedTwoPlane>,
    gpu: Arc<Gpu>,
    summary: CacheSummary,
}

/// The page cache of an asset rendered through one (`serve --cache-mib`).
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct CacheSummary {
    /// The policy: `none`, `lru` or `predict`.
    pub prefetch: String,
    /// Most pages a frame loads.
    pub pages_per_frame: u32,
    /// Device bytes of the cache (slots and coarse level), charged to the asset memory budget.
    pub device_bytes: u64,
    /// Device bytes the asset would take with every page resident.
    pub resident_bytes: u64,
    /// Page slots.
    pub slots: u32,
    /// Pages of the asset.
    pub pages: u32,
    /// Side of a page in texels.
    pub page_size: u32,
    /// The coarse level's downsampling factor.
    pub coarse_factor: u32,
    /// Page levels between the full resolution and the coarse level (each camera downsampled
    /// 2×, 4×, …: read by pixels spanning 2 or more st texels, paged like the full resolution).
    pub page_levels: u32,
    /// Pages of those levels.
    pub level_pages: u32,
    /// Bytes of the temporary file holding those levels' pages (zstd-compressed).
    pub level_file_bytes: u64,
}

impl PagedField {
    /// The cache, locked (a render that panicked leaves it usable: its residency is only ever
    /// changed with the pages it names uploaded or forgotten).
    pub fn lock(&self) -> std::sync::MutexGuard<'_, PagedTwoPlane> {
        self.cache.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl AssetField {
    /// The device the textures live on.
    pub fn gpu(&self) -> &Arc<Gpu> {
        match self {
            AssetField::Spherical(f) => f.gpu(),
            AssetField::TwoPlane(f) => f.gpu(),
            AssetField::Paged(f) => &f.gpu,
        }
    }

    /// Device bytes of the textures.
    pub fn gpu_bytes(&self) -> u64 {
        match self {
            AssetField::Spherical(f) => f.gpu_bytes,
            AssetField::TwoPlane(f) => f.bytes,
            AssetField::Paged(f) => f.summary.device_bytes,
        }
    }
}

/// A share of the store's memory budget and of the server's, released on drop.
pub struct MemoryCharge {
    bytes: u64,
    charged: Arc<AtomicU64>,
    _server: Charge,
}

impl Drop for MemoryCharge {
    fn drop(&mut self) {
        self.charged.fetch_sub(self.bytes, Ordering::AcqRel);
    }
}

/// What the store lets an asset take.
#[derive(Clone, Copy, Debug)]
pub struct AssetLimits {
    /// Most bytes one asset may decode to ([`AssetHeader::decoded_bytes`]).
    pub max_decoded_bytes: u64,
    /// Most texture bytes ([`field_bytes`]) all loaded assets may hold together.
    pub memory_budget: u64,
    /// The page cache of two-plane light fields whose resident textures exceed its budget
    /// (`serve --cache-mib`); `None`: every asset resident.
    pub page_cache: Option<CacheConfig>,
}

/// One line of `GET /v1/assets`.
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct AssetSummary {
    /// Asset id, usable in `/v1/assets/{id}` and `/v1/stream?asset=`.
    pub id: String,
    /// Light-field kind, e.g. `spherical`.
    pub kind: String,
    /// Number of cameras (12, 42, 162 or 642); every smaller count is available as `lod`.
    pub camera_count: u32,
    /// Side of each camera image in pixels.
    pub resolution_px: u32,
    /// Layer names.
    pub layers: Vec<String>,
    /// Each layer's default opacity, in the order of `layers` (the `layers` render option
    /// overrides them per request).
    pub layer_opacities: Vec<f32>,
    /// State names.
    pub states: Vec<String>,
    /// The deformation states among them (`bake --state NAME=MESH2`): what the `state` render
    /// option takes besides `base`.
    pub deformations: Vec<String>,
    /// The asset's animation (`bake --animation`), if any: what `time`, `frame` and the
    /// stream's `playing` take.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub animation: Option<AnimationSummary>,
    /// Bounding sphere centre in world units (a good orbit target).
    pub center: [f64; 3],
    /// Bounding sphere radius in world units.
    pub radius: f64,
    /// File size in bytes.
    pub file_bytes: u64,
    /// GPU memory the asset takes, in bytes, charged to the asset memory budget.
    pub gpu_bytes: u64,
    /// The planes of a two-plane light field (DESIGN §9's JSON): what `focus` and `aperture`
    /// are measured against.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub planes: Option<TwoPlanes>,
    /// The page cache it renders through, when its resident textures exceed the server's
    /// `--cache-mib`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub page_cache: Option<CacheSummary>,
}

/// An asset's animation.
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct AnimationSummary {
    /// The animation's name.
    pub name: String,
    /// Frames.
    pub frames: usize,
    /// Frames per second.
    pub fps: f64,
    /// Time of its last key, seconds.
    pub duration: f64,
}

impl LoadedAsset {
    /// The summary shown in listings.
    pub fn summary(&self) -> AssetSummary {
        let h = &self.header;
        AssetSummary {
            id: self.id.clone(),
            kind: h.kind.name().to_owned(),
            camera_count: h.camera_count(),
            resolution_px: h.image_size()[0],
            layers: h.layers.iter().map(|l| l.name.clone()).collect(),
            layer_opacities: h.layers.iter().map(|l| l.default_opacity).collect(),
            states: h.states.iter().map(|s| s.name.clone()).collect(),
            deformations: h
                .states
                .iter()
                .enumerate()
                .filter(|&(i, s)| {
                    lumigraph_core::deform::is_geometry_state(h, i)
                        && s.params.contains_key(lumigraph_core::deform::PARAM_KEY)
                })
                .map(|(_, s)| s.name.clone())
                .collect(),
            animation: lumigraph_core::deform::AnimationInfo::of(h).map(|a| AnimationSummary {
                name: a.name,
                frames: a.states.len(),
                fps: a.fps,
                duration: a.duration,
            }),
            center: h.frame.center,
            radius: h.frame.radius,
            file_bytes: self.file_bytes,
            gpu_bytes: self.field.gpu_bytes(),
            planes: h.two_plane().copied(),
            page_cache: match &self.field {
                AssetField::Paged(f) => Some(f.summary.clone()),
                _ => None,
            },
        }
    }
}

/// Why a file could not be loaded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LoadError {
    /// The file is not a valid asset.
    #[error(transparent)]
    Asset(#[from] lumigraph_core::asset::AssetError),
    /// The asset could not be uploaded to the GPU.
    #[error(transparent)]
    Render(#[from] lumigraph_core::render::RenderError),
    /// The asset is valid but larger than a limit of the service.
    #[error("{0}")]
    OverLimit(String),
    /// The asset fits the limits, but the server's memory budget is taken by frames in flight
    /// and other loads now: retry shortly.
    #[error("{0}")]
    Busy(String),
}

/// `1234 bytes (1.2 KiB)`.
pub fn describe_bytes(bytes: u64) -> String {
    const UNITS: [&str; 6] = ["KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    let mut value = bytes as f64;
    let mut unit = "";
    for next in UNITS {
        if value < 1024.0 {
            break;
        }
        value /= 1024.0;
        unit = next;
    }
    if unit.is_empty() {
        format!("{bytes} bytes")
    } else {
        format!("{bytes} bytes ({value:.1} {unit})")
    }
}

/// Opens one file, checks it against the store's limits, then fully verifies and uploads it
/// (blocking: call from `spawn_blocking`). The limits are checked from the header alone, before
/// any page is decoded.
pub fn load_file(
    store: &AssetStore,
    engine: &Engine,
    id: &str,
    path: &Path,
) -> Result<LoadedAsset, LoadError> {
    let file = Arc::new(AssetFile::open(path)?);
    let (field, charge) = if let Some((config, layout)) = store.paging(file.header(), engine)? {
        let charge = store.admit_paged(file.header(), &layout)?;
        (open_paged(engine, id, &file, config)?, charge)
    } else {
        let charge = store.admit(file.header())?;
        file.verify_all()?;
        let field = if file.header().two_plane().is_some() {
            AssetField::TwoPlane(engine.two_plane.upload(&file)?)
        } else {
            AssetField::Spherical(engine.renderer.upload(&file)?)
        };
        (field, charge)
    };
    Ok(LoadedAsset {
        id: id.to_owned(),
        path: path.to_path_buf(),
        header: file.header().clone(),
        file_bytes: file.file_len(),
        content_id: content_id(&file),
        field,
        _charge: charge,
    })
}

/// Opens `file`'s page cache of `config` on `engine`'s device (reading, and so checking, every
/// page once for the coarse level).
fn open_paged(
    engine: &Engine,
    id: &str,
    file: &Arc<AssetFile>,
    config: CacheConfig,
) -> Result<AssetField, LoadError> {
    let cache = PagedTwoPlane::open(&engine.two_plane, Arc::clone(file), config)?;
    tracing::info!(
        asset = id,
        "paged: {} slots of {}² px for {} pages; {} on the device for {} resident; {} page \
         levels above the full resolution ({} in a temporary file)",
        cache.slots,
        cache.grid.page_size,
        cache.grid.total(),
        describe_bytes(cache.bytes),
        describe_bytes(cache.full_bytes),
        cache.grid.levels - 1,
        describe_bytes(cache.level_file_bytes())
    );
    let summary = CacheSummary {
        prefetch: config.prefetch.to_string(),
        pages_per_frame: config.pages_per_frame,
        device_bytes: cache.bytes,
        resident_bytes: cache.full_bytes,
        slots: cache.slots,
        pages: cache.grid.total(),
        page_size: cache.grid.page_size,
        coarse_factor: cache.coarse_factor,
        page_levels: cache.grid.levels - 1,
        level_pages: cache.grid.all_pages() - cache.grid.total(),
        level_file_bytes: cache.level_file_bytes(),
    };
    Ok(AssetField::Paged(Box::new(PagedField {
        gpu: Arc::clone(engine.gpu()),
        summary,
        cache: Mutex::new(cache),
    })))
}

/// A fingerprint of an asset file's content, from what the file already checksums: SHA-256 of
/// its preamble (with the header's and the index's CRC-32), its length, its header and every
/// index entry (each page's place, sizes and CRC-32). Hashing the page bytes themselves would
/// read the whole file again; every page was just verified against its entry.
pub fn content_id(file: &AssetFile) -> String {
    let header = serde_json::to_vec(file.header()).unwrap_or_default();
    let mut bytes = Vec::with_capacity(96 + header.len() + file.index().len() * 40);
    bytes.extend_from_slice(&file.preamble().to_bytes());
    bytes.extend_from_slice(&file.file_len().to_le_bytes());
    bytes.extend_from_slice(&header);
    for entry in file.index() {
        bytes.extend_from_slice(&entry.key.layer.to_le_bytes());
        bytes.extend_from_slice(&entry.key.state.to_le_bytes());
        bytes.extend_from_slice(&entry.key.camera.to_le_bytes());
        bytes.push(entry.key.channel.code());
        bytes.extend_from_slice(&entry.page.to_le_bytes());
        bytes.push(entry.codec.code());
        bytes.extend_from_slice(&entry.offset.to_le_bytes());
        bytes.extend_from_slice(&entry.length.to_le_bytes());
        bytes.extend_from_slice(&entry.raw_length.to_le_bytes());
        bytes.extend_from_slice(&entry.crc32.to_le_bytes());
    }
    lumigraph_core::bake::sha256_hex(&bytes)
}

/// The loaded assets, by id.
pub struct AssetStore {
    dir: PathBuf,
    limits: AssetLimits,
    /// The server's budget, which every asset's texture bytes are charged to as well.
    budget: Arc<MemoryBudget>,
    /// Texture bytes of the assets alive (loaded, or deleted but still held by a render or a
    /// stream) plus those being loaded.
    charged: Arc<AtomicU64>,
    assets: RwLock<BTreeMap<String, Arc<LoadedAsset>>>,
    /// Ids taken out to be uploaded again to a new device ([`Self::take_all`]).
    reloading: Mutex<HashSet<String>>,
    /// Their files, which stay in use until [`Self::end_reload`].
    reloading_paths: Mutex<Vec<PathBuf>>,
    /// Ids an upload or bake is writing right now.
    reserved: Arc<Mutex<HashSet<String>>>,
}

/// A claim on a new asset id, released on drop.
pub struct Reservation {
    id: String,
    reserved: Arc<Mutex<HashSet<String>>>,
}

impl Reservation {
    /// The reserved id.
    pub fn id(&self) -> &str {
        &self.id
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        self.reserved
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .remove(&self.id);
    }
}

impl AssetStore {
    /// An empty store over `dir`, charging loaded assets to `budget` as well as to its own
    /// asset memory budget.
    pub fn new(dir: PathBuf, limits: AssetLimits, budget: Arc<MemoryBudget>) -> Self {
        Self {
            dir,
            limits,
            budget,
            charged: Arc::default(),
            assets: RwLock::new(BTreeMap::new()),
            reloading: Mutex::default(),
            reloading_paths: Mutex::default(),
            reserved: Arc::default(),
        }
    }

    /// Claims `id` for a new asset: 409 if an asset, a file or another upload already has it.
    pub fn reserve(&self, id: &str) -> Result<Reservation, AppError> {
        validate_id(id)?;
        let mut reserved = self.reserved.lock().unwrap_or_else(PoisonError::into_inner);
        if self.contains(id) || reserved.contains(id) || self.path_for(id).exists() {
            return Err(AppError::Conflict(format!(
                "asset id {id:?} is taken: delete it first or choose another id"
            )));
        }
        reserved.insert(id.to_owned());
        Ok(Reservation {
            id: id.to_owned(),
            reserved: Arc::clone(&self.reserved),
        })
    }

    /// The store's limits.
    pub fn limits(&self) -> AssetLimits {
        self.limits
    }

    /// Texture bytes charged to the memory budget now.
    pub fn charged_bytes(&self) -> u64 {
        self.charged.load(Ordering::Acquire)
    }

    /// Checks an asset's header against the limits and charges its texture bytes to the memory
    /// budget, or says which limit it exceeds.
    ///
    /// # Errors
    /// [`LoadError::OverLimit`] naming the limit and the asset's size.
    pub fn admit(&self, header: &AssetHeader) -> Result<MemoryCharge, LoadError> {
        let decoded = header.decoded_bytes();
        let max_decoded = self.limits.max_decoded_bytes;
        if decoded > max_decoded {
            let [width, height] = header.image_size();
            return Err(LoadError::OverLimit(format!(
                "the asset decodes to {} ({} cameras × {width}×{height} px × {} layers × {} \
                 states), above the limit of {} per asset (--max-asset-decoded-bytes)",
                describe_bytes(decoded),
                header.camera_count(),
                header.layers.len(),
                header.states.len(),
                describe_bytes(max_decoded),
            )));
        }
        self.charge(field_bytes(header))
    }

    /// Whether `header`'s asset is rendered through the page cache, and the cache's config and
    /// layout on `engine`'s device: a two-plane light field whose resident textures exceed the
    /// cache's budget, when the store has one.
    ///
    /// # Errors
    /// [`LoadError::Render`] for a budget that holds no page or a layout beyond the device.
    pub fn paging(
        &self,
        header: &AssetHeader,
        engine: &Engine,
    ) -> Result<Option<(CacheConfig, CacheLayout)>, LoadError> {
        let (Some(config), Some(planes)) = (self.limits.page_cache, header.two_plane()) else {
            return Ok(None);
        };
        let Some(budget) = config.budget_bytes else {
            return Ok(None);
        };
        if field_bytes(header) <= budget {
            return Ok(None);
        }
        let layout = CacheLayout::of(planes, header.page_size, &config, engine.gpu())?;
        Ok(Some((config, layout)))
    }

    /// [`Self::admit`] for an asset rendered through a page cache of `layout`: the host holds
    /// one camera's pages at a time (checked against the decode limit), the device the cache.
    ///
    /// # Errors
    /// As [`Self::admit`].
    pub fn admit_paged(
        &self,
        header: &AssetHeader,
        layout: &CacheLayout,
    ) -> Result<MemoryCharge, LoadError> {
        let [width, height] = header.image_size();
        // RGBA8 colour and f32 depth of one camera.
        let camera = u64::from(width) * u64::from(height) * 8;
        if camera > self.limits.max_decoded_bytes {
            return Err(LoadError::OverLimit(format!(
                "one camera of the asset decodes to {} ({width}×{height} px), above the limit of \
                 {} per asset (--max-asset-decoded-bytes)",
                describe_bytes(camera),
                describe_bytes(self.limits.max_decoded_bytes),
            )));
        }
        self.charge(layout.bytes)
    }

    /// Charges `bytes` of textures to the asset and server memory budgets.
    fn charge(&self, bytes: u64) -> Result<MemoryCharge, LoadError> {
        let budget = self.limits.memory_budget;
        let mut charged = self.charged.load(Ordering::Acquire);
        loop {
            let total = charged.saturating_add(bytes);
            if total > budget {
                return Err(LoadError::OverLimit(format!(
                    "the asset needs {} of GPU memory, but {} of the asset memory budget of {} \
                     (--asset-memory-budget) are taken: delete an asset or raise the budget",
                    describe_bytes(bytes),
                    describe_bytes(charged),
                    describe_bytes(budget),
                )));
            }
            match self.charged.compare_exchange_weak(
                charged,
                total,
                Ordering::AcqRel,
                Ordering::Acquire,
            ) {
                Ok(_) => break,
                Err(now) => charged = now,
            }
        }
        // Checked after the asset budget, so that an asset that can never fit gets 413, not
        // a retry; the asset budget's share is given back when the server's is refused.
        let server = match self.budget.try_charge(bytes) {
            Ok(server) => server,
            Err(used) => {
                self.charged.fetch_sub(bytes, Ordering::AcqRel);
                return Err(LoadError::Busy(format!(
                    "the asset needs {}, but {} of the server's memory budget of {} are in use \
                     by assets and frames in flight: retry shortly",
                    describe_bytes(bytes),
                    describe_bytes(used),
                    describe_bytes(self.budget.total()),
                )));
            }
        };
        Ok(MemoryCharge {
            bytes,
            charged: Arc::clone(&self.charged),
            _server: server,
        })
    }

    /// The assets folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Where the asset `id` lives (the id must be valid).
    pub fn path_for(&self, id: &str) -> PathBuf {
        self.dir.join(format!("{id}.lfa"))
    }

    /// The asset `id`, or 404.
    pub fn get(&self, id: &str) -> Result<Arc<LoadedAsset>, AppError> {
        validate_id(id)?;
        self.assets
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .get(id)
            .cloned()
            .ok_or_else(|| {
                if self.reloading().contains(id) {
                    AppError::Unavailable(format!(
                        "asset {id:?} is being uploaded again to a new GPU device; retry shortly"
                    ))
                } else {
                    AppError::NotFound(format!("no asset with id {id:?}"))
                }
            })
    }

    fn reloading(&self) -> std::sync::MutexGuard<'_, HashSet<String>> {
        self.reloading
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// Ends a reload that [`Self::take_all`] began: ids that did not come back are now simply
    /// unknown (404).
    pub fn end_reload(&self) {
        self.reloading().clear();
        self.reloading_paths
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clear();
    }

    /// The first asset in id order, if any.
    pub fn first(&self) -> Option<Arc<LoadedAsset>> {
        self.assets
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .values()
            .next()
            .cloned()
    }

    /// Whether `id` is loaded.
    pub fn contains(&self, id: &str) -> bool {
        self.assets
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .contains_key(id)
    }

    /// Summaries of every asset, in id order.
    pub fn list(&self) -> Vec<AssetSummary> {
        self.assets
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .values()
            .map(|a| a.summary())
            .collect()
    }

    /// The files in use: those of the loaded assets and of those being uploaded again to a new
    /// device.
    pub fn paths(&self) -> Vec<PathBuf> {
        let mut paths: Vec<PathBuf> = self
            .assets
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .values()
            .map(|a| a.path.clone())
            .collect();
        paths.extend(
            self.reloading_paths
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .iter()
                .cloned(),
        );
        paths
    }

    /// Number of loaded assets.
    pub fn len(&self) -> usize {
        self.assets
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .len()
    }

    /// Whether no asset is loaded.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Adds (or replaces) an asset.
    pub fn insert(&self, asset: LoadedAsset) {
        self.reloading().remove(&asset.id);
        self.assets
            .write()
            .unwrap_or_else(PoisonError::into_inner)
            .insert(asset.id.clone(), Arc::new(asset));
    }

    /// Empties the store, returning every asset's id and file (to load them again on a new
    /// device); renders holding them finish first.
    /// Until [`Self::end_reload`], asking for one of them gets 503 instead of 404.
    pub fn take_all(&self) -> Vec<(String, PathBuf)> {
        let mut assets = self.assets.write().unwrap_or_else(PoisonError::into_inner);
        let taken = std::mem::take(&mut *assets);
        self.reloading().extend(taken.keys().cloned());
        self.reloading_paths
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .extend(taken.values().map(|a| a.path.clone()));
        drop(assets);
        taken
            .into_values()
            .map(|asset| (asset.id.clone(), asset.path.clone()))
            .collect()
    }

    /// Removes an asset from the store; renders holding it finish first.
    pub fn remove(&self, id: &str) -> Option<Arc<LoadedAsset>> {
        self.assets
            .write()
            .unwrap_or_else(PoisonError::into_inner)
            .remove(id)
    }

    /// Deletes the temporary files an upload (`.upload-*.part`) or an atomic write of an asset
    /// (`.ID.lfa.tmp-*`) leaves behind when the server is killed mid-write, logging each; returns
    /// how many were removed. Call at start-up only: a folder is served by one server, and a
    /// running server's files of the same names are writes in progress.
    ///
    /// # Errors
    /// The folder cannot be listed.
    pub fn remove_leftovers(&self) -> std::io::Result<usize> {
        let mut removed = 0;
        for entry in std::fs::read_dir(&self.dir)? {
            let entry = entry?;
            let name = entry.file_name();
            let Some(name) = name.to_str() else {
                continue;
            };
            if !is_leftover_name(name) || !entry.file_type()?.is_file() {
                continue;
            }
            let path = entry.path();
            match std::fs::remove_file(&path) {
                Ok(()) => {
                    tracing::warn!(path = %path.display(), "removed a temporary file left by an interrupted upload or bake");
                    removed += 1;
                }
                Err(err) => {
                    tracing::warn!(path = %path.display(), error = %err, "cannot remove a leftover temporary file");
                }
            }
        }
        Ok(removed)
    }

    /// `(id, path)` of every `*.lfa` file in the folder whose stem is a valid id, sorted.
    pub fn scan(&self) -> std::io::Result<Vec<(String, PathBuf)>> {
        let mut found = Vec::new();
        for entry in std::fs::read_dir(&self.dir)? {
            let path = entry?.path();
            if path.extension().and_then(|e| e.to_str()) != Some("lfa") || !path.is_file() {
                continue;
            }
            let Some(stem) = path.file_stem().and_then(|s| s.to_str()) else {
                continue;
            };
            if validate_id(stem).is_ok() {
                found.push((stem.to_owned(), path));
            } else {
                tracing::warn!(path = %path.display(), "skipping asset file: its name is not a valid id");
            }
        }
        found.sort();
        Ok(found)
    }
}

/// Prefix and suffix of the hidden temporary file an upload streams into.
const UPLOAD_TEMP: (&str, &str) = (".upload-", ".part");

/// The hidden temporary file an upload streams into before it is verified and renamed.
pub fn upload_temp_name(tag: &str) -> String {
    format!("{}{tag}{}", UPLOAD_TEMP.0, UPLOAD_TEMP.1)
}

/// Whether `name` is one of the temporary names the server writes: [`upload_temp_name`]
/// (uploads) or an atomic write of an asset ([`lumigraph_core::temp_target`] ending `.lfa`).
fn is_leftover_name(name: &str) -> bool {
    // Exactly the names the server writes, so the comparison is case-sensitive.
    let upload = name
        .strip_prefix(UPLOAD_TEMP.0)
        .and_then(|rest| rest.strip_suffix(UPLOAD_TEMP.1))
        .is_some();
    let atomic = lumigraph_core::temp_target(name)
        .is_some_and(|target| Path::new(target).extension().is_some_and(|e| e == "lfa"));
    upload || atomic
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leftover_names_are_the_temporary_names_only() {
        for leftover in [
            ".upload-tmp-3f9c0a12b4d5e6f7.part",
            ".demo.lfa.tmp-1234-0",
            ".mesh-00ff.lfa.tmp-99-17",
        ] {
            assert!(is_leftover_name(leftover), "{leftover}");
        }
        for kept in [
            "demo.lfa",
            "upload-x.part",
            ".upload-x.lfa",
            ".lfa.tmp-1-0",
            "notes.txt",
            ".hidden",
        ] {
            assert!(!is_leftover_name(kept), "{kept}");
        }
    }

    #[test]
    fn ids_cannot_escape_the_folder() {
        for bad in [
            "", "..", "../x", "a/b", "a\\b", ".hidden", "-x", "a.lfa", "a b", "ä", "%2e%2e",
        ] {
            assert!(validate_id(bad).is_err(), "{bad:?}");
        }
        assert!(validate_id(&"a".repeat(65)).is_err());
        for good in ["demo", "a", "A_1-b", &"a".repeat(64)] {
            assert!(validate_id(good).is_ok(), "{good:?}");
        }
    }
}
