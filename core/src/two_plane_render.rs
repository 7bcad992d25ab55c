//! Rendering two-plane light fields on the GPU (DESIGN §9; `shaders/shared/two_plane.wgsl`,
//! docs/two_plane.md): one compute pass per frame with a uv filter (nearest, bilinear, the
//! seed's dither, or depth-corrected), refocus at a focal plane and a synthetic aperture.
//!
//! The cameras' images live in two texture arrays, one layer per camera (the seed's mosaic as an
//! array: bilinear in (s, t) inside a layer, never filtered across (u, v)): RGBA8 colour and
//! R32F depth. Everything the shader sees is relative to the st plane's centre, in f32.

use std::sync::{Arc, Mutex, PoisonError};

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::asset::{AssetError, AssetFile, Channel, ImageKey};
use crate::frame::{Frame, FrameStats};
use crate::gpu::{
    Gpu, buffer_entry, empty_texture_array, empty_texture_array_with_mips, texture_entry,
};
use crate::render::RenderError;
use crate::two_plane::TwoPlanes;
use crate::view::{DEFAULT_MAX_VIEW_PX, View};

/// How the cameras around a ray's uv crossing are combined (`--uv-filter`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase", try_from = "String")]
pub enum UvFilter {
    /// The nearest camera.
    Nearest,
    /// The four cameras around the crossing, bilinear weights (quadrilinear with the st
    /// lookup).
    #[default]
    Bilinear,
    /// The nearest camera of a uv position moved by the pixel's 4×4 Bayer threshold along a
    /// hashed diagonal (seed 001 §3.1): one camera per pixel, the bilinear blend on average.
    Dither,
    /// Depth-corrected: the ray is marched through the nearest camera's depth to the surface,
    /// and the four cameras around the crossing are read where the ray meets it, each only if
    /// it sees that surface there.
    Depth,
}

impl UvFilter {
    /// Every filter, in the order of the quality tables.
    pub const ALL: [UvFilter; 4] = [
        UvFilter::Nearest,
        UvFilter::Bilinear,
        UvFilter::Dither,
        UvFilter::Depth,
    ];

    /// The name used by the CLI, HTTP and Python.
    pub fn name(self) -> &'static str {
        match self {
            UvFilter::Nearest => "nearest",
            UvFilter::Bilinear => "bilinear",
            UvFilter::Dither => "dither",
            UvFilter::Depth => "depth",
        }
    }

    fn code(self) -> u32 {
        match self {
            UvFilter::Nearest => 0,
            UvFilter::Bilinear => 1,
            UvFilter::Dither => 2,
            UvFilter::Depth => 3,
        }
    }
}

impl std::fmt::Display for UvFilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for UvFilter {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        UvFilter::ALL
            .into_iter()
            .find(|f| f.name() == s)
            .ok_or_else(|| format!("uv filter {s:?}: choose nearest, bilinear, dither or depth"))
    }
}

impl TryFrom<String> for UvFilter {
    type Error = String;

    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

/// Default march steps of the depth-corrected filter over the asset's depth range.
pub const DEFAULT_STEPS: u32 = 48;
/// Default dither amplitude, in uv cells: thresholds in (−½, ½) cells, so that a pixel picks
/// each of two neighbouring cameras with its bilinear weight on average.
pub const DEFAULT_DITHER_AMPLITUDE: f32 = 1.0;
/// Default number of cameras a synthetic aperture reads per pixel and frame; wider apertures
/// draw a stratified subset each frame ([`TwoPlaneOptions::sample_budget`]).
pub const DEFAULT_SAMPLE_BUDGET: u32 = 36;
/// Largest aperture radius, in uv cells.
pub const MAX_APERTURE: f64 = 64.0;
/// Most march steps.
pub const MAX_STEPS: u32 = 1024;

/// How to render a two-plane light field.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TwoPlaneOptions {
    /// uv filter (with `aperture` 0).
    pub uv_filter: UvFilter,
    /// Focal plane: signed distance from the st plane towards the uv plane, world units (DESIGN
    /// §9). 0 reads every camera at the ray's own st crossing.
    pub focus: f64,
    /// Synthetic aperture radius R in uv cells: 0 is the pinhole view through `uv_filter`;
    /// R > 0 weights every camera within R + ½ cells per axis by
    /// `clamp(R + ½ − |Δa|, 0, 1) · clamp(R + ½ − |Δb|, 0, 1)` (the 2R + 1 cameras around the
    /// nearest one per axis for whole R, with a half-cell linear edge either side of the box's
    /// border so the weights move smoothly with the view: at most (2R + 1)² cameras), each read
    /// at the
    /// focal plane's point.
    pub aperture: f64,
    /// March steps of the depth-corrected filter over the asset's depth range.
    pub steps: u32,
    /// Depth-corrected filter: a camera joins the blend when the surface it sees where the ray
    /// meets the marched surface is within this height (world units) of it; `None`: three
    /// march steps.
    pub tolerance: Option<f64>,
    /// Dither amplitude in uv cells.
    pub dither_amplitude: f32,
    /// Most cameras an aperture reads per pixel per frame; a wider aperture draws one camera
    /// per stratum of its window, a new draw for each `frame_index`, and frames averaged over
    /// indices converge to the full aperture.
    pub sample_budget: u32,
    /// Which stratified draw of a wide aperture this frame uses.
    pub frame_index: u32,
    /// Colour of empty pixels (RGBA8).
    pub background: [u8; 4],
}

