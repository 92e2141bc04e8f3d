#!/usr/bin/env python3
"""How far each video kind's codec moves its texture (build/codec_displacement_bench), beside the
engine's per-patch RMS on that video and on its JPEG frames, from a spread run
(bench/run_engine_spread.py --out DIR, whose surveys and results/NAME/KIND.json it reads: NAME is
the binary's name there, --names or its path).

The engine's error on video follows the codec's: what a codec moves together in a region of a frame
(cell_rms_px) is in the frame's content, and no tracker can see past it.

  bench/run_codec_displacement.py [--spread bench/out/spread] [--name after] [--frames 60] [--kinds video-1292,...]
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
    ap.add_argument("--name", default="", help="the engine's figures to show beside the codec's: a binary's name "
                    "in the spread run (its --names); needed when the spread holds several")
    a = ap.parse_args()
    base = os.path.join(a.spread, "results")
    names = sorted(os.listdir(base)) if os.path.isdir(base) else []
    if not a.name and len(names) > 1:
        sys.exit(f"{base} holds the figures of several engines ({', '.join(names)}): say which with --name")
    name = a.name or (names[0] if names else "")
    results = {}
    if name:
        if name not in names:
            sys.exit(f"{base} has no figures for an engine named {name!r} (it has: {', '.join(names) or 'none'})")
        for f in os.listdir(os.path.join(base, name)):
            results[f[:-len(".json")]] = json.load(open(os.path.join(base, name, f)))
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
