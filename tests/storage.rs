//! The coordinator's store when its disk fills, as an operator meets it:
//! its state folder on a real 20 MiB tmpfs (mounted by the test as root,
//! or in a private mount namespace, so no root is needed), filled to a few KiB free while jobs
//! are submitted, then emptied. Every job the coordinator acknowledged is
//! in the database as its client last heard of it, read by another
//! process; no id is handed out twice; the coordinator says while its
//! store refuses writes and recovers when space returns. Real worker and
//! coordinator processes, real gRPC, a real SQLite file on a full disk.

use crate::common;

use common::{Proc, coordinator, small_scene, spawn, spec, submission};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;
use sylva_proto::pb;

/// A tmpfs mounted by this (root) process, unmounted when dropped.
struct Tmpfs(PathBuf);

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// A coordinator whose state folder is a `size`-byte tmpfs: mounted here
/// when this process is root (a chroot allows neither a user namespace
/// nor a private copy of its root's mounts), else in a mount namespace of
/// the coordinator's own, unprivileged. The folder, as this process sees
/// it, is `/proc/PID/cwd`.
fn coordinator_on_tmpfs(mount: &Path, size: &str, workers: &str) -> (Proc, PathBuf, Option<Tmpfs>) {
    let run =
        r#"cd "$0" && exec "$2" coordinator --listen 127.0.0.1:0 --workers "$3" --state-dir ."#;
    // SAFETY: geteuid has no preconditions.
    let root = unsafe { libc::geteuid() } == 0;
    let mut tmpfs = None;
    let mut cmd = if root {
        let ok = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(mount)
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "mount (util-linux) mounts a tmpfs for the test");
        tmpfs = Some(Tmpfs(mount.to_path_buf()));
        let mut c = Command::new("sh");
        c.args(["-c", run]);
        c
    } else {
        let script = format!(r#"mount -t tmpfs -o "size=$1" tmpfs "$0" && {run}"#);
        let mut c = Command::new("unshare");
        c.args(["--user", "--map-root-user", "--mount", "sh", "-c", &script]);
        c
    };
    let mut child = cmd
        .arg(mount)
        .arg(size)
        .arg(env!("CARGO_BIN_EXE_sylva"))
        .arg(workers)
        .env("XDG_RUNTIME_DIR", common::runtime())
        .env("RUST_LOG", "sylva_coordinator=info")
        .env_remove("SYLVA_TOKEN")
        .env_remove("SYLVA_DATABASE_URL")
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(mount.with_extension("log")).unwrap())
        .spawn()
        .expect("the coordinator starts (through unshare, util-linux, unless root)");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    assert!(
        line.contains(" listening on "),
        "the coordinator did not start on a tmpfs: {line:?}\n{}",
        std::fs::read_to_string(mount.with_extension("log")).unwrap_or_default()
    );
    let folder = PathBuf::from(format!("/proc/{}/cwd", child.id()));
    (Proc { addr: line.trim().rsplit(' ').next().unwrap().to_string(), child }, folder, tmpfs)
}

