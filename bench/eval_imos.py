#!/usr/bin/env python3
"""Real AUV frames (../shared/data/imos_auv_seabed): mosaic each of the eight sequences and compare
every consecutive pair of stitched frames with the navigation georeference shipped with the data.

For frames i -> j in one patch, ours is inv(F_j) F_i (F = sidecar frame_to_patch); navigation's is
inv(M_j) M_i (M = each frame's pixel -> UTM affine, georef_frames.csv). The figure is the distance
between where the two put frame i's centre in frame j, in pixels (SOURCE.txt: the navigation itself
disagrees with vision by a median 17-48 px there). Also: frames stitched / rejected with reasons.

  bench/eval_imos.py [--out bench/out/imos] [-- extra rolamos mosaic options]
"""
import csv, glob, json, os, subprocess, sys
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data", "imos_auv_seabed")



def sidecars(store):
    """The patches' sidecars, as the manifest names them (align versions their file names)."""
    m = json.load(open(os.path.join(store, "store.json")))
    return [os.path.join(store, p["sidecar"]) for p in m["patches"]]

def main():
    extra = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    out = os.path.join(ROOT, "bench", "out", "imos")
    os.makedirs(out, exist_ok=True)
    nav = {}
    for r in csv.DictReader(open(os.path.join(DATA, "georef_frames.csv"))):
        g = [float(r[k]) for k in ("gt0_E0", "gt1_dE_dcol", "gt2_dE_drow", "gt3_N0", "gt4_dN_dcol", "gt5_dN_drow")]
        nav[(r["sequence"], r["frame"])] = np.array([[g[1], g[2], g[0]], [g[4], g[5], g[3]], [0, 0, 1]])
    print("| sequence | frames | stitched | rejected (reasons) | patches | pairs | centre vs navigation: median px | max px |")
    print("|---|---|---|---|---|---|---|---|")
    for seq in sorted(os.listdir(DATA)):
        frames_dir = os.path.join(DATA, seq)
        if not os.path.isdir(frames_dir):
            continue
        store = os.path.join(out, seq + ".rolamos")
        subprocess.run(["rm", "-rf", store])
        r = subprocess.run([os.path.join(ROOT, "build", "rolamos"), "mosaic", frames_dir, "-o", store, "-q"] + extra,
                           capture_output=True, text=True)
        if r.returncode != 0:
            print(f"| {seq} | failed: {r.stderr.strip()[:80]} |")
            continue
        n = len(glob.glob(os.path.join(frames_dir, "*.tif")))
        stitched, rejected, errors, patches = 0, [], [], 0
        for side in sidecars(store):
            s = json.load(open(side))
            patches += 1
            stitched += len(s["frames"])
            rejected += [x["reason"] for x in s["rejected"]]
            fr = s["frames"]
            for a, b in zip(fr, fr[1:]):
                fa, fb = os.path.basename(a["source"]), os.path.basename(b["source"])
                Fi, Fj = np.array(a["frame_to_patch"]).reshape(3, 3), np.array(b["frame_to_patch"]).reshape(3, 3)
                ours = np.linalg.inv(Fj) @ Fi
                theirs = np.linalg.inv(nav[(seq, fb)]) @ nav[(seq, fa)]
                c = np.array([679.5, 511.5, 1.0])
                p, q = ours @ c, theirs @ c
                errors.append(float(np.hypot(*(p[:2] / p[2] - q[:2] / q[2]))))
        reasons = ", ".join(sorted(set(rejected))) if rejected else "-"
        med = f"{np.median(errors):.0f}" if errors else "-"
        mx = f"{max(errors):.0f}" if errors else "-"
        print(f"| {seq} | {n} | {stitched} | {len(rejected)} ({reasons}) | {patches} | {len(errors)} | {med} | {mx} |")


if __name__ == "__main__":
    main()
