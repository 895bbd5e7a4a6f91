//! An instanced glTF scene as a Sylva scene file: each mesh a model read
//! from the glTF file by name, each placement (a node, or one transform of
//! its `EXT_mesh_gpu_instancing`) an instance, the first camera the view,
//! the first directional light the sun. What [`super::gltf`] writes comes
//! back as it went; Blender's exports work too.

use crate::error::chain;
use crate::{Error, FileAccess, Result, SceneFile};
use glam::{Mat4, Quat, Vec3, Vec4};
use serde_json::{Map, Value, json};
use std::path::Path;

/// Deepest node hierarchy followed (glTF forbids cycles).
const MAX_DEPTH: usize = 64;
/// Most placements read: more is not a scene this renderer takes.
const MAX_PLACEMENTS: usize = 1 << 22;

/// What a glTF scene's nodes hold, gathered in world space.
#[derive(Default)]
struct Gathered {
    /// Mesh index → placements.
    placements: Vec<Vec<Mat4>>,
    camera: Option<(Mat4, f32)>,
    sun: Option<(Mat4, [f32; 3], f32)>,
    ground: Option<[f32; 3]>,
}

/// The scene file for the glTF scene at `gltf_path`, which the scene file
/// names relative to `scene_dir`.
pub fn import_gltf(gltf_path: &Path, scene_dir: &Path) -> Result<SceneFile> {
    let folder = gltf_path.parent().filter(|f| !f.as_os_str().is_empty()).unwrap_or(Path::new("."));
    import_gltf_with(
        gltf_path,
        scene_dir,
        &FileAccess::Anywhere(folder.to_path_buf()),
        MAX_PLACEMENTS,
        false,
    )
}

/// [`import_gltf`], reading the glTF's buffers only where `access` allows
/// and at most `max_placements` placements (a scene file's `import`, which
/// may come from a hostile bundle). `camera_given`: the scene file that
/// imports it gives its own camera, so a glTF without one is no error.
pub fn import_gltf_with(
    gltf_path: &Path,
    scene_dir: &Path,
    access: &FileAccess,
    max_placements: usize,
    camera_given: bool,
) -> Result<SceneFile> {
    let max = max_placements.min(MAX_PLACEMENTS);
    // The glTF crates assert on some malformed accessors instead of
    // returning errors; a hostile file must cost its scene, not the process.
    std::panic::catch_unwind(|| import_unguarded(gltf_path, scene_dir, access, max, camera_given))
        .unwrap_or_else(|_| {
            Err(Error::gltf(gltf_path.display(), "malformed glTF: the importer failed on it"))
        })
}

