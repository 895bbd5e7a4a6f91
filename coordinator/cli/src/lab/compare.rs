//! `sylva compare SCENE`: renders a scene with every lighting method,
//! measures each one's pre-process and frame time and its error against
//! the path-traced reference, and writes a table (JSON), an image grid in
//! the style of the forest paper's Figure 2 and a chart of error against
//! time. Optionally adds the LB failure-mode sweeps (LB against a Monte
//! Carlo reference of the same medium), each as a chart.

use crate::flags::compare::*;
use crate::lab::chart::{Series, line_chart};
use crate::lab::crowns;
use crate::lab::error::{IndirectError, lit_pixels};
use crate::lab::pareto;
use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;
use sylva_accel::AccelKind;
use sylva_scene::color::luminance;
use sylva_scene::film::{HdrImage, ToneMapStats, reinhard, reinhard_like, write_png};
use sylva_scene::frame::FrameSettings;
use sylva_scene::{ForestGridUse, LbModel, LightingMode, Scene};
use sylva_worker::GpuContext;
use sylva_worker::lighting::Needs;
use sylva_worker::lighting::lb::auto::choose_lb_grids;
use sylva_worker::lighting::reference::{ReferenceImage, ReferenceOptions, render_reference};
use sylva_worker::prepare::prepare;
use sylva_worker::trace::RenderSettings;

/// One method's figures.
#[derive(Debug, Serialize)]
struct MethodReport {
    name: String,
    /// Its curve on the time–error chart.
    family: String,
    lighting: LightingMode,
    /// LB grid per model (empty: none).
    lb_grids: Vec<usize>,
    /// Whether the coarse forest grid scaled the instances' LB light.
    forest_grid: Option<bool>,
    /// Time to build the acceleration structures (the same work for every method).
    build_ms: f64,
    /// Time of the lighting's own pre-process (voxelize, LB, forest LB,
    /// clouds, Boulanger precompute, ambient match, grid choice).
    preprocess_ms: f64,
    /// Time to render the frame.
    frame_ms: f64,
    /// RMSE of the linear RGB image against the reference, over lit pixels.
    rmse: f64,
    /// Mean of |method − reference| / reference luminance over lit pixels.
    mean_relative_error: f64,
    /// Per channel, the method's image mean over lit pixels over the reference's.
    mean_ratio: [f64; 3],
    /// RMS of the indirect component's error (method − local against
    /// reference − local) over the RMS of the reference's indirect light.
    indirect_relative_error: f64,
    /// The same with both images' own sampling noise taken out: the
    /// method's error in expectation (see `IndirectError`).
    indirect_error_net: f64,
    /// What the reference's noise adds to `indirect_relative_error`, as a
    /// fraction of the reference's indirect RMS.
    indirect_noise_reference: f64,
    /// What the method's own pixel sampling (4 rays across leaf edges) adds.
    indirect_noise_method: f64,
    /// Image file.
    image: String,
    /// What the method decided and why (grid choice, forest grid, warnings).
    notes: serde_json::Value,
}

