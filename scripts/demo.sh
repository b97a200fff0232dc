#!/usr/bin/env bash
# The end-to-end demo of what visloc does so far. Run after scripts/setup.sh.
# Writes into demo-out/ (git-ignored).
set -euo pipefail
cd "$(dirname "$0")/.."
VISLOC=build/src/visloc/cli/visloc
DATA=../shared/data
OUT=demo-out
[ -x "$VISLOC" ] || { echo "demo: $VISLOC is missing; run scripts/setup.sh first" >&2; exit 1; }
mkdir -p "$OUT"

if [ -d "$DATA/strecha/fountain-P11" ]; then
  echo "== SIFT features of two real photos (COLMAP-compatible RootSIFT, one thread)"
  "$VISLOC" features "$DATA/strecha/fountain-P11/images/0001.jpg" "$DATA/strecha/fountain-P11/images/0002.jpg" \
    --out "$OUT/features"
  echo
  echo "== Our SIFT queried against COLMAP's SIFT of the same scene (verified matches per image pair)"
  "$VISLOC" bench sift-colmap --scene "$DATA/strecha/fountain-P11"
else
  echo "demo: $DATA is absent; skipping the real-photo part"
fi
