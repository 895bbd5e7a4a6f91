//! `sylva compare SCENE`: renders a scene with every lighting method,
//! measures each one's pre-process and frame time and its error against
//! the path-traced reference, and writes a table (JSON), an image grid in
//! the style of the forest paper's Figure 2 and a chart of error against
//! time. Optionally adds the LB failure-mode sweeps (LB against a Monte
//! Carlo reference of the same medium), each as a chart.

mod figures;
mod methods;
mod reference;

use crate::flags::compare::*;
use crate::lab::crowns;
use crate::measure::chart::{Series, line_chart};
use crate::measure::error::{IndirectError, lit_pixels};
use crate::measure::pareto;
use anyhow::Context;
use figures::{write_figure, write_sweeps};
use indicatif::{ProgressBar, ProgressStyle};
use methods::{Candidate, Output, Preparation, methods_to_compare, render_method, write_hdr};
use reference::{one_bounce_reference, progressive_path_tracer};
use serde::Serialize;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;
use sylva_accel::AccelKind;
use sylva_scene::color::luminance;
use sylva_scene::film::{HdrImage, ToneMapStats, reinhard, reinhard_like, write_png};
use sylva_scene::frame::FrameSettings;
use sylva_scene::sequence::View;
use sylva_scene::{ForestGridUse, LbModel, LightingMode, Scene};
use sylva_worker::frame::reference::{ReferenceImage, ReferenceOptions};
use sylva_worker::frame::{Frame, Fresh, Given, Preparer};
use sylva_worker::lighting::Needs;
use sylva_worker::lighting::lb::auto::choose_lb_grids;
use sylva_worker::prepare::PreparedScene;
use sylva_worker::trace::{RenderSettings, Tracer};

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
    /// The indirect error over the lit pixels that see no cloud, where the
    /// scene has clouds: the leaves' light alone, apart from the cloud
    /// that `local` and `boulanger` do not draw.
    #[serde(skip_serializing_if = "Option::is_none")]
    clear_of_clouds: Option<ClearOfClouds>,
    /// Image file.
    image: String,
    /// What the method decided and why (grid choice, forest grid, warnings).
    notes: serde_json::Value,
}

/// A method's indirect error over the lit pixels no cloud is seen in.
#[derive(Debug, Clone, Copy, Serialize)]
struct ClearOfClouds {
    /// Raw: bias and noise, as `indirect_relative_error`.
    raw: f64,
    /// With both images' noise taken out, as `indirect_error_net`.
    net: f64,
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
    let ctx = Tracer::new()?;
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
    let (r, build_ms, pre, reused) = reference::reference(&a, &ctx, &scene, &settings, &bar)?;
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
        let to = Output { dir: &a.out, exposure: &exposure, hdr: a.hdr };
        rendered.push(render_method(&ctx, c, prepared, &frame, &f, &to, &|m| say(m))?);
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
    let to = Output { dir: &a.out, exposure: &exposure, hdr: a.hdr };
    let mut auto =
        render_method(&ctx, &auto_candidate, &prepared, &frame, &settings, &to, &|m| say(m))?;
    auto.report.preprocess_ms += choose_ms;
    auto.report.notes["grid_choice"] = serde_json::to_value(&choices)?;
    rendered.push(auto);
    say("progressive path tracer");
    let progressive = progressive_path_tracer(&ctx, &scene, &settings, &r, &lit, &|m| say(m))?;
    bar.finish_and_clear();

    // Errors against the reference; the indirect part (method − local)
    // against the reference's own (its estimate minus local along its samples).
    // Where the scene has clouds, again over the lit pixels that see none.
    let (local, local_again) = (rendered[0].image.clone(), rendered[0].again.clone());
    // The scene's structures on the CPU, for which pixel shows what.
    let accel = sylva_accel::SceneAccel::build(&scene, AccelKind::Bvh);
    let clouds = crowns::cloud_pixels(&scene, &accel, a.width, a.height);
    let clear: Option<Vec<bool>> = clouds
        .iter()
        .any(|&c| c)
        .then(|| lit.iter().zip(&clouds).map(|(&l, &c)| l && !c).collect());
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
        m.report.clear_of_clouds = clear.as_ref().map(|clear| {
            let e = IndirectError::measure([&m.image, &m.again], l, &r, clear);
            ClearOfClouds { raw: e.raw, net: e.net }
        });
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
    // Per crown: each instance's mean indirect light, reference and
    // methods, over the lit pixels that see no cloud.
    let ids = crowns::instance_ids(&scene, &accel, a.width, a.height);
    crowns::write_id_image(&a.out.join("instances.png"), a.width, a.height, &ids)?;
    let crown_pixels = clear.as_ref().unwrap_or(&lit);
    if clear.is_some() {
        let mask: Vec<Option<u32>> = clouds.iter().map(|&c| c.then_some(0)).collect();
        crowns::write_id_image(&a.out.join("clouds.png"), a.width, a.height, &mask)?;
    }
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
        crowns::table(&scene, &ids, crown_pixels, &|i| indirect(&r.image, &r.local, i), &columns);
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
        clear_of_clouds: None,
        notes: json!({ "reused": reused, "spp": r.stats.spp, "batches": r.stats.batches, "relative_standard_error": r.stats.relative_error, "converged": r.stats.converged, "max_bounces": sylva_worker::trace::MAX_BOUNCES, "leaf_optics": scene.file.leaf_optics }),
    });

    // The time–error chart: every method (the path tracer's denoised
    // families among them) and the progressive path tracer; not the
    // reference, the last report, which they are measured against.
    let mut points: Vec<pareto::Point> = reports[..rendered.len()]
        .iter()
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
        "lit_pixels_seeing_clouds": clear.as_ref().map(|c| lit.iter().zip(c).filter(|(l, c)| **l && !**c).count()),
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
        if let Some(c) = &clear {
            let seen = lit.iter().zip(c).filter(|(l, c)| **l && !**c).count();
            println!(
                "{seen} lit pixels see a cloud (clouds.png); over the rest, the leaves' light alone:"
            );
            for m in &reports {
                if let Some(e) = m.clear_of_clouds {
                    println!(
                        "  {:<28} {:>5.1} % raw, {:>5.1} % net",
                        m.name,
                        100.0 * e.raw,
                        100.0 * e.net
                    );
                }
            }
        }
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
        clear_of_clouds: None,
        image: String::new(),
        notes: serde_json::Value::Null,
    }
}

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
