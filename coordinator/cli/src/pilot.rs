//! `sylva render --lighting auto`: a short pilot on the scene picks the
//! lighting method and its parameters (LB grid, gather depth and rays,
//! path-tracer samples) for a time budget or an error ceiling.
//!
//! The pilot renders a few of the frame's own columns, at the frame's own
//! size, about [`PILOT_PIXELS`] pixels in all: so its pixels see what the
//! frame's see (leaf edges, the gathers' filter radius in pixels). A short
//! reference first, then every candidate, each measured as `compare`
//! measures it: the error of its indirect light against the reference's
//! expectation, over lit pixels, the candidate's own noise kept (what a
//! viewer sees). A candidate's time is its lighting's pre-process plus
//! its frame (for a sequence, the whole job's: [`Job`]), both measured
//! on the whole frame: the pilot's columns are where the models are, and
//! a model's pixel costs many times a sky's.
//! A sampled method's frame is timed at one and four rays a pixel and
//! taken as a fixed part plus a part per ray.
//!
//! A sampled method (the path tracer, each gather) is measured at two
//! ray counts k and fitted as e(k)² = b² + c/k: its bias b does not
//! change with k, its noise variance falls as 1/k (b = 0 for the path
//! tracer, unbiased by construction). Its curve then gives the k the goal
//! asks for. What was chosen and why goes to the log and to the stats.

use crate::measure::error::{IndirectError, lit_pixels};
use crate::measure::pareto;
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;
use sylva_accel::AccelKind;
use sylva_scene::film::HdrImage;
use sylva_scene::frame::{Denoise, FrameSettings, MAX_SPP};
use sylva_scene::{LightingMode, Scene};
use sylva_worker::frame::reference::ReferenceOptions;
use sylva_worker::frame::{Frame, Fresh};
use sylva_worker::prepare::PreparedScene;
use sylva_worker::trace::{RenderSettings, Tracer};

/// What the user asks of `auto`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Goal {
    /// The most accurate method whose pre-process and frames (the whole
    /// job's, for a sequence) fit this many seconds.
    TimeBudget(f64),
    /// The fastest method whose indirect error is at most this (0.1: 10 %).
    MaxError(f64),
}

/// Pixels the pilot renders at most: whole columns of the frame. Enough
/// lit pixels that a 10 % error is measured to about a percent; few
/// enough that its reference takes seconds.
pub const PILOT_PIXELS: u32 = 16_384;

/// The pilot's columns come in this many strips spread over the frame.
const PILOT_STRIPS: u32 = 4;

/// The pilot's reference stops at this relative standard error of the
/// image (its remaining noise is taken out of every error, see
/// [`IndirectError::seen`]) …
const PILOT_REFERENCE_ERROR: f64 = 0.02;

/// … or after this many seconds.
const PILOT_REFERENCE_SECONDS: f64 = 30.0;

/// The two ray counts each sampled method is measured at.
const MEASURED_RAYS: [u32; 2] = [4, 16];

/// Coarser LB grids tried beside each model's own (every model at once).
const COARSER_GRIDS: [usize; 2] = [16, 32];

/// The job the chosen method renders: its frames, and the suns they are
/// lit by. A method's preparation is paid once (the structures, the
/// voxels), its light once per sun, its frame every frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Job {
    /// Frames in the job.
    pub frames: usize,
    /// Distinct suns among them (1 for a single frame or a camera path).
    pub suns: usize,
}

impl Job {
    /// One frame.
    pub const FRAME: Job = Job { frames: 1, suns: 1 };

    /// The job of a sequence's `views`: its suns counted as the preparer
    /// keys the light it keeps ([`View::sun_key`](sylva_scene::sequence::View::sun_key)).
    pub fn of(views: &[sylva_scene::sequence::View]) -> Job {
        if views.is_empty() {
            return Job::FRAME;
        }
        let mut suns: Vec<Option<[u32; 3]>> = views.iter().map(|v| v.sun_key()).collect();
        suns.sort_unstable();
        suns.dedup();
        Job { frames: views.len(), suns: suns.len() }
    }

    /// The whole job's milliseconds: the first sun's pre-process, each
    /// further sun's light, and every frame.
    fn ms(&self, preprocess_ms: f64, per_sun_ms: f64, frame_ms: f64) -> f64 {
        preprocess_ms
            + per_sun_ms * self.suns.saturating_sub(1) as f64
            + frame_ms * self.frames as f64
    }
}

