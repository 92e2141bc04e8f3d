#!/usr/bin/env python3
"""Colour (issue 15): a synthetic survey whose true seafloor colours are known, under the water's
colour, haze, a vignetting lens, the cone of the vehicle's lights and ~15 % exposure changes from
frame to frame; mosaicked with each colour step switched on in turn, then composed. For the patches
(median) and the mosaic: the low-pass colour error after one colour fit and the seam visibility
(bench/colour_bench.cc defines both), frames/s and compose Mpx/s (medians of --runs).

  bench/run_colour.py [--runs 3] [--out bench/out/colour] [--texture procedural|photo]
"""
import argparse, glob, json, os, re, shutil, statistics, subprocess, sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import timed, write_report  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
EVAL = os.path.join(ROOT, "build", "colour_bench")

SURVEY = ["--width", "800", "--height", "600", "--fov", "60", "--frames", "200", "--lanes", "4", "--overlap", "0.75",
          "--side-overlap", "0.35", "--light-cone", "0.5", "--exposure-jitter", "0.15", "--vignetting", "0.35",
          "--attenuation", "1", "--backscatter", "0.08", "--attitude-jitter", "0.5"]
# (label, mosaic flags, compose flags)
STEPS = [("none", ["--no-flat-field", "--no-exposure", "--no-water-colour"], ["--no-exposure"]),
         ("lighting (flat field)", ["--no-exposure", "--no-water-colour"], ["--no-exposure"]),
         ("lighting + exposure", ["--no-water-colour"], []),
         ("lighting + exposure + water colour (default)", [], []),
         ("default + multi-band compose", [], ["--blend", "multiband"])]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "colour"))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    survey = os.path.join(a.out, "survey")
    if not os.path.exists(os.path.join(survey, "ground_truth.json")):
        timed([CLI, "synth", "-o", survey, "-q"] + SURVEY, check=True)
    lines = ["| colour steps | patch colour error (median) | patch seam visibility | mosaic colour error | mosaic seam visibility | frames/s | compose Mpx/s |",
             "|---|---|---|---|---|---|---|"]
    for label, flags, compose_flags in STEPS:
        fps, mpx = [], []
        for _ in range(a.runs):
            store = os.path.join(a.out, "store.rolamos")
            shutil.rmtree(store, ignore_errors=True)
            r, _, _ = timed([CLI, "mosaic", os.path.join(survey, "frames"), "-o", store, "-q"] + flags, check=True)
            fps.append(float(re.search(r"\(([\d.]+) frames/s\)", r.stdout).group(1)))
            r, t, _ = timed([CLI, "compose", store, "-q", "--no-link"] + compose_flags, check=True)
            size = re.search(r"(\d+) x (\d+)", r.stdout)
            mpx.append(int(size.group(1)) * int(size.group(2)) / 1e6 / t if size else float("nan"))
        rows = [json.loads(l) for l in subprocess.run([EVAL, survey, store], capture_output=True, text=True,
                                                      check=True).stdout.splitlines()]
        patches = [x for x in rows if x["image"].startswith("patch") and "colour_error" in x]
        mosaic = next((x for x in rows if x["image"] == "mosaic"), {})
        lines.append(f"| {label} | {statistics.median(x['colour_error'] for x in patches):.1f} | "
                     f"{statistics.median(x['seam_visibility'] for x in patches):.2f} | "
                     f"{mosaic.get('colour_error', float('nan')):.1f} | {mosaic.get('seam_visibility', float('nan')):.2f} | "
                     f"{statistics.median(fps):.1f} | {statistics.median(mpx):.1f} |")
        print(lines[-1], flush=True)
        # The overview of the last run of each step, for the before/after pictures.
        subprocess.run([CLI, "export", store, "--scale", "0.08", "-o",
                        os.path.join(a.out, re.sub(r"\W+", "_", label.split(" (")[0]) + ".png")], capture_output=True)
    write_report(lines, os.path.join(a.out, "colour.md"))


if __name__ == "__main__":
    main()
