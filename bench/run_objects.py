#!/usr/bin/env python3
"""Object identification figures (issue 6): validation accuracy of `rolamos objects` trained on
the train split only (../shared/data/objects_deepdive_biota), per class, for the default model and
the earlier ones (the paper's plain bag-of-words + chi-square SVM among them), with a HOG + linear
SVM baseline in the same run; training time, classification speed, and sliding-window detection
speed over a mosaic. Everything of rolamos is measured through its CLI.

  bench/run_objects.py [--out bench/out/objects] [--quick]   (--quick: the default model only)
"""
import argparse, json, os, re, statistics, sys

from bench_common import timed

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
BENCH = os.path.join(ROOT, "build", "objects_bench")
DATA = os.path.join(ROOT, "..", "shared", "data", "objects_deepdive_biota")

# The earlier models, spelt out (the defaults have changed since).
PLAIN = ["--no-object-view", "--no-colour-statistics", "--no-spatial-coordinates", "--orientations", "1",
         "--hue-bins", "12", "--saturation-bins", "4"]
CONFIGS = [
    ("rolamos default: Fisher vectors, object view, colour statistics, places, mirror (linear)", []),
    ("session 3: Fisher vectors + object view, HSV histograms (linear)",
     ["--no-colour-statistics", "--no-spatial-coordinates", "--orientations", "1", "--hue-bins", "12",
      "--saturation-bins", "4"]),
    ("session 2 default: VLAD (64 words) + RBF", ["--encoding", "vlad", "--kernel", "rbf"] + PLAIN),
    ("the paper's BoW: 400 words, chi-square kernel", ["--encoding", "bow", "--vocabulary", "400", "--kernel", "chi2"] + PLAIN),
]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "objects"))
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    if not os.path.isdir(os.path.join(DATA, "train")):
        sys.exit("../shared/data/objects_deepdive_biota is absent")
    os.makedirs(a.out, exist_ok=True)
    train, val = os.path.join(DATA, "train"), os.path.join(DATA, "validation")
    rows = []
    for i, (label, flags) in enumerate(CONFIGS[:1] if a.quick else CONFIGS):
        model = os.path.join(a.out, f"model{i}.yml.gz")
        _, train_s, train_mb = timed([CLI, "objects", "train", "-q", "--data", train, "-o", model] + flags, check=True)
        r, _, _ = timed([CLI, "objects", "eval", "-q", "--json", "--data", val, "--model", model], check=True)
        e = json.loads(r.stdout)
        rows.append((label, e["accuracy"], dict(zip(e["classes"], e["recall"])), train_s, e["images"] / e["seconds"],
                     e["classes"], e["confusion"]))
        print(f"{label}: {100 * e['accuracy']:.1f} %, train {train_s:.0f} s ({train_mb:.0f} MB)", file=sys.stderr)
    r, _, _ = timed([BENCH, train, val], check=True)
    h = json.loads(r.stdout)
    rows.append((h["model"], h["accuracy"], h["recall"], h["train_seconds"], 282 / h["test_seconds"], None, None))
    classes = sorted(rows[0][2].keys())
    lines = ["| model | validation accuracy | " + " | ".join(c.replace("_", " ") for c in classes) +
             " | train s | classify images/s |", "|---|---|" + "---|" * len(classes) + "---|---|"]
    for label, acc, recall, train_s, ips, _, _ in rows:
        lines.append(f"| {label} | {100 * acc:.1f} % | " + " | ".join(f"{100 * recall[c]:.0f}" for c in classes) +
                     f" | {train_s:.0f} | {ips:.1f} |")
    # The default model's confusion matrix (rows: truth, columns: prediction).
    names, confusion = rows[0][5], rows[0][6]
    lines += ["", "Default model, confusion on validation (rows: true class, columns: predicted):", "",
              "| | " + " | ".join(n.replace("_", " ") for n in names) + " |", "|---|" + "---|" * len(names)]
    for n, row in zip(names, confusion):
        lines.append(f"| {n.replace('_', ' ')} | " + " | ".join(str(v) for v in row) + " |")
    # Detection: the default model over a 10-megapixel store image, full resolution.
    model = os.path.join(a.out, "model0.yml.gz")
    store = os.path.join(a.out, "m10.rolamos")
    if not os.path.exists(store):
        timed([CLI, "demo", "-q", "--size", "3162", "-o", store], check=True)
    rates = []
    for _ in range(3):
        r, _, mb = timed([CLI, "objects", "detect", "-q", store, "--model", model, "--patch", "1", "--window", "256",
                          "--stride", "0.5"], check=True)
        m = re.search(r"(\d+) detections from (\d+) windows .*?, ([\d.]+) s \(([\d.]+) windows/s\)", r.stdout)
        rates.append((float(m.group(4)), int(m.group(2)), mb))
    rate = statistics.median(x[0] for x in rates)
    lines += ["", f"Detection (`rolamos objects detect`, default model, 256-pixel windows at half-window stride over a "
                  f"3162 x 3162 image at full resolution, median of 3): {rates[0][1]} windows, {rate:.1f} windows/s "
                  f"({rate * 256 * 256 / 1e6 / 4:.2f} Mpx/s of map), peak RSS {statistics.median(x[2] for x in rates):.0f} MB."]
    report = "\n".join(lines)
    print(report)
    open(os.path.join(a.out, "objects.md"), "w").write(report + "\n")


if __name__ == "__main__":
    main()
