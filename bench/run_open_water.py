#!/usr/bin/env python3
"""A dive's open water around its survey: how many water frames the engine places.

An ROV descends through open water lit by its own lights, maps the seafloor, and ascends. The water
is uniform with marine snow: specks the lights catch. Two kinds of snow:
- `still`: specks drawn anew for every frame (stills far apart in time): nothing links two frames;
- `drift`: the same specks in every frame, drifting with the water at a speed that falls with
  their distance (1 to 3 units), as frames of a video see them: neighbouring frames link, but by
  no single plane.
Every water frame should be rejected (the map holds only seafloor) and every seafloor frame placed.
The seafloor is `rolamos synth`'s (800 x 600, 60 degrees across, 40 frames).

  bench/run_open_water.py [--cli build/rolamos] [--out bench/out/open_water] [--water 40] [--specks 300]

Prints a table: per kind of snow, the water frames placed, the seafloor frames placed, the patches
holding water, and the engine's frames/s. Session 52: `still` 0 of 80 water frames placed, `drift`
all 80 (two patches of water: the descent's and the ascent's), the seafloor all placed in both.
"""
import argparse, json, os, re, subprocess, sys

import numpy as np
from PIL import Image, ImageDraw

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import timed, write_report  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
W, H = 800, 600
WATER = (30, 90, 70)  # RGB of the lit water


def water_frames(folder, prefix, count, specks, drift, seed):
    """`count` frames of open water in `folder`, named PREFIX_NNN.jpg; -> their names."""
    rng = np.random.default_rng(seed)
    pos = np.c_[rng.uniform(-100, W + 100, specks), rng.uniform(-100, H + 100, specks)]
    depth, radius = rng.uniform(1, 3, specks), rng.integers(1, 4, specks)
    grey = rng.integers(150, 255, specks)
    velocity = np.array([3.0, 1.5])  # pixels a frame at distance 1
    names = []
    for k in range(count):
        img = np.zeros((H, W, 3), np.float32) + np.array(WATER, np.float32)
        img += rng.normal(0, 3, img.shape)
        im = Image.fromarray(np.clip(img, 0, 255).astype(np.uint8))
        draw = ImageDraw.Draw(im)
        if drift:
            at = pos + np.outer(np.full(specks, k), velocity) / depth[:, None]
        else:
            at = np.c_[rng.uniform(0, W, specks), rng.uniform(0, H, specks)]
        for (x, y), r, v in zip(at, radius, grey):
            draw.ellipse([x - r, y - r, x + r, y + r], fill=(int(v),) * 3)
        name = f"{prefix}_{k:03d}.jpg"
        im.save(os.path.join(folder, name), quality=90)
        names.append(name)
    return names


def placed_in(store):
    """-> [(patch id, frame source)] of every frame the store's patches hold."""
    manifest = json.load(open(os.path.join(store, "store.json")))
    out = []
    for p in manifest["patches"]:
        side = json.load(open(os.path.join(store, p["sidecar"])))
        out += [(side["id"], os.path.basename(f["source"])) for f in side["frames"]]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cli", default=os.path.join(HERE, "..", "build", "rolamos"))
    ap.add_argument("--out", default=os.path.join(HERE, "out", "open_water"))
    ap.add_argument("--water", type=int, default=40, help="water frames before the seafloor and after it")
    ap.add_argument("--specks", type=int, default=300)
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    floor = os.path.join(a.out, "floor")
    if not os.path.exists(os.path.join(floor, "ground_truth.json")):
        timed([a.cli, "synth", "--width", str(W), "--height", str(H), "--fov", "60", "--frames", "40",
               "-o", floor, "-q"], check=True)
    floor_frames = sorted(f for f in os.listdir(os.path.join(floor, "frames")))
    rows = ["| snow | water frames placed | seafloor frames placed | patches holding water | frames/s |",
            "|---|---|---|---|---|"]
    for kind in ("still", "drift"):
        folder = os.path.join(a.out, kind)
        os.makedirs(folder, exist_ok=True)
        down = water_frames(folder, "down", a.water, a.specks, kind == "drift", 1)
        up = water_frames(folder, "up", a.water, a.specks, kind == "drift", 2)
        names = down + [os.path.join(floor, "frames", f) for f in floor_frames] + up
        listing = os.path.join(folder, "frames.txt")
        open(listing, "w").write("\n".join(names) + "\n")
        store = os.path.join(a.out, kind + ".rolamos")
        subprocess.run(["rm", "-rf", store])
        r, _, _ = timed([a.cli, "mosaic", listing, "-o", store, "-q", "--mask", "none"], check=True)
        m = re.search(r"\(([\d.]+) frames/s\)", r.stdout)
        fps = m.group(1) if m else "?"
        frames = placed_in(store)
        water = [f for f in frames if f[1].startswith(("down_", "up_"))]
        ground = [f for f in frames if f[1] in floor_frames]
        rows.append(f"| {kind} | {len(water)} / {2 * a.water} | {len(ground)} / {len(floor_frames)} | "
                    f"{len(set(p for p, _ in water))} | {fps} |")
    write_report(rows, os.path.join(a.out, "open_water.md"))


if __name__ == "__main__":
    main()
