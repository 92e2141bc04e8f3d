"""Every step of the command from Python on data made here: synth, mosaic (a folder, with
progress), compose into a local metric frame (pixel_to_map / map_to_pixel), typed frames, merge,
convert and export; bad input of every kind; Ctrl-C (a real SIGINT) during a long call; memory
while reading 1,000 random windows; object identification trained, evaluated and run over a store."""
import json
import os
import resource
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import rasterio

import rolamos

CLI = os.environ.get("ROLAMOS_CLI", "rolamos")


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    d = tmp_path_factory.mktemp("steps")
    seen = []
    r = rolamos.synth(d / "survey", frames=24, width=480, height=360, focal=420, lanes=2, seed=3,
                      progress=lambda f, what: seen.append(f))
    assert r["frames"] == 24 and r["frame_size"] == (480, 360)
    assert seen and seen[-1] == pytest.approx(1.0)
    truth = json.load(open(d / "survey" / "ground_truth.json"))
    assert len(truth["frames"]) == 24
    return d


@pytest.fixture(scope="module")
def mapped(survey):
    store = survey / "s.rolamos"
    seen = []
    summary = rolamos.mosaic(survey / "survey" / "frames", store, patch_megapixels=0.8,
                             progress=lambda f, what: seen.append((f, what)))
    assert summary["frames"] == 24 and summary["stitched"] >= 23, summary
    assert summary["patches"] >= 2 and summary["keyframes"] >= 1 and "features" in summary["stage_seconds"]
    assert 1 <= summary["blended"] <= summary["keyframes"]
    named = sum(summary["stage_seconds"].values())
    assert summary["rest_cpu_seconds"] == pytest.approx(max(0.0, summary["cpu_seconds"] - named), abs=1e-6)
    assert seen[-1] == (pytest.approx(1.0), "mosaic")
    return rolamos.Store(store)


def test_a_lens_that_distorts_is_said_and_calibrated(tmp_path):
    # A 90-degree lens, uncalibrated: no patch fits a pinhole camera, and the summary says which
    # and why; calibrated from the frames, every patch is adjusted.
    rolamos.synth(tmp_path / "lens", frames=40, width=480, height=360, fov=90, k1=-0.08, lanes=1, overlap=0.9)
    raw = rolamos.mosaic(tmp_path / "lens" / "frames", tmp_path / "raw.rolamos")
    assert raw["stitched"] == 40
    assert raw["unadjusted"] and raw["unadjusted"][0][1].startswith("transfer error"), raw["unadjusted"]
    assert raw["misfit_patches"] == [p for p, _ in raw["unadjusted"]], raw
    cal = rolamos.mosaic(tmp_path / "lens" / "frames", tmp_path / "cal.rolamos", calibration="auto")
    assert "k1 = -0.2" in cal["calibration_note"], cal["calibration_note"]
    assert cal["unadjusted"] == [] and cal["misfit_patches"] == [] and cal["adjusted"] >= 1, cal


def test_compose_in_a_local_frame_places_pixels_on_the_map(mapped):
    r = rolamos.compose(mapped.path, altitude=2.0, focal=420)
    assert r["patches_used"] == len(mapped.patches)
    store = rolamos.Store(mapped.path)
    assert store.georeferenced and store.global_record.crs
    # 2 m over a 420-pixel focal length: 4.76 mm a pixel.
    e0, n0 = store.pixel_to_map(0, 0)
    e1, n1 = store.pixel_to_map(100, 0)
    assert np.hypot(e1 - e0, n1 - n0) == pytest.approx(100 * 2.0 / 420, rel=0.05)
    cols, rows = np.array([10.0, 333.5, 1000.0]), np.array([20.0, 44.25, 700.0])
    back = store.map_to_pixel(*store.pixel_to_map(cols, rows))
    assert np.allclose(back[0], cols) and np.allclose(back[1], rows)
    # The same georeference as GDAL reads from mosaic.tif.
    with rasterio.open(store.mosaic_path) as src:
        assert np.allclose(src.transform * (333.5, 44.25), store.pixel_to_map(333.5, 44.25), atol=1e-6)


def test_frames_are_typed_and_placed_in_the_mosaic(mapped):
    rolamos.compose(mapped.path)
    store = rolamos.Store(mapped.path)
    frames = store.frames()
    assert len(frames) >= 23 and len({f.index for f in frames}) == len(frames)
    f = frames[0]
    assert isinstance(f, rolamos.Frame) and f.frame_to_patch.shape == (3, 3) and f.frame_to_mosaic is not None
    image = rolamos.open_image(store, "mosaic")
    for f in frames:
        cx, cy = f.centre(frame_size=(480, 360))
        assert 0 <= cx < image.width and 0 <= cy < image.height, (f.index, cx, cy)
    assert [f.index for f in store.frames(patch=frames[-1].patch)] == sorted(
        f.index for f in frames if f.patch == frames[-1].patch)


