"""The package without a daemon: bad input, no daemon, the exception hierarchy, and the type
hints against what the module has."""

import subprocess
import sys

import numpy as np
import pytest

import ppfd
from conftest import fresh_prefix, stub_names


@pytest.fixture
def prefix():
    p = fresh_prefix("nodaemon")
    yield p
    ppfd.remove_prefix_leftovers(p)


def test_no_daemon_raises_no_daemon_naming_the_prefix(prefix):
    client = ppfd.Client(prefix=prefix)
    with pytest.raises(ppfd.NoDaemon) as e:
        client.detect("parts", [1])
    assert prefix in str(e.value) and "start one" in str(e.value)
    with pytest.raises(ppfd.NoDaemon):
        client.models()
    with pytest.raises(ppfd.NoDaemon):
        client.stats()
    del client


@pytest.mark.parametrize(
    "args, options, says",
    [
        (("parts", [1, 1]), {}, "object id 1 is asked for twice"),
        (("parts", []), {}, "no object"),
        (("parts", list(range(1, 34))), {}, "33"),
        (("parts", [1]), {"hypotheses": 0}, "0"),
        (("parts", [1]), {"hypotheses": 17}, "17"),
        (("bad name", [1]), {}, "bad name"),
        (("parts", [1]), {"timeout": -1.0}, "timeout must be a number of seconds from 0 to 1.8e19; got -1"),
        (("parts", [1]), {"timeout": 1e300}, "number of seconds from 0 to 1.8e19; got 1e300"),
        (("parts", [1]), {"timeout": 1e30}, "number of seconds from 0 to 1.8e19; got 1e30"),
        (("parts", [1]), {"timeout": float("nan")}, "timeout must be a number of seconds from 0 to 1.8e19; got NaN"),
        (("parts", [1]), {"timeout": 0.0}, "timeout 0 s is out of range"),
        (("parts", [1]), {"max_frame_age": -0.5}, "max_frame_age must be"),
        (("parts", [1]), {"max_frame_age": 0.0}, "maximum frame age 0 s is out of range"),
        (("parts", [5, -1]), {}, "object_ids[1] must be a whole number from 0 to 4294967295; got -1"),
        (("parts", [2**32]), {}, "object_ids[0] must be a whole number"),
        (("parts", "15"), {}, "object_ids must be a list of object ids; got '15'"),
        (("parts", [1]), {"hypotheses": -1}, "hypotheses must be a whole number"),
        # However large: a Python int has no 64-bit bound to overflow.
        (("parts", [1]), {"hypotheses": 2**63}, "hypotheses must be a whole number from 0 to 4294967295; got 9223372036854775808"),
        (("parts", [2**100]), {}, "object_ids[0] must be a whole number from 0 to 4294967295; got 1267650600228229401496703205376"),
        (("parts", [10**5000]), {}, "object_ids[0] must be a whole number from 0 to 4294967295; got a number of 16610 bits"),
        (("parts", [1]), {"hypotheses": np.int64(-2)}, "hypotheses must be a whole number from 0 to 4294967295; got -2"),
        (("parts", [1]), {"hints": [(1, np.full((4, 4), np.nan))]}, "the pose's numbers must be finite"),
        (("bad\0name", [1]), {}, 'camera name "bad\\0name" may hold only'),
    ],
)
def test_a_malformed_request_is_a_value_error_before_it_is_sent(prefix, args, options, says):
    client = ppfd.Client(prefix=prefix)
    with pytest.raises(ppfd.ProtocolError) as e:
        client.detect(*args, **options)
    assert isinstance(e.value, ValueError) and isinstance(e.value, ppfd.Error)
    assert says in str(e.value)


