#!/usr/bin/env python3
"""Compose at scale (issue 4): the global mosaic of synthetic stores much larger than the tile
cache, with peak RSS and output megapixels per second, against gdalwarp doing the same placement
into one tiled BigTIFF (GDAL has no feathering: the last patch wins), and a compose interrupted
and resumed; then a 1,000-frame synthetic survey mosaicked, composed and aligned.

  bench/run_compose_scale.py [--runs 3] [--big]        (--big adds the 20-gigapixel store)

Stores are made once under bench/out/compose/ by build/compose_scale_bench and `rolamos synth`.
"""
from bench_common import PYTHON, timed
import argparse, json, os, re, signal, subprocess, statistics, time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
MAKE = os.path.join(ROOT, "build", "compose_scale_bench")
OUT = os.path.join(ROOT, "bench", "out", "compose")


def timed_checked(cmd, timeout=None):
    return timed(cmd, timeout=timeout, check=True)


def make(name, width, height, patch, overlap, georef=False):
    store = os.path.join(OUT, name)
    if not os.path.exists(os.path.join(store, "store.json")):
        subprocess.run(["rm", "-rf", store])
        cmd = [MAKE, "make", "--width", str(width), "--height", str(height), "--patch", str(patch),
               "--overlap", str(overlap), "-o", store] + (["--georef"] if georef else [])
        subprocess.run(cmd, check=True, stderr=subprocess.DEVNULL)
    return store


def compose(store, codec, extra=()):
    r, t, m = timed_checked([CLI, "compose", store, "-q", "--no-link", "--compression", codec, "--restart", *extra])
    w, h = map(int, re.search(r"mosaic.tif: (\d+) x (\d+)", r.stdout).groups())
    return t, m, w * h / 1e6


def check(store):
    r = subprocess.run([MAKE, "check", "--store", store], capture_output=True, text=True, check=True)
    return json.loads(r.stdout)


def gdalwarp(store, runs, timeout):
    out = os.path.join(OUT, "gdalwarp.tif")
    patches = sorted(os.path.join(store, "patches", f) for f in os.listdir(os.path.join(store, "patches")) if f.endswith(".tif"))
    times, mems = [], []
    for _ in range(runs):
        subprocess.run(["rm", "-f", out])
        # (-co NUM_THREADS=2 as well deadlocked GDAL 3.6 here: every thread waiting, for minutes.)
        _, t1, m1 = timed_checked(["gdalwarp", "-q", "-multi", "-wo", "NUM_THREADS=2", "-wm", "512", "-ovr", "NONE", "-dstalpha",
                           "-co", "TILED=YES", "-co", "BIGTIFF=YES", "-co", "COMPRESS=JPEG",
                           "--config", "GDAL_CACHEMAX", "256", *patches, out], timeout=timeout)
        if t1 is None:
            return None, None
        _, t2, m2 = timed_checked(["gdaladdo", "-q", "-r", "average", "--config", "COMPRESS_OVERVIEW", "JPEG",
                           "--config", "GDAL_NUM_THREADS", "2", out])
        times.append(t1 + t2)
        mems.append(max(m1, m2))
    return statistics.median(times), max(mems)


