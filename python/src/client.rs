//! `ppfd.Client`: detect requests and control requests, over `ppfd_client::Client`.

use std::time::Duration;

use numpy::PyArray2;
use ppfd_client::protocol::control::{DaemonStats, LatencySummary, ModelInfo};
use ppfd_client::{checks, ClientOptions, DetectOptions, Detections as Found, PoseHypothesis};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{protocol_error, shown, to_py};
use crate::requirements::{poses as pose_list, RequirementArgs};
use crate::thread::ThreadBound;

/// A duration from seconds given in Python; `what` names the argument in the error. A value
/// above 0 stays above 0 (1e-10 s is 1 ns, not a zero the library would refuse as given 0).
/// The library refuses a zero where it needs more, with its own message.
pub fn seconds(py: Python<'_>, what: &str, value: f64) -> PyResult<Duration> {
    let duration = Duration::try_from_secs_f64(value).map_err(|_| {
        // `{:e}` keeps a huge value short (1e300 written out is 301 digits).
        let got = if value.is_finite() && value.abs() >= 1e9 {
            format!("{value:e}")
        } else {
            value.to_string()
        };
        protocol_error(
            py,
            format!(
                "{what} must be a number of seconds from 0 to {:.1e}; got {got}",
                Duration::MAX.as_secs_f64()
            ),
        )
    })?;
    Ok(if value > 0.0 {
        duration.max(Duration::from_nanos(1))
    } else {
        duration
    })
}

/// A whole number as Python gives it (an `int`, or anything with `__index__`: numpy's
/// integers, `bool`), however large: its value when it fits 64 bits unsigned, else its digits.
/// Checked against its range by [`unsigned`] or [`unsigned_64`], which name the argument;
/// pyo3's own conversions raise an `OverflowError` that names none.
pub struct Whole {
    value: Option<u64>,
    digits: String,
}

impl Whole {
    /// `n`, an argument's default.
    pub const fn of(n: u64) -> Whole {
        Whole {
            value: Some(n),
            digits: String::new(),
        }
    }

    fn in_range(&self, py: Python<'_>, what: &str, max: u64) -> PyResult<u64> {
        match self.value {
            Some(n) if n <= max => Ok(n),
            Some(n) => Err(out_of_range(py, what, max, &n.to_string())),
            None => Err(out_of_range(py, what, max, &self.digits)),
        }
    }
}

fn out_of_range(py: Python<'_>, what: &str, max: u64, got: &str) -> PyErr {
    // A number of many digits is shown by its length.
    let got = if got.len() > 40 && got.bytes().all(|b| b.is_ascii_digit() || b == b'-') {
        format!("a number of {} digits", got.trim_start_matches('-').len())
    } else {
        got.to_owned()
    };
    protocol_error(
        py,
        format!("{what} must be a whole number from 0 to {max}; got {got}"),
    )
}

impl<'a, 'py> FromPyObject<'a, 'py> for Whole {
    type Error = PyErr;

    fn extract(obj: pyo3::Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        if let Ok(n) = obj.extract::<u64>() {
            return Ok(Whole {
                value: Some(n),
                digits: String::new(),
            });
        }
        // Not a whole number at all: the TypeError of Python's own conversion, which pyo3
        // names the argument in.
        let index = obj.call_method0("__index__").map_err(|_| {
            pyo3::exceptions::PyTypeError::new_err(format!(
                "'{}' object cannot be interpreted as an integer",
                obj.get_type()
                    .name()
                    .map_or_else(|_| "?".into(), |n| n.to_string())
            ))
        })?;
        // Python refuses to write out more than 4 300 digits: such a number is shown by its size.
        let digits = match index.str() {
            Ok(text) => text.to_string(),
            Err(_) => format!(
                "a number of {} bits",
                index
                    .call_method0("bit_length")
                    .and_then(|b| b.extract::<u64>())
                    .unwrap_or(0)
            ),
        };
        Ok(Whole {
            value: None,
            digits,
        })
    }
}

/// A whole number from 0 to 2³²−1 given in Python; `what` names the argument in the error.
pub fn unsigned(py: Python<'_>, what: &str, value: &Whole) -> PyResult<u32> {
    value.in_range(py, what, u32::MAX.into()).map(|n| n as u32)
}

/// A whole number from 0 to 2⁶⁴−1 given in Python; `what` names the argument in the error.
pub fn unsigned_64(py: Python<'_>, what: &str, value: &Whole) -> PyResult<u64> {
    value.in_range(py, what, u64::MAX)
}

