//! The scene file: JSON, every field typed, unknown fields refused.

use crate::trees::TreeParams;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// A scene as written on disk.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Models by name: a glTF file or a generated tree.
    pub models: BTreeMap<String, ModelSpec>,
    /// Placements of the models.
    pub instances: Vec<InstanceSpec>,
    /// The view.
    pub camera: CameraSpec,
    /// The sun.
    pub sun: SunSpec,
    /// The sky's colour.
    #[serde(default)]
    pub sky: SkySpec,
    /// A ground plane at y = 0, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ground: Option<GroundSpec>,
    /// How indirect light is computed.
    #[serde(default)]
    pub lighting: LightingMode,
    /// LB settings for models that give none.
    #[serde(default)]
    pub lb: LbSpec,
    /// Which LB model lights the scene: the grounded one (default) or the
    /// papers' as written.
    #[serde(default)]
    pub lb_model: LbModel,
    /// The coarse LB grid over the whole forest.
    #[serde(default)]
    pub forest_grid: ForestGridSpec,
    /// Clouds: LB-lit density volumes.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub clouds: Vec<CloudSpec>,
    /// Leaf reflection and transmission per side, for the reference and
    /// Boulanger methods (default: from the measured leaf scattering).
    #[serde(default)]
    pub leaf_optics: crate::leaf::LeafOptics,
    /// A sequence of frames: a sun sweep and/or a camera path
    /// ([`crate::sequence`]); absent: one frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sequence: Option<crate::sequence::SequenceSpec>,
}

/// Where a model comes from: exactly one of `gltf` and `tree`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSpec {
    /// A glTF 2.0 file, relative to the scene file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gltf: Option<PathBuf>,
    /// With `gltf`: only the mesh of this name, in its own space (one
    /// species of an instanced glTF scene, as `sylva scene import` writes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
    /// A generated tree.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tree: Option<TreeParams>,
    /// LB settings for this model (otherwise the scene's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lb: Option<LbSpec>,
}

/// One placement of a model: a full matrix, or translate–rotate–scale.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InstanceSpec {
    /// Name of the model.
    pub model: String,
    /// Translation.
    #[serde(default)]
    pub position: [f32; 3],
    /// Rotation about the vertical axis, degrees.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub rotate_y_deg: f32,
    /// Uniform scale.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub scale: f32,
    /// A column-major 4 × 4 model-to-world matrix, instead of the above.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub matrix: Option<[f32; 16]>,
}

fn one() -> f32 {
    1.0
}
fn is_one(v: &f32) -> bool {
    *v == 1.0
}
fn is_zero(v: &f32) -> bool {
    *v == 0.0
}

/// The camera.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Eye position.
    pub position: [f32; 3],
    /// Point looked at.
    pub look_at: [f32; 3],
    /// Up direction.
    #[serde(default = "y_up")]
    pub up: [f32; 3],
    /// Vertical field of view, degrees.
    #[serde(default = "default_fov")]
    pub fov_y_deg: f32,
}

pub(crate) fn y_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}
pub(crate) fn default_fov() -> f32 {
    40.0
}

/// The sun: where it is, its colour temperature and strength.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SunSpec {
    /// Degrees above the horizon (with `azimuth_deg`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elevation_deg: Option<f32>,
    /// Degrees from +x towards +z.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub azimuth_deg: Option<f32>,
    /// A vector pointing at the sun, instead of the angles.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub direction: Option<[f32; 3]>,
    /// Black-body temperature, kelvin.
    #[serde(default = "default_temperature")]
    pub temperature_k: f32,
    /// Irradiance multiplier.
    #[serde(default = "default_sun_intensity")]
    pub intensity: f32,
}

fn default_temperature() -> f32 {
    6500.0
}
fn default_sun_intensity() -> f32 {
    3.0
}

/// A gradient sky, linear RGB.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkySpec {
    /// Colour straight up.
    pub zenith: [f32; 3],
    /// Colour at the horizon.
    pub horizon: [f32; 3],
}

impl Default for SkySpec {
    fn default() -> Self {
        Self { zenith: [0.25, 0.45, 0.85], horizon: [0.75, 0.82, 0.9] }
    }
}

/// A ground plane at y = 0.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroundSpec {
    /// Linear RGB albedo.
    pub color: [f32; 3],
}

/// How the image's indirect light is computed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum LightingMode {
    /// Direct sun light only.
    Local,
    /// Direct light plus a constant ambient term matched to the LB image.
    Ambient,
    /// Direct light plus LB indirect light.
    #[default]
    Lb,
    /// The LB value alone.
    LbVisualize,
    /// The reference: a path tracer with the leaf BSDF, sky, sun and clouds.
    Reference,
    /// Boulanger et al. 2008: per-leaf envelope distances, direct sky and
    /// sun and one-bounce indirect light in closed form.
    Boulanger,
    /// A final gather over the LB: the first one or two bounces traced
    /// through the real geometry, the rest read from the lattice.
    Gather,
    /// The same gather, its far end reading the matched constant instead
    /// of the LB (what the lattice adds over a constant, measured).
    GatherAmbient,
}

