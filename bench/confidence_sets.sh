#!/usr/bin/env bash
# The real-photo sets of issue #14 in one run, so that its figures come from
# one command on a clean checkout: each set's map built or imported, its
# queries localized with `visloc eval` at the default confidence threshold,
# and OUT/report.md (and report.json) with, per set, the queries, the
# registered poses, the wrong ones (more than 5 m or 10° from the truth), the
# median position error and the share of registered errors within 1σ and 2σ.
#   * KITTI odd: the map of the even frames 0-158 (known poses and intrinsics,
#     8 placemarks per segment, 1 shared), the 80 odd frames as queries;
#   * KITTI hard split: the map of frames 0-99, frames 100-159 as queries
#     (most stand past the map's end; a repeated facade lies 40 m back);
#   * Strecha holdouts: each scene imported from its COLMAP model with its
#     held-out photos left out, the photos localized with the model's
#     features and intrinsics (settings 3+ and 1), and with our SIFT and an
#     estimated focal length (`--no-exif-focal`).
# Resumable: a set whose report exists is not run again (delete it to rerun).
# Options after `--` go to every `visloc eval` (e.g. -- --min-confidence 0).
#   bench/confidence_sets.sh OUT [--shared-data DIR] [-- eval options...]
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
V="${VISLOC:-$ROOT/build/src/visloc/cli/visloc}"  # VISLOC: another build's CLI
usage="usage: bench/confidence_sets.sh OUT [--shared-data DIR] [-- eval options...]"
case "${1:-}" in
  ""|-h|--help) sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'; [ -n "${1:-}" ] && exit 0; echo "$usage" >&2; exit 2 ;;
esac
OUT="$1"
shift
DATA="$ROOT/../shared/data"
EVAL_OPTS=()
while [ $# -gt 0 ]; do
  case "$1" in
    --shared-data) DATA="$2"; shift 2 ;;
    --) shift; EVAL_OPTS=("$@"); break ;;
    *) echo "confidence_sets: unknown option $1 ($usage)" >&2; exit 2 ;;
  esac
done
[ -x "$V" ] || { echo "confidence_sets: $V is missing; run scripts/setup.sh" >&2; exit 1; }
K="$DATA/kitti07"
S="$DATA/strecha"
[ -f "$K/truth.txt" ] || { echo "confidence_sets: $K/truth.txt is missing (--shared-data DIR)" >&2; exit 1; }
[ -d "$S" ] || { echo "confidence_sets: $S is missing (--shared-data DIR)" >&2; exit 1; }
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
LOG="$OUT/log.txt"
echo "== $(date -Is) confidence_sets: data $DATA, eval options: ${EVAL_OPTS[*]:-(defaults)}" | tee -a "$LOG"

# KITTI P0: the rectified left grey camera of every frame.
echo "* PINHOLE 1226 370 707.0912 707.0912 601.8873 183.1104" > "$OUT/kitti_intrinsics.txt"

# kitti_set NAME GPS_FILTER QUERY_FILTER: the map of the frames GPS_FILTER
# keeps (awk on the frame number f), the frames QUERY_FILTER keeps as queries.
kitti_set() {
  local name="$1" map_frames="$2" query_frames="$3" dir="$OUT/$1"
  mkdir -p "$dir"
  if [ ! -f "$dir/map/manifest.json" ]; then
    awk -F, -v OFS=, "NR == 1 { print; next } { f = substr(\$1, 1, 6) + 0 } $map_frames" "$K/gps.csv" > "$dir/map_gps.csv"
    echo "-- $(date -Is) $name: map build" | tee -a "$LOG"
    rm -rf "$dir/map"
    "$V" map build --images "$K/images" --gps "$dir/map_gps.csv" --gps-subset --poses known \
      --known-poses "$K/truth.txt" --known-intrinsics "$OUT/kitti_intrinsics.txt" --min-placemarks 8 \
      --max-placemarks 8 --overlap 1 --out "$dir/map" >> "$LOG" 2>&1
  fi
  if [ ! -f "$dir/eval/report.json" ]; then
    awk "{ f = substr(\$1, 1, 6) + 0 } $query_frames" "$K/truth.txt" | cut -d' ' -f1 > "$dir/queries.txt"
    echo "-- $(date -Is) $name: eval" | tee -a "$LOG"
    "$V" eval --map "$dir/map" --queries "$dir/queries.txt" --images "$K/images" --truth "$K/truth.txt" \
      --intrinsics "$OUT/kitti_intrinsics.txt" --out "$dir/eval" "${EVAL_OPTS[@]}" >> "$LOG" 2>&1
  fi
}
kitti_set kitti-odd 'f % 2 == 0 && f < 160' 'f % 2 == 1 && f < 160'
kitti_set kitti-hard 'f < 100' 'f >= 100 && f < 160'

