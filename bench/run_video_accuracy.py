#!/usr/bin/env python3
"""Per-patch accuracy of the engine on nine MPEG-4 videos at 800 x 600 (issue 27).

One video's per-patch RMS moves by 0.1-0.3 px with any change to the tracks or links the engine
keeps (a different random walk of the same size), so a change to the engine is judged on the mean
of nine: the three `video-800*` surveys of bench/run_engine_spread.py and six more over other
photos, seeds, fields of view, ground sampling and jitter. Accuracy only (two runs at a time):
speed is measured by run_engine_spread.py on a quiet machine.

  bench/run_video_accuracy.py [--cli OLD,build/rolamos --names before,after] [--jpeg] [-- extra mosaic flags]

--jpeg reads each survey's JPEG frames instead of its MPEG-4 file (no video codec).
"""
import argparse, concurrent.futures, json, os, statistics, subprocess, sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import PYTHON, write_report  # noqa: E402
from run_engine_spread import CLI, KINDS, PHOTOS, ROOT, synth_args  # noqa: E402

# The six surveys besides the spread's three: photo, field of view, ground sampling, attitude
# jitter (degrees), seed.
MORE = [(9, 60, 0.9, 0.2, 11), (2, 60, 0.9, 0.3, 12), (4, 70, 0.8, 0.2, 13),
        (6, 60, 1.0, 0.2, 14), (8, 65, 0.9, 0.3, 15), (1, 60, 0.9, 0.2, 16)]


def surveys():
    out = {k: synth_args(KINDS[k][1]) for k in ("video-800", "video-800-b", "video-800-c")}
    for i, (photo, fov, gsd, jitter, seed) in enumerate(MORE, 1):
        out[f"video-800-s{seed}"] = [PHOTOS[photo % len(PHOTOS)], "--width", "800", "--height", "600", "--frames", "300",
                                     "--fov", str(fov), "--lanes", "2", "--overlap", "0.95", "--gsd", str(gsd),
                                     "--attitude-jitter", str(jitter), "--tilt", "1", "--seed", str(seed),
                                     "--video", "video.mp4"]
    return out


def ensure(name, args, out_dir, cli):
    d = os.path.join(out_dir, name)
    stamp = os.path.join(d, "args.json")
    if not (os.path.exists(stamp) and json.load(open(stamp)) == args):
        subprocess.run([cli, "synth"] + args + ["-o", d, "-q"], check=True)
        json.dump(args, open(stamp, "w"))
    return d


def measure(cli, survey, store, jpeg, extra):
    source = os.path.join(survey, "frames") if jpeg else os.path.join(survey, "video.mp4")
    subprocess.run(["rm", "-rf", store], check=True)
    r = subprocess.run([cli, "mosaic", source, "-o", store, "-q"] + extra, capture_output=True, text=True)
    if r.returncode != 0:
        return {"error": (r.stderr or r.stdout).strip().splitlines()[-1:]}
    e = subprocess.run([PYTHON, os.path.join(ROOT, "bench", "eval_mosaic.py"), survey, store],
                       capture_output=True, text=True, check=True)
    return json.loads(e.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cli", default=CLI)
    ap.add_argument("--names", default="")
    ap.add_argument("--jpeg", action="store_true")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "spread"))
    ap.add_argument("extra", nargs="*")
    a = ap.parse_args()
    clis = a.cli.split(",")
    names = a.names.split(",") if a.names else clis
    os.makedirs(a.out, exist_ok=True)
    all_surveys = {n: ensure(n, args, a.out, clis[-1]) for n, args in surveys().items()}
    jobs = {}
    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
        for cli, label in zip(clis, names):
            for n, d in all_surveys.items():
                store = os.path.join(a.out, f"{n}.acc.{os.path.basename(label)}.rolamos")
                jobs[(label, n)] = pool.submit(measure, cli, d, store, a.jpeg, a.extra)
    lines = ["| survey | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    means = {label: [] for label in names}
    for n in all_surveys:
        row = []
        for label in names:
            r = jobs[(label, n)].result()
            if "rms_px" in r:
                means[label].append(r["rms_px"])
                row.append(f"{r['rms_px']:.2f} ({r['stitched']}/{r['frames']}, {r['keyframes']} keyframes)")
            else:
                row.append("failed: " + " ".join(r.get("error", [])))
        lines.append(f"| {n} | " + " | ".join(row) + " |")
    lines.append("| **mean** | " + " | ".join(f"**{statistics.mean(means[l]):.3f}**" if means[l] else "-"
                                            for l in names) + " |")
    source = "JPEG frames" if a.jpeg else "MPEG-4"
    write_report([f"Per-patch RMS px on nine 800 x 600 videos ({source}), bench/eval_mosaic.py", ""] + lines,
                 os.path.join(a.out, "video_accuracy.md"))


if __name__ == "__main__":
    main()
