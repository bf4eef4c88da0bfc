#!/usr/bin/env bash
# Runs a cargo-fuzz target for a bounded time: bash scripts/fuzz.sh TARGET SECONDS (targets: obj, soup).
# Installs cargo-fuzz (crates.io) when missing unless FUZZ_NO_INSTALL=1; without cargo-fuzz (or with
# FUZZ_PLAIN_CARGO=1) it builds the target with plain cargo and cargo-fuzz's instrumentation flags
# (what CI does: it cannot download toolchains, and installing cargo-fuzz takes minutes).
# Toolchain: nightly when installed, else stable with RUSTC_BOOTSTRAP=1 (libFuzzer's flags are -Z/-C
# flags of the nightly compiler; no sanitizer is needed for safe Rust: we hunt panics, not UB).
# Crashes land in fuzz/artifacts/TARGET/; the run's last line is libFuzzer's "Done N runs".
set -euo pipefail
cd "$(dirname "$0")/.."
target=${1:?usage: scripts/fuzz.sh TARGET SECONDS [extra libFuzzer args]}
seconds=${2:-60}
shift 2 || shift $#
case "$target" in obj|soup) ;; *) echo "unknown fuzz target '$target' (obj, soup)" >&2; exit 2 ;; esac

if rustup run nightly rustc --version >/dev/null 2>&1; then
  toolchain=(+nightly)
else
  toolchain=()
  export RUSTC_BOOTSTRAP=1
fi
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/fuzz/target}

if ! command -v cargo-fuzz >/dev/null 2>&1 && [ "${FUZZ_NO_INSTALL:-0}" != 1 ] && [ "${FUZZ_PLAIN_CARGO:-0}" != 1 ]; then
  echo "== installing cargo-fuzz (cargo install cargo-fuzz --locked)" >&2
  cargo install cargo-fuzz --locked
fi

corpus=fuzz/corpus/$target
mkdir -p "$corpus" "fuzz/artifacts/$target"
# Seed the obj corpus with a few small valid files so the fuzzer starts from real syntax.
if [ "$target" = obj ] && [ -z "$(ls -A "$corpus")" ]; then
  printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n' > "$corpus/tri.obj"
  printf 'v 0 0 0 1\nv 1 0 0\nv 0 1 0 0.5 0.5 0.5\nvt 0 0\nvn 0 0 1\nf 1/1/1 2//1 -1/1\nl 1 2\nusemtl x\nf 1 2 3 1\n' > "$corpus/mixed.obj"
fi
args=(-max_total_time="$seconds" -timeout=20 -rss_limit_mb=4096 -print_final_stats=1 "$@")

if command -v cargo-fuzz >/dev/null 2>&1 && [ "${FUZZ_PLAIN_CARGO:-0}" != 1 ]; then
  # --sanitizer none: safe Rust needs no ASan, and it keeps the execution rate up.
  cargo "${toolchain[@]}" fuzz run --sanitizer none --release --debug-assertions "$target" "$corpus" -- \
    -artifact_prefix="fuzz/artifacts/$target/" "${args[@]}"
else
  # cargo-fuzz 0.13's flags for `--sanitizer none --release --debug-assertions`, minus codegen-units=1
  # (a faster cold build in CI). All are stable -C/--cfg flags; only a sanitizer would need -Z.
  export RUSTFLAGS="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing -Cllvm-args=-simplifycfg-branch-fold-threshold=0 \
-Cllvm-args=-sanitizer-coverage-stack-depth -Cdebug-assertions"
  host=$(rustc "${toolchain[@]}" -vV | sed -n 's/^host: //p')
  cargo "${toolchain[@]}" build --manifest-path fuzz/Cargo.toml --release --bin "$target" --target "$host"
  "$CARGO_TARGET_DIR/$host/release/$target" "$corpus" -artifact_prefix="fuzz/artifacts/$target/" "${args[@]}"
fi
