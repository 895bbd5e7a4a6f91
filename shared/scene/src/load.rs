//! Scenes: models, their instances, the camera, the sun, sky and ground,
//! and the lighting settings, loaded from a JSON scene file
//! ([`SceneFile`]) and checked field by field.

pub use crate::format::{
    CameraSpec, CloudSpec, ForestGridSpec, ForestGridUse, GroundSpec, InstanceSpec, LbModel,
    LbSpec, LightingMode, ModelSpec, SceneFile, SkySpec, SunSpec,
};

use crate::camera::Camera;
pub use crate::caps::SceneLimits;
use crate::color::black_body_rgb;
pub use crate::sandbox::FileAccess;

use crate::model::{GltfBudget, Model, load_gltf_with};
use crate::trees;
use glam::{Affine3A, Mat4, Vec3};
use std::path::Path;
use std::sync::Arc;

/// A scene file that cannot be used: the file, the field and what is wrong.
#[derive(Debug, thiserror::Error)]
pub struct SceneError {
    /// The scene file.
    pub file: String,
    /// Path of the field (`instances[3].scale`); empty where the error is
    /// the whole file's (it cannot be read, or is not JSON at its start).
    pub field: String,
    /// What is wrong.
    pub message: String,
}

impl std::fmt::Display for SceneError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.field.as_str() {
            "" => write!(f, "{}: {}", self.file, self.message),
            field => write!(f, "{}: {field}: {}", self.file, self.message),
        }
    }
}

/// A model as the scene holds it.
#[derive(Clone, Debug)]
pub struct SceneModel {
    /// Its name in the scene file.
    pub name: String,
    /// Geometry and materials, shared by all its instances.
    pub model: Arc<Model>,
    /// LB settings.
    pub lb: LbSpec,
}

/// One placement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    /// Index into [`Scene::models`].
    pub model: u32,
    /// Model space to world space.
    pub to_world: Affine3A,
}

/// The sun as the renderer uses it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunLight {
    /// Unit vector from the scene towards the sun.
    pub towards: Vec3,
    /// Linear RGB irradiance: black-body colour × intensity.
    pub radiance: [f32; 3],
}

/// A loaded, checked scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Unique models.
    pub models: Vec<SceneModel>,
    /// Placements.
    pub instances: Vec<Instance>,
    /// The view.
    pub camera: Camera,
    /// The sun.
    pub sun: SunLight,
    /// The sky.
    pub sky: SkySpec,
    /// Ground plane at y = 0.
    pub ground: Option<GroundSpec>,
    /// Lighting method.
    pub lighting: LightingMode,
    /// Clouds.
    pub clouds: Vec<CloudSpec>,
    /// The file as parsed (for bundles and reports).
    pub file: SceneFile,
}

impl Scene {
    /// Bytes its models (each once, however many instances share it) and
    /// placements hold in memory.
    pub fn bytes(&self) -> u64 {
        self.models.iter().map(|m| m.model.bytes()).sum::<u64>()
            + (self.instances.len() * std::mem::size_of::<Instance>()) as u64
    }

    /// The scene with a frame's sun in place of its own (the camera is the
    /// renderer's per frame); models are shared, not copied.
    pub fn with_view(&self, view: &crate::sequence::View) -> Scene {
        let mut s = self.clone();
        if let Some(t) = view.sun() {
            s.sun.towards = t;
        }
        s
    }

