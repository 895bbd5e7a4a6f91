//! `lb` and `lb-visualize`: the lattice-Boltzmann light of each model,
//! solved on its own grid in the open, scaled per instance by the coarse
//! grid over the whole forest, which also lights the ground under the
//! stand. The model itself (lattice, collision, boundaries, radiometry)
//! lives in `sylva_light::lb`; this module runs it on the GPU for a scene.
//!
//! - [`forest`]: the forest grid.
//! - [`auto`]: `--lb-grid auto`, the smallest grid the image cannot tell from the next.

pub mod auto;
pub mod forest;

use super::method::{Kernel, Method, Needs};
use crate::gpu::GpuContext;
use forest::GroundLight;
use serde::Serialize;
use sylva_light::lb::coarse::{ForestLight, ModelArea};
use sylva_light::lb::solver::PhaseTimer;
use sylva_light::lb::{
    GridDims, Illumination, LbGrid, LbParams, LightingSolver, MediumGrid, NodeClass, SolveOptions,
    Sun, solve, solve_indirect,
};
use sylva_light::voxel::{GridFrame, leaf_area_in, medium_from_density, voxelize_in};
use sylva_proto::pb;
use sylva_scene::model::Model;
use sylva_scene::{LbModel, LightingMode, Scene, SceneModel};

/// `lb`: the direct sun plus the LB light.
pub const METHOD: Method = Method {
    mode: LightingMode::Lb,
    code: pb::Lighting::Lb as u32,
    wgsl: "LIGHTING_LB",
    kernel: Kernel::Direct,
    needs: Needs { lb: true, envelopes: false, clouds: true },
};

/// `lb-visualize`: the LB light alone, as the paper's figures show it.
pub const VISUALIZE: Method = Method {
    mode: LightingMode::LbVisualize,
    code: pb::Lighting::LbVisualize as u32,
    wgsl: "LIGHTING_LB_VISUALIZE",
    kernel: Kernel::Direct,
    needs: Needs { lb: true, envelopes: false, clouds: true },
};

/// What the LB pre-process did for one model.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct ModelLight {
    /// Model name.
    pub model: String,
    /// Grid size N asked for (about N³ nodes).
    pub grid: usize,
    /// The grid's nodes per axis, fitted to the model's bounds.
    pub dims: GridDims,
    /// Which LB model ("grounded" or "paper").
    pub lb_model: String,
    /// Preset (the paper model) or "leaf optics" (the grounded one).
    pub preset: String,
    /// Single-scattering albedo σ_s/σ_t per channel.
    pub albedo: [f32; 3],
    /// Henyey–Greenstein g per channel.
    pub g: [f32; 3],
    /// Blocking area (one-sided leaf area plus half the wood's), model units² (grounded).
    pub leaf_area: Option<f64>,
    /// Fraction of leaf area the alpha masks cut away (grounded).
    pub alpha_cut: Option<f64>,
    /// Sub-cells per cell edge whose columns gave each cell its gap
    /// fraction, so leaf clumps finer than the grid stop what they stop (grounded).
    pub clumping_sub: Option<usize>,
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
    /// What solved it: "cpu (N threads)" where the adapter is the CPU
    /// itself, else the GPU adapter ([`crate::lb::Backend::for_adapter`]).
    pub solver: String,
}

/// A model's LB medium, ready to solve.
struct ModelMedium {
    frame: GridFrame,
    medium: MediumGrid,
    params: LbParams,
    /// The grounded model's leaf area on its grid (none for the paper's),
    /// which the forest grid also gathers.
    area: Option<ModelArea>,
    /// Whether every instance stands on the scene's ground (the grid's
    /// lower face within a cell of it), so the lattice's floor reflects.
    on_ground: bool,
}

/// Whether every instance of `m` has its grid's lower face within one
/// cell of the ground plane y = 0.
fn stands_on_ground(scene: &Scene, m: &SceneModel, frame: &GridFrame) -> bool {
    let mut instances = scene
        .instances
        .iter()
        .filter(|i| std::ptr::eq(&scene.models[i.model as usize], m))
        .peekable();
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
    let r = model
        .triangles
        .iter()
        .flatten()
        .map(|&i| model.positions[i as usize])
        .map(|p| (p.x * p.x + p.z * p.z).sqrt())
        .fold(0.0f32, f32::max);
    Some((glam::Vec3::new(-r, lo.y, -r).min(lo), glam::Vec3::new(r, hi.y, r).max(hi)))
}