impl Default for TwoPlaneOptions {
    fn default() -> Self {
        Self {
            uv_filter: UvFilter::default(),
            focus: 0.0,
            aperture: 0.0,
            steps: DEFAULT_STEPS,
            tolerance: None,
            dither_amplitude: DEFAULT_DITHER_AMPLITUDE,
            sample_budget: DEFAULT_SAMPLE_BUDGET,
            frame_index: 0,
            background: [0, 0, 0, 0],
        }
    }
}

impl TwoPlaneOptions {
    /// Checks every value.
    ///
    /// # Errors
    /// [`RenderError::Option`] naming the bad value.
    pub fn validate(&self) -> Result<(), RenderError> {
        let bad = |m: String| Err(RenderError::Option(m));
        if !self.focus.is_finite() {
            return bad(format!("focus {} must be finite", self.focus));
        }
        if !(self.aperture.is_finite() && (0.0..=MAX_APERTURE).contains(&self.aperture)) {
            return bad(format!(
                "aperture {} must be in 0..={MAX_APERTURE} uv cells",
                self.aperture
            ));
        }
        if !(1..=MAX_STEPS).contains(&self.steps) {
            return bad(format!("steps {} must be in 1..={MAX_STEPS}", self.steps));
        }
        if let Some(t) = self.tolerance
            && !(t.is_finite() && t > 0.0)
        {
            return bad(format!("tolerance {t} must be finite and positive"));
        }
        if !(self.dither_amplitude.is_finite() && (0.0..=4.0).contains(&self.dither_amplitude)) {
            return bad(format!(
                "dither amplitude {} must be in 0..=4 cells",
                self.dither_amplitude
            ));
        }
        if !(1..=4096).contains(&self.sample_budget) {
            return bad(format!(
                "sample budget {} must be in 1..=4096 cameras",
                self.sample_budget
            ));
        }
        Ok(())
    }
}

/// A two-plane light field on the device.
pub struct GpuTwoPlane {
    /// Its planes.
    pub planes: TwoPlanes,
    /// Smallest and largest finite stored depth (`[1, 1]` when nothing is hit).
    pub depth_range: [f32; 2],
    /// Device bytes of its textures.
    pub bytes: u64,
    gpu: Arc<Gpu>,
    color: wgpu::Texture,
    depth: wgpu::Texture,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
}

impl GpuTwoPlane {
    /// The device its textures live on.
    pub fn gpu(&self) -> &Arc<Gpu> {
        &self.gpu
    }
}

impl Drop for GpuTwoPlane {
    fn drop(&mut self) {
        self.color.destroy();
        self.depth.destroy();
    }
}

/// Device bytes [`TwoPlaneRenderer::upload`] allocates for `planes`: RGBA8 and R32F per texel,
/// for every camera (layers padded as [`Gpu::padded_layers`] does).
pub fn field_bytes(planes: &TwoPlanes) -> u64 {
    field_bytes_with(planes, None)
}

/// [`field_bytes`] of colour kept block-compressed by `color_codec` on the device (what a
/// device that samples BC textures allocates).
pub fn field_bytes_with(planes: &TwoPlanes, color_codec: Option<crate::asset::BlockCodec>) -> u64 {
    let [ns, nt] = planes.st.resolution;
    let color = color_codec.map_or(u64::from(ns) * u64::from(nt) * 4, |c| {
        c.stored_bytes(ns, nt)
    });
    let depth: u64 = depth_bound_sizes([ns, nt])
        .map(|[w, h]| u64::from(w) * u64::from(h) * 4)
        .sum();
    u64::from(Gpu::padded_layers(planes.camera_count())) * (color + depth)
}

/// Sizes of the depth texture's mip levels, level 0 (the stored depth) first: `max(1, side >>
/// level)` down to 1 × 1, as the device allocates them.
fn depth_bound_sizes([w, h]: [u32; 2]) -> impl Iterator<Item = [u32; 2]> {
    let levels = u32::BITS - w.max(h).max(1).leading_zeros();
    (0..levels).map(move |l| [(w >> l).max(1), (h >> l).max(1)])
}

