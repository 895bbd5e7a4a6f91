//! One worker's share of a run: it pulls strips from the run's queue.

use super::run::Finished;
use super::{Client, FarmEvent, MAX_FAILURES, PreparedShare, WorkerReport, decode_reply, said};
use crate::assembly::Assembly;
use crate::executor::RenderedFrame;
use crate::schedule::{Strip, StripTime};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::sync::lock;
use sylva_scene::passes::PassSet;

/// What the workers of one run share: the queue, the frames in flight,
/// and what every strip request carries.
pub(super) struct Shared {
    /// (frame, strip) in pull order.
    pub queue: Mutex<VecDeque<(usize, Strip)>>,
    /// Frames with strips in: only those in flight.
    pub open: Mutex<std::collections::HashMap<usize, OpenFrame>>,
    /// Per frame, strips not yet in.
    pub left: Mutex<Vec<usize>>,
    /// Strips not yet in, all frames.
    pub remaining: Mutex<usize>,
    /// Every frame's width and height.
    pub size: (u32, u32),
    /// Each frame's passes beside the image.
    pub passes: Vec<PassSet>,
    /// Each frame's settings as the workers are sent them.
    pub wires: Vec<pb::FrameSettings>,
    /// The scene bundle's hash.
    pub hash: String,
    /// Bound on each strip's RPC.
    pub deadline: Duration,
    /// Workers pulling (each prefers its own frames of a sequence).
    pub workers: usize,
    pub upload_ms: f64,
    pub prepared: Option<PreparedShare>,
    pub out: tokio::sync::mpsc::Sender<Finished>,
    /// The job the strips belong to.
    pub job: String,
}

/// A frame being put together, and how many of its strips are still out.
pub(super) struct OpenFrame {
    pub assembly: Assembly,
    pub times: Vec<StripTime>,
    pub left: usize,
}

impl OpenFrame {
    pub fn new(width: u32, height: u32, passes: PassSet) -> Self {
        Self { assembly: Assembly::new(width, height, passes), times: Vec::new(), left: 0 }
    }

    pub fn rendered(mut self, upload_ms: f64, prepared: Option<PreparedShare>) -> RenderedFrame {
        self.times.sort_by_key(|s| s.strip);
        RenderedFrame {
            image: self.assembly.image,
            coverage: self.assembly.coverage,
            rays: self.assembly.rays,
            workers: Vec::new(),
            strip_times: self.times,
            upload_ms,
            prepared,
            passes: self.assembly.passes,
            warnings: self.assembly.warnings,
            noisy: None,
        }
    }
}

/// One worker's share of the frames: it pulls strips until none is left,
/// puts back any it fails (and gives up after [`MAX_FAILURES`]), hands
/// each strip and each frame it completes over, and says what it did.
pub(super) async fn pull_strips(
    me: usize,
    client: Option<Client>,
    mut report: WorkerReport,
    shared: &Shared,
    events: &(impl Fn(FarmEvent) + Send + Sync),
) -> WorkerReport {
    let Some(mut client) = client else { return report };
    let (width, height) = shared.size;
    let (passes_of, wires, deadline) = (&shared.passes, &shared.wires, shared.deadline);
    loop {
        let next = {
            // In a sequence each worker prefers the frames that
            // are its own by number (frame mod workers), so a
            // second pass over the same views meets the light it
            // kept per sun; it takes any other when it has none left.
            let mut q = lock(&shared.queue);
            let mine = if wires.len() > 1 {
                q.iter().position(|(f, _)| f % shared.workers == me)
            } else {
                None
            };
            mine.and_then(|i| q.remove(i)).or_else(|| q.pop_front())
        };
        let Some((frame, strip)) = next else {
            if *lock(&shared.remaining) == 0 {
                return report;
            }
            // Strips may still come back from failing workers.
            tokio::time::sleep(Duration::from_millis(5)).await;
            continue;
        };
        let mut req = tonic::Request::new(pb::RenderStripRequest {
            scene_hash: shared.hash.clone(),
            frame: Some(wires[frame].clone()),
            x0: strip.0,
            x1: strip.1,
            job: shared.job.clone(),
        });
        req.set_timeout(deadline);
        let sent = Instant::now();
        let outcome =
            match tokio::time::timeout(deadline + Duration::from_secs(1), client.render_strip(req))
                .await
            {
                Ok(Ok(reply)) => {
                    let r = reply.into_inner();
                    decode_reply(&r, strip, height, passes_of[frame])
                        .map(|px| (r, px))
                        .map_err(|e| e.to_string())
                }
                Ok(Err(status)) => Err(format!("{:?}: {}", status.code(), said(status.message()))),
                Err(_) => Err("deadline passed".to_string()),
            };
        match outcome {
            Ok((r, px)) => {
                report.strips += 1;
                report.render_ms += r.render_ms;
                report.prepare_ms += r.prepare_ms;
                let bytes = (r.rgb_f32.len() + r.coverage_f32.len() + r.passes_f32.len()) as u64;
                events(FarmEvent::StripDone {
                    frame,
                    strip,
                    worker: report.worker.clone(),
                    ms: r.render_ms,
                    bytes,
                    preview: Arc::new(px.preview()),
                });
                let time = StripTime {
                    strip,
                    render_ms: r.render_ms,
                    call_ms: sent.elapsed().as_secs_f64() * 1e3,
                };
                // Put in place now; the frame leaves the farm when whole.
                let whole = {
                    let mut open = lock(&shared.open);
                    let f = open
                        .entry(frame)
                        .or_insert_with(|| OpenFrame::new(width, height, passes_of[frame]));
                    // decode_reply checked the strip against its request,
                    // and the queue hands each columns out once.
                    let _ = f.assembly.add(&px);
                    f.times.push(time);
                    let mut left = lock(&shared.left);
                    left[frame] -= 1;
                    (left[frame] == 0).then(|| open.remove(&frame).expect("open frame"))
                };
                drop(px);
                let handed = match whole {
                    Some(f) => Finished::Frame {
                        frame,
                        rendered: Box::new(f.rendered(shared.upload_ms, shared.prepared.clone())),
                    },
                    None => Finished::Strip {
                        frame,
                        strip,
                        worker: report.worker.clone(),
                        reply: Box::new(r),
                    },
                };
                // A gone receiver has given up on the run; the count still
                // falls, so every worker stops.
                let _ = shared.out.send(handed).await;
                *lock(&shared.remaining) -= 1;
            }
            Err(error) => {
                lock(&shared.queue).push_back((frame, strip));
                report.failures += 1;
                report.last_error = Some(error.clone());
                events(FarmEvent::StripRetried {
                    frame,
                    strip,
                    worker: report.worker.clone(),
                    error: error.clone(),
                });
                if report.failures >= MAX_FAILURES {
                    report.dropped = true;
                    events(FarmEvent::WorkerDropped { worker: report.worker.clone(), error });
                    return report;
                }
            }
        }
    }
}
