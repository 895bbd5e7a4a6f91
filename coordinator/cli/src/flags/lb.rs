//! `sylva lb solve` and `sylva lb verify`. Flags only (clap), and their conversion to settings.

use clap::{Args, Subcommand, ValueEnum};
use serde::Serialize;
use std::path::PathBuf;
use sylva_scene::format::Preset;

#[derive(Debug, Subcommand)]
pub enum LbCommand {
    /// Solve the light field of a model, a built-in shape or a density grid.
    Solve(SolveArgs),
    /// Check the solvers against the model's mathematics.
    Verify(VerifyArgs),
}

/// Which machine solves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// The rayon reference solver.
    Cpu,
    /// The wgpu solver.
    Gpu,
}

/// Node class for a density grid read from `.npy`.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ClassArg {
    /// Participating medium: absorbed light is kept and re-emitted.
    Medium,
    /// Leaves: absorbed light is removed.
    Green,
    /// Wood: back-scatter only.
    Brown,
}

#[derive(Debug, Args)]
pub struct SolveArgs {
    /// `plant` (built-in leaf-filled sphere on a trunk), `cloud` (procedural
    /// cumulus), a glTF model (.gltf/.glb), or a density grid (.npy, float32,
    /// shape (Z, Y, X), values in [0, 1]).
    pub input: String,
    /// Which solver runs.
    #[arg(long, value_enum, default_value = "gpu")]
    pub backend: Backend,
    /// Grid size N (an N³ lattice over the model's bounds); default 64.
    /// A .npy grid brings its own size.
    #[arg(long)]
    pub grid: Option<usize>,
    /// Optical parameters: leaf, dogrose, cloud, pmma. Default: cloud for
    /// `cloud`, leaf otherwise.
    #[arg(long, value_parser = parse_preset)]
    pub preset: Option<Preset>,
    /// Sun as `ELEVATION,AZIMUTH` in degrees (y up, azimuth from +x towards
    /// +z), or as a vector `X,Y,Z` pointing at the sun.
    #[arg(long, default_value = "60,30", allow_hyphen_values = true)]
    pub sun: String,
    /// Density the boundary holds along the sunlight.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    pub sun_intensity: f64,
    /// Class of every node of a .npy grid; default green for plant presets,
    /// medium otherwise.
    #[arg(long, value_enum)]
    pub class: Option<ClassArg>,
    /// Step cap; default 2 × the longest grid edge.
    #[arg(long)]
    pub max_steps: Option<usize>,
    /// Stop when the total density changes by less than this per step.
    #[arg(long, default_value_t = 1e-4)]
    pub tolerance: f64,
    /// Output folder for density.npy, density.png and summary.json.
    #[arg(short, long, default_value = "sylva-out/lb")]
    pub out: PathBuf,
    /// Print the summary JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct VerifyArgs {
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Skip the GPU check (it then reports as failed, not passed).
    #[arg(long)]
    pub no_gpu: bool,
}

pub(crate) fn parse_preset(s: &str) -> Result<Preset, String> {
    Preset::from_name(s).ok_or_else(|| {
        let names: Vec<_> = Preset::ALL.iter().map(|p| p.name()).collect();
        format!("unknown preset {s:?}; one of {}", names.join(", "))
    })
}