    /// Reads, parses and checks a scene file; glTF paths are relative to it
    /// and must lie inside its folder; default limits.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let base = folder_of(path);
        Scene::load_with(path, &FileAccess::Inside(base), &SceneLimits::default())
    }

    /// Reads, parses and checks a scene file, reading its models as
    /// `access` allows, within `limits`.
    pub fn load_with(
        path: &Path,
        access: &FileAccess,
        limits: &SceneLimits,
    ) -> Result<Scene, SceneError> {
        let label = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| SceneError {
            file: label.clone(),
            field: String::new(),
            message: format!("cannot read: {e}"),
        })?;
        let file = parse_with(&text, &label, access, limits)?;
        Scene::build_with(file, access, &label, limits)
    }

    /// Checks a parsed scene and builds its models. `label` names the file
    /// in errors; glTF paths are relative to `base` and must lie inside it;
    /// default limits.
    pub fn build(file: SceneFile, base: &Path, label: &str) -> Result<Scene, SceneError> {
        Scene::build_with(
            file,
            &FileAccess::Inside(base.to_path_buf()),
            label,
            &SceneLimits::default(),
        )
    }

    /// Checks a parsed scene completely — every field, and its size against
    /// `limits` from what the file declares — and only then builds its
    /// models, reading files as `access` allows.
    pub fn build_with(
        file: SceneFile,
        access: &FileAccess,
        label: &str,
        limits: &SceneLimits,
    ) -> Result<Scene, SceneError> {
        let Checked { instances, camera, sun, declared_triangles } = check(&file, label, limits)?;
        let err =
            |field: String, message: String| SceneError { file: label.to_string(), field, message };
        let mut budget = GltfBudget {
            triangles: limits.triangles - declared_triangles,
            texture_pixels: limits.texture_pixels,
        };
        let mut models = Vec::with_capacity(file.models.len());
        for (name, spec) in &file.models {
            let field = format!("models.{name}");
            let model = match (&spec.gltf, &spec.tree) {
                (Some(p), None) => {
                    let full = access
                        .resolve(access.base(), p)
                        .map_err(|m| err(format!("{field}.gltf"), m.to_string()))?;
                    load_gltf_with(&full, access, &mut budget, spec.mesh.as_deref())
                        .map_err(|e| err(format!("{field}.gltf"), format!("{e:#}")))?
                }
                (None, Some(t)) => {
                    trees::generate(t).map_err(|e| err(format!("{field}.tree"), e.to_string()))?
                }
                _ => unreachable!("checked above"),
            };
            models.push(SceneModel {
                name: name.clone(),
                model: Arc::new(model),
                lb: spec.lb.unwrap_or(file.lb),
            });
        }
        Ok(Scene {
            models,
            instances,
            camera,
            sun,
            sky: file.sky.clone(),
            ground: file.ground.clone(),
            lighting: file.lighting,
            clouds: file.clouds.clone(),
            file,
        })
    }

    /// Checks a parsed scene completely without reading or generating any
    /// model: every field, and its size against `limits` from what the file
    /// declares (a glTF model's own size is checked when it is read).
    pub fn check(file: &SceneFile, label: &str, limits: &SceneLimits) -> Result<(), SceneError> {
        check(file, label, limits).map(|_| ())
    }

    /// Triangles of the unique models.
    pub fn unique_triangles(&self) -> u64 {
        self.models.iter().map(|m| m.model.triangle_count() as u64).sum()
    }

    /// Triangles of all instances.
    pub fn instanced_triangles(&self) -> u64 {
        self.instances
            .iter()
            .map(|i| self.models[i.model as usize].model.triangle_count() as u64)
            .sum()
    }
}

/// What the cheap checks of a scene produce.
struct Checked {
    instances: Vec<Instance>,
    camera: Camera,
    sun: SunLight,
    declared_triangles: u64,
}

