//! Helpers the integration tests share: `sylva` processes on loopback
//! (killed when dropped), scratch folders, small scenes, raw gRPC clients.
#![allow(dead_code)] // each test binary uses its own subset

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;
use sylva_proto::pb;
use sylva_proto::pb::coordinator_client::CoordinatorClient;

/// A `sylva` process serving on loopback, killed when dropped.
pub struct Proc {
    pub child: Child,
    pub addr: String,
}

impl Drop for Proc {
    fn drop(&mut self) {
        // SIGTERM first, so it removes its temporary folders; killed if it
        // has not left within a second.
        #[cfg(unix)]
        // SAFETY: signals our own child.
        unsafe {
            libc::kill(self.child.id() as i32, libc::SIGTERM)
        };
        for _ in 0..50 {
            if self.child.try_wait().ok().flatten().is_some() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Proc {
    /// Stops it with SIGTERM, as an orchestrator does, and waits.
    pub fn terminate(mut self) {
        #[cfg(unix)]
        {
            // SAFETY: signals our own child; no `kill` binary needed (Debian's minimal images lack one).
            unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
            for _ in 0..100 {
                if self.child.try_wait().ok().flatten().is_some() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(50));
            }
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A private runtime folder, which silences the Vulkan loader's warning.
pub fn runtime() -> PathBuf {
    let r = std::env::temp_dir().join("sylva-xdg");
    std::fs::create_dir_all(&r).unwrap();
    r
}

fn command(args: &[&str], env: &[(&str, &str)]) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_sylva"));
    cmd.args(args).env("XDG_RUNTIME_DIR", runtime()).env_remove("SYLVA_TOKEN");
    // A coordinator keeps its queue in a state folder; a test's is its own
    // and gone at exit, unless the test names one to restart on.
    if args.first() == Some(&"coordinator") && !args.contains(&"--state-dir") {
        cmd.arg("--ephemeral");
    }
    cmd.env_remove("SYLVA_STATE_DIR").env_remove("SYLVA_DATABASE_URL");
    // Prepared data kept on disk would carry one test's work into the next
    // (and the user's cache into the tests): off, unless a test turns it on.
    cmd.env("SYLVA_PREPARED_CACHE_MIB", "0").env_remove("SYLVA_PREPARED_CACHE_DIR");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd
}

/// Starts `sylva ARGS` and reads the address it announces.
pub fn spawn(args: &[&str], env: &[(&str, &str)]) -> Proc {
    spawn_logging(args, env, None)
}

/// Like [`spawn`], with the process's stderr (its log) going to `log`.
pub fn spawn_logging(args: &[&str], env: &[(&str, &str)], log: Option<&Path>) -> Proc {
    let mut cmd = command(args, env);
    cmd.stdout(Stdio::piped());
    if let Some(l) = log {
        cmd.stderr(std::fs::File::create(l).unwrap());
    }
    let mut child = cmd.spawn().unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    assert!(line.contains(" listening on "), "sylva {args:?} did not start: {line:?}");
    Proc { addr: line.trim().rsplit(' ').next().unwrap().to_string(), child }
}

/// Runs `sylva ARGS` to the end.
pub fn sylva(args: &[&str], env: &[(&str, &str)]) -> Output {
    command(args, env).output().unwrap()
}

/// A fresh, empty folder for one test.
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sylva-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A small two-tree scene with local lighting (no LB solve, so it renders
/// fast), written as `dir/scene.json`.
pub fn small_scene(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let p = dir.join("scene.json");
    std::fs::write(
        &p,
        r#"{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 3000, "seed": 1 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 0] }, { "model": "maple", "position": [8, 0, 4], "rotate_y_deg": 30 } ],
        "camera": { "position": [4, 8, -26], "look_at": [4, 7, 0], "fov_y_deg": 45 },
        "sun": { "elevation_deg": 50, "azimuth_deg": 120 },
        "ground": { "color": [0.1, 0.08, 0.05] },
        "lighting": "local",
        "lb": { "grid": 8, "preset": "leaf" }
    }"#,
    )
    .unwrap();
    p
}

/// A raw coordinator client that sends `token`, if any.
pub type Client = CoordinatorClient<
    tonic::service::interceptor::InterceptedService<
        tonic::transport::Channel,
        sylva_proto::auth::Attach,
    >,
>;

/// Connects to the coordinator at `addr` with `token`.
pub async fn coordinator(addr: &str, token: Option<&str>) -> Client {
    let ch = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect()
        .await
        .unwrap();
    CoordinatorClient::with_interceptor(ch, sylva_proto::auth::attach(token.map(str::to_string)))
        .max_decoding_message_size(64 << 20)
}

/// Waits until the coordinator lists `n` live workers.
pub async fn wait_for_workers(c: &mut Client, n: usize) {
    for _ in 0..200 {
        let w = c.list_workers(pb::ListWorkersRequest {}).await.unwrap().into_inner().workers;
        if w.iter().filter(|w| w.alive).count() >= n {
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("workers did not register");
}

/// A job's submission: the spec and the bundle's bytes in 64 KiB chunks.
pub fn submission(
    spec: pb::JobSpec,
    hash: &str,
    bytes: &[u8],
    declared: u64,
) -> Vec<pb::SubmitChunk> {
    let mut chunks = vec![pb::SubmitChunk {
        spec: Some(spec),
        hash: hash.to_string(),
        total_size: declared,
        data: vec![],
    }];
    chunks.extend(
        bytes.chunks(1 << 16).map(|d| pb::SubmitChunk { data: d.to_vec(), ..Default::default() }),
    );
    chunks
}

/// A job spec for a `width`×`height` frame, 1 spp, the scene's lighting.
pub fn spec(width: u32, height: u32) -> pb::JobSpec {
    pb::JobSpec {
        frame: Some(pb::FrameSettings {
            width,
            height,
            spp: 1,
            seed: 1,
            lighting: pb::Lighting::Scene.into(),
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
        name: "test".into(),
        submitter: "test".into(),
        views: vec![],
    }
}

/// Submits a packed bundle and follows the job to its end; the last event.
pub async fn submit_and_wait(
    c: &mut Client,
    spec: pb::JobSpec,
    b: &sylva_scene::bundle::SceneBundle,
    mut on_event: impl FnMut(&pb::JobEvent),
) -> pb::JobEvent {
    let id = c
        .submit_job(tokio_stream::iter(submission(spec, &b.hash, &b.bytes, b.bytes.len() as u64)))
        .await
        .unwrap()
        .into_inner()
        .id;
    let mut events = c.watch_job(pb::JobId { id }).await.unwrap().into_inner();
    while let Some(ev) = tokio_stream::StreamExt::next(&mut events).await {
        let ev = ev.unwrap();
        on_event(&ev);
        if sylva_coordinator::job_state::wire_ended(ev.state) {
            return ev;
        }
    }
    panic!("the event stream ended early");
}

/// The same frame rendered in a `sylva render --local-workers 0` process.
pub fn reference_png(scene: &Path, out: &Path, width: u32, height: u32) -> Vec<u8> {
    let o = sylva(
        &[
            "render",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--local-workers",
            "0",
            "--width",
            &width.to_string(),
            "--height",
            &height.to_string(),
        ],
        &[],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::read(out).unwrap()
}

/// Runs `sylva ARGS`, which must succeed; its stdout.
pub fn ok(args: &[&str]) -> String {
    let out = sylva(args, &[]);
    assert!(
        out.status.success(),
        "sylva {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Runs `sylva ARGS`, which must fail; its stderr.
pub fn fails(args: &[&str]) -> String {
    let out = sylva(args, &[]);
    assert!(!out.status.success(), "sylva {args:?} should fail");
    String::from_utf8(out.stderr).unwrap()
}
