//! Prepared data kept on disk, so a worker that restarts (or a second
//! `sylva render` of the same scene) does not build and solve again: the
//! acceleration structures the CPU builds, and the LB light per sun.
//!
//! Entries are content-addressed: a file's name is the BLAKE3 hash of what
//! it was made from (the bundle's hash, this format and build, the
//! structure kind, or the sun and every LB setting), so a changed scene or
//! setting misses instead of reading stale data. What is read back is
//! checked, not trusted, exactly as prepared data from another worker is
//! (`crate::share::import`: its bytes against the hash recorded with them,
//! then every structure against its model and every grid's shape and
//! values); an entry that fails is deleted and prepared again. Writes go
//! to a temporary file renamed into place, so a reader never sees half an
//! entry, and the folder is held under its bound by removing the least
//! recently used entries.

use crate::lighting::lb::SceneLb;
use std::path::{Path, PathBuf};
use std::time::SystemTime;
use sylva_accel::{AccelKind, SceneAccel};
use sylva_light::boulanger::LeafEnvelope;
use sylva_scene::Scene;

/// The layout's version: entries of another are misses (their names differ).
const FORMAT: u32 = 2;
/// An entry file's extension.
const EXT: &str = "prepared";

/// A folder of prepared data, bounded in bytes.
#[derive(Clone, Debug)]
pub struct DiskCache {
    dir: PathBuf,
    limit: u64,
}

/// What a lookup found, for logs and status.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Found {
    /// The structures came from disk.
    pub accel: bool,
    /// The LB light came from disk.
    pub lb: bool,
    /// Boulanger's envelopes came from disk.
    pub envelopes: bool,
}

impl Found {
    /// Logs what came from disk, if anything did; whether anything did.
    pub fn logged(&self) -> bool {
        let any = self.accel || self.lb || self.envelopes;
        if any {
            tracing::info!(
                structures = self.accel,
                lb = self.lb,
                envelopes = self.envelopes,
                "prepared data read from the disk cache"
            );
        }
        any
    }
}

impl DiskCache {
    /// The folder used unless one is named: `$XDG_CACHE_HOME/sylva/prepared`,
    /// or `~/.cache/sylva/prepared`.
    pub fn default_dir() -> Option<PathBuf> {
        let base = std::env::var_os("XDG_CACHE_HOME")
            .map(PathBuf::from)
            .filter(|p| p.is_absolute())
            .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
        Some(base.join("sylva").join("prepared"))
    }

    /// Opens (creating it, private to this user) a cache of at most
    /// `limit` bytes in `dir`.
    pub fn open(dir: &Path, limit: u64) -> anyhow::Result<Self> {
        use anyhow::Context;
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create the prepared-data cache", dir.display()))?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let _ = std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700));
        }
        Ok(Self { dir: dir.to_path_buf(), limit })
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Fills what `reuse` lacks of a scene's structures (for `kind`), LB
    /// light (when `lb_for` names the sun it is for) and Boulanger's
    /// envelopes (when `envelopes`) from disk.
    pub fn fill(
        &self,
        bundle: &str,
        scene: &Scene,
        kind: Option<AccelKind>,
        lb_for: Option<Option<[u32; 3]>>,
        envelopes: bool,
        reuse: &mut crate::prepare::Reuse,
    ) -> Found {
        let mut found = Found::default();
        if envelopes
            && reuse.envelopes.is_none()
            && let Some(e) = self.envelopes(bundle, scene)
        {
            reuse.envelopes = Some(std::sync::Arc::new(crate::lighting::boulanger::of(scene, e)));
            found.envelopes = true;
        }
        if let (Some(kind), None) = (kind, &reuse.accel)
            && let Some(bytes) = self.read(&accel_key(bundle, kind))
        {
            match crate::share::import(&bytes.1, &bytes.0, scene, Some(kind), false) {
                Ok(crate::share::Imported { accel: Some(a), .. }) => {
                    reuse.accel = Some(std::sync::Arc::new(a));
                    found.accel = true;
                }
                other => self.discard(&accel_key(bundle, kind), other.err().map(|e| e.to_string())),
            }
        }
        if let (Some(sun), None) = (lb_for, &reuse.lb) {
            let key = lb_key(bundle, scene, sun);
            if let Some(bytes) = self.read(&key) {
                match crate::share::import(&bytes.1, &bytes.0, scene, None, true) {
                    Ok(crate::share::Imported { lb: Some(lb), .. }) => {
                        reuse.lb = Some(std::sync::Arc::new(lb));
                        found.lb = true;
                    }
                    other => self.discard(&key, other.err().map(|e| e.to_string())),
                }
            }
        }
        found
    }

