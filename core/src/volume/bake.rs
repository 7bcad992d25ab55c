//! Baking a volume into a spherical light field on the GPU (seed 002 §3–§5, DESIGN §9).
//!
//! The frame is the bounding sphere of the part of the volume's box that the transfer function
//! leaves visible ([`visible_box`]), so every camera ray through what shows records it whole
//! and no map texels are spent on empty air. For each camera `p_k` and each texel of
//! its parabolic map, `shaders/volume_bake.wgsl` ray-casts the texel's exact ray through the
//! volume with DESIGN §9's integration — the same box clipping, sample positions, transfer
//! function, opacity correction, early stop and gradient shading as the direct ray caster
//! ([`super::raycast`], which the tests hold every texel against) — and stores:
//! - colour: premultiplied `round(255·C)`, `round(255·A)` (encoding `rgba8_premultiplied`, format
//!   version 2); a texel with `round(255·A) = 0` is empty (0, 0, 0, 0) and has no depth;
//! - depth: `t / chord` (the camera's chord to the unit sphere, as for meshes) at the first sample
//!   after which `A ≥ τ_d`; a ray whose `A` stays below `τ_d` (thin haze) stores the
//!   opacity-weighted mean of its samples' `t` instead, so the renderer reprojects its haze from
//!   where it lies rather than dropping it. The renderer reports a pixel's depth only where its
//!   reconstructed `A ≥ τ_d` (the §9 depth output).
//!
//! The volume lives on the GPU as an `R32Float` 3-D texture read with `textureLoad` (trilinear
//! interpolation in the shader, in `f32`, as the CPU does it in `f64`); labels are stored as their
//! `f32` values, exact up to 2²⁴.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use serde::Serialize;

use super::layers::{LayersError, VolumeLayer, validate as validate_layers};
use super::raycast::{RaycastError, RaycastOptions, Segment, SplitRule, VolumeRays};
use super::tf::TransferFunction;
use super::{Volume, Voxels};
use crate::asset::{
    AssetError, AssetHeader, AssetWriter, BlockCodec, Channel, Encoding, ImageKey, LayerOrder,
    LfFrame, Provenance, encode_asset,
};
use crate::bake::{BakeError, check_codecs, encode_depth, gpu_cameras};
use crate::geometry;
use crate::gpu::{Gpu, GpuError, storage_buffer};

/// Largest label a label volume may bake (labels are exact in the shader's `f32` up to 2²⁴).
pub const MAX_LABEL: u32 = 1 << 24;

