//! The worker's gRPC service: bundles cached by hash in a size-bounded LRU,
//! scenes prepared once per (bundle, structure, lighting) and strips
//! rendered one at a time on the GPU. Uploads are counted as they arrive,
//! against both their declared size and this worker's limits; a strip whose
//! caller has gone is not started.
//!
//! `cache` holds the bundles, prepared scenes and LB light, and counts
//! uploads; `grpc` answers the API's calls.

mod cache;
mod grpc;

use cache::{Cached, LbKey, PreparedKey, Used};

use crate::frame::AmbientKey;
use crate::gpu::GpuContext;
use crate::lighting::lb::SceneLb;
use crate::prepare::PreparedScene;
use crate::trace::Tracer;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU32, AtomicU64};
use std::sync::{Arc, Mutex};
use sylva_accel::AccelKind;
use sylva_proto::pb;
use sylva_proto::pb::worker_identity_server::{WorkerIdentity, WorkerIdentityServer};
use sylva_proto::pb::worker_server::WorkerServer;
use sylva_scene::SceneLimits;
use tonic::{Request, Response, Status};

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
    /// The key the coordinator calls with, once this worker has registered
    /// (set by the registration, read by every call).
    pub session: Session,
    /// This worker's recent registrations: the identity check answers
    /// only a coordinator checking one of them.
    pub claims: sylva_proto::auth::Claims,
    /// Bytes the kept scenes may hold at most, all they expand into
    /// together (models, structures, LB light, GPU copies); the least
    /// recently used scenes go first (the one in use stays, whatever its size).
    pub memory_bytes: u64,
    /// Prepared data kept on disk across restarts (none: not kept).
    pub disk_cache: Option<crate::DiskCache>,
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
            memory_bytes: 8 << 30,
            disk_cache: None,
            session: Session::default(),
            claims: Default::default(),
        }
    }
}

/// The coordinator's key for this worker, given at registration.
pub type Session = Arc<std::sync::RwLock<Option<String>>>;

/// How a call was authorised.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Via {
    /// With the key the coordinator was given: the coordinator.
    Coordinator,
    /// With the worker's own token (an operator's tool, or a coordinator
    /// that names this worker rather than being registered with).
    Token,
    /// This worker asks no token.
    Open,
}

/// The worker's interceptor: a call brings the worker's token or the
/// coordinator's key (either, where the worker asks no token), and the
/// call learns which ([`Via`]).
fn authenticate(
    token: Option<String>,
    session: Session,
) -> impl FnMut(Request<()>) -> Result<Request<()>, Status> + Clone {
    move |mut req: Request<()>| {
        let eq = |a: &str, b: &str| sylva_proto::auth::constant_time_eq(a.as_bytes(), b.as_bytes());
        let got = sylva_proto::auth::bearer_of(&req).map(str::to_string);
        let key = sylva_proto::sync::read(&session).clone();
        let via = match (&got, &key, &token) {
            (Some(g), Some(k), _) if eq(g, k) => Via::Coordinator,
            (Some(g), _, Some(t)) if eq(g, t) => Via::Token,
            (_, _, None) => Via::Open,
            (Some(_), _, Some(_)) => return Err(Status::unauthenticated("wrong bearer token")),
            (None, _, Some(_)) => {
                return Err(Status::unauthenticated(
                    "this worker needs a bearer token (authorization: Bearer …)",
                ));
            }
        };
        req.extensions_mut().insert(via);
        Ok(req)
    }
}

