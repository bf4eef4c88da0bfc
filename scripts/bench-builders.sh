#!/usr/bin/env bash
# Builder speed and quality side by side with the Embree anchor, in the same run on the same machine
# (DEVELOPERS.md: speed targets are ratios to ../shared/tools/embree-anchor, release build, medians).
#
# Usage:
#   scripts/bench-builders.sh SCENE [runs=5] [threads=1] [BUILDERS]
#       One scene: our builders (all, or the comma-separated BUILDERS; see build_bench.rs) in a rayon
#       pool of THREADS threads, Embree's builders with the same thread count, and a table.
#       SCENE: path to .obj/.obj.gz (Embree needs a file) or gen:... (then only our builders run).
#   scripts/bench-builders.sh morton [runs=5]
#       The Morton-family issue's speed targets in one run, each with PASS/MISS:
#       (a) stanford_dragon, 2 threads: PLOC r=10 total (encode + build + collapse) <= 2x Embree's
#           2-thread binned SAH build;
#       (b) stanford_dragon: parallel binned SAH at 2 threads >= 1.8x faster than our sequential
#           binned SAH (1 thread), and the same tree (equal bvh_fnv);
#       (c) conference, 1 thread: AAC fast (total) faster than our binned SAH;
#       (d) radix sort of 10M 64-bit codes at 2 threads < 0.5 s (crates/morton/examples/radix_bench.rs).
#
# Times are medians of `runs` runs. For the Morton family the total is encode (codes + sort) + build
# + SAH compaction, and the table also shows the three parts (each part's own median).
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
shared="$repo/../shared"
anchor="$shared/tools/embree-anchor"
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$repo/target}
bench="$CARGO_TARGET_DIR/release/examples/build_bench"

mode=${1:?usage: scripts/bench-builders.sh SCENE [runs=5] [threads=1] [BUILDERS] | morton [runs=5]}
runs=${2:-5}

cargo build --quiet --release -p bvhlab-builders --example build_bench --manifest-path "$repo/Cargo.toml"

# Pull a number field out of a one-line JSON object (no jq dependency).
field() { sed -n "s/.*\"$2\":\([-0-9.eE+]*\).*/\1/p" <<<"$1"; }
sfield() { sed -n "s/.*\"$2\":\"\([^\"]*\)\".*/\1/p" <<<"$1"; }
# Embree's binned SAH (MEDIUM quality) and Morton (LOW) medians out of its JSON line.
embree_part() { sed -n "s/.*\"$2\":{\([^}]*\)}.*/\1/p" <<<"$1"; }
# The line of builder $2 in the JSON lines $1.
line_of() { grep -F "\"builder\":\"$2\"" <<<"$1" | head -n 1 || true; }
ratio() { awk -v a="$1" -v b="$2" 'BEGIN { if (a == "" || b == "" || b + 0 == 0) print "-"; else printf "%.2f", a / b }'; }

# Our table: one row per JSON line; ratio to Embree's binned SAH when $2 (its median ms) is given.
table() {
  local lines=$1 emb_ms=${2:-} emb_sah=${3:-}
  printf '\n%-20s %3s %10s %9s %9s %10s %7s %9s %8s %17s\n' builder thr total_ms encode build embree_bin ratio sah_cost emb_sah bvh_fnv
  while IFS= read -r line; do
    [[ -z "$line" ]] && continue
    local name thr
    name=$(sfield "$line" builder)
    thr=$(field "$line" threads)
    if grep -q '"error"' <<<"$line"; then
      printf '%-20s %3s %s\n' "$name" "$thr" "$(sfield "$line" error)"
      continue
    fi
    local ms
    ms=$(field "$line" build_ms_median)
    printf '%-20s %3s %10s %9s %9s %10s %7s %9s %8s %17s\n' "$name" "$thr" "$ms" \
      "$(field "$line" encode_ms_median)" "$(field "$line" build_part_ms_median)" \
      "${emb_ms:--}" "$(ratio "$ms" "$emb_ms")" \
      "$(field "$line" sah_cost)" "${emb_sah:--}" "$(sfield "$line" bvh_fnv)"
  done <<<"$lines"
}

if [[ "$mode" != morton ]]; then
  scene=$mode
  threads=${3:-1}
  builders=${4:-all}
  ours=$("$bench" "$scene" "$runs" "$threads" "$builders")
  echo "$ours"
  embree=""
  if [[ "$scene" != gen:* && -x "$anchor" ]]; then
    embree=$("$anchor" "$scene" "$threads" "$runs")
    echo "$embree"
  else
    echo "(no Embree anchor for $scene)" >&2
  fi
  medium=$(embree_part "$embree" medium_binned_sah)
  table "$ours" "$(field "$medium" build_ms_median)" "$(field "$medium" sah_cost)"
  exit 0
fi

# ---- morton mode: the issue's comparisons -------------------------------------------------------
# DRAGON / CONFERENCE override the scenes (e.g. gen:... for a quick check of this script).
dragon=${DRAGON:-$shared/scenes/stanford_dragon.obj.gz}
conference=${CONFERENCE:-$shared/scenes/conference.obj.gz}
morton_family="lbvh,aac-hq,aac-fast,ploc-10,ploc-25,ploc-100"

