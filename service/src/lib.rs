//! The ppfd daemon: holds object models in memory and answers detect requests from co-located
//! processes over iceoryx2 shared memory.
//!
//! - [`daemon::run`] receives on one I/O thread that sleeps on a WaitSet, keeps the newest frame
//!   of each camera as the shared-memory sample itself, queues requests, and runs detections on a
//!   rayon pool, whose workers answer through the [`responder::Responder`];
//!   [`housekeeper::Housekeeper`] removes what dead processes left and discovers cameras on a
//!   thread of its own.
//! - A [`engine::DetectionEngine`] does the matching: [`ppf_engine::PpfEngine`] wraps
//!   `ppfd_models`; the daemon itself knows nothing of the method.
//! - [`model_cache::load_or_build`] gives the model of a mesh, built once and reused while the
//!   mesh is unchanged: for the daemon, and for `ppf`'s offline commands and demo.
//! - [`registry::Registry`] holds the loaded models; [`config::DaemonConfig`] the settings (TOML
//!   file and flags); [`stats::Stats`] the counters and latency histograms.
//! - [`Error`] says why the daemon refused its configuration, or could not start or serve.
//!
//! The wire contract is `ppfd_protocol`; clients use `ppfd_client`.

#![warn(missing_docs)]

pub mod cli;
pub mod config;
pub mod daemon;
pub mod engine;
pub mod error;
pub mod housekeeper;
pub mod model_cache;
pub mod ppf_engine;
pub mod registry;
pub mod responder;
pub mod stats;
pub mod termination;
#[cfg(test)]
mod test_log;
pub mod wakeup;

pub use config::DaemonConfig;
pub use daemon::run;
pub use engine::DetectionEngine;
pub use error::{Error, Result};