/// Why a volume bake is refused or fails.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum VolumeBakeError {
    /// A bad camera count, resolution or depth precision.
    #[error(transparent)]
    Options(#[from] BakeError),
    /// The volume, transfer function and ray-cast options do not fit together.
    #[error(transparent)]
    Raycast(#[from] RaycastError),
    /// A label beyond [`MAX_LABEL`].
    #[error("label {0} is above {MAX_LABEL}, the largest label the GPU bake represents exactly")]
    LabelTooLarge(u32),
    /// The transfer function leaves every voxel transparent.
    #[error("the transfer function leaves every voxel transparent: there is nothing to bake")]
    Empty,
    /// The device failed or a limit was exceeded.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// Writing the asset failed.
    #[error(transparent)]
    Asset(#[from] AssetError),
    /// The layers are inconsistent (names, opacities, kinds of TF).
    #[error(transparent)]
    Layers(#[from] LayersError),
}

/// Options of `lumigraph bake VOLUME`.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeBakeOptions {
    /// Cameras: 12, 42, 162 or 642.
    pub cameras: u32,
    /// Parabolic map side in pixels.
    pub resolution: u32,
    /// Depth precision: 16 (default) or 8 bits.
    pub depth_bits: u8,
    /// Sampling, shading and depth threshold (DESIGN §9).
    pub raycast: RaycastOptions,
    /// Block codec of the premultiplied colour pages (`bc7`; `None` stores RGBA8).
    pub color_codec: Option<BlockCodec>,
    /// Block codec of the depth pages (`bc4`, with 8-bit depth; `None` stores the codes).
    pub depth_codec: Option<BlockCodec>,
}

impl Default for VolumeBakeOptions {
    fn default() -> Self {
        Self {
            cameras: 162,
            resolution: 256,
            depth_bits: 16,
            raycast: RaycastOptions::default(),
            color_codec: None,
            depth_codec: None,
        }
    }
}

/// What a volume bake produced.
#[derive(Clone, Debug, Serialize)]
pub struct VolumeBakeReport {
    /// Cameras baked.
    pub cameras: u32,
    /// Map resolution.
    pub resolution: u32,
    /// Voxels of the source.
    pub voxels: u64,
    /// Sample spacing used, world units.
    pub step: f64,
    /// Fraction of texels that hold something (`round(255·A) ≥ 1`).
    pub covered_fraction: f64,
    /// Wall-clock bake time (ray casting, encoding, writing).
    pub bake_ms: f64,
    /// Asset size in bytes (0 for an in-memory bake).
    pub asset_bytes: u64,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct VolumeBakeParams {
    resolution: u32,
    first_camera: u32,
    camera_count: u32,
    labels: u32,
    center: [f32; 3],
    scale: f32,
    inv_m: [[f32; 4]; 3],
    origin: [f32; 3],
    step: f32,
    dims: [f32; 3],
    step_ratio: f32,
    light: [f32; 3],
    ambient: f32,
    spacing: [f32; 3],
    flat_below: f32,
    depth_threshold: f32,
    shade: u32,
    tf_count: u32,
    /// 0: whole rays; 1: split by accumulated opacity; 2: by value; 3: at label transitions
    /// (depth layers).
    split_mode: u32,
    /// The segment a depth layer keeps.
    segment: u32,
    /// Boundaries in `splits`.
    split_count: u32,
    pad: [u32; 2],
    /// The boundaries, four to a vector.
    splits: [[f32; 4]; 4],
}
const _: () = assert!(std::mem::size_of::<VolumeBakeParams>() == 240);

/// Most boundaries the shader's uniform holds.
const MAX_SPLITS: usize = 16;
const _: () = assert!(super::layers::MAX_VOLUME_LAYERS - 1 <= MAX_SPLITS);

impl VolumeBakeParams {
    /// Restricts the rays to a depth layer's segment (whole rays for `None`).
    fn set_segment(&mut self, segment: Option<&Segment>) {
        self.split_mode = 0;
        self.segment = 0;
        self.split_count = 0;
        self.splits = [[0.0; 4]; 4];
        if let Some(s) = segment {
            self.split_mode = match s.split {
                SplitRule::Opacity(_) => 1,
                SplitRule::Value(_) => 2,
                SplitRule::Labels(_) => 3,
            };
            self.segment = u32::try_from(s.index).unwrap_or(u32::MAX);
            self.split_count = s.split.boundary_count().min(MAX_SPLITS) as u32;
            for (k, &b) in s.split.thresholds().iter().take(MAX_SPLITS).enumerate() {
                self.splits[k / 4][k % 4] = b as f32;
            }
        }
    }
}

/// A transfer-function entry as `volume_bake.wgsl` reads it.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TfEntry {
    value: f32,
    pad: [f32; 3],
    rgba: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<TfEntry>() == 32);

/// The index-space box `[lo, hi]` outside which `tf` leaves `volume` fully transparent, or
/// `None` where it is transparent everywhere.
///
/// Scalar volumes: a trilinear sample lies within the range of its cell's eight corner voxels,
/// so a cell (between voxel centres) is kept where the TF's opacity is above zero anywhere on
/// that range ([`TransferFunction::opaque_somewhere`]); the clamped half voxel beyond each edge
/// belongs to the edge cells. Label volumes: the voxels whose label is listed with `a > 0`, each
/// with its nearest-voxel cell `±½`. The box is clamped to the volume's `[−½, dims − ½]`.
pub fn visible_box(volume: &Volume, tf: &TransferFunction) -> Option<([f64; 3], [f64; 3])> {
    let [nx, ny, nz] = volume.dims.map(|d| d as usize);
    let mut lo = [usize::MAX; 3];
    let mut hi = [0usize; 3];
    let mut keep = |i: usize, j: usize, k: usize, i1: usize, j1: usize, k1: usize| {
        lo = [lo[0].min(i), lo[1].min(j), lo[2].min(k)];
        hi = [hi[0].max(i1), hi[1].max(j1), hi[2].max(k1)];
    };
    match &volume.voxels {
        Voxels::Labels(v) => {
            for k in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        let l = f64::from(v[(k * ny + j) * nx + i]);
                        if tf.opaque_somewhere(l, l) {
                            keep(i, j, k, i, j, k);
                        }
                    }
                }
            }
            if lo[0] == usize::MAX {
                return None;
            }
            let f = |a: usize| a as f64;
            Some((
                [f(lo[0]) - 0.5, f(lo[1]) - 0.5, f(lo[2]) - 0.5],
                [f(hi[0]) + 0.5, f(hi[1]) + 0.5, f(hi[2]) + 0.5],
            ))
        }
        Voxels::Scalar(v) => {
            // Cells c..c+1 per axis (a single voxel on an axis of size 1).
            let cells = |n: usize| n.saturating_sub(1).max(1);
            let at = |i: usize, j: usize, k: usize| v[(k * ny + j) * nx + i];
            for k in 0..cells(nz) {
                let k1 = (k + 1).min(nz - 1);
                for j in 0..cells(ny) {
                    let j1 = (j + 1).min(ny - 1);
                    for i in 0..cells(nx) {
                        let i1 = (i + 1).min(nx - 1);
                        let corners = [
                            at(i, j, k),
                            at(i1, j, k),
                            at(i, j1, k),
                            at(i1, j1, k),
                            at(i, j, k1),
                            at(i1, j, k1),
                            at(i, j1, k1),
                            at(i1, j1, k1),
                        ];
                        let (mut min, mut max) = (f32::INFINITY, f32::NEG_INFINITY);
                        for c in corners {
                            min = min.min(c);
                            max = max.max(c);
                        }
                        if tf.opaque_somewhere(f64::from(min), f64::from(max)) {
                            keep(i, j, k, i1, j1, k1);
                        }
                    }
                }
            }
            if lo[0] == usize::MAX {
                return None;
            }
            let dims = [nx, ny, nz];
            let (mut l, mut h) = ([0.0; 3], [0.0; 3]);
            for a in 0..3 {
                // A box touching an edge voxel extends over the clamped half voxel beyond it.
                l[a] = if lo[a] == 0 { -0.5 } else { lo[a] as f64 };
                h[a] = if hi[a] + 1 >= dims[a] {
                    dims[a] as f64 - 0.5
                } else {
                    hi[a] as f64
                };
            }
            Some((l, h))
        }
    }
}