/// The depth pyramid above one camera's stored depths (`w × h`, finite or +inf): level `l`
/// (from 1) holds the smallest depth, the highest surface, of its block of level 0. Texel `x`
/// of a level covers texels `2x` and `2x + 1` of the level below, and the last one also covers
/// what is left of an odd row or column, so the block of level-0 texel `t` at level `l` is
/// `min(t >> l, size_l − 1)` and every texel lies in exactly one block.
/// The depth-corrected march skips ray segments that lie above every block they project to.
fn depth_bound_levels(depth: &[f32], [w, h]: [u32; 2]) -> Vec<Vec<f32>> {
    let sizes: Vec<[u32; 2]> = depth_bound_sizes([w, h]).collect();
    let mut levels: Vec<Vec<f32>> = Vec::with_capacity(sizes.len().saturating_sub(1));
    for pair in sizes.windows(2) {
        let ([pw, ph], [nw, nh]) = (pair[0], pair[1]);
        let below = levels.last().map_or(depth, Vec::as_slice);
        // Texels of the level below that texel `x` of `n` covers (`p` below).
        let span = |x: u32, n: u32, p: u32| {
            (2 * x) as usize..=(if x + 1 == n { p - 1 } else { 2 * x + 1 }) as usize
        };
        let level = (0..nh)
            .flat_map(|y| (0..nw).map(move |x| (x, y)))
            .map(|(x, y)| {
                span(y, nh, ph)
                    .flat_map(|row| below[row * pw as usize..][span(x, nw, pw)].iter())
                    .fold(f32::INFINITY, |m, &d| m.min(d))
            })
            .collect();
        levels.push(level);
    }
    levels
}

struct Outputs {
    pixels: u64,
    uniform: wgpu::Buffer,
    color: wgpu::Buffer,
    depth: wgpu::Buffer,
    /// A staging copy, where the adapter cannot map the buffers the shader writes.
    staging: Option<wgpu::Buffer>,
}

/// The two-plane renderer: one pipeline, output buffers reused across frames of a size.
pub struct TwoPlaneRenderer {
    gpu: Arc<Gpu>,
    module: wgpu::ShaderModule,
    pipeline_layout: wgpu::PipelineLayout,
    /// One pipeline per uv filter, and one for the aperture, without and with the depth
    /// pyramid, compiled on first use.
    pipelines: [std::sync::OnceLock<wgpu::ComputePipeline>; 10],
    /// Whether the depth-corrected march skips samples above the depth pyramid's bound.
    depth_pyramid: bool,
    layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    outputs: Mutex<Option<Outputs>>,
    /// The paged variant (`shaders/two_plane_paged.wgsl`), built on first use.
    paged: std::sync::OnceLock<PagedPipelines>,
}

/// The pipelines of the paged renderer ([`crate::page_cache`]).
struct PagedPipelines {
    module: wgpu::ShaderModule,
    pipeline_layout: wgpu::PipelineLayout,
    layout: wgpu::BindGroupLayout,
    /// Per mode, without and with overview pixels.
    pipelines: [std::sync::OnceLock<wgpu::ComputePipeline>; 10],
}

/// What a paged frame binds besides the parameters and outputs: the cache's slot atlases, its
/// coarse level, the paging uniform, the index table and the feedback buffers (pages touched,
/// degraded pixels), and where the feedback is copied for reading back
/// ([`crate::page_cache`]).
pub(crate) struct PagedBinding<'a> {
    pub slot_color: &'a wgpu::TextureView,
    pub slot_depth: &'a wgpu::TextureView,
    pub coarse_color: &'a wgpu::TextureView,
    pub coarse_depth: &'a wgpu::TextureView,
    pub paging: &'a wgpu::Buffer,
    pub table: &'a wgpu::Buffer,
    pub touched: &'a wgpu::Buffer,
    pub degraded: &'a wgpu::Buffer,
    pub touched_staging: &'a wgpu::Buffer,
    pub degraded_staging: &'a wgpu::Buffer,
    /// Whether the frame may have overview pixels (the pipeline's `OVERVIEW`).
    pub overview: bool,
}

/// The images a frame reads: every camera resident, or pages through a cache.
pub(crate) enum Source<'a> {
    Resident(&'a GpuTwoPlane),
    Paged(PagedBinding<'a>),
}

fn texture_binding(binding: u32, view: &wgpu::TextureView) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: wgpu::BindingResource::TextureView(view),
    }
}

fn buffer_binding(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}

