#!/usr/bin/env bash
# `map build --matcher twoview` (issue #18) on a small synthetic street with
# known poses, segments written with quantized coordinates (issue #15):
#  - every segment is built, is a version 3 file (int16 coordinates) and has points;
#  - the log reports the two-view verification;
#  - the inliers written to COLMAP's database agree with the known poses: at
#    least 80 % of them within 8 px (Sampson) of the true epipolar geometry,
#    over the pairs of different placemarks (same-placemark pairs share a
#    centre: no epipolar geometry to check), and no feature of an image is
#    matched twice in a pair. (On this street of 320 px views, 4 headings,
#    about 90 % are; classic RANSAC's are as well. Before the pairs were
#    verified by their 1-1 inliers, 1m-sprt's were 43 %.)
# Usage: map_build_twoview_test.sh VISLOC   (exit 77: skipped without COLMAP)
set -euo pipefail
V="$1"
command -v colmap > /dev/null || { echo "SKIP: colmap is not installed"; exit 77; }
T="$(mktemp -d)"
cleanup() { pkill -9 -f "$T/" 2> /dev/null || true; rm -rf "$T"; }
trap cleanup EXIT
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
fail() { echo "FAIL: $*"; exit 1; }
"$V" synth city --out "$T/city" --road-length 40 --headings 4 --elevations 10 --size 320x320 --queries 1 \
  --jobs 1 > /dev/null
"$V" map build --images "$T/city/images" --gps "$T/city/gps.csv" --poses known --known-poses "$T/city/sparse" \
  --matcher twoview --point-coordinates int16 --jobs 1 --min-placemarks 3 --max-placemarks 3 --overlap 1 \
  --no-retrieval --pq-training-images 6 --out "$T/map" > "$T/build.log" 2>&1 ||
  { cat "$T/build.log"; fail "the build failed"; }
"$V" map info "$T/map" --json > "$T/info.json"
grep -q "twoview matching (1m-sprt)" "$T"/map/work/seg0000/log.txt || fail "no twoview matching in the segment log"
/usr/bin/python3 - "$T" << 'EOF'
import glob, json, math, sqlite3, struct, sys

root = sys.argv[1]
info = json.load(open(f"{root}/info.json"))
segments = info["segments"]
if len(segments) < 2:
    sys.exit(f"FAIL: {len(segments)} segment(s), expected at least 2")
for s in segments:
    if s.get("format_version") != 3 or s.get("points", 0) < 100:
        sys.exit(f"FAIL: segment {s.get('id')}: version {s.get('format_version')}, {s.get('points')} points")

def quat_to_r(w, x, y, z):
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]

def mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]

def transpose(a):
    return [list(r) for r in zip(*a)]

poses, focal, cx, cy = {}, None, None, None
for line in open(f"{root}/city/sparse/cameras.txt"):
    if line.strip() and not line.startswith("#"):
        p = line.split()  # id PINHOLE w h fx fy cx cy
        focal, cx, cy = float(p[4]), float(p[6]), float(p[7])
for line in open(f"{root}/city/sparse/images.txt"):
    p = line.split()
    if len(p) == 10 and not line.startswith("#"):
        poses[p[9]] = (quat_to_r(*map(float, p[1:5])), [float(v) for v in p[5:8]])
K_inv = [[1 / focal, 0, -cx / focal], [0, 1 / focal, -cy / focal], [0, 0, 1]]

def fundamental(a, b):  # x_b^T F x_a = 0 from the known world-to-camera poses
    Ra, ta = poses[a]
    Rb, tb = poses[b]
    R = mul(Rb, transpose(Ra))
    t = [tb[i] - sum(R[i][k] * ta[k] for k in range(3)) for i in range(3)]
    tx = [[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]
    return mul(transpose(K_inv), mul(mul(tx, R), K_inv))

def sampson(F, x1, x2):
    p1, p2 = (x1[0], x1[1], 1.0), (x2[0], x2[1], 1.0)
    Fx1 = [sum(F[i][k] * p1[k] for k in range(3)) for i in range(3)]
    Ftx2 = [sum(F[k][i] * p2[k] for k in range(3)) for i in range(3)]
    e = sum(p2[i] * Fx1[i] for i in range(3))
    return abs(e) / math.sqrt(Fx1[0] ** 2 + Fx1[1] ** 2 + Ftx2[0] ** 2 + Ftx2[1] ** 2)

checked = within = 0
for db_path in sorted(glob.glob(f"{root}/map/work/seg*/database.db")):
    db = sqlite3.connect(db_path)
    names = dict(db.execute("SELECT image_id, name FROM images"))
    keypoints = {}
    for image_id, rows, cols, data in db.execute("SELECT image_id, rows, cols, data FROM keypoints"):
        values = struct.unpack(f"<{rows * cols}f", data)
        keypoints[image_id] = [values[r * cols:r * cols + 2] for r in range(rows)]
    for pair_id, rows, data, config in db.execute("SELECT pair_id, rows, data, config FROM two_view_geometries"):
        id2, id1 = pair_id % 2147483647, pair_id // 2147483647
        if config not in (2, 3):
            sys.exit(f"FAIL: {db_path}: pair {id1}-{id2} has configuration {config}")
        pairs = struct.unpack(f"<{2 * rows}I", data)
        for column in (0, 1):
            used = pairs[column::2]
            if len(set(used)) != len(used):
                sys.exit(f"FAIL: {db_path}: pair {id1}-{id2} matches a feature twice")
        a, b = names[id1], names[id2]
        if a.split("_")[0] == b.split("_")[0]:
            continue  # same placemark: no baseline
        F = fundamental(a, b)
        for k in range(rows):
            checked += 1
            within += sampson(F, keypoints[id1][pairs[2 * k]], keypoints[id2][pairs[2 * k + 1]]) <= 8.0
if checked < 200:
    sys.exit(f"FAIL: only {checked} inliers between placemarks to check")
if within < 0.8 * checked:
    sys.exit(f"FAIL: {checked - within} of {checked} inliers are more than 8 px from the true epipolar lines")
print(f"{len(segments)} segments (version 3); {within} of {checked} inliers between placemarks "
      f"within 8 px of the true epipolar lines")
EOF
