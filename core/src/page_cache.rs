//! Two-plane light fields larger than device memory (seed 003): a paged GPU cache with an index
//! table, pages read from the `.lfa` on demand, a coarse level that no frame goes without, and
//! three policies (on demand, LRU, and the seed's probability-based prefetch by dead reckoning).
//! docs/two_plane.md "Paged rendering" is the user's account.
//!
//! - **Pages** are the asset's own pages (DESIGN §5: P × P texels, random access in the file):
//!   page `id = camera · pages_per_image + row · pages_x + column`.
//! - **Slots**: the cache is a fixed number of P × P tiles in texture-array layers (RGBA8 colour
//!   and R32F depth); the index table (`page → slot`, or not resident) is a storage buffer the
//!   shader reads (`shaders/two_plane_paged.wgsl`).
//! - **Coarse level**: every camera downsampled F× (mean colour, nearest depth), built by one
//!   pass over the file when the cache opens and always resident; a texel of a page that is not
//!   resident reads it, and the pixel counts as degraded.
//! - **Which pages a frame needs**: [`needed_pages`] projects the view's rays through the focal
//!   plane (or the depth range the depth-corrected filter marches) into every camera the filter
//!   or aperture reads, before the frame; the shader's feedback (every page it touched) counts
//!   the faults after it, exactly.
//! - **Per frame** ([`PagedTwoPlane::render`]): the pages needed and not resident are loaded
//!   first, then (policy `predict`) the most probable pages of the next frames, at most
//!   `pages_per_frame` pages in all; the frame renders; a fault is a page the frame touched that
//!   was not resident when it started. [`PagedTwoPlane::render_nowait`] makes the same plan but
//!   hands the reads to a reader thread and renders at once: the pages are uploaded by the first
//!   frame after they arrive.

use std::collections::{BTreeSet, HashMap, VecDeque};
use std::sync::Arc;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::asset::{AssetError, AssetFile, Channel, ImageKey};
use crate::frame::Frame;
use crate::gpu::{Gpu, empty_texture_array};
use crate::render::RenderError;
use crate::two_plane::TwoPlanes;
use crate::two_plane_render::{
    MAX_APERTURE, PagedBinding, Source, TwoPlaneOptions, TwoPlaneRenderer, UvFilter, march_heights,
};
use crate::view::{DEFAULT_MAX_VIEW_PX, View};

/// Index-table value of a page that is not resident.
const NOT_RESIDENT: u32 = u32::MAX;
/// Bytes per texel of a slot: RGBA8 colour and R32F depth.
const SLOT_TEXEL_BYTES: u64 = 8;
/// Default pages loaded per frame (`--pages-per-frame`).
pub const DEFAULT_PAGES_PER_FRAME: u32 = 64;
/// Pixel stride of the rays [`needed_pages`] projects (the pages between them are covered by
/// the hull of each 2×2 group of rays).
pub const NEEDS_STRIDE: u32 = 8;
/// Relative margin on a group of rays' footprints when choosing its page levels
/// ([`needed_pages`]).
const LEVEL_MARGIN: f64 = 0.03;
/// Frames ahead the predictive policy looks (the estimate one frame ahead, and further along
/// the motion with falling probability).
pub const PREDICT_FRAMES: u32 = 3;

/// Which pages the cache loads and evicts (`--prefetch`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", try_from = "String")]
pub enum Prefetch {
    /// On demand: the pages a frame needs, evicting the page loaded longest ago (FIFO).
    None,
    /// On demand, evicting the least recently used page.
    #[default]
    Lru,
    /// Seed 003: on demand, then the pages of the dead-reckoned next frames by probability,
    /// evicting the least probable (least recently used among equals).
    Predict,
}

impl Prefetch {
    /// Every policy, in the order of the tables.
    pub const ALL: [Prefetch; 3] = [Prefetch::None, Prefetch::Lru, Prefetch::Predict];

    /// The name used by the CLI.
    pub fn name(self) -> &'static str {
        match self {
            Prefetch::None => "none",
            Prefetch::Lru => "lru",
            Prefetch::Predict => "predict",
        }
    }
}

impl std::fmt::Display for Prefetch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Prefetch {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Prefetch::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| format!("prefetch {s:?}: choose none, lru or predict"))
    }
}

impl TryFrom<String> for Prefetch {
    type Error = String;

    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

/// How big the cache is and how it is filled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CacheConfig {
    /// Device bytes for the slots and the coarse level; `None`: every page resident (the
    /// reference the cached frames are compared with).
    pub budget_bytes: Option<u64>,
    /// Policy.
    pub prefetch: Prefetch,
    /// Most pages loaded per frame.
    pub pages_per_frame: u32,
    /// Pixels that span the coarse factor F or more st texels read the coarse level (bilinear)
    /// and need no page: a zoomed-out view loads nothing. Off, they read the pages as every
    /// other pixel does (what the fully resident renderer shows).
    pub overview: bool,
}

impl CacheConfig {
    /// A cache of `mib` MiB.
    pub fn with_mib(mib: f64, prefetch: Prefetch, pages_per_frame: u32) -> CacheConfig {
        CacheConfig {
            budget_bytes: Some((mib.max(0.0) * 1024.0 * 1024.0) as u64),
            prefetch,
            pages_per_frame,
            overview: true,
        }
    }

    /// Every page resident.
    pub fn whole() -> CacheConfig {
        CacheConfig {
            budget_bytes: None,
            prefetch: Prefetch::None,
            pages_per_frame: u32::MAX,
            overview: false,
        }
    }
}

/// How the camera images are cut into pages, at every page level: level 0 is the asset's own
/// pages; level `l ≥ 1` (a cache with intermediate levels, [`CacheLayout::of`]) is every camera
/// downsampled 2^l× (mean colour, nearest depth of each 2^l × 2^l block) cut into pages of the
/// same side P, numbered after the previous level's pages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PageGrid {
    /// Page side P: the asset's, or the image's own power-of-two size when one page holds it.
    pub page_size: u32,
    /// Pages per image row and column.
    pub pages: [u32; 2],
    /// Cameras.
    pub cameras: u32,
    /// Image size (the st resolution).
    pub res: [u32; 2],
    /// Page levels, level 0 included (1: the asset's pages only).
    pub levels: u32,
}

/// Most page levels a cache has (level 0 included): the shader's table of levels.
pub const MAX_PAGE_LEVELS: u32 = 8;

impl PageGrid {
    /// The grid of `planes` cut into pages of `page_size`, level 0 only.
    pub fn new(planes: &TwoPlanes, page_size: u32) -> PageGrid {
        let res = planes.st.resolution;
        // An image within one page is one page of its own (power-of-two) size: a slot that size
        // holds it, and the shader's page arithmetic finds page 0 either way.
        let page_size = page_size.min(res[0].max(res[1]).next_power_of_two());
        PageGrid {
            page_size,
            pages: res.map(|n| n.div_ceil(page_size)),
            cameras: planes.camera_count(),
            res,
            levels: 1,
        }
    }

    /// The same grid with `levels` page levels (clamped to 1..=[`MAX_PAGE_LEVELS`]).
    #[must_use]
    pub fn with_levels(self, levels: u32) -> PageGrid {
        PageGrid {
            levels: levels.clamp(1, MAX_PAGE_LEVELS),
            ..self
        }
    }

    /// Pages per camera image (level 0).
    pub fn per_image(&self) -> u32 {
        self.pages[0] * self.pages[1]
    }

    /// The asset's pages (level 0).
    pub fn total(&self) -> u32 {
        self.per_image() * self.cameras
    }

    /// Image size at level `level`.
    pub fn level_res(&self, level: u32) -> [u32; 2] {
        self.res.map(|n| n.div_ceil(1 << level))
    }

    /// Pages per image row and column at level `level`.
    pub fn level_pages(&self, level: u32) -> [u32; 2] {
        self.level_res(level).map(|n| n.div_ceil(self.page_size))
    }

    /// Pages per camera image at level `level`.
    pub fn level_per_image(&self, level: u32) -> u32 {
        let [x, y] = self.level_pages(level);
        x * y
    }

    /// The id of level `level`'s first page.
    pub fn level_first(&self, level: u32) -> u32 {
        (0..level)
            .map(|l| self.level_per_image(l) * self.cameras)
            .sum()
    }

    /// Pages of every level.
    pub fn all_pages(&self) -> u32 {
        self.level_first(self.levels)
    }

    /// The id of page `(column, row)` of camera `camera`'s image at level `level`.
    pub fn id(&self, level: u32, camera: u32, column: u32, row: u32) -> u32 {
        self.level_first(level)
            + camera * self.level_per_image(level)
            + row * self.level_pages(level)[0]
            + column
    }

    /// The level, the camera and the page number within its image (DESIGN §5 at level 0) of
    /// page `id` (of any level).
    pub fn locate(&self, id: u32) -> (u32, u32, u32) {
        let mut first = 0;
        for level in 0..self.levels {
            let per_image = self.level_per_image(level);
            let count = per_image * self.cameras;
            if id < first + count || level + 1 == self.levels {
                let k = id - first;
                return (level, k / per_image, k % per_image);
            }
            first += count;
        }
        (0, 0, 0)
    }

    /// The camera and the page number within its image (DESIGN §5) of level-0 page `id`.
    pub fn split(&self, id: u32) -> (u32, u32) {
        (id / self.per_image(), id % self.per_image())
    }

    /// Texel rectangle `(x, y, width, height)` of page `page` of a level-0 image.
    pub fn rect(&self, page: u32) -> (u32, u32, u32, u32) {
        self.level_rect(0, page)
    }

    /// Texel rectangle `(x, y, width, height)` of page `page` of a level-`level` image.
    pub fn level_rect(&self, level: u32, page: u32) -> (u32, u32, u32, u32) {
        let p = self.page_size;
        let res = self.level_res(level);
        let columns = self.level_pages(level)[0];
        let (x, y) = ((page % columns) * p, (page / columns) * p);
        (x, y, p.min(res[0] - x), p.min(res[1] - y))
    }
}

/// What a frame through the cache did (one entry of `--report`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PageFrameStats {
    /// Pages the frame touched that were not resident when it started.
    pub faults: u32,
    /// Pixels that read at least one texel from the coarse level for want of a page.
    pub degraded_px: u64,
    /// Pixels that span 2 or more st texels and read a downsampled level by choice (overview,
    /// [`CacheConfig::overview`]: a page level below the coarse factor F, the coarse level and
    /// no page from F on).
    #[serde(default)]
    pub overview_px: u64,
    /// Pages loaded for this frame (needed ones first, then prefetched ones).
    pub pages_loaded: u32,
    /// Bytes those pages uploaded to the device (colour and depth).
    #[serde(default)]
    pub bytes_uploaded: u64,
    /// Pages still being read in the background after the frame
    /// ([`PagedTwoPlane::render_nowait`]).
    #[serde(default)]
    pub pages_pending: u32,
    /// Wall time of the frame: planning, page reads and uploads, render and feedback.
    pub ms: f64,
    /// Pages the frame touched (the shader's feedback).
    pub pages_touched: u32,
    /// Pages [`needed_pages`] projected for the frame.
    pub pages_projected: u32,
    /// Touched pages the projection missed.
    pub projection_missed: u32,
    /// Resident pages after the frame's loads.
    pub resident: u32,
    /// Time spent reading and decoding pages, ms.
    pub load_ms: f64,
    /// Time spent planning, ms: projecting the view onto the pages (and, with the predictive
    /// policy, the predicted views, on threads beside it) and choosing loads and evictions.
    #[serde(default)]
    pub plan_ms: f64,
    /// Pages that could not be read (the frame is degraded there), with the reason.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub read_errors: Vec<String>,
    /// Per pixel (row-major): whether it is degraded.
    #[serde(skip)]
    pub degraded_mask: Vec<bool>,
    /// Per pixel (row-major): whether it is an overview pixel.
    #[serde(skip)]
    pub overview_mask: Vec<bool>,
}

impl PageFrameStats {
    /// Adds the stats of another draw of the same frame (an accumulated aperture): counts and
    /// times add up, a pixel is degraded where any draw degraded it.
    pub fn merge(&mut self, other: PageFrameStats) {
        self.faults += other.faults;
        self.pages_loaded += other.pages_loaded;
        self.bytes_uploaded += other.bytes_uploaded;
        self.pages_pending = other.pages_pending;
        self.ms += other.ms;
        self.load_ms += other.load_ms;
        self.plan_ms += other.plan_ms;
        self.pages_touched = self.pages_touched.max(other.pages_touched);
        self.pages_projected = self.pages_projected.max(other.pages_projected);
        self.projection_missed += other.projection_missed;
        self.resident = other.resident;
        self.read_errors.extend(other.read_errors);
        if self.degraded_mask.len() == other.degraded_mask.len() {
            for (a, b) in self.degraded_mask.iter_mut().zip(other.degraded_mask) {
                *a |= b;
            }
            self.degraded_px = self.degraded_mask.iter().filter(|&&d| d).count() as u64;
        } else {
            self.degraded_px = self.degraded_px.max(other.degraded_px);
        }
        // Every draw of a frame has the same overview pixels (the footprint depends on the
        // view alone), so the first draw's count and mask stand.
    }
}

