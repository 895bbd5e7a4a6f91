//! The worker's gRPC service: bundles cached by hash in a size-bounded LRU,
//! scenes prepared once per (bundle, structure, lighting) and strips
//! rendered one at a time on the GPU. Uploads are counted as they arrive,
//! against both their declared size and this worker's limits; a strip whose
//! caller has gone is not started.

use crate::gpu::GpuContext;
use crate::lighting::lb::SceneLb;
use crate::prepare::{PreparedScene, Reuse, prepare_reusing};
use crate::trace::RenderSettings;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use sylva_accel::AccelKind;
use sylva_proto::pb;
use sylva_proto::pb::worker_identity_server::{WorkerIdentity, WorkerIdentityServer};
use sylva_proto::pb::worker_server::{Worker, WorkerServer};
use sylva_proto::sync::lock;
use sylva_scene::bundle;
use sylva_scene::frame::FrameSettings;
use sylva_scene::sequence::View;
use sylva_scene::{LightingMode, Scene, SceneLimits};
use tokio_stream::StreamExt;
use tonic::{Request, Response, Status, Streaming};

pub use sylva_scene::frame::{MAX_SIDE, MAX_SPP};

/// How a worker runs.
#[derive(Clone, Debug)]
pub struct WorkerConfig {
    /// Largest bundle accepted, in bytes.
    pub max_bundle_bytes: u64,
    /// Bundles kept, at most, in bytes (least recently used go first).
    pub cache_bytes: u64,
    /// Where bundles are unpacked.
    pub cache_dir: PathBuf,
    /// When set, every worker-API and reflection call needs it as a bearer
    /// token (health checks stay open for orchestrators' probes).
    pub token: Option<String>,
    /// Serve over TLS with this identity.
    pub tls: Option<tonic::transport::ServerTlsConfig>,
    /// Per-scene caps on models, instances, triangles, texels and LB nodes.
    pub limits: SceneLimits,
    /// Keep `cache_dir` when the worker stops (default: removed).
    pub keep_cache: bool,
    /// LB light kept per scene and sun direction, so a sequence that comes
    /// back to a sun (or a second pass over a sun sweep) solves it once;
    /// 0: only the light of the sun being rendered is kept.
    pub lb_cache_entries: usize,
    /// Bytes of LB light kept at most, all suns together (the newest is
    /// kept whatever its size): fine grids make the count alone no bound.
    pub lb_cache_bytes: u64,
}

impl Default for WorkerConfig {
    fn default() -> Self {
        Self {
            max_bundle_bytes: 1 << 30,
            cache_bytes: 4 << 30,
            cache_dir: std::env::temp_dir().join(format!("sylva-worker-{}", std::process::id())),
            token: None,
            tls: None,
            limits: SceneLimits::default(),
            keep_cache: false,
            lb_cache_entries: 64,
            lb_cache_bytes: 1 << 30,
        }
    }
}

/// A cached bundle.
struct Cached {
    scene: Arc<Scene>,
    bytes: u64,
    last_used: Instant,
}

/// A prepared scene's key: bundle hash, structure, what the lighting needs
/// prepared, and the sun's bits where that depends on the sun (`None`: the
/// scene's own sun, or a method the sun does not change).
type PreparedKey = (String, AccelKind, crate::lighting::Needs, Option<[u32; 3]>);

/// A scene's LB light's key: bundle hash and the sun's bits (`None`: the
/// scene's own sun).
type LbKey = (String, Option<[u32; 3]>);

/// Sun variants of one scene kept prepared at once (the frame being
/// rendered and the one before, as strips of two frames overlap).
const PREPARED_SUNS: usize = 2;

/// What one frame of a loaded scene needs prepared.
struct Preparation {
    accel_key: (String, AccelKind),
    lb_key: LbKey,
    needs_lb: bool,
    scene: Arc<Scene>,
    frame: FrameSettings,
    lighting: LightingMode,
}

/// Bytes per chunk of exported prepared data.
const EXPORT_CHUNK: usize = 1 << 20;

/// A value and when it was last used.
struct Used<T> {
    value: T,
    stamp: u64,
}

