//! What a worker keeps between requests: scene bundles by hash in a
//! size-bounded LRU, prepared scenes per (bundle, structure, what the
//! lighting needs, sun), acceleration structures across views, LB light per
//! sun; and uploads counted against the limits as their bytes arrive.

use super::{State, normalize_hash};
use crate::frame::{AmbientKey, Preparer};
use crate::lighting::lb::SceneLb;
use crate::prepare::{PreparedScene, Reuse, prepare_reusing};
use crate::trace::Tracer;
use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Instant;
use sylva_accel::AccelKind;
use sylva_proto::pb;
use sylva_proto::sync::lock;
use sylva_scene::frame::{Backend, FrameSettings};
use sylva_scene::sequence::View;
use sylva_scene::{LightingMode, Scene};
use tokio_stream::StreamExt;
use tonic::{Status, Streaming};

/// The worker's caches as the frame layer's [`Preparer`], for one bundle:
/// prepared scenes in memory (else on disk, else prepared here), and the
/// ambient constants matched per frame shape.
pub(super) struct BundleCaches<'a> {
    pub(super) state: &'a State,
    pub(super) hash: &'a str,
}

impl Preparer for BundleCaches<'_> {
    fn prepared(
        &mut self,
        _: &Tracer,
        scene: &Scene,
        accel: Backend,
        lighting: LightingMode,
        view: &View,
        _: &dyn Fn(&str),
    ) -> anyhow::Result<Arc<PreparedScene>> {
        self.state.prepared_for(scene, self.hash, accel, lighting, view)
    }

    fn matched_ambient(&mut self, key: &AmbientKey) -> Option<[f32; 3]> {
        lock(&self.state.ambient).get(&(self.hash.to_string(), key.clone())).copied()
    }

    fn keep_ambient(&mut self, key: AmbientKey, ambient: [f32; 3]) {
        lock(&self.state.ambient).insert((self.hash.to_string(), key), ambient);
    }
}

/// A cached bundle.
pub(super) struct Cached {
    pub(super) scene: Arc<Scene>,
    pub(super) bytes: u64,
    pub(super) last_used: Instant,
}

/// A prepared scene's key: bundle hash, structure, what the lighting needs
/// prepared, and the sun's bits where that depends on the sun (`None`: the
/// scene's own sun, or a method the sun does not change).
pub(super) type PreparedKey = (String, Backend, crate::lighting::Needs, Option<[u32; 3]>);

/// A scene's LB light's key: bundle hash and the sun's bits (`None`: the
/// scene's own sun).
pub(super) type LbKey = (String, Option<[u32; 3]>);

/// Sun variants of one scene kept prepared at once (the frame being
/// rendered and the one before, as strips of two frames overlap).
pub(super) const PREPARED_SUNS: usize = 2;

/// What a worker holds of a frame's preparation that can be shared: the
/// structure the CPU built (none for ray queries), and the LB light where
/// the lighting needs it.
pub(super) type Held = (Option<Arc<sylva_accel::SceneAccel>>, Option<Arc<SceneLb>>);

/// What one frame of a loaded scene needs prepared.
pub(super) struct Preparation {
    /// The bundle's hash.
    pub(super) hash: String,
    /// The structure it walks, built on the CPU (none for ray queries).
    pub(super) structure: Option<AccelKind>,
    pub(super) lb_key: LbKey,
    pub(super) needs_lb: bool,
    pub(super) scene: Arc<Scene>,
    pub(super) frame: FrameSettings,
    pub(super) lighting: LightingMode,
}

/// A value and when it was last used.
pub(super) struct Used<T> {
    pub(super) value: T,
    pub(super) stamp: u64,
}

impl State {
    /// Evicts least recently used bundles until `incoming` more bytes fit.
    pub(super) fn make_room(&self, bundles: &mut HashMap<String, Cached>, incoming: u64) {
        while bundles.values().map(|c| c.bytes).sum::<u64>() + incoming > self.config.cache_bytes
            && !bundles.is_empty()
        {
            let oldest = bundles
                .iter()
                .min_by_key(|(_, c)| c.last_used)
                .map(|(h, _)| h.clone())
                .expect("not empty");
            self.forget(bundles, &oldest, "the bundle cache is full");
        }
    }

