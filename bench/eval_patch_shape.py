#!/usr/bin/env python3
"""Where a patch's error is: each frame's displacement, or its own shape (scale, rotation).

  bench/eval_patch_shape.py SURVEY_DIR STORE_DIR [PATCH_INDEX] [--every N]

For one patch (its index in store.json, default 0): the frames' 5x5 grids are mapped to the patch
by the sidecar and to the texture by the ground truth, one best-fit homography is fitted for the
patch (as bench/eval_mosaic.py does), and each frame's residual is split into its mean
displacement and the rest, its own shape; an affine map fitted to the rest gives its scale
(1e-3), rotation (mrad) and anisotropy (1e-3), and what no affine map explains (px).
"""
import argparse, json, os, sys
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import eval_mosaic as E  # noqa: E402


def frame_index(source):
    name = os.path.basename(source)
    return int(name.split("#")[1]) if "#" in name else None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("survey")
    ap.add_argument("store")
    ap.add_argument("patch", type=int, nargs="?", default=0)
    ap.add_argument("--every", type=int, default=1, help="print every N-th frame")
    a = ap.parse_args()
    gt = json.load(open(os.path.join(a.survey, "ground_truth.json")))
    w, h = gt["frame_size"]
    by_file = {os.path.basename(f["file"]): f["frame_to_world"] for f in gt["frames"]}
    by_index = {f["index"]: f["frame_to_world"] for f in gt["frames"]}
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 5), np.linspace(0, h - 1, 5))
    grid = np.c_[gx.ravel(), gy.ravel()]
    entry = json.load(open(os.path.join(a.store, "store.json")))["patches"][a.patch]
    side = json.load(open(os.path.join(a.store, entry["sidecar"])))
    rows = []
    for f in side["frames"]:
        i = frame_index(f["source"])
        truth = by_index[i] if i is not None else by_file[os.path.basename(f["source"])]
        rows.append((f.get("index", i), f.get("keyframe", True), E.apply(f["frame_to_patch"], grid), E.apply(truth, grid)))
    if len(rows) < 2:
        sys.exit("the patch holds one frame")
    H = E.fit_homography(np.vstack([r[2] for r in rows]), np.vstack([r[3] for r in rows]))
    print("frame key  dx px  dy px  shape px  scale 1e-3  rot mrad  aniso 1e-3  non-affine px  total px")
    for n, (index, key, mine, truth) in enumerate(rows):
        d = E.apply(H, mine) - truth
        X = np.c_[truth - truth.mean(0), np.ones(len(truth))]
        coef, *_ = np.linalg.lstsq(X, d, rcond=None)
        A = coef[:2].T
        m = d.mean(0)
        shape = np.sqrt(np.mean(np.sum((d - m) ** 2, 1)))
        rest = np.sqrt(np.mean(np.sum((d - X @ coef) ** 2, 1)))
        if n % a.every:
            continue
        print("%5s %3s %+6.2f %+6.2f %9.2f %+11.2f %+9.2f %11.2f %14.2f %9.2f" % (
            index, "K" if key else "", m[0], m[1], shape, 1e3 * (A[0, 0] + A[1, 1]) / 2, 1e3 * (A[1, 0] - A[0, 1]) / 2,
            1e3 * np.hypot((A[0, 0] - A[1, 1]) / 2, (A[0, 1] + A[1, 0]) / 2), rest, np.sqrt(np.mean(np.sum(d ** 2, 1)))))


if __name__ == "__main__":
    main()
