#!/usr/bin/env python3
"""Online engine on synthetic surveys over real seafloor photos (../shared/data/seattle_rov_gopro_large):
accuracy against ground truth (bench/eval_mosaic.py: per-frame RMS after one best-fit homography
per patch), share of frames stitched, frames per second and peak RSS at the paper's 1292 x 964,
with every stage on and with ECC or the Kalman gate switched off.

  bench/run_engine.py [--frames 60] [--runs 3] [--out bench/out/engine]
"""
import argparse, glob, json, os, re, statistics, subprocess, sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import PYTHON  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
DATA = os.path.join(ROOT, "..", "shared", "data", "seattle_rov_gopro_large")


def run(cmd):
    r = subprocess.run(["/usr/bin/time", "-f", "TIME %e %M"] + cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"failed: {' '.join(cmd)}\n{r.stdout}\n{r.stderr}")
    return r


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "engine"))
    a = ap.parse_args()
    photos = sorted(glob.glob(os.path.join(DATA, "*.JPG")))[:2]
    if not photos:
        sys.exit("../shared/data/seattle_rov_gopro_large is absent")
    os.makedirs(a.out, exist_ok=True)
    configs = [("all stages", []), ("no ECC", ["--no-ecc"]), ("no Kalman gate", ["--no-kalman"]),
               ("ORB features", ["--features", "orb"]), ("JPEG patches (not WebP)", ["--compression", "jpeg"]),
               ("WebP patches at effort 4 (libtiff's)", ["--webp-method", "4"])]
    rows = []
    for label, flags in configs:
        acc, fps, rss = [], [], []
        for i, photo in enumerate(photos):
            survey = os.path.join(a.out, f"survey{i}")
            if not os.path.exists(os.path.join(survey, "ground_truth.json")):
                run([CLI, "synth", photo, "-o", survey, "--frames", str(a.frames), "-q", "--seed", str(i + 1)])
            for _ in range(a.runs):
                store = os.path.join(a.out, "store.rolamos")
                subprocess.run(["rm", "-rf", store])
                r = run([CLI, "mosaic", os.path.join(survey, "frames"), "-o", store, "-q"] + flags)
                m = re.search(r"\(([\d.]+) frames/s\)", r.stdout)
                fps.append(float(m.group(1)))
                rss.append(int(re.search(r"TIME [\d.]+ (\d+)", r.stderr).group(1)) / 1024)
            e = json.loads(subprocess.run([PYTHON, os.path.join(ROOT, "bench", "eval_mosaic.py"),
                                           survey, store], capture_output=True, text=True).stdout)
            acc.append(e)
        rows.append((label, statistics.median(x["rms_px"] for x in acc), max(x["p95_px"] for x in acc),
                     min(x["stitched_share"] for x in acc), statistics.median(fps), statistics.median(rss)))
    lines = [f"### Engine on synthetic surveys over real photos ({len(photos)} surveys of {a.frames} frames, "
             f"1292 x 964, median of {a.runs} runs)", "",
             "| configuration | RMS px (median over surveys) | p95 px (worst survey) | frames stitched (worst) | frames/s | peak RSS MB |",
             "|---|---|---|---|---|---|"]
    for label, rms, p95, share, f, m in rows:
        lines.append(f"| {label} | {rms:.2f} | {p95:.2f} | {share*100:.0f} % | {f:.1f} | {m:.0f} |")
    # Peer: cv::Stitcher SCANS on the first 30 and 60 frames of the first survey, beside ours.
    peer = os.path.join(ROOT, "build", "stitcher_peer_bench")
    survey = os.path.join(a.out, "survey0")
    frames = sorted(glob.glob(os.path.join(survey, "frames", "*")))
    lines += ["", "| same frames | tool | frames used | seconds | peak RSS MB | result |", "|---|---|---|---|---|---|"]
    for n in (30, 60):
        if len(frames) < n:
            continue
        listing = os.path.join(a.out, f"frames{n}.txt")
        open(listing, "w").write("\n".join(frames[:n]) + "\n")
        store = os.path.join(a.out, f"peer{n}.rolamos")
        subprocess.run(["rm", "-rf", store])
        r = run([CLI, "mosaic", listing, "-o", store, "-q"])
        t, rss = re.search(r"TIME ([\d.]+) (\d+)", r.stderr).groups()
        stitched = int(re.search(r"(\d+) stitched", r.stdout).group(1))
        patches = int(re.search(r"(\d+) patches", r.stdout).group(1))
        lines.append(f"| {n} | rolamos mosaic | {stitched} | {float(t):.1f} | {int(rss)/1024:.0f} | {patches} patches, full resolution |")
        r = run([peer, os.path.join(survey, "frames"), str(n)])
        j = json.loads(r.stdout)
        t, rss = re.search(r"TIME ([\d.]+) (\d+)", r.stderr).groups()
        lines.append(f"| {n} | cv::Stitcher SCANS | {j['used']} | {float(t):.1f} | {int(rss)/1024:.0f} | "
                     f"{j['status']}, {j['width']} x {j['height']}, drops the frames it cannot link |")
    report = "\n".join(lines)
    print(report)
    open(os.path.join(a.out, "engine.md"), "w").write(report + "\n")


if __name__ == "__main__":
    main()
