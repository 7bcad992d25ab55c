//! Baking a mesh into a spherical light field on the GPU (seed 002 §3, DESIGN §4).
//!
//! For each camera `p_k` of the chosen icosphere level and each texel of its `N×N` parabolic map,
//! the bake shader (`shaders/bake.wgsl`) traces the texel's exact ray from `p_k` through a BVH of
//! the mesh (in the light-field frame) to the first hit. Depth is therefore exact per texel — no
//! rasterized flat triangles standing in for the non-linear parabolic mapping, no blending across
//! silhouettes — and colour is the DESIGN §3 shading at the hit with `v` towards the camera.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::asset::{
    AssetError, AssetHeader, AssetWriter, BlockCodec, Channel, Encoding, ImageKey, MemoryWriter,
    Provenance,
};
use crate::deform::{DEFAULT_TOLERANCE, StateMesh, Tolerance};
use crate::geometry::{self, CAMERA_COUNTS};
use crate::gpu::mesh::{GpuMesh, mesh_bind_group, mesh_layout, mesh_sampler, storage_entry};
use crate::gpu::{Gpu, GpuError, storage_buffer};
use crate::mesh::Mesh;
use crate::shading::{GpuShading, ShadePart, Shading, ShadingError};

/// Largest map resolution accepted by the baker.
pub const MAX_BAKE_RESOLUTION: u32 = 4096;

/// Errors while baking.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BakeError {
    /// Camera count is not an icosphere level.
    #[error("--cameras {0} is not one of 12, 42, 162, 642")]
    BadCameras(u32),
    /// Resolution out of range.
    #[error("resolution {0} px must be between 8 and {MAX_BAKE_RESOLUTION}")]
    BadResolution(u32),
    /// Depth bits other than 8 or 16.
    #[error("depth bits {0} must be 8 or 16")]
    BadDepthBits(u8),
    /// A block codec that does not fit its channel or the bake.
    #[error("{0}")]
    BadCodec(String),
    /// Bad shading options.
    #[error(transparent)]
    Shading(#[from] ShadingError),
    /// A bad light-proxy size.
    #[error(transparent)]
    Lights(#[from] crate::light::LightError),
    /// Light states asked of an unlit bake, whose colour does not depend on the light.
    #[error("--lights relights a lit bake: drop --unlit or --lights")]
    LightsUnlit,
    /// Bad deformation states.
    #[error(transparent)]
    Deform(#[from] crate::deform::DeformError),
    /// Light states and deformation states in one asset.
    #[error(
        "--lights and --state in one bake: light states relight the base state only; bake the \
         deformation states into an asset of their own"
    )]
    StatesWithLights,
    /// The device failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// Writing the asset failed.
    #[error(transparent)]
    Asset(#[from] AssetError),
}

/// Bake options (CLI flags of `lumigraph bake`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BakeOptions {
    /// Cameras: 12, 42, 162 or 642.
    pub cameras: u32,
    /// Parabolic map side in pixels.
    pub resolution: u32,
    /// Shading model options.
    pub shading: Shading,
    /// Depth precision: 16 (default) or 8 bits.
    pub depth_bits: u8,
    /// Light states (DESIGN §9, [`crate::light`]): the colour is also baked for each of this
    /// many light directions (12, 42 or 162) plus the ambient part alone, so that renders can
    /// relight the asset; `None`: the base state only (left out of the JSON).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lights: Option<u32>,
    /// Trace only the front of triangles (counter-clockwise seen from the camera), as for the
    /// depth reliefs of imported views ([`crate::import_views`]), whose backs are other views'
    /// business; `false` (the default, left out of the JSON): both sides.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub one_sided: bool,
    /// Block compression of the colour pages (`bc1` or `bc7`; docs/format.md §7.1); `None`
    /// (left out of the JSON): RGBA8 texels.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub color_codec: Option<BlockCodec>,
    /// Block compression of the depth pages (`bc4`, of 8-bit depth); `None`: the texels.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_codec: Option<BlockCodec>,
}

impl Default for BakeOptions {
    fn default() -> Self {
        Self {
            cameras: 162,
            resolution: 256,
            shading: Shading::default(),
            depth_bits: 16,
            lights: None,
            one_sided: false,
            color_codec: None,
            depth_codec: None,
        }
    }
}

