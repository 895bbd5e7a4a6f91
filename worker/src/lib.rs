//! What a Sylva worker runs, and the only crate that links wgpu: the GPU
//! ([`gpu`]), the ray tracer ([`trace`]: scene upload, traversal kernel,
//! strip renderer, the render kernels and their cache), the LB solver on
//! the GPU ([`lb`]), one module per lighting method ([`lighting`]: each
//! declares what it prepares and which kernel draws it), a scene's
//! preparation before tracing ([`prepare`]), the frame layer that composes
//! one frame from these ([`frame`]), the prepared data a farm shares
//! ([`share`]) and the gRPC worker service ([`service`]). WGSL lives in
//! the repository's `shaders/` folder; the CPU reference every kernel is
//! tested against is in `sylva-accel` and `sylva-light`.
//!
//! ```no_run
//! use sylva_worker::frame::{Frame, Fresh};
//! use sylva_worker::trace::Tracer;
//! let scene = sylva_scene::Scene::load("examples/tree.json".as_ref())?;
//! let tracer = Tracer::new()?;
//! let request = sylva_scene::frame::FrameSettings::default();
//! let frame = Frame::compose(&tracer, &scene, &request, &mut Fresh::default(), &|stage| eprintln!("{stage}"))?;
//! let strip = frame.strip(0, request.width)?;
//! assert_eq!(strip.pixels.len(), (request.width * request.height) as usize);
//! # anyhow::Ok(())
//! ```

pub mod disk_cache;
pub mod frame;
pub mod gpu;
pub mod lb;
pub mod lighting;
pub mod prepare;
pub mod service;
pub mod share;
pub mod trace;

pub use disk_cache::DiskCache;
pub use gpu::GpuContext;
pub use lb::GpuSolver;