echo "== stanford_dragon, 1 thread: sequential binned SAH"
d1=$("$bench" "$dragon" "$runs" 1 binned-sah) || echo "(build_bench failed)" >&2
echo "$d1"
echo "== stanford_dragon, 2 threads: parallel binned SAH and the Morton family"
d2=$("$bench" "$dragon" "$runs" 2 "binned-sah-par,$morton_family") || echo "(build_bench failed)" >&2
echo "$d2"
emb_d2=""
if [[ -x "$anchor" && "$dragon" != gen:* ]]; then
  emb_d2=$("$anchor" "$dragon" 2 "$runs")
  echo "$emb_d2"
fi
echo "== conference, 1 thread: binned SAH and the Morton family"
c1=$("$bench" "$conference" "$runs" 1 "binned-sah,$morton_family") || echo "(build_bench failed)" >&2
echo "$c1"
emb_c1=""
if [[ -x "$anchor" && "$conference" != gen:* ]]; then
  emb_c1=$("$anchor" "$conference" 1 "$runs")
  echo "$emb_c1"
fi
radix_ms=""
if [[ -f "$repo/crates/morton/examples/radix_bench.rs" ]]; then
  echo "== radix sort, 10M codes"
  cargo build --quiet --release -p bvhlab-morton --example radix_bench --manifest-path "$repo/Cargo.toml"
  radix=$("$CARGO_TARGET_DIR/release/examples/radix_bench" 10000000 "$runs" || true)
  echo "$radix"
  # The line of our radix sort at 2 threads: "radix::sort_with_index ... threads=2 median_ms=X".
  radix_ms=$(grep -E '^radix::sort_with_index .*threads=2 ' <<<"$radix" | sed -n 's/.*median_ms=\([0-9.]*\).*/\1/p' | head -n 1 || true)
else
  echo "(crates/morton/examples/radix_bench.rs not found: target (d) skipped)" >&2
fi

med_d2=$(embree_part "$emb_d2" medium_binned_sah)
echo
echo "stanford_dragon, 1 and 2 threads (embree_bin = Embree binned SAH at 2 threads):"
table "$d1"$'\n'"$d2" "$(field "$med_d2" build_ms_median)" "$(field "$med_d2" sah_cost)"
low_d2=$(embree_part "$emb_d2" low_morton)
echo "Embree 2 threads: binned SAH $(field "$med_d2" build_ms_median) ms (SAH $(field "$med_d2" sah_cost)), Morton $(field "$low_d2" build_ms_median) ms (SAH $(field "$low_d2" sah_cost))"
med_c1=$(embree_part "$emb_c1" medium_binned_sah)
echo
echo "conference, 1 thread (embree_bin = Embree binned SAH at 1 thread):"
table "$c1" "$(field "$med_c1" build_ms_median)" "$(field "$med_c1" sah_cost)"
low_c1=$(embree_part "$emb_c1" low_morton)
echo "Embree 1 thread: binned SAH $(field "$med_c1" build_ms_median) ms (SAH $(field "$med_c1" sah_cost)), Morton $(field "$low_c1" build_ms_median) ms (SAH $(field "$low_c1" sah_cost))"

# verdict NAME VALUE OP LIMIT: PASS when VALUE OP LIMIT holds, MISS otherwise, n/a without a value.
verdict() {
  awk -v v="$1" -v op="$2" -v l="$3" 'BEGIN {
    if (v == "" || v == "-") { print "n/a"; exit }
    ok = (op == "<=") ? (v <= l) : (op == ">=") ? (v >= l) : (op == "<") ? (v < l) : (v > l)
    print ok ? "PASS" : "MISS" }'
}
ms_of() { field "$(line_of "$1" "$2")" build_ms_median; }

ploc_ms=$(ms_of "$d2" ploc-10)
emb_bin2=$(field "$med_d2" build_ms_median)
ra=$(ratio "$ploc_ms" "$emb_bin2")
seq_ms=$(ms_of "$d1" binned-sah)
par_ms=$(ms_of "$d2" binned-sah-par)
rb=$(ratio "$seq_ms" "$par_ms")
same_tree=no
[[ -n "$seq_ms" && "$(sfield "$(line_of "$d1" binned-sah)" bvh_fnv)" == "$(sfield "$(line_of "$d2" binned-sah-par)" bvh_fnv)" ]] && same_tree=yes
bin_c=$(ms_of "$c1" binned-sah)
aac_c=$(ms_of "$c1" aac-fast)
rc=$(ratio "$bin_c" "$aac_c")

echo
printf '%-74s %10s %10s %8s %9s %5s\n' target ours reference ratio goal verdict
printf '%-74s %10s %10s %8s %9s %5s\n' "(a) dragon 2 thr: PLOC r=10 total / Embree binned SAH (ms)" "${ploc_ms:--}" "${emb_bin2:--}" "$ra" "<= 2.00" "$(verdict "$ra" "<=" 2)"
printf '%-74s %10s %10s %8s %9s %5s\n' "(b) dragon: our binned 1 thr / parallel binned 2 thr (ms; same tree: $same_tree)" "${par_ms:--}" "${seq_ms:--}" "$rb" ">= 1.80" "$(verdict "$rb" ">=" 1.8)"
printf '%-74s %10s %10s %8s %9s %5s\n' "(c) conference 1 thr: our binned SAH / AAC fast total (ms)" "${aac_c:--}" "${bin_c:--}" "$rc" "> 1.00" "$(verdict "$rc" ">" 1)"
printf '%-74s %10s %10s %8s %9s %5s\n' "(d) radix sort 10M 64-bit codes, 2 thr (ms)" "${radix_ms:--}" "-" "-" "< 500" "$(verdict "$radix_ms" "<" 500)"
