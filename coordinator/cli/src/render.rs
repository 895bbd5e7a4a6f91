//! `sylva render SCENE -o out.png`: by default starts a coordinator and
//! `--local-workers` worker processes on loopback and renders through them
//! (the farm's own gRPC path); `--local-workers 0` loads, prepares and
//! traces the scene in this process. Either way the whole frame is
//! tone-mapped once and written with its stats.

use crate::flags::render::*;
use crate::in_process::InProcess;
use crate::pilot::{self, Goal};
use crate::progress;
use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;
use sylva_coordinator::executor::{StripExecutor, even_strips};
use sylva_scene::film::{HdrImage, reinhard, write_png};
use sylva_scene::frame::Backend;
use sylva_scene::{LightingMode, Scene};
use sylva_worker::frame::reference::{MIN_BATCH_SPP, ReferenceOptions};
use sylva_worker::frame::{Frame, Fresh, Given, Preparer};
use sylva_worker::prepare::{DiskSource, Reuse};
use sylva_worker::trace::Tracer;

use crate::spec::job_spec;
use sylva_scene::frame::{FrameSettings, MAX_SPP};
use sylva_scene::sequence::View;
use sylva_scene::{FileAccess, SceneLimits};
/// Columns per strip, for the progress bar.
const STRIP: u32 = 64;

pub fn run(mut a: RenderArgs) -> anyhow::Result<()> {
    crate::flags::render::exr_named(&mut a.out, &mut a.exr);
    let request = a.frame.settings();
    request.check()?;
    let goal = a.goal()?;
    let mut phases: Vec<(&str, f64)> = Vec::new();
    let t = Instant::now();
    let folder = sylva_scene::folder_of(&a.scene);
    let remote = a.local_workers > 0 || !a.workers.is_empty();
    if a.allow_files_outside_scene && remote {
        bail!(
            "--allow-files-outside-scene works in this process only (add --local-workers 0): a bundle holds just the scene folder's files"
        );
    }
    let access = if a.allow_files_outside_scene {
        FileAccess::Anywhere(folder)
    } else {
        FileAccess::Inside(folder)
    };
    let mut scene = Scene::load_with(&a.scene, &access, &SceneLimits::UNLIMITED)?;
    phases.push(("load", ms(t)));
    let grid_choice = match a.lb_grid.as_deref() {
        None => None,
        Some(_) if a.local_workers > 0 || !a.workers.is_empty() => {
            bail!(
                "--lb-grid works in this process only: add --local-workers 0, or set \"lb\": {{ \"grid\": N }} in the scene"
            )
        }
        Some("auto") => Some(()),
        Some(n) => {
            let n: usize = n
                .parse()
                .ok()
                .filter(|n| (4..=256).contains(n))
                .with_context(|| format!("--lb-grid {n:?}: a size in [4, 256] or auto"))?;
            for m in &mut scene.models {
                m.lb.grid = n;
            }
            None
        }
    };
    let lighting = request.lighting_or(scene.lighting);
    let accel = request.accel;
    let views = a.frame.views(&scene.file)?;
    if goal.is_some() && request.denoise.is_on() {
        bail!(
            "--lighting auto chooses whether to denoise (it measures the path tracer denoised beside the other methods): leave out --denoise"
        );
    }
    if goal.is_some() && (remote || grid_choice.is_some() || a.lb_grid.is_some()) {
        bail!(
            "--lighting auto runs its pilot and the frame in this process and picks the LB grid itself: add --local-workers 0, leave out --lb-grid"
        );
    }
    if remote {
        return render_through_coordinator(&a, &request, &views, &scene, lighting, accel, phases);
    }
    if !views.is_empty() {
        if grid_choice.is_some() {
            bail!("--lb-grid auto chooses for one frame: give a sequence its grids (--lb-grid N)");
        }
        let tracer = Tracer::new()?;
        let (request, scene, auto, reuse) = match goal {
            Some(goal) => {
                let c =
                    choose_for_sequence(&a, &tracer, &request, &scene, &views, goal, &mut phases)?;
                // The pilot ran on the middle frame's view and sun.
                let sun = views[views.len() / 2].sun_key();
                (c.frame, c.scene, Some(c.report), Some((c.reuse, sun)))
            }
            None => (request, scene, None, None),
        };
        let s = Sequence { tracer: &tracer, request: &request, scene: &scene, views: &views };
        return render_sequence_here(&a, s, phases, auto, reuse);
    }
    render_here(&a, &request, scene, grid_choice.is_some(), goal, phases)
}

