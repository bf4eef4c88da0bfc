#!/usr/bin/env bash
# issue 19.4: binned SAH build time and SAH cost against tinybvh's BuildAVX (../shared/tools/tinybvh-anchor),
# 1 thread, build by build alternated with BuildAVX (ours, anchor, anchor, ours, ...).
#
# Usage: scripts/bench-binned.sh [runs=11] [rounds=3] [VARIANTS] [SCENES...]
#   VARIANTS: comma-separated build_bench names (default: the thesis configuration `binned-sah`
#   (16 bins), the same with 32 bins, and the all-axes ones `binned-sah:axes=all:bins=8`,
#   `binned-sah:axes=all`).
#   SCENES: default stanford_dragon and conference from ../shared/scenes.
# Each round runs every variant in one build_bench process that alternates its `runs` builds one by one with
# those of tinybvh's BuildAVX on one thread, served by a second process that loaded the scene once
# (scripts/anchors/tinybvh_buildavx_serve.cpp; BUILD_BENCH_PAIR), the order alternating: this machine's
# speed drifts by 20-40 % within minutes, even between processes seconds apart, and builds milliseconds
# apart see the same phase. The table shows the median times, the SAH costs, the median of the rounds'
# paired-ratio medians with how many pairs were faster, and the goal (paired ratio <= 1.00x at SAH <=
# BuildAVX's + 1 %). Where the served BuildAVX cannot be built, a variant's process is paired with an
# anchor process right before or after it instead. `uptime` is printed before and after.
#
# ../shared/tools/tinybvh-anchor is not single-threaded: tinybvh builds scenes of 50k+ triangles with its
# job system (MT_BUILD_THRESHOLD; measured: up to 60 threads and both cores busy during its builds). Where
# tiny_bvh.h is found (TINYBVH_H, or the tinybvh-rs crate's copy in the cargo registry) and g++ is there,
# scripts/anchors/build.sh builds the anchor's source with -DNO_THREADED_BUILDS (same trees, same SAH) into
# the target dir, and the served BuildAVX from it: the 1-thread verdict is against that build, and bvhlab's
# parallel build on 2 threads (binned-sah-par) is put beside the threaded anchor.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
shared="$repo/../shared"
anchor="$shared/tools/tinybvh-anchor"
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$repo/target}
bench="$CARGO_TARGET_DIR/release/examples/build_bench"
runs=${1:-11}
rounds=${2:-3}
variants=${3:-binned-sah,binned-sah:bins=32,binned-sah:axes=all:bins=8,binned-sah:axes=all}
shift $(( $# < 3 ? $# : 3 ))
scenes=("$@")
[[ ${#scenes[@]} -gt 0 ]] || scenes=("$shared/scenes/stanford_dragon.obj.gz" "$shared/scenes/conference.obj.gz")
[[ -x "$anchor" ]] || { echo "missing $anchor" >&2; exit 1; }
# NO_BUILD=1 uses the build_bench binary as it is (e.g. while another cargo command holds the target dir).
[[ -n "${NO_BUILD:-}" ]] || cargo build --quiet --release -p bvhlab-builders --example build_bench --manifest-path "$repo/Cargo.toml"

# The single-thread anchor and the served BuildAVX (see above), if they can be built here.
source "$repo/scripts/anchors/build.sh"
serve=$serve_build

field() { sed -n "s/.*\"$2\":\([-0-9.eE+]*\).*/\1/p" <<<"$1"; }
part() { sed -n "s/.*\"$2\":{\([^}]*\)}.*/\1/p" <<<"$1"; }
med() { sort -g | awk '{a[NR]=$1} END {if (NR == 0) print ""; else if (NR % 2) print a[(NR+1)/2]; else printf "%.2f\n", (a[NR/2]+a[NR/2+1])/2}'; }

# Without the served BuildAVX, each of bvhlab's processes is paired with an anchor process right before
# or after it (the full single-thread anchor where it was built, else the threaded one).
pair_anchor=${anchor1:-$anchor}
[[ -x "$pair_anchor" ]] || pair_anchor=$anchor
echo "load before: $(uptime)"
for scene in "${scenes[@]}"; do
  declare -A ms=() sah=() ratio=() ams=() fast=()
  avx_ms=() avx_sah="" avx1_sah="" par2_ms=()
  IFS=, read -ra names <<<"$variants"
  for ((r = 0; r < rounds; r++)); do
    for ((v = 0; v < ${#names[@]}; v++)); do
      name=${names[$v]}
      if [[ -n "$serve" ]]; then
        # Build by build: build_bench alternates its builds with the served BuildAVX's.
        out=$(BUILD_BENCH_PAIR="$serve" "$bench" "$scene" "$runs" 1 "$name")
        t=$(field "$out" build_ms_median)
        ta=$(field "$out" anchor_ms_median)
        rr=$(field "$out" paired_ratio_median)
        f=$(sed -n 's/.*"paired_faster":"\([0-9]*\)\/.*/\1/p' <<<"$out")
        avx1_sah=$(field "$out" anchor_sah)
      else
        ours() { out=$("$bench" "$scene" "$runs" 1 "$name"); }
        theirs() { a=$(part "$("$pair_anchor" "$scene" "$runs" || true)" binned_sah_avx); }
        # Adjacent processes, the order alternating, so neither side always runs first.
        if (( (r + v) % 2 == 0 )); then ours; theirs; else theirs; ours; fi
        t=$(field "$out" build_ms_median)
        ta=$(field "$a" build_ms_median)
        rr=$(awk -v a="$t" -v b="$ta" 'BEGIN { printf "%.3f", a / b }')
        f=$(awk -v r="$rr" -v n="$runs" 'BEGIN { print (r < 1) ? n : 0 }')
        avx1_sah=$(printf '%.3f' "$(field "$a" sah_cost)")
      fi
      ms[$name]="${ms[$name]:-} $t"
      ams[$name]="${ams[$name]:-} $ta"
      ratio[$name]="${ratio[$name]:-} $rr"
      fast[$name]=$(( ${fast[$name]:-0} + f ))
      sah[$name]=$(field "$out" sah_cost)
    done
    # The threaded anchor (as ../shared/tools builds it) and bvhlab's 2-thread build beside it, every
    # other round (the anchor runs all its builders and a trace: ~20 s on the dragon).
    if (( r % 2 == 0 )); then
      avx=$(part "$("$anchor" "$scene" "$runs")" binned_sah_avx)
      avx_ms+=("$(field "$avx" build_ms_median)")
      avx_sah=$(field "$avx" sah_cost)
      par2_ms+=("$(field "$("$bench" "$scene" "$runs" 2 binned-sah-par)" build_ms_median)")
    fi
  done
  t_avx=$(printf '%s\n' "${avx_ms[@]}" | med)
  t_par=$(printf '%s\n' "${par2_ms[@]}" | med)
  echo
  echo "$(basename "$scene"), $rounds rounds x $runs runs; tinybvh BuildAVX ${t_avx} ms as ../shared/tools builds it (threaded; rounds: ${avx_ms[*]}), SAH $avx_sah; bvhlab binned-sah-par on 2 threads: ${t_par} ms (rounds: ${par2_ms[*]}) = $(awk -v a="$t_par" -v b="$t_avx" 'BEGIN { printf "%.2f", a / b }')x the threaded anchor"
  ref="BuildAVX 1 thread"
  [[ -n "$serve" || "$pair_anchor" != "$anchor" ]] || ref="threaded anchor"
  # The single-thread build must be the same tree (its header may be another tinybvh version).
  awk -v a="$avx1_sah" -v b="$avx_sah" 'BEGIN { exit (a - b < 0.01 && b - a < 0.01) ? 0 : 1 }' \
    || echo "warning: the paired anchor's SAH $avx1_sah differs from the threaded anchor's $avx_sah" >&2
  if [[ -n "$serve" ]]; then
    echo "each build paired with one of $ref ($(basename "$serve")) in the same process pair, the order alternating; ratio = median over the $rounds rounds of each round's median of $runs paired ratios; faster = pairs with a ratio below 1"
  else
    echo "each variant's process paired with $ref ($(basename "$pair_anchor")) in the adjacent process; ratio = median of the $rounds paired ratios; faster = runs of the faster rounds"
  fi
  printf '%-28s %8s %8s %8s %8s %9s %10s %8s %s\n' "variant (1 thread)" ms anchor ratio faster sah_cost "vs thread" sah_vs "verdict (vs $ref)"
  for name in "${names[@]}"; do
    t=$(tr ' ' '\n' <<<"${ms[$name]}" | grep . | med)
    ta=$(tr ' ' '\n' <<<"${ams[$name]}" | grep . | med)
    rr=$(tr ' ' '\n' <<<"${ratio[$name]}" | grep . | med)
    faster="${fast[$name]}/$(( rounds * runs ))"
    ratio_mt=$(awk -v a="$t" -v b="$t_avx" 'BEGIN { printf "%.2f", a / b }')
    rel=$(awk -v a="${sah[$name]}" -v b="$avx_sah" 'BEGIN { printf "%+.1f%%", (a / b - 1) * 100 }')
    ok=$(awk -v r="$rr" -v a="${sah[$name]}" -v b="$avx_sah" 'BEGIN { print (r <= 1.0 && a <= b * 1.01) ? "PASS" : "MISS" }')
    printf '%-28s %8s %8s %7sx %8s %9s %9sx %8s %s\n' "$name" "$t" "$ta" "$rr" "$faster" "${sah[$name]}" "$ratio_mt" "$rel" "$ok"
    echo "  paired ratios: ${ratio[$name]# }"
  done
  unset ms sah ratio ams fast
done
echo
echo "load after: $(uptime)"
