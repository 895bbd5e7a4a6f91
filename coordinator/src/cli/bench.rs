//! `sylva bench …`: benchmarks that print JSON. Speed is reported beside a
//! baseline measured in the same run (GPU against the CPU reference), since
//! the machines are shared and noisy.

use super::lb::{Backend, open_solver};
use super::progress;
use anyhow::bail;
use clap::{Args, Subcommand, ValueEnum};
use serde_json::json;
use std::time::Instant;
use sylva_shared::lb::solver::BYTES_PER_NODE_UPDATE;
use sylva_shared::lb::{GridDims, MediumGrid, NodeClass, Preset, SolveOptions, Sun, solve};
use sylva_shared::rng::SplitMix64;
use sylva_shared::{shapes, voxel};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// The LB solve on the CPU reference and on the GPU, in one run.
    Lb(LbBenchArgs),
}

/// What the benchmark solves.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum BenchMedium {
    /// Every node holds leaf matter of random density: every node collides,
    /// the plain D3Q19 step.
    Dense,
    /// The built-in plant voxelized: mostly empty space, as real models are.
    Plant,
}

#[derive(Debug, Args)]
pub struct LbBenchArgs {
    /// Grid size N (N³ nodes).
    #[arg(long, default_value_t = 64)]
    pub grid: usize,
    /// Medium to solve.
    #[arg(long, value_enum, default_value = "dense")]
    pub medium: BenchMedium,
    /// Backends to run, in order.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "cpu,gpu")]
    pub backends: Vec<Backend>,
    /// Timed repetitions per backend (the median is reported).
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    /// Print JSON (the default output is also JSON; this flag is accepted for scripts).
    #[arg(long)]
    pub json: bool,
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Lb(a) => bench_lb(a),
    }
}

fn bench_medium(kind: BenchMedium, n: usize) -> anyhow::Result<MediumGrid> {
    Ok(match kind {
        BenchMedium::Dense => {
            let dims = GridDims::cube(n);
            let mut rng = SplitMix64::new(42);
            let density = (0..dims.len()).map(|_| 0.05 + 0.95 * rng.next_f32()).collect();
            MediumGrid { dims, density, class: vec![NodeClass::Green; dims.len()] }
        }
        BenchMedium::Plant => voxel::voxelize(&shapes::plant(1), n)?.medium,
    })
}

fn bench_lb(a: LbBenchArgs) -> anyhow::Result<()> {
    if a.grid < 4 {
        bail!("--grid {}: use at least 4", a.grid);
    }
    let medium = bench_medium(a.medium, a.grid)?;
    let params = Preset::Leaf.params();
    let sun = Sun::default();
    let opts = SolveOptions::default();
    let nodes = medium.dims.len() as f64;
    let mut results = Vec::new();
    for &backend in &a.backends {
        let mut solver = open_solver(backend)?;
        // Warm-up: pipeline compilation (lavapipe compiles on first
        // dispatch), allocation, thread-pool start.
        solve(solver.as_mut(), &medium, &params, &sun, &SolveOptions::fixed_steps(8), &|_, _, _| {})?;
        let mut runs = Vec::new();
        for _ in 0..a.repeat.max(1) {
            let bar = progress::lb_bar(&format!("{backend:?}").to_lowercase(), opts.cap(medium.dims));
            let t = Instant::now();
            let s = solve(solver.as_mut(), &medium, &params, &sun, &opts, &progress::lb_callback(&bar))?;
            let wall = t.elapsed().as_secs_f64();
            bar.finish_and_clear();
            runs.push((wall, s));
        }
        runs.sort_by(|x, y| x.0.total_cmp(&y.0));
        let (wall, s) = runs.swap_remove(runs.len() / 2);
        let steps: usize = s.channels.iter().map(|c| c.report.steps).sum();
        let step_ms: f64 = s.channels.iter().map(|c| c.report.phases.ms("steps")).sum();
        let updates = nodes * steps as f64;
        results.push(json!({
            "backend": backend,
            "device": solver.name(),
            "wall_ms": wall * 1e3,
            "steps_per_channel": s.channels.iter().map(|c| c.report.steps).collect::<Vec<_>>(),
            "converged": s.channels.iter().map(|c| c.report.converged).collect::<Vec<_>>(),
            "final_change": s.channels.iter().map(|c| c.report.final_change).collect::<Vec<_>>(),
            "mlups": updates / wall / 1e6,
            "step_mlups": updates / (step_ms / 1e3) / 1e6,
            "ms_per_step": step_ms / steps as f64,
            "bytes_per_second": BYTES_PER_NODE_UPDATE as f64 * updates / (step_ms / 1e3),
            "phases_ms": s.channels.iter().map(|c| &c.report.phases).collect::<Vec<_>>(),
        }));
    }
    let ratio = match (results.iter().find(|r| r["backend"] == "cpu"), results.iter().find(|r| r["backend"] == "gpu")) {
        (Some(c), Some(g)) => json!(g["mlups"].as_f64().unwrap_or(0.0) / c["mlups"].as_f64().unwrap_or(f64::NAN)),
        _ => serde_json::Value::Null,
    };
    let out = json!({
        "benchmark": "lb",
        "grid": a.grid,
        "nodes": nodes,
        "medium": format!("{:?}", a.medium).to_lowercase(),
        "occupancy": medium.occupancy(),
        "preset": "leaf",
        "tolerance": opts.tolerance,
        "max_steps": opts.cap(medium.dims),
        "bytes_per_node_update": BYTES_PER_NODE_UPDATE,
        "machine": machine(),
        "figures": {
            "mlups": "node updates per second over the whole solve of all three channels (set-up, upload, steps, convergence checks, read-back): what a user waits for",
            "step_mlups": "node updates per second over the stepping phase alone",
            "bytes_per_second": "bytes_per_node_update × node updates / stepping time",
        },
        "results": results,
        "gpu_over_cpu": ratio,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

/// The host the benchmark ran on.
fn machine() -> serde_json::Value {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("model name")).map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string()));
    json!({
        "cpu": cpu,
        "threads": std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        "os": std::env::consts::OS,
    })
}
