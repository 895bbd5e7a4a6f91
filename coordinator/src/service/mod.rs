//! The coordinator's gRPC service: a queue of jobs (priority, then
//! submission order), run over the registered workers by the strip farm;
//! progress streamed to watchers; results kept for a retention time and a
//! count, on disk. The queue is durable ([`crate::store`]): jobs, their
//! bundles, finished frames and strips are written before anyone is told of
//! them, so a coordinator killed at any moment and started again on the
//! same state folder resumes its queued and running jobs where they were,
//! still serves finished results, and never hands out an id twice. Workers
//! keep their cached scenes and re-register within one period.
//!
//! Trust: a client's submission is checked completely (frame, schedule,
//! scene, sizes) before it is queued; a worker that registers must prove it
//! holds the farm's token before it is sent anything; a worker's reply is
//! checked before use (see [`crate::farm`]).
//!
//! By resource, as Flamenco's API is split: [`jobs`] (submit, watch,
//! fetch, cancel, requeue, list, priority), [`workers`] (registration, heartbeats,
//! listing), the `queue` that starts jobs, one job's `run` on the farm
//! and its [`stats`], and the [`live`] view the dashboard reads; `grpc`
//! hands each call of the API to its resource. A job's states and their
//! transitions are [`crate::job_state`]'s, below the service.

mod grpc;
pub mod jobs;
pub mod live;
mod owed;
mod queue;
mod run;
pub mod stats;
pub mod workers;

pub use live::{LiveFrame, LiveStrip};
use workers::KnownWorker;

use crate::access::{Access, Caller, Role};
use crate::job_state::{JobState, Transition};
use crate::results::Retention;
use crate::schedule::ScheduleKind;
use crate::store::Store;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::pb::coordinator_server::CoordinatorServer;
use sylva_proto::sync::lock;
use sylva_scene::SceneLimits;
use sylva_scene::frame::FrameSettings;
use sylva_scene::sequence::View;
use tokio::sync::{Semaphore, broadcast};
use tokio_stream::Stream;
use tonic::{Request, Status};

/// Longest job name accepted, bytes.
pub const MAX_NAME: usize = 256;
/// Longest job id or worker address looked at, bytes: longer ones cannot exist.
pub const MAX_ID: usize = 128;
/// Longest submitter name accepted, bytes.
pub const MAX_SUBMITTER: usize = 64;

/// Whether `c` may not appear in a job's name or submitter.
pub use sylva_scene::sandbox::unprintable;

/// Milliseconds since the Unix epoch, for listings.
fn unix_ms() -> u64 {
    crate::store::now_ms() as u64
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
    /// How long and how many finished jobs are kept.
    pub retention: Retention,
    /// Where the database (unless `database` names another), bundles and
    /// results live.
    pub state_dir: PathBuf,
    /// Remove the state folder at shutdown: a coordinator for one command.
    pub ephemeral: bool,
    /// The database's URL (`sqlite://…`, `postgres://…`); `None`: SQLite
    /// in the state folder.
    pub database: Option<String>,
    /// Most pixels one job may render, all frames together.
    pub max_job_pixels: u64,
    /// Most bytes the results of all kept jobs may take on disk.
    pub results_disk_bytes: u64,
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
            limits: SceneLimits::default(),
            token: None,
            workers: Vec::new(),
            strip_deadline: Duration::from_secs(600),
            heartbeat: Duration::from_secs(2),
            registration_ttl: Duration::from_secs(30),
            retention: Retention::default(),
            state_dir: std::env::temp_dir()
                .join(format!("sylva-coordinator-{}", std::process::id())),
            ephemeral: true,
            database: None,
            max_job_pixels: 1 << 30,
            results_disk_bytes: 32 << 30,
            metrics: None,
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
    /// Its scene bundle's hash: the bundle is a file of the state folder
    /// while the job is queued or running, and after it failed or was
    /// cancelled (to be requeued) until it is forgotten.
    bundle_hash: String,
    summary: pb::JobSummary,
    events: broadcast::Sender<pb::JobEvent>,
    task: Option<tokio::task::AbortHandle>,
    finished: Option<Instant>,
    live: LiveFrame,
    /// What the farm last said it is doing (a watcher that joins late
    /// hears it first).
    stage: String,
    /// When its first strip came back, and the strips done then: the
    /// rate of the rest, for the estimate of time left.
    first_strip: Option<(Instant, u32)>,
    /// Bytes its results may take on disk (its estimate until it is done).
    reserved: u64,
    /// Its figures once done: a watcher that comes after the end hears
    /// them in its first event.
    stats_json: String,
    /// Whether its bundle is kept for a requeue once it failed or was
    /// cancelled (only a submitter's latest [`KEPT_FOR_REQUEUE`] are).
    kept: bool,
    /// Whether it was requeued already (once is enough: a second click
    /// makes no second job).
    requeued: bool,
}

