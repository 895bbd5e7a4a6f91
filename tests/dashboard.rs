//! The web dashboard in a real headless browser (Debian's `chromium`,
//! driven over the DevTools protocol): a job submitted from the command
//! line appears, progresses and finishes on the page; the page's cancel
//! button stops another job. A screenshot is written to
//! `sylva-out/dashboard.png` (or `$SYLVA_DASHBOARD_SCREENSHOT`).

use crate::common;

use base64::Engine as _;
use common::{coordinator, scratch, small_scene, spawn, spec, submission, sylva};
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_tungstenite::tungstenite::Message;

const TOKEN: &str = "s3cret";

/// A port free now (the process given it binds it a moment later).
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// A plain HTTP/1.1 GET: status and body (read to its Content-Length,
/// since Chromium's DevTools server keeps the connection open).
async fn get(addr: &str, path: &str, headers: &str) -> (u16, String) {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(
        format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n{headers}\r\n")
            .as_bytes(),
    )
    .await
    .unwrap();
    let mut out = Vec::new();
    let mut buf = [0u8; 65536];
    loop {
        let n = tokio::time::timeout(Duration::from_secs(10), s.read(&mut buf))
            .await
            .expect("an answer")
            .unwrap();
        out.extend_from_slice(&buf[..n]);
        let text = String::from_utf8_lossy(&out).to_string();
        if let Some((head, body)) = text.split_once("\r\n\r\n") {
            let length = head.lines().find_map(|l| {
                l.to_ascii_lowercase()
                    .strip_prefix("content-length:")
                    .map(|v| v.trim().parse::<usize>().unwrap_or(0))
            });
            if n == 0 || length.is_some_and(|len| body.len() >= len) {
                let status =
                    head.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
                return (status, body.to_string());
            }
        }
        if n == 0 {
            return (0, String::new());
        }
    }
}

/// A plain HTTP/1.1 POST with an empty body: the status.
async fn post(addr: &str, path: &str, headers: &str) -> (u16, String) {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(format!("POST {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: 0\r\n{headers}\r\n").as_bytes()).await.unwrap();
    let mut out = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut out))
        .await
        .expect("an answer")
        .unwrap();
    let text = String::from_utf8_lossy(&out).to_string();
    (text.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0), text)
}

