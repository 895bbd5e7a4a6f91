//! One job run on the farm: planned into strips, rendered by the workers
//! with progress streamed to watchers and the live view, tone mapped,
//! encoded and stored.

use super::live::{LiveFrame, LiveStrip};
use super::workers::KnownWorker;
use super::{State, stats};
use crate::farm::{self, FarmEvent, Workers};
use crate::job_state::JobState;
use crate::schedule::{ScheduleKind, Strip, scheduler};
use std::sync::Arc;
use std::time::Instant;
use sylva_proto::pb;
use sylva_proto::sync::lock;
use sylva_scene::bundle::{self, SceneBundle};
use sylva_scene::film::{reinhard, reinhard_like};
use sylva_scene::frame::FrameSettings;
use sylva_scene::sandbox::clip;
use tokio::sync::broadcast;

impl State {
    pub(super) async fn run_job(self: &Arc<Self>, id: &str) {
        let Some((frame, views, schedule, hash, tx)) = ({
            let jobs = lock(&self.jobs);
            jobs.get(id).map(|j| {
                (j.frame, j.views.clone(), j.schedule, j.bundle_hash.clone(), j.events.clone())
            })
        }) else {
            return;
        };
        let _ = tx.send(self.event(id));
        let (addrs, keys): (Vec<String>, std::collections::HashMap<String, String>) = {
            let workers = lock(&self.workers);
            let alive: Vec<&KnownWorker> = workers.values().filter(|w| w.info.alive).collect();
            (
                alive.iter().map(|w| w.info.addr.clone()).collect(),
                alive.iter().filter_map(|w| Some((w.info.addr.clone(), w.key.clone()?))).collect(),
            )
        };
        if addrs.is_empty() {
            return self.fail(id, &tx, "no worker is registered and alive: start workers with --coordinator, or the coordinator with --workers".into()).await;
        }
        // The bundle waited on disk; it is read back and checked.
        let path = self.bundle_path(&hash);
        let read = tokio::task::spawn_blocking(move || std::fs::read(path)).await;
        let bundle = match read {
            Ok(Ok(bytes)) if bundle::hash_of(&bytes) == hash => SceneBundle { bytes, hash },
            _ => {
                return self
                    .fail(id, &tx, "the job's scene is missing or damaged in the coordinator's state folder: submit it again".into())
                    .await;
            }
        };
        let frames: Vec<FrameSettings> = if views.is_empty() {
            vec![frame]
        } else {
            views.iter().map(|v| FrameSettings { view: *v, ..frame }).collect()
        };
        let (plans, cost_key, cost_source) =
            self.plan(&bundle.hash, &frames, schedule, addrs.len());
        let resume = self.resume_of(id, frames.len(), frame.height, frame.passes).await;
        let kept = resume.done.iter().filter(|d| **d).count();
        if let Some(j) = lock(&self.jobs).get_mut(id) {
            j.summary.strips_total = plans.iter().map(Vec::len).sum::<usize>() as u32;
            j.summary.strips_done = 0;
            // A run's estimate starts from its own first strip.
            j.first_strip = None;
            j.summary.frames_done = kept as u32;
            j.live = LiveFrame {
                width: frame.width,
                height: frame.height,
                frame: 0,
                strips: Vec::new(),
                preview: vec![0; frame.width as usize * frame.height as usize * 3],
            };
        }
        if kept > 0 || !resume.strips.is_empty() {
            tracing::info!(%id, frames = kept, strips = resume.strips.len(), "resuming from what an earlier run stored");
        }
        let span = tracing::info_span!("job", %id, frames = frames.len(), workers = addrs.len());
        let _g = span.enter();
        let (me, jid, tx2) = (self.clone(), id.to_string(), tx.clone());
        let started = Instant::now();
        // Frames leave the farm as they are done and go to disk at once:
        // the job holds only those in flight, however long the sequence.
        let (out, finished) = tokio::sync::mpsc::channel(2 * addrs.len() + 2);
        let workers = Workers {
            addrs: addrs.clone(),
            token: self.config.token.clone(),
            tls: self.config.worker_tls.clone(),
            keys,
            job: id.to_string(),
        };
        let job = farm::FarmJob {
            workers: &workers,
            bundle: &bundle,
            frames: &frames,
            plans: &plans,
            deadline: self.config.strip_deadline,
        };
        let farm = async move {
            let run =
                farm::render_streamed(job, move |e| me.on_farm_event(&jid, e, &tx2), resume, out)
                    .await;
            (run, started.elapsed().as_secs_f64() * 1e3)
        };
        let mut phases = stats::JobPhases::default();
        let ((run, farm_ms), kept) =
            tokio::join!(farm, self.keep_frames(id, finished, started, &tx, &mut phases.store_ms));
        (phases.farm_ms, phases.stored_ms) = (farm_ms, started.elapsed().as_secs_f64() * 1e3);
        drop(bundle);
        let run = match run {
            Ok(r) => r,
            Err(e) => return self.fail(id, &tx, format!("{e:#}")).await,
        };
        let first = match kept {
            Ok(f) => f,
            Err(e) => {
                return self.fail(id, &tx, format!("the result could not be stored: {e:#}")).await;
            }
        };
        let tone_started = Instant::now();
        let (per_frame, bytes) = match self.tone_map(id, frames.len()).await {
            Ok(t) => t,
            Err(e) => {
                return self.fail(id, &tx, format!("the frames could not be encoded: {e:#}")).await;
            }
        };
        phases.tone_map_ms = tone_started.elapsed().as_secs_f64() * 1e3;
        let frame_ms = started.elapsed().as_secs_f64() * 1e3;
        if let Some(times) = first {
            self.remember_cost(cost_key, frame.width, &times);
        }
        let n = frames.len();
        let sequence = (!views.is_empty()).then(|| stats::SequenceStats {
            frames: n,
            ms_per_frame: frame_ms / n as f64,
            whole_frames_in_parallel: per_frame
                .first()
                .is_some_and(|f| f["strips"].as_array().is_some_and(|s| s.len() == 1)),
            per_frame: per_frame.clone(),
        });
        let stats = stats::JobStats {
            schedule,
            strip_cost: cost_source,
            frame_ms,
            upload_ms: run.upload_ms,
            phases,
            prepared_once: run.prepared.clone(),
            workers: run.workers.clone(),
            frame: views.is_empty().then(|| per_frame[0].clone()),
            sequence,
        };
        let json = serde_json::to_string(&stats).unwrap_or_default();
        if let Some(j) = lock(&self.jobs).get_mut(id) {
            j.reserved = bytes;
            j.stats_json = json.clone();
        }
        if let Err(e) = self.store.set_stats(id, &json, bytes).await {
            tracing::warn!(%id, "figures not written yet: {e:#}");
            self.owe_stats(id, json.clone(), bytes);
        }
        self.finish(id, JobState::Done, None).await;
        let mut ev = self.event(id);
        ev.stats_json = json;
        let _ = tx.send(ev);
        self.close_events(id);
    }

