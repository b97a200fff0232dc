#!/usr/bin/env bash
# bench/confidence_sets.sh without data or maps: its usage errors; the
# commands it runs (a stub CLI logs them and writes maps and reports), so the
# query lists, settings and options are checked; its summary table against
# reports whose counts are known; its resumption (nothing runs twice, an
# eval runs again when its options or its map change); a failing step; and
# map builds interrupted, with failed segments or without a summary.
#   confidence_sets_test.sh RUNNER
set -u
RUNNER="$1"
T="$(mktemp -d)"
trap 'rm -rf "$T"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

# The data: names and poses are all the runner reads of KITTI.
mkdir -p "$T/data/kitti07" "$T/data/strecha"
echo "image,lat,lon,alt" > "$T/data/kitti07/gps.csv"
for f in $(seq 0 159); do
  printf '%06d.png,49.0,8.4,115.0\n' "$f" >> "$T/data/kitti07/gps.csv"
  printf '%06d.png 1 0 0 0 0 0 0\n' "$f" >> "$T/data/kitti07/truth.txt"
done

# The stub CLI: logs its arguments; `map build|import` write a manifest (and
# build's summary line), `eval` a report from $T/fixtures/<set>.json, where
# <set> is its --out relative to the output folder with / as _.
cat > "$T/visloc" <<'STUB'
#!/usr/bin/env bash
echo "$*" >> "$STUB_LOG"
[ -n "${STUB_FAIL:-}" ] && [[ "$*" == *"$STUB_FAIL"* ]] && { echo "stub: failing on purpose"; exit 3; }
out=""; prev=""
for a in "$@"; do [ "$prev" = "--out" ] && out="$a"; prev="$a"; done
case "$1 $2" in
  "map build") mkdir -p "$out" && echo '{"b": 1}' > "$out/manifest.json"
    if [ -z "${STUB_NO_SUMMARY:-}" ]; then echo "80 images, 10 placemarks, 2 segments (${STUB_FAILED_SEGMENTS:-0} failed)"; fi ;;
  "map import") mkdir -p "$out" && echo '{"i": 1}' > "$out/manifest.json" && touch "$out/holdout.txt" ;;
  eval*) key="${out#"$STUB_OUT"/}"; mkdir -p "$out"; cp "$STUB_FIXTURES/${key//\//_}.json" "$out/report.json" ;;
esac
STUB
chmod +x "$T/visloc"
export VISLOC="$T/visloc" STUB_LOG="$T/calls.log" STUB_OUT="$T/o" STUB_FIXTURES="$T/fixtures"

"$RUNNER" > "$T/out.txt" 2>&1; rc=$?
[ $rc -eq 2 ] || fail "no OUT: exit $rc, expected 2"
grep -q "usage:" "$T/out.txt" || fail "no OUT: no usage line"
"$RUNNER" --help > "$T/out.txt" 2>&1 || fail "--help: exit $?"
grep -q "KITTI hard split" "$T/out.txt" || fail "--help does not describe the sets"
"$RUNNER" "$T/o" --shared-data "$T/none" > "$T/out.txt" 2>&1; rc=$?
[ $rc -eq 1 ] || fail "missing data: exit $rc, expected 1"
grep -q "none/kitti07/truth.txt is missing" "$T/out.txt" || fail "missing data: the message does not name the file"
"$RUNNER" "$T/o" --bogus > "$T/out.txt" 2>&1; rc=$?
[ $rc -eq 2 ] || fail "unknown option: exit $rc, expected 2"
"$RUNNER" "$T/o" --shared-data > "$T/out.txt" 2>&1; rc=$?
[ $rc -eq 2 ] || fail "--shared-data without a folder: exit $rc, expected 2"
[ ! -e "$T/calls.log" ] || fail "a usage error ran the CLI"

# report NAME QUERIES REGISTERED WRONG WITH_SIGMA WITHIN1 WITHIN2 ERRORS...:
# the fixture of one set; ERRORS the registered positives' errors.
report() {
  local name="$1" queries="$2" registered="$3" wrong="$4" n="$5" w1="$6" w2="$7"
  shift 7
  local pq="" e
  for e in "$@"; do pq="$pq{\"registered\": true, \"position_error_m\": $e},"; done
  mkdir -p "$T/fixtures"
  cat > "$T/fixtures/$name.json" <<JSON
{"queries": $queries, "registered": $registered,
 "wrong_poses": {"total": $wrong, "rule": {"position_m": 5.0, "rotation_deg": 10.0}},
 "uncertainty": {"registered_with_sigma": $n, "within_1_sigma": $(python3 -c "print($w1 / max($n, 1))"),
                 "within_2_sigma": $(python3 -c "print($w2 / max($n, 1))")},
 "per_query": [$pq {"registered": true, "negative": true, "position_error_m": 99},
               {"registered": false, "position_error_m": -1}]}
JSON
}
report kitti-odd_eval 80 80 0 80 35 64 0.01 0.02 0.09
report kitti-hard_eval 60 34 3 31 3 15 0.3 0.1 40 0.2
for s in fountain-P11 castle-P19 castle-P30 entry-P10; do
  report "strecha_${s}_known-3+" 5 5 0 5 4 5 0.01
  report "strecha_${s}_known-1" 5 4 0 4 1 3 0.002
  report "strecha_${s}_estimated-3+" 5 5 1 5 0 1 0.07 0.5
