//! What both services share about their state behind locks.

use std::sync::{Mutex, MutexGuard};

/// Locks `m`, whether or not a thread panicked while holding it: the
/// services keep every value behind their locks whole between statements,
/// so one panicking request must not break the service for good.
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}
