#!/usr/bin/env bash
# Issue 6 measurement: SIGKILL a cold `bvhlab sweep` of an experiment at N random moments; after
# each kill, check `cache verify` (nothing half-written is visible), resume the sweep on the same
# cache to completion, compare its results.csv rows (timing columns, the per-pass trace and cache
# paths removed) with a clean reference run, and check `cache verify` again.
#
#   scripts/kill-resume.sh                      # 20 kills of experiments/quick.toml
#   N=5 EXP=experiments/quick.toml BIN=... scripts/kill-resume.sh
#
# Uses the release binary (cargo build --release -p bvhlab). Prints one line per kill and
# "K/N correct resumptions". Exit 0 iff all N are correct. Work dir: $WORK (default: a temp dir;
# caches of failed iterations are kept there for inspection).
set -u
cd "$(dirname "$0")/.."
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/release/bvhlab}
EXP=${EXP:-experiments/quick.toml}
N=${N:-20}
THREADS=${THREADS:-2}
WORK=${WORK:-$(mktemp -d -t bvhlab-kill-XXXXXX)}
mkdir -p "$WORK"
SEED=${SEED:-$$}
RANDOM=$SEED
[ -x "$BIN" ] || { echo "no binary $BIN (cargo build --release -p bvhlab)" >&2; exit 2; }
unset BVHLAB_CACHE

compare() { # reference.csv candidate.csv -> exit 0 iff equal rows minus timings
python3 - "$1" "$2" <<'PY'
import csv, sys
def rows(p):
    with open(p, newline='') as f:
        r = list(csv.reader(f))
    h = r[0]
    keep = [i for i, c in enumerate(h) if not ('seconds' in c or 'mrays' in c or c in ('slowdown', 'optimize_trace', 'heatmap'))]
    return [h[i] for i in keep], [[row[i] for i in keep] for row in r[1:]]
ha, a = rows(sys.argv[1]); hb, b = rows(sys.argv[2])
if ha != hb: print("columns differ"); sys.exit(1)
bad = [i for i, (x, y) in enumerate(zip(a, b)) if x != y]
if len(a) != len(b): print(f"{len(a)} vs {len(b)} rows"); sys.exit(1)
if bad:
    x, y = a[bad[0]], b[bad[0]]
    d = [(ha[j], x[j], y[j]) for j in range(len(x)) if x[j] != y[j]]
    print(f"{len(bad)} rows differ, first: row {bad[0]}: {d[:4]}"); sys.exit(1)
PY
}

now() { date +%s.%N; }
t0=$(now)
"$BIN" sweep "$EXP" --cache "$WORK/ref" --out "$WORK/ref-rep" --threads "$THREADS" > "$WORK/ref.json" 2> "$WORK/ref.err" \
  || { echo "reference run failed: $(tail -3 "$WORK/ref.err")"; exit 1; }
T=$(echo "$(now) - $t0" | bc)
TMS=$(printf '%.0f' "$(echo "$T * 1000" | bc)")
echo "reference: cold sweep of $EXP in ${T%.*} s: $(cat "$WORK/ref.json")"

ok=0
failures=()
for i in $(seq 1 "$N"); do
  d=$(( (RANDOM * 32768 + RANDOM) % TMS ))
  c="$WORK/c$i"; r="$WORK/r$i"
  "$BIN" sweep "$EXP" --cache "$c" --out "$r" --threads "$THREADS" > /dev/null 2>&1 &
  pid=$!
  sleep "$(printf '%d.%03d' $((d / 1000)) $((d % 1000)))"
  if kill -9 "$pid" 2>/dev/null; then state="killed at ${d} ms"; else state="finished before ${d} ms"; fi
  wait "$pid" 2>/dev/null
  problems=""
  v1=$("$BIN" cache verify --cache "$c" 2>&1) || problems="verify after kill: $(echo "$v1" | tail -2 | tr '\n' ' ')"
  res=$("$BIN" sweep "$EXP" --cache "$c" --out "$r" --threads "$THREADS" 2> "$WORK/resume$i.err") \
    || problems="$problems resume failed: $(tail -2 "$WORK/resume$i.err" | tr '\n' ' ')"
  if [ -f "$r/results.csv" ]; then
    diff=$(compare "$WORK/ref-rep/results.csv" "$r/results.csv") || problems="$problems rows differ: $diff"
  else
    problems="$problems no results.csv"
  fi
  v2=$("$BIN" cache verify --cache "$c" 2>&1) || problems="$problems verify after resume: $(echo "$v2" | tail -2 | tr '\n' ' ')"
  counts=$(echo "$res" | tail -1 | python3 -c 'import json,sys; v=json.loads(sys.stdin.read()); print("resume computed %s cached %s" % (v["computed"], v["cached"]))' 2>/dev/null)
  stale=$(echo "$v1" | tail -1 | python3 -c 'import json,sys; v=json.loads(sys.stdin.read()); print("stale temp %s, incomplete %s" % (v["stale_temp"], v["incomplete"]))' 2>/dev/null)
  if [ -z "$problems" ]; then
    ok=$((ok + 1)); echo "kill $i: $state; after kill: $stale; $counts; OK"
    rm -rf "$c" "$r"
  else
    failures+=("$i"); echo "kill $i: $state; $counts; FAILED: $problems"
  fi
done
echo "$ok/$N correct resumptions${failures:+ (failed: ${failures[*]}; see $WORK)}"
[ "$ok" -eq "$N" ] && rm -rf "$WORK/ref" 
[ "$ok" -eq "$N" ]