done

"$RUNNER" "$T/o" --shared-data "$T/data" > "$T/out.txt" 2>&1 || { cat "$T/out.txt"; fail "first run failed"; }
r="$T/o/report.md"
check_row() { grep -qF "$1" "$r" || { cat "$r"; fail "no row: $1"; }; }
check_row "| KITTI odd frames | 80 | 80 | 0 | 0.0200 | 35 / 64 of 80 |"
check_row "| KITTI hard split | 60 | 34 | 3 | 0.2500 | 3 / 15 of 31 |"
check_row "| Strecha holdouts, known intrinsics, setting 3+ | 20 | 20 | 0 | 0.0100 | 16 / 20 of 20 |"
check_row "| Strecha holdouts, known intrinsics, setting 1 | 20 | 16 | 0 | 0.0020 | 4 / 12 of 16 |"
check_row "| Strecha holdouts, estimated focal, setting 3+ | 20 | 20 | 4 | 0.2850 | 0 / 4 of 20 |"
grep -q "Wrong: registered more than 5 m or 10° from the truth" "$r" || fail "the wrong-pose rule is not stated"
grep -q "Segments that failed" "$r" && fail "no segment failed, but the report says some did"

# The commands: query lists from the frame numbers, the settings, the camera.
[ "$(wc -l < "$T/o/kitti-odd/queries.txt")" -eq 80 ] || fail "KITTI odd: not 80 queries"
[ "$(head -n 1 "$T/o/kitti-odd/queries.txt")" = "000001.png" ] || fail "KITTI odd: the first query is not frame 1"
[ "$(wc -l < "$T/o/kitti-hard/queries.txt")" -eq 60 ] || fail "KITTI hard: not 60 queries"
[ "$(head -n 1 "$T/o/kitti-hard/queries.txt")" = "000100.png" ] || fail "KITTI hard: the first query is not frame 100"
[ "$(tail -n +2 "$T/o/kitti-odd/map_gps.csv" | wc -l)" -eq 80 ] || fail "KITTI odd: not 80 map frames"
[ "$(tail -n +2 "$T/o/kitti-hard/map_gps.csv" | wc -l)" -eq 100 ] || fail "KITTI hard: not 100 map frames"
grep -q "^image,lat,lon,alt" "$T/o/kitti-hard/map_gps.csv" || fail "the map GPS list lost its header"
grep -q "PINHOLE 1226 370 707.0912" "$T/o/kitti_intrinsics.txt" || fail "KITTI intrinsics"
grep -q "eval .*fountain-P11/map .*--query-features database --setting 1 --out .*known-1$" "$T/calls.log" ||
  fail "the known-intrinsics setting 1 eval"
grep -q "eval .*--no-exif-focal --setting 3+ --out .*estimated-3+$" "$T/calls.log" || fail "the estimated-focal eval"
[ "$(grep -c "^map build" "$T/calls.log")" -eq 2 ] || fail "not two map builds"
[ "$(grep -c "^map import" "$T/calls.log")" -eq 4 ] || fail "not four map imports"
[ "$(grep -c "^eval" "$T/calls.log")" -eq 14 ] || fail "not 14 evals"

# Resumed: nothing runs again; with other eval options every eval does (and
# gets them), no map is built again.
"$RUNNER" "$T/o" --shared-data "$T/data" > "$T/out.txt" 2>&1 || fail "second run failed"
[ "$(wc -l < "$T/calls.log")" -eq 20 ] || fail "a resumed run ran a step again"
"$RUNNER" "$T/o" --shared-data "$T/data" -- --min-confidence 0 > "$T/out.txt" 2>&1 || fail "third run failed"
[ "$(grep -c "^eval .*--min-confidence 0$" "$T/calls.log")" -eq 14 ] || fail "changed eval options did not rerun"
[ "$(grep -c "^map" "$T/calls.log")" -eq 6 ] || fail "changed eval options rebuilt a map"
grep -q "options: --min-confidence 0" "$r" || fail "the report does not give the eval options"

