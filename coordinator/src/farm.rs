//! Renders a frame on a set of gRPC workers: every worker gets the scene
//! bundle (all at once), then pulls strips from one queue until the frame
//! is done. A strip whose worker fails, misses its deadline or returns a
//! reply that does not fit the strip goes back on the queue for another; a
//! worker that fails three times is dropped for this frame; the frame fails
//! only when no worker is left, and then says what each worker last failed
//! with. Strips land by their columns ([`Assembly`]), so the frame is the
//! same whoever rendered what.

use crate::assembly::{Assembly, StripPixels};
use crate::executor::RenderedFrame;
use crate::schedule::{Strip, StripTime};
use serde::Serialize;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::pb::worker_client::WorkerClient;
use sylva_scene::bundle::SceneBundle;
use sylva_scene::film::RayCounts;
use sylva_scene::frame::FrameSettings;
use sylva_scene::passes::{PassImage, PassSet};
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, ClientTlsConfig};

/// What a worker said (an error's text), as it may be shown and logged:
/// bounded, and escaped so it cannot drive a terminal or forge a log line.
fn said(text: &str) -> String {
    sylva_scene::sandbox::printable(text, 500)
}

/// Failures after which a worker is dropped for the frame.
pub const MAX_FAILURES: u32 = 3;
/// Bytes per upload chunk.
const CHUNK: usize = 1 << 20;
/// Most bytes of prepared data the coordinator forwards between workers.
const MAX_PREPARED_BYTES: u64 = 4 << 30;

/// What happened, for progress bars and logs.
#[derive(Clone, Debug)]
pub enum FarmEvent {
    /// A strip of `frame` (0 unless a sequence) came back with `bytes` of
    /// pixels; `preview` is it in 8-bit sRGB, rows from the top (for a
    /// live view).
    StripDone {
        frame: usize,
        strip: Strip,
        worker: String,
        ms: f64,
        bytes: u64,
        preview: Arc<Vec<[u8; 3]>>,
    },
    /// A scene bundle of `bytes` was sent to a worker.
    BundleSent { worker: String, bytes: u64 },
    /// A strip failed on a worker and was put back on the queue.
    StripRetried { frame: usize, strip: Strip, worker: String, error: String },
    /// A worker was dropped for this frame.
    WorkerDropped { worker: String, error: String },
    /// The scene's prepared data was made or found on one worker and sent
    /// to the others.
    PreparedShared(PreparedShare),
    /// What the farm is doing now, in words: sending the scene, one worker
    /// preparing it, sharing what it prepared, tracing.
    Stage(String),
    /// The strips this run will render (fewer than planned when an earlier
    /// run left frames or strips).
    Planned { strips: usize },
}

/// How a job's scene was prepared once for the farm.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PreparedShare {
    /// The worker that held or made the prepared data.
    pub from: String,
    /// The workers that took it.
    pub to: Vec<String>,
    /// Bytes sent to each.
    pub bytes: u64,
    /// Time `from` spent preparing (0 when it held the data already), ms.
    pub prepare_ms: f64,
    /// Time to export it and for every other worker to take it, ms.
    pub share_ms: f64,
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
    /// What it last failed with.
    pub last_error: Option<String>,
}

/// A worker client that sends the bearer token, if any.
pub type Client = WorkerClient<InterceptedService<Channel, sylva_proto::auth::Attach>>;

/// Connects to a worker at `addr` (`host:port`), over TLS when `tls` is
/// set, sending `token` with every call.
pub async fn connect(
    addr: &str,
    token: Option<String>,
    tls: Option<&ClientTlsConfig>,
) -> anyhow::Result<Client> {
    let ch = sylva_proto::tls::connect(addr, tls, Duration::from_secs(10))
        .await
        .map_err(|e| anyhow::anyhow!("cannot reach worker {addr}: {e}"))?;
    Ok(WorkerClient::with_interceptor(ch, sylva_proto::auth::attach(token))
        .max_decoding_message_size(1 << 30)
        .max_encoding_message_size(1 << 30))
}

