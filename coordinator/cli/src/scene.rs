//! `sylva scene …`: scene files.

use super::render::create_parent;
use crate::flags::scene::*;
use anyhow::Context;
use serde_json::json;
use sylva_scene::table2::{ForestOptions, forest, instances_at};
use sylva_scene::trees::Species;

pub fn run(cmd: SceneCommand) -> anyhow::Result<()> {
    match cmd {
        SceneCommand::Export(a) => export(a),
        SceneCommand::Pack(a) => {
            let b = sylva_scene::bundle::pack(&a.scene)?;
            create_parent(&a.out)?;
            std::fs::write(&a.out, &b.bytes)
                .with_context(|| format!("{}: cannot write", a.out.display()))?;
            if a.json {
                println!("{}", json!({ "bundle": a.out, "hash": b.hash, "bytes": b.bytes.len() }));
            } else {
                println!("wrote {}: {} bytes, {}", a.out.display(), b.bytes.len(), b.hash);
            }
            Ok(())
        }
        SceneCommand::Import(a) => {
            let dir = a
                .out
                .parent()
                .filter(|d| !d.as_os_str().is_empty())
                .unwrap_or(std::path::Path::new("."));
            let file = sylva_scene::interchange::import::import_gltf(&a.gltf, dir)?;
            // Checked as `render` would load it, before it is written.
            sylva_scene::Scene::build(file.clone(), dir, &a.out.display().to_string())?;
            create_parent(&a.out)?;
            std::fs::write(&a.out, serde_json::to_string_pretty(&file)? + "\n")
                .with_context(|| format!("{}: cannot write", a.out.display()))?;
            println!(
                "wrote {}: {} models, {} instances",
                a.out.display(),
                file.models.len(),
                file.instances.len()
            );
            Ok(())
        }
        SceneCommand::Forest(a) => {
            let o =
                ForestOptions { scale: a.scale, triangle_scale: a.triangle_scale, seed: a.seed };
            let scene = forest(&o).map_err(anyhow::Error::msg)?;
            create_parent(&a.out)?;
            std::fs::write(&a.out, serde_json::to_string_pretty(&scene)? + "\n")
                .with_context(|| format!("{}: cannot write", a.out.display()))?;
            let per_species: Vec<_> = Species::ALL
                .iter()
                .map(|&sp| {
                    let tris = scene.models[sp.name()].tree.and_then(|t| t.triangles).unwrap_or(0);
                    json!({ "species": sp.name(), "instances": instances_at(sp, a.scale), "triangles_per_instance": tris })
                })
                .collect();
            let instanced: u64 = per_species
                .iter()
                .map(|s| {
                    s["instances"].as_u64().unwrap_or(0)
                        * s["triangles_per_instance"].as_u64().unwrap_or(0)
                })
                .sum();
            let unique: u64 =
                per_species.iter().map(|s| s["triangles_per_instance"].as_u64().unwrap_or(0)).sum();
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
                println!(
                    "wrote {}: {} instances of 5 species, {} triangles ({} unique)",
                    a.out.display(),
                    scene.instances.len(),
                    instanced,
                    unique
                );
            }
            Ok(())
        }
    }
}

fn export(a: ExportArgs) -> anyhow::Result<()> {
    let scene = sylva_scene::Scene::load(&a.scene)?;
    let summary = match a.format {
        ExportFormat::Gltf => {
            let (bytes, summary) = sylva_scene::interchange::gltf::export_glb(&scene)?;
            create_parent(&a.out)?;
            std::fs::write(&a.out, &bytes)
                .with_context(|| format!("{}: cannot write", a.out.display()))?;
            serde_json::to_value(summary)?
        }
        ExportFormat::Pbrt => {
            serde_json::to_value(sylva_scene::interchange::pbrt::export_pbrt(&scene, &a.out)?)?
        }
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&json!({ "out": a.out, "summary": summary }))?);
    } else {
        println!("wrote {}: {summary}", a.out.display());
    }
    Ok(())
}
