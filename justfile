# bvhlab recipes. `just` alone runs the quick sweep.
set shell := ["bash", "-euo", "pipefail", "-c"]

default: sweep

# Run an experiment (cached: a re-run computes only what changed) and write reports/<name>/index.html.
sweep EXP="experiments/quick.toml" *ARGS="":
    cargo run --release -- sweep {{EXP}} {{ARGS}}

# The README's test command.
test:
    cargo test --workspace

# Rebuild the report of an experiment from the cache without computing anything (chains with a
# missing stage are left out and listed; exit 3 when any is).
report EXP="experiments/quick.toml":
    cargo run --release -- sweep {{EXP}} --report-only

# bvhlab's builders beside Embree 3 and obvhs as methods of one sweep (one thread), with the ratios table.
peers:
    cargo run --release -- sweep experiments/peers.toml --threads 1

# Peer builds inside bvhlab (embree-morton, embree-binned) against embree-anchor, alternated, with ratios.
bench-peers RUNS="5" ROUNDS="2":
    bash scripts/bench-peers.sh {{RUNS}} {{ROUNDS}}

# Builder speed and SAH cost beside Embree (../shared/tools/embree-anchor) in the same run.
bench SCENE="../shared/scenes/stanford_dragon.obj.gz":
    bash scripts/bench-builders.sh {{SCENE}}

# The paper reproduction on the nine shared scenes (several minutes cold).
frantal:
    cargo run --release -- sweep experiments/frantal-sah.toml

# Thesis tables 10 and 25: AAC (HQ, fast) and PLOC (r = 10, 25, 100) with Morton codes and EMC-64-var.
morton:
    cargo run --release -- sweep experiments/frantal-morton.toml

# Thesis tables 20 and 38 (and table 10's INC): FSW, BIN, INC with and without insertion-based optimization.
ibo:
    cargo run --release -- sweep experiments/frantal-ibo.toml

# Bittner 2013: ibo per measure and Kensler rotations from spatial-median and SAH trees; convergence plots.
bittner:
    cargo run --release -- sweep experiments/bittner-ibo.toml

# Thesis table 10 BP0/BP1/BP2: Bonsai mini-tree builds beside the full-sweep SAH.
bonsai:
    cargo run --release -- sweep experiments/bonsai.toml

# The Morton failure study (Riemersma 2024): far outlier e = 0..30 and a huge ground plane.
outliers:
    cargo run --release -- sweep experiments/morton-outliers.toml

# Kilian 2021: compressed layouts (qbvh_chunks, octree, octree_1bit by chunk size, frame, bits; auto) on the shared scenes,
# a hairball and a terrain; bytes per triangle vs trace time vs extra tests, findings table. Cold runtime not measured yet (no release build with the layout stage in time).
kilian:
    cargo run --release -- sweep experiments/kilian-chunks.toml

