//! `sylva bench …`: benchmarks that print JSON. Speed is reported beside a
//! baseline measured in the same run (GPU against the CPU reference), since
//! the machines are shared and noisy.

use crate::flags::bench::*;
use crate::in_process::InProcess;
use crate::lb::open_solver;
use crate::progress;
use anyhow::bail;
use serde_json::json;
use std::time::Instant;
use sylva_coordinator::executor::StripExecutor;
use sylva_light::lb::LbParams;
use sylva_light::lb::solver::BYTES_PER_NODE_UPDATE;
use sylva_light::lb::{GridDims, MediumGrid, NodeClass, SolveOptions, Sun, solve};
use sylva_light::{shapes, voxel};
use sylva_scene::format::Preset;
use sylva_scene::frame::FrameSettings;
use sylva_scene::rng::SplitMix64;

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Lb(a) => bench_lb(a),
        BenchCommand::Trace(a) => bench_trace(a),
        BenchCommand::Scaling(a) => bench_scaling(a),
        BenchCommand::Sequence(a) => super::bench_sequence::run(a),
        BenchCommand::Farm(a) => super::bench_farm::run(a),
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
    let params = LbParams::from_preset(Preset::Leaf);
    let sun = Sun::default();
    let opts = SolveOptions::default();
    let nodes = medium.dims.len() as f64;
    // The machine is shared: the triad is measured before and after the
    // solves and the higher figure kept, so a busy moment cannot flatter
    // the fraction.
    let mut triad = stream_triad();
    let mut results = Vec::new();
    for &backend in &a.backends {
        let mut solver = open_solver(backend)?;
        // Warm-up: pipeline compilation (lavapipe compiles on first
        // dispatch), allocation, thread-pool start.
        solve(
            solver.as_mut(),
            &medium,
            &params,
            &sun,
            &SolveOptions::fixed_steps(8),
            &|_, _, _| {},
        )?;
        let mut runs = Vec::new();
        for _ in 0..a.repeat.max(1) {
            let bar =
                progress::lb_bar(&format!("{backend:?}").to_lowercase(), opts.cap(medium.dims));
            let t = Instant::now();
            let s = solve(
                solver.as_mut(),
                &medium,
                &params,
                &sun,
                &opts,
                &progress::lb_callback(&bar),
            )?;
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
    triad = triad.max(stream_triad());
    for r in &mut results {
        r["fraction_of_triad"] = json!(r["bytes_per_second"].as_f64().unwrap_or(0.0) / triad);
    }
    let ratio = match (
        results.iter().find(|r| r["backend"] == "cpu"),
        results.iter().find(|r| r["backend"] == "gpu"),
    ) {
        (Some(c), Some(g)) => {
            json!(g["mlups"].as_f64().unwrap_or(0.0) / c["mlups"].as_f64().unwrap_or(f64::NAN))
        }
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
        "triad_bytes_per_second": triad,
        "machine": machine(),
        "figures": {
            "mlups": "node updates per second over the whole solve of all three channels (set-up, upload, steps, convergence checks, read-back): what a user waits for",
            "step_mlups": "node updates per second over the stepping phase alone",
            "bytes_per_second": "bytes_per_node_update × node updates / stepping time",
            "triad_bytes_per_second": "a[i] = b[i] + s·c[i] over three 32 MiB f32 arrays on every thread, best of 8 before the solves and 8 after, counting 12 bytes per element as STREAM does",
            "fraction_of_triad": "each backend's bytes_per_second over triad_bytes_per_second: 1 is bound by this machine's memory",
        },
        "results": results,
        "gpu_over_cpu": ratio,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

/// Every instance's triangles a ray can hit (fully cut ones left out,
/// alpha otherwise ignored: Embree's opaque baseline), in world space.
fn flattened(scene: &sylva_scene::Scene) -> Vec<[glam::Vec3; 3]> {
    use sylva_accel::coverage::{Coverage, triangle_coverage};
    let coverage: Vec<Vec<Coverage>> =
        scene.models.iter().map(|m| triangle_coverage(&m.model)).collect();
    let mut tris = Vec::new();
    for inst in &scene.instances {
        let m = &scene.models[inst.model as usize].model;
        for t in
            (0..m.triangle_count()).filter(|&t| coverage[inst.model as usize][t] != Coverage::Cut)
        {
            tris.push(m.triangle(t).map(|p| inst.to_world.transform_point3(p)));
        }
    }
    tris
}

/// Writes the rays and the flattened triangles for `benchmarks/embree.py`.
fn export_rays(
    dir: &std::path::Path,
    rays: &[sylva_accel::Ray],
    tris: &[[glam::Vec3; 3]],
) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)?;
    let r: Vec<f32> =
        rays.iter().flat_map(|r| r.origin.to_array().into_iter().chain(r.dir.to_array())).collect();
    sylva_light::npy::write_f32(&dir.join("rays.npy"), &[rays.len() as u64, 6], &r)?;
    let t: Vec<f32> = tris.iter().flatten().flat_map(|p| p.to_array()).collect();
    sylva_light::npy::write_f32(&dir.join("triangles.npy"), &[tris.len() as u64, 3, 3], &t)?;
    Ok(())
}

/// Closest hits of `rays` on the CPU BVH built over `tris` as one level,
/// every triangle opaque: Sylva's traversal in Embree's setup.
fn flat_opaque(tris: &[[glam::Vec3; 3]], rays: &[sylva_accel::Ray]) -> serde_json::Value {
    use rayon::prelude::*;
    use sylva_accel::coverage::OPAQUE;
    use sylva_accel::triangle::TriangleRecord;
    use sylva_accel::{Aabb, Bvh};
    let t = Instant::now();
    let bounds: Vec<Aabb> = tris.iter().map(|t| Aabb::around(t)).collect();
    let bvh = Bvh::build(&bounds);
    let records: Vec<TriangleRecord> =
        bvh.prims.iter().map(|&p| TriangleRecord::new(p, tris[p as usize], OPAQUE, 0)).collect();
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    // Best of three, as benchmarks/embree.py times Embree.
    let (mut s, mut hits) = (f64::INFINITY, 0);
    for _ in 0..3 {
        let t = Instant::now();
        hits = rays
            .par_iter()
            .filter(|ray| {
                let ahead = |first: u32| sylva_accel::bvh::prefetch(&records[first as usize]);
                let walked =
                    bvh.walk_from((0, 0), ray, 0.0, f32::MAX, ahead, |first, count, limit| {
                        let mut closest = limit;
                        for r in &records[first as usize..(first + count) as usize] {
                            if let Some((t, _, _)) = r.intersect(ray, 0.0, closest) {
                                closest = t;
                            }
                        }
                        (closest < limit).then_some(closest)
                    });
                walked < f32::MAX
            })
            .count();
        s = s.min(t.elapsed().as_secs_f64());
    }
    let bytes =
        bvh.nodes.len() * size_of::<sylva_accel::BvhNode>() + size_of_val(records.as_slice());
    json!({ "mrays_per_second": rays.len() as f64 / s / 1e6, "ms": s * 1e3, "hits": hits, "threads": rayon::current_num_threads(),
            "triangles": tris.len(), "build_ms": build_ms, "bytes": bytes })
}

/// Bytes per second of a STREAM-style triad on all threads (best of 8).
fn stream_triad() -> f64 {
    use rayon::prelude::*;
    const N: usize = 8 << 20;
    const CHUNK: usize = 1 << 16;
    let b = vec![1.0f32; N];
    let c = vec![2.0f32; N];
    let mut a = vec![0.0f32; N];
    let mut best = f64::INFINITY;
    for rep in 0..8 {
        let s = 0.5 + rep as f32;
        let t = Instant::now();
        a.par_chunks_mut(CHUNK).zip(b.par_chunks(CHUNK)).zip(c.par_chunks(CHUNK)).for_each(
            |((a, b), c)| {
                for i in 0..a.len() {
                    a[i] = b[i] + s * c[i];
                }
            },
        );
        best = best.min(t.elapsed().as_secs_f64());
        std::hint::black_box(&a);
    }
    (12 * N) as f64 / best
}

/// The host the benchmark ran on.
pub(super) fn machine() -> serde_json::Value {
    let cpu = std::fs::read_to_string("/proc/cpuinfo").ok().and_then(|s| {
        s.lines()
            .find(|l| l.starts_with("model name"))
            .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
    });
    json!({
        "cpu": cpu,
        "threads": std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        "os": std::env::consts::OS,
    })
}

/// Traversal and frame-time benchmark on the forest: Mrays/s of kd-tree
/// against BVH, GPU against CPU, on the same primary rays, then whole frames
/// at 1 and 4 rays per pixel.
fn bench_trace(a: TraceBenchArgs) -> anyhow::Result<()> {
    use sylva_accel::Ray;
    use sylva_scene::Scene;
    use sylva_scene::table2::{ForestOptions, forest};
    use sylva_worker::trace::{GpuRay, Tracer};

    let file = forest(&ForestOptions { scale: a.scale, triangle_scale: a.triangle_scale, seed: 1 })
        .map_err(anyhow::Error::msg)?;
    let t = Instant::now();
    let scene = Scene::build(file, std::path::Path::new("."), "forest")?;
    let generate_ms = t.elapsed().as_secs_f64() * 1e3;
    let cam = scene.camera;
    let rays: Vec<Ray> = (0..a.height)
        .flat_map(|y| (0..a.width).map(move |x| (x, y)))
        .map(|(x, y)| {
            Ray::new(cam.position, cam.direction(x as f32 + 0.5, y as f32 + 0.5, a.width, a.height))
        })
        .collect();
    let gpu_rays: Vec<GpuRay> = rays
        .iter()
        .map(|r| GpuRay {
            origin: r.origin.to_array(),
            t_min: 0.0,
            dir: r.dir.to_array(),
            t_max: f32::MAX,
        })
        .collect();
    let flat = if a.export.is_some() || a.flat { flattened(&scene) } else { Vec::new() };
    if let Some(dir) = &a.export {
        export_rays(dir, &rays, &flat)?;
    }
    let cpu_flat_opaque = if a.flat { flat_opaque(&flat, &rays) } else { serde_json::Value::Null };
    drop(flat);
    let ctx = Tracer::new()?;
    let mut traversal = Vec::new();
    // Shadow rays toward the sun from the first structure's primary hits:
    // the same rays for every structure.
    let mut shadow: Option<SecondRays> = None;
    let backends = measurable(&ctx, &a.accel);
    for &backend in &backends {
        traversal.push(trace_structure(
            &ctx,
            &scene,
            backend,
            &rays,
            &gpu_rays,
            &mut shadow,
            a.no_cpu,
            a.kernel_rays,
        )?);
    }
    // Ray-query frames on a CPU adapter take minutes each: by default
    // they are left out there, and the output says so.
    let (frame_backends, frames_left_out) = match &a.frames_accel {
        Some(f) => (measurable(&ctx, f), None),
        None if ctx.is_cpu() && backends.contains(&sylva_scene::frame::Backend::Rq) => (
            backends.iter().copied().filter(|b| *b != sylva_scene::frame::Backend::Rq).collect(),
            Some(
                "rq: ray-query frames take minutes each on a CPU adapter (--frames-accel rq to render them)",
            ),
        ),
        None => (backends.clone(), None),
    };
    if let Some(why) = frames_left_out {
        tracing::info!("frames left out: {why}");
    }
    let frames =
        if a.no_frames { Vec::new() } else { bench_frames(&ctx, &scene, &a, &frame_backends)? };
    let first_frame =
        if a.no_first_frame { serde_json::Value::Null } else { bench_first_frame(&a)? };
    let out = json!({
        "benchmark": "trace",
        "scene": { "scale": a.scale, "triangle_scale": a.triangle_scale, "instances": scene.instances.len(),
                   "triangles_unique": scene.unique_triangles(), "triangles_instanced": scene.instanced_triangles(),
                   "generate_ms": generate_ms },
        "image": [a.width, a.height],
        "adapter": ctx.summary(),
        "machine": machine(),
        "traversal": traversal,
        "cpu_flat_opaque": cpu_flat_opaque,
        "frames": frames,
        "frames_left_out": frames_left_out,
        "first_frame": first_frame,
        "figures": {
            "traversal": "closest hits of one primary ray per pixel, the same rays for every structure and machine; GPU time includes upload of the rays and read-back of the hits",
            "kernel": "per ray kind (camera: closest hits of the primary rays; shadow: any hit toward the sun from each primary hit; bounce: closest hits of one diffuse bounce from each primary hit, cosine-distributed about the way back to the camera, as the leaves are two-sided), the traversal kernel alone as the GPU's timestamp queries measure it: the kind's rays cast again and again in one compute pass, at least --kernel-rays rays, no upload or read-back; null where the adapter has no timestamps",
            "cpu_flat_opaque": "with --flat: the CPU BVH built over every instance's triangles flattened to world space as one level, opaque: the same triangles and rays benchmarks/embree.py gives Embree",
            "cpu_opaque": "the CPU's closest hits on the same rays with every triangle opaque (no alpha test), as the Embree baseline of benchmarks/embree.py traces them",
            "shadow": "one shadow ray toward the sun from each primary hit, stopping at the first opaque hit; the same rays for every structure",
            "bytes_per_triangle": "nodes, primitive lists and triangle records of both levels over the scene's unique triangles; for rq, the device's BLASes (compacted) and TLAS as its memory allocator reports them",
            "build_ms": "the CPU's structures (for rq, each triangle's coverage class) plus, for rq, the device's build and compaction",
            "frames": "a whole frame rendered as one strip with LB lighting: primary and shadow rays, shading, read-back; after a warm-up dispatch",
            "first_frame": "`sylva render --local-workers 0 --accel auto` of the same forest at 1 spp with LB lighting, in a process of its own: cold (an empty prepared-data cache) and then warm (a restart that finds the cache). scene_to_frame_ms is the process's load, preparation and tracing (its phases); wall_ms adds starting, opening the GPU, tone mapping and writing the PNG. The targets: cold at most 2 × the frame's trace plus its upload, warm at most the trace plus the upload",
        },
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

/// The asked backends this adapter can run: ray queries only where it
/// has them (said on stderr where it has not).
fn measurable(
    ctx: &sylva_worker::GpuContext,
    asked: &[sylva_scene::frame::Backend],
) -> Vec<sylva_scene::frame::Backend> {
    use sylva_scene::frame::Backend;
    asked
        .iter()
        .copied()
        .filter(|&b| {
            // A benchmark measures a backend: `auto` is a worker's choice among them.
            if b == Backend::Auto {
                eprintln!("auto left out: it measures the others and takes one");
                return false;
            }
            let runs = b != Backend::Rq || ctx.has_ray_queries();
            if !runs {
                eprintln!("rq left out: {} offers no ray queries", ctx.adapter_name());
            }
            runs
        })
        .collect()
}

/// Rays from the first backend's primary hits, the same for every
/// backend: toward the sun (CPU and GPU twins), and one diffuse bounce.
struct SecondRays {
    shadow_cpu: Vec<sylva_accel::Ray>,
    shadow_gpu: Vec<sylva_worker::trace::GpuRay>,
    bounce: Vec<sylva_worker::trace::GpuRay>,
}

/// One diffuse bounce from each primary hit: cosine-distributed about the
/// way back to the camera (the leaves are two-sided, so the side a camera
/// ray meets faces it), from two numbers of a generator seeded by the
/// ray's index, so every run and backend casts the same rays.
fn bounce_rays(
    rays: &[sylva_accel::Ray],
    hits: &[sylva_worker::trace::GpuHit],
) -> Vec<sylva_worker::trace::GpuRay> {
    rays.iter()
        .zip(hits)
        .enumerate()
        .filter(|(_, (_, h))| h.triangle != u32::MAX)
        .map(|(i, (r, h))| {
            let n = -r.dir.normalize();
            let mut rng = sylva_scene::rng::SplitMix64::new(i as u64);
            let (u1, u2) = (rng.next_f32(), rng.next_f32());
            let (phi, s) = (std::f32::consts::TAU * u1, u2.sqrt());
            let (x, y) = n.any_orthonormal_pair();
            let dir = x * (s * phi.cos()) + y * (s * phi.sin()) + n * (1.0 - u2).max(0.0).sqrt();
            sylva_worker::trace::GpuRay {
                origin: r.at(h.t).to_array(),
                t_min: 1e-3,
                dir: dir.to_array(),
                t_max: f32::MAX,
            }
        })
        .collect()
}

/// One backend's traversal figures: build, bytes, GPU and (unless
/// `no_cpu`, and but for ray queries, which have no CPU twin) CPU closest
/// hits, and shadow and bounce rays from the first backend's primary
/// hits (kept in `second`, so every backend traces the same rays); and
/// each kind's kernel time as the GPU measures it, over at least
/// `kernel_rays` rays.
#[allow(clippy::too_many_arguments)]
fn trace_structure(
    ctx: &sylva_worker::GpuContext,
    scene: &sylva_scene::Scene,
    backend: sylva_scene::frame::Backend,
    rays: &[sylva_accel::Ray],
    gpu_rays: &[sylva_worker::trace::GpuRay],
    second: &mut Option<SecondRays>,
    no_cpu: bool,
    kernel_rays: u64,
) -> anyhow::Result<serde_json::Value> {
    use rayon::prelude::*;
    use sylva_accel::{Ray, SceneAccel};
    use sylva_worker::trace::{GpuRay, GpuScene, RayCaster, SceneStructure};
    let t = Instant::now();
    let (accel, coverage) = match backend.structure() {
        Some(kind) => (Some(SceneAccel::build(scene, kind)), Vec::new()),
        None => (
            None,
            scene
                .models
                .par_iter()
                .map(|m| sylva_accel::coverage::triangle_coverage(&m.model))
                .collect(),
        ),
    };
    let structure = match &accel {
        Some(a) if backend == sylva_scene::frame::Backend::Cwbvh => SceneStructure::Cwbvh(a),
        Some(a) => SceneStructure::Walk(a),
        None => SceneStructure::RayQuery(&coverage),
    };
    let cpu_build_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let gpu_scene = GpuScene::upload(ctx, scene, structure, &Default::default())?;
    let upload_ms = t.elapsed().as_secs_f64() * 1e3;
    // Ray queries: the device builds (and compacts) during the upload.
    let device_build_ms = gpu_scene.rq.as_ref().map_or(0.0, |r| r.build_seconds * 1e3);
    let build_ms = cpu_build_ms + device_build_ms;
    let built_bytes = gpu_scene.rq.as_ref().and_then(|r| r.built_bytes);
    let bytes = match (&accel, &gpu_scene.rq) {
        (Some(a), _) if backend == sylva_scene::frame::Backend::Cwbvh => {
            Some(sylva_accel::cwbvh::CwbvhScene::from_accel(scene, a)?.bytes() as u64)
        }
        (Some(a), _) => Some(a.bytes() as u64),
        (None, Some(rq)) => rq.bytes,
        (None, None) => None,
    };
    let caster = RayCaster::new(ctx, &gpu_scene)?;
    caster.cast(ctx, &gpu_scene, &gpu_rays[..gpu_rays.len().min(4096)])?; // warm-up: lavapipe compiles on first dispatch
    let t = Instant::now();
    let hits = caster.cast(ctx, &gpu_scene, gpu_rays)?;
    let s = t.elapsed().as_secs_f64();
    let gpu_hits = hits.iter().filter(|h| h.triangle != u32::MAX).count();
    let gpu =
        json!({ "mrays_per_second": rays.len() as f64 / s / 1e6, "ms": s * 1e3, "hits": gpu_hits });
    let SecondRays { shadow_cpu, shadow_gpu, bounce } = second.get_or_insert_with(|| {
        let towards = scene.sun.towards;
        let cpu: Vec<Ray> = rays
            .iter()
            .zip(&hits)
            .filter(|(_, h)| h.triangle != u32::MAX)
            .map(|(r, h)| Ray::new(r.at(h.t), towards))
            .collect();
        let gpu = cpu
            .iter()
            .map(|r| GpuRay {
                origin: r.origin.to_array(),
                t_min: 1e-3,
                dir: r.dir.to_array(),
                t_max: f32::MAX,
            })
            .collect();
        SecondRays { shadow_cpu: cpu, shadow_gpu: gpu, bounce: bounce_rays(rays, &hits) }
    });
    let shadow_caster = RayCaster::shadow(ctx, &gpu_scene)?;
    shadow_caster.cast(ctx, &gpu_scene, &shadow_gpu[..shadow_gpu.len().min(4096)])?;
    let t = Instant::now();
    let blocked = shadow_caster.cast(ctx, &gpu_scene, shadow_gpu)?;
    let s = t.elapsed().as_secs_f64();
    let gpu_shadow = json!({ "mrays_per_second": shadow_gpu.len() as f64 / s / 1e6, "ms": s * 1e3,
                             "blocked": blocked.iter().filter(|h| h.triangle != u32::MAX).count() });
    let t = Instant::now();
    let bounced = caster.cast(ctx, &gpu_scene, bounce)?;
    let s = t.elapsed().as_secs_f64();
    let gpu_bounce = json!({ "mrays_per_second": bounce.len() as f64 / s / 1e6, "ms": s * 1e3,
                             "hits": bounced.iter().filter(|h| h.triangle != u32::MAX).count() });
    // The kernel alone, timed by the GPU, per ray kind.
    let timed = |c: &RayCaster, r: &[GpuRay]| -> anyhow::Result<serde_json::Value> {
        Ok(match c.kernel_time(ctx, &gpu_scene, r, kernel_rays)? {
            Some(k) => json!({ "mrays_per_second": k.mrays_per_second(), "rays": k.rays,
                               "ms": k.seconds * 1e3, "batch": r.len() }),
            None => serde_json::Value::Null,
        })
    };
    let kernel = json!({
        "camera": timed(&caster, gpu_rays)?,
        "shadow": timed(&shadow_caster, shadow_gpu)?,
        "bounce": timed(&caster, bounce)?,
    });
    // The compressed wide BVH's CPU walk is a test reference, not a renderer.
    let no_cpu = no_cpu || backend == sylva_scene::frame::Backend::Cwbvh;
    let (cpu, cpu_opaque, cpu_shadow) = if let (false, Some(accel)) = (no_cpu, &accel) {
        let threads = rayon::current_num_threads();
        let time = |alpha: bool| {
            let t = Instant::now();
            let hits = rays
                .par_iter()
                .filter(|r| {
                    if alpha {
                        accel.closest(scene, r, 0.0, f32::MAX)
                    } else {
                        accel.closest_opaque(scene, r, 0.0, f32::MAX)
                    }
                    .is_some()
                })
                .count();
            let s = t.elapsed().as_secs_f64();
            json!({ "mrays_per_second": rays.len() as f64 / s / 1e6, "ms": s * 1e3, "hits": hits, "threads": threads })
        };
        let (cpu, cpu_opaque) = (time(true), time(false));
        let t = Instant::now();
        let blocked =
            shadow_cpu.par_iter().filter(|r| accel.occluded(scene, r, 1e-3, f32::MAX)).count();
        let s = t.elapsed().as_secs_f64();
        (
            cpu,
            cpu_opaque,
            json!({ "mrays_per_second": shadow_cpu.len() as f64 / s / 1e6, "ms": s * 1e3, "blocked": blocked, "threads": threads }),
        )
    } else {
        (serde_json::Value::Null, serde_json::Value::Null, serde_json::Value::Null)
    };
    Ok(json!({
        "accel": backend,
        "build_ms": build_ms,
        "cpu_build_ms": cpu_build_ms,
        "device_build_ms": device_build_ms,
        "upload_ms": upload_ms,
        "bytes": bytes,
        "bytes_before_compaction": built_bytes,
        "bytes_per_triangle": bytes.map(|b| b as f64 / scene.unique_triangles().max(1) as f64),
        "cpu": cpu,
        "cpu_opaque": cpu_opaque,
        "gpu": gpu,
        "shadow_rays": shadow_cpu.len(),
        "cpu_shadow": cpu_shadow,
        "gpu_shadow": gpu_shadow,
        "bounce_rays": bounce.len(),
        "gpu_bounce": gpu_bounce,
        "kernel": kernel,
    }))
}

/// Time to the first frame: the forest rendered by `sylva render` in a
/// process of its own, cold and then warm from the prepared-data cache the
/// first left behind.
fn bench_first_frame(a: &TraceBenchArgs) -> anyhow::Result<serde_json::Value> {
    use sylva_scene::table2::{ForestOptions, forest};
    let dir = std::env::temp_dir().join(format!("sylva-first-frame-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let file = forest(&ForestOptions { scale: a.scale, triangle_scale: a.triangle_scale, seed: 1 })
        .map_err(anyhow::Error::msg)?;
    let scene = dir.join("forest.json");
    std::fs::write(&scene, serde_json::to_string(&file)?)?;
    let run = |name: &str| -> anyhow::Result<serde_json::Value> {
        let out = dir.join(format!("{name}.png"));
        let t = Instant::now();
        let done = std::process::Command::new(std::env::current_exe()?)
            .args(["render", &scene.display().to_string(), "--local-workers", "0"])
            .args(["--accel", "auto", "--lighting", "lb", "--spp", "1", "--json"])
            .args(["--width", &a.width.to_string(), "--height", &a.height.to_string()])
            .args(["--out", &out.display().to_string()])
            .args(["--prepared-cache-dir", &dir.join("cache").display().to_string()])
            .args(["--prepared-cache-mib", "65536"])
            .stderr(std::process::Stdio::null())
            .output()?;
        let wall_ms = t.elapsed().as_secs_f64() * 1e3;
        anyhow::ensure!(done.status.success(), "the {name} render failed");
        let stats: serde_json::Value = serde_json::from_slice(&done.stdout)?;
        let phase = |p: &str| -> f64 {
            stats["phases_ms"]
                .as_array()
                .into_iter()
                .flatten()
                .filter(|e| e["phase"] == p)
                .filter_map(|e| e["ms"].as_f64())
                .sum()
        };
        Ok(json!({
            "wall_ms": wall_ms,
            "scene_to_frame_ms": phase("load") + phase("prepare") + phase("trace"),
            "trace_ms": phase("trace"),
            // The chosen backend's buffers (and structures, for rq) and
            // its kernels (compiled beside the LB) and pipeline: what the
            // issue calls the upload.
            "upload_ms": phase(match stats["backend"]["backend"].as_str() {
                Some("rq") => "upload rq",
                Some("cwbvh") => "upload cwbvh",
                _ => "upload",
            })
                + phase("kernels") + phase("pipeline"),
            // What `auto` chose, and why (its probe's figures).
            "backend": stats["backend"],
            "phases_ms": stats["phases_ms"],
        }))
    };
    let cold = run("cold")?;
    let warm = run("warm")?;
    let _ = std::fs::remove_dir_all(&dir);
    let ms = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or(0.0);
    let (trace, upload) = (ms(&warm, "trace_ms"), ms(&warm, "upload_ms"));
    Ok(json!({
        "cold": cold,
        "warm": warm,
        "target_cold_ms": 2.0 * trace + upload,
        "target_warm_ms": trace + upload,
        "cold_over_target": ms(&cold, "scene_to_frame_ms") / (2.0 * trace + upload),
        "warm_over_target": ms(&warm, "scene_to_frame_ms") / (trace + upload),
    }))
}

/// Whole frames with LB lighting at 1 and 4 spp on each backend, after a
/// warm-up dispatch.
fn bench_frames(
    ctx: &sylva_worker::trace::Tracer,
    scene: &sylva_scene::Scene,
    a: &TraceBenchArgs,
    backends: &[sylva_scene::frame::Backend],
) -> anyhow::Result<Vec<serde_json::Value>> {
    use sylva_scene::LightingMode;
    use sylva_worker::frame::{Frame, Fresh};
    use sylva_worker::trace::RenderSettings;
    let mut frames = Vec::new();
    for &kind in backends {
        // Composed once per backend; the spp vary over its preparation.
        let request = FrameSettings {
            width: a.width,
            height: a.height,
            lighting: Some(LightingMode::Lb),
            accel: kind,
            ..FrameSettings::default()
        };
        let composed = Frame::compose(ctx, scene, &request, &mut Fresh::default(), &|_| {})?;
        for spp in [1u32, 4] {
            let frame = composed.with_settings(RenderSettings { spp, ..composed.settings });
            let (prepared, f) = (&frame.prepared, frame.settings);
            frame.with_settings(RenderSettings { width: 64, height: 32, ..f }).strip(0, 64)?; // warm-up
            let t = Instant::now();
            let frame = InProcess::new(&frame).render(&[(0, a.width)], &|_| {})?;
            let s = t.elapsed().as_secs_f64();
            let sylva_scene::film::RayCounts { primary, shadow, transparent } = frame.rays;
            frames.push(json!({
                "accel": kind,
                "spp": spp,
                "frame_ms": s * 1e3,
                "rays": { "primary": primary, "shadow": shadow, "transparent": transparent },
                "mrays_per_second": (primary + shadow) as f64 / s / 1e6,
                "prepare_ms": prepared.phases,
            }));
        }
    }
    Ok(frames)
}

/// The paper's Table 4: G80s, static strips, seconds per frame.
const PAPER_TABLE_4: [(usize, f64); 4] = [(2, 1.162), (4, 0.666), (8, 0.351), (16, 0.170)];

fn bench_scaling(a: ScalingBenchArgs) -> anyhow::Result<()> {
    use crate::lab::simulate::FrameCost;
    use crate::loopback::LoopbackProcesses;
    use crate::measure::chart::{Series, line_chart};
    use sylva_coordinator::executor::Farm;
    use sylva_coordinator::farm::Workers;
    use sylva_coordinator::schedule::{ScheduleKind, column_cost, scheduler};
    use sylva_scene::film::reinhard;

    let kinds: Vec<ScheduleKind> = a
        .schedule
        .iter()
        .map(|s| match s.as_str() {
            "static" => Ok(ScheduleKind::Static),
            "dynamic" => Ok(ScheduleKind::Dynamic),
            o => Err(anyhow::anyhow!("--schedule {o:?}: static or dynamic")),
        })
        .collect::<anyhow::Result<_>>()?;
    anyhow::ensure!(
        a.workers.iter().all(|&n| (1..=1024).contains(&n)),
        "--workers: counts in [1, 1024]"
    );
    anyhow::ensure!(
        a.width > 0 && a.height > 0 && a.width <= 16384 && a.height <= 16384,
        "image sides in [1, 16384]"
    );
    let scene = sylva_scene::Scene::load(&a.scene)?;
    let bundle = sylva_scene::bundle::pack(&a.scene)?;
    let frame = sylva_scene::frame::FrameSettings {
        width: a.width,
        height: a.height,
        spp: a.spp,
        lighting: Some(scene.lighting),
        ..Default::default()
    };
    frame.check()?;
    let rt = tokio::runtime::Runtime::new()?;
    let deadline = std::time::Duration::from_secs(3600);
    // One worker profiles the frame: strips one at a time on one device.
    let token = sylva_proto::auth::random_token();
    let mut profiler = LoopbackProcesses::default();
    let one = Workers {
        addrs: profiler.start_workers(1, &token)?,
        token: Some(token.clone()),
        ..Default::default()
    };
    let whole = vec![(0, a.width)];
    Farm::new(&rt, one.clone(), &bundle, frame, deadline).render(&whole, &|_| {})?; // prepare + compile
    let t = Instant::now();
    let single = Farm::new(&rt, one.clone(), &bundle, frame, deadline).render(&whole, &|_| {})?;
    let single_ms = t.elapsed().as_secs_f64() * 1e3;
    let n = a.profile_strips.clamp(1, a.width);
    let fine: Vec<(u32, u32)> =
        (0..n).map(|i| (i * a.width / n, (i + 1) * a.width / n)).filter(|s| s.0 < s.1).collect();
    let profile = Farm::new(&rt, one, &bundle, frame, deadline).render(&fine, &|_| {})?;
    drop(profiler);
    let column_ms = column_cost(a.width, &profile.strip_times);
    let overhead: f64 =
        profile.strip_times.iter().map(|t| (t.call_ms - t.render_ms).max(0.0)).sum();
    let t = Instant::now();
    let _ = reinhard(&single.image, 0.18);
    let assembly_ms = t.elapsed().as_secs_f64() * 1e3;
    let cost = FrameCost {
        column_ms,
        per_strip_ms: overhead / profile.strip_times.len().max(1) as f64,
        assembly_ms,
    };

    let mut rows = Vec::new();
    let mut lines = Vec::new();
    for &kind in &kinds {
        let base = cost.frame_ms(&scheduler(kind).plan(a.width, 1, &cost.column_ms), 1);
        let mut pts = Vec::new();
        for &w in &a.workers {
            let plan = scheduler(kind).plan(a.width, w, &cost.column_ms);
            let sim = cost.frame_ms(&plan, w);
            // Measured wall time where real workers are at hand.
            let measured =
                if w <= a.real_workers.len() || (a.real_workers.is_empty() && w <= a.local_real) {
                    let (_local, workers) = if a.real_workers.is_empty() {
                        let mut l = LoopbackProcesses::default();
                        let ws = Workers {
                            addrs: l.start_workers(w, &token)?,
                            token: Some(token.clone()),
                            ..Default::default()
                        };
                        (Some(l), ws)
                    } else {
                        (
                            None,
                            Workers {
                                addrs: a.real_workers[..w].to_vec(),
                                token: a.auth.load()?,
                                tls: a.tls.load()?,
                                ..Default::default()
                            },
                        )
                    };
                    let mut farm = Farm::new(&rt, workers, &bundle, frame, deadline);
                    farm.render(&plan, &|_| {})?; // every worker prepares
                    let t = Instant::now();
                    farm.render(&plan, &|_| {})?;
                    Some(t.elapsed().as_secs_f64() * 1e3 + cost.assembly_ms)
                } else {
                    None
                };
            pts.push((w as f64, base / sim));
            rows.push(json!({
                "schedule": kind,
                "workers": w,
                "strips": plan.len(),
                "simulated": { "frame_s": sim / 1e3, "speedup": base / sim, "efficiency": base / sim / w as f64 },
                "measured": measured.map(|m| json!({ "frame_s": m / 1e3 })),
                "paper_g80_s": PAPER_TABLE_4.iter().find(|p| p.0 == w).map(|p| p.1),
            }));
        }
        lines.push(Series {
            name: format!("{kind:?} (simulated)").to_lowercase(),
            color: if kind == ScheduleKind::Static { "#c0392b" } else { "#2471a3" },
            dashed: false,
            points: pts,
        });
    }
    let max_w = a.workers.iter().copied().max().unwrap_or(1) as f64;
    lines.insert(
        0,
        Series {
            name: "ideal".into(),
            color: "#888",
            dashed: true,
            points: vec![(0.0, 0.0), (max_w, max_w)],
        },
    );
    let paper_base = 2.277;
    lines.push(Series {
        name: "paper, G80s".into(),
        color: "#27ae60",
        dashed: true,
        points: std::iter::once((1.0, 1.0))
            .chain(PAPER_TABLE_4.iter().map(|&(w, s)| (w as f64, paper_base / s)))
            .collect(),
    });
    let ticks: Vec<f64> = a.workers.iter().map(|&w| w as f64).collect();
    if let Some(dir) = a.chart.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&a.chart, line_chart("Strip scaling", "workers", "speedup", &ticks, &lines))?;
    let out = json!({
        "benchmark": "scaling",
        "scene": a.scene,
        "image": [a.width, a.height],
        "spp": a.spp,
        "machine": machine(),
        "figures": {
            "measured": "wall time of a frame on real worker processes (after a frame that lets every worker prepare the scene), plus assembly; on one machine the workers share its cores and device",
            "simulated": "each column's render time measured by rendering profile_strips strips one at a time on one worker, plus the mean measured per-strip RPC and transfer overhead; the same scheduler code assigns the strips to N virtual workers that pull in order; plus measured assembly (tone mapping of the whole frame)",
            "paper_g80_s": "Geist & Steele Table 4, static strips on G80s; their one-GPU frame took 2.277 s",
        },
        "profile": {
            "strips": profile.strip_times.len(),
            "render_ms_total": profile.strip_times.iter().map(|t| t.render_ms).sum::<f64>(),
            "per_strip_overhead_ms": cost.per_strip_ms,
            "assembly_ms": cost.assembly_ms,
            "single_worker_frame_ms": single_ms,
            "bundle_upload_ms": profile.upload_ms,
        },
        "chart": a.chart,
        "rows": rows,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
