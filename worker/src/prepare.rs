//! Everything a worker does to a scene before it traces: both levels of
//! acceleration, each model voxelized and lit by the LB solver, and the
//! upload. Reports time per phase.

use crate::gpu::GpuContext;
use crate::lb::GpuSolver;
use crate::trace::{CloudGrid, GpuScene, LbGrid, SceneLight, StripRenderer};
use serde::Serialize;
use sylva_shared::accel::Aabb;
use sylva_shared::accel::{AccelKind, SceneAccel};
use sylva_shared::lb::coarse::{Occupant, WorldGrid, forest_medium};
use sylva_shared::lb::solver::PhaseTimer;
use sylva_shared::lb::{Preset, SolveOptions, Sun, solve};
use sylva_shared::scene::{ForestGridUse, LightingMode, Scene};
use sylva_shared::voxel::voxelize;

/// What the LB pre-process did for one model.
#[derive(Clone, Debug, Serialize)]
pub struct ModelLight {
    /// Model name.
    pub model: String,
    /// Grid size N.
    pub grid: usize,
    /// Preset.
    pub preset: &'static str,
    /// Fraction of nodes with matter.
    pub occupancy: f64,
    /// Steps per channel.
    pub steps: [usize; 3],
    /// Whether each channel converged.
    pub converged: [bool; 3],
    /// Where the LB model is not to be trusted for this medium, and why.
    pub warnings: Vec<String>,
}

/// Voxelizes one model at `grid`³ and solves its LB light.
fn solve_model(solver: &mut GpuSolver, m: &sylva_shared::scene::SceneModel, grid: usize, sun: &Sun) -> anyhow::Result<(LbGrid, ModelLight)> {
    solve_voxels(solver, m, &voxels_of(m, grid)?, grid, sun)
}

/// One model's LB medium: its voxels, filled inside when it is a solid;
/// matter that is not a plant scatters without removing what it absorbs.
fn voxels_of(m: &sylva_shared::scene::SceneModel, grid: usize) -> anyhow::Result<sylva_shared::voxel::Voxelization> {
    use sylva_shared::lb::NodeClass;
    let mut v = voxelize(&m.model, grid)?;
    if !m.lb.preset.is_plant() {
        v.medium.class.iter_mut().for_each(|c| *c = NodeClass::Medium);
    }
    if m.lb.solid {
        let class = if m.lb.preset.is_plant() { NodeClass::Green } else { NodeClass::Medium };
        sylva_shared::voxel::fill_interior(&mut v, class);
    }
    Ok(v)
}

/// Solves the LB light of one model's voxels.
fn solve_voxels(
    solver: &mut GpuSolver,
    m: &sylva_shared::scene::SceneModel,
    v: &sylva_shared::voxel::Voxelization,
    grid: usize,
    sun: &Sun,
) -> anyhow::Result<(LbGrid, ModelLight)> {
    let params = m.lb.preset.params();
    let s = solve(solver, &v.medium, &params, sun, &SolveOptions::default(), &|_, _, _| {})?;
    let warnings = sylva_shared::lb::lb_warnings(&params, &v.medium, sun).into_iter().map(|w| format!("{}: {}", w.kind, w.message)).collect();
    let report = ModelLight {
        model: m.name.clone(),
        grid,
        preset: m.lb.preset.name(),
        occupancy: v.medium.occupancy(),
        steps: std::array::from_fn(|c| s.channels[c].report.steps),
        converged: std::array::from_fn(|c| s.channels[c].report.converged),
        warnings,
    };
    let rgb = s.channels.iter().flat_map(|c| c.total.iter().copied()).collect();
    Ok((LbGrid { n: grid, frame: v.frame, rgb, occupancy: v.medium.occupancy() }, report))
}