/// The light-field frame of a volume seen through `tf`: the bounding sphere of the corners of
/// its [`visible_box`], so that the cameras sit as close to what shows as they can while every
/// ray through it is recorded whole (the bake still samples the whole box, as the direct ray
/// cast does, so the two take the same samples along a ray).
///
/// # Errors
/// [`VolumeBakeError::Empty`] where `tf` leaves every voxel transparent.
pub fn volume_frame(volume: &Volume, tf: &TransferFunction) -> Result<LfFrame, VolumeBakeError> {
    layers_frame(volume, &[tf])
}

/// [`volume_frame`] of several layers' TFs: the sphere around the union of their visible boxes
/// (every layer of a multi light field shares one camera set).
///
/// # Errors
/// [`VolumeBakeError::Empty`] where every TF leaves every voxel transparent.
pub fn layers_frame(
    volume: &Volume,
    tfs: &[&TransferFunction],
) -> Result<LfFrame, VolumeBakeError> {
    let mut union: Option<([f64; 3], [f64; 3])> = None;
    for tf in tfs {
        if let Some((l, h)) = visible_box(volume, tf) {
            union = Some(match union {
                None => (l, h),
                Some((ul, uh)) => (
                    [0, 1, 2].map(|a| ul[a].min(l[a])),
                    [0, 1, 2].map(|a| uh[a].max(h[a])),
                ),
            });
        }
    }
    let (lo, hi) = union.ok_or(VolumeBakeError::Empty)?;
    let center = DVec3::from(volume.world([0, 1, 2].map(|a| f64::midpoint(lo[a], hi[a]))));
    let mut radius: f64 = 0.0;
    for corner in 0..8 {
        let index = [0, 1, 2].map(|a| if corner & (1 << a) == 0 { lo[a] } else { hi[a] });
        radius = radius.max((DVec3::from(volume.world(index)) - center).length());
    }
    Ok(LfFrame {
        center: center.to_array(),
        radius: radius.max(f64::MIN_POSITIVE),
    })
}

/// The volume bake pipeline, built once and reused.
pub struct VolumeBaker {
    gpu: Arc<Gpu>,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    /// The direct view render (`cs_view`).
    view_pipeline: wgpu::ComputePipeline,
    view_layout: wgpu::BindGroupLayout,
}

/// A volume and its transfer function resident on the GPU, with the uniform fields bakes and
/// direct views share ([`VolumeBaker::prepare_direct`], [`VolumeBaker::render_view`]; a bake
/// makes one too). The texture is destroyed on drop.
pub struct DirectVolume {
    /// World position of voxel (0, 0, 0).
    origin: [f64; 3],
    texture: wgpu::Texture,
    view: wgpu::TextureView,
    tf_buffer: wgpu::Buffer,
    params: VolumeBakeParams,
}

impl Drop for DirectVolume {
    fn drop(&mut self) {
        self.texture.destroy();
    }
}

