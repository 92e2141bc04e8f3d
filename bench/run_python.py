#!/usr/bin/env python3
"""The Python module's figures (issue 23), each beside its peer in the same run:

1. Random 512 x 512 window reads per second from Python: rolamos.open_image(...).read against
   rasterio (GDAL) on the same pyramidal tiled BigTIFF (a `rolamos demo` store's patch, JPEG
   tiles, and the same pixels converted to WebP and zstd tiles), cold (a fresh reader per run, windows anywhere) and warm (the same windows again).
2. Mosaicker.push overhead: the same frames mapped by pushing NumPy arrays from Python against
   `rolamos mosaic` on the folder (the C++ engine alone), frames/s.

  PYTHONPATH=build/python /usr/bin/python3 bench/run_python.py [--runs 3] [--size 16384] [--windows 500]
      [--compressions jpeg,webp,zstd] [--no-engine]
"""
import argparse
import os
import statistics
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "build", "python"))
import rasterio  # noqa: E402
from rasterio.windows import Window  # noqa: E402

import rolamos  # noqa: E402

CLI = os.path.join(ROOT, "build", "rolamos")


def windows(w, h, n, seed):
    rng = np.random.default_rng(seed)
    return [(int(rng.integers(0, w - 512)), int(rng.integers(0, h - 512))) for _ in range(n)]


def reads_rolamos(path, spots):
    image = rolamos.open_image(path, cache_mb=256)
    t = time.perf_counter()
    for x, y in spots:
        image.read(x, y, 512, 512)
    cold = len(spots) / (time.perf_counter() - t)
    t = time.perf_counter()
    for x, y in spots:
        image.read(x, y, 512, 512)
    return cold, len(spots) / (time.perf_counter() - t)


def reads_rasterio(path, spots):
    # GDAL's block cache at the same 256 MB.
    with rasterio.Env(GDAL_CACHEMAX=256):
        with rasterio.open(path) as src:
            t = time.perf_counter()
            for x, y in spots:
                np.moveaxis(src.read(window=Window(x, y, 512, 512)), 0, -1)
            cold = len(spots) / (time.perf_counter() - t)
            t = time.perf_counter()
            for x, y in spots:
                np.moveaxis(src.read(window=Window(x, y, 512, 512)), 0, -1)
            return cold, len(spots) / (time.perf_counter() - t)


def push_rate(frames, store):
    subprocess.run(["rm", "-rf", store])
    m = rolamos.Mosaicker(store, mask="none")
    images = [rolamos.open_image(f) for f in frames]
    arrays = [i.read(0, 0, i.width, i.height) for i in images]  # decoded beforehand: the engine's part only
    t = time.perf_counter()
    for a, f in zip(arrays, frames):
        m.push(a, name=os.path.basename(f))
    m.close()
    return len(frames) / (time.perf_counter() - t)


def cli_rate(folder, store):
    subprocess.run(["rm", "-rf", store])
    r = subprocess.run([CLI, "mosaic", folder, "-o", store, "-q", "--mask", "none"], capture_output=True, text=True,
                       check=True)
    import re
    return float(re.search(r"\(([\d.]+) frames/s\)", r.stdout).group(1))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--size", type=int, default=16384)
    ap.add_argument("--windows", type=int, default=500)
    ap.add_argument("--compressions", default="jpeg,webp,zstd", help="tile codecs the reads are measured on")
    ap.add_argument("--no-engine", action="store_true", help="the reads only")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "python"))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    demo = os.path.join(a.out, f"demo{a.size}.rolamos")
    if not os.path.exists(demo):
        subprocess.run([CLI, "demo", "-o", demo, "--size", str(a.size)], check=True, capture_output=True)
    jpeg = rolamos.Store(demo).patches[0].image
    print(f"| tiles | reader | cold 512x512 windows/s | warm windows/s |  ({a.windows} random windows of a "
          f"{a.size}^2 BigTIFF, median of {a.runs}, 256 MB caches)")
    print("|---|---|---|---|")
    for compression in a.compressions.split(","):
        path = jpeg
        if compression != "jpeg":  # the same pixels in the store's other tile codecs
            path = os.path.join(a.out, f"demo{a.size}-{compression}.tif")
            if not os.path.exists(path):
                subprocess.run([CLI, "convert", jpeg, "-o", path, "--compression", compression, "-q"], check=True)
        rows = {"rolamos": [], "rasterio": []}
        for run in range(a.runs):
            spots = windows(a.size, a.size, a.windows, seed=run)
            subprocess.run(["sync"])
            rows["rasterio"].append(reads_rasterio(path, spots))
            rows["rolamos"].append(reads_rolamos(path, spots))
        for name, r in rows.items():
            print(f"| {compression} | {name} | {statistics.median(c for c, _ in r):.0f} | "
                  f"{statistics.median(w for _, w in r):.0f} |", flush=True)

    if a.no_engine:
        return
    survey = os.path.join(a.out, "survey")
    if not os.path.exists(os.path.join(survey, "ground_truth.json")):
        rolamos.synth(survey, frames=120, width=800, height=600, fov=60, lanes=4, overlap=0.7, seed=2)
    folder = os.path.join(survey, "frames")
    frames = sorted(os.path.join(folder, f) for f in os.listdir(folder))
    py, cli = [], []
    for run in range(a.runs):
        cli.append(cli_rate(folder, os.path.join(a.out, "cli.rolamos")))
        py.append(push_rate(frames, os.path.join(a.out, "push.rolamos")))
    print()
    print("| engine | frames/s (120 frames of 800 x 600, median of %d) |" % a.runs)
    print("|---|---|")
    print(f"| rolamos mosaic FOLDER (C++, decodes on every core) | {statistics.median(cli):.1f} |")
    print(f"| rolamos.Mosaicker.push from Python (arrays decoded beforehand, one frame at a time) | "
          f"{statistics.median(py):.1f} |")


if __name__ == "__main__":
    main()