/// One candidate, measured on the pilot (or read off its family's curve).
#[derive(Clone, Debug, Serialize)]
pub struct Measured {
    /// As `compare` names it, with its grid where it is not the scene's.
    pub name: String,
    /// Its curve: the method with every parameter but its rays.
    pub family: String,
    /// The method.
    pub lighting: LightingMode,
    /// Every model's LB grid; `None`: each model's own (or no LB).
    pub lb_grid: Option<usize>,
    /// Rays per pixel (a gather's gather rays, the path tracer's samples).
    pub spp: u32,
    /// The gathers: bounces before the lattice.
    pub gather_bounces: u32,
    /// The gathers: filter radius, pixels.
    pub gather_filter: u32,
    /// What of its frame is denoised (the path tracer's indirect light, or nothing).
    pub denoise: Denoise,
    /// The lighting's own pre-process (LB, forest LB, clouds, ambient
    /// match), measured on the scene itself: it does not scale with pixels.
    pub preprocess_ms: f64,
    /// What each further sun costs it: the pre-process less what every
    /// sun shares (the models' voxels).
    pub per_sun_ms: f64,
    /// Its whole frame, strip by strip as the frame is rendered (a
    /// sampled method's: fixed + per ray × rays, timed at 1 and 4 rays).
    pub frame_ms: f64,
    /// The job's time: pre-process, each further sun's light, and every
    /// frame (one frame: pre-process plus frame).
    pub predicted_ms: f64,
    /// Indirect error a viewer sees, bias and the method's own noise, on the pilot.
    pub error: f64,
    /// Whether `error` and the time are read off the family's fitted
    /// curve rather than measured.
    pub extrapolated: bool,
}

/// The pilot's own columns and reference.
#[derive(Clone, Debug, Serialize)]
pub struct PilotFrame {
    /// The frame's columns rendered, `[x0, x1)`.
    pub columns: Vec<(u32, u32)>,
    /// Pixels whose error counts.
    pub lit_pixels: usize,
    /// Samples per pixel of its reference.
    pub reference_spp: u32,
    /// Its reference's relative standard error.
    pub reference_relative_error: f64,
    /// Whole pilot, milliseconds (preparations, reference, candidates).
    pub ms: f64,
}

/// What `auto` measured, chose and why.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// What was asked.
    pub goal: Goal,
    /// The job it was asked for.
    pub job: Job,
    /// The pilot.
    pub pilot: PilotFrame,
    /// Every candidate: measured, then read off the curves.
    pub candidates: Vec<Measured>,
    /// Candidates the pilot could not measure here, and why.
    pub left_out: Vec<String>,
    /// The choice.
    pub chosen: Measured,
    /// Why, in a sentence.
    pub why: String,
}

/// The choice, ready to render: the scene with its grids, prepared.
pub struct Choice {
    /// What was measured and why this.
    pub report: Report,
    /// The scene with the chosen grids.
    pub scene: Scene,
    /// Its preparation, from the pilot (the frame does not prepare again).
    pub prepared: Arc<PreparedScene>,
    /// The frame with the chosen method and parameters.
    pub frame: FrameSettings,
    /// What the pilot made of the scene that the chosen method's frames
    /// can go on from (the structures, the models' voxels, the light of
    /// the pilot's sun where it is the chosen grids'), for a sequence's
    /// other frames ([`Fresh::with_reuse`]).
    pub reuse: sylva_worker::prepare::Reuse,
}

/// The columns the pilot renders of a `width` × `height` frame whose
/// columns show `coverage` model pixels each: the whole frame when it
/// holds at most [`PILOT_PIXELS`], else [`PILOT_STRIPS`] strips of equal
/// width, centred at equal steps of the models' pixels (so each strip
/// sees as much of the models as the next; at equal steps across the
/// frame when no model shows).
pub fn pilot_columns(width: u32, height: u32, coverage: &[f64]) -> Vec<(u32, u32)> {
    let columns = (PILOT_PIXELS / height.max(1)).max(PILOT_STRIPS);
    if columns >= width {
        return vec![(0, width)];
    }
    let each = columns / PILOT_STRIPS;
    let total: f64 = coverage.iter().sum();
    let mut strips: Vec<(u32, u32)> = Vec::new();
    for i in 0..PILOT_STRIPS {
        let step = (2 * i + 1) as f64 / (2 * PILOT_STRIPS) as f64;
        let centre = if total > 0.0 {
            let mut sum = 0.0;
            coverage.iter().position(|c| {
                sum += c;
                sum >= step * total
            })
        } else {
            None
        }
        .map_or((step * width as f64) as u32, |c| c as u32);
        // Side by side where the models are narrower than the strips.
        let after = strips.last().map_or(0, |s| s.1);
        let x0 = centre.saturating_sub(each / 2).max(after).min(width - each);
        if x0 >= after {
            strips.push((x0, x0 + each));
        }
    }
    strips
}