def test_merge_convert_and_export(mapped, survey, tmp_path):
    other = tmp_path / "other.rolamos"
    rolamos.mosaic(survey / "survey" / "frames", other, patch_megapixels=0.8, mask="none")
    merged = rolamos.merge([mapped.path, other], tmp_path / "merged.rolamos")
    assert merged["stores"] == 2 and merged["patches"] == len(mapped.patches) + len(rolamos.Store(other).patches)
    # A frame converted to a pyramidal tiled TIFF, then a region exported at full resolution.
    frame = sorted((survey / "survey" / "frames").iterdir())[0]
    c = rolamos.convert(frame, tmp_path / "frame.tif", compression="zstd", tile=256)
    assert (c["width"], c["height"]) == (480, 360) and c["levels"] >= 2
    e = rolamos.export(tmp_path / "frame.tif", tmp_path / "part.png", region=(100, 50, 64, 32))
    assert (e["width"], e["height"]) == (64, 32)
    with rasterio.open(tmp_path / "part.png") as src:
        part = np.moveaxis(src.read(), 0, -1)
    assert np.array_equal(part, rolamos.open_image(tmp_path / "frame.tif").read(100, 50, 64, 32))
    with pytest.raises(ValueError, match="compression"):
        rolamos.convert(frame, tmp_path / "bad.tif", compression="gif")


def test_bad_input_raises_clear_errors_and_the_interpreter_lives(mapped, tmp_path):
    with pytest.raises(rolamos.Error, match="no such store"):
        rolamos.Store(tmp_path / "missing.rolamos")
    with pytest.raises(rolamos.Error):
        rolamos.compose(tmp_path / "missing.rolamos")
    # A mistyped input: named, and no empty store left behind.
    with pytest.raises(rolamos.Error, match="no-such-frames: no such folder, list or video"):
        rolamos.mosaic(tmp_path / "no-such-frames", tmp_path / "typo.rolamos")
    assert not (tmp_path / "typo.rolamos").exists()
    # A corrupt sidecar: named when frames are read; the other patches still list.
    broken = tmp_path / "broken.rolamos"
    subprocess.run(["cp", "-r", mapped.path, str(broken)], check=True)
    victim = rolamos.Store(broken).patches[0]
    with open(victim.sidecar, "w") as f:
        f.write('{"id": 1, "frames": [')
    store = rolamos.Store(broken)
    assert any(p.problem for p in store.patches)
    with pytest.raises(rolamos.Error, match=os.path.basename(victim.sidecar)):
        store.frames()
    # Windows outside the image, and bad levels and scales.
    image = rolamos.open_image(mapped, mapped.patches[0].id)
    with pytest.raises(ValueError, match="leaves level 0"):
        image.read(image.width - 10, 0, 20, 20)
    with pytest.raises(ValueError, match="leaves level"):
        image.read(-1, 0, 5, 5)
    with pytest.raises(ValueError, match="positive"):
        image.read(0, 0, 0, 5)
    with pytest.raises(ValueError, match="level 99"):
        image.read(0, 0, 5, 5, level=99)
    with pytest.raises(ValueError, match="scale"):
        image.read(0, 0, 5, 5, scale=2.0)
    # Frames of the wrong dtype or shape, and a closed engine.
    m = rolamos.Mosaicker(tmp_path / "pushed.rolamos")
    with pytest.raises(ValueError, match="dtype float32"):
        m.push(np.zeros((360, 480, 3), np.float32))
    with pytest.raises(ValueError, match="shape"):
        m.push(np.zeros((360, 480, 2), np.uint8))
    with pytest.raises(ValueError, match="NumPy array"):
        m.push([[1, 2], [3, 4]])
    with pytest.raises(ValueError, match="too small"):
        m.push(np.zeros((4, 4, 3), np.uint8))
    m.close()
    assert m.closed
    with pytest.raises(rolamos.Error, match="closed"):
        m.push(np.zeros((360, 480, 3), np.uint8))
    with pytest.raises(ValueError, match="patch_megapixels|budget"):
        rolamos.mosaic(tmp_path / "x", tmp_path / "y.rolamos", patch_megapixels=-1)
    with pytest.raises(ValueError, match="'mask'"):
        rolamos.Mosaicker(tmp_path / "m.rolamos", mask="auto")
    with pytest.raises(ValueError, match="unknown option 'frame'"):
        rolamos.synth(tmp_path / "s", frame=3)