/// The LB light of `g` at a model-space point: trilinear between node
/// centres, as `render.wgsl`'s `lb_light` reads it.
pub fn sample_lb(g: &LbGrid, p: glam::Vec3) -> [f32; 3] {
    let n = g.n;
    let q = ((p - glam::Vec3::from(g.frame.origin)) / g.frame.cell - 0.5).clamp(glam::Vec3::ZERO, glam::Vec3::splat((n - 1) as f32));
    let i0 = q.floor().min(glam::Vec3::splat((n - 2) as f32));
    let f = q - i0;
    let (x0, y0, z0) = (i0.x as usize, i0.y as usize, i0.z as usize);
    std::array::from_fn(|c| {
        let base = c * n * n * n;
        let mut acc = 0.0;
        for k in 0..8 {
            let (dx, dy, dz) = (k & 1, (k >> 1) & 1, (k >> 2) & 1);
            let w = if dx == 1 { f.x } else { 1.0 - f.x } * if dy == 1 { f.y } else { 1.0 - f.y } * if dz == 1 { f.z } else { 1.0 - f.z };
            acc += w * g.rgb[base + (x0 + dx) + n * ((y0 + dy) + n * (z0 + dz))];
        }
        acc
    })
}

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
    anyhow::ensure!(candidates.len() >= 2 && candidates.windows(2).all(|w| w[0] < w[1]), "auto grid candidates must be at least two, ascending");
    let sun = sun_of(scene)?;
    let mut solver = GpuSolver::new(ctx.clone());
    let mut out = Vec::new();
    for m in &scene.models {
        let t = std::time::Instant::now();
        let pts: Vec<glam::Vec3> =
            m.model.triangles.iter().map(|t| t.iter().map(|&i| m.model.positions[i as usize]).sum::<glam::Vec3>() / 3.0).collect();
        let light_at = |g: &LbGrid| -> Vec<f32> { pts.iter().map(|&p| sample_lb(g, p).iter().sum::<f32>()).collect() };
        progress(&format!("choosing the LB grid of {} ({}³)", m.name, candidates[0]));
        let mut coarse = light_at(&solve_model(&mut solver, m, candidates[0], &sun)?.0);
        let mut compared = Vec::new();
        let mut chosen = None;
        for w in candidates.windows(2) {
            progress(&format!("choosing the LB grid of {} ({}³)", m.name, w[1]));
            let fine = light_at(&solve_model(&mut solver, m, w[1], &sun)?.0);
            let num: f64 = coarse.iter().zip(&fine).map(|(a, b)| ((a - b) as f64).powi(2)).sum();
            let den: f64 = fine.iter().map(|b| (*b as f64).powi(2)).sum();
            let diff = if den > 0.0 { (num / den).sqrt() } else { 0.0 };
            compared.push((w[0], w[1], diff));
            if diff < tolerance {
                chosen = Some((w[0], format!("{}³ differs from {}³ by {:.1} % < {:.1} %", w[0], w[1], 100.0 * diff, 100.0 * tolerance)));
                break;
            }
            coarse = fine;
        }
        let last = *candidates.last().expect("two or more");
        let (grid, reason) =
            chosen.unwrap_or((last, format!("no grid up to {last}³ agreed with the next within {:.1} %: the finest was used", 100.0 * tolerance)));
        out.push(GridChoice { model: m.name.clone(), grid, compared, reason, ms: t.elapsed().as_secs_f64() * 1e3 });
    }
    Ok(out)
}

/// What the coarse forest grid decided.
#[derive(Clone, Debug, Serialize)]
pub struct ForestLight {
    /// Whether instances' LB light is scaled by it.
    pub used: bool,
    /// Why.
    pub reason: String,
    /// The grid, when solved.
    pub grid: Option<WorldGrid>,
    /// (max − min) / max of the instances' light.
    pub spread: f32,
    /// Smallest, mean and largest scale applied (all 1 when unused).
    pub scale_min: f32,
    /// Mean scale.
    pub scale_mean: f32,
    /// Largest scale.
    pub scale_max: f32,
}

/// A scene ready to trace, and what preparing it cost.
pub struct PreparedScene {
    /// The renderer.
    pub renderer: StripRenderer,
    /// Wall time per phase: build, voxelize, lb, upload.
    pub phases: PhaseTimer,
    /// Bytes of acceleration structures.
    pub accel_bytes: usize,
    /// The LB solve per model (empty when the lighting needs none).
    pub light: Vec<ModelLight>,
    /// The coarse forest grid's decision (none when the lighting needs no LB).
    pub forest: Option<ForestLight>,
    /// The Boulanger precompute per model (empty unless that lighting).
    pub boulanger: Vec<ModelEnvelope>,
}

/// One model's Boulanger envelope, as reported.
#[derive(Clone, Debug, Serialize)]
pub struct ModelEnvelope {
    /// Model name.
    pub model: String,
    /// Leaves (leaf cards) found.
    pub leaves: usize,
    /// Optical thickness per unit length τ = ρA/2.
    pub tau: f32,
    /// Leaves per unit volume of the envelope.
    pub leaf_density: f32,
    /// Mean leaf area.
    pub leaf_area: f32,
    /// Precompute time, ms.
    pub ms: f64,
}

