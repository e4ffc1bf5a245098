#!/usr/bin/env python3
"""Runs OpenCV's point pair feature detector (cv2.ppf_match_3d, Drost et al. 2010) with its ICP
on a dataset in the BOP layout and writes a BOP results CSV (scene_id,im_id,obj_id,score,R,t,time)
that `ppf score` can read.

For each image with a depth PNG: the depth is back-projected into a cloud (mm), its normals are
estimated with computeNormalsPC3d (flipped towards the camera), then every target object of the
image (from test_targets_bop19.json, else every object of the ground truth) is matched with a
detector trained once on its model (models/obj_XXXXXX.ply with normals), and the best poses are
refined with ICP. `time` is the wall time of all of that for the image (model training excluded,
as it is done once, offline). See README.md for the parameters.
"""

import argparse
import hashlib
import json
import os
import sys
import time

import cv2
import numpy as np


def load_json(path):
    with open(path) as f:
        return json.load(f)


def scene_dirs(root, split):
    split_dir = os.path.join(root, split)
    return sorted(
        (int(name), os.path.join(split_dir, name))
        for name in os.listdir(split_dir)
        if name.isdigit() and os.path.isdir(os.path.join(split_dir, name))
    )


def image_jobs(root, split, targets_file, max_images):
    """(scene_id, im_id, scene_dir, [(obj_id, inst_count)]) for every image with depth."""
    targets = {}
    path = os.path.join(root, targets_file)
    if os.path.isfile(path):
        for t in load_json(path):
            targets.setdefault((t["scene_id"], t["im_id"]), []).append((t["obj_id"], t["inst_count"]))
    jobs = []
    for scene_id, scene_dir in scene_dirs(root, split):
        gt = load_json(os.path.join(scene_dir, "scene_gt.json"))
        for key in sorted(gt, key=int):
            im_id = int(key)
            if not os.path.isfile(os.path.join(scene_dir, "depth", f"{im_id:06d}.png")):
                continue
            objects = targets.get((scene_id, im_id))
            if objects is None:
                counts = {}
                for g in gt[key]:
                    counts[g["obj_id"]] = counts.get(g["obj_id"], 0) + 1
                objects = sorted(counts.items())
            jobs.append((scene_id, im_id, scene_dir, objects))
    return jobs[:max_images] if max_images else jobs


def scene_cloud(scene_dir, im_id, stride, normal_neighbors):
    cams = load_json(os.path.join(scene_dir, "scene_camera.json"))[str(im_id)]
    k = np.array(cams["cam_K"], dtype=np.float64).reshape(3, 3)
    scale = float(cams.get("depth_scale", 1.0))
    depth = cv2.imread(os.path.join(scene_dir, "depth", f"{im_id:06d}.png"), cv2.IMREAD_ANYDEPTH)
    if depth is None:
        raise RuntimeError(f"cannot read the depth of image {im_id} in {scene_dir}")
    z = depth.astype(np.float32) * scale
    v, u = np.mgrid[0 : z.shape[0] : stride, 0 : z.shape[1] : stride]
    z = z[::stride, ::stride]
    valid = z > 0
    x = (u[valid] - k[0, 2]) * z[valid] / k[0, 0]
    y = (v[valid] - k[1, 2]) * z[valid] / k[1, 1]
    cloud = np.ascontiguousarray(np.stack([x, y, z[valid]], axis=1), dtype=np.float32)
    _, with_normals = cv2.ppf_match_3d.computeNormalsPC3d(cloud, normal_neighbors, True, (0.0, 0.0, 0.0))
    return with_normals


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("pairs", nargs="+", metavar="DATASET OUTPUT",
                   help="BOP dataset root (models/, test/...) and the results CSV to write for it; "
                        "several pairs share the trained detectors of identical model files")
    p.add_argument("--split", default="test")
    p.add_argument("--targets", default="test_targets_bop19.json")
    p.add_argument("--max-images", type=int, default=0, help="only the first N images (0 = all)")
    # Training (PPF3DDetector constructor): OpenCV's sample values.
    p.add_argument("--rel-sampling-step", type=float, default=0.05)
    p.add_argument("--rel-distance-step", type=float, default=0.05)
    p.add_argument("--num-angles", type=int, default=30)
    # Matching: scene sampling relative to the scene's bounding box; every k-th sampled point is
    # a reference point.
    p.add_argument("--scene-sample-step", type=float, default=1.0 / 40.0)
    p.add_argument("--scene-distance", type=float, nargs="+", default=[0.025],
                   help="one or more values; with several, the models are trained once and one "
                        "CSV is written per value (output name + _sd<value>)")
    # Scene preparation.
    p.add_argument("--pixel-stride", type=int, default=2, help="use every n-th pixel in u and v")
    p.add_argument("--normal-neighbors", type=int, default=6)
    # ICP (OpenCV's sample: ICP(100, 0.005, 2.5, 8)) on the top N poses.
    p.add_argument("--top-n", type=int, default=2)
    p.add_argument("--icp-iterations", type=int, default=100)
    p.add_argument("--icp-tolerance", type=float, default=0.005)
    p.add_argument("--icp-rejection-scale", type=float, default=2.5)
    p.add_argument("--icp-levels", type=int, default=8)
    a = p.parse_args()

    if len(a.pairs) % 2:
        p.error("give DATASET OUTPUT pairs")
    trained = {}  # model file digest -> (model cloud, detector)
    for dataset, output in zip(a.pairs[::2], a.pairs[1::2]):
        run_dataset(a, dataset, output, trained)


