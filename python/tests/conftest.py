"""Fixtures of the Python tests: the generated scene written by `ppf generate`, a real `ppfd`
daemon serving its parts under an iceoryx2 prefix of this run, and a camera publishing the
scene's depth from Python.

The daemon and `ppf` are taken from `PPFD_BIN_DIR`, else from `target/release` of this
checkout (`cargo build --release -p ppfd -p ppfd-cli`). Without them the tests that need them
are skipped, saying so; under `CI=true` they fail instead.
"""

import ast
import json
import os
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import ppfd

REPO = Path(__file__).resolve().parents[2]
PYTHON_DIR = REPO / "python"
# Model building and detection are slow next to transport; a loaded CI machine gets plenty.
STARTUP_S = 300.0
DETECTION_S = 300.0


def bin_dir() -> Path:
    return Path(os.environ.get("PPFD_BIN_DIR", REPO / "target" / "release"))


def binary(name: str) -> Path:
    path = bin_dir() / name
    if not path.is_file():
        why = (
            f"{path} is missing: build it (cargo build --release -p ppfd -p ppfd-cli) "
            "or point PPFD_BIN_DIR at the folder that holds ppfd and ppf"
        )
        if os.environ.get("CI") == "true":
            pytest.fail(why)
        pytest.skip(why)
    return path


def fresh_prefix(tag: str) -> str:
    return f"ppfdpy_{tag}_{os.getpid()}_{time.monotonic_ns() % 1_000_000_000}_"


@dataclass
class Scene:
    """The generated scene as written in the BOP layout, read back."""

    root: Path
    depth: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float
    truth: list  # (object id, 4×4 pose) per object

    @property
    def object_ids(self) -> list:
        return [object_id for object_id, _ in self.truth]

    def model_path(self, object_id: int) -> Path:
        return self.root / "models" / f"obj_{object_id:06d}.ply"


def read_depth_png(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image, dtype=np.uint16)


@pytest.fixture(scope="session")
def scene(tmp_path_factory) -> Scene:
    root = tmp_path_factory.mktemp("generated")
    subprocess.run([str(binary("ppf")), "generate", str(root), "--seed", "1"], check=True)
    scene_dir = root / "test" / "000000"
    camera = json.loads((scene_dir / "scene_camera.json").read_text())["0"]
    k = camera["cam_K"]
    truth = []
    for entry in json.loads((scene_dir / "scene_gt.json").read_text())["0"]:
        pose = np.eye(4)
        pose[:3, :3] = np.array(entry["cam_R_m2c"]).reshape(3, 3)
        pose[:3, 3] = entry["cam_t_m2c"]
        truth.append((entry["obj_id"], pose))
    return Scene(
        root=root,
        depth=read_depth_png(scene_dir / "depth" / "000000.png"),
        fx=k[0],
        fy=k[4],
        cx=k[2],
        cy=k[5],
        depth_scale=camera["depth_scale"],
        truth=truth,
    )


class Daemon:
    """A `ppfd` process, stopped with SIGTERM (then killed) by `stop`."""

    def __init__(self, prefix: str, models: Path, cache: Path):
        self.prefix = prefix
        self.process = subprocess.Popen(
            [
                str(binary("ppfd")),
                "--prefix", prefix,
                "--models", str(models),
                "--model-cache", str(cache),
                "--housekeeping-ms", "100",
                "--max-frame-age-ms", "60000",
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        ready = threading.Event()

        def read_stdout():
            for line in self.process.stdout:
                if line.startswith("ppfd ready"):
                    ready.set()

        threading.Thread(target=read_stdout, daemon=True).start()
        if not ready.wait(STARTUP_S):
            self.stop()
            pytest.fail(f"ppfd printed no 'ppfd ready' within {STARTUP_S} s")

    def stop(self):
        self.process.terminate()
        try:
            self.process.wait(10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


@pytest.fixture(scope="session")
def daemon(scene, tmp_path_factory):
    prefix = fresh_prefix("daemon")
    d = Daemon(prefix, scene.root / "models", tmp_path_factory.mktemp("model-cache"))
    yield d
    d.stop()
    ppfd.remove_prefix_leftovers(prefix)


@pytest.fixture(scope="session")
def client(daemon):
    return ppfd.Client(prefix=daemon.prefix, control_timeout=60.0)


@pytest.fixture(scope="session")
def camera(daemon, scene):
    """The camera `parts`, publishing the scene's depth from Python."""
    publisher = ppfd.CameraPublisher(
        "parts",
        scene.depth.shape[1],
        scene.depth.shape[0],
        scene.fx,
        scene.fy,
        scene.cx,
        scene.cy,
        scene.depth_scale,
        prefix=daemon.prefix,
    )
    publisher.publish(scene.depth)
    return publisher


def detect_when_subscribed(client, camera, depth, object_ids, **options):
    """Publishes `depth` and detects, again while the daemon has not yet subscribed to the
    camera (it does at its next housekeeping round, or once the driver announces itself)."""
    deadline = time.monotonic() + 20.0
    while True:
        camera.publish(depth)
        try:
            return client.detect("parts", object_ids, timeout=DETECTION_S, **options)
        except (ppfd.NoFrame, ppfd.UnknownCamera):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def stub_names():
    """The stub's top-level names and, per class, its members, from python/ppfd.pyi."""
    tree = ast.parse((PYTHON_DIR / "ppfd.pyi").read_text())
    names, members, typed_dicts = set(), {}, set()
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            names.add(node.name)
            if any(getattr(b, "id", None) == "TypedDict" for b in node.bases):
                typed_dicts.add(node.name)
            members[node.name] = {
                n.name if isinstance(n, ast.FunctionDef) else n.target.id
                for n in node.body
                if isinstance(n, (ast.FunctionDef, ast.AnnAssign))
            }
        elif isinstance(node, ast.FunctionDef):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign):
            names.add(node.target.id)
    return names, members, typed_dicts
