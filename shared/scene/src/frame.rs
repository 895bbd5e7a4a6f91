//! What one frame asks for: size, samples, lighting method and structure.
//! The one type the command line, the coordinator and the workers share;
//! `sylva-proto` converts it to and from the wire, and every side runs
//! [`FrameSettings::check`] before using one.

use crate::LightingMode;
use serde::{Deserialize, Serialize};

/// Largest image side a frame may have.
pub const MAX_SIDE: u32 = 16_384;
/// Most rays per pixel a frame may ask for.
pub const MAX_SPP: u32 = 4_096;
/// Bounces the gather methods trace before reading the lattice, unless asked.
pub const DEFAULT_GATHER_BOUNCES: u32 = 1;
/// Most bounces a gather may trace before the lattice (beyond two, the
/// reference's own paths cost no more).
pub const MAX_GATHER_BOUNCES: u32 = 4;

/// Radius in pixels of the gathers' filter over their indirect light, unless asked.
pub const DEFAULT_GATHER_FILTER: u32 = 3;
/// Largest filter radius a frame may ask for.
pub const MAX_GATHER_FILTER: u32 = 16;

fn default_gather_filter() -> u32 {
    DEFAULT_GATHER_FILTER
}

fn default_gather_bounces() -> u32 {
    DEFAULT_GATHER_BOUNCES
}

/// Which structure a CPU builds for a traversal that walks its own (the
/// compute backends; also the CPU reference's).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum AccelKind {
    /// kd-tree with short-stack traversal (the paper's).
    Kd,
    /// Four-wide bounding-volume hierarchy.
    #[default]
    Bvh,
}

/// How rays traverse the scene on a worker's GPU (`--accel`): what a frame
/// asks for and what a worker chose. `Auto` is asked only: each worker
/// resolves it for its adapter (`sylva_worker::trace::candidates`), so the
/// backend a prepared scene traces with is never `Auto`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    // The order is the variants' number in postcard, which the prepared-data
    // cache on disk and between workers stores: new variants go last (auto,
    // then cwbvh), so a choice kept before them still reads as the backend
    // it named.
    /// Ray queries: the device's own structures, in hardware where it has
    /// them (refused where the adapter has none).
    Rq,
    /// Sylva's four-wide BVH, walked by a compute kernel.
    Bvh,
    /// Sylva's kd-tree, walked by a compute kernel (the paper's).
    Kd,
    /// Each worker chooses for its adapter by a short measurement at
    /// preparation: the BVH, the compressed wide BVH, or ray queries where
    /// it has them.
    #[default]
    Auto,
    /// Sylva's eight-wide compressed BVH (derived from the four-wide one),
    /// walked by a compute kernel with its stack in workgroup memory.
    Cwbvh,
}

impl Backend {
    /// The structure it walks, built on the CPU: `auto` may walk the BVH,
    /// ray queries walk none (the device builds its own).
    pub fn structure(self) -> Option<AccelKind> {
        match self {
            Backend::Rq => None,
            Backend::Auto | Backend::Bvh | Backend::Cwbvh => Some(AccelKind::Bvh),
            Backend::Kd => Some(AccelKind::Kd),
        }
    }

    /// The backend it names; `None` for `auto`, which a worker resolves.
    pub fn resolved(self) -> Option<Backend> {
        (self != Backend::Auto).then_some(self)
    }

    /// Its name, as `--accel` spells it.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Auto => "auto",
            Backend::Rq => "rq",
            Backend::Bvh => "bvh",
            Backend::Kd => "kd",
            Backend::Cwbvh => "cwbvh",
        }
    }
}

impl From<AccelKind> for Backend {
    fn from(k: AccelKind) -> Self {
        match k {
            AccelKind::Bvh => Backend::Bvh,
            AccelKind::Kd => Backend::Kd,
        }
    }
}

/// How a job's frames are cut into strips for the workers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum ScheduleKind {
    /// N equal strips, one per worker (the paper's way).
    Static,
    /// More strips than workers, pulled by idle workers, sized so the last
    /// ones finish together.
    #[default]
    Dynamic,
}

