//! `sylva worker --listen ADDR`: a GPU worker serving the worker API.

use crate::flags::worker::*;
use anyhow::Context;
use std::io::Write;
use sylva_worker::GpuContext;
use sylva_worker::service::{self, WorkerConfig};

pub fn run(a: WorkerArgs) -> anyhow::Result<()> {
    // Scenes are prepared on many threads (rayon, the runtime's blocking
    // pool): without a cap each keeps its own arena at its peak.
    crate::coordinator::limit_malloc_arenas();
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
            memory_bytes: a.memory_mib << 20,
            disk_cache: a.prepared_cache.open()?,
            ..WorkerConfig::default()
        };
        // Compiled kernels are kept beside the prepared data.
        if let Some(d) = &config.disk_cache {
            ctx.keep_kernels_in(d.dir());
        }
        if let Some(d) = &a.cache_dir {
            config.cache_dir = d.clone();
        }
        // Caches of workers killed before they could remove them.
        for d in sylva_proto::workdir::remove_abandoned(&std::env::temp_dir(), "sylva-worker-") {
            tracing::info!(dir = %d.display(), "removed a killed worker's bundle cache");
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
                config.session.clone(),
                config.claims.clone(),
            ));
        }
        service::run(listener, ctx, config, sylva_coordinator::shutdown::signal()).await
    })
}