/// One model's LB medium on a grid of about `n³` nodes fitted to its bounds.
/// The grounded model derives a plant's medium from its leaf area and
/// optics; a solid or a non-plant medium (the PMMA teapot) keeps its
/// voxels and its preset in both models, only lit differently.
fn medium_of(scene: &Scene, m: &SceneModel, n: usize) -> anyhow::Result<ModelMedium> {
    let (lo, hi) =
        lb_bounds(&m.model).ok_or_else(|| anyhow::anyhow!("model {} has no triangles", m.name))?;
    let (frame, dims) = GridFrame::fit(lo, hi, n);
    let leaves = scene.file.lb_model == LbModel::Grounded && m.lb.preset.is_plant() && !m.lb.solid;
    let on_ground = stands_on_ground(scene, m, &frame);
    match leaves {
        true => {
            let area = leaf_area_in(&m.model, &scene.file.leaf_optics, frame, dims);
            let medium = medium_from_density(&area.density, dims);
            Ok(ModelMedium {
                frame,
                medium,
                params: area.scattering.params(),
                area: Some(ModelArea { frame, dims, area }),
                on_ground,
            })
        }
        false => {
            let mut v = voxelize_in(&m.model, frame, dims)?;
            if !m.lb.preset.is_plant() {
                v.medium.class.iter_mut().for_each(|c| *c = NodeClass::Medium);
            }
            if m.lb.solid {
                let class =
                    if m.lb.preset.is_plant() { NodeClass::Green } else { NodeClass::Medium };
                sylva_light::voxel::fill_interior(&mut v, class);
            }
            Ok(ModelMedium {
                frame,
                medium: v.medium,
                params: LbParams::from_preset(m.lb.preset),
                area: None,
                on_ground,
            })
        }
    }
}

/// Solves one model's medium. The grounded model keeps the light the
/// tracer does not add (scattered sun, sky) in physical units; the paper
/// model keeps the total density of a unit sun.
fn solve_medium(
    solver: &mut dyn LightingSolver,
    scene: &Scene,
    m: &SceneModel,
    mm: &ModelMedium,
    n: usize,
) -> anyhow::Result<(LbGrid, ModelLight)> {
    let opts = SolveOptions::default();
    let (rgb, steps, converged, uncollided_steps): (
        Vec<f32>,
        [usize; 3],
        [bool; 3],
        Option<usize>,
    ) = match scene.file.lb_model {
        LbModel::Grounded => {
            let light =
                Illumination { floor_reflects: mm.on_ground, ..Illumination::of_scene(scene) };
            let s = solve_indirect(solver, &mm.medium, &mm.params, &light, &opts, &|_| {})?;
            let r = &s.reports;
            let mut rgb = s.indirect.concat();
            if let Some(ModelArea { area, .. }) = &mm.area {
                // The light a node's own leaves receive, not the node's mean.
                let n = area.readout.len();
                rgb.iter_mut().enumerate().for_each(|(i, v)| *v *= area.readout[i % n]);
            }
            (
                rgb,
                std::array::from_fn(|c| r[c].steps),
                std::array::from_fn(|c| r[c].converged),
                Some(r[3].steps),
            )
        }
        LbModel::Paper => {
            let s = solve(solver, &mm.medium, &mm.params, &sun_of(scene)?, &opts, &|_, _, _| {})?;
            let r = |c: usize| &s.channels[c].report;
            let rgb = s.channels.iter().flat_map(|c| c.total.iter().copied()).collect();
            (
                rgb,
                std::array::from_fn(|c| r(c).steps),
                std::array::from_fn(|c| r(c).converged),
                None,
            )
        }
    };
    let warnings =
        sylva_light::studies::limits::lb_warnings(&mm.params, &mm.medium, &sun_of(scene)?)
            .into_iter()
            .map(|w| format!("{}: {}", w.kind, w.message))
            .collect();
    let p = &mm.params.channels;
    let report = ModelLight {
        model: m.name.clone(),
        grid: n,
        dims: mm.medium.dims,
        lb_model: scene.file.lb_model.name().to_string(),
        preset: if mm.area.is_some() { "leaf optics" } else { m.lb.preset.name() }.to_string(),
        albedo: std::array::from_fn(|c| p[c].sigma_s / p[c].sigma_t()),
        g: std::array::from_fn(|c| p[c].g),
        leaf_area: mm.area.as_ref().map(|a| a.area.total_area),
        alpha_cut: mm.area.as_ref().map(|a| a.area.cut_fraction),
        clumping_sub: mm.area.as_ref().map(|a| a.area.clumping_sub),
        occupancy: mm.medium.occupancy(),
        steps,
        converged,
        uncollided_steps,
        reflecting_floor: scene.file.lb_model == LbModel::Grounded && mm.on_ground,
        warnings,
        solver: solver.name(),
    };
    Ok((
        LbGrid { dims: mm.medium.dims, frame: mm.frame, rgb, occupancy: mm.medium.occupancy() },
        report,
    ))
}

