#!/usr/bin/env python3
"""Object identification figures (issue 6): validation accuracy of `rolamos objects` trained on
the train split only (../shared/data/objects_deepdive_biota), per class, with the paper's plain
bag-of-words + chi-square SVM beside the default, and a HOG + linear SVM baseline in the same
run; training time, classification speed, and sliding-window detection speed over a mosaic.

  bench/run_objects.py [--out bench/out/objects]
"""
import argparse, json, os, re, statistics, subprocess, sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
BENCH = os.path.join(ROOT, "build", "objects_bench")
DATA = os.path.join(ROOT, "..", "shared", "data", "objects_deepdive_biota")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "objects"))
    a = ap.parse_args()
    if not os.path.isdir(os.path.join(DATA, "train")):
        sys.exit("../shared/data/objects_deepdive_biota is absent")
    os.makedirs(a.out, exist_ok=True)
    train, val = os.path.join(DATA, "train"), os.path.join(DATA, "validation")
    rows = []
    configs = [("rolamos default: VLAD (64 words) + RBF one-vs-all", [], True),
               ("rolamos --encoding bow --vocabulary 400 --kernel chi2 (the paper's BoW)",
                ["--encoding", "bow", "--vocabulary", "400", "--kernel", "chi2"], False),
               ("rolamos --encoding fisher --object-view --kernel linear (best on validation)",
                ["--encoding", "fisher", "--object-view", "--kernel", "linear"], False)]
    for label, flags, baseline in configs:
        r = subprocess.run([BENCH, train, val] + flags + ([] if baseline else ["--no-baseline"]),
                           capture_output=True, text=True, check=True)
        for line in r.stdout.strip().splitlines():
            j = json.loads(line)
            rows.append((label if "settings" in j else j["model"], j))
    classes = sorted(rows[0][1]["recall"].keys())
    lines = ["| model | validation accuracy | " + " | ".join(c.replace("_", " ") for c in classes) +
             " | train s | classify images/s |", "|---|---|" + "---|" * len(classes) + "---|---|"]
    for label, j in rows:
        ips = j.get("images_per_second", 282 / j["test_seconds"])
        lines.append(f"| {label} | {100 * j['accuracy']:.1f} % | " +
                     " | ".join(f"{100 * j['recall'][c]:.0f}" for c in classes) +
                     f" | {j['train_seconds']:.0f} | {ips:.0f} |")
    # Detection: the default model over a 10-megapixel store image, full resolution.
    model = os.path.join(a.out, "model.yml.gz")
    subprocess.run([CLI, "objects", "train", "-q", "--data", train, "-o", model], check=True, capture_output=True)
    store = os.path.join(a.out, "m10.rolamos")
    if not os.path.exists(store):
        subprocess.run([CLI, "demo", "-q", "--size", "3162", "-o", store], check=True, capture_output=True)
    rates = []
    for _ in range(3):
        r = subprocess.run(["/usr/bin/time", "-f", "TIME %e %M", CLI, "objects", "detect", "-q", store, "--model", model,
                            "--patch", "1", "--window", "256", "--stride", "0.5"], capture_output=True, text=True, check=True)
        m = re.search(r"(\d+) detections from (\d+) windows .*?, ([\d.]+) s \(([\d.]+) windows/s\)", r.stdout)
        rates.append((float(m.group(4)), int(m.group(2)), int(m.group(1)),
                      int(re.search(r"TIME [\d.]+ (\d+)", r.stderr).group(1)) / 1024))
    rate = statistics.median(x[0] for x in rates)
    lines += ["", f"Detection (`rolamos objects detect`, default model, 256-pixel windows at half-window stride over a "
                  f"3162 x 3162 image at full resolution, median of 3): {rates[0][1]} windows, {rate:.0f} windows/s "
                  f"({rate * 256 * 256 / 1e6 / 4:.1f} Mpx/s of map), peak RSS {statistics.median(x[3] for x in rates):.0f} MB."]
    report = "\n".join(lines)
    print(report)
    open(os.path.join(a.out, "objects.md"), "w").write(report + "\n")


if __name__ == "__main__":
    main()
