"""The examples as a user runs them: `camera_from_bop.py` replays the generated scene written in
the BOP layout, and `picking_loop.py` picks from it through the real daemon."""

import json
import re
import subprocess
import sys
import threading

import numpy as np

import ppfd

from conftest import PYTHON_DIR, fresh_prefix

EXAMPLES = PYTHON_DIR / "examples"


def test_the_picking_loop_picks_replayed_parts_at_their_true_poses(daemon, client, scene):
    camera = subprocess.Popen(
        [sys.executable, str(EXAMPLES / "camera_from_bop.py"), str(scene.root),
         "--camera", "replayed", "--fps", "20", "--loop", "--prefix", daemon.prefix],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        first = threading.Event()
        lines = []

        def read():
            for line in camera.stdout:
                lines.append(line)
                if line.startswith("frame 1"):
                    first.set()

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        assert first.wait(60), f"the camera printed no first frame: {lines}"
        picking = subprocess.run(
            [sys.executable, str(EXAMPLES / "picking_loop.py"), "replayed", "6", "1,2", "3,4",
             "--prefix", daemon.prefix, "--timeout", "300"],
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert picking.returncode == 0, picking.stderr
    finally:
        camera.terminate()
        camera.wait(10)
    reader.join(10)
    assert "camera stopped\n" in lines, lines
    assert camera.returncode == 0

    diameters = {m["object_id"]: m["diameter_mm"] for m in client.models()}
    truth = dict(scene.truth)
    picks = re.findall(
        r"order \[([\d, ]+)\] -> pick object (\d+) \(score [\d.]+\) at \((\S+), (\S+), (\S+)\) mm",
        picking.stdout,
    )
    # The first cycles may come before the daemon has the camera's first frame.
    assert len(picks) >= 3, picking.stdout
    for order, object_id, *xyz in picks:
        object_id = int(object_id)
        assert object_id in [int(i) for i in order.split(",")]
        dt = np.linalg.norm(np.array(xyz, dtype=float) - truth[object_id][:3, 3])
        # The printed position is rounded to millimetres.
        assert dt < 0.1 * diameters[object_id] + 1.0, (object_id, dt, picking.stdout)
    assert f"{len(picks)} picks in 6 cycles" in picking.stdout


def test_the_latency_bench_measures_the_call_around_the_transport(daemon, client, camera, scene):
    from conftest import detect_when_subscribed

    detect_when_subscribed(client, camera, scene.depth, [1])
    bench = subprocess.run(
        [sys.executable, str(PYTHON_DIR / "benches" / "detect_latency.py"), "--camera", "parts",
         "--objects", "1", "--requests", "5", "--warmup", "1", "--timeout", "300",
         "--prefix", daemon.prefix, "--json"],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert bench.returncode == 0, bench.stderr
    result = json.loads(bench.stdout)
    assert result["requests"] == 5
    latency = result["latency"]
    for name in ("call", "end_to_end", "overhead"):
        row = latency[name]
        assert 0 < row["p50_ns"] <= row["p90_ns"] <= row["p99_ns"] <= row["max_ns"], (name, row)
    # Each call holds its request's whole way, and each end to end its detection: so does
    # every order statistic.
    for q in ("p50_ns", "max_ns"):
        assert latency["call"][q] >= latency["end_to_end"][q] >= latency["overhead"][q], q


def test_the_replay_example_names_a_folder_that_is_no_dataset(tmp_path):
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / "camera_from_bop.py"), str(tmp_path / "nosuch"),
         "--camera", "k"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 1
    assert "nosuch: not a BOP dataset (no test/ folder)" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr


def test_the_replay_example_names_a_camera_another_driver_publishes(scene):
    prefix = fresh_prefix("taken")
    first = subprocess.Popen(
        [sys.executable, str(EXAMPLES / "camera_from_bop.py"), str(scene.root),
         "--camera", "taken", "--loop", "--prefix", prefix],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert first.stdout.readline().startswith("publishing"), "the first driver did not start"
        second = subprocess.run(
            [sys.executable, str(EXAMPLES / "camera_from_bop.py"), str(scene.root),
             "--camera", "taken", "--prefix", prefix],
            capture_output=True,
            text=True,
            timeout=60,
        )
    finally:
        first.terminate()
        first.wait(10)
        ppfd.remove_prefix_leftovers(prefix)
    assert second.returncode == 1
    assert "camera 'taken': another driver already publishes" in second.stderr, second.stderr
    assert "Traceback" not in second.stderr


def test_the_picking_loop_stopped_by_ctrl_c_prints_its_summary(daemon):
    import signal

    # A camera that never comes: every cycle waits and retries, until Ctrl-C.
    picking = subprocess.Popen(
        [sys.executable, str(EXAMPLES / "picking_loop.py"), "nocamera", "1000", "1",
         "--prefix", daemon.prefix, "--timeout", "5"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        first = picking.stdout.readline()
        assert first.startswith("cycle 0: "), first
        picking.send_signal(signal.SIGINT)
        out, err = picking.communicate(timeout=60)
    finally:
        picking.kill()
    assert picking.returncode == 130, (out, err)
    assert re.search(r"^0 picks in \d+ cycles \(stopped by Ctrl-C\); 0 failed$", out, re.M), out
    assert "Traceback" not in err, err