fn import_unguarded(
    gltf_path: &Path,
    scene_dir: &Path,
    access: &FileAccess,
    max_placements: usize,
    camera_given: bool,
) -> Result<SceneFile> {
    let shown = crate::model::shown_name(gltf_path, access);
    let bytes = std::fs::read(gltf_path).map_err(|e| Error::file(&shown, "cannot read glTF", e))?;
    let gltf::Gltf { document: doc, blob } = gltf::Gltf::from_slice(&bytes)
        .map_err(|e| Error::gltf(&shown, format!("cannot read glTF: {}", chain(&e))))?;
    drop(bytes);
    let folder = gltf_path.parent().unwrap_or(Path::new("."));
    // Every file the document names must be one we may read, before any is.
    crate::model::files_named(&doc, access, folder, &shown)?;
    crate::model::check_accessors(&doc).map_err(|e| e.within(&shown))?;
    let buffers = gltf::import_buffers(&doc, Some(folder), blob)
        .map_err(|e| Error::gltf(&shown, format!("cannot read its buffers: {}", chain(&e))))?;
    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| Error::gltf(&shown, "no scene"))?;
    let mut g = Gathered { placements: vec![Vec::new(); doc.meshes().len()], ..Default::default() };
    let mut stack: Vec<(gltf::Node, Mat4, usize)> =
        scene.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect();
    let mut count = 0usize;
    // glTF's nodes form trees: a node reached twice (a child of two
    // parents, or listed twice) would multiply the walk without end.
    let mut seen = vec![false; doc.nodes().len()];
    while let Some((node, parent, depth)) = stack.pop() {
        if depth >= MAX_DEPTH {
            return Err(Error::gltf(
                &shown,
                format!("the node hierarchy is deeper than {MAX_DEPTH}"),
            ));
        }
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(Error::gltf(
                &shown,
                format!("node {} is reached twice (glTF nodes form trees)", node.index()),
            ));
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        let sylva_role =
            node.extras().as_ref().and_then(|r| serde_json::from_str::<Value>(r.get()).ok());
        if let Some(mesh) = node.mesh() {
            if sylva_role.as_ref().and_then(|v| v.get("sylva")).and_then(Value::as_str)
                == Some("ground")
            {
                g.ground = ground_colour(&mesh);
            } else {
                let places = match node.extension_value("EXT_mesh_gpu_instancing") {
                    Some(ext) => {
                        instancing(&doc, &buffers, ext, max_placements - count).map_err(|e| {
                            e.within(format!(
                                "{shown}: node {}: EXT_mesh_gpu_instancing",
                                node.index()
                            ))
                        })?
                    }
                    None => vec![Mat4::IDENTITY],
                };
                count += places.len();
                if count > max_placements {
                    return Err(Error::limit(
                        &shown,
                        format!("more than {max_placements} placements"),
                    ));
                }
                g.placements[mesh.index()].extend(places.into_iter().map(|p| world * p));
            }
        }
        if let Some(cam) = node.camera()
            && g.camera.is_none()
            && let gltf::camera::Projection::Perspective(p) = cam.projection()
        {
            g.camera = Some((world, p.yfov()));
        }
        if g.sun.is_none()
            && let Some(light) = node.light()
            && matches!(light.kind(), gltf::khr_lights_punctual::Kind::Directional)
        {
            g.sun = Some((world, light.color(), light.intensity()));
        }
        stack.extend(node.children().map(|c| (c, world, depth + 1)));
    }
    let extras = scene
        .extras()
        .as_ref()
        .and_then(|r| serde_json::from_str::<Value>(r.get()).ok())
        .and_then(|v| v.get("sylva").cloned());

    // Models: one per mesh that is placed, named after the mesh.
    let file = pathdiff(gltf_path, scene_dir);
    let (mut models, mut instances) = (Map::new(), Vec::new());
    for mesh in doc.meshes() {
        let places = &g.placements[mesh.index()];
        if places.is_empty() {
            continue;
        }
        let Some(name) = mesh.name().filter(|n| !n.is_empty()) else {
            return Err(Error::gltf(
                &shown,
                format!(
                    "mesh {} has no name; a scene file names meshes to read them",
                    mesh.index()
                ),
            ));
        };
        if doc.meshes().filter(|m| m.name() == Some(name)).count() > 1 {
            return Err(Error::gltf(
                &shown,
                format!("two meshes are named {name:?}; a scene file names meshes to read them"),
            ));
        }
        models.insert(name.to_string(), json!({ "gltf": file, "mesh": name }));
        for p in places {
            instances.push(json!({ "model": name, "matrix": p.to_cols_array() }));
        }
    }
    if models.is_empty() {
        return Err(Error::gltf(&shown, "no mesh is placed in the scene"));
    }

    let camera = match g.camera {
        Some((w, yfov)) => {
            let eye = w.transform_point3(Vec3::ZERO);
            let forward = w.transform_vector3(Vec3::NEG_Z).normalize();
            let up = w.transform_vector3(Vec3::Y).normalize();
            json!({ "position": eye.to_array(), "look_at": (eye + 10.0 * forward).to_array(), "up": up.to_array(), "fov_y_deg": yfov.to_degrees() })
        }
        // The importing scene file's camera replaces this one, unseen.
        None if camera_given => {
            json!({ "position": [0.0, 0.0, 0.0], "look_at": [0.0, 0.0, -1.0], "up": [0.0, 1.0, 0.0], "fov_y_deg": 45.0 })
        }
        None => {
            return Err(Error::gltf(&shown, "no perspective camera; a scene needs a view"));
        }
    };
    let sun_extras = extras.as_ref().and_then(|e| e.get("sun"));
    let sun = match g.sun {
        Some((w, _, intensity)) => {
            let towards = w.transform_vector3(Vec3::Z).normalize();
            let mut s = json!({ "direction": towards.to_array() });
            // Sylva's own strength and colour temperature, where it wrote them.
            match sun_extras {
                Some(e) => {
                    s["temperature_k"] = e.get("temperature_k").cloned().unwrap_or(json!(6500.0));
                    s["intensity"] = e.get("intensity").cloned().unwrap_or(json!(intensity));
                }
                None => s["intensity"] = json!(intensity),
            }
            s
        }
        None => json!({ "elevation_deg": 45.0, "azimuth_deg": 135.0 }),
    };
    let mut out = json!({ "models": models, "instances": instances, "camera": camera, "sun": sun });
    if let Some(sky) = extras.as_ref().and_then(|e| e.get("sky")) {
        out["sky"] = sky.clone();
    }
    let ground = extras
        .as_ref()
        .and_then(|e| e.get("ground"))
        .filter(|v| !v.is_null())
        .cloned()
        .or(g.ground.map(|c| json!(c)));
    if let Some(c) = ground {
        out["ground"] = json!({ "color": c });
    }
    if let Some(l) = extras.as_ref().and_then(|e| e.get("lighting")) {
        out["lighting"] = l.clone();
    }
    if let Some(o) = extras.as_ref().and_then(|e| e.get("leaf_optics")) {
        out["leaf_optics"] = o.clone();
    }
    serde_path_to_error::deserialize(out).map_err(|e| {
        // The path names keys the file wrote.
        let field = crate::sandbox::escaped(&e.path().to_string());
        // Fields Sylva's own export records in the scene's extras: a
        // Blender custom property of the same name lands there too.
        let from_extras = ["sky", "ground", "lighting", "leaf_optics", "sun"]
            .iter()
            .any(|k| field == *k || field.starts_with(&format!("{k}.")));
        let whence = if from_extras { " (from the glTF scene's extras \"sylva\")" } else { "" };
        Error::gltf(
            &shown,
            format!(
                "the imported scene is not a valid scene file: {field}{whence}: {}",
                e.into_inner()
            ),
        )
    })
}

