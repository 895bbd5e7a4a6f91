//! `sylva coordinator --listen ADDR` and `sylva submit SCENE --coordinator ADDR`.

use super::worker::shutdown_signal;
use anyhow::{Context, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;
use sylva_coordinator::service::{self, CoordinatorConfig};
use sylva_proto::pb;
use sylva_proto::pb::coordinator_client::CoordinatorClient;
use tokio_stream::StreamExt;

#[derive(Debug, Args)]
pub struct CoordinatorArgs {
    /// Address to listen on (port 0 picks one; the bound address is printed).
    #[arg(long, default_value = "127.0.0.1:50150")]
    pub listen: String,
    /// Workers to use from the start (`host:port,…`); others register themselves.
    #[arg(long, value_delimiter = ',')]
    pub workers: Vec<String>,
    /// Jobs rendered at the same time.
    #[arg(long, default_value_t = 2)]
    pub max_running: usize,
    /// Largest scene bundle accepted, MiB.
    #[arg(long, default_value_t = 1024)]
    pub max_bundle_mib: u64,
    /// Seconds one strip may take before it goes to another worker.
    #[arg(long, default_value_t = 600)]
    pub strip_deadline_s: u64,
    /// The token clients must send, and workers are sent.
    #[command(flatten)]
    pub auth: super::security::TokenArgs,
    #[command(flatten)]
    pub tls: super::security::ServeTlsArgs,
    /// How to reach the workers over TLS.
    #[command(flatten)]
    pub worker_tls: super::security::ConnectTlsArgs,
    /// Serve Prometheus metrics on this address (`GET /metrics`).
    #[arg(long)]
    pub metrics: Option<String>,
}

pub fn run_coordinator(a: CoordinatorArgs) -> anyhow::Result<()> {
    let token = a.auth.load()?;
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async {
        let listener = tokio::net::TcpListener::bind(&a.listen).await.with_context(|| format!("cannot listen on {}", a.listen))?;
        let addr = listener.local_addr()?;
        let metrics = match &a.metrics {
            Some(m) => Some(tokio::net::TcpListener::bind(m).await.with_context(|| format!("cannot listen on {m}"))?),
            None => None,
        };
        let metrics_addr = metrics.as_ref().map(|l| l.local_addr()).transpose()?;
        let config = CoordinatorConfig {
            metrics,
            max_running: a.max_running,
            max_bundle_bytes: a.max_bundle_mib << 20,
            token,
            workers: a.workers.clone(),
            strip_deadline: Duration::from_secs(a.strip_deadline_s.max(1)),
            tls: a.tls.load()?,
            worker_tls: a.worker_tls.load()?,
            ..Default::default()
        };
        if let Some(m) = metrics_addr {
            eprintln!("sylva coordinator metrics on http://{m}/metrics");
        }
        println!("sylva coordinator listening on {addr}");
        std::io::stdout().flush()?;
        service::run(listener, config, shutdown_signal()).await
    })
}

#[derive(Debug, Args)]
pub struct SubmitArgs {
    /// Scene file.
    pub scene: PathBuf,
    /// The coordinator, `host:port`.
    #[arg(long)]
    pub coordinator: String,
    /// Output PNG (an EXR beside it with --exr).
    #[arg(short, long, default_value = "sylva-out/render.png")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 896)]
    pub width: u32,
    #[arg(long, default_value_t = 448)]
    pub height: u32,
    #[arg(long, default_value_t = 1)]
    pub spp: u32,
    /// kd or bvh.
    #[arg(long, default_value = "bvh")]
    pub accel: String,
    /// local, ambient, lb or lb-visualize; default the scene's.
    #[arg(long, default_value = "")]
    pub lighting: String,
    /// static or dynamic.
    #[arg(long, default_value = "dynamic")]
    pub schedule: String,
    /// Higher runs first.
    #[arg(long, default_value_t = 0)]
    pub priority: i32,
    #[arg(long, default_value_t = 1)]
    pub seed: u32,
    /// Also fetch the linear HDR frame as OpenEXR.
    #[arg(long)]
    pub exr: bool,
    #[command(flatten)]
    pub auth: super::security::TokenArgs,
    #[command(flatten)]
    pub tls: super::security::ConnectTlsArgs,
}