def test_zero_timeouts_and_negative_ids_are_refused_naming_the_argument(prefix):
    with pytest.raises(ppfd.ProtocolError, match="control timeout 0 s is out of range"):
        ppfd.Client(prefix=prefix, control_timeout=0.0)
    client = ppfd.Client(prefix=prefix)
    # Refused before it is sent: without a daemon, anything sent would raise NoDaemon.
    with pytest.raises(ppfd.ProtocolError, match="timeout 0 s is out of range"):
        client.load_model("obj_000001.ply", 1, timeout=0.0)
    # Negative ids name the argument, as out-of-range values of the other arguments do.
    with pytest.raises(ppfd.ProtocolError, match="object_id must be a whole number"):
        client.drop_model(-1)
    with pytest.raises(ppfd.ProtocolError, match="object_id must be a whole number"):
        client.load_model("obj_000001.ply", -1)
    with pytest.raises(ppfd.ProtocolError, match="camera_id must be a whole number"):
        ppfd.CameraPublisher("cam", 640, 480, 500.0, 500.0, 320.0, 240.0, prefix=prefix, camera_id=-3)
    del client


@pytest.mark.parametrize(
    "options, message",
    [
        ({"min_score": 1.5}, "minimum score 1.5 is out of range: expected 0 to 1"),
        (
            {"instance_distance": 3.0},
            "instance distance 3 diameters is out of range: expected above 0 and at most 2 "
            "diameters, or 0 for the daemon's setting",
        ),
        (
            {"roi": (10, 20, 50, 0)},
            "region of interest 50x0 at (10, 20) is out of range: expected a width and height "
            "of at least 1 pixel, or 0x0 for the whole frame",
        ),
        (
            {"max_tilt_deg": 270.0},
            "pose restriction angle 270 degrees is out of range: expected 0 to 180 degrees",
        ),
        (
            {"max_tilt_deg": 30.0, "tilt_direction": (0.0, float("nan"), 0.0)},
            "pose restriction camera direction [0.0, NaN, 0.0] is out of range: expected a "
            "finite, non-zero vector",
        ),
        (
            {"max_tilt_deg": 30.0, "tilt_axis": [0, 0, 0]},
            "pose restriction model axis [0.0, 0.0, 0.0] is out of range: expected a finite, "
            "non-zero vector",
        ),
        # The forms Python gives them in.
        ({"order": "nearest"}, 'order must be "score" or "distance", got "nearest"'),
        ({"roi": (1, 2, 3)}, "roi must be 4 pixel counts (x, y, width, height), got (1, 2, 3)"),
        (
            {"roi": (-1, 0, 10, 10)},
            "roi must be 4 pixel counts (x, y, width, height), got (-1, 0, 10, 10)",
        ),
        (
            {"max_tilt_deg": 30.0, "tilt_axis": "up"},
            "tilt_axis must be 3 numbers (x, y, z), got 'up'",
        ),
        (
            {"tilt_axis": (1.0, 0.0, 0.0)},
            "tilt_axis applies only with max_tilt_deg: give max_tilt_deg too",
        ),
    ],
)
def test_a_requirement_out_of_range_raises_the_rust_message_before_sending(
    prefix, options, message
):
    # No daemon serves this prefix: a request that got as far as sending would raise NoDaemon.
    client = ppfd.Client(prefix=prefix)
    with pytest.raises(ppfd.ProtocolError) as e:
        client.detect("parts", [1], **options)
    assert isinstance(e.value, ValueError)
    assert str(e.value) == message


def test_requirements_in_range_are_sent(prefix):
    client = ppfd.Client(prefix=prefix)
    with pytest.raises(ppfd.NoDaemon):
        client.detect(
            "parts",
            [1],
            min_score=0.5,
            instance_distance=0.5,
            roi=[0, 0, 64, 48],
            max_tilt_deg=30.0,
            tilt_axis=np.array([1.0, 0.0, 0.0]),
            tilt_direction=(0, 0, -1),
            order="distance",
        )


@pytest.fixture
def publisher(prefix):
    p = ppfd.CameraPublisher("pycam", 64, 48, 60.0, 60.0, 32.0, 24.0, 1.0, prefix=prefix)
    yield p
    del p


