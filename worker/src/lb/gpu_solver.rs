//! The wgpu LB solver: pipelines and buffers for one channel, stepped in
//! ping-pong batches between convergence checks.

use super::codegen::{self, StateLayout};
use crate::gpu::GpuContext;
use anyhow::Context;
use sylva_light::lb::lattice::Q;
use sylva_light::lb::solver::{Convergence, PhaseTimer, initial_state};
use sylva_light::lb::{
    Boundary, ChannelParams, ChannelSolution, Collision, LightingSolver, MediumGrid, SolveOptions,
    SolverError,
};
use wgpu::util::DeviceExt;

/// Solves LB channels on a GPU.
pub struct GpuSolver {
    ctx: GpuContext,
}

/// Read-back slots per batch: the steps before and at a check, and the cap.
const SUM_SLOTS: u64 = 3;

impl GpuSolver {
    /// A solver on an open GPU.
    pub fn new(ctx: GpuContext) -> Self {
        Self { ctx }
    }

    /// Opens the default GPU.
    pub fn open() -> anyhow::Result<Self> {
        Ok(Self::new(GpuContext::new()?))
    }

    /// The GPU it runs on.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }
}

/// The GPU objects of one channel's solve.
struct Kernels {
    step: wgpu::ComputePipeline,
    totals: wgpu::ComputePipeline,
    /// `[0]` reads copy A and writes copy B; `[1]` the reverse.
    bind_groups: [wgpu::BindGroup; 2],
    node_total: wgpu::Buffer,
    group_sum: wgpu::Buffer,
    sums_staging: wgpu::Buffer,
}

impl LightingSolver for GpuSolver {
    fn name(&self) -> String {
        self.ctx.adapter_name()
    }

    fn solve_channel(
        &mut self,
        medium: &MediumGrid,
        params: &ChannelParams,
        boundary: &Boundary,
        opts: &SolveOptions,
        progress: &dyn Fn(usize, usize),
    ) -> Result<ChannelSolution, SolverError> {
        let mut phases = PhaseTimer::default();
        let dims = medium.dims;
        let layout = StateLayout::new(dims, &self.ctx.limits)?;
        let source = phases.time("codegen", || {
            codegen::step_shader(&layout, &Collision::new(params), boundary.ground.as_ref())
        });
        let k = phases.time("upload", || {
            self.ctx.checked("building the LB kernels", || {
                self.build(&layout, &source, medium, boundary)
            })
        })?;
        let mut conv = Convergence::new(*opts, dims);
        let cap = conv.cap();
        let check = opts.check_every.max(1);
        let [gx, gy] = layout.groups;
        let steps = phases.time("steps", || {
            self.ctx.checked("running the LB steps", || {
                let mut step = 0;
                while step < cap {
                    let batch_end = cap.min((step / check + 1) * check);
                    let mut enc = self.ctx.device.create_command_encoder(&Default::default());
                    let mut measured = Vec::new();
                    for s in step + 1..=batch_end {
                        let mut pass = enc.begin_compute_pass(&Default::default());
                        pass.set_pipeline(&k.step);
                        pass.set_bind_group(0, &k.bind_groups[(s - 1) % 2], &[]);
                        pass.dispatch_workgroups(gx, gy, 1);
                        if conv.wants_total(s) {
                            // After step s the state is in the copy bind group s % 2 reads.
                            pass.set_pipeline(&k.totals);
                            pass.set_bind_group(0, &k.bind_groups[s % 2], &[]);
                            pass.dispatch_workgroups(gx, gy, 1);
                            drop(pass);
                            let bytes = layout.group_count() as u64 * 4;
                            enc.copy_buffer_to_buffer(
                                &k.group_sum,
                                0,
                                &k.sums_staging,
                                measured.len() as u64 * bytes,
                                bytes,
                            );
                            measured.push(s);
                        }
                    }
                    self.ctx.queue.submit([enc.finish()]);
                    step = batch_end;
                    if !measured.is_empty() {
                        let raw = self.ctx.map_read(&k.sums_staging)?;
                        let sums: &[f32] = bytemuck::cast_slice(&raw);
                        let per = layout.group_count() as usize;
                        for (i, &s) in measured.iter().enumerate() {
                            let total: f64 =
                                sums[i * per..(i + 1) * per].iter().map(|&v| v as f64).sum();
                            if conv.record(s, total) {
                                step = s;
                                progress(step, cap);
                                return Ok(step);
                            }
                        }
                    }
                    progress(step, cap);
                }
                self.ctx.wait()?;
                Ok(step)
            })
        })?;
        let total = phases.time("read-back", || -> anyhow::Result<Vec<f32>> {
            let mut enc = self.ctx.device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&k.totals);
                pass.set_bind_group(0, &k.bind_groups[steps % 2], &[]);
                pass.dispatch_workgroups(gx, gy, 1);
            }
            self.ctx.queue.submit([enc.finish()]);
            let raw = self.ctx.read_back(&k.node_total, dims.len() as u64 * 4)?;
            Ok(bytemuck::cast_slice(&raw).to_vec())
        })?;
        Ok(conv.finish(steps, total, phases))
    }
}