struct Rendered {
    report: MethodReport,
    image: HdrImage,
    /// A second render with other seeds: beside `local`'s, the spread of
    /// the two renders' indirect light is the method's sampling noise.
    again: HdrImage,
    /// The per-sample kernels (the gathers): what `local` shows along the
    /// same camera samples, for both renders. Their indirect light is the
    /// image minus this, as the reference's is, so edges sampled
    /// differently from `local`'s rays do not count as indirect light.
    own_local: Option<(HdrImage, HdrImage)>,
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

pub fn run(a: CompareArgs) -> anyhow::Result<()> {
    let distinct = checked_grids(&a)?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("{}: cannot create folder", a.out.display()))?;
    let scene = Scene::load(&a.scene)?;
    let ctx = GpuContext::new()?;
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} {elapsed}").expect("valid template"),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let say = |m: &str| bar.set_message(m.to_string());
    let frame = FrameSettings {
        width: a.width,
        height: a.height,
        spp: a.spp,
        lighting: Some(LightingMode::Local),
        ..FrameSettings::default()
    };
    let settings = RenderSettings::resolve(&frame, scene.lighting);

    // The reference first: every error is measured against it.
    say("reference: path tracing");
    let (r, build_ms, pre, reused) = reference(&a, &ctx, &scene, &settings, &bar)?;
    let reference = r.image.clone();
    let lit = lit_pixels(&r);
    anyhow::ensure!(
        lit.iter().any(|&l| l),
        "no pixel of the frame shows a lit model: nothing to compare"
    );
    let (_, exposure) = reinhard(&reference, 0.18);

    let methods = methods_to_compare(&scene, &a.grids, &a.gather_rays, &a.gather_filters);

    let mut rendered: Vec<Rendered> = Vec::new();
    // Candidates of one group share a scene: those whose methods need the
    // same preparation share one (the LB solve is not repeated per variant).
    let mut last: Option<(usize, Needs, Preparation)> = None;
    for c in &methods {
        say(&c.name);
        let needs = sylva_worker::lighting::method(c.lighting).needs;
        let reuse = matches!(&last, Some((g, n, _)) if *g == c.group && *n == needs);
        if !reuse {
            drop(last.take());
            last =
                Some((c.group, needs, Preparation::new(&ctx, &c.scene, c.lighting, &|m| say(m))?));
        }
        let (_, _, prepared) = last.as_ref().expect("prepared above");
        let f = RenderSettings {
            spp: c.spp.unwrap_or(settings.spp),
            gather_bounces: c.gather_bounces,
            gather_filter: c.gather_filter,
            ..settings
        };
        rendered.push(render_method(&ctx, c, prepared, &f, &a.out, &exposure, a.hdr, &|m| say(m))?);
    }
    // `--lb-grid auto`: the smallest grid per species that agrees with the next finer one.
    say("lb auto: choosing grids");
    let t = Instant::now();
    let choices = choose_lb_grids(&ctx, &scene, &distinct, a.auto_tolerance, &|m| say(m))?;
    let choose_ms = ms(t);
    let mut auto_scene = scene.clone();
    for (m, c) in auto_scene.models.iter_mut().zip(&choices) {
        m.lb.grid = c.grid;
    }
    let auto_candidate = Candidate::new("lb auto", LightingMode::Lb, auto_scene, 0);
    let prepared = Preparation::new(&ctx, &auto_candidate.scene, LightingMode::Lb, &|m| say(m))?;
    let mut auto = render_method(
        &ctx,
        &auto_candidate,
        &prepared,
        &settings,
        &a.out,
        &exposure,
        a.hdr,
        &|m| say(m),
    )?;
    auto.report.preprocess_ms += choose_ms;
    auto.report.notes["grid_choice"] = serde_json::to_value(&choices)?;
    rendered.push(auto);
    say("progressive path tracer");
    let progressive = progressive_path_tracer(&ctx, &scene, &settings, &r, &lit, &|m| say(m))?;
    bar.finish_and_clear();

    // Errors against the reference; the indirect part (method − local)
    // against the reference's own (its estimate minus local along its samples).
    let (local, local_again) = (rendered[0].image.clone(), rendered[0].again.clone());
    for m in &mut rendered {
        (m.report.rmse, m.report.mean_relative_error) = errors(&m.image, &reference, &lit);
        m.report.mean_ratio = mean_ratio(&m.image, &reference, &lit);
        let l = match &m.own_local {
            Some((a, b)) => [a, b],
            None => [&local, &local_again],
        };
        let ind = IndirectError::measure([&m.image, &m.again], l, &r, &lit);
        m.report.indirect_relative_error = ind.raw;
        m.report.indirect_error_net = ind.net;
        m.report.indirect_noise_reference = ind.reference_noise;
        m.report.indirect_noise_method = ind.method_noise;
    }
    // Boulanger et al. against what their model holds, as their paper
    // compares: the direct sky and one bounce of sun light, from a
    // converged one-bounce gather (far end dark, ground lit by the sky).
    if let Some(b) = rendered.iter_mut().find(|m| m.report.lighting == LightingMode::Boulanger) {
        say("one-bounce reference (Boulanger's terms)");
        let one = one_bounce_reference(&a, &ctx, &scene, &settings, &|m| say(m))?;
        let e = IndirectError::measure([&b.image, &b.again], [&local, &local_again], &one, &lit);
        let indirect_mean = |img: &HdrImage, loc: &HdrImage| -> [f64; 3] {
            let n = lit.iter().filter(|&&l| l).count().max(1) as f64;
            std::array::from_fn(|c| {
                lit.iter()
                    .enumerate()
                    .filter(|(_, l)| **l)
                    .map(|(i, _)| (img.pixels[i][c] - loc.pixels[i][c]) as f64)
                    .sum::<f64>()
                    / n
            })
        };
        let ratio = |x: [f64; 3], y: [f64; 3]| -> [f64; 3] { [0, 1, 2].map(|c| x[c] / y[c]) };
        let (mb, mo, mr) = (
            indirect_mean(&b.image, &local),
            indirect_mean(&one.image, &one.local),
            indirect_mean(&r.image, &r.local),
        );
        b.report.notes["paper_form"] = json!({
            "what": "its indirect light (image − local) against a one-bounce reference: direct sky and one bounce of sun light, the terms the paper models and compares",
            "one_bounce_reference": { "spp": one.stats.spp, "relative_standard_error": one.stats.relative_error, "converged": one.stats.converged },
            "indirect_error": e.raw,
            "indirect_error_net": e.net,
            "mean_ratio": ratio(mb, mo),
            "one_bounce_share_of_all_indirect": ratio(mo, mr),
        });
    }
    // Per crown: each instance's mean indirect light, reference and methods.
    let ids = crowns::instance_ids(&scene, a.width, a.height);
    crowns::write_id_image(&a.out.join("instances.png"), a.width, a.height, &ids)?;
    let indirect = |img: &HdrImage, loc: &HdrImage, i: usize| -> [f32; 3] {
        std::array::from_fn(|c| img.pixels[i][c] - loc.pixels[i][c])
    };
    let columns: Vec<(String, crowns::PixelLight<'_>)> = rendered
        .iter()
        .filter(|m| m.report.lighting != LightingMode::Local)
        .map(|m| {
            let own = m.own_local.as_ref().map(|(l, _)| l).unwrap_or(&local);
            let f: crowns::PixelLight<'_> = Box::new(move |i| indirect(&m.image, own, i));
            (m.report.name.clone(), f)
        })
        .collect();
    let crown_table =
        crowns::table(&scene, &ids, &lit, &|i| indirect(&r.image, &r.local, i), &columns);
    drop(columns);
    std::fs::write(a.out.join("crowns.md"), crowns::markdown(&crown_table))?;
    let ref_png = a.out.join("reference.png");
    write_png(&ref_png, a.width, a.height, &reinhard_like(&reference, &exposure))?;
    if a.hdr {
        write_hdr(&a.out.join("reference.npy"), &reference)?;
        write_hdr(&a.out.join("reference-local.npy"), &r.local)?;
        let (h, w) = (a.height as u64, a.width as u64);
        let var: Vec<f32> = r.indirect_variance.iter().flatten().copied().collect();
        sylva_light::npy::write_f32(
            &a.out.join("reference-indirect-variance.npy"),
            &[h, w, 3],
            &var,
        )?;
        sylva_light::npy::write_f32(&a.out.join("reference-coverage.npy"), &[h, w], &r.coverage)?;
    }
    let grid_svg = a.out.join("figure2.svg");
    write_figure(&grid_svg, &a, &rendered, &reference)?;
    let mut reports: Vec<MethodReport> =
        rendered.iter_mut().map(|m| std::mem::replace(&mut m.report, empty_report())).collect();
    reports.push(MethodReport {
        name: "reference".into(),
        family: "reference".into(),
        lighting: LightingMode::Reference,
        lb_grids: vec![],
        forest_grid: None,
        build_ms,
        preprocess_ms: pre,
        frame_ms: r.stats.ms,
        rmse: 0.0,
        mean_relative_error: 0.0,
        mean_ratio: [1.0; 3],
        indirect_relative_error: 0.0,
        image: ref_png.display().to_string(),
        indirect_error_net: 0.0,
        indirect_noise_reference: 0.0,
        indirect_noise_method: 0.0,
        notes: json!({ "reused": reused, "spp": r.stats.spp, "batches": r.stats.batches, "relative_standard_error": r.stats.relative_error, "converged": r.stats.converged, "max_bounces": sylva_worker::trace::MAX_BOUNCES, "leaf_optics": scene.file.leaf_optics }),
    });

    // The time–error chart: every method and the progressive path tracer.
    let mut points: Vec<pareto::Point> = reports
        .iter()
        .filter(|m| m.lighting != LightingMode::Reference)
        .map(|m| pareto::Point {
            name: m.name.clone(),
            family: m.family.clone(),
            ms: m.preprocess_ms + m.frame_ms,
            raw: m.indirect_relative_error,
            net: Some(m.indirect_error_net),
        })
        .collect();
    points.extend(progressive.iter().cloned());
    let front = pareto::front(&points);
    let chart = a.chart.clone().unwrap_or_else(|| a.out.join("compare.svg"));
    std::fs::write(&chart, pareto::chart(&points, false))
        .with_context(|| format!("{}: cannot write", chart.display()))?;
    std::fs::write(a.out.join("compare-net.svg"), pareto::chart(&points, true))?;
    let budget = a.budget.map(|b| {
        pareto::best_within(&front, b * 1e3).map_or_else(
            || format!("no method fits {b} s"),
            |p| {
                format!(
                    "best within {b} s: {} ({:.1} % raw indirect error, {:.1} s)",
                    p.name,
                    100.0 * p.raw,
                    p.ms / 1e3
                )
            },
        )
    });
    let sweeps = if a.sweeps { Some(write_sweeps(&a.out)?) } else { None };
    let best = winner(&reports);
    let table = json!({
        "scene": a.scene,
        "image": [a.width, a.height],
        "spp": a.spp,
        "adapter": ctx.summary(),
        "lit_pixels": lit.iter().filter(|&&l| l).count(),
        "reference": { "reused": reused, "spp": r.stats.spp, "relative_standard_error": r.stats.relative_error, "converged": r.stats.converged, "ms": r.stats.ms },
        "methods": reports,
        "summary": best,
        "figure": grid_svg,
        "chart": chart,
        "sweeps": sweeps,
        "crowns": crown_table,
        "progressive": progressive,
        "front": front,
        "budget": budget,
        "instance_image": a.out.join("instances.png"),
    });
    std::fs::write(a.out.join("compare.json"), serde_json::to_string_pretty(&table)? + "\n")?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&table)?);
    } else {
        print_table(&reports, &best);
        println!("Pareto front (raw indirect error against time):\n{}", pareto::describe(&front));
        if let Some(b) = &budget {
            println!("{b}");
        }
        println!(
            "wrote {}, {} and {}",
            a.out.join("compare.json").display(),
            grid_svg.display(),
            chart.display()
        );
    }
    Ok(())
}

