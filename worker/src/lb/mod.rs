//! The LB lighting solver on the GPU: WGSL generated from one template
//! (`shaders/lb/step.wgsl`) per grid layout and channel, dispatched in
//! ping-pong over direction-major storage split across bindings.

pub mod codegen;
mod gpu_solver;

pub use codegen::StateLayout;
pub(crate) use gpu_solver::DeviceLb;
pub use gpu_solver::{GpuSolver, KeptCounts};

use crate::gpu::GpuContext;
use sylva_light::lb::{CpuSolver, LightingSolver};

/// Which machine solves the LB light.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// The rayon reference solver.
    Cpu,
    /// The wgpu solver.
    Gpu,
}

impl Backend {
    /// Where a scene's LB light is solved beside tracing on `ctx`: on the
    /// GPU, unless the adapter is itself the CPU (lavapipe). There the
    /// rayon solver does the same steps natively, about 6× faster than
    /// the WGSL kernel run through a software Vulkan (`sylva bench lb
    /// --medium plant` at 64³ on 2 cores, Mesa 25: 39.7 against 6.9 MLUPS
    /// stepping; docs/lighting.md, "Where the LB is solved").
    pub fn for_adapter(ctx: &GpuContext) -> Self {
        if ctx.is_cpu() { Backend::Cpu } else { Backend::Gpu }
    }
}

/// The solver a scene's LB light is solved with on `ctx`
/// ([`Backend::for_adapter`]).
pub fn scene_solver(ctx: &GpuContext) -> Box<dyn LightingSolver + Send> {
    match Backend::for_adapter(ctx) {
        Backend::Cpu => Box::new(CpuSolver),
        Backend::Gpu => Box::new(GpuSolver::new(ctx.clone())),
    }
}

/// A solver for `backend`: the CPU reference, or the wgpu solver on this
/// machine's adapter.
pub fn open_solver(backend: Backend) -> anyhow::Result<Box<dyn LightingSolver>> {
    Ok(match backend {
        Backend::Cpu => Box::new(CpuSolver),
        Backend::Gpu => Box::new(GpuSolver::open()?),
    })
}
