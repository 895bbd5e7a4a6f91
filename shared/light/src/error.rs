//! The crate's one error type and its `Result`.
//!
//! Each variant's text is the whole message, its causes included
//! ("`d.npy: cannot open: No such file or directory`"), so `{}` and `{:#}`
//! print the same and wrapping it in `anyhow` repeats nothing.

use crate::lb::boundary::SunError;
use crate::lb::medium::MediumError;
use crate::lb::params::ParamError;
use crate::lb::solver::SolverError;
use std::path::PathBuf;

/// `Result` with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// What can go wrong in Sylva's lighting code.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// LB parameters out of range.
    #[error(transparent)]
    Param(#[from] ParamError),
    /// A medium grid that cannot be solved.
    #[error(transparent)]
    Medium(#[from] MediumError),
    /// A sun that cannot light the grid.
    #[error(transparent)]
    Sun(#[from] SunError),
    /// A [`LightingSolver`](crate::lb::LightingSolver) failed (the GPU's,
    /// say); its own error, chain and all.
    #[error(transparent)]
    Solver(#[from] SolverError),
    /// A file that cannot be opened, created or read.
    #[error("{}: {what}: {error}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// What was being done ("cannot open", "not a .npy file").
        what: &'static str,
        /// Why.
        error: std::io::Error,
    },
    /// Writing a stream whose file is already open.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// A density grid file that reads but is not one.
    #[error("{}: not a valid density grid: {error}", path.display())]
    Density {
        /// The file.
        path: PathBuf,
        /// What is wrong with its values.
        error: MediumError,
    },
    /// A file whose contents are not what was asked for: its shape, order
    /// or type.
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An image that cannot be written.
    #[error("{}: cannot write PNG: {error}", path.display())]
    Image {
        /// The file.
        path: PathBuf,
        /// Why.
        error: image::ImageError,
    },
    /// Inputs that do not fit together.
    #[error("{0}")]
    Invalid(String),
}