/// Failed or cancelled jobs per submitter whose bundles are kept for a
/// requeue: a submitter who submits and cancels in a loop fills no disk.
pub const KEPT_FOR_REQUEUE: usize = 4;

impl Job {
    /// A job just taken, waiting for a slot: `id` and `seq` from the
    /// store's counter, its spec already checked into `frame`, its
    /// schedule and views.
    fn queued(
        seq: u64,
        id: String,
        spec: pb::JobSpec,
        (frame, schedule, views): (FrameSettings, ScheduleKind, Vec<View>),
        bundle_hash: String,
        submitter: String,
        reserved: u64,
    ) -> Job {
        let summary = pb::JobSummary {
            id,
            state: JobState::Queued.to_wire(),
            name: spec.name.clone(),
            priority: spec.priority,
            submitter,
            submitted_unix_ms: unix_ms(),
            frames: views.len().max(1) as u32,
            ..Default::default()
        };
        Job {
            seq,
            state: JobState::Queued,
            spec,
            frame,
            views,
            schedule,
            bundle_hash,
            summary,
            events: broadcast::channel(256).0,
            task: None,
            finished: None,
            live: LiveFrame::default(),
            stage: String::new(),
            first_strip: None,
            reserved,
            stats_json: String::new(),
            kept: true,
            requeued: false,
        }
    }

    /// Moves the job to `to`, if its state machine allows it; the summary
    /// clients see follows.
    fn set_state(&mut self, to: JobState) -> Result<(), Transition> {
        self.state = self.state.to(to)?;
        self.summary.state = self.state.to_wire();
        if self.state.ended() {
            self.summary.stage.clear();
            self.summary.eta_ms = 0;
        }
        Ok(())
    }

    /// The time left, from the strips returned since the first (the
    /// preparation before it, often most of a first frame, is not a rate
    /// the rest will keep).
    fn estimate(&mut self) {
        let (done, total) = (self.summary.strips_done, self.summary.strips_total);
        let Some((t0, done0)) = self.first_strip else {
            self.first_strip = Some((Instant::now(), done));
            return;
        };
        let since = (done.saturating_sub(done0)) as f64;
        if since > 0.0 && total > done {
            let per_strip = t0.elapsed().as_secs_f64() * 1e3 / since;
            self.summary.eta_ms = (per_strip * (total - done) as f64) as u64;
        } else {
            self.summary.eta_ms = 0;
        }
    }

    /// The job as the database keeps it.
    fn row(&self) -> crate::store::JobRow {
        use prost::Message;
        let s = &self.summary;
        crate::store::JobRow {
            id: s.id.clone(),
            seq: self.seq,
            state: Some(self.state),
            priority: s.priority,
            name: s.name.clone(),
            submitter: s.submitter.clone(),
            spec: self.spec.encode_to_vec(),
            bundle_hash: self.bundle_hash.clone(),
            frames: s.frames,
            frames_done: s.frames_done,
            strips_done: s.strips_done,
            strips_total: s.strips_total,
            retries: s.retries,
            error: s.error.clone(),
            stats_json: self.stats_json.clone(),
            submitted_ms: s.submitted_unix_ms,
            started_ms: s.started_unix_ms,
            finished_ms: s.finished_unix_ms,
            result_bytes: self.reserved,
        }
    }
}

