//! What robot and camera processes link to talk to the `ppfd` daemon over iceoryx2 shared memory.
//! Light: the protocol, iceoryx2 and a few small crates, no matching engine (the `ppf` command
//! line is the crate `ppfd-cli`).
//!
//! - [`Client`] opens the daemon's services; [`Client::detect`] asks for objects in the newest
//!   frame of a camera and returns [`Detections`]: pose hypotheses and a [`Latency`] breakdown.
//!   [`Client::detect_inline`] sends a frame of its own instead. Control: [`Client::models`],
//!   [`Client::load_model`], [`Client::drop_model`], [`Client::stats`].
//! - [`CameraPublisher`] is the driver side: it loans a shared-memory slice, the driver writes
//!   the depth straight into it, and [`ReadyFrame::send`] publishes it (no copy after that).
//!   Between frames the driver waits with [`CameraPublisher::idle`], so that a daemon that
//!   subscribes late still gets the newest frame.
//!
//! Ports are not `Send`: use one `Client` per thread.
//!
//! ```no_run
//! use ppfd_client::{Client, DetectOptions};
//! let client = Client::connect()?;
//! let found = client.detect("kinect", &[1, 5], &DetectOptions::default())?;
//! for h in &found.hypotheses {
//!     println!("object {} at {:?} mm, score {:.2}", h.object_id, h.translation_mm, h.score);
//! }
//! println!("overhead {} µs", found.latency.overhead_ns() / 1000);
//! # Ok::<(), ppfd_client::Error>(())
//! ```

mod camera;
mod client;

pub use camera::{CameraPublisher, CameraViewer, FrameLoan, ReadyFrame};
pub use client::{
    Client, ClientOptions, DetectOptions, Detections, InterruptCheck, Latency, ModelListing,
};
pub use ppfd_protocol as protocol;
pub use ppfd_protocol::clock::monotonic_now_ns;
pub use ppfd_protocol::control::{DaemonStats, ModelInfo};
pub use ppfd_protocol::detect::{
    checks, order, DetectCounts, LatencyBreakdown, PoseHint, PoseHypothesis, PoseRestriction,
    RegionOfInterest, Requirements, Status,
};
pub use ppfd_protocol::frame::{FrameHeader, Intrinsics};

/// A duration in whole milliseconds, rounded: the timeout a caller gave, though the wait
/// measured it from a later start (2000 ms, not 1.999999642 s).
fn millis(d: &std::time::Duration) -> u128 {
    (d.as_nanos() + 500_000) / 1_000_000
}

/// What can go wrong talking to the daemon.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The daemon answered with a refusal.
    #[error("refused ({status}): {message}")]
    Refused {
        /// Why.
        status: Status,
        /// The daemon's explanation.
        message: String,
        /// The status's value: the unknown object id, the stale frame's age in ns, ...
        value: u64,
    },
    /// No answer within the timeout.
    #[error("no answer from ppfd within {} ms: the daemon is busy, slow or stopped (a longer timeout waits more)", millis(.0))]
    Timeout(std::time::Duration),
    /// The daemon let go of the request without answering it (it will not answer; sending the
    /// request again is safe).
    #[error("ppfd let go of the request without an answer; send it again")]
    Dropped,
    /// The daemon's process ended (it was killed or crashed) while the request waited for its
    /// answer.
    #[error("ppfd exited while the request waited for its answer (killed or crashed); the request is lost, send it again once a daemon serves")]
    DaemonGone,
    /// A signal arrived while the request waited, and the client's interrupt check
    /// ([`crate::Client::set_interrupt_check`]) asked to stop waiting: the request is abandoned
    /// (the daemon finishes it and counts it abandoned).
    #[error("interrupted by a signal while the request waited for its answer")]
    Interrupted,
    /// No daemon serves under this client's prefix.
    #[error("no ppfd daemon is serving {service} under the iceoryx2 prefix {prefix:?}; start one (ppfd --models <dir>), or give the daemon's prefix (--prefix, or PPFD_PREFIX)")]
    NoDaemon {
        /// The service without a server (`ppfd/detect`, `ppfd/control`).
        service: &'static str,
        /// The iceoryx2 prefix the client looked under.
        prefix: String,
    },
    /// A live driver already publishes under that camera name. A camera has one live driver;
    /// a driver that replaces a dead one is let in.
    #[error("another driver already publishes as camera {camera:?} (a camera has one live driver; one that replaces a dead driver is let in): stop that driver, or publish under another camera name")]
    CameraTaken {
        /// The camera's name.
        camera: String,
    },
    /// The request was malformed before it was sent.
    #[error("{0}")]
    Protocol(#[from] ppfd_protocol::ProtocolError),
    /// A detect call on a client connected to send control requests only
    /// ([`ClientOptions::detects`] `false`).
    #[error("this client was connected for control requests only (ClientOptions::detects false): connect one that detects")]
    ControlOnly,
    /// At `connect`: the daemon serves as many clients as it can. Connect again once one has
    /// disconnected (or its process ended).
    #[error("{what}: {max} clients are connected to the daemon, the most it serves at once; one must disconnect (or its process end) first")]
    TooManyClients {
        /// The port that could not be made.
        what: &'static str,
        /// The most clients a daemon serves at once.
        max: usize,
    },
    /// At `connect`: the daemon serves the messages of another protocol version than this
    /// client's. Connecting again does not help: the daemon and its clients must come from the
    /// same ppfd release.
    #[error("cannot open {service}: it is served with the messages of another protocol version than this client's ({version}); the daemon and its clients must come from the same ppfd release")]
    OtherProtocolVersion {
        /// The service (`ppfd/detect`, `ppfd/control`).
        service: &'static str,
        /// This client's [`ppfd_protocol::PROTOCOL_VERSION`].
        version: u32,
    },
    /// An iceoryx2 operation failed (shared memory, a port). The `Client` stays usable: its
    /// next request is sent afresh; one whose every request fails so is best made anew.
    #[error("{0}")]
    Transport(String),
}

/// `Result` with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

pub(crate) fn transport<E: std::fmt::Debug>(what: &'static str) -> impl FnOnce(E) -> Error {
    move |e| Error::Transport(format!("{what}: {e:?}"))
}

/// The iceoryx2 configuration for a prefix (`None`: `PPFD_PREFIX`, else iceoryx2's default), as
/// the daemon takes its own: a client, a camera driver and a viewer given no prefix all meet
/// the daemon started in the same environment.
pub(crate) fn iceoryx_config(prefix: Option<&str>) -> Result<iceoryx2::config::Config> {
    let mut config = iceoryx2::config::Config::default();
    if let Some(prefix) = ppfd_protocol::services::prefix_or_env(prefix)?.as_deref() {
        use iceoryx2::prelude::SemanticString;
        ppfd_protocol::services::check_prefix(prefix)?;
        config.global.prefix = iceoryx2::prelude::FileName::new(prefix.as_bytes())
            .map_err(|e| Error::Transport(format!("iceoryx2 prefix {prefix:?}: {e:?}")))?;
    }
    Ok(config)
}

pub use ppfd_protocol::services::prefix_from_env;

/// Removes the files iceoryx2 leaves behind under `prefix` once every process using it has
/// ended ([`ppfd_protocol::services::remove_prefix_leftovers`]). Returns how many entries were
/// removed; refuses a prefix a running daemon serves.
pub fn remove_prefix_leftovers(prefix: &str) -> Result<usize> {
    Ok(ppfd_protocol::services::remove_prefix_leftovers(prefix)?)
}
