#!/usr/bin/env python3
"""A vehicle that stops: a survey's frames with one frame held for a long run of identical frames.

The engine's memory must stay bounded by its patch budget whatever the input does; a vehicle
holding still makes no keyframe for as long as it stays. The survey's frames are listed in order
(a frame list, `rolamos mosaic LIST`), frame --at repeated --hold times, and mapped with and
without the hold, each binary of --cli in turn, --runs times (medians).

  bench/run_hold.py --survey bench/out/spread/video-800 --hold 1500 --runs 3 --cli A,B
"""
import argparse, os, re, statistics, subprocess, sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import timed, write_report  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def frame_list(frames_dir, at, hold, path):
    names = sorted(n for n in os.listdir(frames_dir) if n.lower().endswith((".jpg", ".jpeg", ".png", ".tif")))
    if not 0 <= at < len(names):
        sys.exit(f"--at {at}: {frames_dir} holds {len(names)} frames")
    paths = [os.path.join(frames_dir, n) for n in names]
    listed = paths[:at + 1] + [paths[at]] * hold + paths[at + 1:]
    with open(path, "w") as f:
        f.write("\n".join(listed) + "\n")
    return len(listed)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--survey", required=True, help="a survey made by rolamos synth (its frames/ folder is used)")
    ap.add_argument("--hold", type=int, default=1500, help="identical frames in the stop (1500: 50 s at 30 frames/s)")
    ap.add_argument("--at", type=int, default=100, help="the frame held")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--cli", default=os.path.join(ROOT, "build", "rolamos"), help="binaries, comma-separated")
    ap.add_argument("--names", default="")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "hold"))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    clis = a.cli.split(",")
    names = a.names.split(",") if a.names else clis
    frames_dir = os.path.join(a.survey, "frames")
    held = os.path.join(a.out, "held.txt")
    inputs = {"no stop": (frames_dir, len(os.listdir(frames_dir))),
              f"{a.hold} frames held": (held, frame_list(frames_dir, a.at, a.hold, held))}
    lines = [f"Survey {a.survey}, frame {a.at} held; medians of {a.runs} run(s)", "",
             "| input | build | frames placed | frames/s | peak RSS MB |", "|---|---|---|---|---|"]
    for label, (source, total) in inputs.items():
        for n, cli in enumerate(clis):
            fps, rss, placed = [], [], 0
            for _ in range(a.runs):
                store = os.path.join(a.out, f"hold.{n}.rolamos")
                subprocess.run(["rm", "-rf", store])
                r, _, m = timed([cli, "mosaic", source, "-o", store, "-q"], check=True)
                fps.append(float(re.search(r"\(([\d.]+) frames/s\)", r.stdout).group(1)))
                placed = int(re.search(r"(\d+) stitched", r.stdout).group(1))
                rss.append(m)
            lines.append(f"| {label} | {names[n]} | {placed} / {total} | {statistics.median(fps):.1f} | "
                         f"{statistics.median(rss):.0f} |")
            print(lines[-1], flush=True)
    write_report(lines, os.path.join(a.out, "hold.md"))


if __name__ == "__main__":
    main()