    /// Writes what a preparation built or solved (`accel`; `lb`, under the
    /// name [`LbName::of`] gave it; Boulanger's `envelopes`, one a model),
    /// then holds the folder under its bound. Failures are logged: the
    /// cache only ever saves work.
    pub fn keep(
        &self,
        bundle: &str,
        accel: Option<&SceneAccel>,
        lb: Option<(&LbName, &SceneLb)>,
        envelopes: Option<&[&LeafEnvelope]>,
    ) {
        if let Some(a) = accel {
            self.write(&accel_key(bundle, a.kind), crate::share::export(Some(a), None, None));
        }
        if let Some((name, lb)) = lb {
            self.write(&name.0, crate::share::export(None, Some(lb), None));
        }
        if let Some(e) = envelopes {
            self.write_postcard(&envelopes_key(bundle), &e);
        }
        self.bound();
    }

    /// Boulanger's envelopes of a scene's models, if they were kept: each
    /// checked against its model before it is used.
    fn envelopes(&self, bundle: &str, scene: &Scene) -> Option<Vec<LeafEnvelope>> {
        self.read_postcard(&envelopes_key(bundle), "envelopes", |e: &Vec<LeafEnvelope>| {
            if e.len() != scene.models.len() {
                return Err(format!("{} envelopes for {} models", e.len(), scene.models.len()));
            }
            scene.models.iter().zip(e).try_for_each(|(m, e)| e.check(m.model.triangle_count()))
        })
    }

    /// `--accel auto`'s choice for a scene on this adapter, if one was
    /// kept: a restart need not build both backends and measure again.
    pub fn choice(&self, bundle: &str, adapter: &str) -> Option<crate::share::SharedChoice> {
        let what = "a choice made on this adapter";
        self.read_postcard(&choice_key(bundle, adapter), what, |c: &crate::share::SharedChoice| {
            (c.adapter == adapter && c.why.len() <= 1024)
                .then_some(())
                .ok_or_else(|| format!("not {what}"))
        })
    }

    /// Keeps `auto`'s choice for a scene (on the adapter it names).
    pub fn keep_choice(&self, bundle: &str, choice: &crate::share::SharedChoice) {
        self.write_postcard(&choice_key(bundle, &choice.adapter), choice);
    }

    /// What `auto`'s probe last measured on this adapter, for any scene,
    /// if kept.
    pub fn probe(&self, adapter: &str) -> Option<Vec<crate::trace::ProbeTime>> {
        let what = "a probe of this adapter";
        self.read_postcard(&probe_key(adapter), what, |p: &Vec<crate::trace::ProbeTime>| {
            let fine = |t: &crate::trace::ProbeTime| {
                t.mrays_per_second.is_finite() && t.mrays_per_second >= 0.0
            };
            (p.len() <= 8 && p.iter().all(fine)).then_some(()).ok_or_else(|| format!("not {what}"))
        })
    }

    /// Keeps what `auto`'s probe measured on this adapter.
    pub fn keep_probe(&self, adapter: &str, probe: &[crate::trace::ProbeTime]) {
        self.write_postcard(&probe_key(adapter), probe);
    }

    /// An entry [`DiskCache::write_postcard`] wrote, decoded as `what` and
    /// passed by `check` before it is used (its bytes were checked against
    /// their hash as [`DiskCache::read`] read them); one that fails either
    /// is removed, saying why.
    fn read_postcard<T: serde::de::DeserializeOwned>(
        &self,
        key: &str,
        what: &str,
        check: impl FnOnce(&T) -> Result<(), String>,
    ) -> Option<T> {
        let (_, body) = self.read(key)?;
        let decoded = postcard::from_bytes::<T>(&body).map_err(|_| format!("not {what}"));
        decoded.and_then(|v| check(&v).map(|()| v)).map_err(|why| self.discard(key, Some(why))).ok()
    }

    /// Writes `value` as postcard under `key`, with the hash of its bytes.
    fn write_postcard<T: serde::Serialize + ?Sized>(&self, key: &str, value: &T) {
        let exported = postcard::to_stdvec(value).map_err(anyhow::Error::from).map(|bytes| {
            crate::share::Exported { hash: blake3::hash(&bytes).to_hex().to_string(), bytes }
        });
        self.write(key, exported);
    }

    fn path(&self, key: &str) -> PathBuf {
        self.dir.join(format!("{key}.{EXT}"))
    }