/// The object ids of a request: each as [`unsigned`], named by its place in the list.
fn object_id_list(py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<Vec<u32>> {
    let not_a_list = || {
        protocol_error(
            py,
            format!(
                "object_ids must be a list of object ids; got {}",
                shown(value)
            ),
        )
    };
    // A string iterates over its characters: "15" is no list of ids.
    if value.is_instance_of::<pyo3::types::PyString>() {
        return Err(not_a_list());
    }
    let items = value.try_iter().map_err(|_| not_a_list())?;
    items
        .enumerate()
        .map(|(i, item)| {
            let item = item?;
            let n = item.extract::<Whole>().map_err(|_| {
                protocol_error(
                    py,
                    format!("object_ids[{i}] must be an object id; got {}", shown(&item)),
                )
            })?;
            unsigned(py, &format!("object_ids[{i}]"), &n)
        })
        .collect()
}

/// One pose hypothesis: `pose` maps model to camera coordinates, millimetres.
#[pyclass(module = "ppfd", frozen)]
pub struct Detection {
    hypothesis: PoseHypothesis,
}

impl Detection {
    /// This pose as a hint for a later frame.
    pub fn hint(&self) -> ppfd_client::PoseHint {
        ppfd_client::PoseHint::from(&self.hypothesis)
    }
}

#[pymethods]
impl Detection {
    /// Object id of the model.
    #[getter]
    fn object_id(&self) -> u32 {
        self.hypothesis.object_id
    }

    /// 0 for the first hypothesis of this object in the request's order (the best, or with
    /// `order="distance"` the nearest), 1 for the next, ...
    #[getter]
    fn rank(&self) -> u32 {
        self.hypothesis.instance_rank
    }

    /// Score after the last stage the hypothesis passed, 0 to 1.
    #[getter]
    fn score(&self) -> f32 {
        self.hypothesis.score
    }

    /// Votes of the pose cluster the hypothesis came from.
    #[getter]
    fn votes(&self) -> u32 {
        self.hypothesis.votes
    }

    /// The verification stages passed, as bits of `ppfd.Checks`.
    #[getter]
    fn checks(&self) -> u32 {
        self.hypothesis.checks
    }

    /// The pose as a new 4×4 float64 array `[[R, t], [0, 0, 0, 1]]`: `p_cam = R p_model + t`,
    /// millimetres.
    #[getter]
    fn pose<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let (r, t) = (&self.hypothesis.rotation, &self.hypothesis.translation_mm);
        let mut m = [[0.0f64; 4]; 4];
        for (row, out) in m.iter_mut().take(3).enumerate() {
            for col in 0..3 {
                out[col] = f64::from(r[3 * row + col]);
            }
            out[3] = f64::from(t[row]);
        }
        m[3][3] = 1.0;
        PyArray2::from_owned_array(py, numpy::ndarray::Array2::from(m.to_vec()))
    }

    fn __repr__(&self) -> String {
        let h = &self.hypothesis;
        format!(
            "Detection(object_id={}, rank={}, score={:.3}, t=({:.1}, {:.1}, {:.1}) mm, checks={})",
            h.object_id,
            h.instance_rank,
            h.score,
            h.translation_mm[0],
            h.translation_mm[1],
            h.translation_mm[2],
            h.checks
        )
    }
}

/// Bits of `Detection.checks`: the verification stages a hypothesis passed.
#[pyclass(module = "ppfd", frozen)]
pub struct Checks;

#[pymethods]
impl Checks {
    /// Re-scored against the scene from the camera's view.
    #[classattr]
    const RESCORED: u32 = checks::RESCORED;
    /// Refined by ICP.
    #[classattr]
    const REFINED: u32 = checks::REFINED;
    /// Passed the geometric consistency filter.
    #[classattr]
    const CONSISTENT: u32 = checks::CONSISTENT;
    /// Passed the silhouette filter.
    #[classattr]
    const SILHOUETTE: u32 = checks::SILHOUETTE;
    /// Came from one of the request's hints, not from voting.
    #[classattr]
    const HINT: u32 = checks::HINT;
}

