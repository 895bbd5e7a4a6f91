//! The traversal kernel on its own: a batch of rays in, closest hits out.

use super::gpu_scene::GpuScene;
use super::shaders::tracer_source;
use crate::gpu::GpuContext;
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// A ray as `rays.wgsl` reads it.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuRay {
    /// Origin.
    pub origin: [f32; 3],
    /// Hits must lie beyond this.
    pub t_min: f32,
    /// Direction.
    pub dir: [f32; 3],
    /// Hits must lie before this.
    pub t_max: f32,
}

/// A kernel's time as the GPU measured it.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct KernelTime {
    /// Rays cast in the timed pass.
    pub rays: u64,
    /// Seconds between the pass's first and last timestamp.
    pub seconds: f64,
}

impl KernelTime {
    /// Millions of rays a second.
    pub fn mrays_per_second(&self) -> f64 {
        self.rays as f64 / self.seconds.max(1e-12) / 1e6
    }
}

/// A hit's triangle when the ray hit nothing (`NO_HIT` in the WGSL).
pub const NO_HIT: u32 = u32::MAX;

/// A hit as `rays.wgsl` writes it; `triangle == NO_HIT` for a miss.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuHit {
    /// Instance index.
    pub instance: u32,
    /// Global triangle index.
    pub triangle: u32,
    /// Ray parameter.
    pub t: f32,
    /// Barycentric u.
    pub u: f32,
    /// Barycentric v.
    pub v: f32,
    /// Padding.
    pub pad: [u32; 3],
}

const SOURCE: &str = include_str!("../../../shaders/trace/rays.wgsl");
const WORKGROUP: u32 = 64;

/// The ray-casting pipeline for one scene upload.
pub struct RayCaster {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl RayCaster {
    /// Builds the closest-hit pipeline for `scene` (its accel kind picks
    /// the traversal).
    pub fn new(ctx: &GpuContext, scene: &GpuScene) -> anyhow::Result<Self> {
        ctx.checked("building the ray-casting pipeline", || Ok(Self::build(ctx, scene, false)))
    }

    /// Builds the shadow-ray pipeline: each hit says only whether the ray
    /// is blocked (`triangle != u32::MAX`), found by the first hit.
    pub fn shadow(ctx: &GpuContext, scene: &GpuScene) -> anyhow::Result<Self> {
        ctx.checked("building the shadow-ray pipeline", || Ok(Self::build(ctx, scene, true)))
    }

    fn build(ctx: &GpuContext, scene: &GpuScene, any_hit: bool) -> Self {
        let device = &ctx.device;
        let module = ctx.trusted_module("rays", tracer_source(SOURCE, scene.backend));
        let entry = crate::gpu::storage_entry;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("rays"),
            entries: &[entry(0, true), entry(1, false)],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("rays"),
            bind_group_layouts: &[Some(&scene.layout), Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("rays"),
            layout: Some(&pl),
            module: &module,
            entry_point: Some("cast_rays"),
            compilation_options: super::shaders::tracer_options(&[
                ("ACCEL_KIND", scene.accel_kind() as f64),
                ("ANY_HIT", any_hit as u8 as f64),
            ]),
            cache: ctx.pipeline_cache(),
        });
        Self { pipeline, layout }
    }

    /// `rays` uploaded, room for their hits (with `out_usage` beside
    /// STORAGE), and the bind group that hands both to the kernel.
    fn bind(
        &self,
        ctx: &GpuContext,
        rays: &[GpuRay],
        out_usage: wgpu::BufferUsages,
    ) -> (wgpu::Buffer, wgpu::Buffer, wgpu::BindGroup) {
        let device = &ctx.device;
        let input = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("rays in"),
            contents: bytemuck::cast_slice(rays),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let output = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hits out"),
            size: (rays.len() * size_of::<GpuHit>()) as u64,
            usage: wgpu::BufferUsages::STORAGE | out_usage,
            mapped_at_creation: false,
        });
        let bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("rays"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: input.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: output.as_entire_binding() },
            ],
        });
        (input, output, bg)
    }

    /// The kernel's own time over at least `at_least` rays: `rays` cast
    /// again and again, every dispatch in one compute pass whose start and
    /// end the GPU stamps, so uploads, read-backs and the host's waits are
    /// not counted. `None` where the adapter has no timestamp queries.
    pub fn kernel_time(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        rays: &[GpuRay],
        at_least: u64,
    ) -> anyhow::Result<Option<KernelTime>> {
        if rays.is_empty() || !ctx.has_timestamps() {
            return Ok(None);
        }
        ctx.checked("timing the traversal kernel", || {
            let device = &ctx.device;
            let (_input, _output, bg) = self.bind(ctx, rays, wgpu::BufferUsages::empty());
            let queries = device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("kernel time"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            });
            let resolved = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("kernel time"),
                size: 16,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let repeats = at_least.div_ceil(rays.len() as u64).max(1);
            let groups = (rays.len() as u32).div_ceil(WORKGROUP);
            let gx = groups.min(65_535);
            let mut enc = device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("timed rays"),
                    timestamp_writes: Some(wgpu::ComputePassTimestampWrites {
                        query_set: &queries,
                        beginning_of_pass_write_index: Some(0),
                        end_of_pass_write_index: Some(1),
                    }),
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &scene.bind_group, &[]);
                pass.set_bind_group(1, &bg, &[]);
                for _ in 0..repeats {
                    pass.dispatch_workgroups(gx, groups.div_ceil(gx), 1);
                }
            }
            enc.resolve_query_set(&queries, 0..2, &resolved, 0);
            ctx.queue.submit([enc.finish()]);
            let raw = ctx.read_back(&resolved, 16)?;
            let stamps: &[u64] = bytemuck::cast_slice(&raw);
            let ns = stamps[1].saturating_sub(stamps[0]) as f64
                * ctx.queue.get_timestamp_period() as f64;
            Ok(Some(KernelTime { rays: repeats * rays.len() as u64, seconds: ns * 1e-9 }))
        })
    }

    /// Casts `rays` and returns their closest hits, in order.
    pub fn cast(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        rays: &[GpuRay],
    ) -> anyhow::Result<Vec<GpuHit>> {
        if rays.is_empty() {
            return Ok(Vec::new());
        }
        ctx.checked("casting rays", || {
            let device = &ctx.device;
            let (_input, output, bg) = self.bind(ctx, rays, wgpu::BufferUsages::COPY_SRC);
            let bytes = output.size();
            let groups = (rays.len() as u32).div_ceil(WORKGROUP);
            let gx = groups.min(65_535);
            let mut enc = device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &scene.bind_group, &[]);
                pass.set_bind_group(1, &bg, &[]);
                pass.dispatch_workgroups(gx, groups.div_ceil(gx), 1);
            }
            ctx.queue.submit([enc.finish()]);
            let raw = ctx.read_back(&output, bytes)?;
            Ok(bytemuck::cast_slice(&raw).to_vec())
        })
    }
}