/// Builds and solves one model's grid of about `n³` nodes.
pub(crate) fn solve_model(
    solver: &mut dyn LightingSolver,
    scene: &Scene,
    m: &SceneModel,
    n: usize,
) -> anyhow::Result<(LbGrid, ModelLight)> {
    solve_medium(solver, scene, m, &medium_of(scene, m, n)?, n)
}

/// The LB light of a scene, ready to upload, and what it took.
#[derive(Clone, serde::Serialize, serde::Deserialize)]
pub struct SceneLb {
    /// Each model's light (indexed by model).
    pub grids: Vec<Option<LbGrid>>,
    /// Each instance's scale from the forest grid.
    pub scales: Vec<f32>,
    /// The ground under the stand, lit by the forest grid (grounded model).
    pub ground: Option<GroundLight>,
    /// What each model's solve did.
    pub light: Vec<ModelLight>,
    /// What the forest grid decided.
    pub forest: ForestLight,
}

/// Every model's LB medium, which the sun does not change: a sequence's
/// new sun solves the light again on these, not voxelizes again.
pub struct LbMedia {
    /// The grid size each model was voxelized at (they are kept for these).
    grids: Vec<usize>,
    /// Per model, its medium.
    media: Vec<ModelMedium>,
}

impl LbMedia {
    /// Voxelizes every model of `scene` at its LB grid, in parallel.
    pub fn of(scene: &Scene) -> anyhow::Result<Self> {
        use rayon::prelude::*;
        let media = scene
            .models
            .par_iter()
            .map(|m| medium_of(scene, m, m.lb.grid))
            .collect::<anyhow::Result<Vec<_>>>()?;
        Ok(Self { grids: scene.models.iter().map(|m| m.lb.grid).collect(), media })
    }

    /// Whether these media are `scene`'s (its models' grids unchanged).
    pub fn fits(&self, scene: &Scene) -> bool {
        self.grids.iter().copied().eq(scene.models.iter().map(|m| m.lb.grid))
    }

    /// Bytes held, for caches' budgets.
    pub fn bytes(&self) -> u64 {
        let per_node = |mm: &ModelMedium| {
            let leaf = mm.area.as_ref().map_or(0, |a| 3 * a.area.density.len());
            mm.medium.density.len() + mm.medium.class.len() / 4 + leaf
        };
        (self.media.iter().map(per_node).sum::<usize>() * 4) as u64
    }
}