/// Totals of a run of frames.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PageSummary {
    /// Frames.
    pub frames: u32,
    /// Sum of faults.
    pub faults: u64,
    /// Sum of degraded pixels.
    pub degraded_px: u64,
    /// Sum of overview pixels.
    #[serde(default)]
    pub overview_px: u64,
    /// Sum of pages loaded.
    pub pages_loaded: u64,
    /// Sum of bytes uploaded.
    #[serde(default)]
    pub bytes_uploaded: u64,
    /// Mean and largest frame time, ms.
    pub mean_ms: f64,
    /// Largest frame time, ms.
    pub max_ms: f64,
    /// Touched pages the projection missed, in all.
    pub projection_missed: u64,
}

impl PageSummary {
    /// Adds one frame to the totals.
    pub fn add(&mut self, frame: &PageFrameStats) {
        let n = f64::from(self.frames);
        self.mean_ms = (self.mean_ms * n + frame.ms) / (n + 1.0);
        self.frames += 1;
        self.faults += u64::from(frame.faults);
        self.degraded_px += frame.degraded_px;
        self.overview_px += frame.overview_px;
        self.pages_loaded += u64::from(frame.pages_loaded);
        self.bytes_uploaded += frame.bytes_uploaded;
        self.max_ms = self.max_ms.max(frame.ms);
        self.projection_missed += u64::from(frame.projection_missed);
    }

    /// The totals of `frames`.
    pub fn of(frames: &[PageFrameStats]) -> PageSummary {
        let mut summary = PageSummary::default();
        for frame in frames {
            summary.add(frame);
        }
        summary
    }
}

/// What [`needed_pages`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct Projection {
    /// The pages, sorted.
    pub pages: Vec<u32>,
    /// The largest st footprint of the projected rays (0 without `overview`): the frame's
    /// pixels span about this many st texels at most (the footprint grows towards the frame's
    /// edges, which the rays include).
    pub max_footprint: f64,
}

/// The pages of `grid` that rendering `view` of `planes` with `options` reads (stored depths in
/// `depth_range`), sorted: every `stride`-th pixel's ray (and the last row and column) is
/// projected, through the focal plane (or the heights the depth-corrected filter marches), into
/// every camera the uv filter or aperture reads; each 2×2 group of rays covers the hull of its
/// projections (a texel wider for the bilinear footprint). With `overview` (the coarse factor
/// F of a cache whose [`CacheConfig::overview`] is on), a group whose rays all span F or more
/// st texels needs no page, and with page levels ([`PageGrid::levels`]) a group's pixels that
/// span 2^l to 2^(l+1) texels need level `l`'s pages (each level within 3 % of a group's
/// footprints: the pixels between its rays differ a little).
///
/// # Errors
/// [`RenderError::View`] for an invalid view.
pub fn needed_pages(
    planes: &TwoPlanes,
    grid: &PageGrid,
    depth_range: [f32; 2],
    view: &View,
    options: &TwoPlaneOptions,
    stride: u32,
    overview: Option<u32>,
) -> Result<Projection, RenderError> {
    /// A projected ray: its uv cell and its points at each height.
    struct Ray {
        cell: [f64; 2],
        points: Vec<DVec3>,
        inside: bool,
        /// St texels the pixel spans (0 without `overview`).
        footprint: f64,
    }
    let basis = view.basis(DEFAULT_MAX_VIEW_PX)?;
    // Tiny views sample finer: a light field smaller than a group of rays would slip between.
    let stride = stride.clamp(1, (basis.width.min(basis.height) / 4).max(1));
    let origin = DVec3::from(planes.st.center);
    let (right, up) = planes.axes();
    let normal = planes.normal();
    let sep = planes.separation();
    let uv_center = DVec3::from(planes.uv.center) - origin;
    let [uw, uh] = planes.uv.size;
    let [sw, sh] = planes.st.size;
    let g = planes.uv.grid.map(f64::from);
    let res = grid.res.map(f64::from);
    let o = basis.eye - origin;
    let (h_hi, h_lo) = march_heights(sep, depth_range);
    let aperture = options.aperture > 0.0;
    let heights: Vec<f64> = if !aperture && options.uv_filter == UvFilter::Depth {
        vec![h_hi, h_lo, options.focus]
    } else {
        vec![options.focus]
    };
    // Camera position relative to st's centre.
    let camera = |a: u32, b: u32| {
        let x = (f64::from(a) + 0.5) / g[0] - 0.5;
        let y = 0.5 - (f64::from(b) + 0.5) / g[1];
        uv_center + x * uw * right + y * uh * up
    };
    // Continuous texel coordinates where camera `c` reads point `q`.
    let lookup = |c: DVec3, q: DVec3| -> Option<[f64; 2]> {
        let towards = q - c;
        let along = towards.dot(normal);
        if !(along < 0.0) {
            return None;
        }
        let s = c - sep / along * towards;
        Some([
            (s.dot(right) / sw + 0.5) * res[0] - 0.5,
            (0.5 - s.dot(up) / sh) * res[1] - 0.5,
        ])
    };
    let eh = o.dot(normal);
    // The st texels pixel (i, j) spans, as the shader's `st_footprint` measures them, from
    // `ps`, where its ray meets st.
    let footprint_from = |ps: DVec3, i: u32, j: u32| {
        let span = |n: DVec3| {
            let along = n.dot(normal);
            if !(along < 0.0) {
                return f64::INFINITY;
            }
            let delta = o - eh / along * n - ps;
            (delta.dot(right) / sw * res[0]).hypot(delta.dot(up) / sh * res[1])
        };
        span(basis.pixel_dir(i, j + 1)).max(span(basis.pixel_dir(i + 1, j)))
    };
    let footprint = |i: u32, j: u32| {
        let d = basis.pixel_dir(i, j);
        footprint_from(o - eh / d.dot(normal) * d, i, j)
    };
    // The (row, column) where the eye's foot on st (the st point nearest the eye) is seen,
    // where it is in front of the eye (the pixel of smallest footprint).
    let foot = {
        let d = -o.dot(normal) * normal;
        let ahead = d.dot(basis.forward);
        (ahead > 0.0).then(|| {
            (
                f64::from(basis.height) / 2.0 - 0.5 - d.dot(basis.true_up) / ahead * basis.focal_px,
                f64::from(basis.width) / 2.0 - 0.5 + d.dot(basis.right) / ahead * basis.focal_px,
            )
        })
    };
    // The rays on the stride grid: their uv cell and their points at each height.
    let xs: Vec<u32> = (0..basis.width)
        .step_by(stride as usize)
        .chain(std::iter::once(basis.width - 1))
        .collect();
    let ys: Vec<u32> = (0..basis.height)
        .step_by(stride as usize)
        .chain(std::iter::once(basis.height - 1))
        .collect();
    let mut rays: Vec<Option<Ray>> = Vec::with_capacity(xs.len() * ys.len());
    for &i in &ys {
        for &j in &xs {
            let d = basis.pixel_dir(i, j);
            let along = d.dot(normal);
            if !(along < 0.0) {
                rays.push(None);
                continue;
            }
            let t_uv = (sep - eh) / along;
            let t_st = -eh / along;
            let pu = o + t_uv * d - uv_center;
            let uv = [pu.dot(right) / uw + 0.5, 0.5 - pu.dot(up) / uh];
            // As `footprint`'s (the same rounding as the shader's).
            let ps = o - eh / along * d;
            let st = [ps.dot(right) / sw + 0.5, 0.5 - ps.dot(up) / sh];
            let inside =
                t_uv >= 0.0 && t_st > t_uv && uv.iter().chain(&st).all(|x| (0.0..=1.0).contains(x));
            let cell = [
                (uv[0] * g[0] - 0.5).clamp(0.0, g[0] - 1.0),
                (uv[1] * g[1] - 0.5).clamp(0.0, g[1] - 1.0),
            ];
            let points = heights.iter().map(|&h| o + (h - eh) / along * d).collect();
            rays.push(Some(Ray {
                cell,
                points,
                inside,
                footprint: if overview.is_some() {
                    footprint_from(ps, i, j)
                } else {
                    0.0
                },
            }));
        }
    }
    // The cameras a pixel with uv cell in [lo, hi] reads (per axis).
    let reach = if aperture {
        options.aperture + 0.5
    } else {
        match options.uv_filter {
            UvFilter::Dither => 0.5 * f64::from(options.dither_amplitude) + 1.0,
            _ => 1.0,
        }
    };
    let mut pages = BTreeSet::new();
    let nx = xs.len();
    let p = f64::from(grid.page_size);
    // The page level of a pixel spanning `fp` st texels (the shader's choice; level 0 below 2
    // texels and without levels, the last paged level at most).
    let level_of = |fp: f64| -> u32 {
        if grid.levels <= 1 || !(fp >= 2.0) {
            return 0;
        }
        (fp.log2().floor() as u32).min(grid.levels - 1)
    };
    for qy in 0..ys.len().saturating_sub(1) {
        for qx in 0..nx.saturating_sub(1) {
            let corners: Vec<&Ray> = [(qx, qy), (qx + 1, qy), (qx, qy + 1), (qx + 1, qy + 1)]
                .iter()
                .filter_map(|&(x, y)| rays[y * nx + x].as_ref())
                .collect();
            if !corners.iter().any(|r| r.inside) {
                continue;
            }
            // A group of overview rays needs no page when every pixel in it is overview. The
            // footprint grows away from the pixel nearest the eye's foot on st, so the corners
            // bound a group that does not hold that pixel; the group that does is measured
            // pixel by pixel.
            let holds_foot = foot.is_some_and(|(fi, fj)| {
                (f64::from(ys[qy])..=f64::from(ys[qy + 1])).contains(&fi)
                    && (f64::from(xs[qx])..=f64::from(xs[qx + 1])).contains(&fj)
            });
            // The page levels the group's pixels read: from its least footprint's to its
            // largest's.
            let (mut level_lo, mut level_hi) = (0, 0);
            if let Some(f) = overview.map(f64::from) {
                let mut least = corners.iter().map(|r| r.footprint).fold(f64::MAX, f64::min);
                if holds_foot {
                    for i in ys[qy]..=ys[qy + 1] {
                        for j in xs[qx]..=xs[qx + 1] {
                            least = least.min(footprint(i, j));
                        }
                    }
                }
                if corners.len() == 4 && least >= f {
                    continue;
                }
                let most = corners.iter().map(|r| r.footprint).fold(0.0, f64::max);
                level_lo = level_of(least * (1.0 - LEVEL_MARGIN));
                level_hi = level_of(most * (1.0 + LEVEL_MARGIN));
            }
            let mut lo = [f64::INFINITY; 2];
            let mut hi = [f64::NEG_INFINITY; 2];
            for r in &corners {
                for k in 0..2 {
                    lo[k] = lo[k].min(r.cell[k]);
                    hi[k] = hi[k].max(r.cell[k]);
                }
            }
            let a0 = (lo[0] - reach).ceil().max(0.0) as u32;
            let a1 = (hi[0] + reach).floor().min(g[0] - 1.0) as u32;
            let b0 = (lo[1] - reach).ceil().max(0.0) as u32;
            let b1 = (hi[1] + reach).floor().min(g[1] - 1.0) as u32;
            for b in b0..=b1 {
                for a in a0..=a1 {
                    let c = camera(a, b);
                    let mut jlo = [f64::INFINITY; 2];
                    let mut jhi = [f64::NEG_INFINITY; 2];
                    for r in &corners {
                        for &q in &r.points {
                            if let Some(ji) = lookup(c, q) {
                                for k in 0..2 {
                                    jlo[k] = jlo[k].min(ji[k]);
                                    jhi[k] = jhi[k].max(ji[k]);
                                }
                            }
                        }
                    }
                    if !(jlo[0] <= jhi[0] && jlo[1] <= jhi[1]) {
                        continue;
                    }
                    let cam = b * planes.uv.grid[0] + a;
                    for level in level_lo..=level_hi {
                        // Texels read: the bilinear and 2×2 depth footprints reach one texel
                        // past the lookup (depth at level l: the block holding the texel;
                        // colour: the level's own bilinear footprint); f32 on the device may
                        // round a hair either way.
                        let scale = f64::from(1u32 << level);
                        let level_res = grid.level_res(level).map(f64::from);
                        let range = |k: usize| {
                            let d0 = (jlo[k] - 0.01).floor().clamp(0.0, res[k] - 1.0);
                            let d1 = ((jhi[k] + 0.01).floor() + 1.0).clamp(0.0, res[k] - 1.0);
                            let c0 = ((jlo[k] + 0.5) / scale - 0.5 - 0.01).floor();
                            let c1 = ((jhi[k] + 0.5) / scale - 0.5 + 0.01).floor() + 1.0;
                            let t0 = (d0 / scale).floor().min(c0).clamp(0.0, level_res[k] - 1.0);
                            let t1 = (d1 / scale).floor().max(c1).clamp(0.0, level_res[k] - 1.0);
                            ((t0 / p) as u32, (t1 / p) as u32)
                        };
                        let (px0, px1) = range(0);
                        let (py0, py1) = range(1);
                        for py in py0..=py1 {
                            for px in px0..=px1 {
                                pages.insert(grid.id(level, cam, px, py));
                            }
                        }
                    }
                }
            }
        }
    }
    Ok(Projection {
        pages: pages.into_iter().collect(),
        max_footprint: rays
            .iter()
            .flatten()
            .map(|r| r.footprint)
            .fold(0.0, f64::max),
    })
}

