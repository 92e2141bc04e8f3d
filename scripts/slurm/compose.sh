#!/usr/bin/env bash
# The global mosaic of a store composed on a Slurm cluster: the chunks as an `sbatch` job array of
# N shards (`rolamos compose STORE --shard I/N`), then `rolamos compose STORE --finish` once every
# shard has succeeded (--dependency=afterok). Slurm schedules, retries nothing by itself, and
# rolamos keeps no scheduler of its own. See docs/scale-out.md.
#
#   scripts/slurm/compose.sh STORE N [options] [-- compose flags]
#     --retry        submit again only the shards not done (after a failed or cancelled shard),
#                    and a new finish
#     --wait         return when the finish has ended, with its exit status
#     --logs DIR     job output (default: STORE/../slurm-logs)
#     --rolamos BIN  the rolamos binary, as the nodes see it (default: the one beside this script's
#                    build, else `rolamos` on PATH)
#   SBATCH_ARGS="--partition=x --time=1:00:00 ..." adds sbatch options to every job.
#   Compose flags (codec, --chunk, --max-pixels, ...) must be the same for the shards and the
#   finish; the script passes the same ones to both.
set -euo pipefail

usage() { sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
[ $# -ge 2 ] || usage
STORE=$1 N=$2
shift 2
RETRY=0 WAIT=0 LOGS="" ROLAMOS=""
here=$(cd "$(dirname "$0")/../.." && pwd)
while [ $# -gt 0 ]; do
  case $1 in
    --retry) RETRY=1 ;;
    --wait) WAIT=1 ;;
    --logs) LOGS=$2; shift ;;
    --rolamos) ROLAMOS=$2; shift ;;
    --) shift; break ;;
    *) echo "compose.sh: unknown option $1" >&2; usage ;;
  esac
  shift
done
FLAGS=("$@")
[[ $N =~ ^[1-9][0-9]*$ ]] || { echo "compose.sh: the number of shards must be a positive whole number, not '$N'" >&2; exit 2; }
[ -f "$STORE/store.json" ] || { echo "compose.sh: $STORE is not a rolamos store (no store.json)" >&2; exit 2; }
STORE=$(cd "$STORE" && pwd)  # the nodes' working folders differ: absolute paths only
if [ -z "$ROLAMOS" ]; then
  if [ -x "$here/build/rolamos" ]; then ROLAMOS=$here/build/rolamos; else ROLAMOS=$(command -v rolamos); fi
fi
LOGS=${LOGS:-$(dirname "$STORE")/slurm-logs}
mkdir -p "$LOGS"
read -r -a EXTRA <<< "${SBATCH_ARGS:-}"
q() { if [ $# -gt 0 ]; then printf '%q ' "$@"; fi; }

ARRAY="1-$N"
if [ $RETRY -eq 1 ]; then
  ARRAY=$("$ROLAMOS" compose "$STORE" --status | tail -1)
  case $ARRAY in
    *"not split"*) echo "compose.sh: $STORE has no shards to retry; submit without --retry" >&2; exit 2 ;;
  esac
fi

dependency=()
if [ "$ARRAY" != "none" ]; then
  shards=$(sbatch --parsable "${EXTRA[@]}" --job-name=rolamos-shard --array="$ARRAY" --cpus-per-task=1 \
             --output="$LOGS/shard-%A_%a.out" \
             --wrap="exec $(q "$ROLAMOS") compose -q $(q "$STORE") --shard \${SLURM_ARRAY_TASK_ID}/$N $(q "${FLAGS[@]}")")
  shards=${shards%%;*}
  echo "shards: job array $shards (tasks $ARRAY of $N)"
  dependency=(--dependency="afterok:$shards" --kill-on-invalid-dep=yes)
fi
wait_flag=()
[ $WAIT -eq 1 ] && wait_flag=(--wait)
set +e
finish=$(sbatch --parsable "${EXTRA[@]}" "${dependency[@]}" "${wait_flag[@]}" --job-name=rolamos-finish \
           --output="$LOGS/finish-%j.out" \
           --wrap="exec $(q "$ROLAMOS") compose -q $(q "$STORE") --finish $(q "${FLAGS[@]}")")
rc=$?
set -e
echo "finish: job ${finish%%;*} (after every shard succeeds; a failed shard cancels it: rerun with --retry)"
exit $rc
