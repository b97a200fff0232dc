#!/usr/bin/env bash
# Builds the seed corpora of the fuzz targets (fuzz/*_fuzzer.cc) and the
# reference files that some targets keep valid beside the fuzzed one:
#   fuzz/make_seeds.sh OUT_DIR
# writes
#   OUT_DIR/<target>/             a few small real files per target
#   OUT_DIR/reference/map/        a small real map (hash rotation "map", 2 segments)
#   OUT_DIR/reference/map/retrieval/  a small retrieval map (k = 4, 16-D)
#   OUT_DIR/reference/colmap/     a small real COLMAP model, .bin and .txt
#   OUT_DIR/reference/pq32_codebook.vlpq  the segment imported with 32-byte PQ codes: its codebook
# Sources: a tiny synthetic street rendered, mapped (COLMAP triangulates the
# known poses) and imported with the project's own CLI, about a minute on 2
# cores; and real files from ../shared/data, read in place, when present.
# Needs build/src/visloc/cli/visloc (built here when missing), colmap and sqlite3.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:?usage: fuzz/make_seeds.sh OUT_DIR}"
VISLOC="${VISLOC:-build/src/visloc/cli/visloc}"
DATA="${VISLOC_SHARED_DATA_DIR:-../shared/data}"
note() { echo "make_seeds: $*" >&2; }
# quietly COMMAND...: runs it with its output in a log, shown when it fails.
quietly() {
  "$@" >"$WORK/command.log" 2>&1 || { tail -20 "$WORK/command.log" >&2; note "failed: $*"; exit 1; }
}

for tool in colmap sqlite3 gzip od awk; do
  command -v "$tool" >/dev/null || { note "$tool is missing (scripts/setup.sh installs it)"; exit 1; }
done
if [ ! -x "$VISLOC" ]; then
  note "building $VISLOC (Release, build/)"
  [ -f build/build.ninja ] || cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
  nice cmake --build build -j "${JOBS:-2}" --target visloc >/dev/null
fi

mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
WORK="$(mktemp -d "${TMPDIR:-/tmp}/visloc-seeds.XXXXXX")"
trap 'rm -rf "$WORK"' EXIT
REF="$OUT/reference"
rm -rf "$REF"
mkdir -p "$REF"

# seed TARGET FILE [NAME]: copies FILE into the target's corpus.
seed() {
  mkdir -p "$OUT/$1"
  cp "$2" "$OUT/$1/${3:-$(basename "$2")}"
}
# seed_with_byte TARGET BYTE FILE NAME: FILE prefixed with one byte (the COLMAP targets' file selector).
seed_with_byte() {
  mkdir -p "$OUT/$1"
  { printf "\\x$2"; cat "$3"; } >"$OUT/$1/$4"
}

# --- 1. A tiny synthetic street: 4 placemarks × 4 views of 320×320, 3 queries.
note "rendering a tiny synthetic street"
quietly "$VISLOC" synth city --out "$WORK/city" --road-length 40 --headings 4 --elevations 10 --size 320x320 \
  --queries 3 --query-sizes 320x240 --quiet --jobs 1

# --- 2. Its map: 2 segments triangulated by COLMAP, one hash rotation for the map.
note "building a 2-segment map (COLMAP triangulation, PQ and ITQ training)"
quietly "$VISLOC" map build --images "$WORK/city/images" --gps "$WORK/city/gps.csv" --poses known \
  --known-poses "$WORK/city/sparse" --out "$WORK/map" --jobs 1 --min-placemarks 2 --max-placemarks 3 \
  --overlap 1 --hash-rotation map --no-retrieval --point-coordinates int16  # version-3 segments (the import: 2)
MAP="$WORK/map"
SEG_MODEL="$MAP/work/seg0001/sparse/0"  # the smaller segment: 8 images
SEG_DB="$MAP/work/seg0001/database.db"

# --- 3. The same segment imported with a rotation of its own.
note "importing one segment's COLMAP model (segment hash rotation)"
quietly "$VISLOC" map import --colmap "$SEG_MODEL" --database "$SEG_DB" --pq-train-database "$SEG_DB" \
  --itq-iterations 10 --out "$WORK/imported"