/// Checks the flags; the distinct LB grid sizes `lb auto` chooses between.
fn checked_grids(a: &CompareArgs) -> anyhow::Result<Vec<usize>> {
    anyhow::ensure!(
        a.width >= 8 && a.height >= 8 && a.width <= 4096 && a.height <= 4096,
        "image sides in [8, 4096]"
    );
    anyhow::ensure!((1..=256).contains(&a.spp), "--spp {}: valid range [1, 256]", a.spp);
    anyhow::ensure!(a.grids.iter().all(|g| (4..=256).contains(g)), "--grids: each in [4, 256]");
    anyhow::ensure!(
        a.gather_rays.iter().all(|k| (1..=1024).contains(k)),
        "--gather-rays: each in [1, 1024]"
    );
    anyhow::ensure!(
        a.gather_filters.iter().all(|r| *r <= sylva_scene::frame::MAX_GATHER_FILTER),
        "--gather-filters: each in [0, {}]",
        sylva_scene::frame::MAX_GATHER_FILTER
    );
    if let Some(b) = a.budget {
        anyhow::ensure!(b.is_finite() && b > 0.0, "--budget {b}: seconds > 0");
    }
    let mut distinct = a.grids.clone();
    distinct.sort_unstable();
    distinct.dedup();
    anyhow::ensure!(
        distinct.len() >= 2,
        "--grids needs two sizes or more: `lb auto` chooses between them"
    );
    anyhow::ensure!(
        a.target_error.is_finite() && a.target_error > 0.0,
        "--target-error must be > 0"
    );
    anyhow::ensure!(
        a.auto_tolerance.is_finite() && a.auto_tolerance > 0.0,
        "--auto-tolerance must be > 0"
    );
    Ok(distinct)
}

