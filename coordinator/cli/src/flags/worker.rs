//! `sylva worker`. Flags only (clap), and their conversion to settings.

use clap::Args;

#[derive(Debug, Args)]
pub struct WorkerArgs {
    /// Address to listen on (port 0 picks a free port; the bound address is
    /// printed on stdout).
    #[arg(long, default_value = "127.0.0.1:50151")]
    pub listen: String,
    /// Largest scene bundle accepted, MiB.
    #[arg(long, default_value_t = 1024)]
    pub max_bundle_mib: u64,
    /// Scene bundles kept in the cache, MiB.
    #[arg(long, default_value_t = 4096)]
    pub cache_mib: u64,
    #[command(flatten)]
    pub auth: crate::flags::security::TokenArgs,
    #[command(flatten)]
    pub tls: crate::flags::security::ServeTlsArgs,
    /// How to reach the coordinator over TLS.
    #[command(flatten)]
    pub coordinator_tls: crate::flags::security::ConnectTlsArgs,
    /// Register with this coordinator (`host:port`) and re-register every few seconds.
    #[arg(long)]
    pub coordinator: Option<String>,
    /// The address the coordinator should use for this worker (default: the bound one; for
    /// `0.0.0.0` or `::`, this machine's address on the route to the coordinator).
    #[arg(long)]
    pub advertise: Option<String>,
    #[command(flatten)]
    pub limits: crate::flags::caps::LimitArgs,
    /// Where bundles are unpacked (default: a fresh folder under the system's temporary folder).
    #[arg(long)]
    pub cache_dir: Option<std::path::PathBuf>,
    /// Keep the bundle cache folder when the worker stops.
    #[arg(long)]
    pub keep_cache: bool,
    /// LB solutions kept per scene and sun direction, for sequences that
    /// come back to a sun (0: only the sun being rendered).
    #[arg(long, default_value_t = 64)]
    pub lb_cache_entries: usize,
    /// MiB of LB light kept at most, all suns together.
    #[arg(long, default_value_t = 1024)]
    pub lb_cache_mib: u64,
    /// MiB the kept scenes may hold, everything each expands into
    /// together (models, structures, LB light, GPU copies): the least
    /// recently used scenes are let go beyond it.
    #[arg(long, default_value_t = 8192)]
    pub memory_mib: u64,
    #[command(flatten)]
    pub prepared_cache: crate::flags::caps::PreparedCacheArgs,
}
