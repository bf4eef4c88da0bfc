#!/usr/bin/env bash
# issue 19.4: binned SAH build time and SAH cost against tinybvh's BuildAVX (../shared/tools/tinybvh-anchor),
# 1 thread, alternated in one run on the same machine (ours, anchor, ours, anchor, ...).
#
# Usage: scripts/bench-binned.sh [runs=5] [rounds=3] [VARIANTS] [SCENES...]
#   VARIANTS: comma-separated build_bench names (default: the thesis configuration `binned-sah`
#   (16 bins), the same with 32 bins, and the all-axes ones `binned-sah:axes=all:bins=8`,
#   `binned-sah:axes=all`).
#   SCENES: default stanford_dragon and conference from ../shared/scenes.
# Each round runs every variant `runs` times (its median) and then the anchor `runs` times (its medians);
# the table shows the median over the rounds, the SAH cost, and the ratio to BuildAVX with the goal
# (time <= 1.00x at SAH <= BuildAVX's + 1 %). `uptime` is printed before and after: others' load skews
# both sides, which is why only same-run ratios count.
#
# ../shared/tools/tinybvh-anchor is not single-threaded: tinybvh builds scenes of 50k+ triangles with its
# job system (MT_BUILD_THRESHOLD; measured: up to 60 threads and both cores busy during its builds). Where
# tiny_bvh.h is found (TINYBVH_H, or the tinybvh-rs crate's copy in the cargo registry) and g++ is there,
# the script also builds the same anchor source with -DNO_THREADED_BUILDS (same trees, same SAH) into the
# target dir and times it in the same rounds: the 1-thread verdict is against that build, and bvhlab's
# parallel build on 2 threads (binned-sah-par) is put beside the threaded anchor.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
shared="$repo/../shared"
anchor="$shared/tools/tinybvh-anchor"
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$repo/target}
bench="$CARGO_TARGET_DIR/release/examples/build_bench"
runs=${1:-5}
rounds=${2:-3}
variants=${3:-binned-sah,binned-sah:bins=32,binned-sah:axes=all:bins=8,binned-sah:axes=all}
shift $(( $# < 3 ? $# : 3 ))
scenes=("$@")
[[ ${#scenes[@]} -gt 0 ]] || scenes=("$shared/scenes/stanford_dragon.obj.gz" "$shared/scenes/conference.obj.gz")
[[ -x "$anchor" ]] || { echo "missing $anchor" >&2; exit 1; }
# NO_BUILD=1 uses the build_bench binary as it is (e.g. while another cargo command holds the target dir).
[[ -n "${NO_BUILD:-}" ]] || cargo build --quiet --release -p bvhlab-builders --example build_bench --manifest-path "$repo/Cargo.toml"

# The single-thread anchor (see above), if it can be built here.
anchor1=""
find_header() { { ls "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/tinybvh-rs-*/ffi/tinybvh/tiny_bvh.h 2>/dev/null || true; } | head -1; }
header=${TINYBVH_H:-$(find_header)}
if [[ -z "$header" ]]; then
  # A fresh machine: put the tinybvh-rs crate (its tiny_bvh.h 1.6.8) into the cargo registry
  # through a throwaway manifest (crates.io is reachable where the build's own crates are).
  tmp=$(mktemp -d)
  mkdir -p "$tmp/src" && echo 'fn main() {}' >"$tmp/src/main.rs"
  printf '[package]\nname = "fetch-tinybvh"\nversion = "0.0.0"\nedition = "2021"\n[dependencies]\ntinybvh-rs = "=0.1.0-beta.3"\n' >"$tmp/Cargo.toml"
  (cd "$tmp" && cargo fetch --quiet) >/dev/null 2>&1 || echo "note: could not fetch tinybvh-rs for tiny_bvh.h" >&2
  rm -rf "$tmp"
  header=$(find_header)
fi
if [[ -n "$header" && -f "$header" && -f "$shared/tools/tinybvh_anchor.cpp" ]] && command -v g++ >/dev/null; then
  dir="$CARGO_TARGET_DIR/anchors"
  anchor1="$dir/tinybvh-anchor-1t"
  # Rebuilt when the anchor source or the header is newer, or the header is another file.
  if [[ ! -x "$anchor1" || "$shared/tools/tinybvh_anchor.cpp" -nt "$anchor1" || "$header" -nt "$anchor1" ]] \
     || ! cmp -s "$header" "$dir/tiny_bvh.h"; then
    if ! { mkdir -p "$dir" && cp "$header" "$dir/tiny_bvh.h" && cp "$shared/tools/tinybvh_anchor.cpp" "$dir/" \
         && g++ -O3 -march=x86-64-v3 -std=c++17 -DNO_THREADED_BUILDS "$dir/tinybvh_anchor.cpp" -o "$anchor1" -lpthread; }; then
      echo "note: could not build the single-thread anchor: only the threaded one" >&2
      anchor1=""
    fi
  fi
else
  echo "note: tiny_bvh.h, g++ or the anchor source not found: only the threaded anchor (set TINYBVH_H=path/to/tiny_bvh.h)" >&2
fi

field() { sed -n "s/.*\"$2\":\([-0-9.eE+]*\).*/\1/p" <<<"$1"; }
part() { sed -n "s/.*\"$2\":{\([^}]*\)}.*/\1/p" <<<"$1"; }
med() { sort -g | awk '{a[NR]=$1} END {if (NR == 0) print ""; else if (NR % 2) print a[(NR+1)/2]; else printf "%.2f\n", (a[NR/2]+a[NR/2+1])/2}'; }

echo "load before: $(uptime)"
for scene in "${scenes[@]}"; do
  declare -A ms=() sah=()
  avx_ms=() avx_sah="" avx1_ms=() avx1_sah="" par2_ms=()
  for ((r = 0; r < rounds; r++)); do
    out=$("$bench" "$scene" "$runs" 1 "$variants")
    while IFS= read -r line; do
      [[ -z "$line" ]] && continue
      name=$(sed -n 's/.*"builder":"\([^"]*\)".*/\1/p' <<<"$line")
      ms[$name]="${ms[$name]:-} $(field "$line" build_ms_median)"
      sah[$name]=$(field "$line" sah_cost)
    done <<<"$out"
    a=$("$anchor" "$scene" "$runs")
    avx=$(part "$a" binned_sah_avx)
    avx_ms+=("$(field "$avx" build_ms_median)")
    avx_sah=$(field "$avx" sah_cost)
    if [[ -n "$anchor1" ]]; then
      avx1=$(part "$("$anchor1" "$scene" "$runs" || true)" binned_sah_avx)
      avx1_ms+=("$(field "$avx1" build_ms_median)")
      avx1_sah=$(field "$avx1" sah_cost)
      par2_ms+=("$(field "$("$bench" "$scene" "$runs" 2 binned-sah-par)" build_ms_median)")
    fi
  done
  t_avx=$(printf '%s\n' "${avx_ms[@]}" | med)
  # The 1-thread verdict's reference: the single-thread build where there is one.
  t_ref=$t_avx ref="threaded anchor"
  echo
  echo "$(basename "$scene"), $rounds rounds x $runs runs; tinybvh BuildAVX ${t_avx} ms as ../shared/tools builds it (threaded; rounds: ${avx_ms[*]}), SAH $avx_sah"
  t1=$( { printf '%s\n' "${avx1_ms[@]}" | grep . || true; } | med)
  if [[ -n "$anchor1" && -n "$t1" ]]; then
    t_ref=$t1 ref="BuildAVX 1 thread"
    # The single-thread build must be the same tree (its header may be another tinybvh version).
    [[ "$avx1_sah" == "$avx_sah" ]] || echo "warning: the 1-thread anchor's SAH $avx1_sah differs from the threaded anchor's $avx_sah" >&2
    t_par=$(printf '%s\n' "${par2_ms[@]}" | med)
    echo "tinybvh BuildAVX 1 thread (-DNO_THREADED_BUILDS): ${t_ref} ms (rounds: ${avx1_ms[*]}); bvhlab binned-sah-par on 2 threads: ${t_par} ms (rounds: ${par2_ms[*]}) = $(awk -v a="$t_par" -v b="$t_avx" 'BEGIN { printf "%.2f", a / b }')x the threaded anchor"
  fi
  col1="vs 1-thr"
  [[ "$t_ref" == "$t_avx" ]] && col1="vs thread"
  printf '%-32s %9s %-26s %9s %10s %10s %9s %s\n' "variant (1 thread)" ms rounds sah_cost "$col1" "vs thread" sah_vs "verdict (vs $ref)"
  IFS=, read -ra names <<<"$variants"
  for name in "${names[@]}"; do
    t=$(tr ' ' '\n' <<<"${ms[$name]}" | grep . | med)
    ratio=$(awk -v a="$t" -v b="$t_ref" 'BEGIN { printf "%.2f", a / b }')
    ratio_mt=$(awk -v a="$t" -v b="$t_avx" 'BEGIN { printf "%.2f", a / b }')
    rel=$(awk -v a="${sah[$name]}" -v b="$avx_sah" 'BEGIN { printf "%+.1f%%", (a / b - 1) * 100 }')
    ok=$(awk -v r="$ratio" -v a="${sah[$name]}" -v b="$avx_sah" 'BEGIN { print (r <= 1.0 && a <= b * 1.01) ? "PASS" : "MISS" }')
    printf '%-32s %9s %-26s %9s %10s %10s %9s %s\n' "$name" "$t" "$(echo ${ms[$name]})" "${sah[$name]}" "${ratio}x" "${ratio_mt}x" "$rel" "$ok"
  done
  unset ms sah
done
echo
echo "load after: $(uptime)"
