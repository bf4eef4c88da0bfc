#!/usr/bin/env bash
# Stops the localhost Slurm daemons started by scripts/setup-slurm.sh (jobs still running are killed).
set -u
pkill -x slurmd 2>/dev/null
pkill -x slurmctld 2>/dev/null
pkill -x munged 2>/dev/null
exit 0