/// The path-traced reference every method is measured against: the one
/// saved for this scene, binary and flags when asked to reuse it, else
/// traced now; with its build and pre-process times and whether it was reused.
fn reference(
    a: &CompareArgs,
    ctx: &GpuContext,
    scene: &Scene,
    settings: &RenderSettings,
    bar: &ProgressBar,
) -> anyhow::Result<(ReferenceImage, f64, f64, bool)> {
    let cache = a.out.join("reference.bin");
    let key = reference_key(a)?;
    let cached =
        if a.reuse_reference { load_reference(&cache, &key, a.width, a.height) } else { None };
    Ok(match cached {
        Some(r) => (r, 0.0, 0.0, true),
        None => {
            let prepared = prepare(ctx, scene, AccelKind::Bvh, LightingMode::Reference, &|m| {
                bar.set_message(m.to_string())
            })?;
            let opts = ReferenceOptions {
                target_error: a.target_error,
                max_seconds: a.max_seconds,
                ..Default::default()
            };
            let build_ms = prepared.phases.ms("build");
            let pre = prepared.lighting_ms();
            let r = render_reference(ctx, &prepared.renderer, settings, &opts, &|s| {
                bar.set_message(format!(
                    "reference: {} spp, relative standard error {:.4} (target {})",
                    s.spp, s.relative_error, a.target_error
                ))
            })?;
            save_reference(&cache, &key, &r)?;
            (r, build_ms, pre, false)
        }
    })
}

/// One method `compare` renders: a lighting method on a variant of the
/// scene, with its own rays per pixel and gather depth where it differs.
struct Candidate {
    name: String,
    lighting: LightingMode,
    scene: Scene,
    /// Candidates of one group have the same scene, so methods with the
    /// same needs share its preparation.
    group: usize,
    /// Rays per pixel; `None`: `--spp`.
    spp: Option<u32>,
    gather_bounces: u32,
    gather_filter: u32,
    /// The curve it belongs to on the time–error chart (its variants
    /// differ by rays, grid or filter).
    family: String,
}

impl Candidate {
    fn new(name: &str, lighting: LightingMode, scene: Scene, group: usize) -> Self {
        Candidate {
            name: name.into(),
            lighting,
            scene,
            group,
            spp: None,
            gather_bounces: sylva_scene::frame::DEFAULT_GATHER_BOUNCES,
            gather_filter: 0,
            family: name.into(),
        }
    }
}

/// The methods `compare` renders: local, ambient, the LB at each grid
/// size, with the forest grid, the papers' model as written, Boulanger et
/// al., and the final gathers over the scene's own LB (at each count of
/// gather rays, one and two bounces deep, and reading the matched constant
/// at their far end instead); `lb auto` and the reference come apart.
fn methods_to_compare(
    scene: &Scene,
    grids: &[usize],
    gather_rays: &[u32],
    gather_filters: &[u32],
) -> Vec<Candidate> {
    let mut methods = vec![
        Candidate::new("local", LightingMode::Local, scene.clone(), 0),
        Candidate::new("ambient", LightingMode::Ambient, scene.clone(), 0),
    ];
    for &g in grids {
        let s = with_lb(scene, Some(g), Some(ForestGridUse::Never));
        let c = Candidate::new(&format!("lb {g}³"), LightingMode::Lb, s, methods.len());
        methods.push(Candidate { family: "lb".into(), ..c });
    }
    let forest_grid = scene.models.first().map_or(32, |m| m.lb.grid);
    let s = with_lb(scene, None, Some(ForestGridUse::Always));
    let name = format!("lb {forest_grid}³ + forest grid");
    methods.push(Candidate::new(&name, LightingMode::Lb, s, methods.len()));
    // The papers' model as written, beside the grounded one.
    let mut paper = with_lb(scene, None, Some(ForestGridUse::Always));
    paper.file.lb_model = LbModel::Paper;
    let name = format!("lb paper {forest_grid}³ + forest grid");
    methods.push(Candidate::new(&name, LightingMode::Lb, paper, methods.len()));
    methods.push(Candidate::new("boulanger", LightingMode::Boulanger, scene.clone(), 0));
    let most = gather_rays.iter().copied().max();
    let filter = sylva_scene::frame::DEFAULT_GATHER_FILTER;
    for bounces in [1, 2] {
        for &r in gather_filters {
            for &k in gather_rays {
                let family = format!("gather {bounces}b r{r}");
                methods.push(Candidate {
                    spp: Some(k),
                    gather_bounces: bounces,
                    gather_filter: r,
                    family: family.clone(),
                    ..Candidate::new(
                        &format!("{family} {k} rays"),
                        LightingMode::Gather,
                        scene.clone(),
                        0,
                    )
                });
            }
        }
        if let Some(k) = most {
            let family = format!("gather-ambient {bounces}b r{filter}");
            methods.push(Candidate {
                spp: Some(k),
                gather_bounces: bounces,
                gather_filter: filter,
                family: family.clone(),
                ..Candidate::new(
                    &format!("{family} {k} rays"),
                    LightingMode::GatherAmbient,
                    scene.clone(),
                    0,
                )
            });
        }
    }
    methods
}

/// One preparation of a scene for a method, and the time its lighting's
/// own pre-process took (voxelize, LB, forest LB, clouds, Boulanger).
struct Preparation {
    prepared: sylva_worker::prepare::PreparedScene,
    preprocess_ms: f64,
}

impl Preparation {
    fn new(
        ctx: &GpuContext,
        scene: &Scene,
        lighting: LightingMode,
        say: &dyn Fn(&str),
    ) -> anyhow::Result<Self> {
        let prepared = prepare(ctx, scene, AccelKind::Bvh, lighting, say)?;
        let preprocess_ms = prepared.lighting_ms();
        Ok(Self { prepared, preprocess_ms })
    }
}

/// The methods as a table a person reads, then the summary.
fn print_table(reports: &[MethodReport], best: &str) {
    println!(
        "{:<28} {:>12} {:>10} {:>9} {:>10} {:>10} {:>10} {:>13}",
        "method", "pre-process", "frame", "RMSE", "rel. err", "indirect", "net", "noise r / m"
    );
    for m in reports {
        println!(
            "{:<28} {:>9.0} ms {:>7.0} ms {:>9.4} {:>9.1} % {:>9.1} % {:>8.1} % {:>5.1} / {:>4.1} %",
            m.name,
            m.preprocess_ms,
            m.frame_ms,
            m.rmse,
            100.0 * m.mean_relative_error,
            100.0 * m.indirect_relative_error,
            100.0 * m.indirect_error_net,
            100.0 * m.indirect_noise_reference,
            100.0 * m.indirect_noise_method
        );
    }
    println!("{}", best);
}