/// Prepares `scene` for tracing with `kind` structures; `lighting` decides
/// whether the LB pre-process runs. `progress` hears each step.
pub fn prepare(ctx: &GpuContext, scene: &Scene, kind: AccelKind, lighting: LightingMode, progress: &dyn Fn(&str)) -> anyhow::Result<PreparedScene> {
    let mut phases = PhaseTimer::default();
    progress("building acceleration structures");
    let accel = phases.time("build", || SceneAccel::build(scene, kind));
    let needs_lb = lighting.needs_lb();
    let mut grids: Vec<Option<LbGrid>> = vec![None; scene.models.len()];
    let mut light = Vec::new();
    if needs_lb {
        progress("voxelizing models");
        let voxels = phases.time("voxelize", || scene.models.iter().map(|m| voxels_of(m, m.lb.grid)).collect::<Result<Vec<_>, _>>())?;
        let sun = sun_of(scene)?;
        let mut solver = GpuSolver::new(ctx.clone());
        phases.time("lb", || -> anyhow::Result<()> {
            for (i, (m, v)) in scene.models.iter().zip(&voxels).enumerate() {
                progress(&format!("LB light of {} ({}³)", m.name, m.lb.grid));
                let (grid, report) = solve_voxels(&mut solver, m, v, m.lb.grid, &sun)?;
                for w in &report.warnings {
                    tracing::warn!(model = %m.name, "LB: {w}");
                }
                light.push(report);
                grids[i] = Some(grid);
            }
            Ok(())
        })?;
    }
    let mut forest = None;
    let mut scales = vec![1.0f32; scene.instances.len()];
    if needs_lb {
        progress("LB light of the whole forest");
        let fills: Vec<f32> = grids.iter().zip(&scene.models).map(|(g, m)| crown_fill(g.as_ref(), &m.model)).collect();
        let f = phases.time("forest lb", || forest_light(ctx, scene, &fills, &sun_of(scene)?, &mut scales))?;
        forest = Some(f);
    }
    let mut envelopes = Vec::new();
    let mut boulanger = Vec::new();
    if lighting == LightingMode::Boulanger {
        progress("Boulanger envelope distances");
        phases.time("boulanger precompute", || {
            for m in &scene.models {
                let e = sylva_shared::boulanger::precompute(&m.model);
                boulanger.push(ModelEnvelope {
                    model: m.name.clone(),
                    leaves: e.leaves,
                    tau: e.tau,
                    leaf_density: e.leaf_density,
                    leaf_area: e.leaf_area,
                    ms: e.precompute_ms,
                });
                envelopes.push(Some(std::sync::Arc::new(e)));
            }
        });
    }
    // The reference path-traces the clouds' density; the LB methods light them.
    let clouds = if (needs_lb || lighting == LightingMode::Reference) && !scene.clouds.is_empty() {
        progress("LB light of the clouds");
        phases.time("cloud lb", || solve_clouds(ctx, scene))?
    } else {
        Vec::new()
    };
    progress("uploading the scene");
    let renderer = phases.time("upload", || -> anyhow::Result<StripRenderer> {
        let light = SceneLight { models: grids, instance_scales: scales, clouds, envelopes };
        let gpu_scene = GpuScene::upload(ctx, scene, &accel, &light)?;
        let r = StripRenderer::new(ctx, gpu_scene, scene)?;
        ctx.wait()?;
        Ok(r)
    })?;
    Ok(PreparedScene { renderer, phases, accel_bytes: accel.bytes(), light, forest, boulanger })
}

fn sun_of(scene: &Scene) -> anyhow::Result<Sun> {
    Ok(Sun::towards(scene.sun.towards.as_dvec3().to_array(), 1.0)?)
}

/// How much of its bounding box a model's crown fills: the volume of its
/// occupied voxels over the box's volume.
fn crown_fill(grid: Option<&LbGrid>, model: &sylva_shared::model::Model) -> f32 {
    let (Some(g), Some((lo, hi))) = (grid, model.bounds()) else { return 0.0 };
    let e = (hi - lo).max(glam::Vec3::splat(g.frame.cell));
    let occupied = g.occupancy as f32 * (g.n * g.n * g.n) as f32 * g.frame.cell.powi(3);
    (occupied / (e.x * e.y * e.z)).clamp(0.0, 1.0)
}