/// Bytes a frame's results take on disk at most: its EXR (three 32-bit
/// floats a pixel, uncompressed) and PNG (three bytes a pixel and the
/// filter byte of each row, when it does not compress), and their headers.
pub fn result_bytes(width: u32, height: u32) -> u64 {
    let px = width as u64 * height as u64;
    px * 12 + px * 3 + height as u64 + 4096
}

struct State {
    config: CoordinatorConfig,
    metrics: Arc<crate::metrics::Metrics>,
    jobs: Mutex<BTreeMap<String, Job>>,
    /// The durable queue: every change is written here first.
    store: Store,
    workers: Mutex<BTreeMap<String, KnownWorker>>,
    /// Per-column cost of frames rendered before, by scene and frame shape.
    costs: Mutex<std::collections::HashMap<String, Vec<f64>>>,
    /// The database's id prefix (ids are `job-PREFIX-SEQ`, SEQ from its counter).
    prefix: String,
    slots: Arc<Semaphore>,
    wake: tokio::sync::Notify,
    /// Held while this coordinator uses the state folder.
    _lock: std::fs::File,
    /// Whose tokens are accepted, with what role.
    access: Arc<Access>,
    /// Writes the database has not taken yet, written again until it does.
    owed: Mutex<owed::Owed>,
    /// When each (user, action) refusal was last audited: one row a minute
    /// each, so a token's holder cannot flood the log by being refused.
    refusals: Mutex<std::collections::HashMap<(String, String), std::time::Instant>>,
    /// The scheduler, heartbeat and owed-writes loops: stopped before the
    /// database closes, so none writes to a closed one.
    background: Mutex<Vec<tokio::task::JoinHandle<()>>>,
}

/// The `sylva.v1.Coordinator` service.
#[derive(Clone)]
pub struct CoordinatorService {
    state: Arc<State>,
}

impl CoordinatorService {
    /// A coordinator on its state folder and database, with the jobs and
    /// workers they hold (a running job is queued again, to resume where it
    /// was); call [`CoordinatorService::spawn_background`] to run jobs.
    pub async fn open(mut config: CoordinatorConfig) -> anyhow::Result<Self> {
        let metrics_listener = config.metrics.take();
        let dir = config.state_dir.clone();
        let lock = sylva_proto::workdir::claim(&dir, "state folder")?;
        // Scene checks a killed coordinator left half done.
        let _ = std::fs::remove_dir_all(dir.join("check"));
        let url = config
            .database
            .clone()
            .unwrap_or_else(|| format!("sqlite://{}", dir.join("sylva.db").display()));
        let store = Store::claim(&url).await?;
        let prefix = farm_of(&dir, &store, &url).await?;
        // Named workers count as alive until a heartbeat says otherwise, so a
        // job submitted at once can use them (the farm copes if one is not);
        // so do workers the database saw within their registration's life,
        // so a restarted coordinator resumes on them at once.
        let mut workers: BTreeMap<String, KnownWorker> = BTreeMap::new();
        let ttl_ms = config.registration_ttl.as_millis() as u64;
        for w in store.workers().await? {
            if (crate::store::now_ms() as u64).saturating_sub(w.last_seen_ms) < ttl_ms {
                workers.insert(w.addr.clone(), KnownWorker::restored(&w));
            }
        }
        for a in &config.workers {
            workers.insert(
                a.clone(),
                KnownWorker {
                    info: pb::WorkerInfo { addr: a.clone(), alive: true, ..Default::default() },
                    named: true,
                    seen: Instant::now(),
                    key: None,
                },
            );
        }
        let jobs = jobs::restore(&store).await?;
        let access = Arc::new(Access::new(config.token.clone()));
        access.set(store.tokens().await?);
        let slots = Arc::new(Semaphore::new(config.max_running.max(1)));
        tracing::info!(
            state = %dir.display(),
            database = store.kind(),
            jobs = jobs.len(),
            queued = jobs.values().filter(|j| j.state == JobState::Queued).count(),
            "coordinator state opened"
        );
        let service = Self {
            state: Arc::new(State {
                config,
                metrics: Arc::new(crate::metrics::Metrics::default()),
                jobs: Mutex::new(jobs),
                store,
                workers: Mutex::new(workers),
                costs: Mutex::new(Default::default()),
                prefix,
                slots,
                wake: tokio::sync::Notify::new(),
                _lock: lock,
                access,
                owed: Default::default(),
                refusals: Default::default(),
                background: Default::default(),
            }),
        };
        if let Some(l) = metrics_listener {
            let s = service.state.clone();
            tokio::spawn(crate::metrics::serve(l, service.state.metrics.clone(), move || {
                s.gauges()
            }));
        }
        Ok(service)
    }