/// The camera parameters dead reckoning extrapolates (seed 003: position, aperture, focus,
/// field of view; the viewing direction too).
#[derive(Clone, Debug, PartialEq)]
struct CameraState {
    eye: DVec3,
    forward: DVec3,
    distance: f64,
    up: [f64; 3],
    yfov: f64,
    focus: f64,
    aperture: f64,
    size: [u32; 2],
}

impl CameraState {
    fn of(view: &View, options: &TwoPlaneOptions) -> CameraState {
        let eye = DVec3::from(view.eye);
        let towards = DVec3::from(view.target) - eye;
        CameraState {
            eye,
            forward: towards.normalize_or_zero(),
            distance: towards.length(),
            up: view.up,
            yfov: view.yfov_deg,
            focus: options.focus,
            aperture: options.aperture,
            size: [view.width, view.height],
        }
    }

    fn view(&self) -> View {
        View {
            eye: self.eye.to_array(),
            target: (self.eye + self.forward * self.distance).to_array(),
            up: self.up,
            yfov_deg: self.yfov,
            width: self.size[0],
            height: self.size[1],
        }
    }
}

/// What projecting a view onto a paged light field's pages reads ([`needed_pages`]'s
/// arguments but the view's): shared by the frame's projection and the prediction's threads.
#[derive(Clone, Copy)]
struct Projector<'a> {
    planes: &'a TwoPlanes,
    grid: &'a PageGrid,
    depth_range: [f32; 2],
    overview: Option<u32>,
}

impl Projector<'_> {
    /// [`needed_pages`] of `view` with `options`, rays `stride` pixels apart.
    fn project(
        self,
        view: &View,
        options: &TwoPlaneOptions,
        stride: u32,
    ) -> Result<Projection, RenderError> {
        needed_pages(
            self.planes,
            self.grid,
            self.depth_range,
            view,
            options,
            stride,
            self.overview,
        )
    }

    /// Each page the predictive policy would prefetch after the frames in `history` (the
    /// last two count), with its probability: for each camera parameter that moved over them
    /// (and for all of them together), the pages of that parameter dead-reckoned 1, 2, …,
    /// [`PREDICT_FRAMES`] frames ahead with probability 1/k; a page's probability is the mean
    /// over the parameters (equal weights). The parameters that moved are projected on threads
    /// of their own; their probabilities add up in the parameters' order, as one thread would.
    fn predict(
        self,
        history: &VecDeque<CameraState>,
        options: &TwoPlaneOptions,
    ) -> (Vec<u32>, HashMap<u32, f32>) {
        let mut probability: HashMap<u32, f32> = HashMap::new();
        let (Some(now), Some(before)) = (history.back(), history.iter().rev().nth(1)) else {
            return (Vec::new(), probability);
        };
        let moved: Vec<Param> = Param::ALL
            .into_iter()
            .filter(|p| p.extrapolate(now, before, 1.0).is_some())
            .collect();
        let per_param: Vec<HashMap<u32, f32>> = std::thread::scope(|scope| {
            let threads: Vec<_> = moved
                .iter()
                .map(|&param| scope.spawn(move || self.predicted(param, now, before, options)))
                .collect();
            threads
                .into_iter()
                .map(|t| t.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
                .collect()
        });
        let weight = 1.0 / Param::ALL.len() as f32;
        for best in per_param {
            for (page, p) in best {
                *probability.entry(page).or_insert(0.0) += weight * p;
            }
        }
        let mut order: Vec<u32> = probability.keys().copied().collect();
        order.sort_by(|a, b| probability[b].total_cmp(&probability[a]).then(a.cmp(b)));
        (order, probability)
    }

    /// The pages of `param` dead-reckoned 1, 2, …, [`PREDICT_FRAMES`] frames ahead from
    /// `before` and `now`, each with its largest probability 1/k.
    fn predicted(
        self,
        param: Param,
        now: &CameraState,
        before: &CameraState,
        options: &TwoPlaneOptions,
    ) -> HashMap<u32, f32> {
        let mut best: HashMap<u32, f32> = HashMap::new();
        for k in 1..=PREDICT_FRAMES {
            let Some(state) = param.extrapolate(now, before, f64::from(k)) else {
                break;
            };
            let mut o = *options;
            o.focus = state.focus;
            o.aperture = state.aperture;
            // An extrapolated view may be invalid (a field of view past its range): nothing
            // to prefetch for it.
            let Ok(Projection { pages, .. }) = self.project(&state.view(), &o, 4 * NEEDS_STRIDE)
            else {
                continue;
            };
            let p = 1.0 / k as f32;
            for page in pages {
                let e = best.entry(page).or_insert(0.0);
                *e = e.max(p);
            }
        }
        best
    }
}

/// The parameters the predictive policy extrapolates one at a time (and all together).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Param {
    Position,
    Direction,
    FieldOfView,
    Focus,
    Aperture,
    All,
}

impl Param {
    const ALL: [Param; 6] = [
        Param::Position,
        Param::Direction,
        Param::FieldOfView,
        Param::Focus,
        Param::Aperture,
        Param::All,
    ];

    /// `now` with this parameter moved `k` frames further at the velocity `now − before`;
    /// `None` where it does not move.
    fn extrapolate(self, now: &CameraState, before: &CameraState, k: f64) -> Option<CameraState> {
        let mut s = now.clone();
        let moves = |a: f64, b: f64| (a - b).abs() > 1e-12 * (1.0 + a.abs());
        let position = |s: &mut CameraState| s.eye = now.eye + k * (now.eye - before.eye);
        let direction = |s: &mut CameraState| {
            s.forward =
                (now.forward + k * (now.forward - before.forward)).normalize_or(now.forward);
        };
        let fov = |s: &mut CameraState| {
            s.yfov = (now.yfov + k * (now.yfov - before.yfov)).clamp(0.5, 170.0);
        };
        let focus = |s: &mut CameraState| s.focus = now.focus + k * (now.focus - before.focus);
        let aperture = |s: &mut CameraState| {
            s.aperture =
                (now.aperture + k * (now.aperture - before.aperture)).clamp(0.0, MAX_APERTURE);
        };
        let moved = match self {
            Param::Position => {
                position(&mut s);
                now.eye.distance(before.eye) > 1e-12 * (1.0 + now.eye.length())
            }
            Param::Direction => {
                direction(&mut s);
                now.forward.distance(before.forward) > 1e-12
            }
            Param::FieldOfView => {
                fov(&mut s);
                moves(now.yfov, before.yfov)
            }
            Param::Focus => {
                focus(&mut s);
                moves(now.focus, before.focus)
            }
            Param::Aperture => {
                aperture(&mut s);
                moves(now.aperture, before.aperture)
            }
            Param::All => {
                position(&mut s);
                direction(&mut s);
                fov(&mut s);
                focus(&mut s);
                aperture(&mut s);
                s != *now
            }
        };
        moved.then_some(s)
    }
}

/// Where pages live and which to load or evict: the CPU half of the cache, testable without a
/// device.
#[derive(Clone, Debug)]
pub struct Residency {
    /// Page → slot, or [`NOT_RESIDENT`].
    table: Vec<u32>,
    /// Slot → page, or [`NOT_RESIDENT`].
    slot_page: Vec<u32>,
    /// Per page: the last frame that touched it (0: never).
    last_used: Vec<u32>,
    /// Per slot: the frame its page was loaded.
    loaded_at: Vec<u32>,
    policy: Prefetch,
}

impl Residency {
    /// An empty cache of `slots` slots for `pages` pages.
    pub fn new(pages: u32, slots: u32, policy: Prefetch) -> Residency {
        Residency {
            table: vec![NOT_RESIDENT; pages as usize],
            slot_page: vec![NOT_RESIDENT; slots as usize],
            last_used: vec![0; pages as usize],
            loaded_at: vec![0; slots as usize],
            policy,
        }
    }

    /// Whether page `id` is resident.
    pub fn resident(&self, id: u32) -> bool {
        self.table
            .get(id as usize)
            .is_some_and(|&s| s != NOT_RESIDENT)
    }

    /// Resident pages.
    pub fn resident_count(&self) -> u32 {
        self.slot_page
            .iter()
            .filter(|&&p| p != NOT_RESIDENT)
            .count() as u32
    }

    /// The index table (page → slot, `u32::MAX` where not resident).
    pub fn table(&self) -> &[u32] {
        &self.table
    }

    /// Plans frame `frame`'s loads: the `needed` pages that are not resident (in order), then
    /// the `prefetch` pages (most probable first; `probability` of every page that has one),
    /// at most `budget` in all. Each load takes a free slot or evicts the policy's victim: never
    /// a page `needed` by this frame or loaded for it, and for prefetches only a page less
    /// probable than the one coming in. Returns `(page, slot)` per load; the table is updated.
    pub fn plan(
        &mut self,
        frame: u32,
        needed: &[u32],
        prefetch: &[u32],
        probability: &HashMap<u32, f32>,
        budget: u32,
    ) -> Vec<(u32, u32)> {
        let protected: std::collections::HashSet<u32> = needed.iter().copied().collect();
        let mut loads = Vec::new();
        let wanted = needed
            .iter()
            .map(|&p| (p, true))
            .chain(prefetch.iter().map(|&p| (p, false)));
        for (page, is_needed) in wanted {
            if loads.len() as u32 >= budget {
                break;
            }
            if (page as usize) >= self.table.len() || self.resident(page) {
                continue;
            }
            let incoming = probability.get(&page).copied().unwrap_or(0.0);
            let Some(slot) = self.victim(frame, &protected, probability, is_needed, incoming)
            else {
                // No room for this page nor any after it: for a needed page, every slot holds
                // a page this frame needs or loaded (which no later page changes); for a
                // prefetch, the least probable resident page is likelier, and later prefetches
                // are less probable still. (Going on cost a scan of every slot per page: 50–75
                // ms a frame once a frame needs more pages than there are slots.)
                break;
            };
            let old = self.slot_page[slot as usize];
            if old != NOT_RESIDENT {
                self.table[old as usize] = NOT_RESIDENT;
            }
            self.slot_page[slot as usize] = page;
            self.table[page as usize] = slot;
            self.loaded_at[slot as usize] = frame;
            loads.push((page, slot));
        }
        loads
    }

    /// A free slot, or the slot whose page the policy evicts.
    fn victim(
        &self,
        frame: u32,
        protected: &std::collections::HashSet<u32>,
        probability: &HashMap<u32, f32>,
        for_needed: bool,
        incoming: f32,
    ) -> Option<u32> {
        if let Some(free) = self.slot_page.iter().position(|&p| p == NOT_RESIDENT) {
            return Some(free as u32);
        }
        let candidates =
            self.slot_page.iter().enumerate().filter(|&(slot, &page)| {
                !protected.contains(&page) && self.loaded_at[slot] != frame
            });
        let chosen = match self.policy {
            Prefetch::None => candidates.min_by_key(|&(slot, _)| self.loaded_at[slot]),
            Prefetch::Lru => candidates.min_by_key(|&(_, &page)| self.last_used[page as usize]),
            Prefetch::Predict => candidates.min_by(|&(_, &a), &(_, &b)| {
                let pa = probability.get(&a).copied().unwrap_or(0.0);
                let pb = probability.get(&b).copied().unwrap_or(0.0);
                pa.total_cmp(&pb)
                    .then(self.last_used[a as usize].cmp(&self.last_used[b as usize]))
            }),
        }?;
        let page = *chosen.1;
        let p = probability.get(&page).copied().unwrap_or(0.0);
        (for_needed || p < incoming).then_some(chosen.0 as u32)
    }

    /// Drops page `id` from `slot` (a load that failed), leaving the slot free.
    fn forget(&mut self, id: u32, slot: u32) {
        if self.table.get(id as usize) == Some(&slot) {
            self.table[id as usize] = NOT_RESIDENT;
            self.slot_page[slot as usize] = NOT_RESIDENT;
        }
    }

    /// Records the pages frame `frame` touched; returns how many of them were not resident at
    /// its start (`resident_at_start`: the table before [`Residency::plan`]).
    pub fn touched(&mut self, frame: u32, touched: &[u32], resident_at_start: &[u32]) -> u32 {
        let mut faults = 0;
        for &page in touched {
            if let Some(used) = self.last_used.get_mut(page as usize) {
                *used = frame;
                if resident_at_start[page as usize] == NOT_RESIDENT {
                    faults += 1;
                }
            }
        }
        faults
    }
}

