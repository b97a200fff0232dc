#!/usr/bin/env bash
# End-to-end demo, from nothing but this repository (run after scripts/setup.sh):
#   1. render a small synthetic street (exact poses, GPS, queries from other cameras);
#   2. build a map: segments of placemarks reconstructed by COLMAP from the known
#      poses, compressed (ITQ codes, PQ codes: 44 bytes per point), geo-registered, plus retrieval;
#   3. localize the queries and print the evaluation report; write the map and
#      the report as one offline HTML page (visloc view: three.js, any browser);
#   4. if ../shared/data is present: import a real COLMAP model with held-out
#      images and localize those photos with our SIFT.
# Everything is written under demo-out/ (git-ignored). About 5 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
VISLOC=build/src/visloc/cli/visloc
DATA=../shared/data
OUT=demo-out
JOBS="${JOBS:-$(nproc)}"
[ -x "$VISLOC" ] || { echo "demo: $VISLOC is missing; run scripts/setup.sh first" >&2; exit 1; }
mkdir -p "$OUT"

echo "== 1. Synthetic city: 120 m of street, 8 views per placemark, 12 queries"
if [ ! -f "$OUT/city/queries/truth.txt" ]; then
  rm -rf "$OUT/city"
  "$VISLOC" synth city --out "$OUT/city" --road-length 120 --headings 8 --elevations 10 --queries 12 --jobs "$JOBS"
fi

echo "== 2. Map: COLMAP per segment from the known poses (resumable)"
"$VISLOC" map build --images "$OUT/city/images" --gps "$OUT/city/gps.csv" --poses known \
  --known-poses "$OUT/city/sparse" --out "$OUT/city-map" --jobs "$JOBS"
"$VISLOC" map info "$OUT/city-map"

echo "== 3. Localize the queries and evaluate"
"$VISLOC" eval --map "$OUT/city-map" --queries "$OUT/city/queries/list.txt" --images "$OUT/city/queries/images" \
  --truth "$OUT/city/queries/truth.txt" --intrinsics "$OUT/city/queries/intrinsics.txt" --out "$OUT/city-report"
echo "(report and plots in $OUT/city-report/)"

echo "== 3a. The map and the report in 3D: one offline HTML file (open it in any browser)"
view_status=0
"$VISLOC" view "$OUT/city-map" --report "$OUT/city-report" --out "$OUT/city-view.html" || view_status=$?
if [ "$view_status" = 3 ]; then
  echo "demo: this build has no three.js (npm ci --prefix src/visloc/viewer, then build again); skipping the viewer"
elif [ "$view_status" != 0 ]; then
  exit "$view_status"
fi

if [ -f build/python/visloc/__init__.py ]; then
  echo "== 3b. The same map from Python (examples/localize.py, import visloc)"
  mapfile -t first < <(head -3 "$OUT/city/queries/list.txt")
  PYTHONPATH="$PWD/build/python" /usr/bin/python3 examples/localize.py "$OUT/city-map" \
    --intrinsics "$OUT/city/queries/intrinsics.txt" "${first[@]/#/$OUT/city/queries/images/}"
fi

SCENE="$DATA/strecha/fountain-P11"
if [ -d "$SCENE" ]; then
  echo "== 4. Real photos: fountain-P11 imported with its held-out queries, localized with our SIFT"
  "$VISLOC" map import --colmap "$SCENE/colmap/sparse" --database "$SCENE/colmap/database.db" \
    --holdout "$SCENE/queries.txt" --out "$OUT/fountain-map" --overwrite
  "$VISLOC" eval --map "$OUT/fountain-map" --queries "$SCENE/queries.txt" --images "$SCENE/images" \
    --truth "$OUT/fountain-map/holdout.txt" --max-features 16384 --out "$OUT/fountain-report"
  if [ "$view_status" = 0 ]; then
    "$VISLOC" view "$OUT/fountain-map" --report "$OUT/fountain-report" --out "$OUT/fountain-view.html"
  fi
else
  echo "demo: $DATA is absent; skipping the real-photo part"
fi
