#!/usr/bin/env python3
"""Tile server figures (issue 5), with wrk on loopback: 256 x 256 JPEG tiles at full resolution
from a 10-megapixel and a 10-gigapixel image, warm (a working set already in the cache: what a
viewer asks for while panning) and cold (random tiles anywhere: each one decoded from the file),
then a 60-second soak of cold requests with the server's RSS sampled every second against the
cache limit. wrk runs on the same 2 cores as the server.

  bench/run_serve_scale.py SMALL_STORE BIG_STORE [--seconds 10] [--soak 60] [--cache-mb 256]
The image served is the store's mosaic when it has one, else patch 1.
"""
import argparse, json, os, re, statistics, subprocess, sys, time, urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "build", "rolamos")


def start(store, port, cache_mb):
    p = subprocess.Popen([CLI, "serve", store, "--port", str(port), "--cache-mb", str(cache_mb)],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    for _ in range(100):
        try:
            images = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/api/images"))
            return p, images
        except Exception:
            time.sleep(0.1)
    sys.exit("server did not start")


def rss_mb(pid):
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024
    return 0


def wrk(port, script, seconds):
    r = subprocess.run(["wrk", "-t2", "-c8", f"-d{seconds}s", "-s", script, "--latency", f"http://127.0.0.1:{port}/"],
                       capture_output=True, text=True, check=True).stdout
    rate = float(re.search(r"Requests/sec:\s+([\d.]+)", r).group(1))
    def ms(label):
        m = re.search(label + r"\s+([\d.]+)(us|ms|s)", r)
        v = float(m.group(1))
        return v / 1000 if m.group(2) == "us" else v * 1000 if m.group(2) == "s" else v
    errors = re.search(r"Non-2xx or 3xx responses: (\d+)", r)
    return {"tiles_per_s": rate, "p50_ms": ms("50%"), "p99_ms": ms("99%"), "errors": int(errors.group(1)) if errors else 0}


def script(path, name, z, x0, x1, y0, y1, seed):
    open(path, "w").write(f"""math.randomseed({seed})
request = function()
  return wrk.format("GET", "/tiles/{name}/{z}/" .. math.random({x0}, {x1}) .. "/" .. math.random({y0}, {y1}) .. ".jpg")
end
""")
    return path


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("small")
    ap.add_argument("big")
    ap.add_argument("--seconds", type=int, default=10)
    ap.add_argument("--soak", type=int, default=60)
    ap.add_argument("--cache-mb", type=int, default=256)
    ap.add_argument("--runs", type=int, default=3)
    a = ap.parse_args()
    rows, soak = [], None
    for label, store, port in (("10 MP", a.small, 18301), ("10 GP", a.big, 18302)):
        server, images = start(store, port, a.cache_mb)
        try:
            img = next((i for i in images if i["name"] == "mosaic"), images[0])
            z, nx, ny = img["xyz_max_zoom"], (img["width"] + 255) // 256, (img["height"] + 255) // 256
            base = f"{img['width']} x {img['height']}"
            # Warm: a 12 x 12 tile working set (a 3072-pixel view and its surroundings), read once first.
            cx, cy = nx // 2, ny // 2
            w = script("/tmp/rolamos-warm.lua", img["name"], z, max(0, cx - 6), min(nx - 1, cx + 5), max(0, cy - 6), min(ny - 1, cy + 5), 7)
            wrk(port, w, 2)
            warm = [wrk(port, w, a.seconds) for _ in range(a.runs)]
            rows.append((label, base, "warm (working set in cache)", warm))
            if nx * ny > 100000:
                cold = []
                for k in range(a.runs):
                    c = script("/tmp/rolamos-cold.lua", img["name"], z, 0, nx - 1, 0, ny - 1, 100 + k)
                    cold.append(wrk(port, c, a.seconds))
                rows.append((label, base, "cold (random tiles anywhere)", cold))
                # Soak: cold requests for a minute, RSS sampled each second.
                c = script("/tmp/rolamos-soak.lua", img["name"], z, 0, nx - 1, 0, ny - 1, 999)
                samples = []
                proc = subprocess.Popen(["wrk", "-t2", "-c8", f"-d{a.soak}s", "-s", c, f"http://127.0.0.1:{port}/"],
                                        stdout=subprocess.PIPE, text=True)
                t0 = time.time()
                while proc.poll() is None:
                    samples.append((time.time() - t0, rss_mb(server.pid)))
                    time.sleep(1)
                out = proc.stdout.read()
                soak = {"seconds": a.soak, "tiles_per_s": float(re.search(r"Requests/sec:\s+([\d.]+)", out).group(1)),
                        "rss_first_mb": samples[1][1], "rss_max_mb": max(s[1] for s in samples),
                        "rss_last_mb": samples[-1][1], "rss_at_half_mb": samples[len(samples) // 2][1]}
        finally:
            server.terminate()
            server.wait()
    lines = [f"| image | size | access | tiles/s | p50 ms | p99 ms | non-2xx |", "|---|---|---|---|---|---|---|"]
    for label, size, access, runs in rows:
        med = lambda k: statistics.median(r[k] for r in runs)
        lines.append(f"| {label} | {size} | {access} | {med('tiles_per_s'):,.0f} | {med('p50_ms'):.2f} | {med('p99_ms'):.2f} | {sum(r['errors'] for r in runs)} |")
    if soak:
        lines += ["", f"Soak: {soak['seconds']} s of cold random tiles from the 10-gigapixel image at {soak['tiles_per_s']:,.0f} tiles/s; "
                      f"server RSS {soak['rss_first_mb']:.0f} MB after 1 s, {soak['rss_at_half_mb']:.0f} MB at half time, "
                      f"{soak['rss_last_mb']:.0f} MB at the end, {soak['rss_max_mb']:.0f} MB at most (tile cache limit {a.cache_mb} MB)."]
    report = "\n".join(lines)
    print(report)
    os.makedirs(os.path.join(ROOT, "bench", "out"), exist_ok=True)
    open(os.path.join(ROOT, "bench", "out", "serve.md"), "w").write(report + "\n")


if __name__ == "__main__":
    main()
