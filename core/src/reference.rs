//! The reference renderer: direct rasterization of the source mesh with the same view
//! convention and shading as the baker (DESIGN §3, §6) — the ground truth for every quality
//! number. It reads the same storage buffers as the bake ray tracer, so geometry, attributes and
//! texture sampling are identical; colour and world z-depth come from one fragment shader.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use crate::frame::{Frame, FrameStats};
use crate::gpu::mesh::{GpuMesh, mesh_bind_group, mesh_layout, mesh_sampler};
use crate::gpu::{Gpu, GpuError};
use crate::mesh::Mesh;
use crate::metrics::DepthFootprint;
use crate::shading::{GpuShading, Shading, ShadingError};
use crate::view::{DEFAULT_MAX_VIEW_PX, View, ViewError};

/// Errors of the reference renderer.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReferenceError {
    /// The view is invalid.
    #[error(transparent)]
    View(#[from] ViewError),
    /// Bad shading options.
    #[error(transparent)]
    Shading(#[from] ShadingError),
    /// The device failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// A projection ([`ReferenceRenderer::render_projection`]) is invalid.
    #[error("invalid projection: {0}")]
    Projection(String),
}

/// A pinhole camera more general than a [`View`]: separate horizontal and vertical focal lengths
/// and a principal point off the image centre (the off-axis frusta of two-plane cameras). Pixel
/// `(row i, column j)` sees the direction `x·right + y·up + forward` with
/// `x = (j + ½ − W/2 − center_px[0]) / focal_px[0]` and
/// `y = (H/2 − i − ½ − center_px[1]) / focal_px[1]`; a [`View`] is the case of equal focal lengths
/// and a centred principal point (DESIGN §3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projection {
    /// Camera position, world units.
    pub eye: glam::DVec3,
    /// Unit image-right axis.
    pub right: glam::DVec3,
    /// Unit image-up axis, orthogonal to `right`.
    pub up: glam::DVec3,
    /// Unit viewing axis, orthogonal to both.
    pub forward: glam::DVec3,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Horizontal and vertical focal lengths, pixels.
    pub focal_px: [f64; 2],
    /// Principal point offset from the image centre, pixels (+x right, +y up).
    pub center_px: [f64; 2],
    /// Near clipping distance along `forward`, world units: nearer geometry is not drawn.
    pub near: f64,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ReferenceParams {
    eye: [f32; 3],
    width: f32,
    right: [f32; 3],
    height: f32,
    up: [f32; 3],
    focal_px: f32,
    forward: [f32; 3],
    near: f32,
    depth_scale: f32,
    focal_y_px: f32,
    center_px: [f32; 2],
    shading: GpuShading,
}
const _: () = assert!(std::mem::size_of::<ReferenceParams>() == 112);

/// The rasterization pipeline, built once.
pub struct ReferenceRenderer {
    gpu: Arc<Gpu>,
    pipeline: wgpu::RenderPipeline,
    frame_layout: wgpu::BindGroupLayout,
    mesh_layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    lock: Mutex<()>,
}

const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const ZDEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

impl ReferenceRenderer {
    /// Builds the pipeline.
    pub fn new(gpu: Arc<Gpu>) -> ReferenceRenderer {
        let device = &gpu.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("reference.wgsl"),
            source: wgpu::ShaderSource::Wgsl(crate::shaders::REFERENCE.into()),
        });
        let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("reference frame"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let mesh_layout = mesh_layout(
            &gpu,
            wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT,
        );
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("reference"),
            bind_group_layouts: &[Some(&frame_layout), Some(&mesh_layout)],
            immediate_size: 0,
        });
        let target = |format| {
            Some(wgpu::ColorTargetState {
                format,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })
        };
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("reference"),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState {
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Greater),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                targets: &[target(COLOR_FORMAT), target(ZDEPTH_FORMAT)],
            }),
            multiview_mask: None,
            cache: None,
        });
        let sampler = mesh_sampler(&gpu);
        ReferenceRenderer {
            gpu,
            pipeline,
            frame_layout,
            mesh_layout,
            sampler,
            lock: Mutex::new(()),
        }
    }

    /// Uploads a mesh for repeated reference renders.
    ///
    /// # Errors
    /// [`GpuError::Limit`] when the mesh exceeds device limits.
    pub fn upload(&self, mesh: &Mesh) -> Result<GpuMesh, GpuError> {
        GpuMesh::upload(&self.gpu, mesh)
    }

    /// Rasterizes `mesh` from `view` (world coordinates) with `shading`.
    ///
    /// # Errors
    /// [`ReferenceError`] for a bad view or shading, or a device failure.
    pub fn render(
        &self,
        mesh: &GpuMesh,
        view: &View,
        shading: &Shading,
    ) -> Result<Frame, ReferenceError> {
        shading.validate()?;
        let max_px = DEFAULT_MAX_VIEW_PX.min(self.gpu.device.limits().max_texture_dimension_2d);
        let basis = view.basis(max_px)?;
        let start = Instant::now();
        let frame = &mesh.frame;
        let scale = frame.world_from_lf_scale();
        let eye = (basis.eye - glam::DVec3::from(frame.center)) / scale;
        if !eye.is_finite() {
            return Err(ReferenceError::View(ViewError::NotFinite("eye")));
        }
        // Near plane just in front of the bounding sphere (radius 1/√2 in this frame), never
        // closer than 1e-5 of the distance: reverse-Z keeps precision far beyond it.
        let dist = eye.length();
        let near = (dist - std::f64::consts::FRAC_1_SQRT_2 * 1.01).max(dist.max(1.0) * 1e-5);
        // The view as a centred projection, in the mesh's frame.
        let in_frame = Projection {
            eye,
            right: basis.right,
            up: basis.true_up,
            forward: basis.forward,
            width: view.width,
            height: view.height,
            focal_px: [basis.focal_px; 2],
            center_px: [0.0; 2],
            near,
        };
        self.draw(mesh, &in_frame, scale, shading, start)
    }

    /// Rasterizes `mesh` through a general pinhole [`Projection`] (world coordinates) with
    /// `shading`; depth is the z-depth along `forward` in world units, `+inf` where nothing is hit.
    ///
    /// # Errors
    /// [`ReferenceError::Projection`] for non-finite or non-orthonormal axes, a size of 0 or over
    /// the device's limit, focal lengths that are not finite and positive, or a near distance
    /// that is not finite and positive; bad shading; a device failure.
    pub fn render_projection(
        &self,
        mesh: &GpuMesh,
        projection: &Projection,
        shading: &Shading,
    ) -> Result<Frame, ReferenceError> {
        shading.validate()?;
        let p = projection;
        let bad = |why: String| Err(ReferenceError::Projection(why));
        let max_px = DEFAULT_MAX_VIEW_PX.min(self.gpu.device.limits().max_texture_dimension_2d);
        if p.width == 0 || p.height == 0 || p.width > max_px || p.height > max_px {
            return bad(format!(
                "{}x{} pixels (1..={max_px} per side)",
                p.width, p.height
            ));
        }
        if !(p.eye.is_finite() && p.right.is_finite() && p.up.is_finite() && p.forward.is_finite())
        {
            return bad("eye and axes must be finite".to_owned());
        }
        let orthonormal = [p.right, p.up, p.forward]
            .iter()
            .all(|a| (a.length() - 1.0).abs() <= 1e-6)
            && p.right.dot(p.up).abs() <= 1e-6
            && p.right.dot(p.forward).abs() <= 1e-6
            && p.up.dot(p.forward).abs() <= 1e-6;
        if !orthonormal {
            return bad("right, up and forward must be orthonormal".to_owned());
        }
        if !p.focal_px.iter().all(|f| f.is_finite() && *f > 0.0)
            || !p.center_px.iter().all(|c| c.is_finite())
        {
            return bad(format!(
                "focal lengths {:?} must be finite and positive, the centre {:?} finite",
                p.focal_px, p.center_px
            ));
        }
        if !(p.near.is_finite() && p.near > 0.0) {
            return bad(format!("near {} must be finite and positive", p.near));
        }
        let start = Instant::now();
        let frame = &mesh.frame;
        let scale = frame.world_from_lf_scale();
        let eye = (p.eye - glam::DVec3::from(frame.center)) / scale;
        let near = p.near / scale;
        if !(eye.is_finite() && near.is_finite() && near > 0.0) {
            return bad("the eye or near distance is out of range of the mesh's frame".to_owned());
        }
        let in_frame = Projection { eye, near, ..*p };
        self.draw(mesh, &in_frame, scale, shading, start)
    }

    /// Draws through `p`, whose eye and near distance are in the mesh's light-field frame
    /// (`scale` world units per frame unit, for world z-depths).
    fn draw(
        &self,
        mesh: &GpuMesh,
        p: &Projection,
        scale: f64,
        shading: &Shading,
        start: Instant,
    ) -> Result<Frame, ReferenceError> {
        let (width, height) = (p.width, p.height);
        let params = ReferenceParams {
            eye: p.eye.as_vec3().to_array(),
            width: width as f32,
            right: p.right.as_vec3().to_array(),
            height: height as f32,
            up: p.up.as_vec3().to_array(),
            focal_px: p.focal_px[0] as f32,
            forward: p.forward.as_vec3().to_array(),
            near: p.near as f32,
            depth_scale: scale as f32,
            focal_y_px: p.focal_px[1] as f32,
            center_px: [p.center_px[0] as f32, p.center_px[1] as f32],
            shading: shading.to_gpu(),
        };
        let _guard = self
            .lock
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let device = &self.gpu.device;
        let uniform = {
            use wgpu::util::DeviceExt;
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("reference params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            })
        };
        let frame_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("reference frame"),
            layout: &self.frame_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: uniform.as_entire_binding(),
            }],
        });
        let mesh_group = mesh_bind_group(&self.gpu, &self.mesh_layout, mesh, &self.sampler);
        let size = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        };
        let make = |label, format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let attach = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC;
        let color = make("reference colour", COLOR_FORMAT, attach);
        let zdepth = make("reference z", ZDEPTH_FORMAT, attach);
        let depth = make(
            "reference depth buffer",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let color_view = color.create_view(&wgpu::TextureViewDescriptor::default());
        let zdepth_view = zdepth.create_view(&wgpu::TextureViewDescriptor::default());
        let depth_view = depth.create_view(&wgpu::TextureViewDescriptor::default());
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("reference"),
        });
        {
            let attachment = |view, clear| {
                Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(clear),
                        store: wgpu::StoreOp::Store,
                    },
                })
            };
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("reference"),
                color_attachments: &[
                    attachment(&color_view, wgpu::Color::TRANSPARENT),
                    attachment(
                        &zdepth_view,
                        wgpu::Color {
                            r: -1.0,
                            g: 0.0,
                            b: 0.0,
                            a: 0.0,
                        },
                    ),
                ],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &frame_group, &[]);
            pass.set_bind_group(1, &mesh_group, &[]);
            pass.draw(0..mesh.triangles * 3, 0..1);
        }
        // Rows padded to 256 bytes for the copy.
        let row_bytes = width * 4;
        let padded = row_bytes.div_ceil(256) * 256;
        let buffer_size = u64::from(padded) * u64::from(height);
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("reference readback"),
            size: buffer_size * 2,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        for (i, texture) in [&color, &zdepth].into_iter().enumerate() {
            encoder.copy_texture_to_buffer(
                texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: &readback,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: buffer_size * i as u64,
                        bytes_per_row: Some(padded),
                        rows_per_image: Some(height),
                    },
                },
                size,
            );
        }
        self.gpu.queue.submit([encoder.finish()]);
        let bytes = self.gpu.map_read(&readback)?;
        let (w, h) = (width as usize, height as usize);
        let mut color_out = Vec::with_capacity(w * h * 4);
        let mut depth_out = Vec::with_capacity(w * h);
        let half = buffer_size as usize;
        for row in 0..h {
            let start_row = row * padded as usize;
            color_out.extend_from_slice(&bytes[start_row..start_row + w * 4]);
            for c in bytes[half + start_row..half + start_row + w * 4].chunks_exact(4) {
                let z = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                depth_out.push(if z < 0.0 { f32::INFINITY } else { z });
            }
        }
        let covered = depth_out.iter().filter(|z| z.is_finite()).count() as u64;
        Ok(Frame {
            width,
            height,
            color: color_out,
            depth: depth_out,
            translucent: false,
            stats: FrameStats {
                render_ms: start.elapsed().as_secs_f64() * 1e3,
                rays: covered,
                steps: 0,
                fetches: 0,
            },
        })
    }
}

