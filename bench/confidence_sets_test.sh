#!/usr/bin/env bash
# bench/confidence_sets.sh without data: its usage errors, and its summary over
# sets whose maps and reports exist already (the runner resumes past them), so
# the table's counts, median and σ shares are checked against known reports.
#   confidence_sets_test.sh RUNNER VISLOC
set -u
RUNNER="$1"
export VISLOC="$2"
T="$(mktemp -d)"
trap 'rm -rf "$T"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

"$RUNNER" > "$T/out.txt" 2>&1; rc=$?
[ $rc -eq 2 ] || fail "no OUT: exit $rc, expected 2"
grep -q "usage:" "$T/out.txt" || fail "no OUT: no usage line"
"$RUNNER" --help > "$T/out.txt" 2>&1 || fail "--help: exit $?"
grep -q "KITTI hard split" "$T/out.txt" || fail "--help does not describe the sets"
"$RUNNER" "$T/o" --shared-data "$T/none" > "$T/out.txt" 2>&1; rc=$?
[ $rc -eq 1 ] || fail "missing data: exit $rc, expected 1"
grep -q "kitti07/truth.txt is missing" "$T/out.txt" || fail "missing data: the message does not name the file"
"$RUNNER" "$T/o" --bogus > "$T/out.txt" 2>&1; rc=$?
[ $rc -eq 2 ] || fail "unknown option: exit $rc, expected 2"

# Every set done: a map manifest and an eval report each.
mkdir -p "$T/data/kitti07" "$T/data/strecha"
touch "$T/data/kitti07/truth.txt"
report() {  # DIR: 3 queries, 2 registered (errors 0.01 and 0.05 m, σ 0.02), 1 wrong
  mkdir -p "$1"
  cat > "$1/report.json" <<'JSON'
{"queries": 3, "registered": 2, "wrong_poses": {"total": 1},
 "per_query": [{"registered": true, "position_error_m": 0.01, "position_sigma": 0.02},
               {"registered": true, "position_error_m": 0.05, "position_sigma": 0.02},
               {"registered": false, "position_error_m": -1}]}
JSON
}
for s in kitti-odd kitti-hard; do
  mkdir -p "$T/o/$s/map" && echo '{}' > "$T/o/$s/map/manifest.json"
  report "$T/o/$s/eval"
done
for scene in fountain-P11 castle-P19 castle-P30 entry-P10; do
  mkdir -p "$T/o/strecha/$scene/map" && echo '{}' > "$T/o/strecha/$scene/map/manifest.json"
  for run in known-3+ known-1 estimated-3+; do report "$T/o/strecha/$scene/$run"; done
done
"$RUNNER" "$T/o" --shared-data "$T/data" > "$T/out.txt" 2>&1 || { cat "$T/out.txt"; fail "summary: exit $?"; }
grep -qF "| KITTI odd frames | 3 | 2 | 1 | 0.0300 | 1 / 1 of 2 |" "$T/o/report.md" || { cat "$T/o/report.md"; fail "KITTI odd row"; }
grep -qF "| Strecha holdouts, estimated focal, setting 3+ | 12 | 8 | 4 | 0.0300 | 4 / 4 of 8 |" "$T/o/report.md" ||
  { cat "$T/o/report.md"; fail "Strecha row"; }
[ "$(grep -c '^| ' "$T/o/report.md")" -eq 6 ] || fail "expected a header and 5 sets"
echo "confidence_sets: ok"
