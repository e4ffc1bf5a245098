"""Python client of the ppfd daemon: 6D object poses from depth frames over shared memory.

`Client` asks the daemon for objects in a camera's newest frame; `CameraPublisher` writes depth
frames into shared memory, where the daemon reads them in place. Every error is a `ppfd.Error`,
with the message of the Rust client library. docs/PYTHON.md is the guide.
"""

from types import TracebackType
from typing import Iterable, Iterator, Literal, Optional, Sequence, TypedDict, Union, overload
import os

import numpy as np
import numpy.typing as npt

__version__: str
PROTOCOL_VERSION: int

class Latency(TypedDict):
    """Where the time of one request went, nanoseconds of `CLOCK_MONOTONIC`."""

    transport_ns: int
    """Client send → the daemon takes the request."""
    queue_wait_ns: int
    """The daemon takes the request → a worker starts it."""
    scene_preparation_ns: int
    kd_tree_ns: int
    voting_ns: int
    clustering_ns: int
    rescoring_ns: int
    icp_ns: int
    filters_ns: int
    detection_ns: int
    """Wall time of the detection on the worker (the stages plus glue)."""
    total_ns: int
    """Client send → the daemon sends the response."""
    hand_back_ns: int
    """Detection finished → response sent."""
    response_transport_ns: int
    """The daemon sends the response → this client has it."""
    end_to_end_ns: int
    """Client send → this client has the response."""
    overhead_ns: int
    """End to end minus detection: transport both ways, queueing, the daemon's glue."""

class Counts(TypedDict):
    """Sizes of the work done for one request."""

    scene_points: int
    reference_points: int
    pairs: int
    hypotheses: int
    returned: int

class Model(TypedDict):
    """A model the daemon holds."""

    object_id: int
    name: str
    diameter_mm: float
    point_count: int
    table_entries: int
    byte_size: int
    discrete_symmetries: int
    """Transforms other than the identity that map the object onto itself; a symmetric
    object's pose is reported as the one of its equivalent poses nearest the model's frame."""
    continuous_symmetry: bool
    """Whether any turn about an axis maps the object onto itself."""

class LatencySummary(TypedDict):
    """Percentiles and the exact maximum: over the daemon's lifetime (`total` and its kin) from
    a histogram of three significant digits, over the last minute (`recent_*`) exact."""

    count: int
    p50_ns: int
    p90_ns: int
    p99_ns: int
    max_ns: int

class Stats(TypedDict):
    """The daemon's statistics: counters and latencies since it started, and the latencies of
    the last minute (`recent_*`)."""

    uptime_ns: int
    requests_received: int
    requests_served: int
    requests_refused: int
    requests_expired: int
    requests_abandoned: int
    frames_received: int
    """Camera frames the daemon took off the camera ports (it reads them at its housekeeping
    tick and before each detection); a frame a newer one replaced before then is not counted."""
    cameras: int
    models_loaded: int
    model_bytes: int
    resident_bytes: int
    in_flight: int
    """Detections running on a worker now."""
    queued: int
    """Requests waiting for a worker now, in the daemon's queue or handed to busy workers."""
    startup_files: int
    """Model files in the models folder the daemon loads at start."""
    startup_files_done: int
    """Of those, the files loaded or failed so far: fewer while the folder loads, and
    detections wait until it is done."""
    startup_files_failed: int
    """Of those, the files that failed to load (the daemon's log names each)."""
    model_loads_running: int
    """`load_model` requests being served (one at a time)."""
    model_loads_waiting: int
    """`load_model` requests waiting for the one running."""
    total: LatencySummary
    """Client send → the daemon sends the response, over served requests."""
    overhead: LatencySummary
    """Request transport and queue wait, as the daemon sees them: unlike
    `Latency.overhead_ns`, without the response's way back or the daemon's glue."""
    detection: LatencySummary
    recent_window_ns: int
    """The span the `recent_*` summaries cover, ending at the answer: one minute, less while
    the daemon is younger or when it served more than 100 000 requests in that minute."""
    recent_total: LatencySummary
    """`total` over the requests served within `recent_window_ns`."""
    recent_overhead: LatencySummary
    """`overhead` over the requests served within `recent_window_ns`."""
    recent_detection: LatencySummary
    """`detection` over the requests served within `recent_window_ns`."""
    message: str
    """The detector parameters the daemon runs with (`detector: defaults`, or
    `detector: voting.reference_step=2 …`)."""

