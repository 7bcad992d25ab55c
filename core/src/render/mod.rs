//! Rendering new views from a spherical light field on the GPU (seed 000 §2, DESIGN §4).
//!
//! [`Renderer`] holds the compute pipeline (built once); [`GpuLightField`] holds one asset's
//! colour and depth maps as 2D texture arrays plus its cameras and triangle hierarchy; a render
//! fills a [`Frame`] with colour, z-depth in world units and stats.
//!
//! Two methods: [`Method::Fixed`] is the seed's fixed-step search with bilinear depth (the
//! baseline); [`Method::Default`] marches coarse steps with an edge-aware depth lookup and
//! accepts a bisection-refined crossing only where a camera's estimate is continuous across it.

mod composite;
mod gpu_data;
mod guide;
mod options;
mod passes;
mod targets;
mod upload;

#[doc(hidden)]
pub use gpu_data::render_params_layout;
pub use gpu_data::shader_source;
pub use options::{
    COMPOSITING_VARIABLE, Compositing, DEFAULT_FIXED_STEP, DEFAULT_GUIDE, DEFAULT_REFINED_STEP,
    InteriorBlocks, LIGHT_BLEND_VARIABLE, MAX_GUIDE, MIN_STEP, Method, RenderError, RenderOptions,
    ResolvedOptions, SHADOW_RAYS_VARIABLE, Switches, UploadOptions,
};
pub use passes::PASS_TIMING_VARIABLE;
pub use upload::field_bytes;

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use glam::DVec3;

use crate::frame::{Frame, FrameStats};
use crate::geometry;
use crate::gpu::{Gpu, GpuError, buffer_entry, texture_entry};
use crate::view::{DEFAULT_MAX_VIEW_PX, View, ViewError};

use composite::{CompositeParams, CompositePipeline, MAX_GPU_LAYERS};
use gpu_data::{
    EDGE_GAP, FRONT_MASS, MethodSet, REFINE_ITERATIONS, RenderParams, Role, ShaderSetting, Tiling,
    max_steps_for, method_code,
};
use guide::{
    COARSE_REFINE_ITERATIONS, COARSE_STEP_SCALE, GUIDE_REACH, INTERIOR_BLOCK_REACH,
    INTERIOR_CURVATURE, PRE_FACTOR, blocks_share_coarse_cells, coarse_size, interior_block_angle,
};
use passes::{PassTimer, Workgroups, compute_pipeline, record_pass};
use targets::{
    COUNTERS_SIZE, CoarseLevel, GIVEN_BACK_ARGS, INTERIOR_ARGS, MAX_TILES, Targets, coarse_stride,
    quad_grid, tile_grid,
};
use upload::direction_lookup_texture;

/// One asset on the GPU. Cheap to share (`Arc`) between threads.
pub struct GpuLightField {
    /// World units per light-field unit.
    pub scale: f64,
    /// Bounding-sphere centre, world units.
    pub center: DVec3,
    /// Bounding radius, world units.
    pub radius: f64,
    /// Icosphere level baked.
    pub max_level: u32,
    /// Map resolution.
    pub resolution: u32,
    /// Bytes of texture memory used.
    pub gpu_bytes: u64,
    /// Axis-aligned box (light-field units) holding every surface point any camera saw in any
    /// layer, grown by the maps' texel footprint (empty when nothing was seen); the default
    /// marcher clips each layer's rays to that layer's own box.
    pub visible_box: [[f32; 3]; 2],
    /// The asset's layers (names and default opacities), in the order of its maps.
    pub layers: Vec<crate::asset::LayerDesc>,
    /// How its layers composite: by depth, or in their order (depth layers).
    pub layer_order: crate::asset::LayerOrder,
    /// `Some(τ_d)` for a translucent light field (premultiplied RGBA maps, a volume): frames are
    /// [translucent](Frame::translucent) and report depth where their alpha reaches `τ_d`;
    /// `None`: opaque.
    pub translucent: Option<f32>,
    /// Every layer's maps, in the asset's layer order (one for most assets).
    maps: Vec<LayerMaps>,
    /// Each geometry state's maps ([`crate::deform`]), in state order.
    deformations: Vec<StateMaps>,
    /// Geometry states that store no page, drawn from the base state's maps.
    shared_states: Vec<u16>,
    /// The light states' colour maps, when the asset has them ([`crate::light`]).
    lights: Option<LightMaps>,
    /// The device, polled on drop so that wgpu reclaims the textures at once.
    gpu: Arc<Gpu>,
    /// The renderer's count of resident fields, decremented on drop.
    resident: Arc<ResidentCounter>,
}

/// One layer's maps on the GPU.
struct LayerMaps {
    /// The layer's visible box (see [`GpuLightField::visible_box`]).
    visible_box: [[f32; 3]; 2],
    group: wgpu::BindGroup,
    /// The colour and depth texture arrays, destroyed on drop.
    textures: [wgpu::Texture; 2],
    /// Views of `textures`, for a relit frame's bind group.
    views: [wgpu::TextureView; 2],
}

/// A deformation state's maps on the GPU: every layer, whole (the pages the state leaves out
/// are the base state's).
struct StateMaps {
    /// Index into the asset's states.
    state: u16,
    maps: Vec<LayerMaps>,
}

/// A light-state asset's maps on the GPU: the ambient part, the shading normals (when the asset
/// has them) and each proxy direction's direct part, one texture array (a layer per camera) each.
struct LightMaps {
    /// Proxy directions: 12, 42 or 162.
    count: u32,
    ambient: (wgpu::Texture, wgpu::TextureView),
    normal: Option<(wgpu::Texture, wgpu::TextureView)>,
    /// In the proxy's order.
    direct: Vec<(wgpu::Texture, wgpu::TextureView)>,
    /// Whether the states were baked with shadows (DESIGN §9).
    shadows: bool,
}

