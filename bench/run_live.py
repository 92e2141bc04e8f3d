#!/usr/bin/env python3
"""Live mapping at a camera's rate: a feeder writes a survey's frames into a folder at a fixed
rate (each under a temporary name, then renamed, as loggers do) while `rolamos mosaic --live`
maps them; the run ends when the feed has been idle for a few seconds. Reports, per feed: frames
received, registered, rejected and skipped (arrived while the engine was busy), coverage lost
(skips after which the next frame taken did not join the one before), the most frames waiting
or in flight at once (the backlog; bound --max-waiting), patches, the latency from arrival to
integration (p50, p95; STORE/live/status.json), frames mapped while the engine shed load, the
placements' per-patch RMS against the survey's ground truth (bench/eval_mosaic.py), peak RSS.
Each run is printed as well as the medians: one feed varies from run to run where the engine is
about as fast as the feed.

The surveys are the spread's (bench/run_engine_spread.py writes them): still frames at 70 %
overlap fed at 10 frames/s (a stills camera is slower), and camera-rate frames (95 % overlap) fed
at 30 frames/s, at 800 x 600 and 1292 x 964. Two more stills feeds make recovery work: lanes that
do not overlap, and dim, degraded 640 x 480 frames.

  bench/run_live.py [--spread bench/out/spread] [--feeds name,...] [--frames 150] [--runs 3]
                    [--cli OLD,build/rolamos --names before,after] [--fps F] [--load 0.5]
                    [--mosaic-args "--max-waiting 6"]

--fps feeds every feed at F frames/s; --load keeps a busy loop beside the engine for that
fraction of a core (a vehicle's computer doing other work, or a slower machine).
"""
import argparse, json, multiprocessing, os, shutil, statistics, subprocess, sys, threading, time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import PYTHON, write_report  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# name: (spread kind whose frames are fed, frames per second)
FEEDS = {
    "stills-800-10fps": ("lawn-noturn", 10),
    "video-800-30fps": ("video-800", 30),
    "video-1292-30fps": ("video-1292", 30),
    # Lanes that do not overlap, and dim, degraded stills: frames that recovery must place (the
    # failure path runs on the engine's thread).
    "lanes-apart-10fps": ("lanes-apart", 10),
    "degraded-640-10fps": ("small-degraded", 10),
}


def feed(frames, folder, fps, done):
    os.makedirs(folder, exist_ok=True)
    start = time.monotonic()
    for i, f in enumerate(frames):
        tmp = os.path.join(folder, ".incoming")
        shutil.copyfile(f, tmp)
        os.rename(tmp, os.path.join(folder, os.path.basename(f)))
        # On the camera's clock, not the copy's: a slow copy does not slow the feed.
        wait = start + (i + 1) / fps - time.monotonic()
        if wait > 0:
            time.sleep(wait)
    done.set()


def placement_rms(survey, store):
    """Per-patch RMS against the survey's ground truth (bench/eval_mosaic.py), px; None, said on
    stderr, when the evaluation fails (a failure shown as 0 px once passed for a perfect map)."""
    r = subprocess.run([PYTHON, os.path.join(ROOT, "bench", "eval_mosaic.py"), survey, store],
                       capture_output=True, text=True)
    try:
        return json.loads(r.stdout.strip().splitlines()[-1])["rms_px"]
    except (ValueError, IndexError, KeyError):
        print(f"eval_mosaic.py {survey} {store} failed: {r.stderr.strip()[-300:]}", file=sys.stderr)
        return None