    /// Fails a job with `why`, and tells its watchers.
    async fn fail(&self, id: &str, tx: &broadcast::Sender<pb::JobEvent>, why: String) {
        self.finish(id, JobState::Failed, Some(why.clone())).await;
        let mut ev = self.event(id);
        ev.message = why;
        let _ = tx.send(ev);
        self.close_events(id);
    }

    /// What earlier runs of a job stored: its frames, and the strips of
    /// frames they did not finish (each read back and checked as a
    /// worker's reply is; one that does not pass is rendered again).
    async fn resume_of(
        &self,
        id: &str,
        frames: usize,
        height: u32,
        passes: sylva_scene::passes::PassSet,
    ) -> farm::Resume {
        use prost::Message;
        let mut resume = farm::Resume { done: vec![false; frames], strips: Vec::new() };
        if let Ok(rows) = self.store.frames(id).await {
            for f in rows {
                if let Some(d) = resume.done.get_mut(f.frame as usize) {
                    *d = true;
                }
            }
        }
        let strips = self.store.strips(id).await.unwrap_or_default();
        let dir = self.config.state_dir.clone();
        let read = tokio::task::spawn_blocking(move || {
            strips
                .into_iter()
                .filter_map(|s| {
                    let bytes = std::fs::read(dir.join(&s.path)).ok()?;
                    let r = pb::RenderStripReply::decode(bytes.as_slice()).ok()?;
                    let px = farm::decode_reply(&r, (s.x0, s.x1), height, passes).ok()?;
                    Some((s.frame as usize, px, r.render_ms))
                })
                .collect::<Vec<_>>()
        })
        .await;
        resume.strips = read.unwrap_or_default();
        resume
    }

