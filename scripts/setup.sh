#!/usr/bin/env bash
# Installs what bvhlab needs beyond the Rust toolchain, when missing. Safe to re-run.
set -euo pipefail
need=()
command -v pkg-config >/dev/null 2>&1 || need+=(pkg-config)
# plotters renders text through fontconfig/freetype (report crate): headers to build, a font to draw.
pkg-config --exists fontconfig 2>/dev/null || need+=(libfontconfig1-dev)
ls /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf >/dev/null 2>&1 || need+=(fonts-dejavu-core)
# The report is checked in headless Chromium (crates/cli/tests/browser.rs): images, links, scripts.
command -v chromium >/dev/null 2>&1 || need+=(chromium)
# Embree 3 for the peer builders (crates/peers): linked wherever libembree3.so is found at build time.
[ -e /usr/include/embree3/rtcore.h ] || need+=(libembree-dev)
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
  else
    echo "please install: ${need[*]}" >&2
  fi
fi
# The justfile's recipes (`just sweep`, `just peers`, ...): not packaged in Debian 12, so from
# crates.io, pinned (about 2 minutes of compiling, once).
if ! command -v just >/dev/null 2>&1; then
  cargo install --quiet --locked just --version 1.59.0
fi
