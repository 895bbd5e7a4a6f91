//! The coordinator's gRPC service: a queue of jobs (priority, then
//! submission order), run over the registered workers by the strip farm;
//! progress streamed to watchers; results kept in memory. A restart loses
//! the queue, running jobs and results (clients resubmit); workers keep
//! their cached scenes and re-register within one heartbeat.

use crate::farm::{self, FarmEvent, Workers};
use crate::schedule::{ScheduleKind, scheduler};
use std::collections::BTreeMap;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use sylva_proto::pb;
use sylva_proto::pb::coordinator_server::{Coordinator, CoordinatorServer};
use sylva_shared::bundle::{self, SceneBundle};
use sylva_shared::film::reinhard;
use tokio::sync::{Semaphore, broadcast};
use tokio_stream::{Stream, StreamExt};
use tonic::{Request, Response, Status, Streaming};

/// How the coordinator runs.
#[derive(Debug)]
pub struct CoordinatorConfig {
    /// Jobs rendered at the same time.
    pub max_running: usize,
    /// Largest bundle accepted, bytes.
    pub max_bundle_bytes: u64,
    /// Bearer token clients must send and workers are sent.
    pub token: Option<String>,
    /// Workers known from the start.
    pub workers: Vec<String>,
    /// Seconds one strip may take.
    pub strip_deadline: Duration,
    /// Time between worker heartbeats.
    pub heartbeat: Duration,
    /// Serve Prometheus metrics here.
    pub metrics: Option<tokio::net::TcpListener>,
    /// Serve the API over TLS with this identity.
    pub tls: Option<tonic::transport::ServerTlsConfig>,
    /// Reach workers over TLS with this.
    pub worker_tls: Option<tonic::transport::ClientTlsConfig>,
}

impl Default for CoordinatorConfig {
    fn default() -> Self {
        Self {
            max_running: 2,
            max_bundle_bytes: 1 << 30,
            token: None,
            workers: Vec::new(),
            strip_deadline: Duration::from_secs(600),
            heartbeat: Duration::from_secs(2),
            metrics: None,
            tls: None,
            worker_tls: None,
        }
    }
}

struct Job {
    seq: u64,
    spec: pb::JobSpec,
    bundle: Arc<SceneBundle>,
    summary: pb::JobSummary,
    events: broadcast::Sender<pb::JobEvent>,
    png: Option<Vec<u8>>,
    exr: Option<Vec<u8>>,
    task: Option<tokio::task::AbortHandle>,
}

struct State {
    config: CoordinatorConfig,
    metrics: Arc<crate::metrics::Metrics>,
    jobs: Mutex<BTreeMap<String, Job>>,
    workers: Mutex<BTreeMap<String, pb::WorkerInfo>>,
    /// Per-column cost of frames rendered before, by scene and frame shape.
    costs: Mutex<std::collections::HashMap<String, Vec<f64>>>,
    next: Mutex<u64>,
    slots: Arc<Semaphore>,
    wake: tokio::sync::Notify,
}

/// The `sylva.v1.Coordinator` service.
#[derive(Clone)]
pub struct CoordinatorService {
    state: Arc<State>,
}

impl CoordinatorService {
    /// A coordinator; call [`CoordinatorService::spawn_background`] to run jobs.
    pub fn new(mut config: CoordinatorConfig) -> Self {
        let metrics_listener = config.metrics.take();
        // Named workers count as alive until a heartbeat says otherwise, so a
        // job submitted at once can use them (the farm copes if one is not).
        let workers = config.workers.iter().map(|a| (a.clone(), pb::WorkerInfo { addr: a.clone(), alive: true, ..Default::default() })).collect();
        let slots = Arc::new(Semaphore::new(config.max_running.max(1)));
        let service = Self {
            state: Arc::new(State {
                config,
                metrics: Arc::new(crate::metrics::Metrics::default()),
                jobs: Mutex::new(BTreeMap::new()),
                workers: Mutex::new(workers),
                costs: Mutex::new(Default::default()),
                next: Mutex::new(1),
                slots,
                wake: tokio::sync::Notify::new(),
            }),
        };
        if let Some(l) = metrics_listener {
            let s = service.state.clone();
            tokio::spawn(crate::metrics::serve(l, service.state.metrics.clone(), move || s.gauges()));
        }
        service
    }

    /// Starts the scheduler loop and the worker heartbeats.
    pub fn spawn_background(&self) {
        let s = self.state.clone();
        tokio::spawn(async move { s.schedule_loop().await });
        let s = self.state.clone();
        tokio::spawn(async move { s.heartbeat_loop().await });
    }