    /// Stores what the farm hands over as it comes: a strip of an
    /// unfinished frame as the worker's reply, a whole frame as its EXR;
    /// each written, then recorded. Returns the strip times of the first
    /// frame cut into strips (the next frame's plan learns from them).
    async fn keep_frames(
        &self,
        id: &str,
        mut finished: tokio::sync::mpsc::Receiver<farm::Finished>,
        started: Instant,
        tx: &broadcast::Sender<pb::JobEvent>,
        store_ms: &mut f64,
    ) -> anyhow::Result<Option<Vec<crate::schedule::StripTime>>> {
        use prost::Message;
        let dir = crate::results::job_dir(&self.config.state_dir, id);
        let denoise = lock(&self.jobs).get(id).map_or(Default::default(), |j| j.frame.denoise);
        let mut stored = std::collections::HashSet::new();
        let mut first = None;
        let mut in_run = 0u32;
        while let Some(f) = finished.recv().await {
            match f {
                farm::Finished::Strip { frame, strip, worker, reply } => {
                    if stored.contains(&frame) {
                        continue;
                    }
                    let name = format!("strips/{frame:05}-{}-{}.pb", strip.0, strip.1);
                    let path = dir.join(&name);
                    tokio::task::spawn_blocking(move || {
                        crate::results::write_whole(&path, &reply.encode_to_vec())
                    })
                    .await??;
                    let row = crate::store::StripRow {
                        frame: frame as u32,
                        x0: strip.0,
                        x1: strip.1,
                        worker,
                        path: crate::results::relative(id, &name),
                    };
                    self.store.put_strip(id, &row).await?;
                }
                farm::Finished::Frame { frame, rendered } => {
                    let stored_at = Instant::now();
                    in_run += 1;
                    let ms = started.elapsed().as_secs_f64() * 1e3 / in_run as f64;
                    let figures = stats::FrameStats::of(&rendered, &Default::default(), ms);
                    if first.is_none() && rendered.strip_times.len() > 1 {
                        first = Some(rendered.strip_times.clone());
                    }
                    let name = format!("{frame:05}.exr");
                    let path = dir.join(&name);
                    let bytes = tokio::task::spawn_blocking(move || {
                        let mut rendered = rendered;
                        // The whole frame, here where it is assembled.
                        rendered.denoise(denoise)?;
                        let exr = rendered.exr()?;
                        crate::results::write_whole(&path, &exr)?;
                        anyhow::Ok((exr.len() as u64, crate::results::hash(&exr)))
                    })
                    .await??;
                    let row = crate::store::FrameRow {
                        frame: frame as u32,
                        exr: crate::results::relative(id, &name),
                        bytes: bytes.0,
                        stats_json: serde_json::to_string(&figures)?,
                        exr_hash: bytes.1,
                        ..Default::default()
                    };
                    self.store.put_frame(id, &row).await?;
                    stored.insert(frame);
                    // The frame's strips, kept in case of a restart, are done with.
                    let strips = dir.join("strips");
                    let prefix = format!("{frame:05}-");
                    let _ = tokio::task::spawn_blocking(move || {
                        for e in std::fs::read_dir(strips).into_iter().flatten().flatten() {
                            if e.file_name().to_string_lossy().starts_with(&prefix) {
                                let _ = std::fs::remove_file(e.path());
                            }
                        }
                    })
                    .await;
                    let ev = {
                        let mut jobs = lock(&self.jobs);
                        jobs.get_mut(id).map(|j| {
                            j.summary.frames_done += 1;
                            pb::JobEvent {
                                id: id.to_string(),
                                state: j.summary.state,
                                strips_done: j.summary.strips_done,
                                strips_total: j.summary.strips_total,
                                frame: frame as u32,
                                eta_ms: j.summary.eta_ms,
                                ..Default::default()
                            }
                        })
                    };
                    self.save_progress(id).await;
                    *store_ms += stored_at.elapsed().as_secs_f64() * 1e3;
                    if let Some(ev) = ev {
                        let _ = tx.send(ev);
                    }
                }
            }
        }
        Ok(first)
    }

