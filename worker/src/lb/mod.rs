//! The LB lighting solver on the GPU: WGSL generated from one template
//! (`shaders/lb/step.wgsl`) per grid layout and channel, dispatched in
//! ping-pong over direction-major storage split across bindings.

pub mod codegen;
mod gpu_solver;

pub use codegen::StateLayout;
pub use gpu_solver::GpuSolver;

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

/// A solver for `backend`: the CPU reference, or the wgpu solver on this
/// machine's adapter.
pub fn open_solver(backend: Backend) -> anyhow::Result<Box<dyn LightingSolver>> {
    Ok(match backend {
        Backend::Cpu => Box::new(CpuSolver),
        Backend::Gpu => Box::new(GpuSolver::open()?),
    })
}
