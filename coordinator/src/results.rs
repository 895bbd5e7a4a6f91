//! Finished frames kept for `FetchResult`: in memory while they are small
//! and the memory budget allows, else spilled to files in the
//! coordinator's work folder; forgotten (files removed) when their job is.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Duration;

/// How long, how many and how large finished jobs are kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Retention {
    /// A finished job is forgotten this long after it ended.
    pub keep: Duration,
    /// At most this many finished jobs are kept (oldest forgotten first).
    pub max_jobs: usize,
    /// Results held in memory, bytes, all jobs together; the rest are spilled.
    pub memory_bytes: u64,
    /// A single result larger than this goes to disk at once.
    pub spill_bytes: u64,
}

impl Default for Retention {
    fn default() -> Self {
        Self {
            keep: Duration::from_secs(3600),
            max_jobs: 1000,
            memory_bytes: 256 << 20,
            spill_bytes: 8 << 20,
        }
    }
}

/// Where one encoded image is.
#[derive(Clone, Debug)]
pub enum Stored {
    /// In memory.
    Memory(std::sync::Arc<Vec<u8>>),
    /// In a file of the work folder.
    Disk(PathBuf),
}

impl Stored {
    /// The image's bytes.
    pub fn read(&self) -> std::io::Result<Vec<u8>> {
        match self {
            Stored::Memory(b) => Ok(b.to_vec()),
            Stored::Disk(p) => std::fs::read(p),
        }
    }

    fn memory(&self) -> u64 {
        match self {
            Stored::Memory(b) => b.len() as u64,
            Stored::Disk(_) => 0,
        }
    }
}

/// Every kept result, by job id, frame and format.
pub struct ResultStore {
    dir: PathBuf,
    retention: Retention,
    /// Per job, per frame (one unless a sequence): PNG and EXR.
    items: HashMap<String, Vec<[Stored; 2]>>,
    in_memory: u64,
}

impl ResultStore {
    /// An empty store spilling into `dir` (created when first needed).
    pub fn new(dir: PathBuf, retention: Retention) -> Self {
        Self { dir, retention, items: HashMap::new(), in_memory: 0 }
    }

    fn keep(&mut self, id: &str, ext: &str, bytes: Vec<u8>) -> anyhow::Result<Stored> {
        let n = bytes.len() as u64;
        if n <= self.retention.spill_bytes && self.in_memory + n <= self.retention.memory_bytes {
            self.in_memory += n;
            return Ok(Stored::Memory(std::sync::Arc::new(bytes)));
        }
        std::fs::create_dir_all(&self.dir)?;
        let p = self.dir.join(format!("{id}.{ext}"));
        std::fs::write(&p, bytes)?;
        Ok(Stored::Disk(p))
    }

    /// Keeps a job's frames, each as PNG and EXR.
    pub fn put(&mut self, id: &str, frames: Vec<(Vec<u8>, Vec<u8>)>) -> anyhow::Result<()> {
        self.remove(id);
        let mut kept = Vec::with_capacity(frames.len());
        for (i, (png, exr)) in frames.into_iter().enumerate() {
            let name = if i == 0 { id.to_string() } else { format!("{id}.{i:05}") };
            kept.push([self.keep(&name, "png", png)?, self.keep(&name, "exr", exr)?]);
        }
        self.items.insert(id.to_string(), kept);
        Ok(())
    }

    /// Frame `frame` of a job in `format` (`png` or `exr`), if kept.
    pub fn get(&self, id: &str, frame: usize, format: &str) -> Option<Stored> {
        self.items
            .get(id)?
            .get(frame)
            .map(|[png, exr]| if format == "exr" { exr.clone() } else { png.clone() })
    }

    /// Forgets a job's results.
    pub fn remove(&mut self, id: &str) {
        if let Some(items) = self.items.remove(id) {
            for s in items.into_iter().flatten() {
                self.in_memory -= s.memory();
                if let Stored::Disk(p) = s {
                    let _ = std::fs::remove_file(p);
                }
            }
        }
    }

    /// Bytes held in memory.
    pub fn memory_bytes(&self) -> u64 {
        self.in_memory
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_results_spill_to_disk_and_are_removed_with_their_job() {
        let dir = std::env::temp_dir().join(format!("sylva-results-{}", std::process::id()));
        let r = Retention { memory_bytes: 100, spill_bytes: 60, ..Default::default() };
        let mut s = ResultStore::new(dir.clone(), r);
        s.put("a", vec![(vec![1; 50], vec![2; 70])]).unwrap();
        assert!(matches!(s.get("a", 0, "png"), Some(Stored::Memory(_))));
        let exr = s.get("a", 0, "exr").unwrap();
        assert!(matches!(exr, Stored::Disk(_)), "over spill_bytes");
        assert_eq!(exr.read().unwrap(), vec![2; 70]);
        s.put("b", vec![(vec![3; 55], vec![4; 10]), (vec![5; 5], vec![6; 5])]).unwrap();
        assert!(matches!(s.get("b", 0, "png"), Some(Stored::Disk(_))), "over the memory budget");
        assert_eq!(
            s.get("b", 1, "exr").unwrap().read().unwrap(),
            vec![6; 5],
            "a sequence's frames kept apart"
        );
        assert!(s.get("b", 2, "png").is_none());
        assert_eq!(s.memory_bytes(), 70);
        s.remove("a");
        s.remove("b");
        assert_eq!(s.memory_bytes(), 0);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "spilled files removed");
        std::fs::remove_dir_all(&dir).ok();
    }
}
