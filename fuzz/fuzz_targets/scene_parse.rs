//! `scene::parse` then `Scene::build` on arbitrary text: neither may panic.
//! The in-suite version is `shared/scene/tests/fuzz_inputs.rs`; see
//! docs/fuzzing.md.

#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::{Component, Path, PathBuf};
use std::sync::OnceLock;
use sylva_scene::{self as scene, Scene, SceneFile};

/// Largest generated tree built: trees cost time in proportion.
const MAX_TREE_TRIANGLES: u32 = 2000;
const MAX_MODELS: usize = 4;
const MAX_INSTANCES: usize = 256;

/// Small trees with an explicit count (the default is up to half a million
/// triangles) and glTF paths of plain names (in an empty folder).
fn cheap_to_build(f: &SceneFile) -> bool {
    f.models.len() <= MAX_MODELS
        && f.instances.len() <= MAX_INSTANCES
        && f.models.values().all(|m| {
            m.tree.is_none_or(|t| t.triangles.is_some_and(|n| n <= MAX_TREE_TRIANGLES))
                && m.gltf.as_deref().is_none_or(|p| p.components().all(|c| matches!(c, Component::Normal(_))))
        })
}

/// An empty folder that relative glTF paths start from.
fn base() -> &'static Path {
    static BASE: OnceLock<PathBuf> = OnceLock::new();
    BASE.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("sylva-fuzz-scene-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("a temporary folder");
        d
    })
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(file) = scene::parse(text, "fuzz.json") else { return };
    if cheap_to_build(&file) {
        let _ = Scene::build(file, base(), "fuzz.json");
    }
});
