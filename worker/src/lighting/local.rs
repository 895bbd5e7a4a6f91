//! `local`: the sun through shadow rays, transmitted through back-lit
//! leaves, and the open sky on the ground; no light scattered between
//! leaves. Nothing to prepare beyond the geometry.

use super::method::{Kernel, Method, Needs};
use sylva_proto::pb;
use sylva_scene::LightingMode;

/// The method.
pub const METHOD: Method = Method {
    mode: LightingMode::Local,
    code: pb::Lighting::Local as u32,
    wgsl: "LIGHTING_LOCAL",
    kernel: Kernel::Direct,
    needs: Needs { lb: false, envelopes: false, clouds: false },
};