/// Checks block codecs against the bake: the colour codec must keep colour stored in
/// `color_encoding` (`bc1` keeps 1-bit alpha only, so premultiplied semi-transparent colour takes
/// `bc7`), the depth codec compresses 8-bit codes, and blocks tile the maps.
///
/// # Errors
/// [`BakeError::BadCodec`] naming the codec and what to use instead.
pub fn check_codecs(
    color_codec: Option<BlockCodec>,
    depth_codec: Option<BlockCodec>,
    color_encoding: Encoding,
    depth_bits: u8,
    resolution: u32,
) -> Result<(), BakeError> {
    let fitting = |channel, encoding| {
        BlockCodec::ALL
            .iter()
            .filter(|c| c.allowed_for(channel, encoding))
            .map(|c| c.name())
            .collect::<Vec<_>>()
            .join(" or ")
    };
    if let Some(codec) = color_codec
        && !codec.allowed_for(Channel::Color, color_encoding)
    {
        let why = if color_encoding == Encoding::Rgba8Premultiplied {
            " (this colour is semi-transparent and premultiplied; bc1 keeps 1-bit alpha only)"
        } else {
            ""
        };
        return Err(BakeError::BadCodec(format!(
            "colour codec {codec}: use {}{why}",
            fitting(Channel::Color, color_encoding)
        )));
    }
    if let Some(codec) = depth_codec
        && !codec.allowed_for(Channel::Depth, Encoding::R8)
    {
        return Err(BakeError::BadCodec(format!(
            "depth codec {codec}: use {}",
            fitting(Channel::Depth, Encoding::R8)
        )));
    }
    if depth_codec.is_some() && depth_bits != 8 {
        return Err(BakeError::BadCodec(
            "depth codec bc4 compresses 8-bit depth: bake with 8 depth bits".to_owned(),
        ));
    }
    if (color_codec.is_some() || depth_codec.is_some())
        && !resolution.is_multiple_of(crate::asset::BLOCK)
    {
        return Err(BakeError::BadCodec(format!(
            "block compression needs a resolution that is a multiple of 4, not {resolution}"
        )));
    }
    Ok(())
}

impl BakeOptions {
    /// The options an asset was baked with, as its provenance records them; defaults for what
    /// it lacks or cannot be read (assets written before a field existed), the recorded
    /// shading kept whenever it parses, so a reference render shades as the bake did.
    pub fn of(header: &crate::asset::AssetHeader) -> BakeOptions {
        let recorded = &header.provenance.bake_options;
        serde_json::from_value(recorded.clone()).unwrap_or_else(|_| BakeOptions {
            shading: recorded
                .get("shading")
                .and_then(|v| serde_json::from_value(v.clone()).ok())
                .unwrap_or_default(),
            ..BakeOptions::default()
        })
    }

    /// Checks every option.
    ///
    /// # Errors
    /// The [`BakeError`] naming the bad option.
    pub fn validate(&self) -> Result<u32, BakeError> {
        let level = geometry::level_for_camera_count(self.cameras)
            .ok_or(BakeError::BadCameras(self.cameras))?;
        if !(8..=MAX_BAKE_RESOLUTION).contains(&self.resolution) {
            return Err(BakeError::BadResolution(self.resolution));
        }
        if self.depth_bits != 8 && self.depth_bits != 16 {
            return Err(BakeError::BadDepthBits(self.depth_bits));
        }
        check_codecs(
            self.color_codec,
            self.depth_codec,
            Encoding::Rgba8,
            self.depth_bits,
            self.resolution,
        )?;
        self.shading.validate()?;
        if let Some(count) = self.lights {
            crate::light::proxy_level(count).ok_or(crate::light::LightError::BadCount(count))?;
            if self.shading.unlit {
                return Err(BakeError::LightsUnlit);
            }
        }
        Ok(level)
    }
}

/// What a bake produced.
#[derive(Clone, Debug, Serialize)]
pub struct BakeReport {
    /// Cameras baked.
    pub cameras: u32,
    /// Map resolution.
    pub resolution: u32,
    /// Source triangles.
    pub triangles: u64,
    /// Wall-clock bake time (ray tracing, encoding, writing).
    pub bake_ms: f64,
    /// Asset size in bytes.
    pub asset_bytes: u64,
}

