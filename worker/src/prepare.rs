//! Everything a worker does to a scene before it traces: both levels of
//! acceleration, each model voxelized and lit by the LB solver, and the
//! upload. Reports time per phase.

use crate::gpu::GpuContext;
use crate::lb::GpuSolver;
use crate::trace::{GpuScene, LbGrid, StripRenderer};
use serde::Serialize;
use sylva_shared::accel::{AccelKind, SceneAccel};
use sylva_shared::lb::solver::PhaseTimer;
use sylva_shared::lb::{SolveOptions, Sun, solve};
use sylva_shared::scene::{LightingMode, Scene};
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
}

/// Prepares `scene` for tracing with `kind` structures; `lighting` decides
/// whether the LB pre-process runs. `progress` hears each step.
pub fn prepare(
    ctx: &GpuContext,
    scene: &Scene,
    kind: AccelKind,
    lighting: LightingMode,
    progress: &dyn Fn(&str),
) -> anyhow::Result<PreparedScene> {
    let mut phases = PhaseTimer::default();
    progress("building acceleration structures");
    let accel = phases.time("build", || SceneAccel::build(scene, kind));
    let needs_lb = lighting != LightingMode::Local;
    let mut grids: Vec<Option<LbGrid>> = vec![None; scene.models.len()];
    let mut light = Vec::new();
    if needs_lb {
        progress("voxelizing models");
        let voxels = phases.time("voxelize", || {
            scene.models.iter().map(|m| voxelize(&m.model, m.lb.grid)).collect::<Result<Vec<_>, _>>()
        })?;
        let sun = Sun::towards(scene.sun.towards.as_dvec3().to_array(), 1.0)?;
        let mut solver = GpuSolver::new(ctx.clone());
        phases.time("lb", || -> anyhow::Result<()> {
            for (i, (m, v)) in scene.models.iter().zip(&voxels).enumerate() {
                progress(&format!("LB light of {} ({}³)", m.name, m.lb.grid));
                let s = solve(&mut solver, &v.medium, &m.lb.preset.params(), &sun, &SolveOptions::default(), &|_, _, _| {})?;
                light.push(ModelLight {
                    model: m.name.clone(),
                    grid: m.lb.grid,
                    preset: m.lb.preset.name(),
                    occupancy: v.medium.occupancy(),
                    steps: std::array::from_fn(|c| s.channels[c].report.steps),
                    converged: std::array::from_fn(|c| s.channels[c].report.converged),
                });
                let rgb = s.channels.iter().flat_map(|c| c.total.iter().copied()).collect();
                grids[i] = Some(LbGrid { n: m.lb.grid, frame: v.frame, rgb });
            }
            Ok(())
        })?;
    }
    progress("uploading the scene");
    let renderer = phases.time("upload", || -> anyhow::Result<StripRenderer> {
        let gpu_scene = GpuScene::upload(ctx, scene, &accel, &grids)?;
        let r = StripRenderer::new(ctx, gpu_scene, scene)?;
        ctx.wait()?;
        Ok(r)
    })?;
    Ok(PreparedScene { renderer, phases, accel_bytes: accel.bytes(), light })
}
