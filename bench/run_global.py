#!/usr/bin/env python3
"""The global map (issue 14) on surveys of 300, 1,000 and 10,000 frames: random walks with
revisits and lawnmowers with and without turn frames (800 x 600, 60 degrees, roll and pitch
jittered per frame). For each: the README workflow `mosaic`, `align`, `compose`; frames in the
map, global RMS against ground truth (bench/eval_global.py: every frame's 3 x 3 grid after one
best-fit homography for the whole map), time and peak RSS of each step. Peers on the 300-frame
survey: COLMAP 3.8 (CPU SIFT, sequential matcher, mapper; its camera poses projected onto the
seafloor plane fitted to its points) and cv::Stitcher SCANS.

  bench/run_global.py [--kinds random-300,lawn-1000,...] [--peers] [--navigation SIGMA_M] [--cli build/rolamos]
                      [--out bench/out/global]
"""
import argparse, glob, json, os, shutil, subprocess, sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_common import PYTHON, timed, write_report  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")
PHOTOS = sorted(glob.glob(os.path.join(ROOT, "..", "shared", "data", "seattle_rov_gopro_large", "*.JPG")))

CAMERA = ["--width", "800", "--height", "600", "--fov", "60", "--attitude-jitter", "1", "--tilt", "1",
          "--altitude-jitter", "0.05", "--overlap", "0.7", "--side-overlap", "0.4"]
KINDS = {
    "random-300": ("random walk with revisits, 300 frames, real photo",
                   ["PHOTO2", "--frames", "300", "--path", "random", "--max-turn", "40", "--gsd", "0.9"] + CAMERA),
    "lawn-1000": ("lawnmower, 24 lanes joined without turns, 984 frames, real photos",
                  ["PHOTO1,PHOTO2,PHOTO3", "--frames", "984", "--lanes", "24", "--no-turns", "--gsd", "0.9"] + CAMERA),
    "lawn-turns-1000": ("lawnmower with turn frames, 1,000 frames, procedural seafloor",
                        ["--frames", "1000", "--lanes", "16"] + CAMERA),
    "lawn-10000": ("lawnmower, 80 lanes joined without turns, 10,000 frames, procedural seafloor",
                   ["--frames", "10000", "--lanes", "80", "--no-turns"] + CAMERA),
    # Look-alike ground: the bottom-right quarter of the world repeats the top-left one turned 180
    # degrees; frames over the two match at the wrong place.
    "repeat-300": ("random walk with revisits, 300 frames, a quarter repeated turned 180 deg",
                   ["--frames", "300", "--path", "random", "--max-turn", "40", "--gsd", "0.9", "--repeat", "rotate"] + CAMERA),
    "repeat-1000": ("lawnmower, 24 lanes joined without turns, 984 frames, a quarter repeated turned 180 deg",
                    ["--frames", "984", "--lanes", "24", "--no-turns", "--gsd", "0.9", "--repeat", "rotate"] + CAMERA),
    "repeat-10000": ("lawnmower, 80 lanes joined without turns, 10,000 frames, a quarter repeated turned 180 deg",
                     ["--frames", "10000", "--lanes", "80", "--no-turns", "--repeat", "rotate"] + CAMERA),
    # Session 21: a wide lens the engine is not told of (90 degrees; it assumes 70) on a vehicle that
    # rolls and pitches by 3 degrees anew at every frame: the patches must find the focal length,
    # and align must not take a pitched first frame's image plane for the seafloor's.
    "jitter-wide-120": ("lawnmower 800 x 600, 90 deg (not told), roll and pitch jittered by 3 deg a frame, 120 frames",
                        ["PHOTO2", "--width", "800", "--height", "600", "--fov", "90", "--frames", "120", "--lanes", "4",
                         "--overlap", "0.7", "--side-overlap", "0.3", "--gsd", "0.8", "--attitude-jitter", "3",
                         "--tilt", "2", "--seed", "21"]),
    "jitter-wide-1292": ("lawnmower 1292 x 964, 80 deg (not told), roll and pitch jittered by 3 deg a frame, 100 frames",
                         ["PHOTO2", "--width", "1292", "--height", "964", "--fov", "80", "--frames", "100", "--lanes", "3",
                          "--overlap", "0.75", "--side-overlap", "0.3", "--gsd", "0.7", "--attitude-jitter", "3",
                          "--tilt", "2", "--seed", "22"]),
}


def synth_args(args):
    out = []
    for a in args:
        out.append(",".join(PHOTOS[int(p[5:]) % len(PHOTOS)] for p in a.split(",")) if a.startswith("PHOTO") else a)
    return out


