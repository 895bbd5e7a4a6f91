//! The worker's GPU tests against the CPU references, one module per
//! subject, in one test binary (ripgrep's `tests/tests.rs`): wgpu is
//! linked once, not once per file. Run one subject with a filter:
//! `cargo test -p sylva-worker --test gpu render_gpu::`.

mod common;

mod lb_gpu;
mod lighting_gpu;
mod passes_gpu;
mod render_gpu;
mod trace_gpu;
