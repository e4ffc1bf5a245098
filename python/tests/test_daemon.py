"""The package against a real `ppfd` daemon serving the generated parts: poses from Python
against the truth, control requests, refusals as exceptions, the GIL released while waiting."""

import math
import os
import signal
import threading
import time

import numpy as np
import pytest

import ppfd
from conftest import DETECTION_S, Daemon, detect_when_subscribed, fresh_prefix, stub_names

# A correct pose: translation within this fraction of the object's diameter, and rotation
# within this angle (the generated parts have no symmetry to allow for), as the Rust
# end-to-end test of the same scene.
MAX_TRANSLATION_OF_DIAMETER = 0.1
MAX_ROTATION_DEG = 15.0


def rotation_deg(a: np.ndarray, b: np.ndarray) -> float:
    r = a[:3, :3].T @ b[:3, :3]
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0))))


def test_every_part_is_found_at_its_true_pose(client, camera, scene):
    found = detect_when_subscribed(client, camera, scene.depth, scene.object_ids)
    diameters = {m["object_id"]: m["diameter_mm"] for m in client.models()}
    assert len(found) == len(scene.truth)
    for object_id, truth in scene.truth:
        best = found.best(object_id)
        assert best is not None, f"no pose of object {object_id}"
        pose = best.pose
        assert pose.shape == (4, 4) and pose.dtype == np.float64
        assert np.allclose(pose[3], [0, 0, 0, 1])
        assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-5)
        dt = np.linalg.norm(pose[:3, 3] - truth[:3, 3])
        dr = rotation_deg(pose, truth)
        assert dt < MAX_TRANSLATION_OF_DIAMETER * diameters[object_id], (object_id, dt)
        assert dr < MAX_ROTATION_DEG, (object_id, dr)
        assert best.rank == 0 and 0.0 < best.score <= 1.0
        assert best.checks & ppfd.Checks.RESCORED
    latency = found.latency
    _, members, _ = stub_names()
    assert set(latency) == members["Latency"]
    assert set(found.counts) == members["Counts"]
    assert set(client.models()[0]) == members["Model"]
    stats = client.stats()
    assert set(stats) == members["Stats"]
    assert set(stats["total"]) == members["LatencySummary"]
    assert set(stats["recent_total"]) == members["LatencySummary"]
    assert 1 <= stats["recent_total"]["count"] <= stats["total"]["count"]
    assert 0 < stats["recent_window_ns"] <= stats["uptime_ns"]
    assert latency["detection_ns"] > 0
    assert latency["end_to_end_ns"] >= latency["detection_ns"]
    assert latency["overhead_ns"] == latency["end_to_end_ns"] - latency["detection_ns"]
    assert found.counts["returned"] == len(found)
    assert found.counts["scene_points"] > 0


def test_detections_are_a_sequence_grouped_by_object(client, camera, scene):
    found = detect_when_subscribed(client, camera, scene.depth, [3, 1], hypotheses=2)
    poses = list(found)
    assert len(poses) == len(found) and 2 <= len(found) <= 4
    # Grouped by object in request order, best first within an object.
    assert [d.object_id for d in poses] == sorted(
        (d.object_id for d in poses), key=[3, 1].index
    )
    for object_id in (3, 1):
        ranks = [d.rank for d in found.of(object_id)]
        assert ranks == list(range(len(ranks)))
    assert found[-1].object_id == poses[-1].object_id
    with pytest.raises(IndexError, match="out of range"):
        found[len(found)]
    assert found.best(2) is None
    assert found.frame_sequence >= 1
    # The rest of a sequence: slices, index, count.
    assert found[1:] == poses[1:] and found[::-1] == poses[::-1] and found[5:9] == []
    assert found.index(found[1]) == 1 and found.count(found[0]) == 1
    with pytest.raises(ValueError):
        found.index(object())
    # `index` takes a list's bounds, negative ones from the end.
    last = len(found) - 1
    assert found.index(found[last], 1) == last and found.index(found[last], -1) == last
    assert found.index(found[0], 0, 1) == 0
    with pytest.raises(ValueError):
        found.index(found[0], 1)
    with pytest.raises(ValueError):
        found.index(found[last], 0, -1)


