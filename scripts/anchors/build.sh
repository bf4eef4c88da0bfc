# Builds, where tiny_bvh.h and g++ are found, tinybvh programs for bvhlab's benchmarks into
# $CARGO_TARGET_DIR/anchors and sets (sourced from bash; REPO must be set: the repository's root):
#   anchor1      ../shared/tools/tinybvh_anchor.cpp with -DNO_THREADED_BUILDS (tinybvh's job system off: its
#                builds of 50k+ triangles otherwise use both cores);
#   serve_build  tinybvh_buildavx_serve.cpp (BuildAVX, one build per request: build_bench BUILD_BENCH_PAIR);
#   serve_trace  tinybvh_trace_serve.cpp (BVH8_CPU, one trace pass per request: bench_trace --tinybvh-serve).
# Each is empty when it cannot be built. tiny_bvh.h: TINYBVH_H, or the tinybvh-rs crate's copy in the
# cargo registry (fetched there on a fresh machine).
repo=${repo:-$REPO}
shared=${shared:-$repo/../shared}
anchor1="" serve_build="" serve_trace=""
# One of this directory's sources, compiled beside the anchor's source and header it includes.
serve_tool() {
  local src="$repo/scripts/anchors/$1.cpp" bin="$dir/$2"
  if [[ ! -x "$bin" || "$src" -nt "$bin" ]]; then
    if ! { cp "$src" "$dir/" && g++ -O3 -march=x86-64-v3 -std=c++17 -DNO_THREADED_BUILDS -I "$dir" "$dir/$1.cpp" -o "$bin" -lpthread; }; then
      echo "note: could not build $2" >&2
      return 0
    fi
  fi
  echo "$bin"
}
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
  dir="${CARGO_TARGET_DIR:-$repo/target}/anchors"
  anchor1="$dir/tinybvh-anchor-1t"
  # Rebuilt when the anchor source or the header is newer, or the header is another file.
  if [[ ! -x "$anchor1" || "$shared/tools/tinybvh_anchor.cpp" -nt "$anchor1" || "$header" -nt "$anchor1" ]] \
     || ! cmp -s "$header" "$dir/tiny_bvh.h"; then
    if ! { mkdir -p "$dir" && cp "$header" "$dir/tiny_bvh.h" && cp "$shared/tools/tinybvh_anchor.cpp" "$dir/" \
         && g++ -O3 -march=x86-64-v3 -std=c++17 -DNO_THREADED_BUILDS "$dir/tinybvh_anchor.cpp" -o "$anchor1" -lpthread; }; then
      echo "note: could not build the single-thread anchor: only the threaded one" >&2
      anchor1=""
    fi
    rm -f "$dir"/tinybvh-*-serve
  fi
  # BuildAVX served one build at a time (scripts/anchors/tinybvh_buildavx_serve.cpp, which includes the
  # anchor's source): build_bench alternates its own builds with this one's (BUILD_BENCH_PAIR).
  serve_build=$(serve_tool tinybvh_buildavx_serve tinybvh-buildavx-serve)
  # tinybvh's BVH8_CPU traversal served one pass at a time over rays bvhlab sends
  # (scripts/anchors/tinybvh_trace_serve.cpp): bench_trace --tinybvh-serve.
  serve_trace=$(serve_tool tinybvh_trace_serve tinybvh-trace-serve)
else
  echo "note: tiny_bvh.h, g++ or the anchor source not found: only the threaded anchor (set TINYBVH_H=path/to/tiny_bvh.h)" >&2
fi

