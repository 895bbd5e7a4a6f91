//! Which files a scene may read. A scene from the network reads only files
//! inside its bundle; a local scene only files inside its own folder unless
//! the user allows more. Paths are checked lexically first (no absolute
//! paths, no `..`, no URI schemes) and then by their canonical location, so
//! a symbolic link cannot lead out either. Errors name the path as the scene
//! wrote it and never say whether anything outside exists.

use crate::{Error, Result};
use std::path::{Component, Path, PathBuf};

/// Where a scene's files may come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FileAccess {
    /// Only files inside this folder (the bundle's or the scene file's).
    Inside(PathBuf),
    /// Any file the process can read, relative paths against this folder
    /// (a local render whose user asked for it).
    Anywhere(PathBuf),
}

impl FileAccess {
    /// The folder relative paths start from.
    pub fn base(&self) -> &Path {
        match self {
            FileAccess::Inside(p) | FileAccess::Anywhere(p) => p,
        }
    }

    /// The file `rel` (as a scene or model names it, relative to `from`, a
    /// folder inside the base) may be read: its full path, or why not.
    pub fn resolve(&self, from: &Path, rel: &Path) -> Result<PathBuf> {
        match self {
            FileAccess::Anywhere(_) => {
                let full = if rel.is_absolute() { rel.to_path_buf() } else { from.join(rel) };
                if !full.is_file() {
                    return Err(Error::Missing { path: full });
                }
                Ok(full)
            }
            FileAccess::Inside(root) => {
                // One answer for every refusal, so it tells nothing of outside.
                let outside = || Error::Outside { path: rel.to_path_buf() };
                if rel.as_os_str().is_empty()
                    || rel.is_absolute()
                    || rel
                        .components()
                        .any(|c| !matches!(c, Component::Normal(_) | Component::CurDir))
                {
                    return Err(outside());
                }
                let full = from.join(rel);
                // A bare file name's folder is the empty path: the current one.
                let root = if root.as_os_str().is_empty() { Path::new(".") } else { root };
                let (Ok(canon), Ok(root)) = (full.canonicalize(), root.canonicalize()) else {
                    return Err(outside());
                };
                if !canon.starts_with(&root) || !canon.is_file() {
                    return Err(outside());
                }
                Ok(canon)
            }
        }
    }

    /// The file a glTF buffer or image URI names, relative to the glTF file's
    /// folder `from`: `None` for a `data:` URI (the bytes are inline), else
    /// the checked path. Other schemes (`file:`, `http:`) are refused.
    pub fn resolve_uri(&self, from: &Path, uri: &str) -> Result<Option<PathBuf>> {
        if uri.starts_with("data:") {
            return Ok(None);
        }
        if uri.contains(':') {
            return Err(Error::Uri {
                uri: clip(uri),
                why: "has a scheme other than data: (only relative paths and data: URIs are read)",
            });
        }
        let decoded = percent_decode(uri).ok_or_else(|| Error::Uri {
            uri: clip(uri),
            why: "is not valid percent-encoded UTF-8",
        })?;
        self.resolve(from, Path::new(&decoded)).map(Some)
    }
}

/// At most 80 characters of `s`, [`escaped`], for error messages about
/// hostile input.
pub fn clip(s: &str) -> String {
    printable(s, 80)
}

/// At most `max` characters of `s` (an ellipsis marks a cut), with
/// control and bidirectional formatting characters [`escaped`]: a string
/// from outside (a worker's error, a client's name) as it may be printed
/// or logged.
pub fn printable(s: &str, max: usize) -> String {
    match s.char_indices().nth(max) {
        Some((i, _)) => format!("{}…", escaped(&s[..i])),
        None => escaped(s),
    }
}

/// Whether `c` may not reach a terminal or a log as it is: a control
/// character (an escape sequence retitles or clears a terminal that
/// prints it, a newline forges a log line) or a bidirectional formatting
/// character (U+202E turns the rest of a line around).
pub fn unprintable(c: char) -> bool {
    c.is_control()
        || matches!(c, '\u{061C}' | '\u{200E}' | '\u{200F}' | '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}')
}

/// `s` with every [`unprintable`] character written as `\u{…}`.
pub fn escaped(s: &str) -> String {
    if !s.chars().any(unprintable) {
        return s.to_string();
    }
    s.chars()
        .map(|c| if unprintable(c) { format!("\\u{{{:x}}}", c as u32) } else { c.to_string() })
        .collect()
}

/// Decodes `%XX` escapes as the glTF loader does; `None` if the result is not UTF-8.
pub(crate) fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = b.get(i + 1..i + 3).filter(|h| h.iter().all(u8::is_ascii_hexdigit))?;
            let hex = std::str::from_utf8(hex).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sylva-files-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("inside/sub")).unwrap();
        std::fs::write(d.join("inside/sub/model.glb"), b"x").unwrap();
        std::fs::write(d.join("secret.glb"), b"s").unwrap();
        d
    }

    #[test]
    fn only_files_inside_the_folder_resolve_and_errors_say_nothing_of_outside() {
        let d = scratch("inside");
        let root = d.join("inside");
        let a = FileAccess::Inside(root.clone());
        assert!(a.resolve(&root, Path::new("sub/model.glb")).is_ok());
        assert!(a.resolve(&root, Path::new("./sub/model.glb")).is_ok());
        let outside = [
            d.join("secret.glb"),
            PathBuf::from("../secret.glb"),
            PathBuf::from("sub/../../secret.glb"),
            PathBuf::from("/etc/passwd"),
        ];
        for p in &outside {
            let e = a.resolve(&root, p).unwrap_err().to_string();
            // It names the path as given, and says nothing of what is there.
            assert!(
                !e.contains("exist") && !e.contains("bytes") && !e.contains("No such file"),
                "{e}"
            );
        }
        // Existing and missing files outside get the same answer.
        assert_eq!(
            a.resolve(&root, Path::new("../secret.glb"))
                .unwrap_err()
                .to_string()
                .replace("secret", "X"),
            a.resolve(&root, Path::new("../nothere.glb"))
                .unwrap_err()
                .to_string()
                .replace("nothere", "X")
        );
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(d.join("secret.glb"), root.join("link.glb")).unwrap();
            assert!(a.resolve(&root, Path::new("link.glb")).is_err(), "a symlink leads out");
        }
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn uris_other_than_data_and_relative_paths_are_refused() {
        let d = scratch("uri");
        let root = d.join("inside");
        let a = FileAccess::Inside(root.clone());
        assert_eq!(
            a.resolve_uri(&root, "data:application/octet-stream;base64,AAAA").unwrap(),
            None
        );
        assert!(a.resolve_uri(&root, "sub/model.glb").unwrap().is_some());
        assert!(a.resolve_uri(&root, "sub%2Fmodel.glb").unwrap().is_some());
        for bad in [
            "file:///etc/passwd",
            "file:../secret.glb",
            "../../../../etc/passwd",
            "http://example.com/x.bin",
            "%2E%2E/secret.glb",
            "%FF%FE",
            "/etc/shadow",
        ] {
            assert!(a.resolve_uri(&root, bad).is_err(), "{bad}");
        }
        std::fs::remove_dir_all(&d).ok();
    }
}