class Checks:
    """Bits of `Detection.checks`: the verification stages a hypothesis passed."""

    RESCORED: int
    REFINED: int
    CONSISTENT: int
    SILHOUETTE: int
    HINT: int
    """Came from one of the request's hints, not from voting."""

class Detection:
    """One pose hypothesis of one object."""

    @property
    def object_id(self) -> int: ...
    @property
    def rank(self) -> int:
        """0 for the first hypothesis of this object in the request's order (the best, or
        with `order="distance"` the nearest), 1 for the next, ..."""
    @property
    def score(self) -> float:
        """Score after the last stage the hypothesis passed, 0 to 1."""
    @property
    def votes(self) -> int: ...
    @property
    def checks(self) -> int:
        """The verification stages passed, as bits of `Checks`."""
    @property
    def pose(self) -> npt.NDArray[np.float64]:
        """A new 4×4 array `[[R, t], [0, 0, 0, 1]]`, model → camera: `p_cam = R p_model + t`,
        millimetres."""

class Detections(Sequence[Detection]):
    """The answer to a detect request: the detections grouped by object in request order, and
    within an object in the request's order (best or nearest first)."""

    @property
    def latency(self) -> Latency: ...
    @property
    def counts(self) -> Counts: ...
    @property
    def frame_sequence(self) -> int:
        """Sequence number of the camera frame used."""
    @property
    def frame_age_ns(self) -> int:
        """Age of that frame when the detection started."""
    @property
    def request_id(self) -> int: ...
    @property
    def diagnosis(self) -> str:
        """With `diagnose=`: per object diagnosed, a heading line ("object 5: lost at voting")
        and one line per stage; "" otherwise."""
    def __len__(self) -> int: ...
    @overload
    def __getitem__(self, index: int) -> Detection: ...
    @overload
    def __getitem__(self, index: slice) -> list[Detection]: ...
    def __iter__(self) -> Iterator[Detection]: ...
    def index(self, detection: Detection, start: int = 0, stop: Optional[int] = None) -> int:  # type: ignore[override]
        """The position of `detection` (the object indexing returns), from `start` up to
        `stop` as a list's `index`."""
    def count(self, detection: Detection) -> int:  # type: ignore[override]
        """How many times `detection` occurs: 0 or 1."""
    def of(self, object_id: int) -> list[Detection]:
        """The detections of one object, in the request's order (best or nearest first)."""
    def best(self, object_id: int) -> Optional[Detection]:
        """The best-scored detection of one object, or None."""

