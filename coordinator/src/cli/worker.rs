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
}

pub fn run(a: WorkerArgs) -> anyhow::Result<()> {
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async {
        let listener = tokio::net::TcpListener::bind(&a.listen).await.with_context(|| format!("cannot listen on {}", a.listen))?;
        let addr = listener.local_addr()?;
        let ctx = GpuContext::new()?;
        let token = a.auth.load()?;
        let tls = a.tls.load()?;
        let config = WorkerConfig { max_bundle_bytes: a.max_bundle_mib << 20, cache_bytes: a.cache_mib << 20, token, tls, ..WorkerConfig::default() };
        let coordinator_tls = a.coordinator_tls.load()?;
        tracing::info!(%addr, adapter = %ctx.adapter_name(), "worker ready");
        println!("sylva worker listening on {addr}");
        std::io::stdout().flush()?;
        if let Some(coord) = a.coordinator.clone() {
            let me = a.advertise.clone().unwrap_or_else(|| addr.to_string());
            let token = config.token.clone();
            tokio::spawn(register_loop(coord, me, token, coordinator_tls));
        }
        service::run(listener, ctx, config, shutdown_signal()).await
    })
}

/// Resolves on Ctrl-C or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        if let Ok(mut s) = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            s.recv().await;
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
    tracing::info!("shutting down");
}

/// Announces this worker to its coordinator, and again every few seconds
/// (a restarted coordinator learns its workers back within one period).
async fn register_loop(coordinator: String, me: String, token: Option<String>, tls: Option<tonic::transport::ClientTlsConfig>) {
    use sylva_proto::pb;
    loop {
        let sent = async {
            let ch = sylva_proto::tls::connect(&coordinator, tls.as_ref(), std::time::Duration::from_secs(10)).await.ok()?;
            let mut c = pb::coordinator_client::CoordinatorClient::with_interceptor(ch, sylva_proto::auth::attach(token.clone()));
            c.register_worker(pb::RegisterWorkerRequest { addr: me.clone() }).await.ok()
        }
        .await;
        if sent.is_none() {
            tracing::warn!(%coordinator, "cannot register with the coordinator; retrying");
        }
        tokio::time::sleep(std::time::Duration::from_secs(5)).await;
    }
}