/// Solves the coarse forest grid, decides whether to use it, and writes the
/// per-instance scales (normalized so the best-lit instance gets 1).
fn forest_light(ctx: &GpuContext, scene: &Scene, fills: &[f32], sun: &Sun, scales: &mut [f32]) -> anyhow::Result<ForestLight> {
    let spec = scene.file.forest_grid;
    let unused = |reason: String| ForestLight { used: false, reason, grid: None, spread: 0.0, scale_min: 1.0, scale_mean: 1.0, scale_max: 1.0 };
    if spec.use_grid == ForestGridUse::Never {
        return Ok(unused("forest_grid.use is \"never\"".into()));
    }
    if scene.instances.len() < 2 {
        return Ok(unused("a single instance has nothing to shade it".into()));
    }
    let occupants: Vec<Occupant> = scene
        .instances
        .iter()
        .map(|i| Occupant {
            bounds: sylva_shared::accel::scene::model_bounds(&scene.models[i.model as usize].model).transformed(&i.to_world),
            fill: fills[i.model as usize],
        })
        .collect();
    let all = occupants.iter().fold(Aabb::EMPTY, |b, o| b.union(o.bounds));
    let grid = WorldGrid::around(all, spec.grid);
    let medium = forest_medium(&grid, &occupants);
    let mut solver = GpuSolver::new(ctx.clone());
    let sol = solve(&mut solver, &medium, &Preset::Leaf.params(), sun, &SolveOptions::default(), &|_, _, _| {})?;
    let free: f32 = sun.boundary().values.iter().sum();
    let light: Vec<f32> = occupants
        .iter()
        .map(|o| {
            let p = o.bounds.centroid();
            sol.channels.iter().map(|c| grid.sample(&c.total, p)).sum::<f32>() / (3.0 * free)
        })
        .collect();
    let max = light.iter().copied().fold(0.0f32, f32::max).max(f32::MIN_POSITIVE);
    let min = light.iter().copied().fold(f32::INFINITY, f32::min);
    let spread = (max - min) / max;
    let used = spec.use_grid == ForestGridUse::Always || spread > spec.threshold;
    let reason = match spec.use_grid {
        ForestGridUse::Always => "forest_grid.use is \"always\"".to_string(),
        _ if used => format!("the instances' light differs by {:.0} % (threshold {:.0} %)", 100.0 * spread, 100.0 * spec.threshold),
        _ => format!("the instances' light differs by only {:.0} % (threshold {:.0} %): all get full light", 100.0 * spread, 100.0 * spec.threshold),
    };
    if used {
        for (s, l) in scales.iter_mut().zip(&light) {
            *s = l / max;
        }
    }
    let n = scales.len() as f32;
    Ok(ForestLight {
        used,
        reason,
        grid: Some(grid),
        spread,
        scale_min: scales.iter().copied().fold(f32::INFINITY, f32::min),
        scale_mean: scales.iter().sum::<f32>() / n,
        scale_max: scales.iter().copied().fold(0.0, f32::max),
    })
}

/// Generates each cloud's density and solves its light with the chapter's
/// cloud parameters (strongly forward scattering, almost no absorption).
fn solve_clouds(ctx: &GpuContext, scene: &Scene) -> anyhow::Result<Vec<CloudGrid>> {
    let sun = sun_of(scene)?;
    let params = Preset::Cloud.params();
    let mut solver = GpuSolver::new(ctx.clone());
    scene
        .clouds
        .iter()
        .map(|c| {
            let medium = sylva_shared::shapes::cloud(c.grid, c.seed);
            let s = solve(&mut solver, &medium, &params, &sun, &SolveOptions::default(), &|_, _, _| {})?;
            let p = params.channels[0];
            Ok(CloudGrid {
                min: (glam::Vec3::from(c.center) - glam::Vec3::splat(c.size / 2.0)).to_array(),
                size: c.size,
                n: c.grid,
                light: s.channels.iter().flat_map(|ch| ch.total.iter().copied()).collect(),
                density: medium.density,
                sigma_t: p.sigma_t(),
                albedo: p.sigma_s / p.sigma_t(),
                g: p.g,
            })
        })
        .collect()
}
