//! The coordinator's gRPC service: a queue of jobs (priority, then
//! submission order), run over the registered workers by the strip farm;
//! progress streamed to watchers; results kept for a retention time and a
//! count and size budget, spilled to disk when large. A restart loses the
//! queue, running jobs and results (clients resubmit; job ids never repeat,
//! since each start draws a random prefix); workers keep their cached scenes
//! and re-register within one period.
//!
//! Trust: a client's submission is checked completely (frame, schedule,
//! scene, sizes) before it is queued; a worker that registers must prove it
//! holds the farm's token before it is sent anything; a worker's reply is
//! checked before use (see [`crate::farm`]).

use crate::farm::{self, FarmEvent, Workers};
use crate::results::{ResultStore, Retention};
use crate::schedule::{ScheduleKind, Strip, scheduler};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::pb::coordinator_server::{Coordinator, CoordinatorServer};
use sylva_proto::sync::lock;
use sylva_scene::SceneLimits;
use sylva_scene::bundle::{self, SceneBundle};
use sylva_scene::film::{reinhard, reinhard_like};
use sylva_scene::frame::FrameSettings;
use sylva_scene::sandbox::clip;
use sylva_scene::sequence::{MAX_FRAMES, View};
use tokio::sync::{Semaphore, broadcast};
use tokio_stream::{Stream, StreamExt};
use tonic::{Request, Response, Status, Streaming};

/// Longest job name accepted, bytes.
pub const MAX_NAME: usize = 256;
/// Longest job id or worker address looked at, bytes: longer ones cannot exist.
pub const MAX_ID: usize = 128;
/// Longest submitter name accepted, bytes.
pub const MAX_SUBMITTER: usize = 64;

/// Milliseconds since the Unix epoch, for listings.
fn unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

/// How the coordinator runs.
#[derive(Debug)]
pub struct CoordinatorConfig {
    /// Jobs rendered at the same time.
    pub max_running: usize,
    /// Largest bundle accepted, bytes.
    pub max_bundle_bytes: u64,
    /// Per-scene caps checked at submit.
    pub limits: SceneLimits,
    /// Bearer token clients must send and workers are sent.
    pub token: Option<String>,
    /// Workers known from the start.
    pub workers: Vec<String>,
    /// Seconds one strip may take.
    pub strip_deadline: Duration,
    /// Time between worker heartbeats.
    pub heartbeat: Duration,
    /// A registered worker not heard from for this long is forgotten.
    pub registration_ttl: Duration,
    /// How long, how many and how large finished jobs are kept.
    pub retention: Retention,
    /// Where large results and scene checks go; removed at shutdown.
    pub work_dir: PathBuf,
    /// Serve Prometheus metrics here.
    pub metrics: Option<tokio::net::TcpListener>,
    /// Serve the web dashboard here.
    pub http: Option<tokio::net::TcpListener>,
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
            limits: SceneLimits::default(),
            token: None,
            workers: Vec::new(),
            strip_deadline: Duration::from_secs(600),
            heartbeat: Duration::from_secs(2),
            registration_ttl: Duration::from_secs(30),
            retention: Retention::default(),
            work_dir: std::env::temp_dir()
                .join(format!("sylva-coordinator-{}", std::process::id())),
            metrics: None,
            http: None,
            tls: None,
            worker_tls: None,
        }
    }
}

struct Job {
    seq: u64,
    spec: pb::JobSpec,
    frame: FrameSettings,
    /// A sequence's views, one per frame; empty: one frame of the scene's view.
    views: Vec<View>,
    schedule: ScheduleKind,
    /// Dropped when the job ends: only queued and running jobs need it.
    bundle: Option<Arc<SceneBundle>>,
    summary: pb::JobSummary,
    events: broadcast::Sender<pb::JobEvent>,
    task: Option<tokio::task::AbortHandle>,
    finished: Option<Instant>,
    live: LiveFrame,
}

/// A frame as the dashboard shows it while (and after) it renders.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct LiveFrame {
    /// Image size.
    pub width: u32,
    pub height: u32,
    /// The newest frame (of a sequence) a strip came back for: the preview
    /// shows its strips over the frames before it.
    pub frame: usize,
    /// Strips in the order they came back or failed.
    pub strips: Vec<LiveStrip>,
    /// 8-bit sRGB, `width × height × 3`, black where no strip is yet;
    /// dropped when the job ends (its result is the image then).
    #[serde(skip)]
    pub preview: Vec<u8>,
}

/// One strip's outcome on one worker.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LiveStrip {
    /// The frame of a sequence (0 for one frame).
    pub frame: usize,
    /// Columns [x0, x1).
    pub x0: u32,
    pub x1: u32,
    /// The worker that rendered (or failed) it.
    pub worker: String,
    /// Render time on the worker, ms (0 when it failed).
    pub ms: f64,
    /// Why it failed; empty when it came back.
    pub error: String,
}

