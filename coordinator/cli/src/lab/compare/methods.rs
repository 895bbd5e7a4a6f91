//! The methods `compare` renders (every lighting method and its variants
//! on the scene), each prepared once per group and rendered twice with
//! different seeds, its image written with the reference's exposure.

use super::*;
use sylva_coordinator::executor::denoise;
use sylva_scene::frame::Denoise;

/// One method `compare` renders: a lighting method on a variant of the
/// scene, with its own rays per pixel and gather depth where it differs.
pub(super) struct Candidate {
    pub(super) name: String,
    pub(super) lighting: LightingMode,
    pub(super) scene: Scene,
    /// Candidates of one group have the same scene, so methods with the
    /// same needs share its preparation.
    pub(super) group: usize,
    /// Rays per pixel; `None`: `--spp`.
    pub(super) spp: Option<u32>,
    pub(super) gather_bounces: u32,
    pub(super) gather_filter: u32,
    /// The curve it belongs to on the time–error chart (its variants
    /// differ by rays, grid or filter).
    pub(super) family: String,
    /// Denoised (Open Image Denoise, guided by albedo and normal, their
    /// pass and the denoise timed with the frame), and what of it, as
    /// `--denoise` does it.
    pub(super) denoise: Denoise,
}

impl Candidate {
    pub(super) fn new(name: &str, lighting: LightingMode, scene: Scene, group: usize) -> Self {
        Candidate {
            name: name.into(),
            lighting,
            scene,
            group,
            spp: None,
            gather_bounces: sylva_scene::frame::DEFAULT_GATHER_BOUNCES,
            gather_filter: 0,
            family: name.into(),
            denoise: Denoise::Off,
        }
    }
}

/// The methods `compare` renders: local, ambient, the LB at each grid
/// size, with the forest grid, the papers' model as written, Boulanger et
/// al., and the final gathers over the scene's own LB (at each count of
/// gather rays, one and two bounces deep, and reading the matched constant
/// at their far end instead); `lb auto` and the reference come apart.
pub(super) fn methods_to_compare(
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
        // The unfiltered gather denoised instead: where the denoiser pays
        // for its guides and its own time (issue 40).
        if bounces == 2 {
            let gather = (LightingMode::Gather, bounces);
            methods.extend(denoised(scene, "gather 2b", gather, gather_rays, "rays"));
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
    // The path tracer denoised at the gathers' ray counts: the field's
    // answer to its noise (Cycles with Open Image Denoise).
    let path = (LightingMode::Reference, sylva_scene::frame::DEFAULT_GATHER_BOUNCES);
    methods.extend(denoised(scene, "path tracer", path, gather_rays, "spp"));
    methods
}

/// `lighting` (a sampled method with its gather depth, `base` its
/// family's name) at each of `rays` per pixel, denoised whole and in its
/// indirect light alone; none where Open Image Denoise is not installed.
fn denoised(
    scene: &Scene,
    base: &str,
    (lighting, bounces): (LightingMode, u32),
    rays: &[u32],
    unit: &str,
) -> Vec<Candidate> {
    if sylva_denoise::available().is_err() {
        return Vec::new();
    }
    let mut methods = Vec::new();
    for (what, words) in [(Denoise::Frame, "denoise"), (Denoise::Indirect, "denoised indirect")] {
        let family = format!("{base} + {words}");
        for &k in rays {
            methods.push(Candidate {
                spp: Some(k),
                gather_bounces: bounces,
                family: family.clone(),
                denoise: what,
                ..Candidate::new(&format!("{family} {k} {unit}"), lighting, scene.clone(), 0)
            });
        }
    }
    methods
}

/// One preparation of a scene for a method, and the time its lighting's
/// own pre-process took (voxelize, LB, forest LB, clouds, Boulanger).
pub(super) struct Preparation {
    pub(super) prepared: Arc<PreparedScene>,
    pub(super) preprocess_ms: f64,
}

impl Preparation {
    pub(super) fn new(
        ctx: &Tracer,
        scene: &Scene,
        lighting: LightingMode,
        say: &dyn Fn(&str),
    ) -> anyhow::Result<Self> {
        let prepared = prepared(ctx, scene, lighting, say)?;
        let preprocess_ms = prepared.lighting_ms();
        Ok(Self { prepared, preprocess_ms })
    }
}

/// `scene` prepared in this process for `lighting` on the BVH, through
/// the frame layer's own preparer.
pub(super) fn prepared(
    tracer: &Tracer,
    scene: &Scene,
    lighting: LightingMode,
    say: &dyn Fn(&str),
) -> anyhow::Result<Arc<PreparedScene>> {
    Fresh::default().prepared(tracer, scene, AccelKind::Bvh.into(), lighting, &View::default(), say)
}

/// Where `compare` writes a method's image, and with which exposure.
pub(super) struct Output<'a> {
    pub(super) dir: &'a Path,
    pub(super) exposure: &'a ToneMapStats,
    /// Also write the linear image as `.npy`.
    pub(super) hdr: bool,
}