impl VolumeBaker {
    /// Builds the pipeline.
    pub fn new(gpu: Arc<Gpu>) -> VolumeBaker {
        let device = &gpu.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("volume_bake.wgsl"),
            source: wgpu::ShaderSource::Wgsl(crate::shaders::VOLUME_BAKE.into()),
        });
        let compute = wgpu::ShaderStages::COMPUTE;
        let buffer = |binding, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: compute,
            ty: wgpu::BindingType::Buffer {
                ty,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let storage = |read_only| wgpu::BufferBindingType::Storage { read_only };
        let texture_entry = wgpu::BindGroupLayoutEntry {
            binding: 5,
            visibility: compute,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D3,
                multisampled: false,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("volume bake"),
            entries: &[
                buffer(0, wgpu::BufferBindingType::Uniform),
                buffer(1, storage(true)),
                buffer(2, storage(false)),
                buffer(3, storage(false)),
                buffer(4, storage(true)),
                texture_entry,
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("volume bake"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("volume bake"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("cs_main"),
            compilation_options: wgpu::PipelineCompilationOptions::default(),
            cache: None,
        });
        let view_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("volume view"),
            entries: &[
                buffer(0, wgpu::BufferBindingType::Uniform),
                buffer(4, storage(true)),
                texture_entry,
                buffer(6, storage(true)),
                buffer(7, storage(false)),
                buffer(8, storage(false)),
            ],
        });
        let view_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("volume view"),
            bind_group_layouts: &[Some(&view_layout)],
            immediate_size: 0,
        });
        let view_pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("volume view"),
            layout: Some(&view_pipeline_layout),
            module: &module,
            entry_point: Some("cs_view"),
            compilation_options: wgpu::PipelineCompilationOptions::default(),
            cache: None,
        });
        VolumeBaker {
            gpu,
            pipeline,
            layout,
            view_pipeline,
            view_layout,
        }
    }

    /// Uploads `volume` and `tf` for direct view renders (and bakes) with `options`, validated
    /// as the CPU ray caster validates them.
    ///
    /// # Errors
    /// [`VolumeBakeError`]: bad options, a label too large, a device limit.
    pub fn prepare_direct(
        &self,
        volume: &Volume,
        tf: &TransferFunction,
        options: &RaycastOptions,
    ) -> Result<DirectVolume, VolumeBakeError> {
        let rays = VolumeRays::new(volume, tf, options)?;
        let texture = self.upload_volume(volume)?;
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let entries = tf_entries(tf);
        let tf_buffer = storage_buffer(
            &self.gpu,
            "volume transfer function",
            bytemuck::cast_slice(&entries),
            wgpu::BufferUsages::empty(),
        );
        let params = shared_params(volume, &rays, options, entries.len());
        Ok(DirectVolume {
            origin: volume.origin,
            texture,
            view,
            tf_buffer,
            params,
        })
    }

    /// Ray-casts a DESIGN §3 view of a prepared volume on the GPU with the bake's integration
    /// (the direct render a light field is measured against, and its cost): premultiplied RGBA
    /// and z-depth as [`raycast`](super::raycast::raycast) returns them, in `f32` arithmetic.
    ///
    /// # Errors
    /// [`VolumeBakeError`]: a bad view, a device failure or limit.
    pub fn render_view(
        &self,
        direct: &DirectVolume,
        view: &crate::view::View,
    ) -> Result<super::raycast::VolumeImage, VolumeBakeError> {
        let gpu = &self.gpu;
        let basis = view
            .basis(crate::view::DEFAULT_MAX_VIEW_PX)
            .map_err(|e| RaycastError::View(e.to_string()))?;
        let (width, height) = (basis.width, basis.height);
        let pixels = u64::from(width) * u64::from(height);
        let mut dirs = Vec::with_capacity(pixels as usize * 4);
        for i in 0..height {
            for j in 0..width {
                let d = basis.pixel_dir(i, j);
                dirs.extend([
                    d.x as f32,
                    d.y as f32,
                    d.z as f32,
                    d.dot(basis.forward) as f32,
                ]);
            }
        }
        gpu.check_storage("volume view output", pixels * 16)?;
        let dir_buffer = storage_buffer(
            gpu,
            "volume view rays",
            bytemuck::cast_slice(&dirs),
            wgpu::BufferUsages::empty(),
        );
        let out_buffer = |label, bytes| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        };
        let rgba_buffer = out_buffer("volume view colour", pixels * 16);
        let depth_buffer = out_buffer("volume view depth", pixels * 4);
        let mut params = direct.params;
        // Relative to the volume's origin, in f64 before the f32 cast (see `shared_params`).
        params.center = (basis.eye - DVec3::from(direct.origin))
            .as_vec3()
            .to_array();
        params.scale = 1.0;
        params.resolution = width;
        params.camera_count = height;
        self.dispatch(
            "volume view",
            &self.view_pipeline,
            &self.view_layout,
            &params,
            &[
                (4, direct.tf_buffer.as_entire_binding()),
                (5, wgpu::BindingResource::TextureView(&direct.view)),
                (6, dir_buffer.as_entire_binding()),
                (7, rgba_buffer.as_entire_binding()),
                (8, depth_buffer.as_entire_binding()),
            ],
            [width.div_ceil(8), height.div_ceil(8), 1],
        );
        let rgba = gpu.read_buffer(&rgba_buffer, pixels * 16)?;
        let depth = gpu.read_buffer(&depth_buffer, pixels * 4)?;
        gpu.wait()?;
        let rgba: &[[f32; 4]] = bytemuck::cast_slice(&rgba);
        let depth: &[f32] = bytemuck::cast_slice(&depth);
        Ok(super::raycast::VolumeImage {
            width,
            height,
            rgba: rgba.iter().map(|p| p.map(f64::from)).collect(),
            depth: depth
                .iter()
                .map(|&z| if z < 0.0 { f64::INFINITY } else { f64::from(z) })
                .collect(),
            samples: 0,
        })
    }

    /// Runs `pipeline` once over `groups` workgroups with `params` as the uniform at binding 0
    /// and `resources` at their bindings of `layout` (submitted; the caller reads back).
    fn dispatch(
        &self,
        label: &str,
        pipeline: &wgpu::ComputePipeline,
        layout: &wgpu::BindGroupLayout,
        params: &VolumeBakeParams,
        resources: &[(u32, wgpu::BindingResource<'_>)],
        groups: [u32; 3],
    ) {
        use wgpu::util::DeviceExt;
        let device = &self.gpu.device;
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::bytes_of(params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let mut entries = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: uniform.as_entire_binding(),
        }];
        entries.extend(
            resources
                .iter()
                .map(|(binding, resource)| wgpu::BindGroupEntry {
                    binding: *binding,
                    resource: resource.clone(),
                }),
        );
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout,
            entries: &entries,
        });
        let mut encoder =
            device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(label),
                timestamp_writes: None,
            });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
        }
        self.gpu.queue.submit([encoder.finish()]);
    }

    /// Bakes `volume` through `tf` into an `.lfa` file at `path` (written atomically), calling
    /// `progress(cameras_done, cameras_total)` as cameras finish.
    ///
    /// # Errors
    /// [`VolumeBakeError`]; on error nothing is left at `path`.
    pub fn bake_to_file(
        &self,
        volume: &Volume,
        tf: &TransferFunction,
        options: &VolumeBakeOptions,
        source: &Provenance,
        path: &Path,
        progress: &mut dyn FnMut(u32, u32),
    ) -> Result<VolumeBakeReport, VolumeBakeError> {
        let layers = [VolumeLayer::single(tf)];
        self.bake_layers_to_file(volume, &layers, options, source, path, progress)
    }

    /// Bakes a multi light field: every layer of `layers` through its TF on one camera set
    /// ([`layers_frame`]), into an `.lfa` file at `path` (written atomically). `progress` counts
    /// cameras over all layers.
    ///
    /// # Errors
    /// [`VolumeBakeError`]; on error nothing is left at `path`.
    pub fn bake_layers_to_file(
        &self,
        volume: &Volume,
        layers: &[VolumeLayer],
        options: &VolumeBakeOptions,
        source: &Provenance,
        path: &Path,
        progress: &mut dyn FnMut(u32, u32),
    ) -> Result<VolumeBakeReport, VolumeBakeError> {
        let start = Instant::now();
        let header = prepare(volume, layers, options, source)?;
        let mut covered = 0u64;
        let frame = header.frame.clone();
        let mut writer = AssetWriter::create(path, header)?;
        self.cast_all(
            volume,
            layers,
            options,
            &frame,
            progress,
            &mut |key, bytes, count| {
                covered += count;
                writer.add_image(key, &bytes)
            },
        )?;
        let bake_ms = start.elapsed().as_secs_f64() * 1e3;
        writer.set_bake_ms(bake_ms);
        writer.finish()?;
        Ok(report(
            volume,
            layers,
            options,
            covered,
            bake_ms,
            std::fs::metadata(path).map_or(0, |m| m.len()),
        ))
    }

    /// Bakes `volume` into an in-memory `.lfa` image, with its report.
    ///
    /// # Errors
    /// [`VolumeBakeError`].
    pub fn bake_to_bytes(
        &self,
        volume: &Volume,
        tf: &TransferFunction,
        options: &VolumeBakeOptions,
        source: &Provenance,
        progress: &mut dyn FnMut(u32, u32),
    ) -> Result<(Vec<u8>, VolumeBakeReport), VolumeBakeError> {
        let layers = [VolumeLayer::single(tf)];
        self.bake_layers_to_bytes(volume, &layers, options, source, progress)
    }

    /// [`VolumeBaker::bake_layers_to_file`] into an in-memory `.lfa` image.
    ///
    /// # Errors
    /// [`VolumeBakeError`].
    pub fn bake_layers_to_bytes(
        &self,
        volume: &Volume,
        layers: &[VolumeLayer],
        options: &VolumeBakeOptions,
        source: &Provenance,
        progress: &mut dyn FnMut(u32, u32),
    ) -> Result<(Vec<u8>, VolumeBakeReport), VolumeBakeError> {
        let start = Instant::now();
        let mut header = prepare(volume, layers, options, source)?;
        let mut images = Vec::new();
        let mut covered = 0u64;
        let frame = header.frame.clone();
        self.cast_all(
            volume,
            layers,
            options,
            &frame,
            progress,
            &mut |key, bytes, count| {
                covered += count;
                images.push((key, bytes));
                Ok(())
            },
        )?;
        let bake_ms = start.elapsed().as_secs_f64() * 1e3;
        header.provenance.bake_ms = bake_ms;
        let bytes = encode_asset(header, images)?;
        let report = report(
            volume,
            layers,
            options,
            covered,
            bake_ms,
            bytes.len() as u64,
        );
        Ok((bytes, report))
    }

    /// Ray-casts every camera's maps around `frame` (the header's: [`volume_frame`]), handing
    /// each image to `sink` with its count of covered texels (colour images; 0 for depth).
    fn cast_all(
        &self,
        volume: &Volume,
        layers: &[VolumeLayer],
        options: &VolumeBakeOptions,
        frame: &LfFrame,
        progress: &mut dyn FnMut(u32, u32),
        sink: &mut dyn FnMut(ImageKey, Vec<u8>, u64) -> Result<(), AssetError>,
    ) -> Result<(), VolumeBakeError> {
        let gpu = &self.gpu;
        let mut resident = self.prepare_direct(volume, &layers[0].tf, &options.raycast)?;
        let n = options.resolution;
        let texels = u64::from(n) * u64::from(n);
        // Batches of at most 1 Mi texels: a volume texel costs hundreds of samples, and a
        // dispatch should stay short on lavapipe and report progress.
        let per_batch = u32::try_from((1u64 << 20) / texels)
            .unwrap_or(1)
            .clamp(1, 16);
        let total = options.cameras;
        let cameras = gpu_cameras(total as usize);
        let camera_buffer = storage_buffer(
            gpu,
            "volume bake cameras",
            bytemuck::cast_slice(&cameras),
            wgpu::BufferUsages::empty(),
        );
        let out_bytes = u64::from(per_batch) * texels * 4;
        gpu.check_storage("volume bake output", out_bytes)?;
        let make_out = |label| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: out_bytes,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        };
        let out_color = make_out("volume bake colour");
        let out_depth = make_out("volume bake depth");
        let grand_total = total * layers.len() as u32;
        progress(0, grand_total);
        for (layer_index, layer) in layers.iter().enumerate() {
            if layer_index > 0 {
                // The next layer's TF on the resident volume (the texture is uploaded once).
                let rays = layer.rays(volume, &options.raycast)?;
                let entries = tf_entries(&layer.tf);
                resident.tf_buffer = storage_buffer(
                    gpu,
                    "volume transfer function",
                    bytemuck::cast_slice(&entries),
                    wgpu::BufferUsages::empty(),
                );
                resident.params = shared_params(volume, &rays, &options.raycast, entries.len());
            }
            let layer_key = u16::try_from(layer_index).unwrap_or(u16::MAX);
            let done_before = total * layer_index as u32;
            let mut params = resident.params;
            params.set_segment(layer.segment.as_ref());
            params.resolution = n;
            // Relative to the volume's origin, in f64 before the f32 cast (see `shared_params`).
            params.center = [0, 1, 2].map(|a| (frame.center[a] - volume.origin[a]) as f32);
            params.scale = frame.world_from_lf_scale() as f32;
            let mut first = 0;
            while first < total {
                let count = per_batch.min(total - first);
                params.first_camera = first;
                params.camera_count = count;
                self.dispatch(
                    "volume bake",
                    &self.pipeline,
                    &self.layout,
                    &params,
                    &[
                        (1, camera_buffer.as_entire_binding()),
                        (2, out_color.as_entire_binding()),
                        (3, out_depth.as_entire_binding()),
                        (4, resident.tf_buffer.as_entire_binding()),
                        (5, wgpu::BindingResource::TextureView(&resident.view)),
                    ],
                    [n.div_ceil(8), n.div_ceil(8), count],
                );
                let used = u64::from(count) * texels * 4;
                let depths = gpu.read_buffer(&out_depth, used)?;
                let colors = gpu.read_buffer(&out_color, used)?;
                gpu.wait()?;
                let image_bytes = (texels * 4) as usize;
                for c in 0..count {
                    let camera = first + c;
                    let range = c as usize * image_bytes..(c as usize + 1) * image_bytes;
                    let color = colors[range.clone()].to_vec();
                    let covered = color.chunks_exact(4).filter(|t| t[3] > 0).count() as u64;
                    let depth_f32: &[f32] = bytemuck::cast_slice(&depths[range]);
                    let depth = encode_depth(depth_f32, options.depth_bits);
                    sink(
                        ImageKey::new(layer_key, 0, camera, Channel::Color),
                        color,
                        covered,
                    )?;
                    sink(
                        ImageKey::new(layer_key, 0, camera, Channel::Depth),
                        depth,
                        0,
                    )?;
                }
                first += count;
                progress(done_before + first, grand_total);
            }
        }
        Ok(())
    }

    fn upload_volume(&self, volume: &Volume) -> Result<wgpu::Texture, VolumeBakeError> {
        let gpu = &self.gpu;
        let limit = gpu.device.limits().max_texture_dimension_3d;
        if let Some(&side) = volume.dims.iter().find(|&&d| d > limit) {
            return Err(GpuError::Limit {
                what: "3-D texture side (voxels)",
                needed: u64::from(side),
                limit: u64::from(limit),
            }
            .into());
        }
        let values: Vec<f32> = match &volume.voxels {
            Voxels::Scalar(v) => v.clone(),
            Voxels::Labels(v) => {
                if let Some(&big) = v.iter().find(|&&l| l > MAX_LABEL) {
                    return Err(VolumeBakeError::LabelTooLarge(big));
                }
                v.iter().map(|&l| l as f32).collect()
            }
        };
        let [nx, ny, nz] = volume.dims;
        let size = wgpu::Extent3d {
            width: nx,
            height: ny,
            depth_or_array_layers: nz,
        };
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("volume"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format: wgpu::TextureFormat::R32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        // One slab of k-slices at a time keeps the staging copy bounded (≤ 64 MiB).
        let slice_bytes = u64::from(nx) * u64::from(ny) * 4;
        let per_write = u32::try_from(((64u64 << 20) / slice_bytes).max(1))
            .unwrap_or(1)
            .min(nz);
        let mut k = 0;
        while k < nz {
            let count = per_write.min(nz - k);
            let start = (u64::from(k) * slice_bytes / 4) as usize;
            let end = (u64::from(k + count) * slice_bytes / 4) as usize;
            gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: 0, z: k },
                    aspect: wgpu::TextureAspect::All,
                },
                bytemuck::cast_slice(&values[start..end]),
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(nx * 4),
                    rows_per_image: Some(ny),
                },
                wgpu::Extent3d {
                    width: nx,
                    height: ny,
                    depth_or_array_layers: count,
                },
            );
            k += count;
        }
        gpu.wait()?;
        Ok(texture)
    }
}