fn empty_report() -> MethodReport {
    MethodReport {
        name: String::new(),
        family: String::new(),
        lighting: LightingMode::Local,
        lb_grids: vec![],
        forest_grid: None,
        build_ms: 0.0,
        preprocess_ms: 0.0,
        frame_ms: 0.0,
        rmse: 0.0,
        mean_relative_error: 0.0,
        mean_ratio: [0.0; 3],
        indirect_relative_error: 0.0,
        indirect_error_net: 0.0,
        indirect_noise_reference: 0.0,
        indirect_noise_method: 0.0,
        image: String::new(),
        notes: serde_json::Value::Null,
    }
}

/// The scene with every model's LB grid set to `grid` and the forest grid's use set.
fn with_lb(scene: &Scene, grid: Option<usize>, forest: Option<ForestGridUse>) -> Scene {
    let mut s = scene.clone();
    if let Some(g) = grid {
        for m in &mut s.models {
            m.lb.grid = g;
        }
    }
    if let Some(f) = forest {
        s.file.forest_grid.use_grid = f;
    }
    s
}

/// Renders one method on its preparation, writes its image with the reference's exposure.
#[allow(clippy::too_many_arguments)]
fn render_method(
    ctx: &GpuContext,
    c: &Candidate,
    p: &Preparation,
    f: &RenderSettings,
    out: &Path,
    exposure: &ToneMapStats,
    hdr: bool,
    say: &dyn Fn(&str),
) -> anyhow::Result<Rendered> {
    let (name, lighting, scene, prepared) = (c.name.as_str(), c.lighting, &c.scene, &p.prepared);
    let mut pre = p.preprocess_ms;
    let mut settings = RenderSettings { lighting, ..*f };
    if lighting.reads_matched_ambient() {
        let t = Instant::now();
        settings.ambient =
            sylva_worker::lighting::ambient::matched(&prepared.renderer, ctx, &settings)?;
        pre += ms(t);
    }
    say(&format!("{name}: rendering"));
    // One untimed strip first: the pipeline's first dispatch compiles it.
    prepared.renderer.render_strip(
        ctx,
        &RenderSettings { width: 8, height: 8, spp: 1, ..settings },
        0,
        8,
    )?;
    let t = Instant::now();
    let (image, own_local) = render_whole(ctx, prepared, &settings)?;
    let frame_ms = ms(t);
    // The same frame with other seeds (untimed): with `local`'s second
    // render (or its own, below), the spread of the two tells the method's
    // own sampling noise.
    let (again, own_local_again) = render_whole(
        ctx,
        prepared,
        &RenderSettings { seed: settings.seed ^ SECOND_SEED, ..settings },
    )?;
    let file = out.join(format!("{}.png", file_stem(name)));
    write_png(&file, f.width, f.height, &reinhard_like(&image, exposure))?;
    if hdr {
        write_hdr(&file.with_extension("npy"), &image)?;
    }
    let paper =
        scene.file.lb_model == LbModel::Paper && sylva_worker::lighting::method(lighting).needs.lb;
    let notes = json!({
        "lb_model": scene.file.lb_model.name(),
        // The paper model's strength is a knob, not physics: say so where it is used.
        "non_physical": if paper { json!({ "lb_strength": f.lb_strength }) } else { serde_json::Value::Null },
        "lb": prepared.light,
        "forest_grid": prepared.forest,
        "boulanger": prepared.boulanger,
        "ambient": settings.ambient,
        "spp": settings.spp,
        "gather_filter": if sylva_worker::lighting::gather::filtered(&settings) { json!(settings.gather_filter) } else { serde_json::Value::Null },
        "gather_bounces": if sylva_worker::lighting::method(lighting).kernel == sylva_worker::lighting::Kernel::Reference { json!(settings.gather_bounces) } else { serde_json::Value::Null },
        "warnings": prepared.light.iter().flat_map(|l| l.warnings.iter().map(move |w| format!("{}: {w}", l.model))).collect::<Vec<_>>(),
    });
    Ok(Rendered {
        report: MethodReport {
            name: name.into(),
            family: c.family.clone(),
            lighting,
            lb_grids: prepared.light.iter().map(|l| l.grid).collect(),
            forest_grid: prepared.forest.as_ref().map(|f| f.used),
            build_ms: prepared.phases.ms("build"),
            preprocess_ms: pre,
            frame_ms,
            rmse: 0.0,
            mean_relative_error: 0.0,
            mean_ratio: [0.0; 3],
            indirect_relative_error: 0.0,
            indirect_error_net: 0.0,
            indirect_noise_reference: 0.0,
            indirect_noise_method: 0.0,
            image: file.display().to_string(),
            notes,
        },
        image,
        again,
        own_local: own_local.zip(own_local_again),
    })
}

/// The whole frame as one strip: the image and, from the per-sample
/// kernels (the gathers), what `local` shows along the same camera samples.
fn render_whole(
    ctx: &GpuContext,
    prepared: &sylva_worker::prepare::PreparedScene,
    f: &RenderSettings,
) -> anyhow::Result<(HdrImage, Option<HdrImage>)> {
    crate::lab::pilot::render_columns(ctx, &prepared.renderer, f, &[(0, f.width)])
}

/// A method's name as a file name: `lb 32³ + forest grid` → `lb-32-forest-grid`.
fn file_stem(name: &str) -> String {
    name.replace(['³', '+'], "").split_whitespace().collect::<Vec<_>>().join("-")
}

