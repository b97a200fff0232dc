#!/usr/bin/env bash
# Builds and runs the libFuzzer targets of fuzz/ (one per file reader):
#   scripts/fuzz.sh [SECONDS] [TARGET...]     default: 30 s each, every target
#   scripts/fuzz.sh --build-only              build (and make the seeds), run nothing
# Configures build-fuzz/ with clang (-DVISLOC_FUZZ=ON) when needed, builds the
# custom target visloc_fuzzers, makes the seeds once (build-fuzz/seeds, from
# fuzz/make_seeds.sh), then runs each target for SECONDS. New inputs are kept
# in build-fuzz/corpus/TARGET, crashes in build-fuzz/artifacts/TARGET, logs in
# build-fuzz/logs/TARGET.log. Prints one line per target and exits non-zero
# if any target crashed, leaked, ran out of memory or timed out.
# Environment: JOBS (build, default 2), FUZZ_BUILD_TARGET (default visloc_fuzzers), FUZZ_MAX_LEN (bytes, default 1 MiB),
# FUZZ_FLAGS (more libFuzzer flags), VISLOC_SHARED_DATA_DIR (default ../shared/data).
set -uo pipefail
cd "$(dirname "$0")/.."
BUILD=build-fuzz
SECONDS_PER_TARGET=30
BUILD_ONLY=0
if [ "${1:-}" = "--build-only" ]; then BUILD_ONLY=1; shift; fi
if [[ "${1:-}" =~ ^[0-9]+$ ]]; then SECONDS_PER_TARGET=$1; shift; fi
MAX_LEN="${FUZZ_MAX_LEN:-1048576}"
DATA="${VISLOC_SHARED_DATA_DIR:-../shared/data}"
note() { echo "fuzz: $*" >&2; }

# --- Build (incremental) ---
if ! grep -q "^VISLOC_FUZZ:BOOL=ON" "$BUILD/CMakeCache.txt" 2>/dev/null ||
   ! grep -q "^VISLOC_BUILD_TESTS:BOOL=ON" "$BUILD/CMakeCache.txt" 2>/dev/null; then
  note "configuring $BUILD (clang, ASan + UBSan + libFuzzer)"
  CC=clang CXX=clang++ cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DVISLOC_BUILD_TESTS=ON -DVISLOC_BUILD_BENCH=OFF -DVISLOC_BUILD_PYTHON=OFF -DVISLOC_FUZZ=ON >"$BUILD.configure.log" 2>&1 ||
    { tail -20 "$BUILD.configure.log" >&2; exit 1; }
fi
note "building the fuzz targets"
# The tests are configured too (scripts/ci-robustness.sh runs them in this
# build: FUZZ_BUILD_TARGET=all); test discovery runs instrumented programs
# during the build, so no leak check there.
ASAN_OPTIONS=detect_leaks=0 nice cmake --build "$BUILD" -j "${JOBS:-2}" --target "${FUZZ_BUILD_TARGET:-visloc_fuzzers}" \
  >"$BUILD/build.log" 2>&1 ||
  { grep -E "error|FAILED" "$BUILD/build.log" | head -20 >&2; exit 1; }

# --- Seeds (once; delete build-fuzz/seeds to remake them) ---
[ -d "$DATA" ] || note "SKIP: $DATA is absent: seeds from the synthetic street and its map only"
if [ ! -f "$BUILD/seeds/.complete" ]; then
  note "making the seeds (fuzz/make_seeds.sh)"
  rm -rf "$BUILD/seeds"
  VISLOC_SHARED_DATA_DIR="$DATA" fuzz/make_seeds.sh "$BUILD/seeds" || exit 1
  touch "$BUILD/seeds/.complete"
fi

[ "$BUILD_ONLY" = 1 ] && exit 0

# --- Targets ---
if [ $# -gt 0 ]; then
  targets=("$@")
else
  mapfile -t targets < <(sed -n 's/^visloc_fuzzer(\([a-z0-9_]*\) .*/\1/p' fuzz/CMakeLists.txt)
fi
RUN_TMP="$(mktemp -d "/dev/shm/visloc-fuzz-run.XXXXXX" 2>/dev/null || mktemp -d)"
trap 'rm -rf "$RUN_TMP"' EXIT
# LeakSanitizer suppressions of third-party leaks, if any (fuzz/lsan.supp documents them).
LSAN_SUPP=""
[ -f fuzz/lsan.supp ] && LSAN_SUPP=":suppressions=$PWD/fuzz/lsan.supp"

failed=0
printf "%-26s %5s %10s %8s %6s %7s  %s\n" target secs execs exec/s cov ft result
for t in "${targets[@]}"; do
  exe="$BUILD/fuzz/${t}_fuzzer"
  if [ ! -x "$exe" ]; then
    printf "%-26s %s\n" "$t" "no such target ($exe)"
    failed=1
    continue
  fi
  corpus="$BUILD/corpus/$t" artifacts="$BUILD/artifacts/$t" log="$BUILD/logs/$t.log"
  mkdir -p "$corpus" "$artifacts" "$BUILD/logs" "$BUILD/seeds/$t"
  before=$(find "$artifacts" -type f | wc -l)
  start=$(date +%s)
  # Single-threaded OpenMP/BLAS: FAISS's thread pools are not what is tested.
  # In a subshell whose stderr is the log, so that a crash's "Aborted" goes there too.
  (OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 \
    VISLOC_FUZZ_REFERENCE="$PWD/$BUILD/seeds/reference" VISLOC_FUZZ_TMPDIR="$RUN_TMP" \
    ASAN_OPTIONS="abort_on_error=1:detect_leaks=1:allocator_may_return_null=0" \
    UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1" \
    LSAN_OPTIONS="print_suppressions=0$LSAN_SUPP" \
    "$exe" "$corpus" "$BUILD/seeds/$t" -max_total_time="$SECONDS_PER_TARGET" -timeout=10 \
    -rss_limit_mb=2048 -max_len="$MAX_LEN" -artifact_prefix="$artifacts/" -print_final_stats=1 \
    ${FUZZ_FLAGS:-}) >"$log" 2>&1
  rc=$?
  secs=$(($(date +%s) - start))
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  last=$(grep -E "^#[0-9]+" "$log" | grep -E "cov: " | tail -1)
  cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<<"$last")
  ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<<"$last")
  crashes=$(($(find "$artifacts" -type f | wc -l) - before))
  result="ok"
  if [ $rc -ne 0 ] || [ "$crashes" -gt 0 ]; then
    failed=1
    kind=$(grep -oE "ERROR: libFuzzer: [a-z-]+|ERROR: (AddressSanitizer|LeakSanitizer): [a-z-]+|runtime error|==visloc-fuzz== BUG" "$log" | head -1)
    result="CRASH x$crashes (${kind:-exit $rc}; see $log)"
  fi
  printf "%-26s %5s %10s %8s %6s %7s  %s\n" "$t" "$secs" "${execs:-?}" "${rate:-?}" "${cov:-?}" "${ft:-?}" "$result"
done
exit $failed