/// The uniform's fields common to bakes and direct views (the caller sets the ray origin
/// fields: resolution, cameras, centre and scale).
fn shared_params(
    volume: &Volume,
    rays: &VolumeRays<'_>,
    options: &RaycastOptions,
    tf_count: usize,
) -> VolumeBakeParams {
    let inverse = rays.index_from_world();
    let row = |r: usize| {
        [
            inverse[r][0] as f32,
            inverse[r][1] as f32,
            inverse[r][2] as f32,
            0.0,
        ]
    };
    let light = DVec3::from(options.light).normalize();
    VolumeBakeParams {
        resolution: 0,
        first_camera: 0,
        camera_count: 0,
        labels: u32::from(matches!(volume.voxels, Voxels::Labels(_))),
        center: [0.0; 3],
        scale: 1.0,
        inv_m: [row(0), row(1), row(2)],
        // The shader works relative to voxel (0, 0, 0): ray origins are sent as offsets from
        // it, formed in f64, so large world coordinates do not cancel in f32.
        origin: [0.0; 3],
        step: rays.step() as f32,
        dims: volume.dims.map(|d| d as f32),
        step_ratio: (rays.step() / rays.ref_step()) as f32,
        light: light.as_vec3().to_array(),
        ambient: options.ambient as f32,
        spacing: rays.gradient_spacing().map(|s| s as f32),
        flat_below: rays.flat_below() as f32,
        depth_threshold: options.depth_threshold as f32,
        shade: u32::from(options.shade),
        tf_count: u32::try_from(tf_count).unwrap_or(u32::MAX),
        split_mode: 0,
        segment: 0,
        split_count: 0,
        pad: [0; 2],
        splits: [[0.0; 4]; 4],
    }
}

