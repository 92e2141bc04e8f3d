#!/usr/bin/env python3
"""Store TIFF I/O benchmark against libvips, in one run on the same pixels.

  bench/run_tiff_io.py [--size 32768] [--runs 3] [--out bench/out]

1. Writes a SIZE x SIZE procedural seafloor as raw RGB (once, not timed).
2. Write: raw -> JPEG q90 tiled pyramidal BigTIFF, ours (tiff_io_bench write) vs
   `vips rawload ... [tile,pyramid,bigtiff,compression=jpeg,Q=90]` (vips's Q>=90 JPEG is RGB 4:4:4)
   and Q=89 (YCbCr 4:2:0 like ours). Wall time and peak RSS from /usr/bin/time, medians.
3. Convert: a large tiled (non-pyramidal) JPEG TIFF -> pyramid, `rolamos convert` vs `vips copy`.
4. Read: random 256x256 level-0 regions through the tile cache (tiff_io_bench read).
Prints a Markdown report and writes it to OUT/tiff_io.md.
"""
import argparse, json, os, re, statistics, subprocess, sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUILD = os.path.join(ROOT, "build")


def timed(cmd):
    """Runs cmd under /usr/bin/time; returns (seconds, peak_rss_mb, stdout)."""
    r = subprocess.run(["/usr/bin/time", "-f", "TIME %e %M"] + cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"failed: {' '.join(cmd)}\n{r.stdout}\n{r.stderr}")
    m = re.search(r"TIME ([\d.]+) (\d+)", r.stderr)
    return float(m.group(1)), int(m.group(2)) / 1024.0, r.stdout


def median_of(runs, cmd):
    results = [timed(cmd) for _ in range(runs)]
    return statistics.median(t for t, _, _ in results), statistics.median(m for _, m, _ in results)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=32768)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "out"))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    bench = os.path.join(BUILD, "tiff_io_bench")
    cli = os.path.join(BUILD, "rolamos")
    n = a.size
    raw = os.path.join(a.out, f"seafloor{n}.raw")
    if not os.path.exists(raw) or os.path.getsize(raw) != n * n * 3:
        subprocess.run([bench, "make-raw", "--size", str(n), "-o", raw], check=True)
    ours = os.path.join(a.out, "ours.tif")
    vips90 = os.path.join(a.out, "vips_q90.tif")
    vips89 = os.path.join(a.out, "vips_q89.tif")
    opts = "tile,pyramid,bigtiff,compression=jpeg,tile-width=256,tile-height=256"
    rows = []
    t, m = median_of(a.runs, [bench, "write", "--raw", raw, "--size", str(n), "-o", ours])
    rows.append(("write", "rolamos (JPEG q90, YCbCr 4:2:0)", t, m, os.path.getsize(ours)))
    t, m = median_of(a.runs, ["vips", "rawload", raw, f"{vips90}[{opts},Q=90]", str(n), str(n), "3"])
    rows.append(("write", "vips tiffsave Q=90 (RGB JPEG)", t, m, os.path.getsize(vips90)))
    t, m = median_of(a.runs, ["vips", "rawload", raw, f"{vips89}[{opts},Q=89]", str(n), str(n), "3"])
    rows.append(("write", "vips tiffsave Q=89 (YCbCr 4:2:0)", t, m, os.path.getsize(vips89)))

    # Convert: the same large tiled TIFF into a pyramid, both tools.
    src = os.path.join(a.out, "tiled_input.tif")
    if not os.path.exists(src):
        subprocess.run(["vips", "rawload", raw, f"{src}[tile,bigtiff,compression=jpeg,Q=89,"
                        "tile-width=256,tile-height=256]", str(n), str(n), "3"], check=True)
    conv_ours = os.path.join(a.out, "convert_ours.tif")
    conv_vips = os.path.join(a.out, "convert_vips.tif")
    t, m = median_of(a.runs, [cli, "convert", src, "-o", conv_ours, "-q"])
    rows.append(("convert", "rolamos convert", t, m, os.path.getsize(conv_ours)))
    t, m = median_of(a.runs, ["vips", "copy", src, f"{conv_vips}[{opts},Q=89]"])
    rows.append(("convert", "vips copy ... [pyramid,Q=89]", t, m, os.path.getsize(conv_vips)))

    read_rows = []
    for cache_mb in (64, 256):
        reads = [json.loads(timed([bench, "read", "--tif", ours, "--samples", "2000",
                                   "--cache-mb", str(cache_mb)])[2]) for _ in range(a.runs)]
        read_rows.append({k: statistics.median(r[k] for r in reads) for k in reads[0]})

    lines = [f"### TIFF I/O, {n} x {n} RGB ({n*n/1e9:.2f} gigapixels), median of {a.runs} runs", "",
             "| job | tool | seconds | Mpx/s | peak RSS MB | file MB |", "|---|---|---|---|---|---|"]
    for job, tool, t, m, size in rows:
        lines.append(f"| {job} | {tool} | {t:.2f} | {n*n/1e6/t:.0f} | {m:.0f} | {size/2**20:.0f} |")
    lines += ["", "| random 256x256 reads at level 0 | cache MB | median ms | p99 ms | RSS before reads MB | peak RSS MB | growth MB |",
              "|---|---|---|---|---|---|---|"]
    for m in read_rows:
        lines.append(f"| cold: anywhere in the image (decode from file) | {m['cache_mb']:.0f} | {m['cold_median_ms']:.3f} | "
                     f"{m['cold_p99_ms']:.3f} | {m['baseline_rss_mb']:.0f} | {m['peak_rss_mb']:.0f} | {m['growth_mb']:.0f} |")
        lines.append(f"| warm: working set in the cache | {m['cache_mb']:.0f} | {m['warm_median_ms']:.3f} | "
                     f"{m['warm_p99_ms']:.3f} | | | |")
    lines.append("")
    report = "\n".join(lines)
    print(report)
    with open(os.path.join(a.out, "tiff_io.md"), "w") as f:
        f.write(report + "\n")


if __name__ == "__main__":
    main()
