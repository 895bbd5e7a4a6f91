//! The farm as a hostile client or worker finds it: real coordinator and
//! worker processes, raw gRPC, crafted bundles and hostile files on disk.
//! Each test is one finding of issue 9, failing before its fix.

use crate::common;

use common::*;
use std::path::Path;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use sylva_proto::pb;
use sylva_scene::bundle::{self, SceneBundle};
use tonic::Code;

/// A bundle made by hand, as a hostile client would: the scene and blobs
/// written straight into the format, past `bundle::pack`'s own checks.
fn raw_bundle(scene: serde_json::Value, blobs: &[(&str, &[u8])]) -> SceneBundle {
    let manifest = serde_json::json!({
        "scene": scene,
        "blobs": blobs.iter().map(|(n, b)| serde_json::json!({ "name": n, "len": b.len() })).collect::<Vec<_>>(),
    });
    let json = serde_json::to_vec(&manifest).unwrap();
    let mut bytes = b"SYLVABN1".to_vec();
    bytes.extend_from_slice(&(json.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&json);
    for (_, b) in blobs {
        bytes.extend_from_slice(b);
    }
    SceneBundle { hash: bundle::hash_of(&bytes), bytes }
}

fn scene_with_model(model: serde_json::Value) -> serde_json::Value {
    serde_json::json!({
        "models": { "m": model },
        "instances": [ { "model": "m" } ],
        "camera": { "position": [0, 1, -5], "look_at": [0, 1, 0] },
        "sun": { "elevation_deg": 50, "azimuth_deg": 120 },
        "lighting": "local"
    })
}

fn fern() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/models/fern_02.glb")
}

async fn submit_error(c: &mut Client, b: &SceneBundle) -> tonic::Status {
    c.submit_job(tokio_stream::iter(submission(
        spec(16, 8),
        &b.hash,
        &b.bytes,
        b.bytes.len() as u64,
    )))
    .await
    .unwrap_err()
}

async fn load_error(addr: &str, b: &SceneBundle, declared: u64) -> tonic::Status {
    let mut w = sylva_coordinator::farm::connect(addr, None, None).await.unwrap();
    let chunks: Vec<pb::SceneChunk> = b
        .bytes
        .chunks(1 << 16)
        .enumerate()
        .map(|(i, d)| pb::SceneChunk {
            hash: if i == 0 { b.hash.clone() } else { String::new() },
            total_size: if i == 0 { declared } else { 0 },
            data: d.to_vec(),
        })
        .collect();
    w.load_scene(tokio_stream::iter(chunks)).await.unwrap_err()
}

