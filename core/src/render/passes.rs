//! Recording the marcher's compute passes, and timing them.

use std::time::Instant;

use crate::gpu::{Gpu, GpuError};

use super::Renderer;
use super::guide::quads_share_nearest_coarse;
use super::targets::{TILE_ARGS_SIZE, Targets, quad_grid};

/// Environment variable that makes a renderer created while it is set time every frame's passes
/// (logged at `info` level on the `lumigraph_core::render` target): each pass is then submitted
/// and waited for on its own, which costs a little time, so leave it off for benchmarks of
/// whole frames.
pub const PASS_TIMING_VARIABLE: &str = "LUMIGRAPH_PASS_TIMING";

/// Per-pass timing of one frame ([`PASS_TIMING_VARIABLE`]): when on, [`PassTimer::split`]
/// submits what the encoder holds, waits, and logs the time since the previous split.
pub(super) struct PassTimer {
    pub(super) on: bool,
    pub(super) last: Instant,
    pub(super) passes: Vec<(&'static str, f64)>,
}

impl PassTimer {
    pub(super) fn new(on: bool) -> PassTimer {
        PassTimer {
            on,
            last: Instant::now(),
            passes: Vec::new(),
        }
    }

    pub(super) fn split(
        &mut self,
        gpu: &Gpu,
        encoder: wgpu::CommandEncoder,
        pass: &'static str,
    ) -> Result<wgpu::CommandEncoder, GpuError> {
        if !self.on {
            return Ok(encoder);
        }
        gpu.queue.submit([encoder.finish()]);
        gpu.wait()?;
        self.passes
            .push((pass, self.last.elapsed().as_secs_f64() * 1e3));
        self.last = Instant::now();
        Ok(gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("render"),
            }))
    }

    /// Logs the passes, the last one being the readback.
    pub(super) fn finish(&mut self, width: u32, height: u32) {
        if self.on {
            self.passes
                .push(("readback", self.last.elapsed().as_secs_f64() * 1e3));
            let passes: Vec<String> = self
                .passes
                .iter()
                .map(|(pass, ms)| format!("{pass} {ms:.2} ms"))
                .collect();
            tracing::info!("{width}×{height} frame passes: {}", passes.join(", "));
        }
    }
}

/// How a compute pass counts its workgroups.
#[derive(Clone, Copy)]
pub(super) enum Workgroups<'a> {
    /// A `columns` × `rows` grid.
    Grid(u32, u32),
    /// (x, y, z) read from a buffer at a byte offset.
    Indirect(&'a wgpu::Buffer, u64),
}

/// Records one compute pass of the marcher: `pipeline` with `frame` as bind group 0 and the
/// light field's `field` as group 1.
pub(super) fn record_pass(
    encoder: &mut wgpu::CommandEncoder,
    label: &str,
    pipeline: &wgpu::ComputePipeline,
    (frame, field): (&wgpu::BindGroup, &wgpu::BindGroup),
    workgroups: Workgroups,
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: None,
    });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, frame, &[]);
    pass.set_bind_group(1, field, &[]);
    match workgroups {
        Workgroups::Grid(columns, rows) => pass.dispatch_workgroups(columns, rows, 1),
        Workgroups::Indirect(buffer, offset) => pass.dispatch_workgroups_indirect(buffer, offset),
    }
}

/// One entry point of the marcher's module as a compute pipeline, with its override constants.
pub(super) fn compute_pipeline(
    device: &wgpu::Device,
    (layout, module): (&wgpu::PipelineLayout, &wgpu::ShaderModule),
    (label, entry_point): (&str, &str),
    constants: &[(&str, f64)],
) -> wgpu::ComputePipeline {
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: Some(layout),
        module,
        entry_point: Some(entry_point),
        compilation_options: wgpu::PipelineCompilationOptions {
            constants,
            ..Default::default()
        },
        cache: None,
    })
}

impl Renderer {
    /// Records a quad listing (`cs_tiles`, one invocation per 4×4 quad of a `width` × `height`
    /// pass guided at `factor`, in 8×8 workgroups) for the pass whose bind group is `group`,
    /// leaving its indirect dispatch sizes in `targets.tile_args`.
    pub(super) fn list_tiles(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        targets: &Targets,
        group: &wgpu::BindGroup,
        field_group: &wgpu::BindGroup,
        (width, height, factor): (u32, u32, u32),
    ) {
        let (columns, rows) = quad_grid(width, height);
        encoder.copy_buffer_to_buffer(
            &targets.tile_reset,
            0,
            &targets.tile_dispatch,
            0,
            TILE_ARGS_SIZE,
        );
        record_pass(
            encoder,
            "render tiles",
            &self.tiles_pipelines[usize::from(
                quads_share_nearest_coarse(width, height, factor) && !self.switches.wide_tile_reads,
            )],
            (group, field_group),
            Workgroups::Grid(columns.div_ceil(8), rows.div_ceil(8)),
        );
        encoder.copy_buffer_to_buffer(
            &targets.tile_dispatch,
            0,
            &targets.tile_args,
            0,
            TILE_ARGS_SIZE,
        );
    }
}