    /// A job's frame as it renders (strips so far and their preview).
    pub fn live(&self, id: &str) -> Option<LiveFrame> {
        lock(&self.state.jobs).get(id).map(|j| j.live.clone())
    }

    /// Who `token` makes a caller (anyone, on a farm that asks no token);
    /// `None` for a wrong or missing token.
    pub fn caller_of(&self, token: Option<&str>) -> Option<Caller> {
        self.state.access.caller(token)
    }

    /// Whether callers must bring a token.
    pub fn needs_token(&self) -> bool {
        self.state.access.closed()
    }

    /// The API's interceptor: finds who calls from their bearer token and
    /// hands it to the call (UNAUTHENTICATED for a wrong or missing one).
    pub fn authenticate(
        &self,
    ) -> impl FnMut(Request<()>) -> Result<Request<()>, Status> + Clone + use<> {
        let access = self.state.access.clone();
        move |mut req: Request<()>| {
            let caller = access.caller(sylva_proto::auth::bearer_of(&req));
            let caller = caller.ok_or_else(|| token_refused(&req))?;
            req.extensions_mut().insert(caller);
            Ok(req)
        }
    }

    /// Starts the scheduler loop and the worker heartbeats.
    pub fn spawn_background(&self) {
        let s = self.state.clone();
        let schedule = tokio::spawn(async move { s.schedule_loop().await });
        let s = self.state.clone();
        let heartbeat = tokio::spawn(async move { s.heartbeat_loop().await });
        let s = self.state.clone();
        let owed = tokio::spawn(async move { s.owed_loop().await });
        lock(&self.state.background).extend([schedule, heartbeat, owed]);
    }

    /// The tonic server wrapper. Messages are bounded by what the API
    /// carries: bundle chunks of at most 4 MiB and images of at most
    /// 16384² pixels.
    pub fn into_server(self) -> CoordinatorServer<Self> {
        CoordinatorServer::new(self)
            .max_decoding_message_size(8 << 20)
            .max_encoding_message_size(usize::MAX)
    }

    /// Closes the database; removes the state folder of an ephemeral
    /// coordinator (a durable one keeps it for the next start).
    pub async fn clean_up(&self) {
        // Nothing may write once the database is closed (before, the
        // loops and running jobs logged "cannot be written" at every
        // shutdown): the loops and the jobs' runs stop first. A durable
        // coordinator's running jobs resume at its next start.
        let loops: Vec<_> = lock(&self.state.background).drain(..).collect();
        for t in &loops {
            t.abort();
        }
        for j in lock(&self.state.jobs).values_mut() {
            if let Some(t) = j.task.take() {
                t.abort();
            }
        }
        // Ended, not just told to end: a loop in the middle of a poll
        // would otherwise reach the closed pool.
        for t in loops {
            let _ = t.await;
        }
        self.state.store.close().await;
        let dir = &self.state.config.state_dir;
        let gone = if self.state.config.ephemeral { dir.clone() } else { dir.join("check") };
        if gone.exists()
            && let Err(e) = std::fs::remove_dir_all(&gone)
        {
            tracing::warn!(dir = %gone.display(), "cannot remove the folder: {e}");
        }
    }
}

