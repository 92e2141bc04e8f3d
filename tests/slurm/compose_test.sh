#!/usr/bin/env bash
# The sharded compose as a Slurm job array on a private single-node cluster (started and stopped
# here): the result equals a one-process compose byte for byte (hence pixel for pixel); a shard
# cancelled before it ran is submitted again alone (--retry) and the map is still the same.
# Exits 77 (skipped) with the reason when no cluster can start here.
set -uo pipefail
ROLAMOS=$1
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
T=$(mktemp -d /tmp/rolamos-slurm.XXXXXX)
source "$ROOT/tests/slurm/private_cluster.sh"
finish() { cluster_stop; rm -rf "$T"; }
trap finish EXIT
fail() { echo "FAIL: $*"; for f in "$T"/slurm-logs/*.out "$T"/cluster/log/*.log; do [ -f "$f" ] && { echo "== $f"; tail -5 "$f"; }; done; exit 1; }

if ! cluster_start "$T/cluster"; then
  echo "SKIP: no Slurm cluster could start here: $CLUSTER_WHY"
  exit 77
fi
echo "cluster: $(sinfo -h -o '%P %D nodes %T')"

wait_idle() {  # until the cluster has no jobs left (at most $1 s)
  for _ in $(seq 1 $(( $1 * 2 ))); do
    [ -z "$(squeue -h -o %i)" ] && return 0
    sleep 0.5
  done
  fail "jobs still queued after $1 s: $(squeue -h | tr '\n' ';')"
}

"$ROLAMOS" synth -q -o "$T/survey" --frames 40 --width 480 --height 360 --focal 420 --lanes 2 >/dev/null || fail synth
"$ROLAMOS" mosaic -q "$T/survey/frames" -o "$T/one.rolamos" --patch-megapixels 0.5 >/dev/null || fail mosaic
cp -r "$T/one.rolamos" "$T/sharded.rolamos"
FLAGS=(--chunk 256 --compression zstd)
"$ROLAMOS" compose -q "$T/one.rolamos" "${FLAGS[@]}" >/dev/null || fail "one-process compose"

# Held at submission, so that shard 2 can be cancelled before it runs, then released.
out=$(SBATCH_ARGS="--hold" "$ROOT/scripts/slurm/compose.sh" "$T/sharded.rolamos" 4 --logs "$T/slurm-logs" \
        --rolamos "$ROLAMOS" -- "${FLAGS[@]}") || fail "submission: $out"
echo "$out"
array=$(echo "$out" | sed -n 's/^shards: job array \([0-9]*\).*/\1/p')
finish_job=$(echo "$out" | sed -n 's/^finish: job \([0-9]*\).*/\1/p')
[ -n "$array" ] && [ -n "$finish_job" ] || fail "no job ids in: $out"
scancel "${array}_2" || fail "scancel"
scontrol release "$array" || fail "release"
scontrol release "$finish_job" 2>/dev/null
wait_idle 120
[ -f "$T/sharded.rolamos/mosaic.tif" ] && fail "the finish ran although shard 2 was cancelled"
status=$("$ROLAMOS" compose "$T/sharded.rolamos" --status | tail -1)
[ "$status" = "2" ] || fail "shards not done: '$status', expected only 2"

out=$("$ROOT/scripts/slurm/compose.sh" "$T/sharded.rolamos" 4 --retry --wait --logs "$T/slurm-logs" \
        --rolamos "$ROLAMOS" -- "${FLAGS[@]}") || fail "retry: $out"
echo "$out"
echo "$out" | grep -q "tasks 2 of 4" || fail "the retry did not submit shard 2 alone: $out"
wait_idle 60
[ -f "$T/sharded.rolamos/mosaic.tif" ] || fail "no mosaic.tif after the retry"
cmp "$T/one.rolamos/mosaic.tif" "$T/sharded.rolamos/mosaic.tif" || fail "the sharded mosaic differs from the one-process one"
[ -d "$T/sharded.rolamos/mosaic.tif.partial" ] && fail "the partial mosaic was left behind"
"$ROLAMOS" info "$T/sharded.rolamos" >/dev/null || fail "the store does not open"
echo "PASS: 4 shards on Slurm (shard 2 cancelled, retried alone) = one-process compose, byte for byte"
