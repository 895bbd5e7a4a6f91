//! Scene bundles: a scene file and the model files it names, packed into
//! one content-addressed blob that workers cache by hash.
//!
//! Layout: the magic `SYLVABN1`, the manifest's length (u64, little
//! endian), the manifest (JSON: the scene with model paths rewritten to
//! blob names, and each blob's name and length), then the blobs in order.
//! The hash is BLAKE3 of the whole bundle, in hex.
//!
//! The manifest is canonical JSON, so that other packers (the Python
//! client's `sylva_client.bundle`) write the same bytes: the scene is kept
//! as its file wrote it (no defaults filled in), keys sorted, no spaces,
//! numbers as `serde_json` prints them (shortest round-trip floats). See
//! docs/scene-format.md, "Bundles".

use crate::error::chain;
use crate::{Error, FileAccess, Result, Scene, SceneFile, SceneLimits};
use serde::{Deserialize, Serialize};
use std::path::{Component, Path};

const MAGIC: &[u8; 8] = b"SYLVABN1";

/// A packed scene.
#[derive(Clone, Debug)]
pub struct SceneBundle {
    /// The bundle's bytes.
    pub bytes: Vec<u8>,
    /// BLAKE3 of the bytes, hex.
    pub hash: String,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    /// The scene file's JSON (its `import`, if any, is read once the blobs
    /// are written).
    scene: serde_json::Value,
    blobs: Vec<BlobEntry>,
}

/// What [`pack_with`] writes as the manifest: the scene as its file gave
/// it (a JSON value, whose objects serialize with sorted keys).
#[derive(Serialize)]
struct PackedManifest {
    scene: serde_json::Value,
    blobs: Vec<BlobEntry>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct BlobEntry {
    name: String,
    len: u64,
}

/// The hash a bundle of `bytes` is known by.
pub fn hash_of(bytes: &[u8]) -> String {
    blake3::hash(bytes).to_hex().to_string()
}

/// Packs the scene file at `path` and the glTF files it names (with the
/// buffers and images a `.gltf` refers to by relative path), all of which
/// must lie inside the scene file's folder.
pub fn pack(path: &Path) -> Result<SceneBundle> {
    pack_with(path, &FileAccess::Inside(crate::folder_of(path)))
}

/// Packs the scene file at `path`, reading its models as `access` allows.
pub fn pack_with(path: &Path, access: &FileAccess) -> Result<SceneBundle> {
    let label = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| Error::file(&label, "cannot read", e))?;
    // Parsed once as a scene, for its errors, and kept as written for the
    // manifest: the glTF files it names itself (its models', its import)
    // are packed, and their paths rewritten to the blobs' names.
    crate::parse_with(&text, &label, access, &SceneLimits::default())?;
    let mut written: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| Error::Invalid(chain(&e)))?;
    let mut blobs: Vec<(String, Vec<u8>)> = Vec::new();
    let models: Vec<(String, String)> = written
        .get("models")
        .and_then(|m| m.as_object())
        .into_iter()
        .flatten()
        .map(|(name, spec)| (name.clone(), spec.get("gltf").and_then(|g| g.as_str())))
        .enumerate()
        .filter_map(|(i, (name, gltf))| gltf.map(|g| (name, format!("m{i}"), g.to_string())))
        .map(|(name, dir, gltf)| {
            let field = format!("models.{name}.gltf");
            let blob = pack_gltf(access, &gltf, &dir, &label, &field, &mut blobs)?;
            Ok((name, blob))
        })
        .collect::<Result<_>>()?;
    for (name, blob) in models {
        written["models"][&name]["gltf"] = serde_json::Value::from(blob);
    }
    if let Some(rel) = written.get("import").and_then(|v| v.as_str()).map(str::to_string) {
        let blob = pack_gltf(access, &rel, "i", &label, "import", &mut blobs)?;
        written["import"] = serde_json::Value::from(blob);
    }
    let manifest = PackedManifest {
        scene: written,
        blobs: blobs
            .iter()
            .map(|(n, b)| BlobEntry { name: n.clone(), len: b.len() as u64 })
            .collect(),
    };
    let json = serde_json::to_vec(&manifest).map_err(|e| Error::Invalid(chain(&e)))?;
    let mut bytes =
        Vec::with_capacity(16 + json.len() + blobs.iter().map(|b| b.1.len()).sum::<usize>());
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&(json.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&json);
    for (_, b) in &blobs {
        bytes.extend_from_slice(b);
    }
    let hash = hash_of(&bytes);
    Ok(SceneBundle { bytes, hash })
}

