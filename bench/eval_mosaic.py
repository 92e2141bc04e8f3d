#!/usr/bin/env python3
"""Accuracy of a mosaic against a synthetic survey's ground truth.

  bench/eval_mosaic.py SURVEY_DIR STORE_DIR [--json]

For every patch: a 5x5 grid of points in each stitched frame is mapped to the patch by the
sidecar's frame_to_patch and to the texture by the ground-truth frame_to_world; one best-fit
homography (patch -> texture, least squares) is fitted per patch, and the residuals of every
frame (its grid's RMS, in texture pixels) are reported: RMS over frames, 95th percentile, max.
Also the share of frames stitched. Texture pixels equal frame pixels at --gsd 1.

A survey made through a distorting lens (`synth --k1`): its ground truth maps the pinhole's
undistorted pixels, the engine's placements map the frames as it took them (the raw pixels, or the
frames it rectified with a calibration file, whose camera matrix the sidecar holds as
`frame_camera_matrix`); each grid point is followed back to the raw pixel and through the true
lens to the pinhole's pixel first.
"""
import glob, json, os, re, sys
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


def distort(n, k1):
    """Normalised pinhole coordinates -> normalised distorted ones (OpenCV's k1 alone)."""
    return n * (1 + k1 * (n ** 2).sum(1, keepdims=True))


def undistort(d, k1):
    n = d.copy()
    for _ in range(50):
        n = d / (1 + k1 * (n ** 2).sum(1, keepdims=True))
    return n


def to_pixels(K, n):
    return n @ K[:2, :2].T + K[:2, 2]


def to_normalised(K, p):
    return (p - K[:2, 2]) @ np.linalg.inv(K[:2, :2]).T


def read_calibration(path):
    """(camera matrix, k1) of an OpenCV YAML calibration file, as the engine wrote or was given."""
    text = open(path).read()
    def numbers(name):
        m = re.search(name + r":.*?data:\s*\[([^\]]*)\]", text, re.S)
        return [float(x) for x in m.group(1).replace("\n", " ").split(",")] if m else None
    K, dist = numbers("camera_matrix"), numbers("distortion_coefficients")
    return np.array(K).reshape(3, 3), (dist[0] if dist else 0.0)


def lens_of(survey_gt, store, manifest):
    """The true lens (K, k1) and the calibration the engine used (K, k1), or None where it took the
    frames as they came."""
    k1 = survey_gt.get("options", {}).get("k1", 0.0)
    if not k1:
        return None
    true = (np.array(survey_gt["camera_matrix"]).reshape(3, 3), k1)
    cal = (manifest.get("camera") or {}).get("calibration_file")
    if cal == "auto":
        cal = os.path.join(store, "calibration.yml")
    used = read_calibration(cal) if cal and os.path.exists(cal) else None
    if used is not None and used[1] == 0:
        used = None  # no distortion found: the frames as they came
    return true, used


def engine_grid_to_pinhole(grid, lens, side):
    """Grid points in the engine's frame coordinates -> the true pinhole's pixels."""
    (K_true, k1_true), used = lens
    raw = grid
    if used is not None:
        if "frame_camera_matrix" not in side:
            return None  # a store of an engine before session 26: its rectified frames are not known
        K_used, k1_used = used
        K_frame = np.array(side["frame_camera_matrix"]).reshape(3, 3)
        raw = to_pixels(K_used, distort(to_normalised(K_frame, grid), k1_used))
    return to_pixels(K_true, undistort(to_normalised(K_true, raw), k1_true))


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
    lens = lens_of(gt, store, manifest)
    for entry in manifest["patches"]:
        side = os.path.join(store, entry["sidecar"])
        s = json.load(open(side))
        truth_grid = grid if lens is None else engine_grid_to_pinhole(grid, lens, s)
        if truth_grid is None:
            print(f"{side}: no frame_camera_matrix (an older engine's store): its frames through a calibration "
                  "cannot be followed back to the lens; the patch is not evaluated", file=sys.stderr)
            stitched += len(s["frames"])
            continue
        src, dst, owners, keys = [], [], [], []
        for i, f in enumerate(s["frames"]):
            name = os.path.basename(f["source"])
            if "#" in name:  # a video's frame: its number is the survey's frame index
                truth = gt_by_index.get(int(name.split("#")[1]))
            else:
                truth = gt_by_file.get(name)
            if truth is None:
                continue
            src.append(apply(f["frame_to_patch"], grid)); dst.append(apply(truth, truth_grid))
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
