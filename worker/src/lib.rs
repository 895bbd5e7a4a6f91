//! What a Sylva worker runs on its GPU, through wgpu: the LB lighting solver
//! now, the strip tracer later. WGSL sources live in the repository's
//! `shaders/` folder, each beside the name of the Rust module that
//! dispatches it.

pub mod gpu;
pub mod lb;
pub mod lighting;
pub mod prepare;
pub mod service;
pub mod share;
pub mod trace;

pub use gpu::GpuContext;
pub use lb::GpuSolver;