/// What the service shares between requests.
struct State {
    ctx: GpuContext,
    config: WorkerConfig,
    bundles: Mutex<HashMap<String, Cached>>,
    /// Prepared scenes by (hash, structure, what the lighting needs
    /// prepared, sun).
    prepared: Mutex<HashMap<PreparedKey, Used<Arc<PreparedScene>>>>,
    /// Acceleration structures by (hash, structure): kept across views.
    accels: Mutex<HashMap<(String, AccelKind), Arc<sylva_accel::SceneAccel>>>,
    /// LB light by (hash, sun), least recently used dropped first.
    lbs: Mutex<HashMap<LbKey, Used<Arc<SceneLb>>>>,
    /// Use counter for the caches' recency.
    clock: AtomicU64,
    /// LB solves done, for status and benchmarks.
    lb_solves: AtomicU64,
    /// Acceleration structures built here.
    accel_builds: AtomicU64,
    /// Prepared data taken from other workers.
    prepared_imports: AtomicU64,
    /// Matched ambient constants by scene and frame shape.
    ambient: Mutex<HashMap<String, [f32; 3]>>,
    /// One GPU job at a time: strips queue here.
    gpu: Mutex<()>,
    /// Bytes of uploads in progress, so concurrent uploads share the limit.
    incoming: Mutex<u64>,
    busy: AtomicU32,
}

/// The `sylva.v1.Worker` service.
#[derive(Clone)]
pub struct WorkerService {
    state: Arc<State>,
}

impl WorkerService {
    /// A service rendering on `ctx`.
    pub fn new(ctx: GpuContext, config: WorkerConfig) -> Self {
        Self {
            state: Arc::new(State {
                ctx,
                config,
                bundles: Mutex::new(HashMap::new()),
                prepared: Mutex::new(HashMap::new()),
                accels: Mutex::new(HashMap::new()),
                lbs: Mutex::new(HashMap::new()),
                clock: AtomicU64::new(0),
                lb_solves: AtomicU64::new(0),
                accel_builds: AtomicU64::new(0),
                prepared_imports: AtomicU64::new(0),
                ambient: Mutex::new(HashMap::new()),
                gpu: Mutex::new(()),
                incoming: Mutex::new(0),
                busy: AtomicU32::new(0),
            }),
        }
    }

    /// The tonic server wrapper, with messages up to the bundle limit.
    pub fn into_server(self) -> WorkerServer<Self> {
        let limit = (self.state.config.max_bundle_bytes as usize).max(64 << 20);
        WorkerServer::new(self).max_decoding_message_size(limit).max_encoding_message_size(limit)
    }
}

impl State {
    /// Evicts least recently used bundles until `incoming` more bytes fit.
    fn make_room(&self, bundles: &mut HashMap<String, Cached>, incoming: u64) {
        while bundles.values().map(|c| c.bytes).sum::<u64>() + incoming > self.config.cache_bytes
            && !bundles.is_empty()
        {
            let oldest = bundles
                .iter()
                .min_by_key(|(_, c)| c.last_used)
                .map(|(h, _)| h.clone())
                .expect("not empty");
            bundles.remove(&oldest);
            lock(&self.prepared).retain(|k, _| k.0 != oldest);
            lock(&self.accels).retain(|k, _| k.0 != oldest);
            lock(&self.lbs).retain(|k, _| k.0 != oldest);
            let _ = std::fs::remove_dir_all(self.config.cache_dir.join(&oldest));
            tracing::info!(hash = %oldest, "evicted a scene bundle");
        }
    }
}

impl State {
    fn tick(&self) -> u64 {
        self.clock.fetch_add(1, Ordering::Relaxed)
    }

