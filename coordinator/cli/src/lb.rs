//! `sylva lb solve` and `sylva lb verify`.

use super::progress;
use crate::flags::lb::*;
use anyhow::{Context, bail};
use serde_json::json;
use std::path::Path;
use std::time::Instant;
use sylva_light::lb::{
    GridDims, LbParams, LightingSolver, MediumGrid, NodeClass, Solution, SolveOptions, Sun, solve,
};
use sylva_light::studies::verify::{self, Check};
use sylva_light::voxel::{self, GridFrame};
use sylva_light::{npy, shapes, visualize};
use sylva_scene::format::Preset;
use sylva_scene::model;
use sylva_worker::GpuSolver;

pub fn run(cmd: LbCommand) -> anyhow::Result<()> {
    match cmd {
        LbCommand::Solve(a) => solve_cmd(a),
        LbCommand::Verify(a) => verify_cmd(a),
    }
}

/// Parses `--sun`.
pub fn parse_sun(s: &str, intensity: f64) -> anyhow::Result<Sun> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--sun {s:?}: expected ELEVATION,AZIMUTH or X,Y,Z numbers"))?;
    let sun = match v.as_slice() {
        [e, a] => Sun::from_elevation_azimuth(*e, *a, intensity),
        [x, y, z] => Sun::towards([*x, *y, *z], intensity),
        _ => bail!("--sun {s:?}: expected two numbers (ELEVATION,AZIMUTH) or three (X,Y,Z)"),
    };
    sun.with_context(|| format!("--sun {s:?}"))
}

/// A solver for `backend` (the chooser lives beside the solvers).
pub fn open_solver(backend: Backend) -> anyhow::Result<Box<dyn LightingSolver>> {
    sylva_worker::lb::open_solver(match backend {
        Backend::Cpu => sylva_worker::lb::Backend::Cpu,
        Backend::Gpu => sylva_worker::lb::Backend::Gpu,
    })
}

/// What the LB solve reads, resolved from the command line.
struct LoadedInput {
    medium: MediumGrid,
    /// Where the grid sits in model space (models only).
    frame: Option<GridFrame>,
    /// Triangles voxelized (models only).
    triangles: Option<usize>,
    default_preset: Preset,
}

fn load_input(
    a: &SolveArgs,
    timings: &mut Vec<(&'static str, f64)>,
) -> anyhow::Result<LoadedInput> {
    let n = a.grid.unwrap_or(64);
    if n < 4 {
        bail!("--grid {n}: use at least 4 (the outer shell holds the boundary condition)");
    }
    let t = Instant::now();
    let model = match a.input.as_str() {
        "cloud" => {
            let medium = shapes::cloud(n, 1);
            timings.push(("generate", t.elapsed().as_secs_f64() * 1e3));
            return Ok(LoadedInput {
                medium,
                frame: None,
                triangles: None,
                default_preset: Preset::Cloud,
            });
        }
        "plant" => shapes::plant(1),
        path => {
            let p = Path::new(path);
            if !p.exists() {
                bail!(
                    "{path}: no such file (inputs are `plant`, `cloud`, a .gltf/.glb model or a .npy density grid)"
                );
            }
            match p.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref()
            {
                Some("npy") => {
                    if a.grid.is_some() {
                        bail!(
                            "--grid does not apply to a .npy density grid: its shape sets the grid"
                        );
                    }
                    let preset = a.preset.unwrap_or(Preset::Leaf);
                    let class = match a.class {
                        Some(ClassArg::Medium) => NodeClass::Medium,
                        Some(ClassArg::Green) => NodeClass::Green,
                        Some(ClassArg::Brown) => NodeClass::Brown,
                        None if preset.is_plant() => NodeClass::Green,
                        None => NodeClass::Medium,
                    };
                    let medium = npy::read_density(p, class)?;
                    timings.push(("load", t.elapsed().as_secs_f64() * 1e3));
                    return Ok(LoadedInput {
                        medium,
                        frame: None,
                        triangles: None,
                        default_preset: preset,
                    });
                }
                Some("gltf" | "glb") => model::load_gltf(p)?,
                _ => bail!("{path}: unknown input type; expected .gltf, .glb or .npy"),
            }
        }
    };
    timings.push(("load", t.elapsed().as_secs_f64() * 1e3));
    if a.class.is_some() {
        bail!(
            "--class applies to .npy grids only: a model's triangles decide green and brown nodes"
        );
    }
    let t = Instant::now();
    let v = voxel::voxelize(&model, n)?;
    timings.push(("voxelize", t.elapsed().as_secs_f64() * 1e3));
    Ok(LoadedInput {
        medium: v.medium,
        frame: Some(v.frame),
        triangles: Some(model.triangle_count()),
        default_preset: Preset::Leaf,
    })
}

fn solve_cmd(a: SolveArgs) -> anyhow::Result<()> {
    let sun = parse_sun(&a.sun, a.sun_intensity)?;
    if !(a.tolerance.is_finite() && a.tolerance >= 0.0) {
        bail!("--tolerance {}: must be a finite number ≥ 0", a.tolerance);
    }
    let mut timings = Vec::new();
    let input = load_input(&a, &mut timings)?;
    let preset = a.preset.unwrap_or(input.default_preset);
    let params = LbParams::from_preset(preset);
    let opts =
        SolveOptions { max_steps: a.max_steps, tolerance: a.tolerance, ..SolveOptions::default() };
    let t = Instant::now();
    let mut solver = open_solver(a.backend)?;
    timings.push(("open solver", t.elapsed().as_secs_f64() * 1e3));

    let bar = progress::lb_bar("solving", opts.cap(input.medium.dims));
    let t = Instant::now();
    let solution =
        solve(solver.as_mut(), &input.medium, &params, &sun, &opts, &progress::lb_callback(&bar))?;
    timings.push(("solve", t.elapsed().as_secs_f64() * 1e3));
    bar.finish_and_clear();

    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("{}: cannot create output folder", a.out.display()))?;
    let t = Instant::now();
    let npy_path = a.out.join("density.npy");
    let png_path = a.out.join("density.png");
    let flat: Vec<f32> = solution.channels.iter().flat_map(|c| c.total.iter().copied()).collect();
    npy::write_f32(&npy_path, &visualize::solution_shape(solution.dims), &flat)?;
    visualize::write_solution_png(&png_path, &solution)?;
    timings.push(("write", t.elapsed().as_secs_f64() * 1e3));

    let summary = summary_json(
        &a,
        &Solved {
            input: &input,
            preset,
            params: &params,
            sun: &sun,
            solver: solver.name(),
            solution: &solution,
            timings: &timings,
            npy_path: &npy_path,
            png_path: &png_path,
        },
    );
    let summary_path = a.out.join("summary.json");
    std::fs::write(&summary_path, serde_json::to_string_pretty(&summary)? + "\n")
        .with_context(|| format!("{}: cannot write", summary_path.display()))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        let steps: Vec<String> =
            solution.channels.iter().map(|c| c.report.steps.to_string()).collect();
        println!(
            "solved {} on {} ({}, preset {}) in {:.0} ms, steps R/G/B {}; wrote {}, {}, {}",
            a.input,
            input.medium.dims,
            solver.name(),
            preset.name(),
            timings.iter().find(|t| t.0 == "solve").map_or(0.0, |t| t.1),
            steps.join("/"),
            npy_path.display(),
            png_path.display(),
            summary_path.display()
        );
    }
    Ok(())
}

