#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for the Slurm integration tests (crates/cli/tests/slurm.rs)
# and for trying `bvhlab slurm --submit` locally. Installs Debian's slurm-wlm and munge when missing,
# writes a localhost slurm.conf (one node with this machine's CPUs and memory, partition `debug`), starts
# munged, slurmctld and slurmd, and waits until `sinfo` shows the node idle. Safe to re-run.
# Needs root (apt, daemons). scripts/stop-slurm.sh stops the daemons.
set -euo pipefail

if [ "$(id -u)" != 0 ]; then
  echo "setup-slurm.sh: needs root (installs packages, starts daemons)" >&2
  exit 2
fi

need=()
command -v slurmctld >/dev/null 2>&1 || need+=(slurmctld)
command -v slurmd >/dev/null 2>&1 || need+=(slurmd)
command -v sbatch >/dev/null 2>&1 || need+=(slurm-client)
command -v munged >/dev/null 2>&1 || need+=(munge)
if [ ${#need[@]} -gt 0 ]; then
  echo "installing ${need[*]}"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
fi

# ---- munge: the authentication every Slurm message carries.
if [ ! -s /etc/munge/munge.key ]; then
  mkdir -p /etc/munge
  dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key status=none
fi
chown munge:munge /etc/munge/munge.key
chmod 0400 /etc/munge/munge.key
mkdir -p /run/munge /var/lib/munge /var/log/munge
chown munge:munge /run/munge /var/lib/munge /var/log/munge
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
  pkill -x munged 2>/dev/null || true
  rm -f /run/munge/munge.socket.2.lock
  su -s /bin/sh munge -c "munged --force"
  for _ in $(seq 50); do munge -n 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.1; done
fi
munge -n | unmunge >/dev/null || { echo "munged does not answer" >&2; exit 1; }

# ---- slurm.conf: one node = this machine. No cgroups (a VM or container may not delegate them):
# processes are tracked through /proc, tasks are not confined. CR_Core_Memory: tasks share the node by
# cores and memory, so a 2-CPU machine runs two 1-CPU array tasks at once.
host=$(hostname -s)
cpus=$(nproc)
mem_mb=$(awk '/MemTotal/ {printf "%d", $2 / 1024 * 0.9}' /proc/meminfo)
mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm /run/slurm
conf=/etc/slurm/slurm.conf
new=$(mktemp)
cat >"$new" <<EOF
# Written by bvhlab scripts/setup-slurm.sh: a single-node localhost cluster.
ClusterName=bvhlab-local
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=/run/slurm/slurmctld.pid
SlurmdPidFile=/run/slurm/slurmd.pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MaxArraySize=10001
SlurmdTimeout=30
MessageTimeout=10
KillWait=5
MinJobAge=600
DefMemPerCPU=1024
NodeName=$host CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
changed=0
if ! cmp -s "$new" "$conf"; then
  mv "$new" "$conf"
  changed=1
else
  rm -f "$new"
fi
chmod 0644 "$conf"

running() { pgrep -x "$1" >/dev/null 2>&1; }
if [ "$changed" = 1 ]; then
  pkill -x slurmd 2>/dev/null || true
  pkill -x slurmctld 2>/dev/null || true
  for _ in $(seq 50); do running slurmd || running slurmctld || break; sleep 0.1; done
fi
running slurmctld || slurmctld
running slurmd || slurmd

logs() {
  echo "--- slurmctld.log" >&2; tail -n 30 /var/log/slurm/slurmctld.log >&2 || true
  echo "--- slurmd.log" >&2; tail -n 30 /var/log/slurm/slurmd.log >&2 || true
}
state=""
for i in $(seq 120); do
  state=$(sinfo -h -n "$host" -o %T 2>/dev/null | head -n1 || true)
  case "$state" in
    idle|mixed|allocated) break ;;
    down*|drain*|drained*)
      scontrol update nodename="$host" state=resume >/dev/null 2>&1 || true ;;
  esac
  sleep 0.5
done
case "$state" in
  idle|mixed|allocated) ;;
  *) echo "setup-slurm.sh: node $host is '${state:-not known}' after 60 s" >&2; logs; exit 1 ;;
esac
sinfo