/// The state folder's record of the farm whose database it uses (the
/// database's id prefix), beside its results.
const FARM_FILE: &str = "farm";

/// Checks that the database is the state folder's own and brings it up
/// to date: the farm's id prefix. Refused, before anything is written,
/// when the database is not the one the folder's results belong to — a
/// truncated (0-byte) file, a new database where a farm had kept results,
/// or another farm's — since a coordinator would otherwise start a new
/// farm over them: jobs forgotten, results orphaned, users gone.
async fn farm_of(dir: &std::path::Path, store: &Store, url: &str) -> anyhow::Result<String> {
    use crate::store::Found;
    let db = crate::store::redacted(url);
    let recorded = std::fs::read_to_string(dir.join(FARM_FILE)).ok().map(|s| s.trim().to_string());
    let kept_results = std::fs::read_dir(dir.join("results")).is_ok_and(|mut d| d.next().is_some());
    let restore = "restore it from a backup, or give this coordinator a new state folder                    (and database) to start a new farm";
    match store.found() {
        Found::EmptyFile => anyhow::bail!(
            "the database {db} is an empty file (0 bytes): a farm's database truncated or lost,              not a new one; {restore}"
        ),
        Found::New if recorded.is_some() || kept_results => anyhow::bail!(
            "the database {db} is new, but the state folder {} holds an earlier farm's {}:              its database is lost or another was named; {restore}",
            dir.display(),
            if recorded.is_some() { "record" } else { "results" }
        ),
        Found::New => tracing::info!(database = %db, "a new farm: its database is created"),
        Found::Existing => {}
    }
    store.migrate().await?;
    let prefix = store.meta("prefix", || sylva_proto::auth::random_hex(4)).await?;
    match recorded {
        Some(r) if r != prefix => anyhow::bail!(
            "the database {db} is another farm's (ids job-{prefix}-…) than the state folder {}              (job-{r}-…): one database per farm",
            dir.display()
        ),
        Some(_) => {}
        None => {
            crate::results::write_whole(&dir.join(FARM_FILE), format!("{prefix}\n").as_bytes())?
        }
    }
    Ok(prefix)
}

/// Who made a call: the interceptor's finding, or (a call made in this
/// process, as the dashboard's) the one its bearer token names.
fn caller<T>(access: &Access, req: &Request<T>) -> Result<Caller, Status> {
    if let Some(c) = req.extensions().get::<Caller>() {
        return Ok(c.clone());
    }
    access.caller(sylva_proto::auth::bearer_of(req)).ok_or_else(|| token_refused(req))
}

/// A call's token found wanting, in words that say which way and the fix:
/// none brought, or one this farm does not hold (wrong or revoked alike:
/// which of the two is not told).
fn token_refused<T>(req: &Request<T>) -> Status {
    Status::unauthenticated(match sylva_proto::auth::bearer_of(req) {
        None => {
            "this coordinator needs a bearer token and the call brought none: give it with \
             --token-file FILE or SYLVA_TOKEN (the Python client: token= or token_file=)"
        }
        Some(_) => {
            "this coordinator refused the bearer token: it is not one of this farm's, or it \
             was revoked (check --token-file or SYLVA_TOKEN; an operator makes one with \
             `sylva token add NAME --role ROLE`)"
        }
    })
}