/// Finding 1: a scene reads only files inside its bundle, and errors say
/// nothing of what lies outside.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scenes_read_no_file_outside_their_bundle() {
    let dir = scratch("confine");
    let secret = dir.join("secret.glb");
    std::fs::copy(fern(), &secret).unwrap();
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0"], &[]);
    let worker = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let mut c = coordinator(&coord.addr, None).await;
    let gltf = |uri: &str| {
        serde_json::to_vec(&serde_json::json!({
            "asset": { "version": "2.0" },
            "buffers": [ { "uri": uri, "byteLength": 1048576 } ],
            "scenes": [ { "nodes": [] } ], "scene": 0
        }))
        .unwrap()
    };
    let mut messages = Vec::new();
    let cases: Vec<SceneBundle> = vec![
        raw_bundle(scene_with_model(serde_json::json!({ "gltf": secret })), &[]),
        raw_bundle(
            scene_with_model(
                serde_json::json!({ "gltf": "../../../../../../".to_string() + secret.to_str().unwrap() }),
            ),
            &[],
        ),
        raw_bundle(scene_with_model(serde_json::json!({ "gltf": "/etc/shadow" })), &[]),
        raw_bundle(
            scene_with_model(serde_json::json!({ "gltf": "m0/x.gltf" })),
            &[("m0/x.gltf", &gltf("../../../../../../etc/passwd"))],
        ),
        raw_bundle(
            scene_with_model(serde_json::json!({ "gltf": "m0/x.gltf" })),
            &[("m0/x.gltf", &gltf("file:///etc/passwd"))],
        ),
        raw_bundle(
            scene_with_model(serde_json::json!({ "gltf": "m0/x.gltf" })),
            &[("m0/x.gltf", &gltf(&format!("file://{}", secret.display())))],
        ),
    ];
    for b in &cases {
        let e = submit_error(&mut c, b).await;
        assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
        let w = load_error(&worker.addr, b, b.bytes.len() as u64).await;
        assert_eq!(w.code(), Code::InvalidArgument, "{w:?}");
        for m in [e.message(), w.message()] {
            assert!(
                !m.contains("bytes but")
                    && !m.contains("No such file")
                    && !m.contains("expected 1048576"),
                "{m}"
            );
            messages.push(m.to_string());
        }
    }
    // A file outside that exists and one that does not get the same answer.
    let missing =
        raw_bundle(scene_with_model(serde_json::json!({ "gltf": dir.join("nothing.glb") })), &[]);
    let e = submit_error(&mut c, &missing).await;
    assert_eq!(e.message().replace("nothing.glb", "X"), messages[0].replace("secret.glb", "X"));
    // The client-side packer refuses the same paths before sending anything.
    let scene_dir = dir.join("scene");
    std::fs::create_dir_all(&scene_dir).unwrap();
    let outside = scene_dir.join("outside.json");
    std::fs::write(
        &outside,
        serde_json::to_vec(&scene_with_model(serde_json::json!({ "gltf": "../secret.glb" })))
            .unwrap(),
    )
    .unwrap();
    let out = sylva(
        &[
            "submit",
            outside.to_str().unwrap(),
            "--coordinator",
            &coord.addr,
            "-o",
            dir.join("o.png").to_str().unwrap(),
        ],
        &[],
    );
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("is not a file inside the scene's folder"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A local render may, when the user says so.
    let out = sylva(
        &[
            "render",
            outside.to_str().unwrap(),
            "-o",
            dir.join("o.png").to_str().unwrap(),
            "--local-workers",
            "0",
            "--width",
            "16",
            "--height",
            "8",
        ],
        &[],
    );
    assert!(!out.status.success());
    let out = sylva(
        &[
            "render",
            outside.to_str().unwrap(),
            "-o",
            dir.join("o.png").to_str().unwrap(),
            "--local-workers",
            "0",
            "--width",
            "16",
            "--height",
            "8",
            "--allow-files-outside-scene",
        ],
        &[],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // Both services still work.
    let good = bundle::pack(&small_scene(&dir.join("good"))).unwrap();
    let mut w = sylva_coordinator::farm::connect(&worker.addr, None, None).await.unwrap();
    sylva_coordinator::farm::upload(&mut w, &good).await.unwrap();
}

/// Finding 2: a worker counts bytes as they arrive; a false size claim
/// neither bypasses its limits nor reserves memory.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_counts_bundle_bytes_as_they_arrive() {
    let worker = spawn(
        &["worker", "--listen", "127.0.0.1:0", "--max-bundle-mib", "1", "--cache-mib", "2"],
        &[],
    );
    for i in 0..3u8 {
        // 3.4 MB of bytes, declared as 0 and as the truth.
        let mut junk = vec![i; 3_400_000];
        junk[..8].copy_from_slice(b"SYLVABN1");
        let b = SceneBundle { hash: bundle::hash_of(&junk), bytes: junk };
        let e = load_error(&worker.addr, &b, 0).await;
        assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
        assert!(e.message().contains("longer than its declared"), "{}", e.message());
        let e = load_error(&worker.addr, &b, b.bytes.len() as u64).await;
        assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
    }
    let mut w = sylva_coordinator::farm::connect(&worker.addr, None, None).await.unwrap();
    assert!(
        w.status(pb::StatusRequest {}).await.unwrap().into_inner().cached_scenes.is_empty(),
        "nothing was cached"
    );
    // A real bundle still loads, and its hash may come in capitals.
    let good = bundle::pack(&small_scene(&scratch("count"))).unwrap();
    sylva_coordinator::farm::upload(&mut w, &good).await.unwrap();
    let upper = pb::SceneChunk {
        hash: good.hash.to_uppercase(),
        total_size: good.bytes.len() as u64,
        data: vec![],
    };
    assert!(w.load_scene(tokio_stream::iter(vec![upper])).await.unwrap().into_inner().was_cached);
}

/// An error text that drives a terminal that prints it raw.
const HOSTILE_TEXT: &str = "ok\x1b]0;TITLE\x07\x1b[2J\u{202e}dlrow\r\nINFO forged line";

/// A worker that answers every strip with a reply that does not fit it,
/// and records whether any call carried a bearer token.
#[derive(Clone, Default)]
struct BadWorker {
    replies: Arc<AtomicU32>,
    saw_token: Arc<Mutex<bool>>,
}

impl BadWorker {
    fn note<T>(&self, r: &tonic::Request<T>) {
        if r.metadata().get("authorization").is_some() {
            *self.saw_token.lock().unwrap() = true;
        }
    }
}