/// The fractions of the reference's time at which the progressive path
/// tracer's error is measured.
const PROGRESSIVE_FRACTIONS: [f64; 5] = [0.01, 0.02, 0.05, 0.1, 0.2];

/// The reference's path tracer run progressively as a method of its own,
/// with other seeds, [`PROGRESSIVE_PASS_SPP`] samples per pixel per pass
/// (jittered over the pixel as the reference's are: a single sample sits at
/// the pixel's centre, and centre samples alone would count edge aliasing
/// as error that never falls): its raw indirect error
/// against the reference (indirect light along its own samples, as the
/// reference's) at 1, 2, 5, 10 and 20 % of the reference's time, and at
/// least twice the passes of the point before (a fast reference would
/// otherwise put every point at one pass). What brute force reaches at the
/// cost of each fast method.
fn progressive_path_tracer(
    ctx: &GpuContext,
    scene: &Scene,
    f: &RenderSettings,
    r: &ReferenceImage,
    lit: &[bool],
    say: &dyn Fn(&str),
) -> anyhow::Result<Vec<pareto::Point>> {
    let prepared = prepare(ctx, scene, AccelKind::Bvh, LightingMode::Reference, say)?;
    let n = (f.width * f.height) as usize;
    let (mut sum, mut local) = (vec![[0.0f64; 3]; n], vec![[0.0f64; 3]; n]);
    let mut points = Vec::new();
    let t = Instant::now();
    let mut passes = 0u32;
    for &fraction in &PROGRESSIVE_FRACTIONS {
        let until = fraction * r.stats.ms;
        let at_least = (2 * passes).max(1);
        while passes < at_least || ms(t) < until {
            let settings = RenderSettings {
                spp: PROGRESSIVE_PASS_SPP,
                seed: (f.seed ^ PROGRESSIVE_SEED).wrapping_add(passes.wrapping_mul(0x9E37_79B9)),
                lighting: LightingMode::Reference,
                ..*f
            };
            let s = prepared.renderer.render_strip(ctx, &settings, 0, f.width)?;
            for i in 0..n {
                for c in 0..3 {
                    sum[i][c] += s.pixels[i][c] as f64;
                    local[i][c] += s.first_light[i][c] as f64;
                }
            }
            passes += 1;
        }
        let mean = |v: &[[f64; 3]]| HdrImage {
            width: f.width,
            height: f.height,
            pixels: v.iter().map(|p| p.map(|x| (x / passes as f64) as f32)).collect(),
        };
        let (image, own) = (mean(&sum), mean(&local));
        let e = IndirectError::measure([&image, &image], [&own, &own], r, lit);
        say(&format!("progressive path tracer: {passes} spp, {:.1} %", 100.0 * e.raw));
        points.push(pareto::Point {
            name: format!("path tracer {} spp", passes * PROGRESSIVE_PASS_SPP),
            family: "progressive path tracer".into(),
            ms: ms(t),
            raw: e.raw,
            net: None,
        });
    }
    Ok(points)
}

/// Samples per pixel of one pass of the progressive path tracer (2 × 2 strata).
const PROGRESSIVE_PASS_SPP: u32 = 4;

/// The seed bits of the progressive path tracer's samples.
const PROGRESSIVE_SEED: u32 = 0x5EED_0003;

/// (RMSE, mean relative error) over lit pixels of method image `m` against
/// the reference `r`: whole images ([`IndirectError`] takes the indirect part).
fn errors(m: &HdrImage, r: &HdrImage, lit: &[bool]) -> (f64, f64) {
    let (mut se, mut rel, mut n) = (0.0f64, 0.0f64, 0usize);
    for (i, _) in lit.iter().enumerate().filter(|(_, lit)| **lit) {
        let (p, q) = (m.pixels[i], r.pixels[i]);
        for c in 0..3 {
            se += ((p[c] - q[c]) as f64).powi(2);
        }
        let lr = luminance(q) as f64;
        rel += ((luminance(p) as f64) - lr).abs() / lr;
        n += 1;
    }
    let n = n.max(1) as f64;
    ((se / (3.0 * n)).sqrt(), rel / n)
}

/// Per channel, the mean of `m` over lit pixels over the reference `r`'s.
fn mean_ratio(m: &HdrImage, r: &HdrImage, lit: &[bool]) -> [f64; 3] {
    let (mut a, mut b) = ([0.0f64; 3], [0.0f64; 3]);
    for (i, _) in lit.iter().enumerate().filter(|(_, l)| **l) {
        for c in 0..3 {
            a[c] += m.pixels[i][c] as f64;
            b[c] += r.pixels[i][c] as f64;
        }
    }
    [0, 1, 2].map(|c| if b[c] > 0.0 { a[c] / b[c] } else { 0.0 })
}

/// The one-bounce image Boulanger et al.'s terms model, converged as the
/// reference is: a gather one bounce deep whose far end is dark (the
/// matched constant set to zero) and whose ground is lit by the sky, with
/// a quarter of the reference's time at most (its paths are short).
fn one_bounce_reference(
    a: &CompareArgs,
    ctx: &GpuContext,
    scene: &Scene,
    settings: &RenderSettings,
    say: &dyn Fn(&str),
) -> anyhow::Result<ReferenceImage> {
    let prepared = prepare(ctx, scene, AccelKind::Bvh, LightingMode::GatherAmbient, say)?;
    let f = RenderSettings {
        lighting: LightingMode::GatherAmbient,
        ambient: [0.0; 3],
        gather_bounces: 1,
        gather_filter: 0,
        ..*settings
    };
    let opts = ReferenceOptions {
        target_error: a.target_error,
        max_seconds: a.max_seconds / 4.0,
        ..Default::default()
    };
    render_reference(ctx, &prepared.renderer, &f, &opts, &|s| {
        say(&format!(
            "one-bounce reference: {} spp, relative standard error {:.4}",
            s.spp, s.relative_error
        ))
    })
}

