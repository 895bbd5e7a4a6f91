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
//!
//! By resource, as Flamenco's API is split: [`jobs`] (submit, watch,
//! fetch, cancel, list, priority), [`workers`] (registration, heartbeats,
//! listing), the `queue` that starts jobs, one job's `run` on the farm
//! and its [`stats`], the [`live`] view the dashboard reads, and the job
//! [`state`] machine; `grpc` hands each call of the API to its resource.

mod grpc;
pub mod jobs;
pub mod live;
mod queue;
mod run;
pub mod state;
pub mod stats;
pub mod workers;

pub use live::{LiveFrame, LiveStrip};
pub use state::{JobState, wire_ended, wire_name};
use workers::KnownWorker;

use crate::farm::{self, FarmEvent, Workers};
use crate::results::{ResultStore, Retention};
use crate::schedule::{ScheduleKind, Strip, scheduler};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::pb::coordinator_server::CoordinatorServer;
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

/// Whether `c` may not appear in a job's name or submitter: a control
/// character (an escape sequence retitles or clears a terminal that
/// prints it) or a bidirectional formatting character (U+202E turns the
/// rest of a listing's row around).
pub fn unprintable(c: char) -> bool {
    c.is_control()
        || matches!(c, '\u{061C}' | '\u{200E}' | '\u{200F}' | '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}')
}

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
    /// Where it is in its life; changed only through [`Job::set_state`].
    state: JobState,
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
    /// What the farm last said it is doing (a watcher that joins late
    /// hears it first).
    stage: String,
}

impl Job {
    /// Moves the job to `to`, if its state machine allows it; the summary
    /// clients see follows.
    fn set_state(&mut self, to: JobState) -> Result<(), state::Transition> {
        self.state = self.state.to(to)?;
        self.summary.state = self.state.to_wire();
        Ok(())
    }
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
            queued: jobs.values().filter(|j| j.state == JobState::Queued).count() as u64,
            running: jobs.values().filter(|j| j.state == JobState::Running).count() as u64,
            workers_alive: workers.values().filter(|w| w.info.alive).count() as u64,
            workers: workers.len() as u64,
        }
    }

    fn event(&self, id: &str) -> pb::JobEvent {
        let jobs = lock(&self.jobs);
        match jobs.get(id) {
            Some(j) => pb::JobEvent {
                id: id.to_string(),
                state: j.summary.state,
                strips_done: j.summary.strips_done,
                strips_total: j.summary.strips_total,
                ..Default::default()
            },
            None => pb::JobEvent { id: id.to_string(), ..Default::default() },
        }
    }
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
