//! `boulanger`: Boulanger et al. 2008, per-leaf envelope distances and
//! closed forms for the sky, the sun and one bounce of indirect light.
//! Prepares each model's envelope (`sylva_light::boulanger`); its render
//! kernel is the direct one with the envelope terms compiled in.

use super::method::{Kernel, Method, Needs};
use serde::Serialize;
use std::sync::Arc;
use sylva_light::boulanger::LeafEnvelope;
use sylva_proto::pb;
use sylva_scene::{LightingMode, Scene};

/// The Boulanger et al. leaf shading, called from `render.wgsl`.
pub const WGSL: &str = include_str!("../../../shaders/lighting/boulanger.wgsl");

/// The method.
pub const METHOD: Method = Method {
    mode: LightingMode::Boulanger,
    code: pb::Lighting::Boulanger as u32,
    wgsl: "LIGHTING_BOULANGER",
    kernel: Kernel::Boulanger,
    needs: Needs { lb: false, envelopes: true, clouds: false },
};

/// One model's Boulanger envelope, as reported.
#[derive(Clone, Debug, Serialize)]
pub struct ModelEnvelope {
    /// Model name.
    pub model: String,
    /// Leaves (leaf cards) found.
    pub leaves: usize,
    /// Optical thickness per unit length τ = ρA/2.
    pub tau: f32,
    /// Leaves per unit volume of the envelope.
    pub leaf_density: f32,
    /// Mean leaf area.
    pub leaf_area: f32,
    /// Precompute time, ms.
    pub ms: f64,
}

/// Each model's envelope (for upload) and its report.
pub type Envelopes = (Vec<Option<Arc<LeafEnvelope>>>, Vec<ModelEnvelope>);

/// Each model's envelope and its report.
pub fn prepare(scene: &Scene) -> Envelopes {
    of(scene, scene.models.iter().map(|m| sylva_light::boulanger::precompute(&m.model)).collect())
}

/// `scene`'s envelopes (one a model, as [`prepare`] makes them) with
/// their report; `ms` is the time each took to compute when it was.
pub fn of(scene: &Scene, envelopes: Vec<LeafEnvelope>) -> Envelopes {
    scene
        .models
        .iter()
        .zip(envelopes)
        .map(|(m, e)| {
            let report = ModelEnvelope {
                model: m.name.clone(),
                leaves: e.leaves,
                tau: e.tau,
                leaf_density: e.leaf_density,
                leaf_area: e.leaf_area,
                ms: e.precompute_ms,
            };
            (Some(Arc::new(e)), report)
        })
        .unzip()
}

/// The sky's (and the ground's) mean radiance over each Boulanger
/// direction's octant, as the kernel's `bl_sky` reads it. The sky depends
/// only on height, so this holds for instances turned about the vertical too.
pub fn sky_per_direction(scene: &Scene) -> [[f32; 4]; 8] {
    let (z, h) = (glam::Vec3::from(scene.sky.zenith), glam::Vec3::from(scene.sky.horizon));
    let sky = |d: glam::Vec3| h.lerp(z, d.y.max(0.0).sqrt()).to_array();
    let ground = scene.ground.as_ref().map_or([0.0; 3], |g| g.color);
    sylva_light::boulanger::sky_radiance_per_direction(sky, ground).map(|c| [c[0], c[1], c[2], 0.0])
}
