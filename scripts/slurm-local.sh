#!/usr/bin/env bash
# A one-node Slurm cluster on this machine, for tests and for trying
# `visloc map build --executor slurm`: munged, slurmctld and slurmd on
# localhost, no systemd, no cgroups (proctrack/linuxproc, task/none), all
# state in one folder.
#
#   scripts/slurm-local.sh start    start it (installs nothing; see scripts/setup.sh)
#   scripts/slurm-local.sh status   daemons and node state
#   scripts/slurm-local.sh stop     cancel jobs, stop the daemons (by pid file)
#   scripts/slurm-local.sh env      print the export line for clients
#
# Then: export SLURM_CONF=$BASE/etc/slurm.conf (what `start` and `env` print).
# BASE defaults to build/slurm-local; SLURM_LOCAL_PORT (default 6817) sets the
# controller's port, the node daemon's is the next one.
set -euo pipefail
cd "$(dirname "$0")/.."
BASE="${SLURM_LOCAL_BASE:-$PWD/build/slurm-local}"
PORT="${SLURM_LOCAL_PORT:-6817}"
CONF="$BASE/etc/slurm.conf"
SOCKET="$BASE/run/munge.socket.2"

die() { echo "slurm-local: $*" >&2; exit 1; }
need() { command -v "$1" >/dev/null 2>&1 || die "$1 not found: install Debian's slurm-wlm and munge (scripts/setup.sh does)"; }
alive() { [ -f "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

write_conf() {
  local user mem
  user="$(id -un)"
  mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))
  mkdir -p "$BASE"/{etc,state,spool,log,run,munge}
  chmod 700 "$BASE/munge"
  cat > "$CONF" <<CONF
ClusterName=visloc-local
SlurmctldHost=localhost
SlurmUser=$user
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$SOCKET
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
StateSaveLocation=$BASE/state
SlurmdSpoolDir=$BASE/spool
SlurmctldPidFile=$BASE/run/slurmctld.pid
SlurmdPidFile=$BASE/run/slurmd.pid
SlurmctldLogFile=$BASE/log/slurmctld.log
SlurmdLogFile=$BASE/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobContainerType=job_container/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SchedulerType=sched/backfill
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
MpiDefault=none
MailProg=/bin/true
ReturnToService=2
MinJobAge=300
NodeName=localhost NodeAddr=127.0.0.1 CPUs=$(nproc --all) RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=localhost Default=YES MaxTime=INFINITE State=UP
CONF
}

start() {
  need munged; need mungekey; need slurmctld; need slurmd; need sinfo
  export SLURM_CONF="$CONF"
  if alive "$BASE/run/slurmctld.pid" && alive "$BASE/run/slurmd.pid" && alive "$BASE/run/munged.pid"; then
    echo "slurm-local: already running"; echo "export SLURM_CONF=$CONF"; return 0
  fi
  write_conf
  [ -f "$BASE/munge/munge.key" ] || mungekey -c -k "$BASE/munge/munge.key" >/dev/null 2>&1
  if ! alive "$BASE/run/munged.pid"; then
    munged --key-file="$BASE/munge/munge.key" --socket="$SOCKET" --pid-file="$BASE/run/munged.pid" \
      --log-file="$BASE/log/munged.log" --seed-file="$BASE/munge/munged.seed" --force \
      || die "munged did not start (log: $BASE/log/munged.log)"
  fi
  alive "$BASE/run/slurmctld.pid" || slurmctld -f "$CONF" || die "slurmctld did not start (log: $BASE/log/slurmctld.log)"
  alive "$BASE/run/slurmd.pid" || slurmd -f "$CONF" || die "slurmd did not start (log: $BASE/log/slurmd.log)"
  for _ in $(seq 1 100); do
    if sinfo -h -N -o %t 2>/dev/null | grep -qx idle; then
      echo "slurm-local: up ($(nproc --all) CPUs, state in $BASE)"
      echo "export SLURM_CONF=$CONF"
      return 0
    fi
    # A node left down by an earlier run comes back by hand.
    scontrol update nodename=localhost state=resume >/dev/null 2>&1 || true
    sleep 0.2
  done
  die "the node did not become idle in 20 s (logs: $BASE/log/)"
}

stop() {
  export SLURM_CONF="$CONF"
  if alive "$BASE/run/slurmctld.pid"; then scancel --user="$(id -un)" >/dev/null 2>&1 || true; fi
  for d in slurmd slurmctld munged; do
    local pidfile="$BASE/run/$d.pid"
    if alive "$pidfile"; then
      local pid; pid="$(cat "$pidfile")"
      kill "$pid" 2>/dev/null || true
      for _ in $(seq 1 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
      kill -9 "$pid" 2>/dev/null || true
    fi
    rm -f "$pidfile"
  done
  echo "slurm-local: stopped"
}

status() {
  export SLURM_CONF="$CONF"
  local up=0
  for d in munged slurmctld slurmd; do
    if alive "$BASE/run/$d.pid"; then echo "$d: running (pid $(cat "$BASE/run/$d.pid"))"; else echo "$d: stopped"; up=1; fi
  done
  [ $up -eq 0 ] && sinfo -N 2>/dev/null || true
  return $up
}

case "${1:-}" in
  start) start ;;
  stop) stop ;;
  status) status ;;
  env) echo "export SLURM_CONF=$CONF" ;;
  *) echo "usage: $0 start|stop|status|env" >&2; exit 2 ;;
esac
