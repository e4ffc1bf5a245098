//! The one error type of this crate.

use std::path::PathBuf;

/// Everything that can go wrong in `ppfd-bop`: a dataset's files, a results file, and what
/// `ppfd-models` reports for the meshes and depth images it reads for it.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file failed at the operating-system level.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// A dataset file (BOP layout) or a results file is missing or malformed; `reason` says
    /// what was wrong, and where.
    #[error("{path}: {reason}")]
    Dataset {
        /// The file.
        path: PathBuf,
        /// What was wrong, and where in the file.
        reason: String,
    },
    /// A scoring option or a symmetry out of its valid range.
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// An object id that no model of the dataset has (a result scored against its models).
    #[error("unknown object id {0}")]
    UnknownObject(u32),
    /// A mesh, depth image or file that `ppfd-models` refused.
    #[error(transparent)]
    Models(ppfd_models::Error),
}

impl From<ppfd_models::Error> for Error {
    /// `ppfd-models`' error, its operating-system failures as this crate's own [`Error::Io`]:
    /// one form of a failed read, whichever crate opened the file.
    fn from(e: ppfd_models::Error) -> Error {
        match e {
            ppfd_models::Error::Io { path, source } => Error::Io { path, source },
            other => Error::Models(other),
        }
    }
}

/// `Result` with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