/// The pipeline of a mode (the uv filter's, or the aperture's) from `module`, compiled once into
/// `slots`; `overview` specialises the paged shader's `OVERVIEW` (`None` for the resident
/// shader, which has no such override), doubling the slots.
fn mode_pipeline<'p, const N: usize>(
    gpu: &Gpu,
    slots: &'p [std::sync::OnceLock<wgpu::ComputePipeline>; N],
    module: &wgpu::ShaderModule,
    layout: &wgpu::PipelineLayout,
    options: &TwoPlaneOptions,
    (flag, on): (&str, bool),
) -> &'p wgpu::ComputePipeline {
    let aperture = options.aperture > 0.0;
    let mode = if aperture {
        4
    } else {
        options.uv_filter.code() as usize
    };
    let slot = mode + if on { 5 } else { 0 };
    slots[slot].get_or_init(|| {
        let constants = [
            ("MODE", f64::from(options.uv_filter.code())),
            ("APERTURE", if aperture { 1.0 } else { 0.0 }),
            (flag, if on { 1.0 } else { 0.0 }),
        ];
        gpu.device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("two-plane"),
                layout: Some(layout),
                module,
                entry_point: Some("cs_main"),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    ..Default::default()
                },
                cache: None,
            })
    })
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    eye: [f32; 3],
    focus: f32,
    forward: [f32; 3],
    focal_px: f32,
    view_right: [f32; 3],
    aperture: f32,
    view_up: [f32; 3],
    dither_amp: f32,
    normal: [f32; 3],
    separation: f32,
    right: [f32; 3],
    h_hi: f32,
    up: [f32; 3],
    h_lo: f32,
    uv_center: [f32; 3],
    tolerance: f32,
    uv_size: [f32; 2],
    st_size: [f32; 2],
    grid: [u32; 2],
    res: [u32; 2],
    size: [u32; 2],
    pad1: u32,
    steps: u32,
    background: u32,
    sample_budget: u32,
    frame_index: u32,
    pad0: u32,
}

fn f3(v: DVec3) -> [f32; 3] {
    v.as_vec3().to_array()
}

