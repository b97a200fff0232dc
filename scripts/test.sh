#!/usr/bin/env bash
# Runs the whole test suite (unit tests; real-data tests skip when
# ../shared/data is absent). Builds first if needed.
set -euo pipefail
cd "$(dirname "$0")/.."
# One OpenMP thread per test process: ctest runs tests in parallel, and
# FAISS/BLAS spinning on a busy 2-core machine makes tests crawl.
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
if [ ! -f build/build.ninja ]; then SKIP_APT=1 scripts/setup.sh; else cmake --build build -j "$(nproc)"; fi
ctest --test-dir build --output-on-failure -j "$(nproc)" "$@"
