//! A process's own folder (a worker's bundle cache, a coordinator's state):
//! claimed by a lock held for the process's life, so two processes never
//! share one, and a folder whose lock nobody holds belongs to a process
//! that was killed before it could remove it: the next process of the kind
//! removes it.

use anyhow::Context;
use std::fs::File;
use std::path::{Path, PathBuf};

/// The lock file inside a claimed folder.
pub const LOCK: &str = "lock";

/// Creates `dir` if need be and locks it for this process (the lock goes
/// with the returned file, or the process); refused while another holds it.
pub fn claim(dir: &Path, what: &str) -> anyhow::Result<File> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create the {what} {}", dir.display()))?;
    let held = || {
        anyhow::anyhow!(
            "the {what} {} is in use by another process: give this one its own",
            dir.display()
        )
    };
    // An existing lock: someone else's while they hold it.
    if let Ok(existing) = File::open(dir.join(LOCK)) {
        existing.try_lock().map_err(|_| held())?;
    }
    // Locked before it is renamed into place, so a lock file another
    // process sees is never one not yet locked.
    let fresh = dir.join(format!("{LOCK}.{}", std::process::id()));
    let lock = File::create(&fresh)
        .with_context(|| format!("cannot lock the {what} {}", dir.display()))?;
    lock.try_lock().map_err(|_| held())?;
    std::fs::rename(&fresh, dir.join(LOCK))?;
    Ok(lock)
}

/// Removes the folders in `parent` named `prefix…` that no live process
/// holds: locked ones are left, an unlocked one is a killed process's. A
/// folder from before folders were locked counts as held while a process
/// with the number its name ends in runs. Returns what it removed.
pub fn remove_abandoned(parent: &Path, prefix: &str) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(parent) else { return Vec::new() };
    let mut removed = Vec::new();
    for e in entries.flatten() {
        let Some(name) = e.file_name().to_str().map(str::to_string) else { continue };
        if !name.starts_with(prefix) || !e.file_type().is_ok_and(|t| t.is_dir()) {
            continue;
        }
        let dir = e.path();
        let abandoned = match File::open(dir.join(LOCK)) {
            Ok(lock) => lock.try_lock().is_ok(),
            Err(_) => name[prefix.len()..].parse::<u32>().is_ok_and(|pid| {
                cfg!(target_os = "linux") && !Path::new(&format!("/proc/{pid}")).exists()
            }),
        };
        if abandoned && std::fs::remove_dir_all(&dir).is_ok() {
            removed.push(dir);
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_held_folder_stays_and_an_abandoned_one_goes() {
        let parent = std::env::temp_dir().join(format!("sylva-workdir-{}", std::process::id()));
        let (held, dead) = (parent.join("w-held"), parent.join("w-dead"));
        let lock = claim(&held, "cache").unwrap();
        assert!(claim(&held, "cache").is_err(), "one process per folder");
        drop(claim(&dead, "cache").unwrap());
        std::fs::write(dead.join("bundle"), b"x").unwrap();
        assert_eq!(remove_abandoned(&parent, "w-"), vec![dead.clone()]);
        assert!(held.exists() && !dead.exists());
        drop(lock);
        std::fs::remove_dir_all(&parent).unwrap();
    }
}