impl TwoPlaneRenderer {
    /// Builds the pipeline.
    pub fn new(gpu: Arc<Gpu>) -> TwoPlaneRenderer {
        let device = &gpu.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("two_plane.wgsl"),
            source: wgpu::ShaderSource::Wgsl(crate::shaders::TWO_PLANE.into()),
        });
        let storage = wgpu::BufferBindingType::Storage { read_only: false };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("two-plane"),
            entries: &[
                buffer_entry(0, wgpu::BufferBindingType::Uniform),
                texture_entry(1, true),
                texture_entry(2, false),
                buffer_entry(3, storage),
                buffer_entry(4, storage),
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("two-plane st"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("two-plane"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        TwoPlaneRenderer {
            gpu,
            module,
            pipeline_layout,
            pipelines: Default::default(),
            layout,
            sampler,
            outputs: Mutex::new(None),
            paged: std::sync::OnceLock::new(),
            depth_pyramid: true,
        }
    }

    /// The renderer whose depth-corrected march reads every sample instead of skipping those the
    /// depth pyramid shows to lie above every surface (the skips change no pixel: this is the
    /// reference they are tested and measured against).
    #[must_use]
    pub fn reading_every_sample(self) -> TwoPlaneRenderer {
        TwoPlaneRenderer {
            depth_pyramid: false,
            ..self
        }
    }

    /// The paged renderer's module and layouts.
    fn paged(&self) -> &PagedPipelines {
        self.paged.get_or_init(|| {
            let device = &self.gpu.device;
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("two_plane_paged.wgsl"),
                source: wgpu::ShaderSource::Wgsl(crate::shaders::TWO_PLANE_PAGED.into()),
            });
            let storage = wgpu::BufferBindingType::Storage { read_only: false };
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("two-plane paged"),
                entries: &[
                    buffer_entry(0, wgpu::BufferBindingType::Uniform),
                    texture_entry(1, false),
                    texture_entry(2, false),
                    buffer_entry(3, storage),
                    buffer_entry(4, storage),
                    buffer_entry(5, wgpu::BufferBindingType::Uniform),
                    buffer_entry(6, wgpu::BufferBindingType::Storage { read_only: true }),
                    texture_entry(7, false),
                    texture_entry(8, false),
                    buffer_entry(9, storage),
                    buffer_entry(10, storage),
                ],
            });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("two-plane paged"),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            PagedPipelines {
                module,
                pipeline_layout,
                layout,
                pipelines: Default::default(),
            }
        })
    }

    /// The device.
    pub fn gpu(&self) -> &Arc<Gpu> {
        &self.gpu
    }

    /// Uploads a two-plane asset, one camera at a time (every page's checksum verified).
    ///
    /// # Errors
    /// [`RenderError::Asset`] for another kind ([`AssetError::Kind`]) or a bad file,
    /// [`RenderError::Gpu`] when the cameras exceed the device's array layers or the device
    /// fails.
    pub fn upload(&self, asset: &AssetFile) -> Result<GpuTwoPlane, RenderError> {
        let header = asset.header();
        let planes = *header.two_plane().ok_or(AssetError::Kind {
            what: "the two-plane renderer",
            kind: header.kind,
        })?;
        let cameras = planes.camera_count();
        let layers = Gpu::padded_layers(cameras);
        self.gpu.check_layers(layers)?;
        let [ns, nt] = planes.st.resolution;
        let limit = self.gpu.device.limits().max_texture_dimension_2d;
        if ns > limit || nt > limit {
            return Err(RenderError::Option(format!(
                "st resolution {ns}x{nt} exceeds the device's {limit} texels per side"
            )));
        }
        let make = |label, format| empty_texture_array(&self.gpu, label, format, [ns, nt, layers]);
        let sizes: Vec<[u32; 2]> = depth_bound_sizes([ns, nt]).collect();
        // Block-compressed colour stays compressed where the device samples it cheaply
        // ([`Gpu::keeps_compressed`]).
        let blocks = asset
            .compression(Channel::Color)
            .filter(|&codec| self.gpu.keeps_compressed(codec))
            .and_then(|codec| Some((codec, codec.texture_format()?)));
        let color_format = blocks.map_or(wgpu::TextureFormat::Rgba8Unorm, |(_, f)| f);
        let color = make("two-plane colour", color_format);
        // The stored depths with their pyramid of smallest depths above them.
        let depth = empty_texture_array_with_mips(
            &self.gpu,
            "two-plane depth",
            wgpu::TextureFormat::R32Float,
            [ns, nt, layers],
            sizes.len() as u32,
        );
        let write = |texture, mip_level, z, data: &[u8], row_bytes, [w, h]: [u32; 2], rows| {
            self.gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level,
                    origin: wgpu::Origin3d { x: 0, y: 0, z },
                    aspect: wgpu::TextureAspect::All,
                },
                data,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row_bytes),
                    rows_per_image: Some(rows),
                },
                wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: 1,
                },
            );
        };
        let mut range = [f32::INFINITY, f32::NEG_INFINITY];
        for camera in 0..cameras {
            let key = ImageKey::new(0, 0, camera, Channel::Color);
            match blocks {
                Some((codec, _)) => write(
                    &color,
                    0,
                    camera,
                    &asset.read_image_blocks(key)?,
                    ns / crate::asset::BLOCK * codec.block_bytes(),
                    [ns, nt],
                    nt / crate::asset::BLOCK,
                ),
                None => write(
                    &color,
                    0,
                    camera,
                    &asset.read_image(key)?,
                    ns * 4,
                    [ns, nt],
                    nt,
                ),
            }
            let image = asset.read_image(ImageKey::new(0, 0, camera, Channel::Depth))?;
            let stored: Vec<f32> = image
                .chunks_exact(4)
                .map(|d| f32::from_le_bytes([d[0], d[1], d[2], d[3]]))
                .collect();
            for &d in &stored {
                if d.is_finite() {
                    range = [range[0].min(d), range[1].max(d)];
                } else if !(d.is_infinite() && d > 0.0) {
                    return Err(RenderError::Asset(AssetError::Header(format!(
                        "camera {camera} stores depth {d}: two-plane depth is finite or +inf"
                    ))));
                }
            }
            write(&depth, 0, camera, &image, ns * 4, [ns, nt], nt);
            for (level, (texels, [w, h])) in depth_bound_levels(&stored, [ns, nt])
                .iter()
                .zip(sizes.iter().skip(1).copied())
                .enumerate()
            {
                let bytes: &[u8] = bytemuck::cast_slice(texels);
                write(&depth, level as u32 + 1, camera, bytes, w * 4, [w, h], h);
            }
        }
        self.gpu.wait()?;
        if !(range[0] <= range[1]) {
            range = [1.0, 1.0];
        }
        let view = |t: &wgpu::Texture| crate::gpu::array_view(t);
        Ok(GpuTwoPlane {
            gpu: Arc::clone(&self.gpu),
            planes,
            depth_range: range,
            bytes: field_bytes_with(&planes, blocks.map(|(codec, _)| codec)),
            color_view: view(&color),
            depth_view: view(&depth),
            color,
            depth,
        })
    }

    /// Renders `view` (DESIGN §3) of `field`: pixels whose ray is outside the light field, or
    /// that see nothing, are `options.background` with depth `+inf`; the others are opaque
    /// with the z-depth of the surface along the view's forward axis (the depth-corrected
    /// surface, or the surface stored by the highest-weighted camera).
    ///
    /// # Errors
    /// [`RenderError::View`], [`RenderError::Option`], [`RenderError::Gpu`].
    pub fn render(
        &self,
        field: &GpuTwoPlane,
        view: &View,
        options: &TwoPlaneOptions,
    ) -> Result<Frame, RenderError> {
        self.dispatch(
            &field.planes,
            field.depth_range,
            &Source::Resident(field),
            view,
            options,
        )
    }

    /// Renders `view` of the light field with `planes` and stored depths in `depth_range`,
    /// reading the images from `source`.
    pub(crate) fn dispatch(
        &self,
        planes: &TwoPlanes,
        depth_range: [f32; 2],
        source: &Source<'_>,
        view: &View,
        options: &TwoPlaneOptions,
    ) -> Result<Frame, RenderError> {
        options.validate()?;
        let max_px = DEFAULT_MAX_VIEW_PX.min(self.gpu.device.limits().max_texture_dimension_2d);
        let basis = view.basis(max_px)?;
        let start = std::time::Instant::now();
        let p = planes;
        let origin = DVec3::from(p.st.center);
        let (right, up) = p.axes();
        let separation = p.separation();
        let (h_hi, h_lo) = march_heights(separation, depth_range);
        let tolerance = options
            .tolerance
            .unwrap_or(3.0 * (h_hi - h_lo) / f64::from(options.steps));
        let params = Params {
            eye: f3(basis.eye - origin),
            focus: options.focus as f32,
            forward: f3(basis.forward),
            focal_px: basis.focal_px as f32,
            view_right: f3(basis.right),
            aperture: options.aperture as f32,
            view_up: f3(basis.true_up),
            dither_amp: options.dither_amplitude,
            normal: f3(p.normal()),
            separation: separation as f32,
            right: f3(right),
            h_hi: h_hi as f32,
            up: f3(up),
            h_lo: h_lo as f32,
            uv_center: f3(DVec3::from(p.uv.center) - origin),
            tolerance: tolerance as f32,
            uv_size: p.uv.size.map(|x| x as f32),
            st_size: p.st.size.map(|x| x as f32),
            grid: p.uv.grid,
            res: p.st.resolution,
            size: [basis.width, basis.height],
            pad1: 0,
            steps: options.steps,
            background: u32::from_le_bytes(options.background),
            sample_budget: options.sample_budget,
            frame_index: options.frame_index,
            pad0: 0,
        };
        let device = &self.gpu.device;
        let pixels = u64::from(basis.width) * u64::from(basis.height);
        let mut guard = self.outputs.lock().unwrap_or_else(PoisonError::into_inner);
        if guard.as_ref().is_none_or(|o| o.pixels != pixels) {
            let make = |label, size, usage| {
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size,
                    usage,
                    mapped_at_creation: false,
                })
            };
            // On a CPU adapter the results are mapped where the shader wrote them.
            let direct = self.gpu.maps_primary_buffers();
            let out = wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | if direct {
                    wgpu::BufferUsages::MAP_READ
                } else {
                    wgpu::BufferUsages::empty()
                };
            *guard = Some(Outputs {
                pixels,
                uniform: make(
                    "two-plane params",
                    std::mem::size_of::<Params>() as u64,
                    wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                ),
                color: make("two-plane colour", pixels * 4, out),
                depth: make("two-plane depth", pixels * 4, out),
                staging: (!direct).then(|| {
                    make(
                        "two-plane readback",
                        pixels * 8,
                        wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    )
                }),
            });
        }
        let outputs = guard
            .as_ref()
            .ok_or_else(|| RenderError::Option("no output buffers".to_owned()))?;
        self.gpu
            .queue
            .write_buffer(&outputs.uniform, 0, bytemuck::bytes_of(&params));
        let texture = texture_binding;
        let buffer = buffer_binding;
        let common = [
            buffer(0, &outputs.uniform),
            buffer(3, &outputs.color),
            buffer(4, &outputs.depth),
        ];
        let (bind, pipeline) = match source {
            Source::Resident(field) => {
                let mut entries = common.to_vec();
                entries.extend([
                    texture(1, &field.color_view),
                    texture(2, &field.depth_view),
                    wgpu::BindGroupEntry {
                        binding: 5,
                        resource: wgpu::BindingResource::Sampler(&self.sampler),
                    },
                ]);
                let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("two-plane"),
                    layout: &self.layout,
                    entries: &entries,
                });
                let pipeline = mode_pipeline(
                    &self.gpu,
                    &self.pipelines,
                    &self.module,
                    &self.pipeline_layout,
                    options,
                    ("DEPTH_PYRAMID", self.depth_pyramid),
                );
                (bind, pipeline)
            }
            Source::Paged(paged) => {
                let pp = self.paged();
                let mut entries = common.to_vec();
                entries.extend([
                    texture(1, paged.slot_color),
                    texture(2, paged.slot_depth),
                    buffer(5, paged.paging),
                    buffer(6, paged.table),
                    texture(7, paged.coarse_color),
                    texture(8, paged.coarse_depth),
                    buffer(9, paged.touched),
                    buffer(10, paged.degraded),
                ]);
                let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("two-plane paged"),
                    layout: &pp.layout,
                    entries: &entries,
                });
                let pipeline = mode_pipeline(
                    &self.gpu,
                    &pp.pipelines,
                    &pp.module,
                    &pp.pipeline_layout,
                    options,
                    ("OVERVIEW", paged.overview),
                );
                (bind, pipeline)
            }
        };
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("two-plane"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("two-plane"),
                timestamp_writes: None,
            });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind, &[]);
            pass.dispatch_workgroups(basis.width.div_ceil(8), basis.height.div_ceil(8), 1);
        }
        if let Source::Paged(paged) = source {
            for (from, to) in [
                (paged.touched, paged.touched_staging),
                (paged.degraded, paged.degraded_staging),
            ] {
                encoder.copy_buffer_to_buffer(from, 0, to, 0, from.size());
            }
        }
        if let Some(staging) = &outputs.staging {
            encoder.copy_buffer_to_buffer(&outputs.color, 0, staging, 0, pixels * 4);
            encoder.copy_buffer_to_buffer(&outputs.depth, 0, staging, pixels * 4, pixels * 4);
        }
        self.gpu.queue.submit([encoder.finish()]);
        let read = |c: &[u8], d: &[u8]| {
            let depth: Vec<f32> = d
                .chunks_exact(4)
                .map(|x| f32::from_le_bytes([x[0], x[1], x[2], x[3]]))
                .collect();
            (c.to_vec(), depth)
        };
        let split = pixels as usize * 4;
        let (color, depth) = match &outputs.staging {
            Some(staging) => self
                .gpu
                .map_read_with(staging, |bytes| read(&bytes[..split], &bytes[split..]))?,
            None => self
                .gpu
                .map_read_many(&[&outputs.color, &outputs.depth], |bytes| {
                    read(bytes[0], bytes[1])
                })?,
        };
        let render_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(Frame {
            width: basis.width,
            height: basis.height,
            color,
            depth,
            translucent: false,
            stats: FrameStats {
                render_ms,
                ..FrameStats::default()
            },
        })
    }

    /// [`TwoPlaneRenderer::render`] averaged over `draws` stratified aperture draws (frame
    /// indices `options.frame_index` onwards): what a view at rest accumulates towards the full
    /// aperture. A pixel is covered where at least half the draws cover it, with the mean
    /// colour of the draws that do and the nearest depth they saw; `render_ms` is the sum.
    ///
    /// # Errors
    /// As [`TwoPlaneRenderer::render`]; [`RenderError::Option`] for `draws` outside
    /// 1..=[`MAX_DRAWS`].
    pub fn render_accumulated(
        &self,
        field: &GpuTwoPlane,
        view: &View,
        options: &TwoPlaneOptions,
        draws: u32,
    ) -> Result<Frame, RenderError> {
        accumulate_draws(options, draws, |o| self.render(field, view, o))
    }
}