    /// The scene prepared for a frame's structure, lighting and view: kept
    /// from an earlier strip, or prepared now from the structures and the
    /// LB light kept for this sun, building only what is missing.
    fn prepared_for(
        &self,
        scene: &Scene,
        hash: &str,
        accel: AccelKind,
        lighting: LightingMode,
        view: &View,
    ) -> anyhow::Result<Arc<PreparedScene>> {
        let needs = crate::lighting::method(lighting).needs;
        let sun = if needs.lb || needs.clouds { view.sun_key() } else { None };
        let key = (hash.to_string(), accel, crate::lighting::method(lighting).needs, sun);
        if let Some(p) = lock(&self.prepared).get_mut(&key) {
            p.stamp = self.tick();
            return Ok(p.value.clone());
        }
        let lb_key = (hash.to_string(), sun);
        let mut reuse = Reuse {
            accel: lock(&self.accels).get(&(hash.to_string(), accel)).cloned(),
            lb: if needs.lb {
                lock(&self.lbs).get_mut(&lb_key).map(|l| {
                    l.stamp = self.tick();
                    l.value.clone()
                })
            } else {
                None
            },
        };
        let (solved_before, built_before) = (reuse.lb.is_some(), reuse.accel.is_some());
        let scene = scene.with_view(view);
        let p = Arc::new(prepare_reusing(&self.ctx, &scene, accel, lighting, &mut reuse, &|m| {
            tracing::info!("{m}")
        })?);
        if let (Some(a), false) = (reuse.accel, built_before) {
            self.accel_builds.fetch_add(1, Ordering::Relaxed);
            lock(&self.accels).insert((hash.to_string(), accel), a);
        }
        if let (Some(lb), false) = (reuse.lb, solved_before) {
            self.lb_solves.fetch_add(1, Ordering::Relaxed);
            self.keep_lb(lb_key, lb);
        }
        let mut prepared = lock(&self.prepared);
        prepared.insert(key.clone(), Used { value: p.clone(), stamp: self.tick() });
        // Each sun variant holds the whole scene on the GPU: keep the
        // newest few of this scene's.
        loop {
            let variants: Vec<(&PreparedKey, u64)> = prepared
                .iter()
                .filter(|(k, _)| (&k.0, k.1, k.2) == (&key.0, key.1, key.2))
                .map(|(k, u)| (k, u.stamp))
                .collect();
            if variants.len() <= PREPARED_SUNS {
                break;
            }
            let oldest =
                variants.iter().min_by_key(|v| v.1).map(|v| v.0.clone()).expect("not empty");
            prepared.remove(&oldest);
        }
        Ok(p)
    }

    /// Keeps `lb` for its scene and sun, dropping the least recently used
    /// beyond the configured count and bytes.
    fn keep_lb(&self, key: LbKey, lb: Arc<SceneLb>) {
        let mut lbs = lock(&self.lbs);
        lbs.insert(key, Used { value: lb, stamp: self.tick() });
        let keep = self.config.lb_cache_entries.max(1);
        let bytes = |lbs: &HashMap<LbKey, Used<Arc<SceneLb>>>| {
            lbs.values().map(|u| u.value.bytes()).sum::<u64>()
        };
        while lbs.len() > keep || (lbs.len() > 1 && bytes(&lbs) > self.config.lb_cache_bytes) {
            let oldest =
                lbs.iter().min_by_key(|(_, u)| u.stamp).map(|(k, _)| k.clone()).expect("not empty");
            lbs.remove(&oldest);
        }
    }

    /// A loaded scene by hash, marked used.
    fn scene(&self, hash: &str) -> Result<Arc<Scene>, Status> {
        let mut bundles = lock(&self.bundles);
        let c = bundles.get_mut(hash).ok_or_else(|| {
            Status::not_found(format!("scene {hash} is not loaded here; LoadScene it first"))
        })?;
        c.last_used = Instant::now();
        Ok(c.scene.clone())
    }

    /// What a frame of a loaded scene needs prepared: the scene, the keys
    /// of its structures and LB light, and whether it needs the light.
    fn preparation(
        &self,
        scene_hash: &str,
        frame: Option<&pb::FrameSettings>,
    ) -> Result<Preparation, Status> {
        let f = FrameSettings::try_from(
            frame.ok_or_else(|| Status::invalid_argument("frame settings missing"))?,
        )?;
        let hash = normalize_hash(scene_hash)?;
        let scene = self.scene(&hash)?;
        let lighting = f.lighting_or(scene.lighting);
        let needs = crate::lighting::method(lighting).needs;
        let sun = if needs.lb || needs.clouds { f.view.sun_key() } else { None };
        Ok(Preparation {
            accel_key: (hash.clone(), f.accel),
            lb_key: (hash, sun),
            needs_lb: needs.lb,
            scene,
            frame: f,
            lighting,
        })
    }

    /// The structures and LB light held for `p`, if all it needs is held.
    fn held(
        &self,
        p: &Preparation,
    ) -> Option<(Arc<sylva_accel::SceneAccel>, Option<Arc<SceneLb>>)> {
        let accel = lock(&self.accels).get(&p.accel_key).cloned()?;
        if !p.needs_lb {
            return Some((accel, None));
        }
        let lb = lock(&self.lbs).get(&p.lb_key).map(|u| u.value.clone())?;
        Some((accel, Some(lb)))
    }