/// Runs the pilot for `frame` (to be rendered as `plan`'s strips) on
/// `scene` and picks what `goal` asks for.
pub fn choose(
    tracer: &Tracer,
    scene: &Scene,
    frame: &FrameSettings,
    plan: &[(u32, u32)],
    goal: Goal,
    job: Job,
    say: &dyn Fn(&str),
) -> anyhow::Result<Choice> {
    let t = Instant::now();
    // The pilot measures images; the frame it chooses carries the passes.
    let base = RenderSettings {
        lighting: LightingMode::Local,
        passes: Default::default(),
        ..RenderSettings::resolve(frame, scene.lighting)
    };
    // One preparation per grid (the acceleration structures built once):
    // the LB methods' needs cover local's and the path tracer's.
    let own = scene.models.iter().map(|m| m.lb.grid).max().unwrap_or(0);
    let mut grids = vec![None];
    grids.extend(COARSER_GRIDS.iter().filter(|&&g| g < own).map(|&g| Some(g)));
    let mut fresh = Fresh::default();
    let mut preparations = Vec::new();
    // Prepared as the frame layer prepares a gather's frame, on the BVH.
    let request = FrameSettings {
        lighting: Some(LightingMode::Gather),
        accel: AccelKind::Bvh.into(),
        ambient: None,
        ..*frame
    };
    for &g in &grids {
        let mut s = scene.clone();
        if let Some(g) = g {
            for m in &mut s.models {
                m.lb.grid = g;
            }
        }
        say(&format!("pilot: preparing {}", grid_name(g)));
        fresh.reuse.lb = None;
        let p = Frame::compose(tracer, &s, &request, &mut fresh, say)?;
        let pre_ms = p.prepared.lighting_ms();
        preparations.push((g, s, p, pre_ms));
    }

    // Where the models are: `local` at one sample a pixel over the frame.
    let (_, _, first, _) = &preparations[0];
    let whole = first.with_settings(RenderSettings { spp: 1, ..base }).strip(0, base.width)?;
    let mut coverage = vec![0.0f64; base.width as usize];
    for (k, c) in whole.coverage.iter().enumerate() {
        coverage[k % base.width as usize] += *c as f64;
    }
    let columns = pilot_columns(frame.width, frame.height, &coverage);
    // A frame's time, strip by strip as it will be rendered, after an
    // untimed dispatch that compiles its pipeline.
    let time_frame = |p: &Frame, f: &RenderSettings| -> anyhow::Result<f64> {
        p.with_settings(RenderSettings { width: 8, height: 8, spp: 1, ..*f }).strip(0, 8)?;
        let frame = p.with_settings(*f);
        let t = Instant::now();
        frame.strips(plan, &mut |_, _| Ok(()))?;
        Ok(ms(t))
    };

    // The pilot's reference, on the scene's own preparation.
    let opts = ReferenceOptions {
        target_error: PILOT_REFERENCE_ERROR,
        max_seconds: PILOT_REFERENCE_SECONDS,
        ..Default::default()
    };
    let reference = first.with_settings(base).reference(&columns, &opts, &|s| {
        say(&format!("pilot: reference, {} spp, relative error {:.3}", s.spp, s.relative_error))
    })?;
    let lit = lit_pixels(&reference);
    let lit_count = lit.iter().filter(|&&l| l).count();

    let mut measured = Vec::new();
    // Per sampled family: its frame's fixed and per-ray milliseconds.
    let mut timings: Vec<(String, f64, f64)> = Vec::new();
    let mut left_out = Vec::new();
    // A whole frame's denoise, timed once.
    let mut denoise_ms: Option<f64> = None;
    let local = render_columns(first, &base, &columns)?.0;
    for (g, _, p, pre_ms) in &preparations {
        // The voxels are made once for every sun; the rest of the
        // lighting's pre-process again for each.
        let voxelize_ms = p.prepared.phases.ms("voxelize");
        // `pre`: (the first sun's pre-process, each further sun's, what
        // every frame pays again: the ambient match is per view).
        let mut run = |family: &str, f: RenderSettings, pre: (f64, f64, f64), denoise: Denoise| {
            let sampled =
                f.lighting == LightingMode::Reference || f.lighting == LightingMode::Gather;
            let name = if sampled { format!("{family} {} rays", f.spp) } else { family.into() };
            say(&format!("pilot: {name}"));
            let frame_ms = if sampled {
                let (fixed, per_ray) = match timings.iter().find(|t| t.0 == family) {
                    Some(t) => (t.1, t.2),
                    None => {
                        let one = time_frame(p, &RenderSettings { spp: 1, ..f })?;
                        let four = time_frame(p, &RenderSettings { spp: 4, ..f })?;
                        let per_ray = ((four - one) / 3.0).max(0.0);
                        let fixed = (one - per_ray).max(0.0);
                        timings.push((family.to_string(), fixed, per_ray));
                        (fixed, per_ray)
                    }
                };
                fixed + per_ray * f.spp as f64
            } else {
                time_frame(p, &f)?
            };
            let frame_ms = if denoise.is_on() {
                let d = match denoise_ms {
                    Some(d) => d,
                    None => *denoise_ms.insert(denoise_frame_ms(f.width, f.height, denoise)?),
                };
                frame_ms + d
            } else {
                frame_ms
            };
            let frame_ms = frame_ms + pre.2;
            let (image, own) = render_columns_denoised(p, &f, &columns, denoise)?;
            let l = own.as_ref().unwrap_or(&local);
            let e = IndirectError::measure([&image, &image], [l, l], &reference, &lit);
            measured.push(Measured {
                name,
                family: family.into(),
                lighting: f.lighting,
                lb_grid: *g,
                spp: f.spp,
                gather_bounces: f.gather_bounces,
                gather_filter: f.gather_filter,
                denoise,
                preprocess_ms: pre.0,
                per_sun_ms: pre.1,
                frame_ms,
                predicted_ms: job.ms(pre.0, pre.1, frame_ms),
                error: e.seen,
                extrapolated: false,
            });
            anyhow::Ok(())
        };
        let on = |name: &str| match g {
            None => name.to_string(),
            Some(g) => format!("{name} on lb {g}³"),
        };
        if g.is_none() {
            run("local", base, (0.0, 0.0, 0.0), Denoise::Off)?;
            let t = Instant::now();
            let ambient = RenderSettings { lighting: LightingMode::Ambient, ..base };
            let ambient = RenderSettings {
                ambient: sylva_worker::frame::ambient::matched(
                    &p.prepared.renderer,
                    tracer,
                    &ambient,
                )?,
                ..ambient
            };
            let matched = ms(t);
            // The match is per view: every frame pays it.
            run("ambient", ambient, (*pre_ms, pre_ms - voxelize_ms, matched), Denoise::Off)?;
            let clouds_ms = p.prepared.phases.ms("cloud lb");
            for &k in &MEASURED_RAYS {
                let f = RenderSettings { lighting: LightingMode::Reference, spp: k, ..base };
                run("path tracer", f, (clouds_ms, clouds_ms, 0.0), Denoise::Off)?;
            }
            // The path tracer with its indirect light denoised, where the
            // denoiser works here: measured at its ray counts only (a
            // denoised image's error follows no fitted curve). A denoiser
            // that fails leaves it out, not the pilot.
            let denoised = sylva_denoise::available().map_err(anyhow::Error::from).and_then(|()| {
                for &k in &MEASURED_RAYS {
                    let denoise = Denoise::Indirect;
                    let f = RenderSettings {
                        lighting: LightingMode::Reference,
                        spp: k,
                        passes: denoise.passes(),
                        ..base
                    };
                    run(
                        "path tracer + denoised indirect",
                        f,
                        (clouds_ms, clouds_ms, 0.0),
                        denoise,
                    )?;
                }
                Ok(())
            });
            if let Err(e) = denoised {
                tracing::info!("the pilot leaves out denoised methods: {e:#}");
                left_out.push(format!("denoised methods: {e:#}"));
            }
        }
        let lb = RenderSettings { lighting: LightingMode::Lb, ..base };
        let pre = (*pre_ms, pre_ms - voxelize_ms, 0.0);
        run(&on("lb"), lb, pre, Denoise::Off)?;
        for bounces in [1, 2] {
            for &k in &MEASURED_RAYS {
                let f = RenderSettings {
                    lighting: LightingMode::Gather,
                    spp: k,
                    gather_bounces: bounces,
                    gather_filter: sylva_scene::frame::DEFAULT_GATHER_FILTER,
                    ..base
                };
                run(&on(&format!("gather {bounces}b")), f, pre, Denoise::Off)?;
            }
        }
    }
    let mut candidates = measured.clone();
    candidates.extend(along_curves(&measured, goal, job));

    let (chosen, why) = pick(&candidates, goal, lit_count);
    let why = if job.frames > 1 {
        let suns = if job.suns == 1 { "one sun".to_string() } else { format!("{} suns", job.suns) };
        format!(
            "{why}, for the whole job of {} frames under {suns} (each method's preparation once, its light once a sun, its frame every frame)",
            job.frames
        )
    } else {
        why
    };
    let chosen = chosen.clone();
    let index = grids.iter().position(|g| *g == chosen.lb_grid).unwrap_or(0);
    // The preparer holds the last grid's light: another grid's is not
    // the chosen scene's. Structures and voxels are checked where used.
    let last = preparations.len() - 1;
    let (_, scene, prepared, _) = preparations.swap_remove(index);
    let mut reuse = fresh.into_reuse();
    if index != last {
        reuse.lb = None;
    }
    let reuse = sylva_worker::prepare::Reuse {
        accel: reuse.accel,
        coverage: reuse.coverage,
        lb: reuse.lb,
        clouds: reuse.clouds,
        lb_media: reuse.lb_media,
        envelopes: reuse.envelopes,
        ..Default::default()
    };
    let frame = FrameSettings {
        lighting: Some(chosen.lighting),
        spp: chosen.spp,
        gather_bounces: chosen.gather_bounces,
        gather_filter: chosen.gather_filter,
        denoise: chosen.denoise,
        passes: if chosen.denoise.is_on() {
            frame.passes.with(chosen.denoise.passes())
        } else {
            frame.passes
        },
        ..*frame
    };
    let report = Report {
        goal,
        job,
        pilot: PilotFrame {
            columns,
            lit_pixels: lit_count,
            reference_spp: reference.stats.spp,
            reference_relative_error: reference.stats.relative_error,
            ms: ms(t),
        },
        candidates,
        left_out,
        chosen,
        why,
    };
    Ok(Choice { report, scene, prepared: prepared.prepared, frame, reuse })
}