/// `render` (one frame of the options it is given) averaged over `draws` stratified aperture
/// draws, frame indices `options.frame_index` onwards: a pixel is covered where at least half
/// the draws cover it, with the mean colour of the draws that do and the nearest depth they
/// saw; `render_ms` is the sum. The one accumulation of the resident and the paged renderers.
///
/// # Errors
/// `render`'s; [`RenderError::Option`] for `draws` outside 1..=[`MAX_DRAWS`].
pub fn accumulate_draws(
    options: &TwoPlaneOptions,
    draws: u32,
    mut render: impl FnMut(&TwoPlaneOptions) -> Result<Frame, RenderError>,
) -> Result<Frame, RenderError> {
    if !(1..=MAX_DRAWS).contains(&draws) {
        return Err(RenderError::Option(format!(
            "{draws} aperture draws: give 1..={MAX_DRAWS}"
        )));
    }
    let mut options = *options;
    let mut frame = render(&options)?;
    if draws == 1 {
        return Ok(frame);
    }
    let pixels = frame.pixel_count();
    let mut rgb = vec![0u32; 3 * pixels];
    let mut hits = vec![0u32; pixels];
    let mut depth = vec![f32::INFINITY; pixels];
    let mut ms = 0.0;
    let mut add = |next: &Frame| {
        for p in 0..pixels {
            if next.depth[p].is_finite() {
                hits[p] += 1;
                depth[p] = depth[p].min(next.depth[p]);
                for k in 0..3 {
                    rgb[3 * p + k] += u32::from(next.color[4 * p + k]);
                }
            }
        }
        ms += next.stats.render_ms;
    };
    add(&frame);
    let first = options.frame_index;
    for index in 1..draws {
        options.frame_index = first.wrapping_add(index);
        add(&render(&options)?);
    }
    for p in 0..pixels {
        if 2 * hits[p] >= draws {
            for k in 0..3 {
                frame.color[4 * p + k] = ((rgb[3 * p + k] + hits[p] / 2) / hits[p]) as u8;
            }
            frame.color[4 * p + 3] = 255;
            frame.depth[p] = depth[p];
        } else {
            frame.color[4 * p..4 * p + 4].copy_from_slice(&options.background);
            frame.depth[p] = f32::INFINITY;
        }
    }
    frame.stats.render_ms = ms;
    Ok(frame)
}