def test_ctrl_c_stops_a_long_call(survey, tmp_path):
    """A real SIGINT while mosaic runs in a child interpreter: KeyboardInterrupt, quickly, the open patch written."""
    frames = survey / "survey" / "frames"
    big = tmp_path / "big"
    rolamos.synth(big, frames=200, width=640, height=480, focal=560, seed=5)
    code = textwrap.dedent(f"""
        import sys, time, rolamos
        print("started", flush=True)
        try:
            rolamos.mosaic({str(big / 'frames')!r}, {str(tmp_path / 'c.rolamos')!r}, mask="none")
            print("finished", flush=True)
        except KeyboardInterrupt:
            print("interrupted", flush=True)
            sys.exit(3)
    """)
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ))
    assert p.stdout.readline().strip() == "started"
    time.sleep(1.5)
    sent = time.monotonic()
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 3 and "interrupted" in out, (p.returncode, out, err)
    assert time.monotonic() - sent < 10, "SIGINT took too long to be honoured"
    # What was mapped before the stop is in a store that opens: the open patch was written.
    info = rolamos.Store(tmp_path / "c.rolamos").info()
    assert info["kind"] == "store"
    assert sum(p["n_images"] for p in info["patches"]) > 0, info


def vm_rss_mb():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return 0.0


def test_random_windows_stay_within_the_cache_limit(tmp_path):
    """1,000 random 512 x 512 windows of an 8192 x 8192 image through a 32 MB cache: the resident
    set grows by at most the cache plus a stated margin (decoders' buffers, the arrays read)."""
    subprocess.run([CLI, "demo", "-o", str(tmp_path / "demo.rolamos"), "--size", "8192"], check=True,
                   capture_output=True)
    image = rolamos.open_image(tmp_path / "demo.rolamos", 1, cache_mb=32)
    rng = np.random.default_rng(7)
    image.read(0, 0, 512, 512)  # libraries and first buffers in
    before = vm_rss_mb()
    peak = before
    for _ in range(1000):
        x, y = rng.integers(0, image.width - 512), rng.integers(0, image.height - 512)
        a = image.read(int(x), int(y), 512, 512)
        assert a.shape[:2] == (512, 512)
        peak = max(peak, vm_rss_mb())
    margin_mb = 48
    assert peak - before < 32 + margin_mb, f"resident set grew {peak - before:.0f} MB"


