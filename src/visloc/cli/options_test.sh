#!/usr/bin/env bash
# Numeric options: NaN, infinities and out-of-range values are usage errors
# (exit 2, a message naming the option), never silently ignored.
set -uo pipefail
V="$1"
status=0
check() {
  local expected_option="$1"
  shift
  "$V" "$@" > /dev/null 2> /tmp/visloc_options_test.$$
  local rc=$?
  if [ "$rc" != 2 ] || ! grep -q -- "$expected_option" /tmp/visloc_options_test.$$; then
    echo "FAIL: visloc $* -> exit $rc: $(head -c 200 /tmp/visloc_options_test.$$)"
    status=1
  fi
}
for v in nan -nan inf -1 0; do check --focal localize --map /nonexistent --focal="$v" q.jpg; done
for v in nan inf; do
  check --cache-mib localize --map /nonexistent --cache-mib "$v" q.jpg
  check --threshold localize --map /nonexistent --threshold "$v" q.jpg
  check --min-confidence localize --map /nonexistent --min-confidence "$v" q.jpg
done
check --min-confidence localize --map /nonexistent --min-confidence 1.5 q.jpg
check --vote-points localize --map /nonexistent --vote-points -1 q.jpg
check --vote-max-points localize --map /nonexistent --vote-max-points -1 q.jpg
for v in nan inf -1; do check --max-drop-below-map localize --map /nonexistent --max-drop-below-map "$v" q.jpg; done
check --vote-radius localize --map /nonexistent --vote-radius 2 q.jpg
for v in -1 17; do check --lut-flips localize --map /nonexistent --lut-flips "$v" q.jpg; done
check --lut-flips-min-list localize --map /nonexistent --lut-flips-min-list -1 q.jpg
for v in nan -0.1 1.5 abc 0.5x ""; do check --hash-blend localize --map /nonexistent --hash-blend "$v" q.jpg; done
check --views map fit-blend /nonexistent --views 1
check --vote-ratio localize --map /nonexistent --vote-ratio 1.5 q.jpg
check --vote-ratio localize --map /nonexistent --vote-ratio nan q.jpg
check --segment-votes localize --map /nonexistent --segment-votes pixels q.jpg
# The range's own message (an unknown flag would also exit 2 and name it).
check --pq-residual-beam map import --colmap /nonexistent --database /nonexistent --out /nonexistent \
  --pq-quantizer residual --pq-residual-beam nan
check "--pq-residual-beam: 'nan' is not a whole number" map build --images /nonexistent --out /nonexistent \
  --pq-residual-beam nan
for v in 0 65; do
  check "--pq-residual-beam: '$v' is not in \[1, 64\]" map import --colmap /nonexistent --database /nonexistent \
    --out /nonexistent --pq-quantizer residual --pq-residual-beam "$v"
  check "--pq-residual-beam: $v is not in \[1, 64\]" map build --images /nonexistent --out /nonexistent \
    --pq-residual-beam "$v"
done
check "--pq-residual-splits: '3' is not one of the choices" map build --images /nonexistent --out /nonexistent \
  --pq-residual-splits 3
check "--pq-residual-kmeans: fast not in {progressive,plain}" map import --colmap /nonexistent \
  --database /nonexistent --out /nonexistent --pq-residual-kmeans fast
rm -f /tmp/visloc_options_test.$$
[ "$status" = 0 ] && echo "all numeric options refuse NaN and bad ranges"
exit "$status"
