//! Compositing a multi light field's layers on the GPU (shaders/composite.wgsl): every visible
//! layer's marcher output is copied into a stack, one frame per layer, and one pass sorts and
//! blends each pixel's fragments into the frame's own buffers, which are read back once. The
//! rule is [`crate::layers::composite`]'s (the tests hold the two to one code step). The CPU
//! composite remains beside software rasterizers (where this pass runs on the same cores and
//! costs more: [`super::Compositing::Automatic`]), for more than [`MAX_GPU_LAYERS`] visible
//! layers or a stack larger than one storage binding, and for scenes, which mix fields and
//! meshes.

use crate::asset::LayerOrder;

use super::passes::compute_pipeline;
use super::targets::Targets;
use crate::gpu::buffer_entry;

/// The most visible layers one GPU composite takes (the shader's `MAX_LAYERS`, its loops'
/// bound: a pixel's fragments are taken in depth order by one scan of the stack per fragment,
/// so the work grows with the square of the count). More fall back to the CPU composite.
pub(super) const MAX_GPU_LAYERS: usize = 16;

/// The composite pass's parameters, as shaders/composite.wgsl declares them.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct CompositeParams {
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) count: u32,
    pub(super) by_depth: u32,
    pub(super) translucent: u32,
    pub(super) nearest_only: u32,
    pub(super) depth_threshold: f32,
    pub(super) pad: u32,
    /// One per stacked layer (WGSL: four `vec4<f32>`, a uniform array's stride being 16).
    pub(super) opacities: [f32; MAX_GPU_LAYERS],
}

impl CompositeParams {
    /// The parameters for `opacities` (one per stacked layer, at most [`MAX_GPU_LAYERS`]) of a
    /// `width` × `height` frame.
    pub(super) fn new(
        (width, height): (u32, u32),
        opacities: &[f32],
        translucent: bool,
        depth_threshold: f32,
        order: LayerOrder,
    ) -> CompositeParams {
        let mut padded = [0.0; MAX_GPU_LAYERS];
        for (slot, o) in padded.iter_mut().zip(opacities) {
            *slot = *o;
        }
        CompositeParams {
            width,
            height,
            count: opacities.len().min(MAX_GPU_LAYERS) as u32,
            by_depth: u32::from(order == LayerOrder::Depth),
            translucent: u32::from(translucent),
            nearest_only: u32::from(!translucent && opacities.iter().all(|&o| o >= 1.0)),
            depth_threshold,
            pad: 0,
            opacities: padded,
        }
    }
}

/// The composite pipeline and its bind group layout, built with the renderer.
pub(super) struct CompositePipeline {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

impl CompositePipeline {
    pub(super) fn new(device: &wgpu::Device) -> CompositePipeline {
        let read = wgpu::BufferBindingType::Storage { read_only: true };
        let write = wgpu::BufferBindingType::Storage { read_only: false };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("layer composite"),
            entries: &[
                buffer_entry(0, wgpu::BufferBindingType::Uniform),
                buffer_entry(1, read),
                buffer_entry(2, read),
                buffer_entry(3, write),
                buffer_entry(4, write),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("layer composite"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("layer composite"),
            source: wgpu::ShaderSource::Wgsl(crate::shaders::COMPOSITE.into()),
        });
        let pipeline = compute_pipeline(
            device,
            (&pipeline_layout, &module),
            ("layer composite", "cs_composite"),
            &[],
        );
        CompositePipeline { layout, pipeline }
    }

    /// A stack of `layers` frames for `targets`' size, compositing into its colour and depth.
    pub(super) fn stack(
        &self,
        device: &wgpu::Device,
        targets: &Targets,
        layers: usize,
    ) -> LayerStack {
        let frame_bytes = 4 * u64::from(targets.width) * u64::from(targets.height);
        let make = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let stacked = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let color = make("layer stack colour", layers as u64 * frame_bytes, stacked);
        let depth = make("layer stack depth", layers as u64 * frame_bytes, stacked);
        let uniform = make(
            "layer composite params",
            std::mem::size_of::<CompositeParams>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("layer composite"),
            layout: &self.layout,
            entries: &[&uniform, &color, &depth, &targets.color, &targets.depth]
                .iter()
                .enumerate()
                .map(|(binding, buffer)| wgpu::BindGroupEntry {
                    binding: binding as u32,
                    resource: buffer.as_entire_binding(),
                })
                .collect::<Vec<_>>(),
        });
        LayerStack {
            layers,
            frame_bytes,
            color,
            depth,
            uniform,
            group,
        }
    }

    /// Records the composite of the stack (as its parameters say) into the `width` × `height`
    /// frame's buffers.
    pub(super) fn record(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        stack: &LayerStack,
        (width, height): (u32, u32),
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("layer composite"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &stack.group, &[]);
        pass.dispatch_workgroups((width * height).div_ceil(1024), 1, 1);
    }
}

/// Room on the GPU for the visible layers' frames of one size.
pub(super) struct LayerStack {
    /// Frames it holds.
    pub(super) layers: usize,
    /// Bytes of one frame's colour (and of its depth).
    pub(super) frame_bytes: u64,
    pub(super) color: wgpu::Buffer,
    pub(super) depth: wgpu::Buffer,
    pub(super) uniform: wgpu::Buffer,
    group: wgpu::BindGroup,
}

impl LayerStack {
    /// Records the copy of the frame's colour and depth (a layer's marcher output) into slot
    /// `slot`.
    pub(super) fn push(&self, encoder: &mut wgpu::CommandEncoder, targets: &Targets, slot: usize) {
        let at = slot as u64 * self.frame_bytes;
        encoder.copy_buffer_to_buffer(&targets.color, 0, &self.color, at, self.frame_bytes);
        encoder.copy_buffer_to_buffer(&targets.depth, 0, &self.depth, at, self.frame_bytes);
    }
}
