//! Users with their own tokens and roles, as an operator sets them up:
//! `sylva token add` on the coordinator's state folder, a worker joining
//! with a worker token, submitters acting on their own jobs only, an
//! admin on any, revocation, and the audit log. Real processes, real gRPC,
//! a real SQLite file.

use crate::common;

use common::{Client, coordinator, ok, scratch, small_scene, spawn, spec, sylva};
use std::time::Duration;
use sylva_proto::pb;
use sylva_scene::bundle;
use tonic::Code;

fn token_add(state: &str, user: &str, role: &str) -> String {
    ok(&["token", "add", user, "--role", role, "--state-dir", state]).trim().to_string()
}

/// Waits until `c` is refused (the coordinator re-reads tokens every 2 s).
async fn until_refused(c: &mut Client) {
    for _ in 0..100 {
        if c.list_jobs(pb::ListJobsRequest {}).await.is_err() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("the coordinator still takes the token");
}

async fn submit(
    c: &mut Client,
    b: &bundle::SceneBundle,
    claimed: &str,
) -> Result<String, tonic::Status> {
    let mut s = spec(32, 16);
    s.submitter = claimed.into();
    let chunks = common::submission(s, &b.hash, &b.bytes, b.bytes.len() as u64);
    c.submit_job(tokio_stream::iter(chunks)).await.map(|r| r.into_inner().id)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn users_act_within_their_roles_and_every_change_is_audited() {
    let dir = scratch("users");
    let state = dir.join("state");
    let st = state.to_str().unwrap();
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--state-dir", st], &[]);
    let (alice, bob) = (token_add(st, "alice", "submitter"), token_add(st, "bob", "submitter"));
    let (root, wtok) = (token_add(st, "root", "admin"), token_add(st, "render-01", "worker"));
    assert!(alice.starts_with("sylva_") && alice.len() == "sylva_".len() + 12 + 1 + 64);
    // One user, one role (issue 37, finding 8): ownership is by name, so a
    // second token under alice's name as an admin would act on her jobs.
    let said = common::fails(&["token", "add", "alice", "--role", "admin", "--state-dir", st]);
    assert!(said.contains("already has a submitter token"), "{said}");
    // A second token of the same role is made, but the operator is told
    // the first still works (issue 41, point 7).
    let again =
        common::sylva(&["token", "add", "bob", "--role", "submitter", "--state-dir", st], &[]);
    let said = String::from_utf8_lossy(&again.stderr);
    assert!(again.status.success(), "{said}");
    assert!(said.contains("bob also holds 1 live token") && said.contains("still works"), "{said}");
    let bob2 = String::from_utf8_lossy(&again.stdout).trim().to_string();
    assert!(bob2.starts_with("sylva_") && bob2 != bob);
    // The farm was open; with users it takes their tokens only.
    let mut anon = coordinator(&coord.addr, None).await;
    until_refused(&mut anon).await;
    let (mut a, mut b, mut r) = (
        coordinator(&coord.addr, Some(&alice)).await,
        coordinator(&coord.addr, Some(&bob)).await,
        coordinator(&coord.addr, Some(&root)).await,
    );
    let mut w = coordinator(&coord.addr, Some(&wtok)).await;

    // A worker joins with its worker token (and proves it holds it).
    let worker = spawn(
        &["worker", "--listen", "127.0.0.1:0", "--coordinator", &coord.addr],
        &[("SYLVA_TOKEN", &wtok)],
    );
    common::wait_for_workers(&mut r, 1).await;
    // A worker started with a submitter's token can never register: it
    // stops and says why, rather than retry for ever (issue 41, point 7).
    let log = dir.join("bad-worker.log");
    let mut bad = common::spawn_logging(
        &["worker", "--listen", "127.0.0.1:0", "--coordinator", &coord.addr],
        &[("SYLVA_TOKEN", &alice)],
        Some(&log),
    );
    let mut ended = None;
    for _ in 0..300 {
        ended = bad.child.try_wait().unwrap();
        if ended.is_some() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let said = std::fs::read_to_string(&log).unwrap();
    assert!(ended.is_some_and(|s| !s.success()), "it exits, failing: {said}");
    assert!(said.contains("start the worker with a worker token"), "{said}");

    // The submitter shown is the token's user, whatever the client claims.
    let scene = bundle::pack(&small_scene(&dir)).unwrap();
    let id = submit(&mut a, &scene, "mallory").await.unwrap();
    let listed = r.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    assert_eq!(listed.iter().find(|j| j.id == id).unwrap().submitter, "alice");

    // Bob may not touch Alice's job; Alice may; an admin may.
    let denied = b.cancel_job(pb::JobId { id: id.clone() }).await.unwrap_err();
    assert_eq!(denied.code(), Code::PermissionDenied, "{denied:?}");
    assert!(denied.message().contains("alice's"), "{}", denied.message());
    let e = b.set_priority(pb::SetPriorityRequest { id: id.clone(), priority: 9 }).await;
    assert_eq!(e.unwrap_err().code(), Code::PermissionDenied);
    let mine = a.set_priority(pb::SetPriorityRequest { id: id.clone(), priority: 3 }).await;
    assert!(mine.is_ok() || mine.unwrap_err().code() == Code::FailedPrecondition, "ended is fine");
    assert!(r.cancel_job(pb::JobId { id: id.clone() }).await.is_ok());

    // Only the coordinator it registered with may push prepared data into
    // the worker: not its own token's other holders, not an admin.
    for t in [&wtok, &root] {
        let mut direct = sylva_coordinator::farm::connect(&worker.addr, Some(t.to_string()), None)
            .await
            .unwrap();
        let chunk = pb::PreparedChunk { scene_hash: scene.hash.clone(), ..Default::default() };
        let e = direct.import_prepared(tokio_stream::iter(vec![chunk])).await.unwrap_err();
        assert!(matches!(e.code(), Code::PermissionDenied | Code::Unauthenticated), "{e:?}");
    }

    // A worker token reaches the worker-facing call only; a submitter's
    // cannot register workers.
    let refused = submit(&mut w, &scene, "").await.unwrap_err();
    assert_eq!(refused.code(), Code::PermissionDenied);
    // The refusal names the role that may, and how to get a token of it.
    assert!(
        refused.message().starts_with("a worker token cannot")
            && refused.message().contains("that takes a token of the role")
            && refused.message().contains("sylva token add"),
        "{}",
        refused.message()
    );
    let e = w.list_jobs(pb::ListJobsRequest {}).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied);
    let e = a
        .register_worker(pb::RegisterWorkerRequest {
            addr: "127.0.0.1:1".into(),
            ..Default::default()
        })
        .await;
    assert_eq!(e.unwrap_err().code(), Code::PermissionDenied);

    // Revoked, Bob's token stops working.
    let list = ok(&["token", "list", "--json", "--state-dir", st]);
    let tokens: serde_json::Value = serde_json::from_str(&list).unwrap();
    assert!(!list.contains(&bob[19..]), "a listing never shows a token");
    let bob_id = tokens.as_array().unwrap().iter().find(|t| t["user"] == "bob").unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    // Bob follows a long job of his as his token is revoked: the stream
    // ends (issue 37, finding 11: it kept delivering for 8 s and more).
    let mut long = spec(320, 160);
    long.frame.as_mut().unwrap().spp = 4096;
    let chunks = common::submission(long, &scene.hash, &scene.bytes, scene.bytes.len() as u64);
    let bobs = b.submit_job(tokio_stream::iter(chunks)).await.unwrap().into_inner().id;
    let mut events = b.watch_job(pb::JobId { id: bobs.clone() }).await.unwrap().into_inner();
    tokio_stream::StreamExt::next(&mut events).await.unwrap().unwrap();
    ok(&["token", "revoke", &bob_id, "--state-dir", st]);
    let revoked = std::time::Instant::now();
    let ended = loop {
        match tokio::time::timeout(
            Duration::from_secs(10),
            tokio_stream::StreamExt::next(&mut events),
        )
        .await
        {
            Ok(Some(Ok(ev))) => assert!(
                !sylva_coordinator::job_state::wire_ended(ev.state),
                "the job ended first: make it longer"
            ),
            Ok(Some(Err(s))) => break s,
            Ok(None) => panic!("the stream ended without saying why"),
            Err(_) => panic!("the stream still runs 10 s after its token was revoked"),
        }
    };
    assert_eq!(ended.code(), Code::Unauthenticated, "{ended:?}");
    assert!(revoked.elapsed() < Duration::from_secs(5), "{:?}", revoked.elapsed());
    assert!(r.cancel_job(pb::JobId { id: bobs }).await.is_ok());
    until_refused(&mut b).await;
    assert!(!sylva(&["token", "revoke", &bob_id, "--state-dir", st], &[]).status.success());

    // Every change is in the audit log, with who made it.
    let log: serde_json::Value =
        serde_json::from_str(&ok(&["audit", "--json", "--state-dir", st])).unwrap();
    let seen: Vec<(String, String)> = log
        .as_array()
        .unwrap()
        .iter()
        .map(|e| (e["actor"].as_str().unwrap().into(), e["action"].as_str().unwrap().into()))
        .collect();
    for (who, what) in [
        ("operator", "token add"),
        ("render-01", "register worker"),
        ("alice", "submit"),
        ("root", "cancel"),
        ("operator", "token revoke"),
        // Refusals are audited too (issue 41, point 7).
        ("render-01", "refused: submit jobs"),
    ] {
        assert!(seen.contains(&(who.into(), what.into())), "{who} {what} in {seen:?}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A job sent with the farm's own token is listed and audited under the
/// same name: its holder `admin`, and the name and address it came with
/// (issue 41, point 7: the list said an address, the audit `admin`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_farm_token_job_is_listed_and_audited_under_one_name() {
    let dir = scratch("farm-token-audit");
    let state = dir.join("state");
    let st = state.to_str().unwrap();
    let w = spawn(&["worker", "--listen", "127.0.0.1:0"], &[("SYLVA_TOKEN", "farm")]);
    let coord = spawn(
        &["coordinator", "--listen", "127.0.0.1:0", "--state-dir", st, "--token", "farm"]
            .into_iter()
            .chain(["--workers", &w.addr])
            .collect::<Vec<_>>(),
        &[],
    );
    let scene = small_scene(&dir);
    let png = dir.join("x.png");
    let out = sylva(
        &["submit", scene.to_str().unwrap(), "--coordinator", &coord.addr, "-o"]
            .into_iter()
            .chain([png.to_str().unwrap(), "--width", "32", "--height", "16"])
            .collect::<Vec<_>>(),
        &[("SYLVA_TOKEN", "farm"), ("SYLVA_USER", "alice")],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let id = String::from_utf8_lossy(&out.stdout).split_whitespace().next().unwrap().to_string();
    let jobs = sylva(&["jobs", "--coordinator", &coord.addr, "--json"], &[("SYLVA_TOKEN", "farm")]);
    let listed: serde_json::Value = serde_json::from_slice(&jobs.stdout).unwrap();
    let job = listed.as_array().unwrap().iter().find(|j| j["id"] == id.as_str()).unwrap();
    assert_eq!(job["submitter"], "alice@127.0.0.1", "{job}");
    let audit: serde_json::Value =
        serde_json::from_str(&ok(&["audit", "--json", "--state-dir", st])).unwrap();
    let row = audit
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["action"] == "submit" && r["target"] == id.as_str())
        .unwrap_or_else(|| panic!("{audit}"));
    assert_eq!(row["actor"], "admin (alice@127.0.0.1)", "{row}");
    let _ = std::fs::remove_dir_all(&dir);
}
