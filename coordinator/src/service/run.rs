//! One job run on the farm: planned into strips, rendered by the workers
//! with progress streamed to watchers and the live view, tone mapped,
//! encoded and stored.

use super::*;

impl State {
    pub(super) async fn run_job(self: &Arc<Self>, id: &str) {
        let Some((frame, views, schedule, bundle, tx)) = ({
            let jobs = lock(&self.jobs);
            jobs.get(id).and_then(|j| {
                Some((j.frame, j.views.clone(), j.schedule, j.bundle.clone()?, j.events.clone()))
            })
        }) else {
            return;
        };
        let _ = tx.send(self.event(id));
        let fail = |why: String| {
            self.finish(id, JobState::Failed, Some(why.clone()));
            let mut ev = self.event(id);
            ev.message = why;
            let _ = tx.send(ev);
            self.close_events(id);
        };
        let addrs: Vec<String> = lock(&self.workers)
            .values()
            .filter(|w| w.info.alive)
            .map(|w| w.info.addr.clone())
            .collect();
        if addrs.is_empty() {
            return fail("no worker is registered and alive: start workers with --coordinator, or the coordinator with --workers".into());
        }
        let frames: Vec<FrameSettings> = if views.is_empty() {
            vec![frame]
        } else {
            views.iter().map(|v| FrameSettings { view: *v, ..frame }).collect()
        };
        let (plans, cost_key, cost_source) =
            self.plan(&bundle.hash, &frames, schedule, addrs.len());
        let total: usize = plans.iter().map(Vec::len).sum();
        if let Some(j) = lock(&self.jobs).get_mut(id) {
            j.summary.strips_total = total as u32;
            j.live = LiveFrame {
                width: frame.width,
                height: frame.height,
                frame: 0,
                strips: Vec::new(),
                preview: vec![0; frame.width as usize * frame.height as usize * 3],
            };
        }
        let span = tracing::info_span!("job", %id, frames = frames.len(), strips = total, workers = addrs.len());
        let _g = span.enter();
        let (me, jid, tx2) = (self.clone(), id.to_string(), tx.clone());
        let left: Mutex<Vec<usize>> = Mutex::new(plans.iter().map(Vec::len).collect());
        let started = Instant::now();
        let result = farm::render_frames(
            &Workers {
                addrs: addrs.clone(),
                token: self.config.token.clone(),
                tls: self.config.worker_tls.clone(),
            },
            &bundle,
            &frames,
            plans,
            self.config.strip_deadline,
            move |e| me.on_farm_event(&jid, e, &left, &tx2),
        )
        .await;
        drop(bundle);
        let rendered = match result {
            Ok(f) => f,
            Err(e) => return fail(format!("{e:#}")),
        };
        let encoded = match encode_frames(&rendered).await {
            Ok(e) => e,
            Err(e) => return fail(format!("the frame could not be encoded: {e:#}")),
        };
        let frame_ms = started.elapsed().as_secs_f64() * 1e3;
        self.remember_cost(cost_key, frame.width, &rendered[0]);
        let n = rendered.len();
        let sequence = (!views.is_empty()).then(|| stats::SequenceStats {
            frames: n,
            ms_per_frame: frame_ms / n as f64,
            whole_frames_in_parallel: rendered[0].strip_times.len() == 1,
            per_frame: rendered
                .iter()
                .zip(&encoded)
                .map(|(f, e)| stats::FrameStats::of(f, &e.2, frame_ms / n as f64))
                .collect(),
        });
        let stats = stats::JobStats {
            schedule,
            strip_cost: cost_source,
            frame_ms,
            upload_ms: rendered[0].upload_ms,
            prepared_once: rendered[0].prepared.clone(),
            workers: rendered[0].workers.clone(),
            frame: views
                .is_empty()
                .then(|| stats::FrameStats::of(&rendered[0], &encoded[0].2, frame_ms)),
            sequence,
        };
        let stored = lock(&self.results)
            .put(id, encoded.into_iter().map(|(png, exr, _)| (png, exr)).collect());
        if let Err(e) = stored {
            return fail(format!("the result could not be stored: {e:#}"));
        }
        self.finish(id, JobState::Done, None);
        let mut ev = self.event(id);
        ev.stats_json = serde_json::to_string(&stats).unwrap_or_default();
        let _ = tx.send(ev);
        self.close_events(id);
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
    fn on_farm_event(
        &self,
        jid: &str,
        e: FarmEvent,
        left: &Mutex<Vec<usize>>,
        tx: &broadcast::Sender<pb::JobEvent>,
    ) {
        let mut ev = self.event(jid);
        ev.state = JobState::Running.to_wire();
        match e {
            FarmEvent::StripDone { frame, worker, ms, bytes, strip, preview } => {
                self.metrics.strip_done(ms / 1e3, bytes);
                if let Some(w) = lock(&self.workers).get_mut(&worker) {
                    w.info.strips_done += 1;
                }
                let frame_done = {
                    let mut left = lock(left);
                    left[frame] -= 1;
                    left[frame] == 0
                };
                let mut jobs = lock(&self.jobs);
                if let Some(j) = jobs.get_mut(jid) {
                    j.summary.strips_done += 1;
                    j.summary.frames_done += frame_done as u32;
                    ev.strips_done = j.summary.strips_done;
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
            FarmEvent::Stage(s) => {
                if let Some(j) = lock(&self.jobs).get_mut(jid) {
                    j.stage.clone_from(&s);
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
    fn remember_cost(&self, key: String, width: u32, rendered: &crate::executor::RenderedFrame) {
        let mut costs = lock(&self.costs);
        if costs.len() >= 1024 {
            costs.clear();
        }
        if rendered.strip_times.len() > 1 {
            costs.insert(key, crate::schedule::column_cost(width, &rendered.strip_times));
        }
    }
}

/// Tone-maps and encodes every frame (PNG and EXR), off the async runtime.
async fn encode_frames(
    rendered: &[crate::executor::RenderedFrame],
) -> anyhow::Result<Vec<(Vec<u8>, Vec<u8>, sylva_scene::film::ToneMapStats)>> {
    // Tone mapping and encoding are CPU work: off the async runtime.
    let images: Vec<sylva_scene::film::HdrImage> =
        rendered.iter().map(|f| f.image.clone()).collect();
    // A sequence keeps one exposure (its middle frame's), so a sun
    // sweep shows the light change rather than the tone mapper's.
    tokio::task::spawn_blocking(move || {
        let exposure = reinhard(&images[images.len() / 2], 0.18).1;
        images
            .iter()
            .map(|image| {
                let (ldr, tone) = if images.len() == 1 {
                    reinhard(image, 0.18)
                } else {
                    (reinhard_like(image, &exposure), exposure)
                };
                Ok((encode_png(image.width, image.height, &ldr)?, encode_exr(image)?, tone))
            })
            .collect::<anyhow::Result<Vec<_>>>()
    })
    .await
    .map_err(|e| anyhow::anyhow!("{e}"))?
}

fn encode_png(w: u32, h: u32, px: &[[u8; 3]]) -> anyhow::Result<Vec<u8>> {
    let img = image::RgbImage::from_raw(w, h, px.iter().flatten().copied().collect())
        .ok_or_else(|| anyhow::anyhow!("image size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)?;
    Ok(out.into_inner())
}

fn encode_exr(img: &sylva_scene::film::HdrImage) -> anyhow::Result<Vec<u8>> {
    let flat: Vec<f32> = img.pixels.iter().flatten().copied().collect();
    let buf = image::Rgb32FImage::from_raw(img.width, img.height, flat)
        .ok_or_else(|| anyhow::anyhow!("image size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    image::DynamicImage::ImageRgb32F(buf).write_to(&mut out, image::ImageFormat::OpenExr)?;
    Ok(out.into_inner())
}