/// Voxelizes every model (unless `media` holds them already) and solves
/// it, then the forest grid; times each phase ("voxelize", "lb", "forest
/// lb") into `phases` and leaves the media in `media` for the next sun.
pub fn prepare(
    ctx: &GpuContext,
    scene: &Scene,
    media: &mut Option<std::sync::Arc<LbMedia>>,
    phases: &mut PhaseTimer,
    progress: &dyn Fn(&str),
) -> anyhow::Result<SceneLb> {
    let kept = media.clone().filter(|m| m.fits(scene));
    let media = match kept {
        Some(m) => m,
        None => {
            progress("voxelizing models");
            let m = std::sync::Arc::new(phases.time("voxelize", || LbMedia::of(scene))?);
            *media = Some(m.clone());
            m
        }
    };
    let mut grids = Vec::new();
    let mut light = Vec::new();
    phases.time("lb", || -> anyhow::Result<()> {
        let solved: Vec<anyhow::Result<(LbGrid, ModelLight)>> = if ctx.is_cpu() {
            // The CPU solver runs each solve on every core already.
            let mut solver = crate::lb::scene_solver(ctx);
            let mut solved = Vec::new();
            for (m, mm) in scene.models.iter().zip(&media.media) {
                progress(&format!("LB light of {} ({})", m.name, mm.medium.dims));
                let one = solve_medium(solver.as_mut(), scene, m, mm, m.lb.grid);
                let failed = one.is_err();
                solved.push(one);
                if failed {
                    break;
                }
            }
            solved
        } else {
            // On a GPU the species are solved side by side: each solve's
            // kernels are generated for its grid and collision, and their
            // compiles, the host's work, run in parallel (the device's
            // steps take turns). A pool of its own, at most a thread a
            // core, however many models a scene holds: the solves block on
            // the device, and the global pool is building the structures.
            use rayon::prelude::*;
            progress(&format!("LB light of {} models", scene.models.len()));
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(cores.min(scene.models.len()).max(1))
                .build()?;
            pool.install(|| {
                scene
                    .models
                    .par_iter()
                    .zip(&media.media)
                    .map(|(m, mm)| {
                        let mut solver = crate::lb::scene_solver(ctx);
                        solve_medium(solver.as_mut(), scene, m, mm, m.lb.grid)
                    })
                    .collect()
            })
        };
        for (m, result) in scene.models.iter().zip(solved) {
            let (grid, report) = result?;
            for w in &report.warnings {
                warn_once(&m.name, w);
            }
            light.push(report);
            grids.push(Some(grid));
        }
        Ok(())
    })?;
    let mut scales = vec![1.0f32; scene.instances.len()];
    progress("LB light of the whole forest");
    let (forest, ground) =
        phases.time("forest lb", || -> anyhow::Result<(ForestLight, Option<GroundLight>)> {
            match scene.file.lb_model {
                LbModel::Paper => Ok((forest::paper(ctx, scene, &grids, &mut scales)?, None)),
                LbModel::Grounded => {
                    let areas: Vec<_> = media.media.iter().map(|mm| mm.area.as_ref()).collect();
                    forest::grounded(ctx, scene, &areas, &mut scales)
                }
            }
        })?;
    Ok(SceneLb { grids, scales, ground, light, forest })
}

impl SceneLb {
    /// Bytes of light it holds (the grids and the ground's), for caches.
    pub fn bytes(&self) -> u64 {
        let grids: usize = self.grids.iter().flatten().map(|g| g.rgb.len()).sum();
        ((grids + self.ground.as_ref().map_or(0, |g| g.rgb.len())) * std::mem::size_of::<f32>()
            + self.scales.len() * 4) as u64
    }
}

/// The scene's sun as the paper model's boundary takes it (unit strength).
pub(crate) fn sun_of(scene: &Scene) -> anyhow::Result<Sun> {
    Ok(Sun::towards(scene.sun.towards.as_dvec3().to_array(), 1.0)?)
}

/// Logs an LB warning about `model` at warn level the first time this
/// process meets its kind for that model (the text before its first
/// colon: "thin", "small-grid", …), at debug level after: a sequence
/// solves every model again for each sun, and the same finding repeated
/// per model per frame buried everything else. The stats carry every
/// frame's warnings whole.
fn warn_once(model: &str, warning: &str) {
    use std::collections::HashSet;
    use std::sync::{LazyLock, Mutex};
    static SAID: LazyLock<Mutex<HashSet<(String, String)>>> = LazyLock::new(Default::default);
    let kind = warning.split(':').next().unwrap_or(warning).to_string();
    let first = {
        let mut said = sylva_proto::sync::lock(&SAID);
        // A bound for a worker that meets scenes without end.
        if said.len() >= 4096 {
            said.clear();
        }
        said.insert((model.to_string(), kind))
    };
    if first {
        tracing::warn!(model, "LB: {warning}");
    } else {
        tracing::debug!(model, "LB: {warning}");
    }
}