/// "the scene's own LB grids" or "lb 16³".
fn grid_name(g: Option<usize>) -> String {
    g.map_or_else(|| "the scene's own LB grids".into(), |g| format!("lb {g}³"))
}

/// `columns` of the frame side by side, as one image: the method's and,
/// from the per-sample kernels, what `local` shows along the same samples.
pub fn render_columns(
    frame: &Frame,
    f: &RenderSettings,
    columns: &[(u32, u32)],
) -> anyhow::Result<(HdrImage, Option<HdrImage>)> {
    render_columns_with_passes(frame, f, columns).map(|(image, own, _)| (image, own))
}

/// [`render_columns`] with its pixels denoised as `what` says, each run
/// of adjacent columns as an image of its own (a strip is a whole column
/// of the frame; denoised side by side, the denoiser would blur across
/// the seams where strips meet). `f` carries the passes the denoise needs.
fn render_columns_denoised(
    frame: &Frame,
    f: &RenderSettings,
    columns: &[(u32, u32)],
    what: Denoise,
) -> anyhow::Result<(HdrImage, Option<HdrImage>)> {
    if !what.is_on() {
        return render_columns(frame, f, columns);
    }
    let (mut image, own, passes) = render_columns_with_passes(frame, f, columns)?;
    let passes = passes.ok_or_else(|| anyhow::anyhow!("a denoised pilot needs its passes"))?;
    let mut x = 0;
    for run in runs(columns) {
        let w = run.1 - run.0;
        let mut part = image.columns(x, w);
        let part_passes = passes.columns(x, w)?;
        sylva_coordinator::executor::denoise(&mut part, Some(&part_passes), what)?;
        image.paste_strip(x, w, &part.pixels);
        x += w;
    }
    Ok((image, own))
}

