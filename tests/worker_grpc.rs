//! A real `sylva worker` process on loopback, spoken to over real gRPC.

use crate::common;

use common::{Proc, spawn};
use std::path::{Path, PathBuf};
use sylva_proto::pb;
use sylva_proto::pb::worker_client::WorkerClient;
use sylva_scene::bundle;
use tonic::Code;

/// A worker process, killed when dropped.
struct WorkerProcess(Proc);

impl WorkerProcess {
    fn start(extra: &[&str]) -> Self {
        Self::start_with(extra, &[])
    }

    fn start_with(extra: &[&str], env: &[(&str, &str)]) -> Self {
        let mut args = vec!["worker", "--listen", "127.0.0.1:0"];
        args.extend_from_slice(extra);
        Self(spawn(&args, env))
    }

    async fn client(&self) -> WorkerClient<tonic::transport::Channel> {
        WorkerClient::connect(format!("http://{}", self.0.addr))
            .await
            .unwrap()
            .max_decoding_message_size(256 << 20)
    }
}

fn scene_file(dir: &Path) -> PathBuf {
    let text = r#"{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 8000, "seed": 1 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 0] }, { "model": "maple", "position": [9, 0, 5], "rotate_y_deg": 50 } ],
        "camera": { "position": [4, 8, -26], "look_at": [4, 7, 0], "fov_y_deg": 45 },
        "sun": { "elevation_deg": 50, "azimuth_deg": 120 },
        "ground": { "color": [0.1, 0.08, 0.05] },
        "lb": { "grid": 12, "preset": "leaf" }
    }"#;
    std::fs::create_dir_all(dir).unwrap();
    let p = dir.join("scene.json");
    std::fs::write(&p, text).unwrap();
    p
}

type Client = WorkerClient<tonic::transport::Channel>;

/// Two fresh workers (the second with `extra` flags), both holding the
/// test scene's bundle (packed in a folder named for `test`).
async fn two_loaded_workers(
    test: &str,
    extra: &[&str],
) -> (bundle::SceneBundle, (WorkerProcess, WorkerProcess), Client, Client) {
    let dir = std::env::temp_dir().join(format!("sylva-grpc-{test}-{}", std::process::id()));
    let b = bundle::pack(&scene_file(&dir)).unwrap();
    let (wa, wb) = (WorkerProcess::start(&[]), WorkerProcess::start(extra));
    let (mut a, mut bw) = (wa.client().await, wb.client().await);
    for c in [&mut a, &mut bw] {
        c.load_scene(tokio_stream::iter(chunks(&b, 1 << 20))).await.unwrap();
    }
    (b, (wa, wb), a, bw)
}

fn chunks(b: &bundle::SceneBundle, size: usize) -> Vec<pb::SceneChunk> {
    b.bytes
        .chunks(size)
        .enumerate()
        .map(|(i, c)| pb::SceneChunk {
            hash: if i == 0 { b.hash.clone() } else { String::new() },
            total_size: if i == 0 { b.bytes.len() as u64 } else { 0 },
            data: c.to_vec(),
        })
        .collect()
}

fn frame() -> pb::FrameSettings {
    pb::FrameSettings {
        width: 48,
        height: 24,
        spp: 2,
        seed: 3,
        lighting: pb::Lighting::Lb.into(),
        accel: pb::Accel::Bvh.into(),
        lb_strength: 0.35,
        ambient: vec![],
        view: None,
        gather_bounces: 0,
        gather_filter: None,
        passes: vec![],
        denoise: 0,
    }
}

