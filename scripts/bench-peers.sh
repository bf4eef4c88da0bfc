#!/usr/bin/env bash
# Peer builders inside bvhlab against the same libraries measured outside it, in one run (issue 18):
# for each scene, ../shared/tools/embree-anchor (Embree 3 rtcBuildBVH LOW and MEDIUM, 1 thread,
# median of RUNS) and `bvhlab eval --build embree-morton|embree-binned` (the library's own call
# timed, median of RUNS), alternated ROUNDS times so that both see the same machine conditions.
# Prints per scene the medians over rounds, the ratio bvhlab/anchor and both SAH costs.
# Usage: scripts/bench-peers.sh [RUNS=5] [ROUNDS=2] [SCENES...]
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
shared="$repo/../shared"
runs=${1:-5}; rounds=${2:-2}; shift $(( $# > 2 ? 2 : $# ))
scenes=("$@")
[ ${#scenes[@]} -gt 0 ] || scenes=(stanford_dragon conference breakfast_room)
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$repo/target}
cargo build --quiet --release --manifest-path "$repo/Cargo.toml"
bin="$CARGO_TARGET_DIR/release/bvhlab"
echo "load: $(cut -d' ' -f1-3 /proc/loadavg)"
printf '%-16s %-14s %11s %11s %7s %10s %10s\n' scene builder bvhlab_ms anchor_ms ratio sah_bvhlab sah_anchor
for s in "${scenes[@]}"; do
  f="$shared/scenes/$s.obj.gz"
  [ -e "$f" ] || { echo "$s: missing ($f)"; continue; }
  out=$(mktemp -d)
  for r in $(seq "$rounds"); do
    "$shared/tools/embree-anchor" "$f" 1 "$runs" >> "$out/anchor"
    for b in embree-morton embree-binned; do
      "$bin" eval --scene "$f" --build "$b" --repeat "$runs" --threads 1 --no-cache --json 2>/dev/null | tail -n 1 >> "$out/$b"
    done
  done
  python3 - "$out" "$s" <<'PY'
import json, statistics, sys
out, scene = sys.argv[1:]
anchor = [json.loads(l) for l in open(f"{out}/anchor")]
for b, part in (("embree-morton", "low_morton"), ("embree-binned", "medium_binned_sah")):
    ours = [json.loads(l) for l in open(f"{out}/{b}")]
    ms = statistics.median(o["build_seconds"] * 1e3 for o in ours)
    ams = statistics.median(a[part]["build_ms_median"] for a in anchor)
    print(f"{scene:16s} {b:14s} {ms:11.1f} {ams:11.1f} {ms / ams:7.3f} {ours[0]['sah_cost']:10.2f} {anchor[0][part]['sah_cost']:10.2f}")
PY
  rm -rf "$out"
done