impl LightingMode {
    /// Every method, in the order `compare` lists them.
    pub const ALL: [LightingMode; 8] = [
        LightingMode::Local,
        LightingMode::Ambient,
        LightingMode::Lb,
        LightingMode::LbVisualize,
        LightingMode::Boulanger,
        LightingMode::Gather,
        LightingMode::GatherAmbient,
        LightingMode::Reference,
    ];

    /// The name scene files and the command line use.
    pub fn name(self) -> &'static str {
        match self {
            LightingMode::Local => "local",
            LightingMode::Ambient => "ambient",
            LightingMode::Lb => "lb",
            LightingMode::LbVisualize => "lb-visualize",
            LightingMode::Reference => "reference",
            LightingMode::Boulanger => "boulanger",
            LightingMode::Gather => "gather",
            LightingMode::GatherAmbient => "gather-ambient",
        }
    }

    /// Whether the method reads the constant matched to the LB image
    /// (`ambient`, and the gather whose far end reads it): whoever renders
    /// it matches the constant first unless the frame gives one.
    pub fn reads_matched_ambient(self) -> bool {
        matches!(self, LightingMode::Ambient | LightingMode::GatherAmbient)
    }

    /// Parses a name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// Which LB model the `lb`, `ambient` and `lb-visualize` methods use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LbModel {
    /// Derived from the scene (docs/lighting.md): density from leaf area,
    /// σ_a, σ_s, g from the leaf optics, sun and sky on the boundary in
    /// physical units, the uncollided sun left to the tracer, no free constant.
    #[default]
    Grounded,
    /// The papers as written: density from voxel occupancy, the preset's
    /// σ_a, σ_s, g, the sun alone on the boundary, and the LB term
    /// `albedo × LB / LB_free × lb_strength × sun` (a non-physical strength).
    Paper,
}

impl LbModel {
    /// The name scene files use.
    pub fn name(self) -> &'static str {
        match self {
            LbModel::Grounded => "grounded",
            LbModel::Paper => "paper",
        }
    }
}

/// LB settings of a model.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LbSpec {
    /// Grid size N (N³ nodes over the model's bounds).
    #[serde(default = "default_grid")]
    pub grid: usize,
    /// Optical parameters.
    #[serde(default = "default_preset")]
    pub preset: Preset,
    /// The model is a closed solid: its inside is medium too, not only the
    /// cells its surface crosses (the PMMA teapot).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub solid: bool,
}

fn default_grid() -> usize {
    32
}
fn default_preset() -> Preset {
    Preset::Leaf
}

impl Default for LbSpec {
    fn default() -> Self {
        Self { grid: default_grid(), preset: default_preset(), solid: false }
    }
}

/// When to light the forest as a whole with a coarse LB grid, whose value
/// at each instance scales that instance's species grid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ForestGridUse {
    /// When the instances' exposure differs by more than the threshold.
    #[default]
    Auto,
    /// Always.
    Always,
    /// Never: every instance gets full light.
    Never,
}

/// The coarse forest grid's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForestGridSpec {
    /// Cells along the forest's longest horizontal side.
    #[serde(default = "default_grid")]
    pub grid: usize,
    /// When to use it.
    #[serde(default, rename = "use")]
    pub use_grid: ForestGridUse,
    /// `auto` uses the grid when (max − min) / max of the instances' light
    /// exceeds this.
    #[serde(default = "default_threshold")]
    pub threshold: f32,
}

fn default_threshold() -> f32 {
    0.1
}

impl Default for ForestGridSpec {
    fn default() -> Self {
        Self { grid: default_grid(), use_grid: ForestGridUse::Auto, threshold: default_threshold() }
    }
}

/// A cloud: a procedural density volume in a box.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CloudSpec {
    /// Centre of the box.
    pub center: [f32; 3],
    /// Edge length of the (cubic) box.
    pub size: f32,
    /// LB grid size.
    #[serde(default = "default_grid")]
    pub grid: usize,
    /// Shape seed.
    #[serde(default)]
    pub seed: u64,
}

/// The named parameter sets of the papers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// Leaves, forest paper Table 1 (g from measured forward/backward scattering).
    Leaf,
    /// Dog rose, the LB chapter's Table 1.
    Dogrose,
    /// Cumulus cloud, the LB chapter: strongly forward scattering, almost no absorption.
    Cloud,
    /// PMMA plastic, the LB chapter's Table 2.
    Pmma,
}

impl Preset {
    /// Every preset, for listings and tests.
    pub const ALL: [Preset; 4] = [Preset::Leaf, Preset::Dogrose, Preset::Cloud, Preset::Pmma];

    /// The preset's name as the command line and scene files spell it.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Leaf => "leaf",
            Preset::Dogrose => "dogrose",
            Preset::Cloud => "cloud",
            Preset::Pmma => "pmma",
        }
    }

    /// Parses a preset name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Whether the preset describes plant matter, whose nodes are green
    /// (absorbed light is removed) unless voxelized from wood.
    pub fn is_plant(self) -> bool {
        matches!(self, Preset::Leaf | Preset::Dogrose)
    }
}