/// The answer to a detect request: a sequence of `Detection`, grouped by object in request
/// order and within an object in the request's order (best or nearest first), with the
/// latency breakdown and the work's sizes.
#[pyclass(module = "ppfd", frozen, sequence)]
pub struct Detections {
    detections: Vec<Py<Detection>>,
    /// Where the time went, nanoseconds (see `ppfd.pyi` for the keys).
    #[pyo3(get)]
    latency: Py<PyDict>,
    /// Sizes of the work: scene points, reference points, pairs, hypotheses, returned.
    #[pyo3(get)]
    counts: Py<PyDict>,
    /// Sequence number of the camera frame used.
    #[pyo3(get)]
    frame_sequence: u64,
    /// Age of that frame when the detection started, nanoseconds.
    #[pyo3(get)]
    frame_age_ns: u64,
    /// The request's id.
    #[pyo3(get)]
    request_id: u64,
    /// With `diagnose=`: per object diagnosed, a heading line and one line per stage; "" otherwise.
    #[pyo3(get)]
    diagnosis: String,
}

#[pymethods]
impl Detections {
    fn __len__(&self) -> usize {
        self.detections.len()
    }

    /// One detection by index (negative from the end), or a list of them by slice.
    fn __getitem__(&self, py: Python<'_>, index: &Bound<'_, PyAny>) -> PyResult<Py<PyAny>> {
        let n = self.detections.len() as isize;
        if let Ok(slice) = index.cast::<pyo3::types::PySlice>() {
            let s = slice.indices(n)?;
            let picked: Vec<Py<Detection>> = (0..s.slicelength as isize)
                .map(|k| self.detections[(s.start + k * s.step) as usize].clone_ref(py))
                .collect();
            return Ok(picked.into_pyobject(py)?.into_any().unbind());
        }
        let index: isize = index.extract()?;
        let i = if index < 0 { index + n } else { index };
        if !(0..n).contains(&i) {
            return Err(pyo3::exceptions::PyIndexError::new_err(format!(
                "detection index {index} out of range for {n} detections"
            )));
        }
        Ok(self.detections[i as usize].clone_ref(py).into_any())
    }

    /// The position of `detection` (the same object, as indexing returns it) from `start` up to
    /// `stop` (negative: from the end, as a slice's), as a sequence's `index`.
    #[pyo3(signature = (detection, start=0, stop=None))]
    fn index(
        &self,
        detection: &Bound<'_, PyAny>,
        start: isize,
        stop: Option<isize>,
    ) -> PyResult<usize> {
        let len = self.detections.len() as isize;
        let bound = |i: isize| (if i < 0 { i + len } else { i }).clamp(0, len) as usize;
        let (start, stop) = (bound(start), bound(stop.unwrap_or(len)));
        self.detections
            .get(start..stop.max(start))
            .and_then(|part| part.iter().position(|d| d.as_ptr() == detection.as_ptr()))
            .map(|i| start + i)
            .ok_or_else(|| pyo3::exceptions::PyValueError::new_err("not among these detections"))
    }

    /// How many times `detection` occurs (0 or 1), as a sequence's `count`.
    fn count(&self, detection: &Bound<'_, PyAny>) -> usize {
        self.detections
            .iter()
            .filter(|d| d.as_ptr() == detection.as_ptr())
            .count()
    }

    /// The detections of one object, in the request's order (best or nearest first).
    fn of(&self, py: Python<'_>, object_id: Whole) -> PyResult<Vec<Py<Detection>>> {
        let object_id = unsigned(py, "object_id", &object_id)?;
        Ok(self
            .detections
            .iter()
            .filter(|d| d.get().hypothesis.object_id == object_id)
            .map(|d| d.clone_ref(py))
            .collect())
    }

    /// The best-scored detection of one object, or None.
    fn best(&self, py: Python<'_>, object_id: Whole) -> PyResult<Option<Py<Detection>>> {
        let object_id = unsigned(py, "object_id", &object_id)?;
        Ok(self
            .detections
            .iter()
            .filter(|d| d.get().hypothesis.object_id == object_id)
            .max_by(|a, b| {
                a.get()
                    .hypothesis
                    .score
                    .total_cmp(&b.get().hypothesis.score)
            })
            .map(|d| d.clone_ref(py)))
    }

    fn __repr__(&self) -> String {
        format!(
            "Detections({} poses, frame {})",
            self.detections.len(),
            self.frame_sequence
        )
    }
}