def one_run(cli, frames, fps, work, extra=(), survey=None):
    shutil.rmtree(work, ignore_errors=True)
    folder, store = os.path.join(work, "incoming"), os.path.join(work, "live.rolamos")
    os.makedirs(folder)
    done = threading.Event()
    proc = subprocess.Popen(["/usr/bin/time", "-f", "TIME %e %M", cli, "mosaic", folder, "-o", store, "--live",
                             "--idle-timeout", "3", "-q", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(0.5)  # the engine starts before the camera
    feeder = threading.Thread(target=feed, args=(frames, folder, fps, done))
    feeder.start()
    out, err = proc.communicate(timeout=600)
    feeder.join()
    if proc.returncode != 0:
        raise SystemExit(f"{cli} mosaic --live failed:\n{out}\n{err}")
    status = json.load(open(os.path.join(store, "live", "status.json")))
    rss = int(err.strip().split("TIME ")[-1].split()[1]) / 1024
    return dict(received=status["frames_received"], registered=status["frames_registered"],
                rejected=status["frames_rejected"], skipped=status["frames_skipped"],
                coverage_lost=status.get("coverage_lost", 0), backlog=status.get("backlog_max", 0),
                patches=status.get("patches", 0), shedding=status.get("frames_shedding", 0),
                rms=placement_rms(survey, store) if survey else None,
                p50=status.get("latency_ms_p50", 0), p95=status.get("latency_ms_p95", 0), rss=rss)


def median_of(values):
    """The median of the values measured (None: not measured); None when there are none."""
    known = [v for v in values if v is not None]
    return statistics.median(known) if known else None


def px(value):
    return "—" if value is None else f"{value:.2f}"


def hog(duty, stop):
    """A busy loop for `duty` of one core, in 50 ms periods: a vehicle's computer that does other
    work (navigation, logging), or a slower hour of this machine."""
    while not stop.is_set():
        t = time.monotonic()
        while time.monotonic() - t < 0.05 * duty:
            pass
        time.sleep(0.05 * (1 - duty))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spread", default=os.path.join(ROOT, "bench", "out", "spread"))
    ap.add_argument("--feeds", default=",".join(FEEDS))
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--mosaic-args", default="", help="more switches for mosaic, e.g. '--max-waiting 6'")
    ap.add_argument("--load", type=float, default=0,
                    help="a busy loop beside the engine for this fraction of one core (0.5: half a core)")
    ap.add_argument("--fps", type=float, default=0, help="feed every feed at this rate instead of its own")
    ap.add_argument("--cli", default=os.path.join(ROOT, "build", "rolamos"))
    ap.add_argument("--names", default="")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "live"))
    a = ap.parse_args()
    clis = a.cli.split(",")
    # The load in a process of its own: a thread of this script would share the feeder's lock.
    stop_load = multiprocessing.Event()
    if a.load > 0:
        multiprocessing.Process(target=hog, args=(a.load, stop_load), daemon=True).start()
    names = a.names.split(",") if a.names else [os.path.relpath(c, ROOT) for c in clis]
    lines = ["| feed | build | frames fed | received | registered | rejected | skipped | coverage lost | "
             "backlog max | patches | mapped shedding | RMS px | latency p50 / p95 ms | peak RSS MB |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in a.feeds.split(","):
        kind, fps = FEEDS[name]
        fps = a.fps or fps
        frames = sorted(os.path.join(a.spread, kind, "frames", f) for f in os.listdir(os.path.join(a.spread, kind, "frames")))
        frames = frames[: a.frames]
        if not frames:
            sys.exit(f"{a.spread}/{kind}/frames is empty: run bench/run_engine_spread.py --kinds {kind} first")
        results = {cli: [] for cli in clis}
        for _ in range(a.runs):
            for n, cli in enumerate(clis):  # interleaved: the machine's speed drifts
                r = one_run(cli, frames, fps, os.path.join(a.out, f"{name}.{n}"), a.mosaic_args.split(),
                            os.path.join(a.spread, kind))
                results[cli].append(r)
                # One feed varies between runs of one build: each run, not only the medians.
                print(f"  {name} {names[n]}: registered {r['registered']}, skipped {r['skipped']}, "
                      f"coverage lost {r['coverage_lost']}, patches {r['patches']}, mapped shedding {r['shedding']}, "
                      f"RMS {px(r['rms'])} px", flush=True)
        for n, cli in enumerate(clis):
            med = {k: median_of(r[k] for r in results[cli]) for k in results[cli][0]}
            load = f", {a.load:g} core busy beside" if a.load else ""
            lines.append(f"| {name} ({kind} at {fps:g} frames/s{load}) | {names[n]} | {len(frames)} | {med['received']:.0f} | "
                         f"{med['registered']:.0f} | {med['rejected']:.0f} | {med['skipped']:.0f} | "
                         f"{med['coverage_lost']:.0f} | {med['backlog']:.0f} | {med['patches']:.0f} | {med['shedding']:.0f} | "
                         f"{px(med['rms'])} | "
                         f"{med['p50']:.0f} / {med['p95']:.0f} | {med['rss']:.0f} |")
            print(lines[-1], flush=True)
    stop_load.set()
    write_report(lines, os.path.join(a.out, "live.md"))


if __name__ == "__main__":
    main()
