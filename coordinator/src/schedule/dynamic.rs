//! Guided self-scheduling: strips are pulled by whichever worker is idle;
//! each takes a share of the remaining cost that shrinks as the frame
//! fills, so the last strips are small and finish together.

use super::{Scheduler, Strip};

/// The dynamic scheduler.
#[derive(Clone, Copy, Debug)]
pub struct Dynamic {
    /// Each strip takes the remaining cost over `share × workers`.
    pub share: f64,
    /// Narrowest strip, in columns.
    pub min_width: u32,
    /// Cheapest strip, ms, where the cost is measured (and no more than a
    /// worker's share of the frame): each strip is a call, which cost
    /// about 21 ms beside the render on lavapipe (`sylva bench farm`:
    /// docs/farm-overhead.md), so a strip several times that is mostly
    /// render.
    pub min_ms: f64,
}

impl Default for Dynamic {
    fn default() -> Self {
        Self { share: 2.0, min_width: 8, min_ms: 100.0 }
    }
}

impl Scheduler for Dynamic {
    fn plan(&self, width: u32, workers: usize, column_cost: &[f64]) -> Vec<Strip> {
        let uniform;
        let measured = column_cost.len() == width as usize
            && column_cost.iter().all(|c| c.is_finite() && *c >= 0.0)
            && column_cost.iter().sum::<f64>() > 0.0;
        let cost: &[f64] = if measured {
            column_cost
        } else {
            uniform = vec![1.0; width as usize];
            &uniform
        };
        let mut remaining: f64 = cost.iter().sum();
        // A frame of known cost is not cut finer than `min_ms` a strip, nor
        // (for a short one) finer than a strip per worker: one worker
        // takes a 90 ms frame whole instead of in 7 calls. A frame seen
        // for the first time is cut by the schedule alone, so its preview
        // fills in as it renders.
        let floor = if measured { self.min_ms.min(remaining / workers.max(1) as f64) } else { 0.0 };
        let mut strips = Vec::new();
        let mut x = 0u32;
        while x < width {
            let target = (remaining / (self.share * workers.max(1) as f64)).max(floor);
            let mut end = x;
            let mut taken = 0.0;
            while end < width && (taken < target || end - x < self.min_width) {
                taken += cost[end as usize];
                end += 1;
            }
            // Do not leave a sliver narrower than the minimum behind, nor
            // a last strip cheaper than the floor (by more than rounding:
            // a frame split evenly leaves exactly the floor).
            let tail = remaining - taken;
            if width - end < self.min_width || (end < width && tail < floor * (1.0 - 1e-6)) {
                end = width;
                taken = remaining;
            }
            strips.push((x, end));
            remaining -= taken;
            x = end;
        }
        strips
    }
}