def test_a_strided_array_publishes_the_same_frame(client, camera, scene):
    contiguous = detect_when_subscribed(client, camera, scene.depth, [1])
    # Fortran order: no row of it is contiguous in memory.
    fortran = np.asfortranarray(scene.depth)
    assert not fortran.flags.c_contiguous
    strided = detect_when_subscribed(client, camera, fortran, [1])
    assert strided.frame_sequence > contiguous.frame_sequence
    assert strided.counts["scene_points"] == contiguous.counts["scene_points"]
    assert np.allclose(strided[0].pose, contiguous[0].pose)


def test_models_and_stats(client, scene):
    models = client.models()
    assert [m["object_id"] for m in models] == sorted(scene.object_ids)
    assert all(m["diameter_mm"] > 0 and m["point_count"] > 0 for m in models)
    # The generated parts have no symmetry.
    assert all(m["discrete_symmetries"] == 0 and m["continuous_symmetry"] is False for m in models)
    stats = client.stats()
    assert stats["models_loaded"] == len(scene.object_ids)
    assert stats["uptime_ns"] > 0
    assert set(stats["total"]) == {"count", "p50_ns", "p90_ns", "p99_ns", "max_ns"}
    assert stats["message"] == "detector: defaults"
    # The session's daemon loaded its whole models folder at start, each file without failure.
    n = len(scene.object_ids)
    assert (stats["startup_files"], stats["startup_files_done"]) == (n, n)
    assert stats["startup_files_failed"] == 0
    assert (stats["model_loads_running"], stats["model_loads_waiting"]) == (0, 0)


def test_a_monitor_connects_for_control_requests_only(daemon, scene):
    with ppfd.Client(prefix=daemon.prefix, detects=False) as monitor:
        assert monitor.stats()["models_loaded"] == len(scene.object_ids)
        with pytest.raises(ValueError, match="control requests only"):
            monitor.detect("parts", [1])


def test_a_dropped_model_is_unknown_until_loaded_again(client, camera, scene):
    client.drop_model(4)
    try:
        with pytest.raises(ppfd.UnknownObject) as again:
            client.drop_model(4)
        assert again.value.value == 4
        with pytest.raises(ppfd.UnknownObject) as refused:
            detect_when_subscribed(client, camera, scene.depth, [4])
        assert refused.value.value == 4
        assert refused.value.status == "unknown object"
        assert 4 not in [m["object_id"] for m in client.models()]
    finally:
        # A bound of its own, past the client's control timeout.
        model = client.load_model(scene.model_path(4), timeout=60.0)
    assert model["object_id"] == 4
    with pytest.raises(ppfd.ProtocolError, match="timeout"):
        client.load_model(scene.model_path(4), timeout=-1.0)
    found = detect_when_subscribed(client, camera, scene.depth, [4])
    assert found.best(4) is not None


def test_refusals_are_exceptions_with_the_rust_message(client, camera, scene):
    with pytest.raises(ppfd.UnknownObject) as e:
        detect_when_subscribed(client, camera, scene.depth, [1, 99])
    assert isinstance(e.value, ppfd.Refused) and isinstance(e.value, ppfd.Error)
    assert str(e.value).startswith("refused (unknown object): ")
    assert "99" in str(e.value)
    assert (e.value.status, e.value.value) == ("unknown object", 99)

    with pytest.raises(ppfd.UnknownCamera) as e:
        client.detect("nosuchcamera", [1])
    assert str(e.value).startswith("refused (unknown camera): ")
    assert "nosuchcamera" in str(e.value)

    with pytest.raises(ppfd.ModelError):
        client.load_model(scene.root / "no-such-model.ply")


def test_the_gil_is_released_while_the_daemon_works(client, camera, scene):
    counted = 0
    stop = threading.Event()

    def count():
        nonlocal counted
        while not stop.is_set():
            counted += 1

    camera.publish(scene.depth)
    counter = threading.Thread(target=count)
    counter.start()
    try:
        before = counted
        found = client.detect("parts", scene.object_ids, timeout=DETECTION_S)
        during = counted - before
    finally:
        stop.set()
        counter.join()
    # A detection of four parts takes a quarter of a second or more: a thread that held the
    # GIL throughout would let the counter run for none of it.
    assert found.latency["detection_ns"] > 10_000_000
    assert during > 1000, f"the counter ran {during} times during the detection"


class Alarm(Exception):
    pass


