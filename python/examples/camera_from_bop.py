"""Replays the depth images of a BOP dataset as a camera, as `ppf replay` does: each frame is
copied from its numpy array straight into shared memory, where the daemon reads it in place.

    python python/examples/camera_from_bop.py ../shared/data/lmo --camera kinect --fps 10 --loop

Reads `<dataset>/<split>/<scene>/scene_camera.json` and `depth/*.png` (16-bit PNG, needs
Pillow: `pip install pillow`), or a folder that is itself one scene. Stops on Ctrl-C or SIGTERM.
"""

import argparse
import json
import signal
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

import ppfd


def scene_folders(root: Path, split: str) -> list:
    if (root / "scene_camera.json").is_file():
        return [root]
    if not (root / split).is_dir():
        sys.exit(f"{root}: not a BOP dataset (no {split}/ folder) nor a scene folder (no scene_camera.json)")
    folders = sorted(p for p in (root / split).iterdir() if (p / "scene_camera.json").is_file())
    if not folders:
        sys.exit(f"{root}: no scene folder with a scene_camera.json under {split}/")
    return folders


def images(root: Path, split: str):
    """(scene folder, image id, intrinsics, depth scale, depth PNG path) in order."""
    for folder in scene_folders(root, split):
        cameras = json.loads((folder / "scene_camera.json").read_text())
        for image_id in sorted(cameras, key=int):
            png = folder / "depth" / f"{int(image_id):06d}.png"
            if png.is_file():
                camera = cameras[image_id]
                k = camera["cam_K"]
                yield folder, int(image_id), (k[0], k[4], k[2], k[5]), camera.get(
                    "depth_scale", 1.0
                ), png


def read_depth(png: Path) -> np.ndarray:
    with Image.open(png) as image:
        return np.asarray(image, dtype=np.uint16)


def idle(publisher, seconds: float, stopped: list) -> None:
    """Waits without publishing, in short steps: a signal is handled between two (Python
    runs its handlers only between calls)."""
    until = time.monotonic() + seconds
    while not stopped and time.monotonic() < until:
        publisher.idle(min(0.05, max(0.0, until - time.monotonic())))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--camera", required=True, help="camera name to publish as")
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--loop", action="store_true", help="start again after the last frame")
    parser.add_argument("--split", default="test")
    parser.add_argument("--prefix", default=None, help="iceoryx2 prefix (default: PPFD_PREFIX)")
    args = parser.parse_args()
    if not 0.01 <= args.fps <= 1000:
        sys.exit(f"--fps must be 0.01 to 1000, got {args.fps}")

    # Stopped this way rather than killed, the publisher is dropped and takes its shared
    # memory along.
    stopped = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda number, _frame: stopped.append(number))

    frames = list(images(args.dataset, args.split))
    if not frames:
        sys.exit(f"{args.dataset}: no depth image")
    _, _, intrinsics, scale, first = frames[0]
    height, width = read_depth(first).shape
    try:
        publisher = ppfd.CameraPublisher(
            args.camera, width, height, *intrinsics, scale, prefix=args.prefix
        )
    except ppfd.Error as e:  # another live driver under the name, a malformed prefix, ...
        sys.exit(f"camera {args.camera!r}: {e}")
    print(f"publishing {len(frames)} frames of {args.dataset} as camera {args.camera!r}, "
          f"{width}x{height} at {args.fps} fps", flush=True)
    decoded = {}
    period = 1.0 / args.fps
    next_frame = time.monotonic()
    while not stopped:
        for folder, image_id, k, s, png in frames:
            if stopped:
                break
            if (k, s) != (intrinsics, scale):
                sys.exit(f"{folder} image {image_id}: intrinsics {k} and depth scale {s} differ "
                         f"from the first image's ({intrinsics}, {scale}); one camera has one")
            depth = decoded.get(png)
            if depth is None:
                depth = read_depth(png)
                if args.loop:
                    decoded[png] = depth
            sequence = publisher.publish(depth)
            if sequence == 1:
                print(f"frame 1: {folder.name} image {image_id}", flush=True)
            next_frame += period
            # Not time.sleep: a daemon that subscribes meanwhile still gets the newest frame.
            idle(publisher, next_frame - time.monotonic(), stopped)
        if not args.loop:
            # The last frame stays published a little, for a daemon that takes it late.
            idle(publisher, 2.0, stopped)
            break
    print("camera stopped", flush=True)


if __name__ == "__main__":
    main()
