//! The worker's gRPC service: bundles cached by hash in a size-bounded LRU,
//! scenes prepared once per (bundle, structure, lighting) and strips
//! rendered one at a time on the GPU.

use crate::gpu::GpuContext;
use crate::prepare::{PreparedScene, prepare};
use crate::trace::FrameSettings;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use sylva_proto::pb;
use sylva_proto::pb::worker_server::{Worker, WorkerServer};
use sylva_shared::accel::AccelKind;
use sylva_shared::bundle;
use sylva_shared::scene::{LightingMode, Scene};
use tokio_stream::StreamExt;
use tonic::{Request, Response, Status, Streaming};

/// Largest image side a strip request may name.
pub const MAX_SIDE: u32 = 16_384;
/// Most rays per pixel a strip request may ask for.
pub const MAX_SPP: u32 = 4_096;

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
}

impl Default for WorkerConfig {
    fn default() -> Self {
        Self {
            max_bundle_bytes: 1 << 30,
            cache_bytes: 4 << 30,
            cache_dir: std::env::temp_dir().join(format!("sylva-worker-{}", std::process::id())),
            token: None,
            tls: None,
        }
    }
}

/// A cached bundle.
struct Cached {
    scene: Arc<Scene>,
    bytes: u64,
    last_used: Instant,
}

/// What the service shares between requests.
struct State {
    ctx: GpuContext,
    config: WorkerConfig,
    bundles: Mutex<HashMap<String, Cached>>,
    /// Prepared scenes by (hash, structure, what the lighting needs prepared).
    prepared: Mutex<HashMap<(String, AccelKind, &'static str), Arc<PreparedScene>>>,
    /// Matched ambient constants by scene and frame shape.
    ambient: Mutex<HashMap<String, [f32; 3]>>,
    /// One GPU job at a time: strips queue here.
    gpu: Mutex<()>,
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
                ambient: Mutex::new(HashMap::new()),
                gpu: Mutex::new(()),
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
        while bundles.values().map(|c| c.bytes).sum::<u64>() + incoming > self.config.cache_bytes && !bundles.is_empty() {
            let oldest = bundles.iter().min_by_key(|(_, c)| c.last_used).map(|(h, _)| h.clone()).expect("not empty");
            bundles.remove(&oldest);
            self.prepared.lock().expect("lock").retain(|k, _| k.0 != oldest);
            let _ = std::fs::remove_dir_all(self.config.cache_dir.join(&oldest));
            tracing::info!(hash = %oldest, "evicted a scene bundle");
        }
    }
}

fn parse_lighting(s: &str, scene: &Scene) -> Result<LightingMode, Status> {
    Ok(match s {
        "" => scene.lighting,
        o => LightingMode::from_name(o).ok_or_else(|| {
            let names: Vec<&str> = LightingMode::ALL.iter().map(|m| m.name()).collect();
            Status::invalid_argument(format!("lighting {o:?}: one of {}", names.join(", ")))
        })?,
    })
}

fn parse_accel(s: &str) -> Result<AccelKind, Status> {
    match s {
        "" | "bvh" => Ok(AccelKind::Bvh),
        "kd" => Ok(AccelKind::Kd),
        o => Err(Status::invalid_argument(format!("accel {o:?}: one of kd, bvh"))),
    }
}

/// Checks a frame's sizes: the limits every render request obeys.
pub fn check_frame(f: &pb::FrameSettings) -> Result<(), Status> {
    if f.width == 0 || f.height == 0 || f.width > MAX_SIDE || f.height > MAX_SIDE {
        return Err(Status::invalid_argument(format!("image {}×{}: each side must be in [1, {MAX_SIDE}]", f.width, f.height)));
    }
    if f.spp == 0 || f.spp > MAX_SPP {
        return Err(Status::invalid_argument(format!("spp {}: valid range [1, {MAX_SPP}]", f.spp)));
    }
    if !(f.lb_strength.is_finite() && f.lb_strength >= 0.0) {
        return Err(Status::invalid_argument(format!("lb_strength {}: must be finite and ≥ 0", f.lb_strength)));
    }
    if !(f.ambient.is_empty() || (f.ambient.len() == 3 && f.ambient.iter().all(|v| v.is_finite() && *v >= 0.0))) {
        return Err(Status::invalid_argument("ambient: three finite values ≥ 0, or none"));
    }
    Ok(())
}

