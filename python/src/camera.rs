//! `ppfd.CameraPublisher`: a camera driver in Python, over `ppfd_client::CameraPublisher`.

use numpy::{PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use ppfd_client::{monotonic_now_ns, Intrinsics};
use pyo3::prelude::*;

use crate::client::{unsigned, unsigned_64, Whole};
use crate::errors::{protocol_error, to_py};
use crate::thread::ThreadBound;

/// Publishes the depth frames of one camera into shared memory. Used by the thread that made
/// it. Between frames, wait with `idle` rather than `time.sleep`, so that a daemon that
/// subscribes meanwhile gets the newest frame.
#[pyclass(module = "ppfd")]
pub struct CameraPublisher {
    inner: ThreadBound<ppfd_client::CameraPublisher>,
    width: u32,
    height: u32,
}

#[pymethods]
impl CameraPublisher {
    /// Creates the camera `name` (1 to 31 ASCII letters, digits, `_`, `-`) of `width` ×
    /// `height` pixels with pinhole intrinsics in pixels; `depth_scale` is millimetres per raw
    /// depth unit (1.0 for a sensor that reports mm). `prefix` as `ppfd.Client`'s.
    #[new]
    #[pyo3(
        signature = (name, width, height, fx, fy, cx, cy, depth_scale=1.0, *, prefix=None, camera_id=Whole::of(0)),
        text_signature = "(name, width, height, fx, fy, cx, cy, depth_scale=1.0, *, prefix=None, camera_id=0)"
    )]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        name: &str,
        width: Whole,
        height: Whole,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        depth_scale: f32,
        prefix: Option<String>,
        camera_id: Whole,
    ) -> PyResult<Self> {
        let width = unsigned(py, "width", &width)?;
        let height = unsigned(py, "height", &height)?;
        let camera_id = unsigned(py, "camera_id", &camera_id)?;
        let intrinsics = Intrinsics { fx, fy, cx, cy };
        let publisher = ppfd_client::CameraPublisher::new(
            prefix.as_deref(),
            name,
            camera_id,
            width,
            height,
            intrinsics,
            depth_scale,
        )
        .map_err(|e| to_py(py, e))?;
        Ok(CameraPublisher {
            inner: ThreadBound::new("ppfd.CameraPublisher", publisher),
            width,
            height,
        })
    }

    /// Closes the camera now, releasing its shared-memory ports and its name (otherwise
    /// released when the object is collected, and never when that happens on another thread);
    /// using it afterwards raises `ValueError`. Closing again does nothing.
    fn close(&mut self) -> PyResult<()> {
        self.inner.close()
    }

    /// Refused, as every use is, once closed or on another thread.
    fn __enter__(slf: PyRef<'_, Self>) -> PyResult<PyRef<'_, Self>> {
        slf.inner.get()?;
        Ok(slf)
    }

    /// Closes the camera at the end of a `with` block.
    fn __exit__(
        &mut self,
        _kind: &Bound<'_, PyAny>,
        _value: &Bound<'_, PyAny>,
        _traceback: &Bound<'_, PyAny>,
    ) -> PyResult<bool> {
        self.inner.close()?;
        Ok(false)
    }

    /// Copies `depth`, a uint16 array of shape (height, width), into a loaned shared-memory
    /// frame and publishes it: the one copy from the array, none after. `capture_time_ns` is
    /// when the sensor captured it on `CLOCK_MONOTONIC` (`ppfd.monotonic_now_ns()`; None: now).
    /// Returns the frame's sequence number.
    #[pyo3(signature = (depth, capture_time_ns=None))]
    fn publish(
        &mut self,
        py: Python<'_>,
        depth: &Bound<'_, PyAny>,
        capture_time_ns: Option<Whole>,
    ) -> PyResult<u64> {
        let capture_time_ns = capture_time_ns
            .map(|t| unsigned_64(py, "capture_time_ns", &t))
            .transpose()?;
        let expected = format!("uint16 array of shape ({}, {})", self.height, self.width);
        let array = depth.cast::<PyArrayDyn<u16>>().map_err(|_| {
            protocol_error(
                py,
                format!("depth must be a {expected}, got {}", describe(depth)),
            )
        })?;
        if array.shape() != [self.height as usize, self.width as usize] {
            return Err(protocol_error(
                py,
                format!("depth must be a {expected}, got {}", describe(depth)),
            ));
        }
        let view = array.try_readonly()?;
        let publisher = self.inner.get_mut()?;
        let loan = publisher.loan().map_err(|e| to_py(py, e))?;
        // `as_slice` also takes a Fortran-ordered array, in its memory order: only a
        // C-ordered one is copied in one piece.
        let frame = match view.as_slice() {
            Ok(values) if array.is_c_contiguous() => {
                loan.write_from_slice(values).map_err(|e| to_py(py, e))?
            }
            // Strided (a crop, a transposed or Fortran-ordered array): one pass in row order.
            _ => {
                let a = view.as_array();
                let mut values = a.iter();
                loan.write_from_fn(|_| values.next().copied().unwrap_or(0))
            }
        };
        frame
            .send(capture_time_ns.unwrap_or_else(monotonic_now_ns))
            .map_err(|e| to_py(py, e))
    }

    /// Waits `seconds` without publishing, handing the newest frame every 20 ms to a daemon
    /// that subscribes meanwhile. The GIL is released while it waits. Python's signal handlers
    /// run every 50 ms, so Ctrl-C ends it as it ends `time.sleep`.
    fn idle(&self, py: Python<'_>, seconds: f64) -> PyResult<()> {
        const STEP: std::time::Duration = std::time::Duration::from_millis(50);
        let duration = crate::client::seconds(py, "seconds", seconds)?;
        let until = std::time::Instant::now() + duration;
        let publisher = &self.inner;
        loop {
            let left = until.saturating_duration_since(std::time::Instant::now());
            py.detach(|| publisher.get().map(|p| p.idle(left.min(STEP))))?
                .map_err(|e| to_py(py, e))?;
            if left <= STEP {
                return Ok(());
            }
            py.check_signals()?;
        }
    }

    /// Image width, pixels.
    #[getter]
    fn width(&self) -> PyResult<u32> {
        self.inner.get()?;
        Ok(self.width)
    }

    /// Image height, pixels.
    #[getter]
    fn height(&self) -> PyResult<u32> {
        self.inner.get()?;
        Ok(self.height)
    }
}

/// What an argument given as depth is: `float32 array of shape (480, 640)`, or its type.
fn describe(value: &Bound<'_, PyAny>) -> String {
    match value.cast::<numpy::PyUntypedArray>() {
        Ok(array) => {
            let dtype = array
                .dtype()
                .str()
                .map(|s| s.to_string())
                .unwrap_or_else(|_| "unknown dtype".into());
            let shape: Vec<String> = array.shape().iter().map(|n| n.to_string()).collect();
            let shape = if shape.len() == 1 {
                format!("({},)", shape[0])
            } else {
                format!("({})", shape.join(", "))
            };
            format!("{dtype} array of shape {shape}")
        }
        Err(_) => value
            .get_type()
            .name()
            .map(|n| format!("a {n}, not a numpy array"))
            .unwrap_or_else(|_| "something that is not a numpy array".into()),
    }
}
