//! The one error type of this crate.

use std::path::PathBuf;

/// Everything that can go wrong in `ppfd-models`. Messages say what was wrong with the input and
/// what was expected.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading a file failed at the operating-system level.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// A file was refused: not a regular file, larger than its limit, or (read for a mesh's
    /// model, as a `models_info.json` beside it) malformed.
    #[error("{path}: {reason}")]
    File {
        /// The file.
        path: PathBuf,
        /// Why it was refused.
        reason: String,
    },
    /// A PLY file could not be read into a mesh; `reason` says what and where.
    #[error("{path}: malformed PLY: {reason}")]
    Ply {
        /// The file.
        path: PathBuf,
        /// What was wrong, and where in the file.
        reason: String,
    },
    /// A mesh (read or generated) cannot be used, e.g. it is empty.
    #[error("invalid mesh: {0}")]
    InvalidMesh(String),
    /// A depth frame does not match its own header, or its intrinsics are unusable.
    #[error("invalid depth frame: {0}")]
    InvalidFrame(String),
    /// A parameter is out of its valid range.
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// A model store file was refused (truncated, corrupted, wrong version or parameters).
    #[error("{path}: model file refused: {reason}")]
    ModelStore {
        /// The model file.
        path: PathBuf,
        /// Why it was refused.
        reason: String,
    },
    /// The caller's deadline passed before the detection finished.
    #[error("deadline exceeded after {elapsed:?}")]
    DeadlineExceeded {
        /// How long the detection had run.
        elapsed: std::time::Duration,
    },
    /// The caller cancelled the detection ([`crate::detect::detector::RunOptions::cancel`]).
    #[error("cancelled after {elapsed:?}")]
    Cancelled {
        /// How long the detection had run.
        elapsed: std::time::Duration,
    },
}

/// `Result` with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
