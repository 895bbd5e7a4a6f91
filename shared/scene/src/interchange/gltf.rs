//! A scene as one binary glTF 2.0 file (`.glb`) that other tools open:
//! one mesh per model with `EXT_mesh_gpu_instancing` for its placements,
//! alpha-masked leaf textures, the camera, the sun as a `KHR_lights_punctual`
//! directional light, the ground as a large quad. What glTF has no place
//! for (the sky's colours, the sun's strength in Sylva's units, the
//! leaves' transmittance as multipliers of their colour: the one leaf BSDF,
//! docs/lighting.md) rides in the scene's `extras.sylva`, which
//! [`super::import`] reads back and `scripts/cycles-check.py` builds from.

use crate::error::chain;
use crate::model::{Model, Surface, classify_material};
use crate::{Error, Result, Scene};
use glam::{Affine3A, Mat4, Quat, Vec3};
use serde_json::{Value, json};

/// What an export wrote.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct GltfSummary {
    /// Meshes (one per model, plus the ground).
    pub meshes: usize,
    /// Placements written as instancing transforms.
    pub instances: usize,
    /// Placements whose matrix is not translate–rotate–scale, written as
    /// plain nodes with a matrix.
    pub matrix_nodes: usize,
    /// Triangles in the meshes (each model once).
    pub triangles: u64,
    /// Materials and textures.
    pub materials: usize,
    /// Textures (PNG, in the file).
    pub textures: usize,
    /// Bytes of the file.
    pub bytes: usize,
}

/// The binary chunk being built, and the views and accessors into it.
#[derive(Default)]
struct Bin {
    data: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

/// glTF buffer-view targets.
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
/// glTF component types.
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

impl Bin {
    /// Appends `bytes` as a buffer view (4-byte aligned); its index.
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.data.len().is_multiple_of(4) {
            self.data.push(0);
        }
        let mut v =
            json!({ "buffer": 0, "byteOffset": self.data.len(), "byteLength": bytes.len() });
        if let Some(t) = target {
            v["target"] = t.into();
        }
        self.data.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }

