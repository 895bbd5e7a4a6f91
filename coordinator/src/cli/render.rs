//! `sylva render SCENE -o out.png`: load, prepare and trace a scene in this
//! process, tone-map the whole frame once and write the image and its stats.

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;
use sylva_shared::accel::AccelKind;
use sylva_shared::film::{HdrImage, reinhard, write_png};
use sylva_shared::scene::{LightingMode, Scene};
use sylva_worker::GpuContext;
use sylva_worker::prepare::prepare;
use sylva_worker::trace::{FrameSettings, RayCounts};

// The same limits every worker enforces on a strip request.
use sylva_worker::service::{MAX_SIDE, MAX_SPP};
/// Columns per strip, for the progress bar.
const STRIP: u32 = 64;

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum AccelArg {
    /// kd-tree, short-stack traversal.
    Kd,
    /// Bounding-volume hierarchy.
    Bvh,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum LightingArg {
    /// Direct sun light only.
    Local,
    /// Direct light plus a constant ambient matched to the LB image.
    Ambient,
    /// Direct light plus LB indirect light.
    Lb,
    /// The LB light alone.
    LbVisualize,
}

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Scene file (JSON); see `sylva scene forest` and docs/scene-format.md.
    pub scene: PathBuf,
    /// Output PNG; stats go beside it as NAME.stats.json.
    #[arg(short, long, default_value = "sylva-out/render.png")]
    pub out: PathBuf,
    /// Image width.
    #[arg(long, default_value_t = 896)]
    pub width: u32,
    /// Image height.
    #[arg(long, default_value_t = 448)]
    pub height: u32,
    /// Rays per pixel.
    #[arg(long, default_value_t = 1)]
    pub spp: u32,
    /// Acceleration structure.
    #[arg(long, value_enum, default_value = "bvh")]
    pub accel: AccelArg,
    /// Lighting method; default the scene's.
    #[arg(long, value_enum)]
    pub lighting: Option<LightingArg>,
    /// Seed of the per-pixel sample positions.
    #[arg(long, default_value_t = 1)]
    pub seed: u32,
    /// Weight of the LB light relative to the sun's.
    #[arg(long, default_value_t = 0.35)]
    pub lb_strength: f32,
    /// Also write the linear HDR frame as OpenEXR beside the PNG.
    #[arg(long)]
    pub exr: bool,
    /// Print the stats JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Worker processes to start on loopback for this render (0: render in
    /// this process, without gRPC).
    #[arg(long, default_value_t = 2)]
    pub local_workers: usize,
    /// Render on these running workers (`host:port,…`) instead of starting any.
    #[arg(long, value_delimiter = ',')]
    pub workers: Vec<String>,
    /// How the frame is cut into strips for the workers.
    #[arg(long, value_enum, default_value = "dynamic")]
    pub schedule: ScheduleArg,
    /// Seconds a worker may take over one strip before it is handed to another.
    #[arg(long, default_value_t = 600)]
    pub strip_deadline_s: u64,
    /// The token the `--workers` require; local workers get a fresh random one.
    #[command(flatten)]
    pub auth: super::token::TokenArgs,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ScheduleArg {
    /// One equal strip per worker.
    Static,
    /// More strips than workers, pulled by idle workers.
    Dynamic,
}

pub fn run(a: RenderArgs) -> anyhow::Result<()> {
    if a.width == 0 || a.height == 0 || a.width > MAX_SIDE || a.height > MAX_SIDE {
        bail!("image {}×{}: each side must be in [1, {MAX_SIDE}]", a.width, a.height);
    }
    if a.spp == 0 || a.spp > MAX_SPP {
        bail!("--spp {}: valid range [1, {MAX_SPP}]", a.spp);
    }
    if !(a.lb_strength.is_finite() && a.lb_strength >= 0.0) {
        bail!("--lb-strength {}: must be a finite number ≥ 0", a.lb_strength);
    }
    let mut phases: Vec<(&str, f64)> = Vec::new();
    let t = Instant::now();
    let scene = Scene::load(&a.scene)?;
    phases.push(("load", ms(t)));
    let lighting = match a.lighting {
        None => scene.lighting,
        Some(LightingArg::Local) => LightingMode::Local,
        Some(LightingArg::Ambient) => LightingMode::Ambient,
        Some(LightingArg::Lb) => LightingMode::Lb,
        Some(LightingArg::LbVisualize) => LightingMode::LbVisualize,
    };
    let accel = match a.accel {
        AccelArg::Kd => AccelKind::Kd,
        AccelArg::Bvh => AccelKind::Bvh,
    };
    if a.local_workers > 0 || !a.workers.is_empty() {
        return render_on_workers(&a, &scene, lighting, accel, phases);
    }
    let bar = ProgressBar::new_spinner();
    bar.set_style(ProgressStyle::with_template("{spinner} {msg} {elapsed}").expect("valid template"));
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let ctx = GpuContext::new()?;
    let prepared = prepare(&ctx, &scene, accel, lighting, &|m| bar.set_message(m.to_string()))?;
    for p in &prepared.phases.0 {
        phases.push((p.name, p.ms));
    }
    let mut settings = FrameSettings {
        width: a.width,
        height: a.height,
        spp: a.spp,
        seed: a.seed,
        lighting,
        ambient: [0.0; 3],
        lb_strength: a.lb_strength,
    };
    if lighting == LightingMode::Ambient {
        bar.set_message("matching the ambient constant to the LB image");
        let t = Instant::now();
        settings.ambient = matched_ambient(&ctx, &prepared.renderer, &settings)?;
        phases.push(("ambient match", ms(t)));
    }
    bar.finish_and_clear();

    let strips = a.width.div_ceil(STRIP);
    let bar = ProgressBar::new(strips as u64);
    bar.set_style(ProgressStyle::with_template("tracing [{bar:40}] {pos}/{len} strips {elapsed}").expect("valid template").progress_chars("=> "));
    let t = Instant::now();
    let mut frame = HdrImage::new(a.width, a.height);
    let mut coverage = vec![0.0f32; (a.width * a.height) as usize];
    let mut rays = RayCounts::default();
    for s in 0..strips {
        let (x0, x1) = (s * STRIP, ((s + 1) * STRIP).min(a.width));
        let strip = prepared.renderer.render_strip(&ctx, &settings, x0, x1)?;
        frame.paste_strip(x0, strip.width, &strip.pixels);
        for y in 0..a.height {
            for x in 0..strip.width {
                coverage[(y * a.width + x0 + x) as usize] = strip.coverage[(y * strip.width + x) as usize];
            }
        }
        rays.add(&strip.rays);
        bar.inc(1);
    }
    let trace_ms = ms(t);
    phases.push(("trace", trace_ms));
    bar.finish_and_clear();

    let (tone, exr) = write_image(&a, &frame, &mut phases)?;
    let stats = json!({
        "scene": a.scene,
        "image": a.out,
        "exr": exr,
        "width": a.width,
        "height": a.height,
        "spp": a.spp,
        "accel": accel,
        "lighting": lighting,
        "adapter": ctx.summary(),
        "phases_ms": phases.iter().map(|(k, v)| json!({ "phase": k, "ms": v })).collect::<Vec<_>>(),
        "rays": {
            "primary": rays.primary,
            "shadow": rays.shadow,
            "transparent_passed": rays.transparent,
            "mrays_per_second": rays.traced() as f64 / (trace_ms / 1e3) / 1e6,
        },
        "triangles": { "unique": scene.unique_triangles(), "instanced": scene.instanced_triangles() },
        "instances": scene.instances.len(),
        "models": scene.models.len(),
        "gpu_memory_bytes": { "scene": prepared.renderer.scene_bytes(), "acceleration_structures": prepared.accel_bytes },
        "lb": prepared.light,
        "forest_grid": prepared.forest,
        "ambient": settings.ambient,
        "tone_map": tone,
        "coverage": coverage.iter().map(|&c| c as f64).sum::<f64>() / coverage.len() as f64,
    });
    let how = format!("in {:.0} ms of tracing, {:.2} Mrays/s", trace_ms, rays.traced() as f64 / (trace_ms / 1e3) / 1e6);
    report(&a, &stats, accel, lighting, &how)
}

/// Tone-maps the whole frame once and writes the PNG (and the EXR when asked).
fn write_image(a: &RenderArgs, frame: &HdrImage, phases: &mut Vec<(&'static str, f64)>) -> anyhow::Result<(sylva_shared::film::ToneMapStats, Option<PathBuf>)> {
    let t = Instant::now();
    let (ldr, tone) = reinhard(frame, 0.18);
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create folder", dir.display()))?;
    }
    write_png(&a.out, a.width, a.height, &ldr)?;
    phases.push(("tone map", ms(t)));
    let exr = if a.exr {
        let p = a.out.with_extension("exr");
        frame.write_exr(&p)?;
        Some(p)
    } else {
        None
    };
    Ok((tone, exr))
}

/// Writes the stats beside the image and tells the user.
fn report(a: &RenderArgs, stats: &serde_json::Value, accel: AccelKind, lighting: LightingMode, how: &str) -> anyhow::Result<()> {
    let path = stats_path(&a.out);
    std::fs::write(&path, serde_json::to_string_pretty(stats)? + "\n").with_context(|| format!("{}: cannot write", path.display()))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(stats)?);
    } else {
        println!(
            "rendered {} ({}×{}, {} spp, {accel:?}, {lighting:?}) {how}; wrote {} and {}",
            a.scene.display(),
            a.width,
            a.height,
            a.spp,
            a.out.display(),
            path.display()
        );
    }
    Ok(())
}