def test_a_signal_handler_that_returns_leaves_the_request_waiting(client, camera, scene):
    # A watchdog timer firing every 20 ms through a whole detection: each signal wakes the
    # wait, which goes on to the answer.
    fired = 0

    def tick(*_):
        nonlocal fired
        fired += 1

    detect_when_subscribed(client, camera, scene.depth, [1])
    previous = signal.signal(signal.SIGALRM, tick)
    signal.setitimer(signal.ITIMER_REAL, 0.02, 0.02)
    try:
        found = client.detect("parts", scene.object_ids, timeout=DETECTION_S)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert fired > 0 and len(found) == len(scene.truth), (fired, len(found))


def test_a_signal_handler_that_raises_ends_the_request_with_its_exception(client, camera, scene):
    def ring(*_):
        raise Alarm("rang during the detection")

    detect_when_subscribed(client, camera, scene.depth, [1])
    previous = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, 0.02)
    try:
        with pytest.raises(Alarm):
            client.detect("parts", scene.object_ids, timeout=DETECTION_S)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    # The same client serves the next request.
    found = client.detect("parts", scene.object_ids, timeout=DETECTION_S)
    assert len(found) == len(scene.truth)


def test_a_signal_that_another_thread_takes_still_ends_the_request(daemon, client, camera, scene):
    # A signal taken by another thread of the process, or while the waiting thread was busy
    # between waits, interrupts no wait: the handler must still run within the wait. Here the
    # waiting thread blocks the signal, so that the timer's thread takes it; the daemon is
    # paused, so that the request would wait to its timeout.
    def ring(*_):
        raise Alarm("rang from another thread")

    detect_when_subscribed(client, camera, scene.depth, [1])
    previous = signal.signal(signal.SIGALRM, ring)
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGALRM))
    timer.start()  # before the mask: the thread keeps the signal unblocked
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
    daemon.process.send_signal(signal.SIGSTOP)
    started = time.monotonic()
    try:
        with pytest.raises(Alarm):
            client.detect("parts", [1], timeout=20.0)
        waited = time.monotonic() - started
    finally:
        daemon.process.send_signal(signal.SIGCONT)
        timer.join()
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGALRM})
        signal.signal(signal.SIGALRM, previous)
    assert waited < 5.0, waited
    # The same client serves the next request.
    found = client.detect("parts", scene.object_ids, timeout=DETECTION_S)
    assert len(found) == len(scene.truth)


def test_idle_ends_when_a_signal_handler_raises(camera):
    def ring(*_):
        raise Alarm("rang while idle")

    previous = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, 0.05)
    started = time.monotonic()
    try:
        with pytest.raises(Alarm):
            camera.idle(60.0)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    # Well before the minute it was asked to wait.
    assert time.monotonic() - started < 30.0


def test_a_short_deadline_ends_the_request_on_one_side_or_the_other(client, camera, scene):
    camera.publish(scene.depth)
    # The daemon holds to the deadline too: it may refuse the request before the client
    # stops waiting.
    with pytest.raises((ppfd.Timeout, ppfd.DeadlineExceeded)):
        client.detect("parts", scene.object_ids, timeout=0.02)


def test_a_daemon_that_does_not_answer_raises_timeout(scene, tmp_path):
    prefix = fresh_prefix("stopped")
    d = Daemon(prefix, scene.root / "models", tmp_path / "cache")
    try:
        client = ppfd.Client(prefix)
        # Alive but stopped: it holds the request and never answers.
        d.process.send_signal(signal.SIGSTOP)
        started = time.monotonic()
        with pytest.raises(ppfd.Timeout) as e:
            client.detect("parts", scene.object_ids, timeout=0.3)
        waited = time.monotonic() - started
        assert isinstance(e.value, TimeoutError)
        assert "no answer from ppfd within" in str(e.value)
        assert waited >= 0.3
    finally:
        d.process.send_signal(signal.SIGCONT)
        d.stop()
        ppfd.remove_prefix_leftovers(prefix)


def test_a_client_is_used_by_the_thread_that_made_it(client):
    errors = []

    def use():
        try:
            client.models()
        except RuntimeError as e:
            errors.append(str(e))

    t = threading.Thread(target=use)
    t.start()
    t.join()
    assert len(errors) == 1 and "used only by the thread that made it" in errors[0]
    assert client.models()


def found_at(detection, truth, diameter) -> bool:
    dt = np.linalg.norm(detection.pose[:3, 3] - truth[:3, 3])
    return dt < MAX_TRANSLATION_OF_DIAMETER * diameter and (
        rotation_deg(detection.pose, truth) < MAX_ROTATION_DEG
    )