/// Writes a linear image as float32 `.npy`, height × width × 3.
fn write_hdr(path: &Path, img: &HdrImage) -> anyhow::Result<()> {
    let flat: Vec<f32> = img.pixels.iter().flatten().copied().collect();
    Ok(sylva_light::npy::write_f32(path, &[img.height as u64, img.width as u64, 3], &flat)?)
}

/// The seed bits that give a method's second render other samples.
const SECOND_SEED: u32 = 0x5EED_0002;

/// What a saved reference was made for: the scene's bundle (the scene
/// file and every model file it names, as `sylva submit` packs it), the
/// image, the reference's budget and this very binary.
fn reference_key(a: &CompareArgs) -> anyhow::Result<String> {
    let bundle = sylva_scene::bundle::pack(&a.scene)?;
    let mut h = blake3::Hasher::new();
    h.update(bundle.hash.as_bytes());
    h.update(format!("{}x{} {} {}", a.width, a.height, a.target_error, a.max_seconds).as_bytes());
    let exe = std::env::current_exe().context("this program's own file")?;
    let mut file =
        std::fs::File::open(&exe).with_context(|| format!("{}: cannot read", exe.display()))?;
    std::io::copy(&mut file, &mut h).with_context(|| format!("{}: cannot read", exe.display()))?;
    Ok(h.finalize().to_hex().to_string())
}

/// A saved reference and the key it was made for.
#[derive(serde::Serialize, serde::Deserialize)]
struct SavedReference {
    key: String,
    reference: ReferenceImage,
}

/// Writes the reference beside the images, for `--reuse-reference`.
fn save_reference(path: &Path, key: &str, r: &ReferenceImage) -> anyhow::Result<()> {
    let bytes = postcard::to_stdvec(&SavedReference { key: key.into(), reference: r.clone() })?;
    std::fs::write(path, bytes).with_context(|| format!("{}: cannot write", path.display()))
}

/// The saved reference if it was made for `key` and has the image's size;
/// otherwise `None` (and the reason, logged), so the reference is rendered.
fn load_reference(path: &Path, key: &str, width: u32, height: u32) -> Option<ReferenceImage> {
    let bytes = std::fs::read(path)
        .map_err(|e| tracing::info!("{}: no saved reference ({e})", path.display()))
        .ok()?;
    let saved: SavedReference = postcard::from_bytes(&bytes)
        .map_err(|e| tracing::warn!("{}: unreadable reference ({e})", path.display()))
        .ok()?;
    let n = (width * height) as usize;
    let r = saved.reference;
    let sized = [
        r.image.pixels.len(),
        r.local.pixels.len(),
        r.coverage.len(),
        r.std_error.len(),
        r.indirect_variance.len(),
    ]
    .iter()
    .all(|&l| l == n)
        && r.image.width == width
        && r.image.height == height;
    if saved.key != key || !sized {
        tracing::warn!(
            "{}: made for another scene, size, budget or build; rendering a new reference",
            path.display()
        );
        return None;
    }
    tracing::info!("{}: reusing the saved reference ({} spp)", path.display(), r.stats.spp);
    Some(r)
}

/// Which method wins where: the most accurate, the fastest that beats
/// constant ambient, and the best error per unit time.
fn winner(reports: &[MethodReport]) -> String {
    let methods: Vec<&MethodReport> =
        reports.iter().filter(|m| m.lighting != LightingMode::Reference).collect();
    let Some(best) =
        methods.iter().min_by(|a, b| a.mean_relative_error.total_cmp(&b.mean_relative_error))
    else {
        return String::new();
    };
    let ambient = methods
        .iter()
        .find(|m| m.lighting == LightingMode::Ambient)
        .map_or(f64::INFINITY, |m| m.mean_relative_error);
    let cheapest_better = methods
        .iter()
        .filter(|m| m.mean_relative_error < ambient)
        .min_by(|a, b| (a.preprocess_ms + a.frame_ms).total_cmp(&(b.preprocess_ms + b.frame_ms)));
    let lowest_rmse = methods.iter().min_by(|a, b| a.rmse.total_cmp(&b.rmse)).expect("not empty");
    // The relative error weighs dark pixels most, RMSE bright ones: say both.
    let mut s = format!(
        "most accurate: {} ({:.1} % mean relative error); lowest RMSE: {} ({:.4})",
        best.name,
        100.0 * best.mean_relative_error,
        lowest_rmse.name,
        lowest_rmse.rmse
    );
    match cheapest_better {
        Some(c) => {
            s += &format!(
                "; cheapest to beat constant ambient ({:.1} %): {} ({:.1} %, {:.0} ms in all)",
                100.0 * ambient,
                c.name,
                100.0 * c.mean_relative_error,
                c.preprocess_ms + c.frame_ms
            )
        }
        None => s += &format!("; no method beats constant ambient ({:.1} %) here", 100.0 * ambient),
    }
    s
}

