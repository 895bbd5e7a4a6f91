//! The simulated farm: strip render times measured one at a time on one
//! device, scheduled onto N virtual workers by the real scheduler code, to
//! predict what N GPUs would do when only one is at hand.

use sylva_coordinator::schedule::Strip;

/// Measured costs of a frame.
#[derive(Clone, Debug)]
pub struct FrameCost {
    /// Render milliseconds per column (from strips rendered one at a time).
    pub column_ms: Vec<f64>,
    /// Milliseconds a strip costs beyond its rendering: RPC and transfer.
    pub per_strip_ms: f64,
    /// Milliseconds to assemble and tone-map the frame, once.
    pub assembly_ms: f64,
}

impl FrameCost {
    /// The cost of one strip.
    pub fn strip_ms(&self, s: Strip) -> f64 {
        self.column_ms[s.0 as usize..s.1 as usize].iter().sum::<f64>() + self.per_strip_ms
    }

    /// Frame time on `workers` virtual workers: strips go, in plan order, to
    /// whichever worker is free first (what pulling from one queue does);
    /// then assembly.
    pub fn frame_ms(&self, plan: &[Strip], workers: usize) -> f64 {
        let mut free_at = vec![0.0f64; workers.max(1)];
        for &s in plan {
            let w = free_at
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(b.1))
                .map(|(i, _)| i)
                .expect("at least one worker");
            free_at[w] += self.strip_ms(s);
        }
        free_at.iter().copied().fold(0.0, f64::max) + self.assembly_ms
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_coordinator::schedule::{Dynamic, Scheduler, Static};

    #[test]
    fn balanced_work_scales_and_skewed_work_favours_the_dynamic_schedule() {
        let flat = FrameCost { column_ms: vec![1.0; 800], per_strip_ms: 0.0, assembly_ms: 0.0 };
        let one = flat.frame_ms(&Static.plan(800, 1, &[]), 1);
        let four = flat.frame_ms(&Static.plan(800, 4, &[]), 4);
        assert!((one / four - 4.0).abs() < 1e-9);
        // All the work on the right: one static strip gets all of it.
        let skew = FrameCost {
            column_ms: (0..800).map(|x| if x >= 600 { 4.0 } else { 0.1 }).collect(),
            per_strip_ms: 0.5,
            assembly_ms: 2.0,
        };
        let st = skew.frame_ms(&Static.plan(800, 4, &[]), 4);
        let dy = skew.frame_ms(&Dynamic::default().plan(800, 4, &skew.column_ms), 4);
        assert!(dy < 0.6 * st, "dynamic {dy} vs static {st}");
    }
}
