//! `sylva render`, and the frame every rendering command takes. Flags only (clap), and their
//! conversion to settings.

use anyhow::{Context, bail};
use clap::Args;
use std::path::PathBuf;
use sylva_coordinator::schedule::ScheduleKind;
use sylva_scene::LightingMode;
use sylva_scene::format::SceneFile;
use sylva_scene::frame::FrameSettings;
use sylva_scene::sequence::{SequenceSpec, SunAngles, SunSweep, View};

/// What a frame asks for, as `render` and `submit` take it.
#[derive(Debug, Args)]
pub struct FrameArgs {
    /// Image width.
    #[arg(long, default_value_t = 896)]
    pub width: u32,
    /// Image height.
    #[arg(long, default_value_t = 448)]
    pub height: u32,
    /// Rays per pixel.
    #[arg(long, default_value_t = 1)]
    pub spp: u32,
    /// How rays traverse the scene: ray queries (`rq`, the device's own
    /// structures, traced in hardware where it has them), Sylva's BVH,
    /// compressed wide BVH or kd-tree walked by a compute kernel, or
    /// `auto`: each worker measures the BVH, the compressed wide BVH and
    /// (where its adapter has them) ray queries, and says what it chose.
    #[arg(long, value_enum, default_value = "auto")]
    pub accel: sylva_scene::frame::Backend,
    /// Lighting method; default the scene's. `auto` (`render` in this
    /// process only) picks one with its parameters from a short pilot on
    /// the scene, for --time-budget or --max-error.
    #[arg(long, value_enum)]
    pub lighting: Option<LightingChoice>,
    /// Seed of the per-pixel sample positions.
    #[arg(long, default_value_t = 1)]
    pub seed: u32,
    /// The paper LB model's weight of LB light relative to the sun's
    /// (scenes with `"lb_model": "paper"` only; the default grounded model
    /// derives the LB light's scale and ignores this).
    #[arg(long, default_value_t = 0.35)]
    pub lb_strength: f32,
    /// The gather methods: bounces traced through the geometry before the
    /// far end reads the lattice (1 or 2; each ray per pixel is one gather ray).
    #[arg(long, default_value_t = sylva_scene::frame::DEFAULT_GATHER_BOUNCES)]
    pub gather_bounces: u32,
    /// The gather methods: radius in pixels of the filter over their
    /// indirect light, within one crown (0: none).
    #[arg(long, default_value_t = sylva_scene::frame::DEFAULT_GATHER_FILTER)]
    pub gather_filter: u32,
    /// Render passes written beside the image as one multi-layer OpenEXR:
    /// beauty, direct, indirect, albedo, normal, depth, instance,
    /// species, sky, separated by commas, or `all` (docs/passes.md).
    #[arg(long, value_parser = sylva_scene::passes::PassSet::parse, default_value = "beauty")]
    pub passes: sylva_scene::passes::PassSet,
    /// Denoise the frame with Open Image Denoise, guided by the albedo and
    /// normal passes (rendered for it): `--denoise` or `--denoise=frame`
    /// the whole frame, as Cycles does; `--denoise=indirect` its indirect
    /// light alone, the sun's direct light as traced. The EXR keeps the
    /// noisy image as its "Noisy Image" layer (docs/denoising.md).
    #[arg(
        long,
        value_name = "WHAT",
        num_args = 0..=1,
        require_equals = true,
        default_missing_value = "frame",
        default_value = "off",
        value_parser = sylva_scene::frame::Denoise::parse
    )]
    pub denoise: sylva_scene::frame::Denoise,
    /// Render a sequence of this many frames (with --sun-from/--sun-to, a
    /// --camera-path, or the scene's own `sequence`).
    #[arg(long)]
    pub frames: Option<u32>,
    /// A sun sweep's first position: ELEVATION,AZIMUTH in degrees.
    #[arg(long, value_parser = sun_angles, requires = "sun_to")]
    pub sun_from: Option<SunAngles>,
    /// A sun sweep's last position: ELEVATION,AZIMUTH in degrees.
    #[arg(long, value_parser = sun_angles, requires = "sun_from")]
    pub sun_to: Option<SunAngles>,
    /// Camera keyframes: a JSON file holding an array of
    /// `{"frame", "position", "look_at", "up", "fov_y_deg"}`.
    #[arg(long)]
    pub camera_path: Option<PathBuf>,
}

