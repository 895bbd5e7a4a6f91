//! `sylva coordinator --listen ADDR` and `sylva submit SCENE --coordinator ADDR`.

use crate::flags::coordinator::*;
use anyhow::Context;
use std::io::Write;
use std::time::Duration;
use sylva_coordinator::client::submit_and_follow;
use sylva_coordinator::results::Retention;
use sylva_coordinator::service::{self, CoordinatorConfig, CoordinatorService};
use sylva_coordinator::shutdown::Shutdown;

/// glibc gives each thread that allocates its own heap arena, and the scene
/// checks run on the runtime's blocking threads, each leaving its arena at
/// its peak: 100 submissions of a 3.4 MB bundle left the coordinator at
/// 172 MB resident with the default arenas and 44 MB with one. Two keep a
/// long-running coordinator (or worker) near what it actually holds.
pub(crate) fn limit_malloc_arenas() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator tuning; called before any thread starts.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 2);
    }
}

pub fn run_coordinator(a: CoordinatorArgs) -> anyhow::Result<()> {
    limit_malloc_arenas();
    if a.ephemeral {
        // Temporary state of coordinators killed before they removed it.
        for d in sylva_proto::workdir::remove_abandoned(&std::env::temp_dir(), "sylva-coordinator-")
        {
            tracing::info!(dir = %d.display(), "removed a killed coordinator's temporary state");
        }
    }
    let token = a.auth.load()?;
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async {
        let listener = tokio::net::TcpListener::bind(&a.listen)
            .await
            .with_context(|| format!("cannot listen on {}", a.listen))?;
        let addr = listener.local_addr()?;
        let metrics = match &a.metrics {
            Some(m) => Some(
                tokio::net::TcpListener::bind(m)
                    .await
                    .with_context(|| format!("cannot listen on {m}"))?,
            ),
            None => None,
        };
        let metrics_addr = metrics.as_ref().map(|l| l.local_addr()).transpose()?;
        let http = match &a.http {
            Some(h) => Some(
                tokio::net::TcpListener::bind(h)
                    .await
                    .with_context(|| format!("cannot listen on {h}"))?,
            ),
            None => None,
        };
        let http_addr = http.as_ref().map(|l| l.local_addr()).transpose()?;
        let config = CoordinatorConfig {
            metrics,
            max_running: a.max_running,
            max_bundle_bytes: a.max_bundle_mib << 20,
            token,
            workers: a.workers.clone(),
            strip_deadline: Duration::from_secs(a.strip_deadline_s.max(1)),
            limits: a.limits.limits(),
            retention: Retention {
                keep: Duration::from_secs(a.keep_results_s),
                max_jobs: a.keep_jobs,
            },
            state_dir: a.state_dir()?,
            ephemeral: a.ephemeral,
            database: a.database.clone(),
            max_job_pixels: a.max_job_pixels,
            results_disk_bytes: a.results_disk_mib << 20,
            registration_ttl: Duration::from_secs(a.registration_ttl_s.max(1)),
            tls: a.tls.load()?,
            worker_tls: a.worker_tls.load()?,
            ..Default::default()
        };
        let serves_tls = config.tls.is_some();
        // The dashboard serves beside the API, until the same signal.
        let shutdown = Shutdown::new(sylva_coordinator::shutdown::signal());
        let mut dashboard = None;
        // Announced once the state is open: a script that waits for the
        // line may use the state folder (`sylva token add`) at once.
        let ready = |service: &CoordinatorService| {
            if let Some(h) = http {
                dashboard = Some(sylva_coordinator::dashboard::start(h, service, shutdown.wait())?);
            }
            if let Some(m) = metrics_addr {
                eprintln!("sylva coordinator metrics on http://{m}/metrics");
            }
            if let Some(h) = http_addr {
                eprintln!("sylva coordinator dashboard on {}", dashboard_url(h));
            }
            // Tokens sent in the clear beyond this machine can be read on
            // the way: say so where that is the case.
            if service.needs_token() && !addr.ip().is_loopback() && !serves_tls {
                tracing::warn!(
                    %addr,
                    "listening beyond this machine without TLS: bearer tokens cross the network \
                     readable (give --tls-cert and --tls-key)"
                );
            }
            if let Some(h) = http_addr.filter(|h| service.needs_token() && !h.ip().is_loopback()) {
                tracing::warn!(
                    addr = %h,
                    "the dashboard serves beyond this machine over plain HTTP: its bearer tokens \
                     cross the network readable (put it behind a TLS proxy, or on 127.0.0.1)"
                );
            }
            println!("sylva coordinator listening on {addr}");
            let _ = std::io::stdout().flush();
            Ok(())
        };
        let served = service::run(listener, config, ready, shutdown.wait()).await;
        if let Some(d) = dashboard {
            // Ended on the signal already, unless the API stopped on an error.
            d.abort();
            let _ = d.await;
        }
        served
    })
}

