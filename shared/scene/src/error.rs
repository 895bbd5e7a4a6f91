//! The crate's one error type and its `Result`.
//!
//! Each variant's text is the whole message, its causes included
//! ("`scene.glb: cannot read glTF: …`"), so `{}` and `{:#}` print the same
//! and wrapping it in `anyhow` (whose `{:#}` adds the `source()` chain)
//! repeats nothing: the causes are fields, not `source()`s. A scene file's
//! own faults keep their type, [`SceneError`] (file, field, message).

use crate::load::SceneError;
use std::path::PathBuf;

/// `Result` with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// What can go wrong reading, checking, packing or writing a scene.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scene file that cannot be used: the file, the field, what is wrong.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// A file the scene names lies outside what it may read (or is not a
    /// file there); one answer for every refusal, so it tells nothing of
    /// outside.
    #[error(
        "{:?} is not a file inside the scene's folder (scenes name files by relative paths, without \"..\")",
        path.display()
    )]
    Outside {
        /// The path as the scene wrote it.
        path: PathBuf,
    },
    /// A file the scene names is not there (a local scene allowed to read
    /// anywhere).
    #[error("missing file {}", path.display())]
    Missing {
        /// The full path.
        path: PathBuf,
    },
    /// A glTF URI that is never read: another scheme than `data:`, or bad
    /// percent-encoding.
    #[error("URI {uri:?} {why}")]
    Uri {
        /// The URI, clipped for printing.
        uri: String,
        /// Why it is refused.
        why: &'static str,
    },
    /// A file that cannot be read, written or created.
    #[error("{file}: {what}: {}", chain(error))]
    File {
        /// The file, as messages show it.
        file: String,
        /// What was being done ("cannot read", "cannot write").
        what: String,
        /// Why.
        error: std::io::Error,
    },
    /// Reading or writing where the file is named around it.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// A glTF file that cannot be read or used: malformed, no scene, no
    /// such mesh, bad accessors or geometry.
    #[error("{file}: {message}")]
    Gltf {
        /// The file, as messages show it.
        file: String,
        /// What is wrong (its causes included).
        message: String,
    },
    /// More than a cap allows (triangles, texels, placements, bytes).
    #[error("{file}: {message}")]
    Limit {
        /// The file (or part) that is too large.
        file: String,
        /// How much, and the cap.
        message: String,
    },
    /// An image that cannot be read, decoded or written.
    #[error("{context}: {}", chain(error))]
    Image {
        /// The file and what was being done.
        context: String,
        /// Why.
        error: image::ImageError,
    },
    /// An image that cannot be encoded or written, where the file is named
    /// around it.
    #[error(transparent)]
    Codec(#[from] image::ImageError),
    /// A multi-layer OpenEXR that cannot be written or read.
    #[error("{context}: {}", chain(error))]
    Exr {
        /// What was being done.
        context: String,
        /// Why.
        error: exr::error::Error,
    },
    /// JSON that cannot be read.
    #[error("{context}: {}", chain(error))]
    Json {
        /// The file and what was being read.
        context: String,
        /// Why.
        error: serde_json::Error,
    },
    /// A scene bundle that is not one, or is cut short or padded.
    #[error("{0}")]
    Bundle(String),
    /// An error about one file, field or frame of several: its name first.
    #[error("{context}: {error}")]
    In {
        /// The file, field or frame.
        context: String,
        /// What is wrong with it.
        error: Box<Error>,
    },
    /// A camera that cannot be built.
    #[error("camera: {0}")]
    Camera(crate::camera::CameraError),
    /// Inputs that are out of range or do not fit together.
    #[error("{0}")]
    Invalid(String),
}

impl Error {
    /// `self` about `context` (a file, a field, a frame): its text after
    /// the context's.
    pub fn within(self, context: impl Into<String>) -> Error {
        Error::In { context: context.into(), error: Box::new(self) }
    }

    /// An [`Error::File`].
    pub(crate) fn file(
        file: impl std::fmt::Display,
        what: impl Into<String>,
        error: std::io::Error,
    ) -> Self {
        Error::File { file: file.to_string(), what: what.into(), error }
    }

    /// An [`Error::Gltf`].
    pub(crate) fn gltf(file: impl std::fmt::Display, message: impl Into<String>) -> Self {
        Error::Gltf { file: file.to_string(), message: message.into() }
    }

    /// An [`Error::Limit`].
    pub(crate) fn limit(file: impl std::fmt::Display, message: impl Into<String>) -> Self {
        Error::Limit { file: file.to_string(), message: message.into() }
    }
}

/// The message alone, for callers that report errors as text.
impl From<Error> for String {
    fn from(e: Error) -> String {
        e.to_string()
    }
}

/// `error` and its causes, as `anyhow`'s `{:#}` prints them: "outer: inner".
pub(crate) fn chain(error: &dyn std::error::Error) -> String {
    let mut s = error.to_string();
    let mut next = error.source();
    while let Some(e) = next {
        s.push_str(": ");
        s.push_str(&e.to_string());
        next = e.source();
    }
    s
}
