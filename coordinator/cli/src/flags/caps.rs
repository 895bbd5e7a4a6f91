//! The per-scene caps a worker and a coordinator enforce on what clients send.

use clap::Args;
use sylva_scene::SceneLimits;

#[derive(Debug, Args)]
pub struct LimitArgs {
    /// Most models (species) one scene may name.
    #[arg(long, default_value_t = SceneLimits::MODELS)]
    pub max_models: usize,
    /// Most instances one scene may place.
    #[arg(long, default_value_t = SceneLimits::INSTANCES)]
    pub max_instances: usize,
    /// Most triangles over a scene's unique models.
    #[arg(long, default_value_t = SceneLimits::TRIANGLES)]
    pub max_triangles: u64,
    /// Most texels over a scene's textures.
    #[arg(long, default_value_t = SceneLimits::TEXTURE_PIXELS)]
    pub max_texture_pixels: u64,
    /// Most LB lattice nodes over a scene's models, clouds and forest grid.
    #[arg(long, default_value_t = SceneLimits::LB_CELLS)]
    pub max_lb_cells: u64,
}

impl LimitArgs {
    /// The caps.
    pub fn limits(&self) -> SceneLimits {
        SceneLimits {
            models: self.max_models,
            instances: self.max_instances,
            triangles: self.max_triangles,
            texture_pixels: self.max_texture_pixels,
            lb_cells: self.max_lb_cells,
        }
    }
}