class Client:
    """A connection to the daemon, used by the thread that made it (one per thread)."""

    def __init__(
        self, prefix: Optional[str] = None, *, control_timeout: float = 5.0, detects: bool = True
    ) -> None:
        """Connects under the iceoryx2 `prefix` (None: `PPFD_PREFIX`, else iceoryx2's
        default). Works before the daemon starts: requests then raise `NoDaemon`.
        `control_timeout` in seconds, above 0, bounds model listings, loads and statistics.
        `detects=False` connects for control requests only (a monitor): it takes no detect
        place, so it connects while the daemon serves its most detecting clients, and its
        detect calls raise `ValueError`."""
    def close(self) -> None:
        """Closes the connection now, releasing its shared-memory ports (otherwise released
        when the object is collected, and never when that happens on another thread); using it
        afterwards raises `ValueError`. Closing again does nothing. `with ppfd.Client() as c:`
        closes it at the end of the block."""
    def __enter__(self) -> "Client": ...
    def __exit__(
        self,
        kind: Optional[type[BaseException]],
        value: Optional[BaseException],
        traceback: Optional[TracebackType],
    ) -> bool: ...
    def detect(
        self,
        camera: str,
        object_ids: Sequence[int],
        hypotheses: int = 1,
        timeout: Optional[float] = None,
        *,
        max_frame_age: Optional[float] = None,
        min_score: float = 0.0,
        instance_distance: Optional[float] = None,
        roi: Optional[tuple[int, int, int, int]] = None,
        max_tilt_deg: Optional[float] = None,
        tilt_axis: Optional[Sequence[float]] = None,
        tilt_direction: Optional[Sequence[float]] = None,
        order: Literal["score", "distance"] = "score",
        hints: Optional[Iterable[Union[Detection, tuple[int, npt.ArrayLike]]]] = None,
        diagnose: Optional[Iterable[Union[Detection, tuple[int, npt.ArrayLike]]]] = None,
    ) -> Detections:
        """Detects `object_ids` in the newest frame of `camera`, releasing the GIL while the
        daemon works. `hypotheses` per object, 1 to 16; `timeout` in seconds, above 0 (None: 3 s);
        `max_frame_age` in seconds, above 0, the oldest frame accepted (None: the daemon's limit).

        What the poses must satisfy; the defaults ask for nothing:

        - `min_score`: poses scoring below it are left out, 0 to 1.
        - `instance_distance`: poses whose model centres lie closer than this many diameters
          are one instance, above 0 to 2 (None: the daemon's setting).
        - `roi`: reference points only from this pixel rectangle `(x, y, width, height)`,
          within the frame (None, or `(0, 0, 0, 0)`: the whole frame).
        - `max_tilt_deg`: only poses whose model axis `tilt_axis` (None: `(0, 0, 1)`), turned
          by the pose, lies within this angle of the camera direction `tilt_direction` (None:
          `(0, 0, -1)`, towards the camera), 0 to 180 (None: any pose).
        - `order`: each object's poses best score first, or nearest first.

        `hints`: poses already known, at most 64, each a `Detection` of an earlier answer or a
        pair `(object_id, pose)` with a 4×4 (or 3×4) pose of one of `object_ids`; a `Detection`
        of an object not in `object_ids` is left out, so a whole earlier answer can be passed
        while the objects asked for change. A hinted object is
        first refined from its hints (ICP, re-scoring, both filters, the minimum score) and
        goes through voting only when none passes; its pose then has `Checks.HINT`.

        `diagnose`: poses the objects are believed at, given as `hints` are, at least one of
        the objects asked for (an empty list raises `ProtocolError`). The detection
        then runs from scratch (not with `hints` as well), and `Detections.diagnosis` says per
        object with a pose, after each stage, where the best candidate near it stands and at
        which stage it was lost; about twice the detection's time.

        A value out of its range raises `ProtocolError` with the client library's message
        before the request is sent; a region reaching outside the frame is refused
        `InvalidRequest` by the daemon."""
    def models(self) -> list[Model]:
        """The loaded models, by object id (at most 256, the lowest ids)."""
    def stats(self) -> Stats:
        """The daemon's statistics."""
    def load_model(
        self,
        path: Union[str, os.PathLike[str]],
        object_id: int = 0,
        *,
        timeout: Optional[float] = None,
    ) -> Model:
        """Loads a model file, or builds one from a PLY mesh, in the daemon (`path` absolute,
        as the daemon sees it; `object_id` 0 takes the id from the file). Waits at most
        `timeout` seconds (None: the client's `control_timeout`); a large mesh builds for
        seconds to minutes. A load that times out is not cancelled: the daemon finishes it and
        serves the model, and `stats()` (`model_loads_running`, `model_loads_waiting`) and
        `models()` tell when. Sent again, it would be done again after it."""
    def drop_model(self, object_id: int) -> None:
        """Drops a model from the daemon."""