impl CoordinatorService {
    /// The caller of `request`, if their role is one of `roles`; else
    /// PERMISSION_DENIED, and the refusal goes to the audit log (at most
    /// once a minute for the same user and action).
    async fn allowed<T>(
        &self,
        request: &Request<T>,
        roles: &[Role],
        what: &str,
    ) -> Result<Caller, Status> {
        let c = caller(&self.state.access, request)?;
        if let Err(refused) = allow(&c, roles, what) {
            let key = (c.user.clone(), what.to_string());
            let due = {
                let mut last = lock(&self.state.refusals);
                let now = std::time::Instant::now();
                last.retain(|_, t| now.duration_since(*t) < std::time::Duration::from_secs(60));
                let due = !last.contains_key(&key);
                if due {
                    last.insert(key, now);
                }
                due
            };
            if due {
                let detail = format!("a {} token", c.role.name());
                self.state.audit(&c.user, &format!("refused: {what}"), "", &detail).await;
            }
            return Err(refused);
        }
        Ok(c)
    }
}

/// PERMISSION_DENIED unless `caller` has one of `roles`.
fn allow(caller: &Caller, roles: &[Role], what: &str) -> Result<(), Status> {
    if roles.contains(&caller.role) {
        return Ok(());
    }
    let may: Vec<&str> = roles.iter().map(|r| r.name()).collect();
    Err(Status::permission_denied(format!(
        "a {} token cannot {what}: that takes a token of the role {} (an operator makes one \
         with `sylva token add NAME --role ROLE`)",
        caller.role.name(),
        may.join(" or ")
    )))
}

impl State {
    /// Writes an entry of the audit log; one the database refuses is
    /// owed, and written when it can be.
    async fn audit(&self, actor: &str, action: &str, target: &str, detail: &str) {
        let e = crate::store::AuditRow::now(actor, action, target, detail);
        if let Err(err) = self.store.audit(&e).await {
            tracing::warn!(action, target, "audit entry not written yet: {err:#}");
            self.owe_audit(e);
        }
    }

    /// Empty while the database takes writes; otherwise why it does not,
    /// since when, and what is owed (as `sylva jobs` and the dashboard show it).
    fn store_problem(&self) -> String {
        let h = self.store.health();
        if h.ok() {
            return String::new();
        }
        let ago = (crate::store::now_ms() as u64).saturating_sub(h.failing_since_ms) / 1000;
        format!(
            "the coordinator's database has refused writes for {ago} s ({} failed; last: {}); \
             submissions are refused and finished jobs' states are written when it recovers",
            h.failed_writes, h.error
        )
    }

    /// Where a scene bundle waits while a job needs it.
    fn bundle_path(&self, hash: &str) -> PathBuf {
        self.config.state_dir.join("bundles").join(hash)
    }

    /// Whether a job of `frames` frames of `frame` fits the per-job pixel
    /// cap and the results' disk budget: the bytes to reserve for it, or
    /// RESOURCE_EXHAUSTED with the reason.
    async fn room_for(&self, frame: &FrameSettings, frames: usize) -> Result<u64, Status> {
        let pixels = frame.width as u64 * frame.height as u64 * frames as u64;
        let cap = self.config.max_job_pixels;
        if pixels > cap {
            return Err(Status::resource_exhausted(format!(
                "{frames} frame(s) of {}×{} are {pixels} pixels: over this farm's {cap} a job (--max-job-pixels)",
                frame.width, frame.height
            )));
        }
        let need = result_bytes(frame.width, frame.height) * frames as u64;
        let used = self.store.result_bytes().await.map_err(jobs::internal_error)?;
        let budget = self.config.results_disk_bytes;
        if used + need > budget {
            return Err(Status::resource_exhausted(format!(
                "the job's results need up to {need} bytes; {} of this farm's {budget} bytes for results are free (--results-disk-mib); fetch and let older jobs go, or ask later",
                budget.saturating_sub(used)
            )));
        }
        Ok(need)
    }

