#!/usr/bin/env python3
"""How far each video kind's codec moves its texture (build/codec_displacement_bench), beside the
engine's per-patch RMS on that video and on its JPEG frames, from a spread run
(bench/run_engine_spread.py --out DIR, whose surveys and results.json it reads).

The engine's error on video follows the codec's: what a codec moves together in a region of a frame
(cell_rms_px) is in the frame's content, and no tracker can see past it.

  bench/run_codec_displacement.py [--spread bench/out/spread] [--frames 60] [--kinds video-1292,...]
"""
import argparse, json, os, subprocess, sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import write_report  # noqa: E402
from run_engine_spread import KINDS, ROOT, SAME_SURVEY  # noqa: E402

BENCH = os.path.join(ROOT, "build", "codec_displacement_bench")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spread", default=os.path.join(ROOT, "bench", "out", "spread"))
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--kinds", default=",".join(k for k, (_, a) in KINDS.items() if "--video" in a and k not in SAME_SURVEY))
    a = ap.parse_args()
    results = {}
    path = os.path.join(a.spread, "results.json")
    if os.path.exists(path):
        for per_kind in json.load(open(path)).values():  # the last binary's figures win
            results.update(per_kind)
    jpeg_of = {v: k for k, v in SAME_SURVEY.items()}
    fmt = lambda r: "–" if r is None else f"{r['rms_px']:.2f}"
    lines = ["| kind | codec | regions moved (cell RMS px) | single points (median px) | by raw contrast, lowest to highest quarter (median px) | engine per-patch RMS px | from its JPEG frames |",
             "|---|---|---|---|---|---|---|"]
    for kind in a.kinds.split(","):
        survey = os.path.join(a.spread, kind)
        if not os.path.exists(os.path.join(survey, "video.mp4")):
            print(f"{kind}: no survey in {a.spread} (run bench/run_engine_spread.py --out {a.spread} first)", file=sys.stderr)
            continue
        r = subprocess.run([BENCH, survey, str(a.frames)], capture_output=True, text=True, check=True)
        d = json.loads(r.stdout)
        codec = "H.264" if "h264" in KINDS[kind][1] else "MPEG-4"
        quarters = " / ".join(f"{q['median_px']:.2f}" for q in d["by_contrast"])
        lines.append(f"| {kind} | {codec} | {d['cell_rms_px']:.2f} | {d['point_median_px']:.2f} | {quarters} | "
                     f"{fmt(results.get(kind))} | {fmt(results.get(jpeg_of.get(kind)))} |")
        print(lines[-1], flush=True)
    write_report(lines, os.path.join(a.spread, "codec_displacement.md"))


if __name__ == "__main__":
    main()
