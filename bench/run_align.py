#!/usr/bin/env python3
"""Loop closure (issue 4): a 300-frame lawnmower survey over a Seattle ROV photo (lanes side by
side revisit the ground), mosaicked online, composed, then aligned; global RMS of every frame
against ground truth after one best-fit homography for the whole map, before and after
(bench/eval_global.py), for the affine and the similarity model; the time of each step; and
cv::Stitcher SCANS on the same frames (stopped after --peer-timeout seconds).

  bench/run_align.py [--frames 300] [--peer-timeout 300]
"""
from bench_common import timed, write_report
import argparse, glob, json, os, re, subprocess, sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
DATA = os.path.join(ROOT, "..", "shared", "data", "seattle_rov_gopro_large")
OUT = os.path.join(ROOT, "bench", "out", "align")


def evaluate(survey, store, online=False):
    r = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "bench", "eval_global.py"), survey, store] +
                       (["--online"] if online else []), capture_output=True, text=True, check=True)
    return json.loads(r.stdout)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--peer-timeout", type=int, default=300)
    a = ap.parse_args()
    photo = sorted(glob.glob(os.path.join(DATA, "*.JPG")))[0]
    os.makedirs(OUT, exist_ok=True)
    survey = os.path.join(OUT, f"survey{a.frames}")
    if not os.path.exists(os.path.join(survey, "ground_truth.json")):
        subprocess.run([CLI, "synth", photo, "-o", survey, "--frames", str(a.frames), "-q", "--seed", "3"], check=True)
    store = os.path.join(OUT, "s.rolamos")
    subprocess.run(["rm", "-rf", store])
    _, t_mosaic, m_mosaic = timed([CLI, "mosaic", "-q", os.path.join(survey, "frames"), "-o", store])
    _, t_compose, m_compose = timed([CLI, "compose", "-q", store, "--compression", "jpeg"])
    before = evaluate(survey, store, online=True)
    rows = [("online (chain of patches)", before, t_mosaic + t_compose, max(m_mosaic, m_compose))]
    for model in ("similarity", "affine"):
        r, t, m = timed([CLI, "align", "-q", store, "--model", model])
        pairs = re.search(r"(\d+) of (\d+) loop pairs matched, loop error ([\d.]+) -> ([\d.]+) px", r.stdout).groups()
        rows.append((f"after `rolamos align --model {model}` ({pairs[0]}/{pairs[1]} loop pairs, loop error "
                     f"{pairs[2]} -> {pairs[3]} px)", evaluate(survey, store), t, m))
    _, t_recompose, _ = timed([CLI, "compose", "-q", store, "--compression", "jpeg"])
    lines = [f"| placement | global RMS px | p95 px | max px | seconds | peak RSS MB |", "|---|---|---|---|---|---|"]
    for label, e, t, m in rows:
        lines.append(f"| {label} | {e['rms_px']:.2f} | {e['p95_px']:.2f} | {e['max_px']:.2f} | {t:.1f} | {m:.0f} |")
    lines.append(f"\nmosaic {t_mosaic:.1f} s, compose {t_compose:.1f} s, compose again after alignment {t_recompose:.1f} s.")
    peer = os.path.join(ROOT, "build", "stitcher_peer_bench")
    r, t, m = timed([peer, os.path.join(survey, "frames"), str(a.frames)], timeout=a.peer_timeout)
    if r is None:
        lines.append(f"cv::Stitcher SCANS on the same {a.frames} frames: not finished after {a.peer_timeout} s (stopped).")
    else:
        j = json.loads(r.stdout) if r.returncode == 0 else {"status": f"exit {r.returncode}", "used": 0, "width": 0, "height": 0}
        lines.append(f"cv::Stitcher SCANS on the same {a.frames} frames: {j['status']}, used {j['used']} frames, "
                     f"{j['width']} x {j['height']}, {t:.0f} s, peak RSS {m:.0f} MB.")
    write_report(lines, os.path.join(OUT, "align.md"))


if __name__ == "__main__":
    main()
