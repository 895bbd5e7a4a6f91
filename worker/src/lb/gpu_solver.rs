//! The wgpu LB solver: pipelines and buffers for one channel, stepped in
//! ping-pong batches between convergence checks. What a solve builds is
//! kept on the device for the next ([`DeviceLb`]): the compiled kernels
//! by their generated source (grid, collision, reflecting floor; never the
//! sun), and each medium's buffers by its content, so the next channel,
//! the next sun and the next frame send the device only the light that
//! enters (2 × 19 floats) and step.

use super::codegen::{self, StateLayout};
use crate::gpu::GpuContext;
use anyhow::Context;
use std::collections::HashMap;
use std::sync::Arc;
use sylva_light::lb::lattice::Q;
use sylva_light::lb::solver::{Convergence, PhaseTimer};
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

/// Device bytes of media kept between solves (least recently used dropped
/// beyond it; the newest is kept whatever its size).
const KEPT_GRID_BYTES: u64 = 1 << 30;

/// Compiled kernels kept between solves (a forest's species × channels,
/// with room; the oldest dropped beyond it).
const KEPT_KERNELS: usize = 128;

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

    /// What solves on this device have compiled and uploaded so far.
    pub fn made(&self) -> KeptCounts {
        self.ctx.lb.lock().unwrap_or_else(|p| p.into_inner()).made
    }
}

/// What the LB solver keeps on one device between solves (shared by every
/// [`GpuSolver`] on that device through its [`GpuContext`]).
#[derive(Default)]
pub struct DeviceLb {
    /// Bind group and pipeline layouts by the number of state bindings.
    layouts: HashMap<usize, Arc<Layouts>>,
    /// Compiled kernels by generated source, oldest first.
    kernels: Vec<(String, Arc<Kernels>)>,
    /// Media on the device, least recently used first.
    grids: Vec<Grid>,
    /// Kernels compiled and media uploaded on this device so far.
    made: KeptCounts,
}

/// What an LB solver has had to make on its device so far: what the kept
/// kernels and media saved is what these did not count.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KeptCounts {
    /// Kernel sets compiled (a grid layout and a channel's collision each).
    pub compiled: usize,
    /// Media uploaded.
    pub uploaded: usize,
}

struct Layouts {
    bind_group: wgpu::BindGroupLayout,
    pipeline: wgpu::PipelineLayout,
}

/// One channel's compiled kernels.
struct Kernels {
    init: wgpu::ComputePipeline,
    step: wgpu::ComputePipeline,
    totals: wgpu::ComputePipeline,
}

/// One medium on the device, with both state copies and the scratch
/// buffers its solves use.
struct Grid {
    /// BLAKE3 of the layout, the density and the classes.
    key: [u8; 32],
    bytes: u64,
    /// `[0]` reads copy A and writes copy B; `[1]` the reverse.
    bind_groups: [wgpu::BindGroup; 2],
    node_total: wgpu::Buffer,
    group_sum: wgpu::Buffer,
    sums_staging: wgpu::Buffer,
    /// [`codegen::light_in`] of the solve in progress.
    light_in: wgpu::Buffer,
}