/// Figure 2 of the forest paper as an SVG of PNG tiles: full (LB), local,
/// ambient matched, LB visualization, reference, and error heat maps.
fn write_figure(
    path: &Path,
    a: &CompareArgs,
    rendered: &[Rendered],
    reference: &HdrImage,
) -> anyhow::Result<()> {
    let find = |pred: &dyn Fn(&MethodReport) -> bool| rendered.iter().find(|m| pred(&m.report));
    let lb = find(&|m| m.name == "lb auto").or_else(|| find(&|m| m.lighting == LightingMode::Lb));
    let mut tiles: Vec<(String, PathBuf)> = Vec::new();
    let dir = path.parent().unwrap_or(Path::new("."));
    let name_of = |p: &str| {
        PathBuf::from(p).file_name().map(|f| f.to_string_lossy().to_string()).unwrap_or_default()
    };
    if let Some(m) = lb {
        tiles.push((format!("(a) full: {}", m.report.name), name_of(&m.report.image).into()));
    }
    for (label, l) in
        [("(b) local", LightingMode::Local), ("(c) ambient matched", LightingMode::Ambient)]
    {
        if let Some(m) = find(&|m| m.lighting == l) {
            tiles.push((label.into(), name_of(&m.report.image).into()));
        }
    }
    // The LB light alone is a separate render of the auto scene's grids: the
    // (a) − (b) difference shows it without another LB solve.
    if let (Some(m), Some(l)) = (lb, find(&|m| m.lighting == LightingMode::Local)) {
        let diff = HdrImage {
            width: a.width,
            height: a.height,
            pixels: m
                .image
                .pixels
                .iter()
                .zip(&l.image.pixels)
                .map(|(p, q)| std::array::from_fn(|c| (p[c] - q[c]).max(0.0)))
                .collect(),
        };
        let (ldr, _) = reinhard(&diff, 0.18);
        write_png(&dir.join("lb-visualize.png"), a.width, a.height, &ldr)?;
        tiles.push(("(d) LB light alone".into(), "lb-visualize.png".into()));
    }
    tiles.push(("(e) reference (path traced)".into(), "reference.png".into()));
    if let Some(m) = find(&|m| m.lighting == LightingMode::Boulanger) {
        tiles.push(("(f) Boulanger et al.".into(), name_of(&m.report.image).into()));
    }
    for (label, m) in [
        ("error: full", lb),
        ("error: ambient", find(&|m| m.lighting == LightingMode::Ambient)),
        ("error: Boulanger", find(&|m| m.lighting == LightingMode::Boulanger)),
    ] {
        if let Some(m) = m {
            let file = format!("error-{}.png", m.report.name.replace(['³', ' ', '+'], ""));
            write_png(&dir.join(&file), a.width, a.height, &heat_map(&m.image, reference))?;
            tiles.push((format!("{label} (black 0, red 50 %, yellow ≥ 100 %)"), file.into()));
        }
    }
    let (tw, th) = (a.width as f64, a.height as f64 + 22.0);
    let cols = 3usize;
    let rows = tiles.len().div_ceil(cols);
    let mut s = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" width="{}" height="{}" font-family="sans-serif" font-size="13"><rect width="100%" height="100%" fill="white"/>"#,
        tw * cols as f64,
        th * rows as f64
    );
    for (i, (label, file)) in tiles.iter().enumerate() {
        let (x, y) = ((i % cols) as f64 * tw, (i / cols) as f64 * th);
        // `href` for SVG 2 readers, `xlink:href` for older ones: both the file.
        s += &format!(
            r#"<text x="{}" y="{}">{}</text><image x="{x}" y="{}" width="{}" height="{}" href="{file}" xlink:href="{file}"/>"#,
            x + 4.0,
            y + 15.0,
            label,
            y + 20.0,
            a.width,
            a.height,
            file = file.display()
        );
    }
    s += "</svg>\n";
    std::fs::write(path, s).with_context(|| format!("{}: cannot write", path.display()))
}

/// Per-pixel relative luminance error as colour: black 0, red 0.5, yellow ≥ 1.
fn heat_map(m: &HdrImage, r: &HdrImage) -> Vec<[u8; 3]> {
    m.pixels
        .iter()
        .zip(&r.pixels)
        .map(|(&p, &q)| {
            let lr = luminance(q).max(1e-4);
            let e = ((luminance(p) - lr).abs() / lr).clamp(0.0, 1.0);
            let red = (2.0 * e).min(1.0);
            let green = (2.0 * e - 1.0).max(0.0);
            [(red * 255.0) as u8, (green * 255.0) as u8, 0]
        })
        .collect()
}

/// Runs the LB failure-mode sweeps and charts each: LB's error against
/// the Monte Carlo reference beside the best constant's.
fn write_sweeps(out: &Path) -> anyhow::Result<serde_json::Value> {
    let mut all = Vec::new();
    for sweep in sylva_light::studies::limits::failure_sweeps(true) {
        let lb: Vec<(f64, f64)> = sweep.points.iter().map(|p| (p.x, 100.0 * p.lb_error)).collect();
        let amb: Vec<(f64, f64)> =
            sweep.points.iter().map(|p| (p.x, 100.0 * p.ambient_error)).collect();
        let warned: Vec<(f64, f64)> =
            sweep.points.iter().filter(|p| p.warned).map(|p| (p.x, 100.0 * p.lb_error)).collect();
        let mut xs: Vec<f64> = sweep.points.iter().map(|p| p.x).collect();
        xs.sort_by(f64::total_cmp);
        let series = [
            Series { name: "LB".into(), color: "#2ca02c", dashed: false, points: sorted(lb) },
            Series {
                name: "constant ambient".into(),
                color: "#999999",
                dashed: true,
                points: sorted(amb),
            },
            Series {
                name: "LB, warned".into(),
                color: "#d62728",
                dashed: false,
                points: sorted(warned),
            },
        ];
        let file = out.join(format!("failure-{}.svg", sweep.name.replace(' ', "-")));
        std::fs::write(
            &file,
            line_chart(
                &format!("LB against Monte Carlo: {}", sweep.name),
                sweep.x_label,
                "relative RMS error of fluence, %",
                &xs,
                &series,
            ),
        )?;
        all.push(json!({ "name": sweep.name, "x_label": sweep.x_label, "chart": file, "points": sweep.points.iter().map(|p| json!({ "x": p.x, "lb_error": p.lb_error, "ambient_error": p.ambient_error, "warned": p.warned, "lb_ms": p.lb_ms, "mc_ms": p.mc_ms })).collect::<Vec<_>>() }));
    }
    Ok(serde_json::Value::Array(all))
}

fn sorted(mut v: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v
}