fn check(file: &SceneFile, label: &str, limits: &SceneLimits) -> Result<Checked, SceneError> {
    let err =
        |field: String, message: String| SceneError { file: label.to_string(), field, message };
    if file.models.is_empty() {
        return Err(err("models".into(), "at least one model is needed".into()));
    }
    if file.models.len() > limits.models {
        return Err(err(
            "models".into(),
            format!("{} models: at most {} per scene", file.models.len(), limits.models),
        ));
    }
    if file.instances.len() > limits.instances {
        return Err(err(
            "instances".into(),
            format!("{} instances: at most {} per scene", file.instances.len(), limits.instances),
        ));
    }
    let mut lb_cells = 0u64;
    for (name, spec) in &file.models {
        let field = format!("models.{name}");
        let lb = spec.lb.unwrap_or(file.lb);
        check_lb(&lb).map_err(|m| err(format!("{field}.lb"), m.to_string()))?;
        lb_cells += (lb.grid as u64).pow(3);
        match (&spec.gltf, &spec.tree) {
            (Some(_), None) | (None, Some(_)) => {}
            _ => return Err(err(field, "give exactly one of \"gltf\" and \"tree\"".into())),
        }
        if spec.mesh.is_some() && spec.gltf.is_none() {
            return Err(err(
                format!("{field}.mesh"),
                "names a mesh of a \"gltf\" file; this model has none".into(),
            ));
        }
        if spec.mesh.as_ref().is_some_and(|m| m.is_empty() || m.len() > 256) {
            return Err(err(format!("{field}.mesh"), "a mesh name of 1 to 256 bytes".into()));
        }
    }
    check_lb(&file.lb).map_err(|m| err("lb".into(), m.to_string()))?;
    let fg = &file.forest_grid;
    if !(4..=256).contains(&fg.grid) {
        return Err(err("forest_grid.grid".into(), format!("{}: valid range [4, 256]", fg.grid)));
    }
    if !(fg.threshold.is_finite() && fg.threshold >= 0.0) {
        return Err(err(
            "forest_grid.threshold".into(),
            format!("{}: must be a finite number ≥ 0", fg.threshold),
        ));
    }
    lb_cells += (fg.grid as u64).pow(3);
    let names: Vec<&String> = file.models.keys().collect();
    let mut instances = Vec::with_capacity(file.instances.len());
    for (i, inst) in file.instances.iter().enumerate() {
        let field = format!("instances[{i}]");
        let model = names.iter().position(|m| **m == inst.model).ok_or_else(|| {
            err(
                format!("{field}.model"),
                format!("unknown model {:?}", crate::sandbox::clip(&inst.model)),
            )
        })?;
        let to_world = instance_transform(inst).map_err(|(f, m)| err(format!("{field}.{f}"), m))?;
        instances.push(Instance { model: model as u32, to_world });
    }
    if instances.is_empty() {
        return Err(err("instances".into(), "at least one instance is needed".into()));
    }
    let c = &file.camera;
    bounded3(&c.position).map_err(|m| err("camera.position".into(), m.to_string()))?;
    bounded3(&c.look_at).map_err(|m| err("camera.look_at".into(), m.to_string()))?;
    bounded3(&c.up).map_err(|m| err("camera.up".into(), m.to_string()))?;
    let camera = Camera::look_at(c.position.into(), c.look_at.into(), c.up.into(), c.fov_y_deg)
        .map_err(|e| err("camera".into(), e.to_string()))?;
    let sun = sun_light(&file.sun).map_err(|(f, m)| err(format!("sun.{f}"), m))?;
    if let Some(s) = &file.sequence {
        s.views().map_err(|m| err("sequence".into(), m.to_string()))?;
    }
    for (name, v) in [("zenith", file.sky.zenith), ("horizon", file.sky.horizon)] {
        colour(&v).map_err(|m| err(format!("sky.{name}"), m.to_string()))?;
    }
    file.leaf_optics.validate().map_err(|m| err("leaf_optics".into(), m.to_string()))?;
    if let Some(g) = &file.ground {
        colour(&g.color).map_err(|m| err("ground.color".into(), m.to_string()))?;
        // An albedo: a ground that sent back more than it receives would
        // make the LB's reflecting floor a source that grows every step.
        if g.color.iter().any(|&x| x > 1.0) {
            return Err(err(
                "ground.color".into(),
                format!("{:?}: an albedo, each component at most 1", g.color),
            ));
        }
    }
    for (i, c) in file.clouds.iter().enumerate() {
        finite3(&c.center).map_err(|m| err(format!("clouds[{i}].center"), m.to_string()))?;
        if !(c.size.is_finite() && c.size > 0.0) {
            return Err(err(
                format!("clouds[{i}].size"),
                format!("{} must be a finite number > 0", c.size),
            ));
        }
        if !(4..=512).contains(&c.grid) {
            return Err(err(
                format!("clouds[{i}].grid"),
                format!("{}: valid range [4, 512]", c.grid),
            ));
        }
        lb_cells += (c.grid as u64).pow(3);
    }
    if lb_cells > limits.lb_cells {
        return Err(err(
            "lb".into(),
            format!(
                "the LB grids of models, clouds and forest come to {lb_cells} nodes: at most {} per scene",
                limits.lb_cells
            ),
        ));
    }
    // Generated trees declare their size: refuse before generating any.
    let declared: u64 = file
        .models
        .values()
        .filter_map(|m| m.tree.as_ref())
        .map(|t| u64::from(t.triangles.unwrap_or(t.species.shape().paper_triangles)))
        .sum();
    if declared > limits.triangles {
        return Err(err(
            "models".into(),
            format!(
                "the trees come to {declared} triangles: at most {} per scene",
                limits.triangles
            ),
        ));
    }
    Ok(Checked { instances, camera, sun, declared_triangles: declared })
}

