#!/usr/bin/env bash
# A short libFuzzer run for ctest: builds a seed corpus with the rolamos CLI, then mutates it.
#   run_fuzzer.sh FUZZER_BINARY ROLAMOS_CLI tiff_reader|sidecar_parser [RUNS]
set -euo pipefail
fuzzer=$1 cli=$2 kind=$3 runs=${4:-}
work=$(mktemp -d /tmp/rolamos-fuzz.XXXXXX)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/corpus"
case "$kind" in
  tiff_reader)
    runs=${runs:-3000}
    for c in jpeg zstd deflate webp none; do
      "$cli" demo -q --size 300 --compression "$c" -o "$work/s-$c" >/dev/null
      cp "$work/s-$c/patches/000001.tif" "$work/corpus/$c.tif"
    done
    ;;
  sidecar_parser)
    runs=${runs:-100000}
    "$cli" demo -q --size 64 -o "$work/s" >/dev/null
    cp "$work/s/patches/000001.json" "$work/corpus/demo.json"
    cat > "$work/corpus/full.json" <<'JSON'
{"id": 2, "size": [640, 480], "n_images": 2, "offset": [1.5, -2],
 "first_homography": [1,0,0,0,1,0,0,0,1], "last_homography": [1,0,5,0,1,6,0,0,1],
 "patch_to_global": [1,0,100,0,1,50,0,0,1],
 "frames": [{"index": 0, "source": "f0.jpg", "frame_to_patch": [1,0,0,0,1,0,0,0,1],
             "egomotion": {"R": [1,0,0,0,1,0,0,0,1], "t": [0,0,1], "n": [0,0,1]},
             "matches": 412, "inliers": 380, "ecc": 0.93, "status": "stitched"}],
 "rejected": [{"index": 17, "source": "f17.jpg", "reason": "kalman_gate"}]}
JSON
    ;;
  *) echo "unknown fuzzer kind $kind" >&2; exit 2 ;;
esac
# Leaks are not what this run looks for (the libraries keep process-wide caches).
"$fuzzer" -runs="$runs" -seed=1 -detect_leaks=0 -timeout=20 -rss_limit_mb=3072 \
  -artifact_prefix="$work/" "$work/corpus" 2>"$work/log" || {
  tail -50 "$work/log" >&2
  for a in "$work"/crash-* "$work"/timeout-* "$work"/oom-*; do
    [ -f "$a" ] && { echo "artifact: $a"; base64 "$a" | head -40; }
  done
  exit 1
}
grep -E "Done [0-9]+ runs" "$work/log" || tail -3 "$work/log"
