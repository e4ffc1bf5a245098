//! The daemon's one error type: a configuration it refuses before it serves, or a resource it
//! needs failing while it starts or serves. What a request is refused for is no error of the
//! daemon's: it is an answer to the client, [`crate::engine::EngineError`], with the status the
//! client gets.

use std::path::PathBuf;

use crate::config::{MAX_QUEUE_CAPACITY, MAX_THREADS, MAX_THREADS_PER_CORE};

/// Why the daemon cannot start or had to stop. The configuration's variants come before it
/// serves (the command line exits with code 2); the others while it starts or serves (code 1).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The configuration file cannot be read: missing, not a regular file, too large, not text.
    #[error("{0}")]
    ConfigRead(#[source] ppfd_models::Error),
    /// The configuration file is not TOML, or not the settings' (an unknown key, a value of the
    /// wrong kind).
    #[error("{}: {source}", path.display())]
    ConfigSyntax {
        /// The configuration file.
        path: PathBuf,
        /// The cause, with the line and column.
        #[source]
        source: toml::de::Error,
    },
    /// Configuration text that is not TOML, or not the settings'.
    #[error(transparent)]
    Toml(#[from] toml::de::Error),
    /// A detector parameter refused, with `ppfd_models`' message: its name, the value and what
    /// was expected.
    #[error("{0}")]
    DetectorParameter(String),
    /// A `--set` flag that is not `stage.field=value`.
    #[error("--set takes stage.field=value, got {0:?}")]
    SetSyntax(String),
    /// `parallel_detections` is 0.
    #[error("parallel_detections must be at least 1")]
    NoParallelDetections,
    /// `workers` or `parallel_detections` above [`MAX_THREADS_PER_CORE`] per core, or
    /// [`MAX_THREADS`].
    #[error(
        "workers ({workers}) and parallel_detections ({parallel_detections}) may be at most \
         {max} on {cores} cores ({per_core} per core, never above {all}): each is a thread or a \
         detection's scratch memory, and beyond that they only take turns",
        per_core = MAX_THREADS_PER_CORE,
        all = MAX_THREADS
    )]
    TooManyThreads {
        /// The `workers` setting.
        workers: usize,
        /// The `parallel_detections` setting.
        parallel_detections: usize,
        /// Cores available to the process.
        cores: usize,
        /// The bound on each: per-core bound × `cores`, never above [`MAX_THREADS`].
        max: usize,
    },
    /// A number above its bound.
    #[error("{key} may be at most {max} (was {value})")]
    TooLarge {
        /// The setting.
        key: &'static str,
        /// Its value, in the setting's unit.
        value: u64,
        /// Its bound, in the same unit.
        max: u64,
    },
    /// `max_frame_pixels` is 0.
    #[error("max_frame_pixels must be at least 1")]
    NoFramePixels,
    /// `queue_capacity` out of 1 to [`MAX_QUEUE_CAPACITY`].
    #[error("queue_capacity must be 1 to {max} (was {0})", max = MAX_QUEUE_CAPACITY)]
    QueueCapacity(usize),
    /// `housekeeping_ms` is 0.
    #[error("housekeeping_ms must be at least 1")]
    NoHousekeepingPeriod,
    /// `max_frame_age_ms` is 0.
    #[error(
        "max_frame_age_ms must be at least 1: every camera frame is older than 0 ms by the time \
         a detection starts"
    )]
    NoFrameAge,
    /// A prefix iceoryx2 cannot take, with `ppfd_protocol::services::check_prefix`'s message
    /// (which names `PPFD_PREFIX` when the prefix came from it).
    #[error("{0}")]
    Prefix(String),
    /// The models folder cannot be listed.
    #[error("model directory {}: {source}", path.display())]
    ModelDirectory {
        /// The models folder.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// Another daemon serves under the prefix.
    #[error(
        "another ppfd already serves with this prefix ({servers} servers on {service}); stop it \
         first"
    )]
    AlreadyServing {
        /// Servers on the service, this daemon's included.
        servers: usize,
        /// The service's name (`ppfd/detect` or `ppfd/control`).
        service: &'static str,
    },
    /// Two daemons already listen on `ppfd/daemon` under the prefix, the most there may be
    /// (one serving and one replacing a dead one): others starting at the same time.
    #[error(
        "other ppfd daemons are starting or serving with this prefix ({listeners} listen on \
         ppfd/daemon, the most there may be); stop them first"
    )]
    DaemonsStarting {
        /// Daemons listening already.
        listeners: usize,
    },
    /// A request/response service is held open, under this prefix, with the messages of
    /// another protocol version: clients or a daemon of another ppfd release still run.
    #[error(
        "cannot open {service}: processes of another ppfd release (protocol version other than \
         {version}) hold it under this prefix; stop them, so that the daemon and its clients \
         come from one release, or give this daemon another --prefix"
    )]
    OtherProtocolVersion {
        /// The service's name (`ppfd/detect` or `ppfd/control`).
        service: &'static str,
        /// This daemon's protocol version.
        version: u32,
    },
    /// An iceoryx2 or operating-system resource the daemon needs failed (a node, a port, a
    /// thread, the signalfd, the WaitSet): `what` it was, and the cause as it was reported.
    #[error("{what}: {detail}")]
    Resource {
        /// What failed, as a phrase ("cannot create the WaitSet").
        what: String,
        /// The cause, as the failing call reported it.
        detail: String,
    },
    /// The housekeeping thread could not be started.
    #[error("cannot start the housekeeping thread: {0}")]
    HousekeeperThread(#[source] std::io::Error),
    /// The housekeeping thread ended before it was ready.
    #[error("the housekeeping thread died at start")]
    HousekeeperDied,
}

