//! The durable queue as an operator meets it: a coordinator `kill -9`'d in
//! the middle of a 24-frame sequence, started again on the same state
//! folder, finishes the job from the frames it had stored, every frame
//! byte for byte the uninterrupted run's; finished results outlive another
//! kill; ids are never handed out twice. Real worker and coordinator
//! processes, real gRPC, a real SQLite file.

use crate::common;

use common::{Proc, coordinator, ok, scratch, small_scene, spawn, spawn_logging};
use std::path::Path;
use std::time::Duration;
use sylva_proto::pb;

/// Kills a process as a crash or the OOM killer does: no clean-up at all.
fn kill_9(p: Proc) {
    // SAFETY: signals our own child.
    unsafe { libc::kill(p.child.id() as i32, libc::SIGKILL) };
    drop(p);
}

/// The database these tests run on: SQLite in the state folder, or the
/// server `scripts/postgres-check.sh` names.
fn database() -> Option<String> {
    std::env::var("SYLVA_TEST_DATABASE_URL").ok().filter(|u| !u.is_empty())
}

fn durable_coordinator(workers: &str, state: &Path, log: &Path) -> Proc {
    let mut args = vec![
        "coordinator",
        "--listen",
        "127.0.0.1:0",
        "--workers",
        workers,
        "--state-dir",
        state.to_str().unwrap(),
    ];
    let url = database();
    if let Some(u) = &url {
        args.extend(["--database", u.as_str()]);
    }
    spawn_logging(&args, &[("RUST_LOG", "sylva_coordinator=info")], Some(log))
}

/// `sylva ARGS` started and left running (a client whose coordinator
/// will be killed under it), what it says going to `said`.
fn in_background(args: &[String], said: &Path) -> std::process::Child {
    std::process::Command::new(env!("CARGO_BIN_EXE_sylva"))
        .args(args)
        .env("XDG_RUNTIME_DIR", common::runtime())
        .env("SYLVA_PREPARED_CACHE_MIB", "0")
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(said).unwrap())
        .spawn()
        .unwrap()
}