pub fn run_submit(mut a: SubmitArgs) -> anyhow::Result<()> {
    crate::flags::render::exr_named(&mut a.out, &mut a.exr);
    anyhow::ensure!(
        !a.frame.auto(),
        "--lighting auto runs its pilot on this machine's GPU: `sylva render --local-workers 0 --lighting auto …`"
    );
    let started = std::time::Instant::now();
    let token = a.auth.load()?;
    let tls = a.tls.load()?;
    let bundle = sylva_scene::bundle::pack(&a.scene)?;
    let frame = a.frame.settings();
    frame.check()?;
    let text = std::fs::read_to_string(&a.scene)
        .with_context(|| format!("{}: cannot read", a.scene.display()))?;
    let access = sylva_scene::FileAccess::Inside(sylva_scene::folder_of(&a.scene));
    let views = a.frame.views(&sylva_scene::parse_with(
        &text,
        &a.scene.display().to_string(),
        &access,
        &Default::default(),
    )?)?;
    let spec = super::spec::job_spec(
        &frame,
        &views,
        a.schedule,
        a.priority,
        &a.name.clone().unwrap_or_else(|| a.scene.display().to_string()),
    );
    let rt = tokio::runtime::Runtime::new()?;
    // Passes live in the EXR: asking for them asks for it.
    let exr = a.exr || !frame.passes.is_empty();
    let done =
        rt.block_on(submit_and_follow(&a.coordinator, token, tls.as_ref(), spec, &bundle, exr))?;
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    let wrote = if !views.is_empty() {
        let written =
            sylva_coordinator::sequence::write_all(&a.out, &done.pngs, done.exrs.as_deref())?;
        format!(
            "{} frames, {} and {}",
            views.len(),
            written[written.len() - 2].display(),
            written[written.len() - 1].display()
        )
    } else {
        std::fs::write(&a.out, &done.pngs[0])
            .with_context(|| format!("{}: cannot write", a.out.display()))?;
        if let Some(exr) = done.exrs.as_ref().map(|e| &e[0]) {
            std::fs::write(a.out.with_extension("exr"), exr)?;
        }
        a.out.display().to_string()
    };
    // The farm's stats and the client's own times, as `render` writes its.
    let total_ms = started.elapsed().as_secs_f64() * 1e3;
    let stats = serde_json::json!({
        "job": done.id,
        "total_ms": total_ms,
        "client_ms": done.times,
        "farm": done.stats,
    });
    let stats_file = crate::render::stats_path(&a.out);
    std::fs::write(&stats_file, serde_json::to_vec_pretty(&stats)?)
        .with_context(|| format!("{}: cannot write", stats_file.display()))?;
    // What the workers' lighting found reaches the one who asked (the
    // workers' logs are not theirs to read).
    for w in sylva_coordinator::client::warnings_of(&done.stats) {
        eprintln!("warning: {w}");
    }
    println!("{} done in {:.2} s: wrote {wrote}", done.id, total_ms / 1e3);
    Ok(())
}

/// The dashboard's address as a browser on another machine would open it:
/// an unspecified bind (`0.0.0.0`, `::`) is this machine's host name.
fn dashboard_url(bound: std::net::SocketAddr) -> String {
    if !bound.ip().is_unspecified() {
        return format!("http://{bound}/");
    }
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "localhost".into());
    format!("http://{host}:{}/ (every interface)", bound.port())
}