/// Placements of one `EXT_mesh_gpu_instancing` extension: translation,
/// rotation and scale accessors (float, each optional, equal counts).
fn instancing(
    doc: &gltf::Document,
    buffers: &[gltf::buffer::Data],
    ext: &Value,
    max_placements: usize,
) -> Result<Vec<Mat4>> {
    let attrs = ext
        .get("attributes")
        .and_then(Value::as_object)
        .ok_or_else(|| Error::Invalid("no attributes".into()))?;
    let read = |name: &str, n: usize| -> Result<Option<Vec<f32>>> {
        let Some(i) = attrs.get(name).and_then(Value::as_u64) else { return Ok(None) };
        let a = doc
            .accessors()
            .nth(i as usize)
            .ok_or_else(|| Error::Invalid(format!("{name}: no accessor {i}")))?;
        let dims = match n {
            3 => gltf::accessor::Dimensions::Vec3,
            _ => gltf::accessor::Dimensions::Vec4,
        };
        if a.data_type() != gltf::accessor::DataType::F32
            || a.dimensions() != dims
            || a.sparse().is_some()
        {
            return Err(Error::Invalid(format!(
                "{name}: accessor {i} must be dense float {dims:?}"
            )));
        }
        let view = a
            .view()
            .ok_or_else(|| Error::Invalid(format!("{name}: accessor {i} has no buffer view")))?;
        let data = buffers
            .get(view.buffer().index())
            .ok_or_else(|| Error::Invalid(format!("{name}: no buffer")))?;
        let stride = view.stride().unwrap_or(4 * n);
        let start = view.offset() + a.offset();
        // The count is the file's word: checked against the bytes there
        // before anything is reserved for it.
        let last = a
            .count()
            .checked_sub(1)
            .map(|k| k.checked_mul(stride).and_then(|o| o.checked_add(start + 4 * n)));
        if a.count() > max_placements
            || last.is_some_and(|end| end.is_none_or(|e| e > data.0.len()))
        {
            return Err(Error::Invalid(format!(
                "{name}: accessor {i} holds more placements than its buffer or the scene's cap"
            )));
        }
        let mut out = Vec::with_capacity(a.count() * n);
        for k in 0..a.count() {
            let at = start + k * stride;
            let bytes = data.0.get(at..at + 4 * n).ok_or_else(|| {
                Error::Invalid(format!("{name}: accessor {i} runs past its buffer"))
            })?;
            out.extend(bytes.as_chunks::<4>().0.iter().map(|b| f32::from_le_bytes(*b)));
        }
        if !out.iter().all(|v| v.is_finite()) {
            return Err(Error::Invalid(format!("{name}: a value is not finite")));
        }
        Ok(Some(out))
    };
    let (t, r, s) = (read("TRANSLATION", 3)?, read("ROTATION", 4)?, read("SCALE", 3)?);
    let n = [
        t.as_ref().map(|v| v.len() / 3),
        r.as_ref().map(|v| v.len() / 4),
        s.as_ref().map(|v| v.len() / 3),
    ];
    let count = n
        .iter()
        .flatten()
        .copied()
        .max()
        .ok_or_else(|| Error::Invalid("no TRANSLATION, ROTATION or SCALE".into()))?;
    if n.iter().flatten().any(|&c| c != count) {
        return Err(Error::Invalid(format!("the attributes' counts differ: {n:?}")));
    }
    Ok((0..count)
        .map(|k| {
            let tt = t.as_ref().map_or(Vec3::ZERO, |v| Vec3::from_slice(&v[3 * k..]));
            let rr = r.as_ref().map_or(Quat::IDENTITY, |v| {
                Quat::from_vec4(Vec4::from_slice(&v[4 * k..])).normalize()
            });
            let ss = s.as_ref().map_or(Vec3::ONE, |v| Vec3::from_slice(&v[3 * k..]));
            Mat4::from_scale_rotation_translation(ss, rr, tt)
        })
        .collect())
}