/// The in-process pipeline: the frame composed on this process's GPU
/// (`sylva_worker::frame`), then traced as strips, or path traced until
/// the reference's own error is low enough.
fn render_here(
    a: &RenderArgs,
    request: &FrameSettings,
    scene: Scene,
    choose_grids: bool,
    goal: Option<Goal>,
    mut phases: Vec<(&'static str, f64)>,
) -> anyhow::Result<()> {
    let tracer = Tracer::new()?;
    let c = compose_here(a, &tracer, request, scene, choose_grids, goal, &mut phases)?;
    // The reference converges by its own error; `auto`'s path tracer
    // takes the samples the pilot chose, as a frame of strips.
    if c.frame.settings.lighting == LightingMode::Reference && c.auto.is_none() {
        return render_reference_here(a, &c.frame, &c.scene, c.request.accel, phases);
    }
    render_strips_here(a, &tracer, c, phases)
}

/// A sequence in this process: each view's frame composed through the
/// frame layer over one preparation (structures built once, the LB light
/// kept per sun), traced as strips, and written as the farm writes it —
/// numbered PNGs tone-mapped with the middle frame's exposure, EXRs when
/// asked, the contact sheet and the animated preview — so its files are
/// the farm's byte for byte. The middle frame renders first, so every
/// other frame is tone-mapped and encoded as it comes: the process holds
/// one frame's pixels at a time.
fn render_sequence_here(
    a: &RenderArgs,
    Sequence { tracer, request, scene, views }: Sequence<'_>,
    mut phases: Vec<(&'static str, f64)>,
    auto: Option<pilot::Report>,
    reuse: Option<(Reuse, Option<[u32; 3]>)>,
) -> anyhow::Result<()> {
    use sylva_coordinator::results::encode_png;
    use sylva_scene::film::reinhard_like;
    let disk = match a.prepared_cache.open()? {
        Some(cache) => {
            tracer.keep_kernels_in(cache.dir());
            let bundle = sylva_scene::bundle::pack(&a.scene)?.hash;
            Some(DiskSource { cache, bundle, sun: None })
        }
        None => None,
    };
    // Going on from what the pilot made, where it ran.
    let (reuse, sun) = reuse.unwrap_or_default();
    let mut fresh = Fresh::with_reuse(Reuse { disk, ..reuse }, sun);
    let n = views.len();
    let plan = even_strips(a.frame.width, STRIP);
    let bar = ProgressBar::new((n * plan.len()) as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} strips {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let say = |m: &str| progress::stage(&bar, m);
    let (mut pngs, mut exrs) = (vec![Vec::new(); n], vec![Vec::new(); n]);
    let want_exr = a.exr || !a.frame.passes.is_empty();
    let (mut exposure, mut lighting) = (None, request.lighting_or(scene.lighting));
    let (mut prepare_ms, mut trace_ms, mut rays) = (0.0, 0.0, 0u64);
    // Each frame's cost in the order rendered: the first pays for the
    // scene, the others for their sun's light and their trace.
    let mut per_frame = Vec::with_capacity(n);
    let t_all = Instant::now();
    let order = std::iter::once(n / 2).chain((0..n).filter(|&i| i != n / 2));
    for i in order {
        bar.set_message(format!("frame {}/{n}", i + 1));
        let t = Instant::now();
        let frame = Frame::compose(
            tracer,
            scene,
            &FrameSettings { view: views[i], ..*request },
            &mut fresh,
            &say,
        )?;
        let frame_prepare_ms = ms(t);
        prepare_ms += frame_prepare_ms;
        lighting = frame.settings.lighting;
        let t = Instant::now();
        let mut rendered = InProcess::new(&frame).render(&plan, &|_| bar.inc(1))?;
        let frame_trace_ms = ms(t);
        trace_ms += frame_trace_ms;
        // Each frame whole, before its tone map, as the farm does it.
        rendered.denoise(request.denoise)?;
        per_frame.push(json!({
            "frame": i,
            "prepare_ms": frame_prepare_ms,
            "trace_ms": frame_trace_ms,
            "phases_ms": frame.prepared.phases,
        }));
        rays += rendered.rays.primary + rendered.rays.shadow;
        // The farm keeps one exposure for a sequence, its middle frame's.
        let e = exposure.get_or_insert_with(|| reinhard(&rendered.image, 0.18).1);
        let ldr = reinhard_like(&rendered.image, e);
        pngs[i] = encode_png(rendered.image.width, rendered.image.height, &ldr)?;
        if want_exr {
            exrs[i] = rendered.exr()?;
        }
    }
    if let Some(keep) = fresh.reuse.keeper(scene) {
        keep();
    }
    bar.finish_and_clear();
    phases.push(("prepare", prepare_ms));
    phases.push(("trace", trace_ms));
    let sequence_ms = ms(t_all);
    phases.push(("sequence", sequence_ms));
    let written =
        sylva_coordinator::sequence::write_all(&a.out, &pngs, want_exr.then_some(&exrs[..]))?;
    let names = |i: usize| written.get(i).map(|p| p.display().to_string()).unwrap_or_default();
    let wrote = format!(
        "{} … {}, {}, {}",
        names(0),
        names(n - 1),
        names(written.len() - 2),
        names(written.len() - 1)
    );
    let accel = request.accel;
    let stats = with_head(
        a,
        None,
        accel,
        lighting,
        &phases,
        json!({
            "adapter": tracer.summary(),
            "views": views,
            "written": written,
            "tone_map": exposure,
            "rays": { "primary_and_shadow": rays, "mrays_per_second": rays as f64 / (trace_ms / 1e3) / 1e6 },
            "frame_ms": sequence_ms / n as f64,
            "frames": per_frame,
        }),
    );
    let mut how = format!(
        "{n} frames in this process in {sequence_ms:.0} ms ({:.0} ms a frame: {:.0} preparing, {:.0} tracing)",
        sequence_ms / n as f64,
        prepare_ms / n as f64,
        trace_ms / n as f64
    );
    let mut stats = stats;
    if let Some(r) = &auto {
        stats["auto"] = serde_json::to_value(r)?;
        how += &format!("; --lighting auto chose {}", r.why);
    }
    report_wrote(a, &stats, accel, lighting, &how, &wrote)
}

/// What a sequence renders in this process: its frames' settings, scene
/// and views, on one GPU.
struct Sequence<'a> {
    tracer: &'a Tracer,
    request: &'a FrameSettings,
    scene: &'a Scene,
    views: &'a [View],
}

/// A spinner for work whose length is not known, with its message.
fn spinner() -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} {elapsed}").expect("valid template"),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

/// `--lighting auto` for a sequence: the pilot on the view of its middle
/// frame (the one that renders first), each method priced over the whole
/// job: its preparation once, its light once a sun, its frame every frame.
fn choose_for_sequence(
    a: &RenderArgs,
    tracer: &Tracer,
    request: &FrameSettings,
    scene: &Scene,
    views: &[View],
    goal: Goal,
    phases: &mut Vec<(&'static str, f64)>,
) -> anyhow::Result<pilot::Choice> {
    let bar = spinner();
    let say = |m: &str| progress::stage(&bar, m);
    let t = Instant::now();
    let middle = FrameSettings { view: views[views.len() / 2], ..*request };
    let plan = even_strips(a.frame.width, STRIP);
    let job = pilot::Job::of(views);
    let c = pilot::choose(tracer, scene, &middle, &plan, goal, job, &say)?;
    phases.push(("pilot", ms(t)));
    bar.finish_and_clear();
    tracing::info!(chosen = %c.report.chosen.name, "--lighting auto: {}", c.report.why);
    Ok(c)
}

/// A frame composed in this process, and what was chosen on the way.
struct Composed {
    frame: Frame,
    /// The scene as rendered (with the grids the pilot or `--lb-grid auto` chose).
    scene: Scene,
    /// The frame's settings (the method and rays `--lighting auto` chose).
    request: FrameSettings,
    /// What `--lighting auto` measured and chose.
    auto: Option<pilot::Report>,
    /// What `--lb-grid auto` chose per model.
    grids: Option<Vec<sylva_worker::lighting::lb::auto::GridChoice>>,
    /// Writes what was built or solved here to the prepared-data cache:
    /// run once the frame is out, so the first frame does not wait for the disk.
    keep: Option<Box<dyn FnOnce()>>,
}

/// Composes the frame through the frame layer: `--lighting auto`'s pilot
/// first (its preparation is the frame's), `--lb-grid auto`'s choice, then
/// the preparation (reading the prepared-data cache) and the ambient match.
fn compose_here(
    a: &RenderArgs,
    tracer: &Tracer,
    request: &FrameSettings,
    mut scene: Scene,
    choose_grids: bool,
    goal: Option<Goal>,
    phases: &mut Vec<(&'static str, f64)>,
) -> anyhow::Result<Composed> {
    let bar = spinner();
    let say = |m: &str| progress::stage(&bar, m);
    // Compiled kernels are kept beside the prepared data.
    let disk = a.prepared_cache.open()?;
    if let Some(d) = &disk {
        tracer.keep_kernels_in(d.dir());
    }
    let (request, mut given, auto) = match goal {
        Some(goal) => {
            let t = Instant::now();
            let plan = even_strips(a.frame.width, STRIP);
            let c = pilot::choose(tracer, &scene, request, &plan, goal, pilot::Job::FRAME, &say)?;
            phases.push(("pilot", ms(t)));
            tracing::info!(chosen = %c.report.chosen.name, "--lighting auto: {}", c.report.why);
            scene = c.scene;
            (c.frame, Some(Given(c.prepared)), Some(c.report))
        }
        None => (*request, None, None),
    };
    let lighting = request.lighting_or(scene.lighting);
    let mut grids = None;
    if choose_grids && sylva_worker::lighting::method(lighting).needs.lb {
        let t = Instant::now();
        let c = sylva_worker::lighting::lb::auto::choose_lb_grids(
            tracer,
            &scene,
            &[16, 32, 64, 128],
            a.lb_auto_tolerance,
            &say,
        )?;
        for (m, c) in scene.models.iter_mut().zip(&c) {
            m.lb.grid = c.grid;
        }
        phases.push(("lb grid choice", ms(t)));
        grids = Some(c);
    }
    // Otherwise prepared here, reading what the prepared-data cache holds
    // of the scene (its entries named by the bundle's content, as a
    // worker names them).
    let mut fresh = match (&given, disk) {
        (None, Some(cache)) => {
            let bundle = sylva_scene::bundle::pack(&a.scene)?.hash;
            Fresh::with_disk(DiskSource { cache, bundle, sun: None })
        }
        _ => Fresh::default(),
    };
    let preparer: &mut dyn Preparer = match &mut given {
        Some(g) => g,
        None => &mut fresh,
    };
    let frame = Frame::compose(tracer, &scene, &request, preparer, &say)?;
    if given.is_none() {
        phases.extend(frame.prepared.phases.0.iter().map(|p| (p.name, p.ms)));
    }
    phases
        .extend(frame.timings.iter().copied().filter(|(n, _)| given.is_none() || *n != "prepare"));
    bar.finish_and_clear();
    let keep = fresh.reuse.keeper(&scene).map(|k| Box::new(k) as Box<dyn FnOnce()>);
    Ok(Composed { frame, scene, request, auto, grids, keep })
}

/// The composed frame traced as strips, assembled, written with its stats.
fn render_strips_here(
    a: &RenderArgs,
    tracer: &Tracer,
    c: Composed,
    mut phases: Vec<(&'static str, f64)>,
) -> anyhow::Result<()> {
    let Composed { frame, scene, request, auto, grids, keep } = c;
    let (lighting, accel) = (frame.settings.lighting, request.accel);
    let plan = even_strips(a.frame.width, STRIP);
    let bar = ProgressBar::new(plan.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("tracing [{bar:40}] {pos}/{len} strips {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    progress::stage(&bar, &format!("tracing {} strips", plan.len()));
    let t = Instant::now();
    let mut rendered = InProcess::new(&frame).render(&plan, &|_| bar.inc(1))?;
    let sylva_scene::film::RayCounts { primary, shadow, transparent } = rendered.rays;
    let trace_ms = ms(t);
    phases.push(("trace", trace_ms));
    bar.finish_and_clear();
    if request.denoise.is_on() {
        phases.push(("denoise", rendered.denoise(request.denoise)?));
    }
    let coverage = &rendered.coverage;
    let (tone, exr) = write_image(
        a,
        &rendered.image,
        rendered.passes.as_ref(),
        rendered.noisy.as_ref(),
        &mut phases,
    )?;
    if let Some(keep) = keep {
        keep();
    }
    let prepared = &frame.prepared;
    let mut stats = with_head(
        a,
        exr,
        accel,
        lighting,
        &phases,
        json!({
            "adapter": tracer.summary(),
            "rays": {
                "primary": primary,
                "shadow": shadow,
                "transparent_passed": transparent,
                "mrays_per_second": (primary + shadow) as f64 / (trace_ms / 1e3) / 1e6,
            },
            "triangles": { "unique": scene.unique_triangles(), "instanced": scene.instanced_triangles() },
            "instances": scene.instances.len(),
            "models": scene.models.len(),
            "gpu_memory_bytes": { "scene": prepared.renderer.scene_bytes(), "acceleration_structures": prepared.accel_bytes },
            "backend": prepared.backend,
            "lb": prepared.light,
            "lb_grid_choice": grids,
            "boulanger": prepared.boulanger,
            "forest_grid": prepared.forest,
            "ambient": frame.settings.ambient,
            "tone_map": tone,
            "coverage": coverage.iter().map(|&c| c as f64).sum::<f64>() / coverage.len() as f64,
        }),
    );
    let mut how = format!(
        "in {:.0} ms of tracing, {:.2} Mrays/s ({})",
        trace_ms,
        (primary + shadow) as f64 / (trace_ms / 1e3) / 1e6,
        prepared.backend.why
    );
    if let Some(r) = &auto {
        stats["spp"] = json!(request.spp);
        stats["gather_bounces"] = json!(request.gather_bounces);
        stats["gather_filter"] = json!(request.gather_filter);
        stats["auto"] = serde_json::to_value(r)?;
        how += &format!("; --lighting auto chose {}", r.why);
    }
    report(a, &stats, accel, lighting, &how)
}

/// The reference in this process: path traced in batches until its own
/// relative standard error is below `--target-error`.
fn render_reference_here(
    a: &RenderArgs,
    frame: &Frame,
    scene: &Scene,
    accel: Backend,
    mut phases: Vec<(&'static str, f64)>,
) -> anyhow::Result<()> {
    let lighting = frame.settings.lighting;
    anyhow::ensure!(
        a.target_error.is_finite() && a.target_error > 0.0,
        "--target-error {}: must be a finite number > 0",
        a.target_error
    );
    anyhow::ensure!(
        a.max_seconds.is_finite() && a.max_seconds > 0.0,
        "--max-seconds {}: must be a finite number > 0",
        a.max_seconds
    );
    let opts = ReferenceOptions {
        batch_spp: a.frame.spp.max(MIN_BATCH_SPP),
        target_error: a.target_error,
        max_seconds: a.max_seconds,
        max_batches: (MAX_SPP / a.frame.spp.max(MIN_BATCH_SPP)).max(4),
        ..Default::default()
    };
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} reference: {msg} {elapsed}")
            .expect("valid template"),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let t = Instant::now();
    let r = frame.reference(&[(0, frame.settings.width)], &opts, &|s| {
        bar.set_message(format!(
            "{} spp, relative error {:.4} (target {})",
            s.spp, s.relative_error, a.target_error
        ))
    })?;
    phases.push(("trace", ms(t)));
    bar.finish_and_clear();
    let mut r = r;
    let t = Instant::now();
    let noisy =
        sylva_coordinator::executor::denoise(&mut r.image, r.passes.as_ref(), a.frame.denoise)?;
    if noisy.is_some() {
        phases.push(("denoise", ms(t)));
    }
    let (tone, exr) = write_image(a, &r.image, r.passes.as_ref(), noisy.as_ref(), &mut phases)?;
    // Beside the reference, what `local` shows along its own samples:
    // the difference is its indirect light, without edge aliasing.
    let local_exr = match &exr {
        Some(p) => {
            let l = p.with_extension("local.exr");
            r.local.write_exr(&l)?;
            Some(l.display().to_string())
        }
        None => None,
    };
    let stats = with_head(
        a,
        exr,
        accel,
        lighting,
        &phases,
        json!({
            "adapter": frame.tracer().summary(),
            "backend": frame.prepared.backend,
            "reference": r.stats,
            "local_exr": local_exr,
            "leaf_optics": scene.file.leaf_optics,
            "max_bounces": sylva_worker::trace::MAX_BOUNCES,
            "tone_map": tone,
            "coverage": r.coverage.iter().map(|&c| c as f64).sum::<f64>() / r.coverage.len() as f64,
        }),
    );
    let how = format!(
        "{} spp in {:.0} ms, relative standard error {:.4}{}",
        r.stats.spp,
        r.stats.ms,
        r.stats.relative_error,
        if r.stats.converged { "" } else { " (not converged)" }
    );
    report(a, &stats, accel, lighting, &how)
}

/// Tone-maps the whole frame once and writes the PNG, and the EXR when
/// asked or when the frame has passes (a multi-layer EXR holds them).
fn write_image(
    a: &RenderArgs,
    frame: &HdrImage,
    passes: Option<&sylva_scene::passes::PassImage>,
    noisy: Option<&HdrImage>,
    phases: &mut Vec<(&'static str, f64)>,
) -> anyhow::Result<(sylva_scene::film::ToneMapStats, Option<PathBuf>)> {
    let t = Instant::now();
    let (ldr, tone) = reinhard(frame, 0.18);
    create_parent(&a.out)?;
    write_png(&a.out, a.frame.width, a.frame.height, &ldr)?;
    phases.push(("tone map", ms(t)));
    let p = a.out.with_extension("exr");
    let exr = match passes {
        Some(passes) => {
            let bytes = sylva_scene::passes::encode_layers(frame, passes, noisy)?;
            std::fs::write(&p, bytes).with_context(|| format!("{}: cannot write", p.display()))?;
            Some(p)
        }
        None if a.exr => {
            frame.write_exr(&p)?;
            Some(p)
        }
        None => None,
    };
    Ok((tone, exr))
}

/// Stats every render path starts with (what was rendered, where it went,
/// time per phase), followed by the path's own fields in `rest`.
fn with_head(
    a: &RenderArgs,
    exr: Option<PathBuf>,
    accel: Backend,
    lighting: LightingMode,
    phases: &[(&str, f64)],
    rest: serde_json::Value,
) -> serde_json::Value {
    let mut head = json!({
        "scene": a.scene,
        "image": a.out,
        "exr": exr,
        "width": a.frame.width,
        "height": a.frame.height,
        "spp": a.frame.spp,
        "accel": accel,
        "lighting": lighting,
        "phases_ms": phases.iter().map(|(k, v)| json!({ "phase": k, "ms": v })).collect::<Vec<_>>(),
    });
    if let (Some(h), serde_json::Value::Object(r)) = (head.as_object_mut(), rest) {
        h.extend(r);
    }
    head
}

/// Creates the folder `path` goes in, if any.
pub(super) fn create_parent(path: &Path) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create folder", dir.display()))?;
    }
    Ok(())
}

/// Writes the stats beside the image and tells the user.
fn report(
    a: &RenderArgs,
    stats: &serde_json::Value,
    accel: Backend,
    lighting: LightingMode,
    how: &str,
) -> anyhow::Result<()> {
    report_wrote(a, stats, accel, lighting, how, &a.out.display().to_string())
}

/// [`report`], naming what was written as `wrote`.
fn report_wrote(
    a: &RenderArgs,
    stats: &serde_json::Value,
    accel: Backend,
    lighting: LightingMode,
    how: &str,
    wrote: &str,
) -> anyhow::Result<()> {
    let path = stats_path(&a.out);
    std::fs::write(&path, serde_json::to_string_pretty(stats)? + "\n")
        .with_context(|| format!("{}: cannot write", path.display()))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(stats)?);
    } else {
        println!(
            "rendered {} ({}×{}, {} spp, {accel:?}, {lighting:?}) {how}; wrote {} and {}",
            a.scene.display(),
            a.frame.width,
            a.frame.height,
            stats["spp"],
            wrote,
            path.display()
        );
    }
    Ok(())
}

/// `NAME.stats.json` beside `NAME.png`.
pub fn stats_path(image: &Path) -> PathBuf {
    let stem = image
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "render".into());
    image.with_file_name(format!("{stem}.stats.json"))
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Renders through a coordinator process started here, over worker
/// processes started here or the running ones named by `--workers`: the
/// same gRPC path a farm's jobs take.
fn render_through_coordinator(
    a: &RenderArgs,
    request: &FrameSettings,
    views: &[View],
    scene: &Scene,
    lighting: LightingMode,
    accel: Backend,
    mut phases: Vec<(&'static str, f64)>,
) -> anyhow::Result<()> {
    use crate::loopback::LoopbackProcesses;
    use sylva_proto::auth::random_token;
    let t = Instant::now();
    let bundle = sylva_scene::bundle::pack(&a.scene)?;
    phases.push(("bundle", ms(t)));
    let t = Instant::now();
    let mut processes = LoopbackProcesses::default();
    let mut flags = vec!["--strip-deadline-s".to_string(), a.strip_deadline_s.max(1).to_string()];
    let (workers, token) = if a.workers.is_empty() {
        // Other users of this machine must not be able to use our processes.
        let token = random_token();
        let cache = a.prepared_cache.to_args();
        (processes.start_workers_with(a.local_workers, &token, &cache)?, token)
    } else {
        // The coordinator sends its own token to the workers, so it is theirs.
        flags.extend(a.tls.to_args());
        (a.workers.clone(), a.auth.load()?.unwrap_or_else(random_token))
    };
    let coordinator = processes.start_coordinator(&workers, &token, &flags)?;
    phases.push(("start processes", ms(t)));
    let spec = job_spec(request, views, a.schedule, 0, &a.scene.display().to_string());
    let rt = tokio::runtime::Runtime::new()?;
    let t = Instant::now();
    let done = rt.block_on(sylva_coordinator::client::submit_and_follow(
        &coordinator,
        Some(token),
        None,
        spec,
        &bundle,
        // Passes live in the EXR: asking for them asks for it.
        a.exr || !a.frame.passes.is_empty(),
    ))?;
    let frame_ms = ms(t);
    phases.push((if views.is_empty() { "frame" } else { "sequence" }, frame_ms));
    drop(processes);

    create_parent(&a.out)?;
    let mut body = json!({
        "coordinator": coordinator,
        "job": done.id,
        "bundle": { "hash": bundle.hash, "bytes": bundle.bytes.len() },
        "triangles": { "unique": scene.unique_triangles(), "instanced": scene.instanced_triangles() },
        "instances": scene.instances.len(),
        "models": scene.models.len(),
    });
    // A sequence's numbered frames, sheet and preview; or the one image.
    let (exr, wrote, how) = if views.is_empty() {
        std::fs::write(&a.out, &done.pngs[0])
            .with_context(|| format!("{}: cannot write", a.out.display()))?;
        let exr = match done.exrs.as_ref().map(|e| &e[0]) {
            Some(bytes) => {
                let p = a.out.with_extension("exr");
                std::fs::write(&p, bytes)
                    .with_context(|| format!("{}: cannot write", p.display()))?;
                Some(p)
            }
            None => None,
        };
        (
            exr,
            a.out.display().to_string(),
            format!("through a coordinator and {} workers in {:.0} ms", workers.len(), frame_ms),
        )
    } else {
        let written =
            sylva_coordinator::sequence::write_all(&a.out, &done.pngs, done.exrs.as_deref())?;
        let names = |i: usize| written.get(i).map(|p| p.display().to_string()).unwrap_or_default();
        let wrote = format!(
            "{} … {}, {}, {}",
            names(0),
            names(views.len() - 1),
            names(written.len() - 2),
            names(written.len() - 1)
        );
        body["views"] = json!(views);
        body["written"] = json!(written);
        let n = views.len();
        (
            None,
            wrote,
            format!(
                "{n} frames through a coordinator and {} workers in {frame_ms:.0} ms ({:.0} ms a frame)",
                workers.len(),
                frame_ms / n as f64
            ),
        )
    };
    let mut stats = with_head(a, exr, accel, lighting, &phases, body);
    // The coordinator's own figures: schedule, strips, workers, rays, tone map.
    if let (Some(s), serde_json::Value::Object(c)) = (stats.as_object_mut(), done.stats) {
        s.extend(c);
    }
    report_wrote(a, &stats, accel, lighting, &how, &wrote)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Flags {
        #[command(flatten)]
        frame: FrameArgs,
    }

    fn views(flags: &[&str], scene: &str) -> anyhow::Result<Vec<View>> {
        let f = Flags::try_parse_from(std::iter::once("sylva").chain(flags.iter().copied()))?;
        f.frame.views(&sylva_scene::parse(scene, "s.json")?)
    }

    #[test]
    fn the_scene_files_sequence_is_rendered_and_flags_override_it() {
        let plain = include_str!("../../../shared/scene/tests/data/small_scene.json");
        assert!(views(&[], plain).unwrap().is_empty(), "no sequence: one frame");
        let with = plain.trim_end().trim_end_matches('}').to_string()
            + r#", "sequence": { "frames": 6, "sun": { "from": { "elevation_deg": 10, "azimuth_deg": 0 }, "to": { "elevation_deg": 50, "azimuth_deg": 0 } } } }"#;
        let v = views(&[], &with).unwrap();
        assert_eq!(v.len(), 6);
        assert!(v.iter().all(|v| v.camera.is_none() && v.sun_towards.is_some()));
        // Flags: more frames, and the sun sweep replaced.
        let v =
            views(&["--frames", "3", "--sun-from", "60,0", "--sun-to", "60,90"], &with).unwrap();
        assert_eq!(v.len(), 3);
        assert!((v[0].sun_towards.unwrap()[1] - 60f32.to_radians().sin()).abs() < 1e-6);
        // A sweep without a frame count is refused, and so is half a sweep.
        assert!(
            views(&["--sun-from", "10,0", "--sun-to", "20,0"], plain)
                .unwrap_err()
                .to_string()
                .contains("--frames")
        );
        assert!(views(&["--frames", "2", "--sun-from", "10,0"], plain).is_err());
        assert!(views(&["--frames", "2", "--sun-from", "10", "--sun-to", "20,0"], plain).is_err());
    }
}
