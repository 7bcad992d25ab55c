//! Per-size output buffers and bind groups of the marcher's passes.

use super::Renderer;
use super::composite::LayerStack;
use super::gpu_data::RenderParams;
use super::guide::{PRE_FACTOR, coarse_size};

/// Per-size output buffers, reused between frames of the same size: the frame's own, and the
/// coarse pass's (its colour is scratch, its depth guides the frame; both share the counters).
pub(super) struct Targets {
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) uniform: wgpu::Buffer,
    pub(super) color: wgpu::Buffer,
    pub(super) depth: wgpu::Buffer,
    pub(super) counters: wgpu::Buffer,
    /// Where the results are copied to be mapped; `None` where `color`, `depth` and `counters`
    /// are mapped themselves (a CPU adapter: `Gpu::maps_primary_buffers`).
    pub(super) readback: Option<wgpu::Buffer>,
    pub(super) group: wgpu::BindGroup,
    /// Parameters and bind group of the pass that marches the flat quads the interior pass
    /// gave back.
    pub(super) given_back_uniform: wgpu::Buffer,
    pub(super) given_back_group: wgpu::BindGroup,
    /// The coarse pass that guides the frame, and the coarser one that guides it.
    pub(super) coarse: CoarseLevel,
    pub(super) pre: CoarseLevel,
    /// The indirect dispatch size of a compacted guided pass (counted in `tile_dispatch` as
    /// `cs_tiles` lists the quads in a buffer only the bind groups hold, copied to `tile_args`:
    /// one buffer cannot be bound as storage and read as dispatch arguments by the same pass).
    pub(super) tile_dispatch: wgpu::Buffer,
    pub(super) tile_args: wgpu::Buffer,
    /// `tile_dispatch`'s starting values, copied in before each tile listing.
    pub(super) tile_reset: wgpu::Buffer,
    /// The layers of a multi light field before their composite (made for the first such
    /// frame, grown to the most visible layers one frame had).
    pub(super) stack: Option<LayerStack>,
}

/// One coarse pass's buffers: its parameters, its results (rows of [`coarse_stride`] pixels, two
/// floats each, shaders/render/params.wgsl `coarse`; its colour is scratch) and their copy as a texture, which
/// the next finer pass reads, and its bind group (which binds the texture of the pass guiding
/// it).
pub(super) struct CoarseLevel {
    pub(super) uniform: wgpu::Buffer,
    pub(super) depth: wgpu::Buffer,
    pub(super) texture: wgpu::Texture,
    pub(super) group: wgpu::BindGroup,
}

/// The 8×8 tiles (workgroups) of a pass over `width` × `height` pixels, per row and per column.
pub(super) fn tile_grid(width: u32, height: u32) -> (u32, u32) {
    (width.div_ceil(8), height.div_ceil(8))
}

/// The 4×4 quads a compacted pass over `width` × `height` pixels lists (shaders/render/tiles.wgsl
/// `cs_tiles`), per row and per column.
pub(super) fn quad_grid(width: u32, height: u32) -> (u32, u32) {
    (width.div_ceil(4), height.div_ceil(4))
}

/// A compacted guided frame's indirect dispatch sizes, in words: three (x, y, z) triples (the
/// quads to march, the flat quads, the flat quads given back to be marched; four quads per
/// workgroup), then from [`TILE_LIST_LENGTHS`] the three lists' lengths in quads (WGSL
/// `tile_dispatch`).
pub(super) const TILE_DISPATCH_WORDS: u32 = 12;
/// Where the lists' lengths start in `tile_dispatch` (after the three triples).
pub(super) const TILE_LIST_LENGTHS: u32 = 9;
/// [`TILE_DISPATCH_WORDS`] in bytes.
pub(super) const TILE_ARGS_SIZE: u64 = 4 * TILE_DISPATCH_WORDS as u64;
/// Byte offsets of the second and third triple.
pub(super) const INTERIOR_ARGS: u64 = 12;
pub(super) const GIVEN_BACK_ARGS: u64 = 24;
/// The frame's work counters (fetches, steps, rays, one spare), in words (WGSL `counters`).
pub(super) const COUNTER_WORDS: u32 = 4;
/// [`COUNTER_WORDS`] in bytes.
pub(super) const COUNTERS_SIZE: u64 = 4 * COUNTER_WORDS as u64;

/// Most workgroups (four listed quads each) a compacted guided pass may dispatch: its indirect
/// dispatch counts them along one axis, whose size every device allows up to 65 535 (frames up
/// to about 2048²; a larger frame is guided without compaction).
pub(super) const MAX_TILES: u32 = 65_535;

/// Pixels per row of a coarse pass's output: a multiple of 64, so that its rows (8 bytes a
/// pixel) meet the 256-byte row alignment of a buffer-to-texture copy.
pub(super) fn coarse_stride(width: u32) -> u32 {
    width.div_ceil(64) * 64
}