    /// An entry's recorded hash and bytes, marked used; `None` if absent
    /// or unreadable. The bytes are hashed as they stream from the file,
    /// a block at a time, and read into memory only once they match the
    /// hash they were written with: a damaged or foreign entry, however
    /// large, costs one pass over it and no memory.
    fn read(&self, key: &str) -> Option<(String, Vec<u8>)> {
        use std::io::Read;
        let path = self.path(key);
        // Not following links: an entry is a file this cache wrote.
        let meta = std::fs::symlink_metadata(&path).ok()?;
        if !meta.is_file() {
            self.discard(key, Some("not a file".into()));
            return None;
        }
        // Nothing larger than the whole cache was written here.
        if meta.len() > self.limit {
            self.discard(key, Some("larger than the cache's bound".into()));
            return None;
        }
        // 64 hex digits of the content's BLAKE3, then the content.
        let mut file = std::fs::File::open(&path).ok()?;
        let mut header = [0u8; 64];
        if file.read_exact(&mut header).is_err() {
            self.discard(key, Some("shorter than its header".into()));
            return None;
        }
        let Some(hash) = std::str::from_utf8(&header).ok().map(str::to_string) else {
            self.discard(key, Some("its header is not a hash".into()));
            return None;
        };
        let mut hasher = blake3::Hasher::new();
        if std::io::copy(&mut file, &mut hasher).is_err()
            || hasher.finalize().to_hex().as_str() != hash
        {
            self.discard(key, Some("its bytes do not match the hash written with them".into()));
            return None;
        }
        // The same file read again, from the handle hashed: a writer
        // renames a new entry into place, so this one cannot change under it.
        use std::io::Seek;
        file.seek(std::io::SeekFrom::Start(64)).ok()?;
        let mut body = Vec::with_capacity(meta.len().saturating_sub(64) as usize);
        file.read_to_end(&mut body).ok()?;
        // Recency for eviction: the modification time, set on use.
        let _ = std::fs::File::options()
            .append(true)
            .open(&path)
            .and_then(|f| f.set_modified(SystemTime::now()));
        Some((hash, body))
    }

    fn write(&self, key: &str, exported: anyhow::Result<crate::share::Exported>) {
        let result = exported.and_then(|e| {
            let tmp = self.dir.join(format!(".{key}.{}.tmp", std::process::id()));
            let mut data = e.hash.into_bytes();
            data.extend_from_slice(&e.bytes);
            let placed = std::fs::write(&tmp, &data).and_then(|_| {
                // Whatever stands in the entry's place and is not a file
                // this cache wrote (a folder, a link) goes first.
                let path = self.path(key);
                if std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_dir()) {
                    std::fs::remove_dir_all(&path)?;
                }
                std::fs::rename(&tmp, path)
            });
            if placed.is_err() {
                let _ = std::fs::remove_file(&tmp);
            }
            Ok(placed?)
        });
        if let Err(e) = result {
            tracing::warn!(dir = %self.dir.display(), "prepared data not cached: {e:#}");
        }
    }

    /// Removes an entry that failed its checks.
    fn discard(&self, key: &str, why: Option<String>) {
        tracing::warn!(
            entry = key,
            "cached prepared data refused, preparing again: {}",
            // The checks' words may quote the scene's names.
            sylva_scene::sandbox::escaped(
                &why.unwrap_or_else(|| "it holds the wrong parts".into())
            )
        );
        let path = self.path(key);
        if std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_dir()) {
            let _ = std::fs::remove_dir_all(&path);
        } else {
            let _ = std::fs::remove_file(&path);
        }
    }

    /// Removes the least recently used entries (and temporary files older
    /// than an hour, left by a killed writer) until the folder is within
    /// its bound.
    fn bound(&self) {
        let Ok(dir) = std::fs::read_dir(&self.dir) else { return };
        let now = SystemTime::now();
        let mut entries: Vec<(SystemTime, u64, PathBuf)> = Vec::new();
        for e in dir.flatten() {
            let (path, Ok(meta)) = (e.path(), e.metadata()) else { continue };
            let modified = meta.modified().unwrap_or(now);
            if path.extension().is_some_and(|x| x == "tmp") {
                if now.duration_since(modified).is_ok_and(|d| d.as_secs() > 3600) {
                    let _ = std::fs::remove_file(&path);
                }
                continue;
            }
            if path.extension().is_some_and(|x| x == EXT) {
                entries.push((modified, meta.len(), path));
            }
        }
        entries.sort();
        let mut total: u64 = entries.iter().map(|e| e.1).sum();
        for (_, len, path) in entries {
            if total <= self.limit {
                break;
            }
            if std::fs::remove_file(&path).is_ok() {
                total -= len;
            }
        }
    }
}