/// What the service shares between requests.
struct State {
    ctx: Tracer,
    config: WorkerConfig,
    bundles: Mutex<HashMap<String, Cached>>,
    /// Prepared scenes by (hash, structure, what the lighting needs
    /// prepared, sun).
    prepared: Mutex<HashMap<PreparedKey, Used<Arc<PreparedScene>>>>,
    /// Acceleration structures by (hash, structure): kept across views.
    accels: Mutex<HashMap<(String, AccelKind), Arc<sylva_accel::SceneAccel>>>,
    /// Each scene's LB media, voxelized once for every sun (by bundle hash).
    media: Mutex<HashMap<String, Arc<crate::lighting::lb::LbMedia>>>,
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
    /// Scenes let go to stay within the memory budget.
    evictions: AtomicU64,
    /// Preparations that read structures or LB light from the disk cache.
    disk_hits: AtomicU64,
    /// The traversal the latest preparation chose, and why.
    backend: Mutex<Option<crate::trace::BackendChoice>>,
    /// `--accel auto`'s choice per scene, measured here or taken with
    /// another worker's prepared data (same adapter only).
    choices: Mutex<HashMap<String, crate::share::SharedChoice>>,
    /// Scenes whose prepared data came from another worker, and the job
    /// it serves: another job's strips drop it first.
    imported: Mutex<HashMap<String, String>>,
    /// Matched ambient constants by scene and frame shape.
    ambient: Mutex<HashMap<(String, AmbientKey), [f32; 3]>>,
    /// One GPU job at a time: strips queue here.
    gpu: Mutex<()>,
    /// Bytes of uploads in progress, so concurrent uploads share the limit.
    incoming: Mutex<u64>,
    busy: AtomicU32,
    /// Columns a second of strips rendered before, by scene and frame
    /// shape: a strip's first piece is sized by it ([`crate::frame::Frame::strip_until`]).
    strip_rates: Mutex<HashMap<String, f64>>,
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
                ctx: ctx.into(),
                config,
                bundles: Mutex::new(HashMap::new()),
                prepared: Mutex::new(HashMap::new()),
                accels: Mutex::new(HashMap::new()),
                media: Mutex::new(HashMap::new()),
                lbs: Mutex::new(HashMap::new()),
                clock: AtomicU64::new(0),
                lb_solves: AtomicU64::new(0),
                accel_builds: AtomicU64::new(0),
                prepared_imports: AtomicU64::new(0),
                evictions: AtomicU64::new(0),
                disk_hits: AtomicU64::new(0),
                backend: Mutex::default(),
                choices: Mutex::default(),
                imported: Mutex::default(),
                ambient: Mutex::new(HashMap::new()),
                gpu: Mutex::new(()),
                incoming: Mutex::new(0),
                busy: AtomicU32::new(0),
                strip_rates: Default::default(),
            }),
        }
    }

    /// The tonic server wrapper, with messages up to the bundle limit.
    pub fn into_server(self) -> WorkerServer<Self> {
        let limit = (self.state.config.max_bundle_bytes as usize).max(64 << 20);
        WorkerServer::new(self).max_decoding_message_size(limit).max_encoding_message_size(limit)
    }
}

/// Answers a coordinator's identity challenge with this worker's token.
struct Identity {
    token: Option<String>,
    /// The registrations this worker sent lately.
    claims: sylva_proto::auth::Claims,
    /// One proof at a time.
    turn: tokio::sync::Mutex<()>,
}