/// The bake pipeline, built once and reused.
pub struct Baker {
    gpu: Arc<Gpu>,
    pipeline: wgpu::ComputePipeline,
    /// `cs_edges`: sub-texel silhouette positions in the alpha of no-hit texels.
    edges: wgpu::ComputePipeline,
    /// `cs_shade`: a light state's colour from the hits `cs_main` recorded.
    shade: wgpu::ComputePipeline,
    frame_layout: wgpu::BindGroupLayout,
    /// `cs_edges`'s list of texels.
    edge_layout: wgpu::BindGroupLayout,
    mesh_layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BakeParams {
    resolution: u32,
    first_camera: u32,
    camera_count: u32,
    /// Bit 0: record hits (light states); bit 1: front faces only ([`BakeOptions::one_sided`]).
    flags: u32,
    shading: GpuShading,
}
const _: () = assert!(std::mem::size_of::<BakeParams>() == 48);

/// One camera as the shaders read it (bake.wgsl `struct BakeCamera`): position and local frame,
/// 64 bytes.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct GpuCamera {
    pub position: [f32; 4],
    pub x: [f32; 4],
    pub y: [f32; 4],
    pub z: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuCamera>() == 64);

/// The first `count` cameras with their local frames.
pub(crate) fn gpu_cameras(count: usize) -> Vec<GpuCamera> {
    let set = geometry::camera_set();
    set.positions[..count]
        .iter()
        .map(|p| {
            let [x, y, z] = geometry::camera_frame(*p);
            let v4 = |v: glam::Vec3| [v.x, v.y, v.z, 0.0];
            GpuCamera {
                position: v4(*p),
                x: v4(x),
                y: v4(y),
                z: v4(z),
            }
        })
        .collect()
}

/// Hex SHA-256 of `bytes` (provenance).
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    let digest = sha2::Sha256::digest(bytes);
    digest.iter().fold(String::with_capacity(64), |mut hex, b| {
        use std::fmt::Write;
        let _ = write!(hex, "{b:02x}");
        hex
    })
}

/// The deformation states of a bake ([`crate::deform`]).
#[derive(Clone, Debug)]
pub struct StateBake<'a> {
    /// The state meshes, in state order after the base state.
    pub meshes: &'a [StateMesh<'a>],
    /// Largest difference a page may have from the base state and still be left out.
    pub tolerance: Tolerance,
    /// Page side of an asset with states (the unit a state stores; the base state's pages
    /// too): [`crate::deform::DEFAULT_STATE_PAGE`] unless set.
    pub page_size: u32,
    /// The frame every state is baked in: `None`, the base mesh's bounding sphere; an
    /// animation gives the sphere around all its frames.
    pub frame: Option<crate::asset::LfFrame>,
    /// The base state's params (an animation's frame 0).
    pub base_params: Option<&'a serde_json::Map<String, serde_json::Value>>,
}

impl Default for StateBake<'_> {
    fn default() -> Self {
        Self {
            meshes: &[],
            tolerance: DEFAULT_TOLERANCE,
            page_size: crate::deform::DEFAULT_STATE_PAGE,
            frame: None,
            base_params: None,
        }
    }
}

/// Where the baked images go.
enum Sink {
    File(Box<AssetWriter>),
    Memory(Box<MemoryWriter>),
}