def survey_dir(out, kind):
    d = os.path.join(out, kind)
    stamp = os.path.join(d, "args.json")
    args = KINDS[kind][1]
    if not os.path.exists(stamp) or json.load(open(stamp)) != args:
        shutil.rmtree(d, ignore_errors=True)
        timed([CLI, "synth"] + synth_args(args) + ["-o", d, "-q"], check=True)
        json.dump(args, open(stamp, "w"))
    return d


def frames_in_map(store, total):
    m = json.load(open(os.path.join(store, "store.json")))
    placed = 0
    for p in m["patches"]:
        s = json.load(open(os.path.join(store, p["sidecar"])))
        placed += sum(1 for f in s["frames"] if "frame_to_global" in f)
    return placed / total


def colmap_peer(survey, work):
    """COLMAP 3.8 on the survey's frames; its poses onto the plane of its points; RMS like ours."""
    if not shutil.which("colmap"):
        return None
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    db, sparse = os.path.join(work, "db.db"), os.path.join(work, "sparse")
    os.makedirs(sparse)
    frames = os.path.join(survey, "frames")
    steps = [["colmap", "feature_extractor", "--database_path", db, "--image_path", frames,
              "--ImageReader.single_camera", "1", "--ImageReader.camera_model", "PINHOLE",
              "--SiftExtraction.use_gpu", "0", "--SiftExtraction.num_threads", "2"],
             ["colmap", "sequential_matcher", "--database_path", db, "--SiftMatching.use_gpu", "0",
              "--SiftMatching.num_threads", "2", "--SequentialMatching.overlap", "10"],
             ["colmap", "mapper", "--database_path", db, "--image_path", frames, "--output_path", sparse,
              "--Mapper.num_threads", "2"]]
    seconds, rss = 0.0, 0.0
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen")
    for cmd in steps:
        r = subprocess.run(["/usr/bin/time", "-f", "TIME %e %M"] + cmd, capture_output=True, text=True, env=env)
        t, m = r.stderr.strip().split("TIME ")[-1].split()
        seconds += float(t)
        rss = max(rss, int(m) / 1024)
        if r.returncode != 0:
            return {"error": cmd[1] + " failed", "seconds": seconds, "rss": rss}
    models = sorted(glob.glob(os.path.join(sparse, "*")))
    if not models:
        return {"error": "no model", "seconds": seconds, "rss": rss}
    # Every model COLMAP made (it splits where it cannot connect frames); the largest is measured.
    best, counts = None, []
    for k, m in enumerate(models):
        txt = os.path.join(work, f"txt{k}")
        os.makedirs(txt)
        subprocess.run(["colmap", "model_converter", "--input_path", m, "--output_path", txt, "--output_type", "TXT"],
                       capture_output=True, env=env)
        n = sum(1 for l in open(os.path.join(txt, "images.txt")) if not l.startswith("#")) // 2
        counts.append(n)
        if best is None or n > best[0]:
            best = (n, txt)
    e = json.loads(subprocess.run([PYTHON, os.path.join(ROOT, "bench", "eval_colmap.py"), survey, best[1]],
                                  capture_output=True, text=True).stdout)
    e.update(seconds=seconds, rss=rss, models=len(counts), in_models=sum(counts))
    return e