    /// LB solves this worker has done.
    pub fn lb_solves(&self) -> u64 {
        self.lb_solves.load(Ordering::Relaxed)
    }
}

/// Releases its share of the upload budget however the upload ends.
struct Reservation<'a> {
    incoming: &'a Mutex<u64>,
    bytes: u64,
}

impl Reservation<'_> {
    /// Takes `more` bytes of `limit`, or says no.
    fn grow(&mut self, more: u64, limit: u64) -> bool {
        let mut inc = lock(self.incoming);
        if *inc + more > limit {
            return false;
        }
        *inc += more;
        self.bytes += more;
        true
    }
}

impl Drop for Reservation<'_> {
    fn drop(&mut self) {
        *lock(self.incoming) -= self.bytes;
    }
}

impl State {
    /// Receives a chunked upload of `what` (a bundle, prepared data) whose
    /// first chunk declared `total` bytes and carried `first`. Nothing is
    /// reserved from the sender's claim: bytes are counted as they arrive,
    /// against the claim, `max_bundle_bytes` and the room all uploads in
    /// progress share. Returns the bytes and their reservation, to be held
    /// until they are kept.
    async fn receive<C>(
        &self,
        what: &str,
        total: u64,
        first: Vec<u8>,
        rest: &mut Streaming<C>,
        data: impl Fn(C) -> Vec<u8>,
    ) -> Result<(Vec<u8>, Reservation<'_>), Status> {
        let limit = self.config.max_bundle_bytes;
        if total > limit {
            return Err(Status::resource_exhausted(format!(
                "{what} of {total} bytes is over this worker's limit of {limit} bytes"
            )));
        }
        let mut held = Reservation { incoming: &self.incoming, bytes: 0 };
        let mut bytes = Vec::new();
        let mut chunk = Some(first);
        while let Some(d) = chunk.take() {
            let n = d.len() as u64;
            if bytes.len() as u64 + n > total {
                return Err(Status::invalid_argument(format!(
                    "{what} is longer than its declared {total} bytes"
                )));
            }
            if !held.grow(n, self.config.cache_bytes.max(limit)) {
                return Err(Status::resource_exhausted(
                    "this worker is receiving as many bytes as it can hold; try again",
                ));
            }
            bytes.extend_from_slice(&d);
            chunk = rest.next().await.transpose()?.map(&data);
        }
        if (bytes.len() as u64) < total {
            return Err(Status::invalid_argument(format!(
                "truncated {what}: {} of {total} bytes",
                bytes.len()
            )));
        }
        Ok((bytes, held))
    }
}

/// Sets its flag when dropped: a handler future dropped before it finished
/// means the caller cancelled or went away.
struct CancelOnDrop(Arc<AtomicBool>, bool);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        if !self.1 {
            self.0.store(true, Ordering::SeqCst);
        }
    }
}

/// A hash as the cache keys it: 64 lower-case hex digits.
fn normalize_hash(h: &str) -> Result<String, Status> {
    let hash = h.to_ascii_lowercase();
    if hash.len() != 64 || !hash.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(Status::invalid_argument(format!(
            "hash {:?} is not a 64-digit hex BLAKE3 hash",
            sylva_scene::sandbox::clip(h)
        )));
    }
    Ok(hash)
}

#[tonic::async_trait]
impl Worker for WorkerService {
    async fn load_scene(
        &self,
        request: Request<Streaming<pb::SceneChunk>>,
    ) -> Result<Response<pb::LoadSceneReply>, Status> {
        let mut stream = request.into_inner();
        let first = stream
            .next()
            .await
            .ok_or_else(|| Status::invalid_argument("empty upload: no chunk"))??;
        let hash = normalize_hash(&first.hash)?;
        if let Some(c) = lock(&self.state.bundles).get_mut(&hash) {
            c.last_used = Instant::now();
            return Ok(Response::new(pb::LoadSceneReply { hash, was_cached: true }));
        }
        let (bytes, held) = self
            .state
            .receive("bundle", first.total_size, first.data, &mut stream, |c| c.data)
            .await?;
        if bundle::hash_of(&bytes) != hash {
            return Err(Status::invalid_argument("the bundle's bytes do not match its hash"));
        }
        let dir = self.state.config.cache_dir.join(&hash);
        let limits = self.state.config.limits;
        let unpacked = tokio::task::spawn_blocking(move || {
            let r = bundle::unpack_with(&bytes, &dir, &limits);
            if r.is_err() {
                let _ = std::fs::remove_dir_all(&dir);
            }
            r
        })
        .await
        .map_err(|e| Status::internal(e.to_string()))?;
        let scene = unpacked.map_err(|e| Status::invalid_argument(format!("{e:#}")))?;
        let size = held.bytes;
        drop(held);
        let mut bundles = lock(&self.state.bundles);
        self.state.make_room(&mut bundles, size);
        bundles.insert(
            hash.clone(),
            Cached { scene: Arc::new(scene), bytes: size, last_used: Instant::now() },
        );
        tracing::info!(%hash, bytes = size, "cached a scene bundle");
        Ok(Response::new(pb::LoadSceneReply { hash, was_cached: false }))
    }