impl Baker {
    /// Builds the pipeline.
    pub fn new(gpu: Arc<Gpu>) -> Baker {
        let device = &gpu.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("bake.wgsl"),
            source: wgpu::ShaderSource::Wgsl(crate::shaders::BAKE.into()),
        });
        let uniform = wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("bake frame"),
            entries: &[
                uniform,
                storage_entry(1, true),
                storage_entry(2, false),
                storage_entry(3, false),
                storage_entry(4, false),
            ]
            .map(|e| wgpu::BindGroupLayoutEntry {
                visibility: wgpu::ShaderStages::COMPUTE,
                ..e
            }),
        });
        let mesh_layout = mesh_layout(&gpu, wgpu::ShaderStages::COMPUTE);
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("bake"),
            bind_group_layouts: &[Some(&frame_layout), Some(&mesh_layout)],
            immediate_size: 0,
        });
        let edge_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("bake edge texels"),
            entries: &[storage_entry(0, true), storage_entry(1, false)].map(|e| {
                wgpu::BindGroupLayoutEntry {
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ..e
                }
            }),
        });
        let edges_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("bake edges"),
            bind_group_layouts: &[Some(&frame_layout), Some(&mesh_layout), Some(&edge_layout)],
            immediate_size: 0,
        });
        let entry = |name, layout| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(name),
                layout: Some(layout),
                module: &module,
                entry_point: Some(name),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                cache: None,
            })
        };
        let pipeline = entry("cs_main", &layout);
        let edges = entry("cs_edges", &edges_layout);
        let shade = entry("cs_shade", &layout);
        let sampler = mesh_sampler(&gpu);
        Baker {
            gpu,
            pipeline,
            edges,
            shade,
            frame_layout,
            edge_layout,
            mesh_layout,
            sampler,
        }
    }

    /// Bakes `mesh` into an `.lfa` file at `path` (written atomically), calling
    /// `progress(cameras_done, cameras_total)` as cameras finish.
    ///
    /// # Errors
    /// [`BakeError`]; on error nothing is left at `path`.
    pub fn bake_to_file(
        &self,
        mesh: &Mesh,
        options: &BakeOptions,
        source: &Provenance,
        path: &Path,
        progress: &mut dyn FnMut(u32, u32),
    ) -> Result<BakeReport, BakeError> {
        self.bake_states_to_file(mesh, &StateBake::default(), options, source, path, progress)
    }

    /// [`Self::bake_to_file`] with deformation states ([`crate::deform`]): each state mesh is
    /// traced in the base mesh's frame, and only its pages that differ from the base state by
    /// more than the tolerance are stored (pages of `states.page_size` texels).
    ///
    /// # Errors
    /// [`BakeError`]: also [`BakeError::Deform`] for a state outside the base's bounding
    /// sphere or a bad name, [`BakeError::StatesWithLights`]. On error nothing is left at
    /// `path`.
    pub fn bake_states_to_file(
        &self,
        mesh: &Mesh,
        states: &StateBake<'_>,
        options: &BakeOptions,
        source: &Provenance,
        path: &Path,
        progress: &mut dyn FnMut(u32, u32),
    ) -> Result<BakeReport, BakeError> {
        let start = Instant::now();
        let (header, gpu_mesh, state_meshes) = self.prepare(mesh, states, options, source)?;
        let mut sink = Sink::File(Box::new(AssetWriter::create(path, header)?));
        self.trace_all(
            &gpu_mesh,
            &state_meshes,
            states.tolerance,
            options,
            &mut sink,
            progress,
        )?;
        let Sink::File(mut writer) = sink else {
            unreachable!("sink kind is fixed above")
        };
        let bake_ms = start.elapsed().as_secs_f64() * 1e3;
        writer.set_bake_ms(bake_ms);
        writer.finish()?;
        let asset_bytes = std::fs::metadata(path).map_or(0, |m| m.len());
        Ok(BakeReport {
            cameras: options.cameras,
            resolution: options.resolution,
            triangles: mesh.triangles.len() as u64,
            bake_ms,
            asset_bytes,
        })
    }

    /// Bakes `mesh` into an in-memory `.lfa` image.
    ///
    /// # Errors
    /// [`BakeError`].
    pub fn bake_to_bytes(
        &self,
        mesh: &Mesh,
        options: &BakeOptions,
        source: &Provenance,
        progress: &mut dyn FnMut(u32, u32),
    ) -> Result<Vec<u8>, BakeError> {
        self.bake_states_to_bytes(mesh, &StateBake::default(), options, source, progress)
    }

    /// [`Self::bake_to_bytes`] with deformation states, as [`Self::bake_states_to_file`].
    ///
    /// # Errors
    /// As [`Self::bake_states_to_file`].
    pub fn bake_states_to_bytes(
        &self,
        mesh: &Mesh,
        states: &StateBake<'_>,
        options: &BakeOptions,
        source: &Provenance,
        progress: &mut dyn FnMut(u32, u32),
    ) -> Result<Vec<u8>, BakeError> {
        let start = Instant::now();
        let (header, gpu_mesh, state_meshes) = self.prepare(mesh, states, options, source)?;
        let mut sink = Sink::Memory(Box::new(MemoryWriter::new(header)?));
        self.trace_all(
            &gpu_mesh,
            &state_meshes,
            states.tolerance,
            options,
            &mut sink,
            progress,
        )?;
        let Sink::Memory(mut writer) = sink else {
            unreachable!("sink kind is fixed above")
        };
        writer.set_bake_ms(start.elapsed().as_secs_f64() * 1e3);
        Ok(writer.finish()?)
    }

    #[allow(clippy::type_complexity)]
    fn prepare(
        &self,
        mesh: &Mesh,
        states: &StateBake<'_>,
        options: &BakeOptions,
        source: &Provenance,
    ) -> Result<(AssetHeader, GpuMesh, Vec<GpuMesh>), BakeError> {
        let level = options.validate()?;
        if !states.meshes.is_empty() && options.lights.is_some() {
            return Err(BakeError::StatesWithLights);
        }
        let gpu_mesh = match &states.frame {
            Some(frame) => {
                let base = StateMesh {
                    name: "base frame",
                    mesh,
                    source_name: "",
                    source_sha256: "",
                    params: None,
                };
                crate::deform::check_states(frame, &[base])?;
                GpuMesh::upload_in(&self.gpu, mesh, frame.clone())?
            }
            None => GpuMesh::upload(&self.gpu, mesh)?,
        };
        crate::deform::check_states(&gpu_mesh.frame, states.meshes)?;
        let state_meshes = states
            .meshes
            .iter()
            .map(|s| GpuMesh::upload_in(&self.gpu, s.mesh, gpu_mesh.frame.clone()))
            .collect::<Result<Vec<_>, _>>()?;
        let provenance = Provenance {
            lumigraph_version: env!("CARGO_PKG_VERSION").to_owned(),
            bake_options: serde_json::to_value(options).unwrap_or_default(),
            triangles: mesh.triangles.len() as u64,
            vertices: mesh.positions.len() as u64,
            created_unix: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
            ..source.clone()
        };
        let depth = if options.depth_bits == 8 {
            Encoding::R8
        } else {
            Encoding::R16
        };
        let mut header = AssetHeader::new_spherical(
            u8::try_from(level).unwrap_or(u8::MAX),
            options.resolution,
            gpu_mesh.frame.clone(),
            depth,
            provenance,
        )?;
        header.set_compression(Channel::Color, options.color_codec)?;
        header.set_compression(Channel::Depth, options.depth_codec)?;
        if let Some(count) = options.lights {
            header.states.extend(crate::light::state_descs(count)?);
            header.validate()?;
        }
        if let Some(params) = states.base_params
            && let Some(base) = header.states.first_mut()
        {
            base.params.clone_from(params);
        }
        if !states.meshes.is_empty() {
            header
                .states
                .extend(crate::deform::state_descs(states.meshes));
            header.page_size = states.page_size;
            header.validate()?;
        }
        Ok((header, gpu_mesh, state_meshes))
    }

    #[allow(clippy::too_many_arguments, clippy::too_many_lines)]
    fn trace_all(
        &self,
        mesh: &GpuMesh,
        state_meshes: &[GpuMesh],
        tolerance: Tolerance,
        options: &BakeOptions,
        sink: &mut Sink,
        progress: &mut dyn FnMut(u32, u32),
    ) -> Result<(), BakeError> {
        let gpu = &self.gpu;
        let n = options.resolution;
        let texels = u64::from(n) * u64::from(n);
        // Batch cameras so one dispatch stays well below a second on lavapipe and the output
        // buffers stay bounded (≤ 64 MiB per channel).
        let per_batch = u32::try_from((16u64 << 20) / texels)
            .unwrap_or(1)
            .clamp(1, 16);
        let total = options.cameras;
        let cameras = gpu_cameras(total as usize);
        let camera_buffer = storage_buffer(
            gpu,
            "bake cameras",
            bytemuck::cast_slice(&cameras),
            wgpu::BufferUsages::empty(),
        );
        let out_bytes = u64::from(per_batch) * texels * 4;
        gpu.check_storage("bake output", out_bytes)?;
        let make_out = |label| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: out_bytes,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        };
        let out_color = make_out("bake colour");
        let out_depth = make_out("bake depth");
        // Light states shade again from the base pass's hits (16 bytes a texel); without them
        // the binding is a stand-in nothing writes.
        let light_passes = light_passes(options)?;
        let hits_bytes = if light_passes.is_empty() {
            16
        } else {
            u64::from(per_batch) * texels * 16
        };
        gpu.check_storage("bake hits", hits_bytes)?;
        let hits = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bake hits"),
            size: hits_bytes,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let mesh_group = mesh_bind_group(gpu, &self.mesh_layout, mesh, &self.sampler);
        let state_groups: Vec<wgpu::BindGroup> = state_meshes
            .iter()
            .map(|m| mesh_bind_group(gpu, &self.mesh_layout, m, &self.sampler))
            .collect();
        let grid = sink.page_grid()?;
        let shading = options.shading.to_gpu();
        progress(0, total);
        let mut first = 0;
        while first < total {
            let count = per_batch.min(total - first);
            let frame_group = |shading: GpuShading, store_hits: bool| {
                let params = BakeParams {
                    resolution: n,
                    first_camera: first,
                    camera_count: count,
                    flags: u32::from(store_hits) | (u32::from(options.one_sided) << 1),
                    shading,
                };
                let uniform = {
                    use wgpu::util::DeviceExt;
                    gpu.device
                        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                            label: Some("bake params"),
                            contents: bytemuck::bytes_of(&params),
                            usage: wgpu::BufferUsages::UNIFORM,
                        })
                };
                gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("bake frame"),
                    layout: &self.frame_layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: uniform.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: camera_buffer.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: out_color.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 3,
                            resource: out_depth.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 4,
                            resource: hits.as_entire_binding(),
                        },
                    ],
                })
            };
            let base_group = frame_group(shading, !light_passes.is_empty());
            let dispatch = |pipeline: &wgpu::ComputePipeline,
                            mesh_group: &wgpu::BindGroup,
                            frame_group: &wgpu::BindGroup,
                            edge_group: Option<&wgpu::BindGroup>,
                            groups: (u32, u32, u32)| {
                let mut encoder =
                    gpu.device
                        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                            label: Some("bake"),
                        });
                {
                    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                        label: Some("bake"),
                        timestamp_writes: None,
                    });
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, frame_group, &[]);
                    pass.set_bind_group(1, mesh_group, &[]);
                    if let Some(group) = edge_group {
                        pass.set_bind_group(2, group, &[]);
                    }
                    pass.dispatch_workgroups(groups.0, groups.1, groups.2);
                }
                gpu.queue.submit([encoder.finish()]);
            };
            let map_groups = (n.div_ceil(8), n.div_ceil(8), count);
            let used = u64::from(count) * texels * 4;
            // Colours (with sub-texel silhouettes) and float depths of the batch, for one mesh.
            let trace = |mesh_group: &wgpu::BindGroup,
                         frame_group: &wgpu::BindGroup|
             -> Result<(Vec<u8>, Vec<u8>), BakeError> {
                dispatch(&self.pipeline, mesh_group, frame_group, None, map_groups);
                let depths = gpu.read_buffer(&out_depth, used)?;
                let pairs = edge_pairs(bytemuck::cast_slice(&depths), n as usize);
                let mut colors = gpu.read_buffer(&out_color, used)?;
                if !pairs.is_empty() {
                    let list = storage_buffer(
                        gpu,
                        "bake edge pairs",
                        bytemuck::cast_slice(&pairs),
                        wgpu::BufferUsages::empty(),
                    );
                    let crossings_bytes = pairs.len() as u64 * 8;
                    let crossings = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some("bake edge crossings"),
                        size: crossings_bytes,
                        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                        mapped_at_creation: false,
                    });
                    let edge_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some("bake edge pairs"),
                        layout: &self.edge_layout,
                        entries: &[
                            wgpu::BindGroupEntry {
                                binding: 0,
                                resource: list.as_entire_binding(),
                            },
                            wgpu::BindGroupEntry {
                                binding: 1,
                                resource: crossings.as_entire_binding(),
                            },
                        ],
                    });
                    let groups = u32::try_from(pairs.len().div_ceil(64)).unwrap_or(u32::MAX);
                    dispatch(
                        &self.edges,
                        mesh_group,
                        frame_group,
                        Some(&edge_group),
                        (groups, 1, 1),
                    );
                    let found = gpu.read_buffer(&crossings, crossings_bytes)?;
                    store_edges(&mut colors, &pairs, bytemuck::cast_slice(&found));
                }
                Ok((colors, depths))
            };
            let (colors, depths) = trace(&mesh_group, &base_group)?;
            let image_bytes = (texels * 4) as usize;
            let mut base_images = Vec::with_capacity(if state_groups.is_empty() {
                0
            } else {
                count as usize
            });
            for c in 0..count {
                let camera = first + c;
                let range = c as usize * image_bytes..(c as usize + 1) * image_bytes;
                let color = colors[range.clone()].to_vec();
                let depth_f32: &[f32] = bytemuck::cast_slice(&depths[range]);
                let depth = encode_depth(depth_f32, options.depth_bits);
                sink.add(ImageKey::new(0, 0, camera, Channel::Color), &color)?;
                sink.add(ImageKey::new(0, 0, camera, Channel::Depth), &depth)?;
                if !state_groups.is_empty() {
                    base_images.push((color, depth));
                }
            }
            // Light states: colour only, shaded from the hits just traced (one trace per texel
            // serves every light); their depth is the base state's.
            for (state, shading) in &light_passes {
                dispatch(
                    &self.shade,
                    &mesh_group,
                    &frame_group(*shading, true),
                    None,
                    map_groups,
                );
                let colors = gpu.read_buffer(&out_color, used)?;
                for c in 0..count {
                    let range = c as usize * image_bytes..(c as usize + 1) * image_bytes;
                    let key = ImageKey::new(0, *state, first + c, Channel::Color);
                    sink.add(key, &colors[range])?;
                }
            }
            // Deformation states: the same cameras traced through each state mesh, keeping the
            // pages that differ from the base state.
            let state_frame = if state_groups.is_empty() {
                None
            } else {
                Some(frame_group(shading, false))
            };
            let depth_bpp = if options.depth_bits == 8 { 1 } else { 2 };
            for (i, group) in state_groups.iter().enumerate() {
                let Some(state_frame) = &state_frame else {
                    break;
                };
                let state = i as u16 + 1;
                let (colors, depths) = trace(group, state_frame)?;
                for (c, (base_color, base_depth)) in base_images.iter().enumerate() {
                    let camera = first + c as u32;
                    let range = c * image_bytes..(c + 1) * image_bytes;
                    let color = &colors[range.clone()];
                    let depth_f32: &[f32] = bytemuck::cast_slice(&depths[range]);
                    let depth = encode_depth(depth_f32, options.depth_bits);
                    let pages = crate::deform::changed_pages(
                        &grid,
                        base_color,
                        color,
                        4,
                        u16::from(tolerance.color),
                    );
                    sink.add_pages(
                        ImageKey::new(0, state, camera, Channel::Color),
                        color,
                        &pages,
                    )?;
                    let pages = crate::deform::changed_pages(
                        &grid,
                        base_depth,
                        &depth,
                        depth_bpp,
                        tolerance.depth,
                    );
                    sink.add_pages(
                        ImageKey::new(0, state, camera, Channel::Depth),
                        &depth,
                        &pages,
                    )?;
                }
            }
            first += count;
            progress(first, total);
        }
        Ok(())
    }
}