def make_class_images(root, n=14, size=96, seed=0):
    """Two classes a model must tell apart: bright discs and dark crosses on textured ground,
    and bare ground as background."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    for cls in ("disc", "cross", "background"):
        (root / cls).mkdir(parents=True)
        for i in range(n):
            ground = rng.normal(110, 18, (size, size)).clip(0, 255)
            cx, cy = size / 2 + rng.uniform(-8, 8), size / 2 + rng.uniform(-8, 8)
            r = rng.uniform(14, 22)
            if cls == "disc":
                ground[(xx - cx) ** 2 + (yy - cy) ** 2 < r * r] = 230
            elif cls == "cross":
                ground[(abs(xx - cx) < r) & (abs(yy - cy) < r / 4)] = 20
                ground[(abs(yy - cy) < r) & (abs(xx - cx) < r / 4)] = 20
            img = np.repeat(ground[..., None], 3, axis=2).astype(np.uint8)
            img[..., 2] = (img[..., 2] * 0.8).astype(np.uint8)
            from PIL import Image as PILImage  # python3-pil comes with matplotlib
            PILImage.fromarray(img).save(root / cls / f"{cls}_{i:02d}.png")


def test_objects_train_evaluate_classify_and_detect(mapped, tmp_path):
    make_class_images(tmp_path / "train", seed=1)
    make_class_images(tmp_path / "test", n=8, seed=2)
    model = rolamos.objects.train(tmp_path / "train", tmp_path / "model.yml.gz", vocabulary=8, kmeans_samples=4000,
                                  folds=2, image_size=96)
    assert sorted(model.classes) == ["cross", "disc"] and os.path.exists(tmp_path / "model.yml.gz")
    e = rolamos.objects.evaluate(tmp_path / "test", tmp_path / "model.yml.gz")
    assert e["accuracy"] >= 0.8, e
    from PIL import Image as PILImage
    disc = np.asarray(PILImage.open(tmp_path / "test" / "disc" / "disc_00.png").convert("RGB"))
    scores = model.classify(disc)
    assert scores[0][0] == "disc", scores
    rolamos.compose(mapped.path)
    d = rolamos.objects.detect(mapped.path, model, window=128, stride=1.0)
    assert d["windows"] > 0 and d["geojson"]["type"] == "FeatureCollection"
    assert rolamos.Store(mapped.path).detections() == d["geojson"]
    with pytest.raises(ValueError, match="unknown option 'windows'"):
        rolamos.objects.detect(mapped.path, model, windows=3)
    with pytest.raises(rolamos.Error):
        rolamos.objects.ObjectModel.load(tmp_path / "nope.yml.gz")


def burrow_frame(rng, w=480, h=360):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    ground = 120 + 18 * rng.standard_normal((h // 4, w // 4)).astype(np.float32)
    ground = np.kron(ground, np.ones((4, 4), np.float32)) + 6 * rng.standard_normal((h, w)).astype(np.float32)
    boxes = []
    for _ in range(40):
        if len(boxes) == 8:
            break
        r = rng.uniform(12, 30)
        cx, cy = rng.uniform(r + 2, w - r - 2), rng.uniform(r + 2, h - r - 2)
        if any(np.hypot(cx - (bx + bw / 2), cy - (by + bh / 2)) < r + bw / 2 + 10 for bx, by, bw, bh in boxes):
            continue
        dist = np.hypot(xx - cx, yy - cy) / r
        f = np.where(dist < 0.6, 0.45 + 0.2 * dist, np.where(dist < 1.0, 0.57 + 1.44 * (dist - 0.6),
                                                             np.where(dist < 1.3, 1.15 - 0.5 * (dist - 1.0), 1.0)))
        ground = ground * f
        boxes.append((cx - r, cy - r, 2 * r, 2 * r))
    vignette = 1.3 - 1.6 * ((xx - 0.6 * w) ** 2 + (yy - 0.45 * h) ** 2) / (w * w + h * h)
    gray = np.clip(ground * vignette, 0, 255).astype(np.uint8)
    return np.dstack([gray] * 3), boxes


def write_boxed(d, first, count, per_station):
    from PIL import Image as PILImage
    (d / "images").mkdir(parents=True, exist_ok=True)
    (d / "labels_gt").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(first)
    for i in range(first, first + count):
        img, boxes = burrow_frame(rng)
        name = f"image_D2023-06-{3 + (i - first) // per_station:02d}T10-{i % 30:02d}-00-000000Z_{i}"
        PILImage.fromarray(img).save(d / "images" / (name + ".png"))
        h, w = img.shape[:2]
        with open(d / "labels_gt" / (name + ".txt"), "w") as f:
            for x, y, bw, bh in boxes:
                f.write(f"0 {(x + bw / 2) / w} {(y + bh / 2) / h} {bw / w} {bh / h}\n")


def test_box_detector_train_evaluate_validate_detect(mapped, tmp_path):
    write_boxed(tmp_path / "train", 0, 8, 4)
    write_boxed(tmp_path / "test", 100, 3, 10)
    det = rolamos.objects.train_boxes(tmp_path / "train", tmp_path / "b.yml.gz", label="burrow", max_box=80)
    assert det.label == "burrow" and rolamos._rolamos.is_box_detector(str(tmp_path / "b.yml.gz"))
    e = rolamos.objects.evaluate_boxes(tmp_path / "test", tmp_path / "b.yml.gz")
    assert e["ap50"] > 0.6 and e["precision"] > 0.5 and e["recall"] > 0.5, e
    from PIL import Image as PILImage
    frame = np.asarray(PILImage.open(sorted((tmp_path / "test" / "images").iterdir())[0]).convert("RGB"))
    found = det.detect(frame)
    assert found and found[0]["class"] == "burrow" and len(found[0]["bbox"]) == 4
    assert all(f["score"] >= det.threshold for f in found)
    v = rolamos.objects.validate_boxes(tmp_path / "train", 2, max_box=80, hard_negative_rounds=1)
    assert len(v["folds"]) == 2 and all(len(f["stations"]) == 1 for f in v["folds"]) and v["images"] == 8
    rolamos.compose(mapped.path)
    d = rolamos.objects.detect(mapped.path, det, density_cell=256)
    assert d["geojson"]["type"] == "FeatureCollection" and d["megapixels"] > 0
    density = rolamos.Store(mapped.path).density()
    assert density["name"] == "rolamos_density" and sum(f["properties"]["count"] for f in density["features"]) == d["detections"]
    with pytest.raises(ValueError, match="features must be cells or hog"):
        rolamos.objects.train_boxes(tmp_path / "train", features="sift")
    with pytest.raises(rolamos.Error, match="labels_gt"):
        rolamos.objects.train_boxes(tmp_path / "nothing")


def test_the_summary_names_the_frames_rejected(tmp_path):
    # A frame that is not an image: rejected, named with its reason in the summary, the others placed.
    rolamos.synth(tmp_path / "s", frames=10, width=480, height=360, lanes=1, overlap=0.8)
    bad = tmp_path / "s" / "frames" / "frame_00004.jpg"
    bad.write_text("not a jpeg")
    summary = rolamos.mosaic(tmp_path / "s" / "frames", tmp_path / "s.rolamos")
    assert summary["rejected"] == 1 and summary["stitched"] == 9, summary
    [(index, source, reason)] = summary["rejected_frames"]
    assert index == 4 and source.endswith("frame_00004.jpg") and reason.startswith("unreadable"), summary["rejected_frames"]
