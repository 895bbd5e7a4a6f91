//! `reference`: the path tracer of `shaders/lighting/reference.wgsl`, one
//! path per invocation. The frame layer runs it progressively until the
//! image's own error estimate is small enough (`crate::frame::reference`).

use super::method::{Kernel, Method, Needs};
use sylva_proto::pb;
use sylva_scene::LightingMode;

/// The reference integrator, called from `render.wgsl`.
pub const WGSL: &str = include_str!("../../../shaders/lighting/reference.wgsl");

/// The method: it path-traces the clouds' density, so it prepares them.
pub const METHOD: Method = Method {
    mode: LightingMode::Reference,
    code: pb::Lighting::Reference as u32,
    wgsl: "LIGHTING_REFERENCE",
    kernel: Kernel::Reference,
    needs: Needs { lb: false, envelopes: false, clouds: true },
};
