//! The GPU ray tracer: the scene uploaded as flat buffers
//! ([`GpuScene`]), the traversal kernel on its own ([`RayCaster`]) and the
//! strip renderer, which draws every lighting method (`crate::lighting`
//! declares them). WGSL in `shaders/trace/`.

mod gpu_scene;
mod raycast;
pub(crate) mod render;
mod shaders;

pub use gpu_scene::{
    CloudGrid, GpuCloud, GpuInstance, GpuMaterial, GpuModel, GpuScene, GpuTexture, GpuTriangle,
    GroundLight, SceneLight,
};
pub use raycast::{GpuHit, GpuRay, RayCaster};
pub use render::MAX_BOUNCES;
pub use render::{
    FrameUniform, GpuRayCounts, RenderSettings, RenderedStrip, SampleMeans, StripRenderer,
};
pub use shaders::tracer_source;
