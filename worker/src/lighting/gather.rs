//! `gather` and `gather-ambient`: a final gather over the LB. Each ray per
//! pixel is one gather path through the real geometry: at its first
//! `gather_bounces` surfaces it takes the direct sun through a shadow ray
//! and goes on along the leaf's two-sided BSDF (escaping rays see the
//! sky); at the next surface it reads the lattice's multiply-scattered
//! light there (`gather`) or the constant matched to it
//! (`gather-ambient`) and stops. So crown-scale occlusion and the sunlit
//! leaves of neighbours come from the geometry, and only the later
//! bounces from the lattice. The kernel is the reference's, truncated
//! (`shaders/lighting/reference.wgsl`); docs/lighting.md derives the
//! far end's term; the filter over the gathers' indirect light is the
//! tracer's (`crate::trace::filter`).

use super::method::{Kernel, Method, Needs};
use sylva_proto::pb;
use sylva_scene::LightingMode;

/// The gather whose far end reads the LB.
pub const METHOD: Method = Method {
    mode: LightingMode::Gather,
    code: pb::Lighting::Gather as u32,
    wgsl: "LIGHTING_GATHER",
    kernel: Kernel::Reference,
    needs: Needs { lb: true, envelopes: false, clouds: true },
};

/// The gather whose far end reads the constant matched to the LB image.
pub const AMBIENT: Method = Method {
    mode: LightingMode::GatherAmbient,
    code: pb::Lighting::GatherAmbient as u32,
    wgsl: "LIGHTING_GATHER_AMBIENT",
    kernel: Kernel::Reference,
    needs: Needs { lb: true, envelopes: false, clouds: true },
};