impl GpuSolver {
    /// Compiles the kernels and uploads the starting state, the medium and
    /// the scratch buffers.
    fn build(
        &self,
        layout: &StateLayout,
        source: &str,
        medium: &MediumGrid,
        boundary: &Boundary,
    ) -> anyhow::Result<Kernels> {
        let device = &self.ctx.device;
        let n = layout.dims.len();
        let module = self.ctx.trusted_module("lb step", source.to_string());
        let storage = |binding: u32, read_only: bool| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let b = layout.buffers as u32;
        let base = layout.binding_density();
        let mut entries: Vec<_> = (0..b).map(|i| storage(i, true)).collect();
        entries.extend((0..b).map(|i| storage(b + i, false)));
        entries.extend([
            storage(base, true),
            storage(base + 1, true),
            storage(base + 2, false),
            storage(base + 3, false),
        ]);
        let bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("lb"),
            entries: &entries,
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lb"),
            bind_group_layouts: &[Some(&bgl)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pl),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: self.ctx.pipeline_cache(),
            })
        };
        let (step, totals) = (pipeline("step"), pipeline("totals"));

        // Both copies start equal, so boundary nodes (never written) hold the
        // sun's densities whichever copy a step reads.
        let state = initial_state(layout.dims, boundary);
        let copy = |name: &str| -> Vec<wgpu::Buffer> {
            (0..layout.buffers)
                .map(|i| {
                    let dirs = layout.dirs_in(i);
                    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some(name),
                        contents: bytemuck::cast_slice(&state[dirs.start * n..dirs.end * n]),
                        usage: wgpu::BufferUsages::STORAGE,
                    })
                })
                .collect()
        };
        let (a, bb) = (copy("lb state A"), copy("lb state B"));
        drop(state);
        let density = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("lb density"),
            contents: bytemuck::cast_slice(&medium.density),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let classes: Vec<u32> = medium.class.iter().map(|&c| c as u32).collect();
        let class = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("lb class"),
            contents: bytemuck::cast_slice(&classes),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let scratch = |label: &str, bytes: u64, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage,
                mapped_at_creation: false,
            })
        };
        let groups = layout.group_count() as u64;
        let node_total = scratch(
            "lb node totals",
            n as u64 * 4,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        );
        let group_sum = scratch(
            "lb group sums",
            groups * 4,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        );
        let sums_staging = scratch(
            "lb sums staging",
            SUM_SLOTS * groups * 4,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );
        let bind_group = |src: &[wgpu::Buffer], dst: &[wgpu::Buffer]| {
            let mut e: Vec<wgpu::BindGroupEntry> = Vec::with_capacity(2 * src.len() + 4);
            for (i, buf) in src.iter().chain(dst).enumerate() {
                e.push(wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource: buf.as_entire_binding(),
                });
            }
            for (i, buf) in [&density, &class, &node_total, &group_sum].into_iter().enumerate() {
                e.push(wgpu::BindGroupEntry {
                    binding: base + i as u32,
                    resource: buf.as_entire_binding(),
                });
            }
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("lb"),
                layout: &bgl,
                entries: &e,
            })
        };
        let bind_groups = [bind_group(&a, &bb), bind_group(&bb, &a)];
        self.ctx.wait().context("uploading the LB state")?;
        debug_assert_eq!(Q, 19);
        Ok(Kernels { step, totals, bind_groups, node_total, group_sum, sums_staging })
    }
}