    async fn render_strip(
        &self,
        request: Request<pb::RenderStripRequest>,
    ) -> Result<Response<pb::RenderStripReply>, Status> {
        let r = request.into_inner();
        let f = FrameSettings::try_from(
            r.frame.as_ref().ok_or_else(|| Status::invalid_argument("frame settings missing"))?,
        )?;
        if r.x0 >= r.x1 || r.x1 > f.width {
            return Err(Status::invalid_argument(format!(
                "strip [{}, {}) is not inside a frame {} wide",
                r.x0, r.x1, f.width
            )));
        }
        let hash = normalize_hash(&r.scene_hash)?;
        let scene = self.state.scene(&hash)?;
        let settings = RenderSettings::resolve(&f, scene.lighting);
        let (lighting, accel) = (settings.lighting, f.accel);
        let view = f.view;
        let ambient_given = f.ambient.is_some();
        let cancelled = Arc::new(AtomicBool::new(false));
        let mut guard = CancelOnDrop(cancelled.clone(), false);
        let state = self.state.clone();
        state.busy.fetch_add(1, Ordering::SeqCst);
        let span = tracing::info_span!("strip", x0 = r.x0, x1 = r.x1, scene = %hash);
        let result = tokio::task::spawn_blocking(move || {
            let _g = span.enter();
            let _gpu = lock(&state.gpu);
            // Strips queue for the GPU; one whose caller left meanwhile is
            // not worth starting.
            anyhow::ensure!(!cancelled.load(Ordering::SeqCst), Cancelled);
            let t = Instant::now();
            let prepared = state.prepared_for(&scene, &hash, accel, lighting, &view)?;
            let mut settings = settings;
            if lighting == LightingMode::Ambient && !ambient_given {
                // Matched here, once per frame shape, so every client gets
                // the paper's ambient without a round of its own.
                let key = format!(
                    "{hash}/{accel:?}/{}x{}/{}/{}/{:?}",
                    settings.width, settings.height, settings.seed, settings.lb_strength, view
                );
                let known = lock(&state.ambient).get(&key).copied();
                settings.ambient = match known {
                    Some(a) => a,
                    None => {
                        let a = crate::lighting::ambient::matched(
                            &prepared.renderer,
                            &state.ctx,
                            &settings,
                        )?;
                        lock(&state.ambient).insert(key, a);
                        a
                    }
                };
            }
            let prepare_ms = t.elapsed().as_secs_f64() * 1e3;
            anyhow::ensure!(!cancelled.load(Ordering::SeqCst), Cancelled);
            let t = Instant::now();
            let strip = prepared.renderer.render_strip(&state.ctx, &settings, r.x0, r.x1)?;
            anyhow::Ok((strip, prepare_ms, t.elapsed().as_secs_f64() * 1e3))
        })
        .await;
        guard.1 = true;
        self.state.busy.fetch_sub(1, Ordering::SeqCst);
        let (strip, prepare_ms, render_ms) = result
            .map_err(|e| Status::internal(format!("the strip's render panicked: {e}")))?
            .map_err(|e| {
                if e.is::<Cancelled>() {
                    Status::cancelled("the caller cancelled the strip")
                } else {
                    Status::internal(format!("{e:#}"))
                }
            })?;
        Ok(Response::new(pb::RenderStripReply {
            x0: strip.x0,
            width: strip.width,
            height: f.height,
            rgb_f32: strip.pixels.iter().flatten().flat_map(|v| v.to_le_bytes()).collect(),
            coverage_f32: strip.coverage.iter().flat_map(|v| v.to_le_bytes()).collect(),
            rays: Some(pb::RayCounts {
                primary: strip.rays.primary,
                shadow: strip.rays.shadow,
                transparent: strip.rays.transparent,
            }),
            render_ms,
            prepare_ms,
        }))
    }

