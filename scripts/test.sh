#!/usr/bin/env bash
# Runs the whole test suite (unit tests; real-data tests skip when
# ../shared/data is absent). Builds first if needed.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -f build/build.ninja ]; then SKIP_APT=1 scripts/setup.sh; else cmake --build build -j "$(nproc)"; fi
ctest --test-dir build --output-on-failure -j "$(nproc)" "$@"