@pytest.mark.parametrize(
    "depth, got",
    [
        (np.zeros((48, 64), np.float32), "float32 array of shape (48, 64)"),
        (np.zeros((48, 64), np.int16), "int16 array of shape (48, 64)"),
        (np.zeros((64, 48), np.uint16), "uint16 array of shape (64, 48)"),
        (np.zeros(48 * 64, np.uint16), "uint16 array of shape (3072,)"),
        (np.zeros((48, 64, 1), np.uint16), "uint16 array of shape (48, 64, 1)"),
        ([[0] * 64] * 48, "a list, not a numpy array"),
    ],
)
def test_publish_names_the_expected_and_the_given_array(publisher, depth, got):
    with pytest.raises(ValueError) as e:
        publisher.publish(depth)
    assert str(e.value) == f"depth must be a uint16 array of shape (48, 64), got {got}"


def test_publish_numbers_the_frames(publisher):
    depth = np.full((48, 64), 800, np.uint16)
    assert publisher.publish(depth) == 1
    assert publisher.publish(depth[::-1]) == 2
    assert (publisher.width, publisher.height) == (64, 48)


def test_bad_camera_settings_raise_protocol_error(prefix):
    with pytest.raises(ppfd.ProtocolError, match="intrinsics"):
        ppfd.CameraPublisher("pycam", 64, 48, 0.0, 60.0, 32.0, 24.0, prefix=prefix)
    with pytest.raises(ppfd.ProtocolError, match="camera"):
        ppfd.CameraPublisher("no spaces", 64, 48, 60.0, 60.0, 32.0, 24.0, prefix=prefix)


def test_a_malformed_prefix_raises_protocol_error():
    with pytest.raises(ppfd.ProtocolError, match="prefix name"):
        ppfd.Client(prefix="bad prefix!")
    with pytest.raises(ValueError, match="prefix name"):
        ppfd.CameraPublisher("pycam", 64, 48, 60.0, 60.0, 32.0, 24.0, prefix="")


def test_a_second_live_driver_is_refused_and_a_later_one_let_in(prefix):
    args = ("pycam", 64, 48, 60.0, 60.0, 32.0, 24.0)
    # Another process publishing under the name: refused while it runs.
    script = (
        "import sys, ppfd\n"
        f"p = ppfd.CameraPublisher(*{args!r}, prefix={prefix!r})\n"
        "print('ready', flush=True)\n"
        "sys.stdin.read()\n"
    )
    other = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout.readline() == "ready\n"
        with pytest.raises(ppfd.CameraTaken, match="another driver already publishes"):
            ppfd.CameraPublisher(*args, prefix=prefix)
    finally:
        other.stdin.close()
        other.wait(10)
    # Once it has gone, a driver is let in; and the same process may make its publisher anew
    # (a cell run twice) before the old one is dropped.
    first = ppfd.CameraPublisher(*args, prefix=prefix)
    second = ppfd.CameraPublisher(*args, prefix=prefix)
    del first
    assert second.publish(np.zeros((48, 64), dtype=np.uint16)) == 1


def test_the_exceptions_are_one_hierarchy():
    refusals = [
        "ProtocolVersion", "InvalidRequest", "EmptyObjectList", "UnknownObject",
        "InvalidFrame", "InvalidIntrinsics", "UnknownCamera", "NoFrame", "CameraStale",
        "DeadlineExceeded", "Busy", "Internal", "ShuttingDown", "ModelError",
    ]
    for name in refusals:
        assert issubclass(getattr(ppfd, name), ppfd.Refused), name
    for name in ["Refused", "Timeout", "Dropped", "DaemonGone", "NoDaemon", "CameraTaken",
                 "ProtocolError", "TransportError"]:
        assert issubclass(getattr(ppfd, name), ppfd.Error), name
    for name in ["TooManyClients", "OtherProtocolVersion"]:
        assert issubclass(getattr(ppfd, name), ppfd.TransportError), name
    assert issubclass(ppfd.Error, Exception)
    assert issubclass(ppfd.Timeout, TimeoutError)
    assert issubclass(ppfd.ProtocolError, ValueError)
    assert ppfd.UnknownObject.__module__ == "ppfd"