    /// The tonic server wrapper.
    pub fn into_server(self) -> CoordinatorServer<Self> {
        let limit = (self.state.config.max_bundle_bytes as usize).max(64 << 20);
        CoordinatorServer::new(self).max_decoding_message_size(limit).max_encoding_message_size(limit)
    }
}

impl State {
    fn gauges(&self) -> crate::metrics::Gauges {
        let jobs = self.jobs.lock().expect("lock");
        let workers = self.workers.lock().expect("lock");
        crate::metrics::Gauges {
            queued: jobs.values().filter(|j| j.summary.state == "queued").count() as u64,
            running: jobs.values().filter(|j| j.summary.state == "running").count() as u64,
            workers_alive: workers.values().filter(|w| w.alive).count() as u64,
            workers: workers.len() as u64,
        }
    }

    fn event(&self, id: &str) -> pb::JobEvent {
        let jobs = self.jobs.lock().expect("lock");
        let j = &jobs[id];
        pb::JobEvent {
            id: id.to_string(),
            state: j.summary.state.clone(),
            strips_done: j.summary.strips_done,
            strips_total: j.summary.strips_total,
            ..Default::default()
        }
    }

    fn set_state(&self, id: &str, state: &str, error: Option<String>) {
        let mut jobs = self.jobs.lock().expect("lock");
        if let Some(j) = jobs.get_mut(id) {
            j.summary.state = state.to_string();
            if let Some(e) = error {
                j.summary.error = e;
            }
        }
    }

    /// Starts queued jobs, best first, as running slots free up.
    async fn schedule_loop(self: Arc<Self>) {
        loop {
            let permit = self.slots.clone().acquire_owned().await.expect("semaphore open");
            let next = loop {
                let pick = {
                    let jobs = self.jobs.lock().expect("lock");
                    jobs.iter()
                        .filter(|(_, j)| j.summary.state == "queued")
                        .max_by_key(|(_, j)| (j.spec.priority, std::cmp::Reverse(j.seq)))
                        .map(|(id, _)| id.clone())
                };
                match pick {
                    Some(id) => break id,
                    None => self.wake.notified().await,
                }
            };
            self.set_state(&next, "running", None);
            let s = self.clone();
            let id = next.clone();
            let handle = tokio::spawn(async move {
                s.run_job(&id).await;
                drop(permit);
            });
            if let Some(j) = self.jobs.lock().expect("lock").get_mut(&next) {
                j.task = Some(handle.abort_handle());
            }
        }
    }

