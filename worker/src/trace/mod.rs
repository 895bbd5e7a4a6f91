//! The GPU ray tracer: the scene uploaded as flat buffers
//! ([`GpuScene`]), the traversal kernel on its own ([`RayCaster`]) and the
//! strip renderer. WGSL in `shaders/trace/`.

mod gpu_scene;
mod raycast;
mod reference;
pub(crate) mod render;
mod shaders;

pub use gpu_scene::{CloudGrid, GpuCloud, GpuInstance, GpuMaterial, GpuModel, GpuScene, GpuTexture, GpuTriangle, GroundLight, LbGrid, SceneLight};
pub use raycast::{GpuHit, GpuRay, RayCaster};
pub use reference::{MIN_BATCH_SPP, ReferenceImage, ReferenceOptions, ReferenceStats, render_reference};
pub use render::MAX_BOUNCES;
pub use render::{FrameUniform, RayCounts, RenderSettings, Strip, StripRenderer};
pub use shaders::tracer_source;
