#!/usr/bin/env bash
# `map build` killed with SIGKILL after its first segment is written, then run
# again (robustness issue):
#  - no child process (COLMAP) outlives the killed build;
#  - the re-run reuses the written segment;
#  - its manifest and `map info --json` equal those of an uninterrupted build.
# And the hash blend each build fits last (the default): `map fit-blend` on
# the uninterrupted build reads every segment's work folder and fits the same
# weight; a resumed build with --no-fit-blend keeps it.
# A small synthetic street, known poses, our guided matcher, no retrieval.
# Usage: map_build_crash_test.sh VISLOC   (exit 77: skipped without COLMAP)
set -euo pipefail
V="$1"
command -v colmap > /dev/null || { echo "SKIP: colmap is not installed"; exit 77; }
T="$(mktemp -d)"
cleanup() { pkill -9 -f "$T/" 2> /dev/null || true; rm -rf "$T"; }
trap cleanup EXIT
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
fail() { echo "FAIL: $*"; exit 1; }
"$V" synth city --out "$T/city" --road-length 60 --headings 6 --elevations 10 --queries 1 --jobs 1 > /dev/null
args=(--images "$T/city/images" --gps "$T/city/gps.csv" --poses known --known-poses "$T/city/sparse" --jobs 1
      --min-placemarks 3 --max-placemarks 3 --overlap 1 --no-retrieval --pq-training-images 6)
"$V" map build "${args[@]}" --out "$T/reference" > "$T/reference.log" 2>&1 || { cat "$T/reference.log"; fail "the reference build failed"; }

"$V" map build "${args[@]}" --out "$T/killed" > "$T/killed.log" 2>&1 &
pid=$!
for _ in $(seq 1 60000); do
  # A segment counts as written once its result is recorded (what a resume reuses).
  grep -qs '"ok": *true' "$T"/killed/work/seg*/result.json && break
  kill -0 "$pid" 2> /dev/null || break
  sleep 0.01
done
kill -9 "$pid" 2> /dev/null || fail "the build ended before its first segment was seen"
wait "$pid" 2> /dev/null || true
sleep 0.5
written="$( (grep -ls '"ok": *true' "$T"/killed/work/seg*/result.json || true) | wc -l)"
[ "$written" -ge 1 ] || fail "no segment was written before the kill"
if pgrep -f "$T/killed" > /dev/null; then
  pgrep -af "$T/killed"
  fail "processes of the killed build are still running"
fi
"$V" map build "${args[@]}" --out "$T/killed" > "$T/rerun.log" 2>&1 || { cat "$T/rerun.log"; fail "the re-run failed"; }
grep -qi "reus" "$T/rerun.log" || { cat "$T/rerun.log"; fail "the re-run did not say it reused the written segment"; }
"$V" map info "$T/reference" --json > "$T/reference.json"
"$V" map info "$T/killed" --json > "$T/killed.json"
diff "$T/reference.json" "$T/killed.json" || fail "map info differs from the uninterrupted build"
diff "$T/reference/manifest.json" "$T/killed/manifest.json" || fail "the manifest differs from the uninterrupted build"
# By default the build fits the hash blend last, on its own MAP/work models
# and databases, and stores it: the same weight for the same segments
# (compared above with the manifests). `map fit-blend --store` fits the same.
/usr/bin/python3 - "$T/reference/manifest.json" <<'PY' || fail "the default build stored no hash blend"
import json, sys
man = json.load(open(sys.argv[1]))
b = man["hash_blend"]
assert 0 <= b["weight"] <= 1 and b["segment_crc32c"] == [s["file_crc32c"] for s in man["segments"]], b
PY
"$V" map fit-blend "$T/reference" --store --json > "$T/blend.json" || fail "map fit-blend failed on a built map"
/usr/bin/python3 - "$T/blend.json" "$T/reference.json" "$T/killed/manifest.json" <<'PY' || fail "map fit-blend's report of a built map"
import json, sys
fit, info, built = (json.load(open(p)) for p in sys.argv[1:4])
ids = [s["id"] for s in info["segments"]]
assert len(ids) >= 2 and [s["segment"] for s in fit["segments"]] == ids, (fit["segments"], ids)
for s in fit["segments"]:
    assert "/work/seg%04d/sparse/" % s["segment"] in s["model"], s
    assert s["database"].endswith("/work/seg%04d/database.db" % s["segment"]), s
    assert s["views"] > 0, s
grid = fit["grid"]
assert len(grid) == 21 and fit["views_listed"] > 0 and max(g["views_right"] for g in grid) > 0, fit
net = [g["views_right"] - g["views_wrong"] - g["distractors_matched"] for g in grid]
assert fit["weight"] == grid[net.index(max(net))]["weight"], (fit["weight"], net)
assert fit["stored"] is True and fit["weight"] == built["hash_blend"]["weight"], (fit, built["hash_blend"])
PY
"$V" map info "$T/reference" | grep -q "hash blend: weight .* (fitted on these segments" || fail "map info does not show the stored weight"
# --no-fit-blend: a resumed build fits nothing and keeps the stored weight.
cp "$T/reference/manifest.json" "$T/stored_manifest.json"
"$V" map build "${args[@]}" --no-fit-blend --out "$T/reference" > "$T/resume.log" 2>&1 ||
  { cat "$T/resume.log"; fail "the resumed build failed"; }
grep -q "hash blend" "$T/resume.log" && { cat "$T/resume.log"; fail "--no-fit-blend fitted the hash blend"; }
diff "$T/stored_manifest.json" "$T/reference/manifest.json" || fail "a resumed build changed the manifest with its stored weight"
echo "killed after $written segment(s), no process left; re-run reused them; manifest and map info equal the uninterrupted build; the build stored its hash blend; map fit-blend read every segment's work folder and fitted the same; --no-fit-blend kept it"
