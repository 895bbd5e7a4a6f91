//! Everything a worker does to a scene before it traces: both levels of
//! acceleration, what the lighting method declares it needs (the LB light,
//! Boulanger's envelopes, the clouds: `crate::lighting`), and the upload.
//! Reports time per phase.

use crate::lighting::{
    self,
    boulanger::ModelEnvelope,
    lb::{ModelLight, SceneLb},
};
use crate::trace::{GpuScene, SceneLight, SceneStructure, StripRenderer, Tracer};
use std::sync::Arc;
use sylva_accel::SceneAccel;
use sylva_accel::coverage::{Coverage, triangle_coverage};
use sylva_light::lb::coarse::ForestLight;
use sylva_light::lb::solver::PhaseTimer;
use sylva_scene::frame::Backend;
use sylva_scene::{LightingMode, Scene};

/// A scene ready to trace, and what preparing it cost.
pub struct PreparedScene {
    /// The renderer.
    pub renderer: StripRenderer,
    /// Wall time per phase (build, voxelize, lb, upload, …); the structures'
    /// phases overlap the lighting's.
    pub phases: PhaseTimer,
    /// Bytes of the acceleration structures rays traverse (the device's,
    /// with ray queries where its allocator reports them, and the
    /// eight-wide tree's as uploaded).
    pub accel_bytes: usize,
    /// The backend rays take, and why.
    pub backend: crate::trace::BackendChoice,
    /// The LB solve per model (empty when the lighting needs none).
    pub light: Vec<ModelLight>,
    /// The coarse forest grid's decision (none when the lighting needs no LB).
    pub forest: Option<ForestLight>,
    /// The Boulanger precompute per model (empty unless that lighting).
    pub boulanger: Vec<ModelEnvelope>,
}

impl PreparedScene {
    /// Milliseconds of the lighting method's own pre-process: every phase
    /// but the traversal's (building, classifying, uploading, choosing).
    pub fn lighting_ms(&self) -> f64 {
        self.phases.0.iter().filter(|p| !TRAVERSAL_PHASES.contains(&p.name)).map(|p| p.ms).sum()
    }
}

/// The phases that prepare the traversal, whatever the lighting.
pub const TRAVERSAL_PHASES: [&str; 7] =
    ["build", "coverage", "upload", "upload rq", "choose backend", "kernels", "pipeline"];

/// What a worker keeps from one preparation for the next frames: the
/// scene's acceleration structures (the same for every view), and the LB
/// light for the sun it was solved under.
#[derive(Clone, Default)]
pub struct Reuse {
    /// Structures built before for this scene and kind.
    pub accel: Option<Arc<SceneAccel>>,
    /// Each model's triangle coverage, found before (ray queries).
    pub coverage: Option<Arc<Vec<Vec<Coverage>>>>,
    /// LB light solved before for this scene, lighting and sun.
    pub lb: Option<Arc<SceneLb>>,
    /// The clouds' LB light solved before for this scene and sun.
    pub clouds: Option<Arc<Vec<lighting::clouds::CloudGrid>>>,
    /// The scene's LB media (any sun), voxelized before.
    pub lb_media: Option<Arc<lighting::lb::LbMedia>>,
    /// Boulanger's envelopes (any sun or view), found before, with their
    /// report.
    pub envelopes: Option<Arc<lighting::boulanger::Envelopes>>,
    /// Where on disk to look for what is missing before building or
    /// solving it.
    pub disk: Option<DiskSource>,
    /// What was found there.
    pub found: crate::disk_cache::Found,
    /// `--accel auto`'s choice for this scene on this adapter, known
    /// before (measured here or taken with another worker's data); after
    /// an `auto` preparation, the choice it made or took.
    pub choice: Option<crate::share::SharedChoice>,
    /// The scene prepared before under another sun (or view), whose
    /// buffers a new light can share ([`GpuScene::relit`]).
    pub previous: Option<Arc<PreparedScene>>,
    /// Whether the last preparation built the structures itself.
    pub built: bool,
    /// Whether the last preparation solved the LB light itself.
    pub solved: bool,
    /// Whether the last preparation computed Boulanger's envelopes itself.
    pub enveloped: bool,
}

