#!/usr/bin/env python3
"""Accuracy of a mosaic against a synthetic survey's ground truth.

  bench/eval_mosaic.py SURVEY_DIR STORE_DIR [--json]

For every patch: a 5x5 grid of points in each stitched frame is mapped to the patch by the
sidecar's frame_to_patch and to the texture by the ground-truth frame_to_world; one best-fit
homography (patch -> texture, least squares) is fitted per patch, and the residuals of every
frame (its grid's RMS, in texture pixels) are reported: RMS over frames, 95th percentile, max.
Also the share of frames stitched. Texture pixels equal frame pixels at --gsd 1.
"""
import glob, json, os, sys
import numpy as np


def apply(H, pts):
    p = np.c_[pts, np.ones(len(pts))] @ np.asarray(H).reshape(3, 3).T
    return p[:, :2] / p[:, 2:3]


def fit_homography(src, dst):
    # Normalised DLT, then a few Gauss-Newton steps on the reprojection error.
    def norm(p):
        c = p.mean(0); s = np.sqrt(2) / np.mean(np.linalg.norm(p - c, axis=1))
        return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])
    Ts, Td = norm(src), norm(dst)
    a, b = apply(Ts, src), apply(Td, dst)
    rows = []
    for (x, y), (u, v) in zip(a, b):
        rows.append([-x, -y, -1, 0, 0, 0, u * x, u * y, u])
        rows.append([0, 0, 0, -x, -y, -1, v * x, v * y, v])
    _, _, vt = np.linalg.svd(np.array(rows), full_matrices=False)  # U of a large survey would not fit
    H = np.linalg.inv(Td) @ vt[-1].reshape(3, 3) @ Ts
    h = (H / H[2, 2]).ravel()[:8]
    for _ in range(10):
        Hm = np.append(h, 1).reshape(3, 3)
        r = (apply(Hm, src) - dst).ravel()
        J = np.zeros((len(r), 8)); eps = 1e-6
        for k in range(8):
            hk = h.copy(); hk[k] += eps * max(1, abs(h[k]))
            J[:, k] = ((apply(np.append(hk, 1).reshape(3, 3), src) - dst).ravel() - r) / (eps * max(1, abs(h[k])))
        h = h - np.linalg.lstsq(J, r, rcond=None)[0]
    return np.append(h, 1).reshape(3, 3)


def main():
    survey, store = sys.argv[1], sys.argv[2]
    gt = json.load(open(os.path.join(survey, "ground_truth.json")))
    w, h = gt["frame_size"]
    gt_by_file = {os.path.basename(f["file"]): f["frame_to_world"] for f in gt["frames"]}
    gt_by_index = {f["index"]: f["frame_to_world"] for f in gt["frames"]}
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 5), np.linspace(0, h - 1, 5))
    grid = np.c_[gx.ravel(), gy.ravel()]
    frame_rms, stitched, is_key = [], 0, []
    manifest = json.load(open(os.path.join(store, "store.json")))
    for entry in manifest["patches"]:
        side = os.path.join(store, entry["sidecar"])
        s = json.load(open(side))
        src, dst, owners, keys = [], [], [], []
        for i, f in enumerate(s["frames"]):
            name = os.path.basename(f["source"])
            if "#" in name:  # a video's frame: its number is the survey's frame index
                truth = gt_by_index.get(int(name.split("#")[1]))
            else:
                truth = gt_by_file.get(name)
            if truth is None:
                continue
            src.append(apply(f["frame_to_patch"], grid)); dst.append(apply(truth, grid))
            keys.append(f.get("keyframe", True))
            owners += [i] * len(grid)
        stitched += len(s["frames"])
        if len(src) < 2:
            continue
        src, dst = np.vstack(src), np.vstack(dst)
        H = fit_homography(src, dst)
        err = np.linalg.norm(apply(H, src) - dst, axis=1)
        owners = np.array(owners)
        for k, i in enumerate(np.unique(owners)):
            frame_rms.append(np.sqrt(np.mean(err[owners == i] ** 2)))
            is_key.append(keys[k])
    fr = np.array(frame_rms)
    kf = np.array(is_key, dtype=bool)
    out = {"frames": len(gt["frames"]), "stitched": stitched,
           "stitched_share": stitched / len(gt["frames"]),
           "rms_px": float(np.sqrt(np.mean(fr ** 2))) if len(fr) else None,
           "p95_px": float(np.percentile(fr, 95)) if len(fr) else None,
           "max_px": float(fr.max()) if len(fr) else None,
           "keyframes": int(kf.sum()),
           "keyframe_rms_px": float(np.sqrt(np.mean(fr[kf] ** 2))) if kf.any() else None,
           "followed_rms_px": float(np.sqrt(np.mean(fr[~kf] ** 2))) if (~kf).any() else None}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
