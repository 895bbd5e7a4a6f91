//! How a frame is cut into vertical strips for a set of workers.

mod dynamic;
mod r#static;

pub use dynamic::Dynamic;
pub use r#static::Static;

/// A strip: columns `[x0, x1)`.
pub type Strip = (u32, u32);

/// How long one strip took.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StripTime {
    /// The strip.
    pub strip: Strip,
    /// Its render time on the worker, ms.
    pub render_ms: f64,
    /// The whole call as the executor saw it (render plus transfer), ms.
    pub call_ms: f64,
}

pub use sylva_scene::frame::ScheduleKind;

/// Cuts a frame into strips.
pub trait Scheduler {
    /// Strips covering `[0, width)` exactly, in pull order, for `workers`
    /// workers; `column_cost` (ms per column, measured on a frame before)
    /// says where the work is, or is empty when unknown.
    fn plan(&self, width: u32, workers: usize, column_cost: &[f64]) -> Vec<Strip>;
}

/// Per-column cost of a frame from its strips' measured render times
/// (`(strip, ms, …)`), each strip's time spread evenly over its columns;
/// columns no strip covers cost nothing.
pub fn column_cost(width: u32, strips: &[StripTime]) -> Vec<f64> {
    let mut cost = vec![0.0; width as usize];
    for &StripTime { strip: (x0, x1), render_ms: ms, .. } in strips {
        let x1 = x1.min(width);
        if x0 < x1 {
            cost[x0 as usize..x1 as usize].fill(ms / (x1 - x0) as f64);
        }
    }
    cost
}

/// The scheduler of a kind.
pub fn scheduler(kind: ScheduleKind) -> Box<dyn Scheduler + Send + Sync> {
    match kind {
        ScheduleKind::Static => Box::new(Static),
        ScheduleKind::Dynamic => Box::new(Dynamic::default()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn covers(strips: &[Strip], width: u32) -> bool {
        let mut s = strips.to_vec();
        s.sort();
        s.first().map(|f| f.0) == Some(0)
            && s.last().map(|l| l.1) == Some(width)
            && s.windows(2).all(|w| w[0].1 == w[1].0)
            && s.iter().all(|x| x.0 < x.1)
    }

    #[test]
    fn every_plan_covers_the_frame_once() {
        for kind in [ScheduleKind::Static, ScheduleKind::Dynamic] {
            for (w, n) in [(896u32, 1usize), (896, 2), (896, 7), (100, 16), (5, 8), (1, 3)] {
                let p = scheduler(kind).plan(w, n, &[]);
                assert!(covers(&p, w), "{kind:?} {w} {n}: {p:?}");
            }
        }
    }

    /// A frame of measured cost is not cut into strips cheaper than a
    /// call is worth: one worker takes a short frame whole, two split it in
    /// two; a long one is still cut, its strips no cheaper than `min_ms`.
    #[test]
    fn dynamic_strips_are_worth_their_call() {
        let d = Dynamic::default();
        let short = vec![0.1; 896]; // 89.6 ms
        assert_eq!(d.plan(896, 1, &short), vec![(0, 896)]);
        // No cheap strip left at the end either.
        assert_eq!(d.plan(150, 1, &[1.0; 150]), vec![(0, 150)]);
        assert_eq!(d.plan(896, 2, &short), vec![(0, 448), (448, 896)]);
        let long = vec![10.0; 896]; // 8.96 s
        let p = d.plan(896, 1, &long);
        assert!(p.len() > 4, "{p:?}");
        assert!(p.iter().all(|&(a, b)| (b - a) as f64 * 10.0 >= d.min_ms), "{p:?}");
        // Unknown cost: guided self-scheduling alone, so a first frame's
        // preview fills in strip by strip.
        assert!(d.plan(896, 1, &[]).len() > 4);
    }

    #[test]
    fn static_gives_one_equal_strip_per_worker_and_dynamic_more_shrinking_ones() {
        assert_eq!(Static.plan(896, 4, &[]), vec![(0, 224), (224, 448), (448, 672), (672, 896)]);
        let d = Dynamic::default().plan(896, 4, &[]);
        assert!(d.len() > 4);
        let widths: Vec<u32> = d.iter().map(|s| s.1 - s.0).collect();
        assert!(widths.first() > widths.last(), "{widths:?}");
    }

    #[test]
    fn dynamic_strips_follow_the_cost() {
        // All the work in the right half (40 s): the strips there are narrower.
        let cost: Vec<f64> = (0..800).map(|x| if x < 400 { 1.0 } else { 100.0 }).collect();
        let d = Dynamic::default().plan(800, 4, &cost);
        let left = d.iter().filter(|s| s.1 <= 400).count();
        let right = d.iter().filter(|s| s.0 >= 400).count();
        assert!(right > 3 * left.max(1), "left {left}, right {right}: {d:?}");
    }
}
