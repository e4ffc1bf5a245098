#!/usr/bin/env python3
"""How well a pose's model colours agree with the colour image: the evidence ppfd does not use.

For one object of a BOP frame that has an RGB image and a mesh with vertex colours, and for its
ground-truth pose and each pose of the results CSVs given: the model's camera-facing vertices
whose depth the scene confirms (within 6 mm), and the share of them whose chromaticity
(r, g, b divided by their sum) lies within 0.1 (L1) of the image's at their pixel.

    python bench/colour/agreement.py ../shared/data/lmo 2 3 10 lmo.csv

Needs numpy and Pillow (`pip install numpy pillow`). docs/BENCHMARKS.md ("Where the real
frame's misses begin") has its figures for the LM-O frame; `rerank.py` orders a detection's
poses by it.
"""
import argparse
import csv
import json
from pathlib import Path

import numpy as np
from PIL import Image

TOLERANCE_MM = 6.0
CHROMA_L1 = 0.1


def read_ply_ascii(path):
    lines = Path(path).read_text().split("\n")
    end = lines.index("end_header")
    count = int(next(l for l in lines if l.startswith("element vertex")).split()[-1])
    props = [l.split()[-1] for l in lines[:end] if l.startswith("property") and "list" not in l]
    if not {"red", "green", "blue"} <= set(props):
        raise SystemExit(f"{path}: no vertex colours")
    v = np.array([[float(x) for x in l.split()[: len(props)]] for l in lines[end + 1 : end + 1 + count]])
    col = lambda names: v[:, [props.index(n) for n in names]]
    return col("xyz"), col(("nx", "ny", "nz")), col(("red", "green", "blue"))


def chromaticity(rgb):
    return rgb / (rgb.sum(axis=1, keepdims=True) + 1e-6)


class Frame:
    """A BOP frame's camera, depth (mm) and colour image."""

    def __init__(self, dataset, scene, image):
        folder = Path(dataset) / "test" / f"{scene:06d}"
        camera = json.loads((folder / "scene_camera.json").read_text())[str(image)]
        self.k = np.array(camera["cam_K"]).reshape(3, 3)
        self.depth = np.asarray(Image.open(folder / "depth" / f"{image:06d}.png"), dtype=np.float64)
        self.depth *= camera.get("depth_scale", 1.0)
        rgb = Image.open(folder / "rgb" / f"{image:06d}.png").convert("RGB")
        self.rgb = np.asarray(rgb, dtype=np.float64)
        self.truth = json.loads((folder / "scene_gt.json").read_text())[str(image)]

    def agreement(self, model, rotation, translation):
        """(vertices the depth confirms, the share of them whose colour agrees)."""
        points, normals, colours = model
        q = points @ rotation.T + translation
        facing = ((normals @ rotation.T) * q).sum(axis=1) < 0
        q, c = q[facing], colours[facing]
        k, (h, w) = self.k, self.depth.shape
        u = np.round(q[:, 0] / q[:, 2] * k[0, 0] + k[0, 2]).astype(int)
        v = np.round(q[:, 1] / q[:, 2] * k[1, 1] + k[1, 2]).astype(int)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        q, c, u, v = q[inside], c[inside], u[inside], v[inside]
        z = self.depth[v, u]
        confirmed = (z > 0) & (np.abs(z - q[:, 2]) < TOLERANCE_MM)
        if not confirmed.any():
            return 0, float("nan")
        image = self.rgb[v[confirmed], u[confirmed]]
        d = np.abs(chromaticity(c[confirmed]) - chromaticity(image)).sum(axis=1)
        return int(confirmed.sum()), float((d < CHROMA_L1).mean())


def pose_of(row):
    """A results CSV row's rotation and translation (mm)."""
    rotation = np.array([float(x) for x in row["R"].split()]).reshape(3, 3)
    return rotation, np.array([float(x) for x in row["t"].split()])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("scene", type=int)
    ap.add_argument("image", type=int)
    ap.add_argument("object", type=int)
    ap.add_argument("results", nargs="*", type=Path, help="BOP results CSVs (ppf eval --out)")
    a = ap.parse_args()
    frame = Frame(a.dataset, a.scene, a.image)
    model = read_ply_ascii(a.dataset / "models" / f"obj_{a.object:06d}.ply")

    rows = []
    for g in frame.truth:
        if g["obj_id"] == a.object:
            truth = np.array(g["cam_R_m2c"]).reshape(3, 3), np.array(g["cam_t_m2c"])
            rows.append(("ground truth", *frame.agreement(model, *truth)))
    for path in a.results:
        for r in csv.DictReader(path.open()):
            if (int(r["scene_id"]), int(r["im_id"]), int(r["obj_id"])) == (a.scene, a.image, a.object):
                name = f"{path.name}, score {float(r['score']):.3f}"
                rows.append((name, *frame.agreement(model, *pose_of(r))))
    print("| pose | vertices the depth confirms | colour within 0.1 |")
    print("|---|---:|---:|")
    for name, n, share in rows:
        print(f"| {name} | {n} | {share:.2f} |")


if __name__ == "__main__":
    main()
