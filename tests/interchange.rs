//! Scenes that travel: `sylva scene export` to glTF (checked by the Khronos
//! validator and read back by `sylva scene import` and Sylva's own loader)
//! and to pbrt-v4.

use crate::common;

use common::{fails, ok, scratch};
use glam::Mat4;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use sylva_scene::Scene;

/// Two species, three placements (one scaled, one turned), textured leaves.
fn grove(dir: &Path) -> PathBuf {
    let p = dir.join("grove.json");
    std::fs::write(
        &p,
        r#"{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 4000, "seed": 1 } },
                    "birch": { "tree": { "species": "paper_birch", "triangles": 3000, "seed": 2 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 0] },
                       { "model": "birch", "position": [8, 0, 4], "rotate_y_deg": 30 },
                       { "model": "maple", "position": [-6, 0, 9], "rotate_y_deg": 200, "scale": 1.3 } ],
        "camera": { "position": [4, 8, -26], "look_at": [4, 7, 0], "fov_y_deg": 45 },
        "sun": { "elevation_deg": 50, "azimuth_deg": 120, "intensity": 2.5 },
        "sky": { "zenith": [0.2, 0.4, 0.8], "horizon": [0.7, 0.8, 0.9] },
        "ground": { "color": [0.1, 0.08, 0.05] }
    }"#,
    )
    .unwrap();
    p
}