    /// A float accessor of `n`-component elements (`ty`: VEC2, VEC3, VEC4),
    /// with its bounds where glTF asks for them (positions).
    fn floats(
        &mut self,
        values: &[f32],
        n: usize,
        ty: &str,
        bounds: bool,
        target: Option<u32>,
    ) -> usize {
        let view = self.view(bytemuck::cast_slice(values), target);
        let mut a = json!({ "bufferView": view, "componentType": FLOAT, "count": values.len() / n, "type": ty });
        if bounds {
            let (mut lo, mut hi) = (vec![f32::INFINITY; n], vec![f32::NEG_INFINITY; n]);
            for e in values.chunks_exact(n) {
                for c in 0..n {
                    lo[c] = lo[c].min(e[c]);
                    hi[c] = hi[c].max(e[c]);
                }
            }
            (a["min"], a["max"]) = (lo.into(), hi.into());
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    /// A vertex-index accessor.
    fn indices(&mut self, values: &[u32]) -> usize {
        let view = self.view(bytemuck::cast_slice(values), Some(ELEMENT_ARRAY_BUFFER));
        self.accessors.push(json!({ "bufferView": view, "componentType": UNSIGNED_INT, "count": values.len(), "type": "SCALAR" }));
        self.accessors.len() - 1
    }
}

/// A material's name that Sylva's loader classes as the same surface
/// (it reads wood from words in the name).
fn surface_name(name: &str, surface: Surface) -> String {
    let name = if name.is_empty() { "material" } else { name };
    match (surface, classify_material(Some(name))) {
        (Surface::Wood, Surface::Leaf) => format!("{name} (wood)"),
        (Surface::Leaf, Surface::Wood) => "leaf".to_string(),
        _ => name.to_string(),
    }
}

/// `to_world` as translation, rotation and scale, if it is one (no shear,
/// no mirror) within float rounding.
fn trs(m: &Affine3A) -> Option<(Vec3, Quat, Vec3)> {
    if m.matrix3.determinant() <= 0.0 {
        return None;
    }
    let (s, r, t) = m.to_scale_rotation_translation();
    let back = Affine3A::from_scale_rotation_translation(s, r, t);
    let err = (back.matrix3 - m.matrix3).to_cols_array().iter().fold(0.0f32, |e, v| e.max(v.abs()));
    (err <= 1e-4 * s.max_element().max(1.0)).then_some((t, r, s))
}

/// The scene as a binary glTF file, and what went in.
pub fn export_glb(scene: &Scene) -> Result<(Vec<u8>, GltfSummary)> {
    let mut p = Parts::default();
    for (mi, m) in scene.models.iter().enumerate() {
        add_model(&mut p, scene, mi, m)?;
    }
    p.summary.materials = p.materials.len();
    p.summary.textures = p.textures.len();
    if let Some(g) = &scene.ground {
        add_ground(&mut p, scene, g.color);
    }
    p.summary.meshes = p.meshes.len();
    let (cameras, lights) = add_camera_and_sun(&mut p, scene);
    let Parts { mut bin, meshes, materials, images, textures, nodes, scene_nodes, mut summary } = p;
    let file = &scene.file;
    let extras = json!({ "sylva": {
        "sky": { "zenith": scene.sky.zenith, "horizon": scene.sky.horizon },
        "sun": { "temperature_k": file.sun.temperature_k, "intensity": file.sun.intensity, "radiance": scene.sun.radiance },
        "ground": scene.ground.as_ref().map(|g| g.color),
        "leaf_optics": file.leaf_optics,
        "lighting": file.lighting,
    } });
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": concat!("Sylva ", env!("CARGO_PKG_VERSION")) },
        "extensionsUsed": ["EXT_mesh_gpu_instancing", "KHR_lights_punctual"],
        "extensions": { "KHR_lights_punctual": lights },
        "scene": 0,
        "scenes": [{ "name": "sylva", "nodes": scene_nodes, "extras": extras }],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "cameras": cameras,
        "bufferViews": bin.views,
        "accessors": bin.accessors,
    });
    if !textures.is_empty() {
        // Leaf textures tile; nearest texel, as the tracer reads them.
        doc["samplers"] =
            json!([{ "magFilter": 9728, "minFilter": 9728, "wrapS": 10497, "wrapT": 10497 }]);
        doc["images"] = images.into();
        doc["textures"] = textures.into();
    }
    while !bin.data.len().is_multiple_of(4) {
        bin.data.push(0);
    }
    doc["buffers"] = json!([{ "byteLength": bin.data.len() }]);
    let json = serde_json::to_vec(&doc).map_err(|e| Error::Invalid(chain(&e)))?;
    let bytes = glb(&json, &bin.data)?;
    summary.bytes = bytes.len();
    Ok((bytes, summary))
}

/// The glTF document's arrays as they are filled, and the binary buffer.
#[derive(Default)]
struct Parts {
    bin: Bin,
    meshes: Vec<serde_json::Value>,
    materials: Vec<serde_json::Value>,
    images: Vec<serde_json::Value>,
    textures: Vec<serde_json::Value>,
    nodes: Vec<serde_json::Value>,
    scene_nodes: Vec<usize>,
    summary: GltfSummary,
}

