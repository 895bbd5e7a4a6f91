//! Writes the database owes: a job's state, progress or figures, or an
//! audit entry, that failed to be written (a full disk, a database server
//! gone) are kept here and written again until they land. The coordinator
//! goes on from memory meanwhile; what it acknowledged before the failure
//! is in the database already (a submission is refused, not acknowledged,
//! when its row cannot be written), so a restart loses nothing that was
//! promised, and what it owes is written as soon as the store takes writes.

use super::State;
use crate::store::AuditRow;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;
use std::time::Duration;
use sylva_proto::sync::lock;

/// Audit entries kept while the database refuses them; beyond this the
/// oldest are dropped and the log says how many.
const MAX_AUDIT: usize = 10_000;

/// What the database has not taken yet.
#[derive(Default)]
pub(super) struct Owed {
    /// Jobs whose state and progress rows are behind memory.
    rows: BTreeSet<String>,
    /// Finished jobs' figures and result bytes.
    stats: BTreeMap<String, (String, u64)>,
    /// Audit entries, oldest first.
    audit: VecDeque<AuditRow>,
    /// Audit entries dropped for want of room.
    dropped: u64,
}

impl Owed {
    /// Whether nothing is owed.
    pub(super) fn is_empty(&self) -> bool {
        self.rows.is_empty() && self.stats.is_empty() && self.audit.is_empty()
    }
}

impl State {
    /// A job's row must be written again.
    pub(super) fn owe_row(&self, id: &str) {
        lock(&self.owed).rows.insert(id.to_string());
    }

    /// A finished job's figures must be written again.
    pub(super) fn owe_stats(&self, id: &str, json: String, bytes: u64) {
        lock(&self.owed).stats.insert(id.to_string(), (json, bytes));
    }

    /// An audit entry must be written again.
    pub(super) fn owe_audit(&self, e: AuditRow) {
        let mut o = lock(&self.owed);
        if o.audit.len() >= MAX_AUDIT {
            o.audit.pop_front();
            o.dropped += 1;
        }
        o.audit.push_back(e);
    }

    /// Writes what is owed, once a second, until the database takes it.
    pub(super) async fn owed_loop(self: Arc<Self>) {
        loop {
            tokio::time::sleep(Duration::from_secs(1)).await;
            if !lock(&self.owed).is_empty() || !self.store.health().ok() {
                self.pay().await;
            }
        }
    }

    /// One pass over what is owed: each write that lands is crossed off;
    /// the first that fails ends the pass (the store is still failing).
    pub(super) async fn pay(&self) {
        let rows: Vec<String> = lock(&self.owed).rows.iter().cloned().collect();
        for id in rows {
            let row = lock(&self.jobs).get(&id).map(super::Job::row);
            if let Some(row) = row
                && (self.store.set_state(&row).await.is_err()
                    || self.store.set_progress(&row).await.is_err())
            {
                return;
            }
            lock(&self.owed).rows.remove(&id);
        }
        let stats: Vec<(String, (String, u64))> =
            lock(&self.owed).stats.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        for (id, (json, bytes)) in stats {
            if self.store.set_stats(&id, &json, bytes).await.is_err() {
                return;
            }
            lock(&self.owed).stats.remove(&id);
        }
        loop {
            let Some(e) = lock(&self.owed).audit.front().cloned() else { break };
            if self.store.audit(&e).await.is_err() {
                return;
            }
            lock(&self.owed).audit.pop_front();
        }
        let dropped = std::mem::take(&mut lock(&self.owed).dropped);
        if dropped > 0 {
            tracing::error!(dropped, "audit entries lost while the database refused writes");
        }
        self.store.probe().await;
    }
}
