//! How big a scene may be. A scene file of a few hundred bytes can ask for
//! millions of triangles or a huge LB grid; these caps are checked from the
//! file's declared sizes (and a glTF's headers) before any geometry is
//! generated or decoded, so an oversized scene costs nothing to refuse.

use serde::{Deserialize, Serialize};

/// Per-scene caps. The defaults hold the paper's full forest (five species,
/// 1.3 M unique triangles, thousands of instances) with room to spare.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SceneLimits {
    /// Models (species) in one scene.
    pub models: usize,
    /// Instances in one scene.
    pub instances: usize,
    /// Triangles over all unique models.
    pub triangles: u64,
    /// Texels over all of a scene's textures.
    pub texture_pixels: u64,
    /// LB lattice nodes over all models, clouds and the forest grid.
    pub lb_cells: u64,
}

impl SceneLimits {
    /// Default `models`.
    pub const MODELS: usize = 256;
    /// Default `instances`.
    pub const INSTANCES: usize = 1_000_000;
    /// Default `triangles`.
    pub const TRIANGLES: u64 = 20_000_000;
    /// Default `texture_pixels`: 64 textures of 2048².
    pub const TEXTURE_PIXELS: u64 = 1 << 28;
    /// Default `lb_cells`: four 256³ grids.
    pub const LB_CELLS: u64 = 1 << 26;

    /// No caps, for trusted local files that are loaded anyway.
    pub const UNLIMITED: SceneLimits = SceneLimits {
        models: usize::MAX,
        instances: usize::MAX,
        triangles: u64::MAX,
        texture_pixels: u64::MAX,
        lb_cells: u64::MAX,
    };
}

impl Default for SceneLimits {
    fn default() -> Self {
        Self {
            models: Self::MODELS,
            instances: Self::INSTANCES,
            triangles: Self::TRIANGLES,
            texture_pixels: Self::TEXTURE_PIXELS,
            lb_cells: Self::LB_CELLS,
        }
    }
}
