//! One frame on this GPU: the worker's composition function, which every
//! caller uses (the gRPC `RenderStrip`, `sylva render`, `--lighting
//! auto`'s pilot, `compare`, `bench`). In order, as pbrt-v4's `CPURender`
//! composes its parts:
//!
//! 1. the frame's settings resolved once ([`RenderSettings::resolve`]);
//! 2. the scene prepared for its lighting through a [`Preparer`], the
//!    seam to whatever keeps preparations (the worker's memory and disk
//!    caches, or [`Fresh`]: this process's one preparation);
//! 3. the `ambient` methods' constant matched to the LB light
//!    ([`ambient`]), once per frame shape where the preparer keeps it;
//!
//! and then what the frame is: strips of columns ([`Frame::strip`],
//! [`Frame::strips`]), passes included, or the reference converged
//! ([`Frame::reference`], [`reference`](mod@reference)). A [`Frame`] says what it cost
//! ([`Frame::timings`]) and what was chosen (its prepared scene's
//! backend, LB grids and envelopes).
//!
//! The lighting methods declare and prepare (`crate::lighting`); the
//! tracer draws (`crate::trace`); this layer drives both. Its one
//! circular dependency is the ambient match, a frame rendered to set up
//! a frame: it uses the same strip renderer, at a quarter of the size.

pub mod ambient;
pub mod reference;

use crate::prepare::{DiskSource, PreparedScene, Reuse, prepare_reusing};
use crate::trace::{RenderSettings, RenderedStrip, Tracer};
use reference::{ReferenceImage, ReferenceOptions, ReferenceStats};
use std::sync::Arc;
use std::time::Instant;
use sylva_scene::film::RayCounts;
use sylva_scene::frame::{Backend, FrameSettings};
use sylva_scene::passes::PassImage;
use sylva_scene::sequence::View;
use sylva_scene::{LightingMode, Scene};

/// Where a frame's prepared scene comes from, and where matched ambient
/// constants are kept: the seam between the frame layer and the caches.
pub trait Preparer {
    /// `scene`, seen under `view`'s sun, prepared for `lighting` with the
    /// `accel` backend; `progress` hears each step.
    fn prepared(
        &mut self,
        tracer: &Tracer,
        scene: &Scene,
        accel: Backend,
        lighting: LightingMode,
        view: &View,
        progress: &dyn Fn(&str),
    ) -> anyhow::Result<Arc<PreparedScene>>;

    /// The ambient constant matched before for a frame of this shape, if
    /// kept (by default nothing is).
    fn matched_ambient(&mut self, _key: &AmbientKey) -> Option<[f32; 3]> {
        None
    }

    /// Keeps an ambient constant just matched (by default, forgotten).
    fn keep_ambient(&mut self, _key: AmbientKey, _ambient: [f32; 3]) {}
}

/// What a matched ambient constant depends on besides the scene: the
/// frame's shape, seed, LB weight, backend and view.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct AmbientKey(String);

impl AmbientKey {
    fn of(accel: Backend, s: &RenderSettings) -> Self {
        Self(format!(
            "{accel:?}/{}x{}/{}/{}/{:?}",
            s.width, s.height, s.seed, s.lb_strength, s.view
        ))
    }
}

/// This process's preparation: prepared once, reading what the disk cache
/// holds of the scene where one is given ([`Fresh::with_disk`]), and
/// leaving in [`Fresh::reuse`] what a next preparation of the same scene
/// (another LB grid, another lighting, another view) can take. The LB
/// light, the models' and the clouds', is kept per sun, so a sequence's
/// frames under a sun seen before solve nothing, and a new sun never
/// takes another's light.
#[derive(Default)]
pub struct Fresh {
    /// What was built, solved and chosen, for the next preparation and
    /// for the disk cache ([`Reuse::keeper`]).
    pub reuse: Reuse,
    /// The LB light solved here, the models' and the clouds', by the sun
    /// it was solved under (`None`: the scene's own).
    suns: std::collections::HashMap<Option<[u32; 3]>, SunLight>,
    /// The sun `reuse.lb` and `reuse.clouds` were solved under.
    sun: Option<[u32; 3]>,
}

/// The LB light of one sun: the models' and the clouds'.
#[derive(Clone, Default)]
struct SunLight {
    lb: Option<Arc<crate::lighting::lb::SceneLb>>,
    clouds: Option<Arc<Vec<crate::lighting::clouds::CloudGrid>>>,
}

impl Fresh {
    /// A preparation that reads the prepared-data cache first.
    pub fn with_disk(disk: DiskSource) -> Self {
        Self { reuse: Reuse { disk: Some(disk), ..Default::default() }, ..Default::default() }
    }

    /// A preparation that goes on from what another made of the same
    /// scene (`reuse`: its structures, voxels and light), whose light, if
    /// any, is of the sun with key `sun` ([`View::sun_key`]).
    pub fn with_reuse(reuse: Reuse, sun: Option<[u32; 3]>) -> Self {
        Self { reuse, sun, ..Default::default() }
    }