    /// Lets go of a scene and everything it expanded into.
    fn forget(&self, bundles: &mut HashMap<String, Cached>, hash: &str, why: &str) {
        bundles.remove(hash);
        lock(&self.imported).remove(hash);
        lock(&self.prepared).retain(|k, _| k.0 != hash);
        lock(&self.accels).retain(|k, _| k.0 != hash);
        lock(&self.media).remove(hash);
        lock(&self.lbs).retain(|k, _| k.0 != hash);
        lock(&self.choices).remove(hash);
        let _ = std::fs::remove_dir_all(self.config.cache_dir.join(hash));
        self.evictions.fetch_add(1, Ordering::Relaxed);
        // glibc keeps freed memory in its arenas; a scene's hundreds of MB
        // go back to the system here, or the budget bounds what the worker
        // holds but not what it occupies.
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        // SAFETY: malloc_trim only returns free heap pages to the system.
        unsafe {
            libc::malloc_trim(0);
        }
        tracing::info!(%hash, "evicted a scene: {why}");
    }

    /// Drops a scene's prepared data when another worker's export brought
    /// it for a job other than `job`: imported data serves the job that
    /// brought it only, so data poisoned by a hostile exporter cannot
    /// outlive that job. This worker's own data is kept.
    pub(super) fn scope(&self, hash: &str, job: &str) {
        let mut imported = lock(&self.imported);
        if imported.get(hash).is_none_or(|j| j == job) {
            return;
        }
        let was = imported.remove(hash).unwrap_or_default();
        lock(&self.prepared).retain(|k, _| k.0 != hash);
        lock(&self.accels).retain(|k, _| k.0 != hash);
        lock(&self.lbs).retain(|k, _| k.0 != hash);
        lock(&self.choices).remove(hash);
        tracing::info!(%hash, job = %sylva_scene::sandbox::clip(&was), "dropped prepared data imported for another job");
    }

    /// Bytes each kept scene holds: its models, its structures, its LB
    /// light and its prepared GPU copies (by hash).
    pub(super) fn held_bytes(&self, bundles: &HashMap<String, Cached>) -> HashMap<String, u64> {
        let mut held: HashMap<String, u64> =
            bundles.iter().map(|(h, c)| (h.clone(), c.scene.bytes())).collect();
        let mut add = |h: &str, b: u64| *held.entry(h.to_string()).or_insert(0) += b;
        for ((h, _), a) in lock(&self.accels).iter() {
            add(h, a.bytes() as u64);
        }
        for (h, m) in lock(&self.media).iter() {
            add(h, m.bytes());
        }
        for ((h, _), l) in lock(&self.lbs).iter() {
            add(h, l.value.bytes());
        }
        for (k, p) in lock(&self.prepared).iter() {
            add(&k.0, p.value.renderer.scene_bytes());
        }
        held
    }

    /// Lets go of least recently used scenes, never `keep` (the one in
    /// use), until what the kept scenes hold fits the memory budget.
    pub(super) fn bound_memory(&self, keep: &str) {
        let mut bundles = lock(&self.bundles);
        loop {
            let total: u64 = self.held_bytes(&bundles).values().sum();
            if total <= self.config.memory_bytes {
                return;
            }
            let Some(oldest) = bundles
                .iter()
                .filter(|(h, _)| h.as_str() != keep)
                .min_by_key(|(_, c)| c.last_used)
                .map(|(h, _)| h.clone())
            else {
                return;
            };
            let why = format!(
                "the kept scenes hold {total} bytes, over the {} of --memory-mib",
                self.config.memory_bytes
            );
            self.forget(&mut bundles, &oldest, &why);
        }
    }
}

impl State {
    pub(super) fn tick(&self) -> u64 {
        self.clock.fetch_add(1, Ordering::Relaxed)
    }

