#!/usr/bin/env python3
"""QGIS (headless, QT_QPA_PLATFORM=offscreen) as a surveyor would use it on a served survey: the
Web Mercator XYZ layer of `rolamos serve`, the exported COG read remotely through /vsicurl/ (range
requests), and the object detections' GeoJSON, loaded and rendered together. The XYZ rendering
must agree with the COG's where both have data, and the detections must be drawn.
Exits 77 (ctest: skipped) where QGIS's Python bindings are not installed (scripts/setup.sh
installs them with ROLAMOS_WITH_QGIS=1).

  PYTHONPATH=build/python tests/gis/qgis_clients.py ROLAMOS_CLI SCRATCH_DIR ARTEFACTS_DIR
"""
import json
import math
import os
import re
import shutil
import subprocess
import sys
import urllib.parse

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
try:
    from qgis.core import (QgsApplication, QgsCoordinateReferenceSystem, QgsCoordinateTransform, QgsMapRendererSequentialJob,
                           QgsMapSettings, QgsProject, QgsRasterLayer, QgsVectorLayer)
    from qgis.PyQt.QtCore import QSize
    from qgis.PyQt.QtGui import QColor
except ImportError:
    print("SKIP: QGIS's Python bindings (python3-qgis) are not installed; ROLAMOS_WITH_QGIS=1 scripts/setup.sh installs them")
    sys.exit(77)
import numpy as np

cli, scratch, artefacts = sys.argv[1:4]
shutil.rmtree(scratch, ignore_errors=True)
os.makedirs(scratch)
os.makedirs(artefacts, exist_ok=True)
failures = 0


def check(ok, what):
    global failures
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    failures += 0 if ok else 1


def run(*args):
    subprocess.run([cli, *args], cwd=scratch, check=True, capture_output=True, text=True)


# A survey, georeferenced from its navigation (EPSG:32755), its COG exported into the store.
run("synth", "-q", "-o", "survey", "--frames", "24", "--width", "480", "--height", "360", "--focal", "420", "--lanes", "2")
truth = json.load(open(os.path.join(scratch, "survey", "ground_truth.json")))
fw, fh = truth["frame_size"]
with open(os.path.join(scratch, "nav.csv"), "w") as out:
    out.write("frame,easting,northing,epsg,altitude,heading\n")
    for f in truth["frames"]:
        H = f["frame_to_world"]

        def world(x, y):
            z = H[6] * x + H[7] * y + H[8]
            return 500000 + 0.01 * (H[0] * x + H[1] * y + H[2]) / z, 5200000 - 0.01 * (H[3] * x + H[4] * y + H[5]) / z

        c, up, right = world((fw - 1) / 2, (fh - 1) / 2), world((fw - 1) / 2, (fh - 1) / 2 - 1), world((fw + 1) / 2, (fh - 1) / 2)
        heading = math.degrees(math.atan2(up[0] - c[0], up[1] - c[1]))
        out.write(f"{os.path.basename(f['file'])},{c[0]},{c[1]},32755,{math.hypot(right[0] - c[0], right[1] - c[1]) * 420},{heading}\n")
run("mosaic", "-q", "survey/frames", "-o", "s.rolamos")
run("compose", "-q", "s.rolamos", "--navigation", "nav.csv", "--focal", "420")
os.makedirs(os.path.join(scratch, "s.rolamos", "exports"))
run("export", "-q", "s.rolamos", "--cog", "-o", "s.rolamos/exports/mosaic-cog.tif")

# Detections in map coordinates: a small two-class model (bright discs, dark bars) run over it.
rng = np.random.default_rng(3)
from PIL import Image as PILImage  # noqa: E402
for cls in ("disc", "bar"):
    os.makedirs(os.path.join(scratch, "train", cls))
    for i in range(10):
        g = rng.normal(110, 18, (96, 96)).clip(0, 255)
        yy, xx = np.mgrid[0:96, 0:96]
        if cls == "disc":
            g[(xx - 48) ** 2 + (yy - 48) ** 2 < rng.uniform(12, 20) ** 2] = 230
        else:
            g[40:56, 16:80] = 20
        PILImage.fromarray(np.repeat(g[..., None], 3, axis=2).astype(np.uint8)).save(os.path.join(scratch, "train", cls, f"{i}.png"))