fn bytes(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_coordinator_killed_mid_sequence_resumes_it_and_every_frame_is_the_same() {
    let dir = scratch("durable");
    let scene = small_scene(&dir);
    let (w1, w2) = (
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
    );
    let workers = format!("{},{}", w1.addr, w2.addr);
    // A sun sweep: each frame solves its own LB, so the sequence takes long
    // enough to be stopped in the middle.
    let flags = [
        "--width",
        "48",
        "--height",
        "32",
        "--lighting",
        "lb",
        "--frames",
        "24",
        "--sun-from",
        "60,100",
        "--sun-to",
        "20,220",
        "--exr",
    ];
    let submit = |addr: &str, out: &Path| {
        let mut a = vec![
            "submit".to_string(),
            scene.display().to_string(),
            "--coordinator".into(),
            addr.into(),
            "-o".into(),
            out.display().to_string(),
        ];
        a.extend(flags.iter().map(|s| s.to_string()));
        a
    };

    // The uninterrupted run.
    let clean = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &workers], &[]);
    let args = submit(&clean.addr, &dir.join("clean/shot.png"));
    ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    drop(clean);

    // The same job on a durable coordinator, killed once frames are stored.
    let state = dir.join("state");
    let c1 = durable_coordinator(&workers, &state, &dir.join("c1.log"));
    let mut client =
        in_background(&submit(&c1.addr, &dir.join("lost/shot.png")), &dir.join("client.log"));
    let mut c = coordinator(&c1.addr, None).await;
    let (id, at_kill) = loop {
        let jobs = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
        if let Some(j) = jobs.first().filter(|j| j.frames_done >= 4) {
            break (j.id.clone(), j.frames_done);
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    kill_9(c1);
    let _ = client.wait();
    assert!(
        at_kill < 24,
        "the sequence ended before the kill ({at_kill} frames): nothing to resume"
    );

    // Started again on the same folder, it finishes the job from there.
    let log2 = dir.join("c2.log");
    let c2 = durable_coordinator(&workers, &state, &log2);
    // A second coordinator on the same queue would run its jobs twice: it
    // is refused (the state folder's lock; on PostgreSQL, the database's).
    let other = if database().is_some() { dir.join("other-state") } else { state.clone() };
    let mut second =
        vec!["coordinator", "--listen", "127.0.0.1:0", "--state-dir", other.to_str().unwrap()];
    let url = database();
    if let Some(u) = &url {
        second.extend(["--database", u.as_str()]);
    }
    let refused = common::sylva(&second, &[]);
    let said = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && said.contains("another"), "{said}");
    let mut c = coordinator(&c2.addr, None).await;
    let mut events = c.watch_job(pb::JobId { id: id.clone() }).await.unwrap().into_inner();
    let mut last = None;
    while let Some(ev) = tokio_stream::StreamExt::next(&mut events).await {
        let ev = ev.unwrap();
        let end = sylva_coordinator::job_state::wire_ended(ev.state);
        last = Some(ev);
        if end {
            break;
        }
    }
    let last = last.unwrap();
    assert_eq!(sylva_coordinator::job_state::wire_name(last.state), "done", "{last:?}");
    let log = std::fs::read_to_string(&log2).unwrap();
    let resumed = log.lines().find(|l| l.contains("resuming from what an earlier run stored"));
    let kept: u32 = resumed
        .and_then(|l| l.split("frames=").nth(1))
        .and_then(|s| s.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("the restart says what it resumed from:\n{log}"));
    assert!(kept >= at_kill, "frames stored before the kill are kept: {kept} < {at_kill}");
    let out = dir.join("resumed/shot.png");
    ok(&["fetch", &id, "--coordinator", &c2.addr, "--all", "-o", out.to_str().unwrap()]);
    for i in 0..24 {
        let clean = |ext| bytes(&dir.join(format!("clean/shot-{i:04}.{ext}")));
        let png = bytes(&dir.join(format!("resumed/shot-{i:04}.png")));
        assert!(png == clean("png"), "frame {i}'s PNG differs from the uninterrupted run's");
        let exr = c
            .fetch_result(pb::FetchRequest { id: id.clone(), format: "exr".into(), frame: i })
            .await
            .unwrap()
            .into_inner()
            .data;
        assert!(exr == clean("exr"), "frame {i}'s EXR differs from the uninterrupted run's");
    }

    // Killed again, the finished job is still served, and a new job gets
    // an id never handed out before.
    kill_9(c2);
    let c3 = durable_coordinator(&workers, &state, &dir.join("c3.log"));
    let again = dir.join("again.png");
    ok(&["fetch", &id, "--coordinator", &c3.addr, "--frame", "5", "-o", again.to_str().unwrap()]);
    assert!(bytes(&again) == bytes(&dir.join("clean/shot-0005.png")));
    let one = dir.join("one.png");
    let said = ok(&[
        "submit",
        scene.to_str().unwrap(),
        "--coordinator",
        &c3.addr,
        "-o",
        one.to_str().unwrap(),
        "--width",
        "32",
        "--height",
        "16",
    ]);
    let seq = |id: &str| id.rsplit('-').next().unwrap().parse::<u64>().unwrap();
    let new_id = said.split_whitespace().next().unwrap();
    assert!(seq(new_id) > seq(&id) && new_id.starts_with(id.rsplit_once('-').unwrap().0));
    let log3 = std::fs::read_to_string(dir.join("c3.log")).unwrap();
    let kind = if database().is_some() { "PostgreSQL" } else { "SQLite" };
    assert!(log3.contains(&format!("database=\"{kind}\"")), "{log3}");
    c3.terminate();
    assert!(state.join("results").exists(), "a durable coordinator keeps its state at exit");
    assert_eq!(state.join("sylva.db").exists(), database().is_none());
    drop((w1, w2));
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frame_cut_into_strips_keeps_the_strips_done_before_a_kill() {
    let dir = scratch("durable-strips");
    let scene = small_scene(&dir);
    let (w1, w2) = (
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
    );
    let workers = format!("{},{}", w1.addr, w2.addr);
    let submit = |addr: &str, out: &Path| {
        [
            "submit",
            scene.to_str().unwrap(),
            "--coordinator",
            addr,
            "-o",
            out.to_str().unwrap(),
            "--width",
            "384",
            "--height",
            "96",
            // Long enough a frame that strips are still to come a moment
            // after the second is counted (8 and 64 spp could end within
            // that moment once replies stopped waiting on delayed acks).
            "--spp",
            "512",
            "--schedule",
            "dynamic",
        ]
        .map(String::from)
    };
    let clean = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &workers], &[]);
    ok(&submit(&clean.addr, &dir.join("clean.png")).each_ref().map(String::as_str));
    drop(clean);

    let state = dir.join("state");
    let c1 = durable_coordinator(&workers, &state, &dir.join("c1.log"));
    let client_log = dir.join("client.log");
    let mut client = in_background(&submit(&c1.addr, &dir.join("lost.png")), &client_log);
    let mut c = coordinator(&c1.addr, None).await;
    let (id, planned) = loop {
        let jobs = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
        if let Some(j) = jobs.first().filter(|j| j.strips_done >= 2) {
            assert_eq!(j.frames_done, 0, "the frame ended before the kill: nothing to resume");
            break (j.id.clone(), j.strips_total);
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    };
    // A strip is recorded a moment after it is counted.
    tokio::time::sleep(Duration::from_millis(100)).await;
    kill_9(c1);
    let _ = client.wait();
    // The client says what happened in a user's words (issue 37, finding
    // 11: it printed the transport's "h2 protocol error").
    let said = std::fs::read_to_string(&client_log).unwrap();
    assert!(
        said.contains("connection to the coordinator was lost")
            && said.contains(&format!("sylva fetch {id}"))
            && !said.contains("h2 protocol"),
        "{said}"
    );

    let log2 = dir.join("c2.log");
    let c2 = durable_coordinator(&workers, &state, &log2);
    let mut c = coordinator(&c2.addr, None).await;
    let mut events = c.watch_job(pb::JobId { id: id.clone() }).await.unwrap().into_inner();
    while let Some(ev) = tokio_stream::StreamExt::next(&mut events).await {
        if sylva_coordinator::job_state::wire_ended(ev.unwrap().state) {
            break;
        }
    }
    let log = std::fs::read_to_string(&log2).unwrap();
    let kept: u32 = log
        .lines()
        .find(|l| l.contains("resuming from what an earlier run stored"))
        .and_then(|l| l.split("strips=").nth(1))
        .and_then(|s| s.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("the restart says what it resumed from:\n{log}"));
    assert!(kept >= 1, "strips rendered before the kill are kept:\n{log}");
    // Its progress counts the strips the first run rendered (issue 37,
    // finding 11: it listed only the rest, "3/3" of a frame of 6).
    let jobs = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    let j = jobs.iter().find(|j| j.id == id).unwrap();
    assert!(
        j.strips_done == j.strips_total && j.strips_total >= planned,
        "{}/{} strips with {kept} kept, of {planned} planned",
        j.strips_done,
        j.strips_total
    );
    // Once the frame is whole, the strips kept for it are gone.
    let strips = state.join("results").join(&id).join("strips");
    let left = std::fs::read_dir(&strips).map(|d| d.count()).unwrap_or(0);
    assert_eq!(left, 0, "strip files left in {}", strips.display());
    let out = dir.join("resumed.png");
    ok(&["fetch", &id, "--coordinator", &c2.addr, "-o", out.to_str().unwrap()]);
    assert!(
        bytes(&out) == bytes(&dir.join("clean.png")),
        "the frame differs from the uninterrupted run's"
    );
    drop((c2, w1, w2));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 37, findings 4 and 5: a coordinator never starts a second farm
/// over a database or a state folder that is another's. A second
/// coordinator naming a running one's SQLite file (from its own state
/// folder) is refused; a farm whose `sylva.db` was truncated to 0 bytes,
/// or removed while its results stay, is refused with the cause rather
/// than started afresh (jobs forgotten, results orphaned, users gone),
/// and nothing is written over the evidence.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_coordinator_refuses_a_database_that_is_not_its_farms() {
    if database().is_some() {
        return; // SQLite files and folders: the PostgreSQL run has its own lock test.
    }
    let dir = scratch("not-its-farm");
    let b = sylva_scene::bundle::pack(&small_scene(&dir.join("scene"))).unwrap();
    let (a, other) = (dir.join("a"), dir.join("b"));
    let w = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let log = dir.join("a.log");
    let first = durable_coordinator(&w.addr, &a, &log);
    let mut c = coordinator(&first.addr, None).await;
    let done = common::submit_and_wait(&mut c, common::spec(32, 16), &b, |_| {}).await;
    assert_eq!(done.state, pb::JobState::Done as i32, "{}", done.message);
    // A second coordinator on the first's database, from its own folder.
    let url = format!("sqlite://{}", a.join("sylva.db").display());
    let start = |state: &Path, url: Option<&str>| {
        let mut args = vec!["coordinator", "--listen", "127.0.0.1:0", "--workers", &w.addr];
        args.extend(["--state-dir", state.to_str().unwrap()]);
        if let Some(u) = url {
            args.extend(["--database", u]);
        }
        common::sylva(&args, &[])
    };
    let o = start(&other, Some(&url));
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && said.contains("another coordinator is using the database"),
        "{said}"
    );
    first.terminate();
    // The farm's database truncated: refused, and left as it was.
    let db = a.join("sylva.db");
    for f in ["sylva.db-wal", "sylva.db-shm"] {
        let _ = std::fs::remove_file(a.join(f));
    }
    std::fs::write(&db, b"").unwrap();
    let o = start(&a, None);
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && said.contains("empty file (0 bytes)"), "{said}");
    assert_eq!(std::fs::metadata(&db).unwrap().len(), 0, "nothing is written over the evidence");
    // Removed outright, with the farm's results still there: refused too.
    std::fs::remove_file(&db).unwrap();
    let o = start(&a, None);
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && said.contains("holds an earlier farm's"), "{said}");
    let _ = std::fs::remove_dir_all(&dir);
}