pub fn run_submit(a: SubmitArgs) -> anyhow::Result<()> {
    let token = a.auth.load()?;
    let tls = a.tls.load()?;
    let bundle = sylva_shared::bundle::pack(&a.scene)?;
    let spec = pb::JobSpec {
        frame: Some(pb::FrameSettings {
            width: a.width,
            height: a.height,
            spp: a.spp,
            seed: a.seed,
            lighting: a.lighting.clone(),
            accel: a.accel.clone(),
            lb_strength: 0.35,
            ambient: vec![],
        }),
        schedule: a.schedule.clone(),
        priority: a.priority,
        name: a.scene.display().to_string(),
    };
    let rt = tokio::runtime::Runtime::new()?;
    let done = rt.block_on(submit_and_follow(&a.coordinator, token, tls.as_ref(), spec, &bundle, a.exr))?;
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&a.out, &done.png).with_context(|| format!("{}: cannot write", a.out.display()))?;
    if let Some(exr) = &done.exr {
        std::fs::write(a.out.with_extension("exr"), exr)?;
    }
    println!("{} done: wrote {}", done.id, a.out.display());
    Ok(())
}

/// A finished job, fetched.
pub struct FinishedJob {
    /// Its id.
    pub id: String,
    /// The tone-mapped image.
    pub png: Vec<u8>,
    /// The linear HDR frame, when asked for.
    pub exr: Option<Vec<u8>>,
    /// The coordinator's stats of the frame.
    pub stats: serde_json::Value,
}

/// Sends a job to the coordinator at `addr`, follows it with a progress
/// bar and fetches its image.
pub async fn submit_and_follow(
    addr: &str,
    token: Option<String>,
    tls: Option<&tonic::transport::ClientTlsConfig>,
    spec: pb::JobSpec,
    bundle: &sylva_shared::bundle::SceneBundle,
    exr: bool,
) -> anyhow::Result<FinishedJob> {
    let ch = sylva_proto::tls::connect(addr, tls, Duration::from_secs(10)).await.with_context(|| format!("cannot reach the coordinator at {addr}"))?;
    let mut c = CoordinatorClient::with_interceptor(ch, sylva_proto::auth::attach(token))
        .max_decoding_message_size(1 << 30)
        .max_encoding_message_size(1 << 30);
    let mut chunks = vec![pb::SubmitChunk { spec: Some(spec), hash: bundle.hash.clone(), total_size: bundle.bytes.len() as u64, data: vec![] }];
    chunks.extend(bundle.bytes.chunks(1 << 20).map(|d| pb::SubmitChunk { data: d.to_vec(), ..Default::default() }));
    let id = c.submit_job(tokio_stream::iter(chunks)).await.map_err(|s| anyhow::anyhow!("{:?}: {}", s.code(), s.message()))?.into_inner().id;
    let bar = ProgressBar::new(1);
    bar.set_style(ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} strips {elapsed}").expect("valid template").progress_chars("=> "));
    bar.set_message(id.clone());
    let mut events = c.watch_job(pb::JobId { id: id.clone() }).await?.into_inner();
    let mut end = None;
    while let Some(ev) = events.next().await {
        let ev = ev?;
        bar.set_length(ev.strips_total.max(1) as u64);
        bar.set_position(ev.strips_done as u64);
        if !ev.message.is_empty() {
            tracing::warn!("{}", ev.message);
        }
        if matches!(ev.state.as_str(), "done" | "failed" | "cancelled") {
            end = Some(ev);
            break;
        }
    }
    bar.finish_and_clear();
    let end = end.context("the coordinator closed the job's event stream early")?;
    if end.state != "done" {
        bail!("job {id} {}: {}", end.state, end.message);
    }
    let png = c.fetch_result(pb::FetchRequest { id: id.clone(), format: "png".into() }).await?.into_inner().data;
    let exr = if exr { Some(c.fetch_result(pb::FetchRequest { id: id.clone(), format: "exr".into() }).await?.into_inner().data) } else { None };
    let stats = serde_json::from_str(&end.stats_json).unwrap_or(serde_json::Value::Null);
    Ok(FinishedJob { id, png, exr, stats })
}
