//! The one error type of this crate.

use std::path::PathBuf;

/// Everything that can go wrong in `ppfd-models`. Messages say what was wrong with the input and
/// what was expected.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading a file failed at the operating-system level.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file was refused before it was parsed: not a regular file, or larger than its limit.
    #[error("{path}: {reason}")]
    File { path: PathBuf, reason: String },
    /// A PLY file could not be read into a mesh; `reason` says what and where.
    #[error("{path}: malformed PLY: {reason}")]
    Ply { path: PathBuf, reason: String },
    /// A mesh (read or generated) cannot be used, e.g. it is empty.
    #[error("invalid mesh: {0}")]
    InvalidMesh(String),
    /// A depth frame does not match its own header, or its intrinsics are unusable.
    #[error("invalid depth frame: {0}")]
    InvalidFrame(String),
    /// A parameter is out of its valid range.
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// An object id that no model of the set has (a BOP result scored against a dataset's
    /// models, in `ppfd-bop`; the daemon checks its requests' ids itself).
    #[error("unknown object id {0}")]
    UnknownObject(u32),
    /// A model store file was refused (truncated, corrupted, wrong version or parameters).
    #[error("{path}: model file refused: {reason}")]
    ModelStore { path: PathBuf, reason: String },
    /// The caller's deadline passed before the detection finished.
    #[error("deadline exceeded after {elapsed:?}")]
    DeadlineExceeded { elapsed: std::time::Duration },
    /// The caller cancelled the detection ([`crate::detect::detector::RunOptions::cancel`]).
    #[error("cancelled after {elapsed:?}")]
    Cancelled { elapsed: std::time::Duration },
    /// A dataset file (BOP layout) is missing or malformed; `reason` says what was wrong.
    #[error("{path}: {reason}")]
    Dataset { path: PathBuf, reason: String },
}

/// `Result` with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