impl ReferenceRenderer {
    /// The supersampled reference that refined stills ([`crate::refine`]) are measured against:
    /// `view` rasterized at `factor` times its width and height (the same field of view, so
    /// `factor`² sub-pixel samples on a regular grid per pixel) and box-filtered back. Colour is
    /// the mean RGBA of the samples (misses transparent black, so alpha is the covered fraction);
    /// a pixel is covered where at least half its samples hit, with the depth of the hit nearest
    /// its centre (an odd `factor` has a sample at the centre). Stats are the large render's.
    ///
    /// # Errors
    /// As [`ReferenceRenderer::render`]; [`ViewError::BadSize`] when `factor` is 0 or makes the
    /// large view exceed the size cap.
    pub fn render_supersampled(
        &self,
        mesh: &GpuMesh,
        view: &View,
        shading: &Shading,
        factor: u32,
    ) -> Result<Frame, ReferenceError> {
        Ok(self
            .render_supersampled_footprint(mesh, view, shading, factor)?
            .0)
    }

    /// [`ReferenceRenderer::render_supersampled`] and the z-depth of every sub-pixel sample
    /// (for [`crate::metrics::wrong_surface_footprint_px`]).
    ///
    /// # Errors
    /// As [`ReferenceRenderer::render_supersampled`].
    pub fn render_supersampled_footprint(
        &self,
        mesh: &GpuMesh,
        view: &View,
        shading: &Shading,
        factor: u32,
    ) -> Result<(Frame, DepthFootprint), ReferenceError> {
        let max_px = DEFAULT_MAX_VIEW_PX.min(self.gpu.device.limits().max_texture_dimension_2d);
        view.basis(max_px)?;
        let scale = |side: u32| side.saturating_mul(factor);
        let large_view = View {
            width: scale(view.width),
            height: scale(view.height),
            ..view.clone()
        };
        let large = self.render(mesh, &large_view, shading)?;
        let (w, h, k) = (view.width as usize, view.height as usize, factor as usize);
        let large_width = w * k;
        let samples = k * k;
        // Squared distance of sub-sample (a, b) from the pixel centre, in sub-samples (× 4).
        let offset = |a: usize| (2 * a + 1).abs_diff(k);
        let mut color = Vec::with_capacity(w * h * 4);
        let mut depth = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let mut sum = [0_usize; 4];
                let mut hits = 0;
                let mut nearest: Option<(usize, f32)> = None;
                for b in 0..k {
                    for a in 0..k {
                        let i = (y * k + b) * large_width + x * k + a;
                        for (s, &c) in sum.iter_mut().zip(&large.color[4 * i..4 * i + 4]) {
                            *s += usize::from(c);
                        }
                        let z = large.depth[i];
                        if z.is_finite() {
                            hits += 1;
                            let d = offset(a).pow(2) + offset(b).pow(2);
                            if nearest.is_none_or(|(best, _)| d < best) {
                                nearest = Some((d, z));
                            }
                        }
                    }
                }
                color.extend(sum.map(|s| ((s + samples / 2) / samples) as u8));
                depth.push(match nearest {
                    Some((_, z)) if 2 * hits >= samples => z,
                    _ => f32::INFINITY,
                });
            }
        }
        let footprint = DepthFootprint {
            width: view.width,
            height: view.height,
            factor,
            depth: large.depth,
        };
        let frame = Frame {
            width: view.width,
            height: view.height,
            color,
            depth,
            translucent: false,
            stats: large.stats,
        };
        Ok((frame, footprint))
    }
}