#[tokio::test]
async fn a_worker_renders_strips_bit_identical_to_an_in_process_render() {
    let dir = std::env::temp_dir().join(format!("sylva-grpc-{}", std::process::id()));
    let b = bundle::pack(&scene_file(&dir)).unwrap();
    let w = WorkerProcess::start(&[]);
    let mut c = w.client().await;
    let r = c.load_scene(tokio_stream::iter(chunks(&b, 1000))).await.unwrap().into_inner();
    assert_eq!((r.hash.as_str(), r.was_cached), (b.hash.as_str(), false));
    let again = c
        .load_scene(tokio_stream::iter(vec![pb::SceneChunk {
            hash: b.hash.clone(),
            total_size: b.bytes.len() as u64,
            data: vec![],
        }]))
        .await
        .unwrap();
    assert!(again.into_inner().was_cached);

    let mut remote = vec![0f32; 48 * 24 * 3];
    for (x0, x1) in [(0, 20), (20, 48)] {
        let s = c
            .render_strip(pb::RenderStripRequest {
                scene_hash: b.hash.clone(),
                frame: Some(frame()),
                x0,
                x1,
                job: String::new(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!((s.x0, s.width, s.height), (x0, x1 - x0, 24));
        let px: Vec<f32> =
            s.rgb_f32.as_chunks::<4>().0.iter().map(|&c| f32::from_le_bytes(c)).collect();
        for y in 0..24usize {
            for x in 0..(x1 - x0) as usize {
                for k in 0..3 {
                    remote[(y * 48 + x0 as usize + x) * 3 + k] =
                        px[(y * (x1 - x0) as usize + x) * 3 + k];
                }
            }
        }
    }
    // The same frame rendered here, in this process.
    let scene = bundle::unpack(&b.bytes, &dir.join("local")).unwrap();
    let ctx = sylva_worker::trace::Tracer::new().unwrap();
    let p = sylva_worker::prepare::prepare(
        &ctx,
        &scene,
        sylva_accel::AccelKind::Bvh,
        sylva_scene::LightingMode::Lb,
        &|_| {},
    )
    .unwrap();
    let f = sylva_worker::trace::RenderSettings {
        width: 48,
        height: 24,
        spp: 2,
        seed: 3,
        lighting: sylva_scene::LightingMode::Lb,
        ambient: [0.0; 3],
        lb_strength: 0.35,
        view: Default::default(),
        gather_bounces: 1,
        gather_filter: 0,
        passes: Default::default(),
    };
    let local = p.renderer.render_strip(&ctx, &f, 0, 48).unwrap();
    let local: Vec<u32> = local.pixels.iter().flatten().map(|v| v.to_bits()).collect();
    assert_eq!(remote.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), local);

    let st = c.status(pb::StatusRequest {}).await.unwrap().into_inner();
    assert_eq!(st.cached_scenes, vec![b.hash.clone()]);
    assert!(st.gpu_memory_bytes > 0 && !st.adapter.is_empty());
}

#[tokio::test]
async fn bad_requests_get_their_codes_and_the_worker_stays_up() {
    let dir = std::env::temp_dir().join(format!("sylva-grpc-bad-{}", std::process::id()));
    let b = bundle::pack(&scene_file(&dir)).unwrap();
    let w = WorkerProcess::start(&["--max-bundle-mib", "1"]);
    let mut c = w.client().await;
    // Wrong hash.
    let mut wrong = chunks(&b, 4096);
    wrong[0].hash = "0".repeat(64);
    assert_eq!(
        c.load_scene(tokio_stream::iter(wrong)).await.unwrap_err().code(),
        Code::InvalidArgument
    );
    // Truncated upload.
    let mut short = chunks(&b, 64);
    short.pop();
    let e = c.load_scene(tokio_stream::iter(short)).await.unwrap_err();
    assert!(e.code() == Code::InvalidArgument && e.message().contains("truncated"), "{e:?}");
    // Over the worker's bundle limit.
    let big = pb::SceneChunk { hash: b.hash.clone(), total_size: 2 << 20, data: vec![] };
    assert_eq!(
        c.load_scene(tokio_stream::iter(vec![big])).await.unwrap_err().code(),
        Code::ResourceExhausted
    );
    // A malformed bundle with a matching hash.
    let junk = b"SYLVABN1 this is not a manifest".to_vec();
    let jb = bundle::SceneBundle { hash: bundle::hash_of(&junk), bytes: junk };
    let e = c.load_scene(tokio_stream::iter(chunks(&jb, 100))).await.unwrap_err();
    assert!(e.code() == Code::InvalidArgument && e.message().contains("bundle"), "{e:?}");
    // Rendering a scene the worker does not hold.
    let req = |f: pb::FrameSettings, x0, x1| pb::RenderStripRequest {
        scene_hash: b.hash.clone(),
        frame: Some(f),
        x0,
        x1,
        job: String::new(),
    };
    assert_eq!(c.render_strip(req(frame(), 0, 48)).await.unwrap_err().code(), Code::NotFound);
    // Absurd sizes.
    c.load_scene(tokio_stream::iter(chunks(&b, 8192))).await.unwrap();
    for (f, x0, x1) in [
        (pb::FrameSettings { width: 20_000, ..frame() }, 0, 48),
        (pb::FrameSettings { spp: 5000, ..frame() }, 0, 48),
        (pb::FrameSettings { lb_strength: f32::NAN, ..frame() }, 0, 48),
        (pb::FrameSettings { lighting: 99, ..frame() }, 0, 48),
        (frame(), 40, 60),
    ] {
        assert_eq!(c.render_strip(req(f, x0, x1)).await.unwrap_err().code(), Code::InvalidArgument);
    }
    // Still serving.
    c.render_strip(req(frame(), 0, 8)).await.unwrap();
    assert_eq!(c.status(pb::StatusRequest {}).await.unwrap().into_inner().busy_strips, 0);
}

#[tokio::test]
async fn with_a_token_calls_without_it_are_refused() {
    let dir = std::env::temp_dir().join(format!("sylva-grpc-token-{}", std::process::id()));
    let b = bundle::pack(&scene_file(&dir)).unwrap();
    let w = WorkerProcess::start(&["--token", "s3cret"]);
    let mut c = w.client().await;
    assert_eq!(c.status(pb::StatusRequest {}).await.unwrap_err().code(), Code::Unauthenticated);
    assert_eq!(
        c.load_scene(tokio_stream::iter(chunks(&b, 4096))).await.unwrap_err().code(),
        Code::Unauthenticated
    );
    let mut authed =
        sylva_coordinator::farm::connect(&w.0.addr, Some("s3cret".into()), None).await.unwrap();
    sylva_coordinator::farm::upload(&mut authed, &b).await.unwrap();
    assert_eq!(
        authed.status(pb::StatusRequest {}).await.unwrap().into_inner().cached_scenes,
        vec![b.hash.clone()]
    );
    let mut wrong =
        sylva_coordinator::farm::connect(&w.0.addr, Some("guess".into()), None).await.unwrap();
    assert_eq!(wrong.status(pb::StatusRequest {}).await.unwrap_err().code(), Code::Unauthenticated);
    // Health stays open for orchestrators' probes.
    let ch = tonic::transport::Endpoint::from_shared(format!("http://{}", w.0.addr))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut health = tonic_health::pb::health_client::HealthClient::new(ch);
    let h = health
        .check(tonic_health::pb::HealthCheckRequest { service: "sylva.v1.Worker".into() })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(h.status, tonic_health::pb::health_check_response::ServingStatus::Serving as i32);
}

/// Every chunk of a worker's export of `f`'s prepared data.
async fn export(
    c: &mut WorkerClient<tonic::transport::Channel>,
    hash: &str,
    f: pb::FrameSettings,
) -> Vec<pb::PreparedChunk> {
    let mut s = c
        .export_prepared(pb::PrepareRequest {
            scene_hash: hash.into(),
            frame: Some(f),
            build: false,
            job: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    let mut out = Vec::new();
    while let Some(c) = s.message().await.unwrap() {
        out.push(c);
    }
    out
}

/// Columns [0, 48) of `f` as bits.
async fn strip_bits(
    c: &mut WorkerClient<tonic::transport::Channel>,
    hash: &str,
    f: pb::FrameSettings,
) -> Vec<u8> {
    c.render_strip(pb::RenderStripRequest {
        scene_hash: hash.into(),
        frame: Some(f),
        x0: 0,
        x1: 48,
        job: String::new(),
    })
    .await
    .unwrap()
    .into_inner()
    .rgb_f32
}

/// A worker that restarts finds its prepared data on disk: it builds and
/// solves nothing and renders the same bits. An entry damaged on disk is
/// refused, deleted and prepared again.
#[tokio::test]
async fn a_restarted_worker_prepares_from_its_disk_cache_and_checks_it() {
    let dir = std::env::temp_dir().join(format!("sylva-grpc-disk-{}", std::process::id()));
    let cache = dir.join("prepared");
    let _ = std::fs::remove_dir_all(&cache);
    let b = bundle::pack(&scene_file(&dir)).unwrap();
    let cache_arg = cache.display().to_string();
    let env = [("SYLVA_PREPARED_CACHE_MIB", "64")];
    let entries = || -> Vec<PathBuf> {
        std::fs::read_dir(&cache)
            .map(|d| {
                d.flatten()
                    .map(|e| e.path())
                    .filter(|p| p.extension().is_some_and(|x| x == "prepared") && p.is_file())
                    .collect()
            })
            .unwrap_or_default()
    };
    // Prepares and renders one strip on a fresh worker; its status after
    // (and why it traced as it did, in `last_why`).
    let last_why = std::cell::Cell::new(String::new());
    let run_with = async |f: pb::FrameSettings| {
        let w = WorkerProcess::start_with(&["--prepared-cache-dir", &cache_arg], &env);
        let mut c = w.client().await;
        c.load_scene(tokio_stream::iter(chunks(&b, 1 << 20))).await.unwrap();
        let strip = strip_bits(&mut c, &b.hash, f).await;
        let s = c.status(pb::StatusRequest {}).await.unwrap().into_inner();
        last_why.replace(s.backend_why.clone());
        // The entries are written beside the first strip, not before it.
        let t = std::time::Instant::now();
        while entries().len() < 2 && t.elapsed().as_secs() < 60 {
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        }
        (strip, (s.accel_builds, s.lb_solves, s.disk_hits))
    };
    let run = async || run_with(frame()).await;
    let (first, did) = run().await;
    assert_eq!(did, (1, 1, 0), "builds, solves and disk reads of a cold start");
    assert_eq!(entries().len(), 2, "the structures and the LB light, one entry each");
    let (again, did) = run().await;
    assert_eq!(did, (0, 0, 1), "a restart reads both from disk");
    assert_eq!(again, first);
    // One byte changed in each entry: both refused, deleted, prepared again.
    for e in entries() {
        let mut bytes = std::fs::read(&e).unwrap();
        let k = bytes.len() / 2;
        bytes[k] ^= 0x40;
        std::fs::write(&e, bytes).unwrap();
    }
    let (third, did) = run().await;
    assert_eq!(did, (1, 1, 0), "damaged entries are not used");
    assert_eq!(third, first);
    assert_eq!(entries().len(), 2, "and are written again");
    // Each entry replaced by a folder (issue 37, finding 6): cleared and
    // written over as a file, and no temporary file is left behind.
    for e in entries() {
        std::fs::remove_file(&e).unwrap();
        std::fs::create_dir_all(e.join("inside")).unwrap();
    }
    let (fourth, did) = run().await;
    assert_eq!(did, (1, 1, 0), "a folder is not an entry");
    assert_eq!(fourth, first);
    assert_eq!(entries().len(), 2, "written again, as files");
    let tmp = std::fs::read_dir(&cache)
        .unwrap()
        .flatten()
        .filter(|e| e.path().extension().is_some_and(|x| x == "tmp"))
        .count();
    assert_eq!(tmp, 0, "a write that could not take the entry's place leaves nothing");
    // `auto`'s measured choice is kept too: a restart takes it unmeasured.
    let auto = pb::FrameSettings { accel: pb::Accel::Auto.into(), ..frame() };
    run_with(auto.clone()).await;
    let measured = last_why.take();
    assert!(measured.starts_with("auto:") && !measured.contains("measured before"), "{measured}");
    run_with(auto).await;
    assert!(last_why.take().contains("measured before"), "the choice was measured again");
}

/// `auto` chooses on the worker, measured, and says so; ray queries need
/// no structure from the CPU, so their prepared data carries only the LB
/// light, and the worker taking it builds its own structures.
#[tokio::test]
async fn workers_choose_their_traversal_and_share_what_ray_queries_need() {
    let (b, _workers, mut a, mut bw) = two_loaded_workers("rq", &[]).await;
    let with = |accel: pb::Accel| pb::FrameSettings { accel: accel.into(), ..frame() };
    let ask = |f: pb::FrameSettings, build| pb::PrepareRequest {
        scene_hash: b.hash.clone(),
        frame: Some(f),
        build,
        job: String::new(),
    };
    assert!(a.prepare(ask(with(pb::Accel::Auto), true)).await.unwrap().into_inner().held);
    let s = a.status(pb::StatusRequest {}).await.unwrap().into_inner();
    // The two compute walks are measured everywhere, ray queries where the
    // device has them (lavapipe does); the fastest is kept.
    assert!(s.backend_why.starts_with("auto:") && s.backend_why.contains("cwbvh "), "{s:?}");
    if !s.ray_queries {
        assert!(!s.adapter.contains("llvmpipe"), "{s:?}");
        return;
    }
    assert!(s.backend_why.contains("rq "), "{s:?}");
    if s.adapter.contains("llvmpipe") {
        // Ray queries are some 100 times slower there; the two walks are close.
        assert!(s.backend == "bvh" || s.backend == "cwbvh", "{s:?}");
    }
    // The LB light is what there is to share; each device builds its own
    // structures as its first strip is prepared.
    let rq = with(pb::Accel::Rq);
    assert!(a.prepare(ask(rq.clone(), true)).await.unwrap().into_inner().held);
    let shared = export(&mut a, &b.hash, rq.clone()).await;
    bw.import_prepared(tokio_stream::iter(shared)).await.unwrap();
    assert!(bw.prepare(ask(rq.clone(), false)).await.unwrap().into_inner().held);
    assert_eq!(strip_bits(&mut bw, &b.hash, rq).await.len(), 48 * 24 * 12);
    let s = bw.status(pb::StatusRequest {}).await.unwrap().into_inner();
    assert_eq!((s.lb_solves, s.backend.as_str()), (0, "rq"), "{s:?}");
}

/// Prepared data made on one worker and taken by another: the second builds
/// and solves nothing and renders the same bits. Data that does not match
/// its hash, is cut short, is over the limit or walks in a loop is refused
/// with a reason, and the worker still prepares and renders by itself.
#[tokio::test]
async fn prepared_data_moves_between_workers_and_bad_data_is_refused() {
    let dir = std::env::temp_dir().join(format!("sylva-grpc-share-{}", std::process::id()));
    let (b, _workers, mut a, mut bw) =
        two_loaded_workers("share", &["--max-bundle-mib", "4"]).await;
    let ask = |f: pb::FrameSettings, build| pb::PrepareRequest {
        scene_hash: b.hash.clone(),
        frame: Some(f),
        build,
        job: String::new(),
    };
    assert!(!a.prepare(ask(frame(), false)).await.unwrap().into_inner().held);
    let e = a.export_prepared(ask(frame(), false)).await.unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{e:?}");
    assert!(a.prepare(ask(frame(), true)).await.unwrap().into_inner().held);
    // The worker says which traversal it prepared with, and why.
    let s = a.status(pb::StatusRequest {}).await.unwrap().into_inner();
    assert_eq!((s.backend.as_str(), s.backend_why.as_str()), ("bvh", "asked for bvh"));
    let good = export(&mut a, &b.hash, frame()).await;
    assert!(good[0].total_size > 0 && good[0].content_hash.len() == 64);

    let refused = |e: tonic::Status, code: Code, says: &str| {
        assert!(
            e.code() == code && e.message().contains(says),
            "{e:?} should be {code:?} saying {says:?}"
        );
    };
    let mut bw2 = bw.clone();
    let mut import =
        async move |c: Vec<pb::PreparedChunk>| bw2.import_prepared(tokio_stream::iter(c)).await;
    // Bytes that do not match their hash.
    let mut wrong = good.clone();
    wrong[0].content_hash = "0".repeat(64);
    refused(import(wrong).await.unwrap_err(), Code::InvalidArgument, "do not match");
    // Cut short, and over this worker's 4 MiB limit.
    let mut short = good.clone();
    short[0].total_size += 1;
    refused(import(short).await.unwrap_err(), Code::InvalidArgument, "truncated");
    let mut big = good.clone();
    big[0].total_size = 5 << 20;
    refused(import(big).await.unwrap_err(), Code::ResourceExhausted, "limit");
    // A well-formed tree whose first node points back at itself, under
    // its correct hash: walking it would never end.
    let local = frame_with(pb::Lighting::Local);
    let scene = bundle::unpack(&b.bytes, &dir.join("local-share")).unwrap();
    let mut accel = sylva_accel::SceneAccel::build(&scene, sylva_accel::AccelKind::Bvh);
    let sylva_accel::Accel::Bvh(bvh) = &mut accel.models[0] else { unreachable!() };
    let inner = bvh.nodes[0].child.iter().position(|&c| c & sylva_accel::bvh::LEAF == 0).unwrap();
    bvh.nodes[0].child[inner] = 0;
    let loop_data = sylva_worker::share::export(Some(&accel), None, None).unwrap();
    let looped = pb::PreparedChunk {
        scene_hash: b.hash.clone(),
        frame: Some(local.clone()),
        content_hash: loop_data.hash,
        total_size: loop_data.bytes.len() as u64,
        data: loop_data.bytes,
        job: String::new(),
    };
    refused(import(vec![looped]).await.unwrap_err(), Code::InvalidArgument, "not a later node");
    let st = bw.status(pb::StatusRequest {}).await.unwrap().into_inner();
    assert_eq!((st.prepared_imports, st.accel_builds), (0, 0), "nothing refused was kept");

    // The real data: held at once, nothing built or solved, the same bits.
    assert!(import(good).await.unwrap().into_inner().held);
    assert!(bw.prepare(ask(frame(), false)).await.unwrap().into_inner().held);
    assert_eq!(
        strip_bits(&mut bw, &b.hash, frame()).await,
        strip_bits(&mut a, &b.hash, frame()).await
    );
    let st = bw.status(pb::StatusRequest {}).await.unwrap().into_inner();
    assert_eq!((st.prepared_imports, st.accel_builds, st.lb_solves), (1, 0, 0));
    // Other lighting renders from the same structures.
    assert_eq!(
        strip_bits(&mut bw, &b.hash, frame_with(pb::Lighting::Local)).await.len(),
        48 * 24 * 12
    );
}

fn frame_with(lighting: pb::Lighting) -> pb::FrameSettings {
    pb::FrameSettings { lighting: lighting.into(), ..frame() }
}

/// A scene of one tree grown from `seed` (a different bundle per seed).
fn tree_bundle(dir: &Path, seed: u32) -> bundle::SceneBundle {
    let text = format!(
        r#"{{
        "models": {{ "t": {{ "tree": {{ "species": "red_maple", "triangles": 20000, "seed": {seed} }} }} }},
        "instances": [ {{ "model": "t", "position": [0, 0, 0] }} ],
        "camera": {{ "position": [0, 8, -26], "look_at": [0, 7, 0], "fov_y_deg": 45 }},
        "sun": {{ "elevation_deg": 50, "azimuth_deg": 120 }},
        "lb": {{ "grid": 16, "preset": "leaf" }}
    }}"#
    );
    let d = dir.join(format!("tree-{seed}"));
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("scene.json"), text).unwrap();
    bundle::pack(&d.join("scene.json")).unwrap()
}

/// Loads `b` and renders a strip of it with LB light: the worker then
/// holds the scene, its structures, its light and its GPU copy.
async fn use_scene(c: &mut WorkerClient<tonic::transport::Channel>, b: &bundle::SceneBundle) {
    c.load_scene(tokio_stream::iter(chunks(b, 1 << 20))).await.unwrap();
    c.render_strip(pb::RenderStripRequest {
        scene_hash: b.hash.clone(),
        frame: Some(frame()),
        x0: 0,
        x1: 8,
        job: String::new(),
    })
    .await
    .unwrap();
}

/// Finding 2: a worker counted bundle bytes only, not what a bundle expands
/// into, and 12 small bundles of large procedural trees took one from 1.7
/// to 3.6 GB. Now it counts what each scene holds and lets the least
/// recently used go to stay within --memory-mib.
#[tokio::test]
async fn a_worker_keeps_what_its_scenes_hold_within_its_memory_budget() {
    let dir = std::env::temp_dir().join(format!("sylva-memory-{}", std::process::id()));
    let bundles: Vec<_> = (1..=6).map(|s| tree_bundle(&dir, s)).collect();
    // What one scene holds, measured on a worker with room for all.
    let roomy = WorkerProcess::start(&[]);
    let mut c = roomy.client().await;
    use_scene(&mut c, &bundles[0]).await;
    let one = c.status(pb::StatusRequest {}).await.unwrap().into_inner().held_bytes;
    assert!(
        one > bundles[0].bytes.len() as u64 * 10,
        "a scene holds far more than its bundle: {one}"
    );
    drop(roomy);
    // Room for two and a half of them.
    let budget_mib = (one * 5 / 2).div_ceil(1 << 20);
    let w = WorkerProcess::start(&["--memory-mib", &budget_mib.to_string()]);
    let mut c = w.client().await;
    for b in &bundles {
        use_scene(&mut c, b).await;
        let s = c.status(pb::StatusRequest {}).await.unwrap().into_inner();
        assert!(
            s.held_bytes <= budget_mib << 20,
            "{} bytes held over a budget of {budget_mib} MiB ({} scenes)",
            s.held_bytes,
            s.cached_scenes.len()
        );
        assert!(s.cached_scenes.contains(&b.hash), "the scene in use stays");
    }
    let s = c.status(pb::StatusRequest {}).await.unwrap().into_inner();
    assert!(s.scenes_evicted >= 3 && s.cached_scenes.len() <= 3, "{s:?}");
    // A scene let go is simply loaded again when it is needed.
    use_scene(&mut c, &bundles[0]).await;
    std::fs::remove_dir_all(&dir).ok();
}

/// Finding 3: a token holder exported a worker's prepared data, multiplied
/// its LB light by 20, and imported it into another worker, which rendered
/// every later job of that scene wrong. Prepared data another worker sent
/// now serves the job that brought it only: another job's strips find it
/// gone and the worker prepares the scene itself. (Only the coordinator the
/// worker registered with may import at all: `tests/users.rs`.)
#[tokio::test]
async fn imported_prepared_data_serves_only_the_job_that_brought_it() {
    let dir = std::env::temp_dir().join(format!("sylva-grpc-scope-{}", std::process::id()));
    let (b, _workers, mut a, mut bw) = two_loaded_workers("scope", &[]).await;
    let ask = |job: &str| pb::PrepareRequest {
        scene_hash: b.hash.clone(),
        frame: Some(frame()),
        build: true,
        job: job.into(),
    };
    a.prepare(ask("job-1")).await.unwrap();
    let mut data = export(&mut a, &b.hash, frame()).await;
    data[0].job = "job-1".into();
    bw.import_prepared(tokio_stream::iter(data)).await.unwrap();
    let strip = |job: &str| pb::RenderStripRequest {
        scene_hash: b.hash.clone(),
        frame: Some(frame()),
        x0: 0,
        x1: 48,
        job: job.into(),
    };
    let counts = |s: pb::WorkerStatus| (s.prepared_imports, s.accel_builds, s.lb_solves);
    // For its own job the import serves: nothing built, nothing solved.
    bw.render_strip(strip("job-1")).await.unwrap();
    assert_eq!(counts(bw.status(pb::StatusRequest {}).await.unwrap().into_inner()), (1, 0, 0));
    // Not a held scene for another job, and not rendered from it.
    assert!(
        !bw.prepare(pb::PrepareRequest { build: false, ..ask("job-2") })
            .await
            .unwrap()
            .into_inner()
            .held
    );
    bw.render_strip(strip("job-2")).await.unwrap();
    assert_eq!(
        counts(bw.status(pb::StatusRequest {}).await.unwrap().into_inner()),
        (1, 1, 1),
        "the next job's strips are rendered from what this worker prepared itself"
    );
    // What it prepared itself is its own, and stays for the jobs after.
    bw.render_strip(strip("job-3")).await.unwrap();
    assert_eq!(counts(bw.status(pb::StatusRequest {}).await.unwrap().into_inner()), (1, 1, 1));
    std::fs::remove_dir_all(&dir).ok();
}
