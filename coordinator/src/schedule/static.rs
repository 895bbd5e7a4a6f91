//! The paper's schedule: one equal strip per worker, no load balancing.

use super::{Scheduler, Strip};

/// N equal strips for N workers.
#[derive(Clone, Copy, Debug, Default)]
pub struct Static;

impl Scheduler for Static {
    fn plan(&self, width: u32, workers: usize, _cost: &[f64]) -> Vec<Strip> {
        let n = (workers.max(1) as u32).min(width.max(1));
        (0..n).map(|i| (i * width / n, (i + 1) * width / n)).filter(|s| s.0 < s.1).collect()
    }
}