#[tonic::async_trait]
impl WorkerIdentity for Identity {
    async fn prove(
        &self,
        request: Request<pb::ProveRequest>,
    ) -> Result<Response<pb::ProveReply>, Status> {
        let pb::ProveRequest { nonce, claim } = request.into_inner();
        if nonce.len() < 16 || nonce.len() > 64 {
            return Err(Status::invalid_argument("the nonce must be 16 to 64 bytes"));
        }
        // Proof is given only for a registration this worker sent: another
        // holder of its token who names this address gets no key by it.
        if !self.claims.holds(&claim) {
            return Err(Status::permission_denied(
                "this worker did not send that registration: it proves itself only for its own",
            ));
        }
        // Each answer costs a slow key derivation; a flood of questions is
        // answered one at a time, never all at once.
        let _turn = self.turn.lock().await;
        // A user's token: proved with the key its record holds (the secret
        // is 256 random bits, so no slow derivation is needed).
        if let Some((id, secret)) = self.token.as_deref().and_then(sylva_proto::auth::user_token) {
            let key = sylva_proto::auth::user_token_key(secret);
            return Ok(Response::new(pb::ProveReply {
                proof: sylva_proto::auth::prove_with_key(&key, &nonce).to_vec(),
                salt: Vec::new(),
                token_id: id.to_string(),
            }));
        }
        let token = self.token.clone();
        let (salt, proof) =
            tokio::task::spawn_blocking(move || sylva_proto::auth::prove(token.as_deref(), &nonce))
                .await
                .map_err(|_| Status::internal("the proof could not be made"))?;
        Ok(Response::new(pb::ProveReply { proof: proof.to_vec(), salt, token_id: String::new() }))
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
    let auth = authenticate(config.token.clone(), config.session.clone());
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = config.tls.clone() {
        builder = builder.tls_config(tls)?;
    }
    let (cache_dir, keep) = (config.cache_dir.clone(), config.keep_cache);
    // This worker's folder while it runs; what an earlier worker left in
    // it is unindexed, so it goes (unless the operator keeps caches).
    let _lock = sylva_proto::workdir::claim(&cache_dir, "bundle cache")?;
    if !keep {
        for e in std::fs::read_dir(&cache_dir)?.flatten() {
            if e.file_name() != sylva_proto::workdir::LOCK {
                let _ =
                    std::fs::remove_dir_all(e.path()).or_else(|_| std::fs::remove_file(e.path()));
            }
        }
    }
    let identity = Identity {
        token: config.token.clone(),
        claims: config.claims.clone(),
        turn: Default::default(),
    };
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
        .serve_with_incoming_shutdown(sylva_proto::tls::incoming(listener), shutdown)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A coordinator the worker registered with may ask it to prove it
    /// holds the farm's token; the answer must not let a guess list be
    /// tried offline at the speed of a hash: each is salted afresh and
    /// keyed by Argon2id of the token. A check of a registration the
    /// worker did not send is not answered at all.
    #[tokio::test]
    async fn an_identity_proof_does_not_give_a_human_chosen_token_away() {
        let id = Identity {
            token: Some("hunter2".into()),
            claims: Default::default(),
            turn: Default::default(),
        };
        let claim = id.claims.fresh();
        let nonce = vec![7u8; 32];
        let ask = |claim: Vec<u8>, nonce: Vec<u8>| {
            id.prove(Request::new(pb::ProveRequest { nonce, claim }))
        };
        let a = ask(claim.clone(), nonce.clone()).await.unwrap().into_inner();
        let b = ask(claim.clone(), nonce.clone()).await.unwrap().into_inner();
        assert!(a.proof != b.proof && a.salt != b.salt, "the same question, answered afresh");
        // The proof as a keyed BLAKE3 hash of the nonce, tried against a
        // guess list, does not find the token.
        let guesses = ["password", "s3cret", "letmein", "hunter2", "sylva"];
        let cheap = |g: &str| {
            let key = blake3::derive_key("sylva 2026 worker identity v1", g.as_bytes());
            blake3::keyed_hash(&key, &nonce).as_bytes().to_vec()
        };
        assert!(!guesses.iter().any(|g| cheap(g) == a.proof), "a guess list recovers the token");
        assert!(sylva_proto::auth::check_proof(Some("hunter2"), &nonce, &a.salt, &a.proof));
        assert!(!sylva_proto::auth::check_proof(Some("hunter2"), &nonce, &b.salt, &a.proof));
        assert!(sylva_proto::auth::PROOF_KDF.0 >= 19 * 1024 && sylva_proto::auth::PROOF_KDF.1 >= 2);
        // A nonce it did not choose well is refused rather than answered;
        // so is a registration it did not send.
        let e = ask(claim, vec![1; 4]).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument);
        let e = ask(vec![9; 32], nonce).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::PermissionDenied);
    }
}