/// A headless Chromium and one DevTools connection to its page.
struct Browser {
    child: Child,
    ws: tokio_tungstenite::WebSocketStream<
        tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>,
    >,
    next: u64,
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Browser {
    async fn start(profile: &std::path::Path) -> Self {
        let port = free_port();
        let child = Command::new("chromium")
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--no-first-run",
                "--window-size=1280,1100",
                &format!("--remote-debugging-port={port}"),
                &format!("--user-data-dir={}", profile.display()),
                "about:blank",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromium runs (scripts/install-deps.sh installs it)");
        let addr = format!("127.0.0.1:{port}");
        let t = Instant::now();
        let page = loop {
            if let Ok(Ok(s)) =
                tokio::time::timeout(Duration::from_secs(2), tokio::net::TcpStream::connect(&addr))
                    .await
            {
                drop(s);
                let (_, body) = get(&addr, "/json/list", "").await;
                if let Ok(list) = serde_json::from_str::<Value>(&body)
                    && let Some(p) =
                        list.as_array().and_then(|l| l.iter().find(|t| t["type"] == "page"))
                {
                    break p["webSocketDebuggerUrl"].as_str().unwrap().to_string();
                }
            }
            assert!(
                t.elapsed() < Duration::from_secs(60),
                "chromium did not open its DevTools port"
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        };
        let (ws, _) = tokio_tungstenite::connect_async(page).await.unwrap();
        Browser { child, ws, next: 1 }
    }

    /// One DevTools command and its result (events in between are skipped).
    async fn call(&mut self, method: &str, params: Value) -> Value {
        let id = self.next;
        self.next += 1;
        self.ws
            .send(Message::Text(
                json!({ "id": id, "method": method, "params": params }).to_string().into(),
            ))
            .await
            .unwrap();
        loop {
            let msg = tokio::time::timeout(Duration::from_secs(30), self.ws.next())
                .await
                .expect("DevTools answers")
                .unwrap()
                .unwrap();
            if let Message::Text(t) = msg {
                let v: Value = serde_json::from_str(&t).unwrap();
                if v["id"] == id {
                    assert!(v.get("error").is_none(), "{method}: {v}");
                    return v["result"].clone();
                }
            }
        }
    }

    /// Evaluates `js` in the page; its value.
    async fn eval(&mut self, js: &str) -> Value {
        let r = self
            .call(
                "Runtime.evaluate",
                json!({ "expression": js, "returnByValue": true, "awaitPromise": true }),
            )
            .await;
        r["result"]["value"].clone()
    }

    /// Waits until `js` evaluates to true in the page, or fails naming `what`.
    async fn wait_for(&mut self, js: &str, what: &str, limit: Duration) {
        let t = Instant::now();
        while self.eval(js).await != json!(true) {
            let jobs = self.eval("document.querySelector('#jobs').innerText").await;
            assert!(t.elapsed() < limit, "the page never showed {what}; it shows:\n{jobs}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
}

fn state_of(id: &str) -> String {
    format!("(document.querySelector('tr[data-job=\"{id}\"] .state') || {{}}).textContent")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_follows_a_job_to_its_end_and_cancels_another() {
    let dir = scratch("dashboard");
    let scene = small_scene(&dir);
    let w = spawn(&["worker", "--listen", "127.0.0.1:0"], &[("SYLVA_TOKEN", TOKEN)]);
    let http = format!("127.0.0.1:{}", free_port());
    let coord = spawn(
        &[
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--workers",
            &w.addr,
            "--max-running",
            "1",
            "--http",
            &http,
        ],
        &[("SYLVA_TOKEN", TOKEN)],
    );
    let mut c = coordinator(&coord.addr, Some(TOKEN)).await;
    common::wait_for_workers(&mut c, 1).await;

    // Without the token the API tells nothing; the page itself loads.
    assert_eq!(get(&http, "/api/snapshot", "").await.0, 401);
    assert_eq!(
        get(&http, "/api/snapshot", &format!("Authorization: Bearer {TOKEN}\r\n")).await.0,
        200
    );
    let (status, page) = get(&http, "/", "").await;
    assert!(status == 200 && page.contains("Sylva farm"), "{status}");

    let mut b = Browser::start(&dir.join("chromium")).await;
    b.call("Page.enable", json!({})).await;
    b.call("Page.navigate", json!({ "url": format!("http://{http}/") })).await;
    b.wait_for(
        "document.readyState === 'complete' && !!document.querySelector('#token')",
        "itself",
        Duration::from_secs(30),
    )
    .await;
    // The token, entered as a user does.
    b.eval(&format!(
        "(() => {{ const t = document.querySelector('#token'); t.value = '{TOKEN}'; t.dispatchEvent(new Event('change')); return true; }})()"
    ))
    .await;
    b.wait_for(
        "document.querySelector('#connection').textContent === 'live'",
        "a live connection",
        Duration::from_secs(30),
    )
    .await;
    b.wait_for(
        &format!("!!document.querySelector('tr[data-worker=\"{}\"]')", w.addr),
        "the worker",
        Duration::from_secs(30),
    )
    .await;

    // A job submitted from the command line: it appears, progresses, finishes.
    let (cli_addr, cli_scene) = (coord.addr.clone(), scene.clone());
    let out = dir.join("first.png");
    let cli_out = out.clone();
    let submit = std::thread::spawn(move || {
        sylva(
            &[
                "submit",
                cli_scene.to_str().unwrap(),
                "--coordinator",
                &cli_addr,
                "-o",
                cli_out.to_str().unwrap(),
                "--width",
                "320",
                "--height",
                "160",
                "--spp",
                "4",
            ],
            &[("SYLVA_TOKEN", TOKEN), ("SYLVA_USER", "alice")],
        )
    });
    let t = Instant::now();
    let first = loop {
        let ids = b
            .eval("[...document.querySelectorAll('#jobs tbody tr')].map(r => r.dataset.job)")
            .await;
        if let Some(id) = ids.as_array().and_then(|a| a.first()).and_then(Value::as_str) {
            break id.to_string();
        }
        assert!(t.elapsed() < Duration::from_secs(30), "the submitted job never appeared");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let mut seen = Vec::new();
    let t = Instant::now();
    loop {
        let s = b.eval(&state_of(&first)).await.as_str().unwrap_or("").to_string();
        if seen.last() != Some(&s) {
            seen.push(s.clone());
        }
        if s == "done" {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(120), "states seen: {seen:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let said = submit.join().unwrap();
    assert!(said.status.success(), "{}", String::from_utf8_lossy(&said.stderr));
    assert!(
        seen.iter().any(|s| s == "running" || s == "queued"),
        "the page showed the job before it ended: {seen:?}"
    );
    let row =
        b.eval(&format!("document.querySelector('tr[data-job=\"{first}\"]').innerText")).await;
    let row = row.as_str().unwrap();
    assert!(row.contains("alice@127.0.0.1"), "{row}");
    let (done, total) = (
        b.eval(&format!("document.querySelector('tr[data-job=\"{first}\"] progress').value")).await,
        b.eval(&format!("document.querySelector('tr[data-job=\"{first}\"] progress').max")).await,
    );
    assert!(done == total && total.as_f64().unwrap() >= 1.0, "{done} of {total}");
    // The worker's row says which traversal `auto` chose there, and why.
    b.wait_for(
        &format!(
            "(() => {{ const c = document.querySelector('tr[data-worker=\"{}\"]').children[2]; \
             return /^(rq|bvh|cwbvh|kd)/.test(c.textContent) && c.title.startsWith('auto:'); }})()",
            w.addr
        ),
        "the worker's traversal",
        Duration::from_secs(60),
    )
    .await;
    // Its frame: the preview loaded, every column's worker drawn, and the charts.
    b.eval(&format!("document.querySelector('tr[data-job=\"{first}\"]').click(), true")).await;
    b.wait_for(
        "document.querySelector('#preview').complete && document.querySelector('#preview').naturalWidth === 320",
        "the frame's preview",
        Duration::from_secs(30),
    )
    .await;
    b.wait_for(
        "document.querySelectorAll('#columns rect').length > 0 && document.querySelectorAll('#latency rect').length === 16",
        "the strips and charts",
        Duration::from_secs(30),
    )
    .await;
    let covered = b.eval("[...document.querySelectorAll('#columns rect')].reduce((a, r) => a + Number(r.getAttribute('width')), 0)").await;
    assert_eq!(covered.as_f64(), Some(320.0), "the strips cover the frame once");
    // Its results download from its row: the PNG is the one `submit`
    // wrote, the EXR an OpenEXR file, each named for the job.
    let fetched = |format: &str| {
        format!(
            "(async () => {{ const a = document.querySelector('tr[data-job=\"{first}\"] a[data-download=\"{first}:{format}:0\"]'); \
             const r = await fetch(a.href); \
             return [r.status, r.headers.get('content-disposition'), Array.from(new Uint8Array(await r.arrayBuffer()))]; }})()"
        )
    };
    let png = b.eval(&fetched("png")).await;
    assert_eq!(png[0], 200, "{}", png[1]);
    assert_eq!(png[1], format!("attachment; filename=\"{first}-0000.png\""));
    let bytes: Vec<u8> = serde_json::from_value(png[2].clone()).unwrap();
    assert!(bytes == std::fs::read(&out).unwrap(), "the page's PNG is the one submit wrote");
    let exr = b.eval(&fetched("exr")).await;
    let bytes: Vec<u8> = serde_json::from_value(exr[2].clone()).unwrap();
    assert!(exr[0] == 200 && bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]), "{}", exr[1]);
    assert_eq!(
        b.eval(&format!(
            "document.querySelectorAll('#downloads a[data-download^=\"{first}:\"]').length"
        ))
        .await,
        2,
        "the frame's own links"
    );
    // Without the token nothing downloads.
    assert_eq!(get(&http, &format!("/api/jobs/{first}/result/png"), "").await.0, 401);

    // A long job, and a cancel from the page while it runs: long enough that
    // its last strips are still to come after the page has raised it (64 spp
    // took 4.7 s in all with Mesa 25's lavapipe, too quick for that).
    let bundle = sylva_scene::bundle::pack(&scene).unwrap();
    let mut s = spec(640, 480);
    s.frame.as_mut().unwrap().spp = 512;
    let long = c
        .submit_job(tokio_stream::iter(submission(
            s,
            &bundle.hash,
            &bundle.bytes,
            bundle.bytes.len() as u64,
        )))
        .await
        .unwrap()
        .into_inner()
        .id;
    b.wait_for(
        &format!("{} === 'running'", state_of(&long)),
        "the long job running",
        Duration::from_secs(60),
    )
    .await;
    b.eval(&format!("document.querySelector('tr[data-job=\"{long}\"]').click(), true")).await;
    // Its row says what the farm is doing for it.
    b.wait_for(
        &format!(
            "(document.querySelector('tr[data-job=\"{long}\"] .stage') || {{}}).textContent > ''"
        ),
        "the long job's stage",
        Duration::from_secs(60),
    )
    .await;
    // Its preview fills in strip by strip.
    b.wait_for(
        &format!("document.querySelector('tr[data-job=\"{long}\"] progress').value >= 2 && document.querySelectorAll('#columns rect').length >= 2"),
        "the long job's first strips",
        Duration::from_secs(180),
    )
    .await;
    tokio::time::sleep(Duration::from_millis(800)).await;
    // Raised from the page: the + button sends the token in its header.
    b.eval(&format!(
        "document.querySelector('button[data-priority=\"{long}\"][data-delta=\"1\"]').click(), true"
    ))
    .await;
    b.wait_for(
        &format!("(document.querySelector('tr[data-job=\"{long}\"] .priority') || {{}}).textContent === '1 '"),
        "the raised priority",
        Duration::from_secs(30),
    )
    .await;
    let listed = c.list_jobs(sylva_proto::pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    assert_eq!(listed.iter().find(|j| j.id == long).unwrap().priority, 1);
    // A change without the header (the cookie alone, as a form elsewhere would send it) is refused.
    let (status, _) = post(
        &http,
        &format!("/api/jobs/{long}/cancel"),
        &format!("Cookie: sylva_token={TOKEN}\r\nContent-Type: application/json\r\n"),
    )
    .await;
    assert_eq!(status, 401);
    // A form on another site can post only text/plain: refused with the
    // token too, and the job goes on.
    let (status, _) = post(
        &http,
        &format!("/api/jobs/{long}/cancel"),
        &format!("Authorization: Bearer {TOKEN}\r\nContent-Type: text/plain\r\n"),
    )
    .await;
    assert_eq!(status, 415);
    let listed = c.list_jobs(sylva_proto::pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    assert_ne!(
        listed.iter().find(|j| j.id == long).unwrap().state,
        sylva_proto::pb::JobState::Cancelled as i32
    );
    let shot = b
        .call("Page.captureScreenshot", json!({ "format": "png", "captureBeyondViewport": true }))
        .await;
    b.eval(&format!("document.querySelector('button[data-cancel=\"{long}\"]').click(), true"))
        .await;
    b.wait_for(
        &format!("{} === 'cancelled'", state_of(&long)),
        "the long job cancelled",
        Duration::from_secs(30),
    )
    .await;
    let listed = c.list_jobs(sylva_proto::pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    let j = listed.iter().find(|j| j.id == long).unwrap();
    assert_eq!(
        sylva_coordinator::job_state::wire_name(j.state),
        "cancelled",
        "the coordinator cancelled it, not just the page"
    );
    assert_eq!(
        b.eval("document.querySelector('#message').textContent").await,
        "",
        "no error shown"
    );
    // Requeued from the page: a new job with the same settings runs, and
    // the cancelled one stays as it ended.
    b.eval(&format!("document.querySelector('button[data-requeue=\"{long}\"]').click(), true"))
        .await;
    b.wait_for(
        &format!("[...document.querySelectorAll('#jobs tbody tr')].some(r => r.dataset.job !== '{first}' && r.dataset.job !== '{long}')"),
        "the requeued job",
        Duration::from_secs(30),
    )
    .await;
    let listed = c.list_jobs(sylva_proto::pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    let again = listed.iter().find(|j| j.id != first && j.id != long).unwrap();
    let old = listed.iter().find(|j| j.id == long).unwrap();
    assert!(!sylva_coordinator::job_state::wire_ended(again.state), "{again:?}");
    assert_eq!((&again.name, &again.submitter), (&old.name, &old.submitter));
    assert_eq!(old.state, sylva_proto::pb::JobState::Cancelled as i32);
    c.cancel_job(sylva_proto::pb::JobId { id: again.id.clone() }).await.unwrap();
    // At 1,280 px the page fits the window: no table pushes it wider.
    assert_eq!(b.eval("window.innerWidth").await, 1280);
    let widths = b
        .eval("[document.documentElement.scrollWidth, document.querySelector('#jobs').scrollWidth, document.querySelector('#jobs').parentElement.clientWidth]")
        .await;
    let w: Vec<u64> = serde_json::from_value(widths).unwrap();
    assert!(
        w[0] <= 1280 && w[1] <= w[2],
        "page {} px, jobs table {} px in {} px",
        w[0],
        w[1],
        w[2]
    );

    let png =
        base64::engine::general_purpose::STANDARD.decode(shot["data"].as_str().unwrap()).unwrap();
    let path = std::env::var_os("SYLVA_DASHBOARD_SCREENSHOT")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../sylva-out/dashboard.png")
        });
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(&path, png).unwrap();
}

/// One raw HTTP/1.1 request as written; the status of its answer.
async fn raw_status(addr: &str, request: &str) -> u16 {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(request.as_bytes()).await.unwrap();
    let mut out = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut out))
        .await
        .expect("an answer")
        .unwrap();
    let text = String::from_utf8_lossy(&out).to_string();
    text.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0)
}

/// Finding 6: with no token, any web page could change the farm (a
/// cross-site form post, or DNS rebinding reaching the page under the
/// attacker's own name). Now the page serves this machine only: it will
/// not listen elsewhere, answers only to loopback names, and refuses
/// another site's origin.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_token_the_page_serves_this_machine_only() {
    let refused = sylva(&["coordinator", "--listen", "127.0.0.1:0", "--http", "0.0.0.0:0"], &[]);
    assert!(!refused.status.success());
    let said = String::from_utf8_lossy(&refused.stderr);
    assert!(said.contains("without a token the dashboard serves this machine only"), "{said}");

    let http = format!("127.0.0.1:{}", free_port());
    let _coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--http", &http], &[]);
    let port = http.rsplit(':').next().unwrap();
    let cancel = |host: &str, extra: &str| {
        format!(
            "POST /api/jobs/nope/cancel HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: 0\r\n{extra}\r\n"
        )
    };
    // This machine's own page: the change reaches the farm (no such job).
    let mine = format!("Origin: http://{http}\r\n");
    assert_eq!(raw_status(&http, &cancel(&http, &mine)).await, 404);
    assert_eq!(raw_status(&http, &cancel(&format!("localhost:{port}"), "")).await, 404);
    // A page under another name (DNS rebinding): refused, reads too.
    assert_eq!(raw_status(&http, &cancel(&format!("evil.example:{port}"), "")).await, 421);
    let snapshot = format!(
        "GET /api/snapshot HTTP/1.1\r\nHost: evil.example:{port}\r\nConnection: close\r\n\r\n"
    );
    assert_eq!(raw_status(&http, &snapshot).await, 421);
    // Another site's page posting here under the right name: refused.
    let theirs = "Origin: http://evil.example\r\n";
    assert_eq!(raw_status(&http, &cancel(&http, theirs)).await, 403);
    // And a form's text/plain is no change at all.
    let form = format!(
        "POST /api/jobs/nope/cancel HTTP/1.1\r\nHost: {http}\r\nConnection: close\r\nContent-Type: text/plain\r\nContent-Length: 0\r\n\r\n"
    );
    assert_eq!(raw_status(&http, &form).await, 415);
    assert_eq!(get(&http, "/api/snapshot", "").await.0, 200, "the page itself is served");
}

/// A TCP connection to `addr` from the loopback address `from` (another
/// client, as far as the server can tell).
async fn connect_from(from: &str, addr: &str) -> tokio::net::TcpStream {
    let s = tokio::net::TcpSocket::new_v4().unwrap();
    s.bind(format!("{from}:0").parse().unwrap()).unwrap();
    s.connect(addr.parse().unwrap()).await.unwrap()
}

/// Finding 7: 300 half-sent request headers made each real request wait
/// 9–10 s, and 300 unread event streams made the page unavailable. Now one
/// client holds at most a few connections and event streams, and the page
/// stays served to everyone else.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_hoards_connections_does_not_starve_the_page() {
    let http = format!("127.0.0.1:{}", free_port());
    let _coord = spawn(
        &["coordinator", "--listen", "127.0.0.1:0", "--http", &http],
        &[("SYLVA_TOKEN", TOKEN)],
    );
    let auth = format!("Authorization: Bearer {TOKEN}\r\n");
    assert_eq!(get(&http, "/api/snapshot", &auth).await.0, 200);
    // Event streams opened with the token and never read: a few are
    // served, the rest refused at once.
    let mut streams = Vec::new();
    let mut refused = 0;
    for _ in 0..8 {
        let mut s = connect_from("127.0.0.3", &http).await;
        s.write_all(format!("GET /api/events HTTP/1.1\r\nHost: {http}\r\n{auth}\r\n").as_bytes())
            .await
            .unwrap();
        let mut head = [0u8; 12];
        s.read_exact(&mut head).await.unwrap();
        if &head[9..12] == b"429" {
            refused += 1;
        }
        streams.push(s);
    }
    assert_eq!(refused, 4, "four event streams per client");
    // Half-sent request headers from one client: it keeps a few
    // connections; the next are closed as soon as they are accepted.
    let mut hoard = Vec::new();
    for _ in 0..300 {
        let mut s = connect_from("127.0.0.2", &http).await;
        let _ = s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n").await;
        hoard.push(s);
    }
    // (the server closes them as it accepts them: a moment under load)
    tokio::time::sleep(Duration::from_millis(500)).await;
    let mut closed = 0;
    for s in hoard.iter_mut() {
        let mut b = [0u8; 1];
        // Closed: an end of stream, or a reset (closed with our half-sent
        // request unread).
        if let Ok(Ok(0) | Err(_)) =
            tokio::time::timeout(Duration::from_millis(100), s.read(&mut b)).await
        {
            closed += 1;
        }
    }
    assert!(closed >= 250, "connections over the client's share are closed: {closed} of 300");
    // Everyone else is served as before (well inside the header timeout
    // the hoarded connections would otherwise have made them wait).
    let answered = tokio::time::timeout(Duration::from_secs(5), async {
        (get(&http, "/", "").await.0, get(&http, "/api/snapshot", &auth).await.0)
    })
    .await;
    assert_eq!(answered.ok(), Some((200, 200)), "the page stays served");
    drop((streams, hoard));
}

/// Issue 37, finding 7: a job's live page and preview answer only those
/// who may watch jobs, as gRPC's `WatchJob` does: a worker's token is
/// refused, alike for an id that exists and one that does not, so it
/// cannot even tell which ids exist. A submitter's token is served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_workers_token_sees_no_job_on_the_dashboard() {
    let dir = scratch("dashboard-roles");
    let state = dir.join("state");
    let st = state.to_str().unwrap();
    let add = |user: &str, role: &str| {
        common::ok(&["token", "add", user, "--role", role, "--state-dir", st]).trim().to_string()
    };
    let http = format!("127.0.0.1:{}", free_port());
    let coord =
        spawn(&["coordinator", "--listen", "127.0.0.1:0", "--http", &http, "--state-dir", st], &[]);
    let (alice, wtok) = (add("alice", "submitter"), add("render-01", "worker"));
    // The coordinator reads new tokens within a few seconds: until then
    // the farm is open to anyone.
    let mut anon = coordinator(&coord.addr, None).await;
    for _ in 0..100 {
        if anon.list_jobs(sylva_proto::pb::ListJobsRequest {}).await.is_err() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mut c = coordinator(&coord.addr, Some(&alice)).await;
    let b = sylva_scene::bundle::pack(&small_scene(&dir.join("scene"))).unwrap();
    let chunks = submission(spec(16, 8), &b.hash, &b.bytes, b.bytes.len() as u64);
    let id = c.submit_job(tokio_stream::iter(chunks)).await.unwrap().into_inner().id;
    let as_worker = format!("Authorization: Bearer {wtok}\r\n");
    let as_alice = format!("Authorization: Bearer {alice}\r\n");
    for path in ["live", "preview.png"] {
        let real = get(&http, &format!("/api/jobs/{id}/{path}"), &as_worker).await;
        let none = get(&http, &format!("/api/jobs/job-none-1/{path}"), &as_worker).await;
        assert_eq!((real.0, none.0), (403, 403), "{path}: {real:?} {none:?}");
        assert_eq!(real.1, none.1);
    }
    assert_eq!(get(&http, &format!("/api/jobs/{id}/live"), &as_alice).await.0, 200);
    let _ = std::fs::remove_dir_all(&dir);
}
