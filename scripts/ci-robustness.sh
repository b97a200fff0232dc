#!/usr/bin/env bash
# What CI runs after the test suite (issue #20; docs/robustness.md), in one
# clang build, build-fuzz/, where every target carries AddressSanitizer +
# UndefinedBehaviorSanitizer (any finding fatal) and libFuzzer's coverage:
#   1. the test suite under the sanitizers (LeakSanitizer on; fuzz/lsan.supp
#      lists the only suppression, a FAISS leak on corrupted input);
#   2. every libFuzzer target for FUZZ_SECONDS (default 30) seconds
#      (scripts/fuzz.sh; any crash, leak, out-of-memory or timeout fails).
# Installs clang and its libFuzzer runtime when missing (Debian packages).
# Environment: SANITIZE_CTEST_ARGS (ctest arguments instead of the default,
# which runs every test but the three slowest integration tests (the small
# city benchmark, map build killed and resumed, map build on Slurm): minutes
# each under ASan, and they run unsanitized in scripts/test.sh; "all": every
# test), FUZZ_SECONDS,
# JOBS. scripts/sanitize.sh is the same suite built with gcc.
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
for p in clang libclang-rt-14-dev; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || need+=("$p")
done
if [ ${#need[@]} -gt 0 ]; then
  echo "ci-robustness: installing ${need[*]}"
  SUDO=""
  [ "$(id -u)" = "0" ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

t0=$(date +%s)
echo "== ci-robustness: building build-fuzz/ (clang, ASan + UBSan + libFuzzer coverage): tests, CLI, fuzz targets"
# fuzz.sh configures build-fuzz/, builds everything and makes the seeds.
FUZZ_BUILD_TARGET=all scripts/fuzz.sh --build-only
t1=$(date +%s)
echo "== ci-robustness: the test suite under ASan + UBSan"
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
export ASAN_OPTIONS="detect_leaks=1:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
export LSAN_OPTIONS="suppressions=$PWD/fuzz/lsan.supp:print_suppressions=0"
ctest_args=(-E "eval.CityBenchmark.SmallCityRunsAndResumes|cli.map_build_kill_and_resume|cli.map_build_slurm")
case "${SANITIZE_CTEST_ARGS:-}" in
  "") ;;                   # unset or empty: the default above
  all) ctest_args=() ;;    # every test
  *) read -r -a ctest_args <<<"$SANITIZE_CTEST_ARGS" ;;  # words, no glob expansion
esac
# --no-tests=error: a build without tests (or a filter that matches none) must not pass.
ctest --test-dir build-fuzz --output-on-failure --no-tests=error -j "$(nproc)" --timeout 1800 ${ctest_args[@]+"${ctest_args[@]}"}
unset ASAN_OPTIONS UBSAN_OPTIONS LSAN_OPTIONS
t2=$(date +%s)
echo "== ci-robustness: every fuzz target for ${FUZZ_SECONDS:-30} s"
scripts/fuzz.sh "${FUZZ_SECONDS:-30}"
t3=$(date +%s)
echo "ci-robustness: build $((t1 - t0)) s, sanitized suite $((t2 - t1)) s, fuzzing $((t3 - t2)) s"
