//! The queue: queued jobs started best first (priority, then submission
//! order) as running slots free up; a job ended and its resources let go;
//! finished jobs forgotten past their retention.

use super::{State, unix_ms};
use crate::job_state::JobState;
use std::sync::Arc;
use std::time::Instant;
use sylva_proto::sync::lock;
use sylva_scene::sandbox::printable;
use tokio::sync::broadcast;

impl State {
    /// Starts queued jobs, best first, as running slots free up.
    pub(super) async fn schedule_loop(self: Arc<Self>) {
        loop {
            let permit = self.slots.clone().acquire_owned().await.expect("semaphore open");
            let next = loop {
                let pick = {
                    let jobs = lock(&self.jobs);
                    jobs.iter()
                        .filter(|(_, j)| j.state == JobState::Queued)
                        .max_by_key(|(_, j)| (j.spec.priority, std::cmp::Reverse(j.seq)))
                        .map(|(id, _)| id.clone())
                };
                match pick {
                    Some(id) => break id,
                    None => self.wake.notified().await,
                }
            };
            let row = {
                let mut jobs = lock(&self.jobs);
                let j = jobs.get_mut(&next);
                j.and_then(|j| {
                    j.set_state(JobState::Running).ok()?;
                    j.summary.started_unix_ms = unix_ms();
                    Some(j.row())
                })
            };
            if row.is_some() {
                tracing::info!(id = %next, "job started");
            }
            if let Some(row) = row
                && let Err(e) = self.store.set_state(&row).await
            {
                tracing::warn!(id = %next, "the job's start is not written yet: {e:#}");
                self.owe_row(&next);
            }
            let s = self.clone();
            let id = next.clone();
            let handle = tokio::spawn(async move { s.run_job(&id).await });
            if let Some(j) = lock(&self.jobs).get_mut(&next) {
                j.task = Some(handle.abort_handle());
            }
            // Whatever happens to the job's task, its slot comes back and a
            // job left "running" by a panic is failed with the reason.
            let s = self.clone();
            tokio::spawn(async move {
                if let Err(e) = handle.await
                    && e.is_panic()
                {
                    let why = "the coordinator hit an internal error running this job";
                    tracing::error!(id = %next, "job task panicked: {e}");
                    s.finish(&next, JobState::Failed, Some(why.into())).await;
                    let mut ev = s.event(&next);
                    ev.message = why.into();
                    if let Some(tx) = lock(&s.jobs).get(&next).map(|j| j.events.clone()) {
                        let _ = tx.send(ev);
                    }
                    s.close_events(&next);
                }
                drop(permit);
            });
        }
    }

    /// Ends a job: its state and reason, written; its bundle let go.
    pub(super) async fn finish(&self, id: &str, state: JobState, error: Option<String>) {
        {
            let mut jobs = lock(&self.jobs);
            let Some(j) = jobs.get_mut(id) else { return };
            if let Err(e) = j.set_state(state) {
                tracing::debug!(%id, "not ended again: {e}");
                return;
            }
            match &error {
                Some(e) => tracing::warn!(%id, "job {state}: {}", printable(e, 300)),
                None => tracing::info!(%id, "job {state}"),
            }
            if let Some(e) = error {
                j.summary.error = e;
            }
            j.task = None;
            j.finished = Some(Instant::now());
            j.summary.finished_unix_ms = unix_ms();
            j.live.preview = Vec::new();
        }
        self.ended(id).await;
    }

    /// Lets go of a finished job's event channel once its last event is
    /// sent: watchers that come later are answered from its summary, and
    /// the channel's buffer would otherwise stay for the job's retention.
    pub(super) fn close_events(&self, id: &str) {
        if let Some(j) = lock(&self.jobs).get_mut(id) {
            j.events = broadcast::channel(1).0;
        }
    }

    /// Forgets finished jobs past the retention time or beyond the count,
    /// with their results (database rows, then files).
    pub(super) async fn sweep(&self) {
        let r = self.config.retention;
        let gone: Vec<String> = {
            let jobs = lock(&self.jobs);
            let mut finished: Vec<(Instant, String)> =
                jobs.iter().filter_map(|(id, j)| j.finished.map(|t| (t, id.clone()))).collect();
            finished.sort();
            let over = finished.len().saturating_sub(r.max_jobs);
            finished
                .into_iter()
                .enumerate()
                .filter(|(i, (t, _))| *i < over || t.elapsed() > r.keep)
                .map(|(_, (_, id))| id)
                .collect()
        };
        for id in gone {
            if let Err(e) = self.store.delete_job(&id).await {
                tracing::warn!(%id, "not forgotten yet: {e:#}");
                continue;
            }
            let gone = lock(&self.jobs).remove(&id);
            let _ = std::fs::remove_dir_all(crate::results::job_dir(&self.config.state_dir, &id));
            if let Some(j) = gone {
                self.release_bundle(&j.bundle_hash);
            }
        }
    }
}