fn latency_dict<'py>(py: Python<'py>, found: &Found) -> PyResult<Bound<'py, PyDict>> {
    let l = &found.latency;
    let d = &l.daemon;
    let dict = PyDict::new(py);
    for (stage, ns) in d.stages() {
        dict.set_item(format!("{stage}_ns"), ns)?;
    }
    for (key, ns) in [
        ("detection_ns", d.detection_ns),
        ("total_ns", d.total_ns),
        ("hand_back_ns", l.hand_back_ns()),
        ("response_transport_ns", l.response_transport_ns),
        ("end_to_end_ns", l.end_to_end_ns),
        ("overhead_ns", l.overhead_ns()),
    ] {
        dict.set_item(key, ns)?;
    }
    Ok(dict)
}

fn detections(py: Python<'_>, found: Found) -> PyResult<Detections> {
    let c = &found.counts;
    let counts = PyDict::new(py);
    counts.set_item("scene_points", c.scene_points)?;
    counts.set_item("reference_points", c.reference_points)?;
    counts.set_item("pairs", c.pairs)?;
    counts.set_item("hypotheses", c.hypotheses)?;
    counts.set_item("returned", c.returned)?;
    Ok(Detections {
        latency: latency_dict(py, &found)?.unbind(),
        counts: counts.unbind(),
        detections: found
            .hypotheses
            .iter()
            .map(|&hypothesis| Py::new(py, Detection { hypothesis }))
            .collect::<PyResult<_>>()?,
        frame_sequence: found.frame_sequence,
        frame_age_ns: found.frame_age_ns,
        request_id: found.request_id,
        diagnosis: found.diagnosis,
    })
}

fn model_dict<'py>(py: Python<'py>, m: &ModelInfo) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("object_id", m.object_id)?;
    dict.set_item("name", m.name())?;
    dict.set_item("diameter_mm", m.diameter_mm)?;
    dict.set_item("point_count", m.point_count)?;
    dict.set_item("table_entries", m.table_entries)?;
    dict.set_item("byte_size", m.byte_size)?;
    dict.set_item("discrete_symmetries", m.discrete_symmetries)?;
    dict.set_item("continuous_symmetry", m.continuous_symmetry != 0)?;
    Ok(dict)
}

fn summary_dict<'py>(py: Python<'py>, s: &LatencySummary) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("count", s.count)?;
    dict.set_item("p50_ns", s.p50_ns)?;
    dict.set_item("p90_ns", s.p90_ns)?;
    dict.set_item("p99_ns", s.p99_ns)?;
    dict.set_item("max_ns", s.max_ns)?;
    Ok(dict)
}

fn stats_dict<'py>(
    py: Python<'py>,
    s: &DaemonStats,
    message: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    for (key, value) in [
        ("uptime_ns", s.uptime_ns),
        ("requests_received", s.requests_received),
        ("requests_served", s.requests_served),
        ("requests_refused", s.requests_refused),
        ("requests_expired", s.requests_expired),
        ("requests_abandoned", s.requests_abandoned),
        ("frames_received", s.frames_received),
        ("cameras", s.cameras),
        ("models_loaded", s.models_loaded),
        ("model_bytes", s.model_bytes),
        ("resident_bytes", s.resident_bytes),
        ("in_flight", s.in_flight),
        ("queued", s.queued),
        ("startup_files", s.startup_files),
        ("startup_files_done", s.startup_files_done),
        ("startup_files_failed", s.startup_files_failed),
        ("model_loads_running", s.model_loads_running),
        ("model_loads_waiting", s.model_loads_waiting),
        ("recent_window_ns", s.recent_window_ns),
    ] {
        dict.set_item(key, value)?;
    }
    dict.set_item("total", summary_dict(py, &s.total)?)?;
    dict.set_item("overhead", summary_dict(py, &s.overhead)?)?;
    dict.set_item("detection", summary_dict(py, &s.detection)?)?;
    dict.set_item("recent_total", summary_dict(py, &s.recent_total)?)?;
    dict.set_item("recent_overhead", summary_dict(py, &s.recent_overhead)?)?;
    dict.set_item("recent_detection", summary_dict(py, &s.recent_detection)?)?;
    dict.set_item("message", message)?;
    Ok(dict)
}

/// A connection to the daemon. Used by the thread that made it; make one per thread.
#[pyclass(module = "ppfd")]
pub struct Client {
    inner: ThreadBound<ppfd_client::Client>,
}