# Through the command (QGIS's own GDAL and PROJ are the only ones loaded in this process).
run("objects", "train", "-q", "--data", "train", "-o", "model.yml.gz", "--vocabulary", "8", "--kmeans-samples", "4000",
    "--folds", "2", "--image-size", "96")
run("objects", "detect", "-q", "s.rolamos", "--model", "model.yml.gz", "--window", "128", "--stride", "1.0")
geojson = os.path.join(scratch, "s.rolamos", "objects", "detections.geojson")
features = json.load(open(geojson))["features"]
check(len(features) > 0 and abs(features[0]["geometry"]["coordinates"][0][0][0] - 500000) < 1000,
      f"{len(features)} detections in map coordinates (EPSG:32755 eastings)")

server = subprocess.Popen([cli, "serve", "s.rolamos", "--port", "0"], cwd=scratch, stdout=subprocess.PIPE, text=True)
base = None
for line in server.stdout:
    m = re.search(r"on (http://[^\s]+)", line)
    if m:
        base = m.group(1).rstrip("/")
        break
tilejson = json.loads(subprocess.run(["curl", "-s", base + "/tilejson/mosaic.json"], capture_output=True, text=True).stdout)

QgsApplication.setPrefixPath("/usr", True)
app = QgsApplication([], False)
app.initQgis()
try:
    url = base + "/tiles/mosaic/webmercator/{z}/{x}/{y}.png"
    xyz = QgsRasterLayer(f"type=xyz&zmin={tilejson['minzoom']}&zmax={tilejson['maxzoom']}&url=" +
                         urllib.parse.quote(url, safe=":/"), "rolamos XYZ", "wms")
    cog = QgsRasterLayer("/vsicurl/" + base + "/files/exports/mosaic-cog.tif", "rolamos COG", "gdal")
    det = QgsVectorLayer(geojson, "detections", "ogr")
    check(xyz.isValid(), "QGIS opens the XYZ layer (" + url + ")")
    check(cog.isValid(), "QGIS opens the COG through /vsicurl/ (range requests)")
    check(det.isValid() and det.featureCount() == len(features),
          f"QGIS reads the detections ({det.featureCount()} features)")
    check(cog.crs().authid() == "EPSG:32755", "the COG's CRS is " + cog.crs().authid())
    for layer in (xyz, cog, det):
        QgsProject.instance().addMapLayer(layer, False)  # the project owns them from here
    mercator = QgsCoordinateReferenceSystem("EPSG:3857")
    extent = QgsCoordinateTransform(cog.crs(), mercator, QgsProject.instance()).transformBoundingBox(cog.extent())

    def render(layers, name):
        s = QgsMapSettings()
        s.setLayers(layers)
        s.setDestinationCrs(mercator)
        s.setExtent(extent)
        s.setOutputSize(QSize(512, 512))
        s.setBackgroundColor(QColor(0, 0, 0, 0))
        job = QgsMapRendererSequentialJob(s)
        job.start()
        job.waitForFinished()
        img = job.renderedImage()
        img.save(os.path.join(artefacts, name))
        ptr = img.constBits()
        ptr.setsize(img.sizeInBytes())
        a = np.frombuffer(ptr, np.uint8).reshape(img.height(), img.bytesPerLine() // 4, 4)[:, :img.width()]
        return a.copy()  # BGRA (ARGB32, premultiplied)

    a = render([xyz], "qgis-xyz.png")
    b = render([cog], "qgis-cog.png")
    both = (a[..., 3] == 255) & (b[..., 3] == 255)
    check(both.mean() > 0.2, f"both layers cover the map ({both.mean():.0%} of the view)")
    diff = np.abs(a[..., :3].astype(int) - b[..., :3].astype(int))[both].mean() if both.any() else 999
    check(diff < 8, f"the XYZ rendering agrees with the COG's where both have data (mean |diff| {diff:.2f})")
    c = render([det, xyz], "qgis-all.png")
    drawn = (np.abs(c.astype(int) - a.astype(int)).sum(axis=2) > 30).mean()
    check(drawn > 0.001, f"the detections are drawn over the map ({drawn:.1%} of the view)")
finally:
    # Layers go before QGIS does (a layer destroyed after exitQgis crashes the interpreter).
    QgsProject.instance().removeAllMapLayers()
    app.exitQgis()
    server.terminate()
print(f"{failures} check(s) failed" if failures else "all checks passed")
sys.exit(1 if failures else 0)
