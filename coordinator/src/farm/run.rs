//! A farm run: every (frame, strip) of a job on one queue, the workers
//! pulling from it, each frame handed over once whole.

use super::client::upload_to_all;
use super::prepared::share_prepared;
use super::pull::{OpenFrame, Shared, pull_strips};
use super::{FarmEvent, PreparedShare, WorkerReport, Workers};
use crate::assembly::StripPixels;
use crate::executor::RenderedFrame;
use crate::schedule::{Strip, StripTime};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use sylva_proto::pb;
use sylva_proto::sync::lock;
use sylva_scene::bundle::SceneBundle;
use sylva_scene::frame::FrameSettings;

/// What a farm run renders: the frames of a scene (one size, own views),
/// each with its strip plan, on which workers, under which deadline.
#[derive(Clone, Copy, Debug)]
pub struct FarmJob<'a> {
    /// Where and how to reach the workers.
    pub workers: &'a Workers,
    /// The scene.
    pub bundle: &'a SceneBundle,
    /// The frames, in order.
    pub frames: &'a [FrameSettings],
    /// Per frame, its strips in pull order.
    pub plans: &'a [Vec<Strip>],
    /// Bound on each strip's RPC.
    pub deadline: Duration,
}

/// Renders `frame` of `bundle` on `workers`, strips pulled in `plan` order;
/// `deadline` bounds each strip's RPC.
pub async fn render_frame(
    workers: &Workers,
    bundle: &SceneBundle,
    frame: FrameSettings,
    plan: Vec<Strip>,
    deadline: Duration,
    events: impl Fn(FarmEvent) + Send + Sync + 'static,
) -> anyhow::Result<RenderedFrame> {
    let job = FarmJob { workers, bundle, frames: &[frame], plans: &[plan], deadline };
    let mut frames = render_frames(job, events).await?;
    Ok(frames.pop().expect("one frame"))
}

/// Renders every frame of a sequence and returns them all, in order (see
/// [`render_streamed`], which hands each over as it is done and holds
/// only the frames in flight).
pub async fn render_frames(
    job: FarmJob<'_>,
    events: impl Fn(FarmEvent) + Send + Sync + 'static,
) -> anyhow::Result<Vec<RenderedFrame>> {
    let (tx, mut rx) = tokio::sync::mpsc::channel(4);
    let n = job.frames.len();
    let collect = async move {
        let mut out: Vec<Option<RenderedFrame>> = vec![None; n];
        while let Some(f) = rx.recv().await {
            if let Finished::Frame { frame, rendered } = f {
                out[frame] = Some(*rendered);
            }
        }
        out
    };
    let run = render_streamed(job, events, Resume::none(), tx);
    let (run, out) = tokio::join!(run, collect);
    let run = run?;
    out.into_iter()
        .map(|f| {
            let mut f = f.ok_or_else(|| anyhow::anyhow!("a frame was not handed over"))?;
            f.workers.clone_from(&run.workers);
            Ok(f)
        })
        .collect()
}

/// What a farm run hands over as it goes.
pub enum Finished {
    /// A strip of a frame that is not whole yet, with the worker's reply
    /// as received (kept, a restart need not render it again).
    Strip {
        /// Frame number.
        frame: usize,
        /// Its columns.
        strip: Strip,
        /// Who rendered it.
        worker: String,
        /// The reply, checked.
        reply: Box<pb::RenderStripReply>,
    },
    /// A whole frame, put together.
    Frame {
        /// Frame number.
        frame: usize,
        /// The frame.
        rendered: Box<RenderedFrame>,
    },
}

/// What a run already holds from an earlier one (a restarted coordinator):
/// frames to skip, and strips of unfinished frames to build on.
#[derive(Default)]
pub struct Resume {
    /// Per frame, whether it is stored already.
    pub done: Vec<bool>,
    /// Strips kept of unfinished frames, with their render times.
    pub strips: Vec<(usize, StripPixels, f64)>,
}

impl Resume {
    /// Nothing held: every frame renders.
    pub fn none() -> Self {
        Self::default()
    }
}

/// A farm run's figures, once every frame is handed over.
#[derive(Clone, Debug, Default)]
pub struct FarmRun {
    /// Per worker.
    pub workers: Vec<WorkerReport>,
    /// Time to get the scene to the workers, ms.
    pub upload_ms: f64,
    /// How the scene was prepared once for the farm, when it was.
    pub prepared: Option<PreparedShare>,
}

