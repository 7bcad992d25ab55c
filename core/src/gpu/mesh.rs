//! A mesh on the GPU, in the light-field frame (bounding sphere → radius 1/√2 at the origin), as
//! storage buffers that both the bake ray tracer and the reference rasterizer read, so both see
//! exactly the same geometry, attributes and textures.

use glam::{DVec3, Vec3};

use super::{Gpu, array_view, bvh, storage_buffer, texture_array};
use crate::asset::LfFrame;
use crate::mesh::Mesh;

/// Largest side of the shared texture array; larger textures are downscaled to it.
const MAX_ATLAS_PX: u32 = 4096;

/// One vertex (`struct Vertex` in `shaders/shared/mesh.wgsl`): 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuVertex {
    /// Position in the light-field frame.
    pub position: [f32; 3],
    /// Texture u.
    pub u: f32,
    /// Unit normal.
    pub normal: [f32; 3],
    /// Texture v.
    pub v: f32,
    /// Vertex colour (1,1,1,1 when the mesh has none).
    pub color: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuVertex>() == 48);

/// One triangle (`struct Triangle`): vertex indices and material.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTriangle {
    /// Vertex indices.
    pub v: [u32; 3],
    /// Material index.
    pub material: u32,
}
const _: () = assert!(std::mem::size_of::<GpuTriangle>() == 16);

/// One material (`struct Material`): 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuMaterial {
    /// Base-colour factor.
    pub factor: [f32; 4],
    /// Layer in the texture array, or -1 for none.
    pub texture: i32,
    /// Padding.
    pub pad: [i32; 3],
}
const _: () = assert!(std::mem::size_of::<GpuMaterial>() == 32);

/// A mesh uploaded for baking and reference rendering.
pub struct GpuMesh {
    /// The light-field frame the geometry was normalized by.
    pub frame: LfFrame,
    /// Triangle count.
    pub triangles: u32,
    pub(crate) vertex_buffer: wgpu::Buffer,
    pub(crate) triangle_buffer: wgpu::Buffer,
    pub(crate) bvh_buffer: wgpu::Buffer,
    pub(crate) material_buffer: wgpu::Buffer,
    pub(crate) texture_view: wgpu::TextureView,
}

impl GpuMesh {
    /// Uploads `mesh` (already validated by [`Mesh::finish`]).
    ///
    /// # Errors
    /// [`super::GpuError::Limit`] when the mesh exceeds the device's buffer limits.
    pub fn upload(gpu: &Gpu, mesh: &Mesh) -> Result<GpuMesh, super::GpuError> {
        let sphere = mesh.bounding_sphere();
        let frame = LfFrame {
            center: sphere.center.to_array(),
            radius: sphere.radius,
        };
        Self::upload_in(gpu, mesh, frame)
    }

    /// Uploads `mesh` normalized by a given frame rather than its own bounding sphere (a
    /// deformation state is baked in its base mesh's frame); geometry outside the frame's
    /// sphere is the caller's to refuse.
    ///
    /// # Errors
    /// As [`Self::upload`].
    pub fn upload_in(gpu: &Gpu, mesh: &Mesh, frame: LfFrame) -> Result<GpuMesh, super::GpuError> {
        let inv_scale = 1.0 / frame.world_from_lf_scale();
        let center = DVec3::from(frame.center);
        let lf_pos = |p: [f32; 3]| ((DVec3::from(p.map(f64::from)) - center) * inv_scale).as_vec3();
        let vertices: Vec<GpuVertex> = (0..mesh.positions.len())
            .map(|i| {
                let uv = mesh
                    .uvs
                    .as_ref()
                    .and_then(|u| u.get(i))
                    .copied()
                    .unwrap_or([0.0, 0.0]);
                GpuVertex {
                    position: lf_pos(mesh.positions[i]).to_array(),
                    u: uv[0],
                    normal: mesh.normals.get(i).copied().unwrap_or([0.0, 1.0, 0.0]),
                    v: uv[1],
                    color: mesh
                        .colors
                        .as_ref()
                        .and_then(|c| c.get(i))
                        .copied()
                        .unwrap_or([1.0; 4]),
                }
            })
            .collect();
        let corners: Vec<[Vec3; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| Vec3::from(vertices[i as usize].position)))
            .collect();
        let hierarchy = bvh::build(&corners);
        let triangles: Vec<GpuTriangle> = hierarchy
            .order
            .iter()
            .map(|&t| GpuTriangle {
                v: mesh.triangles[t as usize],
                material: mesh
                    .triangle_materials
                    .get(t as usize)
                    .copied()
                    .unwrap_or(0),
            })
            .collect();
        let (atlas_w, atlas_h) = mesh
            .textures
            .iter()
            .fold((1u32, 1u32), |(w, h), t| (w.max(t.width), h.max(t.height)));
        let (atlas_w, atlas_h) = (atlas_w.min(MAX_ATLAS_PX), atlas_h.min(MAX_ATLAS_PX));
        let images: Vec<Vec<u8>> = if mesh.textures.is_empty() {
            vec![vec![255u8; 4]]
        } else {
            mesh.textures
                .iter()
                .map(|t| resize_rgba8(t.width, t.height, &t.rgba8, atlas_w, atlas_h))
                .collect()
        };
        let materials: Vec<GpuMaterial> = mesh
            .materials
            .iter()
            .map(|m| GpuMaterial {
                factor: m.base_color_factor,
                texture: m
                    .base_color_texture
                    .and_then(|t| i32::try_from(t).ok())
                    .unwrap_or(-1),
                pad: [0; 3],
            })
            .collect();
        gpu.check_storage(
            "mesh vertices",
            std::mem::size_of_val(vertices.as_slice()) as u64,
        )?;
        gpu.check_storage(
            "BVH",
            std::mem::size_of_val(hierarchy.nodes.as_slice()) as u64,
        )?;
        gpu.check_layers(Gpu::padded_layers(images.len() as u32))?;
        let refs: Vec<&[u8]> = images.iter().map(Vec::as_slice).collect();
        let texture = texture_array(
            gpu,
            "mesh textures",
            wgpu::TextureFormat::Rgba8Unorm,
            atlas_w,
            atlas_h,
            &refs,
        );
        let none = wgpu::BufferUsages::empty();
        Ok(GpuMesh {
            frame,
            triangles: u32::try_from(triangles.len()).unwrap_or(u32::MAX),
            vertex_buffer: storage_buffer(
                gpu,
                "mesh vertices",
                bytemuck::cast_slice(&vertices),
                none,
            ),
            triangle_buffer: storage_buffer(
                gpu,
                "mesh triangles",
                bytemuck::cast_slice(&triangles),
                none,
            ),
            bvh_buffer: storage_buffer(
                gpu,
                "mesh bvh",
                bytemuck::cast_slice(&hierarchy.nodes),
                none,
            ),
            material_buffer: storage_buffer(
                gpu,
                "mesh materials",
                bytemuck::cast_slice(&materials),
                none,
            ),
            texture_view: array_view(&texture),
        })
    }
}

