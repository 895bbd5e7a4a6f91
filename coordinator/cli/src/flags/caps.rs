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

/// Where prepared data (the structures the CPU builds, the LB light) is
/// kept on disk between runs, and how much: a worker that restarts, or a
/// second render of a scene, reads it instead of preparing again.
#[derive(Debug, Args)]
pub struct PreparedCacheArgs {
    /// Folder of the prepared-data cache (default
    /// `$XDG_CACHE_HOME/sylva/prepared`, or `~/.cache/sylva/prepared`).
    #[arg(long, env = "SYLVA_PREPARED_CACHE_DIR")]
    pub prepared_cache_dir: Option<std::path::PathBuf>,
    /// MiB the prepared-data cache may hold (least recently used entries
    /// go first); 0 turns it off.
    #[arg(long, env = "SYLVA_PREPARED_CACHE_MIB", default_value_t = 8192)]
    pub prepared_cache_mib: u64,
}

impl PreparedCacheArgs {
    /// The cache, or `None` when turned off or without a home to put it in.
    pub fn open(&self) -> anyhow::Result<Option<sylva_worker::DiskCache>> {
        if self.prepared_cache_mib == 0 {
            return Ok(None);
        }
        let Some(dir) =
            self.prepared_cache_dir.clone().or_else(sylva_worker::DiskCache::default_dir)
        else {
            tracing::warn!("no prepared-data cache: neither XDG_CACHE_HOME nor HOME is set");
            return Ok(None);
        };
        Ok(Some(sylva_worker::DiskCache::open(&dir, self.prepared_cache_mib << 20)?))
    }

    /// The flags again, for a worker this process starts.
    pub fn to_args(&self) -> Vec<String> {
        let mut args =
            vec!["--prepared-cache-mib".to_string(), self.prepared_cache_mib.to_string()];
        if let Some(d) = &self.prepared_cache_dir {
            args.extend(["--prepared-cache-dir".to_string(), d.display().to_string()]);
        }
        args
    }
}