impl Sink {
    fn page_grid(&self) -> Result<crate::asset::PageGrid, AssetError> {
        match self {
            Sink::File(writer) => writer.page_grid(),
            Sink::Memory(writer) => Ok(writer.page_grid()),
        }
    }

    fn add(&mut self, key: ImageKey, bytes: &[u8]) -> Result<(), AssetError> {
        match self {
            Sink::File(writer) => writer.add_image(key, bytes),
            Sink::Memory(writer) => writer.add_image(key, bytes),
        }
    }

    fn add_pages(&mut self, key: ImageKey, bytes: &[u8], pages: &[u32]) -> Result<(), AssetError> {
        match self {
            Sink::File(writer) => writer.add_pages(key, bytes, pages),
            Sink::Memory(writer) => writer.add_pages(key, bytes, pages),
        }
    }
}

/// The colour passes of the light states `options` asks for, with their state index (as
/// [`crate::light::state_descs`] orders them after the base state): the ambient part, the
/// shading normal, then the direct part of each proxy direction.
fn light_passes(options: &BakeOptions) -> Result<Vec<(u16, GpuShading)>, BakeError> {
    let Some(count) = options.lights else {
        return Ok(Vec::new());
    };
    let mut out = vec![
        (1, options.shading.part_to_gpu(ShadePart::Ambient)),
        (2, options.shading.part_to_gpu(ShadePart::Normal)),
    ];
    for (i, d) in crate::light::proxy_directions(count)?.iter().enumerate() {
        let shading = Shading {
            light: d.as_vec3().to_array(),
            ..options.shading
        };
        out.push((i as u16 + 3, shading.part_to_gpu(ShadePart::Direct)));
    }
    Ok(out)
}

