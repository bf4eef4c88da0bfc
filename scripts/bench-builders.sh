#!/usr/bin/env bash
# Builder speed and quality side by side with the Embree anchor, in the same run on the same machine
# (DEVELOPERS.md: speed targets are ratios to ../shared/tools/embree-anchor, release build, medians).
# Usage: scripts/bench-builders.sh SCENE [runs=5]
#   SCENE: path to .obj/.obj.gz (Embree needs a file) or gen:... (then only our builders run).
# Prints our JSON lines, Embree's JSON line, then a table: our median ms, Embree's binned-SAH
# (MEDIUM) median ms, the ratio, and both SAH costs (c_T = 3, c_I = 2).
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
scene=${1:?usage: scripts/bench-builders.sh SCENE [runs=5]}
runs=${2:-5}
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$repo/target}

cargo build --quiet --release -p bvhlab-build --example build_bench --manifest-path "$repo/Cargo.toml"
ours=$("$CARGO_TARGET_DIR/release/examples/build_bench" "$scene" "$runs")
echo "$ours"

embree=""
anchor="$repo/../shared/tools/embree-anchor"
if [[ "$scene" != gen:* && -x "$anchor" ]]; then
  embree=$("$anchor" "$scene" 1 "$runs")
  echo "$embree"
else
  echo "(no Embree anchor for $scene)" >&2
fi

# Pull a number field out of a one-line JSON object (no jq dependency).
field() { sed -n "s/.*\"$2\":\([-0-9.eE+]*\).*/\1/p" <<<"$1"; }
emb_ms=""; emb_sah=""
if [[ -n "$embree" ]]; then
  medium=$(sed -n 's/.*"medium_binned_sah":{\([^}]*\)}.*/\1/p' <<<"$embree")
  emb_ms=$(field "$medium" build_ms_median)
  emb_sah=$(field "$medium" sah_cost)
fi

printf '\n%-20s %12s %14s %8s %10s %11s\n' builder median_ms embree_bin_ms ratio sah_cost embree_sah
while IFS= read -r line; do
  name=$(sed -n 's/.*"builder":"\([^"]*\)".*/\1/p' <<<"$line")
  ms=$(field "$line" build_ms_median)
  sah=$(field "$line" sah_cost)
  ratio=-
  [[ -n "$emb_ms" ]] && ratio=$(awk -v a="$ms" -v b="$emb_ms" 'BEGIN { printf "%.2f", a / b }')
  printf '%-20s %12s %14s %8s %10s %11s\n' "$name" "$ms" "${emb_ms:--}" "$ratio" "$sah" "${emb_sah:--}"
done <<<"$ours"