/// `columns` with each run of adjacent ones joined.
fn runs(columns: &[(u32, u32)]) -> Vec<(u32, u32)> {
    let mut out: Vec<(u32, u32)> = Vec::new();
    for &(x0, x1) in columns {
        match out.last_mut() {
            Some(last) if last.1 == x0 => last.1 = x1,
            _ => out.push((x0, x1)),
        }
    }
    out
}

/// Milliseconds to denoise a `width` × `height` frame as `what` says:
/// the denoiser's time depends on the pixels, not on what they show, so
/// a frame of flat passes is timed, after an untimed first call that
/// loads the library and its weights.
fn denoise_frame_ms(width: u32, height: u32, what: Denoise) -> anyhow::Result<f64> {
    use sylva_scene::passes::{Pass, PassImage};
    let n = (width * height) as usize;
    let mut passes = PassImage::new(width, height, what.passes());
    for (p, plane) in what.passes().extra().zip(&mut passes.planes) {
        let value = match p {
            Pass::Albedo => 0.5,
            Pass::Normal => 0.0,
            _ => 0.1,
        };
        plane.iter_mut().for_each(|v| *v = value);
    }
    if let Some(normal) = passes.plane_mut(Pass::Normal) {
        normal.chunks_exact_mut(3).for_each(|v| v[2] = 1.0);
    }
    let image = HdrImage { width, height, pixels: vec![[0.3; 3]; n] };
    let time = || -> anyhow::Result<f64> {
        let t = Instant::now();
        sylva_coordinator::executor::denoise(&mut image.clone(), Some(&passes), what)?;
        Ok(ms(t))
    };
    time()?;
    time()
}

/// [`render_columns`], and the passes `f` asks for, rendered with the
/// image in the same strips.
pub fn render_columns_with_passes(
    frame: &Frame,
    f: &RenderSettings,
    columns: &[(u32, u32)],
) -> anyhow::Result<(HdrImage, Option<HdrImage>, Option<sylva_scene::passes::PassImage>)> {
    let width: u32 = columns.iter().map(|(x0, x1)| x1 - x0).sum();
    let mut passes = (!f.passes.is_empty())
        .then(|| sylva_scene::passes::PassImage::new(width, f.height, f.passes));
    let blank = || HdrImage {
        width,
        height: f.height,
        pixels: vec![[0.0; 3]; (width * f.height) as usize],
    };
    let (mut image, mut own, mut out) = (blank(), blank(), 0);
    let mut per_sample = false;
    let frame = frame.with_settings(*f);
    for &(x0, x1) in columns {
        let s = frame.strip(x0, x1)?;
        per_sample = !s.first_light.is_empty();
        if let (Some(all), Some(p)) = (passes.as_mut(), &s.passes) {
            all.paste_strip(out, p)?;
        }
        for (k, p) in s.pixels.iter().enumerate() {
            let i = (k as u32 / s.width * width + out + k as u32 % s.width) as usize;
            image.pixels[i] = *p;
            if per_sample {
                own.pixels[i] = s.first_light[k];
            }
        }
        out += x1 - x0;
    }
    Ok((image, per_sample.then_some(own), passes))
}