def main():
    global CLI
    ap = argparse.ArgumentParser()
    ap.add_argument("--kinds", default="random-300,lawn-1000,lawn-turns-1000")
    ap.add_argument("--peers", action="store_true", help="COLMAP and cv::Stitcher on the 300-frame survey")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out", "global"))
    ap.add_argument("--navigation", type=float, default=0, metavar="SIGMA_M",
                    help="also align each survey with navigation made from its ground truth, each centre moved by "
                    "Gaussian noise of SIGMA_M metres (bench/nav_from_truth.py: 1 cm a world pixel)")
    ap.add_argument("--align-before", default="", help="another rolamos whose align runs on a copy of the same "
                    "mosaicked store, in the same run (a before/after of align alone)")
    ap.add_argument("--cli", default=CLI, help="the rolamos to measure (default: build/rolamos)")
    a = ap.parse_args()
    CLI = os.path.abspath(a.cli)
    os.makedirs(a.out, exist_ok=True)
    lines = ["| survey | frames in the map | global RMS px (p95, max) | mosaic s / MB | align s / MB | compose s / MB | end to end s | parts |",
             "|---|---|---|---|---|---|---|---|"]
    for kind in a.kinds.split(","):
        desc = KINDS[kind][0]
        survey = survey_dir(a.out, kind)
        total = len(json.load(open(os.path.join(survey, "ground_truth.json")))["frames"])
        store = os.path.join(a.out, kind + ".rolamos")
        shutil.rmtree(store, ignore_errors=True)
        _, tm, mm = timed([CLI, "mosaic", os.path.join(survey, "frames"), "-o", store, "-q"], check=True)
        r, ta, ma = timed([CLI, "align", store, "-q"], check=True)
        parts = r.stdout.strip().splitlines()[-1].split(" frames in ")[1].split(" part")[0]
        _, tc, mc = timed([CLI, "compose", store, "-q", "--no-link"], check=True)
        e = json.loads(subprocess.run([PYTHON, os.path.join(ROOT, "bench", "eval_global.py"), survey, store],
                                      capture_output=True, text=True, check=True).stdout)
        share = frames_in_map(store, total)
        lines.append(f"| {kind}: {desc} | {100 * share:.1f} % ({round(share * total)} / {total}) | "
                     f"{e['rms_px']:.2f} ({e['p95_px']:.2f}, {e['max_px']:.1f}) | {tm:.0f} / {mm:.0f} | {ta:.0f} / {ma:.0f} | "
                     f"{tc:.0f} / {mc:.0f} | {tm + ta + tc:.0f} | {parts} |")
        print(lines[-1], flush=True)
        print("    " + "\n    ".join(r.stdout.strip().splitlines()[-8:-1]), flush=True)
        if a.navigation > 0:
            nav_store, csv = store + ".nav", os.path.join(a.out, kind + ".nav.csv")
            shutil.rmtree(nav_store, ignore_errors=True)
            subprocess.run(["cp", "-al", store, nav_store], check=True)
            subprocess.run([PYTHON, os.path.join(ROOT, "bench", "nav_from_truth.py"), survey, csv, "--sigma",
                            str(a.navigation)], check=True)
            rn, tn, mn = timed([CLI, "align", nav_store, "-q", "--navigation", csv, "--navigation-sigma",
                                str(a.navigation)], check=True)
            en = json.loads(subprocess.run([PYTHON, os.path.join(ROOT, "bench", "eval_global.py"), survey, nav_store],
                                           capture_output=True, text=True, check=True).stdout)
            lines.append(f"| {kind}, aligned with navigation ({a.navigation:g} m noise) | | "
                         f"{en['rms_px']:.2f} ({en['p95_px']:.2f}, {en['max_px']:.1f}) | | {tn:.0f} / {mn:.0f} | | | |")
            print(lines[-1], flush=True)
            print("    " + "\n    ".join(rn.stdout.strip().splitlines()[-8:-1]), flush=True)
        if a.align_before:
            before = store + ".before"
            shutil.rmtree(before, ignore_errors=True)
            shutil.copytree(store, before)
            rb, tb, mb = timed([a.align_before, "align", before, "-q"], check=True)
            eb = json.loads(subprocess.run([PYTHON, os.path.join(ROOT, "bench", "eval_global.py"), survey, before],
                                           capture_output=True, text=True, check=True).stdout)
            lines.append(f"| {kind}, align of {os.path.relpath(a.align_before, ROOT)} on the same store | | "
                         f"{eb['rms_px']:.2f} ({eb['p95_px']:.2f}, {eb['max_px']:.1f}) | | {tb:.0f} / {mb:.0f} | | | |")
            print(lines[-1], flush=True)
        if a.peers and kind == "random-300":
            c = colmap_peer(survey, os.path.join(a.out, "colmap"))
            if c:
                rms = f"{c['rms_px']:.2f} ({c['p95_px']:.2f}, {c['max_px']:.1f})" if "rms_px" in c else c.get("error", "-")
                frames = (f"{c.get('registered', 0)} / {total} in its largest model "
                          f"({c.get('in_models', 0)} in {c.get('models', 0)} separate models)")
                lines.append(f"| {kind}: COLMAP 3.8 (CPU SIFT, sequential matcher, mapper) | {frames} | {rms} | "
                             f"{c['seconds']:.0f} / {c['rss']:.0f} (all steps) | - | - | {c['seconds']:.0f} | - |")
                print(lines[-1], flush=True)
            peer = os.path.join(ROOT, "build", "stitcher_peer_bench")
            r2, ts, ms = timed([peer, os.path.join(survey, "frames"), "300"], timeout=1800)
            if r2 is None:
                lines.append(f"| {kind}: cv::Stitcher SCANS | did not finish in 30 min | - | - | - | - | - | - |")
            else:
                j = json.loads(r2.stdout)
                lines.append(f"| {kind}: cv::Stitcher SCANS | {j['used']} / {total} | no per-frame placement | "
                             f"{ts:.0f} / {ms:.0f} | - | - | {ts:.0f} | {j['status']} |")
            print(lines[-1], flush=True)
    write_report(lines, os.path.join(a.out, "global.md"))


if __name__ == "__main__":
    main()
