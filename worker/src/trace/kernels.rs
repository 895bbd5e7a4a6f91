//! The render kernels and the cache that keeps them: compiled once per
//! process and device, not once per prepared scene (a driver's compiled
//! code is costly to make and, on lavapipe, is not all given back when a
//! pipeline is dropped). [`Tracer`] is a GPU with its kernel cache: what
//! everything that traces takes.

use super::gpu_scene::{GpuScene, accel_kind};
use super::shaders::tracer_source;
use crate::gpu::GpuContext;
use crate::lighting::{self, Kernel};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use sylva_proto::sync::lock;
use sylva_scene::frame::Backend;

/// The render kernels' own WGSL (`shaders/trace/render.wgsl`).
const SOURCE: &str = include_str!("../../../shaders/trace/render.wgsl");

/// A GPU and the render kernels compiled on it (cheap to clone: both are
/// shared handles). It dereferences to its [`GpuContext`], so whatever
/// takes a GPU takes a tracer too.
#[derive(Clone)]
pub struct Tracer {
    /// The device.
    pub gpu: GpuContext,
    /// The render kernels compiled on it so far.
    pub kernels: KernelCache,
}

impl Tracer {
    /// Opens the highest-performance adapter, with an empty kernel cache.
    pub fn new() -> anyhow::Result<Self> {
        Ok(GpuContext::new()?.into())
    }
}

impl From<GpuContext> for Tracer {
    fn from(gpu: GpuContext) -> Self {
        Self { gpu, kernels: KernelCache::default() }
    }
}

impl std::ops::Deref for Tracer {
    type Target = GpuContext;
    fn deref(&self) -> &GpuContext {
        &self.gpu
    }
}

/// Kernels by (`ACCEL_KIND`, clouds), shared by every scene of a device:
/// scenes' bind-group layouts are alike, and wgpu gives alike layouts one
/// identity, so a kernel built for one scene binds every other.
#[derive(Clone, Default)]
pub struct KernelCache(Arc<Mutex<HashMap<KernelKey, Arc<Kernels>>>>);

/// What a kernel is specialised for: `ACCEL_KIND` and whether it draws clouds.
type KernelKey = (u32, bool);

impl KernelCache {
    /// The render kernels for a backend, with or without clouds: compiled
    /// on first use and kept. A preparation calls it early, on a thread of
    /// its own, so compiling overlaps its other work.
    pub fn get(
        &self,
        ctx: &GpuContext,
        backend: Backend,
        clouds: bool,
    ) -> anyhow::Result<Arc<Kernels>> {
        let key = (accel_kind(backend), clouds);
        if let Some(k) = lock(&self.0).get(&key) {
            return Ok(k.clone());
        }
        // Kept only once compiled without an error.
        let k = ctx.checked("building the render pipeline", || {
            Ok(Arc::new(Kernels::compile(ctx, backend, clouds)))
        })?;
        lock(&self.0).insert(key, k.clone());
        Ok(k)
    }
}

/// The render kernels for one specialisation (structure, clouds): the
/// module, the frame's bind-group layout, and one pipeline per lighting
/// family (direct methods, reference, Boulanger), with and without the
/// passes, each compiled on first use. A frame runs one family: compiling
/// all three up front cost a process three pipelines where it needed one
/// (on lavapipe each costs about 0.4 s to create even when the driver's
/// cache holds it).
pub struct Kernels {
    /// By family, then without and with the passes (`PASSES`: the light
    /// split and the guides). A slot's lock is held while it compiles, so
    /// a frame that needs it waits for the compile under way rather than
    /// starting its own.
    pipelines: [[Mutex<Option<wgpu::ComputePipeline>>; 2]; 3],
    /// The frame's bind-group layout (group 1).
    pub(super) layout: wgpu::BindGroupLayout,
    module: wgpu::ShaderModule,
    pipeline_layout: wgpu::PipelineLayout,
    constants: Vec<(&'static str, f64)>,
}

impl Kernels {
    /// Compiles the render kernels for a backend and clouds.
    fn compile(ctx: &GpuContext, backend: Backend, clouds: bool) -> Self {
        let device = &ctx.device;
        let module = ctx.trusted_module("render", render_source(backend));
        let scene_layout = GpuScene::layout_for(device, backend);
        let entry = |binding, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frame"),
            entries: &[
                entry(0, wgpu::BufferBindingType::Uniform),
                entry(1, wgpu::BufferBindingType::Storage { read_only: false }),
                entry(2, wgpu::BufferBindingType::Storage { read_only: false }),
            ],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("render"),
            bind_group_layouts: &[Some(&scene_layout), Some(&layout)],
            immediate_size: 0,
        });
        let constants = vec![
            ("ACCEL_KIND", accel_kind(backend) as f64),
            ("HAS_CLOUDS", if clouds { 1.0 } else { 0.0 }),
        ];
        Kernels { pipelines: Default::default(), layout, module, pipeline_layout: pl, constants }
    }

    /// The kernel of `kernel`'s family, writing the passes or not:
    /// compiled on first use, and kept.
    pub fn render(
        &self,
        ctx: &GpuContext,
        kernel: Kernel,
        passes: bool,
    ) -> anyhow::Result<wgpu::ComputePipeline> {
        let mut slot = lock(&self.pipelines[kernel as usize][passes as usize]);
        if let Some(p) = slot.as_ref() {
            return Ok(p.clone());
        }
        let built = ctx.checked("building the render pipeline", || {
            let (m, l, c) = (&self.module, &self.pipeline_layout, &self.constants);
            Ok(render_pipeline(ctx, m, l, c, kernel, passes))
        })?;
        Ok(slot.insert(built).clone())
    }
}

/// One render kernel: a lighting family, with or without the passes.
fn render_pipeline(
    ctx: &GpuContext,
    module: &wgpu::ShaderModule,
    layout: &wgpu::PipelineLayout,
    constants: &[(&'static str, f64)],
    kernel: Kernel,
    passes: bool,
) -> wgpu::ComputePipeline {
    let mut c = constants.to_vec();
    c.push(("LIGHTING_FAMILY", kernel as u32 as f64));
    c.push(("PASSES", if passes { 1.0 } else { 0.0 }));
    ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("render"),
        layout: Some(layout),
        module,
        entry_point: Some("render_strip"),
        compilation_options: super::shaders::tracer_options(&c),
        cache: ctx.pipeline_cache(),
    })
}

/// The whole render module: scene, traversal, the direct methods and the
/// reference integrator.
pub fn render_source(backend: Backend) -> String {
    tracer_source(
        &format!(
            "{}\n{SOURCE}\n{}\n{}",
            lighting::wgsl_constants(),
            lighting::reference::WGSL,
            lighting::boulanger::WGSL
        ),
        backend,
    )
}
