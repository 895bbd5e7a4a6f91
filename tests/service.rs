//! A coordinator process and worker processes that register with it, driven
//! by `sylva submit` clients and a raw gRPC client, all on loopback.

use crate::common;

use common::{Proc, spawn, sylva};
use std::path::{Path, PathBuf};
use sylva_proto::pb;
use sylva_proto::pb::coordinator_client::CoordinatorClient;
use tonic::Code;

fn scene(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let p = dir.join("scene.json");
    std::fs::write(
        &p,
        r#"{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 5000, "seed": 1 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 0] }, { "model": "maple", "position": [8, 0, 4], "rotate_y_deg": 30 } ],
        "camera": { "position": [4, 8, -26], "look_at": [4, 7, 0], "fov_y_deg": 45 },
        "sun": { "elevation_deg": 50, "azimuth_deg": 120 },
        "ground": { "color": [0.1, 0.08, 0.05] },
        "lb": { "grid": 10, "preset": "leaf" }
    }"#,
    )
    .unwrap();
    p
}

async fn wait_for_workers(addr: &str, n: usize) -> CoordinatorClient<tonic::transport::Channel> {
    wait_for_workers_with(addr, n, None).await
}

/// Waits (up to a minute: workers start their GPU first) until `n` workers
/// are registered and alive, asking with `token` where the coordinator needs one.
async fn wait_for_workers_with(
    addr: &str,
    n: usize,
    token: Option<&str>,
) -> CoordinatorClient<tonic::transport::Channel> {
    let mut c = CoordinatorClient::connect(format!("http://{addr}")).await.unwrap();
    for _ in 0..1200 {
        let mut req = tonic::Request::new(pb::ListWorkersRequest {});
        if let Some(t) = token {
            req.metadata_mut().insert("authorization", format!("Bearer {t}").parse().unwrap());
        }
        let w = c.list_workers(req).await.unwrap().into_inner().workers;
        if w.iter().filter(|w| w.alive).count() >= n {
            return c;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    panic!("workers did not register");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_clients_at_once_get_the_single_process_image() {
    let dir = std::env::temp_dir().join(format!("sylva-service-a-{}", std::process::id()));
    let s = scene(&dir);
    let metrics =
        std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().to_string();
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--metrics", &metrics], &[]);
    // One listens on every interface, as the README's worker line does:
    // it must advertise an address the coordinator can dial, not 0.0.0.0.
    let _workers: Vec<Proc> = ["127.0.0.1:0", "127.0.0.1:0", "0.0.0.0:0"]
        .iter()
        .map(|l| spawn(&["worker", "--listen", l, "--coordinator", &coord.addr], &[]))
        .collect();
    let mut c = wait_for_workers(&coord.addr, 3).await;
    let listed = c.list_workers(pb::ListWorkersRequest {}).await.unwrap().into_inner().workers;
    assert!(
        listed.iter().all(|w| !w.addr.starts_with("0.0.0.0")),
        "{:?}",
        listed.iter().map(|w| &w.addr).collect::<Vec<_>>()
    );
    let reference = dir.join("reference.png");
    let size = ["--width", "80", "--height", "40", "--spp", "2"];
    let out = sylva(
        &[
            &[
                "render",
                s.to_str().unwrap(),
                "-o",
                reference.to_str().unwrap(),
                "--local-workers",
                "0",
            ][..],
            &size[..],
        ]
        .concat(),
        &[],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let clients: Vec<_> = (0..3)
        .map(|i| {
            let png = dir.join(format!("client{i}.png"));
            let args: Vec<String> = [
                &[
                    "submit",
                    s.to_str().unwrap(),
                    "--coordinator",
                    &coord.addr,
                    "-o",
                    png.to_str().unwrap(),
                ][..],
                &size[..],
            ]
            .concat()
            .iter()
            .map(|a| a.to_string())
            .collect();
            (
                png,
                std::thread::spawn(move || {
                    sylva(&args.iter().map(|a| a.as_str()).collect::<Vec<_>>(), &[])
                }),
            )
        })
        .collect();
    for (png, t) in clients {
        let out = t.join().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert_eq!(
            std::fs::read(&png).unwrap(),
            std::fs::read(&reference).unwrap(),
            "{}",
            png.display()
        );
    }
    let jobs = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    assert_eq!(jobs.len(), 3);
    // A watcher that comes after a job's end hears its figures at once,
    // as one there at the end did (a fast frame ended before `submit`
    // watched it, and its figures were lost).
    let mut late = c.watch_job(pb::JobId { id: jobs[0].id.clone() }).await.unwrap().into_inner();
    let first = tokio_stream::StreamExt::next(&mut late).await.unwrap().unwrap();
    let figures: serde_json::Value = serde_json::from_str(&first.stats_json).unwrap();
    assert!(figures["strips"].as_array().is_some_and(|s| !s.is_empty()), "{figures}");
    assert!(figures["phases"]["farm_ms"].as_f64().unwrap() > 0.0, "{figures}");
    assert!(
        jobs.iter().all(|j| sylva_coordinator::job_state::wire_name(j.state) == "done"
            && j.strips_done == j.strips_total
            && j.strips_total > 0),
        "{jobs:?}"
    );
    assert_eq!(
        c.fetch_result(pb::FetchRequest {
            id: "job-99".into(),
            format: "png".into(),
            ..Default::default()
        })
        .await
        .unwrap_err()
        .code(),
        Code::NotFound
    );
    let exr = c
        .fetch_result(pb::FetchRequest {
            id: jobs[0].id.clone(),
            format: "exr".into(),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    assert!(exr.data.starts_with(&[0x76, 0x2f, 0x31, 0x01]), "OpenEXR magic");

    // Prometheus text on the metrics port.
    use std::io::{Read, Write};
    let mut sock = std::net::TcpStream::connect(&metrics).unwrap();
    sock.write_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").unwrap();
    let mut text = String::new();
    sock.read_to_string(&mut text).unwrap();
    let value = |name: &str| -> f64 {
        text.lines()
            .find(|l| l.starts_with(&format!("{name} ")))
            .and_then(|l| l.rsplit(' ').next())
            .unwrap_or_else(|| panic!("{name} in {text}"))
            .parse()
            .unwrap()
    };
    let strips: u32 = jobs.iter().map(|j| j.strips_total).sum();
    assert_eq!(value("sylva_strips_done_total"), strips as f64);
    assert_eq!(value("sylva_strip_seconds_count"), strips as f64);
    assert_eq!(value("sylva_workers_alive"), 3.0);
    assert_eq!(value("sylva_jobs_queued"), 0.0);
    assert!(value("sylva_bytes_received_total") > 0.0 && value("sylva_bytes_sent_total") > 0.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_jobs_are_refused_and_tokens_are_required() {
    let dir = std::env::temp_dir().join(format!("sylva-service-b-{}", std::process::id()));
    let s = scene(&dir);
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--token", "s3cret"], &[]);
    let _w = spawn(
        &["worker", "--listen", "127.0.0.1:0", "--coordinator", &coord.addr],
        &[("SYLVA_TOKEN", "s3cret")],
    );
    let submit = |extra: &[&str], token: Option<&str>| {
        let png = dir.join("out.png");
        let mut args = vec![
            "submit",
            s.to_str().unwrap(),
            "--coordinator",
            &coord.addr,
            "-o",
            png.to_str().unwrap(),
            "--width",
            "32",
        ];
        args.extend_from_slice(extra);
        let env: Vec<(&str, &str)> = token.map(|t| vec![("SYLVA_TOKEN", t)]).unwrap_or_default();
        sylva(&args, &env)
    };
    let no_token = submit(&["--height", "16"], None);
    assert!(
        String::from_utf8_lossy(&no_token.stderr).contains("Unauthenticated"),
        "{}",
        String::from_utf8_lossy(&no_token.stderr)
    );
    // `submit` checks the frame with the same rule the coordinator applies
    // (tests/hostile.rs sends such frames past it, over raw gRPC).
    let absurd = submit(&["--height", "16", "--spp", "5000"], Some("s3cret"));
    assert!(
        String::from_utf8_lossy(&absurd.stderr).contains("spp 5000: valid range [1, 4096]"),
        "{}",
        String::from_utf8_lossy(&absurd.stderr)
    );
    let wide = submit(&["--height", "20000"], Some("s3cret"));
    assert!(
        String::from_utf8_lossy(&wide.stderr).contains("each side must be in [1, 16384]"),
        "{}",
        String::from_utf8_lossy(&wide.stderr)
    );
    // The service is still up and renders a good job (once its worker has
    // registered: under load that can take longer than the refusals above).
    wait_for_workers_with(&coord.addr, 1, Some("s3cret")).await;
    let ok = submit(&["--height", "16"], Some("s3cret"));
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn named_workers_serve_at_once_and_no_workers_is_a_clear_failure() {
    let dir = std::env::temp_dir().join(format!("sylva-service-c-{}", std::process::id()));
    let s = scene(&dir);
    let png = dir.join("out.png");
    // No workers at all: the job fails with the reason.
    let lonely = spawn(&["coordinator", "--listen", "127.0.0.1:0"], &[]);
    let out = sylva(
        &[
            "submit",
            s.to_str().unwrap(),
            "--coordinator",
            &lonely.addr,
            "-o",
            png.to_str().unwrap(),
            "--width",
            "16",
            "--height",
            "8",
        ],
        &[],
    );
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no worker is registered"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A worker named on the command line is used by a job submitted straight away.
    let w = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &w.addr], &[]);
    let out = sylva(
        &[
            "submit",
            s.to_str().unwrap(),
            "--coordinator",
            &coord.addr,
            "-o",
            png.to_str().unwrap(),
            "--width",
            "16",
            "--height",
            "8",
        ],
        &[],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(png.exists());
}

/// Submits `scene` at `width`×`height` to the coordinator at `addr` over
/// raw gRPC; calls `on_event` with each progress event.
async fn submit_raw(
    c: &mut CoordinatorClient<tonic::transport::Channel>,
    scene: &Path,
    width: u32,
    height: u32,
    mut on_event: impl FnMut(&pb::JobEvent),
) -> (pb::JobEvent, Vec<u8>) {
    let b = sylva_scene::bundle::pack(scene).unwrap();
    let spec = pb::JobSpec {
        frame: Some(pb::FrameSettings {
            width,
            height,
            spp: 2,
            seed: 1,
            lighting: pb::Lighting::Lb.into(),
            accel: pb::Accel::Bvh.into(),
            lb_strength: 0.35,
            ambient: vec![],
            view: None,
            gather_bounces: 0,
            gather_filter: None,
            passes: vec![],
            denoise: 0,
        }),
        schedule: pb::Schedule::Dynamic.into(),
        priority: 0,
        name: "raw".into(),
        submitter: "raw".into(),
        views: vec![],
    };
    let mut chunks = vec![pb::SubmitChunk {
        spec: Some(spec),
        hash: b.hash.clone(),
        total_size: b.bytes.len() as u64,
        data: vec![],
    }];
    chunks.extend(
        b.bytes.chunks(1 << 16).map(|d| pb::SubmitChunk { data: d.to_vec(), ..Default::default() }),
    );
    let id = c.submit_job(tokio_stream::iter(chunks)).await.unwrap().into_inner().id;
    let mut events = c.watch_job(pb::JobId { id: id.clone() }).await.unwrap().into_inner();
    let mut last = None;
    while let Some(ev) = tokio_stream::StreamExt::next(&mut events).await {
        let ev = ev.unwrap();
        on_event(&ev);
        if sylva_coordinator::job_state::wire_ended(ev.state) {
            last = Some(ev);
            break;
        }
    }
    let last = last.unwrap();
    assert_eq!(sylva_coordinator::job_state::wire_name(last.state), "done", "{last:?}");
    let png = c
        .fetch_result(pb::FetchRequest { id, format: "png".into(), ..Default::default() })
        .await
        .unwrap()
        .into_inner()
        .data;
    (last, png)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_killed_mid_job_loses_nothing_through_the_coordinator() {
    let dir = std::env::temp_dir().join(format!("sylva-service-d-{}", std::process::id()));
    let s = scene(&dir);
    let reference = dir.join("reference.png");
    let out = sylva(
        &[
            "render",
            s.to_str().unwrap(),
            "-o",
            reference.to_str().unwrap(),
            "--local-workers",
            "0",
            "--width",
            "192",
            "--height",
            "48",
            "--spp",
            "2",
        ],
        &[],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let mut workers: Vec<Proc> =
        (0..3).map(|_| spawn(&["worker", "--listen", "127.0.0.1:0"], &[])).collect();
    let names: Vec<String> = workers.iter().map(|w| w.addr.clone()).collect();
    let coord =
        spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &names.join(",")], &[]);
    let mut c = CoordinatorClient::connect(format!("http://{}", coord.addr)).await.unwrap();
    let mut notices = Vec::new();
    let mut killed = false;
    let (end, png) = submit_raw(&mut c, &s, 192, 48, |ev| {
        if ev.strips_done >= 1 && !killed {
            // SIGKILL: the worker dies with whatever strip it holds.
            workers[1].child.kill().unwrap();
            killed = true;
        }
        if !ev.message.is_empty() {
            notices.push(ev.message.clone());
        }
    })
    .await;
    assert!(killed);
    assert_eq!(
        png,
        std::fs::read(&reference).unwrap(),
        "the frame must be bit-identical to a clean run"
    );
    assert!(
        notices.iter().any(|m| m.contains(&names[1])),
        "the victim's failure is reported: {notices:?}"
    );
    let stats: serde_json::Value = serde_json::from_str(&end.stats_json).unwrap();
    let victim = stats["workers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| w["worker"] == names[1].as_str())
        .unwrap();
    assert!(victim["failures"].as_u64().unwrap() >= 1, "{victim}");
    assert!(stats["strip_cost"].as_str().unwrap().starts_with("uniform"), "{stats}");
    // The next frame of the scene is cut by the cost the first one measured.
    let (end, _) = submit_raw(&mut c, &s, 192, 48, |_| {}).await;
    let stats: serde_json::Value = serde_json::from_str(&end.stats_json).unwrap();
    assert_eq!(stats["strip_cost"], "measured on the previous frame", "{stats}");
}

/// A CA and a certificate for `localhost`/127.0.0.1 signed by it, as PEM
/// files in `dir`: (ca.pem, cert.pem, key.pem).
fn certificates(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, IsCa, KeyPair};
    std::fs::create_dir_all(dir).unwrap();
    let mut ca_params = CertificateParams::new(Vec::<String>::new()).unwrap();
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    let ca = CertifiedIssuer::self_signed(ca_params, KeyPair::generate().unwrap()).unwrap();
    let key = KeyPair::generate().unwrap();
    let cert = CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".to_string()])
        .unwrap()
        .signed_by(&key, &ca)
        .unwrap();
    let paths = (dir.join("ca.pem"), dir.join("cert.pem"), dir.join("key.pem"));
    std::fs::write(&paths.0, ca.pem()).unwrap();
    std::fs::write(&paths.1, cert.pem()).unwrap();
    std::fs::write(&paths.2, key.serialize_pem()).unwrap();
    paths
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_on_both_services_with_a_token() {
    let dir = std::env::temp_dir().join(format!("sylva-service-e-{}", std::process::id()));
    let s = scene(&dir);
    let (ca, cert, key) = certificates(&dir);
    let (ca, cert, key) = (ca.to_str().unwrap(), cert.to_str().unwrap(), key.to_str().unwrap());
    let token = [("SYLVA_TOKEN", "s3cret")];
    let w =
        spawn(&["worker", "--listen", "127.0.0.1:0", "--tls-cert", cert, "--tls-key", key], &token);
    let coord = spawn(
        &[
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--workers",
            &w.addr,
            "--tls-cert",
            cert,
            "--tls-key",
            key,
            "--tls-ca",
            ca,
        ],
        &token,
    );
    let png = dir.join("out.png");
    let submit = |extra: &[&str], env: &[(&str, &str)]| {
        let mut args = vec![
            "submit",
            s.to_str().unwrap(),
            "--coordinator",
            &coord.addr,
            "-o",
            png.to_str().unwrap(),
            "--width",
            "32",
            "--height",
            "16",
        ];
        args.extend_from_slice(extra);
        sylva(&args, env)
    };
    let ok = submit(&["--tls-ca", ca], &token);
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
    // Plain text to a TLS server, and TLS without the token, are refused.
    let plain = submit(&[], &token);
    assert!(!plain.status.success());
    let no_token = submit(&["--tls-ca", ca], &[]);
    assert!(
        String::from_utf8_lossy(&no_token.stderr).contains("Unauthenticated"),
        "{}",
        String::from_utf8_lossy(&no_token.stderr)
    );
    // A client that does not trust the CA is refused by its own TLS check.
    let (other_ca, _, _) = certificates(&dir.join("other"));
    let untrusted = submit(&["--tls-ca", other_ca.to_str().unwrap()], &token);
    assert!(!untrusted.status.success());
}

/// A worker listening on every interface whose coordinator no route
/// reaches refuses to start, naming `--advertise`, rather than register
/// an address nobody can dial (issue 41).
#[test]
fn a_worker_on_every_interface_without_a_route_asks_for_advertise() {
    let out =
        sylva(&["worker", "--listen", "0.0.0.0:0", "--coordinator", "nowhere.invalid:50150"], &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--advertise HOST:"), "{err}");
    assert!(!String::from_utf8_lossy(&out.stdout).contains("listening"), "it never started");
}

/// A coordinator open beyond this machine says what a user must know: a
/// token over plain gRPC or HTTP can be read on the way, and the
/// dashboard's address is one another machine can open, not `0.0.0.0`.
#[test]
fn a_coordinator_on_every_interface_warns_of_clear_text_tokens() {
    let dir = std::env::temp_dir().join(format!("sylva-service-open-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("coordinator.log");
    let args = ["coordinator", "--listen", "0.0.0.0:0", "--http", "0.0.0.0:0", "--token", "t"];
    let c = common::spawn_logging(&args, &[], Some(&log));
    drop(c);
    let said = std::fs::read_to_string(&log).unwrap();
    assert!(said.contains("without TLS: bearer tokens cross the network readable"), "{said}");
    assert!(said.contains("the dashboard serves beyond this machine over plain HTTP"), "{said}");
    let url = said.lines().find(|l| l.contains("dashboard on")).unwrap_or_default();
    assert!(url.contains("http://") && !url.contains("0.0.0.0"), "{url}");
    let _ = std::fs::remove_dir_all(&dir);
}
