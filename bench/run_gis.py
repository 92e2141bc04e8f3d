#!/usr/bin/env python3
"""What GIS clients get from `rolamos serve` (issue 24), timed: a georeferenced survey (synth,
navigation from its ground truth, mosaic, compose --navigation), then

- every Web Mercator tile of the map's two finest zooms fetched twice (cold: warped by GDAL on
  demand; warm: the encoded tiles kept), against the pixel XYZ tiles of its two finest zooms;
- `gdal_translate` of the GDAL WMS description (Web Mercator, full zoom) against `gdalwarp` of
  mosaic.tif to the same grid (GDAL's own answer, locally);
- `gdalinfo -checksum` through /vsicurl/ (range requests) against the local file.

  bench/run_gis.py [--frames 120] [--runs 3]
"""
import argparse
import json
import math
import os
import re
import statistics
import subprocess
import sys
import time
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")


def run(*args, cwd):
    subprocess.run(list(args), cwd=cwd, check=True, capture_output=True)


def survey(out, frames):
    if os.path.exists(os.path.join(out, "s.rolamos", "mosaic.tif")):
        return
    os.makedirs(out, exist_ok=True)
    run(CLI, "synth", "-q", "-o", "survey", "--frames", str(frames), "--width", "800", "--height", "600", "--fov", "60",
        "--lanes", "4", cwd=out)
    truth = json.load(open(os.path.join(out, "survey", "ground_truth.json")))
    fw, fh = truth["frame_size"]
    focal = 0.5 * fw / math.tan(math.radians(30))
    with open(os.path.join(out, "nav.csv"), "w") as f:
        f.write("frame,easting,northing,epsg,altitude,heading\n")
        for fr in truth["frames"]:
            H = fr["frame_to_world"]

            def world(x, y):
                z = H[6] * x + H[7] * y + H[8]
                return 500000 + 0.01 * (H[0] * x + H[1] * y + H[2]) / z, 5200000 - 0.01 * (H[3] * x + H[4] * y + H[5]) / z

            c, up, right = world((fw - 1) / 2, (fh - 1) / 2), world((fw - 1) / 2, (fh - 1) / 2 - 1), world((fw + 1) / 2, (fh - 1) / 2)
            f.write(f"{os.path.basename(fr['file'])},{c[0]},{c[1]},32755,{math.hypot(right[0] - c[0], right[1] - c[1]) * focal},"
                    f"{math.degrees(math.atan2(up[0] - c[0], up[1] - c[1]))}\n")
    run(CLI, "mosaic", "-q", "survey/frames", "-o", "s.rolamos", cwd=out)
    run(CLI, "compose", "-q", "s.rolamos", "--navigation", "nav.csv", "--focal", str(focal), cwd=out)


