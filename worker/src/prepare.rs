//! Everything a worker does to a scene before it traces: both levels of
//! acceleration, each model voxelized and lit by the LB solver, and the
//! upload. Reports time per phase.

use crate::gpu::GpuContext;
use crate::lb::GpuSolver;
use crate::trace::{CloudGrid, GpuScene, GroundLight, LbGrid, SceneLight, StripRenderer};
use serde::Serialize;
use sylva_shared::accel::Aabb;
use sylva_shared::accel::{AccelKind, SceneAccel};
use sylva_shared::lb::coarse::{Occupant, WorldGrid, forest_medium};
use sylva_shared::lb::solver::PhaseTimer;
use sylva_shared::lb::{GridDims, Illumination, LbParams, LeafScattering, MediumGrid, NodeClass, Preset, SolveOptions, Sun, solve, solve_indirect};
use sylva_shared::model::Model;
use sylva_shared::scene::{ForestGridSpec, ForestGridUse, LbModel, LightingMode, Scene, SceneModel};
use sylva_shared::voxel::{GridFrame, LeafArea, leaf_area_in, medium_from_leaf_area, voxelize_in};

/// What the LB pre-process did for one model.
#[derive(Clone, Debug, Serialize)]
pub struct ModelLight {
    /// Model name.
    pub model: String,
    /// Grid size N asked for (about N³ nodes).
    pub grid: usize,
    /// The grid's nodes per axis, fitted to the model's bounds.
    pub dims: GridDims,
    /// Which LB model ("grounded" or "paper").
    pub lb_model: &'static str,
    /// Preset (the paper model) or "leaf optics" (the grounded one).
    pub preset: &'static str,
    /// Single-scattering albedo σ_s/σ_t per channel.
    pub albedo: [f32; 3],
    /// Henyey–Greenstein g per channel.
    pub g: [f32; 3],
    /// Blocking area (one-sided leaf area plus half the wood's), model units² (grounded).
    pub leaf_area: Option<f64>,
    /// Fraction of leaf area the alpha masks cut away (grounded).
    pub alpha_cut: Option<f64>,
    /// Fraction of nodes with matter.
    pub occupancy: f64,
    /// Steps per channel.
    pub steps: [usize; 3],
    /// Whether each channel converged.
    pub converged: [bool; 3],
    /// Steps of the uncollided-sun pass (grounded).
    pub uncollided_steps: Option<usize>,
    /// Whether the grid's floor is the scene's ground, reflecting (grounded
    /// model, every instance standing on it).
    pub reflecting_floor: bool,
    /// Where the LB model is not to be trusted for this medium, and why.
    pub warnings: Vec<String>,
}

/// A model's LB medium, ready to solve.
/// A model's leaf area on its own grid (the grounded model's), which the
/// forest grid gathers per instance.
struct ModelArea {
    frame: GridFrame,
    dims: GridDims,
    area: LeafArea,
}

struct ModelMedium {
    frame: GridFrame,
    medium: MediumGrid,
    params: LbParams,
    /// The grounded model's leaf area (none for the paper's).
    area: Option<LeafArea>,
    /// Whether every instance stands on the scene's ground (the grid's
    /// lower face within a cell of it), so the lattice's floor reflects.
    on_ground: bool,
}

/// Whether every instance of `m` has its grid's lower face within one
/// cell of the ground plane y = 0.
fn stands_on_ground(scene: &Scene, m: &SceneModel, frame: &GridFrame) -> bool {
    let mut instances = scene.instances.iter().filter(|i| std::ptr::eq(&scene.models[i.model as usize], m)).peekable();
    scene.ground.is_some()
        && instances.peek().is_some()
        && instances.all(|i| {
            let floor = i.to_world.transform_point3(glam::Vec3::new(0.0, frame.origin[1], 0.0)).y;
            let cell = frame.cell * i.to_world.matrix3.determinant().abs().cbrt();
            floor.abs() <= 1.5 * cell
        })
}

/// The model-space box an LB grid covers: the model's bounds widened to
/// the cylinder about its vertical axis, since instances turned about the
/// vertical read the grid at turned points (`GpuInstance::to_lb`).
fn lb_bounds(model: &Model) -> Option<(glam::Vec3, glam::Vec3)> {
    let (lo, hi) = model.bounds()?;
    let r = model.triangles.iter().flatten().map(|&i| model.positions[i as usize]).map(|p| (p.x * p.x + p.z * p.z).sqrt()).fold(0.0f32, f32::max);
    Some((glam::Vec3::new(-r, lo.y, -r).min(lo), glam::Vec3::new(r, hi.y, r).max(hi)))
}