/// A model: its textures as PNG images, its materials, one mesh (a
/// primitive per material) and its placements, as one instancing node
/// (`EXT_mesh_gpu_instancing`) plus a matrix node for each placement
/// that is no translation, rotation and scale.
fn add_model(p: &mut Parts, scene: &Scene, mi: usize, m: &crate::SceneModel) -> Result<()> {
    let model: &Model = &m.model;
    // Textures of this model, as PNG p.images in the file.
    let first_texture = p.textures.len();
    for t in &model.textures {
        let img = image::RgbaImage::from_raw(t.width, t.height, t.rgba.clone())
            .ok_or_else(|| Error::Invalid("a texture's size does not match its texels".into()))?;
        let mut png = std::io::Cursor::new(Vec::new());
        img.write_to(&mut png, image::ImageFormat::Png)?;
        let view = p.bin.view(&png.into_inner(), None);
        p.images.push(json!({ "bufferView": view, "mimeType": "image/png" }));
        p.textures.push(json!({ "source": p.images.len() - 1, "sampler": 0 }));
    }
    let first_material = p.materials.len();
    for mat in &model.materials {
        let mut pbr = json!({ "baseColorFactor": mat.base_color, "metallicFactor": 0.0, "roughnessFactor": 1.0 });
        if let Some(t) = mat.texture {
            pbr["baseColorTexture"] = json!({ "index": first_texture + t as usize });
        }
        // The surface is also said plainly, for tools that build Sylva's
        // leaf BSDF from the export (scripts/cycles-check.py).
        let surface = if mat.surface == Surface::Wood { "wood" } else { "leaf" };
        let mut out = json!({ "name": surface_name(&mat.name, mat.surface), "pbrMetallicRoughness": pbr, "doubleSided": mat.double_sided, "extras": { "sylva": { "surface": surface } } });
        if let Some(c) = mat.alpha_cutoff {
            (out["alphaMode"], out["alphaCutoff"]) = ("MASK".into(), c.into());
        }
        p.materials.push(out);
    }
    // One position and one texture-coordinate accessor, one primitive per material.
    let positions: Vec<f32> = model.positions.iter().flat_map(|p| p.to_array()).collect();
    let pos = p.bin.floats(&positions, 3, "VEC3", true, Some(ARRAY_BUFFER));
    let mut attributes = json!({ "POSITION": pos });
    if model.uvs.len() == model.positions.len() {
        let uvs: Vec<f32> = model.uvs.iter().flat_map(|u| u.to_array()).collect();
        attributes["TEXCOORD_0"] = p.bin.floats(&uvs, 2, "VEC2", false, Some(ARRAY_BUFFER)).into();
    }
    let mut primitives = vec![];
    for k in 0..model.materials.len() {
        let idx: Vec<u32> = model
            .triangles
            .iter()
            .zip(&model.material)
            .filter(|(_, mt)| **mt as usize == k)
            .flat_map(|(t, _)| *t)
            .collect();
        if !idx.is_empty() {
            primitives.push(json!({ "attributes": attributes, "indices": p.bin.indices(&idx), "material": first_material + k, "mode": 4 }));
        }
    }
    if primitives.is_empty() {
        return Err(Error::Invalid(format!("model {} has no triangles", m.name)));
    }
    p.summary.triangles += model.triangle_count() as u64;
    p.meshes.push(json!({ "name": m.name, "primitives": primitives }));
    // Its placements: instancing transforms, plain p.nodes for the rest.
    let (mut t, mut r, mut s) = (vec![], vec![], vec![]);
    for inst in scene.instances.iter().filter(|i| i.model as usize == mi) {
        match trs(&inst.to_world) {
            Some((tt, rr, ss)) => {
                t.extend(tt.to_array());
                r.extend(rr.normalize().to_array());
                s.extend(ss.to_array());
            }
            None => {
                let matrix = Mat4::from(inst.to_world).to_cols_array();
                p.nodes.push(json!({ "name": format!("{} (matrix)", m.name), "mesh": p.meshes.len() - 1, "matrix": matrix }));
                p.scene_nodes.push(p.nodes.len() - 1);
                p.summary.matrix_nodes += 1;
            }
        }
    }
    if !t.is_empty() {
        p.summary.instances += t.len() / 3;
        let attrs = json!({
            "TRANSLATION": p.bin.floats(&t, 3, "VEC3", false, None),
            "ROTATION": p.bin.floats(&r, 4, "VEC4", false, None),
            "SCALE": p.bin.floats(&s, 3, "VEC3", false, None),
        });
        p.nodes.push(json!({ "name": m.name, "mesh": p.meshes.len() - 1, "extensions": { "EXT_mesh_gpu_instancing": { "attributes": attrs } } }));
        p.scene_nodes.push(p.nodes.len() - 1);
    }
    Ok(())
}