    /// Writes an ended job's state and lets its bundle go when no job
    /// may run it any more.
    async fn ended(&self, id: &str) {
        let Some((row, hash)) = lock(&self.jobs).get(id).map(|j| (j.row(), j.bundle_hash.clone()))
        else {
            return;
        };
        if let Err(e) = self.store.set_state(&row).await {
            tracing::warn!(%id, "the job's end is not written yet: {e:#}");
            self.owe_row(id);
        }
        // A submitter's older failed or cancelled jobs give up their
        // bundles for a requeue: only the latest few are kept.
        let dropped: Vec<String> = {
            let mut jobs = lock(&self.jobs);
            let who = jobs.get(id).map(|j| j.summary.submitter.clone()).unwrap_or_default();
            let mut kept: Vec<(Instant, String)> = jobs
                .iter()
                .filter(|(_, j)| j.state.requeueable() && j.kept && j.summary.submitter == who)
                .map(|(k, j)| (j.finished.unwrap_or_else(Instant::now), k.clone()))
                .collect();
            kept.sort_by_key(|k| std::cmp::Reverse(k.0));
            kept.iter()
                .skip(KEPT_FOR_REQUEUE)
                .filter_map(|(_, k)| {
                    let j = jobs.get_mut(k)?;
                    j.kept = false;
                    Some(j.bundle_hash.clone())
                })
                .collect()
        };
        for h in dropped.iter().chain([&hash]) {
            self.release_bundle(h);
        }
    }

    /// Deletes a scene bundle that no job listed may run: none waiting or
    /// running, and none failed or cancelled whose bundle is kept for a
    /// requeue. Decided and deleted under the jobs' lock, so a job that
    /// takes the bundle meanwhile is seen.
    fn release_bundle(&self, hash: &str) {
        let jobs = lock(&self.jobs);
        let needed = jobs.values().any(|j| {
            j.bundle_hash == hash && (!j.state.ended() || (j.state.requeueable() && j.kept))
        });
        if !needed {
            let _ = std::fs::remove_file(self.bundle_path(hash));
        }
    }

    /// Writes a job's progress counts.
    async fn save_progress(&self, id: &str) {
        let Some(row) = lock(&self.jobs).get(id).map(Job::row) else { return };
        if let Err(e) = self.store.set_progress(&row).await {
            tracing::warn!(%id, "progress not written yet: {e:#}");
            self.owe_row(id);
        }
    }

    fn gauges(&self) -> crate::metrics::Gauges {
        let jobs = lock(&self.jobs);
        let workers = lock(&self.workers);
        crate::metrics::Gauges {
            queued: jobs.values().filter(|j| j.state == JobState::Queued).count() as u64,
            running: jobs.values().filter(|j| j.state == JobState::Running).count() as u64,
            workers_alive: workers.values().filter(|w| w.info.alive).count() as u64,
            workers: workers.len() as u64,
            store_healthy: self.store.health().ok() as u64,
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
                // Empty until the job is done: any event of a done job,
                // a lagging watcher's too, carries its figures.
                stats_json: j.stats_json.clone(),
                eta_ms: j.summary.eta_ms,
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

/// Opens the coordinator's state, calls `ready` with the service (where
/// the binary starts what serves beside it, as the dashboard; an error
/// there stops the coordinator), serves the API, health and reflection
/// until `shutdown`, then closes the database (and removes an ephemeral
/// state folder).
pub async fn run(
    listener: tokio::net::TcpListener,
    mut config: CoordinatorConfig,
    ready: impl FnOnce(&CoordinatorService) -> anyhow::Result<()>,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let (reporter, health) = tonic_health::server::health_reporter();
    let (reflection, reflection_alpha) = sylva_proto::reflection(&["sylva.v1.Coordinator"])?;
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = config.tls.take() {
        builder = builder.tls_config(tls)?;
    }
    let service = CoordinatorService::open(config).await?;
    if let Err(e) = ready(&service) {
        service.clean_up().await;
        return Err(e);
    }
    let auth = service.authenticate();
    if !service.needs_token() && listener.local_addr().is_ok_and(|a| !a.ip().is_loopback()) {
        tracing::warn!(
            "the API is served beyond this machine without a token: whoever reaches it can submit and cancel jobs (give --token-file, or users: sylva token add)"
        );
    }
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
        .serve_with_incoming_shutdown(sylva_proto::tls::incoming(listener), shutdown)
        .await;
    service.clean_up().await;
    served?;
    Ok(())
}
