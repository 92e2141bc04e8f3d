#!/usr/bin/env python3
"""COLMAP's reconstruction of a synthetic survey against its ground truth, measured as rolamos's
global map is (bench/eval_global.py): a plane is fitted to COLMAP's 3-D points (the seafloor),
each registered camera's pose gives its frame -> plane homography, and every frame's 3 x 3 grid
on that plane is compared with its ground-truth place after one best-fit homography.

  bench/eval_colmap.py SURVEY_DIR COLMAP_TXT_MODEL_DIR
"""
import json, os, sys
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from eval_mosaic import apply, fit_homography  # noqa: E402


def quat_to_R(qw, qx, qy, qz):
    return np.array([[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                     [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                     [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])


def main():
    survey, model = sys.argv[1], sys.argv[2]
    gt = json.load(open(os.path.join(survey, "ground_truth.json")))
    w, h = gt["frame_size"]
    truth = {os.path.basename(f["file"]): np.array(f["frame_to_world"]).reshape(3, 3) for f in gt["frames"]}
    cams = {}
    for line in open(os.path.join(model, "cameras.txt")):
        if line.startswith("#") or not line.strip():
            continue
        p = line.split()
        fx, fy, cx, cy = map(float, p[4:8])
        cams[p[0]] = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    images, lines = [], [l for l in open(os.path.join(model, "images.txt")) if not l.startswith("#")]
    for i in range(0, len(lines) - 1, 2):
        p = lines[i].split()
        if len(p) < 10:
            continue
        images.append((p[9], quat_to_R(*map(float, p[1:5])), np.array(list(map(float, p[5:8]))), cams[p[8]]))
    pts = np.array([list(map(float, l.split()[1:4])) for l in open(os.path.join(model, "points3D.txt"))
                    if not l.startswith("#") and l.strip()])
    if len(images) < 2 or len(pts) < 3:
        print(json.dumps({"registered": len(images)}))
        return
    p0 = np.median(pts, axis=0)
    _, _, vt = np.linalg.svd(pts - p0)
    u, v = vt[0], vt[1]
    grid = np.array([[x * (w - 1) / 2, y * (h - 1) / 2] for x in range(3) for y in range(3)])
    ours, theirs = [], []
    for name, R, t, K in images:
        if name not in truth:
            continue
        H = K @ np.c_[R @ u, R @ v, R @ p0 + t]  # plane (a, b) -> frame
        ours.append(apply(np.linalg.inv(H), grid))
        theirs.append(apply(truth[name], grid))
    ours, theirs = np.vstack(ours), np.vstack(theirs)
    F = fit_homography(ours, theirs)
    err = np.linalg.norm(apply(F, ours) - theirs, axis=1)
    print(json.dumps({"registered": len(images), "rms_px": float(np.sqrt(np.mean(err ** 2))),
                      "p95_px": float(np.percentile(err, 95)), "max_px": float(err.max())}))


if __name__ == "__main__":
    main()