impl LiveFrame {
    fn paint(&mut self, strip: Strip, px: &[[u8; 3]]) {
        let (x0, x1) = strip;
        let w = (x1 - x0) as usize;
        if self.preview.len() != self.width as usize * self.height as usize * 3
            || px.len() != w * self.height as usize
            || x1 > self.width
        {
            return;
        }
        for (y, row) in px.chunks_exact(w).enumerate() {
            let at = 3 * (y * self.width as usize + x0 as usize);
            self.preview[at..at + 3 * w].copy_from_slice(row.as_flattened());
        }
    }
}

/// A worker the coordinator knows.
struct KnownWorker {
    info: pb::WorkerInfo,
    /// Named on the command line: never forgotten.
    named: bool,
    /// Last registration or answered heartbeat.
    seen: Instant,
}

struct State {
    config: CoordinatorConfig,
    metrics: Arc<crate::metrics::Metrics>,
    jobs: Mutex<BTreeMap<String, Job>>,
    results: Mutex<ResultStore>,
    workers: Mutex<BTreeMap<String, KnownWorker>>,
    /// Per-column cost of frames rendered before, by scene and frame shape.
    costs: Mutex<std::collections::HashMap<String, Vec<f64>>>,
    /// This start's random id prefix: ids never repeat across restarts.
    prefix: String,
    next: Mutex<u64>,
    slots: Arc<Semaphore>,
    wake: tokio::sync::Notify,
}

/// The `sylva.v1.Coordinator` service.
#[derive(Clone)]
pub struct CoordinatorService {
    state: Arc<State>,
}

/// Whether a job in `state` has ended (done, failed or cancelled).
pub fn ended(state: &str) -> bool {
    matches!(state, "done" | "failed" | "cancelled")
}

impl CoordinatorService {
    /// A coordinator; call [`CoordinatorService::spawn_background`] to run jobs.
    pub fn new(mut config: CoordinatorConfig) -> Self {
        let metrics_listener = config.metrics.take();
        let http_listener = config.http.take();
        // Named workers count as alive until a heartbeat says otherwise, so a
        // job submitted at once can use them (the farm copes if one is not).
        let workers = config
            .workers
            .iter()
            .map(|a| {
                (
                    a.clone(),
                    KnownWorker {
                        info: pb::WorkerInfo { addr: a.clone(), alive: true, ..Default::default() },
                        named: true,
                        seen: Instant::now(),
                    },
                )
            })
            .collect();
        let slots = Arc::new(Semaphore::new(config.max_running.max(1)));
        let results = ResultStore::new(config.work_dir.join("results"), config.retention);
        let service = Self {
            state: Arc::new(State {
                config,
                metrics: Arc::new(crate::metrics::Metrics::default()),
                jobs: Mutex::new(BTreeMap::new()),
                results: Mutex::new(results),
                workers: Mutex::new(workers),
                costs: Mutex::new(Default::default()),
                prefix: sylva_proto::auth::random_hex(4),
                next: Mutex::new(1),
                slots,
                wake: tokio::sync::Notify::new(),
            }),
        };
        if let Some(l) = metrics_listener {
            let s = service.state.clone();
            tokio::spawn(crate::metrics::serve(l, service.state.metrics.clone(), move || {
                s.gauges()
            }));
        }
        if let Some(l) = http_listener {
            tokio::spawn(crate::dashboard::serve(l, service.clone()));
        }
        service
    }

    /// A job's frame as it renders (strips so far and their preview).
    pub fn live(&self, id: &str) -> Option<LiveFrame> {
        lock(&self.state.jobs).get(id).map(|j| j.live.clone())
    }

    /// Whether `token` is the one this coordinator asks of callers (any, when it asks none).
    pub fn accepts_token(&self, token: Option<&str>) -> bool {
        match &self.state.config.token {
            None => true,
            Some(want) => token.is_some_and(|t| {
                sylva_proto::auth::constant_time_eq(t.as_bytes(), want.as_bytes())
            }),
        }
    }

    /// Whether callers must bring a token.
    pub fn needs_token(&self) -> bool {
        self.state.config.token.is_some()
    }

    /// Starts the scheduler loop and the worker heartbeats.
    pub fn spawn_background(&self) {
        let s = self.state.clone();
        tokio::spawn(async move { s.schedule_loop().await });
        let s = self.state.clone();
        tokio::spawn(async move { s.heartbeat_loop().await });
    }

    /// The tonic server wrapper. Messages are bounded by what the API
    /// carries: bundle chunks of at most 4 MiB and images of at most
    /// 16384² pixels.
    pub fn into_server(self) -> CoordinatorServer<Self> {
        CoordinatorServer::new(self)
            .max_decoding_message_size(8 << 20)
            .max_encoding_message_size(usize::MAX)
    }

    /// Removes what the coordinator wrote on disk.
    pub fn clean_up(&self) {
        let dir = &self.state.config.work_dir;
        if dir.exists()
            && let Err(e) = std::fs::remove_dir_all(dir)
        {
            tracing::warn!(dir = %dir.display(), "cannot remove the work folder: {e}");
        }
    }
}

