//! The LB lighting solver on the GPU: WGSL generated from one template
//! (`shaders/lb/step.wgsl`) per grid layout and channel, dispatched in
//! ping-pong over direction-major storage split across bindings.

pub mod codegen;
mod gpu_solver;

pub use codegen::StateLayout;
pub use gpu_solver::GpuSolver;