/// KiB free on the file system holding `dir`.
fn free_kib(dir: &Path) -> u64 {
    let c = std::ffi::CString::new(dir.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid C string and a zeroed statvfs for it to fill.
    let mut s: libc::statvfs = unsafe { std::mem::zeroed() };
    assert_eq!(unsafe { libc::statvfs(c.as_ptr(), &mut s) }, 0);
    s.f_bavail as u64 * s.f_frsize as u64 / 1024
}

/// Fills `dir`'s file system with `dir/filler` until `kib` KiB are free.
fn fill_to(dir: &Path, kib: u64) {
    let mut f =
        std::fs::OpenOptions::new().create(true).append(true).open(dir.join("filler")).unwrap();
    let block = vec![0u8; 4096];
    while free_kib(dir) > kib {
        if f.write_all(&block).and_then(|_| f.sync_data()).is_err() {
            break;
        }
    }
}

/// How a submission ended, as its client saw it.
#[derive(Clone, Debug)]
enum Outcome {
    /// Refused before it was acknowledged (no id).
    Refused(tonic::Code, String),
    /// Acknowledged with an id, and ended in this wire state.
    Ended(String, i32, String),
}

async fn submit(c: &mut common::Client, b: &sylva_scene::bundle::SceneBundle) -> Outcome {
    let id = match c
        .submit_job(tokio_stream::iter(submission(
            spec(320, 160),
            &b.hash,
            &b.bytes,
            b.bytes.len() as u64,
        )))
        .await
    {
        Ok(r) => r.into_inner().id,
        Err(s) => return Outcome::Refused(s.code(), s.message().to_string()),
    };
    let mut events = c.watch_job(pb::JobId { id: id.clone() }).await.unwrap().into_inner();
    while let Some(ev) = tokio_stream::StreamExt::next(&mut events).await {
        let ev = ev.unwrap();
        if sylva_coordinator::job_state::wire_ended(ev.state) {
            return Outcome::Ended(id, ev.state, ev.message);
        }
    }
    panic!("job {id}'s events ended early");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_disk_full_episode_loses_no_acknowledged_job_and_reuses_no_id() {
    let dir = common::scratch("disk-full");
    let mount = dir.join("state");
    std::fs::create_dir_all(&mount).unwrap();
    let b = sylva_scene::bundle::pack(&small_scene(&dir.join("scene"))).unwrap();
    let worker = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let (coord, state, tmpfs) = coordinator_on_tmpfs(&mount, "20m", &worker.addr);
    let mut c = coordinator(&coord.addr, None).await;
    let mut outcomes = vec![submit(&mut c, &b).await];
    // The free-space steps that lost jobs before: a few KiB, where some
    // writes land and some do not.
    // Whether the store said it refused writes, as `sylva jobs` reads it
    // after each submission (it may recover within the episode: a write
    // that fits in the WAL's pages already taken goes through).
    let mut sick = Vec::new();
    for kib in [20, 28, 0] {
        let _ = std::fs::remove_file(state.join("filler"));
        fill_to(&state, kib);
        for _ in 0..2 {
            outcomes.push(submit(&mut c, &b).await);
            let list = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner();
            sick.push(list.store_problem);
        }
    }
    let refused_for_it = outcomes
        .iter()
        .any(|o| matches!(o, Outcome::Refused(_, m) if m.contains("refused writes")));
    assert!(
        sick.iter().any(|s| s.contains("refused writes")) || refused_for_it,
        "a store that refuses writes is reported (ListJobs.store_problem): {outcomes:?}"
    );
    // Space returns: the store recovers by itself, and takes jobs again.
    std::fs::remove_file(state.join("filler")).unwrap();
    let mut recovered = false;
    for _ in 0..100 {
        let list = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner();
        if list.store_problem.is_empty() {
            recovered = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(recovered, "the store is healthy again once space returns");
    for _ in 0..2 {
        let o = submit(&mut c, &b).await;
        assert!(
            matches!(&o, Outcome::Ended(_, s, _) if *s == pb::JobState::Done as i32),
            "with space again a job renders and is stored: {o:?}"
        );
        outcomes.push(o);
    }
    // Refusals while the disk was full say so, as a state a client may
    // retry (UNAVAILABLE), never as its own error.
    for o in &outcomes {
        if let Outcome::Refused(code, msg) = o {
            assert_eq!(*code, tonic::Code::Unavailable, "{msg}");
        }
    }
    // Ids are never handed out twice: a fresh id is above every one given.
    let next = submit(&mut c, &b).await;
    let Outcome::Ended(last, ..) = &next else { panic!("{next:?}") };
    outcomes.push(next.clone());
    // The coordinator killed as a crash does; its tmpfs kept alive by an
    // open handle on the folder. What is in the database now is what a
    // restart reads: every acknowledged job, in the state its client last
    // heard. (Copied out first: SQLite resolves /proc's links by name.)
    let held = std::fs::File::open(&state).unwrap();
    let held_path =
        PathBuf::from(format!("/proc/self/fd/{}", std::os::fd::AsRawFd::as_raw_fd(&held)));
    // Give owed writes their second to land, then crash it.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    // SAFETY: signals our own child.
    unsafe { libc::kill(coord.child.id() as i32, libc::SIGKILL) };
    drop(coord);
    let copy = dir.join("copy");
    std::fs::create_dir_all(&copy).unwrap();
    for f in ["sylva.db", "sylva.db-wal"] {
        if held_path.join(f).exists() {
            std::fs::copy(held_path.join(f), copy.join(f)).unwrap();
        }
    }
    let url = format!("sqlite://{}", copy.join("sylva.db").display());
    let store = sylva_coordinator::store::Store::open(&url).await.unwrap();
    let rows = store.jobs().await.unwrap();
    let fresh = store.next_seq().await.unwrap();
    store.close().await;
    for o in &outcomes {
        if let Outcome::Ended(id, s, msg) = o {
            let row = rows.iter().find(|r| &r.id == id);
            assert!(
                row.is_some(),
                "acknowledged job {id} ({msg}) is not in the database: {rows:?}"
            );
            assert_eq!(
                row.unwrap().state.map(|s| s.to_wire()),
                Some(*s),
                "job {id} is in the database as its client last heard ({msg})"
            );
        }
    }
    let last: u64 = last.rsplit('-').next().unwrap().parse().unwrap();
    assert!(rows.iter().all(|r| r.seq <= last) && fresh > last, "ids {last}, then {fresh}");
    drop(tmpfs);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Results carry their hash in the database and are checked when served
/// (issue 37, finding 11): a stored PNG or EXR changed on disk is refused
/// as damaged, one removed as missing, each with DATA_LOSS and the cause;
/// neither is served, and the untouched ones still are.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_result_changed_or_removed_on_disk_is_not_served() {
    let dir = common::scratch("result-hash");
    let state = dir.join("state");
    let b = sylva_scene::bundle::pack(&small_scene(&dir.join("scene"))).unwrap();
    let worker = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let coord = spawn(
        &[
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--workers",
            &worker.addr,
            "--state-dir",
            state.to_str().unwrap(),
        ],
        &[],
    );
    let mut c = coordinator(&coord.addr, None).await;
    let Outcome::Ended(id, s, msg) = submit(&mut c, &b).await else { panic!("refused") };
    assert_eq!(s, pb::JobState::Done as i32, "{msg}");
    let fetch = async |c: &mut common::Client, format: &str| {
        c.fetch_result(pb::FetchRequest { id: id.clone(), format: format.into(), frame: 0 }).await
    };
    let png = fetch(&mut c, "png").await.unwrap().into_inner().data;
    assert!(fetch(&mut c, "exr").await.is_ok());
    let files = state.join("results").join(&id);
    // One byte of the PNG changed: refused as damaged, never served.
    let mut changed = png.clone();
    let k = changed.len() / 2;
    changed[k] ^= 1;
    std::fs::write(files.join("00000.png"), &changed).unwrap();
    let e = fetch(&mut c, "png").await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::DataLoss, "{e:?}");
    assert!(e.message().contains("no longer matches what was written"), "{}", e.message());
    // The EXR removed: refused as missing, not as "no longer kept".
    std::fs::remove_file(files.join("00000.exr")).unwrap();
    let e = fetch(&mut c, "exr").await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::DataLoss, "{e:?}");
    assert!(e.message().contains("missing"), "{}", e.message());
    // Put back as written, it is served again.
    std::fs::write(files.join("00000.png"), &png).unwrap();
    assert_eq!(fetch(&mut c, "png").await.unwrap().into_inner().data, png);
    let _ = std::fs::remove_dir_all(&dir);
}
