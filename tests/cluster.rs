//! Frames rendered by real worker processes over real gRPC on loopback:
//! identical to a single in-process render (the scene prepared once for the
//! farm), through a worker killed with SIGKILL mid-frame, and with several
//! jobs at once.

use crate::common;

use common::{Proc, spawn, sylva};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use sylva_coordinator::farm::{self, FarmEvent};
use sylva_coordinator::schedule::{Dynamic, Scheduler, Static};
use sylva_scene::bundle;
use sylva_scene::frame::FrameSettings;

type Worker = Proc;

fn start_worker() -> Worker {
    spawn(&["worker", "--listen", "127.0.0.1:0"], &[])
}

fn scene(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let p = dir.join("scene.json");
    std::fs::write(
        &p,
        r#"{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 6000, "seed": 1 } },
                    "birch": { "tree": { "species": "paper_birch", "triangles": 6000, "seed": 2 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 0] }, { "model": "birch", "position": [8, 0, 4], "rotate_y_deg": 30 } ],
        "camera": { "position": [4, 8, -26], "look_at": [4, 7, 0], "fov_y_deg": 45 },
        "sun": { "elevation_deg": 50, "azimuth_deg": 120 },
        "ground": { "color": [0.1, 0.08, 0.05] },
        "lb": { "grid": 12, "preset": "leaf" }
    }"#,
    )
    .unwrap();
    p
}

fn frame(seed: u32) -> FrameSettings {
    FrameSettings {
        width: 96,
        height: 48,
        spp: 2,
        seed,
        lighting: Some(sylva_scene::LightingMode::Lb),
        ..Default::default()
    }
}

/// The same frame, rendered in this process without gRPC.
fn reference(b: &bundle::SceneBundle, dir: &Path, seed: u32) -> Vec<u32> {
    let scene = bundle::unpack(&b.bytes, dir).unwrap();
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
        width: 96,
        height: 48,
        spp: 2,
        seed,
        lighting: sylva_scene::LightingMode::Lb,
        ambient: [0.0; 3],
        lb_strength: 0.35,
        view: Default::default(),
        gather_bounces: 1,
        gather_filter: 0,
        passes: Default::default(),
    };
    p.renderer
        .render_strip(&ctx, &f, 0, 96)
        .unwrap()
        .pixels
        .iter()
        .flatten()
        .map(|v| v.to_bits())
        .collect()
}

fn bits(img: &sylva_scene::film::HdrImage) -> Vec<u32> {
    img.pixels.iter().flatten().map(|v| v.to_bits()).collect()
}