    async fn run_job(self: &Arc<Self>, id: &str) {
        let (spec, bundle, tx) = {
            let jobs = self.jobs.lock().expect("lock");
            let j = &jobs[id];
            (j.spec.clone(), j.bundle.clone(), j.events.clone())
        };
        let _ = tx.send(self.event(id));
        let frame = spec.frame.clone().unwrap_or_default();
        let addrs: Vec<String> = self.workers.lock().expect("lock").values().filter(|w| w.alive).map(|w| w.addr.clone()).collect();
        if addrs.is_empty() {
            let why = "no worker is registered and alive: start workers with --coordinator, or the coordinator with --workers";
            self.set_state(id, "failed", Some(why.into()));
            let mut ev = self.event(id);
            ev.message = why.into();
            let _ = tx.send(ev);
            return;
        }
        let kind = if spec.schedule == "static" { ScheduleKind::Static } else { ScheduleKind::Dynamic };
        // A frame seen before is cut by its measured cost; a new one by
        // guided self-scheduling alone, whose shrinking strips still let
        // the last ones finish close together.
        let cost_key = format!("{}/{}x{}/{}/{}/{}", bundle.hash, frame.width, frame.height, frame.spp, frame.lighting, frame.accel);
        let cost = self.costs.lock().expect("lock").get(&cost_key).cloned().unwrap_or_default();
        let cost_source = if cost.is_empty() { "uniform (first frame of this scene and size)" } else { "measured on the previous frame" };
        let plan = scheduler(kind).plan(frame.width, addrs.len().max(1), &cost);
        if let Some(j) = self.jobs.lock().expect("lock").get_mut(id) {
            j.summary.strips_total = plan.len() as u32;
        }
        let span = tracing::info_span!("job", %id, strips = plan.len(), workers = addrs.len());
        let _g = span.enter();
        let (me, jid, tx2) = (self.clone(), id.to_string(), tx.clone());
        let started = std::time::Instant::now();
        let result = farm::render_frame(
            &Workers { addrs: addrs.clone(), token: self.config.token.clone(), tls: self.config.worker_tls.clone() },
            &bundle,
            frame.clone(),
            plan,
            self.config.strip_deadline,
            move |e| {
                let mut ev = pb::JobEvent { id: jid.clone(), state: "running".into(), ..Default::default() };
                match e {
                    FarmEvent::StripDone { worker, ms, bytes, .. } => {
                        me.metrics.strip_done(ms / 1e3, bytes);
                        let mut jobs = me.jobs.lock().expect("lock");
                        if let Some(j) = jobs.get_mut(&jid) {
                            j.summary.strips_done += 1;
                            ev.strips_done = j.summary.strips_done;
                            ev.strips_total = j.summary.strips_total;
                        }
                        ev.worker = worker;
                        ev.strip_ms = ms;
                    }
                    FarmEvent::StripRetried { worker, error, .. } => {
                        me.metrics.strip_retried();
                        ev.message = format!("strip re-queued from {worker}: {error}");
                    }
                    FarmEvent::BundleSent { bytes, .. } => {
                        me.metrics.bundle_sent(bytes);
                        return;
                    }
                    FarmEvent::WorkerDropped { worker, error } => ev.message = format!("worker {worker} dropped: {error}"),
                }
                let _ = tx2.send(ev);
            },
        )
        .await;
        match result {
            Ok(f) => {
                let (ldr, tone) = reinhard(&f.image, 0.18);
                let png = encode_png(frame.width, frame.height, &ldr);
                let exr = encode_exr(&f.image);
                let frame_ms = started.elapsed().as_secs_f64() * 1e3;
                {
                    let mut costs = self.costs.lock().expect("lock");
                    if costs.len() >= 1024 {
                        costs.clear();
                    }
                    costs.insert(cost_key, crate::schedule::column_cost(frame.width, &f.strip_ms));
                }
                let stats = serde_json::json!({
                    "schedule": kind,
                    "strip_cost": cost_source,
                    "frame_ms": frame_ms,
                    "upload_ms": f.upload_ms,
                    "workers": f.workers,
                    "strips": f.strip_ms.iter().map(|(s, ms, rpc)| serde_json::json!({ "x0": s.0, "x1": s.1, "render_ms": ms, "rpc_ms": rpc })).collect::<Vec<_>>(),
                    "rays": { "primary": f.rays[0], "shadow": f.rays[1], "transparent_passed": f.rays[2], "mrays_per_second": (f.rays[0] + f.rays[1]) as f64 / (frame_ms / 1e3) / 1e6 },
                    "coverage": f.coverage.iter().map(|&c| c as f64).sum::<f64>() / f.coverage.len().max(1) as f64,
                    "tone_map": tone,
                });
                {
                    let mut jobs = self.jobs.lock().expect("lock");
                    if let Some(j) = jobs.get_mut(id) {
                        j.png = png.ok();
                        j.exr = exr.ok();
                        j.summary.state = "done".into();
                    }
                }
                let mut ev = self.event(id);
                ev.stats_json = stats.to_string();
                let _ = tx.send(ev);
            }
            Err(e) => {
                self.set_state(id, "failed", Some(format!("{e:#}")));
                let mut ev = self.event(id);
                ev.message = format!("{e:#}");
                let _ = tx.send(ev);
            }
        }
    }

    /// Polls every worker's status; a worker that does not answer is not
    /// given new jobs until it does.
    async fn heartbeat_loop(self: Arc<Self>) {
        loop {
            let addrs: Vec<String> = self.workers.lock().expect("lock").keys().cloned().collect();
            for a in addrs {
                let status = async {
                    let mut c = farm::connect(&a, self.config.token.clone(), self.config.worker_tls.as_ref()).await.ok()?;
                    let mut req = Request::new(pb::StatusRequest {});
                    req.set_timeout(Duration::from_secs(5));
                    c.status(req).await.ok().map(|r| r.into_inner())
                }
                .await;
                if let Some(w) = self.workers.lock().expect("lock").get_mut(&a) {
                    match status {
                        Some(s) => {
                            w.alive = true;
                            w.adapter = s.adapter;
                            w.gpu_memory_bytes = s.gpu_memory_bytes;
                            w.cached_scenes = s.cached_scenes;
                            w.busy_strips = s.busy_strips;
                        }
                        None => w.alive = false,
                    }
                }
            }
            tokio::time::sleep(self.config.heartbeat).await;
        }
    }
}