/// The transfer function as the shader's sorted entries.
fn tf_entries(tf: &TransferFunction) -> Vec<TfEntry> {
    let entry = |value: f64, rgba: [f64; 4]| TfEntry {
        value: value as f32,
        pad: [0.0; 3],
        rgba: rgba.map(|c| c as f32),
    };
    match tf {
        TransferFunction::Scalar { points, .. } => points
            .iter()
            .map(|p| entry(p[0], [p[1], p[2], p[3], p[4]]))
            .collect(),
        TransferFunction::Labels { labels, .. } => labels
            .iter()
            .filter(|(label, _)| **label <= MAX_LABEL)
            .map(|(&label, &rgba)| entry(f64::from(label), rgba))
            .collect(),
    }
}

/// The header of a volume asset: the bake's options as provenance, premultiplied colour.
fn prepare(
    volume: &Volume,
    layers: &[VolumeLayer],
    options: &VolumeBakeOptions,
    source: &Provenance,
) -> Result<AssetHeader, VolumeBakeError> {
    validate_layers(layers)?;
    let tf = &layers[0].tf;
    let level = geometry::level_for_camera_count(options.cameras)
        .ok_or(BakeError::BadCameras(options.cameras))?;
    if !(8..=crate::bake::MAX_BAKE_RESOLUTION).contains(&options.resolution) {
        return Err(BakeError::BadResolution(options.resolution).into());
    }
    if options.depth_bits != 8 && options.depth_bits != 16 {
        return Err(BakeError::BadDepthBits(options.depth_bits).into());
    }
    check_codecs(
        options.color_codec,
        options.depth_codec,
        Encoding::Rgba8Premultiplied,
        options.depth_bits,
        options.resolution,
    )?;
    // The same checks the direct ray caster makes, before anything is uploaded.
    for layer in &layers[1..] {
        layer.rays(volume, &options.raycast)?;
    }
    let rays = layers[0].rays(volume, &options.raycast)?;
    let r = &options.raycast;
    let provenance = Provenance {
        lumigraph_version: env!("CARGO_PKG_VERSION").to_owned(),
        bake_options: serde_json::json!({
            "source": "volume",
            "cameras": options.cameras,
            "resolution": options.resolution,
            "depth_bits": options.depth_bits,
            "tf": tf.to_json(),
            "labels": tf.is_labels(),
            "shade": r.shade,
            "step": rays.step(),
            "depth_threshold": r.depth_threshold,
            "light": r.light,
            "ambient": r.ambient,
            "dims": volume.dims,
            "color_codec": options.color_codec,
            "depth_codec": options.depth_codec,
        }),
        triangles: 0,
        vertices: 0,
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
    let mut provenance = provenance;
    if (layers.len() > 1 || layers[0].name != "default")
        && let serde_json::Value::Object(map) = &mut provenance.bake_options
    {
        // Depth layers record the whole split (TF, boundaries, names); TF layers their list.
        let json = VolumeLayer::to_json(layers);
        map.insert(
            "layers".to_owned(),
            match VolumeLayer::order(layers) {
                LayerOrder::Ray => json,
                LayerOrder::Depth => json["layers"].clone(),
            },
        );
    }
    let tfs: Vec<&TransferFunction> = layers.iter().map(|l| &l.tf).collect();
    let mut header = AssetHeader::new_spherical(
        u8::try_from(level).unwrap_or(u8::MAX),
        options.resolution,
        layers_frame(volume, &tfs)?,
        depth,
        provenance,
    )?;
    header.set_color_encoding(Encoding::Rgba8Premultiplied);
    header.set_compression(Channel::Color, options.color_codec)?;
    header.set_compression(Channel::Depth, options.depth_codec)?;
    header.set_layer_order(VolumeLayer::order(layers));
    header.layers = layers
        .iter()
        .map(|l| crate::asset::LayerDesc {
            name: l.name.clone(),
            default_opacity: l.opacity,
        })
        .collect();
    Ok(header)
}

fn report(
    volume: &Volume,
    layers: &[VolumeLayer],
    options: &VolumeBakeOptions,
    covered: u64,
    bake_ms: f64,
    asset_bytes: u64,
) -> VolumeBakeReport {
    let texels =
        u64::from(options.cameras) * u64::from(options.resolution).pow(2) * layers.len() as u64;
    let step = options
        .raycast
        .step
        .unwrap_or_else(|| layers[0].tf.ref_step_for(volume) / 2.0);
    VolumeBakeReport {
        cameras: options.cameras,
        resolution: options.resolution,
        voxels: volume.voxel_count(),
        step,
        covered_fraction: covered as f64 / texels.max(1) as f64,
        bake_ms,
        asset_bytes,
    }
}