#[tonic::async_trait]
impl Worker for WorkerService {
    async fn load_scene(&self, request: Request<Streaming<pb::SceneChunk>>) -> Result<Response<pb::LoadSceneReply>, Status> {
        let mut stream = request.into_inner();
        let first = stream.next().await.ok_or_else(|| Status::invalid_argument("empty upload: no chunk"))??;
        let hash = first.hash.to_ascii_lowercase();
        if hash.len() != 64 || !hash.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(Status::invalid_argument(format!("hash {:?} is not a 64-digit hex BLAKE3 hash", first.hash)));
        }
        if let Some(c) = self.state.bundles.lock().expect("lock").get_mut(&hash) {
            c.last_used = Instant::now();
            return Ok(Response::new(pb::LoadSceneReply { hash, was_cached: true }));
        }
        let total = first.total_size;
        if total > self.state.config.max_bundle_bytes {
            return Err(Status::resource_exhausted(format!(
                "bundle of {total} bytes is over this worker's limit of {} bytes",
                self.state.config.max_bundle_bytes
            )));
        }
        let mut bytes = Vec::with_capacity(total as usize);
        bytes.extend_from_slice(&first.data);
        while let Some(chunk) = stream.next().await {
            bytes.extend_from_slice(&chunk?.data);
            if bytes.len() as u64 > total {
                return Err(Status::invalid_argument(format!("upload is longer than its declared {total} bytes")));
            }
        }
        if (bytes.len() as u64) < total {
            return Err(Status::invalid_argument(format!("truncated upload: {} of {total} bytes", bytes.len())));
        }
        if bundle::hash_of(&bytes) != hash {
            return Err(Status::invalid_argument("the bundle's bytes do not match its hash"));
        }
        let dir = self.state.config.cache_dir.join(&hash);
        let scene = tokio::task::spawn_blocking(move || bundle::unpack(&bytes, &dir))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(|e| Status::invalid_argument(format!("{e:#}")))?;
        let mut bundles = self.state.bundles.lock().expect("lock");
        self.state.make_room(&mut bundles, total);
        bundles.insert(hash.clone(), Cached { scene: Arc::new(scene), bytes: total, last_used: Instant::now() });
        tracing::info!(%hash, bytes = total, "cached a scene bundle");
        Ok(Response::new(pb::LoadSceneReply { hash, was_cached: false }))
    }

    async fn render_strip(&self, request: Request<pb::RenderStripRequest>) -> Result<Response<pb::RenderStripReply>, Status> {
        let r = request.into_inner();
        let f = r.frame.ok_or_else(|| Status::invalid_argument("frame settings missing"))?;
        check_frame(&f)?;
        if r.x0 >= r.x1 || r.x1 > f.width {
            return Err(Status::invalid_argument(format!("strip [{}, {}) is not inside a frame {} wide", r.x0, r.x1, f.width)));
        }
        let scene = {
            let mut bundles = self.state.bundles.lock().expect("lock");
            let c = bundles.get_mut(&r.scene_hash).ok_or_else(|| Status::not_found(format!("scene {} is not loaded here; LoadScene it first", r.scene_hash)))?;
            c.last_used = Instant::now();
            c.scene.clone()
        };
        let lighting = parse_lighting(&f.lighting, &scene)?;
        let accel = parse_accel(&f.accel)?;
        let settings = FrameSettings {
            width: f.width,
            height: f.height,
            spp: f.spp,
            seed: f.seed,
            lighting,
            ambient: if f.ambient.len() == 3 { [f.ambient[0], f.ambient[1], f.ambient[2]] } else { [0.0; 3] },
            lb_strength: f.lb_strength,
        };
        let ambient_given = f.ambient.len() == 3;
        let state = self.state.clone();
        state.busy.fetch_add(1, Ordering::SeqCst);
        let span = tracing::info_span!("strip", x0 = r.x0, x1 = r.x1, scene = %r.scene_hash);
        let result = tokio::task::spawn_blocking(move || {
            let _g = span.enter();
            let _gpu = state.gpu.lock().expect("lock");
            let key = (r.scene_hash.clone(), accel, lighting.preparation());
            let t = Instant::now();
            let cached = state.prepared.lock().expect("lock").get(&key).cloned();
            let prepared = match cached {
                Some(p) => p,
                None => {
                    let p = Arc::new(prepare(&state.ctx, &scene, accel, lighting, &|m| tracing::info!("{m}"))?);
                    state.prepared.lock().expect("lock").insert(key, p.clone());
                    p
                }
            };
            let mut settings = settings;
            if lighting == LightingMode::Ambient && !ambient_given {
                // Matched here, once per frame shape, so every client gets
                // the paper's ambient without a round of its own.
                let key = format!("{}/{:?}/{}x{}/{}/{}", r.scene_hash, accel, settings.width, settings.height, settings.seed, settings.lb_strength);
                let known = state.ambient.lock().expect("lock").get(&key).copied();
                settings.ambient = match known {
                    Some(a) => a,
                    None => {
                        let a = prepared.renderer.matched_ambient(&state.ctx, &settings)?;
                        state.ambient.lock().expect("lock").insert(key, a);
                        a
                    }
                };
            }
            let prepare_ms = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let strip = prepared.renderer.render_strip(&state.ctx, &settings, r.x0, r.x1)?;
            anyhow::Ok((strip, prepare_ms, t.elapsed().as_secs_f64() * 1e3))
        })
        .await;
        self.state.busy.fetch_sub(1, Ordering::SeqCst);
        let (strip, prepare_ms, render_ms) = result.map_err(|e| Status::internal(e.to_string()))?.map_err(|e| Status::internal(format!("{e:#}")))?;
        Ok(Response::new(pb::RenderStripReply {
            x0: strip.x0,
            width: strip.width,
            height: f.height,
            rgb_f32: strip.pixels.iter().flatten().flat_map(|v| v.to_le_bytes()).collect(),
            coverage_f32: strip.coverage.iter().flat_map(|v| v.to_le_bytes()).collect(),
            rays: Some(pb::RayCounts { primary: strip.rays.primary as u64, shadow: strip.rays.shadow as u64, transparent: strip.rays.transparent as u64 }),
            render_ms,
            prepare_ms,
        }))
    }

    async fn status(&self, _: Request<pb::StatusRequest>) -> Result<Response<pb::WorkerStatus>, Status> {
        let cached: Vec<String> = self.state.bundles.lock().expect("lock").keys().cloned().collect();
        let gpu_bytes = self.state.prepared.lock().expect("lock").values().map(|p| p.renderer.scene_bytes()).sum();
        Ok(Response::new(pb::WorkerStatus {
            adapter: self.state.ctx.adapter_name(),
            gpu_memory_bytes: gpu_bytes,
            cached_scenes: cached,
            busy_strips: self.state.busy.load(Ordering::SeqCst),
        }))
    }
}

/// Serves the worker API, health (SERVING once the GPU is open) and
/// reflection on `listener` until `shutdown` resolves.
pub async fn run(
    listener: tokio::net::TcpListener,
    ctx: GpuContext,
    config: WorkerConfig,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let (reporter, health) = tonic_health::server::health_reporter();
    reporter.set_not_serving::<pb::worker_server::WorkerServer<WorkerService>>().await;
    let reflection = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(pb::FILE_DESCRIPTOR_SET)
        .build_v1()?;
    let auth = sylva_proto::auth::require(config.token.clone());
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = config.tls.clone() {
        builder = builder.tls_config(tls)?;
    }
    let service = WorkerService::new(ctx, config);
    reporter.set_serving::<pb::worker_server::WorkerServer<WorkerService>>().await;
    builder
        .add_service(health)
        .add_service(tonic::service::interceptor::InterceptedService::new(reflection, auth.clone()))
        .add_service(tonic::service::interceptor::InterceptedService::new(service.into_server(), auth))
        .serve_with_incoming_shutdown(tokio_stream::wrappers::TcpListenerStream::new(listener), shutdown)
        .await?;
    Ok(())
}
