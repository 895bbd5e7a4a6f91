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
}

impl Default for Dynamic {
    fn default() -> Self {
        Self { share: 2.0, min_width: 8 }
    }
}

impl Scheduler for Dynamic {
    fn plan(&self, width: u32, workers: usize, column_cost: &[f64]) -> Vec<Strip> {
        // One worker has no one to finish together with: every strip more
        // is a call more (7 strips cost a 896-wide frame 130 ms of calls
        // on lavapipe, `sylva bench farm`), and a cancel stops a strip
        // within its first piece anyway.
        if workers <= 1 {
            return vec![(0, width)];
        }
        let uniform;
        let cost: &[f64] = if column_cost.len() == width as usize
            && column_cost.iter().all(|c| c.is_finite() && *c >= 0.0)
            && column_cost.iter().sum::<f64>() > 0.0
        {
            column_cost
        } else {
            uniform = vec![1.0; width as usize];
            &uniform
        };
        let mut remaining: f64 = cost.iter().sum();
        let mut strips = Vec::new();
        let mut x = 0u32;
        while x < width {
            let target = remaining / (self.share * workers.max(1) as f64);
            let mut end = x;
            let mut taken = 0.0;
            while end < width && (taken < target || end - x < self.min_width) {
                taken += cost[end as usize];
                end += 1;
            }
            // Do not leave a sliver narrower than the minimum behind.
            if width - end < self.min_width {
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