impl Renderer {
    pub(super) fn targets_for(&self, width: u32, height: u32) -> Targets {
        let device = &self.gpu.device;
        let pixels = u64::from(width) * u64::from(height);
        // Sized for the finest coarse pass (factor 2), so any factor fits.
        let (coarse_w, coarse_h) = coarse_size(width, height, 2).unwrap_or((1, 1));
        let (pre_w, pre_h) = coarse_size(coarse_w, coarse_h, PRE_FACTOR).unwrap_or((1, 1));
        let depth_texture = |label, width, height| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rg32Float,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            })
        };
        let coarse_texture = depth_texture("coarse depth", coarse_w, coarse_h);
        let pre_texture = depth_texture("pre-coarse depth", pre_w, pre_h);
        let coarse_view = coarse_texture.create_view(&wgpu::TextureViewDescriptor::default());
        let pre_view = pre_texture.create_view(&wgpu::TextureViewDescriptor::default());
        let make = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        // On a CPU adapter the results are mapped where the shaders wrote them: a copy to a
        // staging buffer would cost a share of the frame.
        let direct = self.gpu.maps_primary_buffers();
        let mapped = if direct {
            wgpu::BufferUsages::MAP_READ
        } else {
            wgpu::BufferUsages::empty()
        };
        let out = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | mapped;
        let uniform_usage = wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST;
        let params_size = std::mem::size_of::<RenderParams>() as u64;
        let uniform = make("render params", params_size, uniform_usage);
        // Cleared before a compacted pass.
        let cleared = out | wgpu::BufferUsages::COPY_DST;
        let color = make("render colour", pixels * 4, cleared);
        let depth = make("render depth", pixels * 4, cleared);
        let counters = make(
            "render counters",
            COUNTERS_SIZE,
            out | wgpu::BufferUsages::COPY_DST,
        );
        let readback = (!direct).then(|| {
            make(
                "render readback",
                pixels * 8 + COUNTERS_SIZE,
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            )
        });
        let (columns, rows) = quad_grid(width, height);
        // Two lists (shaders/render/params.wgsl `tiles`).
        let tiles = make(
            "render tiles",
            2 * u64::from(columns) * u64::from(rows) * 4,
            wgpu::BufferUsages::STORAGE,
        );
        let tile_dispatch = make(
            "render tile dispatch",
            TILE_ARGS_SIZE,
            wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        );
        let tile_args = make(
            "render tile dispatch arguments",
            TILE_ARGS_SIZE,
            wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::COPY_DST,
        );
        // Three dispatch sizes (x, 1, 1), none counted yet: the quads to march, the flat quads,
        // the flat quads given back; then their three lengths, 0.
        let tile_reset = {
            use wgpu::util::DeviceExt;
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("render tile dispatch reset"),
                contents: bytemuck::cast_slice(&[0u32, 1, 1, 0, 1, 1, 0, 1, 1, 0, 0, 0]),
                usage: wgpu::BufferUsages::COPY_SRC,
            })
        };
        // Every pass binds the depth texture of the pass guiding it (any, if none) and the tile
        // list; only a guided pass reads them.
        let group = |label, entries: [&wgpu::Buffer; 4], guide: &wgpu::TextureView| {
            let mut entries: Vec<wgpu::BindGroupEntry> = entries
                .iter()
                .enumerate()
                .map(|(binding, buffer)| wgpu::BindGroupEntry {
                    binding: binding as u32,
                    resource: buffer.as_entire_binding(),
                })
                .collect();
            entries.push(wgpu::BindGroupEntry {
                binding: 4,
                resource: wgpu::BindingResource::TextureView(guide),
            });
            entries.push(wgpu::BindGroupEntry {
                binding: 5,
                resource: tiles.as_entire_binding(),
            });
            entries.push(wgpu::BindGroupEntry {
                binding: 6,
                resource: tile_dispatch.as_entire_binding(),
            });
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(label),
                layout: &self.frame_layout,
                entries: &entries,
            })
        };
        let frame_group = group(
            "render frame",
            [&uniform, &color, &depth, &counters],
            &coarse_view,
        );
        // The pass marching the quads the interior pass gave back: the frame's, but for its
        // parameters (`tiled` = 2).
        let given_back_uniform = make("render given-back params", params_size, uniform_usage);
        let given_back_group = group(
            "render given back",
            [&given_back_uniform, &color, &depth, &counters],
            &coarse_view,
        );
        let level = |name: &'static str, w: u32, h: u32, texture: wgpu::Texture, guide| {
            let pixels = u64::from(coarse_stride(w)) * u64::from(h);
            let uniform = make(name, params_size, uniform_usage);
            let color = make(name, pixels * 4, out);
            // Cleared before a compacted pass.
            let depth = make(name, pixels * 8, out | wgpu::BufferUsages::COPY_DST);
            let group = group(name, [&uniform, &color, &depth, &counters], guide);
            CoarseLevel {
                uniform,
                depth,
                texture,
                group,
            }
        };
        let coarse = level("coarse pass", coarse_w, coarse_h, coarse_texture, &pre_view);
        let pre = level("pre-coarse pass", pre_w, pre_h, pre_texture, &pre_view);
        Targets {
            width,
            height,
            uniform,
            color,
            depth,
            counters,
            readback,
            group: frame_group,
            given_back_uniform,
            given_back_group,
            coarse,
            pre,
            tile_dispatch,
            tile_args,
            tile_reset,
            stack: None,
        }
    }
}
