#!/usr/bin/env bash
# `map import` is crash-safe (robustness issue):
#  1. killed with SIGKILL while it writes, it leaves no manifest and no partial
#     map; the re-run gives the same map as an uninterrupted import;
#  2. out of disk space (a file size limit, ulimit -f), it fails with exit 1
#     and a clear message and leaves the previous map byte for byte as it was.
# Usage: map_import_crash_test.sh VISLOC SHARED_DATA_DIR   (exit 77: skipped)
set -euo pipefail
V="$1"
S="$2/strecha/fountain-P11/colmap"
if [ ! -f "$S/sparse/points3D.bin" ]; then echo "SKIP: shared data absent ($S)"; exit 77; fi
T="$(mktemp -d)"
trap 'rm -rf "$T"' EXIT
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
args=(--colmap "$S/sparse" --database "$S/database.db" --itq-iterations 3)
fail() { echo "FAIL: $*"; exit 1; }
# The map's content: manifest and map info, without what may differ by run.
content() { cat "$1/manifest.json"; "$V" map info "$1" --json; }

"$V" map import "${args[@]}" --out "$T/reference" > /dev/null

# 1. An --overwrite import of another map (another seed), killed while it
#    writes (its staging folder exists), over a copy of the reference: the
#    folder must hold either the old map, whole, or the new one, whole.
cp -r "$T/reference" "$T/killed"
"$V" map import "${args[@]}" --seed 2 --out "$T/killed" --overwrite > /dev/null 2>&1 &
pid=$!
for _ in $(seq 1 12000); do
  [ -d "$T/killed.import-staging/segments" ] && break
  kill -0 "$pid" 2> /dev/null || break
  sleep 0.01
done
kill -9 "$pid" 2> /dev/null || echo "note: the import finished before the kill"
wait "$pid" 2> /dev/null || true
"$V" map info "$T/killed" > /dev/null || fail "a killed import left no readable map"
diff <(content "$T/reference") <(content "$T/killed") > /dev/null ||
  echo "note: the kill came after the swap: the new map is whole"
"$V" map import "${args[@]}" --out "$T/killed" --overwrite > /dev/null
[ ! -e "$T/killed.import-staging" ] || fail "the re-run left its staging folder"
diff <(content "$T/reference") <(content "$T/killed") || fail "the re-run's map differs from an uninterrupted import"
echo "kill and re-run: a whole map at every moment; the re-run equals an uninterrupted import"

# 2. Full disk over an existing map: the limit (1000 KiB) lets the segment
#    (~650 KiB) be written and stops the descriptor file (~1.7 MiB), so the
#    failure comes after a first file of the new map is complete.
cp -r "$T/reference" "$T/full"
before="$(cd "$T/full" && find . -type f | sort | xargs sha256sum)"
set +e
(trap '' XFSZ; ulimit -f 1000; exec "$V" map import "${args[@]}" --seed 2 --out "$T/full" --overwrite) > /dev/null 2> "$T/err.txt"
rc=$?
set -e
[ "$rc" = 1 ] || fail "exit $rc on a full disk, expected 1: $(cat "$T/err.txt")"
grep -q "File too large\|No space" "$T/err.txt" || fail "no clear message: $(cat "$T/err.txt")"
grep -q "vldesc" "$T/err.txt" || fail "the limit did not stop a later file: $(cat "$T/err.txt")"
after="$(cd "$T/full" && find . -type f | sort | xargs sha256sum)"
[ "$before" = "$after" ] || fail "the previous map changed after a failed import"
[ ! -e "$T/full.import-staging" ] || fail "a failed import left its staging folder"
echo "full disk: exit 1 ($(head -c 160 "$T/err.txt")), previous map intact"
