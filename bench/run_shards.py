#!/usr/bin/env python3
"""Compose split into shards (issue 17): one synthetic store (build/compose_scale_bench, the same
stores as run_compose_scale.py) composed by one process, and as N shards run one after the other on
this machine (each as a cluster node would: its own process, --threads 0 = all cores) then
--finish. Reports the overhead of sharding (sum of shard and finish times against one process),
each shard's time, and a model of the wall time on K nodes:

    T(K) = max over nodes of the shards it runs (shards dealt out in turn) + finish

built from the measured shard times. Also the merge of two dives' stores (rolamos merge).

  bench/run_shards.py [--size 40000x25000] [--shards 8] [--runs 3]
"""
import argparse, os, re, statistics, subprocess, sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import timed  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
MAKE = os.path.join(ROOT, "build", "compose_scale_bench")
OUT = os.path.join(ROOT, "bench", "out", "shards")


def make(width, height):
    store = os.path.join(OUT, f"s{width}x{height}.rolamos")
    if not os.path.exists(os.path.join(store, "store.json")):
        subprocess.run(["rm", "-rf", store])
        subprocess.run([MAKE, "make", "--width", str(width), "--height", str(height), "--patch", "8192",
                        "--overlap", "1024", "-o", store], check=True, stderr=subprocess.DEVNULL)
    return store


def run(cmd):
    r, t, m = timed(cmd, check=True)
    return r, t, m


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="40000x25000")
    ap.add_argument("--shards", type=int, default=8)
    ap.add_argument("--runs", type=int, default=3)
    a = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    w, h = map(int, a.size.split("x"))
    store = make(w, h)
    flags = ["--no-link", "--compression", "jpeg", "-q"]
    one, sharded, finish, per_shard, rss = [], [], [], [], []
    for _ in range(a.runs):
        subprocess.run(["rm", "-rf", os.path.join(store, "mosaic.tif"), os.path.join(store, "mosaic.tif.partial")])
        r, t, m = run([CLI, "compose", store, "--restart", *flags])
        mw, mh = map(int, re.search(r"mosaic.tif: (\d+) x (\d+)", r.stdout).groups())
        mpx = mw * mh / 1e6
        one.append(t)
        os.rename(os.path.join(store, "mosaic.tif"), os.path.join(OUT, "one.tif"))
        times = []
        for i in range(1, a.shards + 1):
            _, t, m = run([CLI, "compose", store, "--shard", f"{i}/{a.shards}", *flags])
            times.append(t)
            rss.append(m)
        _, tf, m = run([CLI, "compose", store, "--finish", *flags])
        rss.append(m)
        finish.append(tf)
        per_shard.append(times)
        sharded.append(sum(times) + tf)
        same = subprocess.run(["cmp", "-s", os.path.join(OUT, "one.tif"), os.path.join(store, "mosaic.tif")]).returncode == 0
        if not same:
            sys.exit("the sharded mosaic differs from the one-process one")
    med = statistics.median
    shard_med = [med(r[i] for r in per_shard) for i in range(a.shards)]
    lines = [f"store {w} x {h} ({w * h / 1e9:.2f} gigapixels of patches; mosaic {mpx:.0f} Mpx), JPEG, {a.shards} shards, "
             f"median of {a.runs} runs; the sharded mosaic equals the one-process one byte for byte in every run", "",
             "| | seconds | Mpx/s |", "|---|---|---|",
             f"| one process | {med(one):.1f} | {mpx / med(one):.1f} |",
             f"| {a.shards} shards one after the other + finish | {med(sharded):.1f} | {mpx / med(sharded):.1f} |",
             f"| of which finish (upper levels, file layout) | {med(finish):.1f} | |",
             f"| overhead of sharding | {100 * (med(sharded) / med(one) - 1):+.1f} % | |", "",
             "shard seconds: " + ", ".join(f"{t:.1f}" for t in shard_med) + f"; peak RSS of any shard or finish {max(rss):.0f} MB", "",
             "| nodes K | modelled wall time s | speed-up |", "|---|---|---|"]
    for k in (1, 2, 4, 8, 16):
        nodes = [sum(shard_med[i] for i in range(n, a.shards, k)) for n in range(min(k, a.shards))]
        t = max(nodes) + med(finish)
        lines.append(f"| {k} | {t:.1f} | {med(one) / t:.2f} |")
    # The merge of two dives' stores: two halves of the same synthetic survey.
    dives = os.path.join(OUT, "dives")
    if not os.path.exists(os.path.join(dives, "b.rolamos", "store.json")):
        subprocess.run(["rm", "-rf", dives])
        subprocess.run([CLI, "synth", "-q", "-o", os.path.join(dives, "survey"), "--frames", "200", "--lanes", "4",
                        "--width", "800", "--height", "600"], check=True)
        frames = sorted(os.listdir(os.path.join(dives, "survey", "frames")))
        for name, part in (("a", frames[:100]), ("b", frames[100:])):
            d = os.path.join(dives, name)
            os.makedirs(d, exist_ok=True)
            for f in part:
                os.symlink(os.path.join(dives, "survey", "frames", f), os.path.join(d, f))
            subprocess.run([CLI, "mosaic", "-q", d, "-o", os.path.join(dives, name + ".rolamos")], check=True,
                           stdout=subprocess.DEVNULL)
    merge_t, align_t, parts = [], [], ""
    for _ in range(a.runs):
        merged = os.path.join(dives, "merged.rolamos")
        subprocess.run(["rm", "-rf", merged])
        _, t, _ = run([CLI, "merge", "-q", os.path.join(dives, "a.rolamos"), os.path.join(dives, "b.rolamos"), "-o", merged])
        merge_t.append(t)
        r, t, m = run([CLI, "align", "-q", merged])
        align_t.append(t)
        parts = re.search(r"(\d+ frames in \d+ parts?)", r.stdout).group(1)
    lines += ["", f"merge of two dives (100 + 100 frames, 800 x 600): merge {med(merge_t):.2f} s (files hard-linked), "
              f"then align {med(align_t):.1f} s: {parts}"]
    text = "\n".join(lines)
    print(text)
    with open(os.path.join(OUT, "shards.md"), "w") as f:
        f.write(text + "\n")


if __name__ == "__main__":
    main()