#[pymethods]
impl Client {
    /// Connects under the iceoryx2 `prefix` (None: `PPFD_PREFIX`, else iceoryx2's default).
    /// Works before the daemon starts: requests then raise `NoDaemon` until one serves.
    /// `detects=False` connects for control requests only (statistics, models): without a
    /// detect place, so it connects while the daemon serves its most detecting clients.
    #[new]
    #[pyo3(signature = (prefix=None, *, control_timeout=5.0, detects=true))]
    fn new(
        py: Python<'_>,
        prefix: Option<String>,
        control_timeout: f64,
        detects: bool,
    ) -> PyResult<Self> {
        let mut options = ClientOptions {
            control_timeout: seconds(py, "control_timeout", control_timeout)?,
            detects,
            ..ClientOptions::default()
        };
        if prefix.is_some() {
            options.prefix = prefix;
        }
        let mut client = ppfd_client::Client::connect_with(&options).map_err(|e| to_py(py, e))?;
        client.set_interrupt_check(crate::errors::interrupt_check());
        Ok(Client {
            inner: ThreadBound::new("ppfd.Client", client),
        })
    }

    /// Closes the connection now, releasing its shared-memory ports (otherwise released when
    /// the object is collected, and never when that happens on another thread); using it
    /// afterwards raises `ValueError`. Closing again does nothing.
    fn close(&mut self) -> PyResult<()> {
        self.inner.close()
    }

