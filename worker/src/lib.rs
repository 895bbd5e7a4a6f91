//! What a Sylva worker runs, and the only crate that links wgpu: the GPU
//! ([`gpu`]), the ray tracer ([`trace`]: scene upload, traversal kernel,
//! strip renderer), the LB solver on the GPU ([`lb`]), one module per
//! lighting method ([`lighting`]), a scene's preparation before tracing
//! ([`prepare`]), the prepared data a farm shares ([`share`]) and the gRPC
//! worker service ([`service`]). WGSL lives in the repository's `shaders/`
//! folder; the CPU reference every kernel is tested against is in
//! `sylva-accel` and `sylva-light`.
//!
//! ```no_run
//! use sylva_worker::{GpuContext, prepare::prepare, trace::RenderSettings};
//! let scene = sylva_scene::Scene::load("examples/tree.json".as_ref())?;
//! let ctx = GpuContext::new()?;
//! let prepared = prepare(&ctx, &scene, sylva_scene::frame::AccelKind::Bvh, scene.lighting, &|stage| eprintln!("{stage}"))?;
//! let frame = sylva_scene::frame::FrameSettings::default();
//! let settings = RenderSettings::resolve(&frame, scene.lighting);
//! let strip = prepared.renderer.render_strip(&ctx, &settings, 0, frame.width)?;
//! assert_eq!(strip.pixels.len(), (frame.width * frame.height) as usize);
//! # anyhow::Ok(())
//! ```

pub mod disk_cache;
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