/// `--lighting`: a method, or `auto`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LightingChoice {
    /// Picked by a pilot on the scene (`render --lighting auto`).
    Auto,
    /// This method.
    Method(LightingMode),
}

impl clap::ValueEnum for LightingChoice {
    fn value_variants<'a>() -> &'a [Self] {
        // `auto`, then every method in `LightingMode::ALL`'s order.
        static ALL: std::sync::LazyLock<Vec<LightingChoice>> = std::sync::LazyLock::new(|| {
            std::iter::once(LightingChoice::Auto)
                .chain(LightingMode::ALL.map(LightingChoice::Method))
                .collect()
        });
        &ALL
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        match self {
            LightingChoice::Auto => Some(
                clap::builder::PossibleValue::new("auto")
                    .help("The method and its parameters a pilot on the scene picks (render only)"),
            ),
            LightingChoice::Method(m) => m.to_possible_value(),
        }
    }
}

/// `ELEVATION,AZIMUTH` in degrees.
pub(crate) fn sun_angles(s: &str) -> Result<SunAngles, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>().map_err(|e| format!("{x:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [e, a] => Ok(SunAngles { elevation_deg: *e, azimuth_deg: *a }),
        _ => Err(format!("{s:?}: ELEVATION,AZIMUTH in degrees")),
    }
}

impl FrameArgs {
    /// The frame these flags ask for (checked by its user).
    pub fn settings(&self) -> FrameSettings {
        FrameSettings {
            width: self.width,
            height: self.height,
            spp: self.spp,
            seed: self.seed,
            lighting: match self.lighting {
                Some(LightingChoice::Method(m)) => Some(m),
                _ => None,
            },
            accel: self.accel,
            lb_strength: self.lb_strength,
            ambient: None,
            view: Default::default(),
            gather_bounces: self.gather_bounces,
            gather_filter: self.gather_filter,
            passes: self.passes.with(self.denoise.passes()),
            denoise: self.denoise,
        }
    }

    /// Whether `--lighting auto` was asked for.
    pub fn auto(&self) -> bool {
        self.lighting == Some(LightingChoice::Auto)
    }