    /// Tone-maps a job's stored frames and writes their PNGs, one frame in
    /// memory at a time. A sequence keeps one exposure (its middle
    /// frame's), so a sun sweep shows the light change rather than the
    /// tone mapper's. Returns each frame's figures and the bytes of all files.
    async fn tone_map(&self, id: &str, n: usize) -> anyhow::Result<(Vec<serde_json::Value>, u64)> {
        let rows = self.store.frames(id).await?;
        anyhow::ensure!(
            rows.len() == n && rows.iter().enumerate().all(|(i, r)| r.frame as usize == i),
            "{} of {n} frames are stored",
            rows.len()
        );
        let state = self.config.state_dir.clone();
        let read = move |r: &crate::store::FrameRow| {
            crate::results::decode_exr(&std::fs::read(state.join(&r.exr))?)
        };
        // A single frame is exposed for itself, below: no frame is read twice.
        let exposure = if n > 1 {
            let (middle, read2) = (rows[n / 2].clone(), read.clone());
            tokio::task::spawn_blocking(move || anyhow::Ok(reinhard(&read2(&middle)?, 0.18).1))
                .await??
        } else {
            Default::default()
        };
        let (mut per_frame, mut total) = (Vec::with_capacity(n), 0u64);
        for row in rows {
            let read = read.clone();
            let png_path = self.config.state_dir.join(row.exr.replace(".exr", ".png"));
            let (row, tone) = tokio::task::spawn_blocking(move || {
                let image = read(&row)?;
                let (ldr, tone) = if n == 1 {
                    reinhard(&image, 0.18)
                } else {
                    (reinhard_like(&image, &exposure), exposure)
                };
                let png = crate::results::encode_png(image.width, image.height, &ldr)?;
                crate::results::write_whole(&png_path, &png)?;
                let row = crate::store::FrameRow {
                    png: row.exr.replace(".exr", ".png"),
                    bytes: row.bytes + png.len() as u64,
                    png_hash: crate::results::hash(&png),
                    ..row
                };
                anyhow::Ok((row, tone))
            })
            .await??;
            let mut figures: serde_json::Value = serde_json::from_str(&row.stats_json)?;
            figures["tone_map"] = serde_json::to_value(tone)?;
            let row = crate::store::FrameRow { stats_json: figures.to_string(), ..row };
            self.store.put_frame(id, &row).await?;
            total += row.bytes;
            per_frame.push(figures);
        }
        Ok((per_frame, total))
    }

    /// Cuts a job's frames into strips for `workers` workers: a frame seen
    /// before by its measured cost (the key it is remembered by is
    /// returned), a new one by the schedule alone; and says which.
    fn plan(
        &self,
        hash: &str,
        frames: &[FrameSettings],
        schedule: ScheduleKind,
        workers: usize,
    ) -> (Vec<Vec<Strip>>, String, &'static str) {
        let frame = frames[0];
        // A frame seen before is cut by its measured cost; a new one by
        // guided self-scheduling alone, whose shrinking strips still let
        // the last ones finish close together.
        let cost_key = format!(
            "{}/{}x{}/{}/{:?}/{:?}",
            hash, frame.width, frame.height, frame.spp, frame.lighting, frame.accel
        );
        let cost = lock(&self.costs).get(&cost_key).cloned().unwrap_or_default();
        let cost_source = if cost.is_empty() {
            "uniform (first frame of this scene and size)"
        } else {
            "measured on the previous frame"
        };
        // A sequence with at least as many frames as workers renders whole
        // frames side by side (no strip is worth cutting); a shorter one
        // cuts each frame for its share of the workers.
        let plans: Vec<Vec<Strip>> = if frames.len() > 1 && frames.len() >= workers {
            vec![vec![(0, frame.width)]; frames.len()]
        } else {
            let plan =
                scheduler(schedule).plan(frame.width, workers.div_ceil(frames.len()).max(1), &cost);
            vec![plan; frames.len()]
        };
        (plans, cost_key, cost_source)
    }