fn validate(glb: &Path) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/gltf-validate.cjs");
    let out = Command::new("node")
        .arg(&script)
        .arg(glb)
        .output()
        .expect("node runs (scripts/install-deps.sh installs it)");
    let report: Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|_| {
        panic!(
            "no validator report (scripts/install-deps.sh installs gltf-validator): {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    assert!(out.status.success(), "the validator found errors: {report:#}");
    report
}

#[test]
fn an_exported_gltf_passes_the_validator_and_comes_back_the_same() {
    let dir = scratch("gltf-export");
    let scene_path = grove(&dir);
    let glb = dir.join("grove.glb");
    let said: Value = serde_json::from_str(&ok(&[
        "scene",
        "export",
        scene_path.to_str().unwrap(),
        "--format",
        "gltf",
        "-o",
        glb.to_str().unwrap(),
        "--json",
    ]))
    .unwrap();
    let s = &said["summary"];
    assert_eq!(
        (s["meshes"].as_u64(), s["instances"].as_u64(), s["matrix_nodes"].as_u64()),
        (Some(3), Some(3), Some(0)),
        "{said:#}"
    );

    let report = validate(&glb);
    let issues = &report["issues"];
    assert_eq!(issues["numErrors"], 0, "{report:#}");
    let info = &report["info"];
    assert_eq!(info["animationCount"].as_u64().unwrap_or(0), 0);
    assert_eq!(info["materialCount"], 5, "two materials per tree, and the ground: {info:#}");
    assert!(
        info["extensionsUsed"].as_array().unwrap().iter().any(|e| e == "EXT_mesh_gpu_instancing"),
        "{info:#}"
    );

    // Back through `sylva scene import` and the loader.
    let back_path = dir.join("back.json");
    ok(&["scene", "import", glb.to_str().unwrap(), "-o", back_path.to_str().unwrap()]);
    let (a, b) = (Scene::load(&scene_path).unwrap(), Scene::load(&back_path).unwrap());
    assert_eq!(a.models.len(), b.models.len());
    for ma in &a.models {
        let mb = b
            .models
            .iter()
            .find(|m| m.name == ma.name)
            .unwrap_or_else(|| panic!("{} not imported", ma.name));
        let (x, y) = (&ma.model, &mb.model);
        assert_eq!(x.triangle_count(), y.triangle_count(), "{}", ma.name);
        // The same triangles, material by material (glTF groups them per material).
        let key = |m: &sylva_scene::model::Model| {
            let mut t: Vec<(String, [[u32; 3]; 3])> = (0..m.triangle_count())
                .map(|i| {
                    (
                        m.materials[m.material[i] as usize].name.clone(),
                        m.triangle(i).map(|p| p.to_array().map(f32::to_bits)),
                    )
                })
                .collect();
            t.sort();
            t
        };
        assert!(key(x) == key(y), "{}: the triangles differ", ma.name);
        for (i, t) in x.triangles.iter().enumerate() {
            assert_eq!(
                x.uvs[t[0] as usize],
                y.uvs[y.triangles[find(y, x.triangle(i))][0] as usize],
                "{}: uv",
                ma.name
            );
            if i > 50 {
                break;
            }
        }
        // Materials: the same surfaces, colours, masks and textures, and
        // no other species' (a mesh read alone keeps only what it uses).
        assert_eq!(x.materials.len(), y.materials.len(), "{}", ma.name);
        assert_eq!(x.textures.len(), y.textures.len(), "{}", ma.name);
        for mx in &x.materials {
            let my = y
                .materials
                .iter()
                .find(|m| m.name == mx.name)
                .unwrap_or_else(|| panic!("material {} lost", mx.name));
            assert_eq!(
                (mx.surface, mx.base_color, mx.alpha_cutoff, mx.double_sided),
                (my.surface, my.base_color, my.alpha_cutoff, my.double_sided)
            );
            assert_eq!(
                mx.texture.map(|t| &x.textures[t as usize]),
                my.texture.map(|t| &y.textures[t as usize]),
                "{}: texture",
                mx.name
            );
        }
    }
    // Instances: the same placements of the same models.
    let placements = |s: &Scene| {
        let mut v: Vec<(String, Vec<i64>)> = s
            .instances
            .iter()
            .map(|i| {
                (
                    s.models[i.model as usize].name.clone(),
                    Mat4::from(i.to_world)
                        .to_cols_array()
                        .iter()
                        .map(|v| (v * 1e4).round() as i64)
                        .collect(),
                )
            })
            .collect();
        v.sort();
        v
    };
    assert_eq!(placements(&a), placements(&b));
    // The view, the sun, the sky and the ground.
    assert!(
        (a.camera.position - b.camera.position).length() < 1e-4
            && (a.camera.forward - b.camera.forward).length() < 1e-4
    );
    assert!((a.camera.tan_half_fov_y - b.camera.tan_half_fov_y).abs() < 1e-5);
    assert!((a.sun.towards - b.sun.towards).length() < 1e-5, "{:?} {:?}", a.sun, b.sun);
    assert_eq!(
        a.sun.radiance.map(|v| (v * 1e4).round()),
        b.sun.radiance.map(|v| (v * 1e4).round())
    );
    assert_eq!(
        (a.sky.zenith, a.sky.horizon, a.ground.clone()),
        (b.sky.zenith, b.sky.horizon, b.ground.clone())
    );
}

/// The index in `m` of the triangle with corners `t`.
fn find(m: &sylva_scene::model::Model, t: [glam::Vec3; 3]) -> usize {
    (0..m.triangle_count()).find(|&i| m.triangle(i) == t).expect("triangle present")
}

#[test]
fn a_gltf_with_an_unsupported_instancing_accessor_is_refused_with_a_reason() {
    let dir = scratch("gltf-bad");
    let scene_path = grove(&dir);
    let glb = dir.join("grove.glb");
    ok(&[
        "scene",
        "export",
        scene_path.to_str().unwrap(),
        "--format",
        "gltf",
        "-o",
        glb.to_str().unwrap(),
    ]);
    // Point the first node's TRANSLATION at the positions' accessor of a
    // different count: the counts disagree.
    let mut bytes = std::fs::read(&glb).unwrap();
    let len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let mut doc: Value = serde_json::from_slice(&bytes[20..20 + len]).unwrap();
    doc["nodes"][0]["extensions"]["EXT_mesh_gpu_instancing"]["attributes"]["TRANSLATION"] =
        0.into();
    let mut text = serde_json::to_vec(&doc).unwrap();
    text.resize(len, b' ');
    assert!(text.len() == len, "the edited JSON must fit its chunk");
    bytes[20..20 + len].copy_from_slice(&text);
    std::fs::write(&glb, &bytes).unwrap();
    let err = common::fails(&[
        "scene",
        "import",
        glb.to_str().unwrap(),
        "-o",
        dir.join("x.json").to_str().unwrap(),
    ]);
    assert!(err.contains("EXT_mesh_gpu_instancing") && err.contains("counts differ"), "{err}");
}

#[test]
fn a_pbrt_export_instances_each_model_and_writes_its_meshes() {
    let dir = scratch("pbrt-export");
    let scene_path = grove(&dir);
    let out = dir.join("grove.pbrt");
    let said: Value = serde_json::from_str(&ok(&[
        "scene",
        "export",
        scene_path.to_str().unwrap(),
        "--format",
        "pbrt",
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]))
    .unwrap();
    let text = std::fs::read_to_string(&out).unwrap();
    assert_eq!(text.matches("ObjectBegin").count(), 2);
    assert_eq!(text.matches("ObjectInstance").count(), 3);
    assert_eq!(text.matches("AttributeBegin").count(), text.matches("AttributeEnd").count());
    assert_eq!(text.matches("ObjectBegin").count(), text.matches("ObjectEnd").count());
    assert!(
        text.contains("Material \"diffusetransmission\" \"texture reflectance\""),
        "leaves transmit"
    );
    assert!(text.contains("\"texture alpha\""), "leaves are cut by their masks");
    assert!(text.contains("LightSource \"distant\"") && text.contains("LightSource \"infinite\""));
    // Every PLY it names exists, and they hold each model's triangles once.
    let scene = Scene::load(&scene_path).unwrap();
    let want: u64 = scene.models.iter().map(|m| m.model.triangle_count() as u64).sum();
    let mut faces = 0u64;
    for name in text
        .split("\"string filename\" [ \"")
        .skip(1)
        .map(|r| &r[..r.find('"').unwrap()])
        .filter(|f| f.ends_with(".ply"))
    {
        let bytes = std::fs::read(dir.join(name)).unwrap_or_else(|_| panic!("{name} missing"));
        let header = String::from_utf8_lossy(
            &bytes[..bytes.windows(10).position(|w| w == b"end_header").unwrap()],
        )
        .to_string();
        faces += header
            .lines()
            .find_map(|l| l.strip_prefix("element face "))
            .unwrap()
            .parse::<u64>()
            .unwrap();
    }
    assert_eq!(faces, want);
    assert_eq!(said["summary"]["triangles"].as_u64(), Some(want));
}

/// A scene file may import a glTF scene (what the Blender add-on sends):
/// it is the scene `sylva scene import` writes, with the file's own fields
/// in place of the import's, and it travels in a bundle with its glTF; an
/// import must lie inside the scene's folder, and its buffers too.
#[test]
fn a_scene_importing_a_gltf_scene_is_that_scene_and_packs_with_it() {
    let dir = scratch("gltf-import-field");
    let scene_path = grove(&dir);
    let glb = dir.join("grove.glb");
    ok(&[
        "scene",
        "export",
        scene_path.to_str().unwrap(),
        "--format",
        "gltf",
        "-o",
        glb.to_str().unwrap(),
    ]);
    let imported = dir.join("imported.json");
    ok(&["scene", "import", glb.to_str().unwrap(), "-o", imported.to_str().unwrap()]);
    let wrapper = dir.join("wrapper.json");
    std::fs::write(&wrapper, r#"{ "import": "grove.glb", "lighting": "local", "ground": null }"#)
        .unwrap();
    let (a, b) = (Scene::load(&imported).unwrap(), Scene::load(&wrapper).unwrap());
    assert_eq!(a.models.len(), b.models.len());
    assert_eq!(a.instances.len(), b.instances.len());
    assert_eq!(a.unique_triangles(), b.unique_triangles());
    assert_eq!(a.camera.position, b.camera.position);
    // The file's own fields win.
    assert_eq!(b.file.lighting, sylva_scene::LightingMode::Local);
    assert!(a.ground.is_some() && b.ground.is_none());

    // Packed, the glTF goes along; unpacked elsewhere, the same scene.
    std::fs::write(&wrapper, r#"{ "import": "grove.glb", "lighting": "local" }"#).unwrap();
    let bundle = sylva_scene::bundle::pack(&wrapper).unwrap();
    let there = dir.join("unpacked");
    let c = sylva_scene::bundle::unpack(&bundle.bytes, &there).unwrap();
    assert_eq!(
        (c.instances.len(), c.unique_triangles()),
        (b.instances.len(), b.unique_triangles())
    );

    // Rendered, the two files are one frame.
    let frame =
        ["--local-workers", "0", "--width", "48", "--height", "32", "--lighting", "local", "--exr"];
    let (pa, pb) = (dir.join("a.png"), dir.join("b.png"));
    for (scene, out) in [(&imported, &pa), (&wrapper, &pb)] {
        let mut args = vec!["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap()];
        args.extend(frame);
        ok(&args);
    }
    assert_eq!(
        std::fs::read(dir.join("a.exr")).unwrap(),
        std::fs::read(dir.join("b.exr")).unwrap()
    );

    // An import outside the folder, or whose buffer is, is refused.
    std::fs::write(&wrapper, r#"{ "import": "../grove.glb" }"#).unwrap();
    let e = Scene::load(&wrapper).unwrap_err().to_string();
    assert!(e.contains("import") && e.contains("not a file inside"), "{e}");
    let inner = dir.join("inner");
    std::fs::create_dir_all(&inner).unwrap();
    std::fs::write(dir.join("secret.bin"), [0u8; 64]).unwrap();
    std::fs::write(
        inner.join("leak.gltf"),
        r#"{ "asset": { "version": "2.0" }, "buffers": [ { "byteLength": 64, "uri": "../secret.bin" } ] }"#,
    )
    .unwrap();
    std::fs::write(inner.join("s.json"), r#"{ "import": "leak.gltf" }"#).unwrap();
    let e = Scene::load(&inner.join("s.json")).unwrap_err().to_string();
    assert!(e.contains("not a file inside"), "{e}");
    // It tells nothing of outside: a file that is not there reads the same.
    let gltf = std::fs::read_to_string(inner.join("leak.gltf")).unwrap();
    std::fs::write(inner.join("leak.gltf"), gltf.replace("secret", "absent")).unwrap();
    let absent = Scene::load(&inner.join("s.json")).unwrap_err().to_string();
    assert_eq!(e.replace("secret", "absent"), absent);
}

/// A scene file may import a glTF that has no camera (a model, as most
/// asset files are) when it gives the camera itself; without one it is
/// refused, naming the missing view.
#[test]
fn an_import_without_a_camera_takes_the_scene_files_own() {
    let dir = scratch("import-no-camera");
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/models");
    std::fs::copy(models.join("fern_02.glb"), dir.join("fern.glb")).unwrap();
    let with = dir.join("with.json");
    std::fs::write(
        &with,
        r#"{ "import": "fern.glb", "lighting": "local",
             "camera": { "position": [0, 0.4, 2.5], "look_at": [0, 0.3, 0] } }"#,
    )
    .unwrap();
    let png = dir.join("with.png");
    let size = ["--width", "32", "--height", "16", "--local-workers", "0"];
    let mut args = vec!["render", with.to_str().unwrap(), "-o", png.to_str().unwrap()];
    args.extend(size);
    ok(&args);
    let stats: Value =
        serde_json::from_slice(&std::fs::read(dir.join("with.stats.json")).unwrap()).unwrap();
    assert!(stats["instances"].as_u64().unwrap() >= 1, "{stats}");

    let without = dir.join("without.json");
    std::fs::write(&without, r#"{ "import": "fern.glb", "lighting": "local" }"#).unwrap();
    let png = dir.join("without.png");
    let mut args = vec!["render", without.to_str().unwrap(), "-o", png.to_str().unwrap()];
    args.extend(size);
    let said = fails(&args);
    assert!(said.contains("no perspective camera"), "{said}");
}
