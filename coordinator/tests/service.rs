//! A coordinator process and worker processes that register with it, driven
//! by `sylva submit` clients and a raw gRPC client, all on loopback.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use sylva_proto::pb;
use sylva_proto::pb::coordinator_client::CoordinatorClient;
use tonic::Code;

struct Proc {
    child: Child,
    addr: String,
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn runtime() -> PathBuf {
    let r = std::env::temp_dir().join("sylva-xdg");
    std::fs::create_dir_all(&r).unwrap();
    r
}

fn spawn(args: &[&str], env: &[(&str, &str)]) -> Proc {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_sylva"));
    cmd.args(args).env("XDG_RUNTIME_DIR", runtime()).env_remove("SYLVA_TOKEN").stdout(Stdio::piped());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    Proc { addr: line.trim().rsplit(' ').next().unwrap().to_string(), child }
}

fn sylva(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_sylva"));
    cmd.args(args).env("XDG_RUNTIME_DIR", runtime()).env_remove("SYLVA_TOKEN");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().unwrap()
}

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
    let mut c = CoordinatorClient::connect(format!("http://{addr}")).await.unwrap();
    for _ in 0..200 {
        let w = c.list_workers(pb::ListWorkersRequest {}).await.unwrap().into_inner().workers;
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
    let metrics = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().to_string();
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--metrics", &metrics], &[]);
    let _workers: Vec<Proc> = (0..3).map(|_| spawn(&["worker", "--listen", "127.0.0.1:0", "--coordinator", &coord.addr], &[])).collect();
    let mut c = wait_for_workers(&coord.addr, 3).await;
    let reference = dir.join("reference.png");
    let size = ["--width", "80", "--height", "40", "--spp", "2"];
    let out = sylva(&[&["render", s.to_str().unwrap(), "-o", reference.to_str().unwrap(), "--local-workers", "0"][..], &size[..]].concat(), &[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let clients: Vec<_> = (0..3)
        .map(|i| {
            let png = dir.join(format!("client{i}.png"));
            let args: Vec<String> = [&["submit", s.to_str().unwrap(), "--coordinator", &coord.addr, "-o", png.to_str().unwrap()][..], &size[..]]
                .concat()
                .iter()
                .map(|a| a.to_string())
                .collect();
            (png, std::thread::spawn(move || sylva(&args.iter().map(|a| a.as_str()).collect::<Vec<_>>(), &[])))
        })
        .collect();
    for (png, t) in clients {
        let out = t.join().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert_eq!(std::fs::read(&png).unwrap(), std::fs::read(&reference).unwrap(), "{}", png.display());
    }
    let jobs = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    assert_eq!(jobs.len(), 3);
    assert!(jobs.iter().all(|j| j.state == "done" && j.strips_done == j.strips_total && j.strips_total > 0), "{jobs:?}");
    assert_eq!(c.fetch_result(pb::FetchRequest { id: "job-99".into(), format: "png".into() }).await.unwrap_err().code(), Code::NotFound);
    let exr = c.fetch_result(pb::FetchRequest { id: jobs[0].id.clone(), format: "exr".into() }).await.unwrap().into_inner();
    assert!(exr.data.starts_with(&[0x76, 0x2f, 0x31, 0x01]), "OpenEXR magic");

    // Prometheus text on the metrics port.
    use std::io::{Read, Write};
    let mut sock = std::net::TcpStream::connect(&metrics).unwrap();
    sock.write_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
    let mut text = String::new();
    sock.read_to_string(&mut text).unwrap();
    let value = |name: &str| -> f64 {
        text.lines().find(|l| l.starts_with(&format!("{name} "))).and_then(|l| l.rsplit(' ').next()).unwrap_or_else(|| panic!("{name} in {text}")).parse().unwrap()
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
    let _w = spawn(&["worker", "--listen", "127.0.0.1:0", "--coordinator", &coord.addr], &[("SYLVA_TOKEN", "s3cret")]);
    let submit = |extra: &[&str], token: Option<&str>| {
        let png = dir.join("out.png");
        let mut args = vec!["submit", s.to_str().unwrap(), "--coordinator", &coord.addr, "-o", png.to_str().unwrap(), "--width", "32"];
        args.extend_from_slice(extra);
        let env: Vec<(&str, &str)> = token.map(|t| vec![("SYLVA_TOKEN", t)]).unwrap_or_default();
        sylva(&args, &env)
    };
    let no_token = submit(&["--height", "16"], None);
    assert!(String::from_utf8_lossy(&no_token.stderr).contains("Unauthenticated"), "{}", String::from_utf8_lossy(&no_token.stderr));
    let absurd = submit(&["--height", "16", "--spp", "5000"], Some("s3cret"));
    assert!(String::from_utf8_lossy(&absurd.stderr).contains("InvalidArgument: spp 5000"), "{}", String::from_utf8_lossy(&absurd.stderr));
    let wide = submit(&["--height", "20000"], Some("s3cret"));
    assert!(String::from_utf8_lossy(&wide.stderr).contains("InvalidArgument"), "{}", String::from_utf8_lossy(&wide.stderr));
    // The service is still up and renders a good job.
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
    let out = sylva(&["submit", s.to_str().unwrap(), "--coordinator", &lonely.addr, "-o", png.to_str().unwrap(), "--width", "16", "--height", "8"], &[]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("no worker is registered"), "{}", String::from_utf8_lossy(&out.stderr));
    // A worker named on the command line is used by a job submitted straight away.
    let w = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &w.addr], &[]);
    let out = sylva(&["submit", s.to_str().unwrap(), "--coordinator", &coord.addr, "-o", png.to_str().unwrap(), "--width", "16", "--height", "8"], &[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(png.exists());
}