impl DeviceLb {
    fn layouts(&mut self, ctx: &GpuContext, layout: &StateLayout) -> Arc<Layouts> {
        let made = self.layouts.entry(layout.buffers).or_insert_with(|| {
            let storage = crate::gpu::storage_entry;
            let b = layout.buffers as u32;
            let base = layout.binding_density();
            let mut entries: Vec<_> = (0..b).map(|i| storage(i, true)).collect();
            entries.extend((0..b).map(|i| storage(b + i, false)));
            entries.extend([
                storage(base, true),
                storage(base + 1, true),
                storage(base + 2, false),
                storage(base + 3, false),
                storage(base + 4, true),
            ]);
            let bind_group =
                ctx.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some("lb"),
                    entries: &entries,
                });
            let pipeline = ctx.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("lb"),
                bind_group_layouts: &[Some(&bind_group)],
                immediate_size: 0,
            });
            Arc::new(Layouts { bind_group, pipeline })
        });
        made.clone()
    }

    /// The kernels compiled from `source`, if kept (now the most recently used).
    fn kept_kernels(&mut self, source: &str) -> Option<Arc<Kernels>> {
        let i = self.kernels.iter().position(|(s, _)| s == source)?;
        let kept = self.kernels.remove(i);
        let k = kept.1.clone();
        self.kernels.push(kept);
        Some(k)
    }

    /// Keeps kernels compiled from `source`, unless another solve kept the
    /// same meanwhile (then those are used, and these dropped).
    fn keep_kernels(&mut self, source: String, k: Arc<Kernels>) -> Arc<Kernels> {
        if let Some(other) = self.kept_kernels(&source) {
            return other;
        }
        self.made.compiled += 1;
        self.kernels.push((source, k.clone()));
        if self.kernels.len() > KEPT_KERNELS {
            self.kernels.remove(0);
        }
        k
    }

    /// The index of `medium`'s buffers in `grids` (now the most recently
    /// used), uploaded now if not kept.
    fn grid(
        &mut self,
        ctx: &GpuContext,
        layout: &StateLayout,
        medium: &MediumGrid,
    ) -> anyhow::Result<usize> {
        let classes: Vec<u32> = medium.class.iter().map(|&c| c as u32).collect();
        let key = {
            let mut h = blake3::Hasher::new();
            let d = layout.dims;
            for v in [d.nx, d.ny, d.nz, layout.buffers] {
                h.update(&(v as u64).to_le_bytes());
            }
            h.update(bytemuck::cast_slice(&medium.density));
            h.update(bytemuck::cast_slice(&classes));
            *h.finalize().as_bytes()
        };
        if let Some(i) = self.grids.iter().position(|g| g.key == key) {
            let g = self.grids.remove(i);
            self.grids.push(g);
            return Ok(self.grids.len() - 1);
        }
        let layouts = self.layouts(ctx, layout);
        let grid = ctx.checked("uploading the LB medium", || {
            let grid = upload_grid(ctx, layout, &layouts, medium, &classes, key);
            ctx.wait().context("uploading the LB medium")?;
            Ok(grid)
        })?;
        self.made.uploaded += 1;
        self.grids.push(grid);
        while self.grids.len() > 1
            && self.grids.iter().map(|g| g.bytes).sum::<u64>() > KEPT_GRID_BYTES
        {
            self.grids.remove(0);
        }
        Ok(self.grids.len() - 1)
    }
}

/// Creates both state copies (written by the `init` kernel, never
/// uploaded), the medium and the scratch buffers, and their bind groups.
fn upload_grid(
    ctx: &GpuContext,
    layout: &StateLayout,
    layouts: &Layouts,
    medium: &MediumGrid,
    classes: &[u32],
    key: [u8; 32],
) -> Grid {
    let device = &ctx.device;
    let n = layout.dims.len() as u64;
    let scratch = |label: &str, bytes: u64, usage: wgpu::BufferUsages| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes,
            usage,
            mapped_at_creation: false,
        })
    };
    let copy = |name: &str| -> Vec<wgpu::Buffer> {
        (0..layout.buffers)
            .map(|i| {
                let dirs = layout.dirs_in(i).len() as u64;
                scratch(name, dirs * n * 4, wgpu::BufferUsages::STORAGE)
            })
            .collect()
    };
    let (a, b) = (copy("lb state A"), copy("lb state B"));
    let density = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("lb density"),
        contents: bytemuck::cast_slice(&medium.density),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let class = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("lb class"),
        contents: bytemuck::cast_slice(classes),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let groups = layout.group_count() as u64;
    let node_total = scratch(
        "lb node totals",
        n * 4,
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
    let light_in = scratch(
        "lb light in",
        2 * Q as u64 * 4,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
    );
    let base = layout.binding_density();
    let bind_group = |src: &[wgpu::Buffer], dst: &[wgpu::Buffer]| {
        let mut e: Vec<wgpu::BindGroupEntry> = Vec::with_capacity(2 * src.len() + 5);
        for (i, buf) in src.iter().chain(dst).enumerate() {
            e.push(wgpu::BindGroupEntry { binding: i as u32, resource: buf.as_entire_binding() });
        }
        let rest = [&density, &class, &node_total, &group_sum, &light_in];
        for (i, buf) in rest.into_iter().enumerate() {
            e.push(wgpu::BindGroupEntry {
                binding: base + i as u32,
                resource: buf.as_entire_binding(),
            });
        }
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("lb"),
            layout: &layouts.bind_group,
            entries: &e,
        })
    };
    let bind_groups = [bind_group(&a, &b), bind_group(&b, &a)];
    let bytes = (2 * Q as u64 + 3) * n * 4 + (SUM_SLOTS + 1) * groups * 4;
    Grid { key, bytes, bind_groups, node_total, group_sum, sums_staging, light_in }
}