#[tonic::async_trait]
impl pb::worker_server::Worker for BadWorker {
    async fn load_scene(
        &self,
        r: tonic::Request<tonic::Streaming<pb::SceneChunk>>,
    ) -> Result<tonic::Response<pb::LoadSceneReply>, tonic::Status> {
        self.note(&r);
        let mut s = r.into_inner();
        let mut hash = String::new();
        while let Some(c) = tokio_stream::StreamExt::next(&mut s).await {
            let c = c?;
            if hash.is_empty() {
                hash = c.hash;
            }
        }
        Ok(tonic::Response::new(pb::LoadSceneReply { hash, was_cached: false }))
    }

    async fn render_strip(
        &self,
        r: tonic::Request<pb::RenderStripRequest>,
    ) -> Result<tonic::Response<pb::RenderStripReply>, tonic::Status> {
        self.note(&r);
        let r = r.into_inner();
        let h = r.frame.unwrap().height;
        // One pixel short, one column too wide, an error whose text would
        // drive a terminal (retitle, clear, turn a line round, forge a line):
        // in turn.
        let n = self.replies.fetch_add(1, Ordering::SeqCst) % 3;
        if n == 2 {
            return Err(tonic::Status::internal(HOSTILE_TEXT));
        }
        let width = r.x1 - r.x0 + n;
        let px = (width * h).saturating_sub(if n == 0 { 1 } else { 0 }) as usize;
        Ok(tonic::Response::new(pb::RenderStripReply {
            x0: r.x0,
            width,
            height: h,
            rgb_f32: vec![0; px * 12],
            coverage_f32: vec![0; px * 4],
            ..Default::default()
        }))
    }

    async fn status(
        &self,
        r: tonic::Request<pb::StatusRequest>,
    ) -> Result<tonic::Response<pb::WorkerStatus>, tonic::Status> {
        self.note(&r);
        Ok(tonic::Response::new(pb::WorkerStatus { adapter: "bad".into(), ..Default::default() }))
    }

    /// Claims to hold every scene's prepared data...
    async fn prepare(
        &self,
        r: tonic::Request<pb::PrepareRequest>,
    ) -> Result<tonic::Response<pb::PrepareReply>, tonic::Status> {
        self.note(&r);
        Ok(tonic::Response::new(pb::PrepareReply { held: true, prepare_ms: 0.0 }))
    }

    type ExportPreparedStream = std::pin::Pin<
        Box<dyn tokio_stream::Stream<Item = Result<pb::PreparedChunk, tonic::Status>> + Send>,
    >;

    /// ...and exports bytes that match their hash but are no prepared data.
    async fn export_prepared(
        &self,
        r: tonic::Request<pb::PrepareRequest>,
    ) -> Result<tonic::Response<Self::ExportPreparedStream>, tonic::Status> {
        self.note(&r);
        let r = r.into_inner();
        let junk = vec![0xA5u8; 4096];
        let chunk = pb::PreparedChunk {
            scene_hash: r.scene_hash,
            frame: r.frame,
            content_hash: blake3::hash(&junk).to_hex().to_string(),
            total_size: junk.len() as u64,
            data: junk,
            job: String::new(),
        };
        Ok(tonic::Response::new(Box::pin(tokio_stream::iter(vec![Ok(chunk)]))))
    }

    async fn import_prepared(
        &self,
        r: tonic::Request<tonic::Streaming<pb::PreparedChunk>>,
    ) -> Result<tonic::Response<pb::PrepareReply>, tonic::Status> {
        self.note(&r);
        Ok(tonic::Response::new(pb::PrepareReply { held: true, prepare_ms: 0.0 }))
    }
}

#[tonic::async_trait]
impl pb::worker_identity_server::WorkerIdentity for BadWorker {
    async fn prove(
        &self,
        r: tonic::Request<pb::ProveRequest>,
    ) -> Result<tonic::Response<pb::ProveReply>, tonic::Status> {
        // It does not hold the farm's token: it guesses.
        let (salt, proof) = sylva_proto::auth::prove(Some("guess"), &r.into_inner().nonce);
        Ok(tonic::Response::new(pb::ProveReply {
            proof: proof.to_vec(),
            salt,
            token_id: String::new(),
        }))
    }
}

async fn serve_bad_worker(bad: BadWorker) -> String {
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap().to_string();
    tokio::spawn(
        tonic::transport::Server::builder()
            .add_service(pb::worker_server::WorkerServer::new(bad.clone()))
            .add_service(pb::worker_identity_server::WorkerIdentityServer::new(bad))
            .serve_with_incoming(tokio_stream::wrappers::TcpListenerStream::new(l)),
    );
    addr
}