/// The shape of a cache: what [`PagedTwoPlane::open`] allocates for an asset and a budget.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CacheLayout {
    /// The asset's pages.
    pub grid: PageGrid,
    /// The coarse level's downsampling factor F.
    pub coarse_factor: u32,
    /// Page slots.
    pub slots: u32,
    /// Tiles per atlas row and column.
    pub tiles_x: u32,
    /// Tile rows per atlas layer.
    pub tiles_y: u32,
    /// Atlas texels per side and layers.
    pub atlas: [u32; 3],
    /// Coarse level texels per side and layers.
    pub coarse: [u32; 3],
    /// Device bytes of the atlases and the coarse level.
    pub bytes: u64,
    /// Device bytes every page would take resident.
    pub full_bytes: u64,
}

impl CacheLayout {
    /// The layout of a cache of `config` for a light field of `planes` cut into `page_size`
    /// pages, on `gpu` (its texture limits): the coarse level takes the finest power-of-two
    /// factor (at least 2) within an eighth of the budget, the slots the rest.
    ///
    /// # Errors
    /// [`RenderError::Option`] for a budget that holds no page or a page larger than the
    /// device's textures; [`RenderError::Gpu`] for too many layers.
    pub fn of(
        planes: &TwoPlanes,
        page_size: u32,
        config: &CacheConfig,
        gpu: &Gpu,
    ) -> Result<CacheLayout, RenderError> {
        let mut grid = PageGrid::new(planes, page_size);
        let p = u64::from(grid.page_size);
        let slot_bytes = p * p * SLOT_TEXEL_BYTES;
        let total = grid.total();
        let full_bytes = u64::from(total) * slot_bytes;
        let (cameras, res) = (grid.cameras, grid.res);
        let coarse_bytes = |f: u32| {
            u64::from(cameras)
                * u64::from(res[0].div_ceil(f))
                * u64::from(res[1].div_ceil(f))
                * SLOT_TEXEL_BYTES
        };
        let (coarse_factor, slots) = match config.budget_bytes {
            None => (grid.page_size.min(16), total),
            Some(budget) => {
                let mut f = 2;
                while coarse_bytes(f) > budget / 8 && f < grid.res[0].max(grid.res[1]) {
                    f *= 2;
                }
                // With the overview, the levels between the full resolution and the coarse
                // level's F (2, 4, …, F/2) are paged too.
                if config.overview {
                    grid = grid.with_levels(f.trailing_zeros());
                }
                let left = budget.saturating_sub(coarse_bytes(f));
                let slots = (left / slot_bytes).min(u64::from(grid.all_pages())) as u32;
                if slots == 0 {
                    return Err(RenderError::Option(format!(
                        "a cache of {:.2} MiB holds no {}x{} page besides the coarse level \
                         ({:.2} MiB): give at least {:.2} MiB",
                        budget as f64 / 1_048_576.0,
                        grid.page_size,
                        grid.page_size,
                        coarse_bytes(f) as f64 / 1_048_576.0,
                        (coarse_bytes(f) + slot_bytes) as f64 / 1_048_576.0
                    )));
                }
                (f, slots)
            }
        };
        let limits = gpu.device.limits();
        if grid.page_size > limits.max_texture_dimension_2d {
            return Err(RenderError::Option(format!(
                "page size {} exceeds the device's {} texels per side",
                grid.page_size, limits.max_texture_dimension_2d
            )));
        }
        let (tiles_x, tiles_y, layers) = atlas_shape(
            slots,
            grid.page_size,
            limits.max_texture_dimension_2d.min(4096),
        );
        let layers = Gpu::padded_layers(layers);
        gpu.check_layers(layers)?;
        gpu.check_layers(Gpu::padded_layers(grid.cameras))?;
        let coarse_res = grid.res.map(|n| n.div_ceil(coarse_factor));
        let atlas = [tiles_x * grid.page_size, tiles_y * grid.page_size, layers];
        let coarse = [
            coarse_res[0],
            coarse_res[1],
            Gpu::padded_layers(grid.cameras),
        ];
        let texels = |d: [u32; 3]| d.iter().map(|&n| u64::from(n)).product::<u64>();
        Ok(CacheLayout {
            grid,
            coarse_factor,
            slots,
            tiles_x,
            tiles_y,
            atlas,
            coarse,
            bytes: (texels(atlas) + texels(coarse)) * SLOT_TEXEL_BYTES,
            full_bytes,
        })
    }
}

