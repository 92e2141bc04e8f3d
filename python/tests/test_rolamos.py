"""The rolamos Python module on a synthetic survey made here: frames pushed one by one through
rolamos.Mosaicker, the store composed, and windows read through rolamos compared with rasterio's
(GDAL's) reading of the same files, at every level, at scales and at the edges."""
import os
import subprocess

import numpy as np
import pytest
import rasterio
from rasterio.enums import MaskFlags
from rasterio.windows import Window

import rolamos

CLI = os.environ.get("ROLAMOS_CLI", "rolamos")


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    d = tmp_path_factory.mktemp("survey")
    subprocess.run([CLI, "synth", "-q", "-o", str(d / "survey"), "--frames", "16", "--width", "480", "--height",
                    "360", "--focal", "420"], check=True)
    frames = sorted((d / "survey" / "frames").iterdir())
    m = rolamos.Mosaicker(str(d / "s.rolamos"), patch_megapixels=0.6, mask="none")
    reports = []
    for f in frames:
        # A frame as a camera SDK hands it over: RGB uint8.
        image = rolamos.open_image(str(f))
        pixels = image.read(0, 0, image.width, image.height)
        assert pixels.shape == (360, 480, 3) and pixels.dtype == np.uint8
        reports.append(m.push(pixels, name=f.name))
    totals = m.close()
    assert totals["frames"] == 16
    assert sum(r["status"] == "stitched" for r in reports) >= 15
    assert totals["patches"] >= 2
    seen = []
    result = rolamos.compose(str(d / "s.rolamos"), progress=lambda f, what: seen.append((f, what)))
    assert result["patches_used"] == totals["patches"] and result["width"] > 0
    assert seen and seen[-1][0] == pytest.approx(1.0) and seen[0][1] == "compose"
    return rolamos.Store(str(d / "s.rolamos"))


def test_store_lists_patches_and_the_global_record(store):
    assert len(store.patches) >= 2
    assert sum(p.n_images for p in store.patches) >= 15
    assert all(p.problem is None and p.levels >= 1 for p in store.patches)
    g = store.global_record
    assert g.width > 0 and g.height > 0 and g.n_patches == len(store.patches)
    assert store.mosaic_path and os.path.exists(store.mosaic_path)
    assert store.info()["kind"] == "store"
    assert store.sidecar(store.patches[0].id)["id"] == store.patches[0].id


def rasterio_read(path, x, y, w, h, level):
    """The same window through GDAL: level 0 is the file, level L its (L-1)th overview. A
    transparency mask (the engine's jpeg-mask patches) comes as the alpha rolamos reads."""
    with rasterio.open(path, OVERVIEW_LEVEL=level - 1) if level > 0 else rasterio.open(path) as src:
        a = src.read(window=Window(x, y, w, h))
        if src.count in (1, 3) and MaskFlags.per_dataset in src.mask_flag_enums[0]:
            a = np.concatenate([a, src.dataset_mask(window=Window(x, y, w, h))[None]], axis=0)
    return np.moveaxis(a, 0, -1)