/// Renders every frame of a sequence (same size, own views) of `bundle` on
/// `workers`: all (frame, strip) pairs go on one queue, frame by frame in
/// `plans` order, so idle workers start the next frame while the last
/// strips of one finish. Each frame goes to `out` as soon as its last
/// strip is in (and each strip of a frame cut into several as it comes),
/// so the run holds only the frames in flight; a full `out` holds the
/// workers back. Frames and strips that `resume` holds are not rendered
/// again.
pub async fn render_streamed(
    job: FarmJob<'_>,
    events: impl Fn(FarmEvent) + Send + Sync + 'static,
    resume: Resume,
    out: tokio::sync::mpsc::Sender<Finished>,
) -> anyhow::Result<FarmRun> {
    let FarmJob { workers, bundle, frames, plans, deadline } = job;
    anyhow::ensure!(!workers.addrs.is_empty(), "no workers to render on");
    anyhow::ensure!(!frames.is_empty() && frames.len() == plans.len(), "one strip plan per frame");
    anyhow::ensure!(
        frames.iter().all(|f| (f.width, f.height) == (frames[0].width, frames[0].height)),
        "a sequence's frames share one size"
    );
    let (width, height) = (frames[0].width, frames[0].height);
    // What an earlier run left: its strips go in first, and only the
    // columns they leave open are rendered.
    let mut open: std::collections::HashMap<usize, OpenFrame> = Default::default();
    // Strips an earlier run rendered: those of its whole frames, and those
    // kept of the others.
    let mut kept: usize = (0..plans.len())
        .filter(|i| resume.done.get(*i) == Some(&true))
        .map(|i| plans[i].len())
        .sum();
    for (frame, px, render_ms) in resume.strips {
        if frame >= frames.len() || resume.done.get(frame) == Some(&true) {
            continue;
        }
        let f = open
            .entry(frame)
            .or_insert_with(|| OpenFrame::new(width, height, frames[frame].passes));
        if f.assembly.add(&px).is_ok() {
            f.times.push(StripTime { strip: px.strip, render_ms, call_ms: render_ms });
            kept += 1;
        }
    }
    let mut queue = VecDeque::new();
    for (i, plan) in plans.iter().enumerate() {
        if resume.done.get(i) == Some(&true) {
            continue;
        }
        let todo = match open.get(&i) {
            Some(f) => f.assembly.open_columns(plan),
            None => plan.clone(),
        };
        if let Some(f) = open.get_mut(&i) {
            f.left = todo.len();
        }
        queue.extend(todo.into_iter().map(|s| (i, s)));
    }
    // A frame whose every strip an earlier run kept is whole already.
    let whole: Vec<usize> = open.iter().filter(|(_, f)| f.left == 0).map(|(i, _)| *i).collect();
    let mut ready = Vec::new();
    for i in whole {
        let f = open.remove(&i).expect("open frame");
        ready.push(Finished::Frame { frame: i, rendered: Box::new(f.rendered(0.0, None)) });
    }
    for f in ready {
        out.send(f).await.map_err(|_| anyhow::anyhow!("the frames' receiver is gone"))?;
    }
    let left: Vec<usize> =
        (0..frames.len()).map(|i| queue.iter().filter(|(f, _)| *f == i).count()).collect();
    events(FarmEvent::Planned { strips: queue.len(), kept });
    if queue.is_empty() {
        return Ok(FarmRun::default());
    }
    events(FarmEvent::Stage(format!("sending the scene to {} workers", workers.addrs.len())));
    let (clients, reports, upload_ms) = upload_to_all(workers, bundle, &events).await;
    let wires: Vec<pb::FrameSettings> = frames.iter().map(pb::FrameSettings::from).collect();
    let prepared = match share_prepared(
        &clients,
        &workers.addrs,
        &bundle.hash,
        &workers.job,
        &wires[0],
        deadline,
        &|s| events(FarmEvent::Stage(s)),
    )
    .await
    {
        Ok(Some(share)) => {
            events(FarmEvent::PreparedShared(share.clone()));
            Some(share)
        }
        Ok(None) => None,
        Err(e) => {
            // Not fatal: each worker then prepares the scene itself.
            tracing::warn!("prepared data not shared: {e}");
            None
        }
    };
    let total = queue.len();
    let shared = Arc::new(Shared {
        queue: Mutex::new(queue),
        open: Mutex::new(open),
        left: Mutex::new(left),
        remaining: Mutex::new(total),
        size: (width, height),
        passes: frames.iter().map(|f| f.passes).collect(),
        wires,
        hash: bundle.hash.clone(),
        deadline,
        workers: clients.len(),
        upload_ms,
        prepared: prepared.clone(),
        out,
        job: workers.job.clone(),
    });
    events(FarmEvent::Stage(
        "tracing (a worker that does not hold the prepared scene prepares it first: \
         structures, voxels, LB light, upload)"
            .into(),
    ));
    let events = Arc::new(events);
    let mut tasks = Vec::new();
    for (me, (client, report)) in clients.into_iter().zip(reports).enumerate() {
        let (shared, events) = (shared.clone(), events.clone());
        tasks.push(tokio::spawn(async move {
            pull_strips(me, client, report, &shared, &*events).await
        }));
    }
    // A run dropped (its job cancelled) stops its pullers with it: their
    // strip calls are dropped, which tells each worker to stop the strip.
    let _stop = AbortOnDrop(tasks.iter().map(|t| t.abort_handle()).collect());
    // Wait for the frames, or for every worker to be gone.
    let mut reports = Vec::new();
    for t in tasks {
        reports.push(t.await?);
    }
    let remaining = *lock(&shared.remaining);
    if remaining > 0 {
        let why: Vec<String> = reports
            .iter()
            .filter(|r| r.dropped)
            .map(|r| format!("{}: {}", r.worker, r.last_error.as_deref().unwrap_or("dropped")))
            .collect();
        let what = if frames.len() == 1 { "the frame" } else { "the sequence" };
        anyhow::bail!(
            "{what} failed: {} of {total} strips rendered; no worker left that can finish it ({})",
            total - remaining,
            why.join("; ")
        );
    }
    Ok(FarmRun { workers: reports, upload_ms, prepared })
}

/// Aborts its tasks when dropped.
struct AbortOnDrop(Vec<tokio::task::AbortHandle>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.iter().for_each(tokio::task::AbortHandle::abort);
    }
}
