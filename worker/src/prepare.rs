//! Everything a worker does to a scene before it traces: both levels of
//! acceleration, what the lighting method declares it needs (the LB light,
//! Boulanger's envelopes, the clouds: `crate::lighting`), and the upload.
//! Reports time per phase.

use crate::gpu::GpuContext;
use crate::lighting::{
    self,
    boulanger::ModelEnvelope,
    lb::{ModelLight, SceneLb},
};
use crate::trace::{GpuScene, SceneLight, StripRenderer};
use std::sync::Arc;
use sylva_accel::{AccelKind, SceneAccel};
use sylva_light::lb::coarse::ForestLight;
use sylva_light::lb::solver::PhaseTimer;
use sylva_scene::{LightingMode, Scene};

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

/// What a worker keeps from one preparation for the next frames: the
/// scene's acceleration structures (the same for every view), and the LB
/// light for the sun it was solved under.
#[derive(Clone, Default)]
pub struct Reuse {
    /// Structures built before for this scene and kind.
    pub accel: Option<Arc<SceneAccel>>,
    /// LB light solved before for this scene, lighting and sun.
    pub lb: Option<Arc<SceneLb>>,
}

/// Prepares `scene` for tracing with `kind` structures and whatever the
/// `lighting` method needs. `progress` hears each step.
pub fn prepare(
    ctx: &GpuContext,
    scene: &Scene,
    kind: AccelKind,
    lighting: LightingMode,
    progress: &dyn Fn(&str),
) -> anyhow::Result<PreparedScene> {
    prepare_reusing(ctx, scene, kind, lighting, &mut Reuse::default(), progress)
}

/// [`prepare`], taking what `reuse` holds instead of building it again and
/// leaving in it what was built.
pub fn prepare_reusing(
    ctx: &GpuContext,
    scene: &Scene,
    kind: AccelKind,
    lighting: LightingMode,
    reuse: &mut Reuse,
    progress: &dyn Fn(&str),
) -> anyhow::Result<PreparedScene> {
    let needs = lighting::method(lighting).needs;
    let mut phases = PhaseTimer::default();
    let accel = match &reuse.accel {
        Some(a) => a.clone(),
        None => {
            progress("building acceleration structures");
            let a = Arc::new(phases.time("build", || SceneAccel::build(scene, kind)));
            reuse.accel = Some(a.clone());
            a
        }
    };
    let mut light = SceneLight {
        models: vec![None; scene.models.len()],
        instance_scales: vec![1.0; scene.instances.len()],
        ..Default::default()
    };
    let (mut reports, mut forest, mut boulanger) = (Vec::new(), None, Vec::new());
    if needs.lb {
        let lb = match &reuse.lb {
            Some(lb) => lb.clone(),
            None => {
                let lb = Arc::new(lighting::lb::prepare(ctx, scene, &mut phases, progress)?);
                reuse.lb = Some(lb.clone());
                lb
            }
        };
        (light.models, light.instance_scales, light.ground) =
            (lb.grids.clone(), lb.scales.clone(), lb.ground.clone());
        (reports, forest) = (lb.light.clone(), Some(lb.forest.clone()));
    }
    if needs.envelopes {
        progress("Boulanger envelope distances");
        (light.envelopes, boulanger) =
            phases.time("boulanger precompute", || lighting::boulanger::prepare(scene));
    }
    if needs.clouds && !scene.clouds.is_empty() {
        progress("LB light of the clouds");
        light.clouds = phases.time("cloud lb", || lighting::clouds::solve_clouds(ctx, scene))?;
    }
    progress("uploading the scene");
    let renderer = phases.time("upload", || -> anyhow::Result<StripRenderer> {
        let gpu_scene = GpuScene::upload(ctx, scene, &accel, &light)?;
        let r = StripRenderer::new(ctx, gpu_scene, scene)?;
        ctx.wait()?;
        Ok(r)
    })?;
    Ok(PreparedScene {
        renderer,
        phases,
        accel_bytes: accel.bytes(),
        light: reports,
        forest,
        boulanger,
    })
}