fn encode_png(w: u32, h: u32, px: &[[u8; 3]]) -> anyhow::Result<Vec<u8>> {
    let img = image::RgbImage::from_raw(w, h, px.iter().flatten().copied().collect()).ok_or_else(|| anyhow::anyhow!("image size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)?;
    Ok(out.into_inner())
}

fn encode_exr(img: &sylva_shared::film::HdrImage) -> anyhow::Result<Vec<u8>> {
    let flat: Vec<f32> = img.pixels.iter().flatten().copied().collect();
    let buf = image::Rgb32FImage::from_raw(img.width, img.height, flat).ok_or_else(|| anyhow::anyhow!("image size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    image::DynamicImage::ImageRgb32F(buf).write_to(&mut out, image::ImageFormat::OpenExr)?;
    Ok(out.into_inner())
}

type EventStream = Pin<Box<dyn Stream<Item = Result<pb::JobEvent, Status>> + Send>>;

#[tonic::async_trait]
impl Coordinator for CoordinatorService {
    async fn submit_job(&self, request: Request<Streaming<pb::SubmitChunk>>) -> Result<Response<pb::JobId>, Status> {
        let mut stream = request.into_inner();
        let first = stream.next().await.ok_or_else(|| Status::invalid_argument("empty submission"))??;
        let spec = first.spec.ok_or_else(|| Status::invalid_argument("the first message must carry the job spec"))?;
        let frame = spec.frame.clone().ok_or_else(|| Status::invalid_argument("job spec without frame settings"))?;
        sylva_worker::service::check_frame(&frame)?;
        if !matches!(spec.schedule.as_str(), "" | "static" | "dynamic") {
            return Err(Status::invalid_argument(format!("schedule {:?}: static or dynamic", spec.schedule)));
        }
        if first.total_size > self.state.config.max_bundle_bytes {
            return Err(Status::resource_exhausted(format!(
                "bundle of {} bytes is over the limit of {} bytes",
                first.total_size, self.state.config.max_bundle_bytes
            )));
        }
        let mut bytes = first.data;
        while let Some(c) = stream.next().await {
            bytes.extend_from_slice(&c?.data);
            if bytes.len() as u64 > first.total_size {
                return Err(Status::invalid_argument("upload is longer than its declared size"));
            }
        }
        if (bytes.len() as u64) != first.total_size {
            return Err(Status::invalid_argument(format!("truncated upload: {} of {} bytes", bytes.len(), first.total_size)));
        }
        if bundle::hash_of(&bytes) != first.hash.to_ascii_lowercase() {
            return Err(Status::invalid_argument("the bundle's bytes do not match its hash"));
        }
        // Check the scene here, so a bad one fails its client, not a worker.
        let dir = std::env::temp_dir().join(format!("sylva-coordinator-{}", std::process::id())).join(&first.hash);
        let check = bytes.clone();
        tokio::task::spawn_blocking(move || bundle::unpack(&check, &dir).map(|_| ()))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(|e| Status::invalid_argument(format!("{e:#}")))?;
        let seq = {
            let mut n = self.state.next.lock().expect("lock");
            *n += 1;
            *n - 1
        };
        let id = format!("job-{seq}");
        let (tx, _) = broadcast::channel(1024);
        let summary = pb::JobSummary { id: id.clone(), state: "queued".into(), name: spec.name.clone(), priority: spec.priority, ..Default::default() };
        let hash = first.hash.to_ascii_lowercase();
        self.state.jobs.lock().expect("lock").insert(
            id.clone(),
            Job { seq, spec, bundle: Arc::new(SceneBundle { bytes, hash }), summary, events: tx, png: None, exr: None, task: None },
        );
        self.state.wake.notify_one();
        tracing::info!(%id, "job queued");
        Ok(Response::new(pb::JobId { id }))
    }

    type WatchJobStream = EventStream;

    async fn watch_job(&self, request: Request<pb::JobId>) -> Result<Response<Self::WatchJobStream>, Status> {
        let id = request.into_inner().id;
        let (mut rx, current) = {
            let jobs = self.state.jobs.lock().expect("lock");
            let j = jobs.get(&id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            (j.events.subscribe(), j.summary.clone())
        };
        let (tx, out) = tokio::sync::mpsc::channel(64);
        tokio::spawn(async move {
            let first = pb::JobEvent { id: current.id.clone(), state: current.state.clone(), strips_done: current.strips_done, strips_total: current.strips_total, message: current.error.clone(), ..Default::default() };
            let finished = matches!(first.state.as_str(), "done" | "failed" | "cancelled");
            if tx.send(Ok(first)).await.is_err() || finished {
                return;
            }
            while let Ok(ev) = rx.recv().await {
                let end = matches!(ev.state.as_str(), "done" | "failed" | "cancelled");
                // A vanished client ends the forwarding.
                if tx.send(Ok(ev)).await.is_err() || end {
                    break;
                }
            }
        });
        Ok(Response::new(Box::pin(tokio_stream::wrappers::ReceiverStream::new(out))))
    }

    async fn fetch_result(&self, request: Request<pb::FetchRequest>) -> Result<Response<pb::FetchReply>, Status> {
        let r = request.into_inner();
        let jobs = self.state.jobs.lock().expect("lock");
        let j = jobs.get(&r.id).ok_or_else(|| Status::not_found(format!("no job {}", r.id)))?;
        if j.summary.state != "done" {
            return Err(Status::failed_precondition(format!("job {} is {}", r.id, j.summary.state)));
        }
        let (data, format) = match r.format.as_str() {
            "" | "png" => (j.png.clone(), "png"),
            "exr" => (j.exr.clone(), "exr"),
            o => return Err(Status::invalid_argument(format!("format {o:?}: png or exr"))),
        };
        let data = data.ok_or_else(|| Status::internal("the image could not be encoded"))?;
        Ok(Response::new(pb::FetchReply { data, format: format.into() }))
    }

    async fn cancel_job(&self, request: Request<pb::JobId>) -> Result<Response<pb::JobSummary>, Status> {
        let id = request.into_inner().id;
        let (summary, tx) = {
            let mut jobs = self.state.jobs.lock().expect("lock");
            let j = jobs.get_mut(&id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            if matches!(j.summary.state.as_str(), "queued" | "running") {
                if let Some(t) = j.task.take() {
                    t.abort();
                }
                j.summary.state = "cancelled".into();
            }
            (j.summary.clone(), j.events.clone())
        };
        let _ = tx.send(pb::JobEvent { id: id.clone(), state: summary.state.clone(), ..Default::default() });
        Ok(Response::new(summary))
    }

    async fn list_jobs(&self, _: Request<pb::ListJobsRequest>) -> Result<Response<pb::JobList>, Status> {
        let jobs = self.state.jobs.lock().expect("lock").values().map(|j| j.summary.clone()).collect();
        Ok(Response::new(pb::JobList { jobs }))
    }

    async fn list_workers(&self, _: Request<pb::ListWorkersRequest>) -> Result<Response<pb::WorkerList>, Status> {
        let workers = self.state.workers.lock().expect("lock").values().cloned().collect();
        Ok(Response::new(pb::WorkerList { workers }))
    }

    async fn register_worker(&self, request: Request<pb::RegisterWorkerRequest>) -> Result<Response<pb::RegisterWorkerReply>, Status> {
        let addr = request.into_inner().addr;
        if addr.parse::<std::net::SocketAddr>().is_err() && !addr.contains(':') {
            return Err(Status::invalid_argument(format!("worker address {addr:?} is not host:port")));
        }
        let mut w = self.state.workers.lock().expect("lock");
        let entry = w.entry(addr.clone()).or_insert_with(|| pb::WorkerInfo { addr: addr.clone(), ..Default::default() });
        entry.alive = true;
        tracing::info!(%addr, "worker registered");
        Ok(Response::new(pb::RegisterWorkerReply {}))
    }
}

/// Serves the coordinator API, health and reflection until `shutdown`.
pub async fn run(listener: tokio::net::TcpListener, mut config: CoordinatorConfig, shutdown: impl std::future::Future<Output = ()>) -> anyhow::Result<()> {
    let (reporter, health) = tonic_health::server::health_reporter();
    let reflection = tonic_reflection::server::Builder::configure().register_encoded_file_descriptor_set(pb::FILE_DESCRIPTOR_SET).build_v1()?;
    let auth = sylva_proto::auth::require(config.token.clone());
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = config.tls.take() {
        builder = builder.tls_config(tls)?;
    }
    let service = CoordinatorService::new(config);
    service.spawn_background();
    reporter.set_serving::<CoordinatorServer<CoordinatorService>>().await;
    builder
        .add_service(health)
        .add_service(tonic::service::interceptor::InterceptedService::new(reflection, auth.clone()))
        .add_service(tonic::service::interceptor::InterceptedService::new(service.into_server(), auth))
        .serve_with_incoming_shutdown(tokio_stream::wrappers::TcpListenerStream::new(listener), shutdown)
        .await?;
    Ok(())
}
