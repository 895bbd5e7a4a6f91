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
        // Before anything starts: a worker nobody can dial does not register.
        let me = match &a.coordinator {
            Some(coord) => Some(advertised(addr, coord, a.advertise.clone())?),
            None => None,
        };
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
        let registration = match (a.coordinator.clone(), me) {
            (Some(coord), Some(me)) => {
                tracing::info!(advertise = %me, "the coordinator will reach this worker at this address");
                let token = config.token.clone();
                Some(tokio::spawn(sylva_coordinator::registration::register_loop(
                    coord,
                    me,
                    token,
                    coordinator_tls,
                    config.session.clone(),
                    config.claims.clone(),
                )))
            }
            _ => None,
        };
        let serve = service::run(listener, ctx, config, sylva_coordinator::shutdown::signal());
        let Some(registration) = registration else { return serve.await };
        // A worker whose token may not register stops, saying why, rather
        // than retry for ever.
        tokio::select! {
            served = serve => served,
            refused = registration => Err(match refused {
                Ok(e) => anyhow::anyhow!("{e}: start the worker with a worker token"),
                Err(e) => anyhow::anyhow!("the registration task failed: {e}"),
            }),
        }
    })
}

/// The address the coordinator is told to dial: `--advertise` when given,
/// else the bound one, unless that is unspecified (`0.0.0.0`, `::`), which
/// no other machine can dial: then the address of the interface this
/// machine would reach the coordinator through, with the bound port. A
/// worker that cannot find one refuses to start rather than register an
/// address nobody can reach.
fn advertised(
    bound: std::net::SocketAddr,
    coordinator: &str,
    advertise: Option<String>,
) -> anyhow::Result<String> {
    use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
    if let Some(a) = advertise {
        return Ok(a);
    }
    if !bound.ip().is_unspecified() {
        return Ok(bound.to_string());
    }
    let host = coordinator.split_once("://").map_or(coordinator, |(_, rest)| rest);
    let host = host.trim_end_matches('/');
    let route = || -> std::io::Result<SocketAddr> {
        let to = host.to_socket_addrs()?.next().ok_or(std::io::ErrorKind::NotFound)?;
        // A datagram socket "connected" sends nothing: the kernel only
        // picks the route, and with it this end's address.
        let socket = UdpSocket::bind(if to.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" })?;
        socket.connect(to)?;
        socket.local_addr()
    };
    match route() {
        Ok(local) if !local.ip().is_unspecified() => {
            Ok(SocketAddr::new(local.ip(), bound.port()).to_string())
        }
        other => anyhow::bail!(
            "listening on {bound}, which the coordinator cannot dial, and no address of this \
             machine routes to {host}{}: give the address the coordinator should use with \
             --advertise HOST:{}",
            other.err().map(|e| format!(" ({e})")).unwrap_or_default(),
            bound.port()
        ),
    }
}
