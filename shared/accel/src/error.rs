//! The crate's one error type and its `Result`.

use crate::AccelKind;

/// `Result` with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// A structure built elsewhere (another worker's, received over the wire)
/// that cannot be walked safely, or does not belong to the scene.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Nodes or primitive lists that do not fit together: a walk could
    /// loop or read out of bounds.
    #[error("{0}")]
    Malformed(String),
    /// Not one structure per model.
    #[error("{given} model structures for a scene of {models} models")]
    ModelCount {
        /// Structures given.
        given: usize,
        /// Models in the scene.
        models: usize,
    },
    /// A structure of another kind than the one asked for.
    #[error("model {model}: a {got:?} where a {want:?} was asked for")]
    WrongKind {
        /// The model's index.
        model: usize,
        /// The kind given.
        got: AccelKind,
        /// The kind asked for.
        want: AccelKind,
    },
    /// One model's structure is malformed.
    #[error("model {model} ({name}): {error}")]
    Model {
        /// The model's index.
        model: usize,
        /// Its name in the scene.
        name: String,
        /// What is wrong with its structure.
        error: Box<Error>,
    },
}

/// The message alone, for callers that report errors as text.
impl From<Error> for String {
    fn from(e: Error) -> String {
        e.to_string()
    }
}
