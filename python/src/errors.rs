//! The exception hierarchy: one Python class per kind of `ppfd_client::Error`, and one per
//! refusal status under `Refused`. Each exception's message is the Rust error's.
//!
//! ```text
//! ppfd.Error
//! ├── Refused (.status, .value)     UnknownObject, UnknownCamera, NoFrame, CameraStale, ...
//! ├── Timeout                       also TimeoutError
//! ├── Dropped, DaemonGone, NoDaemon, CameraTaken, TransportError
//! └── ProtocolError                 also ValueError: malformed before it was sent
//! ```

use ppfd_client::{Error, Status};
use pyo3::exceptions::{PyException, PyTimeoutError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

/// The classes, made once per interpreter when the module is first imported.
struct Classes {
    error: Py<PyType>,
    refused: Py<PyType>,
    /// One subclass of `refused` per status but `Ok`, with its status.
    by_status: Vec<(Status, Py<PyType>)>,
    timeout: Py<PyType>,
    dropped: Py<PyType>,
    daemon_gone: Py<PyType>,
    no_daemon: Py<PyType>,
    camera_taken: Py<PyType>,
    protocol: Py<PyType>,
    transport: Py<PyType>,
    too_many_clients: Py<PyType>,
    other_protocol_version: Py<PyType>,
}

static CLASSES: PyOnceLock<Classes> = PyOnceLock::new();

/// Every status a response can carry but `Ok`, in wire-code order.
fn refusal_statuses() -> impl Iterator<Item = Status> {
    (1..).map_while(Status::from_code)
}

/// The class name of a refusal status: its Rust name (`CameraStale`).
fn class_name(status: Status) -> String {
    format!("{status:?}")
}

/// `type(name, bases, {"__doc__": doc, "__module__": "ppfd"})`: a class with several bases
/// (`Timeout` is a `ppfd.Error` and a `TimeoutError`).
fn new_class<'py>(
    py: Python<'py>,
    name: &str,
    bases: &[&Bound<'py, PyType>],
    doc: &str,
) -> PyResult<Py<PyType>> {
    let namespace = PyDict::new(py);
    namespace.set_item("__doc__", doc)?;
    namespace.set_item("__module__", "ppfd")?;
    let class = py
        .get_type::<PyType>()
        .call1((name, PyTuple::new(py, bases)?, namespace))?;
    Ok(class.cast_into::<PyType>()?.unbind())
}

fn classes(py: Python<'_>) -> PyResult<&Classes> {
    CLASSES.get_or_try_init(py, || {
        let exception = py.get_type::<PyException>();
        let error = new_class(
            py,
            "Error",
            &[&exception],
            "Anything that went wrong talking to the ppfd daemon.",
        )?;
        let e = error.bind(py);
        let refused = new_class(
            py,
            "Refused",
            &[e],
            "The daemon answered with a refusal: `status` names it (\"camera stale\"), and \
             `value` is what it refers to (the unknown object id, the stale frame's age in ns), \
             0 otherwise. Each status has a subclass of its own.",
        )?;
        let by_status = refusal_statuses()
            .map(|status| {
                let doc = format!("The daemon refused the request: {}.", status.name());
                new_class(py, &class_name(status), &[refused.bind(py)], &doc)
                    .map(|class| (status, class))
            })
            .collect::<PyResult<_>>()?;
        let transport = new_class(
            py,
            "TransportError",
            &[e],
            "An iceoryx2 operation failed (shared memory, ports, the client limit).",
        )?;
        Ok(Classes {
            timeout: new_class(
                py,
                "Timeout",
                &[e, &py.get_type::<PyTimeoutError>()],
                "No answer within the timeout.",
            )?,
            dropped: new_class(
                py,
                "Dropped",
                &[e],
                "The daemon let go of the request without an answer; sending it again is safe.",
            )?,
            daemon_gone: new_class(
                py,
                "DaemonGone",
                &[e],
                "The daemon's process ended while the request waited for its answer.",
            )?,
            no_daemon: new_class(
                py,
                "NoDaemon",
                &[e],
                "No daemon serves under this client's iceoryx2 prefix.",
            )?,
            camera_taken: new_class(
                py,
                "CameraTaken",
                &[e],
                "Another driver already publishes under this camera name.",
            )?,
            protocol: new_class(
                py,
                "ProtocolError",
                &[e, &py.get_type::<PyValueError>()],
                "The request or frame was malformed, found before it was sent.",
            )?,
            transport: transport.clone_ref(py),
            too_many_clients: new_class(
                py,
                "TooManyClients",
                &[transport.bind(py)],
                "At connect: the daemon serves as many clients as it can; connect again once one \
                 has gone.",
            )?,
            other_protocol_version: new_class(
                py,
                "OtherProtocolVersion",
                &[transport.bind(py)],
                "At connect: the daemon serves another protocol version; the daemon and its \
                 clients must come from the same ppfd release.",
            )?,
            error,
            refused,
            by_status,
        })
    })
}

/// Adds the classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    let c = classes(py)?;
    for class in [
        &c.error,
        &c.refused,
        &c.timeout,
        &c.dropped,
        &c.daemon_gone,
        &c.no_daemon,
        &c.camera_taken,
        &c.protocol,
        &c.transport,
        &c.too_many_clients,
        &c.other_protocol_version,
    ]
    .into_iter()
    .chain(c.by_status.iter().map(|(_, class)| class))
    {
        let class = class.bind(py);
        m.add(class.name()?, class)?;
    }
    Ok(())
}