impl Reuse {
    /// What writes to the disk cache what the last preparation built or
    /// solved itself (nothing when it has no cache or made nothing): the
    /// caller runs it when the first frame no longer waits for it.
    pub fn keeper(&self, scene: &Scene) -> Option<impl FnOnce() + Send + 'static + use<>> {
        let d = self.disk.clone()?;
        let accel = self.accel.clone().filter(|_| self.built);
        let lb = self.lb.clone().filter(|_| self.solved);
        let envelopes = self.envelopes.clone().filter(|_| self.enveloped);
        if accel.is_none() && lb.is_none() && envelopes.is_none() {
            return None;
        }
        let name = crate::disk_cache::LbName::of(&d.bundle, scene, d.sun);
        Some(move || {
            // Every model has one: `boulanger::prepare` makes them all.
            let kept: Option<Vec<_>> =
                envelopes.as_ref().map(|e| e.0.iter().flatten().map(|e| e.as_ref()).collect());
            let lb = lb.as_deref().map(|l| (&name, l));
            d.cache.keep(&d.bundle, accel.as_deref(), lb, kept.as_deref());
        })
    }
}

/// A scene's prepared data on disk: the cache, the bundle's hash that names
/// its entries, and the sun key of the light asked for.
#[derive(Clone)]
pub struct DiskSource {
    /// The cache.
    pub cache: crate::DiskCache,
    /// The bundle's hash.
    pub bundle: String,
    /// The frame's sun key (`None`: the scene's own sun).
    pub sun: Option<[u32; 3]>,
}

/// Prepares `scene` for tracing with the `accel` backend (`auto`: this
/// adapter's choice, measured) and whatever the `lighting` method needs.
/// `progress` hears each step.
pub fn prepare(
    ctx: &Tracer,
    scene: &Scene,
    accel: impl Into<Backend>,
    lighting: LightingMode,
    progress: &dyn Fn(&str),
) -> anyhow::Result<PreparedScene> {
    prepare_reusing(ctx, scene, accel, lighting, &mut Reuse::default(), progress)
}