def vertices(scene, object_id) -> np.ndarray:
    """The vertex positions of a part's ASCII PLY mesh, mm."""
    lines = scene.model_path(object_id).read_text().splitlines()
    count = next(int(line.split()[2]) for line in lines if line.startswith("element vertex"))
    start = lines.index("end_header") + 1
    return np.array([line.split()[:3] for line in lines[start:start + count]], float)


def mesh_centre(scene, object_id) -> np.ndarray:
    """The centre of the mesh's bounding box: the model centre whose distance orders poses."""
    v = vertices(scene, object_id)
    return (v.min(axis=0) + v.max(axis=0)) / 2


def distance(detection, centre) -> float:
    return float(np.linalg.norm(detection.pose[:3, :3] @ centre + detection.pose[:3, 3]))


def pixel_box(scene, object_id, truth):
    """The pixel rectangle (x0, y0, x1, y1), inclusive, the part's mesh projects into."""
    points = vertices(scene, object_id) @ truth[:3, :3].T + truth[:3, 3]
    u = np.floor(scene.fx * points[:, 0] / points[:, 2] + scene.cx)
    v = np.floor(scene.fy * points[:, 1] / points[:, 2] + scene.cy)
    return int(u.min()), int(v.min()), int(u.max()), int(v.max())


def test_a_region_of_interest_finds_the_part_in_it_and_not_one_outside(client, camera, scene):
    height, width = scene.depth.shape
    boxes = {
        object_id: pixel_box(scene, object_id, truth) for object_id, truth in scene.truth
    }
    apart = [
        (a, b)
        for a, (ax0, ay0, ax1, ay1) in boxes.items()
        for b, (bx0, by0, bx1, by1) in boxes.items()
        if a != b and (bx0 > ax1 or bx1 < ax0 or by0 > ay1 or by1 < ay0)
    ]
    assert apart, f"no two parts apart in the picture: {boxes}"
    inside, outside = apart[0]
    x0, y0, x1, y1 = boxes[inside]
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width - 1), min(y1, height - 1)
    roi = (x0, y0, x1 - x0 + 1, y1 - y0 + 1)
    truth = dict(scene.truth)
    diameters = {m["object_id"]: m["diameter_mm"] for m in client.models()}

    whole = detect_when_subscribed(client, camera, scene.depth, [inside, outside])
    within = detect_when_subscribed(client, camera, scene.depth, [inside, outside], roi=roi)
    for object_id in (inside, outside):
        assert found_at(whole.best(object_id), truth[object_id], diameters[object_id])
    assert found_at(within.best(inside), truth[inside], diameters[inside])
    assert not any(
        found_at(d, truth[outside], diameters[outside]) for d in within.of(outside)
    ), f"object {outside} found from the region {roi} of object {inside}"
    assert within.counts["reference_points"] < whole.counts["reference_points"] / 2

    # In range, but outside the frame: only the daemon, which knows the frame, tells.
    with pytest.raises(ppfd.InvalidRequest, match=f"outside the {width}x{height} frame"):
        detect_when_subscribed(
            client, camera, scene.depth, [inside], roi=(width - 10, 0, 100, 10)
        )


def test_nearest_first_above_a_minimum_score(client, camera, scene):
    plain = detect_when_subscribed(client, camera, scene.depth, scene.object_ids, hypotheses=4)
    scores = sorted(d.score for d in plain)
    # Just above the lowest score: that pose goes, and enough stay to have an order.
    min_score = (scores[0] + scores[1]) / 2
    assert scores[0] < min_score < scores[1], scores

    found = detect_when_subscribed(
        client,
        camera,
        scene.depth,
        scene.object_ids,
        hypotheses=4,
        min_score=min_score,
        order="distance",
    )
    assert found and all(d.score >= min_score for d in found)
    filters = ppfd.Checks.CONSISTENT | ppfd.Checks.SILHOUETTE
    ordered = 0
    for object_id in scene.object_ids:
        centre = mesh_centre(scene, object_id)
        poses = found.of(object_id)
        assert [d.rank for d in poses] == list(range(len(poses)))
        # Nearest first among the poses that passed as many filters; those that passed fewer
        # come after, as with the best score first.
        for first, second in zip(poses, poses[1:]):
            if bin(first.checks & filters).count("1") == bin(second.checks & filters).count("1"):
                assert distance(first, centre) <= distance(second, centre) + 1e-3, object_id
                ordered += 1
    assert ordered > 0, "no two poses of one object to order"


