#!/usr/bin/env bash
# The real-photo sets of issue #14 in one run, so that its figures come from
# one command on a clean checkout: each set's map built or imported, its
# queries localized with `visloc eval` (the default confidence threshold
# unless eval options say otherwise), and OUT/report.md (and report.json)
# with, per set, the queries, the registered poses, the wrong ones, the
# median position error of the registered positives and how many of those
# with a σ have their error within 1σ and 2σ (as `visloc eval` counts them).
#   * KITTI odd: the map of the even frames 0-158 (known poses and intrinsics,
#     8 placemarks per segment, 1 shared), the 80 odd frames as queries;
#   * KITTI hard split: the map of frames 0-99, frames 100-159 as queries
#     (most stand past the map's end; a repeated facade lies 40 m back);
#   * Strecha holdouts: each scene imported from its COLMAP model with its
#     held-out photos left out, the photos localized with the model's
#     features and intrinsics (settings 3+ and 1), and with our SIFT and an
#     estimated focal length (`--no-exif-focal`, setting 3+).
# Resumable: a finished step is stamped (OUT/.../done), an interrupted map
# build resumes, and an eval runs again when its options, the files it reads,
# its map or the CLI changed.
# Options after `--` go to every `visloc eval` (e.g. -- --min-confidence 0).
# The tools' output goes to OUT/log.txt. VISLOC names another build's CLI.
#   bench/confidence_sets.sh OUT [--shared-data DIR (default ../shared/data)]
#                            [-- eval options...]
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
V="${VISLOC:-$ROOT/build/src/visloc/cli/visloc}"
usage="usage: bench/confidence_sets.sh OUT [--shared-data DIR] [-- eval options...]"
help() { sed -n '2,22p' "$0" | sed 's/^# \{0,1\}//'; }
case "${1:-}" in
  -h|--help) help; exit 0 ;;
  ""|-*) echo "$usage" >&2; exit 2 ;;
esac
OUT="$1"
shift
DATA="$ROOT/../shared/data"
EVAL_OPTS=()
while [ $# -gt 0 ]; do
  case "$1" in
    --shared-data)
      [ $# -ge 2 ] || { echo "confidence_sets: --shared-data needs a folder ($usage)" >&2; exit 2; }
      DATA="$2"; shift 2 ;;
    --) shift; EVAL_OPTS=("$@"); break ;;
    *) echo "confidence_sets: unknown option $1 ($usage)" >&2; exit 2 ;;
  esac
done
[ -x "$V" ] || { echo "confidence_sets: $V is missing; run scripts/setup.sh (or set VISLOC)" >&2; exit 1; }
K="$DATA/kitti07"
S="$DATA/strecha"
for f in "$K/truth.txt" "$K/gps.csv" "$S"; do
  [ -e "$f" ] || { echo "confidence_sets: $f is missing (--shared-data DIR)" >&2; exit 1; }
done
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
LOG="$OUT/log.txt"
echo "== $(date -Is) confidence_sets: data $DATA, eval options: ${EVAL_OPTS[*]:-(none)}" | tee -a "$LOG"

# run WHAT COMMAND...: the command's output to the log; on failure, say so
# on the terminal with the log's last lines.
run() {
  local what="$1"
  shift
  echo "-- $(date -Is) $what" | tee -a "$LOG"
  if ! "$@" >> "$LOG" 2>&1; then
    echo "confidence_sets: $what failed; the end of $LOG:" >&2
    tail -n 5 "$LOG" >&2
    exit 1
  fi
}

# The stamp of an eval: its arguments and options, the files they name (the
# query list, the truth, the intrinsics), its map's manifest and the CLI, so
# that any of them changed runs it again.
stamp_of() {
  local map="$1" a
  shift
  {
    printf '%s\n' "$@" "${EVAL_OPTS[@]}"
    for a in "$@"; do [ -f "$a" ] && cksum < "$a"; done
    cksum < "$map/manifest.json"
    cksum < "$V"
  } | cksum
}

# eval_set DIR MAP ARGS...: `visloc eval` into DIR unless its stamp matches.
eval_set() {
  local dir="$1" map="$2"
  shift 2
  local stamp
  stamp="$(stamp_of "$map" "$@")"
  [ -f "$dir/done" ] && [ "$(cat "$dir/done")" = "$stamp" ] && return 0
  rm -f "$dir/done"
  run "eval ${dir#"$OUT"/}" "$V" eval --map "$map" "$@" --out "$dir" "${EVAL_OPTS[@]}"
  echo "$stamp" > "$dir/done"
}

# KITTI P0: the rectified left grey camera of every frame.
echo "* PINHOLE 1226 370 707.0912 707.0912 601.8873 183.1104" > "$OUT/kitti_intrinsics.txt"