/// `NAME.stats.json` beside `NAME.png`.
pub fn stats_path(image: &Path) -> PathBuf {
    let stem = image.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_else(|| "render".into());
    image.with_file_name(format!("{stem}.stats.json"))
}

/// The constant ambient light whose mean over the models' pixels equals the
/// LB light's (the paper's Figure 2c): the LB light alone, rendered at a
/// quarter of the resolution, averaged over the pixels that see a model.
fn matched_ambient(ctx: &GpuContext, r: &sylva_worker::trace::StripRenderer, f: &FrameSettings) -> anyhow::Result<[f32; 3]> {
    let small = FrameSettings {
        width: (f.width / 4).max(16),
        height: (f.height / 4).max(8),
        spp: 1,
        lighting: LightingMode::LbVisualize,
        ..*f
    };
    let s = r.render_strip(ctx, &small, 0, small.width)?;
    Ok(ambient_from(&s.pixels, &s.coverage))
}

/// The mean of `pixels` weighted by how much of each shows a model.
fn ambient_from(pixels: &[[f32; 3]], coverage: &[f32]) -> [f32; 3] {
    let mut sum = [0.0f64; 3];
    let mut weight = 0.0f64;
    for (p, &c) in pixels.iter().zip(coverage) {
        for k in 0..3 {
            sum[k] += p[k] as f64 * c as f64;
        }
        weight += c as f64;
    }
    if weight == 0.0 {
        return [0.0; 3];
    }
    sum.map(|v| (v / weight) as f32)
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Renders through gRPC workers: local processes started here, or the
/// running ones named by `--workers`.
fn render_on_workers(
    a: &RenderArgs,
    scene: &Scene,
    lighting: LightingMode,
    accel: AccelKind,
    mut phases: Vec<(&'static str, f64)>,
) -> anyhow::Result<()> {
    use sylva_coordinator::farm::{self, FarmEvent};
    use sylva_coordinator::schedule::{ScheduleKind, scheduler};
    let t = Instant::now();
    let bundle = sylva_shared::bundle::pack(&a.scene)?;
    phases.push(("bundle", ms(t)));
    let t = Instant::now();
    let (local, workers) = if a.workers.is_empty() {
        // Other users of this machine must not be able to use our workers.
        let token = super::local::fresh_token();
        let l = super::local::LocalWorkers::start(a.local_workers, &token)?;
        let w = farm::Workers { addrs: l.addrs.clone(), token: Some(token) };
        (Some(l), w)
    } else {
        let token = a.auth.load()?;
        (None, farm::Workers { addrs: a.workers.clone(), token })
    };
    let addrs = workers.addrs.clone();
    if local.is_some() {
        phases.push(("start workers", ms(t)));
    }
    let kind = match a.schedule {
        ScheduleArg::Static => ScheduleKind::Static,
        ScheduleArg::Dynamic => ScheduleKind::Dynamic,
    };
    let lighting_name = serde_json::to_value(lighting)?.as_str().unwrap_or("lb").to_string();
    let accel_name = serde_json::to_value(accel)?.as_str().unwrap_or("bvh").to_string();
    let mut frame = sylva_proto::pb::FrameSettings {
        width: a.width,
        height: a.height,
        spp: a.spp,
        seed: a.seed,
        lighting: lighting_name,
        accel: accel_name,
        lb_strength: a.lb_strength,
        ambient: vec![],
    };
    let deadline = std::time::Duration::from_secs(a.strip_deadline_s.max(1));
    let rt = tokio::runtime::Runtime::new()?;
    let mut ambient = [0.0f32; 3];
    if lighting == LightingMode::Ambient {
        let t = Instant::now();
        let small = sylva_proto::pb::FrameSettings {
            width: (a.width / 4).max(16),
            height: (a.height / 4).max(8),
            spp: 1,
            lighting: "lb-visualize".into(),
            ..frame.clone()
        };
        let w = small.width;
        let f = rt.block_on(farm::render_frame(&workers, &bundle, small, vec![(0, w)], deadline, |_| {}))?;
        ambient = ambient_from(&f.image.pixels, &f.coverage);
        frame.ambient = ambient.to_vec();
        phases.push(("ambient match", ms(t)));
    }
    let plan = scheduler(kind).plan(a.width, addrs.len(), &[]);
    let bar = ProgressBar::new(plan.len() as u64);
    bar.set_style(ProgressStyle::with_template("rendering [{bar:40}] {pos}/{len} strips on {msg} {elapsed}").expect("valid template").progress_chars("=> "));
    bar.set_message(format!("{} workers", addrs.len()));
    let b2 = bar.clone();
    let t = Instant::now();
    let result = rt.block_on(farm::render_frame(&workers, &bundle, frame, plan, deadline, move |e| match e {
        FarmEvent::StripDone { .. } => b2.inc(1),
        FarmEvent::StripRetried { strip, worker, error } => tracing::warn!(?strip, %worker, %error, "strip re-queued"),
        FarmEvent::WorkerDropped { worker, error } => tracing::warn!(%worker, %error, "worker dropped for this frame"),
        FarmEvent::BundleSent { worker, bytes } => tracing::info!(%worker, bytes, "scene sent"),
    }))?;
    let frame_ms = ms(t);
    phases.push(("frame", frame_ms));
    bar.finish_and_clear();
    drop(local);

    let (tone, exr) = write_image(a, &result.image, &mut phases)?;
    let traced = result.rays[0] + result.rays[1];
    let stats = json!({
        "scene": a.scene,
        "image": a.out,
        "exr": exr,
        "width": a.width,
        "height": a.height,
        "spp": a.spp,
        "accel": accel,
        "lighting": lighting,
        "schedule": kind,
        "bundle": { "hash": bundle.hash, "bytes": bundle.bytes.len() },
        "workers": result.workers,
        "strips": result.strip_ms.iter().map(|(s, ms, rpc)| json!({ "x0": s.0, "x1": s.1, "render_ms": ms, "rpc_ms": rpc })).collect::<Vec<_>>(),
        "upload_ms": result.upload_ms,
        "phases_ms": phases.iter().map(|(k, v)| json!({ "phase": k, "ms": v })).collect::<Vec<_>>(),
        "rays": {
            "primary": result.rays[0],
            "shadow": result.rays[1],
            "transparent_passed": result.rays[2],
            "mrays_per_second": traced as f64 / (frame_ms / 1e3) / 1e6,
        },
        "triangles": { "unique": scene.unique_triangles(), "instanced": scene.instanced_triangles() },
        "instances": scene.instances.len(),
        "models": scene.models.len(),
        "ambient": ambient,
        "tone_map": tone,
        "coverage": result.coverage.iter().map(|&c| c as f64).sum::<f64>() / result.coverage.len() as f64,
    });
    report(a, &stats, accel, lighting, &format!("on {} workers in {:.0} ms", addrs.len(), frame_ms))
}