/// What `sylva lb solve` solved, how, and where it wrote it: its summary's content.
struct Solved<'a> {
    input: &'a LoadedInput,
    preset: Preset,
    params: &'a LbParams,
    sun: &'a Sun,
    solver: String,
    solution: &'a Solution,
    timings: &'a [(&'static str, f64)],
    npy_path: &'a Path,
    png_path: &'a Path,
}

fn summary_json(a: &SolveArgs, s: &Solved<'_>) -> serde_json::Value {
    let Solved { input, preset, params, sun, solver, solution, timings, npy_path, png_path } = s;
    let d: GridDims = solution.dims;
    let channels: Vec<_> = ["red", "green", "blue"]
        .iter()
        .zip(&solution.channels)
        .map(|(name, c)| json!({ "channel": name, "report": c.report }))
        .collect();
    json!({
        "input": a.input,
        "triangles": input.triangles,
        "grid": { "nx": d.nx, "ny": d.ny, "nz": d.nz, "frame": input.frame, "occupancy": input.medium.occupancy() },
        "preset": preset.name(),
        "params": params,
        "sun": { "propagation": sun.propagation, "intensity": sun.intensity },
        "backend": a.backend,
        "solver": solver,
        "channels": channels,
        "phases_ms": timings.iter().map(|(k, v)| json!({ "phase": k, "ms": v })).collect::<Vec<_>>(),
        "outputs": {
            "density": {
                "path": npy_path,
                "dtype": "float32",
                "shape": visualize::solution_shape(d),
                "axes": "(channel R,G,B; z; y (up); x): the total photon density sum_m f_m at node (x, y, z); with a frame, node (i, j, k) is the cell origin + (i, j, k) * cell",
            },
            "picture": { "path": png_path, "panels": "side slice (x-y at mid z), front slice (z-y at mid x), top slice (x-z at mid y), side view mean along z" },
        },
    })
}

/// (g) The GPU solver against the CPU reference, or a failed check saying
/// why it could not run.
pub fn gpu_check() -> Check {
    match GpuSolver::open() {
        Ok(mut gpu) => verify::reference_check(&mut gpu),
        Err(e) => Check::new(
            "g",
            "GPU solver matches the CPU reference",
            f64::INFINITY,
            1e-4,
            format!("could not run: {e:#}"),
        ),
    }
}

fn verify_cmd(a: VerifyArgs) -> anyhow::Result<()> {
    let mut checks = verify::model_checks();
    if a.no_gpu {
        checks.push(Check::new(
            "g",
            "GPU solver matches the CPU reference",
            f64::INFINITY,
            1e-4,
            "skipped (--no-gpu)".into(),
        ));
    } else {
        checks.push(gpu_check());
    }
    let pass = checks.iter().all(|c| c.pass);
    if a.json {
        let checks_json: Vec<_> = checks
            .iter()
            .map(|c| {
                // JSON has no infinity: a check that could not run reports null.
                let measured = if c.measured.is_finite() { json!(c.measured) } else { serde_json::Value::Null };
                json!({ "id": c.id, "name": c.name, "measured": measured, "bound": c.bound, "pass": c.pass, "detail": c.detail })
            })
            .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({ "pass": pass, "checks": checks_json }))?
        );
    } else {
        for c in &checks {
            println!(
                "{} ({}) {:<70} measured {:<10.3e} bound {:.0e}\n      {}",
                if c.pass { "PASS" } else { "FAIL" },
                c.id,
                c.name,
                c.measured,
                c.bound,
                c.detail
            );
        }
    }
    if !pass {
        bail!("{} of {} checks failed", checks.iter().filter(|c| !c.pass).count(), checks.len());
    }
    Ok(())
}
