//! Jobs as clients see them: submit (checked completely before it is
//! queued), watch, fetch the result, cancel, requeue, list and re-prioritise.

use super::live::LiveFrame;
use super::{
    CoordinatorService, EventStream, Job, MAX_NAME, MAX_SUBMITTER, caller, job_id, unix_ms,
};
use crate::access::Caller;
use crate::job_state::{JobState, wire_ended};
use crate::schedule::ScheduleKind;
use crate::store::Store;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::sync::lock;
use sylva_scene::bundle;
use sylva_scene::frame::FrameSettings;
use sylva_scene::sandbox::clip;
use sylva_scene::sequence::{MAX_FRAMES, View};
use tokio::sync::broadcast;
use tokio_stream::StreamExt;
use tonic::{Request, Response, Status, Streaming};

impl CoordinatorService {
    pub(super) async fn submit(
        &self,
        request: Request<Streaming<pb::SubmitChunk>>,
    ) -> Result<Response<pb::JobId>, Status> {
        let remote = request.remote_addr();
        let who = caller(&self.state.access, &request)?;
        let mut stream = request.into_inner();
        let first =
            stream.next().await.ok_or_else(|| Status::invalid_argument("empty submission"))??;
        let spec = first
            .spec
            .ok_or_else(|| Status::invalid_argument("the first message must carry the job spec"))?;
        let (frame, schedule, views) = checked_spec(&spec)?;
        can_denoise(&frame)?;
        // A job is acknowledged only once it is written: while the
        // database refuses writes, it is not taken at all.
        let problem = self.state.store_problem();
        if !problem.is_empty() {
            return Err(Status::unavailable(problem));
        }
        let reserved = self.state.room_for(&frame, views.len().max(1)).await?;
        // A user's job is theirs, whatever name the client sends; on a farm
        // of one token (or none) the client's name and address are shown.
        let from = remote.map(|a| a.ip().to_string()).unwrap_or_else(|| "local".into());
        let submitter = if !who.token_id.is_empty() {
            who.user.clone()
        } else if spec.submitter.is_empty() {
            from
        } else {
            format!("{}@{from}", spec.submitter)
        };
        // The audit names whom the job list shows: with the farm's own
        // token, its holder "admin" and the name and address it came with.
        let actor = match (who.token_id.is_empty(), who.user.is_empty()) {
            (false, _) => who.user.clone(),
            (true, true) => submitter.clone(),
            (true, false) => format!("{} ({submitter})", who.user),
        };
        let hash = first.hash.to_ascii_lowercase();
        if hash.len() != 64 || !hash.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(Status::invalid_argument(format!(
                "hash {:?} is not a 64-digit hex BLAKE3 hash",
                clip(&first.hash)
            )));
        }
        let limit = self.state.config.max_bundle_bytes;
        if first.total_size > limit {
            return Err(Status::resource_exhausted(format!(
                "bundle of {} bytes is over the limit of {limit} bytes",
                first.total_size
            )));
        }
        let bytes = receive_bundle(first.data, first.total_size, &mut stream).await?;
        if bundle::hash_of(&bytes) != hash {
            return Err(Status::invalid_argument("the bundle's bytes do not match its hash"));
        }
        // Check the scene here, so a bad one fails its client, not a worker;
        // its files are unpacked for the check alone and removed after it.
        let seq = self.state.store.next_seq().await.map_err(internal_error)?;
        let id = format!("job-{}-{seq}", self.state.prefix);
        let dir = self.state.config.state_dir.join("check").join(&id);
        let limits = self.state.config.limits;
        let bundle_file = self.state.bundle_path(&hash);
        let checked = tokio::task::spawn_blocking(move || {
            let r = bundle::unpack_with(&bytes, &dir, &limits).map(|_| ());
            let _ = std::fs::remove_dir_all(&dir);
            if let Err(e) = r {
                // The coordinator's own disk failing is not the scene's fault:
                // a client may try again later.
                let e = anyhow::Error::from(e);
                return Err(if out_of_space(&e) { internal_error(e) } else { bad_scene(e) });
            }
            // Kept on disk, not in memory, until the job ends.
            keep_file(&bundle_file, &bytes).map_err(internal_error)
        })
        .await
        .map_err(|_| Status::internal("the scene check failed unexpectedly"))?;
        checked?;
        let job = Job::queued(seq, id, spec, (frame, schedule, views), hash, submitter, reserved);
        let detail = format!("{} frame(s), {}", job.summary.frames, job.summary.name);
        let id = self.enqueue(job, &actor, "submit", &detail).await?;
        Ok(Response::new(pb::JobId { id }))
    }

    /// Writes a new job, then lists it, audits it and wakes the queue: an
    /// acknowledged job survives a crash, since the client hears of it
    /// only after the write.
    async fn enqueue(
        &self,
        job: Job,
        actor: &str,
        action: &str,
        detail: &str,
    ) -> Result<String, Status> {
        let id = job.summary.id.clone();
        self.state.store.insert_job(&job.row()).await.map_err(internal_error)?;
        lock(&self.state.jobs).insert(id.clone(), job);
        self.state.audit(actor, action, &id, detail).await;
        self.state.wake.notify_one();
        tracing::info!(%id, "job queued ({action})");
        Ok(id)
    }

    /// Runs a failed or cancelled job again as a new job, with the scene
    /// bundle it kept and the same settings, priority and submitter; the
    /// old job stays as it ended, for its record.
    pub(super) async fn requeue(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<pb::JobId>, Status> {
        let who = caller(&self.state.access, &request)?;
        let old = job_id(&request.into_inner().id)?.to_string();
        let (spec, hash, submitter) = {
            let mut jobs = lock(&self.state.jobs);
            let j = jobs.get_mut(&old).ok_or_else(|| Status::not_found(format!("no job {old}")))?;
            owner(&who, &old, &j.summary.submitter)?;
            if !j.state.requeueable() {
                return Err(Status::failed_precondition(format!(
                    "job {old} is {}: only a failed or cancelled job is requeued",
                    j.state
                )));
            }
            if j.requeued {
                return Err(Status::failed_precondition(format!("job {old} was requeued already")));
            }
            if !j.kept {
                return Err(Status::failed_precondition(format!(
                    "job {old}'s scene is no longer kept here (only a submitter's latest {} failed or cancelled jobs keep theirs): submit it again",
                    super::KEPT_FOR_REQUEUE
                )));
            }
            // Taken now, under the lock: a second call meanwhile is refused.
            j.requeued = true;
            (j.spec.clone(), j.bundle_hash.clone(), j.summary.submitter.clone())
        };
        let taken = self.requeue_as(&who, &old, spec, hash, submitter).await;
        if taken.is_err()
            && let Some(j) = lock(&self.state.jobs).get_mut(&old)
        {
            j.requeued = false;
        }
        Ok(Response::new(pb::JobId { id: taken? }))
    }

    /// The new job of a requeue of `old`: checked, written and queued.
    async fn requeue_as(
        &self,
        who: &Caller,
        old: &str,
        spec: pb::JobSpec,
        hash: String,
        submitter: String,
    ) -> Result<String, Status> {
        let problem = self.state.store_problem();
        if !problem.is_empty() {
            return Err(Status::unavailable(problem));
        }
        let (frame, schedule, views) = checked_spec(&spec)?;
        can_denoise(&frame)?;
        if !self.state.bundle_path(&hash).is_file() {
            return Err(Status::failed_precondition(format!(
                "job {old}'s scene is no longer kept here: submit it again"
            )));
        }
        let reserved = self.state.room_for(&frame, views.len().max(1)).await?;
        let seq = self.state.store.next_seq().await.map_err(internal_error)?;
        let id = format!("job-{}-{seq}", self.state.prefix);
        let job = Job::queued(seq, id, spec, (frame, schedule, views), hash, submitter, reserved);
        self.enqueue(job, &who.user, "requeue", &format!("runs {old} again")).await
    }

    pub(super) async fn watch(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<EventStream>, Status> {
        let token = caller(&self.state.access, &request)?.token_id;
        let id = request.into_inner().id;
        let id = job_id(&id)?.to_string();
        let (mut rx, current, stage, stats_json) = {
            let jobs = lock(&self.state.jobs);
            let j = jobs.get(&id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            (j.events.subscribe(), j.summary.clone(), j.stage.clone(), j.stats_json.clone())
        };
        let (tx, out) = tokio::sync::mpsc::channel(64);
        let state = self.state.clone();
        tokio::spawn(async move {
            let first = pb::JobEvent {
                id: current.id.clone(),
                state: current.state,
                strips_done: current.strips_done,
                strips_total: current.strips_total,
                message: current.error.clone(),
                stage,
                // A job that ended before its watcher came: its figures
                // now, as the end event carried them.
                stats_json,
                ..Default::default()
            };
            if tx.send(Ok(first)).await.is_err() || wire_ended(current.state) {
                return;
            }
            // A token revoked while its stream is open ends the stream
            // (tokens are re-read every heartbeat; this looks once a second).
            let mut check = tokio::time::interval(Duration::from_secs(1));
            loop {
                let next = tokio::select! {
                    ev = rx.recv() => ev,
                    _ = check.tick() => {
                        if state.access.live(&token) {
                            continue;
                        }
                        let _ = tx.send(Err(Status::unauthenticated("this token was revoked"))).await;
                        break;
                    }
                };
                let ev = match next {
                    Ok(ev) => ev,
                    // A slow watcher missed events: it gets the job's state
                    // now and goes on, rather than a stream that just ends.
                    Err(broadcast::error::RecvError::Lagged(n)) => {
                        let mut ev = state.event(&id);
                        ev.message = format!(
                            "{n} progress events skipped: this client reads slower than strips finish"
                        );
                        if wire_ended(ev.state) {
                            ev.message = lock(&state.jobs)
                                .get(&id)
                                .map(|j| j.summary.error.clone())
                                .unwrap_or_default();
                        }
                        ev
                    }
                    Err(broadcast::error::RecvError::Closed) => break,
                };
                let end = wire_ended(ev.state);
                // A vanished client ends the forwarding.
                if tx.send(Ok(ev)).await.is_err() || end {
                    break;
                }
            }
        });
        Ok(Response::new(Box::pin(tokio_stream::wrappers::ReceiverStream::new(out))))
    }

    pub(super) async fn fetch(
        &self,
        request: Request<pb::FetchRequest>,
    ) -> Result<Response<pb::FetchReply>, Status> {
        let r = request.into_inner();
        let id = job_id(&r.id)?;
        let format = match r.format.as_str() {
            "" | "png" => "png",
            "exr" => "exr",
            o => return Err(Status::invalid_argument(format!("format {:?}: png or exr", clip(o)))),
        };
        {
            let jobs = lock(&self.state.jobs);
            let j = jobs.get(id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            if j.state != JobState::Done {
                return Err(Status::failed_precondition(format!("job {id} is {}", j.state)));
            }
            if r.frame >= j.summary.frames.max(1) {
                return Err(Status::out_of_range(format!(
                    "job {id} has {} frame(s), from 0; no frame {}",
                    j.summary.frames.max(1),
                    r.frame
                )));
            }
        }
        let frames = self.state.store.frames(id).await.map_err(internal_error)?;
        let (rel, want) = frames
            .iter()
            .find(|f| f.frame == r.frame)
            .map(|f| if format == "exr" { (&f.exr, &f.exr_hash) } else { (&f.png, &f.png_hash) })
            .filter(|(p, _)| !p.is_empty())
            .map(|(p, h)| (p.clone(), h.clone()))
            .ok_or_else(|| Status::not_found(format!("job {id}'s result is no longer kept")))?;
        let state = self.state.config.state_dir.clone();
        let data = tokio::task::spawn_blocking(move || {
            crate::results::read_checked(&state, &rel, &want)
        })
        .await
        .map_err(|_| Status::internal("reading the result failed unexpectedly"))?
        .map_err(|fault| {
            tracing::error!(%id, frame = r.frame, format, "a stored result is not served: {fault}");
            Status::data_loss(format!(
                "job {id}'s frame {} ({format}) cannot be served: {fault}",
                r.frame
            ))
        })?;
        Ok(Response::new(pb::FetchReply { data, format: format.into() }))
    }

    pub(super) async fn cancel(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<pb::JobSummary>, Status> {
        let who = caller(&self.state.access, &request)?;
        let id = request.into_inner().id;
        let id = job_id(&id)?;
        let (summary, tx, now) = {
            let mut jobs = lock(&self.state.jobs);
            let j = jobs.get_mut(id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            owner(&who, id, &j.summary.submitter)?;
            let now = j.set_state(JobState::Cancelled).is_ok();
            if now {
                if let Some(t) = j.task.take() {
                    t.abort();
                }
                j.finished = Some(Instant::now());
                j.summary.finished_unix_ms = unix_ms();
                j.live.preview = Vec::new();
            }
            (j.summary.clone(), j.events.clone(), now)
        };
        // A job that had ended already is left as it was: cancelling it
        // again records nothing and tells its watchers nothing.
        if !now {
            return Ok(Response::new(summary));
        }
        if wire_ended(summary.state) {
            tracing::info!(%id, user = %who.user, "job cancelled");
            self.state.ended(id).await;
            self.state.audit(&who.user, "cancel", id, "").await;
        }
        let _ = tx.send(pb::JobEvent {
            id: id.to_string(),
            state: summary.state,
            strips_done: summary.strips_done,
            strips_total: summary.strips_total,
            ..Default::default()
        });
        if wire_ended(summary.state) {
            self.state.close_events(id);
        }
        Ok(Response::new(summary))
    }

    pub(super) async fn jobs(
        &self,
        _: Request<pb::ListJobsRequest>,
    ) -> Result<Response<pb::JobList>, Status> {
        let jobs = lock(&self.state.jobs).values().map(|j| j.summary.clone()).collect();
        Ok(Response::new(pb::JobList { jobs, store_problem: self.state.store_problem() }))
    }

    pub(super) async fn reprioritise(
        &self,
        request: Request<pb::SetPriorityRequest>,
    ) -> Result<Response<pb::JobSummary>, Status> {
        let who = caller(&self.state.access, &request)?;
        let r = request.into_inner();
        let id = job_id(&r.id)?;
        let summary = {
            let mut jobs = lock(&self.state.jobs);
            let j = jobs.get_mut(id).ok_or_else(|| Status::not_found(format!("no job {id}")))?;
            owner(&who, id, &j.summary.submitter)?;
            // An ended job is never queued again: a priority would order nothing.
            if j.state.ended() {
                return Err(Status::failed_precondition(format!(
                    "job {id} is {}: its priority orders nothing any more",
                    j.state
                )));
            }
            j.spec.priority = r.priority;
            j.summary.priority = r.priority;
            j.summary.clone()
        };
        self.state.store.set_priority(id, r.priority).await.map_err(internal_error)?;
        self.state.audit(&who.user, "priority", id, &r.priority.to_string()).await;
        tracing::info!(%id, priority = r.priority, "job re-prioritised");
        Ok(Response::new(summary))
    }
}

/// A job spec's frame, schedule and sequence, each checked, and its name
/// and submitter's sizes: INVALID_ARGUMENT with the reason otherwise.
fn checked_spec(spec: &pb::JobSpec) -> Result<(FrameSettings, ScheduleKind, Vec<View>), Status> {
    let frame = FrameSettings::try_from(
        spec.frame
            .as_ref()
            .ok_or_else(|| Status::invalid_argument("job spec without frame settings"))?,
    )?;
    let schedule = sylva_proto::convert::schedule_from_wire(spec.schedule)?;
    if spec.views.len() > MAX_FRAMES as usize {
        return Err(Status::invalid_argument(format!(
            "a sequence of {} frames: at most {MAX_FRAMES}",
            spec.views.len()
        )));
    }
    let views = spec
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            View::try_from(v)
                .map_err(|e| Status::invalid_argument(format!("frame {i}: {}", e.message())))
        })
        .collect::<Result<Vec<View>, Status>>()?;
    if spec.name.len() > MAX_NAME {
        return Err(Status::invalid_argument(format!(
            "job name of {} bytes: at most {MAX_NAME}",
            spec.name.len()
        )));
    }
    if spec.name.chars().any(super::unprintable) {
        return Err(Status::invalid_argument(
            "job name: no control or bidirectional formatting characters",
        ));
    }
    if spec.submitter.len() > MAX_SUBMITTER || spec.submitter.chars().any(super::unprintable) {
        return Err(Status::invalid_argument(format!(
            "submitter name: at most {MAX_SUBMITTER} bytes, no control or bidirectional formatting characters"
        )));
    }
    Ok((frame, schedule, views))
}

/// The rest of a bundle's bytes, counted as they arrive against the size
/// the client declared (itself within the limit): longer or shorter is
/// refused, and nothing is reserved from the claim.
async fn receive_bundle(
    first: Vec<u8>,
    total_size: u64,
    stream: &mut Streaming<pb::SubmitChunk>,
) -> Result<Vec<u8>, Status> {
    // Counted as the bytes arrive, against the declared size (itself
    // within the limit); nothing is reserved from the claim.
    let mut bytes = first;
    if bytes.len() as u64 > total_size {
        return Err(Status::invalid_argument("upload is longer than its declared size"));
    }
    while let Some(c) = stream.next().await {
        bytes.extend_from_slice(&c?.data);
        if bytes.len() as u64 > total_size {
            return Err(Status::invalid_argument("upload is longer than its declared size"));
        }
    }
    if (bytes.len() as u64) != total_size {
        return Err(Status::invalid_argument(format!(
            "truncated upload: {} of {} bytes",
            bytes.len(),
            total_size
        )));
    }
    Ok(bytes)
}

/// A database or disk failure, as clients see it: the job is not harmed,
/// and nothing of the server's is revealed.
pub(super) fn internal_error(e: anyhow::Error) -> Status {
    tracing::error!("state: {e:#}");
    Status::unavailable(if out_of_space(&e) {
        "the coordinator's disk is full: it cannot take the job now; try again later"
    } else {
        "the coordinator cannot write its state now; try again"
    })
}

/// INVALID_ARGUMENT for a scene that does not pass its check.
fn bad_scene(e: anyhow::Error) -> Status {
    Status::invalid_argument(format!("{e:#}"))
}

/// Whether `e` comes from a full disk or quota (the file system's or
/// the database's).
pub(super) fn out_of_space(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>().is_some_and(|io| {
            matches!(io.kind(), std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded)
        })
    }) || format!("{e:#}").contains("database or disk is full")
}

/// Writes `bytes` to `path` whole or not at all (a file named by its
/// content's hash that exists already is that content).
pub(super) fn keep_file(path: &std::path::Path, bytes: &[u8]) -> anyhow::Result<()> {
    if path.exists() {
        return Ok(());
    }
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d)?;
    }
    let tmp = path.with_extension(format!("part-{}", sylva_proto::auth::random_hex(4)));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)?;
    Ok(())
}