impl State {
    fn gauges(&self) -> crate::metrics::Gauges {
        let jobs = lock(&self.jobs);
        let workers = lock(&self.workers);
        crate::metrics::Gauges {
            queued: jobs.values().filter(|j| j.summary.state == "queued").count() as u64,
            running: jobs.values().filter(|j| j.summary.state == "running").count() as u64,
            workers_alive: workers.values().filter(|w| w.info.alive).count() as u64,
            workers: workers.len() as u64,
        }
    }

    fn event(&self, id: &str) -> pb::JobEvent {
        let jobs = lock(&self.jobs);
        match jobs.get(id) {
            Some(j) => pb::JobEvent {
                id: id.to_string(),
                state: j.summary.state.clone(),
                strips_done: j.summary.strips_done,
                strips_total: j.summary.strips_total,
                ..Default::default()
            },
            None => pb::JobEvent { id: id.to_string(), ..Default::default() },
        }
    }

    /// Ends a job: its state and reason, its bundle dropped.
    fn finish(&self, id: &str, state: &str, error: Option<String>) {
        let mut jobs = lock(&self.jobs);
        if let Some(j) = jobs.get_mut(id) {
            j.summary.state = state.to_string();
            if let Some(e) = error {
                j.summary.error = e;
            }
            j.bundle = None;
            j.task = None;
            j.finished = Some(Instant::now());
            j.summary.finished_unix_ms = unix_ms();
            j.live.preview = Vec::new();
        }
    }

    /// Lets go of a finished job's event channel once its last event is
    /// sent: watchers that come later are answered from its summary, and
    /// the channel's buffer would otherwise stay for the job's retention.
    fn close_events(&self, id: &str) {
        if let Some(j) = lock(&self.jobs).get_mut(id) {
            j.events = broadcast::channel(1).0;
        }
    }