@pytest.mark.parametrize("which", ["mosaic", "patch"])
def test_windows_equal_rasterio_at_every_level_and_at_the_edges(store, which):
    image = rolamos.open_image(store, "mosaic" if which == "mosaic" else store.patches[0].id)
    assert image.channels in (3, 4) and image.dtype == "uint8"
    for level, (w, h) in enumerate(image.level_sizes):
        for x, y, ww, hh in [(0, 0, min(w, 70), min(h, 50)),                 # a corner
                             (max(0, w - 37), max(0, h - 29), min(w, 37), min(h, 29)),  # the far edges
                             (w // 3, h // 3, max(1, w // 4), max(1, h // 4))]:
            ours = image.read(x, y, ww, hh, level=level)
            theirs = rasterio_read(image.path, x, y, ww, hh, level)
            assert ours.shape == theirs.shape, (level, x, y)
            assert np.array_equal(ours, theirs), f"level {level} window {x},{y},{ww},{hh}"


def test_reads_at_scales_that_are_not_powers_of_two(store):
    image = rolamos.open_image(store, "mosaic")
    full = image.read(0, 0, image.width, image.height).astype(np.float64)
    for scale in (0.3, 0.5, 0.77):
        small = image.read(0, 0, image.width, image.height, scale=scale)
        assert abs(small.shape[1] - image.width * scale) <= 1 and abs(small.shape[0] - image.height * scale) <= 1
        # Where the mosaic has data everywhere, the reduced image is its area average.
        if image.channels == 4:
            assert small[..., 3].max() == 255
        assert abs(small[..., :3].astype(np.float64).mean() - full[..., :3].mean()) < 12


def test_errors_name_the_file_and_bad_options_name_the_option(tmp_path):
    with pytest.raises(rolamos.Error, match="nope.tif"):
        rolamos.open_image(str(tmp_path / "nope.tif"))
    with pytest.raises(ValueError, match="bogus"):
        rolamos.Mosaicker(str(tmp_path / "x.rolamos"), bogus=1)
    with pytest.raises(ValueError, match="keyframe_overlap"):
        rolamos.Mosaicker(str(tmp_path / "y.rolamos"), keyframe_overlap="high")
    with pytest.raises(ValueError):
        rolamos.Mosaicker(str(tmp_path / "z.rolamos"), max_features=-5)
    with pytest.raises(ValueError, match="followed keyframes"):
        rolamos.Mosaicker(str(tmp_path / "w.rolamos"), followed_max_features=10)
    with pytest.raises(ValueError, match="robust loss"):
        rolamos.Mosaicker(str(tmp_path / "v.rolamos"), patch_robust_loss_px=-1)


def test_align_then_compose_and_export_from_python(store, tmp_path):
    with pytest.raises((ValueError, rolamos.Error), match="scatter floor"):
        rolamos.align(store.path, scatter_floor_px=-1)
    summary = rolamos.align(store.path, scatter_floor_px=0.1)
    assert summary["components"] == 1 and summary["rms_after_px"] < 2.0, summary
    # Every stage timed, in order, with the peak memory at its end (which only grows).
    stages = list(summary["stage_seconds"])
    assert stages[:4] == ["graph", "retrieval", "consistency", "solve"] and stages[-1] == "store", stages
    assert all(t >= 0 for t in summary["stage_seconds"].values())
    peaks = [summary["stage_peak_mib"][name] for name in stages]
    assert peaks[0] > 0 and peaks == sorted(peaks), peaks
    rolamos.compose(store.path)
    image = rolamos.open_image(store.path, "mosaic")
    out = tmp_path / "region.png"
    r = rolamos.export(image, out, region=(10, 20, 200, 100))
    assert (r["width"], r["height"]) == (200, 100)
    with rasterio.open(out) as src:
        exported = np.moveaxis(src.read(), 0, -1)
    assert np.array_equal(exported, image.read(10, 20, 200, 100)[..., : exported.shape[2]])


def test_progress_can_interrupt_a_long_call(store):
    def stop(fraction, what):
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        rolamos.compose(store.path, restart=True, progress=stop)
    rolamos.compose(store.path)  # the store is whole: a compose afterwards finishes it
    assert rolamos.open_image(store.path, "mosaic").width > 0


def test_the_example_plots_the_overview(store, tmp_path):
    out = tmp_path / "overview.png"
    example = os.path.join(os.path.dirname(__file__), "..", "..", "examples", "plot_overview.py")
    r = subprocess.run(["/usr/bin/python3", example, store.path, "-o", str(out)], capture_output=True, text=True,
                       env=dict(os.environ))
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 10_000
    import matplotlib.image
    picture = matplotlib.image.imread(str(out))
    assert picture.shape[0] >= 600 and picture.std() > 0.05  # a picture, not a blank page
