#!/usr/bin/env python3
"""Global accuracy of a store against a synthetic survey's ground truth: every stitched frame's
3 x 3 grid placed in the global frame (patch_to_global x frame_to_patch, or the aligned
frame_to_global when `rolamos align` wrote one), compared with its ground-truth place after one
best-fit homography for the whole map. A map that `align` left in parts (the sidecars'
`component`) has no common gauge: each part gets its own best fit, and `components` says how
many there were. Prints JSON: frames, components, RMS and p95 in pixels.

A survey made through a distorting lens (`synth --k1`, mapped with a calibration): each grid point
of the engine's (rectified) frame is followed back to the raw pixel and through the true lens to
the pinhole's pixel the ground truth maps, as bench/eval_mosaic.py does; without it such a survey
measured ~11 px whatever its map (lawn-lens).

  bench/eval_global.py SURVEY_DIR STORE [--online]
"""
import json, os, sys
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from eval_mosaic import engine_grid_to_pinhole, lens_of  # noqa: E402

survey, store = sys.argv[1], sys.argv[2]
online = "--online" in sys.argv
survey_gt = json.load(open(os.path.join(survey, "ground_truth.json")))
truth = survey_gt["frames"]
gt = {os.path.basename(f["file"]): np.array(f["frame_to_world"]).reshape(3, 3) for f in truth}
# A video's frames are named video.mp4#N: N is the survey's frame index.
gt.update({"#" + str(f["index"]): np.array(f["frame_to_world"]).reshape(3, 3) for f in truth})
manifest = json.load(open(os.path.join(store, "store.json")))
lens = lens_of(survey_gt, store, manifest)
ours, theirs, part = [], [], []
w = h = None
for p in manifest["patches"]:
    s = json.load(open(os.path.join(store, p["sidecar"])))
    w, h = s["frame_size"]
    grid = np.array([(x, y) for x in (0, (w - 1) / 2, w - 1) for y in (0, (h - 1) / 2, h - 1)])
    truth_grid = grid if lens is None else engine_grid_to_pinhole(grid, lens, s)
    if truth_grid is None:
        print(f"{p['sidecar']}: no frame_camera_matrix (an older engine's store): its frames through a calibration "
              "cannot be followed back to the lens; the patch is not evaluated", file=sys.stderr)
        continue
    for f in s["frames"]:
        H = np.array(f["frame_to_global"]).reshape(3, 3) if ("frame_to_global" in f and not online) else \
            (np.array(s.get("patch_to_global_online", s["patch_to_global"])).reshape(3, 3) @ np.array(f["frame_to_patch"]).reshape(3, 3))
        name = os.path.basename(f["source"])
        T = gt["#" + name.split("#")[1]] if "#" in name else gt[name]
        for (x, y), (u, v) in zip(grid, truth_grid):
            a, b = H @ [x, y, 1], T @ [u, v, 1]
            ours.append(a[:2] / a[2]); theirs.append(b[:2] / b[2]); part.append(s.get("component", 0))
ours, theirs, part = np.array(ours), np.array(theirs), np.array(part)


# One best-fit homography (DLT, normalised) from our global frame to the world, per part.
def norm(p):
    c = p.mean(0); s = np.sqrt(2) / np.sqrt(((p - c) ** 2).sum(1)).mean()
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])


def residuals(ours, theirs):
    Ta, Tb = norm(ours), norm(theirs)
    A = []
    for (x, y), (u, v) in zip((Ta @ np.c_[ours, np.ones(len(ours))].T).T[:, :2],
                              (Tb @ np.c_[theirs, np.ones(len(theirs))].T).T[:, :2]):
        A.append([-x, -y, -1, 0, 0, 0, u * x, u * y, u]); A.append([0, 0, 0, -x, -y, -1, v * x, v * y, v])
    Hn = np.linalg.svd(np.array(A), full_matrices=False)[2][-1].reshape(3, 3)
    H = np.linalg.inv(Tb) @ Hn @ Ta
    m = (H @ np.c_[ours, np.ones(len(ours))].T).T
    m = m[:, :2] / m[:, 2:]
    return np.sqrt(((m - theirs) ** 2).sum(1))


err = np.concatenate([residuals(ours[part == c], theirs[part == c]) for c in np.unique(part)])
print(json.dumps({"frames": len(ours) // 9, "components": int(len(np.unique(part))), "rms_px": float(np.sqrt((err ** 2).mean())),
                  "p95_px": float(np.percentile(err, 95)), "max_px": float(err.max())}))