/// A sampled family's error against rays per pixel, fitted to its two
/// measurements: e(k)² = b² + c/k (b = 0 for the unbiased path tracer).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Curve {
    /// b², the squared bias.
    bias2: f64,
    /// c, the noise variance at one ray.
    c: f64,
    /// The frame's milliseconds at k rays: `fixed_ms + ray_ms · k`.
    fixed_ms: f64,
    /// See `fixed_ms`.
    ray_ms: f64,
}

impl Curve {
    /// Through the measurements `a` and `b` (fewer rays first).
    fn fit(a: &Measured, b: &Measured) -> Curve {
        let (ka, kb) = (a.spp as f64, b.spp as f64);
        let (ea, eb) = (a.error.powi(2), b.error.powi(2));
        let (bias2, c) = if a.lighting == LightingMode::Reference {
            // Unbiased: all of its error is noise, known best from the most rays.
            (0.0, eb * kb)
        } else {
            let c = ((ea - eb) / (1.0 / ka - 1.0 / kb)).max(0.0);
            ((eb - c / kb).max(0.0), c)
        };
        let ray_ms = ((b.frame_ms - a.frame_ms) / (kb - ka)).max(0.0);
        Curve { bias2, c, fixed_ms: (b.frame_ms - ray_ms * kb).max(0.0), ray_ms }
    }

    fn error(&self, k: f64) -> f64 {
        (self.bias2 + self.c / k).sqrt()
    }

    fn frame_ms(&self, k: f64) -> f64 {
        self.fixed_ms + self.ray_ms * k
    }
}

/// Each sampled family's point at the rays `goal` asks for, read off its
/// curve: the fewest rays within the error, or the most within the time.
/// None for a family whose measured points already are that point, or
/// that cannot reach it.
fn along_curves(measured: &[Measured], goal: Goal, job: Job) -> Vec<Measured> {
    let mut out = Vec::new();
    let mut families: Vec<&str> = measured.iter().map(|m| m.family.as_str()).collect();
    families.dedup();
    for family in families {
        let points: Vec<&Measured> = measured.iter().filter(|m| m.family == family).collect();
        let [a, b] = points.as_slice() else { continue };
        if a.denoise.is_on() {
            // A denoised image's error is not bias² + noise / k.
            continue;
        }
        let curve = Curve::fit(a, b);
        let k = match goal {
            Goal::MaxError(e) if e * e > curve.bias2 => curve.c / (e * e - curve.bias2),
            Goal::MaxError(_) => continue,
            Goal::TimeBudget(s) => {
                let frames = job.frames as f64;
                let fixed = job.ms(b.preprocess_ms, b.per_sun_ms, curve.fixed_ms);
                (s * 1e3 - fixed) / (curve.ray_ms * frames).max(1e-9)
            }
        };
        // The path tracer samples in passes of 2 × 2 strata.
        let step = if b.lighting == LightingMode::Reference { 4.0 } else { 1.0 };
        let k = match goal {
            Goal::MaxError(_) => (k / step).ceil() * step,
            Goal::TimeBudget(_) => (k / step).floor() * step,
        }
        .clamp(0.0, MAX_SPP as f64);
        if k < 1.0 || points.iter().any(|p| p.spp as f64 == k) {
            continue;
        }
        out.push(Measured {
            name: format!("{family} {k} rays"),
            spp: k as u32,
            frame_ms: curve.frame_ms(k),
            predicted_ms: job.ms(b.preprocess_ms, b.per_sun_ms, curve.frame_ms(k)),
            error: curve.error(k),
            extrapolated: true,
            ..(*b).clone()
        });
    }
    out
}