/// The heights (above st) between which the depth-corrected filter marches: those of the
/// stored depths `depth_range`, a sliver wider so the march brackets the extremes; `(high, low)`.
pub(crate) fn march_heights(separation: f64, depth_range: [f32; 2]) -> (f64, f64) {
    let [d_lo, d_hi] = depth_range.map(f64::from);
    let (h_hi, h_lo) = (separation * (1.0 - d_lo), separation * (1.0 - d_hi));
    let pad = 1e-4 * separation + 1e-3 * (h_hi - h_lo);
    ((h_hi + pad).min(separation), h_lo - pad)
}

/// Most aperture draws [`TwoPlaneRenderer::render_accumulated`] averages (the still refinement
/// limit).
pub const MAX_DRAWS: u32 = crate::refine::MAX_SAMPLES;

/// Which pixels of `view` lie inside the light field of `planes` (DESIGN §9: the ray meets the
/// closed uv rectangle at `t_uv ≥ 0` and the closed st rectangle beyond it), row-major; the
/// region quality is measured over.
///
/// # Errors
/// [`RenderError::View`] for an invalid view.
pub fn valid_region(planes: &TwoPlanes, view: &View) -> Result<Vec<bool>, RenderError> {
    let basis = view.basis(DEFAULT_MAX_VIEW_PX)?;
    let mut mask = Vec::with_capacity(basis.width as usize * basis.height as usize);
    for i in 0..basis.height {
        for j in 0..basis.width {
            mask.push(planes.cross(basis.eye, basis.pixel_dir(i, j)).is_some());
        }
    }
    Ok(mask)
}