    /// What this preparer made, to hand to another ([`Fresh::with_reuse`]).
    pub fn into_reuse(self) -> Reuse {
        self.reuse
    }
}

impl Preparer for Fresh {
    fn prepared(
        &mut self,
        tracer: &Tracer,
        scene: &Scene,
        accel: Backend,
        lighting: LightingMode,
        view: &View,
        progress: &dyn Fn(&str),
    ) -> anyhow::Result<Arc<PreparedScene>> {
        let viewed;
        let scene = if view.sun().is_some() {
            viewed = scene.with_view(view);
            &viewed
        } else {
            scene
        };
        // The light kept for this view's sun, and the disk's entry for it.
        let sun = view.sun_key();
        if sun != self.sun {
            let (lb, clouds) = (self.reuse.lb.take(), self.reuse.clouds.take());
            if lb.is_some() || clouds.is_some() {
                self.suns.insert(self.sun, SunLight { lb, clouds });
            }
            let kept = self.suns.get(&sun).cloned().unwrap_or_default();
            (self.reuse.lb, self.reuse.clouds) = (kept.lb, kept.clouds);
            self.sun = sun;
        }
        if let Some(d) = &mut self.reuse.disk {
            d.sun = sun;
        }
        let p =
            Arc::new(prepare_reusing(tracer, scene, accel, lighting, &mut self.reuse, progress)?);
        self.reuse.previous = Some(p.clone());
        self.reuse.found.logged();
        Ok(p)
    }
}

/// A preparer that hands out one scene prepared before (the pilot's
/// choice, a study's shared preparation).
pub struct Given(pub Arc<PreparedScene>);

impl Preparer for Given {
    fn prepared(
        &mut self,
        _: &Tracer,
        _: &Scene,
        _: Backend,
        _: LightingMode,
        _: &View,
        _: &dyn Fn(&str),
    ) -> anyhow::Result<Arc<PreparedScene>> {
        Ok(self.0.clone())
    }
}

/// A frame ready to trace on one GPU: its scene prepared, its settings
/// resolved, its ambient matched.
pub struct Frame {
    tracer: Tracer,
    /// The prepared scene (shared with the cache that keeps it).
    pub prepared: Arc<PreparedScene>,
    /// What the frame is rendered with.
    pub settings: RenderSettings,
    /// Milliseconds of each composition step (`prepare`, `ambient match`).
    pub timings: Vec<(&'static str, f64)>,
}

impl Frame {
    /// Composes the frame `request` asks of `scene`: settings resolved,
    /// the scene prepared through `preparer`, the ambient matched (unless
    /// the request gives it).
    pub fn compose(
        tracer: &Tracer,
        scene: &Scene,
        request: &FrameSettings,
        preparer: &mut dyn Preparer,
        progress: &dyn Fn(&str),
    ) -> anyhow::Result<Self> {
        let settings = RenderSettings::resolve(request, scene.lighting);
        let t = Instant::now();
        let prepared = preparer.prepared(
            tracer,
            scene,
            request.accel,
            settings.lighting,
            &request.view,
            progress,
        )?;
        let mut frame = Self::of(tracer, prepared, settings);
        frame.timings.push(("prepare", ms(t)));
        if settings.lighting.reads_matched_ambient() && request.ambient.is_none() {
            let key = AmbientKey::of(request.accel, &settings);
            frame.settings.ambient = match preparer.matched_ambient(&key) {
                Some(a) => a,
                None => {
                    progress("matching the ambient constant to the LB image");
                    let t = Instant::now();
                    let a = ambient::matched(&frame.prepared.renderer, tracer, &settings)?;
                    frame.timings.push(("ambient match", ms(t)));
                    preparer.keep_ambient(key, a);
                    a
                }
            };
        }
        Ok(frame)
    }

    /// A frame over a scene prepared before, rendered with `settings` as
    /// they are (no ambient matched): a study's variant of a frame.
    pub fn of(tracer: &Tracer, prepared: Arc<PreparedScene>, settings: RenderSettings) -> Self {
        Self { tracer: tracer.clone(), prepared, settings, timings: Vec::new() }
    }

    /// This frame with other settings over the same preparation.
    pub fn with_settings(&self, settings: RenderSettings) -> Self {
        Self::of(&self.tracer, self.prepared.clone(), settings)
    }

    /// Columns `[x0, x1)`, with the passes the frame asks for.
    pub fn strip(&self, x0: u32, x1: u32) -> anyhow::Result<RenderedStrip> {
        self.prepared.renderer.render_strip(&self.tracer, &self.settings, x0, x1)
    }

    /// What the lighting found about this frame's scene that a user
    /// should hear (an LB medium too thin to pay, a grazing sun), as
    /// `model: LB: finding` (as the log says it), once each.
    pub fn warnings(&self) -> Vec<String> {
        self.prepared
            .light
            .iter()
            .flat_map(|l| l.warnings.iter().map(move |w| format!("{}: LB: {w}", l.model)))
            .collect()
    }