/// Finding 3: a worker whose replies do not fit fails itself, not the
/// frame, and its prepared data is refused (a good worker's is shared); an address that registers gets nothing before it proves it holds
/// the token; stale registrations expire and metrics count live workers.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bad_worker_fails_itself_not_the_frame() {
    let dir = scratch("bad-worker");
    let scene = small_scene(&dir);
    let want = reference_png(&scene, &dir.join("ref.png"), 96, 32);
    let bad = BadWorker::default();
    let bad_addr = serve_bad_worker(bad.clone()).await;
    let good: Vec<Proc> =
        (0..2).map(|_| spawn(&["worker", "--listen", "127.0.0.1:0"], &[])).collect();
    let names = [bad_addr.clone(), good[0].addr.clone(), good[1].addr.clone()].join(",");
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &names], &[]);
    let mut c = coordinator(&coord.addr, None).await;
    let b = bundle::pack(&scene).unwrap();
    let mut retries = Vec::new();
    let end = submit_and_wait(&mut c, spec(96, 32), &b, |ev| {
        if ev.message.contains("re-queued") {
            retries.push((ev.strips_done, ev.strips_total, ev.message.clone()));
        }
    })
    .await;
    assert_eq!(sylva_coordinator::job_state::wire_name(end.state), "done", "{end:?}");
    let png = c
        .fetch_result(pb::FetchRequest {
            id: end.id.clone(),
            format: "png".into(),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner()
        .data;
    assert_eq!(png, want, "the frame is the one a single process renders");
    let stats: serde_json::Value = serde_json::from_str(&end.stats_json).unwrap();
    let w = stats["workers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| w["worker"] == bad_addr.as_str())
        .unwrap()
        .clone();
    assert!(w["dropped"].as_bool().unwrap() && w["failures"] == 3 && w["strips"] == 0, "{w}");
    assert!(
        !retries.is_empty() && retries.iter().all(|r| r.1 > 0),
        "retry events keep the progress: {retries:?}"
    );
    // Its hostile error reached watchers and the stats escaped, not raw.
    let said: Vec<&str> = retries.iter().map(|r| r.2.as_str()).collect();
    assert!(said.iter().any(|m| m.contains("ok\\u{1b}]0;TITLE\\u{7}")), "{said:?}");
    let raw = |t: &str| t.chars().any(sylva_scene::sandbox::unprintable);
    assert!(!said.iter().any(|m| raw(m)) && !raw(&end.stats_json), "{said:?}");
    // It also claimed to hold the scene's prepared data and exported junk
    // under a matching hash: the good workers refused it, then one of them
    // prepared the scene and the other took its data.
    let mut counts = Vec::new();
    for g in &good {
        let mut w = sylva_coordinator::farm::connect(&g.addr, None, None).await.unwrap();
        let s = w.status(pb::StatusRequest {}).await.unwrap().into_inner();
        counts.push((s.accel_builds, s.prepared_imports));
    }
    counts.sort();
    assert_eq!(counts, [(0, 1), (1, 0)], "(builds, imports) per good worker");
}

/// Issue 37, finding 3: a worker proves it holds its token only for a
/// registration it sent itself, so another holder of the token who names
/// its address in `RegisterWorker` gets no proof, and no session key: not
/// with the farm's token, not with the coordinator's. (Before, the victim
/// answered the check and the caller got its key, and with it could push
/// prepared data into the worker.) The worker's own registration renews.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_key_goes_only_to_the_worker_at_the_address() {
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--token", "s3cret"], &[]);
    let mut c = coordinator(&coord.addr, Some("s3cret")).await;
    let victim = spawn(
        &["worker", "--listen", "127.0.0.1:0", "--coordinator", &coord.addr],
        &[("SYLVA_TOKEN", "s3cret")],
    );
    wait_for_workers(&mut c, 1).await;
    for claim in [vec![], vec![9u8; 32]] {
        for _ in 0..3 {
            let e = c
                .register_worker(pb::RegisterWorkerRequest {
                    addr: victim.addr.clone(),
                    claim: claim.clone(),
                    session_key: String::new(),
                })
                .await
                .expect_err("a registration naming another worker's address gets its key");
            assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
            assert!(e.message().contains("did not send this registration"), "{}", e.message());
        }
    }
    // The worker itself asked nothing of that: it is still registered.
    let workers = c.list_workers(pb::ListWorkersRequest {}).await.unwrap().into_inner().workers;
    assert!(workers.iter().any(|w| w.addr == victim.addr && w.alive), "{workers:?}");
    // And its identity service answers no one who checks a registration it
    // did not send (so nobody can replay the check either).
    let ch = tonic::transport::Endpoint::from_shared(format!("http://{}", victim.addr))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut id = pb::worker_identity_client::WorkerIdentityClient::new(ch);
    let e = id
        .prove(pb::ProveRequest { nonce: vec![7u8; 32], claim: vec![9u8; 32] })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn registration_needs_proof_and_expires() {
    let coord = spawn(
        &[
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--token",
            "s3cret",
            "--registration-ttl-s",
            "1",
            "--metrics",
            "127.0.0.1:0",
        ],
        &[],
    );
    let mut c = coordinator(&coord.addr, Some("s3cret")).await;
    // Anyone holding a client token can call RegisterWorker, but an address
    // that cannot prove it holds the token is refused and sent nothing.
    let bad = BadWorker::default();
    let bad_addr = serve_bad_worker(bad.clone()).await;
    let e = c
        .register_worker(pb::RegisterWorkerRequest { addr: bad_addr.clone(), ..Default::default() })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    assert!(e.message().contains("could not prove"), "{}", e.message());
    tokio::time::sleep(Duration::from_millis(2500)).await;
    assert!(!*bad.saw_token.lock().unwrap(), "the token went to an unproven address");
    assert!(
        c.list_workers(pb::ListWorkersRequest {}).await.unwrap().into_inner().workers.is_empty()
    );
    // A real worker proves itself and registers; once it dies, it expires.
    let log = scratch("register").join("worker.log");
    let w = spawn_logging(
        &["worker", "--listen", "127.0.0.1:0", "--coordinator", &coord.addr, "-v"],
        &[("SYLVA_TOKEN", "s3cret")],
        Some(&log),
    );
    wait_for_workers(&mut c, 1).await;
    drop(w);
    let mut gone = false;
    for _ in 0..100 {
        if c.list_workers(pb::ListWorkersRequest {}).await.unwrap().into_inner().workers.is_empty()
        {
            gone = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(gone, "a dead registration is forgotten");
    // A worker without the token says why it cannot register.
    let log = scratch("register-no-token").join("worker.log");
    let _w = spawn_logging(
        &["worker", "--listen", "127.0.0.1:0", "--coordinator", &coord.addr],
        &[],
        Some(&log),
    );
    let mut said = String::new();
    for _ in 0..100 {
        said = std::fs::read_to_string(&log).unwrap_or_default();
        if said.contains("cannot register") {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(said.contains("Unauthenticated"), "{said}");
}

/// Finding 4: job ids never repeat across coordinator restarts.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn job_ids_do_not_repeat_after_a_restart() {
    let dir = scratch("ids");
    let b = bundle::pack(&small_scene(&dir)).unwrap();
    let w = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let first = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &w.addr], &[]);
    let mut c = coordinator(&first.addr, None).await;
    let a = submit_and_wait(&mut c, spec(16, 8), &b, |_| {}).await;
    first.terminate();
    let second = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &w.addr], &[]);
    let mut c = coordinator(&second.addr, None).await;
    let b2 = submit_and_wait(&mut c, spec(16, 8), &b, |_| {}).await;
    assert_ne!(a.id, b2.id);
    let e = c
        .fetch_result(pb::FetchRequest {
            id: a.id.clone(),
            format: "png".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
}

fn folder_of(pid: u32, prefix: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("{prefix}-{pid}"))
}

/// Finding 5: finished jobs are forgotten after their retention; scene
/// checks leave nothing on disk; both services remove their folders on
/// SIGTERM.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn finished_jobs_and_folders_are_freed() {
    let dir = scratch("freed");
    let b = bundle::pack(&small_scene(&dir)).unwrap();
    let cache = dir.join("cache");
    let w =
        spawn(&["worker", "--listen", "127.0.0.1:0", "--cache-dir", cache.to_str().unwrap()], &[]);
    let coord = spawn(
        &["coordinator", "--listen", "127.0.0.1:0", "--workers", &w.addr, "--keep-results-s", "1"],
        &[],
    );
    let work = folder_of(coord.child.id(), "sylva-coordinator");
    let mut c = coordinator(&coord.addr, None).await;
    let end = submit_and_wait(&mut c, spec(32, 16), &b, |_| {}).await;
    assert_eq!(sylva_coordinator::job_state::wire_name(end.state), "done");
    // The result is a file of the state folder; it is served from there.
    let png = c
        .fetch_result(pb::FetchRequest {
            id: end.id.clone(),
            format: "png".into(),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner()
        .data;
    assert_eq!(&png[1..4], b"PNG");
    assert!(work.join("results").read_dir().unwrap().count() >= 1);
    // A refused scene leaves nothing behind either.
    let broken = raw_bundle(
        scene_with_model(
            serde_json::json!({ "tree": { "species": "red_maple", "triangles": 2000 } }),
        )
        .as_object()
        .cloned()
        .map(|mut o| {
            o.insert(
                "camera".into(),
                serde_json::json!({ "position": [0, 0, 0], "look_at": [0, 0, 0] }),
            );
            serde_json::Value::Object(o)
        })
        .unwrap(),
        &[],
    );
    assert_eq!(submit_error(&mut c, &broken).await.code(), Code::InvalidArgument);
    let checks = work.join("check");
    assert!(
        !checks.exists() || checks.read_dir().unwrap().count() == 0,
        "scene checks are cleaned up"
    );
    tokio::time::sleep(Duration::from_millis(3500)).await;
    assert_eq!(
        c.fetch_result(pb::FetchRequest {
            id: end.id.clone(),
            format: "png".into(),
            ..Default::default()
        })
        .await
        .unwrap_err()
        .code(),
        Code::NotFound
    );
    assert!(c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs.is_empty());
    assert_eq!(
        work.join("results").read_dir().unwrap().count(),
        0,
        "spilled results are removed with their job"
    );
    assert!(cache.exists());
    w.terminate();
    assert!(!cache.exists(), "the worker removes its cache on SIGTERM");
    coord.terminate();
    assert!(!work.exists(), "the coordinator removes its folder on SIGTERM");
}

/// Finding 8: a worker killed with `kill -9` cannot remove its bundle cache
/// (401 MB in the report); the next worker started on the machine does,
/// and leaves a live worker's alone. A cache folder named twice is refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_workers_cache_is_removed_by_the_next_worker() {
    let live = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let killed = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let mut w = sylva_coordinator::farm::connect(&killed.addr, None, None).await.unwrap();
    let b = bundle::pack(&small_scene(&scratch("killed-cache"))).unwrap();
    sylva_coordinator::farm::upload(&mut w, &b).await.unwrap();
    let (dead, alive) =
        (folder_of(killed.child.id(), "sylva-worker"), folder_of(live.child.id(), "sylva-worker"));
    assert!(dead.join(&b.hash).exists(), "the bundle is unpacked in the cache");
    // SAFETY: signals our own child.
    unsafe { libc::kill(killed.child.id() as i32, libc::SIGKILL) };
    drop(killed);
    assert!(dead.exists(), "kill -9 leaves the cache behind");
    let log = scratch("killed-cache-log").join("next.log");
    let next = spawn_logging(&["worker", "--listen", "127.0.0.1:0", "-v"], &[], Some(&log));
    assert!(
        !dead.exists(),
        "the next worker removes a killed worker's cache: {}",
        std::fs::read_to_string(&log).unwrap_or_default()
    );
    assert!(alive.exists(), "and leaves a live worker's alone");
    // Two workers on one cache folder would evict each other's files.
    let shared = scratch("shared-cache");
    let _one =
        spawn(&["worker", "--listen", "127.0.0.1:0", "--cache-dir", shared.to_str().unwrap()], &[]);
    let two =
        sylva(&["worker", "--listen", "127.0.0.1:0", "--cache-dir", shared.to_str().unwrap()], &[]);
    assert!(!two.status.success());
    assert!(String::from_utf8_lossy(&two.stderr).contains("in use by another process"));
    drop((live, next));
}

/// Finding 6: an oversized scene is refused from its declared sizes, before
/// anything is generated, and a broken camera before the trees are grown.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_scenes_are_refused_before_any_work() {
    let coord =
        spawn(&["coordinator", "--listen", "127.0.0.1:0", "--max-triangles", "1000000"], &[]);
    let mut c = coordinator(&coord.addr, None).await;
    let huge = |camera: serde_json::Value| {
        raw_bundle(
            serde_json::json!({
                "models": {
                    "a": { "tree": { "species": "red_maple", "triangles": 5000000 } },
                    "b": { "tree": { "species": "paper_birch", "triangles": 5000000 } },
                    "c": { "tree": { "species": "american_beech", "triangles": 5000000 } }
                },
                "instances": [ { "model": "a" } ],
                "camera": camera,
                "sun": { "elevation_deg": 50, "azimuth_deg": 120 }
            }),
            &[],
        )
    };
    let t = std::time::Instant::now();
    let e = submit_error(
        &mut c,
        &huge(serde_json::json!({ "position": [0, 1, 0], "look_at": [0, 1, 0] })),
    )
    .await;
    assert!(e.code() == Code::InvalidArgument && e.message().contains("camera"), "{e:?}");
    let e = submit_error(
        &mut c,
        &huge(serde_json::json!({ "position": [0, 1, -9], "look_at": [0, 1, 0] })),
    )
    .await;
    assert!(
        e.code() == Code::InvalidArgument
            && e.message().contains("15000000 triangles: at most 1000000"),
        "{e:?}"
    );
    let many = raw_bundle(
        serde_json::json!({
            "models": { "a": { "tree": { "species": "red_maple", "triangles": 2000 }, "lb": { "grid": 512 } } },
            "instances": [ { "model": "a" } ],
            "camera": { "position": [0, 1, -9], "look_at": [0, 1, 0] },
            "sun": { "elevation_deg": 50, "azimuth_deg": 120 }
        }),
        &[],
    );
    let e = submit_error(&mut c, &many).await;
    assert!(e.message().contains("LB grids"), "{e:?}");
    // Nothing was generated: three refusals take far less than growing one tree.
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
}

/// Findings 7 and 8: names the wire cannot hold are refused at submit, by
/// field; oversized strings are refused or not echoed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_specs_and_strings_are_refused_at_submit() {
    let dir = scratch("specs");
    let b = bundle::pack(&small_scene(&dir)).unwrap();
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0"], &[]);
    let mut c = coordinator(&coord.addr, None).await;
    let mut unknown = spec(16, 8);
    unknown.frame.as_mut().unwrap().lighting = 42;
    let e = c
        .submit_job(tokio_stream::iter(submission(
            unknown,
            &b.hash,
            &b.bytes,
            b.bytes.len() as u64,
        )))
        .await
        .unwrap_err();
    assert!(e.code() == Code::InvalidArgument && e.message().contains("lighting 42"), "{e:?}");
    let mut unknown = spec(16, 8);
    unknown.frame.as_mut().unwrap().accel = 9;
    let e = c
        .submit_job(tokio_stream::iter(submission(
            unknown,
            &b.hash,
            &b.bytes,
            b.bytes.len() as u64,
        )))
        .await
        .unwrap_err();
    assert!(e.message().contains("accel 9"), "{e:?}");
    let mut unknown = spec(16, 8);
    unknown.schedule = 9;
    let e = c
        .submit_job(tokio_stream::iter(submission(
            unknown,
            &b.hash,
            &b.bytes,
            b.bytes.len() as u64,
        )))
        .await
        .unwrap_err();
    assert!(e.message().contains("schedule 9"), "{e:?}");
    let mut named = spec(16, 8);
    named.name = "n".repeat(4 << 20);
    let e = c
        .submit_job(tokio_stream::iter(submission(named, &b.hash, &b.bytes, b.bytes.len() as u64)))
        .await
        .unwrap_err();
    assert!(
        e.code() == Code::InvalidArgument && e.message().contains("job name of 4194304 bytes"),
        "{e:?}"
    );
    // Names that would drive the terminal of whoever lists the jobs: an
    // escape that retitles and clears it, a forged row, a right-to-left override.
    for (name, submitter) in [
        ("ok\u{1b}]0;TITLE\u{7}\u{1b}[2J", "alice"),
        ("ok\r\njob-999 done", "alice"),
        ("gpj.exe\u{202e}", "alice"),
        ("fine", "\u{2067}mallory"),
    ] {
        let mut s = spec(16, 8);
        (s.name, s.submitter) = (name.into(), submitter.into());
        let e = c
            .submit_job(tokio_stream::iter(submission(s, &b.hash, &b.bytes, b.bytes.len() as u64)))
            .await
            .unwrap_err();
        assert!(
            e.code() == Code::InvalidArgument && e.message().contains("bidirectional formatting"),
            "{name:?} {submitter:?}: {e:?}"
        );
    }
    let e = c
        .fetch_result(pb::FetchRequest {
            id: "x".repeat(1 << 20),
            format: "png".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    assert!(e.message().len() < 200);
    assert!(c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs.is_empty());
}

/// Finding 7: a job that no worker can finish ends with the reason.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failed_job_names_its_cause() {
    let dir = scratch("cause");
    let b = bundle::pack(&small_scene(&dir)).unwrap();
    let bad_addr = serve_bad_worker(BadWorker::default()).await;
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &bad_addr], &[]);
    let mut c = coordinator(&coord.addr, None).await;
    let end = submit_and_wait(&mut c, spec(16, 8), &b, |_| {}).await;
    assert_eq!(sylva_coordinator::job_state::wire_name(end.state), "failed");
    assert!(
        end.message.contains(&bad_addr) && end.message.contains("Internal: ok\\u{1b}]0;TITLE"),
        "{}",
        end.message
    );
    let jobs = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    assert!(jobs[0].error.contains("Internal: ok\\u{1b}]0;TITLE"), "{:?}", jobs[0]);
}