fn resize_rgba8(w: u32, h: u32, rgba: &[u8], to_w: u32, to_h: u32) -> Vec<u8> {
    if w == to_w && h == to_h {
        return rgba.to_vec();
    }
    match image::RgbaImage::from_raw(w, h, rgba.to_vec()) {
        Some(img) => {
            image::imageops::resize(&img, to_w, to_h, image::imageops::FilterType::Triangle)
                .into_raw()
        }
        None => vec![255u8; (to_w * to_h * 4) as usize],
    }
}

/// Sampler used for mesh textures by both the baker and the reference: bilinear, repeat
/// (glTF's default wrap), level 0 only.
pub(crate) fn mesh_sampler(gpu: &Gpu) -> wgpu::Sampler {
    gpu.device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("mesh texture sampler"),
        address_mode_u: wgpu::AddressMode::Repeat,
        address_mode_v: wgpu::AddressMode::Repeat,
        address_mode_w: wgpu::AddressMode::ClampToEdge,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        mipmap_filter: wgpu::MipmapFilterMode::Nearest,
        ..Default::default()
    })
}

/// A storage-buffer entry visible to compute, vertex and fragment stages.
pub(crate) fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE
            | wgpu::ShaderStages::VERTEX
            | wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// The mesh bind group layout shared by baker and reference renderer (`@group(1)`).
pub(crate) fn mesh_layout(gpu: &Gpu, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayout {
    let mut entries: Vec<wgpu::BindGroupLayoutEntry> = (0..4)
        .map(|b| wgpu::BindGroupLayoutEntry {
            visibility,
            ..storage_entry(b, true)
        })
        .collect();
    entries.push(wgpu::BindGroupLayoutEntry {
        binding: 4,
        visibility,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: true },
            view_dimension: wgpu::TextureViewDimension::D2Array,
            multisampled: false,
        },
        count: None,
    });
    entries.push(wgpu::BindGroupLayoutEntry {
        binding: 5,
        visibility,
        ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
        count: None,
    });
    gpu.device
        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("mesh"),
            entries: &entries,
        })
}

/// The `@group(1)` bind group of `mesh` in [`mesh_layout`].
pub(crate) fn mesh_bind_group(
    gpu: &Gpu,
    layout: &wgpu::BindGroupLayout,
    mesh: &GpuMesh,
    sampler: &wgpu::Sampler,
) -> wgpu::BindGroup {
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("mesh"),
        layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: mesh.vertex_buffer.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: mesh.triangle_buffer.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: mesh.bvh_buffer.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: mesh.material_buffer.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 4,
                resource: wgpu::BindingResource::TextureView(&mesh.texture_view),
            },
            wgpu::BindGroupEntry {
                binding: 5,
                resource: wgpu::BindingResource::Sampler(sampler),
            },
        ],
    })
}