/// The ground: a square three times the stand's extent, at least 200 m.
fn add_ground(p: &mut Parts, scene: &Scene, colour: [f32; 3]) {
    // Each model's box once, not once per instance.
    let boxes: Vec<_> = scene.models.iter().map(|m| m.model.bounds()).collect();
    let (lo, hi) =
        scene.instances.iter().filter_map(|i| boxes[i.model as usize].map(|b| (i, b))).fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), (i, (a, b))| {
                let corners = [a, b, Vec3::new(a.x, a.y, b.z), Vec3::new(b.x, a.y, a.z)]
                    .map(|c| i.to_world.transform_point3(c));
                corners.iter().fold((lo, hi), |(lo, hi), &c| (lo.min(c), hi.max(c)))
            },
        );
    let (centre, half) = if lo.is_finite() && hi.is_finite() {
        ((lo + hi) * 0.5, (1.5 * (hi - lo).max_element()).max(100.0))
    } else {
        (Vec3::ZERO, 100.0)
    };
    let (cx, cz) = (centre.x, centre.z);
    let quad = [
        cx - half,
        0.0,
        cz - half,
        cx + half,
        0.0,
        cz - half,
        cx + half,
        0.0,
        cz + half,
        cx - half,
        0.0,
        cz + half,
    ];
    let pos = p.bin.floats(&quad, 3, "VEC3", true, Some(ARRAY_BUFFER));
    let idx = p.bin.indices(&[0, 2, 1, 0, 3, 2]);
    p.materials.push(json!({ "name": "ground", "pbrMetallicRoughness": { "baseColorFactor": [colour[0], colour[1], colour[2], 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0 }, "extras": { "sylva": { "surface": "ground" } } }));
    p.meshes.push(json!({ "name": "ground", "primitives": [{ "attributes": { "POSITION": pos }, "indices": idx, "material": p.materials.len() - 1, "mode": 4 }] }));
    p.nodes.push(
        json!({ "name": "ground", "mesh": p.meshes.len() - 1, "extras": { "sylva": "ground" } }),
    );
    p.scene_nodes.push(p.nodes.len() - 1);
}

/// The camera node and the sun's light node; the cameras array.
fn add_camera_and_sun(p: &mut Parts, scene: &Scene) -> (Vec<serde_json::Value>, serde_json::Value) {
    // The camera: glTF cameras look down their node's −Z with +Y up.
    let c = &scene.camera;
    let view = Mat4::look_to_rh(c.position, c.forward, c.up);
    let (_, rot, pos) = view.inverse().to_scale_rotation_translation();
    let yfov = 2.0 * c.tan_half_fov_y.atan();
    let cameras = vec![
        json!({ "name": "camera", "type": "perspective", "perspective": { "yfov": yfov, "znear": 0.05 } }),
    ];
    p.nodes.push(json!({ "name": "camera", "camera": 0, "translation": pos.to_array(), "rotation": rot.normalize().to_array() }));
    p.scene_nodes.push(p.nodes.len() - 1);

    // The sun: a directional light shines down its node's −Z.
    let sun = scene.sun;
    let strength = sun.radiance.iter().copied().fold(0.0f32, f32::max);
    let colour = if strength > 0.0 { sun.radiance.map(|v| v / strength) } else { [1.0; 3] };
    let lights = json!({ "lights": [{ "name": "sun", "type": "directional", "color": colour, "intensity": strength }] });
    let sun_rot = Quat::from_rotation_arc(Vec3::NEG_Z, -sun.towards.normalize());
    p.nodes.push(json!({ "name": "sun", "rotation": sun_rot.normalize().to_array(), "extensions": { "KHR_lights_punctual": { "light": 0 } } }));
    p.scene_nodes.push(p.nodes.len() - 1);
    (cameras, lights)
}

/// The GLB container: a 12-byte header, the JSON chunk padded with spaces
/// and the binary chunk padded with zeros, each to 4 bytes.
fn glb(json: &[u8], bin: &[u8]) -> Result<Vec<u8>> {
    let pad = |n: usize| n.div_ceil(4) * 4;
    let total = 12 + 8 + pad(json.len()) + 8 + pad(bin.len());
    let total32 = u32::try_from(total).map_err(|e| {
        Error::Invalid(format!("the scene is over the 4 GiB a GLB file can hold: {}", chain(&e)))
    })?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(pad(json.len()) as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(out.len() + pad(json.len()) - json.len(), b' ');
    out.extend_from_slice(&(pad(bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    out.resize(total, 0);
    Ok(out)
}