/// One model's LB medium on a grid of about `n³` nodes fitted to its bounds.
/// The grounded model derives a plant's medium from its leaf area and
/// optics; a solid or a non-plant medium (the PMMA teapot) keeps its
/// voxels and its preset in both models, only lit differently.
fn medium_of(scene: &Scene, m: &SceneModel, n: usize) -> anyhow::Result<ModelMedium> {
    let (lo, hi) = lb_bounds(&m.model).ok_or_else(|| anyhow::anyhow!("model {} has no triangles", m.name))?;
    let (frame, dims) = GridFrame::fit(lo, hi, n);
    let leaves = scene.file.lb_model == LbModel::Grounded && m.lb.preset.is_plant() && !m.lb.solid;
    let on_ground = stands_on_ground(scene, m, &frame);
    match leaves {
        true => {
            let area = leaf_area_in(&m.model, &scene.file.leaf_optics, frame, dims);
            let medium = medium_from_leaf_area(&area.area, dims, frame.cell);
            Ok(ModelMedium { frame, medium, params: area.scattering.params(), area: Some(area), on_ground })
        }
        false => {
            let mut v = voxelize_in(&m.model, frame, dims)?;
            if !m.lb.preset.is_plant() {
                v.medium.class.iter_mut().for_each(|c| *c = NodeClass::Medium);
            }
            if m.lb.solid {
                let class = if m.lb.preset.is_plant() { NodeClass::Green } else { NodeClass::Medium };
                sylva_shared::voxel::fill_interior(&mut v, class);
            }
            Ok(ModelMedium { frame, medium: v.medium, params: m.lb.preset.params(), area: None, on_ground })
        }
    }
}

/// Solves one model's medium. The grounded model keeps the light the
/// tracer does not add (scattered sun, sky) in physical units; the paper
/// model keeps the total density of a unit sun.
fn solve_medium(solver: &mut GpuSolver, scene: &Scene, m: &SceneModel, mm: &ModelMedium, n: usize) -> anyhow::Result<(LbGrid, ModelLight)> {
    let opts = SolveOptions::default();
    let (rgb, steps, converged, uncollided_steps): (Vec<f32>, [usize; 3], [bool; 3], Option<usize>) = match scene.file.lb_model {
        LbModel::Grounded => {
            let light = Illumination { floor_reflects: mm.on_ground, ..scene.illumination() };
            let s = solve_indirect(solver, &mm.medium, &mm.params, &light, &opts, &|_| {})?;
            let r = &s.reports;
            (s.indirect.concat(), std::array::from_fn(|c| r[c].steps), std::array::from_fn(|c| r[c].converged), Some(r[3].steps))
        }
        LbModel::Paper => {
            let s = solve(solver, &mm.medium, &mm.params, &sun_of(scene)?, &opts, &|_, _, _| {})?;
            let r = |c: usize| &s.channels[c].report;
            let rgb = s.channels.iter().flat_map(|c| c.total.iter().copied()).collect();
            (rgb, std::array::from_fn(|c| r(c).steps), std::array::from_fn(|c| r(c).converged), None)
        }
    };
    let warnings =
        sylva_shared::lb::lb_warnings(&mm.params, &mm.medium, &sun_of(scene)?).into_iter().map(|w| format!("{}: {}", w.kind, w.message)).collect();
    let p = &mm.params.channels;
    let report = ModelLight {
        model: m.name.clone(),
        grid: n,
        dims: mm.medium.dims,
        lb_model: scene.file.lb_model.name(),
        preset: if mm.area.is_some() { "leaf optics" } else { m.lb.preset.name() },
        albedo: std::array::from_fn(|c| p[c].sigma_s / p[c].sigma_t()),
        g: std::array::from_fn(|c| p[c].g),
        leaf_area: mm.area.as_ref().map(|a| a.total_area),
        alpha_cut: mm.area.as_ref().map(|a| a.cut_fraction),
        occupancy: mm.medium.occupancy(),
        steps,
        converged,
        uncollided_steps,
        reflecting_floor: scene.file.lb_model == LbModel::Grounded && mm.on_ground,
        warnings,
    };
    Ok((LbGrid { dims: mm.medium.dims, frame: mm.frame, rgb, occupancy: mm.medium.occupancy() }, report))
}

