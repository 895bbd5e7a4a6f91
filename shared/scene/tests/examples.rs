//! Every example scene loads as shipped: its files lie inside its folder
//! and pass the same checks a submitted scene does.

use sylva_scene::Scene;

#[test]
fn every_example_scene_loads() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples");
    let mut loaded = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "json") {
            let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(!scene.instances.is_empty(), "{}", path.display());
            loaded.push(path.file_name().unwrap().to_string_lossy().into_owned());
        }
    }
    loaded.sort();
    assert_eq!(loaded, ["cloud.json", "ferns.json", "grove.json", "teapot.json", "tree.json"]);
}
