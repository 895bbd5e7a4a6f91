//! `sylva worker --listen ADDR`: a GPU worker serving the worker API.

use anyhow::Context;
use clap::Args;
use std::io::Write;
use sylva_worker::GpuContext;
use sylva_worker::service::{self, WorkerConfig};

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
    pub auth: super::security::TokenArgs,
    #[command(flatten)]
    pub tls: super::security::ServeTlsArgs,
    /// How to reach the coordinator over TLS.
    #[command(flatten)]
    pub coordinator_tls: super::security::ConnectTlsArgs,
    /// Register with this coordinator (`host:port`) and re-register every few seconds.
    #[arg(long)]
    pub coordinator: Option<String>,
    /// The address the coordinator should use for this worker (default: the bound one).
    #[arg(long)]
    pub advertise: Option<String>,
    #[command(flatten)]
    pub limits: super::caps::LimitArgs,
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
}

pub fn run(a: WorkerArgs) -> anyhow::Result<()> {
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async {
        let listener = tokio::net::TcpListener::bind(&a.listen)
            .await
            .with_context(|| format!("cannot listen on {}", a.listen))?;
        let addr = listener.local_addr()?;
        let ctx = GpuContext::new()?;
        let token = a.auth.load()?;
        let tls = a.tls.load()?;
        let mut config = WorkerConfig {
            max_bundle_bytes: a.max_bundle_mib << 20,
            cache_bytes: a.cache_mib << 20,
            token,
            tls,
            limits: a.limits.limits(),
            keep_cache: a.keep_cache,
            lb_cache_entries: a.lb_cache_entries,
            lb_cache_bytes: a.lb_cache_mib << 20,
            ..WorkerConfig::default()
        };
        if let Some(d) = &a.cache_dir {
            config.cache_dir = d.clone();
        }
        let coordinator_tls = a.coordinator_tls.load()?;
        tracing::info!(%addr, adapter = %ctx.adapter_name(), "worker ready");
        println!("sylva worker listening on {addr}");
        std::io::stdout().flush()?;
        if let Some(coord) = a.coordinator.clone() {
            let me = a.advertise.clone().unwrap_or_else(|| addr.to_string());
            let token = config.token.clone();
            tokio::spawn(sylva_coordinator::registration::register_loop(
                coord,
                me,
                token,
                coordinator_tls,
            ));
        }
        service::run(listener, ctx, config, sylva_coordinator::shutdown::signal()).await
    })
}