# kitti_set NAME MAP_FRAMES QUERY_FRAMES: the map of the frames that the awk
# condition MAP_FRAMES keeps (f: the frame number), QUERY_FRAMES the queries.
kitti_set() {
  local name="$1" map_frames="$2" query_frames="$3" dir="$OUT/$1"
  mkdir -p "$dir"
  if [ ! -f "$dir/map.done" ] || [ ! -f "$dir/map/manifest.json" ]; then
    rm -f "$dir/map.done"
    awk -F, "NR == 1 { print; next } { f = substr(\$1, 1, 6) + 0 } $map_frames" "$K/gps.csv" > "$dir/map_gps.csv"
    local logged
    logged=$(wc -l < "$LOG")
    # map build resumes an interrupted build in its --out.
    run "$name: map build" "$V" map build --images "$K/images" --gps "$dir/map_gps.csv" --gps-subset --poses known \
      --known-poses "$K/truth.txt" --known-intrinsics "$OUT/kitti_intrinsics.txt" --min-placemarks 8 \
      --max-placemarks 8 --overlap 1 --out "$dir/map"
    # Its summary line, "... N segments (F failed); ...", among what it logged.
    { tail -n +"$((logged + 1))" "$LOG" | grep -o '[0-9]* segments ([0-9]* failed)' || true; } | tail -n 1 \
      > "$dir/map.done"
  fi
  awk "{ f = substr(\$1, 1, 6) + 0 } $query_frames" "$K/truth.txt" | cut -d' ' -f1 > "$dir/queries.txt"
  eval_set "$dir/eval" "$dir/map" --queries "$dir/queries.txt" --images "$K/images" --truth "$K/truth.txt" \
    --intrinsics "$OUT/kitti_intrinsics.txt"
}
kitti_set kitti-odd 'f % 2 == 0 && f < 160' 'f % 2 == 1 && f < 160'
kitti_set kitti-hard 'f < 100' 'f >= 100 && f < 160'

for scene in fountain-P11 castle-P19 castle-P30 entry-P10; do
  dir="$OUT/strecha/$scene"
  mkdir -p "$dir"
  # map import builds in a staging folder and renames it: a map is whole.
  [ -f "$dir/map/manifest.json" ] ||
    run "$scene: map import" "$V" map import --colmap "$S/$scene/colmap/sparse" \
      --database "$S/$scene/colmap/database.db" --holdout "$S/$scene/queries.txt" --out "$dir/map"
  common=(--queries "$S/$scene/queries.txt" --images "$S/$scene/images" --truth "$dir/map/holdout.txt")
  eval_set "$dir/known-3+" "$dir/map" "${common[@]}" --query-features database --setting 3+
  eval_set "$dir/known-1" "$dir/map" "${common[@]}" --query-features database --setting 1
  eval_set "$dir/estimated-3+" "$dir/map" "${common[@]}" --no-exif-focal --setting 3+
done

/usr/bin/python3 - "$OUT" "${EVAL_OPTS[*]:-}" <<'PY'
import json, os, statistics, sys
out, eval_options = sys.argv[1], sys.argv[2]
scenes = ["fountain-P11", "castle-P19", "castle-P30", "entry-P10"]
sets = [("KITTI odd frames", ["kitti-odd/eval"]), ("KITTI hard split", ["kitti-hard/eval"])]
for run, label in [("known-3+", "known intrinsics, setting 3+"), ("known-1", "known intrinsics, setting 1"),
                   ("estimated-3+", "estimated focal, setting 3+")]:
    sets.append((f"Strecha holdouts, {label}", [f"strecha/{s}/{run}" for s in scenes]))

def read(path):
    with open(os.path.join(out, path)) as f:
        return f.read().strip()

rows, rule, failed_maps = [], None, []
for name in ("kitti-odd", "kitti-hard"):
    done = read(f"{name}/map.done")
    if "(0 failed)" not in done:
        failed_maps.append(f"{name}: {done or 'no build summary in the log'} (delete {name}/map.done to build again)")
for name, dirs in sets:
    r = {"set": name, "queries": 0, "registered": 0, "wrong": 0, "with_sigma": 0, "within_1_sigma": 0,
         "within_2_sigma": 0}
    errors = []
    for d in dirs:
        with open(os.path.join(out, d, "report.json")) as f:
            rep = json.load(f)
        rule = rep["wrong_poses"]["rule"]
        r["queries"] += rep["queries"]
        r["registered"] += rep["registered"]
        r["wrong"] += rep["wrong_poses"]["total"]
        # As `visloc eval` counts them: registered positives with a σ.
        u = rep["uncertainty"]
        n = u["registered_with_sigma"]
        r["with_sigma"] += n
        r["within_1_sigma"] += round(u["within_1_sigma"] * n)
        r["within_2_sigma"] += round(u["within_2_sigma"] * n)
        errors += [q["position_error_m"] for q in rep["per_query"]
                   if q.get("registered") and not q.get("negative") and q.get("position_error_m", -1) >= 0]
    r["median_position_error_m"] = statistics.median(errors) if errors else None
    rows.append(r)

with open(os.path.join(out, "report.json"), "w") as f:
    json.dump({"eval_options": eval_options, "failed_maps": failed_maps, "sets": rows}, f, indent=1)
lines = ["# Issue #14's real-photo sets", "",
         "| set | queries | registered | wrong | median error (m) | within 1σ / 2σ |", "|---|---|---|---|---|---|"]
for r in rows:
    med = "-" if r["median_position_error_m"] is None else f"{r['median_position_error_m']:.4f}"
    lines.append(f"| {r['set']} | {r['queries']} | {r['registered']} | {r['wrong']} | {med} | "
                 f"{r['within_1_sigma']} / {r['within_2_sigma']} of {r['with_sigma']} |")
lines += ["", f"Wrong: registered more than {rule['position_m']:g} m or {rule['rotation_deg']:g}° from the truth, "
          "or a registered negative. Median error: over the registered positives; σ: the registered positives "
          "with one. `visloc eval` options: " + (eval_options or "none") + ". Each set's report is in its folder."]
if failed_maps:
    lines += ["", "Segments that failed to build: " + "; ".join(failed_maps) + "."]
with open(os.path.join(out, "report.md"), "w") as f:
    f.write("\n".join(lines) + "\n")
print("\n".join(lines))
PY