/// The folder a file lies in: `.` for a bare file name.
pub fn folder_of(path: &Path) -> std::path::PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    }
}

/// Parses a scene file, reading the glTF scene its `import` names, if any
/// (docs/scene-format.md, "Importing a glTF scene"): that scene as
/// `sylva scene import` reads it, with every other field the file gives
/// in place of the import's. Files are read as `access` allows, and at
/// most `limits.instances` placements.
pub fn parse_with(
    text: &str,
    label: &str,
    access: &FileAccess,
    limits: &SceneLimits,
) -> Result<SceneFile, SceneError> {
    match serde_json::from_str::<serde_json::Value>(text) {
        Ok(v) => expand(v, label, access, limits),
        // Syntax errors, with their place, as `parse` reports them.
        Err(_) => parse(text, label),
    }
}

/// A scene file's JSON as a scene, its `import` read (see [`parse_with`])
/// with at most `limits.instances` placements.
pub fn expand(
    value: serde_json::Value,
    label: &str,
    access: &FileAccess,
    limits: &SceneLimits,
) -> Result<SceneFile, SceneError> {
    let err =
        |message: String| SceneError { file: label.to_string(), field: "import".into(), message };
    let Some(import) = value.get("import") else { return from_value(value, label) };
    let rel =
        import.as_str().ok_or_else(|| err("a path to a glTF scene (.glb or .gltf)".into()))?;
    let full = access.resolve(access.base(), Path::new(rel)).map_err(|e| err(e.to_string()))?;
    let imported = crate::interchange::import::import_gltf_with(
        &full,
        access.base(),
        access,
        limits.instances,
        value.get("camera").is_some(),
    )
    .map_err(|e| err(format!("{e:#}")))?;
    let mut merged = serde_json::to_value(imported).map_err(|e| err(e.to_string()))?;
    for (k, v) in value.as_object().into_iter().flatten().filter(|(k, _)| *k != "import") {
        merged[k] = v.clone();
    }
    from_value(merged, label)
}

fn from_value(value: serde_json::Value, label: &str) -> Result<SceneFile, SceneError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let path = e.path().to_string();
        SceneError {
            file: label.to_string(),
            field: if path == "." { String::new() } else { path },
            message: e.into_inner().to_string(),
        }
    })
}

/// Parses scene JSON; errors carry the path of the offending field.
pub fn parse(text: &str, label: &str) -> Result<SceneFile, SceneError> {
    let de = &mut serde_json::Deserializer::from_str(text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        // A syntax error inside a field ends the path in "?" (the value
        // that could not be read): the field is what the reader wants.
        let path = e.path().to_string();
        let field = path.strip_suffix(".?").or(path.strip_suffix("?")).unwrap_or(&path);
        SceneError {
            file: label.to_string(),
            field: if field == "." { String::new() } else { field.to_string() },
            message: e.into_inner().to_string(),
        }
    })
}

fn check_lb(lb: &LbSpec) -> crate::Result<()> {
    if !(4..=512).contains(&lb.grid) {
        return Err(crate::Error::Invalid(format!("grid {}: valid range [4, 512]", lb.grid)));
    }
    Ok(())
}

/// Coordinates beyond this, metres, are refused: their squares would
/// overflow f32 and turn directions into zero or NaN.
const MAX_COORDINATE: f32 = 1e9;