note "importing it again with 32-byte PQ codes (segment format version 4, codebook version 2)"
quietly "$VISLOC" map import --colmap "$SEG_MODEL" --database "$SEG_DB" --pq-train-database "$SEG_DB" \
  --itq-iterations 10 --pq-bytes 32 --point-coordinates int16 --out "$WORK/imported32"
note "importing it again with residual PQ codes (codebook version 3), trained on one image's descriptors"
sqlite3 "$SEG_DB" "SELECT name FROM images ORDER BY image_id LIMIT 1" >"$WORK/one-image.txt"
quietly "$VISLOC" map import --colmap "$SEG_MODEL" --database "$SEG_DB" --pq-train-database "$SEG_DB" \
  --pq-train-images "$WORK/one-image.txt" --itq-iterations 10 --pq-quantizer residual --pq-residual-splits 4 \
  --out "$WORK/imported_residual"

# --- 4. A small retrieval map of the street's images.
note "building a small retrieval map"
quietly "$VISLOC" retrieval build --images "$WORK/city/images" --gps "$WORK/city/gps.csv" --out "$WORK/retrieval" \
  --k 4 --dims 16 --nlist 1 --pq-bytes 4 --segment-placemarks 2 --overlap 1

# --- Reference files.
mkdir -p "$REF/map" "$REF/colmap"
cp -r "$MAP/manifest.json" "$MAP/pq_codebook.vlpq" "$MAP/hash_rotation.vlitq" "$MAP/segments" \
  "$MAP/descriptors" "$REF/map/"
