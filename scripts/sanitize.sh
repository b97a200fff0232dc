#!/usr/bin/env bash
# Builds visloc with AddressSanitizer + UndefinedBehaviorSanitizer (gcc,
# -DVISLOC_SANITIZE=ON, any UB finding is fatal) in build-asan/ and runs the
# test suite under it:
#   scripts/sanitize.sh              the whole suite
#   scripts/sanitize.sh -L LABEL...  extra ctest arguments (e.g. a label subset)
# LeakSanitizer runs too; fuzz/lsan.supp lists the only suppression (FAISS's
# readers leak when they throw on a corrupted index).
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=build-asan
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$PWD/fuzz/lsan.supp}"
if [ ! -f "$BUILD/build.ninja" ]; then
  cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DVISLOC_SANITIZE=ON -DVISLOC_BUILD_BENCH=OFF -DVISLOC_BUILD_PYTHON=OFF \
    > "$BUILD.configure.log" 2>&1 || { tail -20 "$BUILD.configure.log"; exit 1; }
fi
cmake --build "$BUILD" -j "${JOBS:-$(nproc)}"
ctest --test-dir "$BUILD" --output-on-failure -j "$(nproc)" --timeout 1800 "$@"