/// Shape of the slot atlas: tiles per layer row, rows per layer, layers. At least two layers,
/// and never a multiple of six, so that [`Gpu::padded_layers`] adds none.
fn atlas_shape(slots: u32, page_size: u32, max_side: u32) -> (u32, u32, u32) {
    // The index table packs a tile's column and row in 8 bits each.
    let max_tiles = (max_side / page_size).clamp(1, 256);
    let per_layer_max = max_tiles * max_tiles;
    let mut layers = slots.div_ceil(per_layer_max).max(2);
    if layers.is_multiple_of(6) {
        layers += 1;
    }
    let per_layer = slots.div_ceil(layers);
    let tiles_x = per_layer.min(max_tiles);
    let tiles_y = per_layer.div_ceil(tiles_x);
    (tiles_x, tiles_y, layers)
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PagingUniform {
    page_shift: u32,
    coarse_shift: u32,
    coarse_res: [u32; 2],
    stamp: u32,
    overview_min: f32,
    mask_words: u32,
    levels: u32,
    level_min: f32,
    pad: [u32; 3],
    /// Per page level (0: the full resolution): its first page, pages per image row and per
    /// image, and its image size (width in bits 0–15, height in 16–31).
    level: [[u32; 4]; MAX_PAGE_LEVELS as usize],
}

/// A page read from the file: its id and colour and depth texels.
struct LoadedPage {
    id: u32,
    color: Vec<u8>,
    depth: Vec<u8>,
}

/// Where a cache reads its pages: the asset's (level 0) from the file, the intermediate levels'
/// from the store built when the cache opened.
struct PageSource {
    asset: Arc<AssetFile>,
    grid: PageGrid,
    levels: LevelStore,
}

/// The pages of the intermediate levels (1 ≤ l < [`PageGrid::levels`]), built from the file's
/// pages when the cache opens and kept in an unnamed temporary file (zstd, level 1: the host holds
/// none of them), each read back alone like the file's.
#[derive(Default)]
struct LevelStore {
    file: Option<std::sync::Mutex<std::fs::File>>,
    /// Per page of the levels (id − the first level-1 id): offset and length in the file.
    index: Vec<(u64, u32)>,
    /// Bytes written.
    bytes: u64,
}

impl LevelStore {
    /// A store for `grid`'s intermediate levels: no file where it has none.
    fn new(grid: &PageGrid) -> Result<LevelStore, RenderError> {
        if grid.levels <= 1 {
            return Ok(LevelStore::default());
        }
        let file = tempfile::tempfile().map_err(|e| {
            RenderError::Option(format!(
                "cannot create the temporary file of the cache's page levels in {}: {e}",
                std::env::temp_dir().display()
            ))
        })?;
        Ok(LevelStore {
            file: Some(std::sync::Mutex::new(file)),
            index: vec![(0, 0); (grid.all_pages() - grid.level_first(1)) as usize],
            bytes: 0,
        })
    }

    /// Stores pages `(k, colour bytes then depth bytes)`, compressed on every core.
    fn put(&mut self, pages: &[(usize, Vec<u8>)]) -> Result<(), RenderError> {
        use rayon::prelude::*;
        use std::io::Write;
        let io = |e: std::io::Error| {
            RenderError::Option(format!("cannot write the cache's page levels: {e}"))
        };
        let packed: Vec<Vec<u8>> = pages
            .par_iter()
            .map(|(_, raw)| zstd::bulk::compress(raw, 1))
            .collect::<Result<_, _>>()
            .map_err(io)?;
        let Some(file) = &mut self.file else {
            return Err(RenderError::Option(
                "the cache has no page levels".to_owned(),
            ));
        };
        let file = file
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        for ((k, _), packed) in pages.iter().zip(packed) {
            let Some(entry) = self.index.get_mut(*k) else {
                return Err(RenderError::Option(format!("no page level holds page {k}")));
            };
            file.write_all(&packed).map_err(io)?;
            *entry = (self.bytes, packed.len() as u32);
            self.bytes += packed.len() as u64;
        }
        Ok(())
    }

    /// Page `k`: `texels` texels of colour (RGBA8) and depth (f32).
    fn get(&self, k: usize, texels: usize) -> Result<(Vec<u8>, Vec<u8>), RenderError> {
        use std::io::{Read, Seek};
        let (Some(file), Some(&(offset, len))) = (&self.file, self.index.get(k)) else {
            return Err(RenderError::Option(format!("no page level holds page {k}")));
        };
        let io = |e: std::io::Error| {
            RenderError::Option(format!("cannot read the cache's page levels: {e}"))
        };
        let mut packed = vec![0; len as usize];
        {
            let mut file = file
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            file.seek(std::io::SeekFrom::Start(offset)).map_err(io)?;
            file.read_exact(&mut packed).map_err(io)?;
        }
        let mut color = zstd::bulk::decompress(&packed, texels * 8).map_err(io)?;
        if color.len() != texels * 8 {
            return Err(RenderError::Option(format!(
                "page level entry {k}: {} bytes for {texels} texels",
                color.len()
            )));
        }
        let depth = color.split_off(texels * 4);
        Ok((color, depth))
    }
}

/// Block sums of one level of a camera image, over a rectangle of it (a tile, or the whole
/// image): per texel the RGBA sums and the count of the full-resolution texels in its block, and
/// their nearest depth.
struct LevelSums {
    /// The rectangle's first texel, at this level.
    origin: [u32; 2],
    res: [u32; 2],
    sum: Vec<[u32; 5]>,
    near: Vec<f32>,
}

impl LevelSums {
    /// Empty sums of `res` texels from `origin`.
    fn new(origin: [u32; 2], res: [u32; 2]) -> LevelSums {
        let n = res[0] as usize * res[1] as usize;
        LevelSums {
            origin,
            res,
            sum: vec![[0; 5]; n],
            near: vec![f32::INFINITY; n],
        }
    }

    /// Adds the full-resolution texel `(x, y)` at level `shift` (its block `(x, y) >> shift`,
    /// inside the rectangle).
    #[inline]
    fn add(&mut self, x: u32, y: u32, shift: u32, color: &[u8], depth: f32) {
        let k = ((y >> shift) - self.origin[1]) as usize * self.res[0] as usize
            + ((x >> shift) - self.origin[0]) as usize;
        let s = &mut self.sum[k];
        for i in 0..4 {
            s[i] += u32::from(color[i]);
        }
        s[4] += 1;
        self.near[k] = self.near[k].min(depth);
    }

    /// The next level: 2 × 2 blocks of these (exact: sums add; the origin must be even).
    fn halve(&self) -> LevelSums {
        let res = self.res.map(|n| n.div_ceil(2));
        let mut out = LevelSums::new(self.origin.map(|o| o / 2), res);
        let (w, half) = (self.res[0].max(1) as usize, res[0] as usize);
        for (y, (sums, nears)) in self
            .sum
            .chunks_exact(w)
            .zip(self.near.chunks_exact(w))
            .enumerate()
        {
            let row = (y / 2) * half;
            let (to_sum, to_near) = (
                &mut out.sum[row..row + half],
                &mut out.near[row..row + half],
            );
            for (x, (s, n)) in sums.iter().zip(nears).enumerate() {
                let t = &mut to_sum[x / 2];
                for i in 0..5 {
                    t[i] += s[i];
                }
                to_near[x / 2] = to_near[x / 2].min(*n);
            }
        }
        out
    }

    /// The pages of camera `camera`'s image at `level` (whose sums these are) inside the
    /// rectangle (whose origin is on a page border), as the store keeps them (index after the
    /// first level-1 page `level_first`; colour rows, then depth rows).
    fn pages(
        &self,
        grid: &PageGrid,
        level: u32,
        camera: u32,
        level_first: u32,
    ) -> Vec<(usize, Vec<u8>)> {
        let p = grid.page_size;
        let columns = grid.level_pages(level)[0];
        let [c0, r0] = self.origin.map(|o| o / p);
        let [c1, r1] = [0, 1].map(|k| (self.origin[k] + self.res[k]).div_ceil(p));
        let mut out = Vec::new();
        for row in r0..r1 {
            for column in c0..c1 {
                let page = row * columns + column;
                let (x0, y0, w, h) = grid.level_rect(level, page);
                let mut raw = Vec::with_capacity((w * h * 8) as usize);
                let at = |x: u32, y: u32| {
                    ((y - self.origin[1]) * self.res[0] + (x - self.origin[0])) as usize
                };
                for y in y0..y0 + h {
                    for x in x0..x0 + w {
                        raw.extend_from_slice(&mean(&self.sum[at(x, y)]));
                    }
                }
                for y in y0..y0 + h {
                    for x in x0..x0 + w {
                        raw.extend_from_slice(&self.near[at(x, y)].to_le_bytes());
                    }
                }
                let id = grid.id(level, camera, column, row);
                out.push(((id - level_first) as usize, raw));
            }
        }
        out
    }

    /// The rectangle's texels: mean colour (rounded) and nearest depth.
    fn texels(&self) -> (Vec<u8>, Vec<f32>) {
        let color = self.sum.iter().flat_map(mean).collect();
        (color, self.near.clone())
    }
}

/// What one camera image gives the cache besides its pages: its page levels' pages (as
/// [`LevelStore::put`] takes them), its coarse level (RGBA8 colour and f32 depth) and its range
/// of finite depths.
struct CameraLevels {
    pages: Vec<(usize, Vec<u8>)>,
    color: Vec<u8>,
    depth: Vec<f32>,
    range: [f32; 2],
}

/// One tile of [`camera_levels`]: its level pages, its block of the coarse level's sums and its
/// range of finite depths.
type TileLevels = (Vec<(usize, Vec<u8>)>, LevelSums, [f32; 2]);

/// Builds camera `camera`'s page levels and coarse level (factor `1 << coarse_shift`) from its
/// full-resolution `pages` (in page order), in tiles on every core: a tile is whole pages at
/// every paged level and whole coarse texels, so its block sums stay small (a few MB) and
/// tiles need nothing from each other. Each level is the exact block sums of the one before
/// (the same as direct accumulation), one rounding per texel.
///
/// # Errors
/// [`RenderError::Asset`] for a depth that is neither finite nor +inf.
fn camera_levels(
    grid: &PageGrid,
    coarse_shift: u32,
    camera: u32,
    pages: &[LoadedPage],
) -> Result<CameraLevels, RenderError> {
    use rayon::prelude::*;
    let p = grid.page_size;
    let tile = (p << (grid.levels - 1)).max(1 << coarse_shift);
    let tiles = grid.res.map(|n| n.div_ceil(tile));
    let level_first = grid.level_first(1);
    // Sums at level 1 where there are page levels, at the coarse level itself otherwise.
    let first_shift = if grid.levels > 1 { 1 } else { coarse_shift };
    let results: Vec<Result<TileLevels, RenderError>> = (0..tiles[0] * tiles[1])
        .into_par_iter()
        .map(|t| {
            let (x0, y0) = ((t % tiles[0]) * tile, (t / tiles[0]) * tile);
            let (x1, y1) = ((x0 + tile).min(grid.res[0]), (y0 + tile).min(grid.res[1]));
            let origin = [x0 >> first_shift, y0 >> first_shift];
            let res = [
                x1.div_ceil(1 << first_shift) - origin[0],
                y1.div_ceil(1 << first_shift) - origin[1],
            ];
            let mut sums = LevelSums::new(origin, res);
            let mut range = [f32::INFINITY, f32::NEG_INFINITY];
            for py in y0 / p..y1.div_ceil(p) {
                for px in x0 / p..x1.div_ceil(p) {
                    let number = py * grid.pages[0] + px;
                    let Some(page) = pages.get(number as usize) else {
                        continue;
                    };
                    let (px0, py0, w, h) = grid.rect(number);
                    for y in 0..h {
                        for x in 0..w {
                            let k = (y * w + x) as usize;
                            let d = f32::from_le_bytes([
                                page.depth[4 * k],
                                page.depth[4 * k + 1],
                                page.depth[4 * k + 2],
                                page.depth[4 * k + 3],
                            ]);
                            if d.is_finite() {
                                range = [range[0].min(d), range[1].max(d)];
                            } else if !(d.is_infinite() && d > 0.0) {
                                return Err(RenderError::Asset(AssetError::Header(format!(
                                    "camera {camera} stores depth {d}: two-plane depth is \
                                     finite or +inf"
                                ))));
                            }
                            sums.add(px0 + x, py0 + y, first_shift, &page.color[4 * k..], d);
                        }
                    }
                }
            }
            let mut level_pages = Vec::new();
            let mut shift = first_shift;
            while shift < coarse_shift {
                if shift < grid.levels {
                    level_pages.extend(sums.pages(grid, shift, camera, level_first));
                }
                sums = sums.halve();
                shift += 1;
            }
            Ok((level_pages, sums, range))
        })
        .collect();
    let [cw, ch] = grid.level_res(coarse_shift);
    let mut out = CameraLevels {
        pages: Vec::new(),
        color: vec![0; (cw * ch * 4) as usize],
        depth: vec![f32::INFINITY; (cw * ch) as usize],
        range: [f32::INFINITY, f32::NEG_INFINITY],
    };
    for result in results {
        let (level_pages, coarse, range) = result?;
        out.pages.extend(level_pages);
        out.range = [out.range[0].min(range[0]), out.range[1].max(range[1])];
        let (color, depth) = coarse.texels();
        let w = coarse.res[0] as usize;
        for (y, (c, d)) in color
            .chunks_exact(4 * w)
            .zip(depth.chunks_exact(w))
            .enumerate()
        {
            let at = (coarse.origin[1] as usize + y) * cw as usize + coarse.origin[0] as usize;
            out.color[4 * at..4 * (at + w)].copy_from_slice(c);
            out.depth[at..at + w].copy_from_slice(d);
        }
    }
    Ok(out)
}

/// The rounded mean colour of a block's sums (`[r, g, b, a, count]`; an empty block is 0).
fn mean(s: &[u32; 5]) -> [u8; 4] {
    let n = s[4].max(1);
    [0, 1, 2, 3].map(|i| ((s[i] + n / 2) / n) as u8)
}

/// Reads and decodes `ids` (of any level) from `source`, on up to the machine's cores: each
/// page's result.
fn read_pages(source: &PageSource, ids: &[u32]) -> Vec<Result<LoadedPage, RenderError>> {
    let grid = &source.grid;
    let read = |id: u32| -> Result<LoadedPage, RenderError> {
        let (level, camera, page) = grid.locate(id);
        let (_, _, w, h) = grid.level_rect(level, page);
        let texels = w as usize * h as usize;
        let (color, depth) = if level == 0 {
            (
                source
                    .asset
                    .read_page(ImageKey::new(0, 0, camera, Channel::Color), page)?,
                source
                    .asset
                    .read_page(ImageKey::new(0, 0, camera, Channel::Depth), page)?,
            )
        } else {
            source
                .levels
                .get((id - grid.level_first(1)) as usize, texels)?
        };
        if color.len() != texels * 4 || depth.len() != texels * 4 {
            return Err(RenderError::Asset(AssetError::Header(format!(
                "camera {camera} page {page}: {} colour and {} depth bytes for {w}x{h} texels \
                 (RGBA8 and f32 expected)",
                color.len(),
                depth.len()
            ))));
        }
        Ok(LoadedPage { id, color, depth })
    };
    let workers = std::thread::available_parallelism()
        .map_or(1, std::num::NonZeroUsize::get)
        .min(ids.len().max(1));
    if workers <= 1 {
        return ids.iter().map(|&id| read(id)).collect();
    }
    let chunk = ids.len().div_ceil(workers);
    std::thread::scope(|scope| {
        let handles: Vec<_> = ids
            .chunks(chunk)
            .map(|part| {
                (
                    part.len(),
                    scope.spawn(move || part.iter().map(|&id| read(id)).collect::<Vec<_>>()),
                )
            })
            .collect();
        let mut out = Vec::with_capacity(ids.len());
        for (n, h) in handles {
            match h.join() {
                Ok(part) => out.extend(part),
                Err(_) => out.extend(
                    (0..n).map(|_| Err(RenderError::Option("a page reader panicked".to_owned()))),
                ),
            }
        }
        out
    })
}

/// A two-plane light field rendered through a paged cache ([module docs](self)).
pub struct PagedTwoPlane {
    /// Its planes.
    pub planes: TwoPlanes,
    /// Smallest and largest finite stored depth (`[1, 1]` when nothing is hit).
    pub depth_range: [f32; 2],
    /// The pages.
    pub grid: PageGrid,
    /// Slots of the cache.
    pub slots: u32,
    /// The coarse level's downsampling factor F.
    pub coarse_factor: u32,
    /// Device bytes: slots and coarse level.
    pub bytes: u64,
    /// Device bytes every page would take resident (slots for all pages).
    pub full_bytes: u64,
    config: CacheConfig,
    source: Arc<PageSource>,
    gpu: Arc<Gpu>,
    tiles_x: u32,
    per_layer: u32,
    slot_color: wgpu::Texture,
    slot_depth: wgpu::Texture,
    coarse_color: wgpu::Texture,
    coarse_depth: wgpu::Texture,
    views: [wgpu::TextureView; 4],
    paging: wgpu::Buffer,
    table: wgpu::Buffer,
    touched: wgpu::Buffer,
    touched_staging: wgpu::Buffer,
    /// The degraded-pixel count and mask of frames of a pixel count, and its readback copy.
    degraded: Option<(u64, wgpu::Buffer, wgpu::Buffer)>,
    residency: Residency,
    /// Slot → the page whose texels it holds on the device (or [`NOT_RESIDENT`]): a page the
    /// residency gave a slot is in the device's table only once its texels are there.
    slot_data: Vec<u32>,
    /// The background reader of [`Self::render_nowait`], started on its first frame.
    loader: Option<Loader>,
    frame: u32,
    history: VecDeque<CameraState>,
    /// Pages the last frame touched that its projection missed and that were not on the
    /// device after its loads (sorted): the next frame needs them whatever its projection says.
    missed: Vec<u32>,
}

/// A thread that reads and decodes pages for [`PagedTwoPlane::render_nowait`] while frames
/// render: requests of `(page, slot)` in, each page's result out.
struct Loader {
    requests: std::sync::mpsc::Sender<Vec<(u32, u32)>>,
    results: std::sync::mpsc::Receiver<(u32, u32, Result<LoadedPage, RenderError>)>,
    /// Pages requested and not received yet.
    in_flight: usize,
}

impl Loader {
    fn start(source: Arc<PageSource>) -> Result<Loader, RenderError> {
        let (requests, inbox) = std::sync::mpsc::channel::<Vec<(u32, u32)>>();
        let (outbox, results) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("page-loader".to_owned())
            .spawn(move || {
                // Ends when the cache (the requests' sender) is dropped.
                while let Ok(batch) = inbox.recv() {
                    let ids: Vec<u32> = batch.iter().map(|&(id, _)| id).collect();
                    for (&(id, slot), result) in batch.iter().zip(read_pages(&source, &ids)) {
                        if outbox.send((id, slot, result)).is_err() {
                            return;
                        }
                    }
                }
            })
            .map_err(|e| RenderError::Option(format!("cannot start the page loader: {e}")))?;
        Ok(Loader {
            requests,
            results,
            in_flight: 0,
        })
    }
}

impl Drop for PagedTwoPlane {
    fn drop(&mut self) {
        self.slot_color.destroy();
        self.slot_depth.destroy();
        self.coarse_color.destroy();
        self.coarse_depth.destroy();
    }
}

impl PagedTwoPlane {
    /// Opens `asset` (a two-plane light field with depth) through a cache: one pass over every
    /// page builds the coarse level, the intermediate page levels (into a temporary file) and
    /// the depth range (and, with [`CacheConfig::whole`], uploads every page); no other page is
    /// loaded until a frame needs it.
    ///
    /// # Errors
    /// [`RenderError::Asset`] for another kind or a bad page; [`RenderError::Option`] for a
    /// budget that holds no page; [`RenderError::Gpu`] for device limits.
    pub fn open(
        renderer: &TwoPlaneRenderer,
        asset: Arc<AssetFile>,
        config: CacheConfig,
    ) -> Result<PagedTwoPlane, RenderError> {
        let gpu = Arc::clone(renderer.gpu());
        let header = asset.header();
        let planes = *header.two_plane().ok_or(AssetError::Kind {
            what: "the paged two-plane renderer",
            kind: header.kind,
        })?;
        let layout = CacheLayout::of(&planes, header.page_size, &config, &gpu)?;
        let CacheLayout {
            grid,
            coarse_factor,
            slots,
            tiles_x,
            atlas,
            coarse,
            bytes,
            full_bytes,
            ..
        } = layout;
        // Every level's pages: the index table and the feedback cover them all.
        let total = grid.all_pages();
        let slot_color = empty_texture_array(
            &gpu,
            "page cache colour",
            wgpu::TextureFormat::Rgba8Unorm,
            atlas,
        );
        let slot_depth = empty_texture_array(
            &gpu,
            "page cache depth",
            wgpu::TextureFormat::R32Float,
            atlas,
        );
        let coarse_color = empty_texture_array(
            &gpu,
            "coarse colour",
            wgpu::TextureFormat::Rgba8Unorm,
            coarse,
        );
        let coarse_depth =
            empty_texture_array(&gpu, "coarse depth", wgpu::TextureFormat::R32Float, coarse);
        let buffer = |label, size: u64, usage| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let copy = wgpu::BufferUsages::COPY_DST;
        let paging = buffer(
            "paging",
            std::mem::size_of::<PagingUniform>() as u64,
            wgpu::BufferUsages::UNIFORM | copy,
        );
        let table = buffer(
            "page table",
            u64::from(total) * 4,
            wgpu::BufferUsages::STORAGE | copy,
        );
        let touched = buffer(
            "pages touched",
            u64::from(total) * 4,
            wgpu::BufferUsages::STORAGE | copy | wgpu::BufferUsages::COPY_SRC,
        );
        let touched_staging = buffer(
            "pages touched readback",
            u64::from(total) * 4,
            wgpu::BufferUsages::MAP_READ | copy,
        );
        gpu.queue
            .write_buffer(&touched, 0, &vec![0u8; total as usize * 4]);
        let views =
            [&slot_color, &slot_depth, &coarse_color, &coarse_depth].map(crate::gpu::array_view);
        let mut paged = PagedTwoPlane {
            planes,
            depth_range: [1.0, 1.0],
            grid,
            slots,
            coarse_factor,
            bytes,
            full_bytes,
            config,
            source: Arc::new(PageSource {
                asset,
                grid,
                levels: LevelStore::default(),
            }),
            gpu,
            tiles_x,
            per_layer: tiles_x * layout.tiles_y,
            slot_color,
            slot_depth,
            coarse_color,
            coarse_depth,
            views,
            paging,
            table,
            touched,
            touched_staging,
            degraded: None,
            residency: Residency::new(total, slots, config.prefetch),
            slot_data: vec![NOT_RESIDENT; slots as usize],
            loader: None,
            frame: 0,
            history: VecDeque::new(),
            missed: Vec::new(),
        };
        paged.build_coarse(config.budget_bytes.is_none())?;
        Ok(paged)
    }

    /// One pass over every page: the coarse level, the intermediate page levels, the depth
    /// range, and with `load_all` every page uploaded to its slot.
    fn build_coarse(&mut self, load_all: bool) -> Result<(), RenderError> {
        let grid = self.grid;
        let coarse_shift = self.coarse_factor.trailing_zeros();
        let mut levels = LevelStore::new(&grid)?;
        let level_first = grid.level_first(1);
        let mut range = [f32::INFINITY, f32::NEG_INFINITY];
        let per_image = grid.per_image();
        for camera in 0..grid.cameras {
            let ids: Vec<u32> = (0..per_image).map(|p| camera * per_image + p).collect();
            let pages = read_pages(&self.source, &ids)
                .into_iter()
                .collect::<Result<Vec<_>, _>>()?;
            let built = camera_levels(&grid, coarse_shift, camera, &pages)?;
            range = [range[0].min(built.range[0]), range[1].max(built.range[1])];
            if !built.pages.is_empty() {
                levels.put(&built.pages)?;
            }
            let [cw, ch] = grid.level_res(coarse_shift);
            let depth: Vec<u8> = bytemuck::cast_slice(&built.depth).to_vec();
            for (texture, data) in [
                (&self.coarse_color, &built.color),
                (&self.coarse_depth, &depth),
            ] {
                self.write(texture, [0, 0, camera], [cw, ch], data);
            }
            if load_all {
                let loads: Vec<(u32, u32)> =
                    self.residency.plan(0, &ids, &[], &HashMap::new(), u32::MAX);
                self.upload(&loads, &pages);
            }
        }
        if range[0] <= range[1] {
            self.depth_range = range;
        }
        if grid.levels > 1 {
            tracing::debug!(
                levels = grid.levels - 1,
                pages = grid.all_pages() - level_first,
                bytes = levels.bytes,
                "page levels stored"
            );
        }
        self.source = Arc::new(PageSource {
            asset: Arc::clone(&self.source.asset),
            grid,
            levels,
        });
        self.write_table();
        self.gpu.wait()?;
        Ok(())
    }

    fn write(&self, texture: &wgpu::Texture, origin: [u32; 3], size: [u32; 2], data: &[u8]) {
        self.gpu.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: 0,
                origin: wgpu::Origin3d {
                    x: origin[0],
                    y: origin[1],
                    z: origin[2],
                },
                aspect: wgpu::TextureAspect::All,
            },
            data,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(size[0] * 4),
                rows_per_image: Some(size[1]),
            },
            wgpu::Extent3d {
                width: size[0],
                height: size[1],
                depth_or_array_layers: 1,
            },
        );
    }

    /// Copies loaded pages into their slots (`loads`: page → slot; `pages` holds them).
    fn upload(&mut self, loads: &[(u32, u32)], pages: &[LoadedPage]) {
        let by_id: HashMap<u32, &LoadedPage> = pages.iter().map(|p| (p.id, p)).collect();
        for &(id, slot) in loads {
            let Some(page) = by_id.get(&id) else {
                continue;
            };
            let (level, _, number) = self.grid.locate(id);
            let (_, _, w, h) = self.grid.level_rect(level, number);
            let (x, y, layer) = self.place(slot);
            let origin = [x * self.grid.page_size, y * self.grid.page_size, layer];
            self.write(&self.slot_color, origin, [w, h], &page.color);
            self.write(&self.slot_depth, origin, [w, h], &page.depth);
            self.slot_data[slot as usize] = id;
        }
    }

    /// The tile and layer of `slot` in the atlas.
    fn place(&self, slot: u32) -> (u32, u32, u32) {
        let tile = slot % self.per_layer;
        (
            tile % self.tiles_x,
            tile / self.tiles_x,
            slot / self.per_layer,
        )
    }

    /// Uploads the index table: per page its slot's place packed as the shader reads it (tile
    /// column in bits 0–7, row in 8–15, layer in 16–31), or `u32::MAX`.
    fn write_table(&self) {
        let packed: Vec<u32> = self
            .device_table()
            .iter()
            .map(|&slot| {
                if slot == NOT_RESIDENT {
                    return NOT_RESIDENT;
                }
                let (x, y, layer) = self.place(slot);
                x | (y << 8) | (layer << 16)
            })
            .collect();
        self.gpu
            .queue
            .write_buffer(&self.table, 0, bytemuck::cast_slice(&packed));
    }

    /// Bytes of the intermediate page levels' temporary file (zstd-compressed pages; 0
    /// without levels).
    pub fn level_file_bytes(&self) -> u64 {
        self.source.levels.bytes
    }

    /// Pages resident now.
    pub fn resident_pages(&self) -> u32 {
        self.residency.resident_count()
    }

    /// The cache's configuration.
    pub fn config(&self) -> &CacheConfig {
        &self.config
    }

    /// The coarse factor where overview pixels are on.
    fn overview_factor(&self) -> Option<u32> {
        self.config.overview.then_some(self.coarse_factor)
    }

    /// What projects views onto this cache's pages.
    fn projector(&self) -> Projector<'_> {
        Projector {
            planes: &self.planes,
            grid: &self.grid,
            depth_range: self.depth_range,
            overview: self.overview_factor(),
        }
    }

    /// Renders `view` through the cache: plans, reads and uploads the frame's pages (the needed
    /// ones, then prefetches; pages still being read for [`Self::render_nowait`] are waited
    /// for first), renders, and reads back the shader's feedback.
    ///
    /// # Errors
    /// As [`TwoPlaneRenderer::render`]. A page that cannot be read is not an error: it stays
    /// missing (the frame is degraded there) and is named in the stats' `read_errors`.
    pub fn render(
        &mut self,
        renderer: &TwoPlaneRenderer,
        view: &View,
        options: &TwoPlaneOptions,
    ) -> Result<(Frame, PageFrameStats), RenderError> {
        self.render_with(renderer, view, options, true)
    }

    /// [`Self::render`] without waiting for pages: the frame uploads the pages read in the
    /// background since the last one, asks a reader thread for the pages it plans (the same
    /// plan as [`Self::render`]) and renders at once with what is on the device, the coarse
    /// level where a page is missing. What an interactive view does: no frame waits for the
    /// file or the decoder.
    ///
    /// # Errors
    /// As [`Self::render`].
    pub fn render_nowait(
        &mut self,
        renderer: &TwoPlaneRenderer,
        view: &View,
        options: &TwoPlaneOptions,
    ) -> Result<(Frame, PageFrameStats), RenderError> {
        self.render_with(renderer, view, options, false)
    }

    /// Takes the pages the reader finished (waiting for all of them with `wait`) and
    /// [`Self::accept`]s them.
    fn receive(&mut self, wait: bool) -> (u32, u64, Vec<String>) {
        let Some(loader) = &mut self.loader else {
            return (0, 0, Vec::new());
        };
        let mut arrived = Vec::new();
        while loader.in_flight > 0 {
            let next = if wait {
                loader.results.recv().ok()
            } else {
                loader.results.try_recv().ok()
            };
            let Some(result) = next else {
                break;
            };
            loader.in_flight -= 1;
            arrived.push(result);
        }
        self.accept(arrived)
    }

    /// Uploads each page read for its slot, where the slot is still its own (a page evicted or
    /// moved while it was being read is dropped); a page that failed to read stays missing
    /// (frames read the coarse level there) and its slot is freed. Returns the pages and bytes
    /// uploaded and the read errors.
    fn accept(
        &mut self,
        arrived: Vec<(u32, u32, Result<LoadedPage, RenderError>)>,
    ) -> (u32, u64, Vec<String>) {
        let (mut pages, mut bytes, mut errors) = (0, 0, Vec::new());
        for (id, slot, result) in arrived {
            match result {
                Ok(page) => {
                    if self.residency.table().get(id as usize) == Some(&slot) {
                        bytes += (page.color.len() + page.depth.len()) as u64;
                        pages += 1;
                        self.upload(&[(id, slot)], std::slice::from_ref(&page));
                    }
                }
                Err(e) => {
                    tracing::warn!(page = id, "page read failed: {e}");
                    self.residency.forget(id, slot);
                    errors.push(format!("page {id}: {e}"));
                }
            }
        }
        (pages, bytes, errors)
    }

    /// The index table as the device sees it: a page's slot where its texels are there.
    fn device_table(&self) -> Vec<u32> {
        self.residency
            .table()
            .iter()
            .enumerate()
            .map(|(page, &slot)| {
                if slot != NOT_RESIDENT && self.slot_data[slot as usize] == page as u32 {
                    slot
                } else {
                    NOT_RESIDENT
                }
            })
            .collect()
    }

    fn render_with(
        &mut self,
        renderer: &TwoPlaneRenderer,
        view: &View,
        options: &TwoPlaneOptions,
        wait: bool,
    ) -> Result<(Frame, PageFrameStats), RenderError> {
        options.validate()?;
        view.basis(DEFAULT_MAX_VIEW_PX)?;
        let start = std::time::Instant::now();
        let predicting = self.config.prefetch == Prefetch::Predict;
        if predicting {
            self.history.push_back(CameraState::of(view, options));
            while self.history.len() > 2 {
                self.history.pop_front();
            }
        }
        // The frame's own projection beside the prediction's (on threads of its own): the
        // planning is all CPU work done while the device waits for it.
        let projector = self.projector();
        let history = &self.history;
        let plan_start = std::time::Instant::now();
        let (projection, (prefetch, probability)) = std::thread::scope(|scope| {
            let prediction =
                predicting.then(|| scope.spawn(move || projector.predict(history, options)));
            let projection = projector.project(view, options, NEEDS_STRIDE);
            let predicted = prediction.map_or_else(
                || (Vec::new(), HashMap::new()),
                |t| t.join().unwrap_or_else(|e| std::panic::resume_unwind(e)),
            );
            (projection, predicted)
        });
        let mut plan_ms = plan_start.elapsed().as_secs_f64() * 1e3;
        let Projection {
            pages: projected,
            max_footprint,
        } = projection?;
        // Pixels that read a downsampled level (a page level from 2 texels, the coarse level
        // from F) are possible where the projected rays reach 90 % of that footprint (the rays
        // include the frame's edges, where the footprint is largest, and between rays it
        // changes by a few per cent at most); otherwise the frame runs the pipeline without the
        // footprint test.
        let overview = self.overview_factor().is_some_and(|f| {
            let least = if self.grid.levels > 1 { 2 } else { f };
            max_footprint >= 0.9 * f64::from(least)
        });
        // The projection, and the shader's feedback of the last frame where it saw more.
        let needed: std::borrow::Cow<'_, [u32]> = if self.missed.is_empty() {
            std::borrow::Cow::Borrowed(&projected)
        } else {
            let mut needed = projected.clone();
            needed.extend(std::mem::take(&mut self.missed));
            needed.sort_unstable();
            needed.dedup();
            std::borrow::Cow::Owned(needed)
        };
        self.frame = self.frame.wrapping_add(1).max(1);
        let frame = self.frame;
        let load_start = std::time::Instant::now();
        let (mut pages_loaded, mut bytes_uploaded, mut read_errors) = self.receive(wait);
        let mut load_ms = load_start.elapsed().as_secs_f64() * 1e3;
        let at_start = self.device_table();
        let plan_start = std::time::Instant::now();
        let loads = self.residency.plan(
            frame,
            &needed,
            &prefetch,
            &probability,
            self.config.pages_per_frame,
        );
        plan_ms += plan_start.elapsed().as_secs_f64() * 1e3;
        let load_start = std::time::Instant::now();
        if wait {
            let ids: Vec<u32> = loads.iter().map(|&(id, _)| id).collect();
            let read = read_pages(&self.source, &ids);
            let (pages, bytes, errors) = self.accept(
                loads
                    .iter()
                    .zip(read)
                    .map(|(&(id, slot), result)| (id, slot, result))
                    .collect(),
            );
            pages_loaded += pages;
            bytes_uploaded += bytes;
            read_errors.extend(errors);
        } else if !loads.is_empty() {
            let loader = match &mut self.loader {
                Some(loader) => loader,
                slot @ None => slot.insert(Loader::start(Arc::clone(&self.source))?),
            };
            if loader.requests.send(loads.clone()).is_ok() {
                loader.in_flight += loads.len();
            } else {
                for &(id, slot) in &loads {
                    self.residency.forget(id, slot);
                }
                read_errors.push("the page loader stopped".to_owned());
            }
        }
        load_ms += load_start.elapsed().as_secs_f64() * 1e3;
        // The table changes with uploads and with the plan's evictions.
        if pages_loaded > 0 || !loads.is_empty() || !read_errors.is_empty() {
            self.write_table();
        }
        let pixels = u64::from(view.width) * u64::from(view.height);
        let uniform = PagingUniform {
            page_shift: self.grid.page_size.trailing_zeros(),
            coarse_shift: self.coarse_factor.trailing_zeros(),
            coarse_res: self.grid.res.map(|n| n.div_ceil(self.coarse_factor)),
            stamp: frame,
            overview_min: self.overview_factor().map_or(f32::INFINITY, |f| f as f32),
            mask_words: pixels.div_ceil(32) as u32,
            levels: self.grid.levels,
            level_min: if self.grid.levels > 1 {
                2.0
            } else {
                f32::INFINITY
            },
            pad: [0; 3],
            level: std::array::from_fn(|l| {
                let l = l as u32;
                if l >= self.grid.levels {
                    return [0; 4];
                }
                let [w, h] = self.grid.level_res(l);
                [
                    self.grid.level_first(l),
                    self.grid.level_pages(l)[0],
                    self.grid.level_per_image(l),
                    w | (h << 16),
                ]
            }),
        };
        self.gpu
            .queue
            .write_buffer(&self.paging, 0, bytemuck::bytes_of(&uniform));
        let mask_bytes = (2 + 2 * pixels.div_ceil(32)) * 4;
        if self.degraded.as_ref().is_none_or(|d| d.0 != pixels) {
            let make = |label, usage| {
                self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: mask_bytes,
                    usage,
                    mapped_at_creation: false,
                })
            };
            let copy = wgpu::BufferUsages::COPY_DST;
            self.degraded = Some((
                pixels,
                make(
                    "degraded pixels",
                    wgpu::BufferUsages::STORAGE | copy | wgpu::BufferUsages::COPY_SRC,
                ),
                make(
                    "degraded pixels readback",
                    wgpu::BufferUsages::MAP_READ | copy,
                ),
            ));
        }
        let Some((_, degraded, degraded_staging)) = &self.degraded else {
            return Err(RenderError::Option("no degraded-pixel buffer".to_owned()));
        };
        self.gpu
            .queue
            .write_buffer(degraded, 0, &vec![0u8; mask_bytes as usize]);
        let frame_out = renderer.dispatch(
            &self.planes,
            self.depth_range,
            &Source::Paged(PagedBinding {
                slot_color: &self.views[0],
                slot_depth: &self.views[1],
                coarse_color: &self.views[2],
                coarse_depth: &self.views[3],
                paging: &self.paging,
                table: &self.table,
                touched: &self.touched,
                degraded,
                touched_staging: &self.touched_staging,
                degraded_staging,
                overview,
            }),
            view,
            options,
        )?;
        let word = |w: &[u8]| u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
        let words = pixels.div_ceil(32) as usize;
        let (touched, (degraded, overview, degraded_mask, overview_mask)) = self
            .gpu
            .map_read_many(&[&self.touched_staging, degraded_staging], |bytes| {
                let touched: Vec<u32> = bytes[0]
                    .chunks_exact(4)
                    .enumerate()
                    .filter(|&(_, w)| word(w) == frame)
                    .map(|(page, _)| page as u32)
                    .collect();
                let all: Vec<u32> = bytes[1].chunks_exact(4).map(word).collect();
                let mask = |first: usize| -> Vec<bool> {
                    (0..pixels as usize)
                        .map(|i| all[first + i / 32] >> (i % 32) & 1 == 1)
                        .collect()
                };
                (touched, (all[0], all[1], mask(2), mask(2 + words)))
            })?;
        let faults = self.residency.touched(frame, &touched, &at_start);
        let on_device = self.device_table();
        self.missed = touched
            .iter()
            .copied()
            .filter(|&p| {
                on_device[p as usize] == NOT_RESIDENT && projected.binary_search(&p).is_err()
            })
            .collect();
        let stats = PageFrameStats {
            faults,
            degraded_px: u64::from(degraded),
            overview_px: u64::from(overview),
            pages_loaded,
            bytes_uploaded,
            pages_pending: self.loader.as_ref().map_or(0, |l| l.in_flight as u32),
            ms: start.elapsed().as_secs_f64() * 1e3,
            pages_touched: touched.len() as u32,
            pages_projected: projected.len() as u32,
            // `projected` is sorted.
            projection_missed: touched
                .iter()
                .filter(|p| projected.binary_search(p).is_err())
                .count() as u32,
            resident: self.residency.resident_count(),
            load_ms,
            plan_ms,
            read_errors,
            degraded_mask,
            overview_mask,
        };
        Ok((frame_out, stats))
    }

    /// [`Self::render`] (or with `wait` false [`Self::render_nowait`]) averaged over `draws`
    /// stratified aperture draws, as [`crate::two_plane_render::accumulate_draws`] averages
    /// them; the stats of every draw merged ([`PageFrameStats::merge`]).
    ///
    /// # Errors
    /// As [`Self::render`]; [`RenderError::Option`] for `draws` outside 1..=`MAX_DRAWS`.
    pub fn render_accumulated(
        &mut self,
        renderer: &TwoPlaneRenderer,
        view: &View,
        options: &TwoPlaneOptions,
        draws: u32,
        wait: bool,
    ) -> Result<(Frame, PageFrameStats), RenderError> {
        let mut stats: Option<PageFrameStats> = None;
        let frame = crate::two_plane_render::accumulate_draws(options, draws, |o| {
            let (frame, s) = self.render_with(renderer, view, o, wait)?;
            match &mut stats {
                Some(total) => total.merge(s),
                None => stats = Some(s),
            }
            Ok(frame)
        })?;
        Ok((frame, stats.unwrap_or_default()))
    }
}