cp -r "$WORK/retrieval" "$REF/map/retrieval"
cp "$WORK/imported32/pq_codebook.vlpq" "$REF/pq32_codebook.vlpq"
cp "$SEG_MODEL"/*.bin "$REF/colmap/"
quietly colmap model_converter --input_path "$SEG_MODEL" --output_path "$REF/colmap" --output_type TXT

# --- Section files.
for f in "$MAP"/segments/*.vlseg "$WORK"/imported/segments/*.vlseg "$WORK"/imported32/segments/*.vlseg; do
  seed segment "$f" "$(basename "$(dirname "$(dirname "$f")")")-$(basename "$f")"
  seed segment_map_rotation "$f" "$(basename "$(dirname "$(dirname "$f")")")-$(basename "$f")"
done
seed pq_codebook "$MAP/pq_codebook.vlpq" map.vlpq
seed pq_codebook "$WORK/imported/pq_codebook.vlpq" imported.vlpq
seed pq_codebook "$WORK/imported32/pq_codebook.vlpq" imported32.vlpq
seed pq_codebook "$WORK/imported_residual/pq_codebook.vlpq" imported-residual.vlpq
seed hash_rotation "$MAP/hash_rotation.vlitq"
for f in "$MAP"/descriptors/*.vldesc "$WORK"/imported/descriptors/*.vldesc; do
  seed point_descriptors "$f" "$(basename "$(dirname "$(dirname "$f")")")-$(basename "$f")"
done
seed triangulation_embedding "$WORK/retrieval/embedding.vltemb"
seed image_index "$WORK/retrieval/index.vlidx"
for f in images.vlimg index.vlidx embedding.vltemb; do seed retrieval_map "$WORK/retrieval/$f"; done
quietly "$VISLOC" features --out "$WORK/features" --max-features 40 "$WORK/city/images/p00001_h01_e0.jpg"
seed feature_file "$WORK/features/p00001_h01_e0.jpg.vlfeat" synthetic-40.vlfeat
seed feature_file "$(ls "$MAP"/work/features/*.vlfeat | head -1)" synthetic-map.vlfeat
seed section_file "$MAP/segments/0001.vlseg" segment-map-rotation.vlseg
seed section_file "$WORK/imported/segments/0000.vlseg" segment-own-rotation.vlseg
seed section_file "$MAP/hash_rotation.vlitq" rotation.vlitq
seed section_file "$MAP/descriptors/0001.vldesc" descriptors.vldesc
seed section_file "$WORK/features/p00001_h01_e0.jpg.vlfeat" features.vlfeat
seed section_file "$WORK/retrieval/embedding.vltemb" embedding.vltemb
seed section_file "$WORK/retrieval/index.vlidx" index.vlidx
seed section_file "$WORK/retrieval/images.vlimg" images.vlimg
seed section_file "$WORK/imported/pq_codebook.vlpq" codebook.vlpq
seed map_manifest "$MAP/manifest.json" map-manifest.json
seed map_manifest "$WORK/imported/manifest.json" imported-manifest.json

# --- COLMAP models: selector byte 0 cameras, 1 images, 2 points3D.
i=0
for f in cameras images points3D; do
  seed_with_byte colmap_binary "0$i" "$REF/colmap/$f.bin" "segment-$f.bin"
  seed_with_byte colmap_text "0$i" "$REF/colmap/$f.txt" "segment-$f.txt"
  i=$((i + 1))
done
for f in cameras images points3D; do seed_with_byte colmap_text "0$i" "$WORK/city/sparse/$f.txt" "known-$f.txt"; i=$((i + 1)); done
seed colmap_images_txt_poses "$REF/colmap/images.txt" segment-images.txt
seed colmap_images_txt_poses "$WORK/city/sparse/images.txt" known-images.txt

# A COLMAP database cut to 3 images of at most 48 features and 24 matches per pair.
trim_database() {  # SRC DST
  sqlite3 "$1" ".backup '$2'"
  sqlite3 "$2" "PRAGMA journal_mode=DELETE;
    DELETE FROM images WHERE image_id NOT IN (SELECT image_id FROM images ORDER BY image_id LIMIT 3);
    DELETE FROM cameras WHERE camera_id NOT IN (SELECT camera_id FROM images);
    DELETE FROM keypoints WHERE image_id NOT IN (SELECT image_id FROM images);
    DELETE FROM descriptors WHERE image_id NOT IN (SELECT image_id FROM images);
    UPDATE keypoints SET data = substr(data, 1, min(rows, 48) * cols * 4), rows = min(rows, 48);
    UPDATE descriptors SET data = substr(data, 1, min(rows, 48) * cols), rows = min(rows, 48);
    DELETE FROM matches;
    DELETE FROM two_view_geometries WHERE pair_id / 2147483647 NOT IN (SELECT image_id FROM images)
      OR pair_id % 2147483647 NOT IN (SELECT image_id FROM images);
    UPDATE two_view_geometries SET data = substr(data, 1, min(rows, 24) * 8), rows = min(rows, 24);
    VACUUM;" >/dev/null
}
trim_database "$SEG_DB" "$WORK/segment.db"
seed colmap_database "$WORK/segment.db" synthetic-segment.db

# Bundler: bundle.out and list exported by COLMAP; Lowe key files made from
# the database's keypoints and descriptors (first 30 of an image).
quietly colmap model_converter --input_path "$SEG_MODEL" --output_path "$WORK/bundler" --output_type Bundler
seed bundler_file "$WORK/bundler.bundle.out" segment-bundle.out
gzip -c "$WORK/bundler.bundle.out" >"$WORK/bundle.out.gz"
seed bundler_file "$WORK/bundle.out.gz" segment-bundle.out.gz
seed bundler_list "$WORK/bundler.list.txt" segment-list.txt
make_key_file() {  # DB IMAGE_ID OUT
  local cols
  cols=$(sqlite3 "$1" "SELECT cols FROM keypoints WHERE image_id = $2")
  sqlite3 "$1" "SELECT writefile('$WORK/kp.bin', data) FROM keypoints WHERE image_id = $2;
                SELECT writefile('$WORK/desc.bin', data) FROM descriptors WHERE image_id = $2;" >/dev/null
  head -c $((30 * cols * 4)) "$WORK/kp.bin" | od -An -v -t f4 -w$((cols * 4)) >"$WORK/kp.txt"
  head -c $((30 * 128)) "$WORK/desc.bin" | od -An -v -t u1 -w128 >"$WORK/desc.txt"
  paste -d'|' "$WORK/kp.txt" "$WORK/desc.txt" | awk -F'|' -v cols="$cols" '
    BEGIN { n = 0 }
    { line[++n] = $0 }
    END {
      print n, 128
      for (i = 1; i <= n; ++i) {
        split(line[i], part, "|"); split(part[1], k, " "); split(part[2], d, " ")
        scale = 1.0; orientation = 0.0
        if (cols == 4) { scale = k[3]; orientation = k[4] }
        if (cols == 6) { scale = sqrt(k[3] * k[3] + k[5] * k[5]); orientation = atan2(k[5], k[3]) }
        # Lowe: row col scale orientation (towards -y), pixel centres at integers.
        printf "%.2f %.2f %.2f %.3f\n", k[2] - 0.5, k[1] - 0.5, scale, -orientation
        for (j = 1; j <= 128; ++j) printf "%d%s", d[j], (j % 20 == 0 || j == 128) ? "\n" : " "
      }
    }' >"$3"
}
make_key_file "$WORK/segment.db" 1 "$WORK/synthetic.key"
seed lowe_key "$WORK/synthetic.key" synthetic.key
gzip -c "$WORK/synthetic.key" >"$WORK/synthetic.key.gz"
seed lowe_key "$WORK/synthetic.key.gz" synthetic.key.gz

# Text lists of the synthetic street.
seed gps_csv "$WORK/city/gps.csv" city-gps.csv
seed gps_csv "$WORK/city/queries/gps.csv" queries-gps.csv
seed pose_list "$WORK/city/queries/truth.txt" queries-truth.txt
seed intrinsics_list "$WORK/city/queries/intrinsics.txt" queries-intrinsics.txt
seed name_list "$WORK/city/queries/list.txt" queries-list.txt
seed name_list "$WORK/bundler.list.txt" bundler-list.txt

# --- Real data sets, read in place (small files, or their first lines).
if [ -d "$DATA/strecha/fountain-P11" ]; then
  note "adding real files from $DATA"
  S="$DATA/strecha/fountain-P11"
  for scene in fountain-P11 entry-P10; do
    seed gps_csv "$DATA/strecha/$scene/gps.csv" "$scene-gps.csv"
    seed pose_list "$DATA/strecha/$scene/truth.txt" "$scene-truth.txt"
    seed name_list "$DATA/strecha/$scene/queries.txt" "$scene-queries.txt"
  done
  seed gps_csv "$DATA/opensfm-lund/gps.csv" lund-gps.csv
  head -40 "$DATA/kitti07/gps.csv" >"$WORK/kitti-gps.csv" && seed gps_csv "$WORK/kitti-gps.csv"
  head -40 "$DATA/kitti07/truth.txt" >"$WORK/kitti-truth.txt" && seed pose_list "$WORK/kitti-truth.txt"
  head -40 "$DATA/kitti07/queries.txt" >"$WORK/kitti-queries.txt" && seed name_list "$WORK/kitti-queries.txt"
  seed_with_byte colmap_binary 00 "$S/colmap/sparse/cameras.bin" fountain-cameras.bin
  seed_with_byte colmap_text 00 "$S/colmap/sparse/cameras.txt" fountain-cameras.txt
  # COLMAP 3.8's own database (6-column affine keypoints), cut down.
  trim_database "$S/colmap/database.db" "$WORK/fountain.db"
  seed colmap_database "$WORK/fountain.db" fountain.db
  make_key_file "$WORK/fountain.db" 1 "$WORK/fountain.key"
  seed lowe_key "$WORK/fountain.key" fountain-0000.key
  quietly "$VISLOC" features --out "$WORK/features" --max-features 40 --max-side 512 "$S/images/0000.jpg"
  seed feature_file "$WORK/features/0000.jpg.vlfeat" fountain-40.vlfeat
  quietly "$VISLOC" features --out "$WORK/features" --max-features 40 --max-side 640 "$DATA/kitti07/images/000000.png"
  seed feature_file "$WORK/features/000000.png.vlfeat" kitti-40.vlfeat
else
  note "SKIP: $DATA is absent; seeds come from the synthetic street and its map only"
fi
du -sh "$OUT" | awk '{print "make_seeds: " $1 " of seeds and references in '"$OUT"'"}' >&2