def run_dataset(a, dataset, output, trained):
    jobs = image_jobs(dataset, a.split, a.targets, a.max_images)
    if not jobs:
        sys.exit(f"no image with depth in {dataset}/{a.split}")
    object_ids = sorted({o for _, _, _, objs in jobs for o, _ in objs})

    detectors, models = {}, {}
    for obj_id in object_ids:
        path = os.path.join(dataset, "models", f"obj_{obj_id:06d}.ply")
        with open(path, "rb") as f:
            digest = hashlib.sha256(f.read()).hexdigest()
        if digest not in trained:
            t0 = time.perf_counter()
            model = cv2.ppf_match_3d.loadPLYSimple(path, 1)
            detector = cv2.ppf_match_3d.PPF3DDetector(a.rel_sampling_step, a.rel_distance_step, a.num_angles)
            detector.trainModel(model)
            trained[digest] = (model, detector)
            print(f"object {obj_id}: trained on {model.shape[0]} points in {time.perf_counter() - t0:.1f} s",
                  file=sys.stderr)
        models[obj_id], detectors[obj_id] = trained[digest]

    icp = cv2.ppf_match_3d.ICP(a.icp_iterations, a.icp_tolerance, a.icp_rejection_scale, a.icp_levels)
    outputs = {}
    for sd in a.scene_distance:
        if len(a.scene_distance) == 1:
            outputs[sd] = output
        else:
            stem, ext = os.path.splitext(output)
            outputs[sd] = f"{stem}_sd{sd:g}{ext or '.csv'}"
    lines = {sd: ["scene_id,im_id,obj_id,score,R,t,time"] for sd in a.scene_distance}
    for n, (scene_id, im_id, scene_dir, objects) in enumerate(jobs):
        for sd in a.scene_distance:
            t0 = time.perf_counter()
            scene = scene_cloud(scene_dir, im_id, a.pixel_stride, a.normal_neighbors)
            rows = []
            for obj_id, inst_count in objects:
                results = detectors[obj_id].match(scene, a.scene_sample_step, sd)
                best = list(results[: max(a.top_n, inst_count)])
                if not best:
                    continue
                _, best = icp.registerModelToScene(models[obj_id], scene, best)
                best = sorted(best, key=lambda r: r.numVotes, reverse=True)[:inst_count]
                for r in best:
                    pose = np.asarray(r.pose, dtype=np.float64)
                    rows.append((obj_id, float(r.numVotes), pose[:3, :3], pose[:3, 3]))
            elapsed = time.perf_counter() - t0
            for obj_id, score, rot, t in rows:
                lines[sd].append(
                    f"{scene_id},{im_id},{obj_id},{score},"
                    + " ".join(f"{v:.9g}" for v in rot.reshape(-1))
                    + ","
                    + " ".join(f"{v:.6f}" for v in t)
                    + f",{elapsed:.4f}"
                )
            print(f"[{n + 1}/{len(jobs)}] scene {scene_id} image {im_id} scene distance {sd:g}: "
                  f"{len(scene)} points, {len(objects)} objects, {elapsed:.1f} s", file=sys.stderr)
        # Written after every image, so an interrupted run leaves what it did.
        for sd, path in outputs.items():
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            with open(path, "w") as f:
                f.write("\n".join(lines[sd]) + "\n")
    for sd, path in outputs.items():
        print(f"wrote {len(lines[sd]) - 1} estimates to {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
