//! The Python package `ppfd`: the client library `ppfd-client` for Python, so that the wire
//! contract has one source of truth.
//!
//! - `Client` asks the daemon for objects (`detect`), and lists, loads and drops its models
//!   and reads its statistics; it releases the GIL while it waits.
//! - `CameraPublisher` is a camera driver: `publish` copies a uint16 numpy array into a loaned
//!   shared-memory frame, which the daemon then reads in place.
//! - Errors are one hierarchy under `ppfd.Error` (`errors.rs`), with the Rust messages.
//!
//! `ppfd.pyi` holds the type hints; docs/PYTHON.md the guide.

mod camera;
mod client;
mod errors;
mod requirements;
mod thread;

use pyo3::prelude::*;

/// `CLOCK_MONOTONIC` now, nanoseconds: the clock of frame capture times and of the daemon.
#[pyfunction]
fn monotonic_now_ns() -> u64 {
    ppfd_client::monotonic_now_ns()
}

/// Removes what iceoryx2 leaves under `prefix` once every process using it has ended (for a
/// prefix made for one run, as tests do; never one that processes still use). Returns how many
/// entries were removed.
#[pyfunction]
fn remove_prefix_leftovers(py: Python<'_>, prefix: &str) -> PyResult<usize> {
    ppfd_client::remove_prefix_leftovers(prefix).map_err(|e| errors::to_py(py, e))
}

#[pymodule]
fn ppfd(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("PROTOCOL_VERSION", ppfd_client::protocol::PROTOCOL_VERSION)?;
    m.add_class::<client::Client>()?;
    m.add_class::<client::Detections>()?;
    // A sequence to `isinstance` and type checkers as well as to `len`, indexing and `for`.
    m.py()
        .import("collections.abc")?
        .getattr("Sequence")?
        .call_method1("register", (m.getattr("Detections")?,))?;
    m.add_class::<client::Detection>()?;
    m.add_class::<client::Checks>()?;
    m.add_class::<camera::CameraPublisher>()?;
    m.add_function(wrap_pyfunction!(monotonic_now_ns, m)?)?;
    m.add_function(wrap_pyfunction!(remove_prefix_leftovers, m)?)?;
    errors::register(m)
}