    /// What one event of the farm does to the job: counts, the live view,
    /// the workers' tallies, metrics, and an event for watchers.
    fn on_farm_event(&self, jid: &str, e: FarmEvent, tx: &broadcast::Sender<pb::JobEvent>) {
        let mut ev = self.event(jid);
        ev.state = JobState::Running.to_wire();
        match e {
            FarmEvent::StripDone { frame, worker, ms, bytes, strip, preview } => {
                self.metrics.strip_done(ms / 1e3, bytes);
                if let Some(w) = lock(&self.workers).get_mut(&worker) {
                    w.info.strips_done += 1;
                }
                let mut jobs = lock(&self.jobs);
                if let Some(j) = jobs.get_mut(jid) {
                    j.summary.strips_done += 1;
                    ev.strips_done = j.summary.strips_done;
                    j.estimate();
                    ev.eta_ms = j.summary.eta_ms;
                    j.live.frame = j.live.frame.max(frame);
                    j.live.paint(strip, &preview);
                    j.live.strips.push(LiveStrip {
                        frame,
                        x0: strip.0,
                        x1: strip.1,
                        worker: worker.clone(),
                        ms,
                        error: String::new(),
                    });
                }
                ev.worker = worker;
                ev.strip_ms = ms;
                ev.frame = frame as u32;
            }
            FarmEvent::StripRetried { frame, worker, error, strip } => {
                self.metrics.strip_retried();
                if let Some(w) = lock(&self.workers).get_mut(&worker) {
                    w.info.strips_failed += 1;
                }
                if let Some(j) = lock(&self.jobs).get_mut(jid) {
                    j.summary.retries += 1;
                    j.live.strips.push(LiveStrip {
                        frame,
                        x0: strip.0,
                        x1: strip.1,
                        worker: worker.clone(),
                        ms: 0.0,
                        error: clip(&error),
                    });
                }
                ev.message = format!("strip re-queued from {worker}: {error}");
                ev.frame = frame as u32;
            }
            FarmEvent::BundleSent { bytes, .. } => {
                self.metrics.bundle_sent(bytes);
                return;
            }
            FarmEvent::WorkerDropped { worker, error } => {
                ev.message = format!("worker {worker} dropped: {error}")
            }
            FarmEvent::Planned { strips, kept } => {
                if let Some(j) = lock(&self.jobs).get_mut(jid) {
                    j.summary.strips_done = kept as u32;
                    j.summary.strips_total = (kept + strips) as u32;
                    ev.strips_done = j.summary.strips_done;
                    ev.strips_total = j.summary.strips_total;
                }
            }
            FarmEvent::Stage(s) => {
                if let Some(j) = lock(&self.jobs).get_mut(jid) {
                    j.stage.clone_from(&s);
                    j.summary.stage.clone_from(&s);
                }
                ev.stage = s;
            }
            FarmEvent::PreparedShared(p) => {
                // Not a notice for clients (their `message` is for
                // failures and retries): the job's stats carry it.
                tracing::info!(job = %jid, from = %p.from, to = p.to.len(), bytes = p.bytes, prepare_ms = p.prepare_ms, share_ms = p.share_ms, "scene prepared once and shared");
                return;
            }
        }
        let _ = tx.send(ev);
    }

    /// Remembers a frame's per-column cost (of a frame cut into strips) for
    /// the next frame of the same scene and shape.
    fn remember_cost(&self, key: String, width: u32, times: &[crate::schedule::StripTime]) {
        let mut costs = lock(&self.costs);
        if costs.len() >= 1024 {
            costs.clear();
        }
        if times.len() > 1 {
            costs.insert(key, crate::schedule::column_cost(width, times));
        }
    }
}