    async fn status(
        &self,
        _: Request<pb::StatusRequest>,
    ) -> Result<Response<pb::WorkerStatus>, Status> {
        let cached: Vec<String> = lock(&self.state.bundles).keys().cloned().collect();
        let gpu_bytes =
            lock(&self.state.prepared).values().map(|p| p.value.renderer.scene_bytes()).sum();
        Ok(Response::new(pb::WorkerStatus {
            adapter: self.state.ctx.adapter_name(),
            gpu_memory_bytes: gpu_bytes,
            cached_scenes: cached,
            busy_strips: self.state.busy.load(Ordering::SeqCst),
            lb_solves: self.state.lb_solves(),
            accel_builds: self.state.accel_builds.load(Ordering::Relaxed),
            prepared_imports: self.state.prepared_imports.load(Ordering::Relaxed),
        }))
    }

    async fn prepare(
        &self,
        request: Request<pb::PrepareRequest>,
    ) -> Result<Response<pb::PrepareReply>, Status> {
        let r = request.into_inner();
        let p = self.state.preparation(&r.scene_hash, r.frame.as_ref())?;
        let t = Instant::now();
        let held = self.state.held(&p).is_some();
        if held || !r.build {
            return Ok(Response::new(pb::PrepareReply { held, prepare_ms: 0.0 }));
        }
        let state = self.state.clone();
        let span = tracing::info_span!("prepare", scene = %p.accel_key.0);
        tokio::task::spawn_blocking(move || {
            let _g = span.enter();
            let _gpu = lock(&state.gpu);
            state
                .prepared_for(&p.scene, &p.accel_key.0, p.frame.accel, p.lighting, &p.frame.view)
                .map(|_| ())
        })
        .await
        .map_err(|e| Status::internal(format!("preparing panicked: {e}")))?
        .map_err(|e| Status::internal(format!("{e:#}")))?;
        Ok(Response::new(pb::PrepareReply {
            held: true,
            prepare_ms: t.elapsed().as_secs_f64() * 1e3,
        }))
    }

    type ExportPreparedStream = std::pin::Pin<
        Box<dyn tokio_stream::Stream<Item = Result<pb::PreparedChunk, Status>> + Send>,
    >;

    async fn export_prepared(
        &self,
        request: Request<pb::PrepareRequest>,
    ) -> Result<Response<Self::ExportPreparedStream>, Status> {
        let r = request.into_inner();
        let p = self.state.preparation(&r.scene_hash, r.frame.as_ref())?;
        let (accel, lb) = self.state.held(&p).ok_or_else(|| {
            Status::not_found("this worker does not hold that frame's prepared data")
        })?;
        let out = tokio::task::spawn_blocking(move || crate::share::export(&accel, lb.as_deref()))
            .await
            .map_err(|e| Status::internal(format!("exporting panicked: {e}")))?
            .map_err(|e| Status::internal(format!("{e:#}")))?;
        let (total, hash, frame, scene_hash) =
            (out.bytes.len() as u64, out.hash, r.frame, p.accel_key.0);
        let chunks: Vec<Result<pb::PreparedChunk, Status>> = out
            .bytes
            .chunks(EXPORT_CHUNK)
            .enumerate()
            .map(|(i, c)| {
                let first = i == 0;
                Ok(pb::PreparedChunk {
                    scene_hash: if first { scene_hash.clone() } else { String::new() },
                    frame: if first { frame.clone() } else { None },
                    content_hash: if first { hash.clone() } else { String::new() },
                    total_size: if first { total } else { 0 },
                    data: c.to_vec(),
                })
            })
            .collect();
        Ok(Response::new(Box::pin(tokio_stream::iter(chunks))))
    }