def test_hints_from_an_answer_or_the_truth_come_back_refined(client, camera, scene):
    voted = detect_when_subscribed(client, camera, scene.depth, scene.object_ids)
    assert not any(d.checks & ppfd.Checks.HINT for d in voted)

    # The previous answer as hints: every part comes back from its hint, where it was.
    again = detect_when_subscribed(client, camera, scene.depth, scene.object_ids, hints=voted)
    for object_id in scene.object_ids:
        before, after = voted.best(object_id), again.best(object_id)
        assert after.checks & ppfd.Checks.HINT, object_id
        assert np.linalg.norm(after.pose[:3, 3] - before.pose[:3, 3]) < 5.0, object_id
        assert rotation_deg(after.pose, before.pose) < 3.0, object_id

    # The whole answer as hints for fewer objects: the other objects' poses are left out.
    first = scene.object_ids[0]
    fewer = detect_when_subscribed(client, camera, scene.depth, [first], hints=voted)
    assert {d.object_id for d in fewer} == {first}
    assert fewer.best(first).checks & ppfd.Checks.HINT

    # The truth as (object id, 4×4 array) pairs, one of them moved far away: the far hint
    # fails and its part is voted for, at its true pose all the same.
    far_id, far_truth = scene.truth[0]
    moved = far_truth.copy()
    moved[:3, 3] += [400.0, 0.0, 0.0]
    hints = [(far_id, moved)] + [(i, t) for i, t in scene.truth[1:]]
    found = detect_when_subscribed(client, camera, scene.depth, scene.object_ids, hints=hints)
    diameters = {m["object_id"]: m["diameter_mm"] for m in client.models()}
    for object_id, truth in scene.truth:
        best = found.best(object_id)
        assert bool(best.checks & ppfd.Checks.HINT) == (object_id != far_id), object_id
        dt = np.linalg.norm(best.pose[:3, 3] - truth[:3, 3])
        assert dt < MAX_TRANSLATION_OF_DIAMETER * diameters[object_id], (object_id, dt)
        assert rotation_deg(best.pose, truth) < MAX_ROTATION_DEG, object_id
    assert found.latency["voting_ns"] > 0


def test_a_diagnosis_says_where_each_object_is_lost(client, camera, scene):
    # Against the truth every part is found; against a pose far from the first part, that
    # part is lost at some stage. A request with hints as well is refused before sending.
    far_id, far_truth = scene.truth[0]
    moved = far_truth.copy()
    moved[:3, 3] += [0.0, 0.0, 600.0]
    poses = [(far_id, moved)] + [(i, t) for i, t in scene.truth[1:]]
    found = detect_when_subscribed(
        client, camera, scene.depth, scene.object_ids, diagnose=poses
    )
    heads = [line for line in found.diagnosis.splitlines() if not line.startswith(" ")]
    assert heads[0].startswith(f"object {far_id}: lost at "), found.diagnosis
    assert heads[1:] == [f"object {i}: found" for i, _ in scene.truth[1:]], found.diagnosis
    assert len(found) >= len(scene.object_ids)
    plain = detect_when_subscribed(client, camera, scene.depth, scene.object_ids[:1])
    assert plain.diagnosis == ""
    with pytest.raises(ppfd.ProtocolError, match="hints"):
        client.detect("parts", [far_id], hints=[(far_id, far_truth)], diagnose=[(far_id, far_truth)])
    with pytest.raises(ppfd.ProtocolError, match=r"diagnose\[0\]"):
        client.detect("parts", [far_id], diagnose=[(far_id, far_truth[:2])])
    with pytest.raises(ppfd.ProtocolError, match="diagnose holds no pose"):
        client.detect("parts", [far_id], diagnose=[])


def test_malformed_hints_are_refused_before_sending(client, camera, scene):
    object_id, truth = scene.truth[0]
    sheared = truth.copy()
    sheared[0, 1] += 0.5
    with pytest.raises(ppfd.ProtocolError, match="rotation"):
        client.detect("parts", [object_id], hints=[(object_id, sheared)])
    with pytest.raises(ppfd.ProtocolError, match=r"hints\[0\]"):
        client.detect("parts", [object_id], hints=[(object_id, truth[:2])])
    with pytest.raises(ppfd.ProtocolError, match=r"hints\[1\]"):
        client.detect("parts", [object_id], hints=[(object_id, truth), "a pose"])
    other = next(i for i in scene.object_ids if i != object_id)
    with pytest.raises(ppfd.ProtocolError, match=str(other)):
        client.detect("parts", [object_id], hints=[(other, truth)])