impl GpuLightField {
    /// The device the field lives on: only a renderer of that device can draw it.
    pub fn gpu(&self) -> &Arc<Gpu> {
        &self.gpu
    }

    /// The layers' default opacities, in their order.
    pub fn default_opacities(&self) -> Vec<f32> {
        self.layers.iter().map(|l| l.default_opacity).collect()
    }

    /// The deformation states uploaded with the field (indices into the asset's states).
    pub fn deformation_states(&self) -> Vec<u16> {
        self.deformations.iter().map(|d| d.state).collect()
    }

    /// The maps of `state` (`None` or 0: the base state), one per layer. A geometry state
    /// uploaded without maps of its own (it stores no page) reads as the base state.
    fn layer_maps(&self, state: Option<u16>) -> Result<&[LayerMaps], RenderError> {
        match state {
            None | Some(0) => Ok(&self.maps),
            Some(s) if self.shared_states.contains(&s) => Ok(&self.maps),
            Some(s) => self
                .deformations
                .iter()
                .find(|d| d.state == s)
                .map(|d| d.maps.as_slice())
                .ok_or_else(|| {
                    RenderError::Option(format!(
                        "state {s} is not a deformation state of this light field (or was not \
                         uploaded)"
                    ))
                }),
        }
    }

    /// The `τ_d` its layers composite with: the bake's for a translucent field, else DESIGN
    /// §9's default.
    pub fn depth_threshold(&self) -> f32 {
        self.translucent
            .unwrap_or(crate::volume::raycast::DEFAULT_DEPTH_THRESHOLD as f32)
    }
}

impl Drop for GpuLightField {
    fn drop(&mut self) {
        // Dropping the handles alone leaves the memory to wgpu's next maintenance, which runs
        // only when some later frame is submitted: an asset deleted on an idle service would
        // stay resident. `destroy` frees the textures now, or as soon as the last submission
        // that reads them completes, whoever else still holds a handle to them.
        for texture in self
            .maps
            .iter()
            .chain(self.deformations.iter().flat_map(|d| &d.maps))
            .flat_map(|m| &m.textures)
        {
            texture.destroy();
        }
        if let Some(lights) = &self.lights {
            for (texture, _) in std::iter::once(&lights.ambient)
                .chain(&lights.normal)
                .chain(&lights.direct)
            {
                texture.destroy();
            }
        }
        // A non-blocking poll reclaims what completed submissions held. Its only error is a
        // lost device, whose memory is gone anyway; a drop has no one to report to.
        let _ = self.gpu.device.poll(wgpu::PollType::Poll);
        self.resident.fields.fetch_sub(1, Ordering::AcqRel);
        self.resident
            .bytes
            .fetch_sub(self.gpu_bytes, Ordering::AcqRel);
    }
}

/// A relit frame's light parameters (RenderParams `light_weights`, `light_dir`, `light_a..c`).
struct Relit {
    weights: [f32; 4],
    light: [f32; 4],
    proxy: [[f32; 4]; 3],
    /// Whether shadow rays decide contested texels (RenderParams `shadow_rays`).
    shadow_rays: bool,
}

/// The light fields a [`Renderer`] has on the device: uploaded and not yet dropped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ResidentFields {
    /// Number of [`GpuLightField`]s alive.
    pub fields: usize,
    /// Their texture bytes ([`GpuLightField::gpu_bytes`] summed).
    pub bytes: u64,
}

#[derive(Debug, Default)]
struct ResidentCounter {
    fields: AtomicUsize,
    bytes: AtomicU64,
}

/// One coarse pass of a guided frame: its buffers, size, focal length (pixels) and jitter (its
/// pixels).
type CoarsePass<'a> = (&'a CoarseLevel, (u32, u32), f32, [f32; 2]);

/// The light-field render pipeline; one per process, shared by threads.
pub struct Renderer {
    gpu: Arc<Gpu>,
    module: wgpu::ShaderModule,
    layout: wgpu::PipelineLayout,
    /// Specialised pipelines, built on first use: index `5 · (methods − 1) + role` (see
    /// [`Renderer::pipeline`]).
    pipelines: [std::sync::OnceLock<wgpu::ComputePipeline>; 15],
    /// The tile pass (shaders/render/tiles.wgsl `cs_tiles`); index 1 where the quads share their
    /// nearest coarse pixel ([`quads_share_nearest_coarse`]): it reads 3×3 coarse pixels per
    /// quad, not 4×4.
    tiles_pipelines: [wgpu::ComputePipeline; 2],
    switches: Switches,
    frame_layout: wgpu::BindGroupLayout,
    field_layout: wgpu::BindGroupLayout,
    linear: wgpu::Sampler,
    camera_buffer: wgpu::Buffer,
    hierarchy_buffer: wgpu::Buffer,
    /// [`geometry::CameraSet::direction_lookup`] (`locate` in the marcher).
    lookup_view: wgpu::TextureView,
    /// The GPU composite of a multi light field's layers.
    composite: CompositePipeline,
    /// Reusable targets; the lock also serializes frames on the one queue.
    targets: Mutex<Option<Targets>>,
    max_px: u32,
    /// Light fields uploaded by this renderer and still alive.
    resident: Arc<ResidentCounter>,
}

impl Renderer {
    /// Builds the pipeline and uploads the icosphere cameras and hierarchy.
    pub fn new(gpu: Arc<Gpu>) -> Renderer {
        Renderer::with_switches(gpu, Switches::default())
    }