/// The base colour of a mesh's first material (the ground's albedo).
fn ground_colour(mesh: &gltf::Mesh) -> Option<[f32; 3]> {
    let c = mesh.primitives().next()?.material().pbr_metallic_roughness().base_color_factor();
    Some([c[0], c[1], c[2]])
}

/// `path` as the scene file in `dir` names it: relative where it lies
/// inside `dir`, else absolute (a scene bundle takes only files inside).
fn pathdiff(path: &Path, dir: &Path) -> String {
    let abs = |p: &Path| p.canonicalize().unwrap_or_else(|_| p.to_path_buf());
    let (p, d) = (abs(path), abs(dir));
    p.strip_prefix(&d).map(Path::to_path_buf).unwrap_or(p).to_string_lossy().into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;
    use base64::Engine;

    /// A `.gltf` (buffer inline) of one triangle mesh "t" on node 0 with
    /// `placements` instancing translations whose accessor claims `count`,
    /// a camera, and `extra` nodes; written into a fresh folder.
    fn write(name: &str, placements: usize, count: u64, extra: Value) -> std::path::PathBuf {
        let mut bytes: Vec<u8> =
            [0f32, 0., 0., 1., 0., 0., 0., 1., 0.].iter().flat_map(|v| v.to_le_bytes()).collect();
        for k in 0..placements {
            bytes.extend([k as f32, 0., 0.].iter().flat_map(|v| v.to_le_bytes()));
        }
        let data = base64::engine::general_purpose::STANDARD.encode(&bytes);
        let mut nodes = vec![
            json!({ "mesh": 0, "extensions": { "EXT_mesh_gpu_instancing": { "attributes": { "TRANSLATION": 1 } } } }),
            json!({ "camera": 0, "translation": [0, 0, 5] }),
        ];
        nodes.extend(extra.as_array().cloned().unwrap_or_default());
        let roots: Vec<usize> = (0..2).collect();
        let gltf = json!({
            "asset": { "version": "2.0" },
            "extensionsUsed": ["EXT_mesh_gpu_instancing"],
            "scene": 0, "scenes": [ { "nodes": roots.iter().chain([2usize].iter().filter(|_| nodes.len() > 2)).collect::<Vec<_>>() } ],
            "nodes": nodes,
            "cameras": [ { "type": "perspective", "perspective": { "yfov": 0.8, "znear": 0.1 } } ],
            "meshes": [ { "name": "t", "primitives": [ { "attributes": { "POSITION": 0 } } ] } ],
            "buffers": [ { "byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{data}") } ],
            "bufferViews": [
                { "buffer": 0, "byteOffset": 0, "byteLength": 36 },
                { "buffer": 0, "byteOffset": 36, "byteLength": bytes.len() - 36 }
            ],
            "accessors": [
                { "bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0] },
                { "bufferView": 1, "componentType": 5126, "count": count, "type": "VEC3" }
            ]
        });
        let dir = std::env::temp_dir().join(format!("sylva-import-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("s.gltf");
        std::fs::write(&p, gltf.to_string()).unwrap();
        p
    }

    fn import(p: &Path, max: usize) -> Result<SceneFile> {
        let dir = p.parent().unwrap();
        import_gltf_with(p, dir, &FileAccess::Inside(dir.to_path_buf()), max, false)
    }

    #[test]
    fn hostile_scenes_are_refused_before_they_cost_time_or_memory() {
        let ok = write("ok", 5, 5, json!([]));
        assert_eq!(import(&ok, 100).unwrap().instances.len(), 5);
        // More placements than the scene may have: refused, not built.
        let e = format!("{:#}", import(&ok, 4).unwrap_err());
        assert!(e.contains("the scene's cap"), "{e}");
        // An accessor that claims more than its bytes: refused before any
        // memory is reserved for it.
        let liar = write("liar", 5, 1 << 40, json!([]));
        let e = format!("{:#}", import(&liar, usize::MAX).unwrap_err());
        assert!(e.contains("more placements than its buffer"), "{e}");
        // Nodes listing a child twice would multiply the walk: 2^60 visits.
        let chain: Vec<Value> =
            (0..60).map(|i| json!({ "children": [3 + i, 3 + i] })).chain([json!({})]).collect();
        let fork = write("fork", 1, 1, Value::Array(chain));
        let e = import(&fork, 100).unwrap_err().to_string();
        assert!(e.contains("reached twice"), "{e}");
    }
}