/// A frame to render.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameSettings {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Rays per pixel.
    pub spp: u32,
    /// Seed of the per-pixel sample hash.
    pub seed: u32,
    /// Lighting method; `None`: the scene file's.
    pub lighting: Option<LightingMode>,
    /// The traversal backend asked for (`auto`: each worker's choice).
    pub accel: Backend,
    /// Weight of the LB light relative to the sun's.
    pub lb_strength: f32,
    /// The `ambient` method's constant, linear RGB; `None`: matched to the
    /// LB image by the worker.
    pub ambient: Option<[f32; 3]>,
    /// The frame's camera and sun, where they differ from the scene's (a
    /// frame of a sequence).
    #[serde(default)]
    pub view: crate::sequence::View,
    /// The gather methods: bounces traced through the geometry before the
    /// far end reads the lattice (or the matched constant).
    #[serde(default = "default_gather_bounces")]
    pub gather_bounces: u32,
    /// The gather methods: radius in pixels of the filter over their
    /// indirect light, within one crown (docs/lighting.md); 0: none.
    #[serde(default = "default_gather_filter")]
    pub gather_filter: u32,
    /// Render passes beside the beauty image (docs/passes.md).
    #[serde(default)]
    pub passes: crate::passes::PassSet,
    /// What of the assembled frame is denoised (Open Image Denoise,
    /// guided by the albedo and normal passes, which it needs); the EXR
    /// keeps the noisy image beside it (docs/denoising.md).
    #[serde(default)]
    pub denoise: Denoise,
}

/// What of a frame the denoiser smooths (docs/denoising.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Denoise {
    /// Nothing: the frame as traced.
    #[default]
    Off,
    /// The whole frame, as Cycles denoises.
    Frame,
    /// The indirect light alone (the light split's pass, which it needs
    /// too), the direct light and the sky as traced: on foliage the whole
    /// frame's denoise smooths the sun's leaf-sized detail into the crown.
    Indirect,
}

impl Denoise {
    /// Its name, as flags and scene files write it.
    pub fn name(self) -> &'static str {
        match self {
            Denoise::Off => "off",
            Denoise::Frame => "frame",
            Denoise::Indirect => "indirect",
        }
    }

    /// Parses a name: `off`, `frame` or `indirect`.
    pub fn parse(name: &str) -> Result<Self, String> {
        [Denoise::Off, Denoise::Frame, Denoise::Indirect]
            .into_iter()
            .find(|d| d.name() == name)
            .ok_or_else(|| format!("denoise {name:?}: one of off, frame, indirect"))
    }

    /// Whether anything is denoised.
    pub fn is_on(self) -> bool {
        self != Denoise::Off
    }

    /// The passes its denoise reads: the guides, and for the indirect
    /// light alone the light split's indirect pass.
    pub fn passes(self) -> crate::passes::PassSet {
        use crate::passes::{DENOISE_GUIDES, Pass, PassSet};
        match self {
            Denoise::Off => PassSet::NONE,
            Denoise::Frame => DENOISE_GUIDES,
            Denoise::Indirect => DENOISE_GUIDES.with(PassSet::of([Pass::Indirect])),
        }
    }
}

/// Read as a name (`off`, `frame`, `indirect`) or, as frames written
/// before there was a choice, a bool (`true`: the whole frame).
impl<'de> Deserialize<'de> for Denoise {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Written {
            Bool(bool),
            Name(String),
        }
        match Written::deserialize(d)? {
            Written::Bool(b) => Ok(if b { Denoise::Frame } else { Denoise::Off }),
            Written::Name(n) => Denoise::parse(&n).map_err(serde::de::Error::custom),
        }
    }
}

impl Default for FrameSettings {
    fn default() -> Self {
        Self {
            width: 896,
            height: 448,
            spp: 1,
            seed: 1,
            lighting: None,
            accel: Backend::Auto,
            lb_strength: 0.35,
            ambient: None,
            view: Default::default(),
            gather_bounces: DEFAULT_GATHER_BOUNCES,
            gather_filter: DEFAULT_GATHER_FILTER,
            passes: crate::passes::PassSet::NONE,
            denoise: Denoise::Off,
        }
    }
}

/// A frame that cannot be rendered, and why.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct FrameError(pub String);