/// The jobs the database holds, as they were; a job that was running is
/// queued again (its frames and strips stay, and it resumes from them),
/// and one whose spec this coordinator cannot read is failed with why.
pub(super) async fn restore(store: &Store) -> anyhow::Result<BTreeMap<String, Job>> {
    use prost::Message;
    let mut out = BTreeMap::new();
    let now = unix_ms();
    for row in store.jobs().await? {
        let mut state = row.state.unwrap_or(JobState::Failed);
        let mut error = row.error.clone();
        let spec = pb::JobSpec::decode(row.spec.as_slice()).unwrap_or_default();
        let (frame, schedule, views) = match checked_spec(&spec) {
            Ok(v) => v,
            Err(e) => {
                if !state.ended() {
                    state = JobState::Failed;
                    error = format!("its spec cannot be read back: {}", e.message());
                }
                (FrameSettings::default(), ScheduleKind::Dynamic, Vec::new())
            }
        };
        if state == JobState::Running {
            // Not a transition of the job's life: the coordinator that ran
            // it is gone, and the job waits for a slot again.
            state = JobState::Queued;
        }
        let summary = pb::JobSummary {
            id: row.id.clone(),
            state: state.to_wire(),
            name: row.name.clone(),
            priority: row.priority,
            submitter: row.submitter.clone(),
            submitted_unix_ms: row.submitted_ms,
            started_unix_ms: row.started_ms,
            finished_unix_ms: row.finished_ms,
            frames: row.frames,
            frames_done: row.frames_done,
            strips_done: row.strips_done,
            strips_total: row.strips_total,
            retries: row.retries,
            error,
            // Live figures, not kept: a resumed job says its stage anew.
            ..Default::default()
        };
        let finished = state.ended().then(|| {
            let ago = Duration::from_millis(now.saturating_sub(row.finished_ms));
            Instant::now().checked_sub(ago).unwrap_or_else(Instant::now)
        });
        let job = Job {
            seq: row.seq,
            state,
            spec,
            frame,
            views,
            schedule,
            bundle_hash: row.bundle_hash.clone(),
            summary,
            events: broadcast::channel(if state.ended() { 1 } else { 256 }).0,
            task: None,
            finished,
            live: LiveFrame::default(),
            stage: String::new(),
            first_strip: None,
            reserved: row.result_bytes,
            stats_json: row.stats_json.clone(),
            kept: true,
            requeued: false,
        };
        if Some(state) != row.state || job.summary.error != row.error {
            store.set_state(&job.row()).await?;
        }
        out.insert(row.id, job);
    }
    Ok(out)
}

/// FAILED_PRECONDITION where `frame` asks to be denoised and this
/// coordinator, which denoises the frames it assembles, cannot: said before
/// the workers render anything. Why it cannot (a path, the loader's words)
/// is for the coordinator's log, not the client.
fn can_denoise(frame: &FrameSettings) -> Result<(), Status> {
    if !frame.denoise.is_on() {
        return Ok(());
    }
    sylva_denoise::available().map_err(|e| {
        tracing::warn!("a job asks to be denoised: {e}");
        Status::failed_precondition(
            "this coordinator cannot denoise: Open Image Denoise is not installed where it runs (its operator: scripts/fetch-oidn.sh and SYLVA_OIDN_LIB)",
        )
    })
}

/// PERMISSION_DENIED unless `who` may act on job `id`, which `submitter`
/// submitted: an admin may act on any, a submitter on their own.
fn owner(who: &Caller, id: &str, submitter: &str) -> Result<(), Status> {
    if who.owns(submitter) {
        return Ok(());
    }
    Err(Status::permission_denied(format!(
        "job {id} is {}'s: a submitter acts on their own jobs only",
        submitter
    )))
}
