//! `sylva scene …`: scene files.

use anyhow::Context;
use clap::{Args, Subcommand};
use serde_json::json;
use std::path::PathBuf;
use sylva_shared::scene::forest::{ForestOptions, forest, instances_at};
use sylva_shared::trees::Species;

#[derive(Debug, Subcommand)]
pub enum SceneCommand {
    /// Write the forest paper's Table 2 forest as a scene file.
    Forest(ForestArgs),
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

pub fn run(cmd: SceneCommand) -> anyhow::Result<()> {
    match cmd {
        SceneCommand::Forest(a) => {
            let o = ForestOptions { scale: a.scale, triangle_scale: a.triangle_scale, seed: a.seed };
            let scene = forest(&o).map_err(anyhow::Error::msg)?;
            std::fs::write(&a.out, serde_json::to_string_pretty(&scene)? + "\n").with_context(|| format!("{}: cannot write", a.out.display()))?;
            let per_species: Vec<_> = Species::ALL
                .iter()
                .map(|&sp| {
                    let tris = scene.models[sp.name()].tree.and_then(|t| t.triangles).unwrap_or(0);
                    json!({ "species": sp.name(), "instances": instances_at(sp, a.scale), "triangles_per_instance": tris })
                })
                .collect();
            let instanced: u64 =
                per_species.iter().map(|s| s["instances"].as_u64().unwrap_or(0) * s["triangles_per_instance"].as_u64().unwrap_or(0)).sum();
            let unique: u64 = per_species.iter().map(|s| s["triangles_per_instance"].as_u64().unwrap_or(0)).sum();
            let summary = json!({
                "scene": a.out,
                "scale": a.scale,
                "instances": scene.instances.len(),
                "triangles_instanced": instanced,
                "triangles_unique": unique,
                "species": per_species,
            });
            if a.json {
                println!("{}", serde_json::to_string_pretty(&summary)?);
            } else {
                println!("wrote {}: {} instances of 5 species, {} triangles ({} unique)", a.out.display(), scene.instances.len(), instanced, unique);
            }
            Ok(())
        }
    }
}