def fetch_all(urls):
    t = time.perf_counter()
    n = 0
    for u in urls:
        with urllib.request.urlopen(u) as r:
            n += len(r.read())
    return len(urls) / (time.perf_counter() - t), n


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "gis"))
    a = ap.parse_args()
    survey(a.out, a.frames)
    mosaic = os.path.join(a.out, "s.rolamos", "mosaic.tif")
    size = subprocess.run(["gdalinfo", mosaic], capture_output=True, text=True).stdout
    print("mosaic:", re.search(r"Size is (\d+, \d+)", size).group(1), "pixels")
    rows = {k: [] for k in ("merc_cold", "merc_warm", "xyz_cold", "xyz_warm", "wms", "warp", "vsicurl", "local")}
    for _ in range(a.runs):
        server = subprocess.Popen([CLI, "serve", "s.rolamos", "--port", "0"], cwd=a.out, stdout=subprocess.PIPE, text=True)
        base = re.search(r"on (http://[^\s]+)", server.stdout.readline()).group(1).rstrip("/")
        try:
            images = json.load(urllib.request.urlopen(base + "/api/images"))
            m = next(i for i in images if i["name"] == "mosaic")
            wm = m["webmercator"]
            w, s, e, n = wm["bounds"]
            merc = []
            for z in (wm["max_zoom"] - 1, wm["max_zoom"]):
                k = 2 ** z
                x0, x1 = int((w + 180) / 360 * k), int((e + 180) / 360 * k)
                ty = lambda lat: int((1 - math.log(math.tan(math.radians(lat)) + 1 / math.cos(math.radians(lat))) / math.pi) / 2 * k)
                merc += [f"{base}/tiles/mosaic/webmercator/{z}/{x}/{y}.png" for x in range(x0, x1 + 1) for y in range(ty(n), ty(s) + 1)]
            xyz = []
            zmax = m["xyz_max_zoom"]
            for z in (zmax - 1, zmax):
                scale = 2.0 ** (z - zmax)
                xyz += [f"{base}/tiles/mosaic/{z}/{x}/{y}.png" for x in range(math.ceil(m["width"] * scale / 256))
                        for y in range(math.ceil(m["height"] * scale / 256))]
            rows["merc_cold"].append(fetch_all(merc)[0])
            rows["merc_warm"].append(fetch_all(merc)[0])
            rows["xyz_cold"].append(fetch_all(xyz)[0])
            rows["xyz_warm"].append(fetch_all(xyz)[0])
            t = time.perf_counter()
            subprocess.run(["gdal_translate", "-q", f"/vsicurl/{base}/gdal/mosaic.webmercator.xml", os.path.join(a.out, "wms.tif")],
                           check=True)
            rows["wms"].append(time.perf_counter() - t)
            info = json.loads(subprocess.run(["gdalinfo", "-json", os.path.join(a.out, "wms.tif")], capture_output=True, text=True).stdout)
            g, (sx, sy) = info["geoTransform"], info["size"]
            t = time.perf_counter()
            subprocess.run(["gdalwarp", "-q", "-overwrite", "-t_srs", "EPSG:3857", "-r", "bilinear", "-te", str(g[0]),
                            str(g[3] + sy * g[5]), str(g[0] + sx * g[1]), str(g[3]), "-ts", str(sx), str(sy), mosaic,
                            os.path.join(a.out, "warp.tif")], check=True)
            rows["warp"].append(time.perf_counter() - t)
            t = time.perf_counter()
            remote = subprocess.run(["gdalinfo", "-checksum", f"/vsicurl/{base}/files/mosaic.tif"], capture_output=True, text=True).stdout
            rows["vsicurl"].append(time.perf_counter() - t)
            t = time.perf_counter()
            local = subprocess.run(["gdalinfo", "-checksum", mosaic], capture_output=True, text=True).stdout
            rows["local"].append(time.perf_counter() - t)
            same = re.findall(r"Checksum=\d+", remote) == re.findall(r"Checksum=\d+", local)
        finally:
            server.terminate()
    med = {k: statistics.median(v) for k, v in rows.items()}
    print(f"| what | figure (median of {a.runs}) |")
    print("|---|---|")
    print(f"| Web Mercator tiles, two finest zooms ({len(merc)} tiles), cold: warped by GDAL | {med['merc_cold']:.0f} tiles/s |")
    print(f"| the same again (kept encoded) | {med['merc_warm']:.0f} tiles/s |")
    print(f"| pixel XYZ tiles, two finest zooms ({len(xyz)} tiles), cold | {med['xyz_cold']:.0f} tiles/s |")
    print(f"| the same again (the tile cache) | {med['xyz_warm']:.0f} tiles/s |")
    print(f"| gdal_translate of the GDAL WMS description (full zoom) | {med['wms']:.2f} s |")
    print(f"| gdalwarp of mosaic.tif to the same grid, locally | {med['warp']:.2f} s |")
    print(f"| gdalinfo -checksum through /vsicurl/ (checksums {'equal' if same else 'DIFFERENT'}) | {med['vsicurl']:.2f} s |")
    print(f"| gdalinfo -checksum of the local file | {med['local']:.2f} s |")


if __name__ == "__main__":
    main()