async fn http_get(addr: &str, path: &str) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).await.unwrap();
    out
}

/// Findings 9 and 10: metrics answer only their path; reflection speaks
/// both protocol versions and lists what each server serves, plus health.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_and_reflection_answer_as_standard_clients_expect() {
    let log = scratch("metrics").join("coordinator.log");
    let coord = spawn_logging(
        &["coordinator", "--listen", "127.0.0.1:0", "--metrics", "127.0.0.1:0"],
        &[],
        Some(&log),
    );
    let mut metrics = String::new();
    for _ in 0..50 {
        let said = std::fs::read_to_string(&log).unwrap_or_default();
        if let Some(a) = said.split("metrics on http://").nth(1) {
            metrics = a.split('/').next().unwrap().to_string();
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(http_get(&metrics, "/metrics").await.starts_with("HTTP/1.1 200"));
    assert!(http_get(&metrics, "/etc/passwd").await.starts_with("HTTP/1.1 404"));
    let worker = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    for (addr, want) in [
        (&coord.addr, vec!["grpc.health.v1.Health", "sylva.v1.Coordinator"]),
        (&worker.addr, vec!["grpc.health.v1.Health", "sylva.v1.Worker", "sylva.v1.WorkerIdentity"]),
    ] {
        let ch = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
            .unwrap()
            .connect()
            .await
            .unwrap();
        use tonic_reflection::pb::v1alpha as alpha;
        let mut c = alpha::server_reflection_client::ServerReflectionClient::new(ch.clone());
        let req = alpha::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(alpha::server_reflection_request::MessageRequest::ListServices(
                String::new(),
            )),
        };
        let mut replies =
            c.server_reflection_info(tokio_stream::iter(vec![req])).await.unwrap().into_inner();
        let reply = tokio_stream::StreamExt::next(&mut replies).await.unwrap().unwrap();
        let Some(alpha::server_reflection_response::MessageResponse::ListServicesResponse(l)) =
            reply.message_response
        else {
            panic!("{reply:?}")
        };
        let mut names: Vec<String> = l.service.into_iter().map(|s| s.name).collect();
        names.sort();
        assert_eq!(names, want, "v1alpha on {addr}");
        use tonic_reflection::pb::v1;
        let mut c = v1::server_reflection_client::ServerReflectionClient::new(ch);
        let req = v1::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(v1::server_reflection_request::MessageRequest::ListServices(
                String::new(),
            )),
        };
        let mut replies =
            c.server_reflection_info(tokio_stream::iter(vec![req])).await.unwrap().into_inner();
        assert!(tokio_stream::StreamExt::next(&mut replies).await.unwrap().is_ok(), "v1 on {addr}");
    }
}

