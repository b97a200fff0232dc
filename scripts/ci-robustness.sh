#!/usr/bin/env bash
# What CI runs after the test suite (issue #20; docs/robustness.md):
#   1. the test suite built with AddressSanitizer + UndefinedBehaviorSanitizer
#      (scripts/sanitize.sh, build-asan/; any finding fails the test);
#   2. every libFuzzer target for FUZZ_SECONDS (default 30) seconds
#      (scripts/fuzz.sh, build-fuzz/; any crash, leak or timeout fails).
# Installs clang and its libFuzzer runtime when missing (Debian packages).
# Environment: SANITIZE_CTEST_ARGS (extra ctest arguments for the sanitized
# suite, e.g. "-LE cli"), FUZZ_SECONDS.
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
echo "== ci-robustness: the test suite under ASan + UBSan"
# shellcheck disable=SC2086
scripts/sanitize.sh ${SANITIZE_CTEST_ARGS:-}
t1=$(date +%s)
echo "== ci-robustness: every fuzz target for ${FUZZ_SECONDS:-30} s"
scripts/fuzz.sh "${FUZZ_SECONDS:-30}"
t2=$(date +%s)
echo "ci-robustness: sanitized suite $((t1 - t0)) s, fuzzing $((t2 - t1)) s"
