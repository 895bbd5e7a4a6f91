//! A cancel stops the work, as a user means it: a long frame on two real
//! workers, cancelled after its first strip, leaves both workers idle
//! within a piece of a strip (the strips in flight stop between two GPU
//! dispatches), renders no further strip, and the next job runs at once.
//!
//! How soon is measured against the same run's strip time, not a clock:
//! on a loaded two-core lavapipe machine one column of a many-sample strip
//! alone can take a second, where a GPU takes milliseconds.

use crate::common;

use common::{coordinator, small_scene, spawn, spec, submission, wait_for_workers};
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::pb::worker_client::WorkerClient;

/// Strips each worker is rendering now, as it says itself.
async fn busy(workers: &[String]) -> Vec<u32> {
    let mut out = Vec::new();
    for a in workers {
        let mut w = WorkerClient::connect(format!("http://{a}")).await.unwrap();
        out.push(w.status(pb::StatusRequest {}).await.unwrap().into_inner().busy_strips);
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancel_stops_the_strips_in_flight_on_every_worker_within_a_piece() {
    let dir = common::scratch("cancel");
    let b = sylva_scene::bundle::pack(&small_scene(&dir)).unwrap();
    let w1 = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let w2 = spawn(&["worker", "--listen", "127.0.0.1:0"], &[]);
    let addrs = vec![w1.addr.clone(), w2.addr.clone()];
    let coord =
        spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &addrs.join(",")], &[]);
    let mut c = coordinator(&coord.addr, None).await;
    wait_for_workers(&mut c, 2).await;
    // A long frame: many seconds a strip on lavapipe, a dozen strips.
    let mut long = spec(320, 160);
    long.frame.as_mut().unwrap().spp = 2048;
    let id = c
        .submit_job(tokio_stream::iter(submission(long, &b.hash, &b.bytes, b.bytes.len() as u64)))
        .await
        .unwrap()
        .into_inner()
        .id;
    let mut events = c.watch_job(pb::JobId { id: id.clone() }).await.unwrap().into_inner();
    let (total, strip_ms) = loop {
        let ev = tokio_stream::StreamExt::next(&mut events).await.unwrap().unwrap();
        if ev.strips_done >= 1 {
            break (ev.strips_total, ev.strip_ms);
        }
    };
    assert!(total >= 4, "a frame of several strips: {total}");
    // Both workers are on a strip of it when the cancel comes.
    let mut both = false;
    for _ in 0..100 {
        if busy(&addrs).await.iter().all(|b| *b > 0) {
            both = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(both, "both workers render the frame");
    let asked = Instant::now();
    let s = c.cancel_job(pb::JobId { id: id.clone() }).await.unwrap().into_inner();
    assert_eq!(s.state, pb::JobState::Cancelled as i32);
    let done_at_cancel = s.strips_done;
    // Watched for as long as a whole strip takes.
    let mut idle = None;
    while asked.elapsed().as_secs_f64() * 1e3 < strip_ms.max(1000.0) {
        if busy(&addrs).await.iter().all(|b| *b == 0) {
            idle = Some(asked.elapsed());
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let idle = idle.expect("the workers stopped the cancelled strips");
    eprintln!(
        "both workers idle {} ms after the cancel ({done_at_cancel} of {total} strips done, \
         the first in {strip_ms:.0} ms)",
        idle.as_millis()
    );
    // Within a piece: a small part of a strip. Strips that ran on to their
    // end (as before cancels reached the workers) would keep a worker
    // busy for most of a strip's time: the one just handed out had barely
    // begun.
    assert!(strip_ms > 0.0, "the event names the strip's time");
    assert!(
        idle.as_secs_f64() * 1e3 < strip_ms / 5.0,
        "idle only after {idle:?}, against {strip_ms:.0} ms for a whole strip"
    );
    // No strip of it is rendered after the cancel.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let jobs = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    let j = jobs.iter().find(|j| j.id == id).unwrap();
    assert_eq!(j.state, pb::JobState::Cancelled as i32);
    assert!(j.strips_done <= done_at_cancel + 2 && j.strips_done < total, "{j:?}");
    assert_eq!(busy(&addrs).await, vec![0, 0]);
    // The workers are free for the next job: it runs at once.
    let ev = common::submit_and_wait(&mut c, spec(64, 32), &b, |_| {}).await;
    assert_eq!(ev.state, pb::JobState::Done as i32, "{}", ev.message);
    let _ = std::fs::remove_dir_all(&dir);
}