/// Finding 1: any size of sequence was accepted (10,000 frames of
/// 16384 × 16384), and held whole in memory. Now a job's pixels and the
/// disk its results would take are capped (flags with documented defaults)
/// and refused at submit, with the figures, before the bundle arrives.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_too_large_for_the_farm_is_refused_at_submit() {
    let coord = spawn(
        &[
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--max-job-pixels",
            "100000",
            "--results-disk-mib",
            "1",
        ],
        &[],
    );
    let mut c = coordinator(&coord.addr, None).await;
    let b = bundle::pack(&small_scene(&scratch("too-large"))).unwrap();
    let try_submit = |w: u32, h: u32, frames: usize| {
        let mut s = spec(w, h);
        // A sequence of the scene's own view, `frames` long.
        s.views = vec![pb::FrameView::default(); if frames > 1 { frames } else { 0 }];
        submission(s, &b.hash, &b.bytes, b.bytes.len() as u64)
    };
    let e = c.submit_job(tokio_stream::iter(try_submit(16384, 16384, 10_000))).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
    assert!(e.message().contains("--max-job-pixels"), "{}", e.message());
    let e = c.submit_job(tokio_stream::iter(try_submit(100, 100, 9))).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
    assert!(e.message().contains("--results-disk-mib"), "{}", e.message());
    // Within both, a job is taken.
    assert!(c.submit_job(tokio_stream::iter(try_submit(64, 32, 1))).await.is_ok());
}