/// The candidate `goal` asks for, from the Pareto front of the pilot's
/// candidates (predicted time against error), and why, in a sentence.
fn pick(candidates: &[Measured], goal: Goal, lit: usize) -> (&Measured, String) {
    let by_name = |n: &str| candidates.iter().find(|c| c.name == n).expect("a candidate's point");
    if lit == 0 {
        let local = by_name("local");
        let why = "no pixel of the pilot shows a lit model, so indirect light cannot show: local";
        return (local, why.into());
    }
    let points: Vec<pareto::Point> = candidates
        .iter()
        .map(|c| pareto::Point {
            name: c.name.clone(),
            family: c.family.clone(),
            ms: c.predicted_ms,
            raw: c.error,
            net: None,
        })
        .collect();
    let front = pareto::front(&points);
    let said = |c: &Measured| {
        format!(
            "{} ({:.1} % indirect error on the pilot, {:.2} s predicted{})",
            c.name,
            100.0 * c.error,
            c.predicted_ms / 1e3,
            if c.extrapolated { ", off its curve" } else { "" }
        )
    };
    match goal {
        Goal::TimeBudget(s) => match pareto::best_within(&front, s * 1e3) {
            Some(p) => {
                let c = by_name(&p.name);
                let better = front.iter().find(|q| q.raw < p.raw).map(|q| by_name(&q.name));
                let beyond =
                    better.map_or(String::new(), |b| format!("; {} does not fit", said(b)));
                (c, format!("the most accurate within {s} s: {}{beyond}", said(c)))
            }
            None => {
                let c = by_name(&front[0].name);
                (c, format!("nothing fits {s} s; the fastest: {}", said(c)))
            }
        },
        Goal::MaxError(e) => match front.iter().find(|p| p.raw <= e) {
            Some(p) => {
                let c = by_name(&p.name);
                let faster = front.iter().rev().find(|q| q.ms < p.ms).map(|q| by_name(&q.name));
                let miss =
                    faster.map_or(String::new(), |f| format!("; the faster {} misses", said(f)));
                (c, format!("the fastest within {:.1} % error: {}{miss}", 100.0 * e, said(c)))
            }
            None => {
                let c = by_name(&front[front.len() - 1].name);
                let why = format!(
                    "nothing reaches {:.1} % error; the most accurate: {}",
                    100.0 * e,
                    said(c)
                );
                (c, why)
            }
        },
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(name: &str, ms: f64, error: f64) -> Measured {
        Measured {
            name: name.into(),
            family: name.into(),
            lighting: LightingMode::Lb,
            lb_grid: None,
            spp: 1,
            gather_bounces: 1,
            gather_filter: 3,
            denoise: Denoise::Off,
            preprocess_ms: 0.0,
            per_sun_ms: 0.0,
            frame_ms: ms,
            predicted_ms: ms,
            error,
            extrapolated: false,
        }
    }

    /// A sampled family's point: `k` rays, 500 ms of pre-process.
    fn sampled(
        family: &str,
        lighting: LightingMode,
        k: u32,
        frame_ms: f64,
        error: f64,
    ) -> Measured {
        Measured {
            name: format!("{family} {k} rays"),
            family: family.into(),
            lighting,
            spp: k,
            preprocess_ms: 500.0,
            per_sun_ms: 300.0,
            frame_ms,
            predicted_ms: 500.0 + frame_ms,
            ..c("", 0.0, error)
        }
    }

    #[test]
    fn a_jobs_suns_are_its_distinct_suns() {
        use sylva_scene::sequence::View;
        let sun = |d: [f32; 3]| View { camera: None, sun_towards: Some(d) };
        assert_eq!(Job::of(&[]), Job::FRAME);
        let path = vec![View::default(); 5];
        assert_eq!(Job::of(&path), Job { frames: 5, suns: 1 });
        let sweep = [sun([0.0, 1.0, 0.0]), sun([0.6, 0.8, 0.0]), sun([0.0, 1.0, 0.0])];
        assert_eq!(Job::of(&sweep), Job { frames: 3, suns: 2 });
        assert_eq!(Job { frames: 3, suns: 2 }.ms(500.0, 300.0, 100.0), 1100.0);
    }

    #[test]
    fn adjacent_columns_are_denoised_as_one_image() {
        assert_eq!(runs(&[(0, 4), (4, 8), (10, 12), (12, 13)]), [(0, 8), (10, 13)]);
        assert_eq!(runs(&[(3, 9)]), [(3, 9)]);
    }

    #[test]
    fn the_pilot_takes_whole_columns_where_the_models_are() {
        assert_eq!(pilot_columns(64, 32, &[1.0; 64]), [(0, 64)]);
        // Nothing shows: strips at equal steps across the frame.
        let c = pilot_columns(896, 448, &[0.0; 896]);
        assert_eq!(c.len(), PILOT_STRIPS as usize);
        assert!(c.iter().map(|(a, b)| (b - a) * 448).sum::<u32>() <= PILOT_PIXELS);
        assert!(c.windows(2).all(|w| w[0].1 <= w[1].0) && c[3].1 <= 896);
        assert!(c[0].0 < 896 / 4 && c[3].1 > 3 * 896 / 4, "{c:?}");
        // A model over columns 400..600: every strip on it, side by side.
        let mut cov = vec![0.0; 896];
        cov[400..600].iter_mut().for_each(|c| *c = 100.0);
        let c = pilot_columns(896, 448, &cov);
        assert_eq!(c.len(), PILOT_STRIPS as usize);
        assert!(c.iter().all(|&(a, b)| a >= 390 && b <= 610), "{c:?}");
        assert!(c.windows(2).all(|w| w[0].1 <= w[1].0), "{c:?}");
        // Narrower than the strips: still no strip overlaps another.
        let mut cov = vec![0.0; 896];
        cov[500] = 1.0;
        let c = pilot_columns(896, 448, &cov);
        assert!(c.windows(2).all(|w| w[0].1 <= w[1].0) && !c.is_empty(), "{c:?}");
    }

    #[test]
    fn a_budget_takes_the_most_accurate_that_fits_and_an_error_the_fastest_that_meets_it() {
        let all = [
            c("local", 100.0, 1.0),
            c("lb", 1_000.0, 0.4),
            c("gather", 5_000.0, 0.12),
            c("slow and worse", 9_000.0, 0.5),
            c("gather more", 20_000.0, 0.06),
        ];
        let pick = |g| pick(&all, g, 10).0.name.clone();
        assert_eq!(pick(Goal::TimeBudget(6.0)), "gather");
        assert_eq!(pick(Goal::TimeBudget(60.0)), "gather more");
        assert_eq!(pick(Goal::TimeBudget(0.01)), "local", "nothing fits: the fastest");
        assert_eq!(pick(Goal::MaxError(0.2)), "gather");
        assert_eq!(pick(Goal::MaxError(0.05)), "gather more", "nothing meets it: the best");
        assert_eq!(pick(Goal::MaxError(0.5)), "lb");
        let why = super::pick(&all, Goal::TimeBudget(6.0), 10).1;
        assert!(why.contains("gather more") && why.contains("does not fit"), "{why}");
        assert_eq!(super::pick(&all, Goal::MaxError(0.2), 0).0.name, "local", "nothing lit");
    }

    #[test]
    fn a_sampled_family_is_bias_and_noise_falling_as_one_over_rays() {
        // Gather: b = 0.1, c = 0.16 (e(4)² = 0.05, e(16)² = 0.02); 100 ms + 10 ms a ray.
        let g4 = sampled("gather 1b", LightingMode::Gather, 4, 140.0, 0.05f64.sqrt());
        let g16 = sampled("gather 1b", LightingMode::Gather, 16, 260.0, 0.02f64.sqrt());
        let curve = Curve::fit(&g4, &g16);
        assert!((curve.bias2 - 0.01).abs() < 1e-12 && (curve.c - 0.16).abs() < 1e-12);
        // Within 12 %: k = 0.16 / (0.0144 − 0.01) = 36.4 → 37 rays.
        let more = along_curves(&[g4.clone(), g16.clone()], Goal::MaxError(0.12), Job::FRAME);
        assert_eq!(more.len(), 1);
        assert_eq!((more[0].spp, more[0].name.as_str()), (37, "gather 1b 37 rays"));
        assert!(more[0].error <= 0.12 && more[0].extrapolated);
        assert!((more[0].predicted_ms - (500.0 + 100.0 + 10.0 * 37.0)).abs() < 1e-6);
        // Under its bias nothing helps; a budget of 1.5 s buys (1500 − 500 − 100) / 10 = 90 rays.
        assert!(
            along_curves(&[g4.clone(), g16.clone()], Goal::MaxError(0.09), Job::FRAME).is_empty()
        );
        assert_eq!(
            along_curves(&[g4.clone(), g16.clone()], Goal::TimeBudget(1.5), Job::FRAME)[0].spp,
            90
        );
        // A job of 10 frames under 2 suns: 500 + 300 ms of light, then
        // 10 frames of 100 ms + 10 ms a ray within 10 s: (10000 − 800 − 1000) / 100 = 82 rays.
        let job = Job { frames: 10, suns: 2 };
        let k = along_curves(&[g4.clone(), g16.clone()], Goal::TimeBudget(10.0), job);
        assert_eq!(k[0].spp, 82);
        assert!((k[0].predicted_ms - (800.0 + 10.0 * (100.0 + 10.0 * 82.0))).abs() < 1e-6);
        // The path tracer: unbiased, whole passes of 4.
        let p4 = sampled("path tracer", LightingMode::Reference, 4, 4.0, 0.8);
        let p16 = sampled("path tracer", LightingMode::Reference, 16, 16.0, 0.4);
        assert_eq!(Curve::fit(&p4, &p16).bias2, 0.0);
        let pt = along_curves(&[p4, p16], Goal::MaxError(0.1), Job::FRAME);
        assert_eq!(pt[0].spp, 256);
        assert!((pt[0].error - 0.1).abs() < 1e-9);
        // Denoised, it is not on that curve: only its measured points count.
        let denoised = |k, e| Measured {
            denoise: Denoise::Indirect,
            ..sampled("path tracer + denoised indirect", LightingMode::Reference, k, 9.0, e)
        };
        assert!(
            along_curves(&[denoised(4, 0.3), denoised(16, 0.2)], Goal::MaxError(0.1), Job::FRAME)
                .is_empty()
        );
    }
}