/// The Python exception of a client error, with the Rust message.
pub fn to_py(py: Python<'_>, error: Error) -> PyErr {
    match raise(py, &error) {
        Ok(e) | Err(e) => e,
    }
}

thread_local! {
    /// What a Python signal handler raised while this thread's request waited
    /// ([`interrupt_check`]), for [`to_py`] to raise in place of `Error::Interrupted`.
    static RAISED_BY_A_HANDLER: std::cell::RefCell<Option<PyErr>> =
        const { std::cell::RefCell::new(None) };
}

/// The client's interrupt check: runs Python's signal handlers when a signal wakes the wait for
/// an answer. A handler that returns lets the wait go on (a watchdog timer, a SIGTERM handler
/// that sets a flag); one that raises (Ctrl-C's `KeyboardInterrupt`) ends it, and its exception
/// is what the call raises. Handlers run only on the main thread; elsewhere the wait goes on.
pub fn interrupt_check() -> ppfd_client::InterruptCheck {
    Box::new(|| {
        Python::attach(|py| match py.check_signals() {
            Ok(()) => false,
            Err(e) => {
                RAISED_BY_A_HANDLER.with(|slot| *slot.borrow_mut() = Some(e));
                true
            }
        })
    })
}

fn raise(py: Python<'_>, error: &Error) -> PyResult<PyErr> {
    let c = classes(py)?;
    let message = error.to_string();
    let class = match error {
        Error::Refused { status, value, .. } => {
            let class = c
                .by_status
                .iter()
                .find(|(s, _)| s == status)
                .map_or(&c.refused, |(_, class)| class);
            let exception = class.bind(py).call1((message,))?;
            exception.setattr("status", status.name())?;
            exception.setattr("value", *value)?;
            return Ok(PyErr::from_value(exception));
        }
        Error::Timeout(_) => &c.timeout,
        Error::Dropped => &c.dropped,
        Error::DaemonGone => &c.daemon_gone,
        Error::NoDaemon { .. } => &c.no_daemon,
        Error::CameraTaken { .. } => &c.camera_taken,
        Error::Protocol(_) => &c.protocol,
        // A call the client was connected without (`Client(detects=False)`), as a closed
        // client's calls raise.
        Error::ControlOnly => {
            return Ok(pyo3::exceptions::PyValueError::new_err(message));
        }
        Error::Transport(_) => &c.transport,
        Error::TooManyClients { .. } => &c.too_many_clients,
        Error::OtherProtocolVersion { .. } => &c.other_protocol_version,
        // What the handler raised, as Python would have raised it between two calls.
        Error::Interrupted => {
            let raised = RAISED_BY_A_HANDLER.with(|slot| slot.borrow_mut().take());
            return Ok(
                raised.unwrap_or_else(|| pyo3::exceptions::PyKeyboardInterrupt::new_err(message))
            );
        }
    };
    Ok(PyErr::from_value(class.bind(py).call1((message,))?))
}

/// A value as an error message shows it: its `repr` on one line, cut to at most 80 characters
/// with `…` (a numpy array's is many lines long).
pub fn shown(value: &Bound<'_, PyAny>) -> String {
    const MAX: usize = 79;
    let Ok(repr) = value.repr() else {
        return "an unprintable value".into();
    };
    let line = repr
        .to_string()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ");
    match line.char_indices().nth(MAX) {
        Some((cut, _)) => format!("{}…", &line[..cut]),
        None => line,
    }
}

/// A `ProtocolError` with `message`: bad input found in this package before anything is sent.
pub fn protocol_error(py: Python<'_>, message: String) -> PyErr {
    match classes(py).and_then(|c| c.protocol.bind(py).call1((message,))) {
        Ok(e) => PyErr::from_value(e),
        Err(e) => e,
    }
}