fn bounded3(v: &[f32; 3]) -> crate::Result<()> {
    finite3(v)?;
    if v.iter().any(|x| x.abs() > MAX_COORDINATE) {
        return Err(crate::Error::Invalid(format!(
            "{v:?}: each component must be within ±{MAX_COORDINATE:e}"
        )));
    }
    Ok(())
}

fn finite3(v: &[f32; 3]) -> crate::Result<()> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(crate::Error::Invalid(format!("{v:?} has a value that is not a finite number")))
    }
}

fn colour(v: &[f32; 3]) -> crate::Result<()> {
    finite3(v)?;
    if v.iter().any(|&x| x < 0.0) {
        return Err(crate::Error::Invalid(format!("{v:?}: colour components must be ≥ 0")));
    }
    Ok(())
}

fn instance_transform(inst: &InstanceSpec) -> Result<Affine3A, (&'static str, String)> {
    let m = match inst.matrix {
        Some(cols) => {
            if cols.iter().any(|v| !v.is_finite()) {
                return Err(("matrix", "has a value that is not a finite number".into()));
            }
            let m = Mat4::from_cols_array(&cols);
            if m.row(3) != glam::Vec4::W {
                return Err((
                    "matrix",
                    "the bottom row must be (0, 0, 0, 1): only affine transforms place instances"
                        .into(),
                ));
            }
            Affine3A::from_mat4(m)
        }
        None => {
            finite3(&inst.position).map_err(|e| ("position", e.to_string()))?;
            if !inst.rotate_y_deg.is_finite() {
                return Err((
                    "rotate_y_deg",
                    format!("{} is not a finite number", inst.rotate_y_deg),
                ));
            }
            if !(inst.scale.is_finite() && inst.scale > 0.0) {
                return Err(("scale", format!("{}: must be a finite number > 0", inst.scale)));
            }
            Affine3A::from_scale_rotation_translation(
                Vec3::splat(inst.scale),
                glam::Quat::from_rotation_y(inst.rotate_y_deg.to_radians()),
                inst.position.into(),
            )
        }
    };
    let det = m.matrix3.determinant();
    if det.abs() < 1e-12 || !det.is_finite() {
        return Err((
            "matrix",
            "degenerate transform (determinant 0): it flattens the model".into(),
        ));
    }
    Ok(m)
}