    /// Refused, as every use is, once closed or on another thread.
    fn __enter__(slf: PyRef<'_, Self>) -> PyResult<PyRef<'_, Self>> {
        slf.inner.get()?;
        Ok(slf)
    }

    /// Closes the client at the end of a `with` block.
    fn __exit__(
        &mut self,
        _kind: &Bound<'_, PyAny>,
        _value: &Bound<'_, PyAny>,
        _traceback: &Bound<'_, PyAny>,
    ) -> PyResult<bool> {
        self.inner.close()?;
        Ok(false)
    }

    /// Detects `object_ids` in the newest frame of `camera`; the GIL is released while the
    /// daemon works. `hypotheses` per object (1 to 16); `timeout` in seconds (None: the
    /// client library's, 3 s); `max_frame_age` in seconds, above 0, the oldest frame accepted
    /// (None: the daemon's limit).
    ///
    /// What the poses must satisfy (the defaults ask for nothing): `min_score`, 0 to 1;
    /// `instance_distance` in diameters, above 0 to 2 (None: the daemon's); `roi`, a pixel
    /// rectangle `(x, y, width, height)` reference points are taken from (None: the whole
    /// frame); `max_tilt_deg`, 0 to 180, the largest angle between the model axis `tilt_axis`
    /// (None: `(0, 0, 1)`) turned by the pose and the camera direction `tilt_direction` (None:
    /// `(0, 0, -1)`, towards the camera) (None: any pose); `order`, `"score"` (best first) or
    /// `"distance"` (nearest first). A value out of its range raises `ProtocolError` before
    /// the request is sent.
    ///
    /// `hints`: poses already known (None: none), each a `Detection` of an earlier answer or a
    /// pair `(object_id, pose)` with a 4×4 (or 3×4) pose; at most 64. A pair must be of one of
    /// `object_ids`; a `Detection` of another object is left out, so a whole earlier answer
    /// can be passed. A hinted object is first refined from its hints and goes through voting
    /// only when none passes; `Detection.checks` has `Checks.HINT` on a pose that came from a
    /// hint.
    ///
    /// `diagnose`: poses the objects are believed at, given as `hints` are, at least one of
    /// the objects asked for (None: no diagnosis; an empty list raises `ProtocolError`). The
    /// detection then runs from scratch (not with `hints` as well), and `Detections.diagnosis`
    /// says per object, after each stage, where the best candidate near its pose stands and at
    /// which stage it was lost; about twice the detection's time.
    #[pyo3(signature = (
        camera, object_ids, hypotheses=Whole::of(1), timeout=None, *, max_frame_age=None, min_score=0.0,
        instance_distance=None, roi=None, max_tilt_deg=None, tilt_axis=None,
        tilt_direction=None, order="score", hints=None, diagnose=None
    ), text_signature = "($self, camera, object_ids, hypotheses=1, timeout=None, *, \
        max_frame_age=None, min_score=0.0, instance_distance=None, roi=None, max_tilt_deg=None, \
        tilt_axis=None, tilt_direction=None, order=\"score\", hints=None, diagnose=None)")]
    #[allow(clippy::too_many_arguments)]
    fn detect(
        &self,
        py: Python<'_>,
        camera: &str,
        object_ids: &Bound<'_, PyAny>,
        hypotheses: Whole,
        timeout: Option<f64>,
        max_frame_age: Option<f64>,
        min_score: f32,
        instance_distance: Option<f32>,
        roi: Option<&Bound<'_, PyAny>>,
        max_tilt_deg: Option<f32>,
        tilt_axis: Option<&Bound<'_, PyAny>>,
        tilt_direction: Option<&Bound<'_, PyAny>>,
        order: &str,
        hints: Option<&Bound<'_, PyAny>>,
        diagnose: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Detections> {
        let object_ids = object_id_list(py, object_ids)?;
        let hypotheses = unsigned(py, "hypotheses", &hypotheses)?;
        let requirements = RequirementArgs {
            min_score,
            instance_distance,
            roi,
            max_tilt_deg,
            tilt_axis,
            tilt_direction,
            order,
        }
        .wire(py)?;
        let options = DetectOptions {
            hypotheses_per_object: hypotheses,
            timeout: match timeout {
                Some(t) => seconds(py, "timeout", t)?,
                None => DetectOptions::default().timeout,
            },
            max_frame_age: max_frame_age
                .map(|a| seconds(py, "max_frame_age", a))
                .transpose()?,
            requirements,
            hints: match hints {
                Some(h) => pose_list(py, "hints", h, &object_ids)?,
                None => Vec::new(),
            },
            diagnose: match diagnose {
                Some(d) => {
                    let poses = pose_list(py, "diagnose", d, &object_ids)?;
                    // An empty list would run a plain detection and say nothing.
                    if poses.is_empty() {
                        return Err(protocol_error(
                            py,
                            "diagnose holds no pose of the objects asked for: a diagnosis needs \
                             at least one"
                                .into(),
                        ));
                    }
                    poses
                }
                None => Vec::new(),
            },
        };
        let client = &self.inner;
        let found = py
            .detach(|| {
                client
                    .get()
                    .map(|c| c.detect(camera, &object_ids, &options))
            })?
            .map_err(|e| to_py(py, e))?;
        detections(py, found)
    }

    /// The loaded models, by object id (at most 256, the lowest ids), each a dict.
    fn models<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let client = &self.inner;
        let models = py
            .detach(|| client.get().map(|c| c.models()))?
            .map_err(|e| to_py(py, e))?;
        models.iter().map(|m| model_dict(py, m)).collect()
    }

    /// The daemon's statistics as a dict; `message` holds the detector parameters it runs
    /// with, and the `startup_files*` counts how far its start-up loading has got.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let client = &self.inner;
        let (stats, message) = py
            .detach(|| client.get().map(|c| c.statistics()))?
            .map_err(|e| to_py(py, e))?;
        stats_dict(py, &stats, &message)
    }

    /// Loads a model file (`.ppfm`), or builds one from a PLY mesh, in the daemon; `path` as
    /// the daemon sees it; `object_id` 0 takes the id from the file; `timeout` in seconds
    /// (None: the client's `control_timeout`). Returns the model's dict.
    #[pyo3(
        signature = (path, object_id=Whole::of(0), *, timeout=None),
        text_signature = "($self, path, object_id=0, *, timeout=None)"
    )]
    fn load_model<'py>(
        &self,
        py: Python<'py>,
        path: std::path::PathBuf,
        object_id: Whole,
        timeout: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let object_id = unsigned(py, "object_id", &object_id)?;
        let path = path
            .to_str()
            .ok_or_else(|| protocol_error(py, format!("model path {path:?} is not valid UTF-8")))?;
        let timeout = timeout.map(|t| seconds(py, "timeout", t)).transpose()?;
        let client = &self.inner;
        let model = py
            .detach(|| {
                client.get().map(|c| match timeout {
                    Some(t) => c.load_model_within(path, object_id, t),
                    None => c.load_model(path, object_id),
                })
            })?
            .map_err(|e| to_py(py, e))?;
        model_dict(py, &model)
    }

    /// Drops a model from the daemon.
    fn drop_model(&self, py: Python<'_>, object_id: Whole) -> PyResult<()> {
        let object_id = unsigned(py, "object_id", &object_id)?;
        let client = &self.inner;
        py.detach(|| client.get().map(|c| c.drop_model(object_id)))?
            .map_err(|e| to_py(py, e))
    }
}