/// The evaluation views of a two-plane light field: `n` square views of `size_px`, eyes beyond
/// the uv plane (0.3 to 1 plane separations behind it, within 0.6 of the uv rectangle's half
/// size of its centre), looking at the st plane's centre (moved by up to a tenth of the st
/// rectangle) with the field of view that spans 0.6 of the st rectangle's height; `up` is the
/// planes' `up`. Drawn from `seed`.
pub fn evaluation_views(planes: &TwoPlanes, n: usize, size_px: u32, seed: u64) -> Vec<View> {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let (right, up) = planes.axes();
    let normal = planes.normal();
    let separation = planes.separation();
    let uv = DVec3::from(planes.uv.center);
    let st = DVec3::from(planes.st.center);
    let [uw, uh] = planes.uv.size;
    let [sw, sh] = planes.st.size;
    (0..n)
        .map(|_| {
            let back: f64 = rng.random_range(0.3..1.0);
            let x: f64 = rng.random_range(-0.6..0.6);
            let y: f64 = rng.random_range(-0.6..0.6);
            let tx: f64 = rng.random_range(-0.1..0.1);
            let ty: f64 = rng.random_range(-0.1..0.1);
            let eye = uv + back * separation * normal + 0.5 * (x * uw * right + y * uh * up);
            let target = st + tx * sw * right + ty * sh * up;
            let distance = (target - eye).length();
            let yfov_deg = 2.0 * (0.3 * sh / distance).atan().to_degrees();
            View {
                eye: eye.to_array(),
                target: target.to_array(),
                up: up.to_array(),
                yfov_deg,
                width: size_px,
                height: size_px,
            }
        })
        .collect()
}

/// `frame` with every pixel outside `region` emptied (colour `background`, depth `+inf`): the
/// reference restricted to the light field's valid region, or a render to the same pixels.
///
/// # Panics
/// Never for matching sizes; a `region` shorter than the frame leaves the rest as it is.
pub fn restrict(frame: &Frame, region: &[bool], background: [u8; 4]) -> Frame {
    let mut out = frame.clone();
    for ((px, d), &inside) in out
        .color
        .chunks_exact_mut(4)
        .zip(out.depth.iter_mut())
        .zip(region)
    {
        if !inside {
            px.copy_from_slice(&background);
            *d = f32::INFINITY;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::{depth_bound_levels, depth_bound_sizes};

    /// Every texel of level `l` holds the smallest depth of the level-0 texels whose block is
    /// `min(t >> l, size − 1)` per axis (odd and non-square sides, misses at +inf).
    #[test]
    fn depth_pyramid_levels_hold_the_smallest_depth_of_their_blocks() {
        for [w, h] in [
            [1u32, 1],
            [2, 1],
            [5, 3],
            [7, 16],
            [13, 9],
            [64, 64],
            [33, 100],
        ] {
            let depth: Vec<f32> = (0..w * h)
                .map(|i| {
                    let v = (i.wrapping_mul(2_654_435_761) >> 7) % 1000;
                    if v % 7 == 0 {
                        f32::INFINITY
                    } else {
                        v as f32 / 1000.0
                    }
                })
                .collect();
            let sizes: Vec<[u32; 2]> = depth_bound_sizes([w, h]).collect();
            assert_eq!(sizes[0], [w, h]);
            assert_eq!(*sizes.last().unwrap(), [1, 1]);
            let levels = depth_bound_levels(&depth, [w, h]);
            assert_eq!(levels.len() + 1, sizes.len());
            for (l, level) in levels.iter().enumerate() {
                let l = l as u32 + 1;
                let [lw, lh] = sizes[l as usize];
                let mut expected = vec![f32::INFINITY; (lw * lh) as usize];
                for y in 0..h {
                    for x in 0..w {
                        let b = ((y >> l).min(lh - 1) * lw + (x >> l).min(lw - 1)) as usize;
                        expected[b] = expected[b].min(depth[(y * w + x) as usize]);
                    }
                }
                assert_eq!(level, &expected, "{w}x{h} level {l}");
            }
        }
    }
}