/// [`prepare`], taking what `reuse` holds instead of building it again and
/// leaving in it what was built.
pub fn prepare_reusing(
    ctx: &Tracer,
    scene: &Scene,
    accel: impl Into<Backend>,
    lighting: LightingMode,
    reuse: &mut Reuse,
    progress: &dyn Fn(&str),
) -> anyhow::Result<PreparedScene> {
    let asked = accel.into();
    // `auto` measured before for this scene on this adapter (in memory, or
    // on disk from before a restart) is not measured again.
    let adapter = ctx.adapter_name();
    let adopted = (asked == Backend::Auto)
        .then(|| {
            let known = reuse.choice.clone().filter(|c| c.adapter == adapter);
            known.or_else(|| reuse.disk.as_ref().and_then(|d| d.cache.choice(&d.bundle, &adapter)))
        })
        .flatten()
        // Another worker's word (or the disk's): only a backend, never
        // `auto` itself, and one this device can run.
        .filter(|c| c.backend.resolved().is_some())
        .filter(|c| c.backend != Backend::Rq || ctx.has_ray_queries());
    let resolved = adopted.as_ref().map_or(asked, |c| c.backend);
    let candidates = crate::trace::candidates(ctx, resolved)?;
    // A backend far behind on this adapter's last probe, of any scene, is
    // neither built nor measured for this one.
    let last_probe = (candidates.len() > 1)
        .then(|| reuse.disk.as_ref().and_then(|d| d.cache.probe(&adapter)))
        .flatten();
    let (candidates, left_behind) = match &last_probe {
        Some(last) => crate::trace::worth_measuring(candidates, last),
        None => (candidates, Vec::new()),
    };
    let needs = lighting::method(lighting).needs;
    let mut phases = PhaseTimer::default();
    // Where the backend is known, the render kernel of the lighting's
    // family compiles from the start, beside everything else until the
    // pipeline needs it. Under `auto` on a GPU every candidate's does: the
    // host's cores are otherwise idle while the scene is prepared, and the
    // one not chosen is kept for the process. On a CPU adapter the same
    // cores build and trace, so only the chosen backend's compiles.
    let family = lighting::method(lighting).kernel;
    let early = if candidates.len() == 1 || !ctx.is_cpu() { candidates.clone() } else { vec![] };
    let mut compilers: Vec<(Backend, std::thread::JoinHandle<f64>)> = early
        .into_iter()
        .map(|backend| {
            let (ctx, clouds) = (ctx.clone(), !scene.clouds.is_empty());
            let compile = std::thread::spawn(move || {
                let t = std::time::Instant::now();
                // An error here is the pipeline's to report, below.
                let _ =
                    ctx.kernels.get(&ctx, backend, clouds).map(|k| k.render(&ctx, family, false));
                t.elapsed().as_secs_f64() * 1e3
            });
            (backend, compile)
        })
        .collect();
    if let Some(d) = reuse.disk.clone() {
        let lb_for = needs.lb.then_some(d.sun);
        let envelopes = needs.envelopes;
        reuse.found =
            d.cache.fill(&d.bundle, scene, resolved.structure(), lb_for, envelopes, reuse);
    }
    let had_accel = reuse.accel.clone();
    // The structures are built on another thread while this one solves the
    // LB light: neither needs the other (phases then overlap in time).
    let structures = {
        let (accel, coverage) = (reuse.accel.clone(), reuse.coverage.clone());
        let candidates = candidates.clone();
        move || {
            let (mut accel, mut coverage, mut phases) = (accel, coverage, PhaseTimer::default());
            for &b in &candidates {
                match b.structure() {
                    Some(kind) if accel.as_ref().is_none_or(|a| a.kind != kind) => {
                        let a = phases.time("build", || SceneAccel::build(scene, kind));
                        accel = Some(Arc::new(a));
                    }
                    None if coverage.is_none() => {
                        use rayon::prelude::*;
                        let c = phases.time("coverage", || {
                            scene.models.par_iter().map(|m| triangle_coverage(&m.model)).collect()
                        });
                        coverage = Some(Arc::new(c));
                    }
                    _ => {}
                }
            }
            (accel, coverage, phases)
        }
    };
    progress("building acceleration structures");
    let lb_now = needs.lb && reuse.lb.is_none();
    let envelopes_now = needs.envelopes && reuse.envelopes.is_none();
    let (built, lb) = std::thread::scope(|s| {
        let builder = s.spawn(structures);
        let lb = lb_now
            .then(|| lighting::lb::prepare(ctx, scene, &mut reuse.lb_media, &mut phases, progress));
        // Boulanger's envelopes walk each model's own tree, not the
        // scene's: they too need nothing the builder makes.
        if envelopes_now {
            progress("Boulanger envelope distances");
            let e = phases.time("boulanger precompute", || lighting::boulanger::prepare(scene));
            reuse.envelopes = Some(Arc::new(e));
        }
        reuse.enveloped = envelopes_now;
        (builder.join(), lb)
    });
    let (accel, coverage, built_phases) =
        built.map_err(|_| anyhow::anyhow!("building the acceleration structures panicked"))?;
    phases.0.extend(built_phases.0);
    reuse.built = match (&accel, &had_accel) {
        (Some(a), Some(h)) => !Arc::ptr_eq(a, h),
        (a, _) => a.is_some(),
    };
    (reuse.accel, reuse.coverage) = (accel, coverage);
    reuse.solved = lb.is_some();
    if let Some(lb) = lb {
        reuse.lb = Some(Arc::new(lb?));
    }
    let mut light = SceneLight {
        models: vec![None; scene.models.len()],
        instance_scales: vec![1.0; scene.instances.len()],
        ..Default::default()
    };
    let (mut reports, mut forest, mut boulanger) = (Vec::new(), None, Vec::new());
    if needs.lb {
        let lb = reuse.lb.clone().expect("solved above");
        (light.models, light.instance_scales, light.ground) =
            (lb.grids.clone(), lb.scales.clone(), lb.ground.clone());
        (reports, forest) = (lb.light.clone(), Some(lb.forest.clone()));
    }
    if needs.envelopes {
        let e = reuse.envelopes.as_deref().expect("found above");
        (light.envelopes, boulanger) = (e.0.clone(), e.1.clone());
    }
    if needs.clouds && !scene.clouds.is_empty() {
        // Solved once a sun: a camera path's frames share it.
        let clouds = match &reuse.clouds {
            Some(c) => c.clone(),
            None => {
                progress("LB light of the clouds");
                let c = phases.time("cloud lb", || lighting::clouds::solve_clouds(ctx, scene))?;
                reuse.clouds.insert(Arc::new(c)).clone()
            }
        };
        light.clouds = clouds.as_ref().clone();
    }
    progress("uploading the scene");
    let structure = |b: Backend| match b {
        Backend::Rq => SceneStructure::RayQuery(reuse.coverage.as_deref().expect("found above")),
        Backend::Cwbvh => SceneStructure::Cwbvh(reuse.accel.as_deref().expect("built above")),
        _ => SceneStructure::Walk(reuse.accel.as_deref().expect("built above")),
    };
    let mut uploads = Vec::new();
    let mut candidates = candidates;
    for (i, b) in candidates.clone().into_iter().enumerate() {
        // Ray queries: the device builds its structures as the scene goes up.
        let name = match b {
            Backend::Rq => "upload rq",
            Backend::Cwbvh => "upload cwbvh",
            _ => "upload",
        };
        // Under a new sun only the light goes up, beside the buffers
        // uploaded before (the structures are the same: one candidate, the
        // backend the scene was prepared with, nothing built since).
        let before = reuse
            .previous
            .as_ref()
            .map(|p| p.renderer.scene())
            .filter(|s| candidates.len() == 1 && s.backend == b && !reuse.built);
        if let Some(s) = before
            && let Some(g) = phases.time("relight", || s.relit(ctx, &light))?
        {
            uploads.push(g);
            continue;
        }
        match phases.time(name, || GpuScene::upload(ctx, scene, structure(b), &light)) {
            Ok(g) => uploads.push(g),
            // `auto` runs without a candidate the scene does not fit (the
            // first, the BVH, fits every scene).
            Err(e) if i > 0 => {
                tracing::warn!("auto: leaving {} out: {e:#}", b.name());
                candidates.retain(|&c| c != b);
            }
            Err(e) => return Err(e),
        }
    }
    let (gpu_scene, mut backend) = if uploads.len() == 1 {
        let mut b = crate::trace::BackendChoice::asked(asked, candidates[0], ctx);
        if let Some(c) = &adopted {
            b.why = format!("{} (measured before, for this scene)", c.why);
        } else if !left_behind.is_empty() {
            b.why = format!("auto: {}, the one backend left to measure", b.backend.name());
        }
        (uploads.pop().expect("one"), b)
    } else {
        progress("measuring the traversal backends");
        phases.time("choose backend", || crate::trace::choose(ctx, scene, asked, uploads))?
    };
    if !left_behind.is_empty() {
        backend.why = format!("{}; {}", backend.why, left_behind.join("; "));
    }
    // What this probe measured, with the last probe's figures for the
    // backends it left out, is kept for the next scene on this adapter.
    if let (false, Some(d)) = (backend.probe.is_empty(), &reuse.disk) {
        let mut all = backend.probe.clone();
        let earlier: Vec<_> = last_probe
            .iter()
            .flatten()
            .filter(|t| !all.iter().any(|n| n.backend == t.backend))
            .cloned()
            .collect();
        all.extend(earlier);
        d.cache.keep_probe(&adapter, &all);
    }
    if asked == Backend::Auto {
        let measured = adopted.is_none();
        let c = adopted.unwrap_or_else(|| crate::share::SharedChoice {
            adapter,
            backend: backend.backend,
            why: backend.why.clone(),
        });
        if let (true, Some(d)) = (measured, &reuse.disk) {
            d.cache.keep_choice(&d.bundle, &c);
        }
        reuse.choice = Some(c);
    }
    let accel_bytes = match gpu_scene.backend {
        Backend::Rq => gpu_scene.rq.as_ref().and_then(|r| r.bytes).unwrap_or(0) as usize,
        // The eight-wide tree exists on the device only (derived at upload).
        Backend::Cwbvh => gpu_scene.structure_bytes as usize,
        _ => reuse.accel.as_ref().map_or(0, |a| a.bytes()),
    };
    // The chosen backend's compile is waited for; another candidate's
    // goes on (its kernel is kept in the process's cache).
    if let Some(i) = compilers.iter().position(|(b, _)| *b == gpu_scene.backend)
        && let Ok(ms) = compilers.swap_remove(i).1.join()
    {
        phases.0.push(sylva_light::lb::solver::Phase { name: "kernels", ms });
    }
    let renderer = phases.time("pipeline", || -> anyhow::Result<StripRenderer> {
        let r = StripRenderer::new(ctx, gpu_scene, scene)?;
        // The family's kernel, unless compiled above: a frame's first
        // dispatch is not to be timed as its trace.
        r.kernels().render(ctx, family, false)?;
        ctx.wait()?;
        Ok(r)
    })?;
    // What was compiled for this preparation, kept for the next process.
    ctx.save_kernels();
    Ok(PreparedScene { renderer, phases, backend, accel_bytes, light: reports, forest, boulanger })
}