/// One frame of a camera trace (`render --trace`): a DESIGN §3 view (its keys at the top level
/// of the frame) plus optional `focus` and `aperture` (the options' when absent).
#[derive(Clone, Debug, PartialEq)]
pub struct TraceFrame {
    /// The view.
    pub view: View,
    /// Focal plane (world units above st).
    pub focus: Option<f64>,
    /// Aperture radius, uv cells.
    pub aperture: Option<f64>,
}

impl TraceFrame {
    /// `base` with this frame's focus and aperture.
    pub fn options(&self, base: &TwoPlaneOptions) -> TwoPlaneOptions {
        let mut o = *base;
        if let Some(f) = self.focus {
            o.focus = f;
        }
        if let Some(a) = self.aperture {
            o.aperture = a;
        }
        o
    }
}

/// Removes `key` from a trace frame's object: its number, `None` when absent or null.
fn take_number(
    frame: &mut serde_json::Map<String, serde_json::Value>,
    key: &str,
) -> Result<Option<f64>, String> {
    match frame.remove(key) {
        None | Some(serde_json::Value::Null) => Ok(None),
        Some(v) => v
            .as_f64()
            .map(Some)
            .ok_or_else(|| format!("{key} {v} is not a number")),
    }
}

/// Parses a camera trace: a JSON list of [`TraceFrame`]s, each frame's view read as
/// [`View`] reads it (no unknown keys), every view and option checked.
///
/// # Errors
/// [`RenderError::Option`] naming the frame and what is wrong (bad JSON, an empty list, a
/// non-finite number, an invalid view or option).
pub fn parse_trace(text: &str, base: &TwoPlaneOptions) -> Result<Vec<TraceFrame>, RenderError> {
    let frames: Vec<serde_json::Map<String, serde_json::Value>> = serde_json::from_str(text)
        .map_err(|e| RenderError::Option(format!("camera trace: {e}")))?;
    if frames.is_empty() {
        return Err(RenderError::Option("camera trace: no frames".to_owned()));
    }
    frames
        .into_iter()
        .enumerate()
        .map(|(i, mut object)| {
            let bad = |m: String| RenderError::Option(format!("camera trace frame {i}: {m}"));
            let focus = take_number(&mut object, "focus").map_err(bad)?;
            let aperture = take_number(&mut object, "aperture").map_err(bad)?;
            let view: View = serde_json::from_value(serde_json::Value::Object(object))
                .map_err(|e| bad(e.to_string()))?;
            let frame = TraceFrame {
                view,
                focus,
                aperture,
            };
            frame
                .view
                .basis(DEFAULT_MAX_VIEW_PX)
                .map_err(|e| bad(e.to_string()))?;
            frame
                .options(base)
                .validate()
                .map_err(|e| bad(e.to_string()))?;
            Ok(frame)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residency_evicts_by_policy_and_never_what_the_frame_needs() {
        // Two slots, four pages.
        let none = HashMap::new();
        let mut lru = Residency::new(4, 2, Prefetch::Lru);
        assert_eq!(lru.plan(1, &[0, 1], &[], &none, 8), vec![(0, 0), (1, 1)]);
        lru.touched(1, &[0, 1], &[NOT_RESIDENT; 4]);
        lru.touched(2, &[0], lru.table().to_vec().as_slice());
        // Page 1 is the least recently used: page 2 takes its slot.
        assert_eq!(lru.plan(3, &[2], &[], &none, 8), vec![(2, 1)]);
        assert!(lru.resident(0) && lru.resident(2) && !lru.resident(1));
        // FIFO evicts the page loaded first whatever was used since.
        let mut fifo = Residency::new(4, 2, Prefetch::None);
        fifo.plan(1, &[0], &[], &none, 8);
        fifo.plan(2, &[1], &[], &none, 8);
        fifo.touched(3, &[0], fifo.table().to_vec().as_slice());
        assert_eq!(fifo.plan(4, &[2], &[], &none, 8), vec![(2, 0)]);
        // A frame needing more pages than slots loads what fits, evicting none of its own.
        let mut small = Residency::new(4, 2, Prefetch::Lru);
        let loads = small.plan(1, &[0, 1, 2], &[], &none, 8);
        assert_eq!(loads.len(), 2);
        // The per-frame budget caps loads.
        let mut capped = Residency::new(4, 4, Prefetch::Lru);
        assert_eq!(capped.plan(1, &[0, 1, 2, 3], &[], &none, 3).len(), 3);
    }

    #[test]
    fn predictive_policy_prefetches_only_over_less_probable_pages() {
        let mut r = Residency::new(6, 2, Prefetch::Predict);
        let p: HashMap<u32, f32> = [(2, 0.9), (3, 0.5), (4, 0.1)].into_iter().collect();
        // Frame 1 needs page 0; prefetch fills the free slot with the likeliest page.
        assert_eq!(r.plan(1, &[0], &[2, 3, 4], &p, 8), vec![(0, 0), (2, 1)]);
        // Frame 2 needs nothing new: page 0 (probability 0) makes way for page 3, but page 2
        // (0.9) is not evicted for page 4 (0.1).
        let loads = r.plan(2, &[], &[3, 4], &p, 8);
        assert_eq!(loads, vec![(3, 0)]);
        assert!(r.resident(2) && r.resident(3) && !r.resident(4));
    }

    #[test]
    fn prediction_on_threads_equals_the_parameters_in_order() {
        // A 9×9 grid of 512² images in 128² pages, seen from beyond the uv plane while the
        // eye pans, turns, zooms and refocuses at once: every parameter moves.
        let planes = crate::two_plane_io::default_planes([9, 9], [512, 512]);
        let grid = PageGrid::new(&planes, 128);
        let projector = Projector {
            planes: &planes,
            grid: &grid,
            depth_range: [0.5, 1.5],
            overview: None,
        };
        let frame = |x: f64, fov: f64, focus: f64| {
            let view = View {
                eye: [x, 0.2, 6.0],
                target: [0.5 * x, 0.0, 0.0],
                up: [0.0, 1.0, 0.0],
                yfov_deg: fov,
                width: 256,
                height: 256,
            };
            let options = TwoPlaneOptions {
                focus,
                aperture: 0.5,
                ..TwoPlaneOptions::default()
            };
            CameraState::of(&view, &options)
        };
        let history: VecDeque<CameraState> = [frame(-0.4, 30.0, 0.4), frame(-0.1, 33.0, 0.5)]
            .into_iter()
            .collect();
        let options = TwoPlaneOptions {
            focus: 0.5,
            aperture: 0.5,
            ..TwoPlaneOptions::default()
        };
        let (order, probability) = projector.predict(&history, &options);
        // The same sum, one parameter after the other on this thread.
        let (now, before) = (&history[1], &history[0]);
        let mut serial: HashMap<u32, f32> = HashMap::new();
        let mut moved = 0;
        for param in Param::ALL {
            if param.extrapolate(now, before, 1.0).is_some() {
                moved += 1;
            }
            for (page, p) in projector.predicted(param, now, before, &options) {
                *serial.entry(page).or_insert(0.0) += (1.0 / Param::ALL.len() as f32) * p;
            }
        }
        assert!(moved >= 4, "{moved} parameters moved");
        assert!(!probability.is_empty());
        assert_eq!(probability.len(), serial.len());
        for (page, p) in &serial {
            // Bit for bit: the same additions in the same order.
            assert_eq!(probability[page].to_bits(), p.to_bits(), "page {page}");
        }
        assert_eq!(order.len(), probability.len());
        assert!(
            order
                .windows(2)
                .all(|w| probability[&w[0]] >= probability[&w[1]])
        );
    }

    #[test]
    fn faults_count_touched_pages_absent_at_the_frame_start() {
        let mut r = Residency::new(4, 4, Prefetch::Lru);
        let start = r.table().to_vec();
        r.plan(1, &[0, 1], &[], &HashMap::new(), 8);
        assert_eq!(r.touched(1, &[0, 1, 2], &start), 3);
        let start = r.table().to_vec();
        assert_eq!(r.touched(2, &[0, 1, 2], &start), 1);
    }

    #[test]
    fn atlas_holds_every_slot_within_the_side_limit() {
        for slots in [1, 2, 15, 16, 17, 255, 256, 257, 1000, 5000] {
            let (tx, ty, layers) = atlas_shape(slots, 128, 2048);
            assert!(tx * 128 <= 2048 && ty * 128 <= 2048, "{slots}");
            assert!(tx * ty * layers >= slots, "{slots}");
            assert_eq!(Gpu::padded_layers(layers), layers, "{slots}");
            // Less than a row of tiles per layer is wasted.
            assert!(tx * ty * layers - slots < tx * layers, "{slots}");
        }
    }

    /// A grid of `cameras` images of `res` texels in pages of `page_size` with `levels` levels.
    fn grid_of(res: [u32; 2], page_size: u32, cameras: u32, levels: u32) -> PageGrid {
        PageGrid {
            page_size,
            pages: res.map(|n| n.div_ceil(page_size)),
            cameras,
            res,
            levels,
        }
    }

    /// A grid of 5 cameras of 100 × 37 texels in pages of 16 with 4 levels (100 × 37, 50 × 19,
    /// 25 × 10, 13 × 5 texels).
    fn levelled_grid() -> PageGrid {
        grid_of([100, 37], 16, 5, 4)
    }

    #[test]
    fn page_ids_number_every_page_of_every_level_once() {
        let grid = levelled_grid();
        assert_eq!(grid.level_res(3), [13, 5]);
        assert_eq!(
            (1..4).map(|l| grid.level_pages(l)).collect::<Vec<_>>(),
            vec![[4, 2], [2, 1], [1, 1]]
        );
        assert_eq!(grid.all_pages(), 5 * (21 + 8 + 2 + 1));
        let mut next = 0;
        for level in 0..grid.levels {
            let [columns, rows] = grid.level_pages(level);
            for camera in 0..grid.cameras {
                let (mut width, mut height) = (0, 0);
                for row in 0..rows {
                    for column in 0..columns {
                        let id = grid.id(level, camera, column, row);
                        assert_eq!(id, next, "level {level} camera {camera}");
                        next += 1;
                        let page = row * columns + column;
                        assert_eq!(grid.locate(id), (level, camera, page));
                        let (x, y, w, h) = grid.level_rect(level, page);
                        assert!(w > 0 && h > 0 && w <= 16 && h <= 16);
                        if y == 0 {
                            width += w;
                        }
                        if x == 0 {
                            height += h;
                        }
                    }
                }
                assert_eq!([width, height], grid.level_res(level), "level {level}");
            }
        }
        assert_eq!(next, grid.all_pages());
        assert_eq!(grid.with_levels(0).levels, 1);
        assert_eq!(grid.with_levels(99).levels, MAX_PAGE_LEVELS);
    }

    /// The levels built from level-1 sums and halving equal each 2^l block's rounded mean
    /// colour and nearest depth computed directly, odd sizes (partial blocks) included.
    #[test]
    fn level_sums_are_block_means_and_nearest_depths() {
        let res = [37u32, 23u32];
        let texel = |x: u32, y: u32| -> ([u8; 4], f32) {
            let h = x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503);
            let color = [(h % 251) as u8, (h / 7 % 256) as u8, (x * 6) as u8, 255];
            let depth = if h.is_multiple_of(5) {
                f32::INFINITY
            } else {
                (h % 1000) as f32 / 1000.0
            };
            (color, depth)
        };
        let mut sums = LevelSums::new([0, 0], res.map(|n| n.div_ceil(2)));
        for y in 0..res[1] {
            for x in 0..res[0] {
                let (c, d) = texel(x, y);
                sums.add(x, y, 1, &c, d);
            }
        }
        for level in 1..5u32 {
            let (color, near) = sums.texels();
            let size = res.map(|n| n.div_ceil(1 << level));
            assert_eq!(sums.res, size);
            for by in 0..size[1] {
                for bx in 0..size[0] {
                    let mut total = [0u32; 4];
                    let (mut n, mut depth) = (0, f32::INFINITY);
                    for y in (by << level)..((by + 1) << level).min(res[1]) {
                        for x in (bx << level)..((bx + 1) << level).min(res[0]) {
                            let (c, d) = texel(x, y);
                            for i in 0..4 {
                                total[i] += u32::from(c[i]);
                            }
                            n += 1;
                            depth = depth.min(d);
                        }
                    }
                    let k = (by * size[0] + bx) as usize;
                    let mean = total.map(|t| ((t + n / 2) / n) as u8);
                    assert_eq!(
                        &color[4 * k..4 * k + 4],
                        &mean,
                        "level {level} ({bx}, {by})"
                    );
                    assert_eq!(
                        near[k].to_bits(),
                        depth.to_bits(),
                        "level {level} ({bx}, {by})"
                    );
                }
            }
            // Cut into pages of 8 (as the store keeps them): each texel where `texels` has it.
            let grid = grid_of(res, 8, 3, 5);
            let first = grid.level_first(1);
            for (k, raw) in sums.pages(&grid, level, 2, first) {
                let (l, camera, page) = grid.locate(k as u32 + first);
                assert_eq!((l, camera), (level, 2));
                let (x0, y0, w, h) = grid.level_rect(level, page);
                let n = (w * h) as usize;
                assert_eq!(raw.len(), 8 * n);
                for (i, (x, y)) in (y0..y0 + h)
                    .flat_map(|y| (x0..x0 + w).map(move |x| (x, y)))
                    .enumerate()
                {
                    let at = (y * size[0] + x) as usize;
                    assert_eq!(&raw[4 * i..4 * i + 4], &color[4 * at..4 * at + 4]);
                    assert_eq!(
                        &raw[4 * n + 4 * i..4 * n + 4 * i + 4],
                        &near[at].to_le_bytes()
                    );
                }
            }
            sums = sums.halve();
        }
    }

    /// A camera's levels built in tiles (4 × 2 tiles of 32 texels here, partial ones at the
    /// right and bottom) equal the levels of the whole image's sums: every page of every level,
    /// the coarse level and the depth range; a NaN depth is refused.
    #[test]
    fn camera_levels_in_tiles_equal_the_whole_image() {
        let res = [100u32, 37u32];
        let grid = grid_of(res, 8, 2, 3);
        let texel = |x: u32, y: u32| -> ([u8; 4], f32) {
            let h = x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503);
            let d = if h.is_multiple_of(7) {
                f32::INFINITY
            } else {
                0.2 + (h % 997) as f32 / 2000.0
            };
            (
                [
                    (h % 256) as u8,
                    (x * 2) as u8,
                    (y * 5) as u8,
                    (h % 200) as u8,
                ],
                d,
            )
        };
        let camera = 1;
        let mut pages: Vec<LoadedPage> = (0..grid.per_image())
            .map(|number| {
                let (x0, y0, w, h) = grid.rect(number);
                let (mut color, mut depth) = (Vec::new(), Vec::new());
                for y in y0..y0 + h {
                    for x in x0..x0 + w {
                        let (c, d) = texel(x, y);
                        color.extend_from_slice(&c);
                        depth.extend_from_slice(&d.to_le_bytes());
                    }
                }
                LoadedPage {
                    id: camera * grid.per_image() + number,
                    color,
                    depth,
                }
            })
            .collect();
        let built = camera_levels(&grid, 3, camera, &pages).expect("levels");
        // The whole image's sums, level by level.
        let mut sums = LevelSums::new([0, 0], grid.level_res(1));
        let mut range = [f32::INFINITY, f32::NEG_INFINITY];
        for y in 0..res[1] {
            for x in 0..res[0] {
                let (c, d) = texel(x, y);
                sums.add(x, y, 1, &c, d);
                if d.is_finite() {
                    range = [range[0].min(d), range[1].max(d)];
                }
            }
        }
        let first = grid.level_first(1);
        let mut expected = sums.pages(&grid, 1, camera, first);
        sums = sums.halve();
        expected.extend(sums.pages(&grid, 2, camera, first));
        sums = sums.halve();
        let mut got = built.pages;
        got.sort();
        expected.sort();
        assert_eq!(got.len(), 7 * 3 + 4 * 2);
        assert_eq!(got, expected);
        let (color, depth) = sums.texels();
        assert_eq!(built.color, color);
        assert_eq!(
            built.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(built.range, range);
        pages[3].depth[..4].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(camera_levels(&grid, 3, camera, &pages).is_err());
    }

    #[test]
    fn level_store_reads_back_what_it_stored() {
        let grid = levelled_grid();
        assert!(
            LevelStore::new(&grid.with_levels(1))
                .expect("store")
                .file
                .is_none()
        );
        let mut store = LevelStore::new(&grid).expect("store");
        let pages = (grid.all_pages() - grid.level_first(1)) as usize;
        assert_eq!(store.index.len(), pages);
        let page = |k: usize| -> (Vec<u8>, Vec<u8>) {
            let color = (0..k * 4 + 4).map(|i| (i * 7 + k) as u8).collect();
            let depth = (0..=k)
                .flat_map(|i| (i as f32 * 0.5).to_le_bytes())
                .collect();
            (color, depth)
        };
        // Out of order, as any order of pages would be, in two calls.
        let all: Vec<(usize, Vec<u8>)> = (0..pages)
            .rev()
            .map(|k| {
                let (c, d) = page(k);
                (k, [c, d].concat())
            })
            .collect();
        let (first, second) = all.split_at(pages / 3);
        store.put(first).expect("put");
        store.put(second).expect("put");
        for k in 0..pages {
            assert_eq!(store.get(k, k + 1).expect("get"), page(k), "page {k}");
        }
        assert!(store.get(pages, 1).is_err());
        assert!(store.put(&[(pages, vec![0; 8])]).is_err());
        assert!(LevelStore::default().put(&[(0, vec![0; 8])]).is_err());
        // A texel count that does not match what was stored is an error, not a short page.
        assert!(store.get(3, 5).is_err());
    }

    #[test]
    fn traces_reject_nan_and_bad_views() {
        let base = TwoPlaneOptions::default();
        let good = r#"[{"eye":[0,0,3],"target":[0,0,0],"yfov_deg":40,"width":64,"height":64,"focus":0.5}]"#;
        let frames = parse_trace(good, &base).expect("a good trace parses");
        assert_eq!(frames[0].options(&base).focus, 0.5);
        for bad in [
            "[]",
            "{}",
            r#"[{"eye":[0,0,3],"target":[0,0,0],"yfov_deg":40,"width":64,"height":64,"zoom":1}]"#,
            r#"[{"eye":[0,0,3],"target":[0,0,3],"yfov_deg":40,"width":64,"height":64}]"#,
            r#"[{"eye":[0,0,3],"target":[0,0,0],"yfov_deg":400,"width":64,"height":64}]"#,
            r#"[{"eye":[0,0,3],"target":[0,0,0],"yfov_deg":40,"width":64,"height":64,"aperture":-1}]"#,
            r#"[{"eye":[0,0,1e400],"target":[0,0,0],"yfov_deg":40,"width":64,"height":64}]"#,
            r#"[{"eye":[0,0,3],"target":[0,0,0],"yfov_deg":40,"width":64,"height":64,"focus":"near"}]"#,
        ] {
            assert!(
                matches!(parse_trace(bad, &base), Err(RenderError::Option(_))),
                "{bad}"
            );
        }
    }
}
