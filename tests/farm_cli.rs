//! The farm tools as a user runs them (`sylva jobs`, `workers`, `cancel`,
//! `requeue`, `priority`, `fetch`): real processes against a real coordinator and
//! worker over loopback gRPC.

use crate::common;

use common::{coordinator, scratch, small_scene, spawn, spec, submission, sylva, wait_for_workers};
use serde_json::Value;
use std::time::Duration;

/// Runs `sylva ARGS` as the user `alice`; it must succeed. Its stdout.
fn ok_as_alice(args: &[&str]) -> String {
    let out = sylva(args, &[("SYLVA_USER", "alice")]);
    assert!(
        out.status.success(),
        "sylva {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn jobs(addr: &str) -> Vec<Value> {
    let v: Value =
        serde_json::from_str(&ok_as_alice(&["jobs", "--coordinator", addr, "--json"])).unwrap();
    v.as_array().unwrap().clone()
}

fn job<'a>(list: &'a [Value], id: &str) -> &'a Value {
    list.iter().find(|j| j["id"] == id).unwrap_or_else(|| panic!("{id} not listed: {list:?}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_user_lists_reorders_cancels_and_fetches_jobs_from_the_command_line() {
    let dir = scratch("farm-cli");
    let scene = small_scene(&dir);
    let w = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    // One job at a time, so the others wait in the queue.
    let coord = spawn(
        &["coordinator", "--listen", "127.0.0.1:0", "--workers", &w.addr, "--max-running", "1"],
        &[],
    );
    let addr = coord.addr.clone();
    let mut c = coordinator(&addr, None).await;
    wait_for_workers(&mut c, 1).await;

    // A job submitted and followed by `sylva submit`, as alice, with the
    // coordinator named as the other farm commands take it (the
    // environment) and a name of her own.
    let png = dir.join("first.png");
    let args = ["submit", scene.to_str().unwrap(), "-o", png.to_str().unwrap(), "--name", "shot 1"];
    let out = sylva(
        &[&args[..], &["--width", "64", "--height", "32", "--lighting", "lb"]].concat(),
        &[("SYLVA_USER", "alice"), ("SYLVA_COORDINATOR", &addr)],
    );
    let said = String::from_utf8_lossy(&out.stdout).to_string();
    let told = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{told}");
    // What the worker's LB found about the scene reaches her, once each
    // (issue 41, point 3), as a `render` in one process logs it.
    let warned: Vec<&str> = told.lines().filter(|l| l.starts_with("warning: ")).collect();
    assert!(warned.iter().any(|l| l.contains(": LB: ")), "{told}");
    let unique: std::collections::HashSet<&&str> = warned.iter().collect();
    assert_eq!(unique.len(), warned.len(), "{told}");
    assert!(said.contains(" done in ") && said.contains("first.png"), "{said}");
    let first = said.split_whitespace().next().unwrap().to_string();
    // Its stats beside the image, as `render` writes them, with the warnings.
    let stats: Value =
        serde_json::from_slice(&std::fs::read(dir.join("first.stats.json")).unwrap()).unwrap();
    assert_eq!(stats["job"], first.as_str(), "{stats}");
    assert!(stats["total_ms"].as_f64().unwrap() > 0.0, "{stats}");
    assert!(stats["farm"].is_object(), "{stats}");
    let kept = stats["farm"]["warnings"].as_array().map_or(0, Vec::len);
    assert_eq!(kept, warned.len(), "{stats}");
    let listed = jobs(&addr);
    let j = job(&listed, &first);
    assert_eq!(j["name"], "shot 1", "{j}");
    assert_eq!(j["state"], "done", "{j}");
    assert_eq!(j["submitter"], "alice@127.0.0.1", "{j}");
    assert!(
        j["strips_total"].as_u64().unwrap() > 0 && j["strips_done"] == j["strips_total"],
        "{j}"
    );
    let (s, r, f) = (
        j["submitted_unix_ms"].as_u64().unwrap(),
        j["started_unix_ms"].as_u64().unwrap(),
        j["finished_unix_ms"].as_u64().unwrap(),
    );
    assert!(s > 0 && s <= r && r <= f, "{j}");

    // The worker did the strips, failed none, and holds the scene.
    let workers: Value =
        serde_json::from_str(&ok_as_alice(&["workers", "--coordinator", &addr, "--json"])).unwrap();
    let wk = &workers[0];
    assert_eq!(
        (wk["addr"].as_str().unwrap(), wk["alive"].as_bool().unwrap()),
        (w.addr.as_str(), true),
        "{workers}"
    );
    assert!(
        wk["strips_done"].as_u64().unwrap() >= j["strips_total"].as_u64().unwrap(),
        "{workers}"
    );
    assert_eq!(wk["strips_failed"], 0);
    // It says which traversal `auto` chose there, and why (the coordinator
    // hears it with the worker's next heartbeat).
    let t = std::time::Instant::now();
    loop {
        let ws: Value =
            serde_json::from_str(&ok_as_alice(&["workers", "--coordinator", &addr, "--json"]))
                .unwrap();
        if ws[0]["backend"].as_str().is_some_and(|b| !b.is_empty()) {
            assert!(ws[0]["backend_why"].as_str().unwrap().starts_with("auto:"), "{ws}");
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "no traversal reported: {ws}");
        std::thread::sleep(Duration::from_millis(200));
    }
    // The table for people names the same worker, and its traversal.
    let table = ok_as_alice(&["workers", "--coordinator", &addr]);
    assert!(table.contains(&w.addr) && table.contains("TRAVERSAL"), "{table}");

    // `fetch` gives back the image `submit` wrote, and its HDR frame.
    let fetched = dir.join("fetched.png");
    ok_as_alice(&["fetch", &first, "--coordinator", &addr, "-o", fetched.to_str().unwrap()]);
    assert_eq!(std::fs::read(&fetched).unwrap(), std::fs::read(&png).unwrap());
    let exr = dir.join("fetched.exr");
    ok_as_alice(&["fetch", &first, "--coordinator", &addr, "-o", exr.to_str().unwrap()]);
    assert_eq!(&std::fs::read(&exr).unwrap()[..4], &[0x76, 0x2f, 0x31, 0x01], "OpenEXR magic");

    // A long job holds the only slot; two more wait behind it.
    let b = sylva_scene::bundle::pack(&scene).unwrap();
    let mut submit = async |width: u32, height: u32, spp: u32| {
        let mut s = spec(width, height);
        s.frame.as_mut().unwrap().spp = spp;
        c.submit_job(tokio_stream::iter(submission(s, &b.hash, &b.bytes, b.bytes.len() as u64)))
            .await
            .unwrap()
            .into_inner()
            .id
    };
    let long = submit(640, 480, 64).await;
    let (q1, q2, q3) = (submit(64, 32, 1).await, submit(64, 32, 1).await, submit(64, 32, 1).await);
    for _ in 0..100 {
        if job(&jobs(&addr), &long)["state"] == "running" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let listed = jobs(&addr);
    for q in [&q1, &q2, &q3] {
        assert_eq!(job(&listed, q)["state"], "queued", "{listed:?}");
    }
    // A running job says what the farm is doing for it (issue 41, point
    // 2); a done one says nothing more, and estimates nothing.
    let mut stage = String::new();
    for _ in 0..200 {
        stage = job(&jobs(&addr), &long)["stage"].as_str().unwrap_or_default().to_string();
        if !stage.is_empty() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(!stage.is_empty(), "{:?}", job(&jobs(&addr), &long));
    let done = job(&listed, &first);
    assert!(done["stage"] == "" && done["eta_s"].is_null(), "{done}");
    assert!(ok_as_alice(&["jobs", "--coordinator", &addr, "--wide"]).contains("STAGE"));
    // The last is raised above the others; the first is cancelled while it waits.
    let raised: Value = serde_json::from_str(&ok_as_alice(&[
        "priority",
        &q3,
        "5",
        "--coordinator",
        &addr,
        "--json",
    ]))
    .unwrap();
    assert_eq!(raised["priority"], 5);
    let cancelled: Value =
        serde_json::from_str(&ok_as_alice(&["cancel", &q1, "--coordinator", &addr, "--json"]))
            .unwrap();
    assert_eq!(cancelled[0]["state"], "cancelled", "{cancelled}");
    // And the long one, while it runs: the slot frees for the queue.
    let out = ok_as_alice(&["cancel", &long, "--coordinator", &addr]);
    assert!(out.contains("cancelled"), "{out}");
    let mut listed = Vec::new();
    for _ in 0..600 {
        listed = jobs(&addr);
        if job(&listed, &q2)["state"] == "done" && job(&listed, &q3)["state"] == "done" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let started = |id: &str| {
        job(&listed, id)["started_unix_ms"]
            .as_u64()
            .unwrap_or_else(|| panic!("{id} did not start: {listed:?}"))
    };
    assert!(started(&q3) <= started(&q2), "the raised job runs first: {listed:?}");
    assert_eq!(job(&listed, &q1)["state"], "cancelled");
    assert_eq!(job(&listed, &long)["state"], "cancelled");
    // A finished job's priority orders nothing: changing it is refused.
    let out = sylva(&["priority", &q2, "9", "--coordinator", &addr], &[("SYLVA_USER", "alice")]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("is done: its priority orders nothing"), "{err}");
    assert_eq!(job(&jobs(&addr), &q2)["priority"], 0);
    // Nor is a finished job cancelled: a user is told, with a failing code.
    let out = sylva(&["cancel", &q2, "--coordinator", &addr], &[("SYLVA_USER", "alice")]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("is done: nothing to cancel"), "{err}");
    assert_eq!(job(&jobs(&addr), &q2)["state"], "done");
    assert!(
        job(&listed, &q1)["started_unix_ms"].is_null(),
        "a job cancelled in the queue never started"
    );

    // Filters and errors a user meets.
    let done: Vec<Value> = serde_json::from_str::<Value>(&ok_as_alice(&[
        "jobs",
        "--coordinator",
        &addr,
        "--state",
        "done",
        "--json",
    ]))
    .unwrap()
    .as_array()
    .unwrap()
    .clone();
    assert_eq!(done.len(), 3, "{done:?}");
    let table = ok_as_alice(&["jobs", "--coordinator", &addr]);
    assert!(
        table.starts_with("ID ") && table.contains(&long) && table.contains("alice@127.0.0.1"),
        "{table}"
    );
    // The listing keeps to 80 columns; --wide has every column, however wide.
    assert!(table.lines().all(|l| l.chars().count() <= 80), "{table}");
    assert!(ok_as_alice(&["jobs", "--coordinator", &addr, "--wide"]).contains("RETRIES"));
    // A cancelled job runs again as a new job, to its end; the old one
    // stays cancelled, and a done job is not requeued.
    let again: Value =
        serde_json::from_str(&ok_as_alice(&["requeue", &q1, "--coordinator", &addr, "--json"]))
            .unwrap();
    let again = again[0]["requeued_as"].as_str().unwrap().to_string();
    assert_ne!(again, q1);
    for _ in 0..600 {
        if job(&jobs(&addr), &again)["state"] == "done" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let listed = jobs(&addr);
    assert_eq!(job(&listed, &again)["state"], "done", "{listed:?}");
    assert_eq!(job(&listed, &q1)["state"], "cancelled");
    // Once: a second requeue (a double click) makes no second job.
    let out = sylva(&["requeue", &q1, "--coordinator", &addr], &[("SYLVA_USER", "alice")]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("requeued already"), "{err}");
    let out = sylva(&["requeue", &q2, "--coordinator", &addr], &[("SYLVA_USER", "alice")]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("only a failed or cancelled job"), "{err}");
    let out = sylva(&["cancel", "job-nope", "--coordinator", &addr], &[]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("NotFound"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = sylva(
        &["fetch", &q1, "--coordinator", &addr, "-o", dir.join("x.png").to_str().unwrap()],
        &[],
    );
    assert!(!out.status.success(), "a cancelled job has no image");
}
