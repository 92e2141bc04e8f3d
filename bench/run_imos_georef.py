#!/usr/bin/env python3
"""Georeferencing the eight IMOS AUV sequences (issue 4): each is mosaicked (radial distortion
estimated, one patch where possible), composed and georeferenced from the per-frame navigation
georeference shipped with the frames; then aligned with the navigation as a constraint
(`align --navigation`) and georeferenced again. Residual: distance between each frame centre's
position on the georeferenced mosaic and its navigation position, in metres.

  bench/run_imos_georef.py [--weight W]
"""
from bench_common import write_report
import argparse, csv, glob, json, os, re, subprocess
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
DATA = os.path.join(ROOT, "..", "shared", "data", "imos_auv_seabed")
OUT = os.path.join(ROOT, "bench", "out", "imos_georef")



def sidecars(store):
    """The patches' sidecars, as the manifest names them (align versions their file names)."""
    m = json.load(open(os.path.join(store, "store.json")))
    return [os.path.join(store, p["sidecar"]) for p in m["patches"]]

def run(cmd):
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}:\n{r.stdout}{r.stderr}")
    return r.stdout


def navigation_scatter(store, seq, nav):
    """The navigation's own disagreement with vision: for consecutive frames of a patch, where the
    online homography and the navigation put frame i's centre in frame j (as bench/eval_imos.py),
    in metres at the navigation's pixel size; the median over pairs."""
    d = []
    for side in sidecars(store):
        fr = json.load(open(side))["frames"]
        for a, b in zip(fr, fr[1:]):
            Ma, Mb = nav[(seq, os.path.basename(a["source"]))], nav[(seq, os.path.basename(b["source"]))]
            Fi, Fj = np.array(a["frame_to_patch"]).reshape(3, 3), np.array(b["frame_to_patch"]).reshape(3, 3)
            c = np.array([679.5, 511.5, 1.0])
            p, q = np.linalg.inv(Fj) @ Fi @ c, np.linalg.inv(Mb) @ Ma @ c
            d.append(float(np.hypot(*(p[:2] / p[2] - q[:2] / q[2]))) * float(np.hypot(Mb[0, 0], Mb[1, 0])))
    return float(np.median(d)) if d else float("nan")


def georeference(store, nav):
    out = run([CLI, "compose", store, "-q", "--no-link", "--compression", "jpeg", "--navigation", nav])
    m = re.search(r"\((EPSG:\d+|[^)]*)\): pixel ([\d.e-]+) m, residual median ([\d.]+) m, max ([\d.]+) m", out)
    return m.group(1), float(m.group(2)), float(m.group(3)), float(m.group(4))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sigma", type=float, default=None, help="align --navigation-sigma (m)")
    a = ap.parse_args()
    nav = os.path.join(DATA, "georef_frames.csv")
    os.makedirs(OUT, exist_ok=True)
    affines = {}
    for r in csv.DictReader(open(nav)):
        g = [float(r[k]) for k in ("gt0_E0", "gt1_dE_dcol", "gt2_dE_drow", "gt3_N0", "gt4_dN_dcol", "gt5_dN_drow")]
        affines[(r["sequence"], r["frame"])] = np.array([[g[1], g[2], g[0]], [g[4], g[5], g[3]], [0, 0, 1]])
    lines = ["| sequence | CRS | pixel size (m) | residual median / max (m), vision only | after `align --navigation` | "
             "navigation's own scatter (m) |", "|---|---|---|---|---|---|"]
    before_all, after_all, within = [], [], 0
    for seq in sorted(d for d in os.listdir(DATA) if d.startswith("test")):
        store = os.path.join(OUT, f"{seq}.rolamos")
        subprocess.run(["rm", "-rf", store])
        run([CLI, "mosaic", "-q", os.path.join(DATA, seq), "-o", store, "--calibration", "auto", "--patch-megapixels", "20"])
        run([CLI, "compose", store, "-q", "--compression", "jpeg"])
        scatter = navigation_scatter(store, seq, affines)
        crs, px, med0, max0 = georeference(store, nav)
        align = [CLI, "align", store, "-q", "--navigation", nav]
        if a.sigma is not None:
            align += ["--navigation-sigma", str(a.sigma)]
        out = run(align)
        crs, px1, med1, max1 = georeference(store, nav)
        before_all.append(med0)
        after_all.append(med1)
        lines.append(f"| {seq} | {crs} | {px1:.5f} | {med0:.3f} / {max0:.3f} | {med1:.3f} / {max1:.3f} | {scatter:.3f} |")
        within += med1 <= scatter
    lines.append(f"\nmedian of the sequences' medians: {sorted(before_all)[4]:.3f} m vision only, "
                 f"{sorted(after_all)[4]:.3f} m after alignment with the navigation; {within} of 8 sequences within "
                 f"the navigation's own scatter")
    write_report(lines, os.path.join(OUT, "imos_georef.md"))


if __name__ == "__main__":
    main()