/// The scene with every model's LB grid set to `grid` and the forest grid's use set.
pub(super) fn with_lb(scene: &Scene, grid: Option<usize>, forest: Option<ForestGridUse>) -> Scene {
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

/// Renders one method on its preparation (the frame `base` asks for,
/// with `f`'s rays and gather settings), writes its image with the
/// reference's exposure.
pub(super) fn render_method(
    ctx: &Tracer,
    c: &Candidate,
    p: &Preparation,
    base: &FrameSettings,
    f: &RenderSettings,
    out: &Output,
    say: &dyn Fn(&str),
) -> anyhow::Result<Rendered> {
    let (name, lighting, scene) = (c.name.as_str(), c.lighting, &c.scene);
    // The frame layer composes it (and matches the ambient where the
    // method reads it) over the shared preparation.
    let request = FrameSettings {
        lighting: Some(lighting),
        accel: AccelKind::Bvh.into(),
        spp: f.spp,
        gather_bounces: f.gather_bounces,
        gather_filter: f.gather_filter,
        // A denoised method renders what its denoise needs with its image.
        passes: if c.denoise.is_on() { c.denoise.passes() } else { base.passes },
        ..*base
    };
    let frame = Frame::compose(ctx, scene, &request, &mut Given(p.prepared.clone()), say)?;
    let pre = p.preprocess_ms
        + frame.timings.iter().filter(|(n, _)| *n == "ambient match").map(|(_, t)| t).sum::<f64>();
    let (settings, prepared) = (frame.settings, &frame.prepared);
    say(&format!("{name}: rendering"));
    // One untimed strip first: the pipeline's first dispatch compiles it.
    frame.with_settings(RenderSettings { width: 8, height: 8, spp: 1, ..settings }).strip(0, 8)?;
    if c.denoise.is_on() {
        // The denoiser's library loaded, untimed too.
        sylva_denoise::available()?;
    }
    let t = Instant::now();
    let (mut image, own_local, passes) = render_whole(&frame)?;
    denoise(&mut image, passes.as_ref(), c.denoise)?;
    let frame_ms = ms(t);
    // The same frame with other seeds (untimed): with `local`'s second
    // render (or its own, below), the spread of the two tells the method's
    // own sampling noise.
    let other =
        frame.with_settings(RenderSettings { seed: settings.seed ^ SECOND_SEED, ..settings });
    let (mut again, own_local_again, passes) = render_whole(&other)?;
    denoise(&mut again, passes.as_ref(), c.denoise)?;
    let file = out.dir.join(format!("{}.png", file_stem(name)));
    write_png(&file, f.width, f.height, &reinhard_like(&image, out.exposure))?;
    if out.hdr {
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
        "gather_filter": if settings.gather_filtered() { json!(settings.gather_filter) } else { serde_json::Value::Null },
        "gather_bounces": if sylva_worker::lighting::method(lighting).kernel == sylva_worker::lighting::Kernel::Reference { json!(settings.gather_bounces) } else { serde_json::Value::Null },
        "warnings": prepared.light.iter().flat_map(|l| l.warnings.iter().map(move |w| format!("{}: {w}", l.model))).collect::<Vec<_>>(),
        "denoised": if c.denoise.is_on() { json!(c.denoise.name()) } else { serde_json::Value::Null },
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
            image: file.display().to_string(),
            notes,
            // The errors are measured once every method is rendered.
            ..empty_report()
        },
        image,
        again,
        own_local: own_local.zip(own_local_again),
    })
}

/// The whole frame as one strip: the image and, from the per-sample
/// kernels (the gathers), what `local` shows along the same camera samples.
pub(super) fn render_whole(
    frame: &Frame,
) -> anyhow::Result<(HdrImage, Option<HdrImage>, Option<sylva_scene::passes::PassImage>)> {
    crate::pilot::render_columns_with_passes(frame, &frame.settings, &[(0, frame.settings.width)])
}

/// A method's name as a file name: `lb 32³ + forest grid` → `lb-32-forest-grid`.
pub(super) fn file_stem(name: &str) -> String {
    name.replace(['³', '+'], "").split_whitespace().collect::<Vec<_>>().join("-")
}

/// Writes a linear image as float32 `.npy`, height × width × 3.
pub(super) fn write_hdr(path: &Path, img: &HdrImage) -> anyhow::Result<()> {
    let flat: Vec<f32> = img.pixels.iter().flatten().copied().collect();
    Ok(sylva_light::npy::write_f32(path, &[img.height as u64, img.width as u64, 3], &flat)?)
}

/// The seed bits that give a method's second render other samples.
pub(super) const SECOND_SEED: u32 = 0x5EED_0002;
