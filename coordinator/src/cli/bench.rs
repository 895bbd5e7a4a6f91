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
    /// Ray traversal (kd-tree and BVH, GPU and CPU) and frame time on the forest.
    Trace(TraceBenchArgs),
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
        BenchCommand::Trace(a) => bench_trace(a),
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

#[derive(Debug, Args)]
pub struct TraceBenchArgs {
    /// Forest scale (instance count multiplier of the paper's Table 2).
    #[arg(long, default_value_t = 0.05)]
    pub scale: f64,
    /// Triangle count multiplier per tree.
    #[arg(long, default_value_t = 1.0)]
    pub triangle_scale: f64,
    /// Frame width.
    #[arg(long, default_value_t = 896)]
    pub width: u32,
    /// Frame height.
    #[arg(long, default_value_t = 448)]
    pub height: u32,
    /// Skip the CPU traversal (slow on big scenes).
    #[arg(long)]
    pub no_cpu: bool,
    /// Print JSON (always JSON; accepted for scripts).
    #[arg(long)]
    pub json: bool,
}

/// Traversal and frame-time benchmark on the forest: Mrays/s of kd-tree
/// against BVH, GPU against CPU, on the same primary rays, then whole frames
/// at 1 and 4 rays per pixel.
fn bench_trace(a: TraceBenchArgs) -> anyhow::Result<()> {
    use sylva_shared::accel::{AccelKind, Ray, SceneAccel};
    use sylva_shared::scene::forest::{ForestOptions, forest};
    use sylva_shared::scene::{LightingMode, Scene};
    use sylva_worker::GpuContext;
    use sylva_worker::prepare::prepare;
    use sylva_worker::trace::{FrameSettings, GpuRay, GpuScene, RayCaster};
    use rayon::prelude::*;

    let file = forest(&ForestOptions { scale: a.scale, triangle_scale: a.triangle_scale, seed: 1 }).map_err(anyhow::Error::msg)?;
    let t = Instant::now();
    let scene = Scene::build(file, std::path::Path::new("."), "forest")?;
    let generate_ms = t.elapsed().as_secs_f64() * 1e3;
    let cam = scene.camera;
    let rays: Vec<Ray> = (0..a.height)
        .flat_map(|y| (0..a.width).map(move |x| (x, y)))
        .map(|(x, y)| Ray::new(cam.position, cam.direction(x as f32 + 0.5, y as f32 + 0.5, a.width, a.height)))
        .collect();
    let gpu_rays: Vec<GpuRay> =
        rays.iter().map(|r| GpuRay { origin: r.origin.to_array(), t_min: 0.0, dir: r.dir.to_array(), t_max: f32::MAX }).collect();
    let ctx = GpuContext::new()?;
    let mut traversal = Vec::new();
    for kind in [AccelKind::Kd, AccelKind::Bvh] {
        let t = Instant::now();
        let accel = SceneAccel::build(&scene, kind);
        let build_ms = t.elapsed().as_secs_f64() * 1e3;
        let cpu = if a.no_cpu {
            serde_json::Value::Null
        } else {
            let t = Instant::now();
            let hits = rays.par_iter().filter(|r| accel.closest(&scene, r, 0.0, f32::MAX).is_some()).count();
            let s = t.elapsed().as_secs_f64();
            json!({ "mrays_per_second": rays.len() as f64 / s / 1e6, "ms": s * 1e3, "hits": hits, "threads": rayon::current_num_threads() })
        };
        let gpu_scene = GpuScene::upload(&ctx, &scene, &accel, &Default::default())?;
        let caster = RayCaster::new(&ctx, &gpu_scene)?;
        caster.cast(&ctx, &gpu_scene, &gpu_rays[..gpu_rays.len().min(4096)])?; // warm-up: lavapipe compiles on first dispatch
        let t = Instant::now();
        let hits = caster.cast(&ctx, &gpu_scene, &gpu_rays)?;
        let s = t.elapsed().as_secs_f64();
        let gpu_hits = hits.iter().filter(|h| h.triangle != u32::MAX).count();
        traversal.push(json!({
            "accel": kind,
            "build_ms": build_ms,
            "bytes": accel.bytes(),
            "cpu": cpu,
            "gpu": { "mrays_per_second": rays.len() as f64 / s / 1e6, "ms": s * 1e3, "hits": gpu_hits },
        }));
    }
    let mut frames = Vec::new();
    for kind in [AccelKind::Kd, AccelKind::Bvh] {
        let prepared = prepare(&ctx, &scene, kind, LightingMode::Lb, &|_| {})?;
        for spp in [1u32, 4] {
            let f = FrameSettings { width: a.width, height: a.height, spp, seed: 1, lighting: LightingMode::Lb, ambient: [0.0; 3], lb_strength: 0.35 };
            prepared.renderer.render_strip(&ctx, &FrameSettings { width: 64, height: 32, ..f }, 0, 64)?; // warm-up
            let t = Instant::now();
            let strip = prepared.renderer.render_strip(&ctx, &f, 0, a.width)?;
            let s = t.elapsed().as_secs_f64();
            frames.push(json!({
                "accel": kind,
                "spp": spp,
                "frame_ms": s * 1e3,
                "rays": strip.rays,
                "mrays_per_second": strip.rays.traced() as f64 / s / 1e6,
                "prepare_ms": prepared.phases,
            }));
        }
    }
    let out = json!({
        "benchmark": "trace",
        "scene": { "scale": a.scale, "triangle_scale": a.triangle_scale, "instances": scene.instances.len(),
                   "triangles_unique": scene.unique_triangles(), "triangles_instanced": scene.instanced_triangles(),
                   "generate_ms": generate_ms },
        "image": [a.width, a.height],
        "adapter": ctx.summary(),
        "machine": machine(),
        "traversal": traversal,
        "frames": frames,
        "figures": {
            "traversal": "closest hits of one primary ray per pixel, the same rays for every structure and machine; GPU time includes upload of the rays and read-back of the hits",
            "frames": "a whole frame rendered as one strip with LB lighting: primary and shadow rays, shading, read-back; after a warm-up dispatch",
        },
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