# Trace throughput, 1 thread, 10^6 random rays of the anchors' kind: bvhlab bvh2, bvh4, bvh8 (and bvh8 on
# 2 threads) beside Embree rtcIntersect1 and tinybvh BVH8_CPU run in the same invocation, once per round after
# bvhlab's runs, so both sides are medians of the same interleaved rounds (RUNS in each of PROCS processes, pooled);
# ratios of medians (issue 19). Where tiny_bvh.h and
# g++ are found, tinybvh's BVH8_CPU also traces bvhlab's own rays in a warm pass next to a warm extra pass of bvh8 at the end of every round (T-same,
# bvh8/Ts: the median of the paired ratios). Every side on transparent huge pages (bvhlab's timed layouts and Embree
# advise their memory; tinybvh runs with glibc.malloc.hugetlb=1); BVHLAB_THP=0: none of them.
# Scenes: stanford_dragon, conference, breakfast_room, stanford_bunny when present.
bench-trace RUNS="2" *SCENES="":
    #!/usr/bin/env bash
    set -euo pipefail
    scenes="{{SCENES}}"
    if [ -z "$scenes" ]; then
        for s in stanford_dragon conference breakfast_room stanford_bunny; do
            f=../shared/scenes/$s.obj.gz
            if [ -f "$f" ]; then scenes="$scenes $f"; else echo "skipping $s: $f not found" >&2; fi
        done
    fi
    echo "# uptime: $(uptime)"
    # The binary tree is built as tinybvh builds its BVH8_CPU's (BuildAVX: 8 bins on all axes), so the ratios compare
    # traversals over trees of one construction. AXES=largest: the thesis' binned SAH (16 bins, largest axis) instead.
    # BINS=N: N bins (default 8, or 16 with AXES=largest); AXES=largest BINS=32 is the build that passes issue 19's build target.
    # tinybvh's BVH8_CPU served over bvhlab's own rays (scripts/anchors/build.sh), paired with bvh8 per round: bvh8/Ts.
    repo=$PWD; source scripts/anchors/build.sh
    # RUNS rounds in each of PROCS processes (default 3; PROCS=1: one process, as before), pooled: one process's bvh8
    # median on the dragon ranged 2.79-3.62 Mrays/s over six processes (docs/decisions.md), while the anchors run a
    # process per round.
    cargo run --quiet --release -p bvhlab-layout --example bench_trace -- --runs {{RUNS}} --procs "${PROCS:-3}" --tools ../shared/tools --axes "${AXES:-all}" ${BINS:+--bins "$BINS"} ${serve_trace:+--tinybvh-serve "$serve_trace"} $scenes

# issue 19.4: binned SAH (thesis and all-axes configurations) against tinybvh's BuildAVX, alternated: 1 thread against
# the anchor built single-threaded (where tiny_bvh.h is found), 2 threads against the shared (threaded) anchor.
bench-binned RUNS="11" ROUNDS="3":
    bash scripts/bench-binned.sh {{RUNS}} {{ROUNDS}}

# Peak RSS and build heap of each builder on a scene (default the dragon), one process per builder.
mem SCENE="../shared/scenes/stanford_dragon.obj.gz":
    cargo build --quiet --release -p bvhlab-builders --example build_mem
    for b in spatial-median binned-sah binned-sah:axes=all:bins=8 sweep-sah lbvh aac-hq aac-fast ploc-10 ploc-25 bonsai-bp1; do ${CARGO_TARGET_DIR:-target}/release/examples/build_mem {{SCENE}} $b; done

# The Morton-family speed targets with PASS/MISS, beside Embree, in one run.
bench-morton RUNS="5":
    bash scripts/bench-builders.sh morton {{RUNS}}

# The optimization-family speed targets (ibo vs sweep-SAH build, Bonsai vs sweep SAH) with PASS/MISS.
bench-opt RUNS="5":
    bash scripts/bench-opt.sh {{RUNS}}

# What CI runs.
ci:
    bash .ci/run

# Fuzz a target (obj: the OBJ/.obj.gz loader; soup: triangle soups through every builder and layout)
# for SECONDS; installs cargo-fuzz when missing. Crashes land in fuzz/artifacts/TARGET/.
fuzz TARGET="soup" SECONDS="60":
    bash scripts/fuzz.sh {{TARGET}} {{SECONDS}}

# Scale invariance (issue 15) at N triangles per scene, release build: every method at 1e-30..1e30 and
# moved by 10^k extents, on the generated and (thinned) shared scenes; prints the cells above 1 %.
scale N="30000":
    SCALE_N={{N}} cargo test --release -p bvhlab-pipeline --test scale -- --nocapture --test-threads=1

# Every builder, compaction and layout vs brute force on the shared scenes with 10^5 random rays.
oracle-large *ARGS="":
    cargo run --release -p bvhlab-pipeline --example oracle_large -- {{ARGS}}

# Run an experiment on a Slurm cluster: a job array of TASKS shards over one shared cache (CACHE must be on
# a filesystem every node sees) plus a report job after it. Re-run to compute only what is missing.
cluster EXP="experiments/quick.toml" TASKS="16" *ARGS="":
    cargo build --release
    ./target/release/bvhlab slurm {{EXP}} --tasks {{TASKS}} --submit {{ARGS}}
