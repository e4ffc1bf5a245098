#!/usr/bin/env python3
"""Would colour pick the right pose? Re-orders each object's poses by score and colour agreement.

Reads a results CSV with several poses per object and image (`ppf eval --hypotheses N`), weighs
each pose's score by its colour agreement (`agreement.py`: the share of the depth-confirmed
camera-facing vertices whose chromaticity agrees with the image), and writes the best pose of
each object and image to a new CSV, for `ppf score`. Also prints, per object, the nearest pose
to the ground truth among those given (mm between the translations): when none is near, no
reordering can find the object.

    ppf eval ../shared/data/lmo --hypotheses 50 --out many.csv
    python bench/colour/rerank.py ../shared/data/lmo many.csv best.csv --weight product
    ppf score ../shared/data/lmo best.csv

`--weight`: `score` (the detector's order, a control), `product` (score × agreement), `soft`
(score × (0.5 + agreement)) or `square` (score × agreement²). Frames need rgb/ images and models
vertex colours.
"""
import argparse
import csv
from pathlib import Path

import numpy as np

from agreement import Frame, pose_of, read_ply_ascii

WEIGHTS = {
    "score": lambda s, a: s,
    "product": lambda s, a: s * a,
    "soft": lambda s, a: s * (0.5 + a),
    "square": lambda s, a: s * a * a,
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("results", type=Path, help="a BOP results CSV with several poses per object")
    ap.add_argument("out", type=Path, help="the CSV of the best pose per object and image")
    ap.add_argument("--weight", choices=sorted(WEIGHTS), default="product")
    a = ap.parse_args()
    weigh = WEIGHTS[a.weight]
    rows = list(csv.DictReader(a.results.open()))
    frames, models, best, nearest = {}, {}, {}, {}
    for r in rows:
        scene, image, obj = int(r["scene_id"]), int(r["im_id"]), int(r["obj_id"])
        if (scene, image) not in frames:
            frames[scene, image] = Frame(a.dataset, scene, image)
        if obj not in models:
            models[obj] = read_ply_ascii(a.dataset / "models" / f"obj_{obj:06d}.ply")
        frame = frames[scene, image]
        rotation, translation = pose_of(r)
        _, share = frame.agreement(models[obj], rotation, translation)
        value = weigh(float(r["score"]), 0.0 if np.isnan(share) else share)
        key = scene, image, obj
        if key not in best or value > best[key][0]:
            best[key] = value, r
        for g in frame.truth:
            if g["obj_id"] == obj:
                distance = float(np.linalg.norm(translation - np.array(g["cam_t_m2c"])))
                nearest[key] = min(nearest.get(key, np.inf), distance)
    with a.out.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=rows[0].keys())
        writer.writeheader()
        for key in sorted(best):
            writer.writerow(best[key][1])
    print("| scene | image | object | poses | nearest to the truth (mm) |")
    print("|---:|---:|---:|---:|---:|")
    for key in sorted(best):
        count = sum(1 for r in rows if (int(r["scene_id"]), int(r["im_id"]), int(r["obj_id"])) == key)
        print(f"| {key[0]} | {key[1]} | {key[2]} | {count} | {nearest.get(key, float('nan')):.0f} |")


if __name__ == "__main__":
    main()
