//! The client library's ports are not `Send`: each belongs to the thread that made it. Python
//! may hand an object to any thread, so each port is kept in a [`ThreadBound`], which refuses
//! use from another thread with a Python error instead of a panic.

use std::mem::ManuallyDrop;
use std::thread::ThreadId;

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::PyResult;

/// A value used only on the thread that made it, until it is closed.
pub struct ThreadBound<T> {
    owner: ThreadId,
    what: &'static str,
    value: ManuallyDrop<Option<T>>,
}

// SAFETY: the value is reached only through `get`, on its owner thread, and dropped only there
// (elsewhere it is leaked), so it never crosses threads however the wrapper travels.
unsafe impl<T> Send for ThreadBound<T> {}
// SAFETY: as above; a shared reference on another thread cannot reach the value.
unsafe impl<T> Sync for ThreadBound<T> {}

impl<T> ThreadBound<T> {
    /// Binds `value` to the current thread; `what` names it in errors (`ppfd.Client`).
    pub fn new(what: &'static str, value: T) -> Self {
        ThreadBound {
            owner: std::thread::current().id(),
            what,
            value: ManuallyDrop::new(Some(value)),
        }
    }

    /// The value, on its owner thread, unless closed.
    pub fn get(&self) -> PyResult<&T> {
        self.check()?;
        self.value.as_ref().ok_or_else(|| self.closed())
    }

    /// The value, mutably, on its owner thread, unless closed.
    pub fn get_mut(&mut self) -> PyResult<&mut T> {
        self.check()?;
        let what = self.what;
        self.value
            .as_mut()
            .ok_or_else(|| PyValueError::new_err(format!("the {what} is closed")))
    }

    /// Drops the value now, on its owner thread, releasing its ports; using it afterwards
    /// raises `ValueError`. Closing again does nothing.
    pub fn close(&mut self) -> PyResult<()> {
        self.check()?;
        drop(self.value.take());
        Ok(())
    }

    fn closed(&self) -> pyo3::PyErr {
        PyValueError::new_err(format!("the {} is closed", self.what))
    }

    fn check(&self) -> PyResult<()> {
        if std::thread::current().id() == self.owner {
            Ok(())
        } else {
            Err(PyRuntimeError::new_err(format!(
                "a {} is used only by the thread that made it (its shared-memory ports belong \
                 to that thread); make one in each thread that needs one",
                self.what
            )))
        }
    }
}

impl<T> Drop for ThreadBound<T> {
    fn drop(&mut self) {
        if std::thread::current().id() == self.owner {
            // SAFETY: dropped once, here, on the owner thread.
            unsafe { ManuallyDrop::drop(&mut self.value) };
        }
        // Elsewhere the ports are leaked: closing them from a thread they do not belong to is
        // not allowed. iceoryx2 counts a leaked port as its process's until the process ends.
    }
}