def test_the_type_hints_list_what_the_module_has():
    names, members, typed_dicts = stub_names()
    module = {n for n in dir(ppfd) if not n.startswith("_") and n != "ppfd"} | {"__version__"}
    assert names - typed_dicts == module
    for name in ["Client", "CameraPublisher", "Detection", "Detections", "Checks"]:
        cls = getattr(ppfd, name)
        public = {m for m in vars(cls) if not m.startswith("_") or m in members[name]}
        stubbed = {m for m in members[name] if not m.startswith("__") or m in vars(cls)}
        assert public - {"__init__"} == stubbed - {"__init__"}, name


def test_a_client_and_a_camera_close_and_refuse_use_after(prefix):
    with ppfd.Client(prefix=prefix) as client:
        with pytest.raises(ppfd.NoDaemon):
            client.models()
    with pytest.raises(ValueError, match="the ppfd.Client is closed"):
        client.models()
    client.close()
    with ppfd.CameraPublisher("pyclose", 64, 48, 60.0, 60.0, 32.0, 24.0, prefix=prefix) as camera:
        assert camera.publish(np.zeros((48, 64), np.uint16)) == 1
    with pytest.raises(ValueError, match="the ppfd.CameraPublisher is closed"):
        camera.publish(np.zeros((48, 64), np.uint16))
    with pytest.raises(ValueError, match="closed"):
        camera.idle(0.01)
    # A with-block and the frame's size are uses too.
    with pytest.raises(ValueError, match="closed"):
        camera.width
    with pytest.raises(ValueError, match="closed"):
        with camera:
            pass
    with pytest.raises(ValueError, match="the ppfd.Client is closed"):
        with client:
            pass
    camera.close()


def test_a_bad_value_is_shown_on_one_short_line(prefix):
    client = ppfd.Client(prefix=prefix)
    with pytest.raises(ppfd.ProtocolError) as e:
        client.detect("parts", [1], hints=[(1, np.zeros((5, 40)))])
    message = str(e.value)
    assert message.startswith("hints[0] must be a Detection or (object_id, 4×4 pose)"), message
    assert "\n" not in message and message.endswith("…"), message
    del client


def test_a_bad_prefix_variable_is_refused_by_name():
    """A `PPFD_PREFIX` the daemon would refuse, read by a client and a camera given no prefix,
    is a ValueError that names the variable (in a process of its own: the variable is the
    whole process's)."""
    script = """
import ppfd
for make in (lambda: ppfd.Client(), lambda: ppfd.CameraPublisher("cam", 64, 48, 60.0, 60.0, 32.0, 24.0)):
    try:
        make()
    except ppfd.ProtocolError as e:
        assert isinstance(e, ValueError), type(e)
        print(e)
    else:
        raise SystemExit("accepted")
"""
    env = {"PPFD_PREFIX": "cell1", "PATH": "/usr/bin:/bin"}
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert len(lines) == 2 and all(
        line.startswith("PPFD_PREFIX: prefix name \"cell1\" must end with '_'") for line in lines
    ), out.stdout


def test_whole_numbers_of_any_size_name_their_argument(prefix):
    client = ppfd.Client(prefix=prefix)
    with pytest.raises(ppfd.ProtocolError, match="object_id must be a whole number from 0 to 4294967295; got 9223372036854775808"):
        client.drop_model(2**63)
    with pytest.raises(ppfd.ProtocolError, match="object_id must be a whole number"):
        client.load_model("/m/obj_000001.ply", -(2**70))
    with pytest.raises(ppfd.ProtocolError, match="width must be a whole number from 0 to 4294967295; got 9223372036854775808"):
        ppfd.CameraPublisher("wide", 2**63, 48, 60.0, 60.0, 32.0, 24.0, prefix=prefix)
    camera = ppfd.CameraPublisher("whole", 64, 48, 60.0, 60.0, 32.0, 24.0, prefix=prefix)
    depth = np.zeros((48, 64), np.uint16)
    with pytest.raises(ppfd.ProtocolError, match="capture_time_ns must be a whole number from 0 to 18446744073709551615; got -1"):
        camera.publish(depth, -1)
    assert camera.publish(depth, np.uint64(5)) == 1
    # Not a number at all: Python's TypeError, as for its own int conversions.
    with pytest.raises(TypeError):
        client.detect("parts", [1], hypotheses="3")
    camera.close()
    del client