/// Mask of a pair's texel index in `edge_pairs`; the neighbour's direction is above it.
const EDGE_INDEX_MASK: u32 = (1 << 30) - 1;

/// `cs_edges`'s work (bake.wgsl) for a batch of `n×n` depth maps (normalized, ≥ 1 = no hit):
/// each no-hit texel with a hit 4-neighbour, once per such neighbour, as the texel's index into
/// the batch with the neighbour's direction (0 +x, 1 −x, 2 +y, 3 −y) in bits 30–31.
fn edge_pairs(depths: &[f32], n: usize) -> Vec<u32> {
    let hit = |i: usize| depths[i] < 1.0;
    let mut out = Vec::new();
    for (map, _) in depths.chunks_exact(n * n).enumerate() {
        let base = map * n * n;
        for texel in 0..n * n {
            let i = base + texel;
            let Ok(index) = u32::try_from(i) else {
                continue;
            };
            if hit(i) {
                continue;
            }
            let neighbours = geometry::texel_neighbours(texel, n);
            for (direction, _) in neighbours
                .iter()
                .enumerate()
                .filter(|(_, j)| j.is_some_and(|j| hit(base + j)))
            {
                out.push((index & EDGE_INDEX_MASK) | ((direction as u32) << 30));
            }
        }
    }
    out
}