fn sun_light(s: &SunSpec) -> Result<SunLight, (&'static str, String)> {
    let towards = match (s.direction, s.elevation_deg, s.azimuth_deg) {
        (Some(d), None, None) => {
            let v = Vec3::from(d);
            if !v.is_finite()
                || v.abs().max_element() > MAX_COORDINATE
                || v.length_squared() < 1e-12
            {
                return Err(("direction", format!("{d:?} must be a finite, non-zero vector")));
            }
            v.normalize()
        }
        (None, Some(e), Some(a)) => {
            if !(e.is_finite() && e.abs() <= 90.0) {
                return Err(("elevation_deg", format!("{e}: valid range [-90, 90]")));
            }
            if !a.is_finite() {
                return Err(("azimuth_deg", format!("{a} is not a finite number")));
            }
            let (e, a) = (e.to_radians(), a.to_radians());
            Vec3::new(e.cos() * a.cos(), e.sin(), e.cos() * a.sin())
        }
        _ => {
            return Err((
                "direction",
                "give either direction or both elevation_deg and azimuth_deg".into(),
            ));
        }
    };
    if !(s.temperature_k.is_finite() && (1000.0..=40000.0).contains(&s.temperature_k)) {
        return Err(("temperature_k", format!("{}: valid range [1000, 40000]", s.temperature_k)));
    }
    if !(s.intensity.is_finite() && (0.0..=1e6).contains(&s.intensity)) {
        return Err(("intensity", format!("{}: valid range [0, 1e6]", s.intensity)));
    }
    let c = black_body_rgb(s.temperature_k);
    Ok(SunLight { towards, radiance: c.map(|x| x * s.intensity) })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Shared with `tests/fuzz_inputs.rs`.
    const SMALL: &str = include_str!("../tests/data/small_scene.json");

    fn build(text: &str) -> Result<Scene, SceneError> {
        Scene::build(parse(text, "test.json")?, Path::new("."), "test.json")
    }

    fn error_of(text: &str) -> String {
        build(text).unwrap_err().to_string()
    }

    #[test]
    fn a_small_scene_loads() {
        let s = build(SMALL).unwrap();
        assert_eq!(s.models.len(), 1);
        assert_eq!(s.instances.len(), 2);
        assert_eq!(s.unique_triangles(), 2000);
        assert_eq!(s.instanced_triangles(), 4000);
        assert_eq!(s.lighting, LightingMode::Lb);
        let p = s.instances[1].to_world.transform_point3(Vec3::new(1.0, 0.0, 0.0));
        assert!((p - Vec3::new(10.0, 0.0, -1.2)).length() < 1e-5, "{p}");
        assert!(s.sun.towards.y > 0.6);
    }

    #[test]
    fn malformed_scenes_name_file_field_and_fault() {
        let cases = [
            (
                SMALL.replace("\"ground\"", "\"grund\""),
                "test.json: grund: unknown field `grund`, expected one of",
            ),
            (
                SMALL.replace(
                    "\"model\": \"maple\", \"position\": [10",
                    "\"model\": \"oak\", \"position\": [10",
                ),
                "instances[1].model: unknown model \"oak\"",
            ),
            (
                SMALL.replace("\"scale\": 1.2", "\"scale\": 0"),
                "instances[1].scale: 0: must be a finite number > 0",
            ),
            (SMALL.replace("\"scale\": 1.2", "\"scale\": 1e39"), "instances[1].scale"),
            (SMALL.replace("\"position\": [0, 0, 0]", "\"position\": [0, NaN, 0]"), "test.json"),
            (
                SMALL.replace(
                    "\"rotate_y_deg\": 90, \"scale\": 1.2",
                    "\"matrix\": [1,0,0,0, 0,0,0,0, 0,0,1,0, 0,0,0,1]",
                ),
                "instances[1].matrix: degenerate transform",
            ),
            (
                SMALL.replace("\"tree\": {", "\"gltf\": \"nowhere.glb\", \"tree\": {"),
                "models.maple: give exactly one",
            ),
            (
                SMALL.replace(
                    "\"tree\": { \"species\": \"red_maple\", \"triangles\": 2000, \"seed\": 1 }",
                    "\"gltf\": \"nowhere.glb\"",
                ),
                "models.maple.gltf: \"nowhere.glb\" is not a file inside the scene's folder",
            ),
            (SMALL.replace("red_maple", "oak"), "models.maple.tree.species: unknown variant `oak`"),
            (
                SMALL.replace("\"triangles\": 2000", "\"triangles\": 3"),
                "models.maple.tree: red_maple needs at least",
            ),
            (
                SMALL.replace("\"look_at\": [0, 5, 0]", "\"look_at\": [0, 5, -30]"),
                "camera: camera position and look_at must be distinct",
            ),
            (
                SMALL.replace("\"elevation_deg\": 40", "\"elevation_deg\": 140"),
                "sun.elevation_deg: 140: valid range [-90, 90]",
            ),
            (
                SMALL.replace("\"elevation_deg\": 40, ", ""),
                "sun.direction: give either direction or both",
            ),
            (SMALL.replace("[0.1, 0.08, 0.05]", "[0.1, -0.08, 0.05]"), "ground.color"),
            (
                SMALL.replace("[0.1, 0.08, 0.05]", "[0.1, 1.5, 0.05]"),
                "ground.color: [0.1, 1.5, 0.05]: an albedo, each component at most 1",
            ),
        ];
        for (text, want) in cases {
            let e = error_of(&text);
            assert!(e.contains(want), "wanted {want:?}, got {e:?}");
            assert!(e.starts_with("test.json: "), "{e}");
        }
    }

    #[test]
    fn the_fern_loads_from_a_scene_relative_path() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/models");
        let text = SMALL.replace(
            "\"tree\": { \"species\": \"red_maple\", \"triangles\": 2000, \"seed\": 1 }",
            "\"gltf\": \"fern_02.glb\"",
        );
        let s = Scene::build(parse(&text, "t.json").unwrap(), &dir, "t.json").unwrap();
        assert_eq!(s.unique_triangles(), 6232);
    }
}