impl FrameSettings {
    /// Checks every field against the limits every renderer obeys.
    pub fn check(&self) -> Result<(), FrameError> {
        let bad = |m: String| Err(FrameError(m));
        if self.width == 0 || self.height == 0 || self.width > MAX_SIDE || self.height > MAX_SIDE {
            return bad(format!(
                "image {}×{}: each side must be in [1, {MAX_SIDE}]",
                self.width, self.height
            ));
        }
        if self.spp == 0 || self.spp > MAX_SPP {
            return bad(format!("spp {}: valid range [1, {MAX_SPP}]", self.spp));
        }
        if !(self.lb_strength.is_finite() && self.lb_strength >= 0.0) {
            return bad(format!("lb_strength {}: must be a finite number ≥ 0", self.lb_strength));
        }
        if !(1..=MAX_GATHER_BOUNCES).contains(&self.gather_bounces) {
            return bad(format!(
                "gather_bounces {}: valid range [1, {MAX_GATHER_BOUNCES}]",
                self.gather_bounces
            ));
        }
        if self.gather_filter > MAX_GATHER_FILTER {
            return bad(format!(
                "gather_filter {}: valid range [0, {MAX_GATHER_FILTER}]",
                self.gather_filter
            ));
        }
        if let Some(a) = self.ambient
            && !a.iter().all(|v| v.is_finite() && *v >= 0.0)
        {
            return bad(format!("ambient {a:?}: three finite values ≥ 0"));
        }
        let needs = self.denoise.passes();
        if !needs.extra().all(|p| self.passes.contains(p)) {
            return bad(format!(
                "denoise {}: the passes it reads must be rendered too (passes {})",
                self.denoise.name(),
                needs.extra().map(|p| p.name()).collect::<Vec<_>>().join(",")
            ));
        }
        self.view.check().map_err(|e| FrameError(e.to_string()))
    }

    /// The lighting method, given the scene's own.
    pub fn lighting_or(&self, scene: LightingMode) -> LightingMode {
        self.lighting.unwrap_or(scene)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_limit_is_checked_and_named() {
        assert!(FrameSettings::default().check().is_ok());
        let cases = [
            (FrameSettings { width: 0, ..Default::default() }, "each side"),
            (FrameSettings { height: MAX_SIDE + 1, ..Default::default() }, "each side"),
            (FrameSettings { spp: 0, ..Default::default() }, "spp 0"),
            (FrameSettings { spp: MAX_SPP + 1, ..Default::default() }, "spp"),
            (FrameSettings { gather_bounces: 0, ..Default::default() }, "gather_bounces 0"),
            (
                FrameSettings { gather_bounces: MAX_GATHER_BOUNCES + 1, ..Default::default() },
                "gather_bounces",
            ),
            (FrameSettings { lb_strength: f32::NAN, ..Default::default() }, "lb_strength NaN"),
            (
                FrameSettings { ambient: Some([0.1, f32::INFINITY, 0.0]), ..Default::default() },
                "ambient",
            ),
            (FrameSettings { ambient: Some([0.1, -1.0, 0.0]), ..Default::default() }, "ambient"),
            (
                FrameSettings { denoise: Denoise::Frame, ..Default::default() },
                "denoise frame: the passes it reads must be rendered too (passes albedo,normal)",
            ),
            (
                FrameSettings {
                    denoise: Denoise::Indirect,
                    passes: crate::passes::DENOISE_GUIDES,
                    ..Default::default()
                },
                "passes direct,indirect,albedo,normal,sky",
            ),
        ];
        for (f, want) in cases {
            let e = f.check().unwrap_err().to_string();
            assert!(e.contains(want), "{want}: {e}");
        }
    }

    /// A frame written before there was a choice said `"denoise": true`:
    /// it reads as the whole frame; names read as themselves.
    #[test]
    fn denoise_reads_old_bools_and_names() {
        let read = |v: &str| serde_json::from_str::<Denoise>(v);
        assert_eq!(read("true").unwrap(), Denoise::Frame);
        assert_eq!(read("false").unwrap(), Denoise::Off);
        for d in [Denoise::Off, Denoise::Frame, Denoise::Indirect] {
            assert_eq!(read(&serde_json::to_string(&d).unwrap()).unwrap(), d);
            assert_eq!(Denoise::parse(d.name()), Ok(d));
        }
        assert!(read("\"sky\"").unwrap_err().to_string().contains("one of off, frame, indirect"));
        let ok = FrameSettings {
            denoise: Denoise::Indirect,
            passes: Denoise::Indirect.passes(),
            ..Default::default()
        };
        assert!(ok.check().is_ok());
    }
}