/// Sends `bundle` to a worker (a single empty chunk first, in case it is
/// cached); returns the bytes sent.
pub async fn upload(client: &mut Client, bundle: &SceneBundle) -> Result<u64, tonic::Status> {
    let probe = pb::SceneChunk {
        hash: bundle.hash.clone(),
        total_size: bundle.bytes.len() as u64,
        data: Vec::new(),
    };
    if bundle.bytes.is_empty()
        || client
            .load_scene(tokio_stream::iter(vec![probe]))
            .await
            .is_ok_and(|r| r.get_ref().was_cached)
    {
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
    /// (frame, strip) in pull order.
    queue: Mutex<VecDeque<(usize, Strip)>>,
    /// Frames with strips in: only those in flight.
    open: Mutex<std::collections::HashMap<usize, OpenFrame>>,
    /// Per frame, strips not yet in.
    left: Mutex<Vec<usize>>,
    /// Strips not yet in, all frames.
    remaining: Mutex<usize>,
    /// Every frame's width and height.
    size: (u32, u32),
    /// Each frame's passes beside the image.
    passes: Vec<PassSet>,
    upload_ms: f64,
    prepared: Option<PreparedShare>,
    out: tokio::sync::mpsc::Sender<Finished>,
    /// The job the strips belong to.
    job: String,
}

/// Where and how to reach the workers.
#[derive(Clone, Debug, Default)]
pub struct Workers {
    /// Addresses, `host:port`.
    pub addrs: Vec<String>,
    /// Bearer token the workers require, if any.
    pub token: Option<String>,
    /// TLS to reach them with, if they serve it.
    pub tls: Option<ClientTlsConfig>,
    /// Per worker, the key it was given at registration, sent in place of
    /// `token` (only calls with it may push prepared data into the worker).
    pub keys: std::collections::HashMap<String, String>,
    /// The job these calls serve: a worker uses prepared data imported
    /// for a job for that job's strips only.
    pub job: String,
}

impl Workers {
    /// Workers that need no token.
    pub fn open(addrs: &[String]) -> Self {
        Self { addrs: addrs.to_vec(), ..Default::default() }
    }

    /// The bearer token to call `addr` with.
    pub fn token_for(&self, addr: &str) -> Option<String> {
        self.keys.get(addr).cloned().or_else(|| self.token.clone())
    }
}

/// Decodes a worker's reply to `strip` and checks it before any use: a
/// reply for other columns, of another size or with values that are no
/// radiance is the worker's failure.
pub fn decode_reply(
    r: &pb::RenderStripReply,
    strip: Strip,
    height: u32,
    passes: PassSet,
) -> Result<StripPixels, String> {
    if r.x0 != strip.0 || r.width != strip.1 - strip.0 || r.height != height {
        return Err(format!(
            "worker replied with columns [{}, {}) × {} rows to a request for [{}, {}) × {height}",
            r.x0,
            r.x0.saturating_add(r.width),
            r.height,
            strip.0,
            strip.1
        ));
    }
    let n = (strip.1 - strip.0) as usize * height as usize;
    if r.rgb_f32.len() != n * 12 || r.coverage_f32.len() != n * 4 {
        return Err(format!(
            "worker replied with {} bytes of pixels and {} of coverage where {} and {} were due",
            r.rgb_f32.len(),
            r.coverage_f32.len(),
            n * 12,
            n * 4
        ));
    }
    let f = |c: &[u8]| f32::from_le_bytes(c.try_into().expect("4 bytes"));
    let rgb = r
        .rgb_f32
        .as_chunks::<12>()
        .0
        .iter()
        .map(|c| [f(&c[0..4]), f(&c[4..8]), f(&c[8..12])])
        .collect();
    let coverage = r.coverage_f32.as_chunks::<4>().0.iter().map(|c| f(c)).collect();
    let rays = r.rays.as_ref().map_or(RayCounts::default(), |c| RayCounts {
        primary: c.primary,
        shadow: c.shadow,
        transparent: c.transparent,
    });
    let passes = if passes.is_empty() {
        if !r.passes_f32.is_empty() {
            return Err("worker replied with passes nobody asked for".into());
        }
        None
    } else {
        Some(PassImage::from_bytes(strip.1 - strip.0, height, passes, &r.passes_f32)?)
    };
    let px = StripPixels { strip, rgb, coverage, rays, passes };
    px.check(height)?;
    Ok(px)
}

/// Has the farm pre-process the scene once: asks every worker whether it
/// holds what `frame` needs prepared; unless all do, one that does (or the
/// first, told to prepare it now) exports it, and the coordinator forwards
/// it to the others, which check it before keeping it. When every one of
/// them refuses it, that source is not trusted again and a refusing worker
/// (it checked the data, so it is sound) prepares and exports instead.
/// Meanwhile no strip is sent, so the others do not start the same work.
async fn share_prepared(
    clients: &[Option<Client>],
    addrs: &[String],
    hash: &str,
    job: &str,
    frame: &pb::FrameSettings,
    deadline: Duration,
    stage: &(dyn Fn(String) + Sync),
) -> Result<Option<PreparedShare>, String> {
    let live: Vec<(usize, Client)> =
        clients.iter().enumerate().filter_map(|(i, c)| c.clone().map(|c| (i, c))).collect();
    if live.len() < 2 {
        return Ok(None);
    }
    let ask = |build: bool| pb::PrepareRequest {
        scene_hash: hash.to_string(),
        frame: Some(frame.clone()),
        build,
        job: job.to_string(),
    };
    let mut held = futures_util::future::join_all(live.iter().map(|(_, c)| {
        let (mut c, req) = (c.clone(), ask(false));
        async move { c.prepare(req).await.ok().map(|r| r.into_inner().held) }
    }))
    .await;
    let t = Instant::now();
    let mut distrusted = Vec::new();
    let mut last = None;
    // Two rounds: the second only after every worker refused the first
    // source's data.
    for _ in 0..2 {
        // Workers that cannot answer (an older build) are left to prepare alone.
        let lacking: Vec<usize> = (0..live.len()).filter(|&k| held[k] == Some(false)).collect();
        if lacking.is_empty() {
            break;
        }
        let holder = (0..live.len()).find(|&k| held[k] == Some(true) && !distrusted.contains(&k));
        let (source, prepare_ms) = match holder {
            Some(k) => (k, 0.0),
            None => {
                let k = lacking[0];
                stage(format!(
                    "{} preparing the scene (structures, voxels, LB light)",
                    addrs[live[k].0]
                ));
                let mut req = tonic::Request::new(ask(true));
                req.set_timeout(deadline);
                let r = live[k].1.clone().prepare(req).await.map_err(|s| {
                    format!("{} could not prepare: {}", addrs[live[k].0], said(s.message()))
                })?;
                held[k] = Some(true);
                (k, r.into_inner().prepare_ms)
            }
        };
        let from = addrs[live[source].0].clone();
        let to: Vec<usize> = lacking.into_iter().filter(|&k| k != source).collect();
        let plural = if to.len() == 1 { "" } else { "s" };
        stage(format!("sharing the prepared scene from {from} with {} worker{plural}", to.len()));
        let mut exported = export_from(&live[source].1, ask(false), &from).await?;
        // The coordinator says which job the data serves, whatever the
        // exporter wrote: the importers use it for this job only.
        if let Some(first) = exported.first_mut() {
            first.job = job.to_string();
        }
        let chunks = Arc::new(exported);
        let bytes = chunks.iter().map(|c| c.data.len() as u64).sum();
        let imported = futures_util::future::join_all(to.iter().map(|&k| {
            let (mut c, chunks) = (live[k].1.clone(), chunks.clone());
            async move {
                c.import_prepared(tokio_stream::iter(chunks.iter().cloned().collect::<Vec<_>>()))
                    .await
                    .map(|r| r.into_inner().held)
            }
        }))
        .await;
        let mut sent = Vec::new();
        for (&k, r) in to.iter().zip(imported) {
            let addr = addrs[live[k].0].clone();
            match r {
                Ok(true) => {
                    held[k] = Some(true);
                    sent.push(addr);
                }
                Ok(false) => {
                    tracing::warn!(worker = %addr, "took the prepared data but does not hold it")
                }
                Err(s) => {
                    tracing::warn!(worker = %addr, from = %from, "refused the prepared data: {}", said(s.message()))
                }
            }
        }
        let refused_by_all = sent.is_empty() && !to.is_empty();
        last = Some(PreparedShare {
            from,
            to: sent,
            bytes,
            prepare_ms,
            share_ms: t.elapsed().as_secs_f64() * 1e3 - prepare_ms,
        });
        if !refused_by_all {
            break;
        }
        distrusted.push(source);
    }
    Ok(last)
}

/// Every chunk of a worker's export, counted against what it declared.
async fn export_from(
    client: &Client,
    req: pb::PrepareRequest,
    from: &str,
) -> Result<Vec<pb::PreparedChunk>, String> {
    let mut stream = client
        .clone()
        .export_prepared(req)
        .await
        .map_err(|s| format!("{from} could not export: {}", said(s.message())))?
        .into_inner();
    let mut chunks: Vec<pb::PreparedChunk> = Vec::new();
    let (mut bytes, mut declared) = (0u64, None);
    while let Some(c) = stream
        .message()
        .await
        .map_err(|s| format!("{from} broke off its export: {}", said(s.message())))?
    {
        let total = *declared.get_or_insert(c.total_size);
        bytes += c.data.len() as u64;
        if bytes > total || total > MAX_PREPARED_BYTES {
            return Err(format!(
                "{from} exported more than its declared {total} bytes, or over {MAX_PREPARED_BYTES}"
            ));
        }
        chunks.push(c);
    }
    Ok(chunks)
}

/// Renders `frame` of `bundle` on `workers`, strips pulled in `plan` order;
/// `deadline` bounds each strip's RPC.
pub async fn render_frame(
    workers: &Workers,
    bundle: &SceneBundle,
    frame: FrameSettings,
    plan: Vec<Strip>,
    deadline: Duration,
    events: impl Fn(FarmEvent) + Send + Sync + 'static,
) -> anyhow::Result<RenderedFrame> {
    let mut frames = render_frames(workers, bundle, &[frame], vec![plan], deadline, events).await?;
    Ok(frames.pop().expect("one frame"))
}

/// Renders every frame of a sequence and returns them all, in order (see
/// [`render_streamed`], which hands each over as it is done and holds
/// only the frames in flight).
pub async fn render_frames(
    workers: &Workers,
    bundle: &SceneBundle,
    frames: &[FrameSettings],
    plans: Vec<Vec<Strip>>,
    deadline: Duration,
    events: impl Fn(FarmEvent) + Send + Sync + 'static,
) -> anyhow::Result<Vec<RenderedFrame>> {
    let (tx, mut rx) = tokio::sync::mpsc::channel(4);
    let n = frames.len();
    let collect = async move {
        let mut out: Vec<Option<RenderedFrame>> = vec![None; n];
        while let Some(f) = rx.recv().await {
            if let Finished::Frame { frame, rendered } = f {
                out[frame] = Some(*rendered);
            }
        }
        out
    };
    let run = render_streamed(workers, bundle, frames, plans, deadline, events, Resume::none(), tx);
    let (run, out) = tokio::join!(run, collect);
    let run = run?;
    out.into_iter()
        .map(|f| {
            let mut f = f.ok_or_else(|| anyhow::anyhow!("a frame was not handed over"))?;
            f.workers.clone_from(&run.workers);
            Ok(f)
        })
        .collect()
}

/// What a farm run hands over as it goes.
pub enum Finished {
    /// A strip of a frame that is not whole yet, with the worker's reply
    /// as received (kept, a restart need not render it again).
    Strip {
        /// Frame number.
        frame: usize,
        /// Its columns.
        strip: Strip,
        /// Who rendered it.
        worker: String,
        /// The reply, checked.
        reply: Box<pb::RenderStripReply>,
    },
    /// A whole frame, put together.
    Frame {
        /// Frame number.
        frame: usize,
        /// The frame.
        rendered: Box<RenderedFrame>,
    },
}

/// What a run already holds from an earlier one (a restarted coordinator):
/// frames to skip, and strips of unfinished frames to build on.
#[derive(Default)]
pub struct Resume {
    /// Per frame, whether it is stored already.
    pub done: Vec<bool>,
    /// Strips kept of unfinished frames, with their render times.
    pub strips: Vec<(usize, StripPixels, f64)>,
}

impl Resume {
    /// Nothing held: every frame renders.
    pub fn none() -> Self {
        Self::default()
    }
}

/// A farm run's figures, once every frame is handed over.
#[derive(Clone, Debug, Default)]
pub struct FarmRun {
    /// Per worker.
    pub workers: Vec<WorkerReport>,
    /// Time to get the scene to the workers, ms.
    pub upload_ms: f64,
    /// How the scene was prepared once for the farm, when it was.
    pub prepared: Option<PreparedShare>,
}

/// Renders every frame of a sequence (same size, own views) of `bundle` on
/// `workers`: all (frame, strip) pairs go on one queue, frame by frame in
/// `plans` order, so idle workers start the next frame while the last
/// strips of one finish. Each frame goes to `out` as soon as its last
/// strip is in (and each strip of a frame cut into several as it comes),
/// so the run holds only the frames in flight; a full `out` holds the
/// workers back. Frames and strips that `resume` holds are not rendered
/// again.
#[allow(clippy::too_many_arguments)]
pub async fn render_streamed(
    workers: &Workers,
    bundle: &SceneBundle,
    frames: &[FrameSettings],
    plans: Vec<Vec<Strip>>,
    deadline: Duration,
    events: impl Fn(FarmEvent) + Send + Sync + 'static,
    resume: Resume,
    out: tokio::sync::mpsc::Sender<Finished>,
) -> anyhow::Result<FarmRun> {
    anyhow::ensure!(!workers.addrs.is_empty(), "no workers to render on");
    anyhow::ensure!(!frames.is_empty() && frames.len() == plans.len(), "one strip plan per frame");
    anyhow::ensure!(
        frames.iter().all(|f| (f.width, f.height) == (frames[0].width, frames[0].height)),
        "a sequence's frames share one size"
    );
    let (width, height) = (frames[0].width, frames[0].height);
    // What an earlier run left: its strips go in first, and only the
    // columns they leave open are rendered.
    let mut open: std::collections::HashMap<usize, OpenFrame> = Default::default();
    for (frame, px, render_ms) in resume.strips {
        if frame >= frames.len() || resume.done.get(frame) == Some(&true) {
            continue;
        }
        let f = open
            .entry(frame)
            .or_insert_with(|| OpenFrame::new(width, height, frames[frame].passes));
        if f.assembly.add(&px).is_ok() {
            f.times.push(StripTime { strip: px.strip, render_ms, call_ms: render_ms });
        }
    }
    let mut queue = VecDeque::new();
    for (i, plan) in plans.iter().enumerate() {
        if resume.done.get(i) == Some(&true) {
            continue;
        }
        let todo = match open.get(&i) {
            Some(f) => f.assembly.open_columns(plan),
            None => plan.clone(),
        };
        if let Some(f) = open.get_mut(&i) {
            f.left = todo.len();
        }
        queue.extend(todo.into_iter().map(|s| (i, s)));
    }
    // A frame whose every strip an earlier run kept is whole already.
    let whole: Vec<usize> = open.iter().filter(|(_, f)| f.left == 0).map(|(i, _)| *i).collect();
    let mut ready = Vec::new();
    for i in whole {
        let f = open.remove(&i).expect("open frame");
        ready.push(Finished::Frame { frame: i, rendered: Box::new(f.rendered(0.0, None)) });
    }
    for f in ready {
        out.send(f).await.map_err(|_| anyhow::anyhow!("the frames' receiver is gone"))?;
    }
    let left: Vec<usize> =
        (0..frames.len()).map(|i| queue.iter().filter(|(f, _)| *f == i).count()).collect();
    events(FarmEvent::Planned { strips: queue.len() });
    if queue.is_empty() {
        return Ok(FarmRun::default());
    }
    events(FarmEvent::Stage(format!("sending the scene to {} workers", workers.addrs.len())));
    let (clients, reports, upload_ms) = upload_to_all(workers, bundle, &events).await;
    let wires: Arc<Vec<pb::FrameSettings>> =
        Arc::new(frames.iter().map(pb::FrameSettings::from).collect());
    let prepared = match share_prepared(
        &clients,
        &workers.addrs,
        &bundle.hash,
        &workers.job,
        &wires[0],
        deadline,
        &|s| events(FarmEvent::Stage(s)),
    )
    .await
    {
        Ok(Some(share)) => {
            events(FarmEvent::PreparedShared(share.clone()));
            Some(share)
        }
        Ok(None) => None,
        Err(e) => {
            // Not fatal: each worker then prepares the scene itself.
            tracing::warn!("prepared data not shared: {e}");
            None
        }
    };
    let total = queue.len();
    let shared = Arc::new(Shared {
        queue: Mutex::new(queue),
        open: Mutex::new(open),
        left: Mutex::new(left),
        remaining: Mutex::new(total),
        size: (width, height),
        passes: frames.iter().map(|f| f.passes).collect(),
        upload_ms,
        prepared: prepared.clone(),
        out,
        job: workers.job.clone(),
    });
    events(FarmEvent::Stage(
        "tracing (a worker that does not hold the prepared scene prepares it first: \
         structures, voxels, LB light, upload)"
            .into(),
    ));
    let events = Arc::new(events);
    let mut tasks = Vec::new();
    let n_workers = clients.len();
    for (me, (client, report)) in clients.into_iter().zip(reports).enumerate() {
        let (shared, events, wires, hash) =
            (shared.clone(), events.clone(), wires.clone(), bundle.hash.clone());
        tasks.push(tokio::spawn(async move {
            pull_strips(me, n_workers, client, report, &shared, &*events, &wires, &hash, deadline)
                .await
        }));
    }
    // Wait for the frames, or for every worker to be gone.
    let mut reports = Vec::new();
    for t in tasks {
        reports.push(t.await?);
    }
    let remaining = *shared.remaining.lock().expect("lock");
    if remaining > 0 {
        let why: Vec<String> = reports
            .iter()
            .filter(|r| r.dropped)
            .map(|r| format!("{}: {}", r.worker, r.last_error.as_deref().unwrap_or("dropped")))
            .collect();
        let what = if frames.len() == 1 { "the frame" } else { "the sequence" };
        anyhow::bail!(
            "{what} failed: {} of {total} strips rendered; no worker left that can finish it ({})",
            total - remaining,
            why.join("; ")
        );
    }
    Ok(FarmRun { workers: reports, upload_ms, prepared })
}

/// A frame being put together, and how many of its strips are still out.
struct OpenFrame {
    assembly: Assembly,
    times: Vec<StripTime>,
    left: usize,
}

impl OpenFrame {
    fn new(width: u32, height: u32, passes: PassSet) -> Self {
        Self { assembly: Assembly::new(width, height, passes), times: Vec::new(), left: 0 }
    }

    fn rendered(mut self, upload_ms: f64, prepared: Option<PreparedShare>) -> RenderedFrame {
        self.times.sort_by_key(|s| s.strip);
        RenderedFrame {
            image: self.assembly.image,
            coverage: self.assembly.coverage,
            rays: self.assembly.rays,
            workers: Vec::new(),
            strip_times: self.times,
            upload_ms,
            prepared,
            passes: self.assembly.passes,
        }
    }
}

/// Sends the bundle to every worker at once (a slow one delays only
/// itself); a worker that cannot take it is reported and left out.
async fn upload_to_all(
    workers: &Workers,
    bundle: &SceneBundle,
    events: &(impl Fn(FarmEvent) + Send + Sync),
) -> (Vec<Option<Client>>, Vec<WorkerReport>, f64) {
    let t = Instant::now();
    // Every worker gets the bundle at once; a slow one delays only itself.
    let uploads = workers.addrs.iter().map(|w| {
        let (w, token, tls) = (w.clone(), workers.token_for(w), workers.tls.clone());
        async move {
            let client = async {
                let mut c = connect(&w, token, tls.as_ref()).await.map_err(|e| e.to_string())?;
                let bytes = upload(&mut c, bundle)
                    .await
                    .map_err(|e| format!("scene upload: {:?}: {}", e.code(), said(e.message())))?;
                Ok::<_, String>((c, bytes))
            }
            .await;
            (w, client)
        }
    });
    let uploaded = futures_util::future::join_all(uploads).await;
    let upload_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut clients = Vec::new();
    let mut reports: Vec<WorkerReport> = Vec::new();
    for (w, r) in uploaded {
        let mut report = WorkerReport { worker: w.clone(), ..Default::default() };
        match r {
            Ok((c, bytes)) => {
                if bytes > 0 {
                    events(FarmEvent::BundleSent { worker: w.clone(), bytes });
                }
                clients.push(Some(c));
            }
            Err(error) => {
                report.dropped = true;
                report.last_error = Some(error.clone());
                events(FarmEvent::WorkerDropped { worker: w.clone(), error });
                clients.push(None);
            }
        }
        reports.push(report);
    }
    (clients, reports, upload_ms)
}

/// One worker's share of the frames: it pulls strips until none is left,
/// puts back any it fails (and gives up after [`MAX_FAILURES`]), hands
/// each strip and each frame it completes over, and says what it did.
#[allow(clippy::too_many_arguments)]
async fn pull_strips(
    me: usize,
    n_workers: usize,
    client: Option<Client>,
    mut report: WorkerReport,
    shared: &Shared,
    events: &(impl Fn(FarmEvent) + Send + Sync),
    wires: &[pb::FrameSettings],
    hash: &str,
    deadline: Duration,
) -> WorkerReport {
    let Some(mut client) = client else { return report };
    let (width, height) = shared.size;
    let passes_of = &shared.passes;
    loop {
        let next = {
            // In a sequence each worker prefers the frames that
            // are its own by number (frame mod workers), so a
            // second pass over the same views meets the light it
            // kept per sun; it takes any other when it has none left.
            let mut q = shared.queue.lock().expect("lock");
            let mine = if wires.len() > 1 {
                q.iter().position(|(f, _)| f % n_workers == me)
            } else {
                None
            };
            mine.and_then(|i| q.remove(i)).or_else(|| q.pop_front())
        };
        let Some((frame, strip)) = next else {
            if *shared.remaining.lock().expect("lock") == 0 {
                return report;
            }
            // Strips may still come back from failing workers.
            tokio::time::sleep(Duration::from_millis(5)).await;
            continue;
        };
        let mut req = tonic::Request::new(pb::RenderStripRequest {
            scene_hash: hash.to_string(),
            frame: Some(wires[frame].clone()),
            x0: strip.0,
            x1: strip.1,
            job: shared.job.clone(),
        });
        req.set_timeout(deadline);
        let sent = Instant::now();
        let outcome =
            match tokio::time::timeout(deadline + Duration::from_secs(1), client.render_strip(req))
                .await
            {
                Ok(Ok(reply)) => {
                    let r = reply.into_inner();
                    decode_reply(&r, strip, height, passes_of[frame]).map(|px| (r, px))
                }
                Ok(Err(status)) => Err(format!("{:?}: {}", status.code(), said(status.message()))),
                Err(_) => Err("deadline passed".to_string()),
            };
        match outcome {
            Ok((r, px)) => {
                report.strips += 1;
                report.render_ms += r.render_ms;
                report.prepare_ms += r.prepare_ms;
                let bytes = (r.rgb_f32.len() + r.coverage_f32.len() + r.passes_f32.len()) as u64;
                events(FarmEvent::StripDone {
                    frame,
                    strip,
                    worker: report.worker.clone(),
                    ms: r.render_ms,
                    bytes,
                    preview: Arc::new(px.preview()),
                });
                let time = StripTime {
                    strip,
                    render_ms: r.render_ms,
                    call_ms: sent.elapsed().as_secs_f64() * 1e3,
                };
                // Put in place now; the frame leaves the farm when whole.
                let whole = {
                    let mut open = shared.open.lock().expect("lock");
                    let f = open
                        .entry(frame)
                        .or_insert_with(|| OpenFrame::new(width, height, passes_of[frame]));
                    // decode_reply checked the strip against its request,
                    // and the queue hands each columns out once.
                    let _ = f.assembly.add(&px);
                    f.times.push(time);
                    let mut left = shared.left.lock().expect("lock");
                    left[frame] -= 1;
                    (left[frame] == 0).then(|| open.remove(&frame).expect("open frame"))
                };
                drop(px);
                let handed = match whole {
                    Some(f) => Finished::Frame {
                        frame,
                        rendered: Box::new(f.rendered(shared.upload_ms, shared.prepared.clone())),
                    },
                    None => Finished::Strip {
                        frame,
                        strip,
                        worker: report.worker.clone(),
                        reply: Box::new(r),
                    },
                };
                // A gone receiver has given up on the run; the count still
                // falls, so every worker stops.
                let _ = shared.out.send(handed).await;
                *shared.remaining.lock().expect("lock") -= 1;
            }
            Err(error) => {
                shared.queue.lock().expect("lock").push_back((frame, strip));
                report.failures += 1;
                report.last_error = Some(error.clone());
                events(FarmEvent::StripRetried {
                    frame,
                    strip,
                    worker: report.worker.clone(),
                    error: error.clone(),
                });
                if report.failures >= MAX_FAILURES {
                    report.dropped = true;
                    events(FarmEvent::WorkerDropped { worker: report.worker.clone(), error });
                    return report;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A worker's reply to a 2 × 3 strip at column 4, with `passes`' bytes.
    fn reply(passes: Vec<u8>) -> pb::RenderStripReply {
        pb::RenderStripReply {
            x0: 4,
            width: 2,
            height: 3,
            rgb_f32: [0.5f32; 18].iter().flat_map(|v| v.to_le_bytes()).collect(),
            coverage_f32: [1.0f32; 6].iter().flat_map(|v| v.to_le_bytes()).collect(),
            passes_f32: passes,
            ..Default::default()
        }
    }

    #[test]
    fn a_workers_passes_are_checked_before_use() {
        let set = PassSet::parse("depth,instance").unwrap();
        let mut good = PassImage::new(2, 3, set);
        good.planes[1].fill(2.0);
        let px = decode_reply(&reply(good.to_bytes()), (4, 6), 3, set).unwrap();
        assert_eq!(px.passes.as_ref(), Some(&good));
        // Passes nobody asked for, too few bytes, an id that is no index,
        // a NaN depth: each the worker's failure, said so.
        let no = decode_reply(&reply(good.to_bytes()), (4, 6), 3, PassSet::NONE).unwrap_err();
        assert!(no.contains("nobody asked for"), "{no}");
        let short =
            decode_reply(&reply(good.to_bytes()[4..].to_vec()), (4, 6), 3, set).unwrap_err();
        assert!(short.contains("bytes where"), "{short}");
        let mut bad = good.clone();
        bad.planes[1][0] = 0.5;
        let e = decode_reply(&reply(bad.to_bytes()), (4, 6), 3, set).unwrap_err();
        assert!(e.contains("instance"), "{e}");
        bad = good.clone();
        bad.planes[0][0] = f32::NAN;
        assert!(
            decode_reply(&reply(bad.to_bytes()), (4, 6), 3, set).unwrap_err().contains("depth")
        );
        assert!(decode_reply(&reply(Vec::new()), (4, 6), 3, set).is_err(), "passes missing");
    }
}