    async fn import_prepared(
        &self,
        request: Request<Streaming<pb::PreparedChunk>>,
    ) -> Result<Response<pb::PrepareReply>, Status> {
        let t = Instant::now();
        let mut stream = request.into_inner();
        let first = stream
            .next()
            .await
            .ok_or_else(|| Status::invalid_argument("empty import: no chunk"))??;
        let p = self.state.preparation(&first.scene_hash, first.frame.as_ref())?;
        let content_hash = normalize_hash(&first.content_hash)?;
        let (bytes, held) = self
            .state
            .receive("prepared data", first.total_size, first.data, &mut stream, |c| c.data)
            .await?;
        let (scene, kind, needs_lb) = (p.scene.clone(), p.frame.accel, p.needs_lb);
        let (accel, lb) = tokio::task::spawn_blocking(move || {
            crate::share::import(&bytes, &content_hash, &scene, kind, needs_lb)
        })
        .await
        .map_err(|e| Status::internal(format!("importing panicked: {e}")))?
        .map_err(|e| Status::invalid_argument(format!("prepared data refused: {e}")))?;
        drop(held);
        lock(&self.state.accels).entry(p.accel_key.clone()).or_insert_with(|| Arc::new(accel));
        if let Some(lb) = lb
            && !lock(&self.state.lbs).contains_key(&p.lb_key)
        {
            self.state.keep_lb(p.lb_key.clone(), Arc::new(lb));
        }
        self.state.prepared_imports.fetch_add(1, Ordering::Relaxed);
        tracing::info!(scene = %p.accel_key.0, "took prepared data from another worker");
        Ok(Response::new(pb::PrepareReply {
            held: self.state.held(&p).is_some(),
            prepare_ms: t.elapsed().as_secs_f64() * 1e3,
        }))
    }
}

/// Why a strip was not rendered: its caller went away first.
#[derive(Debug, thiserror::Error)]
#[error("cancelled")]
struct Cancelled;

/// Answers a coordinator's identity challenge with this worker's token.
struct Identity {
    token: Option<String>,
}

#[tonic::async_trait]
impl WorkerIdentity for Identity {
    async fn prove(
        &self,
        request: Request<pb::ProveRequest>,
    ) -> Result<Response<pb::ProveReply>, Status> {
        let nonce = request.into_inner().nonce;
        if nonce.len() < 16 || nonce.len() > 64 {
            return Err(Status::invalid_argument("the nonce must be 16 to 64 bytes"));
        }
        Ok(Response::new(pb::ProveReply {
            proof: sylva_proto::auth::prove(self.token.as_deref(), &nonce).to_vec(),
        }))
    }
}

/// Serves the worker API, health (SERVING once the GPU is open),
/// reflection and the identity check on `listener` until `shutdown`
/// resolves; then removes the bundle cache unless asked to keep it.
pub async fn run(
    listener: tokio::net::TcpListener,
    ctx: GpuContext,
    config: WorkerConfig,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let (reporter, health) = tonic_health::server::health_reporter();
    reporter.set_not_serving::<WorkerServer<WorkerService>>().await;
    let (reflection, reflection_alpha) =
        sylva_proto::reflection(&["sylva.v1.Worker", "sylva.v1.WorkerIdentity"])?;
    let auth = sylva_proto::auth::require(config.token.clone());
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = config.tls.clone() {
        builder = builder.tls_config(tls)?;
    }
    let (cache_dir, keep) = (config.cache_dir.clone(), config.keep_cache);
    let identity = Identity { token: config.token.clone() };
    let service = WorkerService::new(ctx, config);
    reporter.set_serving::<WorkerServer<WorkerService>>().await;
    let served = builder
        .add_service(health)
        .add_service(WorkerIdentityServer::new(identity))
        .add_service(tonic::service::interceptor::InterceptedService::new(reflection, auth.clone()))
        .add_service(tonic::service::interceptor::InterceptedService::new(
            reflection_alpha,
            auth.clone(),
        ))
        .add_service(tonic::service::interceptor::InterceptedService::new(
            service.into_server(),
            auth,
        ))
        .serve_with_incoming_shutdown(
            tokio_stream::wrappers::TcpListenerStream::new(listener),
            shutdown,
        )
        .await;
    if !keep && cache_dir.exists() {
        match std::fs::remove_dir_all(&cache_dir) {
            Ok(()) => tracing::info!(dir = %cache_dir.display(), "removed the bundle cache"),
            Err(e) => {
                tracing::warn!(dir = %cache_dir.display(), "cannot remove the bundle cache: {e}")
            }
        }
    }
    served?;
    Ok(())
}
