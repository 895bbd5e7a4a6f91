//! `sylva scene forest`, `export` and `import`. Flags only (clap), and their conversion to
//! settings.

use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Debug, Subcommand)]
pub enum SceneCommand {
    /// Write the forest paper's Table 2 forest as a scene file.
    Forest(ForestArgs),
    /// Write a scene for other tools: glTF 2.0 (instanced, for Blender) or pbrt-v4.
    Export(ExportArgs),
    /// Write a scene file for an instanced glTF scene (each mesh a model).
    Import(ImportArgs),
    /// Pack a scene file and its models into the bundle `submit` sends.
    Pack(PackArgs),
}

#[derive(Debug, Args)]
pub struct PackArgs {
    /// Scene file.
    pub scene: PathBuf,
    /// Where to write the bundle.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Print the bundle's hash and size as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Formats `sylva scene export` writes.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum ExportFormat {
    /// Binary glTF 2.0 (`.glb`) with EXT_mesh_gpu_instancing and KHR_lights_punctual.
    Gltf,
    /// A pbrt-v4 scene (`.pbrt`) with object instancing, its meshes and textures beside it.
    Pbrt,
}

#[derive(Debug, Args)]
pub struct ExportArgs {
    /// Scene file.
    pub scene: PathBuf,
    /// Output format.
    #[arg(long, value_enum)]
    pub format: ExportFormat,
    /// Output file.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Print what was written as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ImportArgs {
    /// A glTF 2.0 file (`.glb` or `.gltf`).
    pub gltf: PathBuf,
    /// Where to write the scene file (it names the glTF file relative to itself).
    #[arg(short, long)]
    pub out: PathBuf,
}

#[derive(Debug, Args)]
pub struct ForestArgs {
    /// Multiplies each species' instance count; 1 is the paper's 962 trees.
    #[arg(long, default_value_t = 1.0)]
    pub scale: f64,
    /// Multiplies each tree's triangle count; 1 is the paper's (115 k–497 k).
    #[arg(long, default_value_t = 1.0)]
    pub triangle_scale: f64,
    /// Placement and shape seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Where to write the scene.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Print the counts as JSON.
    #[arg(long)]
    pub json: bool,
}