    /// Columns `[x0, x1)` as [`Frame::strip`] renders them, in pieces of
    /// columns that each take about [`PIECE_SECONDS`], asking `stop`
    /// before each: a strip whose caller went away ends within a piece
    /// with [`Cancelled`], and the GPU is free for the next. A frame is the
    /// same however it is cut, so the pieces put together are the strip
    /// rendered whole. `rate` is the columns a second measured on strips
    /// like this one before, if any (the first piece is sized by it, so a
    /// fast GPU renders a strip in one dispatch), and what this one
    /// measured after.
    pub fn strip_until(
        &self,
        x0: u32,
        x1: u32,
        stop: &dyn Fn() -> bool,
        rate: &mut Option<f64>,
    ) -> anyhow::Result<RenderedStrip> {
        // A filtered gather renders its filter's reach beyond each piece:
        // pieces a few reaches wide keep that cost small.
        let reach = if self.settings.gather_filtered() { self.settings.gather_filter } else { 0 };
        let least = (4 * reach).max(1);
        let (mut pieces, mut at) = (Vec::new(), x0);
        // Without a rate from before, the first piece is as narrow as it
        // may be; each next one is sized to the rate measured, at most four
        // times the last, so a piece that misjudged the rate (a column of
        // sky) cannot run long.
        let mut cols = rate.map_or(least, |r| ((r * PIECE_SECONDS) as u32).max(least));
        while at < x1 {
            anyhow::ensure!(!stop(), Cancelled);
            let end = (at + cols).min(x1);
            let t = Instant::now();
            pieces.push(self.strip(at, end)?);
            let secs = t.elapsed().as_secs_f64().max(1e-4);
            tracing::debug!(x0 = at, x1 = end, ms = secs * 1e3, "rendered a piece of the strip");
            let measured = (end - at) as f64 / secs;
            *rate = Some(measured);
            cols = ((measured * PIECE_SECONDS) as u32).clamp(least, 4 * (end - at));
            at = end;
        }
        Ok(join_columns(pieces, self.settings.height))
    }

    /// Every strip of `plan`, one after another, each handed to `sink`
    /// with its milliseconds of rendering as soon as it is done.
    pub fn strips(
        &self,
        plan: &[(u32, u32)],
        sink: &mut dyn FnMut(RenderedStrip, f64) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        for &(x0, x1) in plan {
            let t = Instant::now();
            let s = self.strip(x0, x1)?;
            sink(s, ms(t))?;
        }
        Ok(())
    }

    /// The frame's columns `ranges` (the whole frame: `&[(0, width)]`)
    /// path traced in batches until `opts` says it has converged:
    /// progressively, `progress` hearing each batch.
    pub fn reference(
        &self,
        ranges: &[(u32, u32)],
        opts: &ReferenceOptions,
        progress: &dyn Fn(&ReferenceStats),
    ) -> anyhow::Result<ReferenceImage> {
        reference::render_reference_columns(
            &self.tracer,
            &self.prepared.renderer,
            &self.settings,
            ranges,
            opts,
            progress,
        )
    }

    /// The GPU the frame traces on.
    pub fn tracer(&self) -> &Tracer {
        &self.tracer
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Why a strip was not rendered whole: its caller went away first.
#[derive(Debug, thiserror::Error)]
#[error("cancelled")]
pub struct Cancelled;

/// About how long each piece of a cancellable strip runs, s: a cancel is
/// heard within this (the farm promises a second), and pieces stay long
/// enough that their dispatches cost next to nothing on a fast GPU.
pub const PIECE_SECONDS: f64 = 0.25;

/// Side-by-side pieces of one strip (left to right, `height` rows) as one.
fn join_columns(pieces: Vec<RenderedStrip>, height: u32) -> RenderedStrip {
    if pieces.len() == 1 {
        return pieces.into_iter().next().expect("one piece");
    }
    let x0 = pieces[0].x0;
    let width: u32 = pieces.iter().map(|p| p.width).sum();
    let rows = |get: &dyn Fn(&RenderedStrip) -> &[[f32; 3]]| -> Vec<[f32; 3]> {
        if pieces.iter().any(|p| get(p).is_empty()) {
            return Vec::new();
        }
        (0..height as usize)
            .flat_map(|y| {
                pieces.iter().flat_map(move |p| {
                    let w = p.width as usize;
                    get(p)[y * w..(y + 1) * w].iter().copied()
                })
            })
            .collect()
    };
    let pixels = rows(&|p| &p.pixels);
    let first_light = rows(&|p| &p.first_light);
    let coverage = (0..height as usize)
        .flat_map(|y| {
            pieces.iter().flat_map(move |p| {
                let w = p.width as usize;
                p.coverage[y * w..(y + 1) * w].iter().copied()
            })
        })
        .collect();
    let mut rays = RayCounts::default();
    pieces.iter().for_each(|p| rays.add(&p.rays));
    let passes = pieces[0].passes.as_ref().map(|first| {
        let mut all = PassImage::new(width, height, first.set);
        for p in &pieces {
            if let Some(img) = &p.passes {
                all.paste_strip(p.x0 - x0, img).expect("pieces of one strip share their passes");
            }
        }
        all
    });
    RenderedStrip { x0, width, pixels, coverage, first_light, rays, passes }
}