/// Builds and solves one model's grid of about `n³` nodes.
fn solve_model(solver: &mut GpuSolver, scene: &Scene, m: &SceneModel, n: usize) -> anyhow::Result<(LbGrid, ModelLight)> {
    solve_medium(solver, scene, m, &medium_of(scene, m, n)?, n)
}

/// The LB light of `g` at a model-space point, summed over channels'
/// planes `c`: trilinear between node centres, as `render.wgsl`'s `lb_light` reads it.
pub fn sample_lb(g: &LbGrid, p: glam::Vec3) -> [f32; 3] {
    let q = ((p - glam::Vec3::from(g.frame.origin)) / g.frame.cell - 0.5).to_array();
    let plane = g.dims.len();
    std::array::from_fn(|c| g.dims.trilinear(&g.rgb[c * plane..(c + 1) * plane], q))
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
    let mut solver = GpuSolver::new(ctx.clone());
    let mut out = Vec::new();
    for m in &scene.models {
        let t = std::time::Instant::now();
        let pts: Vec<glam::Vec3> =
            m.model.triangles.iter().map(|t| t.iter().map(|&i| m.model.positions[i as usize]).sum::<glam::Vec3>() / 3.0).collect();
        let light_at = |g: &LbGrid| -> Vec<f32> { pts.iter().map(|&p| sample_lb(g, p).iter().sum::<f32>()).collect() };
        progress(&format!("choosing the LB grid of {} ({}³)", m.name, candidates[0]));
        let mut coarse = light_at(&solve_model(&mut solver, scene, m, candidates[0])?.0);
        let mut compared = Vec::new();
        let mut chosen = None;
        for w in candidates.windows(2) {
            progress(&format!("choosing the LB grid of {} ({}³)", m.name, w[1]));
            let fine = light_at(&solve_model(&mut solver, scene, m, w[1])?.0);
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
    let mut areas = Vec::new();
    if needs_lb {
        progress("voxelizing models");
        let media = phases.time("voxelize", || scene.models.iter().map(|m| medium_of(scene, m, m.lb.grid)).collect::<anyhow::Result<Vec<_>>>())?;
        let mut solver = GpuSolver::new(ctx.clone());
        phases.time("lb", || -> anyhow::Result<()> {
            for (i, (m, mm)) in scene.models.iter().zip(&media).enumerate() {
                progress(&format!("LB light of {} ({})", m.name, mm.medium.dims));
                let (grid, report) = solve_medium(&mut solver, scene, m, mm, m.lb.grid)?;
                for w in &report.warnings {
                    tracing::warn!(model = %m.name, "LB: {w}");
                }
                light.push(report);
                grids[i] = Some(grid);
            }
            Ok(())
        })?;
        areas = media.into_iter().map(|mm| mm.area.map(|area| ModelArea { frame: mm.frame, dims: mm.medium.dims, area })).collect();
    }
    let mut forest = None;
    let mut ground = None;
    let mut scales = vec![1.0f32; scene.instances.len()];
    if needs_lb {
        progress("LB light of the whole forest");
        let f = phases.time("forest lb", || -> anyhow::Result<ForestLight> {
            match scene.file.lb_model {
                LbModel::Paper => {
                    let fills: Vec<f32> = grids.iter().zip(&scene.models).map(|(g, m)| crown_fill(g.as_ref(), &m.model)).collect();
                    forest_light(ctx, scene, &fills, &sun_of(scene)?, &mut scales)
                }
                LbModel::Grounded => {
                    let (f, g) = forest_light_grounded(ctx, scene, &areas, &mut scales)?;
                    ground = g;
                    Ok(f)
                }
            }
        })?;
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
        let light = SceneLight { models: grids, instance_scales: scales, clouds, envelopes, ground };
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
    let occupied = g.occupancy as f32 * g.dims.len() as f32 * g.frame.cell.powi(3);
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
    let what = ("the instances' light", "all get full light");
    Ok(decide(spec, grid, &light, what, |l| l / max, scales))
}

/// Whether the forest grid's per-instance `light` differs enough (by the
/// scene's rule) to scale each instance by `scale(light)`; fills `scales`
/// and says why. `what` names the light and what happens without the grid.
fn decide(spec: ForestGridSpec, grid: WorldGrid, light: &[f32], what: (&str, &str), scale: impl Fn(f32) -> f32, scales: &mut [f32]) -> ForestLight {
    let max = light.iter().copied().fold(0.0f32, f32::max).max(f32::MIN_POSITIVE);
    let min = light.iter().copied().fold(f32::INFINITY, f32::min);
    let spread = (max - min) / max;
    let used = spec.use_grid == ForestGridUse::Always || spread > spec.threshold;
    let (t, s) = (100.0 * spec.threshold, 100.0 * spread);
    let reason = match spec.use_grid {
        ForestGridUse::Always => "forest_grid.use is \"always\"".to_string(),
        _ if used => format!("{} differs by {s:.0} % (threshold {t:.0} %)", what.0),
        _ => format!("{} differs by only {s:.0} % (threshold {t:.0} %): {}", what.0, what.1),
    };
    if used {
        for (s, &l) in scales.iter_mut().zip(light) {
            *s = scale(l);
        }
    }
    let n = scales.len() as f32;
    ForestLight {
        used,
        reason,
        grid: Some(grid),
        spread,
        scale_min: scales.iter().copied().fold(f32::INFINITY, f32::min),
        scale_mean: scales.iter().sum::<f32>() / n,
        scale_max: scales.iter().copied().fold(0.0, f32::max),
    }
}

/// The forest grid's blocking leaf area per cell (world units²) and the
/// area-weighted optics of what blocks light. Each of a model's cells
/// carries its leaf area to the forest cell its centre falls in, turned
/// and scaled with the instance, so the crown's area stays up in the
/// crown. (Spread evenly over the instance's box, 40 % of a tall tree's
/// leaves sat in its trunk zone and shaded the ground from the low sky
/// under the stand.)
fn forest_leaf_area(scene: &Scene, areas: &[Option<ModelArea>], grid: &WorldGrid) -> (Vec<f32>, LeafScattering) {
    let d = grid.dims;
    let mut area = vec![0.0f32; d.len()];
    let (mut reflect, mut transmit, mut weight) = ([0.0f64; 3], [0.0f64; 3], 0.0f64);
    for inst in &scene.instances {
        let Some(m) = areas.get(inst.model as usize).and_then(|a| a.as_ref()) else { continue };
        let a = &m.area;
        let scale2 = inst.to_world.matrix3.determinant().abs().powf(2.0 / 3.0) as f64;
        let world_area = a.total_area * scale2;
        for c in 0..3 {
            reflect[c] += world_area * a.scattering.reflect[c];
            transmit[c] += world_area * a.scattering.transmit[c];
        }
        weight += world_area;
        let md = m.dims;
        let last = glam::Vec3::new((d.nx - 2) as f32, (d.ny - 2) as f32, (d.nz - 2) as f32);
        for z in 0..md.nz {
            for y in 0..md.ny {
                for x in 0..md.nx {
                    let cell_area = a.area[md.index(x, y, z)];
                    if cell_area <= 0.0 {
                        continue;
                    }
                    let centre = glam::Vec3::from(m.frame.origin) + (glam::Vec3::new(x as f32, y as f32, z as f32) + 0.5) * m.frame.cell;
                    let q =
                        ((inst.to_world.transform_point3(centre) - glam::Vec3::from(grid.origin)) / grid.cell).floor().clamp(glam::Vec3::ONE, last);
                    area[d.index(q.x as usize, q.y as usize, q.z as usize)] += (cell_area as f64 * scale2) as f32;
                }
            }
        }
    }
    let w = weight.max(f64::MIN_POSITIVE);
    (area, LeafScattering { reflect: reflect.map(|r| r / w), transmit: transmit.map(|t| t / w) })
}

/// The grounded forest grid: each instance's blocking area (its model's,
/// × its scale², where its model has it: [`forest_leaf_area`]) sets the coarse medium; the
/// leaves' mean optics set σ_a, σ_s, g; sun and sky light it. An
/// instance's species grid, solved in the open, is scaled by the fraction
/// of the open field's fluence that reaches its crown from outside (the
/// mean over points one cell outside its box, on its top and its sun-facing
/// sides, where its own crown casts no shadow). The ground under the stand
/// reads the grid's indirect light (returned as a [`GroundLight`]).
fn forest_light_grounded(
    ctx: &GpuContext,
    scene: &Scene,
    areas: &[Option<ModelArea>],
    scales: &mut [f32],
) -> anyhow::Result<(ForestLight, Option<GroundLight>)> {
    let spec = scene.file.forest_grid;
    let unused = |reason: String, grid: Option<WorldGrid>| ForestLight {
        used: false,
        reason,
        grid,
        spread: 0.0,
        scale_min: 1.0,
        scale_mean: 1.0,
        scale_max: 1.0,
    };
    if scene.instances.is_empty() || (spec.use_grid == ForestGridUse::Never && scene.ground.is_none()) {
        return Ok((unused("forest_grid.use is \"never\" and there is no ground".into(), None), None));
    }
    let boxes: Vec<Aabb> = scene
        .instances
        .iter()
        .map(|i| sylva_shared::accel::scene::model_bounds(&scene.models[i.model as usize].model).transformed(&i.to_world))
        .collect();
    let all = boxes.iter().fold(Aabb::EMPTY, |b, o| b.union(*o));
    let grid = WorldGrid::around(all, spec.grid);
    let d = grid.dims;
    let (area, leaves) = forest_leaf_area(scene, areas, &grid);
    let medium = medium_from_leaf_area(&area, d, grid.cell);
    let light = scene.illumination();
    let mut solver = GpuSolver::new(ctx.clone());
    let sol = solve_indirect(&mut solver, &medium, &leaves.params(), &light, &SolveOptions::default(), &|_| {})?;
    let sun_y = scene.sun.towards.y.max(0.0);
    let ground = scene.ground.as_ref().map(|g| g.color).map(|albedo| GroundLight {
        origin: [grid.origin[0], grid.origin[2]],
        cell: grid.cell,
        nx: d.nx,
        nz: d.nz,
        // The first layer above the floor, read as isotropic halves: the
        // downward half brings E = φ↓/2, the upward half is what the ground
        // sends back of it and of the direct sun, φ↑ = 2a(E + E_sun). So
        // E = (φ_indirect/2 − a E_sun) / (1 + a), with E_sun = sin(elevation) ×
        // the uncollided beam's fluence (docs/lighting.md, "The ground").
        rgb: (0..3)
            .flat_map(|c| (0..d.nz).flat_map(move |z| (0..d.nx).map(move |x| (c, x, z))))
            .map(|(c, x, z)| {
                let i = d.index(x, 1, z);
                let a = albedo[c];
                let e_sun = sun_y * (sol.total[c][i] - sol.indirect[c][i]).max(0.0);
                ((sol.indirect[c][i] / 2.0 - a * e_sun) / (1.0 + a)).max(0.0)
            })
            .collect(),
    });
    if scene.instances.len() < 2 && spec.use_grid != ForestGridUse::Always {
        return Ok((unused("a single instance has nothing to shade it; the grid lights the ground".into(), Some(grid)), ground));
    }
    if spec.use_grid == ForestGridUse::Never {
        return Ok((unused("forest_grid.use is \"never\"; the grid lights the ground".into(), Some(grid)), ground));
    }
    let free: f64 = light.free_fluence().iter().sum();
    let towards = scene.sun.towards;
    let reach: Vec<f32> = boxes
        .iter()
        .map(|b| {
            let (lo, hi) = (b.min - glam::Vec3::splat(grid.cell), b.max + glam::Vec3::splat(grid.cell));
            let mut sum = 0.0f64;
            let mut count = 0usize;
            let mut add = |p: glam::Vec3| {
                sum += (0..3).map(|c| grid.sample(&sol.total[c], p) as f64).sum::<f64>();
                count += 1;
            };
            // The top face, and each side face that looks towards the sun.
            let faces = [(1usize, 1.0f32), (0, 1.0), (0, -1.0), (2, 1.0), (2, -1.0)];
            for (axis, sign) in faces {
                if axis != 1 && towards[axis] * sign <= 0.0 {
                    continue;
                }
                for i in 0..3 {
                    for j in 0..3 {
                        let (u, v) = ((i as f32 + 0.5) / 3.0, (j as f32 + 0.5) / 3.0);
                        let mut p = lo + (hi - lo) * glam::Vec3::new(u, u, v);
                        let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
                        p[a1] = lo[a1] + (hi[a1] - lo[a1]) * u;
                        p[a2] = lo[a2] + (hi[a2] - lo[a2]) * v;
                        p[axis] = if sign > 0.0 { hi[axis] } else { lo[axis] };
                        add(p);
                    }
                }
            }
            (sum / count.max(1) as f64 / free) as f32
        })
        .collect();
    // Scattering from neighbours can lift a crown's surroundings a hair
    // above the open field's; the species grid is already lit by that field.
    let what = ("the light reaching the crowns", "all get the open field's");
    let f = decide(spec, grid, &reach, what, |r| r.min(1.0), scales);
    Ok((f, ground))
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

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_shared::scene::parse;

    #[test]
    fn the_forest_grid_keeps_each_crowns_leaf_area_where_the_crown_is() {
        let text = r#"{
            "models": { "maple": { "tree": { "species": "red_maple", "triangles": 20000, "seed": 1 } } },
            "instances": [
                { "model": "maple", "position": [0, 0, 0] },
                { "model": "maple", "position": [9, 0, 3], "rotate_y_deg": 70, "scale": 1.5 }
            ],
            "camera": { "position": [0, 6, -30], "look_at": [0, 6, 0] },
            "sun": { "elevation_deg": 50, "azimuth_deg": 30 },
            "ground": { "color": [0.2, 0.2, 0.2] }
        }"#;
        let scene = Scene::build(parse(text, "forest.json").unwrap(), &std::env::temp_dir(), "forest.json").unwrap();
        let m = &scene.models[0];
        let mm = medium_of(&scene, m, 32).unwrap();
        let area = ModelArea { frame: mm.frame, dims: mm.medium.dims, area: mm.area.unwrap() };
        // The model's own area-weighted mean height, in model space.
        let md = area.dims;
        let mut model_height = 0.0f64;
        for z in 0..md.nz {
            for y in 0..md.ny {
                for x in 0..md.nx {
                    let y_centre = area.frame.origin[1] + (y as f32 + 0.5) * area.frame.cell;
                    model_height += area.area.area[md.index(x, y, z)] as f64 * y_centre as f64;
                }
            }
        }
        model_height /= area.area.total_area;
        let boxes = scene.instances.iter().map(|i| sylva_shared::accel::scene::model_bounds(&m.model).transformed(&i.to_world));
        let grid = WorldGrid::around(boxes.fold(Aabb::EMPTY, |b, o| b.union(o)), 16);
        let (cells, _) = forest_leaf_area(&scene, &[Some(area)], &grid);
        // All of it arrives: the first instance's area plus 1.5² the second's.
        let total: f64 = cells.iter().map(|&a| a as f64).sum();
        let want = 1.0 + 1.5 * 1.5;
        let got = total / mm_total(&scene);
        assert!((got - want).abs() < 1e-3 * want, "area {got:.4}× the model's, want {want}");
        // At the crowns' height: the area-weighted mean height is the
        // instances' (1 and 1.5 × the model's), within a forest cell.
        let d = grid.dims;
        let mut height = 0.0f64;
        for z in 0..d.nz {
            for y in 0..d.ny {
                for x in 0..d.nx {
                    height += cells[d.index(x, y, z)] as f64 * (grid.origin[1] + (y as f32 + 0.5) * grid.cell) as f64;
                }
            }
        }
        height /= total;
        let want_height = (model_height + 1.5 * 1.5 * 1.5 * model_height) / want;
        assert!(
            (height - want_height).abs() <= grid.cell as f64,
            "mean height {height:.2} m, the crowns' {want_height:.2} m (cell {:.2} m)",
            grid.cell
        );
        // Above the middle of the trees' boxes, where an even spread put it.
        let even: f64 = scene
            .instances
            .iter()
            .zip([1.0, 1.5 * 1.5])
            .map(|(i, w)| {
                let b = sylva_shared::accel::scene::model_bounds(&m.model).transformed(&i.to_world);
                w * 0.5 * (b.min.y + b.max.y) as f64
            })
            .sum::<f64>()
            / want;
        assert!(height > even + 0.5 * grid.cell as f64, "mean height {height:.2} m, an even spread's {even:.2} m");
    }

    /// The model's total blocking area, solved again for the check.
    fn mm_total(scene: &Scene) -> f64 {
        medium_of(scene, &scene.models[0], 32).unwrap().area.unwrap().total_area
    }
}