/// A result with the daemon's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// The [`Error::Resource`] of `what` failing with the error it gave (written as its `Debug`,
/// which for iceoryx2's errors names the case).
pub(crate) fn resource<E: std::fmt::Debug>(what: &str) -> impl FnOnce(E) -> Error + '_ {
    move |e| Error::Resource {
        what: what.to_owned(),
        detail: format!("{e:?}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Scripts and operators match on these lines: each says what was wrong and what is taken.
    #[test]
    fn messages_name_the_setting_and_what_it_takes() {
        let cases = [
            (
                Error::TooManyThreads {
                    workers: 300,
                    parallel_detections: 1,
                    cores: 2,
                    max: 8,
                },
                "workers (300) and parallel_detections (1) may be at most 8 on 2 cores (4 per \
                 core, never above 256): each is a thread or a detection's scratch memory, and \
                 beyond that they only take turns",
            ),
            (
                Error::TooLarge {
                    key: "housekeeping_ms",
                    value: u64::MAX,
                    max: 60_000,
                },
                "housekeeping_ms may be at most 60000 (was 18446744073709551615)",
            ),
            (
                Error::QueueCapacity(0),
                "queue_capacity must be 1 to 4096 (was 0)",
            ),
            (
                Error::NoFrameAge,
                "max_frame_age_ms must be at least 1: every camera frame is older than 0 ms by \
                 the time a detection starts",
            ),
            (
                Error::SetSyntax("voting.reference_step".into()),
                "--set takes stage.field=value, got \"voting.reference_step\"",
            ),
            (
                Error::AlreadyServing {
                    servers: 2,
                    service: "ppfd/detect",
                },
                "another ppfd already serves with this prefix (2 servers on ppfd/detect); stop \
                 it first",
            ),
            (
                resource("cannot create the WaitSet")("Failure"),
                "cannot create the WaitSet: \"Failure\"",
            ),
            (
                Error::ModelDirectory {
                    path: "/m".into(),
                    source: std::io::Error::from(std::io::ErrorKind::NotFound),
                },
                "model directory /m: entity not found",
            ),
        ];
        for (error, message) in cases {
            assert_eq!(error.to_string(), message);
        }
    }
}