    /// The scene prepared for a frame's structure, lighting and view: kept
    /// from an earlier strip, or prepared now from the structures and the
    /// LB light kept for this sun, building only what is missing.
    pub(super) fn prepared_for(
        &self,
        scene: &Scene,
        hash: &str,
        accel: Backend,
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
            accel: accel
                .structure()
                .and_then(|k| lock(&self.accels).get(&(hash.to_string(), k)).cloned()),
            coverage: None,
            lb_media: lock(&self.media).get(hash).cloned(),
            lb: if needs.lb {
                lock(&self.lbs).get_mut(&lb_key).map(|l| {
                    l.stamp = self.tick();
                    l.value.clone()
                })
            } else {
                None
            },
            // `auto` is measured once per scene and adapter: by this worker,
            // or by the one whose prepared data it took.
            choice: lock(&self.choices).get(hash).cloned(),
            // The newest preparation of this scene under another sun: a
            // new sun's light goes up beside its buffers.
            previous: lock(&self.prepared)
                .iter()
                .filter(|(k, _)| (&k.0, k.1, k.2) == (&key.0, key.1, key.2))
                .max_by_key(|(_, u)| u.stamp)
                .map(|(_, u)| u.value.clone()),
            // What memory lacks, the disk may hold from before a restart.
            disk: self.config.disk_cache.clone().map(|cache| crate::prepare::DiskSource {
                cache,
                bundle: hash.to_string(),
                sun,
            }),
            ..Default::default()
        };
        let (solved_before, built_before) = (reuse.lb.is_some(), reuse.accel.is_some());
        let scene = scene.with_view(view);
        let p = prepare_reusing(&self.ctx, &scene, accel, lighting, &mut reuse, &|m| {
            tracing::info!("{m}")
        })?;
        if let Some(c) = reuse.choice.take() {
            lock(&self.choices).insert(hash.to_string(), c);
        }
        if reuse.found.logged() {
            self.disk_hits.fetch_add(1, Ordering::Relaxed);
        }
        let p = Arc::new(p);
        tracing::info!(backend = p.backend.backend.name(), "{}", p.backend.why);
        *lock(&self.backend) = Some(p.backend.clone());
        self.accel_builds.fetch_add(reuse.built as u64, Ordering::Relaxed);
        self.lb_solves.fetch_add(reuse.solved as u64, Ordering::Relaxed);
        // Written for the next start on a thread of its own: the strips
        // need not wait for the disk.
        if let Some(keep) = reuse.keeper(&scene) {
            std::thread::spawn(keep);
        }
        if let (Some(a), false) = (reuse.accel, built_before) {
            lock(&self.accels).insert((hash.to_string(), a.kind), a);
        }
        if let Some(m) = reuse.lb_media.take() {
            lock(&self.media).insert(hash.to_string(), m);
        }
        if let (Some(lb), false) = (reuse.lb, solved_before) {
            self.keep_lb(lb_key, lb);
        }
        {
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
        }
        self.bound_memory(hash);
        Ok(p)
    }

    /// Keeps `lb` for its scene and sun, dropping the least recently used
    /// beyond the configured count and bytes.
    pub(super) fn keep_lb(&self, key: LbKey, lb: Arc<SceneLb>) {
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
    pub(super) fn scene(&self, hash: &str) -> Result<Arc<Scene>, Status> {
        let mut bundles = lock(&self.bundles);
        let c = bundles.get_mut(hash).ok_or_else(|| {
            Status::not_found(format!("scene {hash} is not loaded here; LoadScene it first"))
        })?;
        c.last_used = Instant::now();
        Ok(c.scene.clone())
    }

    /// What a frame of a loaded scene needs prepared: the scene, the keys
    /// of its structures and LB light, and whether it needs the light.
    pub(super) fn preparation(
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
            hash: hash.clone(),
            structure: f.accel.structure(),
            lb_key: (hash, sun),
            needs_lb: needs.lb,
            scene,
            frame: f,
            lighting,
        })
    }

    /// The structures and LB light held for `p`, if all it needs is held.
    pub(super) fn held(&self, p: &Preparation) -> Option<Held> {
        let accel = match p.structure {
            Some(k) => Some(lock(&self.accels).get(&(p.hash.clone(), k)).cloned()?),
            None => None,
        };
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
pub(super) struct Reservation<'a> {
    pub(super) incoming: &'a Mutex<u64>,
    pub(super) bytes: u64,
}

impl Reservation<'_> {
    /// Takes `more` bytes of `limit`, or says no.
    pub(super) fn grow(&mut self, more: u64, limit: u64) -> bool {
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
    pub(super) async fn receive<C>(
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