/// Writes the sub-texel silhouettes `cs_edges` found into the batch's colours (docs/format.md
/// §8.5): per listed no-hit texel, the mean crossing distance e over its hit neighbours as
/// A = max(1, round(255 · e)) and the mean silhouette depth as a 16-bit code in R (low byte) and
/// G. `crossings[i]` is pair i's (distance, depth).
fn store_edges(colors: &mut [u8], pairs: &[u32], crossings: &[[f32; 2]]) {
    let mut i = 0;
    while i < pairs.len() {
        let index = pairs[i] & EDGE_INDEX_MASK;
        let (mut e, mut depth, mut count) = (0.0_f64, 0.0_f64, 0.0_f64);
        while i < pairs.len() && pairs[i] & EDGE_INDEX_MASK == index {
            e += f64::from(crossings[i][0]);
            depth += f64::from(crossings[i][1]);
            count += 1.0;
            i += 1;
        }
        let a = (255.0 * e / count).round().clamp(1.0, 255.0) as u8;
        let code = (depth / count * 65535.0).round().clamp(0.0, 65534.0) as u16;
        let [lo, hi] = code.to_le_bytes();
        let at = index as usize * 4;
        if let Some(texel) = colors.get_mut(at..at + 4) {
            texel.copy_from_slice(&[lo, hi, 0, a]);
        }
    }
}

/// Encodes a depth map (1 = no hit) at 8 or 16 bits, little-endian.
pub(crate) fn encode_depth(depth: &[f32], bits: u8) -> Vec<u8> {
    if bits == 8 {
        depth
            .iter()
            .map(|&d| geometry::encode_depth_u8(if d >= 1.0 { f32::INFINITY } else { d }))
            .collect()
    } else {
        depth
            .iter()
            .flat_map(|&d| {
                geometry::encode_depth_u16(if d >= 1.0 { f32::INFINITY } else { d }).to_le_bytes()
            })
            .collect()
    }
}

/// The camera count of each level (re-exported for callers choosing `--cameras`).
pub const CAMERA_CHOICES: [u32; 4] = CAMERA_COUNTS;
