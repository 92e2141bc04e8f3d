#!/usr/bin/env python3
"""Open a rolamos store, read a region at full resolution and an overview of the whole mosaic,
and plot the overview with the patch outlines and the object detections over it (matplotlib).

  PYTHONPATH=build/python /usr/bin/python3 examples/plot_overview.py STORE [-o overview.png]
"""
import argparse
import json
import os

import matplotlib

matplotlib.use("Agg")  # files, no window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import rolamos  # noqa: E402


def patch_outline(store, patch, scale):
    """The patch's corners in overview pixels, through its placement in the mosaic."""
    sidecar = store.sidecar(patch.id)
    H = sidecar.get("patch_to_global")
    if H is None:
        return None
    H = np.array(H, dtype=float).reshape(3, 3)
    corners = np.array([[0, 0, 1], [patch.width, 0, 1], [patch.width, patch.height, 1], [0, patch.height, 1]], float)
    p = corners @ H.T
    return p[:, :2] / p[:, 2:] * scale


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store")
    ap.add_argument("-o", "--output", default="overview.png")
    a = ap.parse_args()
    store = rolamos.Store(a.store)
    mosaic = rolamos.open_image(store, "mosaic", cache_mb=128)
    # A region at full resolution: the centre 512 x 512 pixels.
    w, h = min(512, mosaic.width), min(512, mosaic.height)
    detail = mosaic.read((mosaic.width - w) // 2, (mosaic.height - h) // 2, w, h)
    # The whole mosaic at a scale that fits 1,000 pixels.
    scale = min(1.0, 1000 / max(mosaic.width, mosaic.height))
    overview = mosaic.read(0, 0, mosaic.width, mosaic.height, scale=scale)
    s = overview.shape[1] / mosaic.width * store.global_record.scale  # global pixels -> overview pixels

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 7), gridspec_kw={"width_ratios": [2, 1]})
    left.imshow(overview)
    for patch in store.patches:
        outline = patch_outline(store, patch, s)
        if outline is not None:
            left.add_patch(plt.Polygon(outline, fill=False, edgecolor="#e9b44c", linewidth=1))
            left.text(*outline.mean(axis=0), str(patch.id), color="#e9b44c", fontsize=8, ha="center")
    detections = os.path.join(store.path, "objects", "detections.geojson")
    n = 0
    if os.path.exists(detections):
        with open(detections) as f:
            for feature in json.load(f)["features"]:
                x, y, bw, bh = feature["properties"]["pixel_bbox"]
                left.add_patch(plt.Rectangle((x * scale, y * scale), bw * scale, bh * scale, fill=False,
                                             edgecolor="#9cff57", linewidth=1))
                n += 1
    left.set_title(f"{os.path.basename(store.path)}: {mosaic.width} x {mosaic.height} px, "
                   f"{len(store.patches)} patches, {n} detections")
    right.imshow(detail)
    right.set_title(f"centre at full resolution ({w} x {h} px)")
    for ax in (left, right):
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(a.output, dpi=100)
    print(f"{a.output}: overview {overview.shape[1]} x {overview.shape[0]} px, detail {w} x {h} px")


if __name__ == "__main__":
    main()