class CameraPublisher:
    """Publishes the depth frames of one camera into shared memory, used by the thread that
    made it."""

    def __init__(
        self,
        name: str,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        depth_scale: float = 1.0,
        *,
        prefix: Optional[str] = None,
        camera_id: int = 0,
    ) -> None:
        """Creates camera `name` of `width` × `height` pixels, pinhole intrinsics in pixels;
        `depth_scale` is millimetres per raw depth unit."""
    def close(self) -> None:
        """Closes the camera now, releasing its shared-memory ports and its name; using it
        afterwards raises `ValueError`. Closing again does nothing. Also a context manager."""
    def __enter__(self) -> "CameraPublisher": ...
    def __exit__(
        self,
        kind: Optional[type[BaseException]],
        value: Optional[BaseException],
        traceback: Optional[TracebackType],
    ) -> bool: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    def publish(
        self, depth: npt.NDArray[np.uint16], capture_time_ns: Optional[int] = None
    ) -> int:
        """Copies `depth`, uint16 of shape (height, width), into a loaned shared-memory frame
        and publishes it; returns its sequence number. Another dtype or shape raises
        `ProtocolError` (a `ValueError`) naming both."""
    def idle(self, seconds: float) -> None:
        """Waits without publishing, handing the newest frame to a daemon that subscribes
        meanwhile: use it where a driver would sleep."""

def monotonic_now_ns() -> int:
    """`CLOCK_MONOTONIC` now, nanoseconds: the clock of capture times and of the daemon."""

def remove_prefix_leftovers(prefix: str) -> int:
    """Removes what iceoryx2 leaves under a prefix made for one run, once its processes are
    gone (a daemon, driver or client killed without cleanup leaves files in `/dev/shm` and
    `/tmp/iceoryx2`). Returns how many entries were removed. Raises `ProtocolError` while a
    daemon runs under the prefix, removing nothing; this process's own clients and publishers
    under it are to be dropped first."""

class Error(Exception):
    """Anything that went wrong talking to the ppfd daemon."""

class Refused(Error):
    """The daemon refused the request. `status` names why ("camera stale"); `value` is what it
    refers to (the unknown object id, the stale frame's age in ns), 0 otherwise."""

    status: str
    value: int

class ProtocolVersion(Refused): ...
class InvalidRequest(Refused): ...
class EmptyObjectList(Refused): ...
class UnknownObject(Refused): ...
class InvalidFrame(Refused): ...
class InvalidIntrinsics(Refused): ...
class UnknownCamera(Refused): ...
class NoFrame(Refused): ...
class CameraStale(Refused): ...
class DeadlineExceeded(Refused): ...
class Busy(Refused): ...
class Internal(Refused): ...
class ShuttingDown(Refused): ...
class ModelError(Refused): ...

class Timeout(Error, TimeoutError):
    """No answer within the timeout."""

class Dropped(Error):
    """The daemon let go of the request without an answer; sending it again is safe."""

class DaemonGone(Error):
    """The daemon's process ended while the request waited for its answer."""

class NoDaemon(Error):
    """No daemon serves under this client's iceoryx2 prefix."""

class CameraTaken(Error):
    """Another driver already publishes under this camera name."""

class ProtocolError(Error, ValueError):
    """The request or frame was malformed, found before it was sent."""

class TransportError(Error):
    """An iceoryx2 operation failed. The client stays usable: its next request is sent
    afresh."""

class TooManyClients(TransportError):
    """At connect: the daemon serves as many clients as it can; connect again once one has
    gone."""

class OtherProtocolVersion(TransportError):
    """At connect: the daemon serves another protocol version; the daemon and its clients must
    come from the same ppfd release."""