def survey1000(lines):
    survey = os.path.join(OUT, "survey1000")
    if not os.path.exists(os.path.join(survey, "ground_truth.json")):
        subprocess.run([CLI, "synth", "-o", survey, "--frames", "1000", "-q", "--seed", "5"], check=True)
    store = os.path.join(OUT, "s1000.rolamos")
    subprocess.run(["rm", "-rf", store])
    r, t_mosaic, m_mosaic = timed_checked([CLI, "mosaic", "-q", os.path.join(survey, "frames"), "-o", store])
    patches = re.search(r"(\d+) patch", r.stdout)
    rows = []
    for codec in ("webp", "jpeg"):
        t, m, mpx = compose(store, codec)
        rows.append((codec, t, m, mpx))
    r, t_align, m_align = timed_checked([CLI, "align", "-q", store])
    loop = re.search(r"loop error ([\d.]+) -> ([\d.]+) px", r.stdout)
    t_re, m_re, mpx = compose(store, "webp")
    ev = subprocess.run([PYTHON, os.path.join(ROOT, "bench", "eval_global.py"), survey, store],
                        capture_output=True, text=True)
    rms = json.loads(ev.stdout)["rms_px"] if ev.returncode == 0 else float("nan")
    lines.append(f"\n1,000-frame synthetic survey (1292 x 964 frames, procedural seafloor, lawnmower): `mosaic` "
                 f"{t_mosaic:.0f} s ({1000 / t_mosaic:.1f} frames/s, peak RSS {m_mosaic:.0f} MB, "
                 f"{patches.group(1) if patches else '?'} patches); mosaic {mpx:.0f} Mpx.\n")
    lines.append("| step | seconds | output Mpx/s | peak RSS MB |")
    lines.append("|---|---|---|---|")
    for codec, t, m, mpx in rows:
        lines.append(f"| compose ({codec}) | {t:.1f} | {mpx / t:.1f} | {m:.0f} |")
    lines.append(f"| align | {t_align:.1f} | | {m_align:.0f} |")
    lines.append(f"| compose again, aligned (webp) | {t_re:.1f} | {mpx / t_re:.1f} | {m_re:.0f} |")
    lines.append(f"\nLoop error {loop.group(1)} -> {loop.group(2)} px; global RMS against ground truth after "
                 f"alignment {rms:.2f} px." if loop else f"\nalign: {r.stdout.strip()}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--big", action="store_true")
    ap.add_argument("--skip-survey", action="store_true")
    a = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    lines = ["| store | mosaic | tool | seconds (median) | output Mpx/s | peak RSS MB |", "|---|---|---|---|---|---|"]
    notes = []
    if a.big:
        big = make("g20.rolamos", 200000, 100000, 12288, 1024)
        t, m, mpx = compose(big, "jpeg")
        c = check(big)
        lines.append(f"| 20 GP grid, 162 patches of 12288² | {mpx:.0f} Mpx | rolamos compose (jpeg) | {t:.0f} (1 run) | "
                     f"{mpx / t:.1f} | {m:.0f} |")
        notes.append(f"The 20 GP mosaic against the seafloor: mean |difference| {c['mean_abs_diff']:.2f} grey levels "
                     f"over {c['windows']} windows.")
        # Interrupted after a third of the expected time, then resumed. (The complete mosaic is
        # removed first: compose keeps the old one until the new one is in place, and three
        # 20 GB copies do not fit this disk.)
        os.remove(os.path.join(big, "mosaic.tif"))
        p = subprocess.Popen([CLI, "compose", big, "-q", "--no-link", "--compression", "jpeg", "--restart"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(t / 3)
        p.send_signal(signal.SIGKILL)
        p.wait()
        r, t2, m2 = timed_checked([CLI, "compose", big, "-q", "--no-link", "--compression", "jpeg"])
        resumed = re.search(r"resumed: (\d+) of (\d+) chunks", r.stdout)
        notes.append(f"Killed (SIGKILL) after {t / 3:.0f} s and run again: {resumed.group(1)} of {resumed.group(2)} "
                     f"chunks were kept, and the rest took {t2:.0f} s." if resumed else
                     f"Killed and run again: {r.stdout.strip()}")
        print("\n".join(lines + notes), flush=True)
    small = make("g1.rolamos", 40000, 25000, 8192, 1024, georef=True)
    for codec in ("jpeg", "webp"):
        runs = [compose(small, codec) for _ in range(a.runs)]
        t = statistics.median(r[0] for r in runs)
        lines.append(f"| 1 GP grid, 8192² patches | {runs[0][2]:.0f} Mpx | rolamos compose ({codec}) | {t:.1f} | "
                     f"{runs[0][2] / t:.1f} | {max(r[1] for r in runs):.0f} |")
    c = check(small)
    t, m = gdalwarp(small, 1, timeout=600)
    lines.append(f"| same | | gdalwarp -multi + gdaladdo (JPEG, no blending) | {t:.1f} | {runs[0][2] / t:.1f} | {m:.0f} |"
                 if t else "| same | | gdalwarp -multi + gdaladdo (JPEG, no blending) | not finished in 600 s (stopped) | | |")
    print("\n".join(lines), flush=True)
    notes += [f"\nThe 1 GP mosaic against the seafloor it should show: mean |difference| {c['mean_abs_diff']:.2f} "
             f"grey levels over {c['windows']} random 256² windows."]
    report = "\n".join(lines + notes)
    if not a.skip_survey:
        extra = []
        survey1000(extra)
        report += "\n" + "\n".join(extra)
    print(report)
    open(os.path.join(OUT, "compose_scale.md"), "w").write(report + "\n")


if __name__ == "__main__":
    main()
