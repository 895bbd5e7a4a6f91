//! The GPU ray tracer: the scene uploaded as flat buffers
//! ([`GpuScene`]) with Sylva's structures or the device's (ray queries,
//! `rq.rs`), the traversal kernel on its own ([`RayCaster`]) and the
//! strip renderer, which draws every lighting method (`crate::lighting`
//! declares them). WGSL in `shaders/trace/`.

mod choose;
pub mod filter;
mod gpu_scene;
mod kernels;
mod raycast;
pub(crate) mod render;
mod rq;
mod shaders;

pub use choose::{BackendChoice, ProbeTime, candidates, choose, worth_measuring};
pub use filter::SampleMeans;
pub use gpu_scene::{
    GpuCloud, GpuInstance, GpuMaterial, GpuModel, GpuScene, GpuTexture, GpuTriangle, SceneLight,
    SceneStructure,
};
pub use kernels::{KernelCache, Kernels, Tracer, render_source};
pub use raycast::{GpuHit, GpuRay, KernelTime, RayCaster};
pub use render::MAX_BOUNCES;
pub use render::{FrameUniform, GpuRayCounts, RenderSettings, RenderedStrip, StripRenderer};
pub use rq::RqStructures;
pub use shaders::tracer_source;