    /// [`Renderer::new`] with its modes given: for tests that compare a part of the marcher
    /// switched off with the whole.
    pub fn with_switches(gpu: Arc<Gpu>, switches: Switches) -> Renderer {
        let device = &gpu.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("render"),
            source: wgpu::ShaderSource::Wgsl(
                shader_source(device.features().contains(wgpu::Features::SUBGROUP)).into(),
            ),
        });
        let storage = wgpu::BufferBindingType::Storage { read_only: false };
        let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render frame"),
            entries: &[
                buffer_entry(0, wgpu::BufferBindingType::Uniform),
                buffer_entry(1, storage),
                buffer_entry(2, storage),
                buffer_entry(3, storage),
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                buffer_entry(5, storage),
                buffer_entry(6, storage),
            ],
        });
        let field_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("light field"),
            entries: &[
                buffer_entry(0, wgpu::BufferBindingType::Uniform),
                buffer_entry(1, wgpu::BufferBindingType::Uniform),
                texture_entry(2, true),
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                // Light states: ambient, normals and three proxy lights' direct parts.
                texture_entry(6, true),
                texture_entry(7, true),
                texture_entry(8, true),
                texture_entry(9, true),
                texture_entry(10, true),
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("render"),
            bind_group_layouts: &[Some(&frame_layout), Some(&field_layout)],
            immediate_size: 0,
        });
        let sampler = |label, filter| {
            device.create_sampler(&wgpu::SamplerDescriptor {
                label: Some(label),
                address_mode_u: wgpu::AddressMode::ClampToEdge,
                address_mode_v: wgpu::AddressMode::ClampToEdge,
                mag_filter: filter,
                min_filter: filter,
                ..Default::default()
            })
        };
        let linear = sampler("light-field linear", wgpu::FilterMode::Linear);
        let set = geometry::camera_set();
        // Each camera's position and the axis its frame is built from (shared/lightfield.wgsl `camera`).
        let cameras: Vec<[f32; 4]> = set
            .positions
            .iter()
            .map(|p| [p.x, p.y, p.z, geometry::camera_frame_axis(*p) as f32])
            .collect();
        let hierarchy: Vec<[u32; 4]> = set
            .triangles
            .iter()
            .map(|t| [t.v[0], t.v[1], t.v[2], t.first_child])
            .collect();
        // Uniform buffers (docs/marcher.md says why). The largest, the hierarchy, is 27 KiB (the
        // cameras 10 KiB): within every Vulkan, Metal and DX12 device's 64 KiB; a smaller limit
        // fails pipeline creation with a GPU error at the first frame, so say which limit it is
        // here.
        let largest = std::mem::size_of_val(cameras.as_slice())
            .max(std::mem::size_of_val(hierarchy.as_slice())) as u64;
        let limit = gpu.device.limits().max_uniform_buffer_binding_size;
        if largest > limit {
            tracing::error!(
                "the marcher needs {largest}-byte uniform buffers; this device allows {limit}"
            );
        }
        let uniform = |label, contents: &[u8]| {
            use wgpu::util::DeviceExt;
            gpu.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents,
                    usage: wgpu::BufferUsages::UNIFORM,
                })
        };
        let camera_buffer = uniform("icosphere cameras", bytemuck::cast_slice(&cameras));
        let hierarchy_buffer = uniform("icosphere hierarchy", bytemuck::cast_slice(&hierarchy));
        let lookup_view = direction_lookup_texture(&gpu);
        let max_px = DEFAULT_MAX_VIEW_PX.min(gpu.device.limits().max_texture_dimension_2d);
        let tiles_pipelines = [4.0, 3.0].map(|span| {
            compute_pipeline(
                device,
                (&layout, &module),
                ("render tiles", "cs_tiles"),
                &[("TILE_SPAN", span)],
            )
        });
        let composite = CompositePipeline::new(device);
        let renderer = Renderer {
            gpu,
            module,
            layout,
            pipelines: Default::default(),
            tiles_pipelines,
            switches,
            frame_layout,
            field_layout,
            linear,
            camera_buffer,
            hierarchy_buffer,
            lookup_view,
            composite,
            targets: Mutex::new(None),
            max_px,
            resident: Arc::default(),
        };
        // The default method's guided pipelines serve most frames: build them now, not in the
        // first frame.
        for role in [
            Role::Guided,
            Role::Interior,
            Role::Coarse,
            Role::InteriorBlocks,
        ] {
            renderer.pipeline(MethodSet::Default, role);
        }
        renderer
    }

    /// The marcher specialised for `methods` and `role`, built on first use: each pass runs a
    /// pipeline holding only the code it can take (docs/marcher.md).
    fn pipeline(&self, methods: MethodSet, role: Role) -> &wgpu::ComputePipeline {
        let index = (5 * (methods.code() - 1) + role.code()) as usize;
        self.pipelines[index].get_or_init(|| {
            compute_pipeline(
                &self.gpu.device,
                (&self.layout, &self.module),
                ("render", "cs_main"),
                &[
                    ("METHODS", f64::from(methods.code())),
                    ("ROLE", f64::from(role.code())),
                ],
            )
        })
    }

    /// The modes this renderer was built with.
    pub fn switches(&self) -> Switches {
        self.switches
    }

    /// The device.
    pub fn gpu(&self) -> &Arc<Gpu> {
        &self.gpu
    }

    /// The light fields this renderer uploaded that are still alive, and their texture bytes.
    pub fn resident(&self) -> ResidentFields {
        ResidentFields {
            fields: self.resident.fields.load(Ordering::Acquire),
            bytes: self.resident.bytes.load(Ordering::Acquire),
        }
    }

    /// Renders `view` (world coordinates) from `field`.
    ///
    /// # Errors
    /// [`RenderError::View`] / [`RenderError::Option`] for bad input, [`RenderError::Gpu`].
    pub fn render(
        &self,
        field: &GpuLightField,
        view: &View,
        options: &RenderOptions,
    ) -> Result<Frame, RenderError> {
        self.render_blend(field, view, options, options, 0.0)
    }

    /// Renders `view` with a dithered cross-fade between two settings in one pass: a pixel
    /// whose 4×4 ordered-dither threshold `(rank + ½) / 16` is below `weight` renders with `b`,
    /// every other pixel with `a` (automatic LOD's transition, [`crate::lod`]). `weight` 0 is
    /// [`Renderer::render`] with `a`; 1 is with `b`.
    ///
    /// # Errors
    /// As [`Renderer::render`]; [`RenderError::Option`] for a weight outside [0, 1].
    pub fn render_blend(
        &self,
        field: &GpuLightField,
        view: &View,
        a: &RenderOptions,
        b: &RenderOptions,
        weight: f32,
    ) -> Result<Frame, RenderError> {
        self.render_jittered(field, view, a, b, weight, [0.0, 0.0])
    }

    /// [`Renderer::render_blend`] with every sample moved by `jitter` pixels: pixel (i, j)
    /// samples the image at column `j + 0.5 + jitter[0]`, row `i + 0.5 + jitter[1]` (DESIGN §3
    /// otherwise), the coarse passes of a guided frame by the same amount, so that a still
    /// frame can be refined from several sub-pixel samples. `[0, 0]` is
    /// [`Renderer::render_blend`].
    ///
    /// # Errors
    /// As [`Renderer::render_blend`]; [`RenderError::Option`] for a jitter component that is
    /// not finite or lies outside [−0.5, 0.5].
    pub fn render_jittered(
        &self,
        field: &GpuLightField,
        view: &View,
        a: &RenderOptions,
        b: &RenderOptions,
        weight: f32,
        jitter: [f32; 2],
    ) -> Result<Frame, RenderError> {
        self.render_layered(
            field,
            view,
            (a, b, weight),
            jitter,
            &field.default_opacities(),
        )
    }

    /// [`Renderer::render_jittered`] with a runtime opacity per layer (`opacities`, one per
    /// layer of the field, in its order): every layer is rendered and the layers are
    /// composited per pixel in depth order, or in their order for depth layers
    /// ([`crate::layers::composite`], [`GpuLightField::layer_order`]). Layers at opacity 0 are
    /// not rendered, and a single visible layer at opacity 1 is one pass with no compositing.
    ///
    /// # Errors
    /// As [`Renderer::render_jittered`]; [`RenderError::Option`] for an opacity count that is
    /// not the field's layer count or an opacity outside [0, 1].
    pub fn render_layered(
        &self,
        field: &GpuLightField,
        view: &View,
        (a, b, weight): (&RenderOptions, &RenderOptions, f32),
        jitter: [f32; 2],
        opacities: &[f32],
    ) -> Result<Frame, RenderError> {
        let layer_maps = field.layer_maps(a.state)?;
        if opacities.len() != layer_maps.len()
            || !opacities
                .iter()
                .all(|o| o.is_finite() && (0.0..=1.0).contains(o))
        {
            return Err(RenderError::Option(format!(
                "layer opacities {opacities:?}: the light field has {} layers, each opacity in \
                 [0, 1]",
                layer_maps.len()
            )));
        }
        let visible: Vec<(usize, f32)> = opacities
            .iter()
            .copied()
            .enumerate()
            .filter(|&(_, o)| o > 0.0)
            .collect();
        // One visible layer at full opacity (every other at 0) is one pass, no compositing.
        if let [(only, o)] = visible[..]
            && o >= 1.0
        {
            let maps = &layer_maps[only];
            let mut frame = self.render_maps(field, maps, view, a, b, weight, jitter)?;
            if let Some(tau) = field.translucent {
                straighten(&mut frame.color, &mut frame.depth, tau);
            }
            return Ok(frame);
        }
        // Up to MAX_GPU_LAYERS visible layers may composite on the GPU; more, or none (an
        // empty frame, no pass), on the CPU.
        let on_gpu = match self.switches.compositing {
            Compositing::Automatic => !self.gpu.is_software,
            Compositing::Gpu => true,
            Compositing::Cpu => false,
        };
        if on_gpu
            && (1..=MAX_GPU_LAYERS).contains(&visible.len())
            && self.stack_fits(view, visible.len())
        {
            return self.render_composited(field, view, (a, b, weight), jitter, &visible);
        }
        let images = self.render_layer_images(field, view, (a, b, weight), jitter, opacities)?;
        let start = Instant::now();
        let pairs: Vec<(&crate::layers::LayerImage, f32)> =
            images.iter().zip(opacities.iter().copied()).collect();
        let mut frame = crate::layers::composite(
            &pairs,
            view.width,
            view.height,
            field.depth_threshold(),
            field.layer_order,
        );
        frame.stats.render_ms += start.elapsed().as_secs_f64() * 1e3;
        Ok(frame)
    }

    /// Every layer of `field` rendered for `view`, uncomposited: premultiplied colour and the
    /// depth of the maps' surface each pixel met (its sort depth, also where a translucent
    /// layer's alpha stays below `τ_d`). A layer whose opacity in `opacities` (one per layer,
    /// in order) is 0 is not rendered: its image is empty, as compositing would leave it.
    ///
    /// # Errors
    /// As [`Renderer::render_jittered`].
    pub fn render_layer_images(
        &self,
        field: &GpuLightField,
        view: &View,
        (a, b, weight): (&RenderOptions, &RenderOptions, f32),
        jitter: [f32; 2],
        opacities: &[f32],
    ) -> Result<Vec<crate::layers::LayerImage>, RenderError> {
        let layer_maps = field.layer_maps(a.state)?;
        let mut out = Vec::with_capacity(layer_maps.len());
        for (i, maps) in layer_maps.iter().enumerate() {
            if opacities.get(i).is_some_and(|&o| o <= 0.0) {
                let pixels = view.width as usize * view.height as usize;
                out.push(crate::layers::LayerImage {
                    width: view.width,
                    height: view.height,
                    premultiplied: vec![0; 4 * pixels],
                    depth: vec![f32::INFINITY; pixels],
                    translucent: field.translucent.is_some(),
                    stats: crate::frame::FrameStats::default(),
                });
                continue;
            }
            let frame = self.render_maps(field, maps, view, a, b, weight, jitter)?;
            out.push(if frame.translucent {
                let mut premultiplied = frame.color;
                let mut depth = frame.depth;
                for (px, z) in premultiplied.chunks_exact_mut(4).zip(depth.iter_mut()) {
                    if px[3] == 0 {
                        px.copy_from_slice(&[0; 4]);
                        *z = f32::INFINITY;
                    }
                }
                crate::layers::LayerImage {
                    width: frame.width,
                    height: frame.height,
                    premultiplied,
                    depth,
                    translucent: true,
                    stats: frame.stats,
                }
            } else {
                crate::layers::LayerImage::from_opaque(&frame)
            });
        }
        Ok(out)
    }

    /// The targets for `view`'s size (made or remade as needed), locked: the lock also
    /// serializes frames on the one queue.
    ///
    /// # Errors
    /// [`RenderError::View`] for a view that is not valid (before anything is allocated).
    fn lock_targets(
        &self,
        view: &View,
    ) -> Result<std::sync::MutexGuard<'_, Option<Targets>>, RenderError> {
        view.basis(self.max_px)?;
        let mut guard = self
            .targets
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if guard
            .as_ref()
            .is_none_or(|t| (t.width, t.height) != (view.width, view.height))
        {
            *guard = Some(self.targets_for(view.width, view.height));
        }
        Ok(guard)
    }

    /// One layer's pass: the marcher's output as it is (premultiplied colour for a translucent
    /// field, depth wherever the maps' surface was met).
    fn render_maps(
        &self,
        field: &GpuLightField,
        maps: &LayerMaps,
        view: &View,
        a: &RenderOptions,
        b: &RenderOptions,
        weight: f32,
        jitter: [f32; 2],
    ) -> Result<Frame, RenderError> {
        let start = Instant::now();
        let guard = self.lock_targets(view)?;
        let Some(targets) = guard.as_ref() else {
            return Err(GpuError::Operation("render targets missing".to_owned()).into());
        };
        let (encoder, timer) =
            self.encode_maps(targets, field, maps, view, (a, b, weight), jitter, true)?;
        self.read_frame(targets, encoder, timer, start, field.translucent.is_some())
    }

    /// Whether a stack of `layers` frames of `view`'s size fits one storage binding (and one
    /// buffer) of this device: a large frame with many layers composites on the CPU.
    fn stack_fits(&self, view: &View, layers: usize) -> bool {
        let limits = self.gpu.device.limits();
        let bytes = 4 * u64::from(view.width) * u64::from(view.height) * layers as u64;
        bytes
            <= limits
                .max_storage_buffer_binding_size
                .min(limits.max_buffer_size)
    }

    /// The visible layers of `field` (index and opacity, in the field's order, at most
    /// [`MAX_GPU_LAYERS`]) rendered one after the other into the layer stack and composited
    /// there (shaders/composite.wgsl): one readback, no CPU pass over the pixels.
    fn render_composited(
        &self,
        field: &GpuLightField,
        view: &View,
        settings: (&RenderOptions, &RenderOptions, f32),
        jitter: [f32; 2],
        visible: &[(usize, f32)],
    ) -> Result<Frame, RenderError> {
        let start = Instant::now();
        let mut guard = self.lock_targets(view)?;
        let Some(targets) = guard.as_mut() else {
            return Err(GpuError::Operation("render targets missing".to_owned()).into());
        };
        if targets
            .stack
            .as_ref()
            .is_none_or(|s| s.layers < visible.len())
        {
            targets.stack = Some(
                self.composite
                    .stack(&self.gpu.device, targets, visible.len()),
            );
        }
        let targets = &*targets;
        let Some(stack) = targets.stack.as_ref() else {
            return Err(GpuError::Operation("layer stack missing".to_owned()).into());
        };
        let gpu = &self.gpu;
        let size = (view.width, view.height);
        let opacities: Vec<f32> = visible.iter().map(|&(_, o)| o).collect();
        let params = CompositeParams::new(
            size,
            &opacities,
            field.translucent.is_some(),
            field.depth_threshold(),
            field.layer_order,
        );
        for (slot, &(index, _)) in visible.iter().enumerate() {
            let Some(maps) = field.layer_maps(settings.0.state)?.get(index) else {
                return Err(RenderError::Option(format!("no layer {index}")));
            };
            // Each layer's passes are submitted as soon as they are recorded (its parameters
            // are written before its submission, after the previous one's); the counters add
            // up over the layers.
            let (mut encoder, mut timer) =
                self.encode_maps(targets, field, maps, view, settings, jitter, slot == 0)?;
            stack.push(&mut encoder, targets, slot);
            encoder = timer.split(gpu, encoder, "stack")?;
            if slot + 1 < visible.len() {
                gpu.queue.submit([encoder.finish()]);
                timer.finish(view.width, view.height);
                continue;
            }
            gpu.queue
                .write_buffer(&stack.uniform, 0, bytemuck::bytes_of(&params));
            self.composite.record(&mut encoder, stack, size);
            encoder = timer.split(gpu, encoder, "composite")?;
            let mut frame = self.read_frame(targets, encoder, timer, start, true)?;
            frame.translucent = params.nearest_only == 0;
            return Ok(frame);
        }
        Err(RenderError::Option(
            "no visible layer to composite".to_owned(),
        ))
    }

    /// The bind group and light parameters of a frame relit with `light` (world direction; the
    /// asset frame shares the world's axes), or `None` for the base colour.
    ///
    /// # Errors
    /// [`RenderError::Light`] for a bad direction or an asset without light states.
    fn relit_group(
        &self,
        field: &GpuLightField,
        maps: &LayerMaps,
        light: Option<crate::light::LightDirection>,
    ) -> Result<Option<(wgpu::BindGroup, Relit)>, RenderError> {
        let Some(light) = light else {
            return Ok(None);
        };
        let l = light.unit()?;
        let lights = field
            .lights
            .as_ref()
            .ok_or(crate::light::LightError::NoLightStates)?;
        let blend = crate::light::blend_for(lights.count, l, self.switches.light_blend)?;
        let [a, b, c] = blend.directions.map(|i| &lights.direct[i as usize].1);
        // Without a normal state the colour maps stand in (never read: the ratio is off).
        let by_normal = self.switches.light_blend == crate::light::Blend::Normal;
        let normal = match (&lights.normal, by_normal) {
            (Some((_, view)), true) => Some(view),
            _ => None,
        };
        let group = self.field_group(
            &maps.views[0],
            &maps.views[1],
            [&lights.ambient.1, normal.unwrap_or(&maps.views[0]), a, b, c],
        );
        let w = blend.weights.map(|x| x as f32);
        let dir = |v: glam::DVec3| {
            let v = v.as_vec3();
            [v.x, v.y, v.z, 0.0]
        };
        let [da, db, dc] = blend.vectors.map(dir);
        Ok(Some((
            group,
            Relit {
                weights: [w[0], w[1], w[2], f32::from(u8::from(normal.is_some()))],
                light: dir(l),
                proxy: [da, db, dc],
                shadow_rays: self.switches.shadow_rays && lights.shadows && normal.is_some(),
            },
        )))
    }

    /// The light-field bind group of `color` and `depth` maps, with the five light-state maps
    /// (ambient, normals, then three proxy lights; the colour maps themselves when not relit).
    fn field_group(
        &self,
        color: &wgpu::TextureView,
        depth: &wgpu::TextureView,
        lights: [&wgpu::TextureView; 5],
    ) -> wgpu::BindGroup {
        let texture = |binding, view| wgpu::BindGroupEntry {
            binding,
            resource: wgpu::BindingResource::TextureView(view),
        };
        self.gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("light field"),
                layout: &self.field_layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: self.camera_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: self.hierarchy_buffer.as_entire_binding(),
                    },
                    texture(2, color),
                    texture(3, depth),
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: wgpu::BindingResource::Sampler(&self.linear),
                    },
                    texture(5, &self.lookup_view),
                    texture(6, lights[0]),
                    texture(7, lights[1]),
                    texture(8, lights[2]),
                    texture(9, lights[3]),
                    texture(10, lights[4]),
                ],
            })
    }

    /// Records one layer's passes into a new encoder (after writing their parameters): the
    /// frame's colour and depth are in `targets` once it has run. `clear_counters`: start the
    /// work counters from 0 (else they add up).
    #[allow(clippy::too_many_arguments)]
    fn encode_maps(
        &self,
        targets: &Targets,
        field: &GpuLightField,
        maps: &LayerMaps,
        view: &View,
        (a, b, weight): (&RenderOptions, &RenderOptions, f32),
        jitter: [f32; 2],
        clear_counters: bool,
    ) -> Result<(wgpu::CommandEncoder, PassTimer), RenderError> {
        if !Arc::ptr_eq(&field.gpu, &self.gpu) {
            return Err(RenderError::Option(
                "the light field was uploaded on another device than this renderer's".to_owned(),
            ));
        }
        if let Some(why) = self.gpu.lost() {
            return Err(GpuError::DeviceLost(why).into());
        }
        let basis = view.basis(self.max_px)?;
        if !(weight.is_finite() && (0.0..=1.0).contains(&weight)) {
            return Err(RenderError::Option(format!(
                "blend weight {weight} must be in [0, 1]"
            )));
        }
        if !jitter
            .iter()
            .all(|c| c.is_finite() && (-0.5..=0.5).contains(c))
        {
            return Err(RenderError::Option(format!(
                "jitter {jitter:?} must be finite and in [-0.5, 0.5] pixels"
            )));
        }
        let resolved_a = a.resolve(field.max_level)?;
        let relit = self.relit_group(field, maps, a.light)?;
        let first = ShaderSetting::of(&resolved_a);
        let second = ShaderSetting::of(&b.resolve(field.max_level)?);
        let lf_eye = (basis.eye - field.center) / field.scale;
        if !lf_eye.is_finite() {
            return Err(RenderError::View(ViewError::NotFinite("eye")));
        }
        let params = RenderParams {
            eye: lf_eye.as_vec3().to_array(),
            width: view.width,
            right: basis.right.as_vec3().to_array(),
            height: view.height,
            up: basis.true_up.as_vec3().to_array(),
            focal_px: basis.focal_px as f32,
            forward: basis.forward.as_vec3().to_array(),
            level: first.level,
            step: first.step,
            tolerance: first.tolerance,
            max_steps: first.max_steps,
            method: method_code(first.method),
            resolution: field.resolution as f32,
            depth_scale: field.scale as f32,
            edge_gap: EDGE_GAP,
            refine_iterations: REFINE_ITERATIONS,
            front_mass: FRONT_MASS,
            blend: weight,
            coarse_factor: 0,
            near_scale: 0.0,
            box_min: maps.visible_box[0],
            tiled: Tiling::Grid.code(),
            box_max: maps.visible_box[1],
            interior_curvature: 0.0,
            level_b: second.level,
            step_b: second.step,
            tolerance_b: second.tolerance,
            max_steps_b: second.max_steps,
            method_b: method_code(second.method),
            coarse_width: 0,
            coarse_height: 0,
            row_stride: view.width,
            interior_group_quads: 4,
            guide_step_ratio: 1.0,
            jitter,
            premultiplied: u32::from(field.translucent.is_some()),
            lit: u32::from(relit.is_some()),
            shadow_rays: relit.as_ref().map_or(0, |(_, r)| u32::from(r.shadow_rays)),
            pad2: 0,
            light_weights: relit.as_ref().map_or([0.0; 4], |(_, r)| r.weights),
            light_dir: relit.as_ref().map_or([0.0; 4], |(_, r)| r.light),
            light_a: relit.as_ref().map_or([0.0; 4], |(_, r)| r.proxy[0]),
            light_b: relit.as_ref().map_or([0.0; 4], |(_, r)| r.proxy[1]),
            light_c: relit.as_ref().map_or([0.0; 4], |(_, r)| r.proxy[2]),
        };
        let field_group = relit.as_ref().map_or(&maps.group, |(group, _)| group);
        // Coarse-to-fine (`guide`, the first setting's): a coarse pass renders every
        // guide-th pixel per axis, and its depths bound each pixel's march (docs/marcher.md).
        let methods = MethodSet::of(first.method, second.method);
        let guided = methods == MethodSet::Default;
        let factor = resolved_a.guide;
        let coarse = coarse_size(view.width, view.height, factor).filter(|_| guided);
        let pixels = u64::from(view.width) * u64::from(view.height);
        let gpu = &self.gpu;
        let mut fine = params;
        // The coarse passes, coarsest first, with their sizes, focal lengths and jitters (the
        // frame's, in their pixels): the frame's coarse pass is guided in turn by a pre-coarse
        // pass PRE_FACTOR times coarser.
        let mut levels: Vec<CoarsePass> = Vec::new();
        if let Some((cw, ch)) = coarse {
            let focal = params.focal_px / factor as f32;
            let coarse_jitter = jitter.map(|c| c / factor as f32);
            if let Some(pre) = coarse_size(cw, ch, PRE_FACTOR) {
                let pre_jitter = jitter.map(|c| c / (factor * PRE_FACTOR) as f32);
                levels.push((&targets.pre, pre, focal / PRE_FACTOR as f32, pre_jitter));
            }
            levels.push((&targets.coarse, (cw, ch), focal, coarse_jitter));
            fine.coarse_factor = factor;
            fine.coarse_width = cw;
            fine.coarse_height = ch;
            fine.guide_step_ratio = COARSE_STEP_SCALE;
        }
        // A guided pass is compacted: `cs_tiles` lists the 4×4 quads with some pixel to march
        // and the pass runs one workgroup per four listed quads; the rest of its output stays cleared
        // (a miss). Lavapipe would run every instruction for a skipped pixel anyway. The frame's
        // pass and a coarse pass guided by a pre-coarse one are compacted alike.
        let (columns, rows) = tile_grid(view.width, view.height);
        let (quad_columns, quad_rows) = quad_grid(view.width, view.height);
        let tiled = coarse.is_some()
            && (u64::from(quad_columns) * u64::from(quad_rows)).div_ceil(4) <= u64::from(MAX_TILES)
            && self.switches.tile_compaction;
        let tiling = if tiled { Tiling::Listed } else { Tiling::Grid };
        for (i, &(level, (w, h), focal, jitter)) in levels.iter().enumerate() {
            let mut level_params = RenderParams {
                width: w,
                height: h,
                focal_px: focal,
                near_scale: GUIDE_REACH / focal,
                refine_iterations: COARSE_REFINE_ITERATIONS,
                step: params.step * COARSE_STEP_SCALE,
                max_steps: max_steps_for(params.step * COARSE_STEP_SCALE),
                step_b: params.step_b * COARSE_STEP_SCALE,
                max_steps_b: max_steps_for(params.step_b * COARSE_STEP_SCALE),
                row_stride: coarse_stride(w),
                jitter,
                ..params
            };
            if let Some(&(_, (gw, gh), _, _)) = i.checked_sub(1).and_then(|g| levels.get(g)) {
                level_params.coarse_factor = PRE_FACTOR;
                level_params.coarse_width = gw;
                level_params.coarse_height = gh;
                level_params.tiled = tiling.code();
            }
            gpu.queue
                .write_buffer(&level.uniform, 0, bytemuck::bytes_of(&level_params));
        }
        fine.tiled = tiling.code();
        // Flat quads skip the march (default method only: the fixed baseline marches every
        // pixel it renders).
        let interior = tiled && methods == MethodSet::Default && self.switches.interior;
        let blocks = blocks_share_coarse_cells(view.width, view.height, factor)
            && match self.switches.interior_blocks {
                InteriorBlocks::Off => false,
                InteriorBlocks::On => true,
                InteriorBlocks::Automatic => {
                    interior_block_angle(lf_eye.length(), basis.focal_px) <= INTERIOR_BLOCK_REACH
                }
            };
        if blocks {
            // 16 quads per workgroup: 4 invocations each (shaders/render/main.wgsl `cs_main`).
            fine.interior_group_quads = 16;
        }
        if interior {
            fine.interior_curvature =
                INTERIOR_CURVATURE * first.tolerance.min(second.tolerance) * field.scale as f32;
        }
        if interior {
            let given_back = RenderParams {
                tiled: Tiling::GivenBack.code(),
                ..fine
            };
            gpu.queue.write_buffer(
                &targets.given_back_uniform,
                0,
                bytemuck::bytes_of(&given_back),
            );
        }
        gpu.queue
            .write_buffer(&targets.uniform, 0, bytemuck::bytes_of(&fine));
        if clear_counters {
            gpu.queue
                .write_buffer(&targets.counters, 0, &[0u8; COUNTERS_SIZE as usize]);
        }
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("render"),
            });
        let mut timer = PassTimer::new(self.switches.pass_timing);
        encoder = timer.split(gpu, encoder, "uploads")?;
        for (i, &(level, (cw, ch), _, _)) in levels.iter().enumerate() {
            // Every coarse pass marks near misses; all but the coarsest are guided, and
            // compacted with the frame (the pixels it skips read as far misses, cleared to 0).
            let (level_columns, level_rows) = tile_grid(cw, ch);
            let compact = tiled && i > 0;
            if compact {
                encoder.clear_buffer(&level.depth, 0, None);
                self.list_tiles(
                    &mut encoder,
                    targets,
                    &level.group,
                    field_group,
                    (cw, ch, PRE_FACTOR),
                );
            }
            record_pass(
                &mut encoder,
                "render coarse",
                self.pipeline(methods, Role::Coarse),
                (&level.group, field_group),
                if compact {
                    Workgroups::Indirect(&targets.tile_args, 0)
                } else {
                    Workgroups::Grid(level_columns, level_rows)
                },
            );
            encoder.copy_buffer_to_texture(
                wgpu::TexelCopyBufferInfo {
                    buffer: &level.depth,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(8 * coarse_stride(cw)),
                        rows_per_image: Some(ch),
                    },
                },
                wgpu::TexelCopyTextureInfo {
                    texture: &level.texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::Extent3d {
                    width: cw,
                    height: ch,
                    depth_or_array_layers: 1,
                },
            );
            let name = if i + 1 < levels.len() {
                "pre-coarse"
            } else {
                "coarse"
            };
            encoder = timer.split(gpu, encoder, name)?;
        }
        if tiled {
            encoder.clear_buffer(&targets.color, 0, Some(pixels * 4));
            encoder.clear_buffer(&targets.depth, 0, Some(pixels * 4));
            self.list_tiles(
                &mut encoder,
                targets,
                &targets.group,
                field_group,
                (view.width, view.height, factor),
            );
            encoder = timer.split(gpu, encoder, "tiles")?;
        }
        let role = if coarse.is_some() {
            Role::Guided
        } else {
            Role::Plain
        };
        record_pass(
            &mut encoder,
            "render",
            self.pipeline(methods, role),
            (&targets.group, field_group),
            if tiled {
                Workgroups::Indirect(&targets.tile_args, 0)
            } else {
                Workgroups::Grid(columns, rows)
            },
        );
        encoder = timer.split(gpu, encoder, "frame")?;
        if interior {
            record_pass(
                &mut encoder,
                "render interior",
                self.pipeline(
                    methods,
                    if blocks {
                        Role::InteriorBlocks
                    } else {
                        Role::Interior
                    },
                ),
                (&targets.group, field_group),
                Workgroups::Indirect(&targets.tile_args, INTERIOR_ARGS),
            );
            encoder.copy_buffer_to_buffer(
                &targets.tile_dispatch,
                GIVEN_BACK_ARGS,
                &targets.tile_args,
                GIVEN_BACK_ARGS,
                12,
            );
            record_pass(
                &mut encoder,
                "render given back",
                self.pipeline(methods, Role::Guided),
                (&targets.given_back_group, field_group),
                Workgroups::Indirect(&targets.tile_args, GIVEN_BACK_ARGS),
            );
            encoder = timer.split(gpu, encoder, "interior")?;
        }
        Ok((encoder, timer))
    }

    /// Submits `encoder` with the copies the readback needs, waits, and reads the frame back
    /// (`start`: when its work began; `translucent`: the field's).
    fn read_frame(
        &self,
        targets: &Targets,
        mut encoder: wgpu::CommandEncoder,
        mut timer: PassTimer,
        start: Instant,
        translucent: bool,
    ) -> Result<Frame, RenderError> {
        let gpu = &self.gpu;
        let (width, height) = (targets.width, targets.height);
        let pixels = u64::from(width) * u64::from(height);
        let split = (pixels * 4) as usize;
        if let Some(readback) = &targets.readback {
            encoder.copy_buffer_to_buffer(&targets.color, 0, readback, 0, pixels * 4);
            encoder.copy_buffer_to_buffer(&targets.depth, 0, readback, pixels * 4, pixels * 4);
            encoder.copy_buffer_to_buffer(
                &targets.counters,
                0,
                readback,
                pixels * 8,
                COUNTERS_SIZE,
            );
        }
        gpu.queue.submit([encoder.finish()]);
        let read = |color: &[u8], depth: &[u8], counters: &[u8]| {
            let depth: Vec<f32> = depth
                .chunks_exact(4)
                .map(|c| {
                    let z = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                    // Misses: −1 where marched, 0 where a compacted pass cleared (a hit has
                    // z > 0).
                    if z <= 0.0 { f32::INFINITY } else { z }
                })
                .collect();
            let counters: Vec<u32> = counters
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            (color.to_vec(), depth, counters)
        };
        let (color, depth, counters) = match &targets.readback {
            Some(readback) => gpu.map_read_with(readback, |bytes| {
                read(
                    &bytes[..split],
                    &bytes[split..2 * split],
                    &bytes[2 * split..2 * split + COUNTERS_SIZE as usize],
                )
            })?,
            None => gpu.map_read_many(
                &[&targets.color, &targets.depth, &targets.counters],
                |bytes| read(bytes[0], bytes[1], bytes[2]),
            )?,
        };
        let render_ms = start.elapsed().as_secs_f64() * 1e3;
        timer.finish(width, height);
        Ok(Frame {
            width,
            height,
            color,
            depth,
            translucent,
            stats: FrameStats {
                render_ms,
                rays: u64::from(counters[2]),
                steps: u64::from(counters[1]),
                fetches: u64::from(counters[0]),
            },
        })
    }
}

/// A translucent frame from the marcher's premultiplied output: straight colour
/// `round(255·C/A)` with alpha as it is (an empty pixel is (0, 0, 0, 0)), and depth kept only
/// where `A ≥ τ_d` (DESIGN §9's depth output; the marcher's depth there is where the ray met the
/// maps' depth surface, which a volume bake places where each camera's `A` reached `τ_d`).
fn straighten(color: &mut [u8], depth: &mut [f32], tau: f32) {
    // The 8-bit alpha at or above which A ≥ τ_d.
    let tau_code = (255.0 * tau).round().clamp(1.0, 255.0) as u8;
    for (px, z) in color.chunks_exact_mut(4).zip(depth.iter_mut()) {
        let a = px[3];
        if a == 0 {
            px.copy_from_slice(&[0; 4]);
            *z = f32::INFINITY;
            continue;
        }
        for c in &mut px[..3] {
            *c = ((f32::from(*c) * 255.0 / f32::from(a)).round()).min(255.0) as u8;
        }
        if a < tau_code {
            *z = f32::INFINITY;
        }
    }
}