    /// The views of the sequence these flags (over the scene's own
    /// `sequence`) ask for, one per frame; empty for a single frame.
    pub fn views(&self, scene: &SceneFile) -> anyhow::Result<Vec<View>> {
        let flags = self.frames.is_some() || self.sun_from.is_some() || self.camera_path.is_some();
        let mut seq = match (&scene.sequence, flags) {
            (None, false) => return Ok(Vec::new()),
            (Some(s), _) => s.clone(),
            (None, true) => SequenceSpec { frames: 0, sun: None, camera: Vec::new() },
        };
        if let Some(n) = self.frames {
            seq.frames = n;
        }
        if let (Some(from), Some(to)) = (self.sun_from, self.sun_to) {
            seq.sun = Some(SunSweep { from, to });
        }
        if let Some(p) = &self.camera_path {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("{}: cannot read", p.display()))?;
            seq.camera = serde_json::from_str(&text).with_context(|| {
                format!("{}: not a JSON array of camera keyframes", p.display())
            })?;
        }
        if seq.frames == 0 {
            bail!("a sequence needs --frames N (or the scene's sequence.frames)");
        }
        seq.views().map_err(anyhow::Error::msg)
    }
}

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Scene file (JSON); see `sylva scene forest` and docs/scene-format.md.
    pub scene: PathBuf,
    /// Output PNG; stats go beside it as NAME.stats.json. NAME.exr asks for
    /// the OpenEXR (as --exr does), written beside the PNG.
    #[arg(short, long, default_value = "sylva-out/render.png")]
    pub out: PathBuf,
    #[command(flatten)]
    pub frame: FrameArgs,
    /// The prepared-data cache of this process (`--local-workers 0`) and
    /// of the local workers it starts.
    #[command(flatten)]
    pub prepared_cache: crate::flags::caps::PreparedCacheArgs,
    /// `--lighting reference` in this process: stop once the image's own
    /// relative standard error is below this (each batch has --spp samples, at least 16).
    #[arg(long, default_value_t = 0.02)]
    pub target_error: f64,
    /// `--lighting reference` in this process: stop after this many seconds.
    #[arg(long, default_value_t = 600.0)]
    pub max_seconds: f64,
    /// LB grid of every model: a size, or `auto` (the smallest of 16, 32, 64,
    /// 128 whose light differs from the next finer grid's by less than
    /// --lb-auto-tolerance; the stats say what it chose and why). In this
    /// process only (--local-workers 0).
    #[arg(long)]
    pub lb_grid: Option<String>,
    /// `--lb-grid auto`: the largest relative difference accepted.
    #[arg(long, default_value_t = 0.2)]
    pub lb_auto_tolerance: f64,
    /// `--lighting auto`: the most accurate method whose lighting
    /// pre-process and frame are predicted to fit this many seconds.
    #[arg(long, conflicts_with = "max_error")]
    pub time_budget: Option<f64>,
    /// `--lighting auto`: the fastest method whose indirect error (RMS,
    /// relative to the indirect light's) is predicted at most this (0.1: 10 %).
    #[arg(long)]
    pub max_error: Option<f64>,
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
    pub schedule: ScheduleKind,
    /// Seconds a worker may take over one strip before it is handed to another.
    #[arg(long, default_value_t = 600)]
    pub strip_deadline_s: u64,
    /// The token the `--workers` require; local workers get a fresh random one.
    #[command(flatten)]
    pub auth: crate::flags::security::TokenArgs,
    /// How to reach the `--workers` over TLS.
    #[command(flatten)]
    pub tls: crate::flags::security::ConnectTlsArgs,
    /// Let the scene read model files outside its own folder (in this
    /// process only: a bundle for workers always holds just the scene
    /// folder's files).
    #[arg(long)]
    pub allow_files_outside_scene: bool,
}

impl RenderArgs {
    /// `--lighting auto`'s goal (checked), `None` without auto; its flags
    /// without auto are refused.
    pub fn goal(&self) -> anyhow::Result<Option<crate::pilot::Goal>> {
        use crate::pilot::Goal;
        let positive = |name: &str, v: f64| -> anyhow::Result<f64> {
            anyhow::ensure!(v.is_finite() && v > 0.0, "{name} {v}: must be a finite number > 0");
            Ok(v)
        };
        match (self.frame.auto(), self.time_budget, self.max_error) {
            (false, None, None) => Ok(None),
            (false, _, _) => bail!("--time-budget and --max-error go with --lighting auto"),
            (true, Some(s), None) => Ok(Some(Goal::TimeBudget(positive("--time-budget", s)?))),
            (true, None, Some(e)) => Ok(Some(Goal::MaxError(positive("--max-error", e)?))),
            (true, None, None) => {
                bail!("--lighting auto needs a goal: --time-budget SECONDS or --max-error E")
            }
            (true, Some(_), Some(_)) => bail!("--time-budget and --max-error: one or the other"),
        }
    }
}

/// `-o NAME.exr` as a user means it: the EXR, with the PNG and the stats
/// beside it as for any other name. Resolved once, before anything reads
/// `out` or `exr`.
pub fn exr_named(out: &mut PathBuf, exr: &mut bool) {
    if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) {
        *exr = true;
        out.set_extension("png");
    }
}
