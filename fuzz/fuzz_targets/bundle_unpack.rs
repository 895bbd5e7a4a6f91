//! `bundle::unpack` on arbitrary bytes: it may not panic, and it may not
//! write outside the folder it is given. The in-suite version is
//! `shared/scene/tests/fuzz_inputs.rs`; see docs/fuzzing.md.
//!
//! An input that starts with the bundle magic `SYLVABN1` is unpacked as it
//! is. Any other input is `manifest JSON` + `\n--blobs--\n` + `blob bytes`
//! and gets the magic and the manifest's length put in front, so that the
//! fuzzer can edit the manifest as text without breaking its length.

#![no_main]

use libfuzzer_sys::fuzz_target;
use std::collections::BTreeSet;
use std::path::{Component, Path, PathBuf};
use std::sync::OnceLock;
use std::time::SystemTime;
use sylva_scene::bundle;
use sylva_scene::SceneFile;

const MAGIC: &[u8; 8] = b"SYLVABN1";
const SEPARATOR: &[u8] = b"\n--blobs--\n";
const MAX_TREE_TRIANGLES: u32 = 2000;

/// `parent/d1/d2/d3/out`: names with up to four `..` land in `parent`.
struct Sandbox {
    parent: PathBuf,
    dir: PathBuf,
}

fn sandbox() -> &'static Sandbox {
    static SANDBOX: OnceLock<Sandbox> = OnceLock::new();
    SANDBOX.get_or_init(|| {
        let parent = std::env::temp_dir().join(format!("sylva-fuzz-bundle-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&parent);
        let dir = parent.join("d1/d2/d3/out");
        std::fs::create_dir_all(&dir).expect("a temporary folder");
        Sandbox { parent, dir }
    })
}

/// Every path under `p` but `skip` and what it holds.
fn listing(p: &Path, skip: &Path, out: &mut BTreeSet<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(p) else { return };
    for e in entries.flatten() {
        let path = e.path();
        if path == skip {
            continue;
        }
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            listing(&path, skip, out);
        }
        out.insert(path);
    }
}

/// `path` with `.` and `..` resolved lexically.
fn normalize(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            c => out.push(c),
        }
    }
    out
}

/// A file's size and modification time; `None` for no file (folders change
/// as others use them and are not compared).
fn file_stamp(p: &Path) -> Option<(u64, Option<SystemTime>)> {
    std::fs::symlink_metadata(p).ok().filter(|m| !m.is_dir()).map(|m| (m.len(), m.modified().ok()))
}

/// The bundle an input stands for.
fn bundle_of(data: &[u8]) -> Vec<u8> {
    if data.starts_with(MAGIC) {
        return data.to_vec();
    }
    let (manifest, blobs) = match data.windows(SEPARATOR.len()).position(|w| w == SEPARATOR) {
        Some(at) => (&data[..at], &data[at + SEPARATOR.len()..]),
        None => (data, &[][..]),
    };
    let mut b = Vec::with_capacity(16 + data.len());
    b.extend_from_slice(MAGIC);
    b.extend_from_slice(&(manifest.len() as u64).to_le_bytes());
    b.extend_from_slice(manifest);
    b.extend_from_slice(blobs);
    b
}

/// The manifest as JSON, if it is.
fn manifest_of(bundle: &[u8]) -> Option<serde_json::Value> {
    let len = usize::try_from(u64::from_le_bytes(bundle.get(8..16)?.try_into().ok()?)).ok()?;
    serde_json::from_slice(bundle.get(16..)?.get(..len)?).ok()
}

/// Small trees only, and no glTF path that reads outside the folder (a
/// path like `/dev/zero` would stall the fuzzer, not find a bug here).
fn cheap(manifest: Option<&serde_json::Value>) -> bool {
    let Some(scene) = manifest.and_then(|m| m.get("scene")) else { return true };
    let Ok(f) = serde_json::from_value::<SceneFile>(scene.clone()) else { return true };
    f.models.len() <= 4
        && f.instances.len() <= 256
        && f.models.values().all(|m| {
            m.tree.is_none_or(|t| t.triangles.is_some_and(|n| n <= MAX_TREE_TRIANGLES))
                && m.gltf.as_deref().is_none_or(|p| p.components().all(|c| matches!(c, Component::Normal(_))))
        })
}

fuzz_target!(|data: &[u8]| {
    let sb = sandbox();
    let bytes = bundle_of(data);
    let manifest = manifest_of(&bytes);
    if !cheap(manifest.as_ref()) {
        return;
    }
    // Where each blob name would land if it were joined unchecked, and
    // which of those outside `dir` already exist.
    let names: Vec<String> = manifest
        .as_ref()
        .and_then(|m| m.get("blobs")?.as_array().cloned())
        .into_iter()
        .flatten()
        .filter_map(|b| Some(b.get("name")?.as_str()?.to_string()))
        .collect();
    let outside: Vec<PathBuf> =
        names.iter().map(|n| normalize(&sb.dir.join(n))).filter(|t| !t.starts_with(&sb.dir) && !t.as_os_str().is_empty()).collect();
    let before: Vec<Option<(u64, Option<SystemTime>)>> = outside.iter().map(|t| file_stamp(t)).collect();
    let _ = std::fs::remove_dir_all(&sb.dir);

    let _ = bundle::unpack(&bytes, &sb.dir);

    let mut seen = BTreeSet::new();
    listing(&sb.parent, &sb.dir, &mut seen);
    let expected: BTreeSet<PathBuf> = ["d1", "d1/d2", "d1/d2/d3"].iter().map(|p| sb.parent.join(p)).collect();
    assert!(seen.is_subset(&expected), "unpack wrote outside {}: {:?}", sb.dir.display(), seen.difference(&expected).collect::<Vec<_>>());
    for (t, before) in outside.iter().zip(before) {
        assert!(file_stamp(t) == before, "unpack wrote {} outside {}", t.display(), sb.dir.display());
    }
});