    /// Starts queued jobs, best first, as running slots free up.
    async fn schedule_loop(self: Arc<Self>) {
        loop {
            let permit = self.slots.clone().acquire_owned().await.expect("semaphore open");
            let next = loop {
                let pick = {
                    let jobs = lock(&self.jobs);
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
            if let Some(j) = lock(&self.jobs).get_mut(&next) {
                j.summary.state = "running".into();
                j.summary.started_unix_ms = unix_ms();
            }
            let s = self.clone();
            let id = next.clone();
            let handle = tokio::spawn(async move { s.run_job(&id).await });
            if let Some(j) = lock(&self.jobs).get_mut(&next) {
                j.task = Some(handle.abort_handle());
            }
            // Whatever happens to the job's task, its slot comes back and a
            // job left "running" by a panic is failed with the reason.
            let s = self.clone();
            tokio::spawn(async move {
                if let Err(e) = handle.await
                    && e.is_panic()
                {
                    let why = "the coordinator hit an internal error running this job";
                    tracing::error!(id = %next, "job task panicked: {e}");
                    s.finish(&next, "failed", Some(why.into()));
                    let mut ev = s.event(&next);
                    ev.message = why.into();
                    if let Some(tx) = lock(&s.jobs).get(&next).map(|j| j.events.clone()) {
                        let _ = tx.send(ev);
                    }
                    s.close_events(&next);
                }
                drop(permit);
            });
        }
    }

    async fn run_job(self: &Arc<Self>, id: &str) {
        let Some((frame, views, schedule, bundle, tx)) = ({
            let jobs = lock(&self.jobs);
            jobs.get(id).and_then(|j| {
                Some((j.frame, j.views.clone(), j.schedule, j.bundle.clone()?, j.events.clone()))
            })
        }) else {
            return;
        };
        let _ = tx.send(self.event(id));
        let fail = |why: String| {
            self.finish(id, "failed", Some(why.clone()));
            let mut ev = self.event(id);
            ev.message = why;
            let _ = tx.send(ev);
            self.close_events(id);
        };
        let addrs: Vec<String> = lock(&self.workers)
            .values()
            .filter(|w| w.info.alive)
            .map(|w| w.info.addr.clone())
            .collect();
        if addrs.is_empty() {
            return fail("no worker is registered and alive: start workers with --coordinator, or the coordinator with --workers".into());
        }
        let frames: Vec<FrameSettings> = if views.is_empty() {
            vec![frame]
        } else {
            views.iter().map(|v| FrameSettings { view: *v, ..frame }).collect()
        };
        // A frame seen before is cut by its measured cost; a new one by
        // guided self-scheduling alone, whose shrinking strips still let
        // the last ones finish close together.
        let cost_key = format!(
            "{}/{}x{}/{}/{:?}/{:?}",
            bundle.hash, frame.width, frame.height, frame.spp, frame.lighting, frame.accel
        );
        let cost = lock(&self.costs).get(&cost_key).cloned().unwrap_or_default();
        let cost_source = if cost.is_empty() {
            "uniform (first frame of this scene and size)"
        } else {
            "measured on the previous frame"
        };
        // A sequence with at least as many frames as workers renders whole
        // frames side by side (no strip is worth cutting); a shorter one
        // cuts each frame for its share of the workers.
        let plans: Vec<Vec<Strip>> = if frames.len() > 1 && frames.len() >= addrs.len() {
            vec![vec![(0, frame.width)]; frames.len()]
        } else {
            let plan = scheduler(schedule).plan(
                frame.width,
                addrs.len().div_ceil(frames.len()).max(1),
                &cost,
            );
            vec![plan; frames.len()]
        };
        let total: usize = plans.iter().map(Vec::len).sum();
        if let Some(j) = lock(&self.jobs).get_mut(id) {
            j.summary.strips_total = total as u32;
            j.live = LiveFrame {
                width: frame.width,
                height: frame.height,
                frame: 0,
                strips: Vec::new(),
                preview: vec![0; frame.width as usize * frame.height as usize * 3],
            };
        }
        let span = tracing::info_span!("job", %id, frames = frames.len(), strips = total, workers = addrs.len());
        let _g = span.enter();
        let (me, jid, tx2) = (self.clone(), id.to_string(), tx.clone());
        let left: Mutex<Vec<usize>> = Mutex::new(plans.iter().map(Vec::len).collect());
        let started = Instant::now();
        let result = farm::render_frames(
            &Workers { addrs: addrs.clone(), token: self.config.token.clone(), tls: self.config.worker_tls.clone() },
            &bundle,
            &frames,
            plans,
            self.config.strip_deadline,
            move |e| {
                let mut ev = me.event(&jid);
                ev.state = "running".into();
                match e {
                    FarmEvent::StripDone { frame, worker, ms, bytes, strip, preview } => {
                        me.metrics.strip_done(ms / 1e3, bytes);
                        if let Some(w) = lock(&me.workers).get_mut(&worker) {
                            w.info.strips_done += 1;
                        }
                        let frame_done = {
                            let mut left = lock(&left);
                            left[frame] -= 1;
                            left[frame] == 0
                        };
                        let mut jobs = lock(&me.jobs);
                        if let Some(j) = jobs.get_mut(&jid) {
                            j.summary.strips_done += 1;
                            j.summary.frames_done += frame_done as u32;
                            ev.strips_done = j.summary.strips_done;
                            j.live.frame = j.live.frame.max(frame);
                            j.live.paint(strip, &preview);
                            j.live.strips.push(LiveStrip { frame, x0: strip.0, x1: strip.1, worker: worker.clone(), ms, error: String::new() });
                        }
                        ev.worker = worker;
                        ev.strip_ms = ms;
                        ev.frame = frame as u32;
                    }
                    FarmEvent::StripRetried { frame, worker, error, strip } => {
                        me.metrics.strip_retried();
                        if let Some(w) = lock(&me.workers).get_mut(&worker) {
                            w.info.strips_failed += 1;
                        }
                        if let Some(j) = lock(&me.jobs).get_mut(&jid) {
                            j.summary.retries += 1;
                            j.live.strips.push(LiveStrip { frame, x0: strip.0, x1: strip.1, worker: worker.clone(), ms: 0.0, error: clip(&error) });
                        }
                        ev.message = format!("strip re-queued from {worker}: {error}");
                        ev.frame = frame as u32;
                    }
                    FarmEvent::BundleSent { bytes, .. } => {
                        me.metrics.bundle_sent(bytes);
                        return;
                    }
                    FarmEvent::WorkerDropped { worker, error } => ev.message = format!("worker {worker} dropped: {error}"),
                    FarmEvent::PreparedShared(p) => {
                        // Not a notice for clients (their `message` is for
                        // failures and retries): the job's stats carry it.
                        tracing::info!(job = %jid, from = %p.from, to = p.to.len(), bytes = p.bytes, prepare_ms = p.prepare_ms, share_ms = p.share_ms, "scene prepared once and shared");
                        return;
                    }
                }
                let _ = tx2.send(ev);
            },
        )
        .await;
        drop(bundle);
        let rendered = match result {
            Ok(f) => f,
            Err(e) => return fail(format!("{e:#}")),
        };
        // Tone mapping and encoding are CPU work: off the async runtime.
        let images: Vec<sylva_scene::film::HdrImage> =
            rendered.iter().map(|f| f.image.clone()).collect();
        // A sequence keeps one exposure (its middle frame's), so a sun
        // sweep shows the light change rather than the tone mapper's.
        let encoded = tokio::task::spawn_blocking(move || {
            let exposure = reinhard(&images[images.len() / 2], 0.18).1;
            images
                .iter()
                .map(|image| {
                    let (ldr, tone) = if images.len() == 1 {
                        reinhard(image, 0.18)
                    } else {
                        (reinhard_like(image, &exposure), exposure)
                    };
                    Ok((encode_png(image.width, image.height, &ldr)?, encode_exr(image)?, tone))
                })
                .collect::<anyhow::Result<Vec<_>>>()
        })
        .await;
        let encoded = match encoded {
            Ok(Ok(e)) => e,
            Ok(Err(e)) => return fail(format!("the frame could not be encoded: {e:#}")),
            Err(e) => return fail(format!("the frame could not be encoded: {e}")),
        };
        let frame_ms = started.elapsed().as_secs_f64() * 1e3;
        {
            let mut costs = lock(&self.costs);
            if costs.len() >= 1024 {
                costs.clear();
            }
            if rendered[0].strip_times.len() > 1 {
                costs.insert(
                    cost_key,
                    crate::schedule::column_cost(frame.width, &rendered[0].strip_times),
                );
            }
        }
        let per_frame = |f: &crate::executor::RenderedFrame,
                         tone: &sylva_scene::film::ToneMapStats,
                         ms: f64| {
            serde_json::json!({
                "strips": f.strip_times.iter().map(|t| serde_json::json!({ "x0": t.strip.0, "x1": t.strip.1, "render_ms": t.render_ms, "rpc_ms": t.call_ms })).collect::<Vec<_>>(),
                "rays": { "primary": f.rays.primary, "shadow": f.rays.shadow, "transparent_passed": f.rays.transparent, "mrays_per_second": f.rays.traced() as f64 / (ms / 1e3) / 1e6 },
                "coverage": f.coverage.iter().map(|&c| c as f64).sum::<f64>() / f.coverage.len().max(1) as f64,
                "tone_map": tone,
            })
        };
        let mut stats = serde_json::json!({
            "schedule": schedule,
            "strip_cost": cost_source,
            "frame_ms": frame_ms,
            "upload_ms": rendered[0].upload_ms,
            "prepared_once": rendered[0].prepared,
            "workers": rendered[0].workers,
        });
        if views.is_empty() {
            if let (Some(s), serde_json::Value::Object(f)) =
                (stats.as_object_mut(), per_frame(&rendered[0], &encoded[0].2, frame_ms))
            {
                s.extend(f);
            }
        } else {
            stats["sequence"] = serde_json::json!({
                "frames": rendered.len(),
                "ms_per_frame": frame_ms / rendered.len() as f64,
                "whole_frames_in_parallel": rendered[0].strip_times.len() == 1,
                "per_frame": rendered.iter().zip(&encoded).map(|(f, e)| per_frame(f, &e.2, frame_ms / rendered.len() as f64)).collect::<Vec<_>>(),
            });
        }
        let stored = lock(&self.results)
            .put(id, encoded.into_iter().map(|(png, exr, _)| (png, exr)).collect());
        if let Err(e) = stored {
            return fail(format!("the result could not be stored: {e:#}"));
        }
        self.finish(id, "done", None);
        let mut ev = self.event(id);
        ev.stats_json = stats.to_string();
        let _ = tx.send(ev);
        self.close_events(id);
    }

    /// Polls every worker's status at once; a worker that does not answer
    /// is not given new jobs until it does; registrations not renewed
    /// within the TTL are forgotten, and so are finished jobs past their
    /// retention.
    async fn heartbeat_loop(self: Arc<Self>) {
        loop {
            let addrs: Vec<String> = lock(&self.workers).keys().cloned().collect();
            let config = &self.config;
            let polls = addrs.into_iter().map(|a| async move {
                let status = async {
                    let mut c = farm::connect(&a, config.token.clone(), config.worker_tls.as_ref())
                        .await
                        .ok()?;
                    let mut req = Request::new(pb::StatusRequest {});
                    req.set_timeout(Duration::from_secs(5));
                    c.status(req).await.ok().map(|r| r.into_inner())
                }
                .await;
                (a, status)
            });
            for (a, status) in futures_util::future::join_all(polls).await {
                if let Some(w) = lock(&self.workers).get_mut(&a) {
                    match status {
                        Some(s) => {
                            w.info.alive = true;
                            w.seen = Instant::now();
                            // A worker's reply is bounded before it is kept and listed.
                            w.info.adapter = clip(&s.adapter);
                            w.info.gpu_memory_bytes = s.gpu_memory_bytes;
                            w.info.cached_scenes =
                                s.cached_scenes.iter().take(1024).map(|h| clip(h)).collect();
                            w.info.busy_strips = s.busy_strips;
                        }
                        None => w.info.alive = false,
                    }
                }
            }
            let ttl = self.config.registration_ttl;
            lock(&self.workers).retain(|addr, w| {
                let keep = w.named || w.seen.elapsed() < ttl;
                if !keep {
                    tracing::info!(%addr, "forgot a worker whose registration expired");
                }
                keep
            });
            self.sweep();
            tokio::time::sleep(self.config.heartbeat).await;
        }
    }

    /// Forgets finished jobs past the retention time or beyond the count,
    /// with their results.
    fn sweep(&self) {
        let r = self.config.retention;
        let mut jobs = lock(&self.jobs);
        let mut finished: Vec<(Instant, String)> =
            jobs.iter().filter_map(|(id, j)| j.finished.map(|t| (t, id.clone()))).collect();
        finished.sort();
        let over = finished.len().saturating_sub(r.max_jobs);
        let mut results = lock(&self.results);
        for (i, (t, id)) in finished.iter().enumerate() {
            if i < over || t.elapsed() > r.keep {
                jobs.remove(id);
                results.remove(id);
            }
        }
    }

    /// Checks that the worker at `addr` holds the farm's token: it must
    /// answer a fresh nonce with the keyed hash only a token holder can make.
    async fn verify_worker(&self, addr: &str) -> Result<(), Status> {
        let refused =
            |why: &str| Status::permission_denied(format!("worker {}: {why}", clip(addr)));
        let ch = sylva_proto::tls::connect(
            addr,
            self.config.worker_tls.as_ref(),
            Duration::from_secs(5),
        )
        .await
        .map_err(|_| refused("cannot be reached at that address from the coordinator"))?;
        let nonce = sylva_proto::auth::random_bytes(32);
        let mut c = pb::worker_identity_client::WorkerIdentityClient::new(ch);
        let mut req = Request::new(pb::ProveRequest { nonce: nonce.clone() });
        req.set_timeout(Duration::from_secs(5));
        let proof = c
            .prove(req)
            .await
            .map_err(|_| refused("does not answer the identity check (is it a Sylva worker?)"))?
            .into_inner()
            .proof;
        if !sylva_proto::auth::check_proof(self.config.token.as_deref(), &nonce, &proof) {
            return Err(refused(
                "could not prove it holds the farm's token; start it with the coordinator's --token",
            ));
        }
        Ok(())
    }
}

fn encode_png(w: u32, h: u32, px: &[[u8; 3]]) -> anyhow::Result<Vec<u8>> {
    let img = image::RgbImage::from_raw(w, h, px.iter().flatten().copied().collect())
        .ok_or_else(|| anyhow::anyhow!("image size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)?;
    Ok(out.into_inner())
}

fn encode_exr(img: &sylva_scene::film::HdrImage) -> anyhow::Result<Vec<u8>> {
    let flat: Vec<f32> = img.pixels.iter().flatten().copied().collect();
    let buf = image::Rgb32FImage::from_raw(img.width, img.height, flat)
        .ok_or_else(|| anyhow::anyhow!("image size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    image::DynamicImage::ImageRgb32F(buf).write_to(&mut out, image::ImageFormat::OpenExr)?;
    Ok(out.into_inner())
}

/// A job id as clients send it: one longer than any id can be is not found
/// (and not echoed back).
fn job_id(id: &str) -> Result<&str, Status> {
    if id.len() > MAX_ID {
        return Err(Status::not_found("no such job"));
    }
    Ok(id)
}

type EventStream = Pin<Box<dyn Stream<Item = Result<pb::JobEvent, Status>> + Send>>;

/// The schedule a wire number names.
fn schedule_from_wire(v: i32) -> Result<ScheduleKind, Status> {
    match pb::Schedule::try_from(v) {
        Ok(pb::Schedule::Dynamic) => Ok(ScheduleKind::Dynamic),
        Ok(pb::Schedule::Static) => Ok(ScheduleKind::Static),
        Err(_) => Err(Status::invalid_argument(format!("schedule {v}: static or dynamic"))),
    }
}

#[tonic::async_trait]
impl Coordinator for CoordinatorService {
    async fn submit_job(
        &self,
        request: Request<Streaming<pb::SubmitChunk>>,
    ) -> Result<Response<pb::JobId>, Status> {
        let remote = request.remote_addr();
        let mut stream = request.into_inner();
        let first =
            stream.next().await.ok_or_else(|| Status::invalid_argument("empty submission"))??;
        let spec = first
            .spec
            .ok_or_else(|| Status::invalid_argument("the first message must carry the job spec"))?;
        let frame = FrameSettings::try_from(
            spec.frame
                .as_ref()
                .ok_or_else(|| Status::invalid_argument("job spec without frame settings"))?,
        )?;
        let schedule = schedule_from_wire(spec.schedule)?;
        if spec.views.len() > MAX_FRAMES as usize {
            return Err(Status::invalid_argument(format!(
                "a sequence of {} frames: at most {MAX_FRAMES}",
                spec.views.len()
            )));
        }
        let views = spec
            .views
            .iter()
            .enumerate()
            .map(|(i, v)| {
                View::try_from(v)
                    .map_err(|e| Status::invalid_argument(format!("frame {i}: {}", e.message())))
            })
            .collect::<Result<Vec<View>, Status>>()?;
        if spec.name.len() > MAX_NAME {
            return Err(Status::invalid_argument(format!(
                "job name of {} bytes: at most {MAX_NAME}",
                spec.name.len()
            )));
        }
        if spec.submitter.len() > MAX_SUBMITTER || spec.submitter.chars().any(char::is_control) {
            return Err(Status::invalid_argument(format!(
                "submitter name: at most {MAX_SUBMITTER} bytes, no control characters"
            )));
        }
        let from = remote.map(|a| a.ip().to_string()).unwrap_or_else(|| "local".into());
        let submitter =
            if spec.submitter.is_empty() { from } else { format!("{}@{from}", spec.submitter) };
        let hash = first.hash.to_ascii_lowercase();
        if hash.len() != 64 || !hash.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(Status::invalid_argument(format!(
                "hash {:?} is not a 64-digit hex BLAKE3 hash",
                clip(&first.hash)
            )));
        }
        let limit = self.state.config.max_bundle_bytes;
        if first.total_size > limit {
            return Err(Status::resource_exhausted(format!(
                "bundle of {} bytes is over the limit of {limit} bytes",
                first.total_size
            )));
        }
        // Counted as the bytes arrive, against the declared size (itself
        // within the limit); nothing is reserved from the claim.
        let mut bytes = first.data;
        if bytes.len() as u64 > first.total_size {
            return Err(Status::invalid_argument("upload is longer than its declared size"));
        }
        while let Some(c) = stream.next().await {
            bytes.extend_from_slice(&c?.data);
            if bytes.len() as u64 > first.total_size {
                return Err(Status::invalid_argument("upload is longer than its declared size"));
            }
        }
        if (bytes.len() as u64) != first.total_size {
            return Err(Status::invalid_argument(format!(
                "truncated upload: {} of {} bytes",
                bytes.len(),
                first.total_size
            )));
        }
        if bundle::hash_of(&bytes) != hash {
            return Err(Status::invalid_argument("the bundle's bytes do not match its hash"));
        }
        // Check the scene here, so a bad one fails its client, not a worker;
        // its files are unpacked for the check alone and removed after it.
        let seq = {
            let mut n = lock(&self.state.next);
            *n += 1;
            *n - 1
        };
        let id = format!("job-{}-{seq}", self.state.prefix);
        let dir = self.state.config.work_dir.join("check").join(&id);
        let (check, limits) = (bytes.clone(), self.state.config.limits);
        let checked = tokio::task::spawn_blocking(move || {
            let r = bundle::unpack_with(&check, &dir, &limits).map(|_| ());
            let _ = std::fs::remove_dir_all(&dir);
            r
        })
        .await
        .map_err(|_| Status::internal("the scene check failed unexpectedly"))?;
        checked.map_err(|e| Status::invalid_argument(format!("{e:#}")))?;
        let (tx, _) = broadcast::channel(256);
        let summary = pb::JobSummary {
            id: id.clone(),
            state: "queued".into(),
            name: spec.name.clone(),
            priority: spec.priority,
            submitter,
            submitted_unix_ms: unix_ms(),
            frames: views.len().max(1) as u32,
            ..Default::default()
        };
        lock(&self.state.jobs).insert(
            id.clone(),
            Job {
                seq,
                spec,
                frame,
                views,
                schedule,
                bundle: Some(Arc::new(SceneBundle { bytes, hash })),
                summary,
                events: tx,
                task: None,
                finished: None,
                live: LiveFrame::default(),
            },
        );
        self.state.wake.notify_one();
        tracing::info!(%id, "job queued");
        Ok(Response::new(pb::JobId { id }))
    }

    type WatchJobStream = EventStream;

    async fn watch_job(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<Self::WatchJobStream>, Status> {
        let id = request.into_inner().id;
        let id = job_id(&id)?.to_string();
        let (mut rx, current) = {
            let jobs = lock(&self.state.jobs);
            let j = jobs.get(&id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            (j.events.subscribe(), j.summary.clone())
        };
        let (tx, out) = tokio::sync::mpsc::channel(64);
        let state = self.state.clone();
        tokio::spawn(async move {
            let first = pb::JobEvent {
                id: current.id.clone(),
                state: current.state.clone(),
                strips_done: current.strips_done,
                strips_total: current.strips_total,
                message: current.error.clone(),
                ..Default::default()
            };
            if tx.send(Ok(first)).await.is_err() || ended(&current.state) {
                return;
            }
            loop {
                let ev = match rx.recv().await {
                    Ok(ev) => ev,
                    // A slow watcher missed events: it gets the job's state
                    // now and goes on, rather than a stream that just ends.
                    Err(broadcast::error::RecvError::Lagged(n)) => {
                        let mut ev = state.event(&id);
                        ev.message = format!(
                            "{n} progress events skipped: this client reads slower than strips finish"
                        );
                        if ended(&ev.state) {
                            ev.message = lock(&state.jobs)
                                .get(&id)
                                .map(|j| j.summary.error.clone())
                                .unwrap_or_default();
                        }
                        ev
                    }
                    Err(broadcast::error::RecvError::Closed) => break,
                };
                let end = ended(&ev.state);
                // A vanished client ends the forwarding.
                if tx.send(Ok(ev)).await.is_err() || end {
                    break;
                }
            }
        });
        Ok(Response::new(Box::pin(tokio_stream::wrappers::ReceiverStream::new(out))))
    }

    async fn fetch_result(
        &self,
        request: Request<pb::FetchRequest>,
    ) -> Result<Response<pb::FetchReply>, Status> {
        let r = request.into_inner();
        let id = job_id(&r.id)?;
        let format = match r.format.as_str() {
            "" | "png" => "png",
            "exr" => "exr",
            o => return Err(Status::invalid_argument(format!("format {:?}: png or exr", clip(o)))),
        };
        {
            let jobs = lock(&self.state.jobs);
            let j = jobs.get(id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            if j.summary.state != "done" {
                return Err(Status::failed_precondition(format!(
                    "job {id} is {}",
                    j.summary.state
                )));
            }
            if r.frame >= j.summary.frames.max(1) {
                return Err(Status::out_of_range(format!(
                    "job {id} has {} frame(s), from 0; no frame {}",
                    j.summary.frames.max(1),
                    r.frame
                )));
            }
        }
        let stored = lock(&self.state.results).get(id, r.frame as usize, format);
        let data = match stored {
            Some(s) => tokio::task::spawn_blocking(move || s.read())
                .await
                .map_err(|e| Status::internal(e.to_string()))?
                .map_err(|e| Status::internal(format!("the stored result cannot be read: {e}")))?,
            None => return Err(Status::not_found(format!("job {id}'s result is no longer kept"))),
        };
        Ok(Response::new(pb::FetchReply { data, format: format.into() }))
    }

    async fn cancel_job(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<pb::JobSummary>, Status> {
        let id = request.into_inner().id;
        let id = job_id(&id)?;
        let (summary, tx) = {
            let mut jobs = lock(&self.state.jobs);
            let j = jobs.get_mut(id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            if matches!(j.summary.state.as_str(), "queued" | "running") {
                if let Some(t) = j.task.take() {
                    t.abort();
                }
                j.summary.state = "cancelled".into();
                j.bundle = None;
                j.finished = Some(Instant::now());
                j.summary.finished_unix_ms = unix_ms();
                j.live.preview = Vec::new();
            }
            (j.summary.clone(), j.events.clone())
        };
        let _ = tx.send(pb::JobEvent {
            id: id.to_string(),
            state: summary.state.clone(),
            strips_done: summary.strips_done,
            strips_total: summary.strips_total,
            ..Default::default()
        });
        if ended(&summary.state) {
            self.state.close_events(id);
        }
        Ok(Response::new(summary))
    }

    async fn list_jobs(
        &self,
        _: Request<pb::ListJobsRequest>,
    ) -> Result<Response<pb::JobList>, Status> {
        let jobs = lock(&self.state.jobs).values().map(|j| j.summary.clone()).collect();
        Ok(Response::new(pb::JobList { jobs }))
    }

    async fn set_priority(
        &self,
        request: Request<pb::SetPriorityRequest>,
    ) -> Result<Response<pb::JobSummary>, Status> {
        let r = request.into_inner();
        let id = job_id(&r.id)?;
        let summary = {
            let mut jobs = lock(&self.state.jobs);
            let j = jobs.get_mut(id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            j.spec.priority = r.priority;
            j.summary.priority = r.priority;
            j.summary.clone()
        };
        tracing::info!(%id, priority = r.priority, "job re-prioritised");
        Ok(Response::new(summary))
    }

    async fn list_workers(
        &self,
        _: Request<pb::ListWorkersRequest>,
    ) -> Result<Response<pb::WorkerList>, Status> {
        let workers = lock(&self.state.workers).values().map(|w| w.info.clone()).collect();
        Ok(Response::new(pb::WorkerList { workers }))
    }

    async fn register_worker(
        &self,
        request: Request<pb::RegisterWorkerRequest>,
    ) -> Result<Response<pb::RegisterWorkerReply>, Status> {
        let addr = request.into_inner().addr;
        if addr.len() > MAX_ID
            || addr.parse::<std::net::SocketAddr>().is_err() && !addr.contains(':')
        {
            return Err(Status::invalid_argument(format!(
                "worker address {:?} is not host:port",
                clip(&addr)
            )));
        }
        let known = lock(&self.state.workers).get(&addr).is_some_and(|w| w.info.alive);
        if !known {
            // Nothing — not the token, not a bundle — goes to an address
            // before it proves it is one of the farm's workers.
            self.state.verify_worker(&addr).await?;
        }
        let mut w = lock(&self.state.workers);
        let entry = w.entry(addr.clone()).or_insert_with(|| KnownWorker {
            info: pb::WorkerInfo { addr: addr.clone(), ..Default::default() },
            named: false,
            seen: Instant::now(),
        });
        entry.info.alive = true;
        entry.seen = Instant::now();
        if !known {
            tracing::info!(%addr, "worker registered");
        }
        Ok(Response::new(pb::RegisterWorkerReply {}))
    }
}

/// Serves the coordinator API, health and reflection until `shutdown`, then
/// removes what it wrote on disk.
pub async fn run(
    listener: tokio::net::TcpListener,
    mut config: CoordinatorConfig,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let (reporter, health) = tonic_health::server::health_reporter();
    let (reflection, reflection_alpha) = sylva_proto::reflection(&["sylva.v1.Coordinator"])?;
    let auth = sylva_proto::auth::require(config.token.clone());
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = config.tls.take() {
        builder = builder.tls_config(tls)?;
    }
    let service = CoordinatorService::new(config);
    service.spawn_background();
    reporter.set_serving::<CoordinatorServer<CoordinatorService>>().await;
    let served = builder
        .add_service(health)
        .add_service(tonic::service::interceptor::InterceptedService::new(reflection, auth.clone()))
        .add_service(tonic::service::interceptor::InterceptedService::new(
            reflection_alpha,
            auth.clone(),
        ))
        .add_service(tonic::service::interceptor::InterceptedService::new(
            service.clone().into_server(),
            auth,
        ))
        .serve_with_incoming_shutdown(
            tokio_stream::wrappers::TcpListenerStream::new(listener),
            shutdown,
        )
        .await;
    service.clean_up();
    served?;
    Ok(())
}
