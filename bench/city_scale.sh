#!/usr/bin/env bash
# The scale run of issue #12: a synthetic city on a grid of streets (default
# 2×2 blocks of 90 m: 1080 m of street), its map built with the local
# executor and, when a Slurm cluster answers (SLURM_CONF), with the Slurm
# executor; the two maps compared segment by segment, the queries localized,
# and the figures written to OUT/report.md: wall time, median seconds per
# segment, images per hour per core, bytes on disk per km of street, and the
# extrapolation to the paper's 227K images. Resumable (every stage is).
#   bench/city_scale.sh OUT [--blocks-x N] [--blocks-y N] [--block-size M] [--headings N] [--jobs N]
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
V="$ROOT/build/src/visloc/cli/visloc"
OUT="${1:?usage: bench/city_scale.sh OUT [--blocks-x N] [--blocks-y N] [--block-size M] [--headings N] [--jobs N]}"
shift
BX=2 BY=2 BLOCK=90 HEADINGS=8 JOBS=2
while [ $# -gt 0 ]; do
  case "$1" in
    --blocks-x) BX="$2"; shift 2 ;;
    --blocks-y) BY="$2"; shift 2 ;;
    --block-size) BLOCK="$2"; shift 2 ;;
    --headings) HEADINGS="$2"; shift 2 ;;
    --jobs) JOBS="$2"; shift 2 ;;
    *) echo "city_scale: unknown option $1" >&2; exit 2 ;;
  esac
done
[ -x "$V" ] || { echo "city_scale: $V is missing; run scripts/setup.sh" >&2; exit 1; }
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
LOG="$OUT/log.txt"
stamp() { date +%s.%N; }
echo "== $(date -Is) city_scale: grid ${BX}x${BY} blocks of ${BLOCK} m, ${HEADINGS} headings, --jobs ${JOBS}" | tee -a "$LOG"

if [ ! -f "$OUT/city/queries/truth.txt" ]; then
  t0=$(stamp)
  "$V" synth city --out "$OUT/city" --layout grid --grid-blocks-x "$BX" --grid-blocks-y "$BY" --block-size "$BLOCK" \
    --headings "$HEADINGS" --elevations 10 --queries 24 --jobs "$JOBS" --resume --quiet 2>&1 | tee -a "$LOG"
  echo "render_s $(echo "$(stamp) - $t0" | bc)" >> "$OUT/times.txt"
fi

common=(--images "$OUT/city/images" --gps "$OUT/city/gps.csv" --poses known --known-poses "$OUT/city/sparse")
t0=$(stamp)
"$V" map build "${common[@]}" --out "$OUT/map-local" --jobs "$JOBS" >> "$LOG" 2>&1
echo "local_build_s $(echo "$(stamp) - $t0" | bc)" >> "$OUT/times.txt"
"$V" map info "$OUT/map-local" --json > "$OUT/map-local.json"

if command -v sbatch >/dev/null 2>&1 && [ -n "${SLURM_CONF:-}" ] && sinfo -h >/dev/null 2>&1; then
  t0=$(stamp)
  "$V" map build "${common[@]}" --out "$OUT/map-slurm" --executor slurm >> "$LOG" 2>&1
  echo "slurm_build_s $(echo "$(stamp) - $t0" | bc)" >> "$OUT/times.txt"
  "$V" map info "$OUT/map-slurm" --json > "$OUT/map-slurm.json"
else
  echo "city_scale: no Slurm cluster answers (export SLURM_CONF; scripts/slurm-local.sh start): Slurm build skipped" | tee -a "$LOG"
fi

"$V" eval --map "$OUT/map-local" --queries "$OUT/city/queries/list.txt" --images "$OUT/city/queries/images" \
  --truth "$OUT/city/queries/truth.txt" --intrinsics "$OUT/city/queries/intrinsics.txt" --out "$OUT/report-local" >> "$LOG" 2>&1

/usr/bin/python3 - "$OUT" "$JOBS" <<'PY'
import json, os, statistics, sys
out, jobs = sys.argv[1], int(sys.argv[2])
times = {}
for line in open(os.path.join(out, "times.txt")):
    k, v = line.split()
    times[k] = float(v)  # the last run of each stage counts
meta = json.load(open(os.path.join(out, "city", "city.json")))
def results(m):
    d = os.path.join(out, m, "work")
    return [json.load(open(os.path.join(d, s, "result.json"))) for s in sorted(os.listdir(d))
            if s.startswith("seg") and os.path.exists(os.path.join(d, s, "result.json"))]
def du(path):
    return sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(path) for f in fs)
local = results("map-local")
images = sum(1 for l in open(os.path.join(out, "city", "gps.csv")) if l.strip() and not l.startswith(("image", "#")))
road_m = meta["counts"]["road_length_m"]
info = json.load(open(os.path.join(out, "map-local.json")))
map_bytes = sum(du(os.path.join(out, "map-local", p)) for p in ("segments", "retrieval", "pq_codebook.vlpq", "manifest.json"))
seg_s = [r["seconds"] for r in local if r.get("ok")]
rep = json.load(open(os.path.join(out, "report-local", "report.json")))
lines = ["# City-scale map build", ""]
lines.append(f"- images {images}, segments {len(local)} ({sum(not r.get('ok') for r in local)} failed), "
             f"points {sum(r.get('points', 0) for r in local)}")
if "render_s" in times: lines.append(f"- render: {times['render_s']:.0f} s")
wall = times["local_build_s"]
lines.append(f"- local build (--jobs {jobs}): wall {wall:.0f} s; median seconds per segment {statistics.median(seg_s):.1f}; "
             f"images per hour per core {images / (wall / 3600) / jobs:.0f}")
stages = ["seconds_features", "seconds_database", "seconds_matching", "seconds_triangulation", "seconds_compression"]
lines.append("- median per segment by stage: " + ", ".join(
    f"{s[8:]} {statistics.median(r[s] for r in local if r.get('ok')):.1f} s" for s in stages))
if road_m:
    lines.append(f"- street length {road_m:.0f} m; map on disk (segments, retrieval, codebook, manifest) {map_bytes / 1e6:.1f} MB "
                 f"= {map_bytes / 1e6 / (road_m / 1000):.1f} MB per km")
else:
    lines.append(f"- map on disk (segments, retrieval, codebook, manifest) {map_bytes / 1e6:.1f} MB")
per_image_s = wall * jobs / images
lines.append(f"- extrapolation to the paper's 227K images at this rate: {227000 * per_image_s / 3600:.0f} core-hours "
             f"= {227000 * per_image_s / 3600 / 24 / jobs:.1f} days on this 2-core machine")
if "slurm_build_s" in times:
    slurm = results("map-slurm")
    same = [(a["id"], a.get("images"), a.get("points")) for a in local] == [(b["id"], b.get("images"), b.get("points")) for b in slurm]
    lines.append(f"- Slurm build (one-node cluster, same machine): wall {times['slurm_build_s']:.0f} s; "
                 f"same segments, images and points per segment as local: {'yes' if same else 'NO'}")
lines.append(f"- queries: {rep['registered']}/{rep['queries']} registered, median position error "
             f"{rep['position_error_m']['median']:.3f} m")
open(os.path.join(out, "report.md"), "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
PY
