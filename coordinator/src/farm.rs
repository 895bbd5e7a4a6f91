//! Renders a frame on a set of gRPC workers: every worker gets the scene
//! bundle, then pulls strips from one queue until the frame is done. A
//! strip whose worker fails or misses its deadline goes back on the queue
//! for another; a worker that fails three times is dropped for this frame;
//! the frame fails only when no worker is left. Strips land by their
//! columns, so the frame is the same whoever rendered what.

use crate::schedule::Strip;
use serde::Serialize;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::pb::worker_client::WorkerClient;
use sylva_shared::bundle::SceneBundle;
use sylva_shared::film::HdrImage;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, ClientTlsConfig};

/// Failures after which a worker is dropped for the frame.
pub const MAX_FAILURES: u32 = 3;
/// Bytes per upload chunk.
const CHUNK: usize = 1 << 20;

/// What happened, for progress bars and logs.
#[derive(Clone, Debug)]
pub enum FarmEvent {
    /// A strip came back with `bytes` of pixels.
    StripDone { strip: Strip, worker: String, ms: f64, bytes: u64 },
    /// A scene bundle of `bytes` was sent to a worker.
    BundleSent { worker: String, bytes: u64 },
    /// A strip failed on a worker and was put back on the queue.
    StripRetried { strip: Strip, worker: String, error: String },
    /// A worker was dropped for this frame.
    WorkerDropped { worker: String, error: String },
}

/// Per-worker figures of one frame.
#[derive(Clone, Debug, Default, Serialize)]
pub struct WorkerReport {
    /// Address.
    pub worker: String,
    /// Strips rendered.
    pub strips: u32,
    /// Milliseconds spent rendering them (as the worker measured).
    pub render_ms: f64,
    /// Milliseconds of scene preparation (first strip of a new scene).
    pub prepare_ms: f64,
    /// Strips that failed here.
    pub failures: u32,
    /// Whether the worker was dropped.
    pub dropped: bool,
}

/// A rendered frame.
#[derive(Clone, Debug)]
pub struct FarmFrame {
    /// Linear HDR.
    pub image: HdrImage,
    /// Per pixel, the fraction of samples that hit a model.
    pub coverage: Vec<f32>,
    /// Rays: primary, shadow, transparent texels passed.
    pub rays: [u64; 3],
    /// Per worker.
    pub workers: Vec<WorkerReport>,
    /// Every strip: its render time on the worker and the whole RPC's time
    /// as the coordinator saw it (render plus transfer), by strip.
    pub strip_ms: Vec<(Strip, f64, f64)>,
    /// Time to send the bundle to every worker.
    pub upload_ms: f64,
}