/// The name of a scene's structures of `kind`.
fn accel_key(bundle: &str, kind: AccelKind) -> String {
    let mut h = blake3::Hasher::new();
    h.update(
        format!("sylva accel {FORMAT} {} {bundle} {kind:?}", env!("CARGO_PKG_VERSION")).as_bytes(),
    );
    h.finalize().to_hex().to_string()
}

/// The name of a scene's Boulanger envelopes: they depend on its models
/// alone, which its bundle's hash names.
fn envelopes_key(bundle: &str) -> String {
    let mut h = blake3::Hasher::new();
    h.update(format!("sylva envelopes {FORMAT} {} {bundle}", env!("CARGO_PKG_VERSION")).as_bytes());
    h.finalize().to_hex().to_string()
}

/// The name of `auto`'s choice for a scene on an adapter.
fn choice_key(bundle: &str, adapter: &str) -> String {
    let mut h = blake3::Hasher::new();
    h.update(format!("sylva choice {FORMAT} {} {bundle} ", env!("CARGO_PKG_VERSION")).as_bytes());
    h.update(adapter.as_bytes());
    h.finalize().to_hex().to_string()
}

/// The name of what `auto`'s probe last measured on an adapter.
fn probe_key(adapter: &str) -> String {
    let mut h = blake3::Hasher::new();
    h.update(format!("sylva probe {FORMAT} {} ", env!("CARGO_PKG_VERSION")).as_bytes());
    h.update(adapter.as_bytes());
    h.finalize().to_hex().to_string()
}

/// The name a scene's LB light is kept under.
#[derive(Clone, Debug)]
pub struct LbName(String);

impl LbName {
    /// The name of `scene`'s light under `sun` (its view's sun key).
    pub fn of(bundle: &str, scene: &Scene, sun: Option<[u32; 3]>) -> Self {
        Self(lb_key(bundle, scene, sun))
    }
}

