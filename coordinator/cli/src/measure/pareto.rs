//! The time–error chart of `compare` as a Pareto front: every method a
//! curve over its variants (rays, grid, filter), the progressive path
//! tracer a curve over its running time, and the front of the methods no
//! other beats on both: the best method for each time budget.

use crate::measure::chart::{Series, line_chart};
use serde::Serialize;

/// One method (or one moment of the progressive path tracer) on the chart.
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    /// The method.
    pub name: String,
    /// Its curve.
    pub family: String,
    /// Pre-process plus frame, milliseconds.
    pub ms: f64,
    /// Indirect error, raw (bias and noise: what a viewer sees).
    pub raw: f64,
    /// Indirect error net of both images' noise (bias alone); `None` where
    /// it means nothing (the path tracer's own, zero by construction).
    pub net: Option<f64>,
}

/// The points no other point beats on both time and raw error, fastest
/// first: for any budget, the last of them within it is the most accurate
/// method that fits.
pub fn front(points: &[Point]) -> Vec<Point> {
    let mut sorted: Vec<&Point> = points.iter().collect();
    sorted.sort_by(|a, b| a.ms.total_cmp(&b.ms).then(a.raw.total_cmp(&b.raw)));
    let mut best = f64::INFINITY;
    let mut out = Vec::new();
    for p in sorted {
        if p.raw < best {
            best = p.raw;
            out.push(p.clone());
        }
    }
    out
}

/// The most accurate method that fits `budget_ms`, from the front.
pub fn best_within(front: &[Point], budget_ms: f64) -> Option<&Point> {
    front.iter().rev().find(|p| p.ms <= budget_ms)
}

/// The front as lines a person reads: from which time each method is the best.
pub fn describe(front: &[Point]) -> String {
    front
        .iter()
        .map(|p| {
            format!(
                "from {:.1} s: {} ({:.1} % raw indirect error)",
                p.ms / 1e3,
                p.name,
                100.0 * p.raw
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}

const COLORS: [&str; 12] = [
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
    "#bcbd22", "#17becf", "#444444", "#aec7e8",
];

/// Errors above this (percent) are left off the chart so the rest can be read.
const CHART_CEILING: f64 = 120.0;

/// Indirect error (raw, or net when `net`) against log10 of time: a line
/// per family over its variants, and on the raw chart the front, dashed.
pub fn chart(points: &[Point], net: bool) -> String {
    let value = |p: &Point| if net { p.net } else { Some(p.raw) };
    let mut families: Vec<&str> = Vec::new();
    for p in points {
        if !families.contains(&p.family.as_str()) {
            families.push(&p.family);
        }
    }
    let mut left_off = Vec::new();
    let mut series: Vec<Series> = Vec::new();
    for (i, f) in families.iter().enumerate() {
        let mut pts: Vec<(f64, f64)> = Vec::new();
        for p in points.iter().filter(|p| p.family == *f) {
            match value(p) {
                Some(v) if 100.0 * v <= CHART_CEILING => {
                    pts.push((p.ms.max(1.0).log10(), 100.0 * v))
                }
                Some(_) => left_off.push(p.name.clone()),
                None => {}
            }
        }
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        if !pts.is_empty() {
            series.push(Series {
                name: f.to_string(),
                color: COLORS[i % COLORS.len()],
                dashed: false,
                points: pts,
            });
        }
    }
    if !net {
        let pts: Vec<(f64, f64)> = front(points)
            .iter()
            .filter(|p| 100.0 * p.raw <= CHART_CEILING)
            .map(|p| (p.ms.max(1.0).log10(), 100.0 * p.raw))
            .collect();
        series.push(Series {
            name: "Pareto front".into(),
            color: "#000000",
            dashed: true,
            points: pts,
        });
    }
    let hi = series.iter().flat_map(|s| s.points.iter().map(|p| p.0)).fold(1.0f64, f64::max).ceil()
        as i32;
    let ticks: Vec<f64> = (0..=hi).map(f64::from).collect();
    let mut title =
        format!("Indirect error ({}) against time", if net { "net of noise" } else { "raw" });
    if !left_off.is_empty() {
        title += &format!(" — above {CHART_CEILING} %: {}", left_off.join(", "));
    }
    line_chart(
        &title,
        "log10 of pre-process + frame time, ms",
        "indirect error against the reference, %",
        &ticks,
        &series,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(name: &str, ms: f64, raw: f64) -> Point {
        Point { name: name.into(), family: name.into(), ms, raw, net: None }
    }

    #[test]
    fn the_front_keeps_what_nothing_beats_and_picks_the_best_within_a_budget() {
        let pts = [p("a", 10.0, 0.5), p("b", 20.0, 0.6), p("c", 30.0, 0.2), p("d", 5.0, 0.9)];
        let f = front(&pts);
        let names: Vec<&str> = f.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["d", "a", "c"]);
        assert_eq!(best_within(&f, 25.0).unwrap().name, "a");
        assert_eq!(best_within(&f, 30.0).unwrap().name, "c");
        assert!(best_within(&f, 1.0).is_none());
    }
}
