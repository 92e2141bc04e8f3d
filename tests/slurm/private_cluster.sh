#!/usr/bin/env bash
# A private single-node Slurm cluster for tests: munged, slurmctld and slurmd on localhost, with
# their key, sockets, config, spool, state and logs in one folder. Nothing system-wide is used or
# changed (other ports than a real cluster's, SLURM_CONF pointing at the folder's config).
#
#   source tests/slurm/private_cluster.sh
#   cluster_start DIR     # exports SLURM_CONF; returns non-zero with the reason in $CLUSTER_WHY
#   cluster_stop          # stops the daemons
CLUSTER_WHY=""

cluster_free_port() {
  python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1]); s.close()'
}

cluster_start() {
  local dir=$1
  CLUSTER_DIR=$dir
  for tool in munged slurmctld slurmd sbatch squeue scontrol; do
    if ! command -v "$tool" >/dev/null 2>&1 && [ ! -x "/usr/sbin/$tool" ]; then
      CLUSTER_WHY="$tool is not installed (Debian: slurm-wlm and munge)"; return 1
    fi
  done
  export PATH="$PATH:/usr/sbin"
  mkdir -p "$dir"/{munge,state,spool,log}
  chmod 700 "$dir/munge"
  head -c 1024 /dev/urandom > "$dir/munge/munge.key"
  chmod 400 "$dir/munge/munge.key"
  # --force: the folder is under /tmp (world-writable parents) and the test may run as root.
  munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
         --pid-file="$dir/munge/munged.pid" --log-file="$dir/log/munged.log" \
         --seed-file="$dir/munge/munge.seed" 2>"$dir/log/munged.err" || {
    CLUSTER_WHY="munged did not start: $(tail -1 "$dir/log/munged.err")"; return 1; }
  local node user cpus mem ctl_port d_port
  node=$(hostname -s)
  user=$(id -un)
  cpus=$(nproc)
  mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 / 2 ))
  ctl_port=$(cluster_free_port)
  d_port=$(cluster_free_port)
  cat > "$dir/slurm.conf" <<CONF
ClusterName=rolamos-test
SlurmctldHost=$node(127.0.0.1)
SlurmctldPort=$ctl_port
SlurmdPort=$d_port
SlurmUser=$user
SlurmdUser=$user
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
SlurmdTimeout=60
InactiveLimit=0
KillWait=5
NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
  export SLURM_CONF="$dir/slurm.conf"
  slurmctld -D -i -f "$SLURM_CONF" >"$dir/log/slurmctld.out" 2>&1 &
  CLUSTER_CTLD=$!
  slurmd -D -f "$SLURM_CONF" -N "$node" >"$dir/log/slurmd.out" 2>&1 &
  CLUSTER_SLURMD=$!
  # Ready when the node is idle.
  for _ in $(seq 1 60); do
    if sinfo -h -N -o '%T' 2>/dev/null | grep -q '^idle'; then return 0; fi
    if ! kill -0 "$CLUSTER_CTLD" 2>/dev/null; then
      CLUSTER_WHY="slurmctld stopped: $(tail -2 "$dir/log/slurmctld.log" "$dir/log/slurmctld.out" 2>/dev/null | tr '\n' ' ')"; cluster_stop; return 1
    fi
    if ! kill -0 "$CLUSTER_SLURMD" 2>/dev/null; then
      CLUSTER_WHY="slurmd stopped: $(tail -2 "$dir/log/slurmd.log" "$dir/log/slurmd.out" 2>/dev/null | tr '\n' ' ')"; cluster_stop; return 1
    fi
    sleep 0.5
  done
  CLUSTER_WHY="the node did not become idle in 30 s: $(sinfo -h -N 2>&1 | head -2 | tr '\n' ' ')"
  cluster_stop
  return 1
}

cluster_stop() {
  [ -n "${CLUSTER_SLURMD:-}" ] && kill "$CLUSTER_SLURMD" 2>/dev/null
  [ -n "${CLUSTER_CTLD:-}" ] && kill "$CLUSTER_CTLD" 2>/dev/null
  [ -n "${CLUSTER_SLURMD:-}" ] && wait "$CLUSTER_SLURMD" 2>/dev/null
  [ -n "${CLUSTER_CTLD:-}" ] && wait "$CLUSTER_CTLD" 2>/dev/null
  if [ -f "${CLUSTER_DIR:-}/munge/munged.pid" ]; then
    kill "$(cat "$CLUSTER_DIR/munge/munged.pid")" 2>/dev/null
  fi
  CLUSTER_SLURMD="" CLUSTER_CTLD=""
}
