//! `--lb-grid auto`: per model, the smallest grid whose light, where the
//! image reads it, the next finer grid does not change by more than a
//! tolerance.

use super::solve_model;
use crate::gpu::GpuContext;
use serde::Serialize;
use sylva_light::lb::LbGrid;
use sylva_scene::Scene;

/// What `--lb-grid auto` chose for one model, and why.
#[derive(Clone, Debug, Serialize)]
pub struct GridChoice {
    /// Model name.
    pub model: String,
    /// The grid chosen.
    pub grid: usize,
    /// Each pair compared: (N, next finer N, relative RMS difference of
    /// the LB light at the model's triangle centres).
    pub compared: Vec<(usize, usize, f64)>,
    /// Why this grid.
    pub reason: String,
    /// Time spent choosing, ms.
    pub ms: f64,
}

/// Picks per model the smallest of `candidates` (ascending) whose LB light,
/// where the image samples it (every triangle's centre), differs from the
/// next finer grid's by less than `tolerance` (relative RMS).
pub fn choose_lb_grids(
    ctx: &GpuContext,
    scene: &Scene,
    candidates: &[usize],
    tolerance: f64,
    progress: &dyn Fn(&str),
) -> anyhow::Result<Vec<GridChoice>> {
    anyhow::ensure!(
        candidates.len() >= 2 && candidates.windows(2).all(|w| w[0] < w[1]),
        "auto grid candidates must be at least two, ascending"
    );
    let mut solver = crate::lb::scene_solver(ctx);
    let mut out = Vec::new();
    for m in &scene.models {
        let t = std::time::Instant::now();
        let pts: Vec<glam::Vec3> = m
            .model
            .triangles
            .iter()
            .map(|t| t.iter().map(|&i| m.model.positions[i as usize]).sum::<glam::Vec3>() / 3.0)
            .collect();
        let light_at = |g: &LbGrid| -> Vec<f32> {
            pts.iter().map(|&p| g.sample(p).iter().sum::<f32>()).collect()
        };
        progress(&format!("choosing the LB grid of {} ({}³)", m.name, candidates[0]));
        let mut coarse = light_at(&solve_model(solver.as_mut(), scene, m, candidates[0])?.0);
        let mut compared = Vec::new();
        let mut chosen = None;
        for w in candidates.windows(2) {
            progress(&format!("choosing the LB grid of {} ({}³)", m.name, w[1]));
            let fine = light_at(&solve_model(solver.as_mut(), scene, m, w[1])?.0);
            let num: f64 = coarse.iter().zip(&fine).map(|(a, b)| ((a - b) as f64).powi(2)).sum();
            let den: f64 = fine.iter().map(|b| (*b as f64).powi(2)).sum();
            let diff = if den > 0.0 { (num / den).sqrt() } else { 0.0 };
            compared.push((w[0], w[1], diff));
            if diff < tolerance {
                chosen = Some((
                    w[0],
                    format!(
                        "{}³ differs from {}³ by {:.1} % < {:.1} %",
                        w[0],
                        w[1],
                        100.0 * diff,
                        100.0 * tolerance
                    ),
                ));
                break;
            }
            coarse = fine;
        }
        let last = *candidates.last().expect("two or more");
        let (grid, reason) = chosen.unwrap_or((
            last,
            format!(
                "no grid up to {last}³ agreed with the next within {:.1} %: the finest was used",
                100.0 * tolerance
            ),
        ));
        out.push(GridChoice {
            model: m.name.clone(),
            grid,
            compared,
            reason,
            ms: t.elapsed().as_secs_f64() * 1e3,
        });
    }
    Ok(out)
}