/// Compiles one channel's kernels from their generated `source`.
fn compile(ctx: &GpuContext, layouts: &Layouts, source: &str) -> anyhow::Result<Arc<Kernels>> {
    ctx.checked("compiling the LB kernels", || {
        let module = ctx.trusted_module("lb step", source.to_string());
        let pipeline = |entry: &str| {
            ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&layouts.pipeline),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: ctx.pipeline_cache(),
            })
        };
        Ok(Arc::new(Kernels {
            init: pipeline("init"),
            step: pipeline("step"),
            totals: pipeline("totals"),
        }))
    })
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
            codegen::step_shader(&layout, &Collision::new(params), boundary.ground.is_some())
        });
        // Compiled with the device's solver state unlocked: solves on one
        // device (a forest's species, solved in parallel) compile their
        // kernels at the same time, and take turns only on the device.
        let lb = || self.ctx.lb.lock().unwrap_or_else(|p| p.into_inner());
        let k = phases.time("kernels", || -> anyhow::Result<Arc<Kernels>> {
            let layouts = {
                let mut kept = lb();
                if let Some(k) = kept.kept_kernels(&source) {
                    return Ok(k);
                }
                kept.layouts(&self.ctx, &layout)
            };
            let k = compile(&self.ctx, &layouts, &source)?;
            Ok(lb().keep_kernels(source, k))
        })?;
        // Held for the rest of the solve: solves on one device take turns.
        let mut kept = lb();
        let g = phases.time("upload", || kept.grid(&self.ctx, &layout, medium))?;
        let g = &kept.grids[g];
        phases.time("init", || {
            self.ctx.checked("starting the LB state", || {
                let light = codegen::light_in(boundary);
                self.ctx.queue.write_buffer(&g.light_in, 0, bytemuck::cast_slice(&light));
                let mut enc = self.ctx.device.create_command_encoder(&Default::default());
                {
                    // Both copies start equal, so boundary nodes (never
                    // written) hold the entering light whichever a step reads.
                    let mut pass = enc.begin_compute_pass(&Default::default());
                    pass.set_pipeline(&k.init);
                    for bg in &g.bind_groups {
                        pass.set_bind_group(0, bg, &[]);
                        pass.dispatch_workgroups(layout.groups[0], layout.groups[1], 1);
                    }
                }
                self.ctx.queue.submit([enc.finish()]);
                Ok(())
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
                        pass.set_bind_group(0, &g.bind_groups[(s - 1) % 2], &[]);
                        pass.dispatch_workgroups(gx, gy, 1);
                        if conv.wants_total(s) {
                            // After step s the state is in the copy bind group s % 2 reads.
                            pass.set_pipeline(&k.totals);
                            pass.set_bind_group(0, &g.bind_groups[s % 2], &[]);
                            pass.dispatch_workgroups(gx, gy, 1);
                            drop(pass);
                            let bytes = layout.group_count() as u64 * 4;
                            enc.copy_buffer_to_buffer(
                                &g.group_sum,
                                0,
                                &g.sums_staging,
                                measured.len() as u64 * bytes,
                                bytes,
                            );
                            measured.push(s);
                        }
                    }
                    self.ctx.queue.submit([enc.finish()]);
                    step = batch_end;
                    if !measured.is_empty() {
                        let raw = self.ctx.map_read(&g.sums_staging)?;
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
                pass.set_bind_group(0, &g.bind_groups[steps % 2], &[]);
                pass.dispatch_workgroups(gx, gy, 1);
            }
            self.ctx.queue.submit([enc.finish()]);
            let raw = self.ctx.read_back(&g.node_total, dims.len() as u64 * 4)?;
            Ok(bytemuck::cast_slice(&raw).to_vec())
        })?;
        Ok(conv.finish(steps, total, phases))
    }
}