/// The name of a scene's LB light under `sun`: every setting the solve
/// reads that a frame can change after loading (the models' LB settings,
/// chosen grids included, the sun and sky) is part of it.
fn lb_key(bundle: &str, scene: &Scene, sun: Option<[u32; 3]>) -> String {
    let mut h = blake3::Hasher::new();
    h.update(
        format!("sylva lb {FORMAT} {} {bundle} {sun:?}", env!("CARGO_PKG_VERSION")).as_bytes(),
    );
    for m in &scene.models {
        h.update(format!("{:?}", m.lb).as_bytes());
    }
    h.update(format!("{:?} {:?} {:?}", scene.sun, scene.sky, scene.file.lb_model).as_bytes());
    h.finalize().to_hex().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `auto`'s choice is kept on disk as postcard, which numbers a
    /// backend by its variant's place: rq, bvh and kd keep the numbers they
    /// had before `auto` joined the type, so a choice kept by an earlier
    /// build still names the backend it chose.
    #[test]
    fn a_kept_choice_reads_back_as_the_backend_it_named() {
        use sylva_scene::frame::Backend;
        let numbers: Vec<u8> =
            [Backend::Rq, Backend::Bvh, Backend::Kd, Backend::Auto, Backend::Cwbvh]
                .iter()
                .map(|b| postcard::to_stdvec(b).unwrap()[0])
                .collect();
        assert_eq!(numbers, [0, 1, 2, 3, 4]);
        let c = crate::share::SharedChoice {
            adapter: "a".into(),
            backend: Backend::Bvh,
            why: "w".into(),
        };
        let back: crate::share::SharedChoice =
            postcard::from_bytes(&postcard::to_stdvec(&c).unwrap()).unwrap();
        assert_eq!(back.backend, Backend::Bvh);
    }

    /// Beyond its bound, the least recently used entries go first.
    #[test]
    fn the_least_recently_used_entries_go_beyond_the_bound() {
        let dir = std::env::temp_dir().join(format!("sylva-disk-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let c = DiskCache::open(&dir, 2 * (64 + 100)).unwrap();
        let entry = |n: u8| {
            let bytes = vec![n; 100];
            Ok(crate::share::Exported { hash: blake3::hash(&bytes).to_hex().to_string(), bytes })
        };
        let names = ["a", "b", "c"];
        for (i, k) in names.iter().enumerate() {
            c.write(k, entry(i as u8));
            // Distinct times for the recency order.
            let f = std::fs::File::options().append(true).open(c.path(k)).unwrap();
            f.set_modified(SystemTime::UNIX_EPOCH + std::time::Duration::from_secs(100 + i as u64))
                .unwrap();
        }
        // Reading "a" makes it the most recent: "b" is now the oldest.
        assert_eq!(c.read("a").unwrap().1, vec![0; 100]);
        c.bound();
        let left: Vec<bool> = names.iter().map(|k| c.path(k).exists()).collect();
        assert_eq!(left, [true, false, true]);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// An entry is checked as it streams from the file, before it is held:
    /// damaged bytes, a folder or a link in its place are refused and
    /// cleared, and the next write takes the place without leaving its
    /// temporary file behind.
    #[test]
    fn kept_envelopes_read_back_only_for_the_models_they_fit() {
        let dir = std::env::temp_dir().join(format!("sylva-disk-cache-env-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let c = DiskCache::open(&dir, 1 << 30).unwrap();
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/tree.json");
        let scene = Scene::load(path.as_ref()).unwrap();
        let made: Vec<LeafEnvelope> = scene
            .models
            .iter()
            .enumerate()
            .map(|(i, m)| LeafEnvelope {
                s_max: vec![[0.25 + i as f32; 8]; m.model.triangle_count()],
                tau: 1.5,
                leaf_density: 3.0,
                leaf_area: 0.5,
                leaves: m.model.triangle_count() / 2,
                leaf_albedo: [0.1, 0.3, 0.05],
                precompute_ms: 12.0,
            })
            .collect();
        assert!(!made.is_empty(), "the example has models");
        let bundle = "b".repeat(64);
        assert!(c.envelopes(&bundle, &scene).is_none(), "nothing kept yet");
        c.keep(&bundle, None, None, Some(&made.iter().collect::<Vec<_>>()));
        let back = c.envelopes(&bundle, &scene).expect("kept");
        assert_eq!(back.len(), made.len());
        for (a, b) in back.iter().zip(&made) {
            assert_eq!((&a.s_max, a.tau, a.leaves), (&b.s_max, b.tau, b.leaves));
        }
        // Another bundle's name finds nothing.
        assert!(c.envelopes(&"c".repeat(64), &scene).is_none());
        // Envelopes that do not fit the models (a triangle short, a
        // distance not finite) are refused and removed, not used.
        let mut short = made.clone();
        short[0].s_max.pop();
        c.keep(&bundle, None, None, Some(&short.iter().collect::<Vec<_>>()));
        assert!(c.envelopes(&bundle, &scene).is_none());
        assert!(!c.path(&envelopes_key(&bundle)).exists());
        let mut nan = made.clone();
        nan[0].s_max[0][3] = f32::NAN;
        c.keep(&bundle, None, None, Some(&nan.iter().collect::<Vec<_>>()));
        assert!(c.envelopes(&bundle, &scene).is_none());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_damaged_or_foreign_entry_is_refused_and_replaced() {
        let dir = std::env::temp_dir().join(format!("sylva-disk-cache-bad-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let c = DiskCache::open(&dir, 1 << 30).unwrap();
        let bytes = vec![7u8; 1000];
        let good = || {
            Ok(crate::share::Exported {
                hash: blake3::hash(&bytes).to_hex().to_string(),
                bytes: bytes.clone(),
            })
        };
        c.write("k", good());
        assert_eq!(c.read("k").unwrap().1, bytes);
        // One byte changed: refused and removed.
        let mut raw = std::fs::read(c.path("k")).unwrap();
        raw[500] ^= 1;
        std::fs::write(c.path("k"), &raw).unwrap();
        assert!(c.read("k").is_none());
        assert!(!c.path("k").exists());
        // A large file of the wrong bytes (sparse: 64 MiB that take no disk)
        // is refused too, streamed rather than read whole.
        let f = std::fs::File::create(c.path("k")).unwrap();
        f.set_len(64 << 20).unwrap();
        assert!(c.read("k").is_none() && !c.path("k").exists());
        // A folder in the entry's place: refused, cleared, and written over.
        std::fs::create_dir_all(c.path("k").join("inside")).unwrap();
        assert!(c.read("k").is_none() && !c.path("k").exists());
        std::fs::create_dir_all(c.path("k").join("inside")).unwrap();
        c.write("k", good());
        assert_eq!(c.read("k").unwrap().1, bytes);
        let tmp = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .filter(|e| e.path().extension().is_some_and(|x| x == "tmp"))
            .count();
        assert_eq!(tmp, 0, "no temporary file is left behind");
        // A link in its place is not followed.
        #[cfg(unix)]
        {
            let _ = std::fs::remove_file(c.path("k"));
            std::os::unix::fs::symlink(dir.join("elsewhere"), c.path("k")).unwrap();
            assert!(c.read("k").is_none());
            assert!(std::fs::symlink_metadata(c.path("k")).is_err());
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
