//! The `sylva.v1.Worker` API: load a bundle, render a strip, report status,
//! prepare, and export or import prepared data.

use super::cache::{BundleCaches, Cached};
use super::{Via, WorkerService, normalize_hash};
use crate::frame::{Cancelled, Frame};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use sylva_proto::pb;
use sylva_proto::pb::worker_server::Worker;
use sylva_proto::sync::lock;
use sylva_scene::bundle;
use sylva_scene::frame::FrameSettings;
use tokio_stream::StreamExt;
use tonic::{Request, Response, Status, Streaming};

/// Bytes per chunk of exported prepared data.
const EXPORT_CHUNK: usize = 1 << 20;

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

/// Counts one strip in flight on the GPU while it lives.
struct Busy<'a>(&'a std::sync::atomic::AtomicU32);

impl Drop for Busy<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
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
        drop(bundles);
        self.state.bound_memory(&hash);
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
        self.state.scope(&hash, &r.job);
        let scene = self.state.scene(&hash)?;
        let height = f.height;
        let cancelled = Arc::new(AtomicBool::new(false));
        // A caller that goes away (a cancelled job, a coordinator gone)
        // drops this future: the render hears of it between dispatches.
        let mut guard = CancelOnDrop(cancelled.clone(), false);
        let state = self.state.clone();
        state.busy.fetch_add(1, Ordering::SeqCst);
        let span = tracing::info_span!("strip", x0 = r.x0, x1 = r.x1, scene = %hash);
        let result = tokio::task::spawn_blocking(move || {
            let _g = span.enter();
            // Busy until the GPU work ends, whether the caller waits or not.
            let _busy = Busy(&state.busy);
            let _gpu = lock(&state.gpu);
            // Strips queue for the GPU; one whose caller left meanwhile is
            // not worth starting.
            anyhow::ensure!(!cancelled.load(Ordering::SeqCst), Cancelled);
            let t = Instant::now();
            // The ambient is matched here, once per frame shape, so every
            // client gets the paper's ambient without a round of its own.
            let mut caches = BundleCaches { state: &state, hash: &hash };
            let frame =
                Frame::compose(&state.ctx, &scene, &f, &mut caches, &|m| tracing::info!("{m}"))?;
            let prepare_ms = t.elapsed().as_secs_f64() * 1e3;
            anyhow::ensure!(!cancelled.load(Ordering::SeqCst), Cancelled);
            let t = Instant::now();
            let key = format!(
                "{hash} {}x{} {} {:?} {:?} {}",
                f.width, f.height, f.spp, frame.settings.lighting, f.accel, f.gather_bounces
            );
            let mut rate = lock(&state.strip_rates).get(&key).copied();
            let stop = || cancelled.load(Ordering::SeqCst);
            let strip = frame.strip_until(r.x0, r.x1, &stop, &mut rate);
            if let Some(r) = rate {
                let mut rates = lock(&state.strip_rates);
                // A bound, not a cache policy: rates are cheap to measure again.
                if rates.len() > 1024 {
                    rates.clear();
                }
                rates.insert(key, r);
            }
            let strip = strip?;
            anyhow::Ok((strip, prepare_ms, t.elapsed().as_secs_f64() * 1e3, frame.warnings()))
        })
        .await;
        guard.1 = true;
        let (strip, prepare_ms, render_ms, warnings) = result
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
            height,
            rgb_f32: strip.pixels.iter().flatten().flat_map(|v| v.to_le_bytes()).collect(),
            coverage_f32: strip.coverage.iter().flat_map(|v| v.to_le_bytes()).collect(),
            rays: Some(pb::RayCounts {
                primary: strip.rays.primary,
                shadow: strip.rays.shadow,
                transparent: strip.rays.transparent,
            }),
            render_ms,
            prepare_ms,
            passes_f32: strip.passes.map(|p| p.to_bytes()).unwrap_or_default(),
            warnings,
        }))
    }

    async fn status(
        &self,
        _: Request<pb::StatusRequest>,
    ) -> Result<Response<pb::WorkerStatus>, Status> {
        let cached: Vec<String> = lock(&self.state.bundles).keys().cloned().collect();
        let gpu_bytes =
            lock(&self.state.prepared).values().map(|p| p.value.renderer.scene_bytes()).sum();
        let held = {
            let bundles = lock(&self.state.bundles);
            self.state.held_bytes(&bundles).values().sum()
        };
        let backend = lock(&self.state.backend).clone();
        Ok(Response::new(pb::WorkerStatus {
            adapter: self.state.ctx.adapter_name(),
            gpu_memory_bytes: gpu_bytes,
            cached_scenes: cached,
            busy_strips: self.state.busy.load(Ordering::SeqCst),
            lb_solves: self.state.lb_solves(),
            accel_builds: self.state.accel_builds.load(Ordering::Relaxed),
            prepared_imports: self.state.prepared_imports.load(Ordering::Relaxed),
            held_bytes: held,
            scenes_evicted: self.state.evictions.load(Ordering::Relaxed),
            disk_hits: self.state.disk_hits.load(Ordering::Relaxed),
            ray_queries: self.state.ctx.has_ray_queries(),
            backend: backend.as_ref().map_or(String::new(), |b| b.backend.name().to_string()),
            backend_why: backend.map_or(String::new(), |b| b.why),
        }))
    }

    async fn prepare(
        &self,
        request: Request<pb::PrepareRequest>,
    ) -> Result<Response<pb::PrepareReply>, Status> {
        let r = request.into_inner();
        let p = self.state.preparation(&r.scene_hash, r.frame.as_ref())?;
        self.state.scope(&p.hash, &r.job);
        let t = Instant::now();
        let held = self.state.held(&p).is_some();
        if held || !r.build {
            return Ok(Response::new(pb::PrepareReply { held, prepare_ms: 0.0 }));
        }
        let state = self.state.clone();
        let span = tracing::info_span!("prepare", scene = %p.hash);
        tokio::task::spawn_blocking(move || {
            let _g = span.enter();
            let _gpu = lock(&state.gpu);
            state
                .prepared_for(&p.scene, &p.hash, p.frame.accel, p.lighting, &p.frame.view)
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
        // Data imported for another job is not this worker's to pass on.
        self.state.scope(&p.hash, &r.job);
        let (accel, lb) = self.state.held(&p).ok_or_else(|| {
            Status::not_found("this worker does not hold that frame's prepared data")
        })?;
        let choice = lock(&self.state.choices).get(&p.hash).cloned();
        let out = tokio::task::spawn_blocking(move || {
            crate::share::export(accel.as_deref(), lb.as_deref(), choice.as_ref())
        })
        .await
        .map_err(|e| Status::internal(format!("exporting panicked: {e}")))?
        .map_err(|e| Status::internal(format!("{e:#}")))?;
        let (total, hash, frame, scene_hash) = (out.bytes.len() as u64, out.hash, r.frame, p.hash);
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
                    job: String::new(),
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
        // Prepared data is taken from the coordinator this worker
        // registered with, and no one else holding a token.
        let registered = sylva_proto::sync::read(&self.state.config.session).is_some();
        let via = request.extensions().get::<Via>().copied();
        if registered && via != Some(Via::Coordinator) {
            return Err(Status::permission_denied(
                "only the coordinator this worker registered with may push prepared data into it",
            ));
        }
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
        let (scene, kind, needs_lb) = (p.scene.clone(), p.structure, p.needs_lb);
        let crate::share::Imported { accel, lb, choice } = tokio::task::spawn_blocking(move || {
            crate::share::import(&bytes, &content_hash, &scene, kind, needs_lb)
        })
        .await
        .map_err(|e| Status::internal(format!("importing panicked: {e}")))?
        .map_err(|e| Status::invalid_argument(format!("prepared data refused: {e}")))?;
        drop(held);
        // What was imported serves the job that brought it, and no other.
        self.state.scope(&p.hash, &first.job);
        lock(&self.state.imported).insert(p.hash.clone(), first.job.clone());
        if let (Some(k), Some(accel)) = (p.structure, accel) {
            lock(&self.state.accels).entry((p.hash.clone(), k)).or_insert_with(|| Arc::new(accel));
        }
        // The exporter's `auto` choice, where it measured this adapter.
        if let Some(c) = choice.filter(|c| c.adapter == self.state.ctx.adapter_name()) {
            lock(&self.state.choices).entry(p.hash.clone()).or_insert(c);
        }
        if let Some(lb) = lb
            && !lock(&self.state.lbs).contains_key(&p.lb_key)
        {
            self.state.keep_lb(p.lb_key.clone(), Arc::new(lb));
        }
        self.state.prepared_imports.fetch_add(1, Ordering::Relaxed);
        self.state.bound_memory(&p.hash);
        tracing::info!(scene = %p.hash, "took prepared data from another worker");
        Ok(Response::new(pb::PrepareReply {
            held: self.state.held(&p).is_some(),
            prepare_ms: t.elapsed().as_secs_f64() * 1e3,
        }))
    }
}