/// Packs the glTF file `rel` (named by the scene's `field`) into blobs
/// under `dir`, with the files a `.gltf` names: the blob name the scene's
/// field becomes.
fn pack_gltf(
    access: &FileAccess,
    rel: &str,
    dir: &str,
    label: &str,
    field: &str,
    blobs: &mut Vec<(String, Vec<u8>)>,
) -> Result<String> {
    let full = access
        .resolve(access.base(), Path::new(rel))
        .map_err(|e| e.within(format!("{label}: {field}")))?;
    let bytes = std::fs::read(&full)
        .map_err(|e| Error::file(format!("{label}: {field}"), format!("cannot read {rel}"), e))?;
    let file = full
        .file_name()
        .map(|f| f.to_string_lossy().to_string())
        .unwrap_or_else(|| "model.glb".into());
    if file.to_ascii_lowercase().ends_with(".gltf") {
        let folder = full.parent().unwrap_or(Path::new("."));
        let uris = external_uris(&bytes)
            .map_err(|error| Error::Json { context: format!("{rel}: not glTF JSON"), error })?;
        for uri in uris {
            let dep = access
                .resolve_uri(folder, &uri)
                .map_err(|e| e.within(rel))?
                .expect("not a data: URI");
            let data = std::fs::read(&dep)
                .map_err(|e| Error::file(rel, format!("cannot read {uri}"), e))?;
            // Named as the reader finds it: the URI percent-decoded.
            let decoded = crate::sandbox::percent_decode(&uri).expect("resolve_uri decoded it");
            blobs.push((format!("{dir}/{decoded}"), data));
        }
    }
    blobs.push((format!("{dir}/{file}"), bytes));
    Ok(format!("{dir}/{file}"))
}

/// Relative URIs of a `.gltf` file's buffers and images.
fn external_uris(gltf_json: &[u8]) -> serde_json::Result<Vec<String>> {
    let v: serde_json::Value = serde_json::from_slice(gltf_json)?;
    let mut out = Vec::new();
    for key in ["buffers", "images"] {
        for item in v[key].as_array().into_iter().flatten() {
            if let Some(uri) = item["uri"].as_str()
                && !uri.starts_with("data:")
            {
                out.push(uri.to_string());
            }
        }
    }
    Ok(out)
}

/// Unpacks a bundle into `dir` (blobs as files) and builds its scene with
/// the default limits.
pub fn unpack(bytes: &[u8], dir: &Path) -> Result<Scene> {
    unpack_with(bytes, dir, &SceneLimits::default())
}

/// Unpacks a bundle into `dir` (blobs as files) and builds its scene, which
/// reads files inside `dir` alone, within `limits`. Refuses malformed
/// bundles and blob names that would leave `dir`; the scene is checked
/// before any blob is written.
pub fn unpack_with(bytes: &[u8], dir: &Path, limits: &SceneLimits) -> Result<Scene> {
    if bytes.len() < 16 || &bytes[..8] != MAGIC {
        return Err(Error::Bundle("not a Sylva scene bundle (bad magic)".into()));
    }
    let len = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes")) as usize;
    let body = &bytes[16..];
    if len > body.len() {
        return Err(Error::Bundle(format!(
            "truncated scene bundle: manifest of {len} bytes, {} present",
            body.len()
        )));
    }
    let malformed = |error| Error::Json { context: "malformed bundle manifest".into(), error };
    let manifest: Manifest = serde_json::from_slice(&body[..len]).map_err(malformed)?;
    // The cheap checks first: a scene that would be refused costs no disk
    // (one that imports a glTF scene is known once its blobs are written).
    if manifest.scene.get("import").is_none() {
        let file: SceneFile = serde_json::from_value(manifest.scene.clone()).map_err(malformed)?;
        Scene::check(&file, "bundle", limits)?;
    }
    let mut at = len;
    std::fs::create_dir_all(dir).map_err(|e| Error::file(dir.display(), "cannot create", e))?;
    for b in &manifest.blobs {
        let rel = Path::new(&b.name);
        if rel.is_absolute() || rel.components().any(|c| !matches!(c, Component::Normal(_))) {
            return Err(Error::Bundle(format!(
                "bundle blob name {:?} is not a plain relative path",
                b.name
            )));
        }
        let end = at.checked_add(b.len as usize).filter(|&e| e <= body.len());
        let Some(end) = end else {
            return Err(Error::Bundle(format!(
                "truncated scene bundle: blob {:?} runs past the end",
                b.name
            )));
        };
        let target = dir.join(rel);
        if let Some(parent) = target.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(&target, &body[at..end])
            .map_err(|e| Error::file(target.display(), "cannot write", e))?;
        at = end;
    }
    if at != body.len() {
        return Err(Error::Bundle(format!(
            "scene bundle has {} stray bytes after its blobs",
            body.len() - at
        )));
    }
    let access = FileAccess::Inside(dir.to_path_buf());
    let file = crate::expand(manifest.scene, "bundle", &access, limits)?;
    Ok(Scene::build_with(file, &access, "bundle", limits)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scene_with_a_gltf_model_round_trips_and_tampering_is_refused() {
        let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/ferns.json");
        let b = pack(&examples).unwrap();
        assert_eq!(b.hash, hash_of(&b.bytes));
        assert_eq!(pack(&examples).unwrap().hash, b.hash, "packing is deterministic");
        let dir = std::env::temp_dir().join(format!("sylva-bundle-{}", std::process::id()));
        let s = unpack(&b.bytes, &dir).unwrap();
        assert_eq!(s.unique_triangles(), 6232);
        assert!(
            unpack(&b.bytes[..b.bytes.len() - 10], &dir)
                .unwrap_err()
                .to_string()
                .contains("truncated")
        );
        assert!(
            unpack(b"nonsense-bytes-here", &dir).unwrap_err().to_string().contains("bad magic")
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
