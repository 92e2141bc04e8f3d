#!/usr/bin/env python3
"""Per-frame navigation for a synthetic survey, as a vehicle would log it: each frame's
pixel -> map affine (the ground truth linearised at the frame's centre), its centre moved by
Gaussian noise of SIGMA metres (USBL-like), written as the per-frame georeference CSV that
`rolamos align --navigation` and `compose --navigation` read (frame, epsg, gt0..gt5).
World pixels are taken as METRES_PER_PX metres (default 1 cm).

  bench/nav_from_truth.py SURVEY_DIR OUT.csv [--sigma 0.5] [--metres-per-px 0.01] [--seed 1]
"""
import argparse, json, os
import numpy as np

ap = argparse.ArgumentParser()
ap.add_argument("survey")
ap.add_argument("out")
ap.add_argument("--sigma", type=float, default=0.5)
ap.add_argument("--metres-per-px", type=float, default=0.01)
ap.add_argument("--seed", type=int, default=1)
a = ap.parse_args()
gt = json.load(open(os.path.join(a.survey, "ground_truth.json")))
w, h = gt["frame_size"]
rng = np.random.default_rng(a.seed)
m = a.metres_per_px
with open(a.out, "w") as f:
    f.write("frame,epsg,gt0,gt1,gt2,gt3,gt4,gt5\n")
    for fr in gt["frames"]:
        W = np.array(fr["frame_to_world"]).reshape(3, 3)
        def at(x, y):
            q = W @ [x, y, 1.0]
            return q[:2] / q[2]
        cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        c = at(cx, cy)
        dx, dy = at(cx + 1, cy) - c, at(cx, cy + 1) - c
        noise = rng.normal(0, a.sigma, 2)
        # Map x = easting (metres), map y = northing = -world y.
        e0 = 500000 + m * (c[0] - dx[0] * cx - dy[0] * cy) + noise[0]
        n0 = 5200000 - m * (c[1] - dx[1] * cx - dy[1] * cy) + noise[1]
        f.write(f"{os.path.basename(fr['file'])},32755,{e0:.4f},{m * dx[0]:.8f},{m * dy[0]:.8f},"
                f"{n0:.4f},{-m * dx[1]:.8f},{-m * dy[1]:.8f}\n")