for scene in fountain-P11 castle-P19 castle-P30 entry-P10; do
  dir="$OUT/strecha/$scene"
  mkdir -p "$dir"
  if [ ! -f "$dir/map/manifest.json" ]; then
    echo "-- $(date -Is) $scene: map import" | tee -a "$LOG"
    rm -rf "$dir/map"
    "$V" map import --colmap "$S/$scene/colmap/sparse" --database "$S/$scene/colmap/database.db" \
      --holdout "$S/$scene/queries.txt" --out "$dir/map" >> "$LOG" 2>&1
  fi
  for run in known-3+ known-1 estimated-3+; do
    [ -f "$dir/$run/report.json" ] && continue
    echo "-- $(date -Is) $scene: eval $run" | tee -a "$LOG"
    case "$run" in
      known-*) extra=(--query-features database --setting "${run#known-}") ;;
      estimated-*) extra=(--no-exif-focal --setting "${run#estimated-}") ;;
    esac
    "$V" eval --map "$dir/map" --queries "$S/$scene/queries.txt" --images "$S/$scene/images" \
      --truth "$dir/map/holdout.txt" "${extra[@]}" --out "$dir/$run" "${EVAL_OPTS[@]}" >> "$LOG" 2>&1
  done
done

/usr/bin/python3 - "$OUT" <<'PY'
import json, os, statistics, sys
out = sys.argv[1]
scenes = ["fountain-P11", "castle-P19", "castle-P30", "entry-P10"]
sets = [("KITTI odd frames", ["kitti-odd/eval"]), ("KITTI hard split", ["kitti-hard/eval"])]
for run, label in [("known-3+", "known intrinsics, setting 3+"), ("known-1", "known intrinsics, setting 1"),
                   ("estimated-3+", "estimated focal, setting 3+")]:
    sets.append((f"Strecha holdouts, {label}", [f"strecha/{s}/{run}" for s in scenes]))

rows = []
for name, dirs in sets:
    queries = registered = wrong = 0
    errors, within1, within2 = [], 0, 0
    for d in dirs:
        with open(os.path.join(out, d, "report.json")) as f:
            r = json.load(f)
        queries += r["queries"]
        registered += r["registered"]
        wrong += r["wrong_poses"]["total"]
        for q in r["per_query"]:
            if not q.get("registered") or q.get("position_error_m") is None or q["position_error_m"] < 0:
                continue
            errors.append(q["position_error_m"])
            sigma = q.get("position_sigma", 0)
            if sigma > 0:
                within1 += q["position_error_m"] <= sigma
                within2 += q["position_error_m"] <= 2 * sigma
    rows.append({"set": name, "queries": queries, "registered": registered, "wrong": wrong,
                 "median_position_error_m": statistics.median(errors) if errors else None,
                 "within_1_sigma": within1, "within_2_sigma": within2, "with_error": len(errors)})

with open(os.path.join(out, "report.json"), "w") as f:
    json.dump({"sets": rows}, f, indent=1)
lines = ["# Issue #14's real-photo sets", "",
         "| set | queries | registered | wrong | median error (m) | within 1σ / 2σ |", "|---|---|---|---|---|---|"]
for r in rows:
    med = "-" if r["median_position_error_m"] is None else f"{r['median_position_error_m']:.4f}"
    lines.append(f"| {r['set']} | {r['queries']} | {r['registered']} | {r['wrong']} | {med} | "
                 f"{r['within_1_sigma']} / {r['within_2_sigma']} of {r['with_error']} |")
lines += ["", "Wrong: registered more than 5 m or 10° from the truth. Each set's `visloc eval` report is in its folder."]
with open(os.path.join(out, "report.md"), "w") as f:
    f.write("\n".join(lines) + "\n")
print("\n".join(lines))
PY
