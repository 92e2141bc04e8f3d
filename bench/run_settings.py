#!/usr/bin/env python3
"""Settings of the engine compared on the spread's surveys, accuracy beside CPU: for each kind of
bench/run_engine_spread.py (and its other draws, --seeds), every setting in turn, then the next
kind (the machine's speed drifts over minutes: settings compared within a kind are run minutes
apart, not an hour). For each run: frames placed, per-patch RMS (bench/eval_mosaic.py), the
global RMS after `rolamos align` (bench/eval_global.py), the CPU seconds of `mosaic` (user +
system, all threads: on two busy cores frames/s follows CPU, and CPU moves less with the hour
than wall time does) and its engine frames/s. Then, against the first setting, the geometric
mean of each figure's ratio over the kinds and how many were better or worse by more than 2 %.

A setting is NAME=FLAGS (FLAGS for `rolamos mosaic`, space-separated; none for the defaults),
or NAME@CLI=FLAGS for another build's binary (its `align` too).

  bench/run_settings.py --kinds lawn-noturn,random --seeds 81 \\
      --setting 'default=' --setting 'points600=--still-track-points 600' [--out bench/out/settings]

Session 51 measured `--still-track-points 600`, `--no-sift-upsample` and
`--still-describe-overlap 0.5` this way (bench/RESULTS.md).
"""
import argparse, json, math, os, re, subprocess, sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import PYTHON, write_report  # noqa: E402
import run_engine_spread as spread  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def parse_setting(text, default_cli):
    """NAME=FLAGS or NAME@CLI=FLAGS -> (name, cli, flags)."""
    if "=" not in text:
        raise SystemExit(f"--setting {text!r}: expected NAME=FLAGS")
    head, flags = text.split("=", 1)
    name, cli = (head.split("@", 1) + [default_cli])[:2]
    if not os.path.exists(cli):
        raise SystemExit(f"--setting {text!r}: {cli} does not exist")
    return name, cli, flags.split()


def survey_of(out, kind):
    """KIND or KIND-sN -> (kind, survey folder, source), made as run_engine_spread.py makes it."""
    m = re.match(r"(.+)-s(\d+)$", kind)
    base, seed = (m.group(1), int(m.group(2))) if m and m.group(1) in spread.KINDS else (kind, None)
    if base not in spread.KINDS:
        raise SystemExit(f"unknown kind {kind!r} (bench/run_engine_spread.py's KINDS, -sN for another draw)")
    args = spread.KINDS[base][1] if seed is None else spread.with_seed(spread.KINDS[base][1], seed)
    return (base,) + spread.make_survey(out, base, args, seed, spread.CLI)


def run_one(cli, flags, base, survey, source, store):
    """mosaic, eval per patch, align, eval global: a dict of the figures."""
    subprocess.run(["rm", "-rf", store])
    cmd = [cli, "mosaic", source, "-o", store, "-q"] + spread.MOSAIC_FLAGS.get(base, []) + flags
    before = os.times()
    r = subprocess.run(cmd, capture_output=True, text=True)
    after = os.times()
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stdout}\n{r.stderr}")
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    fps = float(re.search(r"\(([\d.]+) frames/s\)", r.stdout).group(1))
    patch = json.loads(subprocess.run([PYTHON, os.path.join(HERE, "eval_mosaic.py"), survey, store], capture_output=True,
                                      text=True, check=True).stdout)
    a = subprocess.run([cli, "align", store, "-q"], capture_output=True, text=True)
    if a.returncode != 0:
        raise SystemExit(f"align {store} failed:\n{a.stdout}\n{a.stderr}")
    glob_ = json.loads(subprocess.run([PYTHON, os.path.join(HERE, "eval_global.py"), survey, store], capture_output=True,
                                      text=True, check=True).stdout)
    return dict(cpu=cpu, fps=fps, placed=patch["stitched"], frames=patch["frames"], patch=patch["rms_px"],
                glob=glob_["rms_px"], parts=glob_["components"])


def summary(results, names, kinds):
    """Geometric means of each figure's ratio to the first setting, with better/worse counts."""
    lines = []
    for name in names[1:]:
        parts = [f"**{name}** against {names[0]} over {len(kinds)} surveys:"]
        for key, label in (("patch", "per patch"), ("glob", "global"), ("cpu", "CPU")):
            ratios = [results[k][name][key] / results[k][names[0]][key] for k in kinds
                      if results[k][names[0]][key] and results[k][name][key]]
            if not ratios:
                continue
            geo = math.exp(sum(map(math.log, ratios)) / len(ratios))
            parts.append(f"{label} {geo:.3f} ({sum(r < 0.98 for r in ratios)} lower, {sum(r > 1.02 for r in ratios)} higher)")
        lines.append(" ".join(parts[:1]) + " " + ", ".join(parts[1:]))
    return lines


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--kinds", required=True, help="run_engine_spread.py's kinds, comma-separated")
    ap.add_argument("--seeds", default="", help="each kind drawn again with these --seed values too")
    ap.add_argument("--setting", action="append", required=True, help="NAME=FLAGS or NAME@CLI=FLAGS (repeat; "
                    "the first is what the others are compared with)")
    ap.add_argument("--out", default=os.path.join(spread.ROOT, "bench", "out", "settings"))
    a = ap.parse_args()
    if not spread.PHOTOS:
        sys.exit("../shared/data/seattle_rov_gopro_large is absent")
    settings = [parse_setting(s, spread.CLI) for s in a.setting]
    names = [s[0] for s in settings]
    if len(set(names)) != len(names):
        sys.exit("--setting names must differ")
    os.makedirs(a.out, exist_ok=True)
    seeds = [s.strip() for s in a.seeds.split(",") if s.strip()]
    kinds = [k + ("" if s is None else f"-s{s}") for k in a.kinds.split(",") for s in [None] + seeds]
    lines = ["| survey | setting | placed | per patch px | global px (parts) | CPU s | frames/s |",
             "|---|---|---|---|---|---|---|"]
    results = {}
    for kind in kinds:
        base, survey, source = survey_of(a.out, kind)
        for name, cli, flags in settings:
            r = run_one(cli, flags, base, survey, source, os.path.join(a.out, f"{kind}.{name}.rolamos"))
            results.setdefault(kind, {})[name] = r
            lines.append(f"| {kind} | {name} | {r['placed']} / {r['frames']} | {r['patch']:.3f} | {r['glob']:.3f} "
                         f"({r['parts']}) | {r['cpu']:.2f} | {r['fps']:.1f} |")
            print(lines[-1], flush=True)
    json.dump(results, open(os.path.join(a.out, "results.json"), "w"), indent=1)
    write_report(lines + [""] + summary(results, names, kinds), os.path.join(a.out, "settings.md"))


if __name__ == "__main__":
    main()