# A changed map: its three evals run again, nothing else.
calls=$(wc -l < "$T/calls.log")
echo '{"i": 2}' > "$T/o/strecha/castle-P19/map/manifest.json"
"$RUNNER" "$T/o" --shared-data "$T/data" -- --min-confidence 0 > "$T/out.txt" 2>&1 || fail "run after a map change"
[ "$(tail -n +"$((calls + 1))" "$T/calls.log" | grep -c "^eval .*castle-P19/map ")" -eq 3 ] ||
  fail "a changed map did not rerun its three evals"
[ "$(wc -l < "$T/calls.log")" -eq "$((calls + 3))" ] || fail "a changed map reran other steps"

# Changed query list: that scene's three evals run again; a rebuilt CLI:
# every eval; a deleted map: its build.
calls=$(wc -l < "$T/calls.log")
mkdir -p "$T/data/strecha/castle-P19" && echo "0001.jpg" >> "$T/data/strecha/castle-P19/queries.txt"
"$RUNNER" "$T/o" --shared-data "$T/data" -- --min-confidence 0 > "$T/out.txt" 2>&1 || fail "run after a query change"
[ "$(tail -n +"$((calls + 1))" "$T/calls.log" | grep -c "^eval .*castle-P19/map ")" -eq 3 ] &&
  [ "$(wc -l < "$T/calls.log")" -eq "$((calls + 3))" ] || fail "a changed query list did not rerun its three evals alone"
calls=$(wc -l < "$T/calls.log")
echo "# rebuilt" >> "$VISLOC"
"$RUNNER" "$T/o" --shared-data "$T/data" -- --min-confidence 0 > "$T/out.txt" 2>&1 || fail "run after a new CLI"
[ "$(tail -n +"$((calls + 1))" "$T/calls.log" | grep -c "^eval ")" -eq 14 ] || fail "a new CLI did not rerun every eval"
calls=$(wc -l < "$T/calls.log")
rm -rf "$T/o/kitti-odd/map"
"$RUNNER" "$T/o" --shared-data "$T/data" -- --min-confidence 0 > "$T/out.txt" 2>&1 || fail "run after a deleted map"
[ "$(tail -n +"$((calls + 1))" "$T/calls.log" | grep -c "^map build .*kitti-odd/map")" -eq 1 ] ||
  fail "a deleted map was not built again"

# A failing step (with new options, so that a stamp exists): exit 1, its name
# on the terminal, the old stamp gone; the next run runs it again.
STUB_FAIL="castle-P30/known-1" "$RUNNER" "$T/o" --shared-data "$T/data" -- --min-confidence 0.5 > "$T/out.txt" 2>&1
rc=$?
[ $rc -eq 1 ] || fail "a failing eval: exit $rc, expected 1"
grep -q "eval strecha/castle-P30/known-1 failed" "$T/out.txt" || { cat "$T/out.txt"; fail "the failure is not named"; }
[ ! -f "$T/o/strecha/castle-P30/known-1/done" ] || fail "a failed eval kept its stamp"
calls=$(wc -l < "$T/calls.log")
"$RUNNER" "$T/o" --shared-data "$T/data" -- --min-confidence 0.5 > "$T/out.txt" 2>&1 || fail "run after a failure"
tail -n +"$((calls + 1))" "$T/calls.log" | grep -q "^eval .*castle-P30/known-1 --min-confidence 0.5$" ||
  fail "the failed eval did not run again"

# Map builds: an interrupted one (a map folder, no stamp) runs again; one that
# reports failed segments, or no summary, is named in the report, each with
# its own line (not another build's).
rm -f "$T/o/kitti-odd/map.done" "$T/o/kitti-hard/map.done"
STUB_FAILED_SEGMENTS=1 "$RUNNER" "$T/o" --shared-data "$T/data" -- --min-confidence 0.5 > "$T/out.txt" 2>&1 ||
  fail "run with failed segments"
grep -q "kitti-odd: 2 segments (1 failed) (delete kitti-odd/map.done to build again)" "$r" ||
  { cat "$r"; fail "failed segments not reported with the way to retry"; }
rm -f "$T/o/kitti-hard/map.done"
STUB_NO_SUMMARY=1 "$RUNNER" "$T/o" --shared-data "$T/data" -- --min-confidence 0.5 > "$T/out.txt" 2>&1 ||
  fail "run without a build summary"
grep -q "kitti-hard: no build summary in the log" "$r" || { cat "$r"; fail "a build without a summary took another's"; }
echo "confidence_sets: ok"