const DEADLINE: Duration = Duration::from_secs(120);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_workers_render_the_frame_a_single_process_renders() {
    let dir = std::env::temp_dir().join(format!("sylva-cluster-a-{}", std::process::id()));
    let b = bundle::pack(&scene(&dir)).unwrap();
    let want = reference(&b, &dir.join("ref"), 5);
    let workers: Vec<Worker> = (0..3).map(|_| start_worker()).collect();
    let addrs: Vec<String> = workers.iter().map(|w| w.addr.clone()).collect();
    let shared = Arc::new(Mutex::new(Vec::new()));
    for plan in [Static.plan(96, 3, &[]), Dynamic::default().plan(96, 3, &[])] {
        let seen = shared.clone();
        let events = move |e: FarmEvent| {
            if let FarmEvent::PreparedShared(p) = e {
                seen.lock().unwrap().push((p.from, p.to.len(), p.bytes));
            }
        };
        let f =
            farm::render_frame(&farm::Workers::open(&addrs), &b, frame(5), plan, DEADLINE, events)
                .await
                .unwrap();
        assert_eq!(bits(&f.image), want);
        assert!(f.workers.iter().all(|w| w.strips > 0 && !w.dropped), "{:?}", f.workers);
    }
    // One worker prepared the scene, the other two took its data; the
    // second frame found it everywhere.
    let shared = shared.lock().unwrap().clone();
    assert!(shared.len() == 1 && shared[0].1 == 2 && shared[0].2 > 0, "{shared:?}");
    let mut totals = [0u64; 3];
    let mut backends = Vec::new();
    for a in &addrs {
        let mut w = sylva_proto::pb::worker_client::WorkerClient::connect(format!("http://{a}"))
            .await
            .unwrap();
        let s = w.status(sylva_proto::pb::StatusRequest {}).await.unwrap().into_inner();
        totals =
            [totals[0] + s.accel_builds, totals[1] + s.lb_solves, totals[2] + s.prepared_imports];
        backends.push((s.backend, s.backend_why));
    }
    assert_eq!(totals, [1, 1, 2], "structure builds, LB solves and imports over the farm");
    // `auto` was measured once, by the worker that prepared, and the others
    // took its choice with its data: every strip traced alike.
    assert!(backends.iter().all(|b| !b.0.is_empty() && b.0 == backends[0].0), "{backends:?}");
    let took = backends.iter().filter(|b| b.1.contains("measured before")).count();
    assert_eq!(took, 2, "{backends:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_killed_mid_frame_loses_nothing() {
    let dir = std::env::temp_dir().join(format!("sylva-cluster-b-{}", std::process::id()));
    let b = bundle::pack(&scene(&dir)).unwrap();
    let want = reference(&b, &dir.join("ref"), 9);
    let workers = Arc::new(Mutex::new((0..3).map(|_| start_worker()).collect::<Vec<_>>()));
    let addrs: Vec<String> = workers.lock().unwrap().iter().map(|w| w.addr.clone()).collect();
    let victim = addrs[1].clone();
    // Many narrow strips, so plenty are still queued when the kill comes.
    let plan = Dynamic { share: 8.0, min_width: 2, ..Default::default() }.plan(96, 3, &[]);
    assert!(plan.len() > 12);
    let killed = Arc::new(Mutex::new(false));
    let (w2, k2) = (workers.clone(), killed.clone());
    let f =
        farm::render_frame(&farm::Workers::open(&addrs), &b, frame(9), plan, DEADLINE, move |e| {
            if let FarmEvent::StripDone { .. } = e {
                let mut k = k2.lock().unwrap();
                if !*k {
                    // SIGKILL: the worker dies with whatever strip it holds.
                    let _ = w2.lock().unwrap()[1].child.kill();
                    *k = true;
                }
            }
        })
        .await
        .unwrap();
    assert!(*killed.lock().unwrap());
    assert_eq!(bits(&f.image), want, "the frame must be bit-identical to a clean run");
    let v = f.workers.iter().find(|w| w.worker == victim).unwrap();
    assert!(v.dropped && v.failures >= 1, "{v:?}");
    let survivors: u32 = f.workers.iter().filter(|w| w.worker != victim).map(|w| w.strips).sum();
    assert!(survivors > 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_jobs_at_once_all_complete_correctly() {
    let dir = std::env::temp_dir().join(format!("sylva-cluster-c-{}", std::process::id()));
    let b = bundle::pack(&scene(&dir)).unwrap();
    let want: Vec<Vec<u32>> =
        (0..3).map(|s| reference(&b, &dir.join(format!("ref{s}")), 20 + s)).collect();
    let workers: Vec<Worker> = (0..3).map(|_| start_worker()).collect();
    let addrs: Vec<String> = workers.iter().map(|w| w.addr.clone()).collect();
    let jobs = (0..3u32).map(|s| {
        let (addrs, b) = (addrs.clone(), b.clone());
        tokio::spawn(async move {
            farm::render_frame(
                &farm::Workers::open(&addrs),
                &b,
                frame(20 + s),
                Dynamic::default().plan(96, 3, &[]),
                DEADLINE,
                |_| {},
            )
            .await
        })
    });
    for (job, want) in jobs.collect::<Vec<_>>().into_iter().zip(&want) {
        let f = job.await.unwrap().unwrap();
        assert_eq!(&bits(&f.image), want);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frame_fails_with_a_reason_when_no_worker_can_finish_it() {
    let dir = std::env::temp_dir().join(format!("sylva-cluster-d-{}", std::process::id()));
    let b = bundle::pack(&scene(&dir)).unwrap();
    // Nobody listens there.
    let gone = vec!["127.0.0.1:9".to_string()];
    let err = farm::render_frame(
        &farm::Workers::open(&gone),
        &b,
        frame(1),
        Static.plan(96, 1, &[]),
        DEADLINE,
        |_| {},
    )
    .await
    .unwrap_err();
    assert!(err.to_string().contains("no worker left"), "{err}");
}

#[test]
fn the_scaling_benchmark_reports_measured_and_simulated_figures_and_a_chart() {
    let dir = std::env::temp_dir().join(format!("sylva-cluster-e-{}", std::process::id()));
    let scene = scene(&dir);
    let chart = dir.join("scaling.svg");
    let out = sylva(
        &[
            "bench",
            "scaling",
            scene.to_str().unwrap(),
            "--workers",
            "1,2,4",
            "--width",
            "64",
            "--height",
            "32",
            "--profile-strips",
            "8",
            "--local-real",
            "1",
            "--chart",
            chart.to_str().unwrap(),
            "--json",
        ],
        &[],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 6);
    for r in rows {
        let sim = &r["simulated"];
        assert!(sim["frame_s"].as_f64().unwrap() > 0.0 && sim["speedup"].as_f64().unwrap() > 0.0);
        // Only one worker count was measured on real processes.
        assert_eq!(r["measured"].is_null(), r["workers"] != 1, "{r}");
    }
    assert!(v["figures"]["simulated"].as_str().unwrap().contains("virtual workers"));
    let svg = std::fs::read_to_string(&chart).unwrap();
    assert!(
        svg.starts_with("<svg")
            && svg.contains("ideal")
            && svg.contains("static")
            && svg.contains("dynamic")
    );
}
