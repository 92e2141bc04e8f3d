#!/usr/bin/env python3
"""Object identification measured the way an unseen split would measure it (issue 25).

Classification (../shared/data/objects_deepdive_biota): train and validation joined, repeated
stratified k-fold cross-validation of the default model (`rolamos objects validate --data TRAIN
--data VALIDATION`), mean and spread over folds, pooled per-class recall; the HOG + linear SVM
peer (build/objects_bench --cross-validate) on the same folds.

Detection (../shared/data/objects_nephrops_burrows): station-wise cross-validation (`rolamos
objects validate --boxes`), AP50, precision and recall pooled and per fold, ours ("cells") and the
HOG + SVM peer ("hog") through the same training and search; then the model trained on every
frame runs over mosaics of two sizes (`rolamos objects detect STORE`): Mpx/s of map and peak RSS.

  bench/run_objects_validation.py [--skip-classification] [--skip-detection] [--folds 5] [--repeats 1]
                                  [--stores A.rolamos,B.rolamos] [--out bench/out/objects_validation]
"""
import argparse, json, os, sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import timed, write_report  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
PEER = os.path.join(ROOT, "build", "objects_bench")
BIOTA = os.path.join(ROOT, "..", "shared", "data", "objects_deepdive_biota")
BURROWS = os.path.join(ROOT, "..", "shared", "data", "objects_nephrops_burrows")


def classification(a, lines):
    dirs = [os.path.join(BIOTA, "train"), os.path.join(BIOTA, "validation")]
    r, secs, mb = timed([CLI, "objects", "validate", "-q", "--json", "--validation-folds", str(a.folds),
                         "--repeats", str(a.repeats)] + sum((["--data", d] for d in dirs), []), check=True)
    v = json.loads(r.stdout)
    p, psecs, _ = timed([PEER, "--cross-validate", str(a.folds), "--repeats", str(a.repeats)] + dirs, check=True)
    h = json.loads(p.stdout)
    lines += ["", f"Classification, {v['images']} images (train + validation), {a.folds} stratified folds x {a.repeats} repeats:", "",
              "| model | cross-validated accuracy (mean ± spread) | folds | " + " | ".join(c.replace('_', ' ') for c in v["classes"]) + " | s |",
              "|---|---|---|" + "---|" * len(v["classes"]) + "---|",
              f"| rolamos default | {100 * v['mean']:.1f} % ± {100 * v['spread']:.1f} | " +
              ", ".join(f"{100 * x:.1f}" for x in v["fold_accuracy"]) + " | " +
              " | ".join(f"{100 * x:.0f}" for x in v["recall"]) + f" | {secs:.0f} |",
              f"| HOG + linear SVM (same folds) | {100 * h['mean']:.1f} % ± {100 * h['spread']:.1f} | " +
              ", ".join(f"{100 * x:.1f}" for x in h["fold_accuracy"]) + " | " + " | ".join("-" for _ in v["classes"]) + f" | {psecs:.0f} |"]
    print("\n".join(lines[-5:]), flush=True)


def detection(a, lines):
    if a.model:
        return search(a, lines, a.model)
    lines += ["", "Detection of burrows, station-wise cross-validation (frames of a station never in both training and validation):", "",
              "| features | pooled AP50 | precision | recall | F1 | per fold AP50 (P, R) [stations, frames] | train s | detect Mpx/s |",
              "|---|---|---|---|---|---|---|---|"]
    for features in ("cells", "hog"):
        r, secs, mb = timed([CLI, "objects", "validate", "-q", "--json", "--boxes", BURROWS, "--validation-folds", "3",
                             "--features", features, "--label", "burrow"], check=True)
        v = json.loads(r.stdout)
        folds = "; ".join(f"{f['ap50']:.3f} ({f['precision']:.2f}, {f['recall']:.2f}) [{len(f['stations'])}, {f['images']}]" for f in v["folds"])
        lines.append(f"| {features} | {v['ap50']:.3f} | {v['precision']:.3f} | {v['recall']:.3f} | {v['f1']:.3f} | {folds} | "
                     f"{v['seconds_train']:.0f} | {v['megapixels_per_second']:.2f} |")
        print(lines[-1], flush=True)
    model = a.model or os.path.join(a.out, "burrows.yml.gz")
    if not a.model:
        r, secs, mb = timed([CLI, "objects", "train", "-q", "--boxes", BURROWS, "-o", model, "--label", "burrow"], check=True)
        lines += ["", f"The model on all 230 frames: trained in {secs:.0f} s, peak {mb:.0f} MB. " + r.stdout.strip(), ""]
    search(a, lines, model)


def search(a, lines, model):
    if a.stores:
        lines += ["| mosaic | Mpx of map | detections | s (median of 3) | Mpx/s | peak RSS MB |", "|---|---|---|---|---|---|"]
        for spec in a.stores.split(","):
            store, _, patch = spec.partition(":")  # STORE or STORE:PATCH
            runs = []
            for _ in range(3):
                out = os.path.join(a.out, os.path.basename(store.rstrip("/")) + ".geojson")
                r, secs, mb = timed([CLI, "objects", "detect", store, "--model", model, "-q", "-o", out,
                                     "--patch", patch or "0"], check=True)
                mpx = float(r.stdout.split(" over ")[1].split(" Mpx")[0])
                runs.append((secs, mb, mpx, int(r.stdout.split(": ")[1].split(" detections")[0])))
            runs.sort()
            secs, mb, mpx, n = runs[1]
            lines.append(f"| {os.path.basename(store.rstrip('/'))}{' patch ' + patch if patch else ''} | {mpx:.0f} | {n} | {secs:.1f} | {mpx / secs:.2f} | {max(r[1] for r in runs):.0f} |")
            print(lines[-1], flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "objects_validation"))
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--skip-classification", action="store_true")
    ap.add_argument("--skip-detection", action="store_true")
    ap.add_argument("--stores", default="", help="stores with a composed mosaic to search (comma-separated; STORE:N "
                    "searches patch N)")
    ap.add_argument("--model", default="", help="search with this box detector instead of training one (skips the validation)")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    lines = ["# Object identification, validated (issue 25)"]
    if not a.skip_detection:
        if not os.path.isdir(os.path.join(BURROWS, "images")):
            sys.exit("../shared/data/objects_nephrops_burrows is absent")
        detection(a, lines)
    if not a.skip_classification:
        if not os.path.isdir(os.path.join(BIOTA, "train")):
            sys.exit("../shared/data/objects_deepdive_biota is absent")
        classification(a, lines)
    write_report(lines, os.path.join(a.out, "objects_validation.md"))


if __name__ == "__main__":
    main()