/// A worker client that sends the bearer token, if any.
pub type Client = WorkerClient<InterceptedService<Channel, Auth>>;
type Auth = Box<dyn FnMut(tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> + Send + Sync>;

/// Connects to a worker at `addr` (`host:port`), over TLS when `tls` is
/// set, sending `token` with every call.
pub async fn connect(addr: &str, token: Option<String>, tls: Option<&ClientTlsConfig>) -> anyhow::Result<Client> {
    let ch = sylva_proto::tls::connect(addr, tls, Duration::from_secs(10)).await.map_err(|e| anyhow::anyhow!("cannot reach worker {addr}: {e}"))?;
    let auth: Auth = Box::new(sylva_proto::auth::attach(token));
    Ok(WorkerClient::with_interceptor(ch, auth).max_decoding_message_size(1 << 30).max_encoding_message_size(1 << 30))
}

/// Sends `bundle` to a worker (a single empty chunk first, in case it is
/// cached); returns the bytes sent.
pub async fn upload(client: &mut Client, bundle: &SceneBundle) -> Result<u64, tonic::Status> {
    let probe = pb::SceneChunk { hash: bundle.hash.clone(), total_size: bundle.bytes.len() as u64, data: Vec::new() };
    if bundle.bytes.is_empty() || client.load_scene(tokio_stream::iter(vec![probe])).await.is_ok_and(|r| r.get_ref().was_cached) {
        return Ok(0);
    }
    let chunks: Vec<pb::SceneChunk> = bundle
        .bytes
        .chunks(CHUNK)
        .enumerate()
        .map(|(i, c)| pb::SceneChunk {
            hash: if i == 0 { bundle.hash.clone() } else { String::new() },
            total_size: if i == 0 { bundle.bytes.len() as u64 } else { 0 },
            data: c.to_vec(),
        })
        .collect();
    client.load_scene(tokio_stream::iter(chunks)).await.map(|_| bundle.bytes.len() as u64)
}

struct Shared {
    queue: Mutex<VecDeque<Strip>>,
    done: Mutex<Vec<(pb::RenderStripReply, Strip, f64)>>,
    total: usize,
}

/// Where and how to reach the workers.
#[derive(Clone, Debug)]
pub struct Workers {
    /// Addresses, `host:port`.
    pub addrs: Vec<String>,
    /// Bearer token the workers require, if any.
    pub token: Option<String>,
    /// TLS to reach them with, if they serve it.
    pub tls: Option<ClientTlsConfig>,
}

impl Workers {
    /// Workers that need no token.
    pub fn open(addrs: &[String]) -> Self {
        Self { addrs: addrs.to_vec(), token: None, tls: None }
    }
}

/// Renders `frame` of `bundle` on `workers`, strips pulled in `plan` order;
/// `deadline` bounds each strip's RPC.
pub async fn render_frame(
    workers: &Workers,
    bundle: &SceneBundle,
    frame: pb::FrameSettings,
    plan: Vec<Strip>,
    deadline: Duration,
    events: impl Fn(FarmEvent) + Send + Sync + 'static,
) -> anyhow::Result<FarmFrame> {
    anyhow::ensure!(!workers.addrs.is_empty(), "no workers to render on");
    let t = Instant::now();
    let mut clients = Vec::new();
    let mut reports: Vec<WorkerReport> = Vec::new();
    let mut sent = Vec::new();
    for w in &workers.addrs {
        let mut report = WorkerReport { worker: w.clone(), ..Default::default() };
        match connect(w, workers.token.clone(), workers.tls.as_ref()).await {
            Ok(mut c) => match upload(&mut c, bundle).await {
                Ok(bytes) => {
                    if bytes > 0 {
                        sent.push((w.clone(), bytes));
                    }
                    clients.push(Some(c))
                }
                Err(e) => {
                    report.dropped = true;
                    events(FarmEvent::WorkerDropped { worker: w.clone(), error: format!("scene upload: {}", e.message()) });
                    clients.push(None);
                }
            },
            Err(e) => {
                report.dropped = true;
                events(FarmEvent::WorkerDropped { worker: w.clone(), error: e.to_string() });
                clients.push(None);
            }
        }
        reports.push(report);
    }
    let upload_ms = t.elapsed().as_secs_f64() * 1e3;
    for (w, b) in &sent {
        events(FarmEvent::BundleSent { worker: w.clone(), bytes: *b });
    }
    let shared = Arc::new(Shared { total: plan.len(), queue: Mutex::new(plan.into_iter().collect()), done: Mutex::new(Vec::new()) });
    let events = Arc::new(events);
    let mut tasks = Vec::new();
    for (client, report) in clients.into_iter().zip(reports) {
        let (shared, events, frame, hash) = (shared.clone(), events.clone(), frame.clone(), bundle.hash.clone());
        tasks.push(tokio::spawn(async move {
            let mut report = report;
            let Some(mut client) = client else { return report };
            loop {
                let next = shared.queue.lock().expect("lock").pop_front();
                let Some(strip) = next else {
                    if shared.done.lock().expect("lock").len() == shared.total {
                        return report;
                    }
                    // Strips may still come back from failing workers.
                    tokio::time::sleep(Duration::from_millis(5)).await;
                    continue;
                };
                let mut req = tonic::Request::new(pb::RenderStripRequest { scene_hash: hash.clone(), frame: Some(frame.clone()), x0: strip.0, x1: strip.1 });
                req.set_timeout(deadline);
                let sent = Instant::now();
                match tokio::time::timeout(deadline + Duration::from_secs(1), client.render_strip(req)).await {
                    Ok(Ok(reply)) => {
                        let r = reply.into_inner();
                        report.strips += 1;
                        report.render_ms += r.render_ms;
                        report.prepare_ms += r.prepare_ms;
                        let bytes = (r.rgb_f32.len() + r.coverage_f32.len()) as u64;
                        events(FarmEvent::StripDone { strip, worker: report.worker.clone(), ms: r.render_ms, bytes });
                        shared.done.lock().expect("lock").push((r, strip, sent.elapsed().as_secs_f64() * 1e3));
                    }
                    failure => {
                        let error = match failure {
                            Ok(Err(status)) => format!("{:?}: {}", status.code(), status.message()),
                            _ => "deadline passed".to_string(),
                        };
                        shared.queue.lock().expect("lock").push_back(strip);
                        report.failures += 1;
                        events(FarmEvent::StripRetried { strip, worker: report.worker.clone(), error: error.clone() });
                        if report.failures >= MAX_FAILURES {
                            report.dropped = true;
                            events(FarmEvent::WorkerDropped { worker: report.worker.clone(), error });
                            return report;
                        }
                    }
                }
            }
        }));
    }
    // Wait for the frame, or for every worker to be gone.
    let mut reports = Vec::new();
    for t in tasks {
        reports.push(t.await?);
    }
    let done = std::mem::take(&mut *shared.done.lock().expect("lock"));
    if done.len() < shared.total {
        let why: Vec<String> = reports.iter().filter(|r| r.dropped).map(|r| r.worker.clone()).collect();
        anyhow::bail!("the frame failed: {} of {} strips rendered; no worker left that can finish it (dropped: {})", done.len(), shared.total, why.join(", "));
    }
    let mut image = HdrImage::new(frame.width, frame.height);
    let mut coverage = vec![0.0f32; (frame.width * frame.height) as usize];
    let mut rays = [0u64; 3];
    let mut strip_ms = Vec::new();
    for (r, strip, rpc_ms) in &done {
        let px: Vec<[f32; 3]> = r.rgb_f32.chunks_exact(12).map(|c| std::array::from_fn(|k| f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().expect("4 bytes")))).collect();
        anyhow::ensure!(px.len() == (r.width * frame.height) as usize && r.x0 == strip.0, "worker returned a malformed strip");
        image.paste_strip(r.x0, r.width, &px);
        for (i, c) in r.coverage_f32.chunks_exact(4).enumerate() {
            let (y, x) = (i as u32 / r.width, i as u32 % r.width);
            coverage[(y * frame.width + r.x0 + x) as usize] = f32::from_le_bytes(c.try_into().expect("4 bytes"));
        }
        if let Some(c) = &r.rays {
            rays[0] += c.primary;
            rays[1] += c.shadow;
            rays[2] += c.transparent;
        }
        strip_ms.push((*strip, r.render_ms, *rpc_ms));
    }
    strip_ms.sort_by_key(|s| s.0);
    Ok(FarmFrame { image, coverage, rays, workers: reports, strip_ms, upload_ms })
}
