//! `ambient`: the direct sun plus one constant indirect radiance, matched
//! so its mean over the models' pixels equals the LB light's (the forest
//! paper's Figure 2c). It needs the LB solve to match against; the frame
//! layer matches it (`crate::frame::ambient`).

use super::method::{Kernel, Method, Needs};
use sylva_proto::pb;
use sylva_scene::LightingMode;

/// The method.
pub const METHOD: Method = Method {
    mode: LightingMode::Ambient,
    code: pb::Lighting::Ambient as u32,
    wgsl: "LIGHTING_AMBIENT",
    kernel: Kernel::Direct,
    needs: Needs { lb: true, envelopes: false, clouds: true },
};
